/* lensrt_lens_image_point: where a light's chief ray (through the stop centre) meets
 * the sensor. The arguments are checked here; the lens kind finds the point (fitted
 * lenses: the stationary point of the polynomials' phase, lens/fitted.c). */
#include "../lens/lens.h"
#include "scene.h"
#include "specialise.h"

#include <math.h>
#include <string.h>

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

/* ------------------------------------------------------------ footprints ----- */

#define FOOT_RIM 64   /* directions on the aperture's rim */
#define FOOT_GRID 9   /* stop points per side of the grid inside it */

/* The stop monomials u^m v^n of slot k at (x, y) mm (mono) and, where dx and dy are not
 * NULL, their derivatives by x and y, per mm (render.h). */
void lensrt_stop_monomials(const lensrt_render r, double x, double y, double *mono, double *dx, double *dy)
{
    const double u = x / r->mono_radius, v = y / r->mono_radius;
    double pu[17], pv[17];
    int k;
    pu[0] = pv[0] = 1.0;
    for (k = 1; k <= r->degree; k++) {
        pu[k] = pu[k - 1] * u;
        pv[k] = pv[k - 1] * v;
    }
    for (k = 0; k < r->n_slots; k++) {
        const int m = r->slot_m[k], n = r->slot_n[k];
        mono[k] = pu[m] * pv[n];
        if (!dx) continue;
        dx[k] = m ? m * pu[m - 1] * pv[n] / r->mono_radius : 0.0;
        dy[k] = n ? n * pu[m] * pv[n - 1] / r->mono_radius : 0.0;
    }
}

/* The total phase's gradient over the stop at stop point (monomial derivatives dx, dy)
 * for the sensor point (x, y), wavelength w: P_s's at (x, y) plus P_o's (g0). */
static void stop_gradient(const lensrt_render r, int w, double x, double y, const double *dx, const double *dy,
                          const double g0[2], double g[2])
{
    double px[16], py[16], c[136];
    int k;
    lensrt_sensor_powers(r->lens, x, y, px, py);
    lensrt_slot_coefficients(&r->ps[w * 4 + 3], px, py, c, r->n_slots);
    g[0] = g0[0];
    g[1] = g0[1];
    for (k = 1; k < r->n_slots; k++) {
        g[0] += c[k] * dx[k];
        g[1] += c[k] * dy[k];
    }
}

/* Output o of the pixel polynomials p (per wavelength: ps or clip_s) at sensor point
 * (x, y) and stop monomials mono. */
static double side_s_value(const lensrt_render r, const lensrt_pixel_poly *p, double x, double y, const double *mono)
{
    double px[16], py[16], c[136], v = 0.0;
    int k;
    lensrt_sensor_powers(r->lens, x, y, px, py);
    lensrt_slot_coefficients(p, px, py, c, r->n_slots);
    for (k = 0; k < r->n_slots; k++) v += c[k] * mono[k];
    return v;
}

/* Whether the ray through stop point (ax, ay) to sensor point (x, y) passes the clips of
 * side P_s: the inner pupil and a ghost's P_clip pairs there (as the devices test them). */
static int passes_side_s(const lensrt_render r, int w, double x, double y, double ax, double ay, const double *mono)
{
    const double h = r->lens->housing_last_mm;
    const double xi = side_s_value(r, &r->ps[w * 4], x, y, mono), yi = side_s_value(r, &r->ps[w * 4 + 1], x, y, mono);
    int q;
    (void)ax;
    (void)ay;
    if (xi * xi + yi * yi > h * h) return 0;
    for (q = 0; r->clip_s && q < r->n_clip_pairs; q++) {
        const int n_out = 2 * r->n_clip_pairs;
        const double hx = side_s_value(r, &r->clip_s[w * n_out + 2 * q], x, y, mono);
        const double hy = side_s_value(r, &r->clip_s[w * n_out + 2 * q + 1], x, y, mono);
        if (r->clip_shaped[q] ? !lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, hx, hy)
                              : hx * hx + hy * hy > r->clip_limit[q] * r->clip_limit[q])
            return 0;
    }
    return 1;
}

/* The stop points of a footprint: the centre, FOOT_RIM points just inside the aperture's
 * boundary (found along each direction by bisection) and a FOOT_GRID x FOOT_GRID grid,
 * those inside the aperture. Returns their count. */
