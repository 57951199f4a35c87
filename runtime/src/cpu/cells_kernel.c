/* The cells integrator's loops over vertices and triangles (cpu/cells.c calls them per
 * pixel and light), written so that the compiler vectorises them: structure of arrays,
 * no calls, selects instead of branches. Built with -O3 (and -march=native with
 * LENSRT_NATIVE) but without fast-math and without FMA contraction, so that the
 * triangles it takes give the very bits lensrt_tri_integral (core/cells.c) gives. */
#include "cells_kernel.h"

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define TWO_PI 6.283185307179586477
/* The larger of two non-NaN numbers, inline (libm's fmax is a call: no vectorising) */
#define MAX2(a, b) ((a) > (b) ? (a) : (b))

void lensrt_cells_vertices(int n, const double *restrict ph, const double *restrict sph, double ref, const double *restrict lna,
                           const double *restrict samp, const double *restrict lnt, const double *restrict st, double *restrict zr, double *restrict zi,
                           double *restrict er, double *restrict ei, size_t stride)
{
    int v;
    for (v = 0; v < n; v++) {
        // The phase in waves relative to vertex 0's, and its fraction reduced to an
        // eighth of a turn around a quadrant: cos and sin by their Taylor series to
        // theta^14 on |theta| <= pi/4 (error below 1e-15), then the quadrant's rotation
        const double w = (ph[v] + sph[v]) - ref, f = w - rint(w), q = rint(4.0 * f), r = f - 0.25 * q;
        const double t = TWO_PI * r, t2 = t * t;
        const double s = t * (1.0 + t2 * (-1.0 / 6 + t2 * (1.0 / 120 + t2 * (-1.0 / 5040 + t2 * (1.0 / 362880 +
                             t2 * (-1.0 / 39916800 + t2 * (1.0 / 6227020800.0)))))));
        const double c = 1.0 + t2 * (-0.5 + t2 * (1.0 / 24 + t2 * (-1.0 / 720 + t2 * (1.0 / 40320 +
                             t2 * (-1.0 / 3628800 + t2 * (1.0 / 479001600.0 + t2 * (-1.0 / 87178291200.0)))))));
        // q in -2 .. 2: the quadrant q mod 4 is 0 for q = 0, 1 for q = 1, 2 for q = +-2,
        // 3 for q = -1 (compares in double: the loop vectorises)
        const double cc = (q == 1.0 || q == -1.0) ? s : c, ss = (q == 1.0 || q == -1.0) ? c : s;
        const double a = samp[v] * st[v];
        zr[(size_t)v * stride] = TWO_PI * w;
        zi[(size_t)v * stride] = -(lna[v] + lnt[v]);
        er[(size_t)v * stride] = a * ((q == 1.0 || q == 2.0 || q == -2.0) ? -cc : cc);
        ei[(size_t)v * stride] = a * ((q == 2.0 || q == -2.0 || q == -1.0) ? -ss : ss);
    }
}

/* Transmittance t at every vertex: its amplitude sqrt(t) in place, and the log of the
 * amplitude, 0.5 log t held at `floor_` (t <= 0, NaN: floor and amplitude 0; +inf stays
 * inf, for the integrator's finiteness check to name). The log is computed here so
 * that the loop vectorises (libm's log is a call per vertex): t = m 2^e with m in
 * [sqrt(1/2), sqrt(2)), log m = 2 atanh(s), s = (m - 1) / (m + 1), |s| < 0.172, by its
 * series to s^23 (the next term is below 1e-19 of the sum), and e ln 2 in two parts
 * (ln 2's leading 32 bits, exact in any product with e): within 2 ulp of log (tested in
 * tests/runtime/test_cells.c). Below 1e-300 (no subnormals reach the series) the log is
 * far under any floor the caller uses (0.5 log 1e-300 = -345). */
void lensrt_cells_log_amplitude(int n, double *restrict st, double *restrict lnt, double floor_)
{
    const double ln2_hi = 6.93147180369123816490e-01, ln2_lo = 1.90821492927058770002e-10;
    int v;
    for (v = 0; v < n; v++) {
        const double x = st[v];
        uint64_t u, mu;
        double m, e, s, s2, p, lg;
        memcpy(&u, &x, sizeof u);
        mu = (u & 0x000fffffffffffffULL) | 0x3ff0000000000000ULL;
        memcpy(&m, &mu, sizeof m);
        e = (double)(int64_t)((u >> 52) & 0x7ff) - 1023.0;
        e = m > 1.4142135623730951 ? e + 1.0 : e;
        m = m > 1.4142135623730951 ? 0.5 * m : m;
        s = (m - 1.0) / (m + 1.0);
        s2 = s * s;
        p = s2 * (1.0 / 3 + s2 * (1.0 / 5 + s2 * (1.0 / 7 + s2 * (1.0 / 9 + s2 * (1.0 / 11 + s2 * (1.0 / 13 +
            s2 * (1.0 / 15 + s2 * (1.0 / 17 + s2 * (1.0 / 19 + s2 * (1.0 / 21 + s2 * (1.0 / 23)))))))))));
        lg = e * ln2_hi + (e * ln2_lo + (2.0 * s + 2.0 * s * p));
        lnt[v] = !(x >= 1e-300) ? floor_ : x > DBL_MAX ? x : MAX2(0.5 * lg, floor_);
        st[v] = x > 0.0 ? sqrt(x) : 0.0;
    }
}

