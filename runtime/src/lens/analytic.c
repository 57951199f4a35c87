/* Analytic lenses (lensrt_lens_create_analytic): the aperture plane, then free space to
 * the sensor, with a perfect thin lens in the aperture when focal_length_mm > 0; in one
 * dimension (a line aperture, cylindrical waves, one sensor row) as the paper's
 * Algorithm 1. They carry the closed-form validations. Per sample the incoming wave is
 * a plane or spherical wave from the light (a perfect lens turns it into a sphere
 * converging on the light's image); the devices evaluate free space after the stop
 * (LENSRT_TRANSPORT_FREE_SPACE) from the sample's x and y. */
#include "lens.h"

#include "../c_numbers.h"

#include <math.h>

static int one_dimensional(lensrt_lens lens) { return lens->model.one_dimensional; }

static void wavelength_range(lensrt_lens lens, double *lo_nm, double *hi_nm)
{
    (void)lens;
    *lo_nm = 380.0;
    *hi_nm = 780.0;
}

static lensrt_result check_light(lensrt_render r, const lensrt_lens_info *info, int i, double x, double y)
{
    const lensrt_light *l = &r->lights[i];
    (void)info;
    (void)x;
    (void)y;
    if (r->lens->model.one_dimensional && l->field_y_deg != 0.0)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "light %d: a one-dimensional lens needs field_y_deg 0, got %g", i, l->field_y_deg);
    return LENSRT_SUCCESS;
}

static lensrt_result choose_stop(lensrt_render r, const lensrt_lens_info *info)
{
    const lensrt_aperture *a = &r->desc.aperture;
    const double f = r->lens->model.focal_length_mm;
    (void)info;
    // A perfect lens of focal length f: N = f / (2 R); free space needs a radius
    if (a->radius_mm > 0) r->stop_radius = a->radius_mm;
    else if (a->f_number > 0 && f > 0) r->stop_radius = f / (2.0 * a->f_number);
    else if (a->shape == LENSRT_APERTURE_SLIT) r->stop_radius = 0.0;
    else
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "aperture: free space needs radius_mm (or a slit); a perfect lens also takes f_number");
    r->f_number = f > 0 && r->stop_radius > 0 ? f / (2.0 * r->stop_radius) : 0.0;
    return LENSRT_SUCCESS;
}

static lensrt_result check_window(lensrt_render r, const lensrt_lens_info *info)
{
    (void)r;
    (void)info;
    return LENSRT_SUCCESS; /* free space reaches every sensor point */
}

static lensrt_result prepare(lensrt_render r)
{
    r->n_rows = 2; /* x, y */
    r->double_rows = 1;
    return LENSRT_SUCCESS;
}

static void sample_rows(const lensrt_render r, int w, double x, double y, double *mono, const lensrt_rows *rows)
{
    (void)r;
    (void)w;
    (void)mono;
    rows->d[0] = x;
    rows->d[rows->stride] = y;
}

/* Incoming wave at the stop: a plane or spherical wave from the light; a perfect lens
 * turns it into a sphere converging on the light's image. */
static void sample_wave(const lensrt_render r, int w, int l, double x, double y, const double *mono, double *amp,
                        double *opl_out)
{
    const int naive = r->desc.precision == LENSRT_PRECISION_NAIVE_FLOAT;
    double lx = r->light_x[l], ly = r->light_y[l], lz = sqrt(1.0 - lx * lx - ly * ly);
    double f = r->lens->model.focal_length_mm, D = r->light_d[l], opl;
    (void)w;
    (void)mono;
    (void)amp;
    if (f > 0) {
        double u = D > 0 ? D * lz : INFINITY;
        double v = D > 0 ? 1.0 / (1.0 / f - 1.0 / u) : f;
        double ix = D > 0 ? -(v / u) * D * lx : -v * lx / lz;
        double iy = D > 0 ? -(v / u) * D * ly : -v * ly / lz;
        opl = -sqrt((ix - x) * (ix - x) + (iy - y) * (iy - y) + v * v);
        if (naive) opl += D > 0 ? D + v : v;
    } else if (D > 0) {
        double px = D * lx, py = D * ly, pz = D * lz;
        opl = sqrt((px - x) * (px - x) + (py - y) * (py - y) + pz * pz);
        if (!naive) opl -= D;
    } else {
        opl = -(lx * x + ly * y);
    }
    *opl_out = opl;
}

