/* A render's images: linear sRGB through the CIE 1931 observer, and the EXR (spectral
 * channels, RGB preview, lens and render metadata) and PNG files (io/image_exr.c,
 * io/image_png.c), written atomically. */
#include "../c_numbers.h"
#include "../core/fourier.h"
#include "../core/render.h"
#include "../lens/lens.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

/* The centre of the image's first pixel (x of column 0, y of row 0), as the render's
 * grid of the point filter has it (core/scene.c): a box filter's grid points lie
 * within the pixels (core/render.h), so renders of either filter add over one window. */
static double first_x(const lensrt_render r)
{
    return r->desc.sensor.center_x_mm + (0 + 0.5 - 0.5 * r->out_width) * r->pixel_x;
}

static double first_y(const lensrt_render r)
{
    if (r->lens_ops->one_dimensional(r->lens)) return r->desc.sensor.center_y_mm;
    return r->desc.sensor.center_y_mm + (0.5 * r->out_height - 0 - 0.5) * r->pixel_y;
}

/* Renders whose images add (a light's direct image and its ghosts'): the same window
 * (resolution, pixel centres) and the same wavelengths as the first; their pixel
 * filters may differ (each image is its own filter's). */
static lensrt_result check_same_frame(const lensrt_render *rs, int n)
{
    const lensrt_render a = rs[0];
    int i, k;
    for (i = 1; i < n; i++) {
        const lensrt_render b = rs[i];
        if (!b) return lensrt_fail(a->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "image sum: render %d is NULL", i);
        if (b->out_width != a->out_width || b->out_height != a->out_height || first_x(b) != first_x(a) || first_y(b) != first_y(a) ||
            b->pixel_x != a->pixel_x || b->pixel_y != a->pixel_y)
            return lensrt_fail(a->ctx, LENSRT_ERROR_INCOMPATIBLE,
                               "image sum: render %d (%s) has a %d x %d window of pitch %.17g x %.17g mm from (%.17g, "
                               "%.17g) mm, render 0 (%s) %d x %d of %.17g x %.17g mm from (%.17g, %.17g) mm: images "
                               "add only over the same pixels", i, b->lens->file, b->out_width, b->out_height, b->pixel_x,
                               b->pixel_y, first_x(b), first_y(b), a->lens->file, a->out_width, a->out_height, a->pixel_x,
                               a->pixel_y, first_x(a), first_y(a));
        if (b->n_wl != a->n_wl)
            return lensrt_fail(a->ctx, LENSRT_ERROR_INCOMPATIBLE,
                               "image sum: render %d (%s) has %d wavelengths, render 0 (%s) %d", i, b->lens->file,
                               b->n_wl, a->lens->file, a->n_wl);
        for (k = 0; k < a->n_wl; k++)
            if (b->wavelengths[k] != a->wavelengths[k])
                return lensrt_fail(a->ctx, LENSRT_ERROR_INCOMPATIBLE,
                                   "image sum: render %d (%s): wavelength %d is %.17g nm, render 0's %.17g nm", i,
                                   b->lens->file, k, b->wavelengths[k], a->wavelengths[k]);
    }
    return LENSRT_SUCCESS;
}

/* The sum of the renders' images into out (count: wavelengths x pixels), summed in double. */
static lensrt_result image_sum(const lensrt_render *rs, int n, float *out, size_t count)
{
    const lensrt_render a = rs[0];
    double *acc;
    size_t k;
    int i;
    lensrt_result res = LENSRT_SUCCESS;
    if (n == 1) return lensrt_render_image(a, out, count);
    acc = lensrt_calloc(a->ctx, count + 1, sizeof(double));
    if (!acc) return lensrt_fail(a->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "image sum: out of memory");
    for (i = 0; i < n && res == LENSRT_SUCCESS; i++) {
        // Each render's image (its own checks and messages, in its own context)
        res = lensrt_render_image(rs[i], out, count);
        if (res != LENSRT_SUCCESS && rs[i]->ctx != a->ctx)
            lensrt_fail(a->ctx, res, "image sum: render %d (%s): %s", i, rs[i]->lens->file, lensrt_context_last_error(rs[i]->ctx));
        for (k = 0; res == LENSRT_SUCCESS && k < count; k++) acc[k] += (double)out[k];
    }
    for (k = 0; res == LENSRT_SUCCESS && k < count; k++) {
        out[k] = (float)acc[k];
        if (!isfinite(out[k]))
            res = lensrt_fail(a->ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "image sum: value %zu is %g, not a finite float", k, acc[k]);
    }
    lensrt_free(a->ctx, acc);
    return res;
}

