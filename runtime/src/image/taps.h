/* The direct layer's taps (taps.c; direct.c uses them). */
#ifndef LENSRT_IMAGE_TAPS_H
#define LENSRT_IMAGE_TAPS_H

/* The quadratic B-spline's taps for a point at u on a grid of unit spacing: grid points
 * *first .. *first + 2 get w[0 .. 2] (sum 1, >= 0, a spread of 1/4 squared pixels about
 * u wherever u falls). */
void image_bspline_taps(double u, int *first, double w[3]);

/* A kernel (kw x kh doubles) sharpened along each axis by the taps -5/24, 1 + 5/12,
 * -5/24 (sum 1), which undo to second order the spread the splat's and the kernels'
 * B-spline taps add less a pixel box's own; line: max(kw, kh) scratch. */
void image_sharpen(double *k, int kw, int kh, double *line);

#endif
