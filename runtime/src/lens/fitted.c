/* Fitted lenses: the polynomials P_o (light to stop) and P_s (stop to sensor) of a
 * coefficient table, valid over the domain they were fitted on.
 *
 * Per render, P_o is specialised to each light and wavelength and P_s to each wavelength
 * (core/specialise.c), and the window's bases are found (core/basis.c). Per sample, the
 * stop monomials (and the basis functions) are the rows of the sample block, and P_o
 * gives the outer-pupil clip, the front group's transmittance and the phase. Devices
 * then specialise P_s per pixel (LENSRT_TRANSPORT_POLYNOMIAL). A ghost table's P_clip
 * is evaluated per sample here when it takes P_o's inputs (side P_o), per pixel and
 * splat by the devices when it takes P_s's. */
#include "lens.h"

#include "../core/basis.h"
#include "../core/cells.h"
#include "../core/specialise.h"

#include <math.h>
#include <string.h>

#define PI 3.14159265358979323846

static int one_dimensional(lensrt_lens lens)
{
    (void)lens;
    return 0;
}

static void wavelength_range(lensrt_lens lens, double *lo_nm, double *hi_nm)
{
    *lo_nm = lens->info.wavelength_min_nm;
    *hi_nm = lens->info.wavelength_max_nm;
}

static lensrt_result check_light(lensrt_render r, const lensrt_lens_info *info, int i, double x, double y)
{
    const lensrt_light *l = &r->lights[i];
    // The fitted field is an ellipse with these semi-axes (direction cosines)
    if ((x / info->field_x) * (x / info->field_x) + (y / info->field_y) * (y / info->field_y) > 1.0 + 1e-9)
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                           "light %d: field (%g, %g) deg is outside the fitted field of %s (%.3g x %.3g deg)",
                           i, l->field_x_deg, l->field_y_deg, info->name,
                           asin(info->field_x) * 180.0 / PI, asin(info->field_y) * 180.0 / PI);
    if (l->distance_mm > 0 && l->distance_mm < info->distance_min_mm * (1 - 1e-9))
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                           "light %d: distance %g mm is closer than the fitted %g mm of %s",
                           i, l->distance_mm, info->distance_min_mm, info->name);
    return LENSRT_SUCCESS;
}

/* A stop this little (relatively) wider than the fitted one is taken as the fitted one:
 * an f-number typed or computed to 7 digits (f/4.9999988 for a fit at f/5) must not be
 * refused. Clamping changes the stop radius by at most 1e-6 of itself, so the PSF's
 * power by 2e-6 and its width by 1e-6, far below the fit's PSF error (0.18% for 0001)
 * and any Monte Carlo error; the polynomials are never evaluated beyond their domain.
 * The same tolerance as lensfit's (paraxial.F_NUMBER_REL_TOL). */
#define STOP_REL_TOL 1e-6

static lensrt_result choose_stop(lensrt_render r, const lensrt_lens_info *info)
{
    const lensrt_aperture *a = &r->desc.aperture;
    lensrt_lens lens = r->lens;
    if (a->radius_mm > 0) r->stop_radius = a->radius_mm;
    else if (a->f_number > 0) r->stop_radius = lens->stop_radius_f1_mm / a->f_number;
    else r->stop_radius = info->stop_radius_max_mm;
    // Refused numbers differ by more than 1e-6 relative, so 9 digits always tell them apart
    if (r->stop_radius > info->stop_radius_max_mm * (1 + STOP_REL_TOL))
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                           "aperture: f/%.9g (stop radius %.9g mm) is wider than %s was fitted for: f/%.9g "
                           "(stop radius %.9g mm; tolerance %g relative)",
                           lens->stop_radius_f1_mm / r->stop_radius, r->stop_radius, info->name,
                           info->f_number_min, info->stop_radius_max_mm, STOP_REL_TOL);
    if (r->stop_radius > info->stop_radius_max_mm) r->stop_radius = info->stop_radius_max_mm;
    r->f_number = lens->stop_radius_f1_mm / r->stop_radius;
    return LENSRT_SUCCESS;
}

