/* The CPU device's host-scheduled tile: the session's samples for one rectangle, on the
 * calling thread (no OpenMP). Passes, wavelengths and sample indices are run()'s, and a
 * pixel's sums get the same additions in the same order, so the sums match run()'s bit
 * for bit. Each pass and wavelength's samples are drawn and prepared once for all tiles
 * (core/tiles.c's shared slots, filled chunk by chunk by the tiles that reach them
 * first); when a slot is not shared (over the session's cap), the tile prepares them
 * into buffers of its own, with the same code and so the same bits. */
#include "pass.h"

#include "../core/tiles.h"

#include <string.h>

#define TILE_CHUNK_BLOCKS 2 /* blocks a tile prepares at a time: 512 samples, about 0.25 ms */

/* The samples of one slot: wavelength w's n samples from index first on. */
typedef struct tile_job {
    int w, n;
    uint64_t first;
} tile_job;

/* Draw chunk `chunk` of a job's samples (run()'s indices) and prepare it into pd. */
static void prepare_chunk(lensrt_render r, lensrt_cpu_pass *pd, const tile_job *job, int chunk)
{
    const int n_blocks = (job->n + LENSRT_BLOCK - 1) / LENSRT_BLOCK;
    const int b0 = chunk * TILE_CHUNK_BLOCKS, b1 = b0 + TILE_CHUNK_BLOCKS < n_blocks ? b0 + TILE_CHUNK_BLOCKS : n_blocks;
    const int j0 = b0 * LENSRT_BLOCK, m = job->n - j0 < (b1 - b0) * LENSRT_BLOCK ? job->n - j0 : (b1 - b0) * LENSRT_BLOCK;
    double xy[2 * TILE_CHUNK_BLOCKS * LENSRT_BLOCK];
    lensrt_sample_aperture(r->desc.sampler, r->desc.seed, job->w, job->first + (uint64_t)j0, (uint64_t)m, &r->region, xy);
    lensrt_cpu_prepare_blocks(r, job->w, xy, m, pd, b0, b1);
}

/* Blocks b0 .. b1 - 1 of a pass, as a pass of their own (the same buffers). */
static lensrt_cpu_pass blocks_of(const lensrt_render r, const lensrt_cpu_pass *pd, int b0, int b1)
{
    const size_t rows = (size_t)b0 * (size_t)r->n_rows * LENSRT_BLOCK, lanes = (size_t)b0 * (size_t)r->n_lights * LENSRT_BLOCK;
    lensrt_cpu_pass v = *pd;
    if (v.mono_f) v.mono_f += rows;
    if (v.mono_d) v.mono_d += rows;
    if (v.phase_f) v.phase_f += lanes;
    if (v.amp_f) v.amp_f += lanes;
    if (v.phase_d) v.phase_d += lanes;
    if (v.amp_d) v.amp_d += lanes;
    v.n_blocks = b1 - b0;
    v.n = (b1 - b0) * LENSRT_BLOCK < pd->n - b0 * LENSRT_BLOCK ? (b1 - b0) * LENSRT_BLOCK : pd->n - b0 * LENSRT_BLOCK;
    return v;
}

/* The sums of pixels p0 .. p1 - 1, wavelength w, into the session's tail (every light). */
static void keep_tail(lensrt_render r, const lensrt_tiles *t, int w, long p0, long p1)
{
    const size_t npix = (size_t)r->width * (size_t)r->height;
    int l;
    for (l = 0; l < r->n_lights; l++) {
        const size_t at = ((size_t)l * (size_t)r->n_wl + (size_t)w) * npix + (size_t)p0, n = (size_t)(p1 - p0);
        memcpy(t->tail_sum + 2 * at, r->sum + 2 * at, 2 * n * sizeof(double));
        if (r->sumsq) memcpy(t->tail_sumsq + at, r->sumsq + at, n * sizeof(double));
    }
}

