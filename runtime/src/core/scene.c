/* The scene of a render: the description's checks, the lights, the stop, the window of
 * pixels and the region the aperture samples are drawn from. What a lens covers is its
 * kind's to say (lens/lens.h); the rest is the same for every lens. */
#include "scene.h"

#include "../lens/lens.h"

#include <math.h>

#define PI 3.14159265358979323846

lensrt_result lensrt_scene_check_desc(lensrt_context ctx, const lensrt_render_desc *d, const lensrt_lens_info *info)
{
    const lensrt_sensor *s = &d->sensor;
    const lensrt_aperture *a = &d->aperture;
    int i;
    if (s->width <= 0 || s->height <= 0 || s->width > LENSRT_MAX_RESOLUTION || s->height > LENSRT_MAX_RESOLUTION)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "sensor: resolution must be 1..%d pixels per side, got %d x %d", LENSRT_MAX_RESOLUTION, s->width,
                           s->height);
    if (!(s->width_mm > 0 && isfinite(s->width_mm)) || !(s->height_mm >= 0 && isfinite(s->height_mm)))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "sensor: width_mm must be positive and height_mm positive or 0, got %g and %g",
                           s->width_mm, s->height_mm);
    if (!isfinite(s->center_x_mm) || !isfinite(s->center_y_mm) || !isfinite(s->focus_offset_mm))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "sensor: centre and focus offset must be finite");
    if (s->focus_offset_mm < info->focus_offset_min_mm - 1e-9 || s->focus_offset_mm > info->focus_offset_max_mm + 1e-9)
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                           "sensor: focus offset %g mm is outside the fitted range [%g, %g] mm of %s",
                           s->focus_offset_mm, info->focus_offset_min_mm, info->focus_offset_max_mm, info->name);
    if (d->n_lights < 0 || (d->n_lights > 0 && !d->lights) || d->n_lights > LENSRT_MAX_LIGHTS)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lights: expected 0..%d lights with a non-NULL array, got %d",
                           LENSRT_MAX_LIGHTS, d->n_lights);
    if (d->n_wavelengths < 0 || d->n_wavelengths > LENSRT_MAX_WAVELENGTHS)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "wavelengths: expected 0..%d, got %d", LENSRT_MAX_WAVELENGTHS,
                           d->n_wavelengths);
    if (d->wavelengths_nm && d->n_wavelengths == 0)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "wavelengths: an array was given with n_wavelengths 0");
    for (i = 0; d->wavelengths_nm && i < d->n_wavelengths; i++) {
        double w = d->wavelengths_nm[i];
        if (!(w >= info->wavelength_min_nm - 1e-9 && w <= info->wavelength_max_nm + 1e-9))
            return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                               "wavelength %d: %g nm is outside the fitted range [%g, %g] nm of %s",
                               i, w, info->wavelength_min_nm, info->wavelength_max_nm, info->name);
    }
    if ((unsigned)d->sampler > LENSRT_SAMPLER_SOBOL || (unsigned)d->estimator > LENSRT_ESTIMATOR_UNBIASED ||
        (unsigned)d->precision > LENSRT_PRECISION_NAIVE_FLOAT || (unsigned)a->shape > LENSRT_APERTURE_SLIT ||
        (unsigned)d->device > LENSRT_DEVICE_GL)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "sampler, estimator, precision, device or aperture shape: unknown value");
    // (|sum X|^2 - sum |X|^2) / (N (N - 1)) is unbiased for independent samples only:
    // with correlated ones (Sobol, strata) the mean's error is far below the i.i.d. term
    if (d->estimator == LENSRT_ESTIMATOR_UNBIASED &&
        (d->sampler == LENSRT_SAMPLER_SOBOL || d->sampler == LENSRT_SAMPLER_STRATIFIED))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "estimator: the unbiased estimator needs independent samples (sampler random "
                           "or default); the %s sampler correlates them and would bias it low",
                           d->sampler == LENSRT_SAMPLER_SOBOL ? "sobol" : "stratified");
    if (!(d->phase_tolerance_waves >= 0 && d->phase_tolerance_waves < 0.5))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "phase_tolerance_waves must be in [0, 0.5), got %g", d->phase_tolerance_waves);
    if (a->shape == LENSRT_APERTURE_BLADES && (a->blades < 3 || a->blades > LENSRT_MAX_BLADES || !(a->blade_curvature >= 0 && a->blade_curvature <= 1)))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "aperture: blades must be 3..%d with curvature in [0, 1], got %d blades, curvature %g",
                           LENSRT_MAX_BLADES,
                           a->blades, a->blade_curvature);
    if (a->shape == LENSRT_APERTURE_SLIT && (!(a->slit_width_mm > 0) || !(a->slit_separation_mm >= 0) ||
                                             (a->slit_separation_mm > 0 && a->slit_separation_mm < a->slit_width_mm)))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "aperture: a slit needs width > 0 and a separation of 0 or at least the width, got %g and %g",
                           a->slit_width_mm, a->slit_separation_mm);
    if (!(a->radius_mm >= 0 && isfinite(a->radius_mm)) || !(a->f_number >= 0 && isfinite(a->f_number)) || !isfinite(a->rotation_deg))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "aperture: radius_mm, f_number and rotation must be finite and not negative");
    if ((unsigned)d->pixel_filter > LENSRT_PIXEL_FILTER_POINT)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "pixel_filter: expected LENSRT_PIXEL_FILTER_BOX (0) or _POINT (1), got %d", d->pixel_filter);
    if (d->pixel_samples_x < 0 || d->pixel_samples_x > LENSRT_MAX_PIXEL_SAMPLES || d->pixel_samples_y < 0 ||
        d->pixel_samples_y > LENSRT_MAX_PIXEL_SAMPLES)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "pixel_samples: expected 0 (automatic) or 1..%d per axis, got %d x %d",
                           LENSRT_MAX_PIXEL_SAMPLES, d->pixel_samples_x, d->pixel_samples_y);
    if (d->pixel_filter == LENSRT_PIXEL_FILTER_POINT && (d->pixel_samples_x > 1 || d->pixel_samples_y > 1))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "pixel_samples: %d x %d sub-pixel samples with the point filter, which samples the "
                           "pixel's centre only; use the box filter", d->pixel_samples_x, d->pixel_samples_y);
    if (lensrt_lens_ops_of(d->lens)->one_dimensional(d->lens) && d->pixel_samples_y > 1)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "pixel_samples: a one-dimensional lens renders one line, pixel_samples_y must be 0 or 1, "
                           "got %d", d->pixel_samples_y);
    if (lensrt_lens_ops_of(d->lens)->one_dimensional(d->lens) && s->height != 1)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "sensor: a one-dimensional lens renders one row, got height %d", s->height);
    return LENSRT_SUCCESS;
}