lensrt_result lensrt_renders_image(const lensrt_render *renders, int n_renders, float *out, size_t count)
{
    lensrt_result res;
    if (!renders || n_renders < 1 || !renders[0] || !out) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = check_same_frame(renders, n_renders)) != LENSRT_SUCCESS) return res;
    if (count != (size_t)renders[0]->out_width * (size_t)renders[0]->out_height * (size_t)renders[0]->n_wl)
        return lensrt_fail(renders[0]->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "image sum: count must be %zu (wavelengths x pixels), got %zu",
                           (size_t)renders[0]->out_width * (size_t)renders[0]->out_height * (size_t)renders[0]->n_wl, count);
    return image_sum(renders, n_renders, out, count);
}

static lensrt_result spectral_and_rgb_of(const lensrt_render *rs, int n, float **spectral, float **rgb)
{
    const lensrt_render r = rs[0];
    size_t npix = (size_t)r->out_width * (size_t)r->out_height, p;
    lensrt_result res;
    *spectral = lensrt_alloc(r->ctx, sizeof(float) * npix * (size_t)r->n_wl);
    *rgb = lensrt_alloc(r->ctx, sizeof(float) * npix * 3);
    if (!*spectral || !*rgb) return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "image: out of memory");
    if ((res = image_sum(rs, n, *spectral, npix * (size_t)r->n_wl)) != LENSRT_SUCCESS) return res;
    lensrt_spectrum_to_rgb(r->n_wl, r->wavelengths, *spectral, npix, *rgb);
    // Finite spectra near FLT_MAX can still add up to inf in a colour channel
    for (p = 0; p < 3 * npix; p++)
        if (!isfinite((*rgb)[p]))
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "rgb: pixel (%d, %d) channel %d is %g, not a finite float",
                               (int)(p / 3 % (size_t)r->out_width), (int)(p / 3 / (size_t)r->out_width), (int)(p % 3),
                               (double)(*rgb)[p]);
    return LENSRT_SUCCESS;
}

static lensrt_result spectral_and_rgb(lensrt_render r, float **spectral, float **rgb)
{
    return spectral_and_rgb_of(&r, 1, spectral, rgb);
}

lensrt_result lensrt_render_rgb(lensrt_render r, float *out, size_t count)
{
    float *spectral = NULL, *rgb = NULL;
    lensrt_result res;
    if (!r || !out) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (count != (size_t)r->out_width * (size_t)r->out_height * 3)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "rgb: count must be %zu, got %zu",
                           (size_t)r->out_width * (size_t)r->out_height * 3, count);
    res = spectral_and_rgb(r, &spectral, &rgb);
    if (res == LENSRT_SUCCESS) memcpy(out, rgb, sizeof(float) * count);
    lensrt_free(r->ctx, spectral);
    lensrt_free(r->ctx, rgb);
    return res;
}

lensrt_result lensrt_spectrum_rgb(lensrt_context ctx, int n_wavelengths, const double *wavelengths_nm, const float *spectral,
                                  size_t n_pixels, float *rgb)
{
    int w;
    if (!ctx || !wavelengths_nm || !spectral || !rgb)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "spectrum_rgb: NULL argument");
    if (n_wavelengths < 1 || n_wavelengths > LENSRT_MAX_WAVELENGTHS)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "spectrum_rgb: %d wavelengths; expected 1 to %d",
                           n_wavelengths, LENSRT_MAX_WAVELENGTHS);
    // The cell widths come from the neighbours: finite, positive and strictly increasing
    for (w = 0; w < n_wavelengths; w++)
        if (!(isfinite(wavelengths_nm[w]) && wavelengths_nm[w] > 0.0) || (w > 0 && !(wavelengths_nm[w] > wavelengths_nm[w - 1])))
            return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                               "spectrum_rgb: wavelength %d is %g nm; expected finite, > 0 and strictly increasing", w,
                               wavelengths_nm[w]);
    lensrt_spectrum_to_rgb(n_wavelengths, wavelengths_nm, spectral, n_pixels, rgb);
    return LENSRT_SUCCESS;
}

