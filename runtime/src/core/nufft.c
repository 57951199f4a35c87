/* The 2-D type-1 non-uniform FFT (core/nufft.h says what and why): spreading with the
 * exponential of semicircle kernel, an FFT of the fine grid, deconvolution. */
#include "nufft.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

#define PI 3.14159265358979323846

/* 2 pi as a float-sized high part (24 bits, so n * HI is exact for |n| < 2^29) and the
 * rest, for the reduction of coordinates modulo 2 pi (Cody and Waite). */
#define TWO_PI_HI 6.283185482025146484375
#define TWO_PI_LO (-1.748455600074497e-07)
#define INV_TWO_PI 0.15915494309189535

/* Kernel widths (grid points), and the polynomials' degree above the width: w + 1
 * follows phi to within 15 % of its own error 10^(1 - w) (at w = 2; 4 to 9 % from w = 3;
 * what is left is the kernel's square-root edge, where phi is below exp(-beta)). */
#define MIN_WIDTH 2
#define MAX_WIDTH 16
#define EXTRA_DEGREE 1

/* Points sorted at once (by bin of the grid, BIN_SIDE x BIN_SIDE bins at most) before
 * they are spread, when a group's grids take more than SORT_BYTES (beyond a last-level
 * cache, where the sort halves the time for random points); smaller grids are spread in
 * the points' own order, the sort's scattered reads of the points costing there more
 * than the cache misses it saves (measured on random points). The sort's scratch:
 * SORT_INTS ints (keys, order, bin starts). */
#define BLOCK 65536
#define BIN_SIDE 32
#define SORT_BYTES ((size_t)16 << 20)
#define SORT_INTS (2 * BLOCK + BIN_SIDE * BIN_SIDE + 1)

/* Vectors spread together: their grids interleaved (vector fastest), so that a point
 * adds to one contiguous run of w GROUP complex values per grid row, and every FFT
 * butterfly serves them all with one twiddle. Larger batches go GROUP at a time. */
#define GROUP 16

/* -------------------------------------------------------------- the sizes ----- */

/* The kernel width for tol (the slack keeps tol = 1e-6 at 7, not 8, when log10 rounds up). */
static int kernel_width(double tol)
{
    int w = (int)ceil(log10(1.0 / tol) - 1e-9) + 1;
    if (w < MIN_WIDTH) w = MIN_WIDTH;
    if (w > MAX_WIDTH) w = MAX_WIDTH;
    return w;
}

/* The fine grid along one side: the smallest power of two >= 2 m and >= 2 w. */
static int fine_size(int m, int w)
{
    int g = 2;
    while (g < 2 * m || g < 2 * w) g *= 2;
    return g;
}

static int valid(int mx, int my, double tol)
{
    return mx >= 1 && my >= 1 && mx <= LENSRT_NUFFT_MAX_MODES && my <= LENSRT_NUFFT_MAX_MODES &&
           tol >= LENSRT_NUFFT_MIN_TOL && tol <= LENSRT_NUFFT_MAX_TOL;
}

/* Doubles of plan memory: coefficients, deconvolution factors, twiddles (the ints follow). */
static size_t plan_doubles(int mx, int my, int w, int gx, int gy)
{
    return 2 * (size_t)(w + 1 + EXTRA_DEGREE) * (size_t)w + (size_t)mx + (size_t)my + 2 * (size_t)(gx - 1) +
           2 * (size_t)(gy - 1);
}

size_t lensrt_nufft_plan_bytes(int mx, int my, double tol)
{
    int w;
    if (!valid(mx, my, tol)) return 0;
    w = kernel_width(tol);
    return plan_doubles(mx, my, w, fine_size(mx, w), fine_size(my, w)) * sizeof(double) +
           ((size_t)mx + (size_t)my) * sizeof(int);
}

/* ---------------------------------------------------------------- the plan ----- */

/* The kernel at z (0 outside [-1, 1]). */
static double kernel(double beta, double z)
{
    const double q = 1.0 - z * z;
    return q > 0.0 ? exp(beta * (sqrt(q) - 1.0)) : (q == 0.0 ? exp(-beta) : 0.0);
}

