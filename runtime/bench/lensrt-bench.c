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
 * evaluated inside; splats per second from lensrt_render_get_stats(). By default it
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
 * single-threaded for context. */
#include "lensrt.h"
#include "lens0001.h"

#include <errno.h>
#include <math.h>
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
        "  --seed S               (default 1)\n",
        DEFAULT_TABLE, DEFAULT_STRIDE);
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
} f_result;

static int fail(lensrt_context ctx, const char *what, lensrt_result r)
{
    fprintf(stderr, "lensrt-bench: %s: %s: %s\n", what, lensrt_result_string(r), ctx ? lensrt_context_last_error(ctx) : "");
    return 1;
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
        else if (strcmp(a, "--baseline-grid") == 0) ok = parse_pair_i(v, 'x', &gx, &gy) && gx > 0 && gy > 0 && gx * gy <= 65536;
        else if (strcmp(a, "--baseline-seconds") == 0) ok = parse_d(v, &base_seconds) && base_seconds >= 0;
        else if (strcmp(a, "--samples") == 0 || strcmp(a, "--seed") == 0 || strcmp(a, "--wavelengths") == 0 ||
                 strcmp(a, "--stride") == 0 || strcmp(a, "--repeats") == 0) {
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
    rw = width / stride;
    rh = height / stride;

    // Lens facts the baseline needs, from the table's lens lines
    if (!table_lens_value(table, "housing_first_mm", &housing_first) ||
        !table_lens_value(table, "housing_last_mm", &housing_last) ||
        !table_lens_value(table, "stop_radius_f1_mm", &stop_f1)) {
        fprintf(stderr, "lensrt-bench: %s: expected lines `lens housing_first_mm`, `lens housing_last_mm` and "
                        "`lens stop_radius_f1_mm` (table version 2)\n", table);
        return 1;
    }

    memset(&init, 0, sizeof init);
    if ((r = lensrt_context_create(&init, &ctx)) != LENSRT_SUCCESS) return fail(NULL, "context", r);
    if ((r = lensrt_lens_load(ctx, table, &lens)) != LENSRT_SUCCESS) {
        status = fail(ctx, table, r);
        goto done;
    }
    lensrt_lens_get_info(lens, &info);
    memset(&light, 0, sizeof light);
    light.field_x_deg = field_x;
    light.field_y_deg = field_y;
    if ((r = lensrt_lens_image_point(ctx, lens, &light, 0.5 * (info.wavelength_min_nm + info.wavelength_max_nm), focus,
                                     center)) != LENSRT_SUCCESS) {
        status = fail(ctx, "image point", r);
        goto done;
    }
    for (i = 0; i < n_wl; i++)
        wl[i] = info.wavelength_min_nm + (info.wavelength_max_nm - info.wavelength_min_nm) * (i + 0.5) / (double)n_wl;
    cpu_model(cpu, sizeof cpu);
    gmtime_r(&t, &tmv);
    strftime(date, sizeof date, "%Y-%m-%dT%H:%M:%SZ", &tmv);

    printf("lensrt-bench: %s\n", info.name);
    printf("  table %s\n", table);
    printf("  light (%g, %g) deg at infinity, image point (%.6f, %.6f) mm, focus offset %g mm\n",
           field_x, field_y, center[0], center[1], focus);
    printf("  frame %ldx%ld pixels over %g x %g mm, %ld wavelengths, %lld samples per wavelength\n",
           width, height, size_x, size_y, n_wl, samples);
    if (stride > 1)
        printf("  lensrt renders one pixel per %ldx%ld block of the frame: %ldx%ld pixels over the same window\n",
               stride, stride, rw, rh);
    printf("  %ld repetitions per f-number, each bracketed by %g s of the %d-thread baseline\n", reps, base_seconds,
           threads);
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
        fr->reps = (int)reps;
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
        for (k = 0; k < reps; k++) {
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
            lensrt_render_get_stats(render, &fr->stats);
            lensrt_render_destroy(render);
            post = run_baseline(&sc, threads, 256, 0.5 * base_seconds, (uint64_t)seed + 2 * (uint64_t)k + 1, center_pixel);
            if (pre.seconds < 0 || post.seconds < 0) {
                fprintf(stderr, "lensrt-bench: out of memory in the baseline\n");
                goto done;
            }
            fr->baseN[k] = combine(&pre, &post);
            fr->sps[k] = fr->stats.splats_per_second;
            fr->seconds[k] = fr->stats.seconds;
            fr->ratio[k] = fr->sps[k] / fr->baseN[k].splats_per_second;
            printf(" [lensrt %.3g/s in %.1f s, baseline %.3g/s: %.0fx]", fr->sps[k], fr->seconds[k],
                   fr->baseN[k].splats_per_second, fr->ratio[k]);
            fflush(stdout);
        }
        b1[1] = run_baseline(&sc, 1, 256, 0.5 * base_seconds, (uint64_t)seed + 101, center_pixel);
        if (b1[0].seconds < 0 || b1[1].seconds < 0) {
            fprintf(stderr, "lensrt-bench: out of memory in the baseline\n");
            goto done;
        }
        fr->base1 = combine(&b1[0], &b1[1]);
        {
            double bn[MAX_REP];
            for (k = 0; k < reps; k++) bn[k] = fr->baseN[k].splats_per_second;
            fr->sps_med = median(fr->sps, (int)reps);
            fr->baseN_med = median(bn, (int)reps);
            fr->ratio_med = median(fr->ratio, (int)reps);
        }
        printf(" 1 thread %.3g/s; baseline splats clipped: %.3g%%\n", fr->base1.splats_per_second,
               100.0 * fr->base1.clipped / fr->base1.splats);
        fflush(stdout);
    }

    // The table
    printf("\nsplats per second (one aperture sample at one pixel, one wavelength), median of %ld; %d threads\n", reps,
           threads);
    printf("%-6s %9s %9s %10s %7s %6s %6s %11s %11s %10s %8s %9s\n", "f/N", "stop mm", "seconds", "lensrt/s", "terms",
           "clip", "tau", "base Nt/s", "base 1t/s", "base coh.", "ratio", "ratio 1t");
    for (i = 0; i < n_f; i++) {
        const f_result *fr = &res[i];
        const lensrt_render_stats *st = &fr->stats;
        printf("%-6g %9.4f %9.2f %10.3g %7.2f %6.3f %6.3f %11.3g %11.3g %10.3f %8.1f %9.1f\n", fr->f_number,
               st->stop_radius_mm, median(fr->seconds, fr->reps), fr->sps_med, st->phase_terms, st->clip_fraction,
               st->tau_fraction, fr->baseN_med, fr->base1.splats_per_second, fr->base1.coherence_center, fr->ratio_med,
               fr->sps_med / fr->base1.splats_per_second);
    }
    printf("headline f/%g: %.3g splats/s, %.1fx the scalar double baseline at %d threads (baseline %.3g splats/s)\n",
           res[head].f_number, res[head].sps_med, res[head].ratio_med, threads, res[head].baseN_med);
    printf("(ratio: median over the repetitions of lensrt / the %d-thread baseline that bracketed it; terms: phase\n"
           " terms per splat after pruning; clip, tau: fractions of pixels that needed the inner-pupil clip or a\n"
           " varying transmittance; base coh.: |sum X| / sum |X| of the baseline at the window centre, a check that\n"
           " its phases agree to a fraction of a wave across the aperture; %.0f s in all)\n", threads,
           now_seconds() - t_start);

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
        fprintf(f, "  \"repeats\": %ld,\n  \"f_number\": %.17g,\n", reps, h->f_number);
        fprintf(f, "  \"splats_per_second\": %.17g,\n", h->sps_med);
        fprintf(f, "  \"baseline_splats_per_second\": %.17g,\n", h->baseN_med);
        fprintf(f, "  \"baseline_threads\": %d,\n", threads);
        fprintf(f, "  \"baseline_single_thread_splats_per_second\": %.17g,\n", h->base1.splats_per_second);
        fprintf(f, "  \"ratio\": %.17g,\n", h->ratio_med);
        fprintf(f, "  \"ratio_vs_single_thread\": %.17g,\n", h->sps_med / h->base1.splats_per_second);
        fprintf(f, "  \"baseline\": {\"algorithm\": \"paper section 3.2 as a plain scalar double loop: generated Horner "
                   "lens0001_P_o_d once per sample, lens0001_P_s_d per splat, housing clips, amplitude "
                   "sqrt(tau_o tau_i), phase 2 pi / lambda (phi_o + phi_i), libm cos/sin\", \"pixels\": %ld, "
                   "\"grid\": [%ld, %ld], \"seconds_per_repetition\": %.17g, \"housing_first_mm\": %.17g, "
                   "\"housing_last_mm\": %.17g},\n",
                gx * gy, gx, gy, base_seconds, housing_first, housing_last);
        fprintf(f, "  \"per_f_number\": {");
        for (i = 0; i < n_f; i++) {
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
        fprintf(f, "\n  },\n  \"wall_seconds\": %.17g\n}\n", now_seconds() - t_start);
        if (fclose(f) != 0) {
            fprintf(stderr, "lensrt-bench: %s: write failed\n", json);
            goto done;
        }
        printf("wrote %s\n", json);
    }
    status = 0;
done:
    free(pix);
    if (lens) lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    return status;
}