static void describe_aperture(const lensrt_render r, char *buf, size_t size)
{
    const lensrt_aperture *a = &r->desc.aperture;
    // EXR metadata: numbers in the "C" locale whatever the host's (c_numbers.h)
    if (a->shape == LENSRT_APERTURE_BLADES)
        lensrt_snprintf_c(buf, size, "%d blades, curvature %g, rotation %g deg", a->blades, a->blade_curvature,
                          a->rotation_deg);
    else if (a->shape == LENSRT_APERTURE_SLIT)
        lensrt_snprintf_c(buf, size, "slit %g mm wide, separation %g mm", a->slit_width_mm, a->slit_separation_mm);
    else
        snprintf(buf, size, "circle");
}

/* Room for "lensrt/sampleRuns": every run a phasor file records, and the render's own. */
#define RUNS_TEXT_SIZE ((64 + 1) * 64)

/* The runs of samples the sums hold, "<seed> <first> <end>; ..." (sample indices
 * [first, end) of that seed's sequence), into text; 0 (text empty) when they are simply
 * the render's own sequence from sample 0, which "lensrt/seed" and
 * "lensrt/samplesPerWavelength" already say. The render's own run since the last save or
 * merge is the one core/render.h says lies past runs_samples (recorded there later). */
static int sample_runs_text(const lensrt_render r, char *text, size_t size)
{
    uint64_t runs[65][3];
    size_t used = 0;
    int n = 0, i;
    text[0] = '\0';
    for (i = 0; i < r->n_runs && i < 64; i++, n++) memcpy(runs[n], r->runs[i], sizeof runs[n]);
    if (r->samples > r->runs_samples) {
        if (n > 0 && runs[n - 1][0] == r->desc.seed && runs[n - 1][2] == r->runs_samples)
            runs[n - 1][2] = r->samples; /* the same sequence, continued */
        else {
            runs[n][0] = r->desc.seed;
            runs[n][1] = r->runs_samples;
            runs[n][2] = r->samples;
            n++;
        }
    }
    if (n == 0 || (n == 1 && runs[0][0] == r->desc.seed && runs[0][1] == 0 && runs[0][2] == r->samples)) return 0;
    for (i = 0; i < n && used < size; i++)
        used += (size_t)snprintf(text + used, size - used, "%s%llu %llu %llu", i ? "; " : "",
                                 (unsigned long long)runs[i][0], (unsigned long long)runs[i][1],
                                 (unsigned long long)runs[i][2]);
    return 1;
}

/* The EXR metadata of render r (`aperture`: 128 bytes for its description, `runs`:
 * RUNS_TEXT_SIZE bytes for its sample runs). Only the integrator's own parameters are
 * set: a cells or Fourier render has no samples, sampler, estimator or seed. */
