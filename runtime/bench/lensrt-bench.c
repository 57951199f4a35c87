/* lensrt-bench: splats per second of lensrt against the paper's algorithm as a plain
 * scalar double loop, measured in the same run (the machines are shared and noisy, so
 * the ratio is the figure to quote; absolute numbers are context).
 *
 *   lensrt-bench --json build/bench/lensrt.json
 *
 * A splat is one aperture sample evaluated at one pixel for one wavelength.
 *
 * The scene follows the paper's Figure 7: the default lens (0001), a point light off
 * the axis at infinity (field (6, 4) deg), a 1440 x 1080 frame over 0.3 x 0.225 mm centred
 * on the light's image point, sensor shift 0.2 mm, 16 wavelengths, f/2, f/8 and f/32.
 *
 * lensrt side: lensrt_render_run() with the default precision and sampler, one pass of
 * 16384 samples per wavelength; clipping at both pupils and the transmittance are
 * evaluated inside; splats per second from bench_stats(). By default it
 * renders one pixel per 12 x 12 block of the frame (120 x 90 pixels over the same
 * window): lensrt's per-pixel work (the window's phase basis, the pruned terms) depends
 * on the window and not on the pixel pitch; `--stride 1` renders every pixel (about
 * 144 times longer: minutes per f-number on 2 cores).
 *
 * Baseline side: the paper's Algorithm (section 3.2) as written, with the generated
 * Horner code of the same lens (lens0001_P_o_d, lens0001_P_s_d): for every sample a
 * random point in the stop disc and one of the 16 wavelengths in turn, P_o once (outer
 * pupil clip at the first surface's housing, tau_o, phi_o), then for every pixel of a
 * grid spread over the same frame P_s (inner pupil clip at the last surface's housing,
 * tau_i, phi_i), phase 2 pi / lambda (phi_o + phi_i) in double, amplitude
 * sqrt(tau_o tau_i), cos and sin from libm into that pixel's phasor sum for that
 * wavelength. It runs with OpenMP over pixels at the same thread count as lensrt, right
 * before and right after every lensrt render (the ratio of each render is against the
 * baseline that bracketed it; medians over the repetitions are reported), and
 * single-threaded for context.
 *
 * GL side (`--device gl` or `both`, the default): the same scene with device
 * LENSRT_DEVICE_GL, once per f-number after the lensrt repetitions, bracketed by the
 * baseline like them. The first run() of a GL render finds the basis terms every pixel
 * needs and compiles the splat shaders for them (one per wavelength at most); that is
 * set-up, not splatting, so each GL render first runs an untimed warm-up of `--gl-warmup`
 * samples per wavelength (default 256: it pays every compile and the term search whatever
 * its size) and the figure is the second run() call, from the difference of the render's
 * stats. A software GL (llvmpipe) is an order of magnitude slower than the CPU path, so GL
 * renders one pixel per 36 x 36 block (40 x 30 pixels over the same window; `--gl-stride`;
 * its splats per second do not depend on the pitch either) and `--gl-samples` per
 * wavelength (default 16384, one pass). Without a GL device the GL part is skipped with
 * the reason; the CPU part still runs.
 *
 * Tiles side (`--tile WxH`, default 32x32; 0x0 skips it): right after each repetition's
 * bracketing baseline, the same render (same seed) scheduled by the host as
 * lensrt_render_tiles_begin, lensrt_render_tile on that many pthreads as lensrt's OpenMP
 * threads (tiles of W x H pixels, smaller at the right and bottom edges, taken in row-major
 * order from a shared counter), lensrt_render_tiles_end; its splats per second (wall time
 * from begin to end) against the run() of the same repetition, and whether its image
 * equals run()'s bit for bit. Every tile draws and prepares the samples itself: the cost
 * of one 1 x 1 tile (that preparation, for every wavelength) is measured once per
 * f-number. */
#include "lensrt.h"
#include "lens0001.h"

#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#ifdef LENSRT_BENCH_OPENMP
#include <omp.h>
#endif

#ifndef LENSRT_GENERATED_DIR
#define LENSRT_GENERATED_DIR "generated"
#endif
#define DEFAULT_TABLE LENSRT_GENERATED_DIR "/0001-angenieux-double-gauss/lens0001.table"

#define PI 3.14159265358979323846
#define NM_PER_MM 1e6
#define MAX_F 8
#define MAX_WL 256
#define MAX_REP 32
#define DEFAULT_STRIDE 12
#define DEFAULT_GL_STRIDE 36
#define DEFAULT_GL_WARMUP 256

