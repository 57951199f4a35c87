/* The CPU device: per wavelength and pass, the samples' rows in parallel over samples,
 * then the splats in parallel over groups of pixels (OpenMP, dynamic schedule). The
 * pass buffers live from begin to end (r->device_data). */
#include "cpu.h"

#include "pass.h"

#ifdef LENSRT_OPENMP
#include <omp.h>
#endif

static lensrt_result cpu_create(lensrt_render r)
{
    (void)r;
    return LENSRT_SUCCESS; /* nothing beyond the host's sums */
}

static lensrt_result cpu_begin(lensrt_render r)
{
    lensrt_cpu_pass *pd = lensrt_calloc(r->ctx, 1, sizeof *pd);
    if (!pd) return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
    if (!lensrt_cpu_alloc_pass(r, pd, LENSRT_PASS)) {
        lensrt_free(r->ctx, pd);
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory for a pass of %d samples", LENSRT_PASS);
    }
    r->device_data = pd;
    return LENSRT_SUCCESS;
}

static lensrt_result cpu_pass(lensrt_render r, int w, const double *xy, int n)
{
    lensrt_cpu_pass *pd = r->device_data;
    const long npix = (long)r->width * r->height, ngroups = (npix + LENSRT_CPU_GROUP - 1) / LENSRT_CPU_GROUP;
    double s_terms = 0, s_clip = 0, s_tau = 0, s_dark = 0;
    long g;
    lensrt_cpu_prepare_samples(r, w, xy, n, pd, 1);
    // Splat: pixel groups in parallel (a pixel's sums belong to one thread)
#ifdef LENSRT_OPENMP
#pragma omp parallel for schedule(dynamic, 4) num_threads(r->ctx->threads > 0 ? r->ctx->threads : omp_get_max_threads()) \
    reduction(+ : s_terms, s_clip, s_tau, s_dark)
#endif
    for (g = 0; g < ngroups; g++) {
        lensrt_cpu_stats st = {0, 0, 0, 0};
        long p0 = g * LENSRT_CPU_GROUP;
        lensrt_cpu_splat_pixels(r, w, pd, p0, p0 + LENSRT_CPU_GROUP < npix ? p0 + LENSRT_CPU_GROUP : npix, &st);
        s_terms += st.terms;
        s_clip += st.clip;
        s_tau += st.tau;
        s_dark += st.dark;
    }
    // Statistics of the last pass, summed over its wavelengths
    if (w == 0) r->stat_terms = r->stat_clip = r->stat_tau = r->stat_dark = r->stat_count = 0;
    r->stat_terms += s_terms;
    r->stat_clip += s_clip;
    r->stat_tau += s_tau;
    r->stat_dark += s_dark;
    r->stat_count += (double)npix;
    return LENSRT_SUCCESS;
}

static lensrt_result cpu_end(lensrt_render r, lensrt_result status)
{
    lensrt_cpu_pass *pd = r->device_data;
    if (pd) {
        lensrt_cpu_free_pass(r->ctx, pd);
        lensrt_free(r->ctx, pd);
        r->device_data = NULL;
    }
    return status;
}

static void cpu_destroy(lensrt_render r) { cpu_end(r, LENSRT_SUCCESS); }

const lensrt_device_ops lensrt_device_cpu = {"cpu", cpu_create, cpu_begin, cpu_pass, cpu_end, cpu_destroy, lensrt_cpu_tile,
                                        lensrt_cpu_cells, lensrt_cpu_cells_tile, lensrt_cpu_fourier,
                                        lensrt_cpu_fourier_tile};
