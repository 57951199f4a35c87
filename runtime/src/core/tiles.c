/* Host-scheduled tiles: a render's next samples, one rectangle of the window per call, on
 * threads the caller schedules.
 *
 * A pixel's sums depend only on the pixel and the samples (each pass adds the pixel's
 * block sums once, in block order), never on which group, thread or call splats it, so
 * tiles that cover every pixel once give run()'s sums bit for bit. The session keeps:
 * the sample range (fixed at begin), a coverage count per pixel (each tile claims its
 * pixels with atomic increments before it splats, so two tiles never write one pixel),
 * a copy of the sums (put back when the session fails), the set-up statistics (integer
 * counts, added atomically), the first failure (claimed atomically, reported by end
 * on the caller's thread: tiles never write the context's last error) and the samples
 * the tiles share (one slot per pass and wavelength, prepared once by the tiles that
 * reach it first and read by all: samples are pure functions of seed, wavelength and
 * index, so the shared data has the bits each tile would have made). */
#include "tiles.h"

#include "../c_numbers.h"
#include "cells.h"
#include "fourier.h"
#include "atomic.h"
#include "device.h"

#include <stdarg.h>
#include <math.h>
#include <string.h>

lensrt_result lensrt_tiles_fail(lensrt_render r, lensrt_result result, const char *fmt, ...)
{
    lensrt_tiles *t = r->tiles;
    va_list args;
    if (!t || !lensrt_atomic_claim(&t->failed)) return result;
    t->failure = result;
    va_start(args, fmt);
    lensrt_vsnprintf_c(t->message, sizeof t->message, fmt, args);
    va_end(args);
    return result;
}

void *lensrt_tiles_shared(lensrt_render r, uint64_t slot, size_t bytes, int n_chunks,
                          lensrt_tiles_prepare_fn prepare, const void *job)
{
    lensrt_tiles *t = r->tiles;
    lensrt_tiles_slot *s;
    int32_t state, c;
    if (slot >= t->n_slots) return NULL;
    s = &t->slots[slot];
    // Ready (every tile after the first few): the data, seen through done's acquire
    state = lensrt_atomic_load_acquire(&s->state);
    if (state == LENSRT_SLOT_OPEN && lensrt_atomic_load_acquire(&s->done) == n_chunks) return s->data;
    // The first tile here takes the slot's share of the cap and allocates its data, then
    // opens it (the release publishes the pointer); over the cap or out of memory, the
    // slot stays private to every tile
    if (state == LENSRT_SLOT_EMPTY) {
        if (lensrt_atomic_cas_i32(&s->state, LENSRT_SLOT_EMPTY, LENSRT_SLOT_CLAIMED)) {
            if (lensrt_atomic_add_fetch_u64(&t->shared_bytes, bytes) > LENSRT_TILES_SHARED_BYTES ||
                !(s->data = lensrt_alloc(r->ctx, bytes))) {
                (void)lensrt_atomic_add_fetch_u64(&t->shared_bytes, (uint64_t)0 - bytes);
                lensrt_atomic_store_release(&s->state, LENSRT_SLOT_PRIVATE);
                return NULL;
            }
            lensrt_atomic_store_release(&s->state, LENSRT_SLOT_OPEN);
        }
        state = lensrt_atomic_load_acquire(&s->state);
    }
    // Another tile is allocating (no work in it but the allocator's): wait for it
    while (state == LENSRT_SLOT_CLAIMED) state = lensrt_atomic_load_acquire(&s->state);
    if (state != LENSRT_SLOT_OPEN) return NULL;
    // Prepare the chunks no tile has taken yet, then wait for those other tiles took
    // (each is being prepared, with no wait inside, so the wait is one chunk at most)
    while (lensrt_atomic_load_acquire(&s->next) < n_chunks && (c = lensrt_atomic_add_i32(&s->next, 1)) < n_chunks) {
        prepare(r, s->data, c, job);
        (void)lensrt_atomic_add_i32(&s->done, 1);
    }
    while (lensrt_atomic_load_acquire(&s->done) < n_chunks) continue;
    return s->data;
}

void lensrt_tiles_add_stats(lensrt_render r, uint64_t terms, uint64_t clip, uint64_t tau, uint64_t dark)
{
    lensrt_tiles *t = r->tiles;
    lensrt_atomic_add_u64(&t->terms, terms);
    lensrt_atomic_add_u64(&t->clip, clip);
    lensrt_atomic_add_u64(&t->tau, tau);
    lensrt_atomic_add_u64(&t->dark, dark);
}

