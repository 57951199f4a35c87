/* The GL device (internal): buffers, programs and the per-pass dispatches of a render.
 *
 * core/render.c draws the samples on the host (the same pure functions of seed,
 * wavelength and index as for the CPU) and hands each wavelength's pass here; the
 * phasor sums live on the device between begin and end. */
#ifndef LENSRT_GL_RENDER_H
#define LENSRT_GL_RENDER_H

#include "../core/device.h"

extern const lensrt_device_ops lensrt_device_gl;

#endif /* LENSRT_GL_RENDER_H */
