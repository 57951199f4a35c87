/* Renders: scene checks, the Monte Carlo integrator over the aperture, resolving the
 * phasor sums into intensities.
 *
 * For every wavelength and pass:
 *   1. draw aperture samples (sampler.c) and evaluate P_o for each light per sample:
 *      outer-pupil clip, transmittance, phase reduced to [-1/2, 1/2] waves in double;
 *   2. for every pixel (in parallel over pixel tiles), specialise P_s to the pixel:
 *      coefficients of the stop monomials in double, phase in waves, constant phase
 *      dropped, negligible terms pruned;
 *   3. splat each block of samples to the pixel (kernel.c) and add the phasor sums.
 * Pixels never share sums and samples are pure functions of their index, so the result
 * does not depend on the number of threads. */
#include "../c_numbers.h"
#include "render.h"
#ifdef LENSRT_GL
#include "../gl/gl_render.h"
#endif

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#ifdef LENSRT_OPENMP
#include <omp.h>
#endif

#define PI 3.14159265358979323846
#define NM_PER_MM 1e6
#define PASS LENSRT_PASS
#define TILE 16              /* pixels per tile */
#define DEFAULT_WAVELENGTHS 16

static const char *sampler_name(lensrt_sampler s)
{
    return s == LENSRT_SAMPLER_RANDOM ? "random" : s == LENSRT_SAMPLER_STRATIFIED ? "stratified" : "sobol";
}

/* ------------------------------------------------------------- scene checks ----- */

static lensrt_result check_desc(lensrt_context ctx, const lensrt_render_desc *d, const lensrt_lens_info *info)
{
    const lensrt_sensor *s = &d->sensor;
    const lensrt_aperture *a = &d->aperture;
    int i;
    if (s->width <= 0 || s->height <= 0 || s->width > 65536 || s->height > 65536)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "sensor: resolution must be 1..65536 pixels per side, got %d x %d", s->width, s->height);
    if (!(s->width_mm > 0 && isfinite(s->width_mm)) || !(s->height_mm >= 0 && isfinite(s->height_mm)))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "sensor: width_mm must be positive and height_mm positive or 0, got %g and %g",
                           s->width_mm, s->height_mm);
    if (!isfinite(s->center_x_mm) || !isfinite(s->center_y_mm) || !isfinite(s->focus_offset_mm))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "sensor: centre and focus offset must be finite");
    if (s->focus_offset_mm < info->focus_offset_min_mm - 1e-9 || s->focus_offset_mm > info->focus_offset_max_mm + 1e-9)
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                           "sensor: focus offset %g mm is outside the fitted range [%g, %g] mm of %s",
                           s->focus_offset_mm, info->focus_offset_min_mm, info->focus_offset_max_mm, info->name);
    if (d->n_lights < 0 || (d->n_lights > 0 && !d->lights) || d->n_lights > 64)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lights: expected 0..64 lights with a non-NULL array, got %d", d->n_lights);
    if (d->n_wavelengths < 0 || d->n_wavelengths > 4096)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "wavelengths: expected 0..4096, got %d", d->n_wavelengths);
    if (d->wavelengths_nm && d->n_wavelengths == 0)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "wavelengths: an array was given with n_wavelengths 0");
    for (i = 0; d->wavelengths_nm && i < d->n_wavelengths; i++) {
        double w = d->wavelengths_nm[i];
        if (!(w >= info->wavelength_min_nm - 1e-9 && w <= info->wavelength_max_nm + 1e-9))
            return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                               "wavelength %d: %g nm is outside the fitted range [%g, %g] nm of %s",
                               i, w, info->wavelength_min_nm, info->wavelength_max_nm, info->name);
    }
    if ((unsigned)d->sampler > LENSRT_SAMPLER_SOBOL || (unsigned)d->estimator > LENSRT_ESTIMATOR_UNBIASED ||
        (unsigned)d->precision > LENSRT_PRECISION_NAIVE_FLOAT || (unsigned)a->shape > LENSRT_APERTURE_SLIT ||
        (unsigned)d->device > LENSRT_DEVICE_GL)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "sampler, estimator, precision, device or aperture shape: unknown value");
    // (|sum X|^2 - sum |X|^2) / (N (N - 1)) is unbiased for independent samples only:
    // with correlated ones (Sobol, strata) the mean's error is far below the i.i.d. term
    if (d->estimator == LENSRT_ESTIMATOR_UNBIASED &&
        (d->sampler == LENSRT_SAMPLER_SOBOL || d->sampler == LENSRT_SAMPLER_STRATIFIED))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "estimator: the unbiased estimator needs independent samples (sampler random "
                           "or default); the %s sampler correlates them and would bias it low",
                           d->sampler == LENSRT_SAMPLER_SOBOL ? "sobol" : "stratified");
    if (!(d->phase_tolerance_waves >= 0 && d->phase_tolerance_waves < 0.5))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "phase_tolerance_waves must be in [0, 0.5), got %g", d->phase_tolerance_waves);
    if (a->shape == LENSRT_APERTURE_BLADES && (a->blades < 3 || a->blades > 64 || !(a->blade_curvature >= 0 && a->blade_curvature <= 1)))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "aperture: blades must be 3..64 with curvature in [0, 1], got %d blades, curvature %g",
                           a->blades, a->blade_curvature);
    if (a->shape == LENSRT_APERTURE_SLIT && (!(a->slit_width_mm > 0) || !(a->slit_separation_mm >= 0) ||
                                             (a->slit_separation_mm > 0 && a->slit_separation_mm < a->slit_width_mm)))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "aperture: a slit needs width > 0 and a separation of 0 or at least the width, got %g and %g",
                           a->slit_width_mm, a->slit_separation_mm);
    if (!(a->radius_mm >= 0 && isfinite(a->radius_mm)) || !(a->f_number >= 0 && isfinite(a->f_number)) || !isfinite(a->rotation_deg))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "aperture: radius_mm, f_number and rotation must be finite and not negative");
    return LENSRT_SUCCESS;
}

/* Direction cosines of a light seen from the lens: along (tan x, tan y, 1). */
static void light_direction(const lensrt_light *l, double *x, double *y)
{
    double tx = tan(l->field_x_deg * (PI / 180.0)), ty = tan(l->field_y_deg * (PI / 180.0));
    double n = sqrt(1.0 + tx * tx + ty * ty);
    *x = tx / n;
    *y = ty / n;
}

static lensrt_result check_lights(lensrt_render r, const lensrt_lens_info *info)
{
    int i;
    for (i = 0; i < r->n_lights; i++) {
        const lensrt_light *l = &r->lights[i];
        double x, y;
        if (!isfinite(l->field_x_deg) || !isfinite(l->field_y_deg) || !isfinite(l->distance_mm) ||
            !(l->intensity >= 0 && isfinite(l->intensity)))
            return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "light %d: values must be finite, intensity not negative", i);
        if (fabs(l->field_x_deg) >= 90.0 || fabs(l->field_y_deg) >= 90.0 || l->distance_mm < 0)
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                               "light %d: at (%g, %g) deg, distance %g mm is behind the lens "
                               "(field angles must be within +-90 deg and the distance positive, 0 for infinity)",
                               i, l->field_x_deg, l->field_y_deg, l->distance_mm);
        light_direction(l, &x, &y);
        r->light_x[i] = x;
        r->light_y[i] = y;
        r->light_d[i] = l->distance_mm;
        if (r->lens->analytic) {
            if (r->lens->model.one_dimensional && l->field_y_deg != 0.0)
                return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                                   "light %d: a one-dimensional lens needs field_y_deg 0, got %g", i, l->field_y_deg);
            continue;
        }
        // The fitted field is an ellipse with these semi-axes (direction cosines)
        if ((x / info->field_x) * (x / info->field_x) + (y / info->field_y) * (y / info->field_y) > 1.0 + 1e-9)
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                               "light %d: field (%g, %g) deg is outside the fitted field of %s (%.3g x %.3g deg)",
                               i, l->field_x_deg, l->field_y_deg, info->name,
                               asin(info->field_x) * 180.0 / PI, asin(info->field_y) * 180.0 / PI);
        if (l->distance_mm > 0 && l->distance_mm < info->distance_min_mm * (1 - 1e-9))
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                               "light %d: distance %g mm is closer than the fitted %g mm of %s",
                               i, l->distance_mm, info->distance_min_mm, info->name);
    }
    return LENSRT_SUCCESS;
}

/* Stop radius from the aperture description. */
static lensrt_result choose_stop(lensrt_render r, const lensrt_lens_info *info)
{
    const lensrt_aperture *a = &r->desc.aperture;
    lensrt_lens lens = r->lens;
    if (lens->analytic) {
        // A perfect lens of focal length f: N = f / (2 R); free space needs a radius
        if (a->radius_mm > 0) r->stop_radius = a->radius_mm;
        else if (a->f_number > 0 && lens->model.focal_length_mm > 0)
            r->stop_radius = lens->model.focal_length_mm / (2.0 * a->f_number);
        else if (a->shape == LENSRT_APERTURE_SLIT)
            r->stop_radius = 0.0;
        else
            return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                               "aperture: free space needs radius_mm (or a slit); a perfect lens also takes f_number");
        r->f_number = lens->model.focal_length_mm > 0 && r->stop_radius > 0
                          ? lens->model.focal_length_mm / (2.0 * r->stop_radius) : 0.0;
        return LENSRT_SUCCESS;
    }
    if (a->radius_mm > 0) r->stop_radius = a->radius_mm;
    else if (a->f_number > 0) r->stop_radius = lens->stop_radius_f1_mm / a->f_number;
    else r->stop_radius = info->stop_radius_max_mm;
    if (r->stop_radius > info->stop_radius_max_mm * (1 + 1e-9))
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                           "aperture: f/%.3g (stop radius %g mm) is wider than %s was fitted for: f/%.3g (stop radius %g mm)",
                           lens->stop_radius_f1_mm / r->stop_radius, r->stop_radius, info->name,
                           info->f_number_min, info->stop_radius_max_mm);
    r->f_number = lens->stop_radius_f1_mm / r->stop_radius;
    return LENSRT_SUCCESS;
}

