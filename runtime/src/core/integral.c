/* What a render's integrals share between its own calls (lensrt_render_integrate,
 * lensrt_render_integrate_fourier: core/render_integrate.c) and host-scheduled tile
 * sessions (core/tiles.c): the checks, the sums made from the integrated field with the
 * error estimate, the Fourier integrator's automatic nodes, and the refusal of samples
 * once the sums hold an integral. */
#include "render.h"
#include "cells.h"
#include "fourier.h"

#include "../lens/lens.h"
#include "device.h"

#include <math.h>
#include <string.h>

/* ------------------------------------------------------ the cells integrator ----- */

lensrt_result lensrt_cells_idle(lensrt_render r, const char *what)
{
    if (r->fourier_nodes)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "%s: the sums hold a Fourier integral (lensrt_render_integrate_fourier, %d nodes), not "
                           "Monte Carlo samples; render samples with a new render",
                           what, r->fourier_nodes);
    if (!r->cells_rings) return LENSRT_SUCCESS;
    return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                       "%s: the sums hold a cells integral (lensrt_render_integrate, %d rings), not Monte Carlo "
                       "samples; render samples with a new render", what, r->cells_rings);
}

/* ||I(Ua) - I(Ub)|| and ||I(Ua)|| over every pixel and wavelength (lights add). */
static void image_distance(lensrt_render r, const double *Ua, const double *Ub, double *dist, double *norm)
{
    // Over the image's pixels: the box filter's mean of its points' intensities (the
    // point filter's, sx = sy = 1, is the point's own)
    const size_t npix = (size_t)r->width * (size_t)r->height;
    const double per_pixel = (double)r->sx * (double)r->sy;
    double num = 0.0, den = 0.0;
    int w, l, i, j, k, m;
    for (w = 0; w < r->n_wl; w++)
        for (j = 0; j < r->out_height; j++)
            for (i = 0; i < r->out_width; i++) {
                double Ia = 0.0, Ib = 0.0;
                for (m = 0; m < r->sy; m++)
                    for (k = 0; k < r->sx; k++) {
                        const size_t p = lensrt_grid_point(r, i, j, k, m);
                        double pa = 0.0, pb = 0.0;
                        for (l = 0; l < r->n_lights; l++) {
                            const size_t at = 2 * (((size_t)l * (size_t)r->n_wl + (size_t)w) * npix + p);
                            pa += Ua[at] * Ua[at] + Ua[at + 1] * Ua[at + 1];
                            pb += Ub[at] * Ub[at] + Ub[at + 1] * Ub[at + 1];
                        }
                        Ia += pa;
                        Ib += pb;
                    }
                Ia /= per_pixel;
                Ib /= per_pixel;
                num += (Ia - Ib) * (Ia - Ib);
                den += Ia * Ia;
            }
    *dist = sqrt(num);
    *norm = sqrt(den);
}

/* The relative L2 error of the image of field Uf (rings m), estimated from the fields of
 * meshes m / 2 and m / 4 (Uc, Uc2; Uc2 NULL: none): with an error c h^p the images'
 * differences d1 = |I_m - I_m/2| and d2 = |I_m/2 - I_m/4| give 2^p = d2 / d1 and
 * the error of I_m is d1 / (2^p - 1). The order is taken within [2, 4] (the method is
 * second order; a cleaner convergence shows as a larger ratio, pre-asymptotic noise is
 * not trusted below 2): without Uc2, p = 2. */
static double cells_estimate(lensrt_render r, const double *Uf, const double *Uc, const double *Uc2)
{
    double d1, d2, n1, n2, ratio = 4.0;
    image_distance(r, Uf, Uc, &d1, &n1);
    if (Uc2 && d1 > 0.0) {
        image_distance(r, Uc, Uc2, &d2, &n2);
        ratio = d2 / d1;
        if (!(ratio >= 4.0)) ratio = 4.0;
        if (ratio > 16.0) ratio = 16.0;
    }
    return n1 > 0.0 ? d1 / (ratio - 1.0) / n1 : 0.0;
}