void lensrt_gauss_legendre01(int n, double *x, double *w)
{
    int i, k, it;
    for (i = 0; i < (n + 1) / 2; i++) {
        // Root i of P_n (descending from near 1), by Newton from Tricomi's estimate
        double z = cos(PI * (i + 0.75) / (n + 0.5)), dp = 1.0;
        for (it = 0; it < 100; it++) {
            double p0 = 1.0, p1 = z, dz;
            for (k = 2; k <= n; k++) {
                const double p2 = ((2.0 * k - 1.0) * z * p1 - (k - 1.0) * p0) / k;
                p0 = p1;
                p1 = p2;
            }
            // P_n' from P_n and P_{n-1}
            dp = n * (z * p1 - p0) / (z * z - 1.0);
            dz = p1 / dp;
            z -= dz;
            if (fabs(dz) < 1e-16) break;
        }
        {
            double p0 = 1.0, p1 = z;
            for (k = 2; k <= n; k++) {
                const double p2 = ((2.0 * k - 1.0) * z * p1 - (k - 1.0) * p0) / k;
                p0 = p1;
                p1 = p2;
            }
            dp = n * (z * p1 - p0) / (z * z - 1.0);
        }
        // Mapped from [-1, 1] to [0, 1]: nodes symmetric about 1/2, weights halved
        x[n - 1 - i] = 0.5 * (1.0 + z);
        x[i] = 0.5 * (1.0 - z);
        w[i] = w[n - 1 - i] = 1.0 / ((1.0 - z * z) * dp * dp);
    }
}

/* Where the DIF FFT of size g (log2 g = bits) leaves frequency index k: bit reversed. */
static int bit_reverse(int k, int bits)
{
    int r = 0, b;
    for (b = 0; b < bits; b++, k >>= 1) r = (r << 1) | (k & 1);
    return r;
}

/* One side's deconvolution factors and output positions. The spread sum's DFT at mode k
 * is f_k psi^(k) / h, h = 2 pi / g the grid step, psi the kernel in radians (half width
 * a = w h / 2) and psi^(k) = a I(k), I(k) = integral over [-1, 1] of phi(z) cos(k a z) dz
 * (phi even); so f_k = DFT_k 2 / (w I(k)), I by Gauss-Legendre (phi at the nodes given). */
static void side_setup(int m, int g, int w, int nq, const double *z, const double *wt, const double *phi,
                       double *decon, int *pos)
{
    int i, q, bits = 0;
    while ((1 << bits) < g) bits++;
    for (i = 0; i < m; i++) {
        const int k = i - m / 2;
        const double ka = k * PI * w / g;
        double I = 0.0;
        for (q = 0; q < nq / 2; q++) I += 2.0 * wt[q] * phi[q] * cos(ka * z[q]);
        decon[i] = 2.0 / (w * I);
        pos[i] = bit_reverse(k < 0 ? k + g : k, bits);
    }
}

/* Twiddles of the DIF FFT of size g: stage of half-span s (1, 2, 4, .., g / 2) uses
 * exp(+i pi j / s), j < s, stored at 2 (s - 1 + j). */
static void twiddles(int g, double *tw)
{
    int s, j;
    for (s = 1; s < g; s *= 2)
        for (j = 0; j < s; j++) {
            tw[2 * (s - 1 + j)] = cos(PI * j / s);
            tw[2 * (s - 1 + j) + 1] = sin(PI * j / s);
        }
}

/* The kernel's values as polynomials. A point at fine-grid coordinate t reaches the grid
 * points i0 + l, l < w, i0 = ceil(t - w / 2); with u = i0 - (t - w / 2) in [0, 1), slot l
 * holds phi(2 (u + l) / w - 1). Per slot: the Chebyshev interpolant in s = 2 u - 1 on
 * n_coef nodes, turned into monomials of s (T_k by T_k+1 = 2 s T_k - T_k-1), which
 * Horner's rule evaluates for all slots of both sides at once: each coefficient is
 * stored twice, coef[k 2 w + 2 l + (0: x, 1: y)]. */