/* ---------------------------------------------------- polynomial preparation ----- */

static double ipow(double x, int e)
{
    double y = 1.0;
    while (e-- > 0) y *= x;
    return y;
}

static int slot_of(int m, int n)
{
    int d = m + n;
    // Slots are ordered by total degree, then by n: (d, n) -> d (d + 1) / 2 + n
    return d * (d + 1) / 2 + n;
}

/* Powers 0..15 of the normalised sensor coordinates of (x, y), for the P_s terms. */
static void sensor_powers(const lensrt_lens lens, double x, double y, double px[16], double py[16])
{
    double xh = lensrt_normalise(&lens->p_s.inputs[0], x), yh = lensrt_normalise(&lens->p_s.inputs[1], y);
    int e;
    px[0] = py[0] = 1.0;
    for (e = 1; e < 16; e++) {
        px[e] = px[e - 1] * xh;
        py[e] = py[e - 1] * yh;
    }
}

/* Specialise output `o` of a system to fixed values of every input except the stop
 * (x_a, y_a at inputs 3, 4) and, when keep_xy, inputs 0, 1 (x_S, y_S).
 *
 * Without keep_xy every term lands in its stop slot. With keep_xy the result is a
 * polynomial in (x_S, y_S, stop): terms that differ only in the fixed inputs' exponents
 * (z_S, lambda) become the same monomial, so they are merged (coefficients summed in
 * table order; terms kept in order of first appearance, so the result is deterministic).
 * A tensor-product fit has ~17,000 terms per output and ~1,000 distinct monomials left,
 * and every pixel's set-up (CPU and GL) walks this list. */
static lensrt_result specialise(lensrt_render r, const lensrt_system *sys, int o, const double *xhat,
                                int keep_xy, lensrt_pixel_poly *out, double *slots)
{
    const lensrt_poly *p = &sys->outputs[o];
    const lensrt_input *xa = &sys->inputs[3];
    double scale = r->mono_radius / xa->s; /* xhat_a = scale * u */
    /* Merge index per packed (slot, ix, iy) key: 0 unseen, else 1 + the term's place */
    const size_t n_keys = (size_t)r->n_slots << 8;
    int *place = NULL, *term_place = NULL;
    int t, n = 0;
    if (keep_xy) {
        place = lensrt_calloc(r->ctx, n_keys, sizeof *place);
        term_place = lensrt_alloc(r->ctx, sizeof(int) * (size_t)p->n_terms + 1);
        if (!place || !term_place) {
            lensrt_free(r->ctx, place);
            lensrt_free(r->ctx, term_place);
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
        }
        // Pass 1: the distinct (x_S, y_S, stop) monomials, in order of first appearance
        for (t = 0; t < p->n_terms; t++) {
            const unsigned char *e = p->exponents + (size_t)t * 6;
            size_t key = (size_t)slot_of(e[3], e[4]) << 8 | (size_t)e[0] << 4 | e[1];
            if (!place[key]) place[key] = ++n;
            term_place[t] = place[key] - 1;
        }
        lensrt_free(r->ctx, place);
        out->n = n;
        out->ix = lensrt_alloc(r->ctx, (size_t)n + 1);
        out->iy = lensrt_alloc(r->ctx, (size_t)n + 1);
        out->slot = lensrt_alloc(r->ctx, sizeof(int) * (size_t)n + 1);
        out->coef = lensrt_calloc(r->ctx, (size_t)n + 1, sizeof(double));
        if (!out->ix || !out->iy || !out->slot || !out->coef) {
            lensrt_free(r->ctx, term_place);
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
        }
    }
    // Pass 2 (the only one without keep_xy): the coefficients with the fixed inputs put in
    for (t = 0; t < p->n_terms; t++) {
        const unsigned char *e = p->exponents + (size_t)t * 6;
        double c = p->coefficients[t] * ipow(scale, e[3] + e[4]);
        int i;
        for (i = keep_xy ? 2 : 0; i < 6; i++)
            if (i != 3 && i != 4) c *= ipow(xhat[i], e[i]);
        if (keep_xy) {
            int k = term_place[t];
            out->ix[k] = e[0];
            out->iy[k] = e[1];
            out->slot[k] = slot_of(e[3], e[4]);
            out->coef[k] += c;
        } else {
            slots[slot_of(e[3], e[4])] += c;
        }
    }
    lensrt_free(r->ctx, term_place);
    return LENSRT_SUCCESS;
}

/* P_o of light l, wavelength w, output o, as coefficients of the stop monomials. */
static double *po_slots(lensrt_render r, int l, int w, int o)
{
    return r->po + ((size_t)(l * r->n_wl + w) * 4 + (size_t)o) * (size_t)r->n_slots;
}

static lensrt_result prepare_fitted(lensrt_render r)
{
    lensrt_lens lens = r->lens;
    const lensrt_input *xa = &lens->p_s.inputs[3];
    int w, o, l, t, k;
    lensrt_result res;
    // The stop inputs must be centred so that monomials of u = x_a / R stay monomials
    if (lens->p_s.inputs[3].c != 0 || lens->p_s.inputs[4].c != 0 || lens->p_o.inputs[3].c != 0 ||
        lens->p_o.inputs[4].c != 0 || xa->s != lens->p_s.inputs[4].s || xa->s != lens->p_o.inputs[3].s)
        return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE,
                           "%s: the stop inputs x_a, y_a must be normalised symmetrically (c = 0, equal s)", lens->file);
    // Highest stop degree in either system
    r->degree = 0;
    for (o = 0; o < 4; o++) {
        const lensrt_poly *ps[2];
        int q;
        ps[0] = &lens->p_o.outputs[o];
        ps[1] = &lens->p_s.outputs[o];
        for (q = 0; q < 2; q++)
            for (t = 0; t < ps[q]->n_terms; t++) {
                const unsigned char *e = ps[q]->exponents + (size_t)t * 6;
                if (e[3] + e[4] > r->degree) r->degree = e[3] + e[4];
            }
    }
    if (r->degree > 15)
        return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE, "%s: stop degree %d is above 15", lens->file, r->degree);
    r->n_slots = (r->degree + 1) * (r->degree + 2) / 2;
    for (k = 0; k <= r->degree; k++) {
        int n;
        for (n = 0; n <= k; n++) {
            r->slot_m[slot_of(k - n, n)] = k - n;
            r->slot_n[slot_of(k - n, n)] = n;
        }
    }
    r->ps = lensrt_calloc(r->ctx, (size_t)r->n_wl * 4, sizeof *r->ps);
    r->po = lensrt_calloc(r->ctx, (size_t)r->n_lights * (size_t)r->n_wl * 4 * (size_t)r->n_slots, sizeof(double));
    if (!r->ps || !r->po) return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
    for (w = 0; w < r->n_wl; w++) {
        double xhat[6] = {0, 0, 0, 0, 0, 0};
        // P_s with z_S and lambda fixed: a polynomial in x_S, y_S and the stop
        xhat[2] = lensrt_normalise(&lens->p_s.inputs[2], r->desc.sensor.focus_offset_mm);
        xhat[5] = lensrt_normalise(&lens->p_s.inputs[5], r->wavelengths[w]);
        for (o = 0; o < 4; o++) {
            res = specialise(r, &lens->p_s, o, xhat, 1, &r->ps[w * 4 + o], NULL);
            if (res != LENSRT_SUCCESS) return res;
        }
        // P_o with the light and lambda fixed: a polynomial in the stop only
        for (l = 0; l < r->n_lights; l++) {
            double u = r->light_d[l] > 0 ? 1.0 / r->light_d[l] : 0.0;
            xhat[0] = lensrt_normalise(&lens->p_o.inputs[0], r->light_x[l]);
            xhat[1] = lensrt_normalise(&lens->p_o.inputs[1], r->light_y[l]);
            xhat[2] = lensrt_normalise(&lens->p_o.inputs[2], u);
            xhat[5] = lensrt_normalise(&lens->p_o.inputs[5], r->wavelengths[w]);
            for (o = 0; o < 4; o++)
                specialise(r, &lens->p_o, o, xhat, 0, NULL, po_slots(r, l, w, o));
        }
    }
    return LENSRT_SUCCESS;
}

/* ------------------------------------------------------------ phase basis ----- */

/* Eigenvectors of the symmetric n x n matrix a (destroyed) by cyclic Jacobi rotations,
 * as columns of v, sorted by decreasing eigenvalue. */