lensrt_result lensrt_tiles_idle(lensrt_render r, const char *what)
{
    if (!r->tiles) return LENSRT_SUCCESS;
    return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                       "%s: a tile session is open (lensrt_render_tiles_begin without lensrt_render_tiles_end)", what);
}

void lensrt_tiles_free(lensrt_render r)
{
    lensrt_tiles *t = r->tiles;
    size_t k;
    if (!t) return;
    for (k = 0; t->slots && k < t->n_slots; k++) lensrt_free(r->ctx, t->slots[k].data);
    lensrt_free(r->ctx, t->slots);
    lensrt_free(r->ctx, t->cover);
    lensrt_free(r->ctx, t->sum0);
    lensrt_free(r->ctx, t->sumsq0);
    lensrt_free(r->ctx, t->tail_sum);
    lensrt_free(r->ctx, t->tail_sumsq);
    if (t->job) {
        int j;
        for (j = 0; j < t->job->n_mesh; j++) {
            if (t->job->mesh[j]) lensrt_mesh_free(r->ctx, (lensrt_mesh *)t->job->mesh[j]);
            lensrt_free(r->ctx, (void *)t->job->mesh[j]);
            lensrt_free(r->ctx, t->job->U[j]);
        }
        lensrt_free(r->ctx, t->job);
    }
    if (t->fjob) {
        int j;
        for (j = 0; j < LENSRT_FOURIER_MAX_LEVELS; j++) {
            if (t->fquad) lensrt_quadrature_free(r->ctx, &t->fquad[j]);
            lensrt_free(r->ctx, t->fjob->U[j]);
        }
        lensrt_free(r->ctx, t->fquad);
        lensrt_free(r->ctx, t->fjob);
    }
    lensrt_free(r->ctx, t);
    r->tiles = NULL;
}

static size_t n_sums(const lensrt_render r)
{
    return (size_t)r->n_lights * (size_t)r->n_wl * (size_t)r->width * (size_t)r->height;
}

