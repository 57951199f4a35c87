/* Fitted polynomials specialised to a scene and to pixels (internal, core/specialise.c).
 *
 * The tables' systems have six inputs (P_o: x_O, y_O, u_O, x_a, y_a, lambda; P_s: x_S,
 * y_S, z_S, x_a, y_a, lambda). Fixing everything but the stop turns an output into
 * coefficients of the stop monomials u^m v^n (u = x_a / mono_radius): slot k of degree
 * d = m + n is d (d + 1) / 2 + n. */
#ifndef LENSRT_SPECIALISE_H
#define LENSRT_SPECIALISE_H

#include "render.h"

#include <math.h>

double lensrt_ipow(double x, int e);

/* The slot of stop monomial u^m v^n: by total degree, then by n. */
static inline int lensrt_slot_of(int m, int n)
{
    int d = m + n;
    return d * (d + 1) / 2 + n;
}

/* P_o per light and wavelength, as coefficients of the stop monomials: its four outputs
 * (x_o, y_o, tau_o, phi_o), then the front group's flux Jacobian (LENSRT_PO_FLUX .. +3):
 * d^2 phi_o / d x_O d x_a, d x_O d y_a, d y_O d x_a, d y_O d y_a (mm / mm: phi_o's
 * derivative by the light's direction cosine is where the ray crosses the first vertex
 * plane, lensrt_front_flux). */
#define LENSRT_PO_FLUX 4
#define LENSRT_PO_OUTPUTS 8

/* P_o of light l, wavelength w, output o (0 .. LENSRT_PO_OUTPUTS - 1), as coefficients of
 * the stop monomials. */
static inline double *lensrt_po_slots(const lensrt_render r, int l, int w, int o)
{
    return r->po + ((size_t)(l * r->n_wl + w) * LENSRT_PO_OUTPUTS + (size_t)o) * (size_t)r->n_slots;
}

/* The flux of light l through the stop per unit stop area, relative to the light's
 * irradiance on the first vertex plane: |det dp/da| / |w . L|, where p is where the ray
 * to stop point a crosses the vertex plane (p = grad of phi_o over the light's direction
 * cosines, so dp/da = h: h11 h12 / h21 h22 from the LENSRT_PO_FLUX slots), w the light's
 * direction (towards the scene) and L the ray's unit direction leaving a near light
 * (|w . L| = 1 at infinity). (xo, yo): the ray on the first surface, for L. */
static inline double lensrt_front_flux(const lensrt_render r, int l, double xo, double yo, const double h[4])
{
    const double det = h[0] * h[3] - h[1] * h[2];
    double f = det < 0 ? -det : det;
    if (r->light_d[l] > 0) {
        // L from the light (at distance d along w from the first vertex) to (xo, yo, 0)
        const double d = r->light_d[l], lx = r->light_x[l], ly = r->light_y[l];
        const double lz = -sqrt(1.0 - lx * lx - ly * ly);
        const double vx = xo - d * lx, vy = yo - d * ly, vz = -d * lz;
        const double wl = (lx * vx + ly * vy + lz * vz) / sqrt(vx * vx + vy * vy + vz * vz);
        f /= wl < 0 ? -wl : wl;
    }
    if (!(f <= LENSRT_MAX_FLUX)) f = f > LENSRT_MAX_FLUX ? LENSRT_MAX_FLUX : 0.0; /* NaN: 0, as a failed sample */
    return f;
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
/* Step (mm) of the central differences of the Huygens amplitude (both devices use it:
 * one definition). */
double lensrt_huygens_step(const lensrt_render r);

#endif /* LENSRT_SPECIALISE_H */
