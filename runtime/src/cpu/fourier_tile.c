/* The CPU device's Fourier integrator: the field of one wavelength over a tile of pixels
 * (cpu/fourier.c drives it: core/fourier.h says what it computes and why).
 *
 * The rule's nodes before the stop (P_o per light: phase, amplitude, the clip levels that
 * must pass), then the window as one tile, split in four while the interpolation across
 * a tile cannot follow the rest of the phase or the amplitude. Per tile: P_s's
 * stop-monomial coefficients at the tile's Chebyshev nodes (cpu/fourier_cheb.h), then
 * per aperture node the phase and amplitude at those pixels, the gradient G (the NUFFT's
 * frequency), the interpolated rest, and one batch of type-1 NUFFTs for every light and
 * kept Chebyshev term. And the pilot, which measures the phase's slope for the rule's
 * nodes. Everything is in double. */
#include "fourier_wave.h"
#include "fourier_cheb.h"

#include "../core/nufft.h"
#include "../core/specialise.h"
#include "../lens/lens.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

/* exp(i t) for |t| <= 0.3 by its Taylor series to t^6 (error below t^7 / 5040, 4.4e-8),
 * else by cos and sin: the rest of the phase is mostly a few hundredths of a wave. */
static void cis(double t, double *c, double *s)
{
    if (fabs(t) <= 0.3) {
        const double t2 = t * t;
        *c = 1.0 - t2 * (0.5 - t2 * (1.0 / 24.0 - t2 * (1.0 / 720.0)));
        *s = t * (1.0 - t2 * (1.0 / 6.0 - t2 * (1.0 / 120.0)));
    } else {
        *c = cos(t);
        *s = sin(t);
    }
}

/* ------------------------------------------------------------- the nodes ----- */

/* A refusal of this wavelength (the first kept), told after the threads end. */
static int wave_fail(fourier_wave *fw, const char *what, double x, double y)
{
    if (fw->fail == LENSRT_SUCCESS) {
        fw->fail = LENSRT_ERROR_UNSUPPORTED;
        snprintf(fw->why, sizeof fw->why,
                 "fourier: %s at (%g, %g) mm at %g nm; the cells integrator resolves clips "
                 "(lensrt_render_integrate)",
                 what, x, y, fw->r->wavelengths[fw->w]);
    }
    return 0;
}

/* The stop points (mm) of the block of nodes from j on (the padding at the centre). */
static void node_block(const fourier_wave *fw, size_t j, double *x, double *y)
{
    int q;
    for (q = 0; q < BLK; q++) {
        const size_t i = j + (size_t)q;
        x[q] = i < (size_t)fw->q->n ? fw->q->xy[2 * i] : 0.0;
        y[q] = i < (size_t)fw->q->n ? fw->q->xy[2 * i + 1] : 0.0;
    }
}

/* What every light's path brings to the stop at every node: phase (waves) and amplitude
 * times the rule's weight; a clip before the stop that cuts a node refuses the render. */
int lensrt_fourier_prepare_nodes(fourier_wave *fw)
{
    const lensrt_render r = fw->r;
    const lensrt_lens_ops *ops = r->lens_ops;
    const int nq = fw->nq;
    double rows_d[256], lev[1 + LENSRT_MAX_CLIP_PAIRS], mono[136];
    float rows_f[256];
    lensrt_rows rows;
    int j, l, i;
    rows.stride = 1;
    rows.d = rows_d;
    rows.f = rows_f;
    for (j = 0; j < nq; j++) {
        const int pad = j >= fw->q->n;
        const double x = pad ? 0.0 : fw->q->xy[2 * j], y = pad ? 0.0 : fw->q->xy[2 * j + 1];
        if (fw->poly) lensrt_stop_monomials(r, x, y, mono, NULL, NULL);
        else ops->sample_rows(r, fw->w, x, y, mono, &rows);
        for (l = 0; l < r->n_lights; l++) {
            double amp = sqrt(r->lights[l].intensity), opl = 0.0;
            const size_t at = (size_t)l * (size_t)nq + (size_t)j;
            if (ops->sample_levels) {
                const int n_lev = ops->sample_levels(r, fw->w, l, mono, &amp, &opl, lev);
                for (i = 0; i < n_lev; i++)
                    if (lev[i] < 0.0)
                        return wave_fail(fw,
                                         i == 0 ? "the outer pupil clips the aperture at its stop point"
                                                : "a P_clip pair before the stop clips the aperture at its stop point",
                                         x, y);
            } else
                ops->sample_wave(r, fw->w, l, x, y, mono, &amp, &opl);
            fw->sph[at] = opl / fw->lambda_mm;
            fw->samp[at] = pad ? 0.0 : (amp > 0.0 ? amp : 0.0) * fw->q->w[j];
        }
    }
    return 1;
}