static void image_meta(const lensrt_render r, lensrt_image_meta *out, char *aperture, char *runs)
{
    lensrt_image_meta meta;
    const int deterministic = r->cells_rings || r->fourier_nodes;
    memset(&meta, 0, sizeof meta);
    describe_aperture(r, aperture, 128);
    meta.lens_name = r->lens->name;
    meta.lens_file = r->lens_ops->table_file(r->lens);
    meta.focal_length_mm = r->lens->focal_length_mm;
    meta.f_number = r->f_number;
    meta.stop_radius_mm = r->stop_radius;
    meta.focus_offset_mm = r->desc.sensor.focus_offset_mm;
    meta.pixel_pitch_x_mm = r->pixel_x;
    meta.pixel_pitch_y_mm = r->pixel_y;
    meta.center_x_mm = r->desc.sensor.center_x_mm;
    meta.center_y_mm = r->desc.sensor.center_y_mm;
    meta.seconds = r->seconds;
    meta.aperture = aperture;
    if (!deterministic) {
        meta.samples_per_wavelength = r->samples;
        meta.splats_per_second = r->seconds > 0 ? (double)r->splats / r->seconds : 0.0;
        meta.sampler = lensrt_sampler_name(r->desc.sampler);
        meta.estimator = r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED ? "unbiased" : "paper";
        meta.seed = r->desc.seed;
        meta.sample_runs = sample_runs_text(r, runs, RUNS_TEXT_SIZE) ? runs : NULL;
        // The pruning tolerance: fitted lenses' phase terms, unless precision DOUBLE keeps all
        if (r->lens_ops->transport == LENSRT_TRANSPORT_POLYNOMIAL && r->desc.precision != LENSRT_PRECISION_DOUBLE)
            meta.phase_tolerance_waves = r->desc.phase_tolerance_waves;
    }
    meta.cells_rings = r->cells_rings;
    meta.fourier_nodes = r->fourier_nodes;
    meta.fourier_tolerance = r->fourier_nodes ? LENSRT_FOURIER_TOL : 0.0;
    meta.error_estimate = deterministic ? r->cells_error : -1.0;
    meta.pixel_filter = r->pixel_filter == LENSRT_PIXEL_FILTER_POINT ? "point" : "box";
    meta.pixel_samples_x = r->sx;
    meta.pixel_samples_y = r->sy;
    meta.n_lights = r->n_lights;
    meta.lights = r->lights;
    *out = meta;
}

/* One render's integrator in words, for "lensrt/renders": "<table>: fourier, 48 nodes
 * per side, error estimate 0.0012" (NUL-terminated, at most size bytes). */
static size_t describe_integrator(const lensrt_render r, char *text, size_t size)
{
    const char *file = r->lens_ops->table_file(r->lens);
    const char *name = file ? file : r->lens->name;
    int n;
    if (r->cells_rings)
        n = lensrt_snprintf_c(text, size, "%s: cells, %d rings", name, r->cells_rings);
    else if (r->fourier_nodes)
        n = lensrt_snprintf_c(text, size, "%s: fourier, %d nodes per side", name, r->fourier_nodes);
    else
        n = lensrt_snprintf_c(text, size, "%s: montecarlo, %llu samples per wavelength, sampler %s, seed %llu", name,
                              (unsigned long long)r->samples, lensrt_sampler_name(r->desc.sampler),
                              (unsigned long long)r->desc.seed);
    if ((r->cells_rings || r->fourier_nodes) && r->cells_error >= 0.0 && n >= 0 && (size_t)n < size)
        n += lensrt_snprintf_c(text + n, size - (size_t)n, ", error estimate %.3g", r->cells_error);
    return n < 0 ? 0 : (size_t)n < size ? (size_t)n : size - 1;
}

/* "lensrt/renders" of a file that adds n > 1 renders: each render's integrator, in file
 * order, separated by "; " (NULL when out of memory; the caller frees it). */
static char *renders_text(lensrt_context ctx, const lensrt_render *rs, int n)
{
    size_t size = 1, used = 0;
    char *text;
    int i;
    for (i = 0; i < n; i++) {
        const char *file = rs[i]->lens_ops->table_file(rs[i]->lens);
        size += strlen(file ? file : rs[i]->lens->name) + 160;
    }
    if (!(text = lensrt_alloc(ctx, size))) return NULL;
    text[0] = '\0';
    for (i = 0; i < n; i++) {
        if (i) used += (size_t)snprintf(text + used, size - used, "; ");
        used += describe_integrator(rs[i], text + used, size - used);
    }
    return text;
}

/* The image (the sum of the renders' images) as EXR, with the first render's metadata
 * (without what differs from run to run when `reproducible`), or PNG. */
