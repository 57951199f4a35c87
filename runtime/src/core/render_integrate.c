/* The deterministic integrals of a render's sums: the cells integrator
 * (lensrt_render_integrate) and the Fourier integrator (lensrt_render_integrate_fourier,
 * lensrt_render_fourier_nodes), each run by the render's device in one call. What they
 * share with tile sessions (checks, finishing the sums, the automatic nodes) is
 * core/integral.c. */
#include "render.h"
#include "cells.h"
#include "fourier.h"

#include "device.h"
#include "tiles.h"

#include <math.h>
#include <string.h>

/* ------------------------------------------------------ the cells integrator ----- */

/* The fields of every light, wavelength and pixel on the meshes of rings[k] rings into
 * U[k] (k < n), in one pass of the device (one set-up per pixel). */
static lensrt_result cells_fields(lensrt_render r, int n, const int *rings, double *const *U,
                                  lensrt_progress_fn progress, void *user_data)
{
    lensrt_mesh mesh[LENSRT_CELLS_MAX_MESHES];
    lensrt_cells_job job;
    lensrt_result res = LENSRT_SUCCESS;
    int k, built = 0;
    memset(&job, 0, sizeof job);
    for (k = 0; k < n && res == LENSRT_SUCCESS; k++, built++) {
        res = lensrt_mesh_build(r->ctx, &r->desc.aperture, r->stop_radius, rings[k], &mesh[k]);
        job.mesh[k] = &mesh[k];
        job.U[k] = U[k];
    }
    job.n_mesh = n;
    if (res == LENSRT_SUCCESS) res = r->device->integrate(r, &job, progress, user_data);
    for (k = 0; k < built; k++) lensrt_mesh_free(r->ctx, &mesh[k]);
    return res;
}

lensrt_result lensrt_render_integrate(lensrt_render r, int32_t rings, double *error_estimate,
                                      lensrt_progress_fn progress, void *user_data)
{
    const double t0 = lensrt_seconds();
    size_t nsum;
    double *U[LENSRT_CELLS_MAX_MESHES] = {NULL, NULL, NULL};
    int levels[LENSRT_CELLS_MAX_MESHES], n = 1, reuse = 0, k;
    lensrt_result res;
    if (!r) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_tiles_idle(r, "integrate")) != LENSRT_SUCCESS ||
        (res = lensrt_cells_check(r, "integrate", rings, error_estimate != NULL)) != LENSRT_SUCCESS)
        return res;
    nsum = 2 * (size_t)r->n_lights * (size_t)r->n_wl * (size_t)r->width * (size_t)r->height;
    // The meshes: rings, and for the estimate rings / 2 and rings / 4 (a quarter and a
    // sixteenth of the cost), unless the last call's fields are those (a refinement
    // costs one new mesh)
    levels[0] = rings;
    if (error_estimate) {
        reuse = r->cells_field && r->cells_rings == rings / 2 && rings % 2 == 0;
        if (!reuse) {
            levels[n++] = rings / 2;
            if (rings / 4 >= 1) levels[n++] = rings / 4;
        }
    }
    for (k = 0; k < n; k++)
        if (!(U[k] = lensrt_calloc(r->ctx, nsum, sizeof(double)))) {
            for (k = 0; k < n; k++) lensrt_free(r->ctx, U[k]);
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "integrate: out of memory");
        }
    res = cells_fields(r, n, levels, U, progress, user_data);
    if (res == LENSRT_SUCCESS) {
        double *coarse = reuse ? r->cells_field : n > 1 ? U[1] : NULL;
        double *coarse2 = reuse ? r->cells_coarse : n > 2 ? U[2] : NULL;
        res = lensrt_cells_finish(r, rings, U[0], coarse, coarse2, error_estimate);
        if (res == LENSRT_SUCCESS) {
            U[0] = NULL; /* the render's now, and the coarse field with it */
            if (!reuse && n > 1) U[1] = NULL;
        }
    }
    for (k = 0; k < n; k++) lensrt_free(r->ctx, U[k]);
    r->seconds += lensrt_seconds() - t0;
    return res;
}

/* ------------------------------------------------------ the Fourier integrator ----- */

