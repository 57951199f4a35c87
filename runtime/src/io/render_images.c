/* A render's images: linear sRGB through the CIE 1931 observer, and the EXR (spectral
 * channels, RGB preview, lens and render metadata) and PNG files (io/image_exr.c,
 * io/image_png.c), written atomically. */
#include "../c_numbers.h"
#include "../core/render.h"
#include "../lens/lens.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

static lensrt_result spectral_and_rgb(lensrt_render r, float **spectral, float **rgb)
{
    size_t npix = (size_t)r->width * (size_t)r->height, p;
    lensrt_result res;
    *spectral = lensrt_alloc(r->ctx, sizeof(float) * npix * (size_t)r->n_wl);
    *rgb = lensrt_alloc(r->ctx, sizeof(float) * npix * 3);
    if (!*spectral || !*rgb) return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "image: out of memory");
    if ((res = lensrt_render_image(r, *spectral, npix * (size_t)r->n_wl)) != LENSRT_SUCCESS) return res;
    lensrt_spectrum_to_rgb(r->n_wl, r->wavelengths, *spectral, npix, *rgb);
    // Finite spectra near FLT_MAX can still add up to inf in a colour channel
    for (p = 0; p < 3 * npix; p++)
        if (!isfinite((*rgb)[p]))
            return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "rgb: pixel (%d, %d) channel %d is %g, not a finite float",
                               (int)(p / 3 % (size_t)r->width), (int)(p / 3 / (size_t)r->width), (int)(p % 3),
                               (double)(*rgb)[p]);
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_render_rgb(lensrt_render r, float *out, size_t count)
{
    float *spectral = NULL, *rgb = NULL;
    lensrt_result res;
    if (!r || !out) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (count != (size_t)r->width * (size_t)r->height * 3)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "rgb: count must be %zu, got %zu",
                           (size_t)r->width * (size_t)r->height * 3, count);
    res = spectral_and_rgb(r, &spectral, &rgb);
    if (res == LENSRT_SUCCESS) memcpy(out, rgb, sizeof(float) * count);
    lensrt_free(r->ctx, spectral);
    lensrt_free(r->ctx, rgb);
    return res;
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

static lensrt_result write_image(lensrt_render r, const char *path, int exr, double decades)
{
    float *spectral = NULL, *rgb = NULL;
    lensrt_result res;
    char err[LENSRT_ERROR_SIZE] = "", aperture[128];
    if (!r || !path) return LENSRT_ERROR_INVALID_ARGUMENT;
    res = spectral_and_rgb(r, &spectral, &rgb);
    if (res == LENSRT_SUCCESS && exr) {
        lensrt_image_meta meta;
        memset(&meta, 0, sizeof meta);
        describe_aperture(r, aperture, sizeof aperture);
        meta.lens_name = r->lens->name;
        meta.lens_file = r->lens_ops->table_file(r->lens);
        meta.focal_length_mm = r->lens->focal_length_mm;
        meta.f_number = r->f_number;
        meta.stop_radius_mm = r->stop_radius;
        meta.focus_offset_mm = r->desc.sensor.focus_offset_mm;
        meta.pixel_pitch_x_mm = r->pitch_x;
        meta.pixel_pitch_y_mm = r->pitch_y;
        meta.center_x_mm = r->desc.sensor.center_x_mm;
        meta.center_y_mm = r->desc.sensor.center_y_mm;
        meta.samples_per_wavelength = r->samples;
        meta.seconds = r->seconds;
        meta.splats_per_second = r->seconds > 0 ? (double)r->splats / r->seconds : 0.0;
        meta.sampler = lensrt_sampler_name(r->desc.sampler);
        meta.estimator = r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED ? "unbiased" : "paper";
        meta.aperture = aperture;
        meta.seed = r->desc.seed;
        meta.n_lights = r->n_lights;
        meta.lights = r->lights;
        res = lensrt_write_exr(&r->ctx->allocator, path, r->width, r->height, r->n_wl, r->wavelengths,
                               spectral, rgb, &meta, err, sizeof err);
    } else if (res == LENSRT_SUCCESS) {
        res = lensrt_write_png(&r->ctx->allocator, path, r->width, r->height, rgb, decades, err, sizeof err);
    }
    if (res != LENSRT_SUCCESS && err[0]) lensrt_fail(r->ctx, res, "%s", err);
    lensrt_free(r->ctx, spectral);
    lensrt_free(r->ctx, rgb);
    return res;
}

lensrt_result lensrt_render_write_exr(lensrt_render r, const char *path) { return write_image(r, path, 1, 0.0); }

lensrt_result lensrt_render_write_png(lensrt_render r, const char *path, double decades)
{
    return write_image(r, path, 0, decades);
}