static lensrt_result write_image_as(const lensrt_render *rs, int n, const char *path, int exr, double decades,
                                   int reproducible)
{
    float *spectral = NULL, *rgb = NULL;
    lensrt_render r = rs ? rs[0] : NULL;
    lensrt_result res;
    char err[LENSRT_ERROR_SIZE] = "", aperture[128], runs[RUNS_TEXT_SIZE], *renders = NULL;
    if (!r || !path || n < 1) return LENSRT_ERROR_INVALID_ARGUMENT;
    if ((res = check_same_frame(rs, n)) != LENSRT_SUCCESS) return res;
    res = spectral_and_rgb_of(rs, n, &spectral, &rgb);
    if (res == LENSRT_SUCCESS && exr && n > 1 && !(renders = renders_text(r->ctx, rs, n)))
        res = lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "EXR '%s': out of memory", path);
    if (res == LENSRT_SUCCESS && exr) {
        lensrt_image_meta meta;
        image_meta(r, &meta, aperture, runs);
        meta.renders = renders;
        meta.reproducible = reproducible;
        res = lensrt_write_exr(&r->ctx->allocator, path, r->out_width, r->out_height, r->n_wl, r->wavelengths,
                               spectral, rgb, &meta, err, sizeof err);
    } else if (res == LENSRT_SUCCESS) {
        res = lensrt_write_png(&r->ctx->allocator, path, r->out_width, r->out_height, rgb, decades, err, sizeof err);
    }
    if (res != LENSRT_SUCCESS && err[0]) lensrt_fail(r->ctx, res, "%s", err);
    lensrt_free(r->ctx, renders);
    lensrt_free(r->ctx, spectral);
    lensrt_free(r->ctx, rgb);
    return res;
}

static lensrt_result write_image(const lensrt_render *rs, int n, const char *path, int exr, double decades)
{
    return write_image_as(rs, n, path, exr, decades, 0);
}

lensrt_result lensrt_render_write_exr(lensrt_render r, const char *path) { return write_image(&r, 1, path, 1, 0.0); }

/* The options of a write_exr_with call, read by their struct_size and checked (NULL:
 * the defaults); *reproducible set from them. */
static lensrt_result exr_options_in(lensrt_context ctx, const char *path, const lensrt_exr_options *options,
                                    int *reproducible)
{
    lensrt_exr_options o;
    lensrt_result res;
    *reproducible = 0;
    if (!options) return LENSRT_SUCCESS;
    if ((res = lensrt_struct_in(ctx, "lensrt_exr_options", options, &o, sizeof o)) != LENSRT_SUCCESS) return res;
    if (o.reproducible != 0 && o.reproducible != 1)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "EXR '%s': lensrt_exr_options.reproducible is %d; expected 0 or 1", path ? path : "(null)",
                           (int)o.reproducible);
    *reproducible = o.reproducible;
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_render_write_exr_with(lensrt_render r, const char *path, const lensrt_exr_options *options)
{
    int reproducible;
    lensrt_result res;
    if (!r) return LENSRT_ERROR_INVALID_ARGUMENT;
    // Read the options by their struct_size (ABI rules), then check the flag
    if ((res = exr_options_in(r->ctx, path, options, &reproducible)) != LENSRT_SUCCESS) return res;
    return write_image_as(&r, 1, path, 1, 0.0, reproducible);
}

lensrt_result lensrt_render_write_png(lensrt_render r, const char *path, double decades)
{
    return write_image(&r, 1, path, 0, decades);
}

lensrt_result lensrt_renders_write_exr(const lensrt_render *renders, int n_renders, const char *path)
{
    return write_image(renders, n_renders, path, 1, 0.0);
}

lensrt_result lensrt_renders_write_png(const lensrt_render *renders, int n_renders, const char *path, double decades)
{
    return write_image(renders, n_renders, path, 0, decades);
}

/* ------------------------------------------------------------- layered EXR ----- */

/* "direct: lens0001.table; flare: ghost_0_2.table + ghost_4_8.table; unprefixed: their
 * sum", for the EXR attribute "lensrt/layers" (lens files, or lens names for lenses
 * without one). NULL when out of memory. */