/* ------------------------------------------------------------- the tiles ----- */

/* Keep the terms of c[0 .. ns) whose dropped sum stays within tol (each monomial is at
 * most 1 on the sampled region, so the dropped terms change the value by at most tol). */
static void prune(const double *c, int ns, double tol, pruned *p)
{
    int order[136], n = 0, i, j, k;
    double dropped = 0.0;
    unsigned char kept[136];
    for (k = 0; k < ns; k++) {
        const double a = fabs(c[k]);
        if (a == 0.0) continue;
        for (j = n; j > 0 && fabs(c[order[j - 1]]) > a; j--) order[j] = order[j - 1];
        order[j] = k;
        n++;
    }
    i = 0;
    while (i < n && dropped + fabs(c[order[i]]) <= tol) dropped += fabs(c[order[i++]]);
    memset(kept, 0, sizeof kept);
    for (j = i; j < n; j++) kept[order[j]] = 1;
    for (p->n = 0, k = 0; k < ns; k++)
        if (kept[k]) {
            p->slot[p->n] = k;
            p->coef[p->n++] = c[k];
        }
}

/* The stop monomials of a block of nodes: mono[k][q]. */
static void block_monomials(const lensrt_render r, const double *x, const double *y, double (*mono)[BLK])
{
    double pu[16][BLK], pv[16][BLK];
    int k, q;
    for (q = 0; q < BLK; q++) {
        pu[0][q] = pv[0][q] = 1.0;
        pu[1][q] = x[q] / r->mono_radius;
        pv[1][q] = y[q] / r->mono_radius;
    }
    for (k = 2; k <= r->degree; k++)
        for (q = 0; q < BLK; q++) {
            pu[k][q] = pu[k - 1][q] * pu[1][q];
            pv[k][q] = pv[k - 1][q] * pv[1][q];
        }
    for (k = 0; k < r->n_slots; k++)
        for (q = 0; q < BLK; q++) mono[k][q] = pu[r->slot_m[k]][q] * pv[r->slot_n[k]][q];
}

/* out[q] = the pruned polynomial at each node of a block. */
static void eval_pruned_blk(const pruned *p, const double (*mono)[BLK], double *out)
{
    double a[BLK] = {0};
    int t, q;
    for (t = 0; t < p->n; t++) {
        const double c = p->coef[t];
        const double *m = mono[p->slot[t]];
        for (q = 0; q < BLK; q++) a[q] += c * m[q];
    }
    memcpy(out, a, sizeof a);
}

static double eval_pruned(const pruned *p, const double *mono)
{
    // Four sums: the terms are independent, and one sum would wait on every addition
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0;
    int t = 0;
    for (; t + 4 <= p->n; t += 4) {
        a0 += p->coef[t] * mono[p->slot[t]];
        a1 += p->coef[t + 1] * mono[p->slot[t + 1]];
        a2 += p->coef[t + 2] * mono[p->slot[t + 2]];
        a3 += p->coef[t + 3] * mono[p->slot[t + 3]];
    }
    for (; t < p->n; t++) a0 += p->coef[t] * mono[p->slot[t]];
    return (a0 + a1) + (a2 + a3);
}

/* 1: every path passes (bounds), 0: none does, 2: test the nodes. */
static int clip_bounds(const lensrt_render r, const double *cx, const double *cy, double lim, int shaped)
{
    double bx = 0.0, by = 0.0, hi, lo_x, lo_y;
    int k;
    for (k = 1; k < r->n_slots; k++) {
        bx += fabs(cx[k]);
        by += fabs(cy[k]);
    }
    if (shaped) {
        const int box = lensrt_stop_shape_box(&r->stop, cx[0], bx, cy[0], by);
        return box == 0 ? 0 : box == 1 ? 1 : 2;
    }
    hi = hypot(fabs(cx[0]) + bx, fabs(cy[0]) + by);
    lo_x = fabs(cx[0]) - bx;
    lo_y = fabs(cy[0]) - by;
    if (lo_x > lim || lo_y > lim || (lo_x > 0 && lo_y > 0 && hypot(lo_x, lo_y) > lim)) return 0;
    return hi <= lim ? 1 : 2;
}

/* The clips after the stop at node pixel (x, y) that the bounds cannot decide (into cl,
 * their count), or -1 when every path through the pixel is clipped. */
