/* The CPU device's Fourier integrator (core/fourier.h says what it computes and why):
 * the driver.
 *
 * One thread per wavelength (OpenMP over wavelengths: each wavelength's field is made by
 * one thread alone, so the result does not depend on the threads); a host tile makes
 * every wavelength on its own thread. A wavelength's field, tile by tile, is
 * cpu/fourier_tile.c's. */
#include "fourier_wave.h"

#include "../core/nufft.h"
#include "../lens/lens.h"

#include <math.h>
#include <stdio.h>
#include <string.h>
#ifdef LENSRT_OPENMP
#include <omp.h>
#endif

/* ------------------------------------------------------------- the driver ----- */

static void free_wave(lensrt_context ctx, fourier_wave *fw)
{
    lensrt_free(ctx, fw->sph);
    lensrt_free(ctx, fw->samp);
    lensrt_free(ctx, fw->tp);
    lensrt_free(ctx, fw->gx);
    lensrt_free(ctx, fw->gy);
    lensrt_free(ctx, fw->cv);
    lensrt_free(ctx, fw->f);
    lensrt_free(ctx, fw->plan_mem);
    lensrt_free(ctx, fw->scratch);
}

/* Scratch for a level's rule (the tile may be the whole window). */
static int alloc_wave(lensrt_render r, const lensrt_quadrature *q, double tol, fourier_wave *fw)
{
    const size_t nq = ((size_t)q->n + BLK - 1) / BLK * BLK, nl = (size_t)r->n_lights, nv = nl * MAX_NODES;
    const size_t npix = (size_t)r->width * (size_t)r->height;
    lensrt_nufft probe;
    memset(fw, 0, sizeof *fw);
    fw->r = r;
    fw->q = q;
    fw->nq = (int)nq;
    fw->tol = tol;
    fw->poly = r->lens_ops->transport == LENSRT_TRANSPORT_POLYNOMIAL;
    {
        int c;
        for (c = 0; c < TOL_CLASSES; c++) {
            const size_t pb = lensrt_nufft_plan_bytes(r->width, r->height, tol * pow(10.0, c));
            if (pb > fw->plan_bytes) fw->plan_bytes = pb;
        }
    }
    fw->sph = lensrt_calloc(r->ctx, nl * nq, sizeof(double));
    fw->samp = lensrt_calloc(r->ctx, nl * nq, sizeof(double));
    fw->tp = lensrt_calloc(r->ctx, 1, sizeof(tile_poly));
    fw->gx = lensrt_calloc(r->ctx, nq, sizeof(double));
    fw->gy = lensrt_calloc(r->ctx, nq, sizeof(double));
    fw->cv = lensrt_calloc(r->ctx, nv * nq * 2, sizeof(double));
    fw->f = lensrt_calloc(r->ctx, nv * npix * 2, sizeof(double));
    fw->plan_mem = lensrt_calloc(r->ctx, fw->plan_bytes, 1);
    if (!fw->sph || !fw->samp || !fw->tp || !fw->gx || !fw->gy || !fw->cv ||
        !fw->f || !fw->plan_mem)
        return 0;
    // The scratch of the largest tile (the window) with every term of every light
    if (!lensrt_nufft_init(&probe, r->width, r->height, tol, fw->plan_mem)) return 0;
    for (fw->batch = NUFFT_BATCH; fw->batch > 1; fw->batch /= 2)
        if (lensrt_nufft_scratch_bytes(&probe, fw->batch) <= NUFFT_SCRATCH_BYTES) break;
    fw->scratch_bytes = lensrt_nufft_scratch_bytes(&probe, fw->batch);
    fw->scratch = lensrt_calloc(r->ctx, fw->scratch_bytes, 1);
    return fw->scratch != NULL;
}

