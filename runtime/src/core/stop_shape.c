/* The stop's shape (render.h, lensrt_stop_shape): the aperture's polygon or circle of a
 * render, and the tests the devices and the lens kinds make against it (a point inside;
 * a box inside, outside or across). */
#include "render.h"

#include <math.h>
#include <string.h>

void lensrt_stop_shape_init(const lensrt_aperture *ap, double radius_mm, lensrt_stop_shape *s)
{
    const double PI_ = 3.14159265358979323846, R = radius_mm;
    int k;
    memset(s, 0, sizeof *s);
    s->r2 = R * R;
    s->scale = R;
    if (ap->shape == LENSRT_APERTURE_BLADES) {
        // The edges as lensrt_aperture_contains draws them: normal k at rot + (2k + 1) pi / n,
        // apothem R cos(pi / n), half-chord R sin(pi / n), sagitta curvature (R - apothem)
        const int n = ap->blades;
        const double half = PI_ / n, rot = ap->rotation_deg * (PI_ / 180.0);
        const double apothem = R * cos(half), chord = R * sin(half);
        const double sag = ap->blade_curvature * (R - apothem);
        double g = 1.0, e;
        s->kind = LENSRT_STOP_BLADES;
        s->n = n;
        s->apothem = apothem;
        s->reach = apothem;
        e = apothem;
        if (sag > 1e-12 * R) { /* the same threshold as lensrt_aperture_contains */
            const double rho = (chord * chord + sag * sag) / (2.0 * sag);
            s->reach = apothem + sag;
            s->a = 1.0 / (2.0 * rho);
            g = 1.0 - s->reach / rho;
            e = s->reach * (1.0 - s->reach / (2.0 * rho));
        }
        for (k = 0; k < n; k++) {
            const double mid = rot + half + k * 2.0 * half;
            s->nx[k] = cos(mid);
            s->ny[k] = sin(mid);
            s->gx[k] = g * s->nx[k];
            s->gy[k] = g * s->ny[k];
            s->c[k] = e;
            s->f_gx[k] = (float)s->gx[k];
            s->f_gy[k] = (float)s->gy[k];
            s->f_c[k] = (float)s->c[k];
        }
    } else if (ap->shape == LENSRT_APERTURE_SLIT) {
        // One slit on the axis or two at +-separation / 2; the circle test only has to let
        // every point of theirs through (four times the squared corner distance)
        s->kind = LENSRT_STOP_SLIT;
        s->half_x = 0.5 * ap->slit_width_mm;
        s->half_y = R;
        s->n = ap->slit_separation_mm > 0.0 ? 2 : 1;
        s->centre[0] = 0.5 * ap->slit_separation_mm;
        s->centre[1] = -s->centre[0];
        s->r2 = 4.0 * (R * R + (s->centre[0] + s->half_x) * (s->centre[0] + s->half_x));
        s->scale = s->half_x < R ? s->half_x : R;
    }
    s->f_r2 = (float)s->r2;
    s->f_a = (float)s->a;
    s->f_half_x = (float)s->half_x;
    s->f_half_y = (float)s->half_y;
    s->f_centre[0] = (float)s->centre[0];
    s->f_centre[1] = (float)s->centre[1];
}

int lensrt_stop_shape_contains(const lensrt_stop_shape *s, double x, double y)
{
    const double r2 = x * x + y * y;
    int k, ok = r2 <= s->r2;
    if (s->kind == LENSRT_STOP_BLADES)
        for (k = 0; k < s->n; k++) ok &= s->a * r2 + s->gx[k] * x + s->gy[k] * y <= s->c[k];
    else if (s->kind == LENSRT_STOP_SLIT)
        ok &= fabs(y) <= s->half_y &&
              (fabs(x - s->centre[0]) <= s->half_x || (s->n == 2 && fabs(x - s->centre[1]) <= s->half_x));
    return ok;
}

int lensrt_stop_shape_box(const lensrt_stop_shape *s, double cx, double bx, double cy, double by)
{
    // The disc of radius sqrt(r2): none passes when the box's nearest point lies beyond
    const double lo_x = fabs(cx) - bx, lo_y = fabs(cy) - by, R = sqrt(s->r2);
    int k, all = 1;
    if (lo_x > R || lo_y > R || (lo_x > 0 && lo_y > 0 && hypot(lo_x, lo_y) > R)) return 0;
    if (s->kind == LENSRT_STOP_BLADES) {
        // Edge k spans [lo, hi] of n_k . p over the box: beyond the edges' farthest reach
        // (apothem + sag) none passes; within the apothem for every edge the box lies in
        // the straight polygon, which the curved one contains; or within the circle
        // inscribed in the shape (radius apothem + sag)
        for (k = 0; k < s->n; k++) {
            const double mid = s->nx[k] * cx + s->ny[k] * cy, half = fabs(s->nx[k]) * bx + fabs(s->ny[k]) * by;
            if (mid - half > s->reach) return 0;
            if (mid + half > s->apothem) all = 0;
        }
        return all || hypot(fabs(cx) + bx, fabs(cy) + by) <= s->reach ? 1 : 2;
    }
    if (s->kind == LENSRT_STOP_SLIT) {
        // The box within |y| <= half_y and within one slit, or outside either
        int in_x = 0, out_x = 1;
        if (fabs(cy) - by > s->half_y) return 0;
        for (k = 0; k < s->n; k++) {
            const double dx = fabs(cx - s->centre[k]);
            if (dx + bx <= s->half_x) in_x = 1;
            if (dx - bx <= s->half_x) out_x = 0;
        }
        if (out_x) return 0;
        return in_x && fabs(cy) + by <= s->half_y ? 1 : 2;
    }
    return hypot(fabs(cx) + bx, fabs(cy) + by) <= R ? 1 : 2;
}
