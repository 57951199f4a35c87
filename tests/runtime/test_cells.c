/* The cells integrator's closed forms (runtime/src/core/cells.c), compiled in:
 *
 *   1. the integral of exp(i z) over a triangle, z linear, against an independent
 *      evaluation in long double (a 96 x 96 Gauss-Legendre rule on the collapsed
 *      square), at and near every removable singularity of the closed form (equal
 *      nodes, differences at the series' thresholds, two nodes equal and the third far,
 *      complex nodes for the amplitude) and over random triangles from 1e-12 to 100 rad;
 *   2. a triangle cut by a level: the two sides add up to the whole, and a cut along a
 *      known line equals the reference over the piece;
 *   3. the meshes: their areas against the polygon and circle they fill.
 *
 * The integrator is double only (no float variant exists to test). */
#include "../../runtime/src/core/cells.h"
#include "../../runtime/src/cpu/cells_kernel.h"

#include "internal_stubs.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>


static int failures;
#define CHECK(cond, ...)                                                                                              \
    do {                                                                                                              \
        if (!(cond)) {                                                                                                \
            failures++;                                                                                               \
            fprintf(stderr, "FAIL %s:%d: ", __FILE__, __LINE__);                                                      \
            fprintf(stderr, __VA_ARGS__);                                                                             \
            fprintf(stderr, "\n");                                                                                    \
        }                                                                                                             \
    } while (0)

/* ----------------------------------------------------------- the reference ----- */

#define NG 96
static long double gx[NG], gw[NG]; /* Gauss-Legendre on [0, 1] */

/* P_NG(x) and P_NG'(x) by the three-term recurrence. */
static long double legendre(long double x, long double *dp)
{
    long double p0 = 1.0L, p1 = x;
    int k;
    for (k = 2; k <= NG; k++) {
        long double p2 = ((2 * k - 1) * x * p1 - (k - 1) * p0) / k;
        p0 = p1;
        p1 = p2;
    }
    *dp = NG * (x * p1 - p0) / (x * x - 1.0L);
    return p1;
}

static void gauss_legendre(void)
{
    int i, it;
    for (i = 0; i < NG; i++) {
        // Newton on P_NG from the Chebyshev guess, in long double
        long double x = cosl(3.14159265358979323846264L * (i + 0.75L) / (NG + 0.5L)), dp;
        for (it = 0; it < 100; it++) {
            long double dx = legendre(x, &dp) / dp;
            x -= dx;
            if (fabsl(dx) < 1e-19L) break;
        }
        legendre(x, &dp);
        gx[i] = 0.5L * (1.0L + x);
        gw[i] = 1.0L / ((1.0L - x * x) * dp * dp); /* 2 / ((1 - x^2) P'^2), halved for [0, 1] */
    }
}

/* integral over the triangle of area S of exp(i z), z linear with vertex values z[k]
 * (complex), by l1 = u, l2 = (1 - u) v on [0, 1]^2 (Jacobian 1 - u, times 2 S). */
static void reference(double S, const double z[6], long double out[2])
{
    long double re = 0.0L, im = 0.0L;
    int i, j;
    for (i = 0; i < NG; i++)
        for (j = 0; j < NG; j++) {
            const long double l1 = gx[i], l2 = (1.0L - gx[i]) * gx[j], l0 = 1.0L - l1 - l2;
            const long double zr = l0 * z[0] + l1 * z[2] + l2 * z[4], zi = l0 * z[1] + l1 * z[3] + l2 * z[5];
            const long double w = gw[i] * gw[j] * (1.0L - gx[i]) * expl(-zi);
            re += w * cosl(zr);
            im += w * sinl(zr);
        }
    out[0] = 2.0L * S * re;
    out[1] = 2.0L * S * im;
}

static void exps(const double z[6], double E[6])
{
    int k;
    for (k = 0; k < 3; k++) {
        const long double a = expl(-(long double)z[2 * k + 1]);
        E[2 * k] = (double)(a * cosl(z[2 * k]));
        E[2 * k + 1] = (double)(a * sinl(z[2 * k]));
    }
}

/* The error of lensrt_tri_integral against the reference, relative to S max |E|. */
static double tri_error(const double z[6])
{
    const double S = 0.37;
    double E[6], out[2], scale = 0.0;
    long double ref[2];
    int k;
    exps(z, E);
    lensrt_tri_integral(S, z, E, out);
    reference(S, z, ref);
    for (k = 0; k < 3; k++) scale = fmax(scale, hypot(E[2 * k], E[2 * k + 1]));
    return (double)(hypotl(out[0] - ref[0], out[1] - ref[1]) / (S * scale));
}