static void jacobi_eigen(int n, double *a, double *v, double *eig)
{
    int sweep, p, q, k;
    for (p = 0; p < n; p++)
        for (q = 0; q < n; q++) v[p * n + q] = p == q;
    for (sweep = 0; sweep < 60; sweep++) {
        double off = 0.0, diag = 0.0;
        for (p = 0; p < n; p++) {
            diag += a[p * n + p] * a[p * n + p];
            for (q = p + 1; q < n; q++) off += a[p * n + q] * a[p * n + q];
        }
        if (off <= 1e-30 * diag || off == 0.0) break;
        for (p = 0; p < n; p++)
            for (q = p + 1; q < n; q++) {
                double apq = a[p * n + q], theta, t, c, s;
                if (fabs(apq) < 1e-300) continue;
                // Rotate rows and columns p, q so that a[p][q] becomes 0
                theta = (a[q * n + q] - a[p * n + p]) / (2.0 * apq);
                t = (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
                c = 1.0 / sqrt(t * t + 1.0);
                s = t * c;
                for (k = 0; k < n; k++) {
                    double akp = a[k * n + p], akq = a[k * n + q];
                    a[k * n + p] = c * akp - s * akq;
                    a[k * n + q] = s * akp + c * akq;
                }
                for (k = 0; k < n; k++) {
                    double apk = a[p * n + k], aqk = a[q * n + k];
                    a[p * n + k] = c * apk - s * aqk;
                    a[q * n + k] = s * apk + c * aqk;
                }
                for (k = 0; k < n; k++) {
                    double vkp = v[k * n + p], vkq = v[k * n + q];
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
    }
    for (p = 0; p < n; p++) eig[p] = a[p * n + p];
    // Selection sort of the columns by decreasing eigenvalue
    for (p = 0; p < n; p++) {
        int best = p;
        for (q = p + 1; q < n; q++)
            if (eig[q] > eig[best]) best = q;
        if (best == p) continue;
        { double t = eig[p]; eig[p] = eig[best]; eig[best] = t; }
        for (k = 0; k < n; k++) {
            double t = v[k * n + p];
            v[k * n + p] = v[k * n + best];
            v[k * n + best] = t;
        }
    }
}

static void slot_coefficients(const lensrt_pixel_poly *p, const double *px, const double *py, double *c, int n_slots);

/* Coordinates u[0 .. R) of the non-constant coefficients c[1 .. n] in the leading R
 * vectors of the orthonormal basis V, and the fewest of them whose dropped tail (the
 * residual) has an l1 norm <= limit; R + 1 when even R vectors are not enough. */
static int basis_keep(const double *V, int n, int R, const double *c, double limit, double *u)
{
    double res[135], l1 = 0.0;
    int j, k;
    for (j = 0; j < R; j++) {
        u[j] = 0.0;
        for (k = 0; k < n; k++) u[j] += V[k * n + j] * c[k + 1];
    }
    // Residual after all R vectors, then add them back from the last one
    for (k = 0; k < n; k++) {
        res[k] = c[k + 1];
        for (j = 0; j < R; j++) res[k] -= V[k * n + j] * u[j];
        l1 += fabs(res[k]);
    }
    if (l1 > limit) return R + 1;
    for (j = R - 1; j >= 0; j--) {
        l1 = 0.0;
        for (k = 0; k < n; k++) {
            res[k] += V[k * n + j] * u[j];
            l1 += fabs(res[k]);
        }
        if (l1 > limit) return j + 1;
    }
    return 0;
}

/* The largest l1 norm of the non-constant coefficients an output may drop: inner pupil
 * position 0.01% of the housing, transmittance 1e-3 relative (5e-4 in amplitude), phase
 * the render's tolerance (waves). */
double lensrt_output_limit(const lensrt_render r, int o, double c0)
{
    return o < 2 ? 1e-4 * r->lens->housing_last_mm : o == 2 ? 1e-3 * fabs(c0) : r->desc.phase_tolerance_waves;
}

/* Step (mm) of the central differences of the Huygens amplitude: 1e-3 of the pixel
 * pitch, at least 1e-6 mm. */
double lensrt_huygens_step(const lensrt_render r)
{
    return 1e-3 * fmax(r->pitch_x, 1e-3);
}

/* The window's bases per wavelength and output: eigenvectors of sum_p c_p c_p^T over a
 * grid of up to 33 x 33 pixels of the window (c_p: the pixel's non-constant coefficients
 * of the output, the phase in waves). Each pixel later keeps the fewest leading basis
 * vectors whose dropped tail stays under the output's limit, so the basis only ever
 * speeds things up. The CPU path uses the phase and transmittance bases (b = 0, 1), the
 * GL path all four outputs in order (x_i, y_i, tau_i, phi_i). */
static lensrt_result prepare_basis(lensrt_render r)
{
    const int ns = r->n_slots, n = ns - 1;
    const int gl = r->desc.device == LENSRT_DEVICE_GL;
    int w, k, q, grid_x = r->width < 33 ? r->width : 33, grid_y = r->height < 33 ? r->height : 33;
    double *g, *eig, *cs;
    r->n_rows = ns;
    r->use_basis = (r->desc.precision == LENSRT_PRECISION_DEFAULT || gl) && n > 0;
    if (!r->use_basis) return LENSRT_SUCCESS;
    r->n_bases = gl ? 4 : 2;
    for (k = 0; k < r->n_bases; k++) r->basis_output[k] = gl ? k : (k ? 2 : 3);
    r->basis = lensrt_calloc(r->ctx, (size_t)r->n_wl * (size_t)r->n_bases * (size_t)n * (size_t)n, sizeof(double));
    r->basis_rank = lensrt_calloc(r->ctx, (size_t)r->n_wl * (size_t)r->n_bases, sizeof(int));
    g = lensrt_calloc(r->ctx, (size_t)n * (size_t)n, sizeof(double));
    eig = lensrt_calloc(r->ctx, (size_t)n, sizeof(double));
    cs = lensrt_calloc(r->ctx, (size_t)(grid_x * grid_y) * (size_t)ns, sizeof(double));
    if (!r->basis || !r->basis_rank || !g || !eig || !cs) {
        lensrt_free(r->ctx, g);
        lensrt_free(r->ctx, eig);
        lensrt_free(r->ctx, cs);
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
    }
    for (w = 0; w < r->n_bases * r->n_wl; w++) {
        /* basis b = w % n_bases of wavelength w / n_bases, for output o */
        int o = r->basis_output[w % r->n_bases], cell;
        double inv_lambda = o == 3 ? NM_PER_MM / r->wavelengths[w / r->n_bases] : 1.0;
        const double *V = r->basis + (size_t)w * (size_t)n * (size_t)n;
        // The grid's coefficients, then their Gram matrix (phase in waves)
        for (cell = 0; cell < grid_x * grid_y; cell++) {
            int gi = cell % grid_x, gj = cell / grid_x;
            int ix = grid_x > 1 ? (int)((double)gi * (r->width - 1) / (grid_x - 1) + 0.5) : 0;
            int iy = grid_y > 1 ? (int)((double)gj * (r->height - 1) / (grid_y - 1) + 0.5) : 0;
            double px[16], py[16], *c = cs + (size_t)cell * (size_t)ns;
            sensor_powers(r->lens, r->xs[ix], r->ys[iy], px, py);
            slot_coefficients(&r->ps[(w / r->n_bases) * 4 + o], px, py, c, ns);
        }
        memset(g, 0, sizeof(double) * (size_t)n * (size_t)n);
        for (cell = 0; cell < grid_x * grid_y; cell++) {
            const double *c = cs + (size_t)cell * (size_t)ns;
            for (k = 0; k < n; k++)
                for (q = 0; q < n; q++) g[k * n + q] += c[k + 1] * c[q + 1] * inv_lambda * inv_lambda;
        }
        jacobi_eigen(n, g, r->basis + (size_t)w * (size_t)n * (size_t)n, eig);
        // How many basis vectors the grid's pixels need (others fall back to monomials);
        // the GL path finds every pixel's need on the device instead
        r->basis_rank[w] = 0;
        if (gl) continue;
        for (cell = 0; cell < grid_x * grid_y; cell++) {
            double c[136], u[135];
            int keep;
            c[0] = cs[(size_t)cell * (size_t)ns];
            for (k = 1; k < ns; k++) c[k] = cs[(size_t)cell * (size_t)ns + (size_t)k] * inv_lambda;
            keep = basis_keep(V, n, n, c, lensrt_output_limit(r, o, c[0]), u);
            if (keep > r->basis_rank[w]) r->basis_rank[w] = keep;
        }
        // A margin for pixels between grid points
        r->basis_rank[w] = r->basis_rank[w] + 2 < n ? r->basis_rank[w] + 2 : n;
    }
    lensrt_free(r->ctx, cs);
    lensrt_free(r->ctx, g);
    lensrt_free(r->ctx, eig);
    r->n_rows = ns + 2 * n;
    return LENSRT_SUCCESS;
}

/* ------------------------------------------------------------ image point ----- */

/* d output / d x_a (which = 3) or d y_a (which = 4) at the stop centre, per mm, with
 * every other input at xhat. */
static double stop_slope(const lensrt_system *sys, int o, int which, const double *xhat)
{
    const lensrt_poly *p = &sys->outputs[o];
    double sum = 0.0;
    int t, i;
    for (t = 0; t < p->n_terms; t++) {
        const unsigned char *e = p->exponents + (size_t)t * 6;
        double c;
        if (e[which] != 1 || e[7 - which] != 0) continue;
        c = p->coefficients[t];
        for (i = 0; i < 6; i++)
            if (i != 3 && i != 4) c *= ipow(xhat[i], e[i]);
        sum += c;
    }
    return sum / sys->inputs[which].s;
}

/* Stop-centre phase gradient of P_s at sensor point (x, y) plus the light's (g0). */
static void total_gradient(const lensrt_lens lens, double x, double y, const double *xs, const double g0[2], double g[2])
{
    double xhat[6];
    memcpy(xhat, xs, sizeof xhat);
    xhat[0] = lensrt_normalise(&lens->p_s.inputs[0], x);
    xhat[1] = lensrt_normalise(&lens->p_s.inputs[1], y);
    g[0] = g0[0] + stop_slope(&lens->p_s, 3, 3, xhat);
    g[1] = g0[1] + stop_slope(&lens->p_s, 3, 4, xhat);
}

lensrt_result lensrt_lens_image_point(lensrt_context ctx, lensrt_lens lens, const lensrt_light *light,
                                      double wavelength_nm, double focus_offset_mm, double xy_mm[2])
{
    double lx, ly, xo[6], xs[6], g0[2], x = 0.0, y = 0.0;
    lensrt_light full;
    lensrt_result res;
    int it;
    if (!ctx || !lens || !light || !xy_mm) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "image_point: NULL argument");
    if ((res = lensrt_struct_in(ctx, "image_point: lensrt_light", light, &full, sizeof full)) != LENSRT_SUCCESS)
        return res;
    light = &full;
    if (!(wavelength_nm > 0) || !isfinite(focus_offset_mm) || fabs(light->field_x_deg) >= 90 || fabs(light->field_y_deg) >= 90)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "image_point: wavelength %g nm, focus %g mm, field (%g, %g) deg",
                           wavelength_nm, focus_offset_mm, light->field_x_deg, light->field_y_deg);
    light_direction(light, &lx, &ly);
    if (lens->analytic) {
        // The undeviated ray through the stop centre, to the sensor plane
        double lz = sqrt(1.0 - lx * lx - ly * ly), z = lens->model.sensor_distance_mm + focus_offset_mm;
        xy_mm[0] = -z * lx / lz;
        xy_mm[1] = -z * ly / lz;
        return LENSRT_SUCCESS;
    }
    // The light's phase slope at the stop centre, from P_o
    xo[0] = lensrt_normalise(&lens->p_o.inputs[0], lx);
    xo[1] = lensrt_normalise(&lens->p_o.inputs[1], ly);
    xo[2] = lensrt_normalise(&lens->p_o.inputs[2], light->distance_mm > 0 ? 1.0 / light->distance_mm : 0.0);
    xo[3] = xo[4] = 0.0;
    xo[5] = lensrt_normalise(&lens->p_o.inputs[5], wavelength_nm);
    g0[0] = stop_slope(&lens->p_o, 3, 3, xo);
    g0[1] = stop_slope(&lens->p_o, 3, 4, xo);
    xs[2] = lensrt_normalise(&lens->p_s.inputs[2], focus_offset_mm);
    xs[3] = xs[4] = 0.0;
    xs[5] = lensrt_normalise(&lens->p_s.inputs[5], wavelength_nm);
    // Newton's method on the total slope, with a finite-difference Jacobian
    for (it = 0; it < 50; it++) {
        double g[2], gx[2], gy[2], h = 1e-4, a, b, c, d, det, dx, dy;
        total_gradient(lens, x, y, xs, g0, g);
        total_gradient(lens, x + h, y, xs, g0, gx);
        total_gradient(lens, x, y + h, xs, g0, gy);
        a = (gx[0] - g[0]) / h; b = (gy[0] - g[0]) / h;
        c = (gx[1] - g[1]) / h; d = (gy[1] - g[1]) / h;
        det = a * d - b * c;
        if (det == 0.0 || !isfinite(det)) break;
        dx = (d * g[0] - b * g[1]) / det;
        dy = (-c * g[0] + a * g[1]) / det;
        x -= dx;
        y -= dy;
        if (fabs(dx) + fabs(dy) < 1e-12) {
            xy_mm[0] = x;
            xy_mm[1] = y;
            return LENSRT_SUCCESS;
        }
    }
    return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "image_point: no chief ray found for the light at (%g, %g) deg through %s",
                       light->field_x_deg, light->field_y_deg, lens->name);
}

