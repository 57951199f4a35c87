/* The splat kernel, compiled with -O3 -ffast-math (this file only; see CMakeLists.txt).
 *
 * Loops run over a fixed block of samples so that the compiler vectorises them; each
 * step is its own loop (phase sum, clip, transmittance, sine/cosine, accumulation),
 * which keeps GCC from fusing sinf/cosf into a scalar sincosf call. */
#include "kernel.h"

#include <math.h>

#define B LENSRT_BLOCK
#define TWO_PI_F 6.28318530717958647692f

/* sin and cos of 2 pi p: reduce p to [-1/2, 1/2], split off the quadrant q = rint(4 p),
 * evaluate Taylor polynomials on |2 pi r| <= pi/4 (errors below 3.3e-7 for sin and
 * 2.5e-8 for cos there), then rotate by the quadrant. */
static inline void sincos2pi(float p, float *c_out, float *s_out)
{
    float t = p - rintf(p);
    float q = rintf(4.0f * t);
    float x = TWO_PI_F * (t - 0.25f * q);
    float x2 = x * x;
    float s = x * (1.0f + x2 * (-1.0f / 6.0f + x2 * (1.0f / 120.0f + x2 * (-1.0f / 5040.0f))));
    float c = 1.0f + x2 * (-0.5f + x2 * (1.0f / 24.0f + x2 * (-1.0f / 720.0f + x2 * (1.0f / 40320.0f))));
    int qi = (int)q & 3;
    float swap_s = (qi & 1) ? c : s, swap_c = (qi & 1) ? s : c;
    *s_out = (qi & 2) ? -swap_s : swap_s;
    *c_out = ((qi + 1) & 2) ? -swap_c : swap_c;
}

void lensrt_sincos2pi_f(float p, float *c, float *s) { sincos2pi(p, c, s); }

/* out[j] = sum_k coef_k * mono[slot_k][j] (+ start) */
static inline void dot_f(const float *mono, const lensrt_terms_f *t, float start, float *out)
{
    int j, k;
    for (j = 0; j < B; j++) out[j] = start;
    for (k = 0; k < t->n; k++) {
        const float *row = mono + (long)t->slot[k] * B;
        float c = t->coef[k];
        for (j = 0; j < B; j++) out[j] += c * row[j];
    }
}

void lensrt_kernel_f(const float *mono, int n_lights, const float *sphase, const float *samp,
                     const lensrt_pixel_f *px, double *acc)
{
    float phase[B], weight[B], x[B], y[B];
    int j, l;
    // Phase after the stop (waves), the same for every light
    dot_f(mono, &px->phase, px->phase0, phase);
    // Amplitude factor after the stop: inner-pupil clip and transmittance
    for (j = 0; j < B; j++) weight[j] = 1.0f;
    if (px->clip) {
        dot_f(mono, &px->xi, 0.0f, x);
        dot_f(mono, &px->yi, 0.0f, y);
        for (j = 0; j < B; j++) weight[j] = (x[j] * x[j] + y[j] * y[j] <= px->housing2) ? 1.0f : 0.0f;
    }
    if (px->tau.n > 0) {
        dot_f(mono, &px->tau, 0.0f, x);
        for (j = 0; j < B; j++) weight[j] *= sqrtf(x[j] > 0.0f ? x[j] : 0.0f);
    }
    // Phasors per light: total phase, its sine and cosine, and the sums
    for (l = 0; l < n_lights; l++) {
        const float *sp = sphase + (long)l * B, *sa = samp + (long)l * B;
        float re = 0.0f, im = 0.0f, sq = 0.0f;
        float c[B], s[B];
        for (j = 0; j < B; j++) sincos2pi(phase[j] + sp[j], &c[j], &s[j]);
        for (j = 0; j < B; j++) {
            float a = weight[j] * sa[j];
            re += a * c[j];
            im += a * s[j];
            sq += a * a;
        }
        acc[3 * l] += re;
        acc[3 * l + 1] += im;
        acc[3 * l + 2] += sq;
    }
}

static inline void dot_d(const double *mono, const lensrt_terms_d *t, double start, double *out)
{
    int j, k;
    for (j = 0; j < B; j++) out[j] = start;
    for (k = 0; k < t->n; k++) {
        const double *row = mono + (long)t->slot[k] * B;
        double c = t->coef[k];
        for (j = 0; j < B; j++) out[j] += c * row[j];
    }
}

void lensrt_kernel_d(const double *mono, int n_lights, const double *sphase,
                     const double *samp, const lensrt_pixel_d *px, double *acc)
{
    double phase[B], weight[B], x[B], y[B];
    int j, l;
    dot_d(mono, &px->phase, px->phase0, phase);
    for (j = 0; j < B; j++) weight[j] = 1.0;
    if (px->clip) {
        dot_d(mono, &px->xi, 0.0, x);
        dot_d(mono, &px->yi, 0.0, y);
        for (j = 0; j < B; j++) weight[j] = (x[j] * x[j] + y[j] * y[j] <= px->housing2) ? 1.0 : 0.0;
    }
    if (px->tau.n > 0) {
        dot_d(mono, &px->tau, 0.0, x);
        for (j = 0; j < B; j++) weight[j] *= sqrt(x[j] > 0.0 ? x[j] : 0.0);
    }
    for (l = 0; l < n_lights; l++) {
        const double *sp = sphase + (long)l * B, *sa = samp + (long)l * B;
        double re = 0.0, im = 0.0, sq = 0.0;
        for (j = 0; j < B; j++) {
            // Reduce in double, then the libm sine and cosine
            double p = phase[j] + sp[j], a = weight[j] * sa[j];
            p = 6.283185307179586477 * (p - rint(p));
            re += a * cos(p);
            im += a * sin(p);
            sq += a * a;
        }
        acc[3 * l] += re;
        acc[3 * l + 1] += im;
        acc[3 * l + 2] += sq;
    }
}

void lensrt_kernel_free_space(const double *xy, int n_lights, const double *sphase,
                              const double *samp, double x, double y, double z,
                              double lambda_mm, int one_d, int naive, double *acc)
{
    double path[B], amp[B], c[B], s[B];
    int j, l;
    // Distance from each sample to the pixel, in waves, and the kernel's amplitude
    for (j = 0; j < B; j++) {
        double dx = x - xy[j], dy = y - xy[B + j], r2 = dx * dx + dy * dy + z * z, r = sqrt(r2);
        path[j] = r / lambda_mm;
        amp[j] = one_d ? z / (r * sqrt(lambda_mm * r)) : z / (lambda_mm * r2);
    }
    for (l = 0; l < n_lights; l++) {
        const double *sp = sphase + (long)l * B, *sa = samp + (long)l * B;
        double re = 0.0, im = 0.0, sq = 0.0;
        // Total phase reduced in double (or summed in float, for the naive mode)
        for (j = 0; j < B; j++) {
            double p = naive ? (double)((float)path[j] + (float)sp[j]) : path[j] + sp[j];
            c[j] = 6.283185307179586477 * (p - rint(p));
        }
        for (j = 0; j < B; j++) s[j] = sin(c[j]);
        for (j = 0; j < B; j++) c[j] = cos(c[j]);
        for (j = 0; j < B; j++) {
            double a = amp[j] * sa[j];
            re += a * c[j];
            im += a * s[j];
            sq += a * a;
        }
        acc[3 * l] += re;
        acc[3 * l + 1] += im;
        acc[3 * l + 2] += sq;
    }
}