static char *layers_text(lensrt_context ctx, const lensrt_exr_layer *ls, int n)
{
    size_t size = 64, used = 0;
    char *text;
    int i, k;
    // Room: every name and file, with their separators
    for (i = 0; i < n; i++) {
        size += strlen(ls[i].name) + 8;
        for (k = 0; k < ls[i].n_renders; k++) {
            const char *file = ls[i].renders[k]->lens_ops->table_file(ls[i].renders[k]->lens);
            size += strlen(file ? file : ls[i].renders[k]->lens->name) + 4;
        }
    }
    if (!(text = lensrt_alloc(ctx, size))) return NULL;
    for (i = 0; i < n; i++) {
        used += (size_t)snprintf(text + used, size - used, "%s%s: ", i ? "; " : "", ls[i].name);
        for (k = 0; k < ls[i].n_renders; k++) {
            const char *file = ls[i].renders[k]->lens_ops->table_file(ls[i].renders[k]->lens);
            used += (size_t)snprintf(text + used, size - used, "%s%s", k ? " + " : "",
                                     file ? file : ls[i].renders[k]->lens->name);
        }
    }
    snprintf(text + used, size - used, "; unprefixed: %s", n > 1 ? "their sum" : "the same");
    return text;
}

/* Read (ABI rules) and check the layers: names valid and unique, renders non-NULL, no
 * render in two places, one window and one set of wavelengths. `ls` gets the layers,
 * `all` every render in layer order. */
static lensrt_result check_layers(lensrt_context ctx, const lensrt_exr_layer *layers, int n, const char *path,
                                  lensrt_exr_layer *ls, lensrt_render *all, int *n_all)
{
    lensrt_result res;
    int i, j, k;
    *n_all = 0;
    if ((res = lensrt_array_in(ctx, "EXR layers", layers, (size_t)n, ls, sizeof *ls)) != LENSRT_SUCCESS) return res;
    for (i = 0; i < n; i++) {
        const char *refusal = lensrt_exr_layer_name_refusal(ls[i].name);
        if (refusal)
            return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "EXR '%s': layer %d: name '%.80s' %s", path, i,
                               ls[i].name ? ls[i].name : "", refusal);
        for (j = 0; j < i; j++)
            if (strcmp(ls[i].name, ls[j].name) == 0)
                return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                                   "EXR '%s': layers %d and %d are both named '%s'; names must be unique", path, j, i,
                                   ls[i].name);
        if (!ls[i].renders || ls[i].n_renders < 1)
            return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "EXR '%s': layer '%s' has %s, expected 1 or more renders",
                               path, ls[i].name, ls[i].renders ? "no render" : "a NULL render list");
        for (k = 0; k < ls[i].n_renders; k++) {
            lensrt_render r = ls[i].renders[k];
            if (!r)
                return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "EXR '%s': layer '%s': render %d is NULL", path,
                                   ls[i].name, k);
            // The unprefixed sum would count a render twice
            for (j = 0; j < *n_all; j++)
                if (all[j] == r)
                    return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                                       "EXR '%s': layer '%s': render %d (%s) is already in this or an earlier layer; "
                                       "the sum of the layers would count it twice", path, ls[i].name, k, r->lens->file);
            all[(*n_all)++] = r;
        }
    }
    if (!path) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "EXR: the path is NULL");
    if ((res = check_same_frame(all, *n_all)) != LENSRT_SUCCESS) {
        char why[LENSRT_ERROR_SIZE];
        snprintf(why, sizeof why, "%s", lensrt_context_last_error(ctx));
        return lensrt_fail(ctx, res, "EXR '%s': layers in one file: %s", path, why);
    }
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_layers_write_exr(const lensrt_exr_layer *layers, int n_layers, const char *path)
{
    return lensrt_layers_write_exr_with(layers, n_layers, path, NULL);
}

