/* The window's bases and the pruning limits.
 *
 * The phase coefficient vectors of a window's pixels span a low-dimensional space (in a
 * PSF window: the phase at the centre plus two tilts). The eigenvectors of their Gram
 * matrix over a grid of the window's pixels (cyclic Jacobi) give a basis in which a
 * pixel needs about 3 terms instead of 30; each pixel keeps the fewest leading vectors
 * whose dropped tail stays under its output's limit, so the basis only ever speeds
 * things up. The limits are here so that both devices use one definition (the Huygens
 * step, which both use too, is core/specialise.c's, with the amplitude it is the step of). */
#include "basis.h"

#include "specialise.h"

#include <math.h>
#include <string.h>

/* Eigenvectors of the symmetric n x n matrix a (destroyed) by cyclic Jacobi rotations,
 * as columns of v, sorted by decreasing eigenvalue. */
static void jacobi_eigen(int n, double *a, double *v, double *eig)
{
    int sweep, p, q, k;
    for (p = 0; p < n; p++)
        for (q = 0; q < n; q++) v[p * n + q] = p == q;
    for (sweep = 0; sweep < 60; sweep++) {
        double off = 0.0, diag = 0.0;
        for (p = 0; p < n; p++) {
            diag += a[p * n + p] * a[p * n + p];
            for (q = p + 1; q < n; q++) off += a[p * n + q] * a[p * n + q];
        }
        if (off <= 1e-30 * diag || off == 0.0) break;
        for (p = 0; p < n; p++)
            for (q = p + 1; q < n; q++) {
                double apq = a[p * n + q], theta, t, c, s;
                if (fabs(apq) < 1e-300) continue;
                // Rotate rows and columns p, q so that a[p][q] becomes 0
                theta = (a[q * n + q] - a[p * n + p]) / (2.0 * apq);
                t = (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
                c = 1.0 / sqrt(t * t + 1.0);
                s = t * c;
                for (k = 0; k < n; k++) {
                    double akp = a[k * n + p], akq = a[k * n + q];
                    a[k * n + p] = c * akp - s * akq;
                    a[k * n + q] = s * akp + c * akq;
                }
                for (k = 0; k < n; k++) {
                    double apk = a[p * n + k], aqk = a[q * n + k];
                    a[p * n + k] = c * apk - s * aqk;
                    a[q * n + k] = s * apk + c * aqk;
                }
                for (k = 0; k < n; k++) {
                    double vkp = v[k * n + p], vkq = v[k * n + q];
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
    }
    for (p = 0; p < n; p++) eig[p] = a[p * n + p];
    // Selection sort of the columns by decreasing eigenvalue
    for (p = 0; p < n; p++) {
        int best = p;
        for (q = p + 1; q < n; q++)
            if (eig[q] > eig[best]) best = q;
        if (best == p) continue;
        { double t = eig[p]; eig[p] = eig[best]; eig[best] = t; }
        for (k = 0; k < n; k++) {
            double t = v[k * n + p];
            v[k * n + p] = v[k * n + best];
            v[k * n + best] = t;
        }
    }
}

/* Every pixel's set-up calls this (twice or more), so it is written for speed while
 * giving the bits of the plain loops: each u[j] and res[k] takes its terms in the same
 * order as there (u over k ascending, the residual over j ascending, then back from the
 * last vector), the loops only interchanged so that they run along contiguous memory
 * (V for u, its transpose for the residual). Adding vectors back, the exact l1 norm is
 * needed only where it could exceed the limit: the last exact norm plus |u_j| |V_j|_1
 * for each vector added since bounds it (triangle inequality), and while that bound is
 * under the limit (with 1e-12 to spare, far above the sums' rounding of n eps) the
 * vectors wait and are added in their order when a norm is next computed. */
int lensrt_basis_keep(const lensrt_render r, int b, int R, const double *c, double limit, double *u)
{
    const int n = r->n_slots - 1;
    const double *V = r->basis + (size_t)b * (size_t)n * (size_t)n;
    const double *VT = r->basis_t + (size_t)b * (size_t)n * (size_t)n, *norm1 = r->basis_l1 + (size_t)b * (size_t)n;
    double res[135], l1 = 0.0, bound;
    int j, k, q, added = R;
    // u = V^T c: row k of V adds c_k times itself to every u[j]
    for (j = 0; j < R; j++) u[j] = 0.0;
    for (k = 0; k < n; k++) {
        const double ck = c[k + 1], *row = V + (size_t)k * (size_t)n;
        for (j = 0; j < R; j++) u[j] += row[j] * ck;
    }
    // Residual after all R vectors
    for (k = 0; k < n; k++) res[k] = c[k + 1];
    for (j = 0; j < R; j++) {
        const double uj = u[j], *col = VT + (size_t)j * (size_t)n;
        for (k = 0; k < n; k++) res[k] -= col[k] * uj;
    }
    for (k = 0; k < n; k++) l1 += fabs(res[k]);
    if (l1 > limit) return R + 1;
    // Add them back from the last one (vectors j .. added - 1 wait in the bound)
    bound = l1;
    for (j = R - 1; j >= 0; j--) {
        bound += fabs(u[j]) * norm1[j];
        if (bound * (1.0 + 1e-12) <= limit) continue;
        for (q = added - 1; q >= j; q--) {
            const double uq = u[q], *col = VT + (size_t)q * (size_t)n;
            for (k = 0; k < n; k++) res[k] += col[k] * uq;
        }
        added = j;
        l1 = 0.0;
        for (k = 0; k < n; k++) l1 += fabs(res[k]);
        if (l1 > limit) return j + 1;
        bound = l1;
    }
    return 0;
}

/* The largest l1 norm of the non-constant coefficients an output may drop: inner pupil
 * position 0.01% of the housing, transmittance 1e-3 relative (5e-4 in amplitude), phase
 * the render's tolerance (waves). */
double lensrt_output_limit(const lensrt_render r, int o, double c0)
{
    // 4 + o: a ghost's P_clip output o, 0.01% of its pair's limit as for the inner pupil
    if (o >= 4) return 1e-4 * r->clip_limit[(o - 4) / 2];
    return o < 2 ? 1e-4 * r->lens->housing_last_mm : o == 2 ? 1e-3 * fabs(c0) : r->desc.phase_tolerance_waves;
}

/* The window's bases per wavelength and output: eigenvectors of sum_p c_p c_p^T over a
 * grid of up to 33 x 33 pixels of the window (c_p: the pixel's non-constant coefficients
 * of the output, the phase in waves). Each pixel later keeps the fewest leading basis
 * vectors whose dropped tail stays under the output's limit, so the basis only ever
 * speeds things up. The CPU path uses the phase and transmittance bases (b = 0, 1), the
 * GL path all four outputs in order (x_i, y_i, tau_i, phi_i). */
lensrt_result lensrt_prepare_basis(lensrt_render r)
{
    const int ns = r->n_slots, n = ns - 1;
    const int gl = r->desc.device == LENSRT_DEVICE_GL;
    int w, k, q, grid_x = r->width < 33 ? r->width : 33, grid_y = r->height < 33 ? r->height : 33;
    double *g, *eig, *cs;
    r->n_rows = ns;
    r->use_basis = (r->desc.precision == LENSRT_PRECISION_DEFAULT || gl) && n > 0;
    if (!r->use_basis) return LENSRT_SUCCESS;
    // CPU: phase and transmittance, then a ghost's P_clip outputs on side P_s (each
    // tested pair is x, y of the stop or a housing: smooth across a window, so a few
    // basis functions carry it); GL: the four outputs
    r->n_bases = gl ? 4 : 2 + (r->clip_s ? 2 * r->n_clip_pairs : 0);
    for (k = 0; k < r->n_bases; k++) r->basis_output[k] = gl ? k : k >= 2 ? 4 + (k - 2) : (k ? 2 : 3);
    r->basis = lensrt_calloc(r->ctx, (size_t)r->n_wl * (size_t)r->n_bases * (size_t)n * (size_t)n, sizeof(double));
    r->basis_t = lensrt_calloc(r->ctx, (size_t)r->n_wl * (size_t)r->n_bases * (size_t)n * (size_t)n, sizeof(double));
    r->basis_l1 = lensrt_calloc(r->ctx, (size_t)r->n_wl * (size_t)r->n_bases * (size_t)n, sizeof(double));
    r->basis_rank = lensrt_calloc(r->ctx, (size_t)r->n_wl * (size_t)r->n_bases, sizeof(int));
    g = lensrt_calloc(r->ctx, (size_t)n * (size_t)n, sizeof(double));
    eig = lensrt_calloc(r->ctx, (size_t)n, sizeof(double));
    cs = lensrt_calloc(r->ctx, (size_t)(grid_x * grid_y) * (size_t)ns, sizeof(double));
    if (!r->basis || !r->basis_t || !r->basis_l1 || !r->basis_rank || !g || !eig || !cs) {
        lensrt_free(r->ctx, g);
        lensrt_free(r->ctx, eig);
        lensrt_free(r->ctx, cs);
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
    }
    for (w = 0; w < r->n_bases * r->n_wl; w++) {
        /* basis b = w % n_bases of wavelength w / n_bases, for output o */
        int o = r->basis_output[w % r->n_bases], cell;
        double inv_lambda = o == 3 ? LENSRT_NM_PER_MM / r->wavelengths[w / r->n_bases] : 1.0;
        const double *V = r->basis + (size_t)w * (size_t)n * (size_t)n;
        // The grid's coefficients, then their Gram matrix (phase in waves)
        for (cell = 0; cell < grid_x * grid_y; cell++) {
            int gi = cell % grid_x, gj = cell / grid_x;
            int ix = grid_x > 1 ? (int)((double)gi * (r->width - 1) / (grid_x - 1) + 0.5) : 0;
            int iy = grid_y > 1 ? (int)((double)gj * (r->height - 1) / (grid_y - 1) + 0.5) : 0;
            double px[16], py[16], *c = cs + (size_t)cell * (size_t)ns;
            lensrt_sensor_powers(r->lens, r->xs[ix], r->ys[iy], px, py);
            lensrt_slot_coefficients(o < 4 ? &r->ps[(w / r->n_bases) * 4 + o]
                                           : &r->clip_s[(w / r->n_bases) * 2 * r->n_clip_pairs + (o - 4)],
                                     px, py, c, ns);
        }
        memset(g, 0, sizeof(double) * (size_t)n * (size_t)n);
        for (cell = 0; cell < grid_x * grid_y; cell++) {
            const double *c = cs + (size_t)cell * (size_t)ns;
            for (k = 0; k < n; k++)
                for (q = 0; q < n; q++) g[k * n + q] += c[k + 1] * c[q + 1] * inv_lambda * inv_lambda;
        }
        jacobi_eigen(n, g, r->basis + (size_t)w * (size_t)n * (size_t)n, eig);
        // Its transpose and the vectors' l1 norms (lensrt_basis_keep; GL's dropped-term bound)
        for (k = 0; k < n; k++) {
            double *l1 = r->basis_l1 + (size_t)w * (size_t)n + k;
            for (q = 0; q < n; q++) {
                r->basis_t[(size_t)w * (size_t)n * (size_t)n + (size_t)k * (size_t)n + q] = V[q * n + k];
                *l1 += fabs(V[q * n + k]);
            }
        }
        // How many basis vectors the grid's pixels need (others fall back to monomials);
        // the GL path finds every pixel's need on the device instead
        r->basis_rank[w] = 0;
        if (gl) continue;
        for (cell = 0; cell < grid_x * grid_y; cell++) {
            double c[136], u[135];
            int keep;
            c[0] = cs[(size_t)cell * (size_t)ns];
            for (k = 1; k < ns; k++) c[k] = cs[(size_t)cell * (size_t)ns + (size_t)k] * inv_lambda;
            keep = lensrt_basis_keep(r, w, n, c, lensrt_output_limit(r, o, c[0]), u);
            if (keep > r->basis_rank[w]) r->basis_rank[w] = keep;
        }
        // A margin for pixels between grid points
        r->basis_rank[w] = r->basis_rank[w] + 2 < n ? r->basis_rank[w] + 2 : n;
    }
    lensrt_free(r->ctx, cs);
    lensrt_free(r->ctx, g);
    lensrt_free(r->ctx, eig);
    // Rows: the monomials, the phase's and the transmittance's basis functions (room for
    // all n each, as always), then each clip output's (room for its largest rank)
    r->row_base[0] = ns;
    r->row_base[1] = ns + n;
    r->n_rows = ns + 2 * n;
    for (k = 2; !gl && k < r->n_bases; k++) {
        int most = 0;
        for (w = 0; w < r->n_wl; w++)
            if (r->basis_rank[w * r->n_bases + k] > most) most = r->basis_rank[w * r->n_bases + k];
        r->row_base[k] = r->n_rows;
        r->n_rows += most;
    }
    return LENSRT_SUCCESS;
}