static void kernel_polynomials(double beta, int w, int nc, double *coef)
{
    double f[MAX_WIDTH + 1 + EXTRA_DEGREE], ch[MAX_WIDTH + 1 + EXTRA_DEGREE], mono[MAX_WIDTH + 1 + EXTRA_DEGREE];
    double t0[MAX_WIDTH + 1 + EXTRA_DEGREE], t1[MAX_WIDTH + 1 + EXTRA_DEGREE], t2[MAX_WIDTH + 1 + EXTRA_DEGREE];
    int l, i, k;
    for (l = 0; l < w; l++) {
        // The slot's values at the Chebyshev nodes s_i = cos(pi (i + 1/2) / nc)
        for (i = 0; i < nc; i++) {
            const double s = cos(PI * (i + 0.5) / nc);
            f[i] = kernel(beta, (s + 1.0 + 2.0 * l) / w - 1.0);
        }
        // Chebyshev coefficients (a discrete cosine transform)
        for (k = 0; k < nc; k++) {
            double sum = 0.0;
            for (i = 0; i < nc; i++) sum += f[i] * cos(PI * k * (i + 0.5) / nc);
            ch[k] = (k ? 2.0 : 1.0) * sum / nc;
        }
        // Monomials: the coefficient of s^k is the sum over j of ch[j] (that of s^k in T_j)
        memset(t0, 0, sizeof t0);
        memset(t1, 0, sizeof t1);
        t0[0] = 1.0;
        t1[1] = 1.0;
        for (k = 0; k < nc; k++) mono[k] = ch[0] * t0[k] + ch[1] * t1[k];
        for (i = 2; i < nc; i++) {
            t2[0] = -t0[0];
            for (k = 1; k < nc; k++) t2[k] = 2.0 * t1[k - 1] - t0[k];
            for (k = 0; k < nc; k++) mono[k] += ch[i] * t2[k];
            memcpy(t0, t1, sizeof t0);
            memcpy(t1, t2, sizeof t1);
        }
        for (k = 0; k < nc; k++) coef[2 * (k * w + l)] = coef[2 * (k * w + l) + 1] = mono[k];
    }
}

int lensrt_nufft_init(lensrt_nufft *p, int mx, int my, double tol, void *memory)
{
    double z[MAX_WIDTH + 8], wt[MAX_WIDTH + 8], phi[MAX_WIDTH + 8];
    double *coef, *decon_x, *decon_y, *tw_x, *tw_y;
    int w, gx, gy, nq, q, *col_x, *row_y;
    if (!p || !memory || (uintptr_t)memory % sizeof(double) != 0 || !valid(mx, my, tol)) return 0;
    // Sizes: the kernel's width and shape, the fine grid, its padded rows
    w = kernel_width(tol);
    gx = fine_size(mx, w);
    gy = fine_size(my, w);
    p->mx = mx;
    p->my = my;
    p->gx = gx;
    p->gy = gy;
    p->w = w;
    p->n_coef = w + 1 + EXTRA_DEGREE;
    p->stride = (size_t)gx + (size_t)w - 1;
    p->beta = 2.30 * w;
    // The memory: doubles (coefficients, deconvolution, twiddles), then ints (positions)
    coef = memory;
    decon_x = coef + 2 * (size_t)p->n_coef * (size_t)w;
    decon_y = decon_x + mx;
    tw_x = decon_y + my;
    tw_y = tw_x + 2 * (size_t)(gx - 1);
    col_x = (int *)(tw_y + 2 * (size_t)(gy - 1));
    row_y = col_x + mx;
    // The kernel as polynomials, its transform at every mode (2 w + 16 Gauss-Legendre
    // nodes on [-1, 1]), the FFTs' twiddles
    nq = 2 * w + 16;
    {
        // The rule on [0, 1] (core/cells.h); its first half mirrored to z > 0 on [-1, 1]
        double x01[2 * MAX_WIDTH + 16], w01[2 * MAX_WIDTH + 16];
        lensrt_gauss_legendre01(nq, x01, w01);
        for (q = 0; q < nq / 2; q++) {
            z[q] = 1.0 - 2.0 * x01[q];
            wt[q] = 2.0 * w01[q];
        }
    }
    for (q = 0; q < nq / 2; q++) phi[q] = kernel(p->beta, z[q]);
    kernel_polynomials(p->beta, w, p->n_coef, coef);
    side_setup(mx, gx, w, nq, z, wt, phi, decon_x, col_x);
    side_setup(my, gy, w, nq, z, wt, phi, decon_y, row_y);
    twiddles(gx, tw_x);
    twiddles(gy, tw_y);
    p->coef = coef;
    p->decon_x = decon_x;
    p->decon_y = decon_y;
    p->tw_x = tw_x;
    p->tw_y = tw_y;
    p->col_x = col_x;
    p->row_y = row_y;
    return 1;
}

