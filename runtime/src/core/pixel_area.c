/* The box pixel filter's sub-pixel points (issue 26): how many per pixel and axis.
 *
 * A pixel's value is the mean of the intensity over its area, taken by the midpoint rule
 * on sx x sy sub-rectangles (core/render.h, the render's grid). The automatic count
 * follows from the intensity's bandwidth. The field reaching the sensor from the
 * aperture is a superposition of waves whose direction cosines (per axis) lie within a
 * range of width D (the spread of the rays' directions over the aperture): its spectrum
 * lies in a band of width D / lambda, and the intensity |U|^2, whose spectrum is that
 * band's autocorrelation, holds no frequency beyond B = D / lambda (cycles per mm; for a
 * lens focused near the sensor D is about 1 / N_w, and B is the incoherent cutoff
 * 1 / (lambda N_w)). By Poisson's summation formula, h sum_k f(x0 + k h) equals the
 * integral of f over the line for every offset x0 once 1 / h > B: the midpoint sums on
 * points h = pitch / n apart integrate any such intensity exactly, whatever the
 * feature's position against the pixels. So
 *
 *     n = floor(1.05 pitch D / lambda_min) + 1, clamped to [1, LENSRT_MAX_PIXEL_SAMPLES],
 *
 * per axis (5% margin for the spread measured at a finite set of points), and a pixel
 * already finer than lambda / D keeps one point: its centre, as the point filter.
 *
 * D is measured from the render's own data: for a fitted lens (polynomial transport),
 * the phase polynomial P_s specialised per wavelength (r->ps, in mm of optical path)
 * gives the ray direction at the sensor as d phi_i / d x_S (the eikonal's gradient), here
 * by central differences in x_S and y_S at 3 x 3 points of the window, over a grid of
 * points of the aperture and its rim; for free space (analytic lenses, with or without
 * the perfect thin lens, whose phase does not depend on the sensor point) the
 * geometric direction from the stop point to the sensor point. Clips (pupils, a ghost's
 * P_clip) only narrow the spread, so it is an upper bound. */
#include "render.h"
#include "specialise.h"

#include "../lens/lens.h"

#include <math.h>
#include <string.h>

#define PI 3.14159265358979323846
#define GRID 15        /* stop points per side of the aperture's grid */
#define RIM 48         /* stop points on its rim */
#define MARGIN 1.05

/* The stop points the spread is measured at: a GRID x GRID grid over the sampled
 * region and RIM points on its boundary, those inside the aperture. Returns their count. */
static int stop_points(const lensrt_render r, double *ax, double *ay)
{
    const double rx = r->region.rx, ry = r->region.kind == LENSRT_REGION_INTERVAL ? 0.0 : r->region.ry > 0 ? r->region.ry : rx;
    int i, j, n = 0;
    for (j = 0; j < GRID; j++)
        for (i = 0; i < GRID; i++) {
            const double x = rx * (2.0 * i / (GRID - 1) - 1.0), y = ry * (2.0 * j / (GRID - 1) - 1.0);
            if (r->region.kind == LENSRT_REGION_INTERVAL && j > 0) continue;
            if (r->region.kind != LENSRT_REGION_INTERVAL &&
                !lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, x, y))
                continue;
            ax[n] = x;
            ay[n] = r->region.kind == LENSRT_REGION_INTERVAL ? 0.0 : y;
            n++;
        }
    for (i = 0; r->region.kind == LENSRT_REGION_DISC && i < RIM; i++) {
        const double t = 2.0 * PI * i / RIM, x = (1.0 - 1e-9) * rx * cos(t), y = (1.0 - 1e-9) * rx * sin(t);
        if (!lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, x, y)) continue;
        ax[n] = x;
        ay[n] = y;
        n++;
    }
    if (n == 0) { /* a shape too small for the grid: its centre */
        ax[0] = ay[0] = 0.0;
        n = 1;
    }
    return n;
}

/* The spread of d phi / d x_S and d phi / d y_S over the stop points at sensor point
 * (x, y), wavelength w: polynomial transport. */
static void spread_polynomial(const lensrt_render r, int w, double x, double y, const double *ax, const double *ay,
                              int n, double spread[2])
{
    const int ns = r->n_slots;
    const double h = 1e-3; /* mm: the phase is a smooth polynomial in x_S, y_S */
    double c[4][136], px[16], py[16], lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    int q, j, k;
    for (q = 0; q < 4; q++) {
        const double sx = x + (q == 0 ? h : q == 1 ? -h : 0.0), sy = y + (q == 2 ? h : q == 3 ? -h : 0.0);
        lensrt_sensor_powers(r->lens, sx, sy, px, py);
        lensrt_slot_coefficients(&r->ps[w * 4 + 3], px, py, c[q], ns);
    }
    for (j = 0; j < n; j++) {
        const double u = ax[j] / r->mono_radius, v = ay[j] / r->mono_radius;
        double pu[16], pv[16], g[2] = {0.0, 0.0};
        pu[0] = pv[0] = 1.0;
        for (k = 1; k <= r->degree; k++) {
            pu[k] = pu[k - 1] * u;
            pv[k] = pv[k - 1] * v;
        }
        for (k = 1; k < ns; k++) {
            const double mono = pu[r->slot_m[k]] * pv[r->slot_n[k]];
            g[0] += (c[0][k] - c[1][k]) * mono;
            g[1] += (c[2][k] - c[3][k]) * mono;
        }
        for (k = 0; k < 2; k++) {
            g[k] /= 2.0 * h;
            if (g[k] < lo[k]) lo[k] = g[k];
            if (g[k] > hi[k]) hi[k] = g[k];
        }
    }
    for (k = 0; k < 2; k++) spread[k] = hi[k] - lo[k];
}

