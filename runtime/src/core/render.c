/* Renders: create, run, splat_points and the results, the same for every lens kind and
 * device.
 *
 * lensrt_render_create checks the scene (core/scene.c), lets the lens kind prepare what
 * is computed once (lens/lens.h: P_o per light and P_s per wavelength specialised, the
 * window's bases) and makes the device's state (core/device.h). For every pass and
 * wavelength, run() draws the aperture samples (core/sampler.c: pure functions of seed,
 * wavelength and index) and the device splats them: the CPU device (cpu/) evaluates P_o
 * per sample, specialises P_s per pixel and streams the samples through the SIMD kernel;
 * the GL device (gl/) does the same in compute shaders. Pixels never share sums and
 * samples are pure functions of their index, so the result does not depend on the
 * number of threads. Elsewhere: the deterministic integrals (core/render_integrate.c,
 * and what they share with tiles: core/integral.c), host-scheduled tiles (core/tiles.c)
 * and the stop's shape (core/stop_shape.c). */
#include "render.h"
#include "cells.h"
#include "fourier.h"

#include "../lens/lens.h"
#include "device.h"
#include "scene.h"
#include "tiles.h"

#include <math.h>
#include <string.h>

#define PASS LENSRT_PASS
#define DEFAULT_WAVELENGTHS 16

/* --------------------------------------------------------------- create ----- */

/* An array of n per-pixel polynomials (P_s's or P_clip's), and what each holds. */
static void free_pixel_polys(lensrt_context ctx, lensrt_pixel_poly *polys, int n)
{
    int i;
    if (polys)
        for (i = 0; i < n; i++) {
            lensrt_free(ctx, polys[i].ix);
            lensrt_free(ctx, polys[i].iy);
            lensrt_free(ctx, polys[i].slot);
            lensrt_free(ctx, polys[i].coef);
        }
    lensrt_free(ctx, polys);
}

/* What the lens kind's prepare allocated, freed and forgotten (so that it can prepare
 * again, for another grid). */
static void free_prepared(lensrt_render r)
{
    lensrt_context ctx = r->ctx;
    free_pixel_polys(ctx, r->ps, r->n_wl * 4);
    free_pixel_polys(ctx, r->ps_grad, r->n_wl);
    lensrt_free(ctx, r->po);
    free_pixel_polys(ctx, r->clip_s, r->n_wl * 2 * r->n_clip_pairs);
    lensrt_free(ctx, r->clip_o);
    lensrt_free(ctx, r->basis);
    lensrt_free(ctx, r->basis_rank);
    lensrt_free(ctx, r->basis_t);
    lensrt_free(ctx, r->basis_l1);
    r->ps = r->ps_grad = r->clip_s = NULL;
    r->po = r->clip_o = r->basis = r->basis_t = r->basis_l1 = NULL;
    r->basis_rank = NULL;
}