static int post_clips(fourier_wave *fw, double x, double y, post_clip *cl)
{
    const lensrt_render r = fw->r;
    const int ns = r->n_slots, w = fw->w;
    double px[16], py[16], cx[136], cy[136];
    int n = 0, q, b;
    lensrt_sensor_powers(r->lens, x, y, px, py);
    // The inner pupil
    lensrt_slot_coefficients(&r->ps[w * 4 + 0], px, py, cx, ns);
    lensrt_slot_coefficients(&r->ps[w * 4 + 1], px, py, cy, ns);
    b = clip_bounds(r, cx, cy, r->lens->housing_last_mm, 0);
    if (b == 0) return -1;
    if (b == 2) {
        prune(cx, ns, 0.0, &cl[n].x);
        prune(cy, ns, 0.0, &cl[n].y);
        cl[n].lim = r->lens->housing_last_mm;
        cl[n].shaped = 0;
        cl[n++].inner = 1;
    }
    // A ghost's P_clip pairs on side P_s
    for (q = 0; r->clip_s && q < r->n_clip_pairs; q++) {
        const int n_out = 2 * r->n_clip_pairs;
        lensrt_slot_coefficients(&r->clip_s[w * n_out + 2 * q], px, py, cx, ns);
        lensrt_slot_coefficients(&r->clip_s[w * n_out + 2 * q + 1], px, py, cy, ns);
        b = clip_bounds(r, cx, cy, r->clip_limit[q], r->clip_shaped[q]);
        if (b == 0) return -1;
        if (b == 2) {
            prune(cx, ns, 0.0, &cl[n].x);
            prune(cy, ns, 0.0, &cl[n].y);
            cl[n].lim = r->clip_limit[q];
            cl[n].shaped = r->clip_shaped[q];
            cl[n++].inner = 0;
        }
    }
    return n;
}

static int post_clip_passes(const lensrt_render r, const post_clip *c, const double *mono)
{
    const double hx = eval_pruned(&c->x, mono), hy = eval_pruned(&c->y, mono);
    if (c->shaped) return lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, hx, hy);
    return hx * hx + hy * hy <= c->lim * c->lim;
}

/* The tile's geometry and interpolation (of degree max_deg at most). */
static void tile_setup(const lensrt_render r, int x0, int y0, int tw, int th, int max_deg, tile_interp *ti)
{
    int ix, iy;
    ti->dx = tw > 1 ? (tw - 1 < max_deg ? tw - 1 : max_deg) : 0;
    ti->dy = th > 1 ? (th - 1 < max_deg ? th - 1 : max_deg) : 0;
    ti->ns = (ti->dx + 1) * (ti->dy + 1);
    ti->xc = 0.5 * (r->xs[x0] + r->xs[x0 + tw - 1]);
    ti->yc = 0.5 * (r->ys[y0] + r->ys[y0 + th - 1]);
    ti->hx = tw > 1 ? 0.5 * fabs(r->xs[x0 + tw - 1] - r->xs[x0]) : 1.0;
    ti->hy = th > 1 ? 0.5 * fabs(r->ys[y0 + th - 1] - r->ys[y0]) : 1.0;
    cheb_nodes(ti->dx, ti->xh);
    cheb_nodes(ti->dy, ti->yh);
    cheb_matrix(ti->dx, ti->Mx);
    cheb_matrix(ti->dy, ti->My);
    for (ix = 0; ix <= ti->dx; ix++) cheb_values(ti->dx, ti->xh[ix], ti->Tx[ix]);
    for (iy = 0; iy <= ti->dy; iy++) cheb_values(ti->dy, ti->yh[iy], ti->Ty[iy]);
    for (iy = 0; iy <= ti->dy; iy++)
        for (ix = 0; ix <= ti->dx; ix++) {
            ti->px[iy * (ti->dx + 1) + ix] = ti->xc + ti->hx * ti->xh[ix];
            ti->py[iy * (ti->dx + 1) + ix] = ti->yc + ti->hy * ti->yh[iy];
            ti->pa[iy * (ti->dx + 1) + ix] = 1.0;
        }
}


/* Split a tile in four (two along an axis one pixel wide) and render the parts. */
static int split_tile(fourier_wave *fw, int x0, int y0, int tw, int th, int depth)
{
    const int ax = tw > 1 ? tw / 2 : tw, ay = th > 1 ? th / 2 : th;
    if (!lensrt_fourier_render_tile(fw, x0, y0, ax, ay, depth + 1)) return 0;
    if (tw > 1 && !lensrt_fourier_render_tile(fw, x0 + ax, y0, tw - ax, ay, depth + 1)) return 0;
    if (th > 1 && !lensrt_fourier_render_tile(fw, x0, y0 + ay, ax, th - ay, depth + 1)) return 0;
    if (tw > 1 && th > 1 && !lensrt_fourier_render_tile(fw, x0 + ax, y0 + ay, tw - ax, th - ay, depth + 1)) return 0;
    return 1;
}

/* What a tile needs per rule node, found once per tile: P_s's phase (waves) and
 * transmittance as polynomials in the stop monomials per Chebyshev term across the
 * tile, each pruned to what the tolerance needs (so a node costs the terms the tile
 * needs); the clips after the stop the bounds leave to the nodes; the Huygens amplitude
 * of the node pixels (ti->pa). Returns 1, 0 on a refusal, -1 when the tile must be split
 * first (its phase's rest may exceed MAX_REST_WAVES). */
