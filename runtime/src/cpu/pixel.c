/* The CPU device's pixel set-up for polynomial transport: P_s specialised to the pixel
 * (stop-monomial coefficients in double), the inner-pupil clip decided from bounds, the
 * phase in waves with its constant dropped (it cannot change the pixel's intensity),
 * negligible terms pruned, phase and transmittance moved into the window's bases where
 * that needs fewer terms, and the Huygens amplitude; for a ghost, its P_clip pairs
 * (side P_s) likewise decided from bounds or kept for the kernel's per-splat test. */
#include "pass.h"

#include "../core/basis.h"
#include "../core/specialise.h"

#include <math.h>
#include <string.h>

/* A ghost's P_clip pairs at the pixel (side P_s), decided from bounds as the inner-pupil
 * clip is: over the sampled region every stop monomial is at most 1, so a pair whose
 * largest possible x^2 + y^2 is within its limit always passes (no test), one whose
 * smallest possible is beyond it never does (the pixel is dark: returns 0), and the
 * others are tested per splat with their terms pruned as x_i, y_i are (dropped terms
 * sum to at most 1e-4 of the limit; none in precision DOUBLE). A stop crossing of a
 * bladed or slit stop is decided from the box of its possible points against the shape
 * (lensrt_stop_shape_box) and tested per splat against it. */
static int setup_clip(const lensrt_render r, int w, const double *px, const double *py, lensrt_cpu_pixel *pt,
                      lensrt_cpu_clip *cl)
{
    const int ns = r->n_slots, n_out = 2 * r->n_clip_pairs;
    const int dbl = r->desc.precision == LENSRT_PRECISION_DOUBLE;
    double c[2][136], bound[2];
    int q, a, k, n_test = 0;
    for (q = 0; q < r->n_clip_pairs; q++) {
        const double lim = r->clip_limit[q];
        // Pruning tolerance: 1e-4 of the limit, or of a shaped stop's smallest size (a
        // narrow slit's half width)
        const double tol = 1e-4 * (r->clip_shaped[q] ? r->stop.scale : lim);
        double hi, lo_x, lo_y;
        for (a = 0; a < 2; a++) {
            lensrt_slot_coefficients(&r->clip_s[w * n_out + 2 * q + a], px, py, c[a], ns);
            bound[a] = 0.0;
            for (k = 1; k < ns; k++) bound[a] += fabs(c[a][k]);
        }
        if (r->clip_shaped[q]) {
            // A stop crossing of a bladed or slit stop: the box of its possible points
            // inside the shape (no test), outside it (dark), or tested per splat
            const int box = lensrt_stop_shape_box(&r->stop, c[0][0], bound[0], c[1][0], bound[1]);
            if (box == 0) return 0;
            if (box == 1) continue;
        } else {
            hi = hypot(fabs(c[0][0]) + bound[0], fabs(c[1][0]) + bound[1]);
            lo_x = fabs(c[0][0]) - bound[0];
            lo_y = fabs(c[1][0]) - bound[1];
            if (lo_x > lim || lo_y > lim || (lo_x > 0 && lo_y > 0 && hypot(lo_x, lo_y) > lim)) return 0;
            if (hi <= lim) continue;
        }
        // Tested: the terms by increasing size, the smallest dropped within the tolerance
        for (a = 0; a < 2; a++) {
            const int row = 2 * n_test + a;
            int order[136], n = 0, i, j;
            double dropped = 0.0;
            unsigned char kept[136];
            for (k = 1; k < ns; k++) {
                double v = fabs(c[a][k]);
                if (v == 0.0) continue;
                for (j = n; j > 0 && fabs(c[a][order[j - 1]]) > v; j--) order[j] = order[j - 1];
                order[j] = k;
                n++;
            }
            i = 0;
            if (!dbl)
                while (i < n && dropped + fabs(c[a][order[i]]) <= tol) dropped += fabs(c[a][order[i++]]);
            memset(kept, 0, sizeof kept);
            kept[0] = 1; /* the constant term (row 0 is the monomial 1) */
            for (j = i; j < n; j++) kept[order[j]] = 1;
            for (j = 0, k = 0; k < ns; k++) {
                if (!kept[k]) continue;
                cl->slot[row][j] = k;
                cl->coef_f[row][j] = (float)c[a][k];
                cl->coef_d[row][j] = c[a][k];
                j++;
            }
            // Or in the window's basis of this output, when that needs fewer terms (the
            // dropped tail's l1 norm under the same limit), the constant term kept
            if (r->use_basis) {
                const int bb = 2 + 2 * q + a, rank = r->basis_rank[r->n_bases * w + bb];
                double u[135];
                int keep = lensrt_basis_keep(r, r->n_bases * w + bb, rank, c[a], tol, u), jj;
                if (keep <= rank && keep + 1 < j) {
                    for (jj = 0; jj < keep; jj++) {
                        cl->slot[row][jj] = r->row_base[bb] + jj;
                        cl->coef_f[row][jj] = (float)u[jj];
                        cl->coef_d[row][jj] = u[jj];
                    }
                    cl->slot[row][keep] = 0;
                    cl->coef_f[row][keep] = (float)c[a][0];
                    cl->coef_d[row][keep] = c[a][0];
                    j = keep + 1;
                }
            }
            {
                lensrt_terms_f *tf = a ? &pt->f.clip_y[n_test] : &pt->f.clip_x[n_test];
                lensrt_terms_d *td = a ? &pt->d.clip_y[n_test] : &pt->d.clip_x[n_test];
                tf->n = td->n = j;
                tf->slot = td->slot = cl->slot[row];
                tf->coef = cl->coef_f[row];
                td->coef = cl->coef_d[row];
            }
        }
        pt->f.clip_r2[n_test] = (float)(lim * lim);
        pt->d.clip_r2[n_test] = lim * lim;
        pt->f.clip_shaped[n_test] = pt->d.clip_shaped[n_test] = r->clip_shaped[q];
        n_test++;
    }
    pt->f.n_clip = pt->d.n_clip = n_test;
    pt->f.stop = pt->d.stop = &r->stop;
    return 1;
}

