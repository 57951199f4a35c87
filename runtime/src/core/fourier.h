/* The Fourier integrator (internal, issue 22): the field of a whole window of pixels at
 * once, instead of pixel by pixel.
 *
 * For a light and wavelength the field at pixel p is U(p) = integral over the aperture of
 * A(a, p) exp(i 2 pi Phi(a, p)) da. Monte Carlo and the cells integrator evaluate it
 * pixel by pixel, at a cost of (pixels x aperture points). Around the centre p0 of a
 * tile of pixels, Phi(a, p0 + d) = Phi(a, p0) + d . G(a) + R(a, d), with G the phase's
 * gradient on the sensor (the direction of the ray through a, in waves per mm) and R the
 * rest, a fraction of a wave over a tile; A and exp(i 2 pi R) are smooth in d and are
 * interpolated in d on Chebyshev nodes of the tile, so that
 *
 *   U(p0 + d) = sum over beta of T_beta(d) sum over j of c_{j beta} exp(i 2 pi d . G(a_j))
 *
 * for the nodes a_j of a Gauss-Legendre rule over the aperture (core/cells.h,
 * lensrt_quadrature): every inner sum, for every pixel of the tile at once, is one
 * type-1 non-uniform FFT (core/nufft.h). The cost is (aperture points + pixels log
 * pixels) per tile instead of their product, and the rule's nodes only need to resolve
 * the waves of phase across the aperture (aberration and the tile's extent), which a
 * Gauss rule does with about 2 nodes per wave along each side, converging spectrally.
 *
 * The integrand is the one lensrt_render_run samples: every term of P_o and P_s (pruned
 * only below `tol` waves), the Huygens amplitude per pixel. A tile whose rest R or whose
 * amplitude the interpolation cannot follow to `tol` is split in four. Clips that cut
 * the aperture (the outer and inner pupil, a ghost's P_clip) are not resolved here: a
 * render where one cuts a quadrature node is refused (LENSRT_ERROR_UNSUPPORTED, naming
 * the clip, the light or pixel and the wavelength), and the cells integrator serves it. */
#ifndef LENSRT_FOURIER_H
#define LENSRT_FOURIER_H

#include "cells.h"

/* The relative tolerance of the interpolation across tiles and of the NUFFT at the
 * render's rule (a tenth of it at the finer rule): far below the percent errors that
 * the rule's nodes decide. */
#define LENSRT_FOURIER_TOL 1e-3

/* Gauss-Legendre nodes per wave of phase along a line of the rule, and the pilot rule
 * that measures the waves (measured on lens 0001's PSFs at f/2, f/8 and f/32, 64 and 256
 * pixels square: 1% at 1.2-1.35 nodes per wave, 1e-4 at 1.5; 1.4 aims at a few 1e-3),
 * plus NODES_EXTRA for the ends. For an error target of 1% or more the rule takes
 * NODES_PER_WAVE_1PCT and NODES_EXTRA_1PCT instead (measured by runtime/bench/
 * fourier_bench.py --sweep: 1% at 1.20-1.33 nodes per wave plus 2 on lens 0001 at f/2 to
 * f/32, blades and circle, in focus and defocused, and a perfect lens defocused 5 and 20
 * waves: that rule gave 7.5e-5 to 5e-3), between 1e-4 and 1% in proportion to the
 * target's logarithm: the convergence is so steep (a decade every 2-5 nodes past the
 * threshold) that the default rule's extra nodes buy a hundred times the accuracy. */
#define LENSRT_FOURIER_NODES_PER_WAVE 1.4
#define LENSRT_FOURIER_NODES_EXTRA 4.0
#define LENSRT_FOURIER_NODES_PER_WAVE_1PCT 1.33
#define LENSRT_FOURIER_NODES_EXTRA_1PCT 2.0
#define LENSRT_FOURIER_PILOT_NODES 16
/* The chosen rule is refused (nodes 0: LENSRT_ERROR_UNSUPPORTED) beyond this many nodes
 * per pixel of the window: there the phase swings so far over the aperture (a defocused
 * ghost) that the cells integrator, whose closed forms follow any tilt, is the cheaper
 * (measured: lens 0001's f/2 PSF on 64 x 64 pixels, 49 nodes per pixel, Fourier 1.03 s
 * and cells 1.42 s to 1%; ghost 0-2 on 64 x 64 pixels, 365 per pixel, 10 times slower) */
#define LENSRT_FOURIER_NODES_PER_PIXEL 64

/* Levels of one call: the render's rule and, for the error estimate, a finer one. */
#define LENSRT_FOURIER_MAX_LEVELS 2

typedef struct lensrt_fourier_job {
    int n_level;
    const lensrt_quadrature *quad[LENSRT_FOURIER_MAX_LEVELS];
    double tol[LENSRT_FOURIER_MAX_LEVELS]; /* interpolation and NUFFT tolerance, relative */
    double *U[LENSRT_FOURIER_MAX_LEVELS];  /* [2 ((l n_wl + w) npix + p) + re/im] */
    /* pilot: no fields; instead *slope, the largest change of the phase (waves) per unit
     * of a line parameter of the rule (core/cells.h, lensrt_quadrature), over every node
     * line, light, wavelength and the window's corner pixels: the rule of `slope` x
     * LENSRT_FOURIER_NODES_PER_WAVE nodes resolves the integrand (auto nodes) */
    int pilot;
    double slope;
} lensrt_fourier_job;

#endif /* LENSRT_FOURIER_H */
