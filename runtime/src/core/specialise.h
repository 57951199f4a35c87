/* Fitted polynomials specialised to a scene and to pixels (internal, core/specialise.c).
 *
 * The tables' systems have six inputs (P_o: x_O, y_O, u_O, x_a, y_a, lambda; P_s: x_S,
 * y_S, z_S, x_a, y_a, lambda). Fixing everything but the stop turns an output into
 * coefficients of the stop monomials u^m v^n (u = x_a / mono_radius): slot k of degree
 * d = m + n is d (d + 1) / 2 + n. */
#ifndef LENSRT_SPECIALISE_H
#define LENSRT_SPECIALISE_H

#include "render.h"

double lensrt_ipow(double x, int e);

/* The slot of stop monomial u^m v^n: by total degree, then by n. */
static inline int lensrt_slot_of(int m, int n)
{
    int d = m + n;
    return d * (d + 1) / 2 + n;
}

/* P_o of light l, wavelength w, output o, as coefficients of the stop monomials. */
static inline double *lensrt_po_slots(const lensrt_render r, int l, int w, int o)
{
    return r->po + ((size_t)(l * r->n_wl + w) * 4 + (size_t)o) * (size_t)r->n_slots;
}

/* P_clip (ghost tables, side P_o) of light l, wavelength w, output o, as coefficients of
 * the stop monomials. */
static inline double *lensrt_clip_o_slots(const lensrt_render r, int l, int w, int o)
{
    return r->clip_o + ((size_t)(l * r->n_wl + w) * (size_t)(2 * r->n_clip_pairs) + (size_t)o) * (size_t)r->n_slots;
}

/* The stop degree, slots, P_s per wavelength with z_S and lambda fixed (a polynomial in
 * x_S, y_S and the stop: r->ps) and P_o per light and wavelength (stop only: r->po); a
 * ghost's P_clip like the system whose inputs it takes (r->clip_s or r->clip_o). */
lensrt_result lensrt_specialise_scene(lensrt_render r);

/* Powers 0..15 of the normalised sensor coordinates of (x, y), for the P_s terms. */
void lensrt_sensor_powers(const lensrt_lens lens, double x, double y, double px[16], double py[16]);
/* c[0 .. n_slots): the stop-monomial coefficients of p at the sensor point whose powers
 * are px, py. */
void lensrt_slot_coefficients(const lensrt_pixel_poly *p, const double *px, const double *py, double *c,
                              int n_slots);
/* The Huygens amplitude of pixel (x, y) for wavelength w: sqrt|det d2 phi / (d a d s)| /
 * lambda at the stop centre (Rayleigh-Sommerfeld's cos(theta) / (lambda r) in free
 * space), by central differences of step lensrt_huygens_step. */
double lensrt_huygens_amplitude(const lensrt_render r, int w, double x, double y);

#endif /* LENSRT_SPECIALISE_H */
