/* The render object (internal): scene, prepared polynomials and phasor sums. */
#ifndef LENSRT_RENDER_H
#define LENSRT_RENDER_H

#include "../cpu/kernel.h"
#include "../internal.h"

#define LENSRT_PASS 16384 /* samples per wavelength and pass (a multiple of LENSRT_BLOCK) */

/* A polynomial in (x_S, y_S) and the stop monomials, for one output and wavelength:
 * sum_t coef[t] * xS^ix[t] * yS^iy[t] * mono[slot[t]] (normalised x_S, y_S). */
typedef struct lensrt_pixel_poly {
    int n;
    unsigned char *ix, *iy;
    int *slot;
    double *coef;
} lensrt_pixel_poly;

struct lensrt_render_s {
    lensrt_context ctx;
    lensrt_lens lens;
    lensrt_render_desc desc;      /* lights and wavelengths point at the copies below */
    lensrt_light *lights;
    double *wavelengths;
    int n_lights, n_wl, width, height;
    double pitch_x, pitch_y;      /* mm per pixel */
    double *xs, *ys;              /* pixel centres (mm) */
    double stop_radius, f_number;
    lensrt_region region;
    double measure;               /* area (or length) of the sampled region */
    double mono_radius;           /* stop monomials use u = x_a / mono_radius */
    /* stop monomials: slot k is u^m v^n, m = slot_m[k], n = slot_n[k] */
    int degree, n_slots;
    /* Rows of a sample block: the stop monomials, then (use_basis) the phase basis:
     * g_j = sum_k V[k][j] u^m_k v^n_k over the non-constant slots, where V holds the
     * eigenvectors of the window's phase-coefficient Gram matrix, so that a few g_j
     * carry the phase of every pixel of a small window. */
    int n_rows, use_basis;
    int n_bases, basis_output[4]; /* bases per wavelength and the output of each */
    double *basis;                /* [w][b][(n_slots - 1)^2], V[(k - 1) * (n_slots - 1) + j];
                                     CPU: b = 0 phase (waves), 1 transmittance; GL: b = output */
    int *basis_rank;              /* [w][b]: rows computed per sample */
    int slot_m[136], slot_n[136];
    /* fitted lenses: P_s per wavelength and output (x_i, y_i, tau_i, phi_i), and P_o per
     * light, wavelength, output and slot (already specialised to the light) */
    lensrt_pixel_poly *ps;        /* [w * 4 + o] */
    double *po;                   /* [((l * n_wl + w) * 4 + o) * n_slots + slot] */
    double *light_x, *light_y, *light_d; /* direction cosines and distance (mm, 0: inf) */
    /* phasor sums: [((l * n_wl + w) * npix + p) * 2 + re/im]; sum of |X|^2 per
     * (l, w, p) when the estimator needs it */
    double *sum, *sumsq;
    uint64_t samples;             /* N per wavelength */
    uint64_t splats;
    double seconds;
    struct lensrt_gl_render_s *gl; /* the GL device's buffers and programs (device GL) */
    /* pruning statistics of the last pass: sums over (pixel, wavelength) */
    double stat_terms, stat_clip, stat_tau, stat_dark, stat_count;
};

/* The largest l1 norm of the non-constant coefficients output o (x_i, y_i, tau_i, phi_i)
 * may drop at a pixel whose constant term is c0. */
double lensrt_output_limit(const lensrt_render r, int o, double c0);
double lensrt_huygens_step(const lensrt_render r);

#endif /* LENSRT_RENDER_H */