lensrt_result lensrt_render_tiles_begin(lensrt_render r, uint64_t samples_per_wavelength)
{
    const size_t npix = r ? (size_t)r->width * (size_t)r->height : 0, ns = r ? n_sums(r) : 0;
    uint64_t n_slots;
    lensrt_tiles *t;
    lensrt_result res;
    if (!r) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_tiles_idle(r, "tiles_begin")) != LENSRT_SUCCESS || (res = lensrt_cells_idle(r, "tiles_begin")) != LENSRT_SUCCESS)
        return res;
    if (!r->device->tile)
        return lensrt_fail(r->ctx, LENSRT_ERROR_UNSUPPORTED,
                           "tiles_begin: the %s device renders whole passes only; host-scheduled tiles need device "
                           "cpu (or use lensrt_render_run)", r->device->name);
    if (samples_per_wavelength == 0 || samples_per_wavelength > ((uint64_t)1 << 40))
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "tiles_begin: samples per wavelength must be 1..2^40, got %llu",
                           (unsigned long long)samples_per_wavelength);
    t = lensrt_calloc(r->ctx, 1, sizeof *t);
    if (!t) return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "tiles_begin: out of memory");
    r->tiles = t;
    t->first = r->samples;
    t->count = samples_per_wavelength;
    t->t0 = lensrt_seconds();
    // After a run that ended inside a block, that block is drawn again from its start, as
    // run() does (lensrt_tail_rewind; here the render changes only at tiles_end)
    if (r->tail_samples && r->tail_samples == r->samples && r->tail_sum) {
        t->redo = r->samples - r->tail_first;
        t->first = r->tail_first;
        t->count += t->redo;
    }
    // The shared samples' slots (empty: the tiles fill them), coverage counts, and the
    // sums as they are (put back if the session fails)
    n_slots = (t->count + LENSRT_PASS - 1) / LENSRT_PASS * (uint64_t)r->n_wl;
    t->n_slots = n_slots < LENSRT_TILES_SLOTS ? (size_t)n_slots : LENSRT_TILES_SLOTS;
    t->slots = lensrt_calloc(r->ctx, t->n_slots, sizeof *t->slots);
    t->cover = lensrt_calloc(r->ctx, npix, sizeof *t->cover);
    t->sum0 = lensrt_alloc(r->ctx, ns * 2 * sizeof(double));
    if (r->sumsq) t->sumsq0 = lensrt_alloc(r->ctx, ns * sizeof(double));
    if (t->count % LENSRT_BLOCK) {
        t->tail_sum = lensrt_alloc(r->ctx, ns * 2 * sizeof(double));
        if (r->sumsq) t->tail_sumsq = lensrt_alloc(r->ctx, ns * sizeof(double));
    }
    if (!t->slots || !t->cover || !t->sum0 || (r->sumsq && !t->sumsq0) ||
        (t->count % LENSRT_BLOCK && (!t->tail_sum || (r->sumsq && !t->tail_sumsq)))) {
        lensrt_tiles_free(r);
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY,
                           "tiles_begin: out of memory for a copy of %zu phasor sums and %zu pixels' coverage", ns, npix);
    }
    memcpy(t->sum0, r->sum, ns * 2 * sizeof(double));
    if (r->sumsq) memcpy(t->sumsq0, r->sumsq, ns * sizeof(double));
    if (t->redo) {
        memcpy(r->sum, r->tail_sum, ns * 2 * sizeof(double));
        if (r->sumsq) memcpy(r->sumsq, r->tail_sumsq, ns * sizeof(double));
    }
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_render_tiles_begin_cells(lensrt_render r, int32_t rings, int32_t estimate)
{
    const size_t npix = r ? (size_t)r->width * (size_t)r->height : 0, ns = r ? n_sums(r) : 0;
    lensrt_tiles *t;
    lensrt_cells_job *job;
    lensrt_result res;
    int levels[LENSRT_CELLS_MAX_MESHES], n = 1, k;
    if (!r) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_tiles_idle(r, "tiles_begin_cells")) != LENSRT_SUCCESS ||
        (res = lensrt_cells_check(r, "tiles_begin_cells", rings, estimate != 0)) != LENSRT_SUCCESS)
        return res;
    if (!r->device->integrate_tile)
        return lensrt_fail(r->ctx, LENSRT_ERROR_UNSUPPORTED,
                           "tiles_begin_cells: the %s device has no host-scheduled cells tiles: render with device cpu",
                           r->device->name);
    // The meshes of lensrt_render_integrate on a fresh render: rings, and with the
    // estimate rings / 2 and rings / 4
    levels[0] = rings;
    if (estimate) {
        levels[n++] = rings / 2;
        if (rings / 4 >= 1) levels[n++] = rings / 4;
    }
    t = lensrt_calloc(r->ctx, 1, sizeof *t);
    job = lensrt_calloc(r->ctx, 1, sizeof *job);
    if (!t || !job) {
        lensrt_free(r->ctx, t);
        lensrt_free(r->ctx, job);
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "tiles_begin_cells: out of memory");
    }
    r->tiles = t;
    t->job = job;
    t->cells_rings = rings;
    t->cells_estimate = estimate != 0;
    t->t0 = lensrt_seconds();
    t->cover = lensrt_calloc(r->ctx, npix, sizeof *t->cover);
    res = t->cover ? LENSRT_SUCCESS : lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "tiles_begin_cells: out of memory");
    for (k = 0; k < n && res == LENSRT_SUCCESS; k++) {
        lensrt_mesh *m = lensrt_calloc(r->ctx, 1, sizeof *m);
        job->mesh[k] = m;
        job->U[k] = lensrt_calloc(r->ctx, ns * 2, sizeof(double));
        job->n_mesh = k + 1;
        if (!m || !job->U[k]) res = lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "tiles_begin_cells: out of memory");
        else res = lensrt_mesh_build(r->ctx, &r->desc.aperture, r->stop_radius, levels[k], m);
    }
    if (res != LENSRT_SUCCESS) lensrt_tiles_free(r);
    return res;
}

