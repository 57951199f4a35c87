/* Fitted polynomials specialised to a scene (once per render) and to a pixel (per pass).
 *
 * Per render: P_s with z_S and lambda fixed, per wavelength (a polynomial in x_S, y_S
 * and the stop), and P_o with the light and lambda fixed, per light and wavelength (the
 * stop only). Per pixel: P_s's stop-monomial coefficients at the pixel, and the Huygens
 * amplitude from its phase. All in double. */
#include "specialise.h"

#include <math.h>
#include <string.h>

double lensrt_ipow(double x, int e)
{
    double y = 1.0;
    while (e-- > 0) y *= x;
    return y;
}

/* Powers 0..15 of the normalised sensor coordinates of (x, y), for the P_s terms. */
void lensrt_sensor_powers(const lensrt_lens lens, double x, double y, double px[16], double py[16])
{
    double xh = lensrt_normalise(&lens->p_s.inputs[0], x), yh = lensrt_normalise(&lens->p_s.inputs[1], y);
    int e;
    px[0] = py[0] = 1.0;
    for (e = 1; e < 16; e++) {
        px[e] = px[e - 1] * xh;
        py[e] = py[e - 1] * yh;
    }
}

/* Specialise output `o` of a system to fixed values of every input except the stop
 * (x_a, y_a at inputs 3, 4) and, when keep_xy, inputs 0, 1 (x_S, y_S).
 *
 * Without keep_xy every term lands in its stop slot. With keep_xy the result is a
 * polynomial in (x_S, y_S, stop): terms that differ only in the fixed inputs' exponents
 * (z_S, lambda) become the same monomial, so they are merged (coefficients summed in
 * table order; terms kept in order of first appearance, so the result is deterministic).
 * A tensor-product fit has ~17,000 terms per output and ~1,000 distinct monomials left,
 * and every pixel's set-up (CPU and GL) walks this list. */
static lensrt_result specialise(lensrt_render r, const lensrt_system *sys, int o, const double *xhat,
                                int keep_xy, lensrt_pixel_poly *out, double *slots)
{
    const lensrt_poly *p = &sys->outputs[o];
    const lensrt_input *xa = &sys->inputs[3];
    double scale = r->mono_radius / xa->s; /* xhat_a = scale * u */
    /* Merge index per packed (slot, ix, iy) key: 0 unseen, else 1 + the term's place */
    const size_t n_keys = (size_t)r->n_slots << 8;
    int *place = NULL, *term_place = NULL;
    int t, n = 0;
    if (keep_xy) {
        place = lensrt_calloc(r->ctx, n_keys, sizeof *place);
        term_place = lensrt_alloc(r->ctx, sizeof(int) * (size_t)p->n_terms + 1);
        if (!place || !term_place) {
            lensrt_free(r->ctx, place);
            lensrt_free(r->ctx, term_place);
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
        }
        // Pass 1: the distinct (x_S, y_S, stop) monomials, in order of first appearance
        for (t = 0; t < p->n_terms; t++) {
            const unsigned char *e = p->exponents + (size_t)t * 6;
            size_t key = (size_t)lensrt_slot_of(e[3], e[4]) << 8 | (size_t)e[0] << 4 | e[1];
            if (!place[key]) place[key] = ++n;
            term_place[t] = place[key] - 1;
        }
        lensrt_free(r->ctx, place);
        out->n = n;
        out->ix = lensrt_alloc(r->ctx, (size_t)n + 1);
        out->iy = lensrt_alloc(r->ctx, (size_t)n + 1);
        out->slot = lensrt_alloc(r->ctx, sizeof(int) * (size_t)n + 1);
        out->coef = lensrt_calloc(r->ctx, (size_t)n + 1, sizeof(double));
        if (!out->ix || !out->iy || !out->slot || !out->coef) {
            lensrt_free(r->ctx, term_place);
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
        }
    }
    // Pass 2 (the only one without keep_xy): the coefficients with the fixed inputs put in
    for (t = 0; t < p->n_terms; t++) {
        const unsigned char *e = p->exponents + (size_t)t * 6;
        double c = p->coefficients[t] * lensrt_ipow(scale, e[3] + e[4]);
        int i;
        for (i = keep_xy ? 2 : 0; i < 6; i++)
            if (i != 3 && i != 4) c *= lensrt_ipow(xhat[i], e[i]);
        if (keep_xy) {
            int k = term_place[t];
            out->ix[k] = e[0];
            out->iy[k] = e[1];
            out->slot[k] = lensrt_slot_of(e[3], e[4]);
            out->coef[k] += c;
        } else {
            slots[lensrt_slot_of(e[3], e[4])] += c;
        }
    }
    lensrt_free(r->ctx, term_place);
    return LENSRT_SUCCESS;
}

