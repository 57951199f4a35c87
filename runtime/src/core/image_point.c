/* lensrt_lens_image_point: where a light's chief ray (through the stop centre) meets
 * the sensor. The arguments are checked here; the lens kind finds the point (fitted
 * lenses: the stationary point of the polynomials' phase, below). */
#include "image_point.h"

#include "../lens/lens.h"
#include "scene.h"
#include "specialise.h"

#include <math.h>
#include <string.h>

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

lensrt_result lensrt_polynomial_image_point(lensrt_context ctx, lensrt_lens lens, const lensrt_light *light,
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

lensrt_result lensrt_lens_image_point(lensrt_context ctx, lensrt_lens lens, const lensrt_light *light,
                                      double wavelength_nm, double focus_offset_mm, double xy_mm[2])
{
    double lx, ly;
    lensrt_light full;
    lensrt_lens_info info = LENSRT_LENS_INFO_INIT;
    lensrt_result res;
    if (!ctx || !lens || !light || !xy_mm) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "image_point: NULL argument");
    if ((res = lensrt_struct_in(ctx, "image_point: lensrt_light", light, &full, sizeof full)) != LENSRT_SUCCESS)
        return res;
    light = &full;
    if (!(wavelength_nm > 0) || !isfinite(wavelength_nm) || !isfinite(focus_offset_mm) ||
        !(fabs(light->field_x_deg) < 90) || !(fabs(light->field_y_deg) < 90) || !(light->distance_mm >= 0) ||
        !isfinite(light->distance_mm))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "image_point: wavelength %g nm, focus %g mm, field (%g, %g) deg, distance %g mm: expected a "
                           "positive wavelength, finite focus, field angles within +-90 deg and a distance >= 0 (0: infinity)",
                           wavelength_nm, focus_offset_mm, light->field_x_deg, light->field_y_deg, light->distance_mm);
    // The lens's fitted ranges (as lensrt_render_create checks them): outside, the
    // polynomials extrapolate and the point would be a guess
    lensrt_lens_get_info(lens, &info);
    if (wavelength_nm < info.wavelength_min_nm - 1e-9 || wavelength_nm > info.wavelength_max_nm + 1e-9)
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "image_point: wavelength %g nm is outside the fitted range [%g, %g] nm of %s",
                           wavelength_nm, info.wavelength_min_nm, info.wavelength_max_nm, info.name);
    if (focus_offset_mm < info.focus_offset_min_mm - 1e-9 || focus_offset_mm > info.focus_offset_max_mm + 1e-9)
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "image_point: focus offset %g mm is outside the fitted range [%g, %g] mm of %s",
                           focus_offset_mm, info.focus_offset_min_mm, info.focus_offset_max_mm, info.name);
    if (light->distance_mm > 0 && light->distance_mm < info.distance_min_mm)
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "image_point: distance %g mm is closer than the fitted %g mm of %s",
                           light->distance_mm, info.distance_min_mm, info.name);
    lensrt_light_direction(light, &lx, &ly);
    return lensrt_lens_ops_of(lens)->image_point(ctx, lens, light, lx, ly, wavelength_nm, focus_offset_mm, xy_mm);
}
