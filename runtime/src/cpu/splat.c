/* The CPU device's splats: every sample block of a pass to every pixel, in groups of
 * LENSRT_CPU_GROUP pixels that are set up together and then streamed past each block
 * (cpu/kernel.c), one group per OpenMP task. Each transport has its group function.
 *
 * Each block's sums are added to the pixel's phasor sums as soon as the block is done
 * (not a pass's worth at once): the sums then see the same additions in the same order
 * however the samples are split into run() calls (a call that ends inside a block has
 * that block drawn again whole by the next: core/render.c, lensrt.h's promise). */
#include "pass.h"

#include "../lens/lens.h"

#include <string.h>

typedef void (*splat_group_fn)(lensrt_render r, int w, const lensrt_cpu_pass *pd, long p0, long p1,
                               lensrt_cpu_stats *st);

/* Add a pixel's block sums, times its amplitude factor, to its phasor sums. */
static void add_sums(lensrt_render r, int w, size_t p, const double *acc, double amp)
{
    size_t npix = (size_t)r->width * (size_t)r->height;
    int l;
    for (l = 0; l < r->n_lights; l++) {
        size_t at = ((size_t)l * (size_t)r->n_wl + (size_t)w) * npix + p;
        r->sum[2 * at] += amp * acc[3 * l];
        r->sum[2 * at + 1] += amp * acc[3 * l + 1];
        if (r->sumsq) r->sumsq[at] += amp * amp * acc[3 * l + 2];
    }
}

/* Polynomial transport: P_s specialised to each pixel of the group, then the float (or
 * double) kernel per block and pixel; clip holds a ghost's P_clip terms per pixel (NULL
 * when the render has none on side P_s). */
static void group_pixels(lensrt_render r, int w, const lensrt_cpu_pass *pd, long p0, long p1, lensrt_cpu_stats *st,
                         lensrt_cpu_clip *clip)
{
    const int nl = r->n_lights, nb = pd->n_blocks;
    const int dbl = r->desc.precision == LENSRT_PRECISION_DOUBLE;
    lensrt_cpu_pixel px[LENSRT_CPU_GROUP];
    int live[LENSRT_CPU_GROUP];
    double acc[3 * 64];
    long p;
    int b;
    for (p = p0; p < p1; p++) {
        live[p - p0] = lensrt_cpu_setup_pixel(r, w, r->xs[p % r->width], r->ys[p / r->width], &px[p - p0],
                                              clip ? &clip[p - p0] : NULL);
        if (!live[p - p0]) {
            st->dark += 1;
            continue;
        }
        st->terms += px[p - p0].f.phase.n;
        st->clip += px[p - p0].f.clip;
        st->tau += px[p - p0].f.tau.n > 0;
    }
    for (b = 0; b < nb; b++)
        for (p = p0; p < p1; p++) {
            if (!live[p - p0]) continue;
            memset(acc, 0, sizeof(double) * 3 * (size_t)nl);
            if (dbl)
                lensrt_kernel_d(pd->mono_d + (size_t)b * r->n_rows * LENSRT_BLOCK, nl,
                                pd->phase_d + (size_t)b * nl * LENSRT_BLOCK,
                                pd->amp_d + (size_t)b * nl * LENSRT_BLOCK, &px[p - p0].d, acc);
            else
                lensrt_kernel_f(pd->mono_f + (size_t)b * r->n_rows * LENSRT_BLOCK, nl,
                                pd->phase_f + (size_t)b * nl * LENSRT_BLOCK,
                                pd->amp_f + (size_t)b * nl * LENSRT_BLOCK, &px[p - p0].f, acc);
            add_sums(r, w, (size_t)p, acc, px[p - p0].amp);
        }
}

/* A ghost with P_clip pairs on side P_s: its terms on this frame's stack (279 KB for the
 * group), so that direct renders keep the stack they had. */
static void group_clipped(lensrt_render r, int w, const lensrt_cpu_pass *pd, long p0, long p1, lensrt_cpu_stats *st)
{
    lensrt_cpu_clip clip[LENSRT_CPU_GROUP];
    group_pixels(r, w, pd, p0, p1, st, clip);
}

static void group_polynomial(lensrt_render r, int w, const lensrt_cpu_pass *pd, long p0, long p1, lensrt_cpu_stats *st)
{
    if (r->clip_s) group_clipped(r, w, pd, p0, p1, st);
    else group_pixels(r, w, pd, p0, p1, st, NULL);
}

/* Free space: the Rayleigh-Sommerfeld kernel from each sample's x, y (in double). */
static void group_free_space(lensrt_render r, int w, const lensrt_cpu_pass *pd, long p0, long p1, lensrt_cpu_stats *st)
{
    const lensrt_analytic_lens *m = &r->lens->model;
    const double z = m->sensor_distance_mm + r->desc.sensor.focus_offset_mm;
    const double lambda_mm = r->wavelengths[w] / LENSRT_NM_PER_MM;
    const int nl = r->n_lights, nb = pd->n_blocks;
    const int naive = r->desc.precision == LENSRT_PRECISION_NAIVE_FLOAT;
    double acc[3 * 64];
    long p;
    int b;
    (void)st; /* no per-pixel set-up to count */
    for (b = 0; b < nb; b++)
        for (p = p0; p < p1; p++) {
            memset(acc, 0, sizeof(double) * 3 * (size_t)nl);
            lensrt_kernel_free_space(pd->mono_d + (size_t)b * r->n_rows * LENSRT_BLOCK, nl,
                                     pd->phase_d + (size_t)b * nl * LENSRT_BLOCK,
                                     pd->amp_d + (size_t)b * nl * LENSRT_BLOCK,
                                     r->xs[p % r->width], r->ys[p / r->width], z, lambda_mm,
                                     m->one_dimensional, naive, acc);
            add_sums(r, w, (size_t)p, acc, 1.0);
        }
}

static const splat_group_fn splat_group[LENSRT_TRANSPORT_COUNT] = {
    [LENSRT_TRANSPORT_POLYNOMIAL] = group_polynomial,
    [LENSRT_TRANSPORT_FREE_SPACE] = group_free_space,
};

void lensrt_cpu_splat_pixels(lensrt_render r, int w, const lensrt_cpu_pass *pd, long p0, long p1, lensrt_cpu_stats *st)
{
    const splat_group_fn group = splat_group[r->lens_ops->transport];
    long p;
    for (p = p0; p < p1; p += LENSRT_CPU_GROUP) group(r, w, pd, p, p + LENSRT_CPU_GROUP < p1 ? p + LENSRT_CPU_GROUP : p1, st);
}