lensrt_result lensrt_cells_check(lensrt_render r, const char *what, int rings, int estimate)
{
    if (rings < 1 || rings > LENSRT_MAX_RINGS || (estimate && rings < 2))
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "%s: rings must be %d..%d (2 or more with an error estimate), got %d", what, estimate ? 2 : 1,
                           LENSRT_MAX_RINGS, rings);
    if (!r->device->integrate)
        return lensrt_fail(r->ctx, LENSRT_ERROR_UNSUPPORTED,
                           "%s: the %s device has no cells integrator (the CPU device has): render with device cpu, "
                           "or with Monte Carlo samples (lensrt_render_run)", what, r->device->name);
    if (r->lens_ops->one_dimensional(r->lens))
        return lensrt_fail(r->ctx, LENSRT_ERROR_UNSUPPORTED,
                           "%s: the cells integrator meshes two-dimensional apertures; %s is one-dimensional "
                           "(use lensrt_render_run)", what, r->lens->info.name);
    if (r->desc.precision == LENSRT_PRECISION_NAIVE_FLOAT || r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED)
        return lensrt_fail(r->ctx, LENSRT_ERROR_UNSUPPORTED,
                           "%s: the cells integrator takes precision DEFAULT or DOUBLE and the paper's estimator "
                           "(precision NAIVE_FLOAT and the unbiased estimator are Monte Carlo's)", what);
    if (r->samples > 0 && !r->cells_rings && !r->fourier_nodes)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "%s: the sums already hold %llu Monte Carlo samples per wavelength; integrate with a new "
                           "render", what, (unsigned long long)r->samples);
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_cells_finish(lensrt_render r, int rings, double *Uf, double *Uc, const double *Uc2,
                                  double *error_estimate)
{
    const size_t nsum = 2 * (size_t)r->n_lights * (size_t)r->n_wl * (size_t)r->width * (size_t)r->height;
    size_t i;
    // Never a NaN or inf in the sums: name the first such field
    for (i = 0; i < nsum; i++)
        if (!isfinite(Uf[i]))
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                               "integrate: the field of pixel %zu is not finite: the lens table or the lights' "
                               "intensities are beyond what double holds",
                               (i / 2) % ((size_t)r->width * (size_t)r->height));
    r->cells_error = Uc ? cells_estimate(r, Uf, Uc, Uc2) : -1.0;
    if (error_estimate) *error_estimate = r->cells_error;
    // The sums hold the field divided by the measure, as one sample would
    for (i = 0; i < nsum; i++) r->sum[i] = Uf[i] / r->measure;
    r->samples = 1;
    lensrt_tail_forget(r);
    r->cells_rings = rings;
    r->fourier_nodes = r->fourier_fine_nodes = 0;
    lensrt_free(r->ctx, r->fourier_fine);
    r->fourier_fine = NULL;
    // The render keeps this field and the one half as fine (the next, doubled call's
    // coarse levels); Uc may be the field it kept before
    if (r->cells_coarse != Uc) lensrt_free(r->ctx, r->cells_coarse);
    if (r->cells_field != Uc) lensrt_free(r->ctx, r->cells_field);
    r->cells_field = Uf;
    r->cells_coarse = Uc;
    return LENSRT_SUCCESS;
}

/* ------------------------------------------------------ the Fourier integrator ----- */

lensrt_result lensrt_fourier_finish(lensrt_render r, int nodes, const double *U, double *Ufine, int fine_nodes,
                                    double *error_estimate)
{
    const size_t nsum = 2 * (size_t)r->n_lights * (size_t)r->n_wl * (size_t)r->width * (size_t)r->height;
    size_t i;
    for (i = 0; i < nsum; i++)
        if (!isfinite(U[i]) || (Ufine && !isfinite(Ufine[i])))
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                               "integrate_fourier: the field of pixel %zu is not finite: the lens table or the "
                               "lights' intensities are beyond what double holds",
                               (i / 2) % ((size_t)r->width * (size_t)r->height));
    // The estimate is the error of this (the coarser) field against the finer one: the
    // rule converges spectrally, so the finer field's own error is far below it
    r->cells_error = -1.0;
    if (Ufine) {
        double d, n;
        image_distance(r, Ufine, U, &d, &n);
        r->cells_error = n > 0.0 ? d / n : 0.0;
    }
    if (error_estimate) *error_estimate = r->cells_error;
    for (i = 0; i < nsum; i++) r->sum[i] = U[i] / r->measure;
    r->samples = 1;
    lensrt_tail_forget(r);
    r->cells_rings = 0;
    lensrt_free(r->ctx, r->cells_field);
    lensrt_free(r->ctx, r->cells_coarse);
    r->cells_field = r->cells_coarse = NULL;
    r->fourier_nodes = nodes;
    if (r->fourier_fine != Ufine) lensrt_free(r->ctx, r->fourier_fine);
    r->fourier_fine = Ufine;
    r->fourier_fine_nodes = Ufine ? fine_nodes : 0;
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_fourier_check(lensrt_render r, const char *what, int nodes, int estimate)
{
    if (nodes < 0 || nodes > LENSRT_MAX_FOURIER_NODES ||
        (estimate && ceil(LENSRT_FOURIER_FINER * nodes) > LENSRT_MAX_FOURIER_NODES))
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "%s: nodes must be 0 (chosen) or 1..%d (%d with an error estimate, whose finer rule has "
                           "%g times the nodes), got %d",
                           what, LENSRT_MAX_FOURIER_NODES, (int)(LENSRT_MAX_FOURIER_NODES / LENSRT_FOURIER_FINER),
                           LENSRT_FOURIER_FINER, nodes);
    if (!r->device->fourier)
        return lensrt_fail(r->ctx, LENSRT_ERROR_UNSUPPORTED,
                           "%s: the %s device has no Fourier integrator (the CPU device has): render with device "
                           "cpu, or with Monte Carlo samples (lensrt_render_run)",
                           what, r->device->name);
    return lensrt_cells_check(r, what, 1, 0);
}