size_t lensrt_nufft_scratch_bytes(const lensrt_nufft *p, int n_vec)
{
    const size_t grid = (size_t)p->gy * p->stride * 2 * sizeof(double), sort = SORT_INTS * sizeof(int);
    const size_t nv = n_vec < GROUP ? (size_t)n_vec : GROUP;
    if (n_vec < 1 || nv > (SIZE_MAX - sort) / grid) return 0;
    // The first group's grids, and the sort's scratch where they call for it
    return nv * grid + (nv * grid > SORT_BYTES ? sort : 0);
}

/* ----------------------------------------------------------- spreading ----- */

/* A coordinate's place on the fine grid of g points: t in [0, g), after x mod 2 pi. */
static double grid_coordinate(double x, int g)
{
    const double n = floor(x * INV_TWO_PI);
    double t = ((x - n * TWO_PI_HI) - n * TWO_PI_LO) * (g * INV_TWO_PI);
    // n may be one off at a multiple of 2 pi, and beyond 2^29 turns the reduction is
    // not exact: back into [0, g) in any case (fmod is exact)
    if (t < 0.0) t += g;
    if (t >= g) t -= g;
    if (!(t >= 0.0 && t < g)) {
        t = fmod(t, (double)g);
        if (t < 0.0) t += g;
        if (!(t < g)) t = 0.0;
    }
    return t;
}

/* The kernel values of a point at grid coordinates (tx, ty), k[2 l] along x and
 * k[2 l + 1] along y, l < w, and the first grid points they reach, *ix in [0, gx), *iy in
 * [0, gy) (kernel_polynomials says how): Horner's rule for every slot of both sides at
 * once (pairs of values, one multiplier each). */
static void kernel_values(const lensrt_nufft *p, double tx, double ty, double *k, int *ix, int *iy)
{
    const int w = p->w, nc = p->n_coef;
    const double *coef = p->coef;
    const double ax = tx - 0.5 * w, ay = ty - 0.5 * w, x0 = ceil(ax), y0 = ceil(ay);
    const double sx = 2.0 * (x0 - ax) - 1.0, sy = 2.0 * (y0 - ay) - 1.0;
    int q, j;
    for (q = 0; q < 2 * w; q++) k[q] = coef[(nc - 1) * 2 * w + q];
    for (j = nc - 2; j >= 0; j--)
        for (q = 0; q < 2 * w; q += 2) {
            k[q] = k[q] * sx + coef[j * 2 * w + q];
            k[q + 1] = k[q + 1] * sy + coef[j * 2 * w + q + 1];
        }
    *ix = x0 < 0.0 ? (int)x0 + p->gx : (int)x0;
    *iy = y0 < 0.0 ? (int)y0 + p->gy : (int)y0;
}

/* Bins per side (g >> shift, at most BIN_SIDE): points are spread bin by bin. */
static int bin_shift(int g)
{
    int s = 0;
    while ((g >> s) > BIN_SIDE) s++;
    return s;
}

/* Adds point j (finite) to nv interleaved grids G (grid point (row, col) of vector v at
 * G[2 ((row stride + col) nv + v)]): its kernel values, ck[a][v] = kx[a] c_v, then per
 * kernel row b one contiguous run G[row][ix .. ix + w - 1][all v] += ky[b] ck (kx, ky:
 * kernel_values' k). The rows wrap here (once per row); the columns run into the row's
 * padding (gx to gx + w - 2), folded back later. */
static void spread_point(const lensrt_nufft *p, double x, double y, int nv, const double *const *c, size_t j,
                         double *G)
{
    const int w = p->w;
    const size_t run = 2 * (size_t)w * (size_t)nv;
    double k[2 * MAX_WIDTH], ck[2 * MAX_WIDTH * GROUP];
    size_t q;
    int ix, iy, a, b, v;
    kernel_values(p, grid_coordinate(x, p->gx), grid_coordinate(y, p->gy), k, &ix, &iy);
    for (v = 0; v < nv; v++) {
        const double cr = c[v][2 * j], ci = c[v][2 * j + 1];
        for (a = 0; a < w; a++) {
            ck[2 * (a * nv + v)] = k[2 * a] * cr;
            ck[2 * (a * nv + v) + 1] = k[2 * a] * ci;
        }
    }
    for (b = 0; b < w; b++) {
        const int r = iy + b < p->gy ? iy + b : iy + b - p->gy;
        double *row = G + 2 * ((size_t)r * p->stride + (size_t)ix) * (size_t)nv;
        const double kb = k[2 * b + 1];
        for (q = 0; q < run; q++) row[q] += kb * ck[q];
    }
}

