/* The pixel set-up's projection on the window's basis (runtime/src/core/basis.c),
 * compiled in: lensrt_basis_keep, written for speed (interchanged loops over a
 * transposed copy, exact l1 norms only where a triangle-inequality bound could pass the
 * limit), must give the very bits of its plain definition, written here as the
 * reference: every coordinate u[j] and the count kept, for every basis rank, for limits
 * at, just above and just below each tail's l1 norm (where one rounding would change
 * the count), and for zero, tiny, huge and NaN coefficients.
 *
 * The bases are those lensrt_prepare_basis builds (Jacobi eigenvectors of a window's
 * coefficient vectors), over a stub of the per-pixel polynomials: a few smooth functions
 * of the pixel times fixed vectors plus a small irregular part, so that the eigenvalues
 * fall off as a real window's do. */
#include "../../runtime/src/core/basis.h"
#include "internal_stubs.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The sensor powers carry the pixel; the stub polynomial reads x and y back. */
void lensrt_sensor_powers(const lensrt_lens lens, double x, double y, double px[16], double py[16])
{
    (void)lens;
    memset(px, 0, 16 * sizeof *px);
    memset(py, 0, 16 * sizeof *py);
    px[1] = x;
    py[1] = y;
}

/* c[k]: 1, x, y, x y, x^2 - y^2 times fixed vectors, plus 1e-9 of an irregular part. */
void lensrt_slot_coefficients(const lensrt_pixel_poly *p, const double *px, const double *py, double *c, int n_slots)
{
    const double x = px[1], y = py[1], f[5] = {1.0, x, y, x * y, x * x - y * y};
    int k, q;
    (void)p;
    for (k = 0; k < n_slots; k++) {
        c[k] = 1e-9 * sin(37.0 * k + 11.0 * x + 7.0 * y * k);
        for (q = 0; q < 5; q++) c[k] += f[q] * cos(1.3 * k * (q + 1) + q) / (1.0 + 0.2 * k);
    }
}

/* The definition: u = V^T c over k ascending, the residual over j ascending, then the
 * vectors added back from the last with the l1 norm after each. */
static int keep_reference(const double *V, int n, int R, const double *c, double limit, double *u)
{
    double res[135], l1 = 0.0;
    int j, k;
    for (j = 0; j < R; j++) {
        u[j] = 0.0;
        for (k = 0; k < n; k++) u[j] += V[k * n + j] * c[k + 1];
    }
    for (k = 0; k < n; k++) {
        res[k] = c[k + 1];
        for (j = 0; j < R; j++) res[k] -= V[k * n + j] * u[j];
        l1 += fabs(res[k]);
    }
    if (l1 > limit) return R + 1;
    for (j = R - 1; j >= 0; j--) {
        l1 = 0.0;
        for (k = 0; k < n; k++) {
            res[k] += V[k * n + j] * u[j];
            l1 += fabs(res[k]);
        }
        if (l1 > limit) return j + 1;
    }
    return 0;
}

/* The l1 norm of the residual after the leading m of R vectors (the reference's loop). */
static double tail_l1(const double *V, int n, const double *u, const double *c, int m)
{
    double l1 = 0.0;
    int k, j;
    for (k = 0; k < n; k++) {
        double res = c[k + 1];
        for (j = 0; j < m; j++) res -= V[k * n + j] * u[j];
        l1 += fabs(res);
    }
    return l1;
}

static int g_failed, g_checks;

static void check(int ok, const char *fmt, ...)
{
    g_checks++;
    if (!ok) {
        va_list ap;
        g_failed++;
        va_start(ap, fmt);
        fprintf(stderr, "FAIL: ");
        vfprintf(stderr, fmt, ap);
        va_end(ap);
        fputc('\n', stderr);
    }
}

static double urand(unsigned *s)
{
    *s = *s * 1664525u + 1013904223u;
    return (double)(*s >> 8) / 16777216.0;
}

/* One coefficient vector against the reference, at limit and at its neighbours. */
static void compare(lensrt_render r, int b, int R, const double *c, double limit, const char *what)
{
    const int n = r->n_slots - 1;
    const double *V = r->basis + (size_t)b * (size_t)n * (size_t)n;
    const double lims[3] = {limit, nextafter(limit, -INFINITY), nextafter(limit, INFINITY)};
    int i, j;
    for (i = 0; i < 3; i++) {
        double u0[135], u1[135];
        const int k0 = keep_reference(V, n, R, c, lims[i], u0), k1 = lensrt_basis_keep(r, b, R, c, lims[i], u1);
        int same = k0 == k1;
        for (j = 0; j < R; j++) same &= memcmp(&u0[j], &u1[j], sizeof(double)) == 0;
        check(same, "%s: basis %d rank %d limit %.17g: kept %d, reference %d (or u differs)", what, b, R, lims[i], k1,
              k0);
    }
}