static void free_render(lensrt_render r)
{
    lensrt_context ctx = r->ctx;
    lensrt_tiles_free(r);
    if (r->device) r->device->destroy(r);
    free_prepared(r);
    lensrt_free(ctx, r->lights);
    lensrt_free(ctx, r->wavelengths);
    lensrt_free(ctx, r->xs);
    lensrt_free(ctx, r->ys);
    lensrt_free(ctx, r->light_x);
    lensrt_free(ctx, r->light_y);
    lensrt_free(ctx, r->light_d);
    lensrt_free(ctx, r->sum);
    lensrt_free(ctx, r->sumsq);
    lensrt_free(ctx, r->tail_sum);
    lensrt_free(ctx, r->tail_sumsq);
    lensrt_free(ctx, r->cells_field);
    lensrt_free(ctx, r->cells_coarse);
    lensrt_free(ctx, r->fourier_fine);
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
    if ((res = lensrt_scene_check_desc(ctx, desc, &info)) != LENSRT_SUCCESS) return res;
    r = lensrt_calloc(ctx, 1, sizeof *r);
    if (!r) return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
    r->ctx = ctx;
    r->lens = desc->lens;
    r->lens_ops = lensrt_lens_ops_of(desc->lens);
    r->desc = *desc;
    if (r->desc.sampler == LENSRT_SAMPLER_DEFAULT)
        r->desc.sampler = r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED ? LENSRT_SAMPLER_RANDOM : LENSRT_SAMPLER_SOBOL;
    if (r->desc.phase_tolerance_waves == 0) r->desc.phase_tolerance_waves = 3e-3;
    // Copy the lights (default: one on the axis at infinity) and wavelengths
    r->n_lights = desc->n_lights > 0 ? desc->n_lights : 1;
    r->n_wl = desc->n_wavelengths > 0 ? desc->n_wavelengths : DEFAULT_WAVELENGTHS;
    r->out_width = r->width = desc->sensor.width;
    r->out_height = r->height = desc->sensor.height;
    r->pixel_filter = desc->pixel_filter;
    r->sx = r->sy = 1;
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
            double lo, hi;
            r->lens_ops->wavelength_range(r->lens, &lo, &hi);
            r->wavelengths[i] = lo + (hi - lo) * (i + 0.5) / r->n_wl;
        }
    }
    r->desc.lights = r->lights;
    r->desc.n_lights = r->n_lights;
    r->desc.wavelengths_nm = r->wavelengths;
    r->desc.n_wavelengths = r->n_wl;
    // The scene (pixel centres, lights, stop, sampled region), then what the lens kind
    // computes once per render
    if ((res = lensrt_scene_place(r, &info)) != LENSRT_SUCCESS || (res = r->lens_ops->prepare(r)) != LENSRT_SUCCESS)
        goto fail;
    // The box filter's sub-pixel points (from what was prepared for the pixel centres);
    // with more than one per pixel the grid becomes theirs, and the lens kind prepares
    // for it again (its bases span the grid's points)
    {
        int sx, sy;
        if ((res = lensrt_pixel_samples_choose(r, &sx, &sy)) != LENSRT_SUCCESS) goto fail;
        if (sx * sy > 1) {
            free_prepared(r);
            lensrt_free(ctx, r->xs);
            lensrt_free(ctx, r->ys);
            r->xs = lensrt_calloc(ctx, (size_t)r->out_width * (size_t)sx, sizeof(double));
            r->ys = lensrt_calloc(ctx, (size_t)r->out_height * (size_t)sy, sizeof(double));
            if (!r->xs || !r->ys) {
                res = lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
                goto fail;
            }
            r->sx = sx;
            r->sy = sy;
            lensrt_scene_grid(r);
            if ((res = r->lens_ops->check_window(r, &info)) != LENSRT_SUCCESS ||
                (res = r->lens_ops->prepare(r)) != LENSRT_SUCCESS)
                goto fail;
        }
    }
    // Phasor sums, and sums of squares for the unbiased estimator
    npix = (size_t)r->width * (size_t)r->height;
    nsum = (size_t)r->n_lights * (size_t)r->n_wl * npix;
    r->sum = lensrt_calloc(ctx, nsum * 2, sizeof(double));
    if (r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED) r->sumsq = lensrt_calloc(ctx, nsum, sizeof(double));
    if (!r->sum || (r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED && !r->sumsq)) {
        res = lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY,
                          "render: out of memory for %zu phasor sums (%d x %d pixels of %d x %d sub-pixel points "
                          "(the box filter), %d wavelengths, %d lights); fewer pixel_samples or the point filter "
                          "need fewer", nsum, r->out_width, r->out_height, r->sx, r->sy, r->n_wl, r->n_lights);
        goto fail;
    }
    // The device's state (core/device.c lists the devices of this build; the CPU is
    // always there, so a missing one is the GL device)
    if (!(r->device = lensrt_device_find(r->desc.device))) {
        res = lensrt_fail(ctx, LENSRT_ERROR_UNSUPPORTED, "device gl: this build of lensrt has no GL path");
        goto fail;
    }
    if ((res = r->device->create(r)) != LENSRT_SUCCESS) goto fail;
    lensrt_log(ctx, LENSRT_LOG_INFO,
               "render: %s, %d x %d pixels (%s filter, %d x %d points per pixel), %d wavelengths, %d lights, stop "
               "%.4g mm (f/%.3g), %s sampling",
               info.name, r->out_width, r->out_height, r->pixel_filter == LENSRT_PIXEL_FILTER_POINT ? "point" : "box",
               r->sx, r->sy, r->n_wl, r->n_lights, r->stop_radius, r->f_number, lensrt_sampler_name(r->desc.sampler));
    *out = r;
    return LENSRT_SUCCESS;
fail:
    free_render(r);
    return res;
}

/* ------------------------------------------------------------- the passes ----- */

/* Passes run between the device's begin and end; the host draws each pass's sample
 * positions into xy (2 LENSRT_PASS values, zeros after the pass's samples). */