static int tile_prepare(fourier_wave *fw, tile_interp *ti, int can_split)
{
    const lensrt_render r = fw->r;
    const int ns = ti->ns, n_slots = r->n_slots, nb = ns;
    static const int outs[2] = {3, 2};
    tile_poly *tp = fw->tp;
    int s, b, o, k;
    double rest = 0.0;
    if (!fw->poly) return 1;
    tp->n_test = 0;
    for (o = 0; o < 2; o++) {
        double cs[MAX_NODES][136], C[MAX_NODES][136];
        // P_s's stop-monomial coefficients at the node pixels (phase in waves)
        for (s = 0; s < ns; s++) {
            double px[16], py[16];
            lensrt_sensor_powers(r->lens, ti->px[s], ti->py[s], px, py);
            lensrt_slot_coefficients(&r->ps[fw->w * 4 + outs[o]], px, py, cs[s], n_slots);
            if (o == 0)
                for (k = 0; k < n_slots; k++) cs[s][k] /= fw->lambda_mm;
        }
        // Per slot, its Chebyshev terms across the tile; then per term, the slots it
        // needs (the phase's to tol / (2 pi) waves, the transmittance's to tol of its
        // value, shared among the terms)
        for (k = 0; k < n_slots; k += BLK) {
            double in[MAX_NODES][BLK], out[MAX_NODES][BLK];
            int q;
            for (s = 0; s < ns; s++)
                for (q = 0; q < BLK; q++) in[s][q] = k + q < n_slots ? cs[s][k + q] : 0.0;
            cheb_transform_blk(ti, (const double(*)[BLK])in, out);
            for (b = 0; b < nb; b++)
                for (q = 0; q < BLK && k + q < n_slots; q++) C[b][k + q] = out[b][q];
        }
        for (b = 0; b < nb; b++)
            prune(C[b], n_slots, o == 0 ? fw->tol / (TWO_PI * nb) : 0.5 * fw->tol * fabs(C[0][0]) / nb,
                  &tp->P[o][b]);
        // The rest of the phase beyond its linear part, at most
        if (o == 0)
            for (b = 0; b < nb; b++) {
                const int bx = b % (ti->dx + 1), by = b / (ti->dx + 1);
                if (bx + by <= 1) continue;
                for (k = 1; k < n_slots; k++) rest += fabs(C[b][k]);
            }
    }
    tp->rest = rest;
    if (can_split && rest > MAX_REST_WAVES) return -1;
    // The clips after the stop that the bounds leave to the nodes
    for (s = 0; s < ns; s++) {
        tp->n_cl[s] = post_clips(fw, ti->px[s], ti->py[s], tp->cl + s * (1 + LENSRT_MAX_CLIP_PAIRS));
        if (tp->n_cl[s] < 0)
            return wave_fail(fw, "every path to a pixel is clipped after the stop: the pixel", ti->px[s], ti->py[s]);
        tp->n_test += tp->n_cl[s];
    }
    // The transmittance's terms beyond the constant: none when it is the same at every
    // pixel of the tile (then its value is its constant term at every node pixel)
    for (b = 1, tp->tau_varies = 0; b < nb; b++) tp->tau_varies |= tp->P[1][b].n > 0;
    for (s = 0; s < ns; s++) ti->pa[s] = lensrt_huygens_amplitude(r, fw->w, ti->px[s], ti->py[s]);
    return 1;
}

/* A block of rule nodes at stop points x, y: the phase after the stop as Chebyshev terms
 * val[b][q] (waves) and the amplitude after the stop at the node pixels amp[s][q]. 0 on
 * a refusal (a clip after the stop cuts a node). */
