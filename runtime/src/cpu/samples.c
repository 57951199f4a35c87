/* The CPU device's samples of one pass and wavelength: per sample, the rows the kernel
 * streams (the lens kind's: stop monomials and basis functions, or x and y), and per
 * light the amplitude and the phase in waves, reduced to [-1/2, 1/2] in double before
 * it is stored (in float unless the render keeps double rows). */
#include "pass.h"

#include "../lens/lens.h"

#include <math.h>
#ifdef LENSRT_OPENMP
#include <omp.h>
#endif

/* Sample j of the pass at xy[0], xy[1] (NULL: padding, zero amplitude). */
static void prepare_sample(const lensrt_render r, int w, const double *xy, const lensrt_cpu_pass *pd, long j)
{
    const lensrt_lens_ops *ops = r->lens_ops;
    const double lambda_mm = r->wavelengths[w] / LENSRT_NM_PER_MM;
    const int nl = r->n_lights, nr = r->n_rows;
    const int naive = r->desc.precision == LENSRT_PRECISION_NAIVE_FLOAT;
    const int b = (int)(j / LENSRT_BLOCK), jj = (int)(j % LENSRT_BLOCK);
    const size_t row0 = (size_t)b * (size_t)nr * LENSRT_BLOCK + (size_t)jj;
    double x = 0, y = 0, inside = 0.0, mono[136];
    lensrt_rows rows;
    int l;
    if (xy) {
        x = xy[0];
        y = xy[1];
        inside = lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, x, y) ? 1.0 : 0.0;
    }
    rows.f = pd->mono_f ? pd->mono_f + row0 : NULL;
    rows.d = pd->mono_d ? pd->mono_d + row0 : NULL;
    rows.stride = LENSRT_BLOCK;
    ops->sample_rows(r, w, x, y, mono, &rows);
    for (l = 0; l < nl; l++) {
        double amp = inside * sqrt(r->lights[l].intensity), opl = 0.0, waves;
        size_t at = ((size_t)b * nl + (size_t)l) * LENSRT_BLOCK + (size_t)jj;
        ops->sample_wave(r, w, l, x, y, mono, &amp, &opl);
        waves = opl / lambda_mm;
        if (!naive) waves -= rint(waves); /* reduce in double: only the fraction matters */
        if (r->double_rows) {
            pd->phase_d[at] = waves;
            pd->amp_d[at] = amp;
        } else {
            pd->phase_f[at] = (float)waves;
            pd->amp_f[at] = (float)amp;
        }
    }
}

void lensrt_cpu_prepare_samples(lensrt_render r, int w, const double *xy, int n, lensrt_cpu_pass *pd, int threaded)
{
    long j, count;
    pd->n = n;
    pd->n_blocks = (n + LENSRT_BLOCK - 1) / LENSRT_BLOCK;
    count = (long)pd->n_blocks * LENSRT_BLOCK;
    if (!threaded) {
        for (j = 0; j < count; j++) prepare_sample(r, w, j < n ? xy + 2 * j : NULL, pd, j);
        return;
    }
#ifdef LENSRT_OPENMP
#pragma omp parallel for schedule(static) num_threads(r->ctx->threads > 0 ? r->ctx->threads : omp_get_max_threads())
#endif
    for (j = 0; j < count; j++) prepare_sample(r, w, j < n ? xy + 2 * j : NULL, pd, j);
}

void lensrt_cpu_prepare_blocks(lensrt_render r, int w, const double *xy, int n, lensrt_cpu_pass *pd, int b0, int b1)
{
    const long j0 = (long)b0 * LENSRT_BLOCK;
    long j;
    for (j = j0; j < (long)b1 * LENSRT_BLOCK; j++) prepare_sample(r, w, j - j0 < n ? xy + 2 * (j - j0) : NULL, pd, j);
}
