/* The deterministic aperture integrator's backend-neutral parts: the mesh of the
 * aperture and the closed-form integral of exp(i z) over a triangle with z linear
 * (core/cells.h says why). */
#include "cells.h"
#include "nufft.h"

#include <math.h>
#include <string.h>

#define PI 3.14159265358979323846

/* ------------------------------------------------------------------ mesh ----- */

/* The boundary of one fan sector at parameter t in [0, 1]: a chord, an arc of a circle
 * (centre cx, cy, radius rho, angles b0 .. b0 + db), in mm. */
typedef struct sector {
    int arc;
    double x0, y0, x1, y1;     /* chord ends */
    double cx, cy, rho, b0, db; /* arc */
} sector;

static void sector_point(const sector *s, double t, double *x, double *y)
{
    if (s->arc) {
        double b = s->b0 + t * s->db;
        *x = s->cx + s->rho * cos(b);
        *y = s->cy + s->rho * sin(b);
    } else {
        *x = s->x0 + t * (s->x1 - s->x0);
        *y = s->y0 + t * (s->y1 - s->y0);
    }
}

/* The sectors of a fan shape: 6 for a circle, one per blade (edges as
 * lensrt_aperture_contains draws them: vertices on the circle at rot + 2 k pi / n, a
 * curved blade the arc through them bulging by curvature * (R - apothem)). */
static int fan_sectors(const lensrt_aperture *ap, double R, sector *sec)
{
    int k, n;
    if (ap->shape != LENSRT_APERTURE_BLADES) {
        n = 6;
        for (k = 0; k < n; k++) {
            memset(&sec[k], 0, sizeof sec[k]);
            sec[k].arc = 1;
            sec[k].rho = R;
            sec[k].b0 = 2.0 * PI * k / n;
            sec[k].db = 2.0 * PI / n;
        }
        return n;
    }
    {
        const double half = PI / ap->blades, rot = ap->rotation_deg * (PI / 180.0);
        const double apothem = R * cos(half), chord = R * sin(half);
        const double sag = ap->blade_curvature * (R - apothem);
        n = ap->blades;
        for (k = 0; k < n; k++) {
            const double a0 = rot + 2.0 * k * half, a1 = a0 + 2.0 * half, mid = a0 + half;
            sector *s = &sec[k];
            memset(s, 0, sizeof *s);
            s->x0 = R * cos(a0);
            s->y0 = R * sin(a0);
            s->x1 = R * cos(a1);
            s->y1 = R * sin(a1);
            if (sag > 1e-12 * R) { /* the same threshold as lensrt_aperture_contains */
                const double rho = (chord * chord + sag * sag) / (2.0 * sag), d = apothem + sag - rho;
                double b1;
                s->arc = 1;
                s->rho = rho;
                s->cx = d * cos(mid);
                s->cy = d * sin(mid);
                s->b0 = atan2(s->y0 - s->cy, s->x0 - s->cx);
                b1 = atan2(s->y1 - s->cy, s->x1 - s->cx);
                s->db = remainder(b1 - s->b0, 2.0 * PI);
            }
        }
        return n;
    }
}

/* A slit's rows of cells: as many as keep the cells near square, at most 16 per ring. */
static int slit_rows(const lensrt_aperture *ap, double R, int rings)
{
    const double h = 0.5 * ap->slit_width_mm;
    double ny = rings * (R / h);
    if (!(ny >= 1.0)) ny = 1.0;
    if (ny > 16.0 * rings) ny = 16.0 * rings;
    return (int)ceil(ny - 1e-9);
}

long lensrt_mesh_triangles(const lensrt_aperture *ap, double radius_mm, int rings)
{
    if (ap->shape == LENSRT_APERTURE_SLIT) {
        const int ns = ap->slit_separation_mm > 0.0 ? 2 : 1;
        return 2L * ns * rings * slit_rows(ap, radius_mm, rings);
    }
    return (long)(ap->shape == LENSRT_APERTURE_BLADES ? ap->blades : 6) * rings * rings;
}

void lensrt_mesh_free(lensrt_context ctx, lensrt_mesh *m)
{
    lensrt_free(ctx, m->xy);
    lensrt_free(ctx, m->tri);
    lensrt_free(ctx, m->area);
    lensrt_free(ctx, m->strip);
    memset(m, 0, sizeof *m);
}

