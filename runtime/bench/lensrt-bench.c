/* lensrt-bench: splats per second of lensrt against the paper's algorithm as a plain
 * scalar double loop, measured in the same run (the machines are shared and noisy, so
 * the ratio is the figure to quote; absolute numbers are context).
 *
 *   lensrt-bench --json build/bench/lensrt.json
 *
 * A splat is one aperture sample evaluated at one pixel for one wavelength.
 *
 * The scene follows the paper's Figure 7: the default lens (0001), a point light off
 * the axis at infinity (field (6, 4) deg), a 1440 x 1080 window of 0.3 x 0.225 mm centred
 * on the light's image point, sensor shift 0.2 mm, 16 wavelengths, f/2, f/8 and f/32.
 *
 * lensrt side: lensrt_render_run() with the default precision and sampler; clipping at
 * both pupils and the transmittance polynomials are evaluated inside; splats per second
 * from lensrt_render_get_stats().
 *
 * Baseline side: the paper's Algorithm (section 3.2) as written, with the generated
 * Horner code of the same lens (lens0001_P_o_d, lens0001_P_s_d): for every sample a
 * random point in the stop disc and one of the 16 wavelengths in turn, P_o once (outer
 * pupil clip at the first surface's housing, tau_o, phi_o), then for every pixel of a
 * grid spread over the same window P_s (inner pupil clip at the last surface's housing,
 * tau_i, phi_i), phase 2 pi / lambda (phi_o + phi_i) in double, amplitude
 * sqrt(tau_o tau_i), cos and sin from libm into that pixel's phasor sum for that
 * wavelength. It runs single-threaded and with OpenMP over pixels; the ratio uses the
 * OpenMP baseline with the same number of threads as lensrt. */
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
        "  --resolution WxH       pixels of the lensrt render (default 1440x1080)\n"
        "  --size WxH             window on the sensor in mm (default 0.3x0.225)\n"
        "  --samples N            aperture samples per wavelength of the lensrt render (default 4096:\n"
        "                         one full pass)\n"
        "  --f-numbers A,B,..     (default 2,8,32; the first 8 in the list, else the first, is the headline)\n"
        "  --wavelengths N        (default 16)\n"
        "  --field X,Y            light direction in degrees (default 6,4), at infinity\n"
        "  --focus Z              sensor shift z_S in mm (default 0.2)\n"
        "  --baseline-grid BxC    baseline pixels, spread over the window (default 8x8)\n"
        "  --baseline-seconds T   run each baseline for at least T seconds (default 2)\n"
        "  --seed S               (default 1)\n",
        DEFAULT_TABLE);
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
    double t0, elapsed = 0.0;
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
#pragma omp parallel for schedule(static) num_threads(threads)
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
                if (s[i].clipped) continue;
                in[3] = s[i].xa;
                in[4] = s[i].ya;
                in[5] = s[i].lambda_nm;
                lens0001_P_s_d(in, out);
                if (out[0] * out[0] + out[1] * out[1] > r2last) continue;
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

/* ------------------------------------------------------------------- main ----- */

typedef struct f_result {
    double f_number;
    lensrt_render_stats stats;
    baseline_result base1, baseN;
} f_result;

static int fail(lensrt_context ctx, const char *what, lensrt_result r)
{
    fprintf(stderr, "lensrt-bench: %s: %s: %s\n", what, lensrt_result_string(r), ctx ? lensrt_context_last_error(ctx) : "");
    return 1;
}

