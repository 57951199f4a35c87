/* The direct layer's taps (taps.h): where a point's light goes on the grid, and the
 * sharpening of the kernels that undoes the constant spread those taps add. Pure
 * functions, shared by the splat and the kernels' shifts (direct.c). */
#include "taps.h"

#include <math.h>
#include <stddef.h>

/* The quadratic B-spline's taps for a point at u on a grid of unit spacing: grid points
 * *first .. *first + 2 get w[0 .. 2] = B2(point - u), B2 the centred quadratic B-spline
 * (support 3, sum 1, >= 0). Unlike bilinear taps, whose spread f(1 - f) squared pixels
 * swings with the fraction f, the spread about u is 1/4 squared pixels wherever u falls
 * (a sampled B-spline keeps the B-spline's moments up to its degree): a constant blur,
 * which the kernels undo (sharpen), not one that changes from pixel to pixel. */
void image_bspline_taps(double u, int *first, double w[3])
{
    const double g = floor(u + 0.5), t = u - g;
    *first = (int)g - 1;
    w[0] = 0.5 * (0.5 - t) * (0.5 - t);
    w[1] = 0.75 - t * t;
    w[2] = 0.5 * (0.5 + t) * (0.5 + t);
}

/* The blur the direct layer adds to every pixel's light, per axis in squared pixels of
 * the bank's pitch: the splat's B-spline taps 1/4 and the kernels' 1/4 (image_bspline_taps),
 * less the 1/12 by which a (sub-)pixel's box spreads its light more than a point at its
 * centre, the point each is splatted as: 5/12 in all. In frequency omega (radians per
 * pixel) the three multiply the light by sinc(omega/2)^3, sinc(omega/2)^3 and
 * 1/sinc(omega/2), i.e. by 1 - (5/24) omega^2 + O(omega^4); sharpen() multiplies the
 * kernels by 1 + (5/12)(1 - cos omega) = 1 + (5/24) omega^2 + O(omega^4), the taps
 * -5/24, 1 + 5/12, -5/24 (sum 1: the kernel's power is kept). So the layer is right to
 * second order in the pitch wherever each light lands, where bilinear taps blur by
 * f (1 - f) - 1/12, which changes with the landing fraction f.
 *
 * Only to second order: the fourth-order taps of 1/sinc(omega/2)^5 (5 taps) were 10 times
 * closer on Gaussian PSFs of 0.4-2 pixels, but worse on real lenses' PSFs, whose Airy
 * cores are narrower than the bank's pitch (aliased: the higher order amplifies what the
 * samples cannot hold). Measured on lens 0001 at f/8 against every lit pixel's own PSF
 * (docs/image.md): the second-order taps 2.5% (oversample 3), the fourth-order 2.8-3.4%,
 * bilinear taps 2.9-5.3%; sharpening by 1/3 or 1/2 instead of 5/12 was worse both ways. */
static const double sharpen_taps[2] = {1.0 + 5.0 / 12.0, -5.0 / 24.0};

/* n values of v (stride apart) through sharpen_taps, in place; line: n scratch. Taps off
 * the ends read 0 (set_up_chiefs pads the kernels so that nothing spreads off them). */
static void sharpen_line(double *v, int n, size_t stride, double *line)
{
    int i;
    for (i = 0; i < n; i++) line[i] = v[(size_t)i * stride];
    for (i = 0; i < n; i++) {
        v[(size_t)i * stride] = sharpen_taps[0] * line[i] +
                                sharpen_taps[1] * ((i >= 1 ? line[i - 1] : 0.0) + (i + 1 < n ? line[i + 1] : 0.0));
    }
}

/* A kernel (kw x kh) through sharpen_taps along each axis; line: max(kw, kh) scratch. */
void image_sharpen(double *k, int kw, int kh, double *line)
{
    int i;
    for (i = 0; i < kh; i++) sharpen_line(k + (size_t)i * (size_t)kw, kw, 1, line);
    for (i = 0; i < kw; i++) sharpen_line(k + (size_t)i, kh, (size_t)kw, line);
}