static int block_values(fourier_wave *fw, const tile_interp *ti, const double *x, const double *y,
                        double (*val)[BLK], double (*amp)[BLK])
{
    const lensrt_render r = fw->r;
    const tile_poly *tp = fw->tp;
    const int ns = ti->ns, nb = ns;
    int s, b, q, k;
    if (!fw->poly) {
        // Free space (Rayleigh-Sommerfeld): the distance in waves and cos(theta) / (lambda r)
        const double z = r->lens->model.sensor_distance_mm + r->desc.sensor.focus_offset_mm;
        double ph[MAX_NODES][BLK];
        for (s = 0; s < ns; s++)
            for (q = 0; q < BLK; q++) {
                const double dx = ti->px[s] - x[q], dy = ti->py[s] - y[q], r2 = dx * dx + dy * dy + z * z;
                ph[s][q] = sqrt(r2) / fw->lambda_mm;
                amp[s][q] = z / (fw->lambda_mm * r2);
            }
        cheb_transform_blk(ti, (const double(*)[BLK])ph, val);
        return 1;
    }
    {
        double mono[136][BLK], ctau[MAX_NODES][BLK], tau[MAX_NODES][BLK];
        block_monomials(r, x, y, mono);
        for (b = 0; b < nb; b++) eval_pruned_blk(&tp->P[0][b], (const double(*)[BLK])mono, val[b]);
        if (tp->tau_varies) {
            // sqrt(tau) across the tile from one square root per node: tau varies by a
            // small fraction e over it, and sqrt(1 + e) to e^3 is within 5 e^4 / 128
            // (4e-10 at e = 1%); beyond 1%, a root per node pixel
            for (b = 0; b < nb; b++) eval_pruned_blk(&tp->P[1][b], (const double(*)[BLK])mono, ctau[b]);
            cheb_inverse_blk(ti, (const double(*)[BLK])ctau, tau);
            for (q = 0; q < BLK; q++) {
                const double t0 = tau[0][q], r0 = t0 > 0.0 ? sqrt(t0) : 0.0;
                for (s = 0; s < ns; s++) {
                    const double e = t0 > 0.0 ? tau[s][q] / t0 - 1.0 : 1.0;
                    amp[s][q] = fabs(e) <= 0.01 ? r0 * (1.0 + e * (0.5 - e * (0.125 - e * 0.0625)))
                                                : tau[s][q] > 0.0 ? sqrt(tau[s][q]) : 0.0;
                }
            }
        } else {
            eval_pruned_blk(&tp->P[1][0], (const double(*)[BLK])mono, ctau[0]);
            for (q = 0; q < BLK; q++) {
                const double a0 = ctau[0][q] > 0.0 ? sqrt(ctau[0][q]) : 0.0;
                for (s = 0; s < ns; s++) amp[s][q] = a0;
            }
        }
        if (tp->n_test)
            for (q = 0; q < BLK; q++) {
                double mq[136];
                for (k = 0; k < r->n_slots; k++) mq[k] = mono[k][q];
                for (s = 0; s < ns; s++) {
                    const post_clip *c = tp->cl + s * (1 + LENSRT_MAX_CLIP_PAIRS);
                    for (k = 0; k < tp->n_cl[s]; k++)
                        if (!post_clip_passes(r, &c[k], mq))
                            return wave_fail(fw,
                                             c[k].inner ? "the inner pupil clips some paths to the pixel"
                                                        : "a P_clip pair after the stop clips some paths to the pixel",
                                             ti->px[s], ti->py[s]);
                }
            }
    }
    return 1;
}

/* The rest of the phase at the node pixels from its Chebyshev terms: the constant and
 * linear terms (into c0, gx, gy: waves, waves per unit of the tile's x and y) taken out. */
static void block_rest(const tile_interp *ti, double (*val)[BLK], double *c0, double *gx, double *gy,
                       double (*rest)[BLK])
{
    int q;
    for (q = 0; q < BLK; q++) {
        c0[q] = val[0][q];
        gx[q] = ti->dx >= 1 ? val[1][q] : 0.0;
        gy[q] = ti->dy >= 1 ? val[ti->dx + 1][q] : 0.0;
        val[0][q] = 0.0;
        if (ti->dx >= 1) val[1][q] = 0.0;
        if (ti->dy >= 1) val[ti->dx + 1][q] = 0.0;
    }
    cheb_inverse_blk(ti, (const double(*)[BLK])val, rest);
}

/* The interpolation's degree for a tile whose rest may reach `rest` waves: exp(i t) with
 * t = 2 pi rest quadratic across the tile has Chebyshev terms of degree 3 and 4 near
 * t^2 / 16 and t^2 / 64, below the tolerance's 1e-3 at t = 0.05 (degree 2) and 0.25
 * (degree 3); the tail check raises it where that was too little. */
static int tile_degree(double rest)
{
    const double t = TWO_PI * rest;
    return t <= 0.05 ? 2 : t <= 0.25 ? 3 : MAX_DEG;
}

static int render_tile_at(fourier_wave *fw, int x0, int y0, int tw, int th, int depth, int deg);

int lensrt_fourier_render_tile(fourier_wave *fw, int x0, int y0, int tw, int th, int depth)
{
    return render_tile_at(fw, x0, y0, tw, th, depth, 0);
}