/* Build the kernel's view of pixel (x, y) for wavelength w; returns 0 when every path
 * through the pixel is clipped. */
int lensrt_cpu_setup_pixel(const lensrt_render r, int w, double x, double y, lensrt_cpu_pixel *pt,
                           lensrt_cpu_clip *clip)
{
    lensrt_pixel_f *pf = &pt->f;
    lensrt_pixel_d *pdb = &pt->d;
    const lensrt_lens lens = r->lens;
    const double lambda_mm = r->wavelengths[w] / LENSRT_NM_PER_MM;
    const int dbl = r->desc.precision == LENSRT_PRECISION_DOUBLE;
    const int naive = r->desc.precision == LENSRT_PRECISION_NAIVE_FLOAT;
    const int ns = r->n_slots;
    double px[16], py[16], c[4][136], bound[4], h = lens->housing_last_mm;
    int o, k, counts[4];
    lensrt_sensor_powers(lens, x, y, px, py);
    // Coefficients of the stop monomials at this pixel, and bounds of the varying parts
    for (o = 0; o < 4; o++) {
        lensrt_slot_coefficients(&r->ps[w * 4 + o], px, py, c[o], ns);
        bound[o] = 0.0;
        for (k = 1; k < ns; k++) bound[o] += fabs(c[o][k]);
    }
    // Inner pupil: skip the clip when every path passes, the pixel when none does
    {
        double hi = hypot(fabs(c[0][0]) + bound[0], fabs(c[1][0]) + bound[1]);
        double lo_x = fabs(c[0][0]) - bound[0], lo_y = fabs(c[1][0]) - bound[1];
        if (lo_x > h || lo_y > h || (lo_x > 0 && lo_y > 0 && hypot(lo_x, lo_y) > h)) return 0;
        pf->clip = pdb->clip = hi > h;
    }
    // A ghost's P_clip pairs (side P_s) likewise
    pf->n_clip = pdb->n_clip = 0;
    if (clip && !setup_clip(r, w, px, py, pt, clip)) return 0;
    // Phase in waves; the constant part is kept only by the naive mode
    for (k = 0; k < ns; k++) c[3][k] *= 1.0 / lambda_mm;
    // Prune: drop the smallest terms while the sum of their bounds stays under the
    // output's tolerance (every stop monomial is bounded by 1 on the sampled region)
    {
        for (o = 0; o < 4; o++) {
            const double limit = lensrt_output_limit(r, o, c[2][0]);
            int order[136], n = 0, i, j;
            unsigned char kept[136];
            double dropped = 0.0;
            counts[o] = 0;
            if ((o == 0 || o == 1) && !pf->clip) continue;
            if (o == 2 && bound[2] <= limit && !dbl) continue; /* constant: folded into amp */
            // Terms by increasing size (insertion sort: at most 135 of them)
            for (k = 1; k < ns; k++) {
                double a = fabs(c[o][k]);
                if (a == 0.0) continue;
                for (j = n; j > 0 && fabs(c[o][order[j - 1]]) > a; j--) order[j] = order[j - 1];
                order[j] = k;
                n++;
            }
            i = 0;
            if (!dbl)
                while (i < n && dropped + fabs(c[o][order[i]]) <= limit) dropped += fabs(c[o][order[i++]]);
            // Keep the rest in slot order (the kernel streams monomial rows)
            memset(kept, 0, sizeof kept);
            for (j = i; j < n; j++) kept[order[j]] = 1;
            for (j = 0, k = 0; k < ns; k++) {
                if (!kept[k]) continue;
                pt->slot[o][j] = k;
                pt->coef_f[o][j] = (float)c[o][k];
                pt->coef_d[o][j] = c[o][k];
                j++;
            }
            counts[o] = j;
            if (o == 2 && counts[2] > 0) {
                // A varying transmittance keeps its constant term in the polynomial
                pt->slot[2][counts[2]] = 0;
                pt->coef_f[2][counts[2]] = (float)c[2][0];
                pt->coef_d[2][counts[2]] = c[2][0];
                counts[2]++;
            }
        }
    }
    // Phase and transmittance in the window's bases: keep the leading vectors whose
    // dropped tail stays under the tolerance (its l1 norm bounds the error, every
    // monomial being at most 1 on the sampled region)
    if (r->use_basis) {
        int bb;
        for (bb = 0; bb < 2; bb++) {
            const int oo = bb ? 2 : 3;
            const double limit = lensrt_output_limit(r, oo, c[2][0]);
            double u[135];
            int j, keep, have = counts[oo] - (oo == 2 && counts[2] > 0);
            if (oo == 2 && counts[2] == 0) continue; /* constant transmittance */
            keep = lensrt_basis_keep(r, r->n_bases * w + bb, r->basis_rank[r->n_bases * w + bb], c[oo], limit, u);
            if (keep > r->basis_rank[r->n_bases * w + bb]) continue; /* beyond the rows computed */
            if (keep >= have) continue;
            for (j = 0; j < keep; j++) {
                pt->slot[oo][j] = r->row_base[bb] + j;
                pt->coef_f[oo][j] = (float)u[j];
                pt->coef_d[oo][j] = u[j];
            }
            counts[oo] = keep;
            if (oo == 2) {
                // The transmittance keeps its constant term (row 0 is the monomial 1)
                pt->slot[2][keep] = 0;
                pt->coef_f[2][keep] = (float)c[2][0];
                pt->coef_d[2][keep] = c[2][0];
                counts[2] = keep + 1;
            }
        }
    }
    // Huygens amplitude (core/specialise.c)
    pt->amp = lensrt_huygens_amplitude(r, w, x, y);
    if (counts[2] == 0) pt->amp *= sqrt(c[2][0] > 0 ? c[2][0] : 0.0);
    // Point the kernel's views at the terms
    pf->phase0 = naive ? (float)c[3][0] : 0.0f;
    pf->housing2 = (float)(h * h);
    pdb->housing2 = h * h;
    {
        lensrt_terms_f *tf[4];
        lensrt_terms_d *td[4];
        tf[0] = &pf->xi; tf[1] = &pf->yi; tf[2] = &pf->tau; tf[3] = &pf->phase;
        td[0] = &pdb->xi; td[1] = &pdb->yi; td[2] = &pdb->tau; td[3] = &pdb->phase;
        for (o = 0; o < 4; o++) {
            tf[o]->n = td[o]->n = counts[o];
            tf[o]->slot = td[o]->slot = pt->slot[o];
            tf[o]->coef = pt->coef_f[o];
            td[o]->coef = pt->coef_d[o];
        }
    }
    if (pf->clip) {
        // The clip needs the constant position too
        for (o = 0; o < 2; o++) {
            pt->slot[o][counts[o]] = 0;
            pt->coef_f[o][counts[o]] = (float)c[o][0];
            pt->coef_d[o][counts[o]] = c[o][0];
            counts[o]++;
        }
        pf->xi.n = pdb->xi.n = counts[0];
        pf->yi.n = pdb->yi.n = counts[1];
    }
    return 1;
}
