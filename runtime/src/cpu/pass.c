/* The CPU device's pass buffers (cpu/pass.h): one wavelength's samples of a pass, as
 * buffers of their own (the device's passes, from begin to end) or laid out in memory the
 * caller holds (host-scheduled tiles' shared samples, cpu/tiles.c). */
#include "pass.h"

#include <string.h>

void lensrt_cpu_free_pass(lensrt_context ctx, lensrt_cpu_pass *pd)
{
    lensrt_free(ctx, pd->mono_f);
    lensrt_free(ctx, pd->mono_d);
    lensrt_free(ctx, pd->phase_f);
    lensrt_free(ctx, pd->amp_f);
    lensrt_free(ctx, pd->phase_d);
    lensrt_free(ctx, pd->amp_d);
    memset(pd, 0, sizeof *pd);
}

int lensrt_cpu_alloc_pass(lensrt_render r, lensrt_cpu_pass *pd, int n_samples)
{
    const size_t nb = ((size_t)n_samples + LENSRT_BLOCK - 1) / LENSRT_BLOCK;
    const size_t rows = (size_t)r->n_rows, lanes = nb * (size_t)r->n_lights * LENSRT_BLOCK;
    memset(pd, 0, sizeof *pd);
    if (r->double_rows) {
        pd->mono_d = lensrt_calloc(r->ctx, nb * rows * LENSRT_BLOCK, sizeof(double));
        pd->phase_d = lensrt_calloc(r->ctx, lanes, sizeof(double));
        pd->amp_d = lensrt_calloc(r->ctx, lanes, sizeof(double));
    } else {
        pd->mono_f = lensrt_calloc(r->ctx, nb * rows * LENSRT_BLOCK, sizeof(float));
        pd->phase_f = lensrt_calloc(r->ctx, lanes, sizeof(float));
        pd->amp_f = lensrt_calloc(r->ctx, lanes, sizeof(float));
    }
    if (r->double_rows ? !pd->mono_d || !pd->phase_d || !pd->amp_d : !pd->mono_f || !pd->phase_f || !pd->amp_f) {
        lensrt_cpu_free_pass(r->ctx, pd);
        return 0;
    }
    return 1;
}

size_t lensrt_cpu_pass_view(lensrt_render r, void *data, int n_samples, lensrt_cpu_pass *pd)
{
    const size_t nb = ((size_t)n_samples + LENSRT_BLOCK - 1) / LENSRT_BLOCK;
    const size_t elt = r->double_rows ? sizeof(double) : sizeof(float);
    const size_t rows = (nb * (size_t)r->n_rows * LENSRT_BLOCK * elt + 63) / 64 * 64;
    const size_t lanes = (nb * (size_t)r->n_lights * LENSRT_BLOCK * elt + 63) / 64 * 64;
    unsigned char *p = data;
    if (!p) return rows + 2 * lanes;
    // Rows, then phases, then amplitudes, in the render's precision
    memset(pd, 0, sizeof *pd);
    pd->n = n_samples;
    pd->n_blocks = (int)nb;
    if (r->double_rows) {
        pd->mono_d = (void *)p;
        pd->phase_d = (void *)(p + rows);
        pd->amp_d = (void *)(p + rows + lanes);
    } else {
        pd->mono_f = (void *)p;
        pd->phase_f = (void *)(p + rows);
        pd->amp_f = (void *)(p + rows + lanes);
    }
    return rows + 2 * lanes;
}