/* Triangle t of a strip for the LENSRT_CELLS_LANES pixels of a block at once: its
 * vertices' values at v0, v1, v2 (each LANES wide, one per pixel), its integral into
 * cr, ci (LANES wide) where the nodes are apart inside every clip, else 0 and rest 1.
 * The arithmetic per lane is lensrt_tri_integral's one-division branch, bit for bit. */
static inline void triangle_lanes(double area, const double *restrict zr0, const double *restrict zi0,
                                  const double *restrict er0, const double *restrict ei0,
                                  const double *restrict in0, const double *restrict zr1,
                                  const double *restrict zi1, const double *restrict er1,
                                  const double *restrict ei1, const double *restrict in1,
                                  const double *restrict zr2, const double *restrict zi2,
                                  const double *restrict er2, const double *restrict ei2,
                                  const double *restrict in2, double *restrict cr, double *restrict ci,
                                  double *restrict rest)
{
    int k;
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC ivdep
#endif
    for (k = 0; k < LENSRT_CELLS_LANES; k++) {
        // Differences a = z1 - z0, b = z2 - z0, c = z2 - z1 and their max norms
        const double ar = zr1[k] - zr0[k], ai = zi1[k] - zi0[k], br = zr2[k] - zr0[k], bi = zi2[k] - zi0[k];
        const double cr_ = zr2[k] - zr1[k], ci_ = zi2[k] - zi1[k];
        const double da = MAX2(fabs(ar), fabs(ai)), db = MAX2(fabs(br), fabs(bi)), dc = MAX2(fabs(cr_), fabs(ci_));
        // The branch lensrt_tri_integral takes for nodes apart (not all within 0.1 of
        // z0, every pair beyond 1/32), inside every clip
        const int apart = ((da > LENSRT_CELLS_SERIES_G) | (db > LENSRT_CELLS_SERIES_G)) &
                          (da > LENSRT_CELLS_SERIES_D) & (db > LENSRT_CELLS_SERIES_D) & (dc > LENSRT_CELLS_SERIES_D) &
                          (in0[k] * in1[k] * in2[k] != 0.0);
        // num = E0 c - E1 b + E2 a, den = a b c, g = -num / den (core/cells.c)
        const double nr = er0[k] * cr_ - ei0[k] * ci_ - (er1[k] * br - ei1[k] * bi) + er2[k] * ar - ei2[k] * ai;
        const double ni = er0[k] * ci_ + ei0[k] * cr_ - (er1[k] * bi + ei1[k] * br) + er2[k] * ai + ei2[k] * ar;
        const double abr = ar * br - ai * bi, abi = ar * bi + ai * br;
        const double dr = abr * cr_ - abi * ci_, di = abr * ci_ + abi * cr_;
        const double q = 1.0 / (dr * dr + di * di);
        const double gr = -((nr * dr + ni * di) * q), gi = -((ni * dr - nr * di) * q);
        cr[k] = apart ? 2.0 * area * gr : 0.0;
        ci[k] = apart ? 2.0 * area * gi : 0.0;
        rest[k] = apart ? 0.0 : 1.0;
    }
}

void lensrt_cells_triangles(const lensrt_mesh *m, int s0, int s1, const double *zr, const double *zi,
                            const double *er, const double *ei, const double *in, double *cr, double *ci,
                            double *rest)
{
    const size_t L = LENSRT_CELLS_LANES;
    const int first = m->strip[5 * s0];
    int s, k;
    for (s = s0; s < s1; s++) {
        const int *st = m->strip + 5 * s, t0 = st[0], n = st[1];
        for (k = 0; k < n; k++) {
            const size_t t = (size_t)(t0 - first + k) * L, a = (size_t)(st[2] + k) * L, b = (size_t)(st[3] + k) * L,
                         c = (size_t)(st[4] + k) * L;
            triangle_lanes(m->area[t0 + k], zr + a, zi + a, er + a, ei + a, in + a, zr + b, zi + b, er + b, ei + b,
                           in + b, zr + c, zi + c, er + c, ei + c, in + c, cr + t, ci + t, rest + t);
        }
    }
}
