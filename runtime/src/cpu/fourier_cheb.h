/* Chebyshev interpolation across a tile of pixels (internal, cpu/fourier_tile.c): the
 * nodes, the values of T_m, and the transforms between node values and coefficients over
 * a block of BLK rule nodes. Static inline: the tile's inner loops take them in place. */
#ifndef LENSRT_CPU_FOURIER_CHEB_H
#define LENSRT_CPU_FOURIER_CHEB_H

#include "fourier_wave.h"

#include <math.h>
#include <string.h>

/* The tile's interpolation: degrees, nodes, transforms, node pixels in mm. */
typedef struct tile_interp {
    int dx, dy, ns;                       /* degrees, node pixels (dx + 1)(dy + 1) */
    double Mx[MAX_DEG + 1][MAX_DEG + 1], My[MAX_DEG + 1][MAX_DEG + 1];
    double Tx[MAX_DEG + 1][MAX_DEG + 1], Ty[MAX_DEG + 1][MAX_DEG + 1]; /* T_m at node i: [i][m] */
    double xh[MAX_DEG + 1], yh[MAX_DEG + 1]; /* nodes on [-1, 1] */
    double xc, yc, hx, hy;                /* centre and half sizes (mm; 1 where one pixel) */
    double px[MAX_NODES], py[MAX_NODES];  /* node pixels (mm): s = iy (dx + 1) + ix */
    double pa[MAX_NODES];                 /* the Huygens amplitude at the node pixels */
} tile_interp;

/* Chebyshev-Lobatto nodes of degree d on [-1, 1] (d = 0: the centre). */
static inline void cheb_nodes(int d, double *x)
{
    int i;
    if (d == 0) x[0] = 0.0;
    for (i = 0; d > 0 && i <= d; i++) x[i] = cos(PI * i / d);
}

/* T_0 .. T_d at x. */
static inline void cheb_values(int d, double x, double *t)
{
    int m;
    t[0] = 1.0;
    if (d >= 1) t[1] = x;
    for (m = 2; m <= d; m++) t[m] = 2.0 * x * t[m - 1] - t[m - 2];
}

/* M[m][i]: the coefficient of T_m from the value at Lobatto node i (degree d). */
static inline void cheb_matrix(int d, double M[MAX_DEG + 1][MAX_DEG + 1])
{
    int m, i;
    if (d == 0) {
        M[0][0] = 1.0;
        return;
    }
    for (m = 0; m <= d; m++)
        for (i = 0; i <= d; i++) {
            double c = (2.0 / d) * cos(PI * m * i / d);
            if (i == 0 || i == d) c *= 0.5;
            if (m == 0 || m == d) c *= 0.5;
            M[m][i] = c;
        }
}

/* out = (Ay x Ax) in over a block of nodes: out[by nx + r][q] = sum over m, k of Ay[by][m]
 * Ax[r][k] in[m nx + k][q] (rows r of Ax and Ay give out's indices, columns in's). */
static inline void cheb_apply_blk(const tile_interp *ti, const double (*Ax)[MAX_DEG + 1], const double (*Ay)[MAX_DEG + 1],
                                  const double (*in)[BLK], double (*out)[BLK])
{
    double tmp[MAX_NODES][BLK];
    const int nx = ti->dx + 1, ny = ti->dy + 1;
    int r, k, by, q;
    // Along x for every row of node pixels, then along y
    for (by = 0; by < ny; by++)
        for (r = 0; r < nx; r++) {
            double a[BLK] = {0};
            for (k = 0; k < nx; k++)
                for (q = 0; q < BLK; q++) a[q] += Ax[r][k] * in[by * nx + k][q];
            memcpy(tmp[by * nx + r], a, sizeof a);
        }
    for (by = 0; by < ny; by++)
        for (r = 0; r < nx; r++) {
            double a[BLK] = {0};
            for (k = 0; k < ny; k++)
                for (q = 0; q < BLK; q++) a[q] += Ay[by][k] * tmp[k * nx + r][q];
            memcpy(out[by * nx + r], a, sizeof a);
        }
}

/* Values out[s][q] at the node pixels of the Chebyshev terms in[b][q] of a block of nodes. */
static inline void cheb_inverse_blk(const tile_interp *ti, const double (*in)[BLK], double (*out)[BLK])
{
    cheb_apply_blk(ti, (const double(*)[MAX_DEG + 1])ti->Tx, (const double(*)[MAX_DEG + 1])ti->Ty, in, out);
}

/* Chebyshev terms of a block's values at the node pixels: in[s][BLK] -> out[b][BLK]. */
static inline void cheb_transform_blk(const tile_interp *ti, const double (*in)[BLK], double (*out)[BLK])
{
    cheb_apply_blk(ti, (const double(*)[MAX_DEG + 1])ti->Mx, (const double(*)[MAX_DEG + 1])ti->My, in, out);
}

#endif /* LENSRT_CPU_FOURIER_CHEB_H */