/* Spreads the finite points among the n into nv interleaved grids G, a block of BLOCK
 * points at a time, in bin order: a stable counting sort of the block by bin of the grid
 * (`work`: SORT_INTS ints), so that points that follow each other add to the same part
 * of the grid, which stays in cache. */
static void spread_sorted(const lensrt_nufft *p, size_t n, const double *x, const double *y, int nv,
                          const double *const *c, double *G, int *work)
{
    const int shx = bin_shift(p->gx), shy = bin_shift(p->gy), nbx = p->gx >> shx, n_bins = nbx * (p->gy >> shy);
    int *const key = work, *const order = key + BLOCK, *const start = order + BLOCK;
    size_t j0;
    for (j0 = 0; j0 < n; j0 += BLOCK) {
        const int nb = n - j0 < BLOCK ? (int)(n - j0) : BLOCK;
        int i, k, kept = 0;
        // Each point's bin (that of the grid point below it), or -1; the bins' sizes
        memset(start, 0, ((size_t)n_bins + 1) * sizeof(int));
        for (i = 0; i < nb; i++) {
            const double xj = x[j0 + (size_t)i], yj = y[j0 + (size_t)i];
            key[i] = -1;
            if (!isfinite(xj) || !isfinite(yj)) continue;
            key[i] = ((int)grid_coordinate(yj, p->gy) >> shy) * nbx + ((int)grid_coordinate(xj, p->gx) >> shx);
            start[key[i] + 1]++;
            kept++;
        }
        // Where each bin starts in `order`, then the points in bin order (index order within)
        for (k = 0; k < n_bins; k++) start[k + 1] += start[k];
        for (i = 0; i < nb; i++)
            if (key[i] >= 0) order[start[key[i]]++] = i;
        for (k = 0; k < kept; k++) {
            const size_t j = j0 + (size_t)order[k];
            spread_point(p, x[j], y[j], nv, c, j, G);
        }
    }
}

/* ---------------------------------------------------------------- the FFT ----- */

/* Radix-2 decimation in frequency, sign +: (a, b) <- (a + b, (a - b) t), for n complex
 * values of runs a and b at one twiddle t. */
static void butterfly_runs(double *a, double *b, size_t n, double tr, double ti)
{
    size_t q;
    for (q = 0; q < 2 * n; q += 2) {
        const double ur = a[q], ui = a[q + 1], vr = b[q], vi = b[q + 1], dr = ur - vr, di = ui - vi;
        a[q] = ur + vr;
        a[q + 1] = ui + vi;
        b[q] = dr * tr - di * ti;
        b[q + 1] = dr * ti + di * tr;
    }
}

/* The same without the twiddle (t = 1). */
static void butterfly_runs_1(double *a, double *b, size_t n)
{
    size_t q;
    for (q = 0; q < 2 * n; q += 2) {
        const double ur = a[q], ui = a[q + 1], vr = b[q], vi = b[q + 1];
        a[q] = ur + vr;
        a[q + 1] = ui + vi;
        b[q] = ur - vr;
        b[q + 1] = ui - vi;
    }
}

/* The same with twiddle t[j] at element j (one vector's FFT along a row). */
static void butterfly_span(double *a, double *b, size_t n, const double *t)
{
    size_t q;
    for (q = 0; q < 2 * n; q += 2) {
        const double ur = a[q], ui = a[q + 1], vr = b[q], vi = b[q + 1], dr = ur - vr, di = ui - vi;
        a[q] = ur + vr;
        a[q + 1] = ui + vi;
        b[q] = dr * t[q] - di * t[q + 1];
        b[q + 1] = dr * t[q + 1] + di * t[q];
    }
}

/* The unnormalised DFT, sign +, in place along a row of g elements of nv interleaved
 * complex values each; frequency k ends at element bit_reverse(k). Half-spans g / 2 down
 * to 2 with twiddles (a run of twiddles for one vector, one twiddle per element pair for
 * several), then 1 without. */