static lensrt_result begin_passes(lensrt_render r, double **xy)
{
    lensrt_result res;
    *xy = lensrt_calloc(r->ctx, (size_t)PASS * 2 + 2, sizeof(double));
    if (!*xy) return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
    if ((res = r->device->begin(r)) != LENSRT_SUCCESS) lensrt_free(r->ctx, *xy);
    return res;
}

static lensrt_result end_passes(lensrt_render r, double *xy, lensrt_result status)
{
    status = r->device->end(r, status);
    lensrt_free(r->ctx, xy);
    return status;
}

/* Progress of one run() call over its segments (below). */
typedef struct run_state {
    uint64_t done, total, redo; /* samples drawn by this call, to draw in all, drawn again */
    double t0;
    lensrt_progress_fn progress;
    void *user_data;
} run_state;

/* `count` more samples from r->samples on, in passes between the device's begin and end
 * (which bring the sums to the device and back). */
static lensrt_result run_passes(lensrt_render r, uint64_t count, run_state *rs)
{
    uint64_t done = 0;
    double *xy;
    lensrt_result res;
    if ((res = begin_passes(r, &xy)) != LENSRT_SUCCESS) return res;
    while (done < count && res == LENSRT_SUCCESS) {
        uint64_t n = count - done < PASS ? count - done : PASS;
        int w, cancelled = 0;
        double elapsed, frac;
        // One pass: the same sample indices for every wavelength (each its own sequence)
        for (w = 0; w < r->n_wl && res == LENSRT_SUCCESS; w++) {
            memset(xy, 0, sizeof(double) * PASS * 2);
            lensrt_sample_aperture(r->desc.sampler, r->desc.seed, w, r->samples, n, &r->region, xy);
            res = r->device->pass(r, w, xy, (int)n);
            elapsed = lensrt_seconds() - rs->t0;
            frac = ((double)rs->done + (double)n * (w + 1) / r->n_wl) / (double)rs->total;
            // A request to stop takes effect when the pass is complete (every wavelength
            // must hold the same samples)
            if (rs->progress && w + 1 < r->n_wl && rs->progress(frac, elapsed * (1.0 - frac) / frac, rs->user_data))
                cancelled = 1;
        }
        if (res != LENSRT_SUCCESS) break;
        r->samples += n;
        done += n;
        rs->done += n;
        r->splats += n * (uint64_t)r->n_wl * (uint64_t)r->width * (uint64_t)r->height;
        elapsed = lensrt_seconds() - rs->t0;
        if (rs->progress && (rs->progress((double)rs->done / (double)rs->total,
                                          elapsed * (double)(rs->total - rs->done) / (double)rs->done, rs->user_data) ||
                             cancelled))
            res = lensrt_fail(r->ctx, LENSRT_ERROR_CANCELLED, "run: cancelled after %llu samples per wavelength",
                              (unsigned long long)(rs->done > rs->redo ? rs->done - rs->redo : 0));
    }
    return end_passes(r, xy, res);
}

/* The sums into the tail's copy (allocated when first needed); 0 when out of memory. */
static int tail_copy(lensrt_render r)
{
    const size_t nsum = lensrt_sums_count(r);
    if (!r->tail_sum && !(r->tail_sum = lensrt_alloc(r->ctx, nsum * sizeof(double)))) return 0;
    if (r->sumsq && !r->tail_sumsq && !(r->tail_sumsq = lensrt_alloc(r->ctx, nsum / 2 * sizeof(double)))) return 0;
    memcpy(r->tail_sum, r->sum, nsum * sizeof(double));
    if (r->sumsq) memcpy(r->tail_sumsq, r->sumsq, nsum / 2 * sizeof(double));
    return 1;
}

/* The sums and the tail's copy exchanged (buffers of the same sizes). */
static void swap_sums(lensrt_render r)
{
    double *t = r->sum;
    r->sum = r->tail_sum;
    r->tail_sum = t;
    if (r->sumsq) {
        t = r->sumsq;
        r->sumsq = r->tail_sumsq;
        r->tail_sumsq = t;
    }
}

uint64_t lensrt_tail_rewind(lensrt_render r)
{
    uint64_t redo;
    if (!r->tail_samples || r->tail_samples != r->samples || !r->tail_sum) {
        lensrt_tail_forget(r);
        return 0;
    }
    // The sums before the partial block (swapped in: the sums as they were are kept in
    // the tail's buffers, for a run that fails before its first pass), and its samples
    // to draw again
    swap_sums(r);
    redo = r->samples - r->tail_first;
    r->samples = r->tail_first;
    r->splats -= redo * (uint64_t)r->n_wl * (uint64_t)r->width * (uint64_t)r->height;
    lensrt_tail_forget(r);
    return redo;
}