/* The same for free space: the direction cosines of the line from the stop point to the
 * sensor point at distance z. */
static void spread_free_space(const lensrt_render r, double x, double y, const double *ax, const double *ay, int n,
                              double spread[2])
{
    const double z = r->lens->model.sensor_distance_mm + r->desc.sensor.focus_offset_mm;
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    int j, k;
    for (j = 0; j < n; j++) {
        const double dx = x - ax[j], dy = y - ay[j], len = sqrt(dx * dx + dy * dy + z * z);
        const double g[2] = {dx / len, dy / len};
        for (k = 0; k < 2; k++) {
            if (g[k] < lo[k]) lo[k] = g[k];
            if (g[k] > hi[k]) hi[k] = g[k];
        }
    }
    for (k = 0; k < 2; k++) spread[k] = hi[k] - lo[k];
}

/* The largest spread over the window (3 x 3 points: its corner, edge and centre pixels)
 * for wavelength w. */
static void window_spread(const lensrt_render r, int w, const double *ax, const double *ay, int n, double out[2])
{
    int i, j;
    out[0] = out[1] = 0.0;
    for (j = 0; j < 3; j++)
        for (i = 0; i < 3; i++) {
            const double x = r->xs[i * (r->width - 1) / 2], y = r->ys[j * (r->height - 1) / 2];
            double s[2];
            if (r->lens_ops->transport == LENSRT_TRANSPORT_FREE_SPACE) spread_free_space(r, x, y, ax, ay, n, s);
            else spread_polynomial(r, w, x, y, ax, ay, n, s);
            if (s[0] > out[0]) out[0] = s[0];
            if (s[1] > out[1]) out[1] = s[1];
        }
}

void lensrt_direction_spread(lensrt_render r, double spread[2])
{
    double ax[GRID * GRID + RIM], ay[GRID * GRID + RIM], s[2];
    const int n = stop_points(r, ax, ay);
    int w;
    spread[0] = spread[1] = 0.0;
    for (w = 0; w < r->n_wl; w++) {
        // Free space does not depend on the wavelength
        if (w > 0 && r->lens_ops->transport == LENSRT_TRANSPORT_FREE_SPACE) break;
        window_spread(r, w, ax, ay, n, s);
        if (s[0] > spread[0]) spread[0] = s[0];
        if (s[1] > spread[1]) spread[1] = s[1];
    }
    if (!isfinite(spread[0]) || !isfinite(spread[1])) spread[0] = spread[1] = INFINITY;
}

/* n = floor(MARGIN pitch D / lambda) + 1 within [1, LENSRT_MAX_PIXEL_SAMPLES]. */
static int count_for(double pitch_mm, double spread, double lambda_mm)
{
    const double t = MARGIN * pitch_mm * spread / lambda_mm;
    if (!(t < LENSRT_MAX_PIXEL_SAMPLES)) return LENSRT_MAX_PIXEL_SAMPLES;
    return (int)floor(t) + 1 > LENSRT_MAX_PIXEL_SAMPLES ? LENSRT_MAX_PIXEL_SAMPLES : (int)floor(t) + 1;
}

lensrt_result lensrt_pixel_samples_choose(lensrt_render r, int *sx, int *sy)
{
    const int one_d = r->lens_ops->one_dimensional(r->lens);
    double lambda = INFINITY, spread[2];
    int w;
    *sx = *sy = 1;
    if (r->pixel_filter == LENSRT_PIXEL_FILTER_POINT) return LENSRT_SUCCESS;
    *sx = r->desc.pixel_samples_x;
    *sy = one_d ? 1 : r->desc.pixel_samples_y;
    if (*sx > 0 && *sy > 0) return LENSRT_SUCCESS;
    for (w = 0; w < r->n_wl; w++)
        if (r->wavelengths[w] < lambda) lambda = r->wavelengths[w];
    lambda /= LENSRT_NM_PER_MM;
    lensrt_direction_spread(r, spread);
    if (*sx == 0) *sx = count_for(r->pixel_x, spread[0], lambda);
    if (*sy == 0) *sy = count_for(r->pixel_y, spread[1], lambda);
    lensrt_log(r->ctx, LENSRT_LOG_INFO,
               "pixel filter box: ray directions spread %.4g x %.4g over the aperture, pixels %.4g x %.4g um, "
               "shortest wavelength %.4g nm: %d x %d points per pixel",
               spread[0], spread[1], 1e3 * r->pixel_x, 1e3 * r->pixel_y, lambda * LENSRT_NM_PER_MM, *sx, *sy);
    return LENSRT_SUCCESS;
}