/* The front group's flux Jacobian of light l at wavelength w (LENSRT_PO_FLUX slots):
 * phi_o differentiated by the light's direction cosine x_O (y_O) with the other inputs
 * fixed, then by x_a and y_a, as stop-monomial coefficients. With d/du (u^m v^n) =
 * m u^(m-1) v^n and u = x_a / R, every derivative stays within the slots. */
static void specialise_flux(lensrt_render r, const double *xhat, int l, int w)
{
    const lensrt_system *sys = &r->lens->p_o;
    const lensrt_poly *p = &sys->outputs[3];
    const double scale = r->mono_radius / sys->inputs[3].s, R = r->mono_radius;
    int i, t, k;
    for (i = 0; i < 2; i++) {
        double *hx = lensrt_po_slots(r, l, w, LENSRT_PO_FLUX + 2 * i);
        double *hy = lensrt_po_slots(r, l, w, LENSRT_PO_FLUX + 2 * i + 1);
        double grad[136];
        memset(grad, 0, sizeof grad);
        // d phi_o / d (x_O or y_O): input i's affine scale s turns d/d xhat into d/dv
        for (t = 0; t < p->n_terms; t++) {
            const unsigned char *e = p->exponents + (size_t)t * 6;
            double c;
            int q;
            if (!e[i]) continue;
            c = p->coefficients[t] * lensrt_ipow(scale, e[3] + e[4]) * e[i] * lensrt_ipow(xhat[i], e[i] - 1) /
                sys->inputs[i].s;
            for (q = 0; q < 6; q++)
                if (q != 3 && q != 4 && q != i) c *= lensrt_ipow(xhat[q], e[q]);
            grad[lensrt_slot_of(e[3], e[4])] += c;
        }
        // ... then by x_a and y_a (slots of one degree less; the slots arrive zeroed)
        for (k = 0; k < r->n_slots; k++) {
            const int m = r->slot_m[k], n = r->slot_n[k];
            if (m > 0) hx[lensrt_slot_of(m - 1, n)] += grad[k] * m / R;
            if (n > 0) hy[lensrt_slot_of(m, n - 1)] += grad[k] * n / R;
        }
    }
}

/* The terms of phase polynomial p in slots 1 and 2 (the stop's linear monomials), in
 * p's order: all the Huygens amplitude's phase gradient needs, a small part of p. */
