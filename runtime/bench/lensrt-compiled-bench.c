/* lensrt-compiled-bench: do the compiled evaluators (lensrt_add_lens) speed up lensrt's
 * per-sample and per-pixel set-up? Built on request:
 *
 *   cmake --build B --target lensrt-compiled-bench && B/runtime/lensrt-compiled-bench
 *
 * One thread throughout (the context's OpenMP threads set to 1), the default lens 0001
 * compiled in with the build's flags (-O3 in Release, -march=native with LENSRT_NATIVE),
 * the scene of lensrt-bench: a light at (-6, -4) deg at infinity, 16 wavelengths, f/8.
 *
 *   Horner     the generated code of the full systems (6 inputs): lens0001_P_o_d and
 *              _P_s_d (and _f) per call, over random rays inside the fitted domain.
 *   per sample lensrt's own: it folds P_o to each light and wavelength once per render
 *              (a polynomial in the stop point only) and evaluates that per sample. A
 *              1 x 1 pixel render of many samples: wall time of a second run() (every
 *              fold made) over its samples.
 *   per pixel  lensrt folds P_s to each pixel and wavelength per pass (stop-monomial
 *              coefficients, then pruning and the window basis). Second runs of 64 and
 *              of 128 samples on 128 x 128 pixels: 2 t(64) - t(128) removes the splats.
 *              Horner gives values, not coefficients: replacing the fold would take at
 *              least one call per stop monomial (66 for stop degree 10) and a solve.
 *   eval       lensrt_lens_eval per ray (values, double, batches of 1, 8, 256) of the table
 *              lens (blocked sums over the terms) and of the compiled lens (Horner).
 * Prints each figure and the ratios. The machine is shared: ratios, not absolute times,
 * are the figures to quote. */
#include "lensrt.h"
#include "lensrt_lens_0001.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define RAYS 4096
#define N_WL 16

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static uint64_t splitmix64(uint64_t *state)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

static int fail(lensrt_context ctx, const char *what)
{
    fprintf(stderr, "lensrt-compiled-bench: %s: %s\n", what, lensrt_context_last_error(ctx));
    return 1;
}

/* Seconds per Horner call of one system over RAYS random in-domain rays, best of 5
 * sweeps (a sink keeps the calls). */
static double horner_seconds(lensrt_lens lens, int system, int is_float, double *sink)
{
    static double in_d[RAYS * 6];
    static float in_f[RAYS * 6];
    lensrt_system_info info = LENSRT_SYSTEM_INFO_INIT;
    uint64_t rng = 99;
    double best = 1e300;
    int k, i, rep;
    lensrt_lens_system_info(lens, system, &info);
    for (k = 0; k < RAYS; k++)
        for (i = 0; i < 6; i++) {
            double u = (double)(splitmix64(&rng) >> 11) * (1.0 / 9007199254740992.0);
            in_d[k * 6 + i] = info.input_min[i] + (info.input_max[i] - info.input_min[i]) * u;
            in_f[k * 6 + i] = (float)in_d[k * 6 + i];
        }
    for (rep = 0; rep < 5; rep++) {
        double t0 = now_seconds(), t;
        for (k = 0; k < RAYS; k++) {
            if (is_float) {
                float out[4];
                (system ? lensrt_lens_0001.sensor_f : lensrt_lens_0001.object_f)(in_f + k * 6, out);
                *sink += out[3];
            } else {
                double out[4];
                (system ? lensrt_lens_0001.sensor_d : lensrt_lens_0001.object_d)(in_d + k * 6, out);
                *sink += out[3];
            }
        }
        t = (now_seconds() - t0) / RAYS;
        if (t < best) best = t;
    }
    return best;
}

/* Seconds per ray of lensrt_lens_eval (values, double) in batches of `batch` rays, best
 * of 5 sweeps over the same RAYS random in-domain rays. */
static double eval_seconds(lensrt_context ctx, lensrt_lens lens, int system, int batch, double *sink)
{
    static double in[RAYS * 6], out[RAYS * 4];
    lensrt_system_info info = LENSRT_SYSTEM_INFO_INIT;
    lensrt_eval_desc d = LENSRT_EVAL_DESC_INIT;
    uint64_t rng = 99;
    double best = 1e300;
    int k, i, rep;
    lensrt_lens_system_info(lens, system, &info);
    for (k = 0; k < RAYS; k++)
        for (i = 0; i < 6; i++) {
            double u = (double)(splitmix64(&rng) >> 11) * (1.0 / 9007199254740992.0);
            in[k * 6 + i] = info.input_min[i] + (info.input_max[i] - info.input_min[i]) * u;
        }
    d.system = system;
    d.type = LENSRT_TYPE_DOUBLE;
    d.n_rays = (size_t)batch;
    for (rep = 0; rep < 5; rep++) {
        double t0 = now_seconds(), t;
        for (k = 0; k + batch <= RAYS; k += batch) {
            d.inputs = in + k * 6;
            d.outputs = out + k * 4;
            if (lensrt_lens_eval(ctx, lens, &d) != LENSRT_SUCCESS) return -1.0;
        }
        t = (now_seconds() - t0) / RAYS;
        if (t < best) best = t;
        *sink += out[3];
    }
    return best;
}

/* Wall time of run(samples) on a fresh render of width x width pixels around the light's
 * image point; with `again`, of a second run(samples) after a first one. */