static int footprint_points(const lensrt_render r, double *ax, double *ay)
{
    const double R = r->region.rx > 0 ? r->region.rx : r->stop_radius, PI_ = 3.14159265358979323846;
    int i, j, n = 0;
    ax[n] = ay[n] = 0.0;
    n++;
    for (i = 0; i < FOOT_RIM; i++) {
        const double c = cos(2.0 * PI_ * i / FOOT_RIM), s = sin(2.0 * PI_ * i / FOOT_RIM);
        double lo = 0.0, hi = R;
        int it;
        if (lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, hi * c, hi * s)) lo = hi;
        else
            for (it = 0; it < 40; it++) {
                const double mid = 0.5 * (lo + hi);
                if (lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, mid * c, mid * s)) lo = mid;
                else hi = mid;
            }
        lo *= 1.0 - 1e-9;
        if (lo <= 0.0 || !lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, lo * c, lo * s)) continue;
        ax[n] = lo * c;
        ay[n] = lo * s;
        n++;
    }
    for (j = 0; j < FOOT_GRID; j++)
        for (i = 0; i < FOOT_GRID; i++) {
            const double x = R * (2.0 * (i + 0.5) / FOOT_GRID - 1.0), y = R * (2.0 * (j + 0.5) / FOOT_GRID - 1.0);
            if (!lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, x, y)) continue;
            ax[n] = x;
            ay[n] = y;
            n++;
        }
    return n;
}

lensrt_result lensrt_render_footprint(lensrt_render r, double box_mm[4])
{
    double ax[1 + FOOT_RIM + FOOT_GRID * FOOT_GRID], ay[1 + FOOT_RIM + FOOT_GRID * FOOT_GRID];
    double box[4] = {INFINITY, -INFINITY, INFINITY, -INFINITY};
    int n, l, w, j, lost = 0;
    if (!r || !box_mm) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (r->lens_ops->transport != LENSRT_TRANSPORT_POLYNOMIAL || r->lens_ops->one_dimensional(r->lens))
        return lensrt_fail(r->ctx, LENSRT_ERROR_UNSUPPORTED,
                           "footprint: fitted two-dimensional lenses only (%s is not one)", r->lens->info.name);
    n = footprint_points(r, ax, ay);
    for (l = 0; l < r->n_lights; l++)
        for (w = 0; w < r->n_wl; w++) {
            // Newton's method from the window's centre, then from the last point found
            double x = r->desc.sensor.center_x_mm, y = r->desc.sensor.center_y_mm;
            const double *cp = lensrt_po_slots(r, l, w, 3);
            for (j = 0; j < n; j++) {
                double mono[136], dx[136], dy[136], g0[2] = {0.0, 0.0}, amp = 1.0, opl = 0.0, sx = x, sy = y;
                int k, it, found = 0;
                lensrt_stop_monomials(r, ax[j], ay[j], mono, dx, dy);
                // Side P_o: the outer pupil and a ghost's P_clip there (amplitude 0)
                r->lens_ops->sample_wave(r, w, l, ax[j], ay[j], mono, &amp, &opl);
                if (!(amp > 0.0)) continue;
                for (k = 1; k < r->n_slots; k++) {
                    g0[0] += cp[k] * dx[k];
                    g0[1] += cp[k] * dy[k];
                }
                for (it = 0; it < 40; it++) {
                    const double hs = 1e-3; /* mm: P_s is a smooth polynomial in x_S, y_S */
                    double g[2], gx[2], gy[2], a, b, c, d, det, ex, ey;
                    stop_gradient(r, w, sx, sy, dx, dy, g0, g);
                    stop_gradient(r, w, sx + hs, sy, dx, dy, g0, gx);
                    stop_gradient(r, w, sx, sy + hs, dx, dy, g0, gy);
                    a = (gx[0] - g[0]) / hs;
                    b = (gy[0] - g[0]) / hs;
                    c = (gx[1] - g[1]) / hs;
                    d = (gy[1] - g[1]) / hs;
                    det = a * d - b * c;
                    if (det == 0.0 || !isfinite(det)) break;
                    ex = (d * g[0] - b * g[1]) / det;
                    ey = (-c * g[0] + a * g[1]) / det;
                    sx -= ex;
                    sy -= ey;
                    if (!isfinite(sx) || !isfinite(sy)) break;
                    if (fabs(ex) + fabs(ey) < 1e-9) {
                        found = 1;
                        break;
                    }
                }
                if (!found) {
                    lost++;
                    continue;
                }
                x = sx;
                y = sy;
                if (!passes_side_s(r, w, sx, sy, ax[j], ay[j], mono)) continue;
                if (sx < box[0]) box[0] = sx;
                if (sx > box[1]) box[1] = sx;
                if (sy < box[2]) box[2] = sy;
                if (sy > box[3]) box[3] = sy;
            }
        }
    if (lost)
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                           "footprint: %d of %d rays through the stop found no landing point on the sensor of %s (its "
                           "polynomials do not say where they land)", lost, n * r->n_lights * r->n_wl, r->lens->info.name);
    memcpy(box_mm, box, sizeof box);
    return LENSRT_SUCCESS;
}
