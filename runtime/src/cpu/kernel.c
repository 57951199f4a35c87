/* The splat kernel, compiled with -O3 -ffast-math (this file only; see CMakeLists.txt).
 *
 * Loops run over a fixed block of samples so that the compiler vectorises them; each
 * step is its own loop (phase sum, clip, transmittance, sine/cosine, accumulation),
 * which keeps GCC from fusing sinf/cosf into a scalar sincosf call. */
#include "kernel.h"

#include <math.h>
#include <string.h>

#define B LENSRT_BLOCK
#define TWO_PI_F 6.28318530717958647692f


#if defined(__GNUC__) && !defined(LENSRT_SCALAR_KERNEL)
/* GCC/Clang vector extensions: 16 floats per vector (two AVX2 registers, or one AVX-512
 * register); a chunk is two vectors whose partial sums stay in registers while the
 * terms stream past. Plain C below is the same computation for other compilers. */
typedef float vf __attribute__((vector_size(64)));
typedef int vi __attribute__((vector_size(64)));
#define VL 16
#define NV 4 /* vectors per chunk */
#define CH (NV * VL)

static inline vf vload(const float *p)
{
    vf v;
    memcpy(&v, p, sizeof v);
    return v;
}

static inline vf vsplat(float x)
{
    vf v = {0};
    return v + x;
}

static inline float vsum(vf v)
{
    float s = 0.0f;
    int j;
    for (j = 0; j < VL; j++) s += v[j];
    return s;
}

/* The vector form of sincos2pi: floor by conversion, fold to [-1/2, 1/2], quadrant by
 * conversion, polynomial, then the quadrant's swap and signs as arithmetic blends. */
static inline void vsincos2pi(vf p, vf *c_out, vf *s_out)
{
    vf f = __builtin_convertvector(__builtin_convertvector(p, vi), vf);
    vf t, x, x2, s, c, swap, sign_s, sign_c;
    vi q, qm;
    f += __builtin_convertvector(p < f, vf);          /* floor: -1 where truncation went up */
    t = p - f;                                          /* [0, 1) */
    t += __builtin_convertvector(t > 0.5f, vf);        /* [-1/2, 1/2] */
    q = __builtin_convertvector(4.0f * t + 2.5f, vi) - 2; /* round(4 t) in -2..2 */
    x = TWO_PI_F * (t - 0.25f * __builtin_convertvector(q, vf));
    x2 = x * x;
    s = x * (1.0f + x2 * (-1.0f / 6.0f + x2 * (1.0f / 120.0f + x2 * (-1.0f / 5040.0f))));
    c = 1.0f + x2 * (-0.5f + x2 * (1.0f / 24.0f + x2 * (-1.0f / 720.0f + x2 * (1.0f / 40320.0f))));
    qm = q & 3;
    swap = __builtin_convertvector(qm & 1, vf);
    sign_s = 1.0f - 2.0f * __builtin_convertvector((qm >> 1) & 1, vf);
    sign_c = 1.0f - 2.0f * __builtin_convertvector(((qm + 1) >> 1) & 1, vf);
    *s_out = sign_s * (s + swap * (c - s));
    *c_out = sign_c * (c + swap * (s - c));
}

/* out[0 .. NV) = start + sum_k coef_k * mono[slot_k][jc .. jc + CH) */
static inline void vdot(const float *mono, const lensrt_terms_f *t, float start, int jc, vf *out)
{
    vf s0 = vsplat(start), s1 = s0, s2 = s0, s3 = s0;
    int k;
    for (k = 0; k < t->n; k++) {
        const float *row = mono + (long)t->slot[k] * B + jc;
        float c = t->coef[k];
        s0 += c * vload(row);
        s1 += c * vload(row + VL);
        s2 += c * vload(row + 2 * VL);
        s3 += c * vload(row + 3 * VL);
    }
    out[0] = s0;
    out[1] = s1;
    out[2] = s2;
    out[3] = s3;
}

/* A stop crossing of a bladed or slit stop (core/render.h): 1 where (x, y) passes its
 * circle (r2_max) and its edge or slit tests, 0 elsewhere. */