/* Tile (x0, y0, tw, th) at interpolation degree deg (0: chosen from the rest). */
static int render_tile_at(fourier_wave *fw, int x0, int y0, int tw, int th, int depth, int deg)
{
    const lensrt_render r = fw->r;
    const int nl = r->n_lights, can_split = depth < MAX_DEPTH && (tw > 1 || th > 1);
    const size_t nq = (size_t)fw->nq;
    const size_t npix = (size_t)r->width * (size_t)r->height;
    tile_interp ti;
    double rref[MAX_NODES], norm[MAX_NODES] = {0}, dxh, dyh, fold_x, fold_y;
    int s, b, l, nb, kept[MAX_NODES], cls[MAX_NODES], n_kept = 0, got;
    size_t j;
    lensrt_nufft plan;
    // A host tile renders the window's tiles that meet its rectangle, and no others
    if (fw->rect[2] && (x0 >= fw->rect[0] + fw->rect[2] || x0 + tw <= fw->rect[0] || y0 >= fw->rect[1] + fw->rect[3] ||
                        y0 + th <= fw->rect[1]))
        return 1;
    tile_setup(r, x0, y0, tw, th, deg ? deg : MAX_DEG, &ti);
    got = tile_prepare(fw, &ti, can_split);
    if (got == 0) return 0;
    if (got < 0) return split_tile(fw, x0, y0, tw, th, depth);
    if (!deg && fw->poly && tile_degree(fw->tp->rest) < MAX_DEG) {
        // A lower degree serves: the same tile on its nodes
        deg = tile_degree(fw->tp->rest);
        tile_setup(r, x0, y0, tw, th, deg, &ti);
        if (tile_prepare(fw, &ti, 0) != 1) return 0;
    }
    if (!deg) deg = MAX_DEG;
    nb = ti.ns;
    // Pixel steps in the tile's coordinates [-1, 1] (signed: rows may run down)
    dxh = tw > 1 ? (r->xs[x0 + 1] - r->xs[x0]) / ti.hx : 0.0;
    dyh = th > 1 ? (r->ys[y0 + 1] - r->ys[y0]) / ti.hy : 0.0;
    // Mode 0 of the NUFFT is pixel tw / 2 (th / 2): its coordinate, folded into the strengths
    fold_x = tw > 1 ? (r->xs[x0 + tw / 2] - ti.xc) / ti.hx : 0.0;
    fold_y = th > 1 ? (r->ys[y0 + th / 2] - ti.yc) / ti.hy : 0.0;
    // The rest at the stop's centre: a phase of the pixel alone (it cannot change the
    // pixel's intensity), taken from every node's rest so that what is interpolated is
    // the rest's variation over the aperture, a small fraction of a wave
    {
        double x[BLK] = {0}, y[BLK] = {0}, val[MAX_NODES][BLK], amp[MAX_NODES][BLK], rest[MAX_NODES][BLK];
        double c0[BLK], gx[BLK], gy[BLK];
        if (!block_values(fw, &ti, x, y, val, amp)) return 0;
        block_rest(&ti, val, c0, gx, gy, rest);
        for (s = 0; s < nb; s++) rref[s] = rest[s][0];
    }
    for (b = 0; b < nb; b++) norm[b] = 0.0;
    // Per block of nodes: the phase's terms, its rest at the node pixels, the
    // interpolated amplitude times exp(i 2 pi rest) in Chebyshev terms E_beta, times
    // every light's wave at the node: the strengths; and the NUFFT's points
    for (j = 0; j < nq; j += BLK) {
        double val[MAX_NODES][BLK], amp[MAX_NODES][BLK], rest[MAX_NODES][BLK], x[BLK], y[BLK];
        double Fr[MAX_NODES][BLK], Fi[MAX_NODES][BLK], Er[MAX_NODES][BLK], Ei[MAX_NODES][BLK], sw[BLK] = {0};
        double c0[BLK], gx[BLK], gy[BLK];
        int q;
        node_block(fw, j, x, y);
        if (!block_values(fw, &ti, x, y, val, amp)) return 0;
        block_rest(&ti, val, c0, gx, gy, rest);
        for (s = 0; s < nb; s++) {
            double t[BLK], big = 0.0;
            for (q = 0; q < BLK; q++) {
                t[q] = TWO_PI * (rest[s][q] - rref[s]);
                big = fabs(t[q]) > big ? fabs(t[q]) : big;
            }
            if (big <= 0.3) {
                // exp(i t) by its Taylor series to t^6 (as cis), for the whole block
                for (q = 0; q < BLK; q++) {
                    const double a = amp[s][q] * ti.pa[s], t2 = t[q] * t[q];
                    Fr[s][q] = a * (1.0 - t2 * (0.5 - t2 * (1.0 / 24.0 - t2 * (1.0 / 720.0))));
                    Fi[s][q] = a * t[q] * (1.0 - t2 * (1.0 / 6.0 - t2 * (1.0 / 120.0)));
                }
            } else
                for (q = 0; q < BLK; q++) {
                    double cr, ci;
                    cis(t[q], &cr, &ci);
                    Fr[s][q] = amp[s][q] * ti.pa[s] * cr;
                    Fi[s][q] = amp[s][q] * ti.pa[s] * ci;
                }
        }
        cheb_transform_blk(&ti, (const double(*)[BLK])Fr, Er);
        cheb_transform_blk(&ti, (const double(*)[BLK])Fi, Ei);
        for (l = 0; l < nl; l++) {
            double er[BLK], ei[BLK];
            for (q = 0; q < BLK; q++) {
                const size_t at = (size_t)l * nq + j + (size_t)q;
                const double a = fw->samp[at];
                const double ph = fw->sph[at] + c0[q] + gx[q] * fold_x + gy[q] * fold_y;
                const double t = TWO_PI * (ph - floor(ph));
                er[q] = a * cos(t);
                ei[q] = a * sin(t);
                sw[q] += fabs(a);
            }
            for (b = 0; b < nb; b++) {
                double *cv = fw->cv + ((size_t)(l * nb + b) * nq + j) * 2;
                for (q = 0; q < BLK; q++) {
                    cv[2 * q] = er[q] * Er[b][q] - ei[q] * Ei[b][q];
                    cv[2 * q + 1] = er[q] * Ei[b][q] + ei[q] * Er[b][q];
                }
            }
        }
        // |re| + |im|: within sqrt(2) of the modulus, enough to rank the terms
        for (b = 0; b < nb; b++)
            for (q = 0; q < BLK; q++) norm[b] += sw[q] * (fabs(Er[b][q]) + fabs(Ei[b][q]));
        // NUFFT points: radians per pixel step
        for (q = 0; q < BLK; q++) {
            fw->gx[j + (size_t)q] = TWO_PI * gx[q] * dxh;
            fw->gy[j + (size_t)q] = TWO_PI * gy[q] * dyh;
        }
    }
    // The interpolation's tail: the highest terms must be within the tolerance, else split
    if (norm[0] > 0.0 && can_split) {
        double tail = 0.0;
        for (b = 1; b < nb; b++) {
            const int bx = b % (ti.dx + 1), by = b / (ti.dx + 1);
            if ((ti.dx > 0 && bx == ti.dx) || (ti.dy > 0 && by == ti.dy))
                if (norm[b] > tail) tail = norm[b];
        }
        if (tail > fw->tol * norm[0]) {
            // Too little: a higher degree where the tile has the pixels for it, else split
            if (deg < MAX_DEG && (ti.dx == deg || ti.dy == deg))
                return render_tile_at(fw, x0, y0, tw, th, depth, deg + 1);
            return split_tile(fw, x0, y0, tw, th, depth);
        }
    }
    // Terms that matter (the rest below a hundredth of the tolerance are dropped), and
    // the tolerance class of each
    for (b = 0; b < nb; b++)
        if (b == 0 || norm[b] > 0.01 * fw->tol * norm[0]) {
            int c = 0;
            while (b > 0 && c + 1 < TOL_CLASSES && norm[b] * pow(10.0, c + 1) <= norm[0]) c++;
            cls[n_kept] = c;
            kept[n_kept++] = b;
        }
    // The NUFFTs of every light and kept term, a batch at a time per tolerance class
    {
        const double *cptr[LENSRT_MAX_LIGHTS * MAX_NODES];
        double *fptr[LENSRT_MAX_LIGHTS * MAX_NODES];
        const size_t tpix = (size_t)tw * (size_t)th;
        int v, ix, iy, c;
        for (c = 0; c < TOL_CLASSES; c++) {
            int n_v = 0;
            for (l = 0; l < nl; l++)
                for (b = 0; b < n_kept; b++)
                    if (cls[b] == c) {
                        cptr[n_v] = fw->cv + (size_t)(l * nb + kept[b]) * (size_t)nq * 2;
                        fptr[n_v++] = fw->f + (size_t)(l * n_kept + b) * tpix * 2;
                    }
            if (n_v == 0) continue;
            if (tpix <= DIRECT_PIXELS) {
                // A few pixels: the sums themselves (exact), cheaper than a NUFFT's grid
                for (v = 0; v < n_v; v++)
                    for (iy = 0; iy < th; iy++)
                        for (ix = 0; ix < tw; ix++) {
                            const double kx = ix - tw / 2, ky = iy - th / 2;
                            double ur = 0.0, ui = 0.0;
                            for (j = 0; j < nq; j++) {
                                const double t = kx * fw->gx[j] + ky * fw->gy[j], cr = cos(t), ci = sin(t);
                                ur += cptr[v][2 * j] * cr - cptr[v][2 * j + 1] * ci;
                                ui += cptr[v][2 * j] * ci + cptr[v][2 * j + 1] * cr;
                            }
                            fptr[v][2 * (iy * tw + ix)] = ur;
                            fptr[v][2 * (iy * tw + ix) + 1] = ui;
                        }
                continue;
            }
            if (!lensrt_nufft_init(&plan, tw, th, fw->tol * pow(10.0, c), fw->plan_mem)) {
                fw->fail = LENSRT_ERROR_INVALID_ARGUMENT;
                snprintf(fw->why, sizeof fw->why, "fourier: a tile of %d x %d pixels has no NUFFT plan", tw, th);
                return 0;
            }
            for (v = 0; v < n_v; v += fw->batch)
                lensrt_nufft_type1(&plan, (size_t)nq, fw->gx, fw->gy, n_v - v < fw->batch ? n_v - v : fw->batch,
                                   cptr + v, fptr + v, fw->scratch);
        }
        // Every pixel: the Chebyshev sum of the terms (the Huygens amplitude is in them)
        for (iy = 0; iy < th; iy++)
            for (ix = 0; ix < tw; ix++) {
                const int x = x0 + ix, y = y0 + iy;
                const size_t p = (size_t)y * (size_t)r->width + (size_t)x, tp = (size_t)iy * (size_t)tw + (size_t)ix;
                double tx[MAX_DEG + 1], ty[MAX_DEG + 1];
                if (fw->rect[2] && (x < fw->rect[0] || x >= fw->rect[0] + fw->rect[2] || y < fw->rect[1] ||
                                    y >= fw->rect[1] + fw->rect[3]))
                    continue;
                cheb_values(ti.dx, tw > 1 ? (r->xs[x] - ti.xc) / ti.hx : 0.0, tx);
                cheb_values(ti.dy, th > 1 ? (r->ys[y] - ti.yc) / ti.hy : 0.0, ty);
                for (l = 0; l < nl; l++) {
                    double ur = 0.0, ui = 0.0;
                    for (b = 0; b < n_kept; b++) {
                        const double t = tx[kept[b] % (ti.dx + 1)] * ty[kept[b] / (ti.dx + 1)];
                        const double *fv = fw->f + ((size_t)(l * n_kept + b) * tpix + tp) * 2;
                        ur += t * fv[0];
                        ui += t * fv[1];
                    }
                    fw->U[2 * (((size_t)l * (size_t)r->n_wl + (size_t)fw->w) * npix + p)] = ur;
                    fw->U[2 * (((size_t)l * (size_t)r->n_wl + (size_t)fw->w) * npix + p) + 1] = ui;
                }
            }
    }
    return 1;
}

