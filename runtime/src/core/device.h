/* Devices (internal): where the passes of a render run.
 *
 * core/render.c draws the samples on the host (pure functions of seed, wavelength and
 * index, the same for every device) and hands each wavelength's pass to the render's
 * device through this table. A device is one folder with one table (cpu/: OpenMP and
 * the SIMD kernel; gl/: OpenGL 4.3 compute shaders); core/device.c lists them, and is the
 * only core file that includes a device's header. A new device (CUDA, Vulkan) is a new
 * folder, its table, and one line there. */
#ifndef LENSRT_DEVICE_H
#define LENSRT_DEVICE_H

#include "render.h"

typedef struct lensrt_device_ops {
    const char *name; /* "cpu", "gl": as lensrt-psf --device spells it */
    /* Check the scene for the device and make its state (r->device_data), once, from
     * lensrt_render_create after the host's sums are allocated. A failure leaves the
     * render to be destroyed, so destroy must accept a half-made state. */
    lensrt_result (*create)(lensrt_render r);
    /* Around the passes of one run() or splat_points() call: begin makes what passes need
     * (the GL device uploads the host's sums, which load and merge may have changed);
     * end is called once begin succeeded, whatever the passes returned, and must leave
     * the completed passes' sums on the host; it returns `status` or its own failure. */
    lensrt_result (*begin)(lensrt_render r);
    /* Splat wavelength w's samples xy[0 .. 2 n) (zeros follow up to 2 LENSRT_PASS) into
     * the sums of every light and pixel. */
    lensrt_result (*pass)(lensrt_render r, int w, const double *xy, int n);
    lensrt_result (*end)(lensrt_render r, lensrt_result status);
    void (*destroy)(lensrt_render r);
    /* Host-scheduled tiles (core/tiles.c), NULL when the device renders whole passes only:
     * render pixels x0 .. x0 + width - 1 of rows y0 .. y0 + height - 1 for the session's
     * sample range on the calling thread (no OpenMP), adding to their sums, while other
     * threads do the same for other pixels. Failures go to lensrt_tiles_fail, the
     * set-up's statistics to lensrt_tiles_add_stats (never to the context). */
    lensrt_result (*tile)(lensrt_render r, int x0, int y0, int width, int height);
    /* The cells integrator (core/cells.h), NULL when the device has none: the job's
     * fields of every light, wavelength and pixel, progress told after each wavelength.
     * integrate_tile: the same for pixels x0 .. x0 + width - 1 of rows
     * y0 .. y0 + height - 1 alone, on the calling thread (no OpenMP, no context
     * errors: the result code says what failed). */
    lensrt_result (*integrate)(lensrt_render r, const struct lensrt_cells_job *job, lensrt_progress_fn progress,
                               void *user_data);
    lensrt_result (*integrate_tile)(lensrt_render r, const struct lensrt_cells_job *job, int x0, int y0, int width,
                                    int height);
    /* The Fourier integrator (core/fourier.h), NULL when the device has none: the job's
     * fields of every level, light, wavelength and pixel, progress told after each
     * wavelength; a clip that cuts the aperture is LENSRT_ERROR_UNSUPPORTED (told to the
     * context). */
    lensrt_result (*fourier)(lensrt_render r, struct lensrt_fourier_job *job, lensrt_progress_fn progress,
                             void *user_data);
    /* fourier_tile: the same fields for pixels x0 .. x0 + width - 1 of rows y0 ..
     * y0 + height - 1 alone, on the calling thread (no OpenMP, no context errors: the
     * result code, and the reason in why[0 .. n_why)), bit for bit as `fourier` makes
     * them: the window's own tiles, those that meet the rectangle, writing its pixels. */
    lensrt_result (*fourier_tile)(lensrt_render r, struct lensrt_fourier_job *job, int x0, int y0, int width,
                                  int height, char *why, size_t n_why);
} lensrt_device_ops;

/* The device table: NULL when this build has no such device. */
const lensrt_device_ops *lensrt_device_find(int device);

#endif /* LENSRT_DEVICE_H */
