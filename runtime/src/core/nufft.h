/* A 2-D type-1 non-uniform FFT (internal, for the Fourier integrator, core/fourier.h).
 *
 * For n points (x_j, y_j) (radians: any real values, taken modulo 2 pi, which is exact
 * because the modes are integers) and complex strengths c_j, every integer mode
 * kx in [-floor(mx/2), ceil(mx/2) - 1], ky likewise with my, gets
 *
 *   f[ky + floor(my/2)][kx + floor(mx/2)] = sum over j of c_j exp(+i (kx x_j + ky y_j))
 *
 * to a relative accuracy tol: max over k of |f_k - exact_k| is about tol sum_j |c_j|.
 * Arrays are interleaved complex doubles: c[2 j + re/im], and f row-major with kx
 * fastest, f[2 (iy mx + ix) + re/im] for the mode (ix - floor(mx/2), iy - floor(my/2)).
 *
 * The method (Barnett, Magland, af Klinteberg, SIAM J. Sci. Comput. 41, 2019): each
 * point is spread onto a periodic fine grid of gx x gy points (g the smallest power of
 * two >= 2 m and >= 2 w) with the "exponential of semicircle" kernel
 * phi(z) = exp(beta (sqrt(1 - z^2) - 1)), |z| <= 1, w grid points wide (w = ceil(log10
 * (1/tol)) + 1 in [2, 16], beta = 2.30 w); a grid FFT gives the modes of the spread
 * sum, of which the central m are kept and divided by the kernel's Fourier transform
 * at each. Cost: (n w^2 per vector) + (gx gy log(gx gy) per vector). The vectors of a
 * batch go 16 at a time, their grids interleaved: each point's kernel values serve the
 * 16 (and each FFT twiddle); grids beyond a last-level cache get their points sorted by
 * region, a block of points at a time, so that the grid is swept instead of hit at random.
 *
 * No allocation: the caller gives the plan's memory (lensrt_nufft_plan_bytes) and each
 * call's scratch (lensrt_nufft_scratch_bytes), both aligned for double. A plan is read
 * only by lensrt_nufft_type1, so threads may share one, each with its own scratch. Both
 * sizes never decrease as mx, my (or n_vec) grow at one tol, so that memory sized for the
 * largest problem serves every smaller one. No globals. */
#ifndef LENSRT_NUFFT_H
#define LENSRT_NUFFT_H

#include <stddef.h>

/* Limits of the arguments: modes per side, and the tolerance. */
#define LENSRT_NUFFT_MAX_MODES 65536
#define LENSRT_NUFFT_MIN_TOL 1e-14
#define LENSRT_NUFFT_MAX_TOL 1e-1

/* A plan: sizes, the kernel, and pointers into the memory given to lensrt_nufft_init
 * (which must outlive the plan). */
typedef struct lensrt_nufft {
    int mx, my;      /* modes along x and y */
    int gx, gy;      /* the fine grid (powers of two) */
    int w;           /* kernel width, grid points */
    int n_coef;      /* polynomial coefficients per kernel slot (degree + 1) */
    size_t stride;   /* a fine-grid row in complex values: gx and w - 1 of wrap padding */
    double beta;     /* kernel shape: phi(z) = exp(beta (sqrt(1 - z^2) - 1)) */
    /* phi at the w grid points a point reaches, as polynomials of its offset s:
     * coef[2 (k w + l)] and coef[2 (k w + l) + 1] (the same value, for x and y) multiply
     * s^k in slot l (core/nufft.c, kernel_polynomials) */
    const double *coef;
    const double *decon_x, *decon_y; /* [mx], [my]: 1 / the kernel's transform, per mode */
    const double *tw_x, *tw_y;       /* [2 (g - 1)]: FFT twiddles, exp(+i pi j / s) at s - 1 + j */
    const int *col_x, *row_y;        /* [mx], [my]: a mode's column (row) in the FFT's output */
} lensrt_nufft;

/* Bytes of plan memory for (mx, my, tol): the kernel's polynomials, the deconvolution
 * factors, the twiddles, the output positions. 0 for arguments lensrt_nufft_init refuses. */
size_t lensrt_nufft_plan_bytes(int mx, int my, double tol);

/* Fills the plan in `memory` (lensrt_nufft_plan_bytes(mx, my, tol) bytes, aligned for
 * double). Returns 1, or 0 (nothing written) for a NULL pointer, memory not aligned for
 * double, mx or my outside [1, LENSRT_NUFFT_MAX_MODES], tol outside [LENSRT_NUFFT_MIN_TOL,
 * LENSRT_NUFFT_MAX_TOL] (NaN included). */
int lensrt_nufft_init(lensrt_nufft *p, int mx, int my, double tol, void *memory);

/* Bytes of scratch for one call with n_vec (>= 1) vectors: min(n_vec, 16) fine grids of
 * gy x stride complex values, and where they take more than 16 MB the sort of a block of
 * points (0.5 MB); 0 when n_vec < 1 or the size does not fit a size_t. */
size_t lensrt_nufft_scratch_bytes(const lensrt_nufft *p, int n_vec);

/* f[v] = the type-1 sums of the strengths c[v] at the n points (x[j], y[j]), for every
 * v < n_vec (each point's kernel values computed once per 16 vectors; n_vec < 1 writes
 * nothing). `scratch`: lensrt_nufft_scratch_bytes(p, n_vec) bytes (or more), aligned for
 * double; its content on entry does not matter. A point with a non-finite x or y is
 * skipped (it adds nothing); non-finite strengths propagate. n = 0 gives zeros.
 * Coordinates are reduced modulo 2 pi to about 1e-15 + 1e-23 |x| radians while
 * |x| < 3e9 (2^29 turns), to about 1e-16 |x| beyond. */
void lensrt_nufft_type1(const lensrt_nufft *p, size_t n, const double *x, const double *y, int n_vec,
                        const double *const *c, double *const *f, void *scratch);

/* Gauss-Legendre nodes x[i] and weights w[i] on [0, 1], n >= 1 (Newton on the Legendre
 * polynomial from Tricomi's first guess): exact for polynomials of degree 2 n - 1. The
 * kernel's transform here, the aperture's rule in core/cells.c. */
void lensrt_gauss_legendre01(int n, double *x, double *w);

#endif /* LENSRT_NUFFT_H */
