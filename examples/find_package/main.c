/*
 * The smallest lensrt program: the PSF of a perfect lens (f = 50 mm at f/8, focused at
 * infinity) along one row of 32 pixels through the image point, 1024 aperture samples at
 * 550 nm. Prints the peak and exits non-zero unless it is finite and positive.
 *
 * Built by examples/find_package/CMakeLists.txt (find_package(lensrt)) or by hand:
 *   cc main.c -o lensrt-example $(pkg-config --cflags --libs lensrt)
 */
#include <lensrt.h>

#include <math.h>
#include <stdio.h>
#include <string.h>

#define WIDTH 32

static int fail(lensrt_context ctx, const char *what, lensrt_result res)
{
    fprintf(stderr, "lensrt-example: %s: %s: %s\n", what, lensrt_result_string(res),
            ctx ? lensrt_context_last_error(ctx) : "");
    return 1;
}

int main(void)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT; /* malloc/free, no log, OpenMP default threads */
    lensrt_context ctx = NULL;
    lensrt_analytic_lens model = LENSRT_ANALYTIC_LENS_INIT;
    lensrt_lens lens = NULL;
    lensrt_render_desc desc = LENSRT_RENDER_DESC_INIT; /* one light on the axis at infinity, circular stop */
    lensrt_render render = NULL;
    const double wavelength_nm = 550.0;
    float image[WIDTH];
    float peak = 0.0f;
    int i, status = 1;
    lensrt_result res;

    // A library of another major version has other structs: refuse it
    if (lensrt_version() / 1000000u != LENSRT_VERSION_MAJOR) {
        fprintf(stderr, "lensrt-example: built for lensrt %d.x, running with %s\n", LENSRT_VERSION_MAJOR,
                lensrt_version_string());
        return 1;
    }
    if ((res = lensrt_context_create(&init, &ctx)) != LENSRT_SUCCESS) return fail(NULL, "context", res);

    model.focal_length_mm = 50.0;
    model.sensor_distance_mm = 50.0; /* in focus for a light at infinity */
    if ((res = lensrt_lens_create_analytic(ctx, &model, &lens)) != LENSRT_SUCCESS) {
        fail(ctx, "lens", res);
        goto done;
    }

    desc.lens = lens;
    desc.aperture.f_number = 8.0;
    desc.sensor.width = WIDTH;
    desc.sensor.height = 1;
    desc.sensor.width_mm = 0.032; /* 1 um pixels; the first dark ring is at 5.4 um */
    desc.wavelengths_nm = &wavelength_nm;
    desc.n_wavelengths = 1;
    desc.seed = 1;
    if ((res = lensrt_render_create(ctx, &desc, &render)) != LENSRT_SUCCESS) {
        fail(ctx, "render", res);
        goto done;
    }
    if ((res = lensrt_render_run(render, 1024, NULL, NULL)) != LENSRT_SUCCESS) {
        fail(ctx, "run", res);
        goto done;
    }
    if ((res = lensrt_render_image(render, image, WIDTH)) != LENSRT_SUCCESS) {
        fail(ctx, "image", res);
        goto done;
    }
    for (i = 0; i < WIDTH; i++)
        if (!(image[i] <= peak)) peak = image[i]; /* NaN becomes the peak and fails below */
    printf("lensrt %s: perfect lens f/8, 550 nm, 1024 samples: peak %g\n", lensrt_version_string(), (double)peak);
    if (isfinite(peak) && peak > 0.0f) {
        status = 0;
    } else {
        fprintf(stderr, "lensrt-example: the peak is not finite and positive\n");
    }
done:
    lensrt_render_destroy(render);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    return status;
}