/* The undeviated ray through the stop centre, to the sensor plane. */
static lensrt_result image_point(lensrt_context ctx, lensrt_lens lens, const lensrt_light *light, double lx, double ly,
                                 double wavelength_nm, double focus_offset_mm, double xy_mm[2])
{
    double lz = sqrt(1.0 - lx * lx - ly * ly), z = lens->model.sensor_distance_mm + focus_offset_mm;
    (void)ctx;
    (void)light;
    (void)wavelength_nm;
    xy_mm[0] = -z * lx / lz;
    xy_mm[1] = -z * ly / lz;
    return LENSRT_SUCCESS;
}

static const char *table_file(lensrt_lens lens)
{
    (void)lens;
    return NULL;
}

const lensrt_lens_ops lensrt_lens_analytic = {
    "analytic", LENSRT_TRANSPORT_FREE_SPACE, 0,
    one_dimensional, wavelength_range, check_light, choose_stop, check_window, prepare,
    sample_rows, sample_wave, image_point, table_file, NULL,
};

lensrt_result lensrt_lens_create_analytic(lensrt_context ctx, const lensrt_analytic_lens *desc,
                                          lensrt_lens *out)
{
    lensrt_lens lens;
    lensrt_analytic_lens full;
    lensrt_result res;
    if (!ctx || !desc || !out) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_lens_create_analytic: NULL argument");
    *out = NULL;
    // Read the caller's struct as far as its struct_size (the ABI rules of lensrt.h)
    if ((res = lensrt_struct_in(ctx, "lensrt_analytic_lens", desc, &full, sizeof full)) != LENSRT_SUCCESS) return res;
    desc = &full;
    if (!(desc->sensor_distance_mm > 0 && isfinite(desc->sensor_distance_mm)))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "analytic lens: sensor_distance_mm must be positive and finite, got %g",
                           desc->sensor_distance_mm);
    if (!isfinite(desc->focal_length_mm) || desc->focal_length_mm < 0)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "analytic lens: focal_length_mm must be 0 (none) or positive, got %g",
                           desc->focal_length_mm);
    lens = lensrt_calloc(ctx, 1, sizeof *lens);
    if (!lens) return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "analytic lens: out of memory");
    lens->ctx = ctx;
    lens->analytic = 1;
    lens->model = *desc;
    // The name goes into EXR metadata and the phasor files' scene hash: the "C" locale
    lensrt_snprintf_c(lens->name, sizeof lens->name, "%s%s, sensor at %g mm",
             desc->one_dimensional ? "one-dimensional " : "",
             desc->focal_length_mm > 0 ? "perfect thin lens" : "free space", desc->sensor_distance_mm);
    lens->focal_length_mm = desc->focal_length_mm;
    lens->info.struct_size = sizeof lens->info;
    lens->info.name = lens->name;
    lens->info.analytic = 1;
    lens->info.psf_vs_exact_cell = lens->psf_vs_exact_cell; /* "": no trust figures */
    lens->info.ghost_label = lens->ghost_label;             /* "": not a ghost */
    lens->info.focal_length_mm = desc->focal_length_mm;
    lens->info.wavelength_min_nm = 1.0;
    lens->info.wavelength_max_nm = 1e6;
    lens->info.focus_offset_min_mm = -desc->sensor_distance_mm;
    lens->info.focus_offset_max_mm = 1e300;
    lens->info.field_x = lens->info.field_y = 1.0;
    *out = lens;
    return LENSRT_SUCCESS;
}
