/* The small render the phasor fuzzer loads into and the seed writer saves from:
 * an analytic thin lens (focal 50 mm, sensor 50 mm), 8x8 pixels, one wavelength. */
#ifndef LENSRT_FUZZ_COMMON_H
#define LENSRT_FUZZ_COMMON_H
#include "lensrt.h"

static lensrt_result fuzz_make_render(lensrt_context *ctx, lensrt_lens *lens, lensrt_render *render)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_analytic_lens analytic = LENSRT_ANALYTIC_LENS_INIT;
    lensrt_render_desc desc = LENSRT_RENDER_DESC_INIT;
    static const double wavelength_nm = 550.0;
    lensrt_result r;
    *ctx = NULL; *lens = NULL; *render = NULL;
    /* One thread, no log */
    init.threads = 1;
    r = lensrt_context_create(&init, ctx);
    if (r != LENSRT_SUCCESS) return r;
    analytic.focal_length_mm = 50.0;
    analytic.sensor_distance_mm = 50.0;
    r = lensrt_lens_create_analytic(*ctx, &analytic, lens);
    if (r != LENSRT_SUCCESS) return r;
    desc.lens = *lens;
    desc.sensor.width = 8;
    desc.sensor.height = 8;
    desc.sensor.width_mm = 0.05;
    desc.aperture.radius_mm = 1.0;
    desc.wavelengths_nm = &wavelength_nm;
    desc.n_wavelengths = 1;
    return lensrt_render_create(*ctx, &desc, render);
}

static void fuzz_free_render(lensrt_context ctx, lensrt_lens lens, lensrt_render render)
{
    if (render) lensrt_render_destroy(render);
    if (lens) lensrt_lens_destroy(ctx, lens);
    if (ctx) lensrt_context_destroy(ctx);
}
#endif