/* Blocks are counted from the first sample of a run (after the rewind above: from a
 * block's start); the samples of a run's last block are added together, whatever the
 * calls. Two segments: the whole blocks, then (when the run ends inside a block) the
 * sums are kept as they are and the partial block added; the next run puts them back
 * and draws that block again, whole or with more of it (lensrt.h's promise). */
lensrt_result lensrt_render_run(lensrt_render r, uint64_t samples_per_wavelength, lensrt_progress_fn progress, void *user_data)
{
    run_state rs;
    uint64_t whole, part;
    lensrt_result res = LENSRT_SUCCESS;
    if (!r) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (samples_per_wavelength == 0 || samples_per_wavelength > ((uint64_t)1 << 40))
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "run: samples per wavelength must be 1..2^40, got %llu", (unsigned long long)samples_per_wavelength);
    if ((res = lensrt_tiles_idle(r, "run")) != LENSRT_SUCCESS || (res = lensrt_cells_idle(r, "run")) != LENSRT_SUCCESS)
        return res;
    rs.t0 = lensrt_seconds();
    rs.progress = progress;
    rs.user_data = user_data;
    rs.done = 0;
    rs.redo = lensrt_tail_rewind(r);
    rs.total = samples_per_wavelength + rs.redo;
    part = rs.total % LENSRT_BLOCK;
    whole = rs.total - part;
    if (whole) res = run_passes(r, whole, &rs);
    if (res == LENSRT_SUCCESS && part) {
        const uint64_t first = r->samples;
        if (!tail_copy(r))
            res = lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY,
                              "run: out of memory for a copy of the sums (a run that ends inside a block of %d samples)",
                              LENSRT_BLOCK);
        else if ((res = run_passes(r, part, &rs)) == LENSRT_SUCCESS) {
            r->tail_first = first;
            r->tail_samples = r->samples;
        }
    }
    if (res != LENSRT_SUCCESS && rs.redo && rs.done == 0) {
        // Failed before its first pass (memory, a device): the sums, samples and tail as
        // they were
        const uint64_t redo = rs.redo;
        swap_sums(r);
        r->samples += redo;
        r->splats += redo * (uint64_t)r->n_wl * (uint64_t)r->width * (uint64_t)r->height;
        r->tail_samples = r->samples;
    } else if (res != LENSRT_SUCCESS) {
        // No tail to keep (the copy, if made, is not the sums' past)
        lensrt_free(r->ctx, r->tail_sum);
        lensrt_free(r->ctx, r->tail_sumsq);
        r->tail_sum = r->tail_sumsq = NULL;
    }
    r->seconds += lensrt_seconds() - rs.t0;
    return res;
}

/* A point outside the aperture contributes nothing (its amplitude is 0), but the devices
 * still evaluate the lens there, and far away its monomials reach inf: 0 * inf is NaN in
 * every pixel. Such points are moved to one fixed point outside the sampled region and
 * the polynomials' reach (twice mono_radius, monomials at most 2^15), where the lens is
 * finite and the aperture test still says outside. Points that are not finite are refused. */