/* A strip of n triangles (a + k, b + k, c + k), each with its area. */
static void add_strip(lensrt_mesh *m, int n, int a, int b, int c)
{
    const double *p = m->xy;
    int k, *st = m->strip + 5 * m->n_strips++;
    st[0] = m->n_triangles;
    st[1] = n;
    st[2] = a;
    st[3] = b;
    st[4] = c;
    for (k = 0; k < n; k++) {
        const int i = a + k, j = b + k, l = c + k;
        int *t = m->tri + 3 * m->n_triangles;
        t[0] = i;
        t[1] = j;
        t[2] = l;
        m->area[m->n_triangles++] = 0.5 * fabs((p[2 * j] - p[2 * i]) * (p[2 * l + 1] - p[2 * i + 1]) -
                                               (p[2 * l] - p[2 * i]) * (p[2 * j + 1] - p[2 * i + 1]));
    }
}

lensrt_result lensrt_mesh_build(lensrt_context ctx, const lensrt_aperture *ap, double radius_mm, int rings,
                                lensrt_mesh *m)
{
    const long nt = lensrt_mesh_triangles(ap, radius_mm, rings);
    long nv;
    int ns = 0, rows = 0, n_slits = 0;
    sector sec[LENSRT_MAX_BLADES > 6 ? LENSRT_MAX_BLADES : 6];
    memset(m, 0, sizeof *m);
    if (ap->shape == LENSRT_APERTURE_SLIT) {
        n_slits = ap->slit_separation_mm > 0.0 ? 2 : 1;
        rows = slit_rows(ap, radius_mm, rings);
        nv = (long)n_slits * (rings + 1) * (rows + 1);
    } else {
        ns = fan_sectors(ap, radius_mm, sec);
        nv = (long)ns * (rings + 1) * (rings + 2) / 2;
    }
    if (nt > 200000000L || nv > 200000000L)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "cells: %d rings make %ld triangles, too many", rings, nt);
    m->xy = lensrt_calloc(ctx, (size_t)nv * 2, sizeof(double));
    m->tri = lensrt_calloc(ctx, (size_t)nt * 3, sizeof(int));
    m->area = lensrt_calloc(ctx, (size_t)nt, sizeof(double));
    m->strip = lensrt_calloc(ctx, 5 * (size_t)(n_slits ? 2 * n_slits * rows : 2 * ns * rings), sizeof(int));
    if (!m->xy || !m->tri || !m->area || !m->strip) {
        lensrt_mesh_free(ctx, m);
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "cells: out of memory for %ld triangles", nt);
    }
    if (n_slits) {
        // Each slit a grid of rings x rows rectangles, two right triangles each
        const double h = 0.5 * ap->slit_width_mm, R = radius_mm;
        int s, i, j;
        for (s = 0; s < n_slits; s++) {
            const double c = n_slits == 2 ? (s ? -0.5 : 0.5) * ap->slit_separation_mm : 0.0;
            const int v0 = m->n_vertices;
            for (j = 0; j <= rows; j++)
                for (i = 0; i <= rings; i++) {
                    m->xy[2 * m->n_vertices] = c - h + 2.0 * h * i / rings;
                    m->xy[2 * m->n_vertices + 1] = -R + 2.0 * R * j / rows;
                    m->n_vertices++;
                }
            for (j = 0; j < rows; j++) {
                // Row j's rectangles (a, a + 1, e = a + rings + 2, d = a + rings + 1)
                const int a = v0 + j * (rings + 1);
                add_strip(m, rings, a, a + 1, a + rings + 2);
                add_strip(m, rings, a, a + rings + 2, a + rings + 1);
            }
        }
        return LENSRT_SUCCESS;
    }
    {
        // Fan sectors: vertex (i, j) of ring i at rho = i / rings, theta = j / i
        int s, i, j;
        for (s = 0; s < ns; s++) {
            const int v0 = m->n_vertices;
            for (i = 0; i <= rings; i++)
                for (j = 0; j <= i; j++) {
                    double bx = 0.0, by = 0.0, rho = (double)i / rings;
                    if (i > 0) sector_point(&sec[s], (double)j / i, &bx, &by);
                    m->xy[2 * m->n_vertices] = rho * bx;
                    m->xy[2 * m->n_vertices + 1] = rho * by;
                    m->n_vertices++;
                }
            for (i = 0; i < rings; i++) {
                // Between rings i and i + 1: i + 1 triangles pointing out, i pointing in
                const int r0 = v0 + i * (i + 1) / 2, r1 = v0 + (i + 1) * (i + 2) / 2;
                add_strip(m, i + 1, r0, r1, r1 + 1);
                if (i > 0) add_strip(m, i, r0, r1 + 1, r0 + 1);
            }
        }
    }
    return LENSRT_SUCCESS;
}