/* ------------------------------------------------------------------ helpers ----- */

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static int max_threads(void)
{
#ifdef LENSRT_BENCH_OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}

static uint64_t splitmix64(uint64_t *state)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

static double uniform01(uint64_t *state) { return (double)(splitmix64(state) >> 11) * (1.0 / 9007199254740992.0); }

static void usage(FILE *f)
{
    fprintf(f,
        "usage: lensrt-bench [options]\n"
        "  --json FILE            write the results as JSON\n"
        "  --table FILE           lens table (default: %s);\n"
        "                         the baseline always uses the compiled-in lens0001 polynomials\n"
        "  --resolution WxH       pixels of the frame (default 1440x1080)\n"
        "  --size WxH             the frame's window on the sensor in mm (default 0.3x0.225)\n"
        "  --stride K             lensrt renders one pixel per K x K block of the frame, (W/K) x (H/K)\n"
        "                         pixels over the same window (default %d; 1: every pixel). Its\n"
        "                         per-pixel work depends on the window, not on the pixel pitch, so\n"
        "                         this measures the frame's splats per second in 1/K^2 of the time\n"
        "  --samples N            aperture samples per wavelength per render (default 16384, one pass:\n"
        "                         the per-pixel set-up is paid once per pass)\n"
        "  --repeats R            renders per f-number, each bracketed by the baseline; medians are\n"
        "                         reported (default 3)\n"
        "  --f-numbers A,B,..     (default 2,8,32; the first 8 in the list, else the first, is the headline)\n"
        "  --wavelengths N        (default 16)\n"
        "  --field X,Y            light direction in degrees (default 6,4), at infinity\n"
        "  --focus Z              sensor shift z_S in mm (default 0.2)\n"
        "  --baseline-grid BxC    baseline pixels, a grid spread over the frame (default 8x8)\n"
        "  --baseline-seconds T   seconds of baseline per repetition, half right before and half right\n"
        "                         after the render (default 1)\n"
        "  --seed S               (default 1)\n"
        "  --device cpu|gl|both   what to measure against the baseline (default both); without a GL\n"
        "                         device `both` skips GL and says why, `gl` exits with status 3\n"
        "  --gl-platform auto|egl-device|egl-surfaceless|glfw\n"
        "                         where the GL context comes from (default auto: in that order)\n"
        "  --gl-stride K          GL renders one pixel per K x K block of the frame (default %d: a\n"
        "                         software GL is an order of magnitude slower than the CPU path)\n"
        "  --gl-samples N         aperture samples per wavelength of the timed GL run (default 16384)\n"
        "  --gl-warmup N          samples per wavelength of the untimed first run() of each GL render,\n"
        "                         which compiles the shaders and finds the terms per pixel (default %d;\n"
        "                         0: time the first call, set-up included)\n"
        "  --tile WxH             host-scheduled tiles of W x H pixels on as many pthreads as\n"
        "                         lensrt's OpenMP threads, against run() (default 32x32; 0x0: skip)\n",
        DEFAULT_TABLE, DEFAULT_STRIDE, DEFAULT_GL_STRIDE, DEFAULT_GL_WARMUP);
}

static int parse_pair_d(const char *s, char sep, double *a, double *b)
{
    char *end;
    if (!s) return 0;
    errno = 0;
    *a = strtod(s, &end);
    if (end == s || *end != sep) return 0;
    s = end + 1;
    *b = strtod(s, &end);
    return end != s && *end == '\0' && errno == 0 && isfinite(*a) && isfinite(*b);
}

static int parse_pair_i(const char *s, char sep, long *a, long *b)
{
    char *end;
    if (!s) return 0;
    errno = 0;
    *a = strtol(s, &end, 10);
    if (end == s || *end != sep) return 0;
    s = end + 1;
    *b = strtol(s, &end, 10);
    return end != s && *end == '\0' && errno == 0;
}

static int parse_d(const char *s, double *v)
{
    char *end;
    if (!s) return 0;
    errno = 0;
    *v = strtod(s, &end);
    return end != s && *end == '\0' && errno == 0 && isfinite(*v);
}

/* A `lens KEY VALUE` line of a lensfit-poly-table (version 2). */
static int table_lens_value(const char *path, const char *key, double *out)
{
    FILE *f = fopen(path, "r");
    char line[512];
    size_t n = strlen(key);
    int found = 0;
    if (!f) return 0;
    while (fgets(line, sizeof line, f)) {
        if (strncmp(line, "system ", 7) == 0) break; /* lens lines come before the systems */
        if (strncmp(line, "lens ", 5) == 0 && strncmp(line + 5, key, n) == 0 && line[5 + n] == ' ') {
            found = parse_d(strtok(line + 6 + n, " \r\n"), out);
            break;
        }
    }
    fclose(f);
    return found;
}

static void cpu_model(char *buf, size_t size)
{
    FILE *f = fopen("/proc/cpuinfo", "r");
    char line[512];
    snprintf(buf, size, "unknown");
    if (!f) return;
    while (fgets(line, sizeof line, f)) {
        char *colon = strchr(line, ':');
        if (strncmp(line, "model name", 10) == 0 && colon) {
            char *v = colon + 1, *e;
            while (*v == ' ' || *v == '\t') v++;
            e = v + strlen(v);
            while (e > v && (e[-1] == '\n' || e[-1] == '\r' || e[-1] == ' ')) *--e = '\0';
            snprintf(buf, size, "%s", v);
            break;
        }
    }
    fclose(f);
}

static void json_string(FILE *f, const char *s)
{
    fputc('"', f);
    for (; *s; s++) {
        if (*s == '"' || *s == '\\') fprintf(f, "\\%c", *s);
        else if ((unsigned char)*s < 0x20) fprintf(f, "\\u%04x", (unsigned)(unsigned char)*s);
        else fputc(*s, f);
    }
    fputc('"', f);
}

/* --------------------------------------------------------------- the baseline ----- */

typedef struct baseline_scene {
    double light_x, light_y;     /* direction cosines of the light */
    double focus_mm;             /* z_S */
    double stop_radius_mm;
    double housing_first_mm, housing_last_mm;
    int n_wl;
    const double *wavelengths_nm;
    int n_pix;
    const double *pix_xy;        /* sensor points (mm), x y pairs */
} baseline_scene;

typedef struct baseline_result {
    double seconds, splats, splats_per_second;
    long samples;
    int threads;
    double coherence_center;     /* |sum X| / sum |X| at the window centre, mean over wavelengths */
    double clipped;              /* splats clipped at either housing */
} baseline_result;

/* Per sample: the stop point, the wavelength index and what P_o gave. */
typedef struct sample_po {
    double xa, ya, lambda_nm, lambda_mm, amp_o, phi_o;
    int w, clipped;
} sample_po;

/* The paper's algorithm, for `chunk` samples per round until `min_seconds` have passed.
 * acc[(p * n_wl + w) * 3 + 0..2]: sum re, sum im, sum |X| per pixel and wavelength. */
static baseline_result run_baseline(const baseline_scene *sc, int threads, int chunk, double min_seconds,
                                    uint64_t seed, int center_pixel)
{
    baseline_result res;
    sample_po *s = malloc(sizeof *s * (size_t)chunk);
    double *acc = calloc((size_t)sc->n_pix * (size_t)sc->n_wl * 3, sizeof(double));
    uint64_t rng = seed * 0x9E3779B97F4A7C15ull + 12345u;
    const double r2first = sc->housing_first_mm * sc->housing_first_mm;
    const double r2last = sc->housing_last_mm * sc->housing_last_mm;
    long k_total = 0;
    double t0, elapsed = 0.0, clipped = 0.0;
    memset(&res, 0, sizeof res);
    if (!s || !acc) {
        free(s);
        free(acc);
        res.seconds = -1;
        return res;
    }
    t0 = now_seconds();
    do {
        long j;
        int p;
        // P_o once per sample
        for (j = 0; j < chunk; j++) {
            double in[lens0001_P_o_N_IN], out[lens0001_P_o_N_OUT], x, y;
            do {
                x = 2.0 * uniform01(&rng) - 1.0;
                y = 2.0 * uniform01(&rng) - 1.0;
            } while (x * x + y * y > 1.0);
            s[j].xa = x * sc->stop_radius_mm;
            s[j].ya = y * sc->stop_radius_mm;
            s[j].w = (int)((k_total + j) % sc->n_wl);
            s[j].lambda_nm = sc->wavelengths_nm[s[j].w];
            s[j].lambda_mm = s[j].lambda_nm / NM_PER_MM;
            in[0] = sc->light_x;
            in[1] = sc->light_y;
            in[2] = 0.0; /* u_O = 1 / distance: infinity */
            in[3] = s[j].xa;
            in[4] = s[j].ya;
            in[5] = s[j].lambda_nm;
            lens0001_P_o_d(in, out);
            s[j].clipped = out[0] * out[0] + out[1] * out[1] > r2first;
            s[j].amp_o = out[2] > 0 ? out[2] : 0.0;
            s[j].phi_o = out[3];
        }
        // P_s per splat; every pixel owns its sums
#ifdef LENSRT_BENCH_OPENMP
#pragma omp parallel for schedule(static) num_threads(threads) reduction(+ : clipped)
#endif
        for (p = 0; p < sc->n_pix; p++) {
            double in[lens0001_P_s_N_IN], out[lens0001_P_s_N_OUT];
            long i;
            in[0] = sc->pix_xy[2 * p];
            in[1] = sc->pix_xy[2 * p + 1];
            in[2] = sc->focus_mm;
            for (i = 0; i < chunk; i++) {
                double tau, amp, phase;
                double *a;
                if (s[i].clipped) {
                    clipped += 1.0;
                    continue;
                }
                in[3] = s[i].xa;
                in[4] = s[i].ya;
                in[5] = s[i].lambda_nm;
                lens0001_P_s_d(in, out);
                if (out[0] * out[0] + out[1] * out[1] > r2last) {
                    clipped += 1.0;
                    continue;
                }
                tau = s[i].amp_o * out[2];
                amp = sqrt(tau > 0 ? tau : 0.0);
                phase = 2.0 * PI / s[i].lambda_mm * (s[i].phi_o + out[3]);
                a = acc + ((size_t)p * (size_t)sc->n_wl + (size_t)s[i].w) * 3;
                a[0] += amp * cos(phase);
                a[1] += amp * sin(phase);
                a[2] += amp;
            }
        }
        k_total += chunk;
        elapsed = now_seconds() - t0;
    } while (elapsed < min_seconds);
    (void)threads;
    res.seconds = elapsed;
    res.samples = k_total;
    res.splats = (double)k_total * (double)sc->n_pix;
    res.splats_per_second = res.splats / elapsed;
    res.threads = threads;
    res.clipped = clipped;
    {
        int w;
        double c = 0.0;
        for (w = 0; w < sc->n_wl; w++) {
            const double *a = acc + ((size_t)center_pixel * (size_t)sc->n_wl + (size_t)w) * 3;
            c += a[2] > 0 ? hypot(a[0], a[1]) / a[2] : 0.0;
        }
        res.coherence_center = c / sc->n_wl;
    }
    free(s);
    free(acc);
    return res;
}

/* Two measurements of the same baseline as one. */
static baseline_result combine(const baseline_result *a, const baseline_result *b)
{
    baseline_result c = *a;
    c.seconds = a->seconds + b->seconds;
    c.samples = a->samples + b->samples;
    c.splats = a->splats + b->splats;
    c.splats_per_second = c.splats / c.seconds;
    c.coherence_center = 0.5 * (a->coherence_center + b->coherence_center);
    c.clipped = a->clipped + b->clipped;
    return c;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

static double median(const double *v, int n)
{
    double s[MAX_REP];
    int i;
    for (i = 0; i < n; i++) s[i] = v[i];
    qsort(s, (size_t)n, sizeof(double), cmp_double);
    return n % 2 ? s[n / 2] : 0.5 * (s[n / 2 - 1] + s[n / 2]);
}

/* ------------------------------------------------------------------- main ----- */

typedef struct f_result {
    double f_number;
    int reps;
    lensrt_render_stats stats;               /* of the last repetition */
    double sps[MAX_REP], seconds[MAX_REP];   /* lensrt, per repetition */
    baseline_result baseN[MAX_REP];          /* the baseline bracketing each repetition */
    double ratio[MAX_REP];
    baseline_result base1;                   /* single thread, before and after the repetitions */
    double sps_med, baseN_med, ratio_med;
    /* host-scheduled tiles, per repetition: splats per second, / run() of the repetition */
    double tile_sps[MAX_REP], tile_seconds[MAX_REP], tile_ratio[MAX_REP];
    int tile_identical;                      /* every repetition's image equal to run()'s */
    double tile_sps_med, tile_ratio_med, one_tile_seconds;
} f_result;

/* Host-scheduled tiles: a pool of pthreads taking W x H tiles from a shared counter. */
typedef struct tile_pool {
    lensrt_render render;
    int width, height, tw, th, nx, n, next;
    lensrt_result first_error;
    pthread_mutex_t lock;
} tile_pool;

static void *tile_worker(void *arg)
{
    tile_pool *p = arg;
    for (;;) {
        int k, x0, y0;
        lensrt_result r;
        pthread_mutex_lock(&p->lock);
        k = p->next < p->n ? p->next++ : -1;
        pthread_mutex_unlock(&p->lock);
        if (k < 0) return NULL;
        x0 = (k % p->nx) * p->tw;
        y0 = (k / p->nx) * p->th;
        r = lensrt_render_tile(p->render, x0, y0, x0 + p->tw <= p->width ? p->tw : p->width - x0,
                               y0 + p->th <= p->height ? p->th : p->height - y0);
        if (r != LENSRT_SUCCESS) {
            pthread_mutex_lock(&p->lock);
            if (p->first_error == LENSRT_SUCCESS) p->first_error = r;
            pthread_mutex_unlock(&p->lock);
        }
    }
}

/* One tile-scheduled render of `samples` per wavelength on `threads` pthreads; the
 * number of tiles in *n_tiles. */
static lensrt_result run_tiles(lensrt_render render, uint64_t samples, int width, int height, int tw, int th,
                               int threads, int *n_tiles)
{
    pthread_t th_[64];
    tile_pool p;
    lensrt_result r;
    int i, started = 0;
    if (threads > 64) threads = 64;
    memset(&p, 0, sizeof p);
    p.render = render;
    p.width = width;
    p.height = height;
    p.tw = tw;
    p.th = th;
    p.nx = (width + tw - 1) / tw;
    p.n = p.nx * ((height + th - 1) / th);
    *n_tiles = p.n;
    if ((r = lensrt_render_tiles_begin(render, samples)) != LENSRT_SUCCESS) return r;
    pthread_mutex_init(&p.lock, NULL);
    for (i = 0; i < threads; i++) started += pthread_create(&th_[started], NULL, tile_worker, &p) == 0;
    if (started == 0) tile_worker(&p); /* no thread could be made: the caller's alone */
    for (i = 0; i < started; i++) pthread_join(th_[i], NULL);
    pthread_mutex_destroy(&p.lock);
    r = lensrt_render_tiles_end(render);
    return p.first_error != LENSRT_SUCCESS ? p.first_error : r;
}

/* Seconds of one 1 x 1 tile: drawing and preparing every wavelength's samples, which each
 * tile repeats, plus one pixel's splats. The session is then refused (the other pixels
 * are not covered) and the render left as it was. */
static double one_tile_seconds(lensrt_context ctx, const lensrt_render_desc *desc, uint64_t samples)
{
    lensrt_render render = NULL;
    double t0, t1;
    if (lensrt_render_create(ctx, desc, &render) != LENSRT_SUCCESS) return -1.0;
    if (lensrt_render_tiles_begin(render, samples) != LENSRT_SUCCESS) {
        lensrt_render_destroy(render);
        return -1.0;
    }
    t0 = now_seconds();
    lensrt_render_tile(render, 0, 0, 1, 1);
    t1 = now_seconds();
    lensrt_render_tiles_end(render); /* refused: 1 pixel of many */
    lensrt_render_destroy(render);
    return t1 - t0;
}

/* Whether two renders' images are equal bit for bit (-1: could not compare). */
static int same_image(lensrt_render a, lensrt_render b, size_t count)
{
    float *ia = malloc(sizeof(float) * count), *ib = malloc(sizeof(float) * count);
    int same = -1;
    if (ia && ib && lensrt_render_image(a, ia, count) == LENSRT_SUCCESS && lensrt_render_image(b, ib, count) == LENSRT_SUCCESS)
        same = memcmp(ia, ib, sizeof(float) * count) == 0;
    free(ia);
    free(ib);
    return same;
}

/* The render's stats into a struct that may have been zeroed with its holder. */
static lensrt_result bench_stats(lensrt_render render, lensrt_render_stats *st)
{
    st->struct_size = sizeof *st;
    return lensrt_render_get_stats(render, st);
}

static int fail(lensrt_context ctx, const char *what, lensrt_result r)
{
    fprintf(stderr, "lensrt-bench: %s: %s: %s\n", what, lensrt_result_string(r), ctx ? lensrt_context_last_error(ctx) : "");
    return 1;
}

/* The GL measurement of one f-number. */
typedef struct gl_result {
    double f_number;
    double sps, seconds, splats;             /* of the timed run() */
    double setup_seconds;                    /* render_create and the warm-up run() */
    lensrt_render_stats stats;               /* after the timed run */
    baseline_result base;                    /* the baseline that bracketed it */
    double ratio_base, ratio_cpu;            /* ratio_cpu < 0: no CPU figure */
} gl_result;

/* One GL render: create, the warm-up run() (untimed), then the timed run(); splats and
 * seconds of the timed call are the difference of the render's stats around it. */
static lensrt_result run_gl(lensrt_context ctx, const lensrt_render_desc *desc, long long warmup, long long samples,
                            gl_result *gr)
{
    lensrt_render render = NULL;
    lensrt_render_stats s0;
    lensrt_result r;
    double t0 = now_seconds();
    memset(&s0, 0, sizeof s0);
    s0.struct_size = sizeof s0;
    if ((r = lensrt_render_create(ctx, desc, &render)) != LENSRT_SUCCESS) return r;
    if (warmup > 0 && (r = lensrt_render_run(render, (uint64_t)warmup, NULL, NULL)) == LENSRT_SUCCESS)
        bench_stats(render, &s0);
    gr->setup_seconds = now_seconds() - t0;
    if (r == LENSRT_SUCCESS) r = lensrt_render_run(render, (uint64_t)samples, NULL, NULL);
    if (r == LENSRT_SUCCESS) {
        bench_stats(render, &gr->stats);
        gr->splats = (double)(gr->stats.splats - s0.splats);
        gr->seconds = gr->stats.seconds - s0.seconds;
        gr->sps = gr->splats / gr->seconds;
    }
    lensrt_render_destroy(render);
    return r;
}

/* The context's last error on one line (the GL device lists every platform it tried). */
static void last_error_line(lensrt_context ctx, lensrt_result r, char *buf, size_t size)
{
    const char *e = lensrt_context_last_error(ctx);
    char *p;
    snprintf(buf, size, "%s: %s", lensrt_result_string(r), e[0] ? e : "no message");
    for (p = buf; *p; p++)
        if (*p == '\n' || *p == '\r') *p = ' ';
}

/* A number, or null where there is none (`--device gl` has no lensrt cpu figures). */
static void json_num(FILE *f, double v, int valid)
{
    if (valid && isfinite(v)) fprintf(f, "%.17g", v);
    else fputs("null", f);
}

static void json_list(FILE *f, const double *v, int n)
{
    int i;
    fputc('[', f);
    for (i = 0; i < n; i++) fprintf(f, "%s%.17g", i ? ", " : "", v[i]);
    fputc(']', f);
}

int main(int argc, char **argv)
{
    const char *json = NULL, *table = DEFAULT_TABLE;
    long width = 1440, height = 1080, stride = DEFAULT_STRIDE, rw, rh, gx = 8, gy = 8, n_wl = 16, reps = 3;
    double size_x = 0.3, size_y = 0.225, field_x = 6.0, field_y = 4.0, focus = 0.2, base_seconds = 1.0;
    double f_numbers[MAX_F] = {2.0, 8.0, 32.0};
    int n_f = 3, i, k, head = -1, threads = max_threads(), center_pixel, status = 1;
    long long samples = 16384, seed = 1;
    // GL: what to measure, where its context comes from, its pixel grid and sample counts
    int do_cpu = 1, do_gl = 1, gl_ok = 0;
    long gl_stride = DEFAULT_GL_STRIDE, gw = 0, gh = 0;
    long tile_w = 32, tile_h = 32;           /* host-scheduled tiles (0 x 0: not measured) */
    long long gl_samples = 16384, gl_warmup = DEFAULT_GL_WARMUP;
    const char *device_arg = "both";
    lensrt_gl_platform gl_platform = LENSRT_GL_PLATFORM_AUTO;
    lensrt_gl_info gl_info;
    char gl_why[1024] = "";                  /* why GL was skipped or failed */
    gl_result glres[MAX_F];
    int n_gl = 0, gl_failed = 0;             /* GL results so far; a GL render failed */
    double housing_first, housing_last, stop_f1, center[2], wl[MAX_WL], *pix = NULL, t_start = now_seconds();
    char cpu[256], date[64];
    lensrt_context ctx = NULL;
    lensrt_context_init init;
    lensrt_lens lens = NULL;
    lensrt_lens_info info;
    lensrt_light light;
    lensrt_result r;
    f_result res[MAX_F];
    time_t t = time(NULL);
    struct tm tmv;

    for (i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        const char *expected = NULL;        /* what a word-valued option takes */
        int ok = 1;
        if (strcmp(a, "-h") == 0 || strcmp(a, "--help") == 0) {
            usage(stdout);
            return 0;
        }
        if (!v) ok = 0;
        else if (strcmp(a, "--json") == 0) json = v;
        else if (strcmp(a, "--table") == 0) table = v;
        else if (strcmp(a, "--resolution") == 0)
            ok = parse_pair_i(v, 'x', &width, &height) && width > 0 && height > 0 && width <= 65536 && height <= 65536;
        else if (strcmp(a, "--size") == 0) ok = parse_pair_d(v, 'x', &size_x, &size_y) && size_x > 0 && size_y > 0;
        else if (strcmp(a, "--field") == 0) ok = parse_pair_d(v, ',', &field_x, &field_y);
        else if (strcmp(a, "--focus") == 0) ok = parse_d(v, &focus);
        else if (strcmp(a, "--tile") == 0)
            ok = parse_pair_i(v, 'x', &tile_w, &tile_h) && ((tile_w > 0 && tile_h > 0) || (tile_w == 0 && tile_h == 0));
        else if (strcmp(a, "--baseline-grid") == 0) ok = parse_pair_i(v, 'x', &gx, &gy) && gx > 0 && gy > 0 && gx * gy <= 65536;
        else if (strcmp(a, "--baseline-seconds") == 0) ok = parse_d(v, &base_seconds) && base_seconds >= 0;
        else if (strcmp(a, "--device") == 0) {
            expected = "expected cpu, gl or both";
            device_arg = v;
            do_cpu = strcmp(v, "gl") != 0;
            do_gl = strcmp(v, "cpu") != 0;
            ok = !do_cpu || !do_gl || strcmp(v, "both") == 0;
        } else if (strcmp(a, "--gl-platform") == 0) {
            expected = "expected auto, egl-device, egl-surfaceless or glfw";
            if (strcmp(v, "auto") == 0) gl_platform = LENSRT_GL_PLATFORM_AUTO;
            else if (strcmp(v, "egl-device") == 0) gl_platform = LENSRT_GL_PLATFORM_EGL_DEVICE;
            else if (strcmp(v, "egl-surfaceless") == 0) gl_platform = LENSRT_GL_PLATFORM_EGL_SURFACELESS;
            else if (strcmp(v, "glfw") == 0) gl_platform = LENSRT_GL_PLATFORM_GLFW;
            else ok = 0;
        } else if (strcmp(a, "--samples") == 0 || strcmp(a, "--seed") == 0 || strcmp(a, "--wavelengths") == 0 ||
                   strcmp(a, "--stride") == 0 || strcmp(a, "--repeats") == 0 || strcmp(a, "--gl-stride") == 0 ||
                   strcmp(a, "--gl-samples") == 0 || strcmp(a, "--gl-warmup") == 0) {
            char *end;
            long long x;
            errno = 0;
            x = strtoll(v, &end, 10);
            ok = end != v && *end == '\0' && errno == 0 && x >= 0;
            if (!ok) {
            } else if (strcmp(a, "--samples") == 0) {
                ok = x > 0;
                samples = x;
            } else if (strcmp(a, "--seed") == 0) {
                seed = x;
            } else if (strcmp(a, "--wavelengths") == 0) {
                ok = x > 0 && x <= MAX_WL;
                n_wl = (long)x;
            } else if (strcmp(a, "--stride") == 0) {
                ok = x >= 1 && x <= 65536;
                stride = (long)x;
            } else if (strcmp(a, "--gl-stride") == 0) {
                ok = x >= 1 && x <= 65536;
                gl_stride = (long)x;
            } else if (strcmp(a, "--gl-samples") == 0) {
                ok = x > 0 && x <= (long long)1 << 40;
                gl_samples = x;
            } else if (strcmp(a, "--gl-warmup") == 0) {
                ok = x <= (long long)1 << 40;
                gl_warmup = x;
            } else {
                ok = x >= 1 && x <= MAX_REP;
                reps = (long)x;
            }
        } else if (strcmp(a, "--f-numbers") == 0) {
            const char *p = v;
            n_f = 0;
            while (ok && *p && n_f < MAX_F) {
                char *end;
                f_numbers[n_f] = strtod(p, &end);
                if (end == p || !(f_numbers[n_f] > 0) || (*end != ',' && *end != '\0')) ok = 0;
                n_f++;
                p = *end == ',' ? end + 1 : end;
            }
            if (*p || n_f == 0) ok = 0;
        } else {
            fprintf(stderr, "lensrt-bench: unknown option %s\n", a);
            usage(stderr);
            return 2;
        }
        if (!ok && expected) {
            fprintf(stderr, "lensrt-bench: %s: %s, got '%s'\n", a, expected, v);
            return 2;
        }
        if (!ok) {
            fprintf(stderr, "lensrt-bench: %s: bad or missing value '%s'\n", a, v ? v : "");
            return 2;
        }
        i++;
    }
    for (i = 0; i < n_f && head < 0; i++)
        if (f_numbers[i] == 8.0) head = i;
    if (head < 0) head = 0;
    if (width % stride != 0 || height % stride != 0) {
        fprintf(stderr, "lensrt-bench: --stride %ld must divide the resolution %ldx%ld\n", stride, width, height);
        return 2;
    }
    if (do_gl && (width % gl_stride != 0 || height % gl_stride != 0)) {
        fprintf(stderr, "lensrt-bench: --gl-stride %ld must divide the resolution %ldx%ld\n", gl_stride, width, height);
        return 2;
    }
    rw = width / stride;
    rh = height / stride;
    gw = width / gl_stride;
    gh = height / gl_stride;

    // Lens facts the baseline needs, from the table's lens lines
    if (!table_lens_value(table, "housing_first_mm", &housing_first) ||
        !table_lens_value(table, "housing_last_mm", &housing_last) ||
        !table_lens_value(table, "stop_radius_f1_mm", &stop_f1)) {
        fprintf(stderr, "lensrt-bench: %s: expected lines `lens housing_first_mm`, `lens housing_last_mm` and "
                        "`lens stop_radius_f1_mm` (table version 2)\n", table);
        return 1;
    }

    {
        const lensrt_context_init zero_init = LENSRT_CONTEXT_INIT;
        init = zero_init;
    }
    init.gl_platform = gl_platform;
    if ((r = lensrt_context_create(&init, &ctx)) != LENSRT_SUCCESS) return fail(NULL, "context", r);
    if ((r = lensrt_lens_load(ctx, table, &lens)) != LENSRT_SUCCESS) {
        status = fail(ctx, table, r);
        goto done;
    }
    info.struct_size = sizeof info;
    lensrt_lens_get_info(lens, &info);
    memset(&light, 0, sizeof light);
    light.struct_size = sizeof light;
    light.field_x_deg = field_x;
    light.field_y_deg = field_y;
    if ((r = lensrt_lens_image_point(ctx, lens, &light, 0.5 * (info.wavelength_min_nm + info.wavelength_max_nm), focus,
                                     center)) != LENSRT_SUCCESS) {
        status = fail(ctx, "image point", r);
        goto done;
    }
    for (i = 0; i < n_wl; i++)
        wl[i] = info.wavelength_min_nm + (info.wavelength_max_nm - info.wavelength_min_nm) * (i + 0.5) / (double)n_wl;
    // The GL device first: without one, `both` measures the CPU only and says why
    memset(&gl_info, 0, sizeof gl_info);
    gl_info.struct_size = sizeof gl_info;
    if (do_gl) {
        r = lensrt_context_gl_info(ctx, &gl_info);
        if (r == LENSRT_SUCCESS) {
            gl_ok = 1;
        } else if (r == LENSRT_ERROR_NO_DEVICE || r == LENSRT_ERROR_UNSUPPORTED) {
            last_error_line(ctx, r, gl_why, sizeof gl_why);
            if (!do_cpu) {
                fprintf(stderr, "lensrt-bench: --device gl: %s\n", gl_why);
                status = 3;
                goto done;
            }
        } else {
            status = fail(ctx, "GL device", r);
            goto done;
        }
    }
    cpu_model(cpu, sizeof cpu);
    gmtime_r(&t, &tmv);
    strftime(date, sizeof date, "%Y-%m-%dT%H:%M:%SZ", &tmv);

    printf("lensrt-bench: %s\n", info.name);
    printf("  table %s\n", table);
    printf("  light (%g, %g) deg at infinity, image point (%.6f, %.6f) mm, focus offset %g mm\n",
           field_x, field_y, center[0], center[1], focus);
    printf("  frame %ldx%ld pixels over %g x %g mm, %ld wavelengths", width, height, size_x, size_y, n_wl);
    if (do_cpu) printf(", %lld samples per wavelength", samples);
    printf("\n");
    if (do_cpu && stride > 1)
        printf("  lensrt renders one pixel per %ldx%ld block of the frame: %ldx%ld pixels over the same window\n",
               stride, stride, rw, rh);
    if (do_cpu)
        printf("  %ld repetitions per f-number, each bracketed by %g s of the %d-thread baseline\n", reps,
               base_seconds, threads);
    if (gl_ok) {
        printf("  gl: %s, GL_RENDERER %s, GL_VERSION %s%s\n", gl_info.platform, gl_info.renderer, gl_info.version,
               gl_info.software ? " (software)" : "");
        printf("  gl: one render per f-number, bracketed by the baseline, one pixel per %ldx%ld block of the frame\n"
               "      (%ldx%ld pixels over the same window), %lld samples per wavelength timed ", gl_stride, gl_stride,
               gw, gh, gl_samples);
        if (gl_warmup > 0)
            printf("after an untimed\n      warm-up run() of %lld (shader compiles, terms per pixel)\n", gl_warmup);
        else
            printf("in the first run()\n      (shader compiles and terms per pixel included)\n");
    } else if (do_gl) {
        printf("  gl: skipped: %s\n", gl_why);
    }
    printf("  housings: first %g mm, last %g mm; threads %d; cpu %s\n", housing_first, housing_last, threads, cpu);
    fflush(stdout);

    // Baseline pixels: a gx x gy grid of the frame's pixel centres; (gx/2, gy/2) is the
    // pixel at the window centre
    pix = malloc(sizeof(double) * 2 * (size_t)(gx * gy));
    if (!pix) {
        fprintf(stderr, "lensrt-bench: out of memory\n");
        goto done;
    }
    {
        double pitch_x = size_x / (double)width, pitch_y = size_y / (double)height;
        long a, b;
        for (b = 0; b < gy; b++)
            for (a = 0; a < gx; a++) {
                long px = a * width / gx, py = b * height / gy;
                pix[2 * (b * gx + a)] = center[0] + ((double)px + 0.5 - 0.5 * (double)width) * pitch_x;
                pix[2 * (b * gx + a) + 1] = center[1] + (0.5 * (double)height - (double)py - 0.5) * pitch_y;
            }
        center_pixel = (int)((gy / 2) * gx + gx / 2);
    }

    for (i = 0; i < n_f; i++) {
        lensrt_render_desc desc;
        baseline_scene sc;
        baseline_result b1[2];
        f_result *fr = &res[i];
        memset(fr, 0, sizeof *fr);
        memset(&desc, 0, sizeof desc);
        desc.struct_size = sizeof desc;
        desc.lens = lens;
        desc.sensor.width = (int)rw;
        desc.sensor.height = (int)rh;
        desc.sensor.width_mm = size_x;
        desc.sensor.height_mm = size_y;
        desc.sensor.center_x_mm = center[0];
        desc.sensor.center_y_mm = center[1];
        desc.sensor.focus_offset_mm = focus;
        desc.aperture.f_number = f_numbers[i];
        desc.lights = &light;
        desc.n_lights = 1;
        desc.wavelengths_nm = wl;
        desc.n_wavelengths = (int)n_wl;
        fr->f_number = f_numbers[i];
        fr->reps = do_cpu ? (int)reps : 0;
        {
            // Direction cosines along (tan x, tan y, 1), as lensrt turns field angles into P_o inputs
            double tx = tan(field_x * PI / 180.0), ty = tan(field_y * PI / 180.0), n = sqrt(1.0 + tx * tx + ty * ty);
            sc.light_x = tx / n;
            sc.light_y = ty / n;
        }
        sc.focus_mm = focus;
        sc.stop_radius_mm = stop_f1 / f_numbers[i];
        sc.housing_first_mm = housing_first;
        sc.housing_last_mm = housing_last;
        sc.n_wl = (int)n_wl;
        sc.wavelengths_nm = wl;
        sc.n_pix = (int)(gx * gy);
        sc.pix_xy = pix;
        printf("f/%g:", f_numbers[i]);
        fflush(stdout);
        b1[0] = run_baseline(&sc, 1, 256, 0.5 * base_seconds, (uint64_t)seed + 100, center_pixel);
        // Each repetition: baseline, lensrt, baseline, so that the two halves of the
        // baseline bracket the render in time and see the same machine
        for (k = 0; k < fr->reps; k++) {
            lensrt_render render = NULL;
            baseline_result pre, post;
            pre = run_baseline(&sc, threads, 256, 0.5 * base_seconds, (uint64_t)seed + 2 * (uint64_t)k, center_pixel);
            desc.seed = (uint64_t)seed + (uint64_t)k;
            if ((r = lensrt_render_create(ctx, &desc, &render)) != LENSRT_SUCCESS) {
                status = fail(ctx, "render", r);
                goto done;
            }
            r = lensrt_render_run(render, (uint64_t)samples, NULL, NULL);
            if (r != LENSRT_SUCCESS) {
                status = fail(ctx, "run", r);
                lensrt_render_destroy(render);
                goto done;
            }
            bench_stats(render, &fr->stats);
            post = run_baseline(&sc, threads, 256, 0.5 * base_seconds, (uint64_t)seed + 2 * (uint64_t)k + 1, center_pixel);
            if (pre.seconds < 0 || post.seconds < 0) {
                fprintf(stderr, "lensrt-bench: out of memory in the baseline\n");
                lensrt_render_destroy(render);
                goto done;
            }
            fr->baseN[k] = combine(&pre, &post);
            fr->sps[k] = fr->stats.splats_per_second;
            fr->seconds[k] = fr->stats.seconds;
            fr->ratio[k] = fr->sps[k] / fr->baseN[k].splats_per_second;
            printf(" [lensrt %.3g/s in %.1f s, baseline %.3g/s: %.0fx", fr->sps[k], fr->seconds[k],
                   fr->baseN[k].splats_per_second, fr->ratio[k]);
            // The same render (same seed) scheduled as tiles on pthreads
            if (tile_w > 0) {
                lensrt_render tiled = NULL;
                lensrt_render_stats ts;
                int n_tiles = 0, same;
                memset(&ts, 0, sizeof ts);
                if ((r = lensrt_render_create(ctx, &desc, &tiled)) != LENSRT_SUCCESS ||
                    (r = run_tiles(tiled, (uint64_t)samples, (int)rw, (int)rh, (int)tile_w, (int)tile_h, threads,
                                   &n_tiles)) != LENSRT_SUCCESS) {
                    status = fail(ctx, "tiles", r);
                    lensrt_render_destroy(tiled);
                    lensrt_render_destroy(render);
                    goto done;
                }
                bench_stats(tiled, &ts);
                same = same_image(render, tiled, (size_t)rw * (size_t)rh * (size_t)n_wl);
                if (k == 0) fr->tile_identical = same;
                else if (same != 1) fr->tile_identical = same;
                fr->tile_sps[k] = ts.splats_per_second;
                fr->tile_seconds[k] = ts.seconds;
                fr->tile_ratio[k] = fr->tile_sps[k] / fr->sps[k];
                printf("; %d tiles %.3g/s in %.1f s: %.2fx run%s", n_tiles, fr->tile_sps[k], fr->tile_seconds[k],
                       fr->tile_ratio[k], same == 1 ? ", same image" : same == 0 ? ", IMAGE DIFFERS" : "");
                lensrt_render_destroy(tiled);
            }
            printf("]");
            lensrt_render_destroy(render);
            fflush(stdout);
        }
        if (tile_w > 0 && fr->reps > 0) {
            desc.seed = (uint64_t)seed;
            fr->one_tile_seconds = one_tile_seconds(ctx, &desc, (uint64_t)samples);
            fr->tile_sps_med = median(fr->tile_sps, fr->reps);
            fr->tile_ratio_med = median(fr->tile_ratio, fr->reps);
        }
        if (fr->reps > 0) {
            double bn[MAX_REP];
            for (k = 0; k < fr->reps; k++) bn[k] = fr->baseN[k].splats_per_second;
            fr->sps_med = median(fr->sps, fr->reps);
            fr->baseN_med = median(bn, fr->reps);
            fr->ratio_med = median(fr->ratio, fr->reps);
        }
        // GL: the same scene on its own pixel grid, bracketed by the baseline like a repetition
        if (gl_ok) {
            lensrt_render_desc gdesc = desc;
            baseline_result pre, post;
            gl_result *gr = &glres[n_gl];
            memset(gr, 0, sizeof *gr);
            gr->f_number = f_numbers[i];
            gdesc.device = LENSRT_DEVICE_GL;
            gdesc.sensor.width = (int)gw;
            gdesc.sensor.height = (int)gh;
            gdesc.seed = (uint64_t)seed;
            pre = run_baseline(&sc, threads, 256, 0.5 * base_seconds, (uint64_t)seed + 2 * (uint64_t)reps,
                               center_pixel);
            r = run_gl(ctx, &gdesc, gl_warmup, gl_samples, gr);
            post = run_baseline(&sc, threads, 256, 0.5 * base_seconds, (uint64_t)seed + 2 * (uint64_t)reps + 1,
                                center_pixel);
            if (pre.seconds < 0 || post.seconds < 0) {
                fprintf(stderr, "lensrt-bench: out of memory in the baseline\n");
                goto done;
            }
            if (r != LENSRT_SUCCESS) {
                // A device that fails mid-way: the CPU figures still count, the exit status says so
                last_error_line(ctx, r, gl_why, sizeof gl_why);
                printf(" [gl failed: %s]", gl_why);
                gl_ok = 0;
                gl_failed = 1;
            } else {
                gr->base = combine(&pre, &post);
                gr->ratio_base = gr->sps / gr->base.splats_per_second;
                gr->ratio_cpu = fr->reps > 0 ? gr->sps / fr->sps_med : -1.0;
                printf(" [gl %.3g/s in %.1f s (set-up %.1f s), baseline %.3g/s: %.2fx", gr->sps, gr->seconds,
                       gr->setup_seconds, gr->base.splats_per_second, gr->ratio_base);
                if (gr->ratio_cpu >= 0) printf(", %.3gx lensrt cpu", gr->ratio_cpu);
                printf("]");
                n_gl++;
            }
            fflush(stdout);
        }
        b1[1] = run_baseline(&sc, 1, 256, 0.5 * base_seconds, (uint64_t)seed + 101, center_pixel);
        if (b1[0].seconds < 0 || b1[1].seconds < 0) {
            fprintf(stderr, "lensrt-bench: out of memory in the baseline\n");
            goto done;
        }
        fr->base1 = combine(&b1[0], &b1[1]);
        printf(" 1 thread %.3g/s; baseline splats clipped: %.3g%%\n", fr->base1.splats_per_second,
               100.0 * fr->base1.clipped / fr->base1.splats);
        fflush(stdout);
    }

    // The tables
    if (do_cpu) {
        printf("\nsplats per second (one aperture sample at one pixel, one wavelength), median of %ld; %d threads\n",
               reps, threads);
        printf("%-6s %9s %9s %10s %7s %6s %6s %11s %11s %10s %8s %9s\n", "f/N", "stop mm", "seconds", "lensrt/s",
               "terms", "clip", "tau", "base Nt/s", "base 1t/s", "base coh.", "ratio", "ratio 1t");
        for (i = 0; i < n_f; i++) {
            const f_result *fr = &res[i];
            const lensrt_render_stats *st = &fr->stats;
            printf("%-6g %9.4f %9.2f %10.3g %7.2f %6.3f %6.3f %11.3g %11.3g %10.3f %8.1f %9.1f\n", fr->f_number,
                   st->stop_radius_mm, median(fr->seconds, fr->reps), fr->sps_med, st->phase_terms,
                   st->clip_fraction, st->tau_fraction, fr->baseN_med, fr->base1.splats_per_second,
                   fr->base1.coherence_center, fr->ratio_med, fr->sps_med / fr->base1.splats_per_second);
        }
        printf("headline f/%g: %.3g splats/s, %.1fx the scalar double baseline at %d threads (baseline %.3g splats/s)\n",
               res[head].f_number, res[head].sps_med, res[head].ratio_med, threads, res[head].baseN_med);
        printf("(ratio: median over the repetitions of lensrt / the %d-thread baseline that bracketed it; terms: phase\n"
               " terms per splat after pruning; clip, tau: fractions of pixels that needed the inner-pupil clip or a\n"
               " varying transmittance; base coh.: |sum X| / sum |X| of the baseline at the window centre, a check\n"
               " that its phases agree to a fraction of a wave across the aperture)\n", threads);
    }
    if (do_cpu && tile_w > 0) {
        const int n_tiles = (int)(((rw + tile_w - 1) / tile_w) * ((rh + tile_h - 1) / tile_h));
        printf("\nhost-scheduled tiles of %ldx%ld pixels (%d tiles of the %ldx%ld window) on %d pthreads against\n"
               "run() on %d OpenMP threads, same renders, median of %ld\n", tile_w, tile_h, n_tiles, rw, rh, threads,
               threads, reps);
        printf("%-6s %10s %10s %8s %12s %11s %11s\n", "f/N", "run/s", "tiles/s", "ratio", "1x1 tile s", "prep share",
               "same image");
        for (i = 0; i < n_f; i++) {
            const f_result *fr = &res[i];
            double share = fr->one_tile_seconds * n_tiles / (median(fr->tile_seconds, fr->reps) * threads);
            printf("%-6g %10.3g %10.3g %8.3f %12.4f %10.1f%% %11s\n", fr->f_number, fr->sps_med, fr->tile_sps_med,
                   fr->tile_ratio_med, fr->one_tile_seconds, 100.0 * share,
                   fr->tile_identical == 1 ? "yes" : fr->tile_identical == 0 ? "NO" : "?");
        }
        printf("headline tiles f/%g: %.3g splats/s, %.3fx run() (%ldx%ld tiles, %d pthreads)\n", res[head].f_number,
               res[head].tile_sps_med, res[head].tile_ratio_med, tile_w, tile_h, threads);
        printf("(ratio: tiles / run() of the same repetition; 1x1 tile s: one tile's fixed cost, drawing and\n"
               " preparing every wavelength's samples, which every tile repeats; prep share: that cost times the\n"
               " tiles over the tiled render's thread-seconds; same image: the tiled render's image equals run()'s\n"
               " bit for bit)\n");
    }
    if (n_gl > 0) {
        const gl_result *gh_ = NULL;
        printf("\ngl splats per second, %s on %s (%s),\none render per f-number, %ldx%ld pixels, %lld samples per "
               "wavelength (warm-up %lld)\n", gl_info.renderer, gl_info.platform,
               gl_info.software ? "software" : "hardware", gw, gh, gl_samples, gl_warmup);
        printf("%-6s %9s %9s %10s %9s %7s %11s %8s %10s\n", "f/N", "stop mm", "seconds", "gl/s", "set-up s", "terms",
               "base Nt/s", "ratio", "vs cpu");
        for (i = 0; i < n_gl; i++) {
            const gl_result *gr = &glres[i];
            char vs[32] = "-";
            if (gr->ratio_cpu >= 0) snprintf(vs, sizeof vs, "%.3g", gr->ratio_cpu);
            printf("%-6g %9.4f %9.2f %10.3g %9.2f %7.2f %11.3g %8.2f %10s\n", gr->f_number, gr->stats.stop_radius_mm,
                   gr->seconds, gr->sps, gr->setup_seconds, gr->stats.phase_terms, gr->base.splats_per_second,
                   gr->ratio_base, vs);
            if (gr->f_number == res[head].f_number) gh_ = gr;
        }
        if (gh_) {
            printf("headline gl f/%g: %.3g splats/s, %.2fx the baseline at %d threads", gh_->f_number, gh_->sps,
                   gh_->ratio_base, threads);
            if (gh_->ratio_cpu >= 0) printf(", %.3gx lensrt on the cpu", gh_->ratio_cpu);
            printf(" (%s)\n", gl_info.renderer);
        }
        printf("(ratio: gl / the %d-thread baseline that bracketed it; vs cpu: gl / the median lensrt cpu figure\n"
               " of the same f-number; terms: phase terms the gl splat shader evaluates, the most any pixel needs)\n",
               threads);
    } else if (gl_failed) {
        printf("\ngl: failed: %s\n", gl_why);
    }
    printf("(%.0f s in all)\n", now_seconds() - t_start);

    if (json) {
        FILE *f = fopen(json, "w");
        const f_result *h = &res[head];
        if (!f) {
            fprintf(stderr, "lensrt-bench: %s: %s\n", json, strerror(errno));
            goto done;
        }
        fprintf(f, "{\n  \"benchmark\": \"lensrt-bench\",\n  \"lens\": ");
        json_string(f, info.name);
        fprintf(f, ",\n  \"table\": ");
        json_string(f, table);
        fprintf(f, ",\n  \"date\": \"%s\",\n  \"cpu\": ", date);
        json_string(f, cpu);
        fprintf(f, ",\n  \"threads\": %d,\n", threads);
        fprintf(f, "  \"resolution\": [%ld, %ld],\n  \"stride\": %ld,\n  \"rendered_resolution\": [%ld, %ld],\n",
                width, height, stride, rw, rh);
        fprintf(f, "  \"window_mm\": [%.17g, %.17g],\n", size_x, size_y);
        fprintf(f, "  \"center_mm\": [%.17g, %.17g],\n  \"focus_offset_mm\": %.17g,\n", center[0], center[1], focus);
        fprintf(f, "  \"light_field_deg\": [%.17g, %.17g],\n  \"wavelengths\": %ld,\n  \"samples\": %lld,\n",
                field_x, field_y, n_wl, samples);
        fprintf(f, "  \"repeats\": %d,\n  \"f_number\": %.17g,\n", h->reps, h->f_number);
        fprintf(f, "  \"device\": ");
        json_string(f, device_arg);
        fprintf(f, ",\n  \"splats_per_second\": ");
        json_num(f, h->sps_med, do_cpu);
        fprintf(f, ",\n  \"baseline_splats_per_second\": ");
        json_num(f, h->baseN_med, do_cpu);
        fprintf(f, ",\n  \"baseline_threads\": %d,\n", threads);
        fprintf(f, "  \"baseline_single_thread_splats_per_second\": %.17g,\n", h->base1.splats_per_second);
        fprintf(f, "  \"ratio\": ");
        json_num(f, h->ratio_med, do_cpu);
        fprintf(f, ",\n  \"ratio_vs_single_thread\": ");
        json_num(f, h->sps_med / h->base1.splats_per_second, do_cpu);
        fprintf(f, ",\n");
        fprintf(f, "  \"baseline\": {\"algorithm\": \"paper section 3.2 as a plain scalar double loop: generated Horner "
                   "lens0001_P_o_d once per sample, lens0001_P_s_d per splat, housing clips, amplitude "
                   "sqrt(tau_o tau_i), phase 2 pi / lambda (phi_o + phi_i), libm cos/sin\", \"pixels\": %ld, "
                   "\"grid\": [%ld, %ld], \"seconds_per_repetition\": %.17g, \"housing_first_mm\": %.17g, "
                   "\"housing_last_mm\": %.17g},\n",
                gx * gy, gx, gy, base_seconds, housing_first, housing_last);
        fprintf(f, "  \"per_f_number\": {");
        for (i = 0; i < n_f && do_cpu; i++) {
            const f_result *fr = &res[i];
            const lensrt_render_stats *st = &fr->stats;
            double bn[MAX_REP];
            for (k = 0; k < fr->reps; k++) bn[k] = fr->baseN[k].splats_per_second;
            fprintf(f, "%s\n    \"%g\": {\"splats_per_second\": %.17g, \"baseline_splats_per_second\": %.17g, "
                       "\"ratio\": %.17g, \"baseline_single_thread_splats_per_second\": %.17g, "
                       "\"stop_radius_mm\": %.17g, \"splats\": %llu, \"samples_per_wavelength\": %llu, "
                       "\"phase_terms\": %.17g, \"clip_fraction\": %.17g, \"tau_fraction\": %.17g, "
                       "\"dark_fraction\": %.17g, \"baseline_coherence_center\": %.17g, "
                       "\"baseline_clipped_fraction\": %.17g,\n      \"repetitions\": ",
                    i ? "," : "", fr->f_number, fr->sps_med, fr->baseN_med, fr->ratio_med,
                    fr->base1.splats_per_second, st->stop_radius_mm, (unsigned long long)st->splats,
                    (unsigned long long)st->samples_per_wavelength, st->phase_terms, st->clip_fraction,
                    st->tau_fraction, st->dark_fraction, fr->base1.coherence_center,
                    fr->base1.clipped / fr->base1.splats);
            fprintf(f, "{\"splats_per_second\": ");
            json_list(f, fr->sps, fr->reps);
            fprintf(f, ", \"seconds\": ");
            json_list(f, fr->seconds, fr->reps);
            fprintf(f, ", \"baseline_splats_per_second\": ");
            json_list(f, bn, fr->reps);
            fprintf(f, ", \"ratio\": ");
            json_list(f, fr->ratio, fr->reps);
            fprintf(f, "}}");
        }
        fprintf(f, "\n  },\n  \"gl\": ");
        if (!gl_info.renderer) {
            // No device (or not asked for): why
            fprintf(f, "{\"skipped\": ");
            json_string(f, do_gl ? gl_why : "--device cpu");
            fprintf(f, "}");
        } else {
            fprintf(f, "{\"renderer\": ");
            json_string(f, gl_info.renderer);
            fprintf(f, ", \"version\": ");
            json_string(f, gl_info.version);
            fprintf(f, ", \"platform\": ");
            json_string(f, gl_info.platform);
            fprintf(f, ", \"software\": %s,\n    \"stride\": %ld, \"rendered_resolution\": [%ld, %ld], "
                       "\"samples\": %lld, \"warmup_samples\": %lld, \"timing\": \"%s\",\n",
                    gl_info.software ? "true" : "false", gl_stride, gw, gh, gl_samples, gl_warmup,
                    gl_warmup > 0 ? "the second run() of the render, after an untimed warm-up run()"
                                  : "the first run() of the render, shader compiles and set-up included");
            if (gl_failed) {
                fprintf(f, "    \"error\": ");
                json_string(f, gl_why);
                fprintf(f, ",\n");
            }
            fprintf(f, "    \"results\": [");
            for (i = 0; i < n_gl; i++) {
                const gl_result *gr = &glres[i];
                fprintf(f, "%s\n      {\"f_number\": %.17g, \"splats_per_second\": %.17g, \"seconds\": %.17g, "
                           "\"splats\": %.17g, \"setup_seconds\": %.17g, \"baseline_splats_per_second\": %.17g, "
                           "\"ratio_vs_baseline\": %.17g, \"ratio_vs_cpu\": ",
                        i ? "," : "", gr->f_number, gr->sps, gr->seconds, gr->splats, gr->setup_seconds,
                        gr->base.splats_per_second, gr->ratio_base);
                json_num(f, gr->ratio_cpu, gr->ratio_cpu >= 0);
                fprintf(f, ", \"stop_radius_mm\": %.17g, \"phase_terms\": %.17g, \"clip_fraction\": %.17g, "
                           "\"tau_fraction\": %.17g, \"dark_fraction\": %.17g}",
                        gr->stats.stop_radius_mm, gr->stats.phase_terms, gr->stats.clip_fraction,
                        gr->stats.tau_fraction, gr->stats.dark_fraction);
            }
            fprintf(f, "%s]}", n_gl ? "\n    " : "");
        }
        // Host-scheduled tiles: the headline, then per f-number
        fprintf(f, ",\n  \"tiles\": ");
        if (!do_cpu || tile_w == 0) {
            fprintf(f, "{\"skipped\": ");
            json_string(f, !do_cpu ? "--device gl" : "--tile 0x0");
            fprintf(f, "}");
        } else {
            fprintf(f, "{\"tile\": [%ld, %ld], \"tiles\": %ld, \"threads\": %d, \"scheduler\": \"pthreads, tiles in "
                       "row-major order from a shared counter\", \"f_number\": %.17g, \"splats_per_second\": %.17g, "
                       "\"ratio_vs_run\": %.17g,\n    \"per_f_number\": {",
                    tile_w, tile_h, ((rw + tile_w - 1) / tile_w) * ((rh + tile_h - 1) / tile_h), threads, h->f_number,
                    h->tile_sps_med, h->tile_ratio_med);
            for (i = 0; i < n_f; i++) {
                const f_result *fr = &res[i];
                fprintf(f, "%s\n      \"%g\": {\"splats_per_second\": %.17g, \"ratio_vs_run\": %.17g, "
                           "\"one_tile_seconds\": %.17g, \"identical_to_run\": %s, \"repetitions\": "
                           "{\"splats_per_second\": ",
                        i ? "," : "", fr->f_number, fr->tile_sps_med, fr->tile_ratio_med, fr->one_tile_seconds,
                        fr->tile_identical == 1 ? "true" : "false");
                json_list(f, fr->tile_sps, fr->reps);
                fprintf(f, ", \"seconds\": ");
                json_list(f, fr->tile_seconds, fr->reps);
                fprintf(f, ", \"ratio_vs_run\": ");
                json_list(f, fr->tile_ratio, fr->reps);
                fprintf(f, "}}");
            }
            fprintf(f, "\n    }}");
        }
        fprintf(f, ",\n  \"wall_seconds\": %.17g\n}\n", now_seconds() - t_start);
        if (fclose(f) != 0) {
            fprintf(stderr, "lensrt-bench: %s: write failed\n", json);
            goto done;
        }
        printf("wrote %s\n", json);
    }
    status = gl_failed ? 1 : 0;
done:
    free(pix);
    if (lens) lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    return status;
}