/* --------------------------------------------------------------- create ----- */

static void free_render(lensrt_render r)
{
    lensrt_context ctx = r->ctx;
    int i;
#ifdef LENSRT_GL
    lensrt_gl_render_destroy(r);
#endif
    if (r->ps)
        for (i = 0; i < r->n_wl * 4; i++) {
            lensrt_free(ctx, r->ps[i].ix);
            lensrt_free(ctx, r->ps[i].iy);
            lensrt_free(ctx, r->ps[i].slot);
            lensrt_free(ctx, r->ps[i].coef);
        }
    lensrt_free(ctx, r->ps);
    lensrt_free(ctx, r->po);
    lensrt_free(ctx, r->basis);
    lensrt_free(ctx, r->basis_rank);
    lensrt_free(ctx, r->lights);
    lensrt_free(ctx, r->wavelengths);
    lensrt_free(ctx, r->xs);
    lensrt_free(ctx, r->ys);
    lensrt_free(ctx, r->light_x);
    lensrt_free(ctx, r->light_y);
    lensrt_free(ctx, r->light_d);
    lensrt_free(ctx, r->sum);
    lensrt_free(ctx, r->sumsq);
    lensrt_free(ctx, r);
}

void lensrt_render_destroy(lensrt_render render)
{
    if (render) free_render(render);
}

lensrt_result lensrt_render_create(lensrt_context ctx, const lensrt_render_desc *desc, lensrt_render *out)
{
    lensrt_render r;
    lensrt_render_desc full;
    lensrt_lens_info info = LENSRT_LENS_INFO_INIT;
    lensrt_result res;
    size_t npix, nsum;
    int i;
    if (!ctx || !desc || !out) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_render_create: NULL argument");
    *out = NULL;
    // Read the caller's struct as far as its struct_size (the ABI rules of lensrt.h)
    if ((res = lensrt_struct_in(ctx, "lensrt_render_desc", desc, &full, sizeof full)) != LENSRT_SUCCESS) return res;
    desc = &full;
    if (!desc->lens) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "render: no lens");
    lensrt_lens_get_info(desc->lens, &info);
    if ((res = check_desc(ctx, desc, &info)) != LENSRT_SUCCESS) return res;
    if (desc->lens->analytic && desc->lens->model.one_dimensional && desc->sensor.height != 1)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "sensor: a one-dimensional lens renders one row, got height %d", desc->sensor.height);
    r = lensrt_calloc(ctx, 1, sizeof *r);
    if (!r) return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
    r->ctx = ctx;
    r->lens = desc->lens;
    r->desc = *desc;
    if (r->desc.sampler == LENSRT_SAMPLER_DEFAULT)
        r->desc.sampler = r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED ? LENSRT_SAMPLER_RANDOM : LENSRT_SAMPLER_SOBOL;
    if (r->desc.phase_tolerance_waves == 0) r->desc.phase_tolerance_waves = 3e-3;
    // Copy the lights (default: one on the axis at infinity) and wavelengths
    r->n_lights = desc->n_lights > 0 ? desc->n_lights : 1;
    r->n_wl = desc->n_wavelengths > 0 ? desc->n_wavelengths : DEFAULT_WAVELENGTHS;
    r->width = desc->sensor.width;
    r->height = desc->sensor.height;
    r->lights = lensrt_calloc(ctx, (size_t)r->n_lights, sizeof *r->lights);
    r->wavelengths = lensrt_calloc(ctx, (size_t)r->n_wl, sizeof(double));
    r->light_x = lensrt_calloc(ctx, (size_t)r->n_lights, sizeof(double));
    r->light_y = lensrt_calloc(ctx, (size_t)r->n_lights, sizeof(double));
    r->light_d = lensrt_calloc(ctx, (size_t)r->n_lights, sizeof(double));
    r->xs = lensrt_calloc(ctx, (size_t)r->width, sizeof(double));
    r->ys = lensrt_calloc(ctx, (size_t)r->height, sizeof(double));
    if (!r->lights || !r->wavelengths || !r->light_x || !r->light_y || !r->light_d || !r->xs || !r->ys) {
        res = lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
        goto fail;
    }
    if (desc->n_lights > 0 &&
        (res = lensrt_array_in(ctx, "lights", desc->lights, (size_t)desc->n_lights, r->lights, sizeof *r->lights)) !=
            LENSRT_SUCCESS)
        goto fail;
    for (i = 0; i < r->n_lights; i++)
        if (r->lights[i].intensity == 0) r->lights[i].intensity = 1.0;
    for (i = 0; i < r->n_wl; i++) {
        if (desc->wavelengths_nm) {
            r->wavelengths[i] = desc->wavelengths_nm[i];
        } else {
            // Uniform bins over the lens's range (380-780 nm for analytic lenses)
            double lo = info.analytic ? 380.0 : info.wavelength_min_nm;
            double hi = info.analytic ? 780.0 : info.wavelength_max_nm;
            r->wavelengths[i] = lo + (hi - lo) * (i + 0.5) / r->n_wl;
        }
    }
    r->desc.lights = r->lights;
    r->desc.n_lights = r->n_lights;
    r->desc.wavelengths_nm = r->wavelengths;
    r->desc.n_wavelengths = r->n_wl;
    // Pixel centres; row 0 is the top of the image (+y)
    r->pitch_x = desc->sensor.width_mm / r->width;
    r->pitch_y = desc->sensor.height_mm > 0 ? desc->sensor.height_mm / r->height : r->pitch_x;
    for (i = 0; i < r->width; i++) r->xs[i] = desc->sensor.center_x_mm + (i + 0.5 - 0.5 * r->width) * r->pitch_x;
    for (i = 0; i < r->height; i++) r->ys[i] = desc->sensor.center_y_mm + (0.5 * r->height - i - 0.5) * r->pitch_y;
    if (desc->lens->analytic && desc->lens->model.one_dimensional) r->ys[0] = desc->sensor.center_y_mm;
    if ((res = check_lights(r, &info)) != LENSRT_SUCCESS || (res = choose_stop(r, &info)) != LENSRT_SUCCESS)
        goto fail;
    if (!info.analytic) {
        // The window must lie inside the fitted sensor square
        const lensrt_input *xs = &desc->lens->p_s.inputs[0], *ys = &desc->lens->p_s.inputs[1];
        double x0 = r->xs[0], x1 = r->xs[r->width - 1], y0 = r->ys[r->height - 1], y1 = r->ys[0];
        if (x0 < xs->lo - 1e-9 || x1 > xs->hi + 1e-9 || y0 < ys->lo - 1e-9 || y1 > ys->hi + 1e-9) {
            res = lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                              "sensor: pixel centres span x [%g, %g] mm, y [%g, %g] mm, beyond the fitted "
                              "[%g, %g] x [%g, %g] mm of %s", x0, x1, y0, y1, xs->lo, xs->hi, ys->lo, ys->hi, info.name);
            goto fail;
        }
    }
    // Where samples are drawn: the bounding disc, the slits' box, or an interval
    if (desc->aperture.shape == LENSRT_APERTURE_SLIT) {
        double half = 0.5 * (desc->aperture.slit_separation_mm + desc->aperture.slit_width_mm);
        int one_d = info.analytic && desc->lens->model.one_dimensional;
        if (!one_d && !(r->stop_radius > 0)) {
            res = lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "aperture: a two-dimensional slit needs radius_mm (half its length)");
            goto fail;
        }
        r->region.kind = one_d ? LENSRT_REGION_INTERVAL : LENSRT_REGION_BOX;
        r->region.rx = half;
        r->region.ry = one_d ? 0.0 : r->stop_radius;
        if (!one_d && !info.analytic && (half > r->stop_radius)) {
            res = lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "aperture: the slits reach %g mm, beyond the stop radius %g mm", half, r->stop_radius);
            goto fail;
        }
    } else {
        int one_d = info.analytic && desc->lens->model.one_dimensional;
        r->region.kind = one_d ? LENSRT_REGION_INTERVAL : LENSRT_REGION_DISC;
        r->region.rx = r->stop_radius;
    }
    r->measure = lensrt_region_measure(&r->region);
    r->mono_radius = fmax(r->region.rx, r->region.ry);
    if (!info.analytic && ((res = prepare_fitted(r)) != LENSRT_SUCCESS || (res = prepare_basis(r)) != LENSRT_SUCCESS))
        goto fail;
    // Phasor sums, and sums of squares for the unbiased estimator
    npix = (size_t)r->width * (size_t)r->height;
    nsum = (size_t)r->n_lights * (size_t)r->n_wl * npix;
    r->sum = lensrt_calloc(ctx, nsum * 2, sizeof(double));
    if (r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED) r->sumsq = lensrt_calloc(ctx, nsum, sizeof(double));
    if (!r->sum || (r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED && !r->sumsq)) {
        res = lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY,
                          "render: out of memory for %zu phasor sums (%d x %d pixels, %d wavelengths, %d lights)",
                          nsum, r->width, r->height, r->n_wl, r->n_lights);
        goto fail;
    }
    if (r->desc.device == LENSRT_DEVICE_GL) {
#ifdef LENSRT_GL
        if ((res = lensrt_gl_render_create(r)) != LENSRT_SUCCESS) goto fail;
#else
        res = lensrt_fail(ctx, LENSRT_ERROR_UNSUPPORTED, "device gl: this build of lensrt has no GL path");
        goto fail;
#endif
    }
    lensrt_log(ctx, LENSRT_LOG_INFO, "render: %s, %d x %d pixels, %d wavelengths, %d lights, stop %.4g mm (f/%.3g), %s sampling",
               info.name, r->width, r->height, r->n_wl, r->n_lights, r->stop_radius, r->f_number,
               sampler_name(r->desc.sampler));
    *out = r;
    return LENSRT_SUCCESS;