/* ------------------------------------------------------------ quadrature ----- */

/* B'(t) of a sector's boundary (mm per unit t). */
static void sector_tangent(const sector *s, double t, double *dx, double *dy)
{
    if (s->arc) {
        const double b = s->b0 + t * s->db;
        *dx = -s->rho * s->db * sin(b);
        *dy = s->rho * s->db * cos(b);
    } else {
        *dx = s->x1 - s->x0;
        *dy = s->y1 - s->y0;
    }
}

void lensrt_quadrature_free(lensrt_context ctx, lensrt_quadrature *q)
{
    lensrt_free(ctx, q->xy);
    lensrt_free(ctx, q->w);
    lensrt_free(ctx, q->ua);
    lensrt_free(ctx, q->ub);
    memset(q, 0, sizeof *q);
}

lensrt_result lensrt_quadrature_build(lensrt_context ctx, const lensrt_aperture *ap, double radius_mm, int n,
                                      lensrt_quadrature *q)
{
    sector sec[LENSRT_MAX_BLADES > 6 ? LENSRT_MAX_BLADES : 6];
    const int slit = ap->shape == LENSRT_APERTURE_SLIT, n_slits = ap->slit_separation_mm > 0.0 ? 2 : 1;
    const int rows = slit ? slit_rows(ap, radius_mm, n) : 0, ns = slit ? 0 : fan_sectors(ap, radius_mm, sec);
    const double total = slit ? (double)n_slits * n * rows : (double)ns * n * n;
    double *gx = NULL, *gw = NULL, *hx = NULL, *hw = NULL;
    int s, i, j;
    memset(q, 0, sizeof *q);
    if (n < 1 || total > 2e8)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "fourier: %d nodes per side make %.0f nodes, too many",
                           n, total);
    q->xy = lensrt_calloc(ctx, 2 * (size_t)total, sizeof(double));
    q->w = lensrt_calloc(ctx, (size_t)total, sizeof(double));
    gx = lensrt_calloc(ctx, (size_t)n, sizeof(double));
    gw = lensrt_calloc(ctx, (size_t)n, sizeof(double));
    if (slit) {
        hx = lensrt_calloc(ctx, (size_t)rows, sizeof(double));
        hw = lensrt_calloc(ctx, (size_t)rows, sizeof(double));
    }
    q->ua = lensrt_calloc(ctx, (size_t)n, sizeof(double));
    q->ub = lensrt_calloc(ctx, (size_t)(slit ? rows : n), sizeof(double));
    if (!q->xy || !q->w || !gx || !gw || (slit && (!hx || !hw)) || !q->ua || !q->ub) {
        lensrt_free(ctx, gx);
        lensrt_free(ctx, gw);
        lensrt_free(ctx, hx);
        lensrt_free(ctx, hw);
        lensrt_quadrature_free(ctx, q);
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "fourier: out of memory for %.0f nodes", total);
    }
    lensrt_gauss_legendre01(n, gx, gw);
    q->na = n;
    q->nb = slit ? rows : n;
    q->patches = slit ? n_slits : ns;
    memcpy(q->ua, gx, sizeof(double) * (size_t)n);
    if (!slit) memcpy(q->ub, gx, sizeof(double) * (size_t)n);
    if (slit) {
        // Each slit: n nodes across its width, `rows` along its height
        const double h = 0.5 * ap->slit_width_mm, R = radius_mm;
        lensrt_gauss_legendre01(rows, hx, hw);
        memcpy(q->ub, hx, sizeof(double) * (size_t)rows);
        for (s = 0; s < n_slits; s++) {
            const double c = n_slits == 2 ? (s ? -0.5 : 0.5) * ap->slit_separation_mm : 0.0;
            for (j = 0; j < rows; j++)
                for (i = 0; i < n; i++) {
                    q->xy[2 * q->n] = c - h + 2.0 * h * gx[i];
                    q->xy[2 * q->n + 1] = -R + 2.0 * R * hx[j];
                    q->w[q->n++] = 4.0 * h * R * gw[i] * hw[j];
                }
        }
    } else {
        // Each sector: x = rho B(t), dA = rho |B x B'| d rho dt
        for (s = 0; s < ns; s++)
            for (j = 0; j < n; j++) {
                double bx, by, dx, dy, jac;
                sector_point(&sec[s], gx[j], &bx, &by);
                sector_tangent(&sec[s], gx[j], &dx, &dy);
                jac = fabs(bx * dy - by * dx);
                for (i = 0; i < n; i++) {
                    q->xy[2 * q->n] = gx[i] * bx;
                    q->xy[2 * q->n + 1] = gx[i] * by;
                    q->w[q->n++] = gx[i] * jac * gw[i] * gw[j];
                }
            }
    }
    lensrt_free(ctx, gx);
    lensrt_free(ctx, gw);
    lensrt_free(ctx, hx);
    lensrt_free(ctx, hw);
    return LENSRT_SUCCESS;
}