/* lensrt_tiles_prepare_fn: a chunk into a slot's shared data. */
static void prepare_shared(lensrt_render r, void *data, int chunk, const void *job)
{
    lensrt_cpu_pass pd;
    lensrt_cpu_pass_view(r, data, ((const tile_job *)job)->n, &pd);
    prepare_chunk(r, &pd, job, chunk);
}

lensrt_result lensrt_cpu_tile(lensrt_render r, int x0, int y0, int width, int height)
{
    const lensrt_tiles *t = r->tiles;
    const int n_max = t->count < LENSRT_PASS ? (int)t->count : LENSRT_PASS;
    lensrt_cpu_stats st = {0, 0, 0, 0};
    lensrt_cpu_pass own, shared; /* own buffers (made when first needed), a view of a slot */
    int have_own = 0, w, y, c;
    uint64_t done, pass;
    memset(&own, 0, sizeof own);
    for (done = 0, pass = 0; done < t->count; done += (uint64_t)n_max, pass++) {
        const int n = t->count - done < (uint64_t)n_max ? (int)(t->count - done) : n_max;
        const int n_chunks = ((n + LENSRT_BLOCK - 1) / LENSRT_BLOCK + TILE_CHUNK_BLOCKS - 1) / TILE_CHUNK_BLOCKS;
        const int last = done + (uint64_t)n == t->count;
        // Per wavelength: run()'s samples of this pass, shared or else prepared here,
        // then the rows of the rectangle (the set-up's statistics once, from the last pass)
        for (w = 0; w < r->n_wl; w++) {
            tile_job job;
            const lensrt_cpu_pass *pd = &shared;
            void *data;
            job.w = w;
            job.n = n;
            job.first = t->first + done;
            data = lensrt_tiles_shared(r, pass * (uint64_t)r->n_wl + (uint64_t)w, lensrt_cpu_pass_view(r, NULL, n, NULL),
                                       n_chunks, prepare_shared, &job);
            if (data) {
                lensrt_cpu_pass_view(r, data, n, &shared);
            } else {
                if (!have_own && !(have_own = lensrt_cpu_alloc_pass(r, &own, n_max)))
                    return lensrt_tiles_fail(r, LENSRT_ERROR_OUT_OF_MEMORY,
                                             "tile %d x %d at (%d, %d): out of memory for a pass of %d samples", width,
                                             height, x0, y0, n_max);
                for (c = 0; c < n_chunks; c++) prepare_chunk(r, &own, &job, c);
                own.n = n;
                own.n_blocks = (n + LENSRT_BLOCK - 1) / LENSRT_BLOCK;
                pd = &own;
            }
            for (y = y0; y < y0 + height; y++) {
                long p0 = (long)y * r->width + x0;
                lensrt_cpu_stats row = {0, 0, 0, 0};
                if (last && t->count % LENSRT_BLOCK) {
                    // The session ends inside a block: its whole blocks, the sums kept
                    // (the render's tail at tiles_end, as run() keeps them), the last block
                    const lensrt_cpu_pass whole = blocks_of(r, pd, 0, pd->n_blocks - 1);
                    const lensrt_cpu_pass part = blocks_of(r, pd, pd->n_blocks - 1, pd->n_blocks);
                    if (whole.n_blocks) lensrt_cpu_splat_pixels(r, w, &whole, p0, p0 + width, &row);
                    keep_tail(r, t, w, p0, p0 + width);
                    row.terms = row.clip = row.tau = row.dark = 0; /* the set-up's, once */
                    lensrt_cpu_splat_pixels(r, w, &part, p0, p0 + width, &row);
                } else
                    lensrt_cpu_splat_pixels(r, w, pd, p0, p0 + width, &row);
                if (last) {
                    st.terms += row.terms;
                    st.clip += row.clip;
                    st.tau += row.tau;
                    st.dark += row.dark;
                }
            }
        }
    }
    if (have_own) lensrt_cpu_free_pass(r->ctx, &own);
    lensrt_tiles_add_stats(r, (uint64_t)st.terms, (uint64_t)st.clip, (uint64_t)st.tau, (uint64_t)st.dark);
    return LENSRT_SUCCESS;
}