fail:
    free_render(r);
    return res;
}

/* ------------------------------------------------------------- the passes ----- */

/* Samples of one pass for one wavelength, laid out for the kernel. */
typedef struct pass_data {
    int n, n_blocks;          /* samples, blocks of LENSRT_BLOCK */
    double *xy;               /* positions (mm) */
    float *mono_f;            /* [block][slot][j] */
    double *mono_d;
    float *phase_f, *amp_f;   /* [block][light][j] */
    double *phase_d, *amp_d;
} pass_data;


/* Evaluate P_o (or the analytic incoming wave) per sample and light, and the stop
 * monomials, for samples xy[0 .. n). */
static void prepare_samples(lensrt_render r, int w, pass_data *pd)
{
    const double lambda_mm = r->wavelengths[w] / NM_PER_MM;
    const int nb = pd->n_blocks, ns = r->n_slots, nl = r->n_lights, nr = r->n_rows;
    const int naive = r->desc.precision == LENSRT_PRECISION_NAIVE_FLOAT;
    const int dbl = r->desc.precision == LENSRT_PRECISION_DOUBLE;
    const lensrt_lens lens = r->lens;
    long j;
#ifdef LENSRT_OPENMP
#pragma omp parallel for schedule(static) num_threads(r->ctx->threads > 0 ? r->ctx->threads : omp_get_max_threads())
#endif
    for (j = 0; j < (long)nb * LENSRT_BLOCK; j++) {
        int b = (int)(j / LENSRT_BLOCK), jj = (int)(j % LENSRT_BLOCK), l, k;
        double x = 0, y = 0, inside = 0.0, mono[136];
        if (j < pd->n) {
            x = pd->xy[2 * j];
            y = pd->xy[2 * j + 1];
            inside = lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, x, y) ? 1.0 : 0.0;
        }
        // Stop monomials u^m v^n with u = x / R, v = y / R
        if (!lens->analytic) {
            double u = x / r->mono_radius, v = y / r->mono_radius, pu[16], pv[16];
            pu[0] = pv[0] = 1.0;
            for (k = 1; k <= r->degree; k++) {
                pu[k] = pu[k - 1] * u;
                pv[k] = pv[k - 1] * v;
            }
            for (k = 0; k < ns; k++) {
                mono[k] = pu[r->slot_m[k]] * pv[r->slot_n[k]];
                if (dbl) pd->mono_d[((size_t)b * nr + k) * LENSRT_BLOCK + jj] = mono[k];
                else pd->mono_f[((size_t)b * nr + k) * LENSRT_BLOCK + jj] = (float)mono[k];
            }
            // The phase basis of this wavelength at the sample
            if (r->use_basis) {
                int q, bb;
                for (bb = 0; bb < 2; bb++) {
                    const double *V = r->basis + (size_t)(2 * w + bb) * (size_t)(ns - 1) * (size_t)(ns - 1);
                    for (q = 0; q < r->basis_rank[2 * w + bb]; q++) {
                        double gq = 0.0;
                        for (k = 1; k < ns; k++) gq += V[(k - 1) * (ns - 1) + q] * mono[k];
                        pd->mono_f[((size_t)b * nr + ns + bb * (ns - 1) + q) * LENSRT_BLOCK + jj] = (float)gq;
                    }
                }
            }
        } else {
            pd->mono_d[((size_t)b * 2 + 0) * LENSRT_BLOCK + jj] = x;
            pd->mono_d[((size_t)b * 2 + 1) * LENSRT_BLOCK + jj] = y;
        }
        for (l = 0; l < nl; l++) {
            double amp = inside * sqrt(r->lights[l].intensity), opl = 0.0, waves;
            size_t at = ((size_t)b * nl + (size_t)l) * LENSRT_BLOCK + (size_t)jj;
            if (!lens->analytic) {
                // P_o: outer-pupil clip, transmittance, OPL from the light minus its distance
                double xo = 0, yo = 0, tau = 0;
                const double *cx = po_slots(r, l, w, 0), *cy = po_slots(r, l, w, 1);
                const double *ct = po_slots(r, l, w, 2), *cp = po_slots(r, l, w, 3);
                for (k = 0; k < ns; k++) {
                    xo += cx[k] * mono[k];
                    yo += cy[k] * mono[k];
                    tau += ct[k] * mono[k];
                    opl += cp[k] * mono[k];
                }
                if (xo * xo + yo * yo > lens->housing_first_mm * lens->housing_first_mm) amp = 0.0;
                amp *= sqrt(tau > 0 ? tau : 0.0);
                if (naive) opl += r->light_d[l];
            } else {
                // Incoming wave at the stop: a plane or spherical wave from the light; a
                // perfect lens turns it into a sphere converging on the light's image
                double lx = r->light_x[l], ly = r->light_y[l], lz = sqrt(1.0 - lx * lx - ly * ly);
                double f = lens->model.focal_length_mm, D = r->light_d[l];
                if (f > 0) {
                    double u = D > 0 ? D * lz : INFINITY;
                    double v = D > 0 ? 1.0 / (1.0 / f - 1.0 / u) : f;
                    double ix = D > 0 ? -(v / u) * D * lx : -v * lx / lz;
                    double iy = D > 0 ? -(v / u) * D * ly : -v * ly / lz;
                    opl = -sqrt((ix - x) * (ix - x) + (iy - y) * (iy - y) + v * v);
                    if (naive) opl += D > 0 ? D + v : v;
                } else if (D > 0) {
                    double px = D * lx, py = D * ly, pz = D * lz;
                    opl = sqrt((px - x) * (px - x) + (py - y) * (py - y) + pz * pz);
                    if (!naive) opl -= D;
                } else {
                    opl = -(lx * x + ly * y);
                }
            }
            waves = opl / lambda_mm;
            if (!naive) waves -= rint(waves); /* reduce in double: only the fraction matters */
            if (dbl || lens->analytic) {
                pd->phase_d[at] = waves;
                pd->amp_d[at] = amp;
            } else {
                pd->phase_f[at] = (float)waves;
                pd->amp_f[at] = (float)amp;
            }
        }
    }
}