lensrt_result lensrt_layers_write_exr_with(const lensrt_exr_layer *layers, int n_layers, const char *path,
                                           const lensrt_exr_options *options)
{
    lensrt_exr_layer *ls = NULL;
    lensrt_render *all = NULL, r0;
    lensrt_exr_image *images = NULL;
    float **planes = NULL; /* image i's spectral planes at 2 i, its RGB at 2 i + 1 */
    lensrt_context ctx;
    lensrt_image_meta meta;
    lensrt_result res = LENSRT_SUCCESS;
    char err[LENSRT_ERROR_SIZE] = "", aperture[128], runs[RUNS_TEXT_SIZE], *text = NULL, *renders = NULL;
    size_t size, n_total = 0;
    int i, n_all = 0, reproducible = 0;

    // Step 1: a context for messages, the first layer's first render's (a caller's struct
    // too small to hold our fields, e.g. zeroed without its INIT macro, has none to read)
    if (!layers || n_layers < 1) return LENSRT_ERROR_INVALID_ARGUMENT;
    memcpy(&size, layers, sizeof size);
    if (size < sizeof(lensrt_exr_layer) || !layers[0].renders || layers[0].n_renders < 1 || !layers[0].renders[0])
        return LENSRT_ERROR_INVALID_ARGUMENT;
    r0 = layers[0].renders[0];
    ctx = r0->ctx;
    if (n_layers > LENSRT_MAX_LAYERS)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "EXR '%s': %d layers, at most %d",
                           path ? path : "(null)", n_layers, LENSRT_MAX_LAYERS);
    if ((res = exr_options_in(ctx, path, options, &reproducible)) != LENSRT_SUCCESS) return res;

    // Step 2: the layers, read and checked; every render of every layer, in order
    for (i = 0; i < n_layers; i++) {
        const lensrt_exr_layer *l = (const lensrt_exr_layer *)(const void *)((const unsigned char *)layers + (size_t)i * size);
        if (l->struct_size == size && l->n_renders > 0) n_total += (size_t)l->n_renders;
    }
    ls = lensrt_calloc(ctx, (size_t)n_layers, sizeof *ls);
    all = lensrt_calloc(ctx, n_total + 1, sizeof *all);
    images = lensrt_calloc(ctx, (size_t)n_layers + 1, sizeof *images);
    planes = lensrt_calloc(ctx, 2 * ((size_t)n_layers + 1), sizeof *planes);
    if (!ls || !all || !images || !planes) {
        res = lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "EXR '%s': out of memory", path ? path : "(null)");
        goto done;
    }
    if ((res = check_layers(ctx, layers, n_layers, path, ls, all, &n_all)) != LENSRT_SUCCESS) goto done;

    // Step 3: the images: unprefixed, the sum of every render (lensrt_renders_write_exr
    // of all of them); then each layer's own sum
    res = spectral_and_rgb_of(all, n_all, &planes[0], &planes[1]);
    for (i = 0; i < n_layers && res == LENSRT_SUCCESS; i++) {
        images[1 + i].name = ls[i].name;
        res = spectral_and_rgb_of(ls[i].renders, ls[i].n_renders, &planes[2 + 2 * i], &planes[3 + 2 * i]);
    }
    if (res != LENSRT_SUCCESS) goto done;
    for (i = 0; i <= n_layers; i++) {
        images[i].spectral = planes[2 * i];
        images[i].rgb = planes[2 * i + 1];
    }

    // Step 4: the file, with the first render's metadata and what each layer holds
    image_meta(r0, &meta, aperture, runs);
    if (!(text = layers_text(ctx, ls, n_layers)) || (n_all > 1 && !(renders = renders_text(ctx, all, n_all)))) {
        res = lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "EXR '%s': out of memory", path);
        goto done;
    }
    meta.layers = text;
    meta.renders = renders;
    meta.reproducible = reproducible;
    res = lensrt_write_exr_layers(&ctx->allocator, path, r0->out_width, r0->out_height, r0->n_wl, r0->wavelengths,
                                  n_layers + 1, images, &meta, err, sizeof err);
    if (res != LENSRT_SUCCESS && err[0]) lensrt_fail(ctx, res, "%s", err);
done:
    for (i = 0; planes && i < 2 * (n_layers + 1); i++) lensrt_free(ctx, planes[i]);
    lensrt_free(ctx, planes);
    lensrt_free(ctx, images);
    lensrt_free(ctx, text);
    lensrt_free(ctx, renders);
    lensrt_free(ctx, all);
    lensrt_free(ctx, ls);
    return res;
}