/* ------------------------------------------------- integral over a triangle ----- */

typedef struct cpx {
    double re, im;
} cpx;

static cpx c_mul(cpx a, cpx b) { return (cpx){a.re * b.re - a.im * b.im, a.re * b.im + a.im * b.re}; }
static cpx c_sub(cpx a, cpx b) { return (cpx){a.re - b.re, a.im - b.im}; }
/* a / b through one real division: |b| is at least 1/32 wherever it is used here (the
 * series take the closer nodes) and at most a few thousand radians, so |b|^2 neither
 * overflows nor underflows. */
static cpx c_div(cpx a, cpx b)
{
    const double k = 1.0 / (b.re * b.re + b.im * b.im);
    return (cpx){(a.re * b.re + a.im * b.im) * k, (a.im * b.re - a.re * b.im) * k};
}
static double c_abs1(cpx a) { return fabs(a.re) > fabs(a.im) ? fabs(a.re) : fabs(a.im); }

/* Where the series take over (in the max norm of the components, so within sqrt(2)
 * of it in modulus):
 *   SERIES_G: every node within 0.1 of z0: the series of G below, 10 terms;
 *   SERIES_D: two nodes within 1/32 of each other: phi1's series, 6 terms.
 * Elsewhere the divided differences lose at most about log10(s / 2^-5 / 0.1) digits to
 * cancellation (s: the largest difference): 2e-13 relative for s up to 100 radians. */
#define SERIES_G LENSRT_CELLS_SERIES_G
#define SERIES_D LENSRT_CELLS_SERIES_D

/* G(a, b) = integral over the unit simplex {l1, l2 >= 0, l1 + l2 <= 1} of
 * exp(i (l1 a + l2 b)) = sum_m i^m h_m(a, b) / (m + 2)!, h_m = sum_j a^j b^(m-j) the
 * complete homogeneous polynomial (Hermite-Genocchi: the second divided difference of
 * exp(i t) at 0, a, b, times -1). With |a|, |b| <= 0.1 sqrt(2) term m is below
 * (m + 1) 0.1414^m / (m + 2)!: terms 0 .. 9 leave 3e-20 of G(0, 0) = 1/2. */
static cpx g_series(cpx a, cpx b)
{
    cpx h = {1.0, 0.0}, ap = {1.0, 0.0}, ip = {1.0, 0.0}, sum = {0.5, 0.0};
    double inv_fact = 0.5;
    int m;
    for (m = 1; m <= 9; m++) {
        cpx t;
        ap = c_mul(ap, a);
        h = c_mul(h, b);
        h.re += ap.re;
        h.im += ap.im;
        ip = (cpx){-ip.im, ip.re}; /* i^m */
        inv_fact /= (double)(m + 2);
        t = c_mul(ip, h);
        sum.re += t.re * inv_fact;
        sum.im += t.im * inv_fact;
    }
    return sum;
}