/* Per-pixel terms of the fitted P_s, pruned. Returns 0 when the pixel sees nothing. */
typedef struct pixel_terms {
    int slot[4][136];
    float coef_f[4][136];
    double coef_d[4][136];
    double amp;                 /* Huygens amplitude factor times constant transmittance */
} pixel_terms;

static void slot_coefficients(const lensrt_pixel_poly *p, const double *px, const double *py, double *c, int n_slots)
{
    int t;
    memset(c, 0, sizeof(double) * (size_t)n_slots);
    for (t = 0; t < p->n; t++) c[p->slot[t]] += p->coef[t] * px[p->ix[t]] * py[p->iy[t]];
}

/* The slot (1,0) and (0,1) coefficients of phi at a sensor point: d phi / d u, d phi / d v. */
static void phase_gradient(const lensrt_lens lens, const lensrt_pixel_poly *p, double x, double y, double g[2])
{
    double px[16], py[16];
    int t;
    sensor_powers(lens, x, y, px, py);
    g[0] = g[1] = 0.0;
    for (t = 0; t < p->n; t++) {
        if (p->slot[t] == 1) g[0] += p->coef[t] * px[p->ix[t]] * py[p->iy[t]];
        if (p->slot[t] == 2) g[1] += p->coef[t] * px[p->ix[t]] * py[p->iy[t]];
    }
}

/* Build the kernel's view of pixel (x, y) for wavelength w; returns 0 when every path
 * through the pixel is clipped. */
static int setup_pixel(lensrt_render r, int w, double x, double y, pixel_terms *pt, lensrt_pixel_f *pf, lensrt_pixel_d *pdb)
{
    const lensrt_lens lens = r->lens;
    const double lambda_mm = r->wavelengths[w] / NM_PER_MM;
    const int dbl = r->desc.precision == LENSRT_PRECISION_DOUBLE;
    const int naive = r->desc.precision == LENSRT_PRECISION_NAIVE_FLOAT;
    const int ns = r->n_slots;
    double px[16], py[16], c[4][136], bound[4], h = lens->housing_last_mm, grad[4][2], det, step;
    int o, k, counts[4];
    sensor_powers(lens, x, y, px, py);
    // Coefficients of the stop monomials at this pixel, and bounds of the varying parts
    for (o = 0; o < 4; o++) {
        slot_coefficients(&r->ps[w * 4 + o], px, py, c[o], ns);
        bound[o] = 0.0;
        for (k = 1; k < ns; k++) bound[o] += fabs(c[o][k]);
    }
    // Inner pupil: skip the clip when every path passes, the pixel when none does
    {
        double hi = hypot(fabs(c[0][0]) + bound[0], fabs(c[1][0]) + bound[1]);
        double lo_x = fabs(c[0][0]) - bound[0], lo_y = fabs(c[1][0]) - bound[1];
        if (lo_x > h || lo_y > h || (lo_x > 0 && lo_y > 0 && hypot(lo_x, lo_y) > h)) return 0;
        pf->clip = pdb->clip = hi > h;
    }
    // Phase in waves; the constant part is kept only by the naive mode
    for (k = 0; k < ns; k++) c[3][k] *= 1.0 / lambda_mm;
    // Prune: drop the smallest terms while the sum of their bounds stays under the
    // output's tolerance (every stop monomial is bounded by 1 on the sampled region)
    {
        for (o = 0; o < 4; o++) {
            const double limit = lensrt_output_limit(r, o, c[2][0]);
            int order[136], n = 0, i, j;
            unsigned char kept[136];
            double dropped = 0.0;
            counts[o] = 0;
            if ((o == 0 || o == 1) && !pf->clip) continue;
            if (o == 2 && bound[2] <= limit && !dbl) continue; /* constant: folded into amp */
            // Terms by increasing size (insertion sort: at most 135 of them)
            for (k = 1; k < ns; k++) {
                double a = fabs(c[o][k]);
                if (a == 0.0) continue;
                for (j = n; j > 0 && fabs(c[o][order[j - 1]]) > a; j--) order[j] = order[j - 1];
                order[j] = k;
                n++;
            }
            i = 0;
            if (!dbl)
                while (i < n && dropped + fabs(c[o][order[i]]) <= limit) dropped += fabs(c[o][order[i++]]);
            // Keep the rest in slot order (the kernel streams monomial rows)
            memset(kept, 0, sizeof kept);
            for (j = i; j < n; j++) kept[order[j]] = 1;
            for (j = 0, k = 0; k < ns; k++) {
                if (!kept[k]) continue;
                pt->slot[o][j] = k;
                pt->coef_f[o][j] = (float)c[o][k];
                pt->coef_d[o][j] = c[o][k];
                j++;
            }
            counts[o] = j;
            if (o == 2 && counts[2] > 0) {
                // A varying transmittance keeps its constant term in the polynomial
                pt->slot[2][counts[2]] = 0;
                pt->coef_f[2][counts[2]] = (float)c[2][0];
                pt->coef_d[2][counts[2]] = c[2][0];
                counts[2]++;
            }
        }
    }
    // Phase and transmittance in the window's bases: keep the leading vectors whose
    // dropped tail stays under the tolerance (its l1 norm bounds the error, every
    // monomial being at most 1 on the sampled region)
    if (r->use_basis) {
        const int n = ns - 1;
        int bb;
        for (bb = 0; bb < 2; bb++) {
            const int oo = bb ? 2 : 3;
            const double *V = r->basis + (size_t)(2 * w + bb) * (size_t)n * (size_t)n;
            const double limit = lensrt_output_limit(r, oo, c[2][0]);
            double u[135];
            int j, keep, have = counts[oo] - (oo == 2 && counts[2] > 0);
            if (oo == 2 && counts[2] == 0) continue; /* constant transmittance */
            keep = basis_keep(V, n, r->basis_rank[2 * w + bb], c[oo], limit, u);
            if (keep > r->basis_rank[2 * w + bb]) continue; /* beyond the rows computed */
            if (keep >= have) continue;
            for (j = 0; j < keep; j++) {
                pt->slot[oo][j] = ns + bb * n + j;
                pt->coef_f[oo][j] = (float)u[j];
                pt->coef_d[oo][j] = u[j];
            }
            counts[oo] = keep;
            if (oo == 2) {
                // The transmittance keeps its constant term (row 0 is the monomial 1)
                pt->slot[2][keep] = 0;
                pt->coef_f[2][keep] = (float)c[2][0];
                pt->coef_d[2][keep] = c[2][0];
                counts[2] = keep + 1;
            }
        }
    }
    // Huygens amplitude: sqrt|det d2 phi / (d a d s)| / lambda at the stop centre
    // (Rayleigh-Sommerfeld's cos(theta) / (lambda r) in free space), by central differences
    step = lensrt_huygens_step(r);
    phase_gradient(lens, &r->ps[w * 4 + 3], x + step, y, grad[0]);
    phase_gradient(lens, &r->ps[w * 4 + 3], x - step, y, grad[1]);
    phase_gradient(lens, &r->ps[w * 4 + 3], x, y + step, grad[2]);
    phase_gradient(lens, &r->ps[w * 4 + 3], x, y - step, grad[3]);
    {
        double s = 1.0 / (2.0 * step * r->mono_radius); /* slot coefficients are per unit u */
        double a11 = (grad[0][0] - grad[1][0]) * s, a12 = (grad[2][0] - grad[3][0]) * s;
        double a21 = (grad[0][1] - grad[1][1]) * s, a22 = (grad[2][1] - grad[3][1]) * s;
        det = fabs(a11 * a22 - a12 * a21);
    }
    pt->amp = sqrt(det) / lambda_mm;
    if (counts[2] == 0) pt->amp *= sqrt(c[2][0] > 0 ? c[2][0] : 0.0);
    // Point the kernel's views at the terms
    pf->phase0 = naive ? (float)c[3][0] : 0.0f;
    pf->housing2 = (float)(h * h);
    pdb->housing2 = h * h;
    {
        lensrt_terms_f *tf[4];
        lensrt_terms_d *td[4];
        tf[0] = &pf->xi; tf[1] = &pf->yi; tf[2] = &pf->tau; tf[3] = &pf->phase;
        td[0] = &pdb->xi; td[1] = &pdb->yi; td[2] = &pdb->tau; td[3] = &pdb->phase;
        for (o = 0; o < 4; o++) {
            tf[o]->n = td[o]->n = counts[o];
            tf[o]->slot = td[o]->slot = pt->slot[o];
            tf[o]->coef = pt->coef_f[o];
            td[o]->coef = pt->coef_d[o];
        }
    }
    if (pf->clip) {
        // The clip needs the constant position too
        for (o = 0; o < 2; o++) {
            pt->slot[o][counts[o]] = 0;
            pt->coef_f[o][counts[o]] = (float)c[o][0];
            pt->coef_d[o][counts[o]] = c[o][0];
            counts[o]++;
        }
        pf->xi.n = pdb->xi.n = counts[0];
        pf->yi.n = pdb->yi.n = counts[1];
    }
    return 1;
}


static void add_sums(lensrt_render r, int w, size_t p, const double *acc, double amp)
{
    size_t npix = (size_t)r->width * (size_t)r->height;
    int l;
    for (l = 0; l < r->n_lights; l++) {
        size_t at = ((size_t)l * (size_t)r->n_wl + (size_t)w) * npix + p;
        r->sum[2 * at] += amp * acc[3 * l];
        r->sum[2 * at + 1] += amp * acc[3 * l + 1];
        if (r->sumsq) r->sumsq[at] += amp * amp * acc[3 * l + 2];
    }
}