static lensrt_result check_window(lensrt_render r, const lensrt_lens_info *info)
{
    // The window must lie inside the fitted sensor square
    const lensrt_input *xs = &r->lens->p_s.inputs[0], *ys = &r->lens->p_s.inputs[1];
    double x0 = r->xs[0], x1 = r->xs[r->width - 1], y0 = r->ys[r->height - 1], y1 = r->ys[0];
    if (x0 < xs->lo - 1e-9 || x1 > xs->hi + 1e-9 || y0 < ys->lo - 1e-9 || y1 > ys->hi + 1e-9)
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                           "sensor: pixel centres span x [%g, %g] mm, y [%g, %g] mm, beyond the fitted "
                           "[%g, %g] x [%g, %g] mm of %s", x0, x1, y0, y1, xs->lo, xs->hi, ys->lo, ys->hi, info->name);
    return LENSRT_SUCCESS;
}

/* A ghost whose P_clip tests stop crossings (case C: its path meets the stop plane
 * again) tests each crossing against the render's aperture, exactly the set
 * lensrt_aperture_contains defines (circle, blades, slits): r->stop, in the form the
 * kernels test it in (core/render.h). A round stop keeps the circle test of its radius;
 * a shaped one tests its circle (the stop radius, or one around the slits) and then the
 * shape. Side P_o tests here per sample with lensrt_aperture_contains itself. */
static void prepare_stop_pairs(lensrt_render r)
{
    const lensrt_lens lens = r->lens;
    int q;
    lensrt_stop_shape_init(&r->desc.aperture, r->stop_radius, &r->stop);
    for (q = 0; q < r->n_clip_pairs; q++) {
        r->clip_shaped[q] = lens->clip_stop[q] && r->stop.kind != LENSRT_STOP_CIRCLE;
        if (r->clip_shaped[q]) r->clip_limit[q] = sqrt(r->stop.r2);
    }
}

static lensrt_result prepare(lensrt_render r)
{
    lensrt_result res;
    r->double_rows = r->desc.precision == LENSRT_PRECISION_DOUBLE;
    if ((res = lensrt_specialise_scene(r)) != LENSRT_SUCCESS) return res;
    prepare_stop_pairs(r);
    return lensrt_prepare_basis(r);
}

/* Stop monomials u^m v^n with u = x / R, v = y / R, then the window's basis functions
 * of this wavelength (as many as its pixels use). */
static void sample_rows(const lensrt_render r, int w, double x, double y, double *mono, const lensrt_rows *rows)
{
    const int ns = r->n_slots;
    const size_t st = rows->stride;
    double u = x / r->mono_radius, v = y / r->mono_radius, pu[16], pv[16];
    int k;
    pu[0] = pv[0] = 1.0;
    for (k = 1; k <= r->degree; k++) {
        pu[k] = pu[k - 1] * u;
        pv[k] = pv[k - 1] * v;
    }
    for (k = 0; k < ns; k++) {
        mono[k] = pu[r->slot_m[k]] * pv[r->slot_n[k]];
        if (r->double_rows) rows->d[(size_t)k * st] = mono[k];
        else rows->f[(size_t)k * st] = (float)mono[k];
    }
    if (r->use_basis) {
        int q, bb;
        for (bb = 0; bb < r->n_bases; bb++) {
            const double *V = r->basis + (size_t)(r->n_bases * w + bb) * (size_t)(ns - 1) * (size_t)(ns - 1);
            for (q = 0; q < r->basis_rank[r->n_bases * w + bb]; q++) {
                double gq = 0.0;
                for (k = 1; k < ns; k++) gq += V[(k - 1) * (ns - 1) + q] * mono[k];
                rows->f[(size_t)(r->row_base[bb] + q) * st] = (float)gq;
            }
        }
    }
}

/* P_o at a stop point: the outer-pupil position and every P_clip pair on this side as
 * level functions (>= 0: the path passes; mm-like, zero on the clip's boundary), the
 * front group's transmittance and the OPL from the light minus its distance. Returns
 * the number of levels: 1 + the ghost's pairs on side P_o. *pass says whether every
 * test passes, decided as the Monte Carlo samples always were (x^2 + y^2 against the
 * limit squared, a shaped stop crossing by lensrt_aperture_contains); levels NULL: only
 * those (the Monte Carlo samples' hot path computes no level). */