static lensrt_result gradient_terms(lensrt_render r, const lensrt_pixel_poly *p, lensrt_pixel_poly *out)
{
    int t, n = 0;
    out->ix = lensrt_alloc(r->ctx, (size_t)p->n + 1);
    out->iy = lensrt_alloc(r->ctx, (size_t)p->n + 1);
    out->slot = lensrt_alloc(r->ctx, sizeof(int) * (size_t)p->n + 1);
    out->coef = lensrt_alloc(r->ctx, sizeof(double) * (size_t)p->n + 1);
    if (!out->ix || !out->iy || !out->slot || !out->coef)
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
    for (t = 0; t < p->n; t++)
        if (p->slot[t] == 1 || p->slot[t] == 2) {
            out->ix[n] = p->ix[t];
            out->iy[n] = p->iy[t];
            out->slot[n] = p->slot[t];
            out->coef[n] = p->coef[t];
            n++;
        }
    out->n = n;
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_specialise_scene(lensrt_render r)
{
    lensrt_lens lens = r->lens;
    const lensrt_input *xa = &lens->p_s.inputs[3];
    int w, o, l, t, k, n_clip;
    lensrt_result res;
    // The stop inputs must be centred so that monomials of u = x_a / R stay monomials
    if (lens->p_s.inputs[3].c != 0 || lens->p_s.inputs[4].c != 0 || lens->p_o.inputs[3].c != 0 ||
        lens->p_o.inputs[4].c != 0 || xa->s != lens->p_s.inputs[4].s || xa->s != lens->p_o.inputs[3].s)
        return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE,
                           "%s: the stop inputs x_a, y_a must be normalised symmetrically (c = 0, equal s)", lens->file);
    // Highest stop degree in either system (and a ghost's P_clip)
    r->degree = 0;
    for (o = 0; o < 8; o++) {
        const lensrt_poly *ps[3];
        int q;
        ps[0] = o < 4 ? &lens->p_o.outputs[o] : NULL;
        ps[1] = o < 4 ? &lens->p_s.outputs[o] : NULL;
        ps[2] = o < lens->p_clip.n_outputs ? &lens->p_clip.outputs[o] : NULL;
        for (q = 0; q < 3; q++)
            for (t = 0; ps[q] && t < ps[q]->n_terms; t++) {
                const unsigned char *e = ps[q]->exponents + (size_t)t * 6;
                if (e[3] + e[4] > r->degree) r->degree = e[3] + e[4];
            }
    }
    // The flux Jacobian differentiates phi_o by the light's direction cosines: they must
    // be affine inputs
    if (lens->p_o.inputs[0].transform != LENSRT_TRANSFORM_AFFINE || lens->p_o.inputs[1].transform != LENSRT_TRANSFORM_AFFINE)
        return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE, "%s: P_o's inputs x_O, y_O must be affine", lens->file);
    if (r->degree > 15)
        return lensrt_fail(r->ctx, LENSRT_ERROR_PARSE, "%s: stop degree %d is above 15", lens->file, r->degree);
    r->n_slots = (r->degree + 1) * (r->degree + 2) / 2;
    for (k = 0; k <= r->degree; k++) {
        int n;
        for (n = 0; n <= k; n++) {
            r->slot_m[lensrt_slot_of(k - n, n)] = k - n;
            r->slot_n[lensrt_slot_of(k - n, n)] = n;
        }
    }
    r->ps = lensrt_calloc(r->ctx, (size_t)r->n_wl * 4, sizeof *r->ps);
    r->ps_grad = lensrt_calloc(r->ctx, (size_t)r->n_wl, sizeof *r->ps_grad);
    r->po = lensrt_calloc(r->ctx, (size_t)r->n_lights * (size_t)r->n_wl * LENSRT_PO_OUTPUTS * (size_t)r->n_slots,
                          sizeof(double));
    if (!r->ps || !r->ps_grad || !r->po) return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
    // A ghost's P_clip, specialised as the system whose inputs it takes
    n_clip = 2 * lens->n_clip_pairs;
    r->n_clip_pairs = lens->n_clip_pairs;
    r->clip_side = lens->ghost_side == LENSRT_SYSTEM_SENSOR;
    for (k = 0; k < lens->n_clip_pairs; k++) r->clip_limit[k] = lens->clip_stop[k] ? r->stop_radius : 1.0;
    if (n_clip && r->clip_side)
        r->clip_s = lensrt_calloc(r->ctx, (size_t)r->n_wl * (size_t)n_clip, sizeof *r->clip_s);
    else if (n_clip)
        r->clip_o = lensrt_calloc(r->ctx, (size_t)r->n_lights * (size_t)r->n_wl * (size_t)n_clip * (size_t)r->n_slots,
                                  sizeof(double));
    if (n_clip && !r->clip_s && !r->clip_o) return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "render: out of memory");
    for (w = 0; w < r->n_wl; w++) {
        double xhat[6] = {0, 0, 0, 0, 0, 0};
        // P_s with z_S and lambda fixed: a polynomial in x_S, y_S and the stop
        xhat[2] = lensrt_normalise(&lens->p_s.inputs[2], r->desc.sensor.focus_offset_mm);
        xhat[5] = lensrt_normalise(&lens->p_s.inputs[5], r->wavelengths[w]);
        for (o = 0; o < 4; o++) {
            res = specialise(r, &lens->p_s, o, xhat, 1, &r->ps[w * 4 + o], NULL);
            if (res != LENSRT_SUCCESS) return res;
        }
        if ((res = gradient_terms(r, &r->ps[w * 4 + 3], &r->ps_grad[w])) != LENSRT_SUCCESS) return res;
        for (o = 0; r->clip_s && o < n_clip; o++) {
            res = specialise(r, &lens->p_clip, o, xhat, 1, &r->clip_s[w * n_clip + o], NULL);
            if (res != LENSRT_SUCCESS) return res;
        }
        // P_o with the light and lambda fixed: a polynomial in the stop only
        for (l = 0; l < r->n_lights; l++) {
            double u = r->light_d[l] > 0 ? 1.0 / r->light_d[l] : 0.0;
            xhat[0] = lensrt_normalise(&lens->p_o.inputs[0], r->light_x[l]);
            xhat[1] = lensrt_normalise(&lens->p_o.inputs[1], r->light_y[l]);
            xhat[2] = lensrt_normalise(&lens->p_o.inputs[2], u);
            xhat[5] = lensrt_normalise(&lens->p_o.inputs[5], r->wavelengths[w]);
            for (o = 0; o < 4; o++)
                specialise(r, &lens->p_o, o, xhat, 0, NULL, lensrt_po_slots(r, l, w, o));
            specialise_flux(r, xhat, l, w);
            for (o = 0; r->clip_o && o < n_clip; o++)
                specialise(r, &lens->p_clip, o, xhat, 0, NULL, lensrt_clip_o_slots(r, l, w, o));
        }
    }
    return LENSRT_SUCCESS;
}