/* Splat every sample of pd to every pixel for wavelength w. */
static void splat_pass(lensrt_render r, int w, const pass_data *pd)
{
    const long npix = (long)r->width * r->height, ntiles = (npix + TILE - 1) / TILE;
    const int nl = r->n_lights, nb = pd->n_blocks;
    const int dbl = r->desc.precision == LENSRT_PRECISION_DOUBLE;
    const double lambda_mm = r->wavelengths[w] / NM_PER_MM;
    long tile;
    double s_terms = 0, s_clip = 0, s_tau = 0, s_dark = 0;
#ifdef LENSRT_OPENMP
#pragma omp parallel for schedule(dynamic, 4) num_threads(r->ctx->threads > 0 ? r->ctx->threads : omp_get_max_threads()) \
    reduction(+ : s_terms, s_clip, s_tau, s_dark)
#endif
    for (tile = 0; tile < ntiles; tile++) {
        pixel_terms pts[TILE];
        lensrt_pixel_f pf[TILE];
        lensrt_pixel_d pdd[TILE];
        int live[TILE];
        double acc[TILE][3 * 64];
        long p0 = tile * TILE, p1 = p0 + TILE < npix ? p0 + TILE : npix, p;
        int b;
        memset(acc, 0, sizeof acc);
        if (r->lens->analytic) {
            const lensrt_analytic_lens *m = &r->lens->model;
            double z = m->sensor_distance_mm + r->desc.sensor.focus_offset_mm;
            for (b = 0; b < nb; b++)
                for (p = p0; p < p1; p++)
                    lensrt_kernel_free_space(pd->mono_d + (size_t)b * 2 * LENSRT_BLOCK, nl,
                                             pd->phase_d + (size_t)b * nl * LENSRT_BLOCK,
                                             pd->amp_d + (size_t)b * nl * LENSRT_BLOCK,
                                             r->xs[p % r->width], r->ys[p / r->width], z, lambda_mm,
                                             m->one_dimensional, r->desc.precision == LENSRT_PRECISION_NAIVE_FLOAT,
                                             acc[p - p0]);
            for (p = p0; p < p1; p++) add_sums(r, w, (size_t)p, acc[p - p0], 1.0);
            continue;
        }
        // Specialise P_s to each pixel of the tile, then stream the sample blocks
        for (p = p0; p < p1; p++) {
            live[p - p0] = setup_pixel(r, w, r->xs[p % r->width], r->ys[p / r->width], &pts[p - p0], &pf[p - p0], &pdd[p - p0]);
            if (!live[p - p0]) {
                s_dark += 1;
                continue;
            }
            s_terms += pf[p - p0].phase.n;
            s_clip += pf[p - p0].clip;
            s_tau += pf[p - p0].tau.n > 0;
        }
        for (b = 0; b < nb; b++)
            for (p = p0; p < p1; p++) {
                if (!live[p - p0]) continue;
                if (dbl)
                    lensrt_kernel_d(pd->mono_d + (size_t)b * r->n_rows * LENSRT_BLOCK, nl,
                                    pd->phase_d + (size_t)b * nl * LENSRT_BLOCK,
                                    pd->amp_d + (size_t)b * nl * LENSRT_BLOCK, &pdd[p - p0], acc[p - p0]);
                else
                    lensrt_kernel_f(pd->mono_f + (size_t)b * r->n_rows * LENSRT_BLOCK, nl,
                                    pd->phase_f + (size_t)b * nl * LENSRT_BLOCK,
                                    pd->amp_f + (size_t)b * nl * LENSRT_BLOCK, &pf[p - p0], acc[p - p0]);
            }
        for (p = p0; p < p1; p++)
            if (live[p - p0]) add_sums(r, w, (size_t)p, acc[p - p0], pts[p - p0].amp);
    }
    if (!r->lens->analytic) {
        if (w == 0) r->stat_terms = r->stat_clip = r->stat_tau = r->stat_dark = r->stat_count = 0;
        r->stat_terms += s_terms;
        r->stat_clip += s_clip;
        r->stat_tau += s_tau;
        r->stat_dark += s_dark;
        r->stat_count += (double)npix;
    }
}

static void free_pass(lensrt_context ctx, pass_data *pd)
{
    lensrt_free(ctx, pd->xy);
    lensrt_free(ctx, pd->mono_f);
    lensrt_free(ctx, pd->mono_d);
    lensrt_free(ctx, pd->phase_f);
    lensrt_free(ctx, pd->amp_f);
    lensrt_free(ctx, pd->phase_d);
    lensrt_free(ctx, pd->amp_d);
}

static lensrt_result alloc_pass(lensrt_render r, int n, pass_data *pd)
{
    const int dbl = r->desc.precision == LENSRT_PRECISION_DOUBLE || r->lens->analytic;
    size_t nb, rows, lanes;
    memset(pd, 0, sizeof *pd);
    if (r->desc.device == LENSRT_DEVICE_GL) {
        // The device evaluates the samples: the host only draws their positions
        pd->n = n;
        pd->xy = lensrt_calloc(r->ctx, (size_t)n * 2 + 2, sizeof(double));
        return pd->xy ? LENSRT_SUCCESS : lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
    }
    pd->n = n;
    pd->n_blocks = (n + LENSRT_BLOCK - 1) / LENSRT_BLOCK;
    nb = (size_t)pd->n_blocks;
    rows = r->lens->analytic ? 2 : (size_t)r->n_rows;
    lanes = nb * (size_t)r->n_lights * LENSRT_BLOCK;
    pd->xy = lensrt_calloc(r->ctx, (size_t)n * 2 + 2, sizeof(double));
    if (dbl) {
        pd->mono_d = lensrt_calloc(r->ctx, nb * rows * LENSRT_BLOCK, sizeof(double));
        pd->phase_d = lensrt_calloc(r->ctx, lanes, sizeof(double));
        pd->amp_d = lensrt_calloc(r->ctx, lanes, sizeof(double));
    } else {
        pd->mono_f = lensrt_calloc(r->ctx, nb * rows * LENSRT_BLOCK, sizeof(float));
        pd->phase_f = lensrt_calloc(r->ctx, lanes, sizeof(float));
        pd->amp_f = lensrt_calloc(r->ctx, lanes, sizeof(float));
    }
    if (!pd->xy || (dbl ? !pd->mono_d || !pd->phase_d || !pd->amp_d : !pd->mono_f || !pd->phase_f || !pd->amp_f)) {
        free_pass(r->ctx, pd);
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory for a pass of %d samples", n);
    }
    return LENSRT_SUCCESS;
}

/* One wavelength's samples (pd->xy), splatted on the render's device. */
static lensrt_result splat_samples(lensrt_render r, int w, pass_data *pd)
{
#ifdef LENSRT_GL
    if (r->gl) return lensrt_gl_pass(r, w, pd->xy, pd->n);
#endif
    prepare_samples(r, w, pd);
    splat_pass(r, w, pd);
    return LENSRT_SUCCESS;
}

/* Passes run between begin and end: the GL device holds the sums in between. */
static lensrt_result begin_passes(lensrt_render r, pass_data *pd)
{
    lensrt_result res = alloc_pass(r, PASS, pd);
#ifdef LENSRT_GL
    if (res == LENSRT_SUCCESS && r->gl && (res = lensrt_gl_begin(r)) != LENSRT_SUCCESS) free_pass(r->ctx, pd);
#endif
    return res;
}

static lensrt_result end_passes(lensrt_render r, pass_data *pd, lensrt_result status)
{
#ifdef LENSRT_GL
    if (r->gl) status = lensrt_gl_end(r, status);
#endif
    free_pass(r->ctx, pd);
    return status;
}

lensrt_result lensrt_render_run(lensrt_render r, uint64_t samples_per_wavelength, lensrt_progress_fn progress, void *user_data)
{
    uint64_t done = 0;
    double t0 = lensrt_seconds();
    pass_data pd;
    lensrt_result res;
    if (!r) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (samples_per_wavelength == 0 || samples_per_wavelength > ((uint64_t)1 << 40))
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "run: samples per wavelength must be 1..2^40, got %llu", (unsigned long long)samples_per_wavelength);
    if ((res = begin_passes(r, &pd)) != LENSRT_SUCCESS) return res;
    while (done < samples_per_wavelength && res == LENSRT_SUCCESS) {
        uint64_t n = samples_per_wavelength - done < PASS ? samples_per_wavelength - done : PASS;
        int w, cancelled = 0;
        double elapsed, frac;
        // One pass: the same sample indices for every wavelength (each its own sequence)
        for (w = 0; w < r->n_wl && res == LENSRT_SUCCESS; w++) {
            memset(pd.xy, 0, sizeof(double) * PASS * 2);
            pd.n = (int)n;
            pd.n_blocks = (int)((n + LENSRT_BLOCK - 1) / LENSRT_BLOCK);
            lensrt_sample_aperture(r->desc.sampler, r->desc.seed, w, r->samples, n, &r->region, pd.xy);
            res = splat_samples(r, w, &pd);
            elapsed = lensrt_seconds() - t0;
            frac = ((double)done + (double)n * (w + 1) / r->n_wl) / (double)samples_per_wavelength;
            // A request to stop takes effect when the pass is complete (every wavelength
            // must hold the same samples)
            if (progress && w + 1 < r->n_wl && progress(frac, elapsed * (1.0 - frac) / frac, user_data))
                cancelled = 1;
        }
        if (res != LENSRT_SUCCESS) break;
        r->samples += n;
        done += n;
        r->splats += n * (uint64_t)r->n_wl * (uint64_t)r->width * (uint64_t)r->height;
        elapsed = lensrt_seconds() - t0;
        if (progress && (progress((double)done / (double)samples_per_wavelength,
                                  elapsed * (double)(samples_per_wavelength - done) / (double)done, user_data) ||
                         cancelled))
            res = lensrt_fail(r->ctx, LENSRT_ERROR_CANCELLED, "run: cancelled after %llu samples per wavelength",
                              (unsigned long long)done);
    }
    res = end_passes(r, &pd, res);
    r->seconds += lensrt_seconds() - t0;
    return res;
}

