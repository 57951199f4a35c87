/* The CPU device's host-scheduled tile: the session's samples for one rectangle, on the
 * calling thread (no OpenMP). Passes, wavelengths and sample indices are run()'s, and a
 * pixel's sums get the same additions in the same order, so the sums match run()'s bit
 * for bit. The samples are drawn and prepared by every tile again (the price of needing
 * nothing shared but the sums of the tile's own pixels). */
#include "pass.h"

#include "../core/tiles.h"

#include <string.h>

lensrt_result lensrt_cpu_tile(lensrt_render r, int x0, int y0, int width, int height)
{
    const lensrt_tiles *t = r->tiles;
    const int n_max = t->count < LENSRT_PASS ? (int)t->count : LENSRT_PASS;
    lensrt_cpu_stats st = {0, 0, 0, 0};
    lensrt_cpu_pass pd;
    double *xy;
    uint64_t done;
    int w, y;
    // One pass's buffers, as large as the session's passes need
    xy = lensrt_alloc(r->ctx, sizeof(double) * ((size_t)n_max * 2 + 2));
    if (!xy || !lensrt_cpu_alloc_pass(r, &pd, n_max)) {
        lensrt_free(r->ctx, xy);
        return lensrt_tiles_fail(r, LENSRT_ERROR_OUT_OF_MEMORY, "tile %d x %d at (%d, %d): out of memory for a pass of %d samples",
                                 width, height, x0, y0, n_max);
    }
    for (done = 0; done < t->count; done += (uint64_t)n_max) {
        const int n = t->count - done < (uint64_t)n_max ? (int)(t->count - done) : n_max;
        const int last = done + (uint64_t)n == t->count;
        // Per wavelength: run()'s samples of this pass, prepared here, then the rows of
        // the rectangle (the set-up's statistics once, from the last pass)
        for (w = 0; w < r->n_wl; w++) {
            memset(xy, 0, sizeof(double) * ((size_t)n_max * 2 + 2));
            lensrt_sample_aperture(r->desc.sampler, r->desc.seed, w, t->first + done, (uint64_t)n, &r->region, xy);
            lensrt_cpu_prepare_samples(r, w, xy, n, &pd, 0);
            for (y = y0; y < y0 + height; y++) {
                long p0 = (long)y * r->width + x0;
                lensrt_cpu_stats row = {0, 0, 0, 0};
                lensrt_cpu_splat_pixels(r, w, &pd, p0, p0 + width, &row);
                if (last) {
                    st.terms += row.terms;
                    st.clip += row.clip;
                    st.tau += row.tau;
                    st.dark += row.dark;
                }
            }
        }
    }
    lensrt_cpu_free_pass(r->ctx, &pd);
    lensrt_free(r->ctx, xy);
    lensrt_tiles_add_stats(r, (uint64_t)st.terms, (uint64_t)st.clip, (uint64_t)st.tau, (uint64_t)st.dark);
    return LENSRT_SUCCESS;
}