void lensrt_slot_coefficients(const lensrt_pixel_poly *p, const double *px, const double *py, double *c, int n_slots)
{
    int t;
    memset(c, 0, sizeof(double) * (size_t)n_slots);
    for (t = 0; t < p->n; t++) c[p->slot[t]] += p->coef[t] * px[p->ix[t]] * py[p->iy[t]];
}

/* Step (mm) of the central differences of the Huygens amplitude: 1e-3 of the pixel
 * pitch, at least 1e-6 mm. */
double lensrt_huygens_step(const lensrt_render r)
{
    return 1e-3 * fmax(r->pitch_x, 1e-3);
}

/* The slot (1,0) and (0,1) coefficients of phi at a sensor point: d phi / d u, d phi / d v
 * (p: phi's terms of those slots, r->ps_grad). */
static void phase_gradient(const lensrt_lens lens, const lensrt_pixel_poly *p, double x, double y, double g[2])
{
    double px[16], py[16];
    int t;
    lensrt_sensor_powers(lens, x, y, px, py);
    g[0] = g[1] = 0.0;
    for (t = 0; t < p->n; t++) {
        if (p->slot[t] == 1) g[0] += p->coef[t] * px[p->ix[t]] * py[p->iy[t]];
        if (p->slot[t] == 2) g[1] += p->coef[t] * px[p->ix[t]] * py[p->iy[t]];
    }
}

double lensrt_huygens_amplitude(const lensrt_render r, int w, double x, double y)
{
    const lensrt_lens lens = r->lens;
    const double lambda_mm = r->wavelengths[w] / LENSRT_NM_PER_MM;
    const double step = lensrt_huygens_step(r);
    const double s = 1.0 / (2.0 * step * r->mono_radius); /* slot coefficients are per unit u */
    double grad[4][2], a11, a12, a21, a22, det;
    phase_gradient(lens, &r->ps_grad[w], x + step, y, grad[0]);
    phase_gradient(lens, &r->ps_grad[w], x - step, y, grad[1]);
    phase_gradient(lens, &r->ps_grad[w], x, y + step, grad[2]);
    phase_gradient(lens, &r->ps_grad[w], x, y - step, grad[3]);
    a11 = (grad[0][0] - grad[1][0]) * s;
    a12 = (grad[2][0] - grad[3][0]) * s;
    a21 = (grad[0][1] - grad[1][1]) * s;
    a22 = (grad[2][1] - grad[3][1]) * s;
    det = fabs(a11 * a22 - a12 * a21);
    return sqrt(det) / lambda_mm;
}