lensrt_result lensrt_cpu_fourier(lensrt_render r, lensrt_fourier_job *job, lensrt_progress_fn progress,
                                 void *user_data)
{
    const int nthreads =
#ifdef LENSRT_OPENMP
        r->ctx->threads > 0 ? r->ctx->threads : omp_get_max_threads();
#else
        1;
#endif
    const int nth = nthreads < r->n_wl ? nthreads : r->n_wl;
    const double t0 = lensrt_seconds();
    fourier_wave fws[64];
    lensrt_result res = LENSRT_SUCCESS;
    int lv, t, w, done = 0, cancelled = 0;
    if (nth > 64) return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "fourier: more than 64 threads");
    job->slope = 0.0;
    for (lv = 0; lv < job->n_level && res == LENSRT_SUCCESS; lv++) {
        int ok = 1;
        for (t = 0; t < nth; t++) {
            ok &= alloc_wave(r, job->quad[lv], job->tol[lv], &fws[t]);
            fws[t].U = job->U[lv];
        }
        if (!ok) {
            for (t = 0; t < nth; t++) free_wave(r->ctx, &fws[t]);
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "fourier: out of memory for %d nodes",
                               job->quad[lv]->n);
        }
        // One thread per wavelength, in any order: each writes its wavelength's fields only
#ifdef LENSRT_OPENMP
#pragma omp parallel for schedule(dynamic, 1) num_threads(nth)
#endif
        for (w = 0; w < r->n_wl; w++) {
#ifdef LENSRT_OPENMP
            fourier_wave *fw = &fws[omp_get_thread_num()];
#else
            fourier_wave *fw = &fws[0];
#endif
            int stop;
#ifdef LENSRT_OPENMP
#pragma omp atomic read
#endif
            stop = cancelled;
            if (stop || fw->fail != LENSRT_SUCCESS) continue;
            fw->w = w;
            fw->lambda_mm = r->wavelengths[w] / LENSRT_NM_PER_MM;
            if (lensrt_fourier_prepare_nodes(fw)) {
                if (job->pilot) lensrt_fourier_pilot_slope(fw);
                else lensrt_fourier_render_tile(fw, 0, 0, r->width, r->height, 0);
            }
#ifdef LENSRT_OPENMP
#pragma omp critical(lensrt_fourier_progress)
#endif
            {
                done++;
                if (progress && !cancelled) {
                    const double frac = (double)done / (r->n_wl * job->n_level), el = lensrt_seconds() - t0;
                    if (progress(frac, el * (1.0 - frac) / frac, user_data)) cancelled = 1;
                }
            }
        }
        for (t = 0; t < nth; t++) {
            if (res == LENSRT_SUCCESS && fws[t].fail != LENSRT_SUCCESS)
                res = lensrt_fail(r->ctx, fws[t].fail, "%s", fws[t].why);
            if (fws[t].slope > job->slope) job->slope = fws[t].slope;
            free_wave(r->ctx, &fws[t]);
        }
        if (res == LENSRT_SUCCESS && cancelled) res = lensrt_fail(r->ctx, LENSRT_ERROR_CANCELLED, "fourier: cancelled");
    }
    return res;
}

lensrt_result lensrt_cpu_fourier_tile(lensrt_render r, lensrt_fourier_job *job, int x0, int y0, int width, int height,
                                      char *why, size_t n_why)
{
    fourier_wave fw;
    lensrt_result res = LENSRT_SUCCESS;
    int lv, w;
    // Every level and wavelength on this thread: the window's tiles that meet the
    // rectangle, as lensrt_cpu_fourier makes them (the same steps, so the same bits)
    for (lv = 0; lv < job->n_level && res == LENSRT_SUCCESS; lv++) {
        if (!alloc_wave(r, job->quad[lv], job->tol[lv], &fw)) {
            free_wave(r->ctx, &fw);
            snprintf(why, n_why, "out of memory for the Fourier integrator's %d nodes", job->quad[lv]->n);
            return LENSRT_ERROR_OUT_OF_MEMORY;
        }
        fw.U = job->U[lv];
        fw.rect[0] = x0;
        fw.rect[1] = y0;
        fw.rect[2] = width;
        fw.rect[3] = height;
        for (w = 0; w < r->n_wl && fw.fail == LENSRT_SUCCESS; w++) {
            fw.w = w;
            fw.lambda_mm = r->wavelengths[w] / LENSRT_NM_PER_MM;
            if (lensrt_fourier_prepare_nodes(&fw)) lensrt_fourier_render_tile(&fw, 0, 0, r->width, r->height, 0);
        }
        if (fw.fail != LENSRT_SUCCESS) {
            res = fw.fail;
            snprintf(why, n_why, "%s", fw.why);
        }
        free_wave(r->ctx, &fw);
    }
    return res;
}