int main(int argc, char **argv)
{
    const char *json = NULL, *table = DEFAULT_TABLE;
    long width = 1440, height = 1080, gx = 8, gy = 8, n_wl = 16;
    double size_x = 0.3, size_y = 0.225, field_x = 6.0, field_y = 4.0, focus = 0.2, base_seconds = 2.0;
    double f_numbers[MAX_F] = {2.0, 8.0, 32.0};
    int n_f = 3, i, head = -1, threads = max_threads(), center_pixel;
    long long samples = 4096, seed = 1;
    double housing_first, housing_last, stop_f1, center[2], wl[MAX_WL], *pix = NULL;
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
        else if (strcmp(a, "--resolution") == 0) ok = parse_pair_i(v, 'x', &width, &height) && width > 0 && height > 0 && width <= 65536 && height <= 65536;
        else if (strcmp(a, "--size") == 0) ok = parse_pair_d(v, 'x', &size_x, &size_y) && size_x > 0 && size_y > 0;
        else if (strcmp(a, "--field") == 0) ok = parse_pair_d(v, ',', &field_x, &field_y);
        else if (strcmp(a, "--focus") == 0) ok = parse_d(v, &focus);
        else if (strcmp(a, "--baseline-grid") == 0) ok = parse_pair_i(v, 'x', &gx, &gy) && gx > 0 && gy > 0 && gx * gy <= 65536;
        else if (strcmp(a, "--baseline-seconds") == 0) ok = parse_d(v, &base_seconds) && base_seconds >= 0;
        else if (strcmp(a, "--samples") == 0 || strcmp(a, "--seed") == 0 || strcmp(a, "--wavelengths") == 0) {
            char *end;
            long long x;
            errno = 0;
            x = strtoll(v, &end, 10);
            ok = end != v && *end == '\0' && errno == 0 && x >= 0;
            if (ok && strcmp(a, "--samples") == 0) ok = x > 0 && (samples = x) > 0;
            else if (ok && strcmp(a, "--seed") == 0) seed = x;
            else if (ok) ok = x > 0 && x <= MAX_WL && (n_wl = (long)x) > 0;
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
            if (*p) ok = 0;
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
    if ((r = lensrt_lens_load(ctx, table, &lens)) != LENSRT_SUCCESS) return fail(ctx, table, r);
    lensrt_lens_get_info(lens, &info);
    memset(&light, 0, sizeof light);
    light.field_x_deg = field_x;
    light.field_y_deg = field_y;
    if ((r = lensrt_lens_image_point(ctx, lens, &light, 0.5 * (info.wavelength_min_nm + info.wavelength_max_nm), focus,
                                     center)) != LENSRT_SUCCESS)
        return fail(ctx, "image point", r);
    for (i = 0; i < n_wl; i++)
        wl[i] = info.wavelength_min_nm + (info.wavelength_max_nm - info.wavelength_min_nm) * (i + 0.5) / (double)n_wl;
    cpu_model(cpu, sizeof cpu);
    gmtime_r(&t, &tmv);
    strftime(date, sizeof date, "%Y-%m-%dT%H:%M:%SZ", &tmv);

    printf("lensrt-bench: %s\n", info.name);
    printf("  table %s\n", table);
    printf("  light (%g, %g) deg at infinity, image point (%.6f, %.6f) mm, focus offset %g mm\n",
           field_x, field_y, center[0], center[1], focus);
    printf("  window %ldx%ld pixels over %g x %g mm, %ld wavelengths, %lld samples per wavelength\n",
           width, height, size_x, size_y, n_wl, samples);
    printf("  housings: first %g mm, last %g mm; threads %d; cpu %s\n", housing_first, housing_last, threads, cpu);
    fflush(stdout);

    // Baseline pixels: a gx x gy grid of the render's pixel centres; (gx/2, gy/2) is the
    // pixel at the window centre
    pix = malloc(sizeof(double) * 2 * (size_t)(gx * gy));
    if (!pix) return 1;
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
        lensrt_render render = NULL;
        baseline_scene sc;
        memset(&desc, 0, sizeof desc);
        desc.lens = lens;
        desc.sensor.width = (int)width;
        desc.sensor.height = (int)height;
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
        desc.seed = (uint64_t)seed;
        res[i].f_number = f_numbers[i];
        printf("f/%g: lensrt render ...", f_numbers[i]);
        fflush(stdout);
        if ((r = lensrt_render_create(ctx, &desc, &render)) != LENSRT_SUCCESS) return fail(ctx, "render", r);
        if ((r = lensrt_render_run(render, (uint64_t)samples, NULL, NULL)) != LENSRT_SUCCESS) return fail(ctx, "run", r);
        lensrt_render_get_stats(render, &res[i].stats);
        lensrt_render_destroy(render);
        printf(" %.3g splats/s in %.2f s; baseline ...", res[i].stats.splats_per_second, res[i].stats.seconds);
        fflush(stdout);

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
        res[i].base1 = run_baseline(&sc, 1, 256, base_seconds, (uint64_t)seed, center_pixel);
        res[i].baseN = threads > 1 ? run_baseline(&sc, threads, 256, base_seconds, (uint64_t)seed, center_pixel)
                                   : res[i].base1;
        if (res[i].base1.seconds < 0 || res[i].baseN.seconds < 0) {
            fprintf(stderr, "lensrt-bench: out of memory in the baseline\n");
            return 1;
        }
        printf(" %.3g splats/s (1 thread), %.3g (%d threads)\n", res[i].base1.splats_per_second,
               res[i].baseN.splats_per_second, threads);
        fflush(stdout);
    }

    // The table
    printf("\nsplats per second (one aperture sample at one pixel, one wavelength); %d threads\n", threads);
    printf("%-6s %9s %9s %12s %10s %7s %6s %6s %11s %11s %11s %8s %9s\n", "f/N", "stop mm", "seconds", "splats",
           "lensrt/s", "terms", "clip", "tau", "base 1t/s", "base Nt/s", "base coh.", "ratio", "ratio 1t");
    for (i = 0; i < n_f; i++) {
        const lensrt_render_stats *st = &res[i].stats;
        printf("%-6g %9.4f %9.2f %12.4g %10.3g %7.2f %6.3f %6.3f %11.3g %11.3g %11.3f %8.1f %9.1f\n", res[i].f_number,
               st->stop_radius_mm, st->seconds, (double)st->splats, st->splats_per_second, st->phase_terms,
               st->clip_fraction, st->tau_fraction, res[i].base1.splats_per_second, res[i].baseN.splats_per_second,
               res[i].baseN.coherence_center, st->splats_per_second / res[i].baseN.splats_per_second,
               st->splats_per_second / res[i].base1.splats_per_second);
    }
    printf("headline f/%g: %.3g splats/s, %.1fx the scalar double baseline at %d threads (baseline %.3g splats/s)\n",
           res[head].f_number, res[head].stats.splats_per_second,
           res[head].stats.splats_per_second / res[head].baseN.splats_per_second, threads,
           res[head].baseN.splats_per_second);
    printf("(terms: phase terms per splat after pruning; clip, tau: fractions of pixels that needed the inner-pupil\n"
           " clip or a varying transmittance; base coh.: |sum X| / sum |X| of the baseline at the window centre,\n"
           " a check that its phases are coherent to a fraction of a wave)\n");

    if (json) {
        FILE *f = fopen(json, "w");
        if (!f) {
            fprintf(stderr, "lensrt-bench: %s: %s\n", json, strerror(errno));
            return 1;
        }
        fprintf(f, "{\n  \"benchmark\": \"lensrt-bench\",\n  \"lens\": ");
        json_string(f, info.name);
        fprintf(f, ",\n  \"table\": ");
        json_string(f, table);
        fprintf(f, ",\n  \"date\": \"%s\",\n  \"cpu\": ", date);
        json_string(f, cpu);
        fprintf(f, ",\n  \"threads\": %d,\n", threads);
        fprintf(f, "  \"resolution\": [%ld, %ld],\n  \"window_mm\": [%.17g, %.17g],\n", width, height, size_x, size_y);
        fprintf(f, "  \"center_mm\": [%.17g, %.17g],\n  \"focus_offset_mm\": %.17g,\n", center[0], center[1], focus);
        fprintf(f, "  \"light_field_deg\": [%.17g, %.17g],\n  \"wavelengths\": %ld,\n  \"samples\": %lld,\n",
                field_x, field_y, n_wl, samples);
        fprintf(f, "  \"f_number\": %.17g,\n", res[head].f_number);
        fprintf(f, "  \"splats_per_second\": %.17g,\n", res[head].stats.splats_per_second);
        fprintf(f, "  \"baseline_splats_per_second\": %.17g,\n", res[head].baseN.splats_per_second);
        fprintf(f, "  \"baseline_threads\": %d,\n", res[head].baseN.threads);
        fprintf(f, "  \"baseline_single_thread_splats_per_second\": %.17g,\n", res[head].base1.splats_per_second);
        fprintf(f, "  \"ratio\": %.17g,\n", res[head].stats.splats_per_second / res[head].baseN.splats_per_second);
        fprintf(f, "  \"ratio_vs_single_thread\": %.17g,\n",
                res[head].stats.splats_per_second / res[head].base1.splats_per_second);
        fprintf(f, "  \"baseline\": {\"algorithm\": \"paper section 3.2, scalar double, generated Horner lens0001_P_o_d "
                   "once per sample and lens0001_P_s_d per splat, libm cos/sin\", \"pixels\": %ld, \"grid\": [%ld, %ld], "
                   "\"housing_first_mm\": %.17g, \"housing_last_mm\": %.17g},\n",
                gx * gy, gx, gy, housing_first, housing_last);
        fprintf(f, "  \"per_f_number\": {");
        for (i = 0; i < n_f; i++) {
            const lensrt_render_stats *st = &res[i].stats;
            const baseline_result *b1 = &res[i].base1, *bn = &res[i].baseN;
            fprintf(f, "%s\n    \"%g\": {\"splats_per_second\": %.17g, \"seconds\": %.17g, \"splats\": %llu, "
                       "\"samples_per_wavelength\": %llu, \"stop_radius_mm\": %.17g, \"phase_terms\": %.17g, "
                       "\"clip_fraction\": %.17g, \"tau_fraction\": %.17g, \"dark_fraction\": %.17g, "
                       "\"baseline_splats_per_second\": %.17g, \"baseline_seconds\": %.17g, \"baseline_samples\": %ld, "
                       "\"baseline_single_thread_splats_per_second\": %.17g, \"baseline_single_thread_seconds\": %.17g, "
                       "\"baseline_single_thread_samples\": %ld, \"baseline_coherence_center\": %.17g, \"ratio\": %.17g}",
                    i ? "," : "", res[i].f_number, st->splats_per_second, st->seconds, (unsigned long long)st->splats,
                    (unsigned long long)st->samples_per_wavelength, st->stop_radius_mm, st->phase_terms,
                    st->clip_fraction, st->tau_fraction, st->dark_fraction, bn->splats_per_second, bn->seconds,
                    bn->samples, b1->splats_per_second, b1->seconds, b1->samples, bn->coherence_center,
                    st->splats_per_second / bn->splats_per_second);
        }
        fprintf(f, "\n  }\n}\n");
        if (fclose(f) != 0) {
            fprintf(stderr, "lensrt-bench: %s: write failed\n", json);
            return 1;
        }
        printf("wrote %s\n", json);
    }
    free(pix);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    return 0;
}