/* The one place lensrt turns field angles into P_o's (x_O, y_O) (lensfit's is
 * lensfit.psf.psf.light_direction). Field angles are the designers' (lensrt.h, lensrt_light):
 * the chief ray travels along (tan x, tan y, 1), so the light lies the other way, along
 * (-tan x, -tan y, 1), and x_O, y_O are that direction's cosines. */
void lensrt_light_direction(const lensrt_light *l, double *x, double *y)
{
    double tx = tan(l->field_x_deg * (PI / 180.0)), ty = tan(l->field_y_deg * (PI / 180.0));
    double n = sqrt(1.0 + tx * tx + ty * ty);
    *x = -tx / n;
    *y = -ty / n;
}

lensrt_result lensrt_light_direction_cosines(lensrt_context ctx, const lensrt_light *light, double xy[2])
{
    lensrt_light full;
    lensrt_result res;
    if (!ctx || !light || !xy) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "light_direction_cosines: NULL argument");
    if ((res = lensrt_struct_in(ctx, "light_direction_cosines: lensrt_light", light, &full, sizeof full)) != LENSRT_SUCCESS)
        return res;
    // Beyond +-90 deg tan() wraps round: the light would be behind the lens
    if (!(fabs(full.field_x_deg) < 90.0) || !(fabs(full.field_y_deg) < 90.0))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "light_direction_cosines: field (%g, %g) deg: expected finite angles within +-90 deg",
                           full.field_x_deg, full.field_y_deg);
    lensrt_light_direction(&full, &xy[0], &xy[1]);
    return LENSRT_SUCCESS;
}

/* The lights' direction cosines and distances (r->light_x, light_y, light_d), each
 * light checked to be finite, in front of the lens and where the lens covers it. */