int main(void)
{
    const int degrees[2] = {6, 15};
    int d;
    for (d = 0; d < 2; d++) {
        struct lensrt_render_s rs;
        lensrt_render r = &rs;
        double xs[12], ys[10], wl = 550.0;
        const int ns = (degrees[d] + 1) * (degrees[d] + 2) / 2, n = ns - 1;
        unsigned seed = 12345u + (unsigned)d;
        int i, b, trial;
        memset(&rs, 0, sizeof rs);
        for (i = 0; i < 12; i++) xs[i] = -1.0 + 2.0 * i / 11.0;
        for (i = 0; i < 10; i++) ys[i] = -0.8 + 1.6 * i / 9.0;
        r->n_slots = ns;
        r->width = 12;
        r->height = 10;
        r->xs = xs;
        r->ys = ys;
        r->n_wl = 1;
        r->wavelengths = &wl;
        r->desc.precision = LENSRT_PRECISION_DEFAULT;
        r->desc.device = LENSRT_DEVICE_CPU;
        r->desc.phase_tolerance_waves = 3e-3;
        check(lensrt_prepare_basis(r) == LENSRT_SUCCESS && r->use_basis && r->n_bases == 2, "degree %d: no bases",
              degrees[d]);
        if (!r->basis) return 1;
        // The transpose and the vectors' l1 norms that the fast path reads
        for (b = 0; b < r->n_bases; b++) {
            const double *V = r->basis + (size_t)b * (size_t)n * (size_t)n, *VT = r->basis_t + (size_t)b * (size_t)n * (size_t)n;
            int j, k, ok = 1;
            for (j = 0; j < n; j++) {
                double l1 = 0.0;
                for (k = 0; k < n; k++) {
                    ok &= VT[j * n + k] == V[k * n + j];
                    l1 += fabs(V[k * n + j]);
                }
                ok &= r->basis_l1[(size_t)b * (size_t)n + j] == l1;
            }
            check(ok, "degree %d basis %d: transpose or l1 norms differ from the basis", degrees[d], b);
        }
        for (trial = 0; trial < 300; trial++) {
            double c[136], u[135], x = 2.0 * urand(&seed) - 1.0, y = 2.0 * urand(&seed) - 1.0, px[16], py[16];
            const double *V;
            int R, m;
            b = trial % 2;
            V = r->basis + (size_t)b * (size_t)n * (size_t)n;
            R = trial % 3 == 0 ? n : 1 + (int)(urand(&seed) * n);
            lensrt_sensor_powers(NULL, x, y, px, py);
            lensrt_slot_coefficients(NULL, px, py, c, ns);
            if (trial % 5 == 1) c[1 + (int)(urand(&seed) * n)] = 0.0;
            if (trial % 7 == 2) c[1 + (int)(urand(&seed) * n)] *= 1e8;
            // Limits: each tail's own l1 norm (ties), the output's, zero, above all
            keep_reference(V, n, R, c, 0.0, u);
            for (m = 0; m <= R; m += 1 + R / 9) compare(r, b, R, c, tail_l1(V, n, u, c, m), "tail");
            compare(r, b, R, c, 3e-3, "tolerance");
            compare(r, b, R, c, 0.0, "zero");
            compare(r, b, R, c, 1e300, "huge");
            compare(r, b, R, c, 1e-300, "tiny");
        }
        {
            // Non-finite coefficients: the same answer as the reference, never a crash
            double c[136], px[16], py[16];
            lensrt_sensor_powers(NULL, 0.3, -0.2, px, py);
            lensrt_slot_coefficients(NULL, px, py, c, ns);
            c[3] = NAN;
            compare(r, 0, n, c, 3e-3, "NaN");
            c[3] = INFINITY;
            compare(r, 1, n / 2, c, 3e-3, "inf");
        }
        free(r->basis);
        free(r->basis_t);
        free(r->basis_l1);
        free(r->basis_rank);
    }
    printf("%d checks, %d failed\n", g_checks, g_failed);
    return g_failed != 0;
}