static int po_levels(const lensrt_render r, int w, int l, const double *mono, double *tau_out, double *opl_out,
                     double *levels, int *pass)
{
    const lensrt_lens lens = r->lens;
    const int ns = r->n_slots;
    const double *cx = lensrt_po_slots(r, l, w, 0), *cy = lensrt_po_slots(r, l, w, 1);
    const double *ct = lensrt_po_slots(r, l, w, 2), *cp = lensrt_po_slots(r, l, w, 3);
    const double *j0 = lensrt_po_slots(r, l, w, LENSRT_PO_FLUX), *j1 = lensrt_po_slots(r, l, w, LENSRT_PO_FLUX + 1);
    const double *j2 = lensrt_po_slots(r, l, w, LENSRT_PO_FLUX + 2), *j3 = lensrt_po_slots(r, l, w, LENSRT_PO_FLUX + 3);
    const double h = lens->housing_first_mm;
    double xo = 0, yo = 0, tau = 0, opl = 0.0, jac[4] = {0, 0, 0, 0};
    int k, n = 1;
    for (k = 0; k < ns; k++) {
        xo += cx[k] * mono[k];
        yo += cy[k] * mono[k];
        tau += ct[k] * mono[k];
        opl += cp[k] * mono[k];
        jac[0] += j0[k] * mono[k];
        jac[1] += j1[k] * mono[k];
        jac[2] += j2[k] * mono[k];
        jac[3] += j3[k] * mono[k];
    }
    // The flux through the stop per unit area: the transmittance times the front
    // group's ray density from the light (pupil distortion, a ghost's own mapping)
    tau *= lensrt_front_flux(r, l, xo, yo, jac);
    *pass = !(xo * xo + yo * yo > h * h);
    if (levels) levels[0] = (h * h - (xo * xo + yo * yo)) / (2.0 * (h > 0.0 ? h : 1.0));
    // A ghost's P_clip on this side: every pair must pass (x^2 + y^2 <= its limit^2, or
    // a stop crossing inside the aperture's shape)
    if (r->clip_o) {
        int q;
        for (q = 0; q < r->n_clip_pairs; q++) {
            const double *qx = lensrt_clip_o_slots(r, l, w, 2 * q), *qy = lensrt_clip_o_slots(r, l, w, 2 * q + 1);
            const double lim = r->clip_limit[q];
            double hx = 0.0, hy = 0.0;
            for (k = 0; k < ns; k++) {
                hx += qx[k] * mono[k];
                hy += qy[k] * mono[k];
            }
            if (r->clip_shaped[q]) {
                if (levels) levels[n] = lensrt_stop_shape_level(&r->stop, hx, hy);
                if (!lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, hx, hy)) *pass = 0;
            } else {
                if (levels) levels[n] = (lim * lim - (hx * hx + hy * hy)) / (2.0 * (lim > 0.0 ? lim : 1.0));
                if (hx * hx + hy * hy > lim * lim) *pass = 0;
            }
            n++;
        }
    }
    if (r->desc.precision == LENSRT_PRECISION_NAIVE_FLOAT) opl += r->light_d[l];
    *tau_out = tau;
    *opl_out = opl;
    return n;
}

/* P_o: outer-pupil clip, transmittance, OPL from the light minus its distance. */
static void sample_wave(const lensrt_render r, int w, int l, double x, double y, const double *mono, double *amp,
                        double *opl_out)
{
    double tau;
    int pass;
    (void)x;
    (void)y;
    po_levels(r, w, l, mono, &tau, opl_out, NULL, &pass);
    if (!pass) *amp = 0.0;
    *amp *= sqrt(tau > 0 ? tau : 0.0);
}

/* The cells integrator's view (lens/lens.h): the same without zeroing the amplitude. */
static int sample_levels(const lensrt_render r, int w, int l, const double *mono, double *amp, double *opl,
                         double *levels)
{
    double tau;
    int pass, n = po_levels(r, w, l, mono, &tau, opl, levels, &pass);
    *amp *= sqrt(tau > 0 ? tau : 0.0);
    return n;
}

/* ------------------------------------------------------------ chief rays ----- */

/* d output / d x_a (which = 3) or d y_a (which = 4) at the stop centre, per mm, with
 * every other input at xhat. */