static void fft_row(double *a, int g, int nv, const double *tw)
{
    const size_t e = 2 * (size_t)nv; /* doubles per element */
    int s, base, j;
    for (s = g / 2; s >= 2; s /= 2)
        for (base = 0; base < g; base += 2 * s) {
            double *lo = a + (size_t)base * e, *hi = lo + (size_t)s * e;
            if (nv == 1)
                butterfly_span(lo, hi, (size_t)s, tw + 2 * (s - 1));
            else
                for (j = 0; j < s; j++)
                    butterfly_runs(lo + j * e, hi + j * e, (size_t)nv, tw[2 * (s - 1 + j)], tw[2 * (s - 1 + j) + 1]);
        }
    for (base = 0; base < g; base += 2) butterfly_runs_1(a + (size_t)base * e, a + (size_t)(base + 1) * e, (size_t)nv);
}

/* The same along y, for the first gx columns of all gy rows of nv interleaved grids at
 * once: each butterfly combines two whole rows (contiguous runs of gx nv complex values,
 * one twiddle); frequency ky ends at row bit_reverse(ky). */
static void fft_columns(const lensrt_nufft *p, double *G, int nv)
{
    const size_t n = (size_t)p->gx * (size_t)nv, st = 2 * p->stride * (size_t)nv;
    int s, base, j;
    for (s = p->gy / 2; s >= 1; s /= 2)
        for (base = 0; base < p->gy; base += 2 * s) {
            double *a = G + (size_t)base * st, *b = a + (size_t)s * st;
            butterfly_runs_1(a, b, n);
            for (j = 1; j < s; j++)
                butterfly_runs(a + (size_t)j * st, b + (size_t)j * st, n, p->tw_y[2 * (s - 1 + j)],
                               p->tw_y[2 * (s - 1 + j) + 1]);
        }
}

/* ------------------------------------------------------------- the transform ----- */

void lensrt_nufft_type1(const lensrt_nufft *p, size_t n, const double *x, const double *y, int n_vec,
                        const double *const *c, double *const *f, void *scratch)
{
    const int w = p->w;
    const size_t row = 2 * p->stride; /* doubles per grid row, per vector */
    int v0;
    for (v0 = 0; v0 < n_vec; v0 += GROUP) {
        const int nv = n_vec - v0 < GROUP ? n_vec - v0 : GROUP;
        const size_t grid = (size_t)p->gy * row * (size_t)nv, run = row * (size_t)nv;
        double *const G = scratch;
        int *const work = (int *)(G + grid);
        int r, m, i, v;
        size_t q, j;
        // Spread the group's vectors into their interleaved grids (in bin order if large)
        memset(G, 0, grid * sizeof(double));
        if (grid * sizeof(double) > SORT_BYTES)
            spread_sorted(p, n, x, y, nv, c + v0, G, work);
        else
            for (j = 0; j < n; j++)
                if (isfinite(x[j]) && isfinite(y[j])) spread_point(p, x[j], y[j], nv, c + v0, j, G);
        // Fold each row's padding back onto its first w - 1 columns (the periodic wrap)
        for (r = 0; r < p->gy; r++) {
            double *g = G + (size_t)r * run;
            for (q = 0; q < 2 * (size_t)(w - 1) * (size_t)nv; q++) g[q] += g[2 * (size_t)p->gx * (size_t)nv + q];
        }
        // The DFT along y of every column, then along x of the my rows that hold the modes
        fft_columns(p, G, nv);
        for (m = 0; m < p->my; m++) fft_row(G + (size_t)p->row_y[m] * run, p->gx, nv, p->tw_x);
        // The central modes, divided by the kernel's transform, in the output's order
        for (m = 0; m < p->my; m++) {
            const double *g = G + (size_t)p->row_y[m] * run;
            for (v = 0; v < nv; v++) {
                double *out = f[v0 + v] + 2 * (size_t)m * (size_t)p->mx;
                for (i = 0; i < p->mx; i++) {
                    const double s = p->decon_y[m] * p->decon_x[i], *at = g + 2 * ((size_t)p->col_x[i] * nv + v);
                    out[2 * i] = s * at[0];
                    out[2 * i + 1] = s * at[1];
                }
            }
        }
    }
}
