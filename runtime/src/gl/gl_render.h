/* The GL path of a render (internal): buffers, programs and the per-pass dispatches.
 *
 * render.c draws the samples on the CPU (the same pure functions of seed, wavelength
 * and index as the CPU path) and hands each wavelength's pass here; the phasor sums
 * live on the device between lensrt_gl_begin and lensrt_gl_end. */
#ifndef LENSRT_GL_RENDER_H
#define LENSRT_GL_RENDER_H

#include "../core/render.h"

/* Check the scene for the GL path, make the device, compile, upload what is fixed. */
lensrt_result lensrt_gl_render_create(lensrt_render r);
void lensrt_gl_render_destroy(lensrt_render r);
/* Make the device current and upload the phasor sums; then passes; then download. */
lensrt_result lensrt_gl_begin(lensrt_render r);
/* Wavelength w's pass: xy holds 2 LENSRT_PASS values, n samples then zeros. */
lensrt_result lensrt_gl_pass(lensrt_render r, int w, const double *xy, int n);
lensrt_result lensrt_gl_end(lensrt_render r, lensrt_result status);

#endif /* LENSRT_GL_RENDER_H */