lensrt_result lensrt_render_tiles_begin_fourier(lensrt_render r, int32_t nodes, int32_t estimate)
{
    const size_t npix = r ? (size_t)r->width * (size_t)r->height : 0, ns = r ? n_sums(r) : 0;
    lensrt_tiles *t;
    lensrt_fourier_job *job;
    lensrt_result res;
    int k, fine;
    if (!r) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = lensrt_tiles_idle(r, "tiles_begin_fourier")) != LENSRT_SUCCESS ||
        (res = lensrt_fourier_check(r, "tiles_begin_fourier", nodes, estimate != 0)) != LENSRT_SUCCESS)
        return res;
    if (!r->device->fourier_tile)
        return lensrt_fail(r->ctx, LENSRT_ERROR_UNSUPPORTED,
                           "tiles_begin_fourier: the %s device has no host-scheduled Fourier tiles: render with device "
                           "cpu",
                           r->device->name);
    // The rules of lensrt_render_integrate_fourier on a fresh render: nodes (chosen as it
    // chooses them), and with the estimate the finer one
    if (nodes == 0 && (res = lensrt_fourier_auto_nodes(r, 0.0, &nodes)) != LENSRT_SUCCESS) return res;
    fine = (int)ceil(LENSRT_FOURIER_FINER * nodes);
    t = lensrt_calloc(r->ctx, 1, sizeof *t);
    job = lensrt_calloc(r->ctx, 1, sizeof *job);
    if (!t || !job) {
        lensrt_free(r->ctx, t);
        lensrt_free(r->ctx, job);
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "tiles_begin_fourier: out of memory");
    }
    r->tiles = t;
    t->fjob = job;
    t->fourier_nodes = nodes;
    t->cells_estimate = estimate != 0;
    t->t0 = lensrt_seconds();
    t->cover = lensrt_calloc(r->ctx, npix, sizeof *t->cover);
    t->fquad = lensrt_calloc(r->ctx, LENSRT_FOURIER_MAX_LEVELS, sizeof *t->fquad);
    res = t->cover && t->fquad ? LENSRT_SUCCESS
                               : lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "tiles_begin_fourier: out of memory");
    job->n_level = estimate ? 2 : 1;
    for (k = 0; k < job->n_level && res == LENSRT_SUCCESS; k++) {
        job->tol[k] = k == 0 ? LENSRT_FOURIER_TOL : 0.1 * LENSRT_FOURIER_TOL;
        job->quad[k] = &t->fquad[k];
        job->U[k] = lensrt_calloc(r->ctx, ns * 2, sizeof(double));
        if (!job->U[k]) res = lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "tiles_begin_fourier: out of memory");
        else res = lensrt_quadrature_build(r->ctx, &r->desc.aperture, r->stop_radius, k ? fine : nodes, &t->fquad[k]);
    }
    if (res != LENSRT_SUCCESS) lensrt_tiles_free(r);
    return res;
}

lensrt_result lensrt_render_tile(lensrt_render r, int x0, int y0, int width, int height)
{
    lensrt_tiles *t = r ? r->tiles : NULL;
    int x, y, twice = 0, tx = 0, ty = 0, pw, ph, px0, py0;
    if (!t) return LENSRT_ERROR_INVALID_ARGUMENT; /* no session: nowhere to record why */
    if (x0 < 0 || y0 < 0 || width <= 0 || height <= 0 || x0 > r->out_width - width || y0 > r->out_height - height)
        return lensrt_tiles_fail(r, LENSRT_ERROR_INVALID_ARGUMENT,
                                 "tile: pixels %lld .. %lld of rows %lld .. %lld (%d x %d at (%d, %d)) are not inside the %d x %d "
                                 "window", /* in 64 bits: x0 + width overflows int near INT_MAX */
                                 (long long)x0, (long long)x0 + width - 1, (long long)y0, (long long)y0 + height - 1, width,
                                 height, x0, y0, r->out_width, r->out_height);
    // The image's pixels are sx x sy points of the render's grid each (core/render.h):
    // the tile is its pixels' points, and messages below name image pixels
    pw = width;
    ph = height;
    px0 = x0;
    py0 = y0;
    {
        x0 = px0 * r->sx;
        y0 = py0 * r->sy;
        width = pw * r->sx;
        height = ph * r->sy;
        for (y = y0; y < y0 + height; y++)
            for (x = x0; x < x0 + width; x++)
                if (lensrt_atomic_add_u32(&t->cover[(size_t)y * (size_t)r->width + (size_t)x], 1) != 0 && !twice) {
                    twice = 1;
                    tx = x / r->sx;
                    ty = y / r->sy;
                }
        if (twice)
            return lensrt_tiles_fail(r, LENSRT_ERROR_INVALID_ARGUMENT,
                                     "tile %d x %d at (%d, %d): pixel (%d, %d) was already covered by another tile",
                                     pw, ph, px0, py0, tx, ty);
    }
    if (t->cells_rings) {
        // A cells session: the tile's pixels on every mesh, into the session's fields
        lensrt_result res = r->device->integrate_tile(r, t->job, x0, y0, width, height);
        if (res != LENSRT_SUCCESS)
            return lensrt_tiles_fail(r, res, "tile %d x %d at (%d, %d): out of memory for the cells integrator's scratch",
                                     pw, ph, px0, py0);
        return LENSRT_SUCCESS;
    }
    if (t->fourier_nodes) {
        // A Fourier session: the window's tiles that meet this one, its pixels written
        char why[LENSRT_ERROR_SIZE];
        lensrt_result res = r->device->fourier_tile(r, t->fjob, x0, y0, width, height, why, sizeof why);
        if (res != LENSRT_SUCCESS) return lensrt_tiles_fail(r, res, "tile %d x %d at (%d, %d): %s", pw, ph, px0, py0, why);
        return LENSRT_SUCCESS;
    }
    return r->device->tile(r, x0, y0, width, height);
}