static double render_seconds(lensrt_context ctx, lensrt_lens lens, int width, uint64_t samples, int again)
{
    lensrt_light light = LENSRT_LIGHT_INIT;
    lensrt_render_desc desc = LENSRT_RENDER_DESC_INIT;
    desc.pixel_filter = LENSRT_PIXEL_FILTER_POINT; /* set-up against the Horner code, per pixel centre */
    lensrt_render render = NULL;
    double xy[2], t = -1.0;
    light.field_x_deg = -6.0; /* the demo's light (scenes/demo.toml) */
    light.field_y_deg = -4.0;
    if (lensrt_lens_image_point(ctx, lens, &light, 550.0, 0.0, xy) != LENSRT_SUCCESS) return -1.0;
    desc.lens = lens;
    desc.sensor.width = desc.sensor.height = width;
    desc.sensor.width_mm = 0.1;
    desc.sensor.center_x_mm = xy[0];
    desc.sensor.center_y_mm = xy[1];
    desc.aperture.f_number = 8.0;
    desc.lights = &light;
    desc.n_lights = 1;
    desc.n_wavelengths = N_WL;
    desc.seed = 1;
    if (lensrt_render_create(ctx, &desc, &render) == LENSRT_SUCCESS &&
        (!again || lensrt_render_run(render, samples, NULL, NULL) == LENSRT_SUCCESS)) {
        double t0 = now_seconds();
        if (lensrt_render_run(render, samples, NULL, NULL) == LENSRT_SUCCESS) t = now_seconds() - t0;
    }
    lensrt_render_destroy(render);
    return t;
}

static double min3(double a, double b, double c) { return fmin(a, fmin(b, c)); }

int main(void)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    lensrt_lens lens = NULL;
    double sink = 0.0, po_d, ps_d, po_f, ps_f, t_samples, per_sample, t64, t128, per_pixel;
    const uint64_t n_samples = 65536;
    const int slots = 66; /* stop monomials of degree <= 10 */
    init.threads = 1;
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) return 1;
    if (lensrt_lens_load_compiled(ctx, &lensrt_lens_0001, &lens) != LENSRT_SUCCESS) return fail(ctx, "load");

    // The generated Horner code of the full systems, per call
    po_d = horner_seconds(lens, LENSRT_SYSTEM_OBJECT, 0, &sink);
    ps_d = horner_seconds(lens, LENSRT_SYSTEM_SENSOR, 0, &sink);
    po_f = horner_seconds(lens, LENSRT_SYSTEM_OBJECT, 1, &sink);
    ps_f = horner_seconds(lens, LENSRT_SYSTEM_SENSOR, 1, &sink);
    printf("Horner per call (4 outputs): P_o double %.2f us, float %.2f us; P_s double %.2f us, float %.2f us\n",
           1e6 * po_d, 1e6 * po_f, 1e6 * ps_d, 1e6 * ps_f);

    // lensrt_lens_eval of the same lens from its table (the blocked sums) and compiled in
    {
        lensrt_lens table = NULL;
        static const int batches[3] = {1, 8, 256};
        double e_o, e_s, c_o, c_s;
        int b;
        if (lensrt_lens_load_text(ctx, lensrt_lens_0001.table_text, lensrt_lens_0001.table_size, "lens0001.table",
                                  &table) != LENSRT_SUCCESS)
            return fail(ctx, "load the table");
        for (b = 0; b < 3; b++) {
            e_o = eval_seconds(ctx, table, LENSRT_SYSTEM_OBJECT, batches[b], &sink);
            e_s = eval_seconds(ctx, table, LENSRT_SYSTEM_SENSOR, batches[b], &sink);
            c_o = eval_seconds(ctx, lens, LENSRT_SYSTEM_OBJECT, batches[b], &sink);
            c_s = eval_seconds(ctx, lens, LENSRT_SYSTEM_SENSOR, batches[b], &sink);
            printf("lensrt_lens_eval per ray (double values, batches of %d): table P_o %.2f us, P_s %.2f us; "
                   "compiled (Horner) P_o %.2f us, P_s %.2f us\n", batches[b], 1e6 * e_o, 1e6 * e_s, 1e6 * c_o,
                   1e6 * c_s);
        }
        lensrt_lens_destroy(ctx, table);
    }

    // lensrt per sample: 1 x 1 pixel, the second run of n_samples per wavelength, best of 3
    t_samples = min3(render_seconds(ctx, lens, 1, n_samples, 1), render_seconds(ctx, lens, 1, n_samples, 1),
                     render_seconds(ctx, lens, 1, n_samples, 1));
    if (t_samples < 0) return fail(ctx, "render (samples)");
    per_sample = t_samples / ((double)n_samples * N_WL);
    printf("lensrt per sample (1 light, folded P_o, 1 x 1 pixel): %.3f us = Horner P_o / %.1f\n", 1e6 * per_sample,
           po_d / per_sample);

    // lensrt per pixel and wavelength: 128 x 128 pixels, second runs (the per-render folds
    // made), 2 t(64) - t(128) to remove the splats, best of 3 each
    t64 = min3(render_seconds(ctx, lens, 128, 64, 1), render_seconds(ctx, lens, 128, 64, 1),
               render_seconds(ctx, lens, 128, 64, 1));
    t128 = min3(render_seconds(ctx, lens, 128, 128, 1), render_seconds(ctx, lens, 128, 128, 1),
                render_seconds(ctx, lens, 128, 128, 1));
    if (t64 < 0 || t128 < 0) return fail(ctx, "render (pixels)");
    per_pixel = (2.0 * t64 - t128) / (128.0 * 128.0 * N_WL);
    printf("lensrt per pixel and wavelength (P_s folded to stop coefficients, pruned, basis): %.3f us; "
           "%d Horner P_s calls (one per stop monomial, before any solve) %.1f us = %.0fx\n", 1e6 * per_pixel, slots,
           1e6 * slots * ps_d, slots * ps_d / per_pixel);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    return sink == 12345.678 ? 2 : 0; /* keeps the sink alive */
}