lensrt_result lensrt_render_splat_points(lensrt_render r, int wavelength, const double *xy_mm, size_t n_points)
{
    double t0 = lensrt_seconds();
    pass_data pd;
    lensrt_result res;
    size_t done = 0;
    if (!r || !xy_mm) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (wavelength < 0 || wavelength >= r->n_wl || n_points == 0)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "splat_points: wavelength index %d of %d, %zu points",
                           wavelength, r->n_wl, n_points);
    if (r->n_wl != 1)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "splat_points: needs a render with one wavelength (sample counts are shared), it has %d", r->n_wl);
    if ((res = begin_passes(r, &pd)) != LENSRT_SUCCESS) return res;
    while (done < n_points && res == LENSRT_SUCCESS) {
        size_t n = n_points - done < PASS ? n_points - done : PASS;
        memset(pd.xy, 0, sizeof(double) * PASS * 2);
        memcpy(pd.xy, xy_mm + 2 * done, sizeof(double) * 2 * n);
        pd.n = (int)n;
        pd.n_blocks = (int)((n + LENSRT_BLOCK - 1) / LENSRT_BLOCK);
        res = splat_samples(r, wavelength, &pd);
        if (res == LENSRT_SUCCESS) {
            done += n;
            r->samples += n;
            r->splats += (uint64_t)n * (uint64_t)r->width * (uint64_t)r->height;
        }
    }
    res = end_passes(r, &pd, res);
    r->seconds += lensrt_seconds() - t0;
    return res;
}

/* ------------------------------------------------------------- results ----- */

lensrt_result lensrt_render_get_stats(lensrt_render r, lensrt_render_stats *caller)
{
    lensrt_render_stats *out = caller;
    lensrt_render_stats st;
    if (!r || !out) return LENSRT_ERROR_INVALID_ARGUMENT;
    memset(&st, 0, sizeof st);
    st.struct_size = sizeof st;
    out = &st; /* written to the caller's struct at the end, as far as its struct_size */
    out->width = r->width;
    out->height = r->height;
    out->n_wavelengths = r->n_wl;
    out->n_lights = r->n_lights;
    out->samples_per_wavelength = r->samples;
    out->splats = r->splats;
    out->seconds = r->seconds;
    out->splats_per_second = r->seconds > 0 ? (double)r->splats / r->seconds : 0.0;
    out->stop_radius_mm = r->stop_radius;
    out->f_number = r->f_number;
    if (r->stat_count > 0) {
        double live = r->stat_count - r->stat_dark;
        out->phase_terms = live > 0 ? r->stat_terms / live : 0.0;
        out->clip_fraction = r->stat_clip / r->stat_count;
        out->tau_fraction = r->stat_tau / r->stat_count;
        out->dark_fraction = r->stat_dark / r->stat_count;
    }
    return lensrt_struct_out(r->ctx, "lensrt_render_stats", caller, &st, sizeof st);
}

const double *lensrt_render_wavelengths(lensrt_render r) { return r ? r->wavelengths : NULL; }

lensrt_result lensrt_render_image(lensrt_render r, float *out, size_t count)
{
    const size_t npix = r ? (size_t)r->width * (size_t)r->height : 0;
    const double n = r ? (double)r->samples : 0.0;
    size_t p;
    int w, l;
    if (!r || !out) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (count != npix * (size_t)r->n_wl)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "image: count must be %zu (wavelengths x pixels), got %zu",
                           npix * (size_t)r->n_wl, count);
    if (r->samples == 0 || (r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED && r->samples < 2))
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "image: no samples yet (the unbiased estimator needs 2)");
    for (w = 0; w < r->n_wl; w++)
        for (p = 0; p < npix; p++) {
            double total = 0.0;
            // Lights are incoherent: add intensities, each from its own phasor sum
            for (l = 0; l < r->n_lights; l++) {
                size_t at = ((size_t)l * (size_t)r->n_wl + (size_t)w) * npix + p;
                double re = r->sum[2 * at], im = r->sum[2 * at + 1], s2 = re * re + im * im;
                if (r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED)
                    total += r->measure * r->measure * (s2 - r->sumsq[at]) / (n * (n - 1.0));
                else
                    total += r->measure * r->measure * s2 / (n * n);
            }
            out[(size_t)w * npix + p] = (float)total;
        }
    return LENSRT_SUCCESS;
}

static lensrt_result spectral_and_rgb(lensrt_render r, float **spectral, float **rgb)
{
    size_t npix = (size_t)r->width * (size_t)r->height;
    lensrt_result res;
    *spectral = lensrt_alloc(r->ctx, sizeof(float) * npix * (size_t)r->n_wl);
    *rgb = lensrt_alloc(r->ctx, sizeof(float) * npix * 3);
    if (!*spectral || !*rgb) return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "image: out of memory");
    if ((res = lensrt_render_image(r, *spectral, npix * (size_t)r->n_wl)) != LENSRT_SUCCESS) return res;
    lensrt_spectrum_to_rgb(r->n_wl, r->wavelengths, *spectral, npix, *rgb);
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_render_rgb(lensrt_render r, float *out, size_t count)
{
    float *spectral = NULL, *rgb = NULL;
    lensrt_result res;
    if (!r || !out) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (count != (size_t)r->width * (size_t)r->height * 3)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "rgb: count must be %zu, got %zu",
                           (size_t)r->width * (size_t)r->height * 3, count);
    res = spectral_and_rgb(r, &spectral, &rgb);
    if (res == LENSRT_SUCCESS) memcpy(out, rgb, sizeof(float) * count);
    lensrt_free(r->ctx, spectral);
    lensrt_free(r->ctx, rgb);
    return res;
}

static void describe_aperture(const lensrt_render r, char *buf, size_t size)
{
    const lensrt_aperture *a = &r->desc.aperture;
    // EXR metadata: numbers in the "C" locale whatever the host's (c_numbers.h)
    if (a->shape == LENSRT_APERTURE_BLADES)
        lensrt_snprintf_c(buf, size, "%d blades, curvature %g, rotation %g deg", a->blades, a->blade_curvature,
                          a->rotation_deg);
    else if (a->shape == LENSRT_APERTURE_SLIT)
        lensrt_snprintf_c(buf, size, "slit %g mm wide, separation %g mm", a->slit_width_mm, a->slit_separation_mm);
    else
        snprintf(buf, size, "circle");
}

static lensrt_result write_image(lensrt_render r, const char *path, int exr, double decades)
{
    float *spectral = NULL, *rgb = NULL;
    lensrt_result res;
    char err[LENSRT_ERROR_SIZE] = "", aperture[128];
    if (!r || !path) return LENSRT_ERROR_INVALID_ARGUMENT;
    res = spectral_and_rgb(r, &spectral, &rgb);
    if (res == LENSRT_SUCCESS && exr) {
        lensrt_image_meta meta;
        memset(&meta, 0, sizeof meta);
        describe_aperture(r, aperture, sizeof aperture);
        meta.lens_name = r->lens->name;
        meta.lens_file = r->lens->analytic ? NULL : r->lens->file;
        meta.focal_length_mm = r->lens->focal_length_mm;
        meta.f_number = r->f_number;
        meta.stop_radius_mm = r->stop_radius;
        meta.focus_offset_mm = r->desc.sensor.focus_offset_mm;
        meta.pixel_pitch_x_mm = r->pitch_x;
        meta.pixel_pitch_y_mm = r->pitch_y;
        meta.center_x_mm = r->desc.sensor.center_x_mm;
        meta.center_y_mm = r->desc.sensor.center_y_mm;
        meta.samples_per_wavelength = r->samples;
        meta.seconds = r->seconds;
        meta.splats_per_second = r->seconds > 0 ? (double)r->splats / r->seconds : 0.0;
        meta.sampler = sampler_name(r->desc.sampler);
        meta.estimator = r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED ? "unbiased" : "paper";
        meta.aperture = aperture;
        meta.seed = r->desc.seed;
        meta.n_lights = r->n_lights;
        meta.lights = r->lights;
        res = lensrt_write_exr(&r->ctx->allocator, path, r->width, r->height, r->n_wl, r->wavelengths,
                               spectral, rgb, &meta, err, sizeof err);
    } else if (res == LENSRT_SUCCESS) {
        res = lensrt_write_png(&r->ctx->allocator, path, r->width, r->height, rgb, decades, err, sizeof err);
    }
    if (res != LENSRT_SUCCESS && err[0]) lensrt_fail(r->ctx, res, "%s", err);
    lensrt_free(r->ctx, spectral);
    lensrt_free(r->ctx, rgb);
    return res;
}

lensrt_result lensrt_render_write_exr(lensrt_render r, const char *path) { return write_image(r, path, 1, 0.0); }

lensrt_result lensrt_render_write_png(lensrt_render r, const char *path, double decades)
{
    return write_image(r, path, 0, decades);
}