static double stop_slope(const lensrt_system *sys, int o, int which, const double *xhat)
{
    const lensrt_poly *p = &sys->outputs[o];
    double sum = 0.0;
    int t, i;
    for (t = 0; t < p->n_terms; t++) {
        const unsigned char *e = p->exponents + (size_t)t * 6;
        double c;
        if (e[which] != 1 || e[7 - which] != 0) continue;
        c = p->coefficients[t];
        for (i = 0; i < 6; i++)
            if (i != 3 && i != 4) c *= lensrt_ipow(xhat[i], e[i]);
        sum += c;
    }
    return sum / sys->inputs[which].s;
}

/* Stop-centre phase gradient of P_s at sensor point (x, y) plus the light's (g0). */
static void total_gradient(const lensrt_lens lens, double x, double y, const double *xs, const double g0[2], double g[2])
{
    double xhat[6];
    memcpy(xhat, xs, sizeof xhat);
    xhat[0] = lensrt_normalise(&lens->p_s.inputs[0], x);
    xhat[1] = lensrt_normalise(&lens->p_s.inputs[1], y);
    g[0] = g0[0] + stop_slope(&lens->p_s, 3, 3, xhat);
    g[1] = g0[1] + stop_slope(&lens->p_s, 3, 4, xhat);
}

/* The chief ray (lensrt_lens_ops.image_point): where the total phase P_o + P_s of the
 * light (direction cosines lx, ly) is stationary at the stop centre, on the sensor
 * shifted by focus_offset_mm: Newton's method. */
static lensrt_result polynomial_image_point(lensrt_context ctx, lensrt_lens lens, const lensrt_light *light,
                                           double lx, double ly, double wavelength_nm, double focus_offset_mm,
                                           double xy_mm[2])
{
    double xo[6], xs[6], g0[2], x = 0.0, y = 0.0;
    int it;
    // The light's phase slope at the stop centre, from P_o
    xo[0] = lensrt_normalise(&lens->p_o.inputs[0], lx);
    xo[1] = lensrt_normalise(&lens->p_o.inputs[1], ly);
    xo[2] = lensrt_normalise(&lens->p_o.inputs[2], light->distance_mm > 0 ? 1.0 / light->distance_mm : 0.0);
    xo[3] = xo[4] = 0.0;
    xo[5] = lensrt_normalise(&lens->p_o.inputs[5], wavelength_nm);
    g0[0] = stop_slope(&lens->p_o, 3, 3, xo);
    g0[1] = stop_slope(&lens->p_o, 3, 4, xo);
    xs[2] = lensrt_normalise(&lens->p_s.inputs[2], focus_offset_mm);
    xs[3] = xs[4] = 0.0;
    xs[5] = lensrt_normalise(&lens->p_s.inputs[5], wavelength_nm);
    // Newton's method on the total slope, with a finite-difference Jacobian
    for (it = 0; it < 50; it++) {
        double g[2], gx[2], gy[2], h = 1e-4, a, b, c, d, det, dx, dy;
        total_gradient(lens, x, y, xs, g0, g);
        total_gradient(lens, x + h, y, xs, g0, gx);
        total_gradient(lens, x, y + h, xs, g0, gy);
        a = (gx[0] - g[0]) / h; b = (gy[0] - g[0]) / h;
        c = (gx[1] - g[1]) / h; d = (gy[1] - g[1]) / h;
        det = a * d - b * c;
        if (det == 0.0 || !isfinite(det)) break;
        dx = (d * g[0] - b * g[1]) / det;
        dy = (-c * g[0] + a * g[1]) / det;
        x -= dx;
        y -= dy;
        if (fabs(dx) + fabs(dy) < 1e-12) {
            xy_mm[0] = x;
            xy_mm[1] = y;
            return LENSRT_SUCCESS;
        }
    }
    return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "image_point: no chief ray found for the light at (%g, %g) deg through %s",
                       light->field_x_deg, light->field_y_deg, lens->name);
}

static const char *table_file(lensrt_lens lens) { return lens->file; }

const lensrt_lens_ops lensrt_lens_fitted = {
    "fitted", LENSRT_TRANSPORT_POLYNOMIAL, 1,
    one_dimensional, wavelength_range, check_light, choose_stop, check_window, prepare,
    sample_rows, sample_wave, polynomial_image_point, table_file, sample_levels,
};