/* Tolerance: rounding times the cancellation the divided differences allow. Near the
 * series' thresholds (0.1 for G, 1/32 for a pair, cells.c) the one-division formula
 * divides by a b c >= (1/32)^2 0.1 after adding terms of size 0.1: about 1e3 units of
 * rounding, 2e-13 (measured up to 5.6e-14 there); for far nodes the recursion's
 * first differences lose about s / (1/32) units: 1e-15 * 320 s. The reference itself:
 * the 96-point rule is exact to long double for differences up to ~100 rad (its error
 * falls like (e s / 4 n)^2n). */
static double tolerance(const double z[6])
{
    double s = 0.0;
    int a, b;
    for (a = 0; a < 3; a++)
        for (b = 0; b < 3; b++) s = fmax(s, hypot(z[2 * a] - z[2 * b], z[2 * a + 1] - z[2 * b + 1]));
    return 2e-13 + 1e-15 * 320.0 * s;
}

static void check_case(const char *what, double z0r, double z0i, double z1r, double z1i, double z2r, double z2i)
{
    const double z[6] = {z0r, z0i, z1r, z1i, z2r, z2i};
    const double e = tri_error(z), tol = tolerance(z);
    CHECK(e <= tol, "%s: (%.17g%+.17gi, %.17g%+.17gi, %.17g%+.17gi): error %.3g > %.3g", what, z0r, z0i, z1r, z1i, z2r,
          z2i, e, tol);
}

static void test_singularities(void)
{
    const double G = 0.1, D = 0.03125, eps[] = {0.0, 1e-15, 1e-12, 1e-9, 1e-6};
    int i, k;
    check_case("equal nodes", 0, 0, 0, 0, 0, 0);
    check_case("equal nodes, far from 0", 1234.5, 0, 1234.5, 0, 1234.5, 0);
    for (i = 0; i < 5; i++) {
        const double e = eps[i];
        // Tiny differences: the series
        check_case("tiny", 0, 0, e, 0, 2 * e, 0);
        check_case("tiny, complex", 0, 0, e, -e, -e, 2 * e);
        // At the series' threshold from both sides (the series, then the recursion)
        for (k = -1; k <= 1; k += 2) {
            check_case("at SERIES_G", 0, 0, G + k * e, 0, 0.5 * G, 0);
            check_case("at SERIES_G, both", 0, 0, G + k * e, 0, -(G + k * e), 0);
            check_case("at SERIES_D, third far", 0, 0, D + k * e, 0, 3.0, 0);
            check_case("at SERIES_D, all apart", 0, 0, D + k * e, 0, 2 * (D + k * e), 0);
        }
        // Two nodes (nearly) equal, the third far: every pairing
        check_case("z1 = z2 far", 0, 0, 5.0, 0, 5.0 + e, 0);
        check_case("z0 = z1", 0, 0, e, 0, 5.0, 0);
        check_case("z0 = z2", 3.0, 0, 0, 0, 3.0 + e, 0);
        check_case("z1 = z2 far, complex", 0, 0, 5.0, 0.7, 5.0 + e, 0.7 - e);
    }
    // Complex nodes (log amplitude linear), mild and strong
    check_case("amplitude ramp", 0, 0, 0.5, -0.2, 1.0, 0.3);
    check_case("strong amplitude ramp", 0, 0, 0, -3.0, 2.0, 0);
    check_case("amplitude only", 0, 0, 0, 1.0, 0, -1.0);
    // Many waves across the triangle
    check_case("large", 0, 0, 50.0, 0, -30.0, 0);
    check_case("large, two equal", 0, 0, 100.0, 0, 100.00001, 0);
}

/* Random triangles: differences log-uniform in 1e-12 .. 100 rad, random complex parts. */
static void test_random(void)
{
    unsigned long long st = 0x9E3779B97F4A7C15ULL;
    double worst = 0.0;
    int n;
    for (n = 0; n < 400; n++) {
        double z[6], e, tol;
        int k;
        for (k = 0; k < 6; k++) {
            double u, mag;
            st = st * 6364136223846793005ULL + 1442695040888963407ULL;
            u = (double)(st >> 11) / 9007199254740992.0;
            mag = pow(10.0, -12.0 + 14.0 * u);
            st = st * 6364136223846793005ULL + 1442695040888963407ULL;
            z[k] = ((st >> 63) ? -mag : mag) * ((k & 1) ? 0.05 : 1.0);
        }
        e = tri_error(z);
        tol = tolerance(z);
        worst = fmax(worst, e / tol);
        CHECK(e <= tol, "random triangle %d: error %.3g > %.3g", n, e, tol);
    }
    printf("random triangles: worst error %.2f of the tolerance\n", worst);
}