static lensrt_result outside_to_edge(lensrt_render r, double *xy, size_t n, size_t first)
{
    const double edge = 2.0 * r->mono_radius;
    size_t j;
    for (j = 0; j < n; j++) {
        if (!isfinite(xy[2 * j]) || !isfinite(xy[2 * j + 1]))
            return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "splat_points: point %zu (%g, %g) mm is not finite",
                               first + j, xy[2 * j], xy[2 * j + 1]);
        if (!lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, xy[2 * j], xy[2 * j + 1])) {
            xy[2 * j] = edge;
            xy[2 * j + 1] = 0.0;
        }
    }
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_render_splat_points(lensrt_render r, int wavelength, const double *xy_mm, size_t n_points)
{
    double t0 = lensrt_seconds();
    double *xy;
    lensrt_result res;
    size_t done = 0;
    if (!r || !xy_mm) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (wavelength < 0 || wavelength >= r->n_wl || n_points == 0)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "splat_points: wavelength index %d of %d, %zu points",
                           wavelength, r->n_wl, n_points);
    if (r->n_wl != 1)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "splat_points: needs a render with one wavelength (sample counts are shared), it has %d", r->n_wl);
    if ((res = lensrt_tiles_idle(r, "splat_points")) != LENSRT_SUCCESS ||
        (res = lensrt_cells_idle(r, "splat_points")) != LENSRT_SUCCESS || (res = begin_passes(r, &xy)) != LENSRT_SUCCESS)
        return res;
    lensrt_tail_forget(r);
    while (done < n_points && res == LENSRT_SUCCESS) {
        size_t n = n_points - done < PASS ? n_points - done : PASS;
        memset(xy, 0, sizeof(double) * PASS * 2);
        memcpy(xy, xy_mm + 2 * done, sizeof(double) * 2 * n);
        if ((res = outside_to_edge(r, xy, n, done)) != LENSRT_SUCCESS) break;
        res = r->device->pass(r, wavelength, xy, (int)n);
        if (res == LENSRT_SUCCESS) {
            done += n;
            r->samples += n;
            r->splats += (uint64_t)n * (uint64_t)r->width * (uint64_t)r->height;
        }
    }
    res = end_passes(r, xy, res);
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
    out->width = r->out_width;
    out->height = r->out_height;
    out->pixel_filter = r->pixel_filter;
    out->pixel_samples_x = r->sx;
    out->pixel_samples_y = r->sy;
    out->n_wavelengths = r->n_wl;
    out->n_lights = r->n_lights;
    out->samples_per_wavelength = r->samples;
    out->splats = r->splats;
    out->seconds = r->seconds;
    out->splats_per_second = r->seconds > 0 ? (double)r->splats / r->seconds : 0.0;
    out->stop_radius_mm = r->stop_radius;
    out->f_number = r->f_number;
    out->cells_rings = r->cells_rings;
    out->cells_error_estimate = r->cells_rings || r->fourier_nodes ? r->cells_error : -1.0;
    out->fourier_nodes = r->fourier_nodes;
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
    const size_t npix = r ? (size_t)r->out_width * (size_t)r->out_height : 0;
    const size_t ngrid = r ? (size_t)r->width * (size_t)r->height : 0;
    const double n = r ? (double)r->samples : 0.0;
    const double per_pixel = r ? (double)r->sx * (double)r->sy : 1.0;
    size_t p;
    int w, l, k, m;
    lensrt_result res;
    if (!r || !out) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_tiles_idle(r, "image")) != LENSRT_SUCCESS) return res;
    if (count != npix * (size_t)r->n_wl)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "image: count must be %zu (wavelengths x pixels), got %zu",
                           npix * (size_t)r->n_wl, count);
    if (r->samples == 0 || (r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED && r->samples < 2))
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "image: no samples yet (the unbiased estimator needs 2)");
    for (w = 0; w < r->n_wl; w++)
        for (p = 0; p < npix; p++) {
            const int i = (int)(p % (size_t)r->out_width), j = (int)(p / (size_t)r->out_width);
            double total = 0.0;
            // The box filter: the mean of the intensities (never the fields) of the
            // pixel's sx x sy points; the point filter's one point is the pixel's centre
            for (m = 0; m < r->sy; m++)
                for (k = 0; k < r->sx; k++) {
                    const size_t g = lensrt_grid_point(r, i, j, k, m);
                    double point = 0.0;
                    // Lights are incoherent: add intensities, each from its own phasor sum
                    for (l = 0; l < r->n_lights; l++) {
                        size_t at = ((size_t)l * (size_t)r->n_wl + (size_t)w) * ngrid + g;
                        double re = r->sum[2 * at], im = r->sum[2 * at + 1], s2 = re * re + im * im;
                        if (r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED)
                            point += r->measure * r->measure * (s2 - r->sumsq[at]) / (n * (n - 1.0));
                        else
                            point += r->measure * r->measure * s2 / (n * n);
                    }
                    total += point;
                }
            total /= per_pixel;
            out[(size_t)w * npix + p] = (float)total;
            // Never a silent inf or NaN: name the pixel and wavelength instead
            if (!isfinite(out[(size_t)w * npix + p]))
                return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                                   "image: pixel (%d, %d) at %g nm (wavelength %d) is %g, not a finite float: the "
                                   "lights' intensities or the lens table are beyond what the sums can hold",
                                   (int)(p % (size_t)r->width), (int)(p / (size_t)r->width), r->wavelengths[w], w, total);
        }
    return LENSRT_SUCCESS;
}
