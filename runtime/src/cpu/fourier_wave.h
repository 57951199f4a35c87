/* The CPU device's Fourier integrator (internal, cpu/fourier*.c): one wavelength's work
 * and what the driver (cpu/fourier.c) and the tiles (cpu/fourier_tile.c) share. */
#ifndef LENSRT_CPU_FOURIER_WAVE_H
#define LENSRT_CPU_FOURIER_WAVE_H

#include "pass.h"

#include "../core/fourier.h"

#define PI 3.14159265358979323846
#define TWO_PI 6.28318530717958647692

/* Chebyshev degree of the interpolation across a tile, per axis, at most. */
#define MAX_DEG 4
#define MAX_NODES ((MAX_DEG + 1) * (MAX_DEG + 1))
/* Splits of a tile in four, at most (a 4096-pixel window down to single pixels). */
#define MAX_DEPTH 12
/* A tile is split before its nodes are computed when its phase rest may reach this many
 * waves (the interpolation of exp(i 2 pi R) at degree MAX_DEG converges fast below it). */
#define MAX_REST_WAVES 0.15
/* NUFFT vectors per call at most (each holds a fine grid of about 4 x the tile's pixels),
 * and the scratch they may take together. */
#define NUFFT_BATCH 16
#define NUFFT_SCRATCH_BYTES ((size_t)256 << 20)
/* Tolerance classes of the NUFFT: a Chebyshev term whose strengths sum to 10^-c of the
 * constant term's is transformed at 10^c times the tolerance (its error, relative to
 * the field, stays the tolerance). */
#define TOL_CLASSES 3
/* Tiles of at most this many pixels take the sums directly (a NUFFT's fine grid and
 * kernel would cost more, and the direct sums are exact). */
#define DIRECT_PIXELS 4

/* One wavelength's work: the rule, what P_o gives at its nodes per light, scratch. */
typedef struct fourier_wave {
    lensrt_render r;
    int w, poly;
    double lambda_mm, tol;
    const lensrt_quadrature *q;
    double *sph, *samp;    /* [l][j]: waves before the stop, amplitude at the stop times weight */
    int nq;                /* rule nodes padded to a multiple of BLK */
    double *gx, *gy;       /* [j]: NUFFT points (radians per pixel step) */
    struct tile_poly *tp;  /* the tile's polynomials and clips (tile_prepare) */
    double *cv;            /* [v][2 j]: NUFFT strengths, v = l n_beta + beta */
    double *f;             /* [v][2 p]: NUFFT outputs of a tile */
    void *plan_mem, *scratch;
    size_t plan_bytes, scratch_bytes;
    int batch;             /* NUFFT vectors per call */
    double *U;             /* the job level's fields */
    int rect[4];           /* a host tile's pixels (x0, y0, width, height); width 0: all */
    double slope;          /* the pilot's */
    lensrt_result fail;
    char why[320];
} fourier_wave;

/* Rule nodes are processed in blocks of BLK, the loops over a block's nodes being the
 * inner ones (they vectorise); the rule is padded to a whole number of blocks with
 * nodes of weight 0 at the stop's centre. */
#define BLK 8

/* A polynomial in the stop monomials, pruned: terms (slot, coef). */
typedef struct pruned {
    int n, slot[136];
    double coef[136];
} pruned;

/* A ghost's P_clip pair or the inner pupil at a node pixel: x and y as polynomials in the
 * stop monomials, the limit, whether the stop's shape decides it. */
struct post_clip {
    pruned x, y;
    double lim;
    int shaped, inner;
};
typedef struct post_clip post_clip;

/* A tile's per-node polynomials and clips (tile_prepare). */
typedef struct tile_poly {
    pruned P[2][MAX_NODES]; /* [0] phase (waves), [1] transmittance, per Chebyshev term */
    post_clip cl[MAX_NODES * (1 + LENSRT_MAX_CLIP_PAIRS)];
    int n_cl[MAX_NODES], n_test, tau_varies;
    double rest; /* the phase's rest beyond its linear part across the tile, at most (waves) */
} tile_poly;

/* What every light's path brings to the stop at every node for wavelength fw->w: phase
 * (waves) and amplitude times the rule's weight; a clip before the stop that cuts a node
 * refuses the render (0, fw->fail and fw->why set). */
int lensrt_fourier_prepare_nodes(fourier_wave *fw);
/* The field of tile (x0, y0, tw, th) of the window, split in four (depth + 1) while its
 * interpolation cannot follow the phase or the amplitude; 0 on failure (fw->fail). */
int lensrt_fourier_render_tile(fourier_wave *fw, int x0, int y0, int tw, int th, int depth);
/* The pilot (lensrt_fourier_job.pilot): the phase's largest change per unit of a line
 * parameter, into fw->slope; 0 on failure. */
int lensrt_fourier_pilot_slope(fourier_wave *fw);

#endif /* LENSRT_CPU_FOURIER_WAVE_H */