/* The first divided difference of exp(i t) at p, q (values Ep, Eq):
 * (Eq - Ep) / (q - p), or for close nodes Ep i phi1(i d), d = q - p,
 * phi1(w) = (e^w - 1) / w = sum_n w^n / (n + 1)! (|w| <= 0.0442: terms 0 .. 6 leave
 * less than 0.0442^7 / 8! = 8e-15 / 40320 = 2e-19). */
static cpx dd1(cpx p, cpx q, cpx Ep, cpx Eq)
{
    cpx d = c_sub(q, p);
    if (c_abs1(d) > SERIES_D) return c_div(c_sub(Eq, Ep), d);
    {
        // Horner: phi1(w) = 1 + w/2 (1 + w/3 (1 + w/4 (1 + w/5 (1 + w/6 (1 + w/7)))))
        const cpx w = {-d.im, d.re};
        cpx s = {1.0, 0.0};
        int n;
        for (n = 7; n >= 2; n--) {
            s = c_mul(s, w);
            s.re = 1.0 + s.re / n;
            s.im /= n;
        }
        s = c_mul(s, Ep);
        return (cpx){-s.im, s.re}; /* i Ep phi1(w) */
    }
}

void lensrt_tri_integral(double S, const double z[6], const double E[6], double out[2])
{
    const cpx z0 = {z[0], z[1]}, z1 = {z[2], z[3]}, z2 = {z[4], z[5]};
    const cpx E0 = {E[0], E[1]}, E1 = {E[2], E[3]}, E2 = {E[4], E[5]};
    const cpx a = c_sub(z1, z0), b = c_sub(z2, z0), c = c_sub(z2, z1);
    const double da = c_abs1(a), db = c_abs1(b), dc = c_abs1(c);
    cpx g;
    if (da <= SERIES_G && db <= SERIES_G) {
        // Close nodes: the series about z0, times E0
        g = c_mul(E0, g_series(a, b));
    } else if (da > SERIES_D && db > SERIES_D && dc > SERIES_D) {
        // Nodes apart: f[z0, z1, z2] = (E0 c - E1 b + E2 a) / (a b c), one division
        const cpx num = {E0.re * c.re - E0.im * c.im - (E1.re * b.re - E1.im * b.im) + E2.re * a.re - E2.im * a.im,
                         E0.re * c.im + E0.im * c.re - (E1.re * b.im + E1.im * b.re) + E2.re * a.im + E2.im * a.re};
        g = c_div(num, c_mul(c_mul(a, b), c));
        g = (cpx){-g.re, -g.im};
    } else {
        // Two nodes close, the third apart: the recursion over the pair farthest apart,
        // f[p, q, r] = (f[q, r] - f[p, q]) / (r - p), G = -f[z0, z1, z2]
        cpx f;
        if (da >= db && da >= dc) /* p = z0, r = z1, q = z2 */
            f = c_div(c_sub(dd1(z2, z1, E2, E1), dd1(z0, z2, E0, E2)), a);
        else if (db >= dc) /* p = z0, r = z2, q = z1 */
            f = c_div(c_sub(dd1(z1, z2, E1, E2), dd1(z0, z1, E0, E1)), b);
        else /* p = z1, r = z2, q = z0 */
            f = c_div(c_sub(dd1(z0, z2, E0, E2), dd1(z1, z0, E1, E0)), c);
        g = (cpx){-f.re, -f.im};
    }
    // The simplex has area 1/2: the triangle's integral is 2 S times it
    out[0] = 2.0 * S * g.re;
    out[1] = 2.0 * S * g.im;
}

/* A vertex of a clipped polygon: barycentric position, z and the levels. */
typedef struct cvert {
    double b1, b2, z[2], lev[LENSRT_CELLS_MAX_LEVELS];
} cvert;