lensrt_result lensrt_render_tiles_end(lensrt_render r)
{
    lensrt_tiles *t = r ? r->tiles : NULL;
    const size_t npix = r ? (size_t)r->width * (size_t)r->height : 0, ns = r ? n_sums(r) : 0;
    lensrt_result res = LENSRT_SUCCESS;
    size_t p, pc;
    if (!r) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (!t) return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "tiles_end: no tile session (lensrt_render_tiles_begin)");
    // Every pixel exactly once (the first offender in row-major order), then the tiles'
    // own failures
    for (pc = 0; pc < npix && t->cover[pc] == 1; pc++) continue;
    // (the image pixel of grid point pc: core/render.h)
    p = pc < npix ? (pc / (size_t)r->width / (size_t)r->sy) * (size_t)r->out_width + pc % (size_t)r->width / (size_t)r->sx
                  : npix;
    if (pc < npix && t->cover[pc] == 0)
        res = lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                          "tiles_end: pixel (%d, %d) was not covered; every pixel must be covered exactly once between "
                          "tiles_begin and tiles_end (the sums are as before tiles_begin)",
                          (int)(p % (size_t)r->out_width), (int)(p / (size_t)r->out_width));
    else if (pc < npix)
        res = lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                          "tiles_end: pixel (%d, %d) was covered %u times; every pixel must be covered exactly once "
                          "between tiles_begin and tiles_end (the sums are as before tiles_begin)",
                          (int)(p % (size_t)r->out_width), (int)(p / (size_t)r->out_width), (unsigned)t->cover[pc]);
    else if (t->failed)
        res = lensrt_fail(r->ctx, t->failure, "%s (the sums are as before tiles_begin)", t->message);
    if (res != LENSRT_SUCCESS) {
        if (t->sum0) memcpy(r->sum, t->sum0, ns * 2 * sizeof(double));
        if (r->sumsq && t->sumsq0) memcpy(r->sumsq, t->sumsq0, ns * sizeof(double));
        lensrt_tiles_free(r);
        return res;
    }
    if (t->cells_rings) {
        // A cells session: the fields become the sums as lensrt_render_integrate's do
        lensrt_cells_job *job = t->job;
        double est;
        res = lensrt_cells_finish(r, t->cells_rings, job->U[0], job->n_mesh > 1 ? job->U[1] : NULL,
                                  job->n_mesh > 2 ? job->U[2] : NULL, t->cells_estimate ? &est : NULL);
        if (res == LENSRT_SUCCESS) {
            job->U[0] = NULL; /* the render's now, and the coarse field with it */
            if (job->n_mesh > 1) job->U[1] = NULL;
        }
        r->seconds += lensrt_seconds() - t->t0;
        lensrt_tiles_free(r);
        return res;
    }
    if (t->fourier_nodes) {
        // A Fourier session: the fields become the sums as lensrt_render_integrate_fourier's do
        lensrt_fourier_job *job = t->fjob;
        double est;
        res = lensrt_fourier_finish(r, t->fourier_nodes, job->U[0], job->n_level > 1 ? job->U[1] : NULL,
                                    job->n_level > 1 ? job->quad[1]->na : 0, t->cells_estimate ? &est : NULL);
        if (res == LENSRT_SUCCESS && job->n_level > 1) job->U[1] = NULL; /* the render's now */
        r->seconds += lensrt_seconds() - t->t0;
        lensrt_tiles_free(r);
        return res;
    }
    // Commit as run() would: samples, splats, the partial block's tail, the statistics of
    // a pass, the wall time
    r->samples = t->first + t->count;
    r->splats += (t->count - t->redo) * (uint64_t)r->n_wl * (uint64_t)npix;
    lensrt_tail_forget(r);
    if (t->count % LENSRT_BLOCK) {
        lensrt_free(r->ctx, r->tail_sum);
        lensrt_free(r->ctx, r->tail_sumsq);
        r->tail_sum = t->tail_sum;
        r->tail_sumsq = t->tail_sumsq;
        t->tail_sum = t->tail_sumsq = NULL;
        r->tail_first = r->samples - t->count % LENSRT_BLOCK;
        r->tail_samples = r->samples;
    }
    r->stat_terms = (double)t->terms;
    r->stat_clip = (double)t->clip;
    r->stat_tau = (double)t->tau;
    r->stat_dark = (double)t->dark;
    r->stat_count = (double)npix * r->n_wl;
    r->seconds += lensrt_seconds() - t->t0;
    lensrt_tiles_free(r);
    return LENSRT_SUCCESS;
}
