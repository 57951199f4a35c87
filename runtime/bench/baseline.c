/* baseline.c: what lensrt-bench measures lensrt against, the paper's Algorithm (section
 * 3.2) as written, with the generated Horner code of the same lens (lens0001_P_o_d,
 * lens0001_P_s_d): for every sample a random point in the stop disc and one of the 16
 * wavelengths in turn, P_o once (outer pupil clip at the first surface's housing, tau_o,
 * phi_o), then for every pixel of a grid spread over the same frame P_s (inner pupil clip
 * at the last surface's housing, tau_i, phi_i), phase 2 pi / lambda (phi_o + phi_i) in
 * double, amplitude sqrt(tau_o tau_i), cos and sin from libm into that pixel's phasor sum
 * for that wavelength. It runs with OpenMP over pixels at the same thread count as lensrt,
 * right before and right after every lensrt render (the ratio of each render is against
 * the baseline that bracketed it; medians over the repetitions are reported), and
 * single-threaded for context. Also here: the lens facts it reads from the table
 * (housings, stop radius) and its grid of pixels.
 *
 * Built with the build's -O level and, with LENSRT_NATIVE, -march=native; no fast-math
 * (libm cos/sin in double, as the paper's algorithm). */
#include "baseline.h"
#include "bench.h"
#include "lens0001.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define NM_PER_MM 1e6

static uint64_t splitmix64(uint64_t *state)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

static double uniform01(uint64_t *state) { return (double)(splitmix64(state) >> 11) * (1.0 / 9007199254740992.0); }

/* Per sample: the stop point, the wavelength index and what P_o gave. */
typedef struct sample_po {
    double xa, ya, lambda_nm, lambda_mm, amp_o, phi_o;
    int w, clipped;
} sample_po;

/* The paper's algorithm, for `chunk` samples per round until `min_seconds` have passed.
 * acc[(p * n_wl + w) * 3 + 0..2]: sum re, sum im, sum |X| per pixel and wavelength. */
baseline_result run_baseline(const baseline_scene *sc, int threads, int chunk, double min_seconds, uint64_t seed,
                             int center_pixel)
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
baseline_result combine(const baseline_result *a, const baseline_result *b)
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

/* A `lens KEY VALUE` line of the table: a number, nothing after it. */
int table_lens_value(const char *path, const char *key, double *out)
{
    FILE *f = fopen(path, "r");
    char line[512];
    size_t n = strlen(key);
    int found = 0;
    if (!f) return 0;
    while (fgets(line, sizeof line, f)) {
        if (strncmp(line, "system ", 7) == 0) break; /* lens lines come before the systems */
        if (strncmp(line, "lens ", 5) == 0 && strncmp(line + 5, key, n) == 0 && line[5 + n] == ' ') {
            char *v = strtok(line + 6 + n, " \r\n"), *end;
            if (v) {
                errno = 0;
                *out = strtod(v, &end);
                found = end != v && *end == '\0' && errno == 0 && isfinite(*out);
            }
            break;
        }
    }
    fclose(f);
    return found;
}

/* A gx x gy grid of the frame's pixel centres (mm, x y pairs; caller frees); the pixel
 * (gx/2, gy/2), at the window centre, in *center_pixel. NULL: out of memory. */
double *baseline_grid(long gx, long gy, long width, long height, double size_x, double size_y, const double center[2],
                      int *center_pixel)
{
    double *pix = malloc(sizeof(double) * 2 * (size_t)(gx * gy));
    double pitch_x = size_x / (double)width, pitch_y = size_y / (double)height;
    long a, b;
    if (!pix) return NULL;
    for (b = 0; b < gy; b++)
        for (a = 0; a < gx; a++) {
            long px = a * width / gx, py = b * height / gy;
            pix[2 * (b * gx + a)] = center[0] + ((double)px + 0.5 - 0.5 * (double)width) * pitch_x;
            pix[2 * (b * gx + a) + 1] = center[1] + (0.5 * (double)height - (double)py - 0.5) * pitch_y;
        }
    *center_pixel = (int)((gy / 2) * gx + gx / 2);
    return pix;
}
