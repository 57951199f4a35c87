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