static lensrt_result place_lights(lensrt_render r, const lensrt_lens_info *info)
{
    int i;
    lensrt_result res;
    for (i = 0; i < r->n_lights; i++) {
        const lensrt_light *l = &r->lights[i];
        double x, y;
        if (!isfinite(l->field_x_deg) || !isfinite(l->field_y_deg) || !isfinite(l->distance_mm) ||
            !(l->intensity >= 0 && isfinite(l->intensity)))
            return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "light %d: values must be finite, intensity not negative", i);
        // Bounded so that no float accumulator of the kernel can overflow (lensrt.h)
        if (l->intensity > LENSRT_MAX_INTENSITY)
            return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "light %d: intensity %g is above LENSRT_MAX_INTENSITY (%g)",
                               i, l->intensity, LENSRT_MAX_INTENSITY);
        if (fabs(l->field_x_deg) >= 90.0 || fabs(l->field_y_deg) >= 90.0 || l->distance_mm < 0)
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                               "light %d: at (%g, %g) deg, distance %g mm is behind the lens "
                               "(field angles must be within +-90 deg and the distance positive, 0 for infinity)",
                               i, l->field_x_deg, l->field_y_deg, l->distance_mm);
        lensrt_light_direction(l, &x, &y);
        r->light_x[i] = x;
        r->light_y[i] = y;
        r->light_d[i] = l->distance_mm;
        if ((res = r->lens_ops->check_light(r, info, i, x, y)) != LENSRT_SUCCESS) return res;
    }
    return LENSRT_SUCCESS;
}

/* Where samples are drawn: the bounding disc, the slits' box, or an interval. */
static lensrt_result choose_region(lensrt_render r)
{
    const lensrt_aperture *a = &r->desc.aperture;
    const int one_d = r->lens_ops->one_dimensional(r->lens);
    if (a->shape == LENSRT_APERTURE_SLIT) {
        double half = 0.5 * (a->slit_separation_mm + a->slit_width_mm);
        if (!one_d && !(r->stop_radius > 0))
            return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "aperture: a two-dimensional slit needs radius_mm (half its length)");
        r->region.kind = one_d ? LENSRT_REGION_INTERVAL : LENSRT_REGION_BOX;
        r->region.rx = half;
        r->region.ry = one_d ? 0.0 : r->stop_radius;
        if (!one_d && r->lens_ops->slits_within_stop && half > r->stop_radius)
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "aperture: the slits reach %g mm, beyond the stop radius %g mm",
                               half, r->stop_radius);
    } else {
        r->region.kind = one_d ? LENSRT_REGION_INTERVAL : LENSRT_REGION_DISC;
        r->region.rx = r->stop_radius;
    }
    return LENSRT_SUCCESS;
}

void lensrt_scene_grid(lensrt_render r)
{
    const lensrt_sensor *s = &r->desc.sensor;
    int i;
    // The image's pixels, then the grid's points: sx x sy per pixel at the midpoints of
    // its sub-rectangles (with sx = sy = 1 the pixel centres, as before 0.8.0); row 0 is
    // the top of the image (+y); a one-dimensional lens's row lies on the window's
    // centre line
    r->pixel_x = s->width_mm / r->out_width;
    r->pixel_y = s->height_mm > 0 ? s->height_mm / r->out_height : r->pixel_x;
    r->width = r->out_width * r->sx;
    r->height = r->out_height * r->sy;
    r->pitch_x = s->width_mm / r->width;
    r->pitch_y = s->height_mm > 0 ? s->height_mm / r->height : r->pixel_x / r->sy;
    for (i = 0; i < r->width; i++) r->xs[i] = s->center_x_mm + (i + 0.5 - 0.5 * r->width) * r->pitch_x;
    for (i = 0; i < r->height; i++) r->ys[i] = s->center_y_mm + (0.5 * r->height - i - 0.5) * r->pitch_y;
    if (r->lens_ops->one_dimensional(r->lens)) r->ys[0] = s->center_y_mm;
}

lensrt_result lensrt_scene_place(lensrt_render r, const lensrt_lens_info *info)
{
    lensrt_result res;
    lensrt_scene_grid(r);
    if ((res = place_lights(r, info)) != LENSRT_SUCCESS || (res = r->lens_ops->choose_stop(r, info)) != LENSRT_SUCCESS ||
        (res = r->lens_ops->check_window(r, info)) != LENSRT_SUCCESS || (res = choose_region(r)) != LENSRT_SUCCESS)
        return res;
    r->measure = lensrt_region_measure(&r->region);
    r->mono_radius = fmax(r->region.rx, r->region.ry);
    return LENSRT_SUCCESS;
}