/* The pilot (lensrt_fourier_job.pilot): the whole phase at the window's corner pixels
 * (degree 1 across the window) at every node, then its largest change per unit of a
 * line parameter between neighbouring nodes of a line, into fw->slope. */
int lensrt_fourier_pilot_slope(fourier_wave *fw)
{
    const lensrt_render r = fw->r;
    const lensrt_quadrature *qd = fw->q;
    const size_t nq = (size_t)fw->nq;
    double *ph = fw->cv; /* [corner][j]: scratch of at least 4 nq doubles */
    tile_interp ti;
    size_t j;
    int s, l, p, b, i, q;
    tile_setup(r, 0, 0, r->width, r->height, 1, &ti);
    if (tile_prepare(fw, &ti, 0) != 1) return 0;
    for (l = 0; l < r->n_lights; l++) {
        for (j = 0; j < nq; j += BLK) {
            double val[MAX_NODES][BLK], amp[MAX_NODES][BLK], at[MAX_NODES][BLK], x[BLK], y[BLK];
            node_block(fw, j, x, y);
            if (!block_values(fw, &ti, x, y, val, amp)) return 0;
            cheb_inverse_blk(&ti, (const double(*)[BLK])val, at);
            for (s = 0; s < ti.ns; s++)
                for (q = 0; q < BLK; q++) ph[(size_t)s * nq + j + q] = at[s][q] + fw->sph[(size_t)l * nq + j + q];
        }
        for (s = 0; s < ti.ns; s++) {
            const double *f = ph + (size_t)s * nq;
            for (p = 0; p < qd->patches; p++)
                for (b = 0; b < qd->nb; b++)
                    for (i = 0; i < qd->na; i++) {
                        const size_t k = ((size_t)p * (size_t)qd->nb + (size_t)b) * (size_t)qd->na + (size_t)i;
                        // Along the line, and across lines (scaled to the rule's nodes per
                        // side: a slit's lines are na / nb as many per unit)
                        if (i + 1 < qd->na) {
                            const double d = fabs(f[k + 1] - f[k]) / (qd->ua[i + 1] - qd->ua[i]);
                            if (d > fw->slope) fw->slope = d;
                        }
                        if (b + 1 < qd->nb) {
                            const double d = fabs(f[k + (size_t)qd->na] - f[k]) / (qd->ub[b + 1] - qd->ub[b]) *
                                             ((double)qd->na / qd->nb);
                            if (d > fw->slope) fw->slope = d;
                        }
                    }
        }
    }
    return 1;
}