lensrt_result lensrt_render_fourier_nodes(lensrt_render r, double target, int32_t *nodes)
{
    const double t0 = lensrt_seconds();
    lensrt_result res;
    int n = 0;
    if (!r || !nodes) return LENSRT_ERROR_INVALID_ARGUMENT;
    *nodes = 0;
    if (!(target >= 0.0) || !isfinite(target))
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "fourier_nodes: the target error must be 0 (the default rule) or a finite positive "
                           "relative L2 error, got %g", target);
    if ((res = lensrt_fourier_check(r, "fourier_nodes", 0, 0)) != LENSRT_SUCCESS) return res;
    res = lensrt_fourier_auto_nodes(r, target, &n);
    // The pilot is part of the integral's cost
    r->seconds += lensrt_seconds() - t0;
    if (res == LENSRT_SUCCESS) *nodes = n;
    return res;
}

lensrt_result lensrt_render_integrate_fourier(lensrt_render r, int32_t nodes, double *error_estimate,
                                              lensrt_progress_fn progress, void *user_data)
{
    const double t0 = lensrt_seconds();
    int fine, reuse;
    lensrt_quadrature quad[LENSRT_FOURIER_MAX_LEVELS];
    lensrt_fourier_job job;
    double *U[LENSRT_FOURIER_MAX_LEVELS] = {NULL, NULL};
    size_t nsum;
    lensrt_result res = LENSRT_SUCCESS;
    int k, built = 0;
    if (!r) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_tiles_idle(r, "integrate_fourier")) != LENSRT_SUCCESS ||
        (res = lensrt_fourier_check(r, "integrate_fourier", nodes, error_estimate != NULL)) != LENSRT_SUCCESS)
        return res;
    if (nodes == 0 && (res = lensrt_fourier_auto_nodes(r, 0.0, &nodes)) != LENSRT_SUCCESS) {
        r->seconds += lensrt_seconds() - t0;
        return res;
    }
    fine = error_estimate ? (int)ceil(LENSRT_FOURIER_FINER * nodes) : 0;
    reuse = error_estimate && r->fourier_fine && r->fourier_fine_nodes == nodes;
    nsum = 2 * (size_t)r->n_lights * (size_t)r->n_wl * (size_t)r->width * (size_t)r->height;
    memset(&job, 0, sizeof job);
    // The rule of `nodes`, and for the estimate a finer one (unless the last call's finer
    // rule is this one: then its field is this call's, and only the finer is new)
    job.n_level = error_estimate ? 2 : 1;
    for (k = 0; k < job.n_level; k++) {
        const int n = k == 0 ? nodes : fine;
        if (k == 0 && reuse) continue;
        if ((res = lensrt_quadrature_build(r->ctx, &r->desc.aperture, r->stop_radius, n, &quad[k])) !=
            LENSRT_SUCCESS)
            break;
        built |= 1 << k;
        if (!(U[k] = lensrt_calloc(r->ctx, nsum, sizeof(double)))) {
            res = lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "integrate_fourier: out of memory");
            break;
        }
    }
    if (res == LENSRT_SUCCESS) {
        // The finer level with the tolerance a tenth of the coarser's, so that the
        // difference sees the interpolation and the NUFFT too
        int n = 0;
        for (k = 0; k < job.n_level; k++) {
            if (k == 0 && reuse) continue;
            job.quad[n] = &quad[k];
            job.tol[n] = k == 0 ? LENSRT_FOURIER_TOL : 0.1 * LENSRT_FOURIER_TOL;
            job.U[n++] = U[k];
        }
        job.n_level = n;
        res = r->device->fourier(r, &job, progress, user_data);
    }
    if (res == LENSRT_SUCCESS) {
        const double *coarse = reuse ? r->fourier_fine : U[0];
        if (reuse) {
            // The kept field is this call's: take it, so that finish may replace it
            U[0] = r->fourier_fine;
            r->fourier_fine = NULL;
            coarse = U[0];
        }
        res = lensrt_fourier_finish(r, nodes, coarse, error_estimate ? U[1] : NULL, fine, error_estimate);
        if (res == LENSRT_SUCCESS) U[1] = NULL; /* the render's now */
    }
    for (k = 0; k < LENSRT_FOURIER_MAX_LEVELS; k++) {
        if (built & (1 << k)) lensrt_quadrature_free(r->ctx, &quad[k]);
        lensrt_free(r->ctx, U[k]);
    }
    r->seconds += lensrt_seconds() - t0;
    return res;
}