/* The nodes that resolve the integrand (render.h): a pilot rule measures the phase's largest change
 * per unit of a line parameter over the window's corners (core/fourier.h), and
 * LENSRT_FOURIER_NODES_PER_WAVE nodes go to each wave, NODES_EXTRA more for the ends;
 * fewer for a target of 1e-4 or more (fourier.h). */
lensrt_result lensrt_fourier_auto_nodes(lensrt_render r, double target, int *nodes)
{
    lensrt_quadrature q;
    lensrt_fourier_job job;
    lensrt_result res = lensrt_quadrature_build(r->ctx, &r->desc.aperture, r->stop_radius,
                                                LENSRT_FOURIER_PILOT_NODES, &q);
    double n, q_ratio;
    int q_patches;
    const double most = LENSRT_MAX_FOURIER_NODES / LENSRT_FOURIER_FINER;
    if (res != LENSRT_SUCCESS) return res;
    // The rule's nodes per (nodes per side)^2: patches, and a slit's lines per node
    q_patches = q.patches;
    q_ratio = (double)q.nb / q.na;
    memset(&job, 0, sizeof job);
    job.n_level = 1;
    job.quad[0] = &q;
    job.tol[0] = LENSRT_FOURIER_TOL;
    job.pilot = 1;
    res = r->device->fourier(r, &job, NULL, NULL);
    lensrt_quadrature_free(r->ctx, &q);
    if (res != LENSRT_SUCCESS) return res;
    {
        // 0 at a target of 1e-4 or less (or none), 1 at 1% or more
        const double t = target > 1e-4 ? (log10(target) + 4.0) / 2.0 : 0.0, f = t > 1.0 ? 1.0 : t;
        const double per_wave = LENSRT_FOURIER_NODES_PER_WAVE + f * (LENSRT_FOURIER_NODES_PER_WAVE_1PCT - LENSRT_FOURIER_NODES_PER_WAVE);
        const double extra = LENSRT_FOURIER_NODES_EXTRA + f * (LENSRT_FOURIER_NODES_EXTRA_1PCT - LENSRT_FOURIER_NODES_EXTRA);
        n = ceil(per_wave * job.slope) + extra;
    }
    *nodes = n < 8.0 ? 8 : n > most ? (int)most : (int)n;
    {
        // Where the rule outgrows the window (nodes per pixel), cells is the cheaper
        const double rule = (double)q_patches * (double)*nodes * (double)*nodes * q_ratio;
        const double npix = (double)r->width * (double)r->height;
        if (rule > LENSRT_FOURIER_NODES_PER_PIXEL * npix)
            return lensrt_fail(r->ctx, LENSRT_ERROR_UNSUPPORTED,
                               "integrate_fourier: the phase swings over %.3g waves across the aperture: a rule of "
                               "%d nodes per side (%.3g nodes) for %.0f pixels, beyond %d per pixel, where the "
                               "cells integrator is the cheaper (lensrt_render_integrate); name the nodes to "
                               "insist",
                               job.slope, *nodes, rule, npix, LENSRT_FOURIER_NODES_PER_PIXEL);
    }
    return LENSRT_SUCCESS;
}