/* A cut by a level l(x) = c - x (x = barycentric l1 here): both sides add to the whole,
 * and the side l >= 0 equals the reference over the piece (split into triangles). */
static void test_clip(void)
{
    const double S = 0.5, z[6] = {0.0, 0.0, 7.0, 0.1, -3.0, -0.2};
    double E[6], whole[2], a[2] = {0, 0}, b[2] = {0, 0};
    double lev_a[3], lev_b[3];
    long double r1[2], r2[2];
    const double c = 0.4;
    int k;
    exps(z, E);
    lensrt_tri_integral(S, z, E, whole);
    // Level at the vertices (l1 = 0, 1, 0): c - l1
    lev_a[0] = c, lev_a[1] = c - 1.0, lev_a[2] = c;
    for (k = 0; k < 3; k++) lev_b[k] = -lev_a[k];
    lensrt_tri_integral_clipped(S, z, E, lev_a, 1, a);
    lensrt_tri_integral_clipped(S, z, E, lev_b, 1, b);
    CHECK(hypot(a[0] + b[0] - whole[0], a[1] + b[1] - whole[1]) < 1e-14 * S,
          "the two sides of a cut do not add to the whole");
    // The side l1 <= c: the quad (0,0), (c,0), (c,1-c), (0,1) in (l1, l2) as two
    // triangles: (0,0),(c,0),(c,1-c) of area S c (1 - c), and (0,0),(c,1-c),(0,1) of S c
    {
        const double zc = (1 - c) * z[0] + c * z[2], zci = (1 - c) * z[1] + c * z[3];
        const double zd = c * z[2] + (1 - c) * z[4], zdi = c * z[3] + (1 - c) * z[5];
        const double t1[6] = {z[0], z[1], zc, zci, zd, zdi}, t2[6] = {z[0], z[1], zd, zdi, z[4], z[5]};
        reference(S * c * (1 - c), t1, r1);
        reference(S * c, t2, r2);
        CHECK(hypotl(a[0] - (r1[0] + r2[0]), a[1] - (r1[1] + r2[1])) < 1e-13L * S,
              "the cut piece differs from the reference by %.3Lg", hypotl(a[0] - (r1[0] + r2[0]), a[1] - (r1[1] + r2[1])));
    }
    // A level positive everywhere keeps the whole, one negative everywhere nothing
    {
        const double pos[3] = {1, 2, 3}, neg[3] = {-1, -2, -3};
        double p[2] = {0, 0}, q[2] = {0, 0};
        lensrt_tri_integral_clipped(S, z, E, pos, 1, p);
        lensrt_tri_integral_clipped(S, z, E, neg, 1, q);
        CHECK(p[0] == whole[0] && p[1] == whole[1] && q[0] == 0 && q[1] == 0, "uncut levels change the integral");
    }
}

/* Mesh areas: a straight-bladed polygon exactly, the circle's inscribed 6 m-gon exactly,
 * curved blades converging as 1 / m^2 to their area. */
static double mesh_area(const lensrt_aperture *ap, double R, int rings)
{
    lensrt_mesh m;
    double a = 0.0;
    int t;
    if (lensrt_mesh_build(NULL, ap, R, rings, &m) != LENSRT_SUCCESS) return -1.0;
    CHECK(m.n_triangles == lensrt_mesh_triangles(ap, R, rings), "triangle count");
    for (t = 0; t < m.n_triangles; t++) {
        const int *v = m.tri + 3 * t;
        const double *p = m.xy;
        double s = 0.5 * ((p[2 * v[1]] - p[2 * v[0]]) * (p[2 * v[2] + 1] - p[2 * v[0] + 1]) -
                          (p[2 * v[2]] - p[2 * v[0]]) * (p[2 * v[1] + 1] - p[2 * v[0] + 1]));
        CHECK(s > 0 && fabs(s - m.area[t]) <= 1e-15 * R * R, "triangle %d not counter-clockwise or wrong area", t);
        a += m.area[t];
    }
    lensrt_mesh_free(NULL, &m);
    return a;
}

