/* The CPU device's passes (internal): one wavelength's samples laid out in blocks for the
 * kernel (cpu/samples.c), then splatted to pixel groups (cpu/splat.c, cpu/pixel.c).
 *
 * Pixels never share sums and samples are pure functions of their index, so a pixel's
 * sums do not depend on which group, thread or call splats it. */
#ifndef LENSRT_CPU_PASS_H
#define LENSRT_CPU_PASS_H

#include "../core/render.h"
#include "kernel.h"

#define LENSRT_CPU_GROUP 16 /* pixels set up together, then streamed past each sample block */

/* The samples of one pass for one wavelength, laid out for the kernel. */
typedef struct lensrt_cpu_pass {
    int n, n_blocks;          /* samples, blocks of LENSRT_BLOCK */
    float *mono_f;            /* [block][row][j] */
    double *mono_d;
    float *phase_f, *amp_f;   /* [block][light][j] */
    double *phase_d, *amp_d;
} lensrt_cpu_pass;

/* Statistics of the per-pixel set-up, summed over (pixel, wavelength). */
typedef struct lensrt_cpu_stats {
    double terms, clip, tau, dark;
} lensrt_cpu_stats;

/* Buffers for up to n_samples (at most LENSRT_PASS) samples, rows in float or double as
 * the render keeps them; 0 when out of memory (nothing kept, no message: tiles call it
 * from many threads). */
int lensrt_cpu_alloc_pass(lensrt_render r, lensrt_cpu_pass *pd, int n_samples);
void lensrt_cpu_free_pass(lensrt_context ctx, lensrt_cpu_pass *pd);

/* The rows, phases and amplitudes of samples xy[0 .. 2 n) of wavelength w (blocks padded
 * with zero amplitude), in OpenMP threads (threaded) or on the calling thread alone. */
void lensrt_cpu_prepare_samples(lensrt_render r, int w, const double *xy, int n, lensrt_cpu_pass *pd, int threaded);

/* The same for blocks b0 .. b1 - 1 alone, on the calling thread: xy[0 .. 2 n) are the
 * samples from the first of them on (n may be less than the blocks hold: padding). pd's
 * n and n_blocks are left as they are. */
void lensrt_cpu_prepare_blocks(lensrt_render r, int w, const double *xy, int n, lensrt_cpu_pass *pd, int b0, int b1);

/* One pass's buffers of up to n_samples samples laid out in `data` (NULL: only the size):
 * the bytes they take, each buffer aligned to 64 bytes from data. */
size_t lensrt_cpu_pass_view(lensrt_render r, void *data, int n_samples, lensrt_cpu_pass *pd);

/* Splat every sample of pd to pixels p0 .. p1 - 1 (row-major indices) for wavelength w,
 * adding to their sums, on the calling thread; the set-up's statistics add to *st. */
void lensrt_cpu_splat_pixels(lensrt_render r, int w, const lensrt_cpu_pass *pd, long p0, long p1, lensrt_cpu_stats *st);

/* A pixel of polynomial transport (cpu/pixel.c): P_s's terms at the pixel, pruned, and
 * the kernel's float and double views of them. Returns 0 when every path through the
 * pixel is clipped. */
typedef struct lensrt_cpu_pixel {
    int slot[4][136];
    float coef_f[4][136];
    double coef_d[4][136];
    double amp;                 /* Huygens amplitude factor times constant transmittance */
    lensrt_pixel_f f;
    lensrt_pixel_d d;
} lensrt_cpu_pixel;

/* The terms of a ghost's P_clip pairs at a pixel (side P_s): x of pair q in row 2 q, y
 * in row 2 q + 1. Kept apart from lensrt_cpu_pixel (17 KB each), so that only renders
 * of such ghosts carry them on the stack. */
typedef struct lensrt_cpu_clip {
    int slot[2 * LENSRT_MAX_CLIP_PAIRS][136];
    float coef_f[2 * LENSRT_MAX_CLIP_PAIRS][136];
    double coef_d[2 * LENSRT_MAX_CLIP_PAIRS][136];
} lensrt_cpu_clip;

/* clip: where a ghost's P_clip terms go (NULL when the render has none on side P_s). */
int lensrt_cpu_setup_pixel(const lensrt_render r, int w, double x, double y, lensrt_cpu_pixel *px,
                           lensrt_cpu_clip *clip);

/* The CPU device's cells integrator (cpu/cells.c; lensrt_device_ops.integrate and
 * integrate_tile). */
lensrt_result lensrt_cpu_cells(lensrt_render r, const struct lensrt_cells_job *job, lensrt_progress_fn progress,
                               void *user_data);
lensrt_result lensrt_cpu_cells_tile(lensrt_render r, const struct lensrt_cells_job *job, int x0, int y0, int width,
                                    int height);

/* The CPU device's Fourier integrator (cpu/fourier.c; lensrt_device_ops.fourier). */
lensrt_result lensrt_cpu_fourier(lensrt_render r, struct lensrt_fourier_job *job, lensrt_progress_fn progress,
                                 void *user_data);
lensrt_result lensrt_cpu_fourier_tile(lensrt_render r, struct lensrt_fourier_job *job, int x0, int y0, int width,
                                      int height, char *why, size_t n_why);

/* The CPU device's host-scheduled tile (cpu/tiles.c; lensrt_device_ops.tile). */
lensrt_result lensrt_cpu_tile(lensrt_render r, int x0, int y0, int width, int height);

#endif /* LENSRT_CPU_PASS_H */
