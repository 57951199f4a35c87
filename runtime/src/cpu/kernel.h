/* The splat kernel (internal): one pixel against one block of aperture samples.
 *
 * Per pixel, the transport after the stop, P_s, is a polynomial in the stop coordinates
 * whose coefficients depend only on the pixel and the wavelength. cpu/pixel.c computes them
 * once per pixel and pass, in double, drops the constant phase (it cannot change the
 * pixel's intensity), converts the phase to waves and prunes terms too small to matter.
 * Each splat is then a short dot product with the sample's stop monomials, a sine and a
 * cosine, and two multiply-adds per light. */
#ifndef LENSRT_KERNEL_H
#define LENSRT_KERNEL_H

#include "../core/render.h" /* LENSRT_BLOCK: samples per block (padded with zero amplitude) */

typedef struct lensrt_terms_f {
    int n;
    const int *slot;    /* row of the monomial block */
    const float *coef;
} lensrt_terms_f;

typedef struct lensrt_terms_d {
    int n;
    const int *slot;
    const double *coef;
} lensrt_terms_d;

/* A pixel for the float kernel. */
typedef struct lensrt_pixel_f {
    lensrt_terms_f phase; /* waves; the constant term is phase0 (naive mode only) */
    lensrt_terms_f xi, yi; /* inner pupil position (mm), when clip */
    lensrt_terms_f tau;    /* power transmittance, when n > 0 (else constant, folded in) */
    float phase0;
    float housing2;        /* housing radius squared (mm^2) */
    int clip;
    /* A ghost's P_clip pairs tested per splat (side P_s; 0 for every direct render): a
     * sample passes pair q when x^2 + y^2 <= clip_r2[q] (x, y with their constant terms)
     * and, when clip_shaped[q] (a stop crossing of a bladed or slit aperture), when
     * `stop` contains (x, y) (core/render.h: its edge or slit tests, in float) */
    int n_clip;
    lensrt_terms_f clip_x[LENSRT_MAX_CLIP_PAIRS], clip_y[LENSRT_MAX_CLIP_PAIRS];
    float clip_r2[LENSRT_MAX_CLIP_PAIRS];
    int clip_shaped[LENSRT_MAX_CLIP_PAIRS];
    const lensrt_stop_shape *stop;
} lensrt_pixel_f;

typedef struct lensrt_pixel_d {
    lensrt_terms_d phase, xi, yi, tau; /* phase without its constant term */
    double housing2;
    int clip;
    int n_clip;
    lensrt_terms_d clip_x[LENSRT_MAX_CLIP_PAIRS], clip_y[LENSRT_MAX_CLIP_PAIRS];
    double clip_r2[LENSRT_MAX_CLIP_PAIRS];
    int clip_shaped[LENSRT_MAX_CLIP_PAIRS];
    const lensrt_stop_shape *stop;
} lensrt_pixel_d;

/* Accumulate acc[3 l + 0..2] += (sum re, sum im, sum |X|^2) over the block for every
 * light l. mono[slot * LENSRT_BLOCK + j]: stop monomials of sample j; sphase and samp
 * [l * LENSRT_BLOCK + j]: the sample's phase (waves, reduced) and amplitude per light
 * (0 for padding and for samples clipped before the stop). */
void lensrt_kernel_f(const float *mono, int n_lights, const float *sphase, const float *samp,
                     const lensrt_pixel_f *px, double *acc);
void lensrt_kernel_d(const double *mono, int n_lights, const double *sphase,
                     const double *samp, const lensrt_pixel_d *px, double *acc);

/* Free space after the stop (analytic lenses), in double: the Rayleigh-Sommerfeld
 * kernel cos(theta) / (lambda r), or cos(theta) / sqrt(lambda r) for cylindrical waves
 * (one_d). xy: the block's x row then y row (mm); sphase and samp as above; (x, y) the
 * pixel, z the distance from the stop plane to the sensor (mm). With naive, the phase
 * sum is rounded to float first (to show why the default does not). */
void lensrt_kernel_free_space(const double *xy, int n_lights, const double *sphase,
                              const double *samp, double x, double y, double z,
                              double lambda_mm, int one_d, int naive, double *acc);

#endif /* LENSRT_KERNEL_H */