static inline vf vstop(const lensrt_stop_shape *st, vf x, vf y, float r2_max)
{
    vf r2 = x * x + y * y;
    vi m = r2 <= r2_max;
    int k;
    if (st->kind == LENSRT_STOP_BLADES) {
        for (k = 0; k < st->n; k++) m &= st->f_a * r2 + st->f_gx[k] * x + st->f_gy[k] * y <= st->f_c[k];
    } else {
        vf d0 = x - st->f_centre[0], d1 = x - st->f_centre[1];
        vi in = (d0 <= st->f_half_x) & (d0 >= -st->f_half_x);
        if (st->n == 2) in |= (d1 <= st->f_half_x) & (d1 >= -st->f_half_x);
        m &= in & (y <= st->f_half_y) & (y >= -st->f_half_y);
    }
    return -__builtin_convertvector(m, vf);
}

/* The kernel, compiled twice: shaped 0 (every direct render, and ghosts whose pixel tests
 * no stop crossing of a bladed or slit stop: the code the kernel always was) and 1. */
static inline __attribute__((always_inline)) void kernel_f(const float *mono, int n_lights, const float *sphase,
                                                           const float *samp, const lensrt_pixel_f *px, double *acc,
                                                           const int shaped)
{
    vf re[64], im[64], sq[64];
    int jc, l, h, q;
    for (l = 0; l < n_lights; l++) re[l] = im[l] = sq[l] = vsplat(0.0f);
    for (jc = 0; jc < B; jc += CH) {
        vf ph[NV], w[NV], x[NV], y[NV];
        // Phase after the stop (waves), the same for every light
        vdot(mono, &px->phase, px->phase0, jc, ph);
        for (h = 0; h < NV; h++) w[h] = vsplat(1.0f);
        // Inner-pupil clip: 1 inside the housing, 0 outside
        if (px->clip) {
            vdot(mono, &px->xi, 0.0f, jc, x);
            vdot(mono, &px->yi, 0.0f, jc, y);
            for (h = 0; h < NV; h++)
                w[h] = -__builtin_convertvector(x[h] * x[h] + y[h] * y[h] <= px->housing2, vf);
        }
        // A ghost's clip pairs (none in a direct render): 0 where any pair fails
        for (q = 0; q < px->n_clip; q++) {
            vdot(mono, &px->clip_x[q], 0.0f, jc, x);
            vdot(mono, &px->clip_y[q], 0.0f, jc, y);
            if (!shaped || !px->clip_shaped[q]) {
                for (h = 0; h < NV; h++)
                    w[h] *= -__builtin_convertvector(x[h] * x[h] + y[h] * y[h] <= px->clip_r2[q], vf);
            } else {
                // A stop crossing of a bladed or slit stop: its circle, then its shape
                for (h = 0; h < NV; h++) w[h] *= vstop(px->stop, x[h], y[h], px->clip_r2[q]);
            }
        }
        // Amplitude transmittance: the square root of the power transmittance
        if (px->tau.n > 0) {
            vdot(mono, &px->tau, 0.0f, jc, x);
            for (h = 0; h < NV; h++) {
                vf tv = x[h] + __builtin_convertvector(x[h] < 0.0f, vf) * x[h]; /* max(x, 0) */
                vf r = vsplat(0.0f);
                int j;
                for (j = 0; j < VL; j++) r[j] = sqrtf(tv[j]);
                w[h] *= r;
            }
        }
        // Phasors per light
        for (l = 0; l < n_lights; l++) {
            for (h = 0; h < NV; h++) {
                vf c, s, a = w[h] * vload(samp + (long)l * B + jc + h * VL);
                vsincos2pi(ph[h] + vload(sphase + (long)l * B + jc + h * VL), &c, &s);
                re[l] += a * c;
                im[l] += a * s;
                sq[l] += a * a;
            }
        }
    }
    for (l = 0; l < n_lights; l++) {
        acc[3 * l] += vsum(re[l]);
        acc[3 * l + 1] += vsum(im[l]);
        acc[3 * l + 2] += vsum(sq[l]);
    }
}

static __attribute__((noinline)) void kernel_f_round(const float *mono, int n_lights, const float *sphase,
                                                     const float *samp, const lensrt_pixel_f *px, double *acc)
{
    kernel_f(mono, n_lights, sphase, samp, px, acc, 0);
}