void lensrt_tri_integral_clipped(double S, const double z[6], const double E[6], const double *lev, int n_lev,
                                 double out[2])
{
    cvert buf[2][3 + LENSRT_CELLS_MAX_LEVELS];
    int n = 3, k, l, cur = 0, all_in = 1;
    // Quick decisions: every level >= 0 at every vertex (whole), one < 0 at all (none)
    for (l = 0; l < n_lev; l++) {
        int neg = 0;
        for (k = 0; k < 3; k++) neg += lev[k * n_lev + l] < 0.0;
        if (neg == 3) return;
        if (neg) all_in = 0;
    }
    if (all_in) {
        double o[2];
        lensrt_tri_integral(S, z, E, o);
        out[0] += o[0];
        out[1] += o[1];
        return;
    }
    // Sutherland-Hodgman in barycentric coordinates, one level at a time
    for (k = 0; k < 3; k++) {
        buf[0][k].b1 = k == 1;
        buf[0][k].b2 = k == 2;
        buf[0][k].z[0] = z[2 * k];
        buf[0][k].z[1] = z[2 * k + 1];
        for (l = 0; l < n_lev; l++) buf[0][k].lev[l] = lev[k * n_lev + l];
    }
    for (l = 0; l < n_lev && n > 0; l++) {
        const cvert *in = buf[cur];
        cvert *o = buf[1 - cur];
        int m = 0;
        for (k = 0; k < n; k++) {
            const cvert *p = &in[k], *q = &in[(k + 1) % n];
            const int pin = p->lev[l] >= 0.0, qin = q->lev[l] >= 0.0;
            if (pin) o[m++] = *p;
            if (pin != qin) {
                // The zero of the level on edge p q, everything interpolated there
                const double t = p->lev[l] / (p->lev[l] - q->lev[l]);
                cvert *v = &o[m++];
                int j;
                v->b1 = p->b1 + t * (q->b1 - p->b1);
                v->b2 = p->b2 + t * (q->b2 - p->b2);
                v->z[0] = p->z[0] + t * (q->z[0] - p->z[0]);
                v->z[1] = p->z[1] + t * (q->z[1] - p->z[1]);
                for (j = 0; j < n_lev; j++) v->lev[j] = p->lev[j] + t * (q->lev[j] - p->lev[j]);
                v->lev[l] = 0.0;
            }
        }
        n = m;
        cur = 1 - cur;
    }
    // The clipped polygon (convex) as a fan of triangles
    if (n < 3) return;
    {
        const cvert *P = buf[cur];
        double Ev[2 * (3 + LENSRT_CELLS_MAX_LEVELS)];
        for (k = 0; k < n; k++) {
            const double a = exp(-P[k].z[1]);
            Ev[2 * k] = a * cos(P[k].z[0]);
            Ev[2 * k + 1] = a * sin(P[k].z[0]);
        }
        for (k = 1; k + 1 < n; k++) {
            // Area of the piece: S times twice its area in barycentric coordinates
            const double det = (P[k].b1 - P[0].b1) * (P[k + 1].b2 - P[0].b2) -
                               (P[k].b2 - P[0].b2) * (P[k + 1].b1 - P[0].b1);
            double zz[6], EE[6], o[2];
            zz[0] = P[0].z[0], zz[1] = P[0].z[1], zz[2] = P[k].z[0], zz[3] = P[k].z[1];
            zz[4] = P[k + 1].z[0], zz[5] = P[k + 1].z[1];
            EE[0] = Ev[0], EE[1] = Ev[1], EE[2] = Ev[2 * k], EE[3] = Ev[2 * k + 1];
            EE[4] = Ev[2 * k + 2], EE[5] = Ev[2 * k + 3];
            lensrt_tri_integral(S * fabs(det), zz, EE, o);
            out[0] += o[0];
            out[1] += o[1];
        }
    }
}

/* ------------------------------------------------------------ stop level ----- */

double lensrt_stop_shape_level(const lensrt_stop_shape *s, double x, double y)
{
    const double r2 = x * x + y * y, R = sqrt(s->r2);
    double lv = (s->r2 - r2) / (2.0 * R);
    int k;
    if (s->kind == LENSRT_STOP_BLADES) {
        for (k = 0; k < s->n; k++) {
            double e = s->c[k] - (s->a * r2 + s->gx[k] * x + s->gy[k] * y);
            if (e < lv) lv = e;
        }
    } else if (s->kind == LENSRT_STOP_SLIT) {
        double best = -INFINITY;
        for (k = 0; k < s->n; k++) {
            double e = s->half_x - fabs(x - s->centre[k]), f = s->half_y - fabs(y);
            if (f < e) e = f;
            if (e > best) best = e;
        }
        lv = best;
    }
    return lv;
}