static void test_meshes(void)
{
    const double R = 2.5, PI_ = 3.14159265358979323846;
    lensrt_aperture ap = {0, 0, 0, 0, 0, 0, 0, 0};
    int m;
    for (m = 1; m <= 64; m *= 4) {
        double n = 6.0 * m, poly = 0.5 * n * R * R * sin(2 * PI_ / n);
        CHECK(fabs(mesh_area(&ap, R, m) - poly) < 1e-13 * R * R, "circle, %d rings: area", m);
    }
    ap.shape = LENSRT_APERTURE_BLADES;
    ap.blades = 7;
    ap.rotation_deg = 10.0;
    CHECK(fabs(mesh_area(&ap, R, 5) - 3.5 * R * R * sin(2 * PI_ / 7)) < 1e-13 * R * R, "7 straight blades: area");
    {
        // Curved blades: each adds the circular segment of its arc over the chord
        const double half = PI_ / 7, apothem = R * cos(half), chord = R * sin(half), sag = 0.3 * (R - apothem);
        const double rho = (chord * chord + sag * sag) / (2 * sag), th = 2 * asin(chord / rho);
        const double exact = 3.5 * R * R * sin(2 * half) + 7 * 0.5 * rho * rho * (th - sin(th));
        const double e16 = fabs(mesh_area(&(lensrt_aperture){LENSRT_APERTURE_BLADES, 0, 0, 7, 0.3, 10.0, 0, 0}, R, 16) - exact);
        const double e32 = fabs(mesh_area(&(lensrt_aperture){LENSRT_APERTURE_BLADES, 0, 0, 7, 0.3, 10.0, 0, 0}, R, 32) - exact);
        // The chords of an arc miss area of order h^2: halving h divides it by 4
        CHECK(e32 < 0.3 * e16 && e32 < 1e-4 * exact, "curved blades: area errors %.3g, %.3g", e16, e32);
    }
    {
        // Two slits, 0.2 mm wide, 1 mm apart, half height R: exactly 2 x 0.2 x 2 R
        lensrt_aperture s = {LENSRT_APERTURE_SLIT, 0, 0, 0, 0, 0, 0.2, 1.0};
        CHECK(fabs(mesh_area(&s, R, 4) - 0.8 * R) < 1e-13 * R * R, "double slit: area");
    }
}

/* The kernel's vectorised log of the transmittance amplitude (cpu/cells_kernel.c)
 * against libm's in long double: within 2 ulp of 0.5 log t from 1e-300 to 1e300
 * (log-uniform, and near the mantissa's sqrt(2) split and powers of two), the floor below
 * it and for t <= 0 or NaN, inf kept, the amplitude sqrt(t) exact. */
static void test_log_amplitude(void)
{
    enum { N = 20000 };
    static double st[N + 16], lnt[N + 16], t[N + 16];
    const double floor_ = -80.0;
    double worst = 0.0;
    unsigned s = 7u;
    int i, n = 0;
    for (i = 0; i < N; i++) {
        s = s * 1664525u + 1013904223u;
        t[n++] = pow(10.0, -300.0 + 600.0 * (double)(s >> 8) / 16777216.0);
    }
    {
        const double special[16] = {1.0, 2.0, 0.5, 1.4142135623730951, 1.4142135623730949, 0.7071067811865476,
                                    1.0 + 1e-15, 1.0 - 1e-16, 3.0, 0.9999, 1e-300, 2e-300,
                                    0.0, -1.0, NAN, INFINITY};
        for (i = 0; i < 16; i++) t[n++] = special[i];
    }
    for (i = 0; i < n; i++) st[i] = t[i];
    lensrt_cells_log_amplitude(n, st, lnt, floor_);
    for (i = 0; i < n; i++) {
        const double x = t[i];
        if (!(x > 0.0) || x != x) {
            CHECK(lnt[i] == floor_ && st[i] == 0.0, "t = %g: log amplitude %g, amplitude %g", x, lnt[i], st[i]);
        } else if (isinf(x)) {
            CHECK(isinf(lnt[i]) && isinf(st[i]), "t = inf: %g %g", lnt[i], st[i]);
        } else {
            const long double ref = 0.5L * logl((long double)x);
            const double want = ref < floor_ ? floor_ : (double)ref;
            const double ulp = nextafter(fabs(want), INFINITY) - fabs(want);
            const double err = want == floor_ ? (lnt[i] == floor_ ? 0.0 : 1e9) : fabs((double)((long double)lnt[i] - ref)) / ulp;
            if (err > worst) worst = err;
            CHECK(err <= 2.0, "t = %.17g: 0.5 log t %.17g, want %.17Lg (%.2f ulp)", x, lnt[i], ref, err);
            CHECK(st[i] == sqrt(x), "t = %.17g: amplitude", x);
        }
    }
    printf("log amplitude: worst %.2f ulp over %d values\n", worst, n);
}

int main(void)
{
    gauss_legendre();
    test_log_amplitude();
    test_singularities();
    test_random();
    test_clip();
    test_meshes();
    if (failures) {
        fprintf(stderr, "%d failures\n", failures);
        return 1;
    }
    printf("cells: every check passed\n");
    return 0;
}