static __attribute__((noinline)) void kernel_f_shaped(const float *mono, int n_lights, const float *sphase,
                                                      const float *samp, const lensrt_pixel_f *px, double *acc)
{
    kernel_f(mono, n_lights, sphase, samp, px, acc, 1);
}

void lensrt_kernel_f(const float *mono, int n_lights, const float *sphase, const float *samp,
                     const lensrt_pixel_f *px, double *acc)
{
    int q, shaped = 0;
    for (q = 0; q < px->n_clip; q++) shaped |= px->clip_shaped[q];
    if (shaped) kernel_f_shaped(mono, n_lights, sphase, samp, px, acc);
    else kernel_f_round(mono, n_lights, sphase, samp, px, acc);
}

#else

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

/* A stop crossing inside a bladed or slit stop (core/render.h), in float: 1 or 0 (the
 * circle test is the caller's) */
static float stop_f(const lensrt_stop_shape *st, float x, float y, float r2)
{
    int k;
    if (st->kind == LENSRT_STOP_BLADES) {
        for (k = 0; k < st->n; k++)
            if (st->f_a * r2 + st->f_gx[k] * x + st->f_gy[k] * y > st->f_c[k]) return 0.0f;
        return 1.0f;
    }
    if (fabsf(y) > st->f_half_y) return 0.0f;
    return fabsf(x - st->f_centre[0]) <= st->f_half_x || (st->n == 2 && fabsf(x - st->f_centre[1]) <= st->f_half_x)
               ? 1.0f : 0.0f;
}

/* out[j] = start + sum_k coef_k * mono[slot_k][j] */
static void dot_f(const float *mono, const lensrt_terms_f *t, float start, float *out)
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
    float phase[B], weight[B], x[B], y[B], c[B], s[B];
    int j, l, q;
    dot_f(mono, &px->phase, px->phase0, phase);
    for (j = 0; j < B; j++) weight[j] = 1.0f;
    if (px->clip) {
        dot_f(mono, &px->xi, 0.0f, x);
        dot_f(mono, &px->yi, 0.0f, y);
        for (j = 0; j < B; j++) weight[j] = (x[j] * x[j] + y[j] * y[j] <= px->housing2) ? 1.0f : 0.0f;
    }
    for (q = 0; q < px->n_clip; q++) {
        dot_f(mono, &px->clip_x[q], 0.0f, x);
        dot_f(mono, &px->clip_y[q], 0.0f, y);
        for (j = 0; j < B; j++)
            weight[j] *= (x[j] * x[j] + y[j] * y[j] <= px->clip_r2[q]) ? 1.0f : 0.0f;
        if (px->clip_shaped[q])
            for (j = 0; j < B; j++) weight[j] *= stop_f(px->stop, x[j], y[j], x[j] * x[j] + y[j] * y[j]);
    }
    if (px->tau.n > 0) {
        dot_f(mono, &px->tau, 0.0f, x);
        for (j = 0; j < B; j++) weight[j] *= sqrtf(x[j] > 0.0f ? x[j] : 0.0f);
    }
    for (l = 0; l < n_lights; l++) {
        const float *sp = sphase + (long)l * B, *sa = samp + (long)l * B;
        float re = 0.0f, im = 0.0f, sq = 0.0f;
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
#endif

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
    int j, l, q;
    dot_d(mono, &px->phase, 0.0, phase); /* the constant phase is dropped */
    for (j = 0; j < B; j++) weight[j] = 1.0;
    if (px->clip) {
        dot_d(mono, &px->xi, 0.0, x);
        dot_d(mono, &px->yi, 0.0, y);
        for (j = 0; j < B; j++) weight[j] = (x[j] * x[j] + y[j] * y[j] <= px->housing2) ? 1.0 : 0.0;
    }
    for (q = 0; q < px->n_clip; q++) {
        dot_d(mono, &px->clip_x[q], 0.0, x);
        dot_d(mono, &px->clip_y[q], 0.0, y);
        for (j = 0; j < B; j++)
            weight[j] *= (x[j] * x[j] + y[j] * y[j] <= px->clip_r2[q]) ? 1.0 : 0.0;
        // A stop crossing of a bladed or slit stop: its shape too, in double
        if (px->clip_shaped[q])
            for (j = 0; j < B; j++) weight[j] *= lensrt_stop_shape_contains(px->stop, x[j], y[j]) ? 1.0 : 0.0;
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
