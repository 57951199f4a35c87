/* test_abi: the ABI rules of lensrt.h, as a caller built against another header sees them.
 *
 * An "older" caller is simulated by the prefix of a struct (what an earlier header's
 * struct would be: the same fields, fewer of them) inside a buffer filled with a
 * sentinel: the library must write nothing past the caller's struct_size, and must read
 * nothing past it either (garbage there changes nothing). A "newer" caller is a struct
 * with extra bytes after ours: zero means defaults and is accepted, anything else is
 * refused. Every *_INIT macro must equal a zeroed struct with its size set. */
#include "lensrt.h"

#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "check.h"

#define SENTINEL 0xA5
#define SLACK 64 /* bytes of sentinel after the largest struct */

/* A buffer for one struct and the sentinel bytes behind it. */
typedef union buffer {
    unsigned char bytes[512 + SLACK];
    size_t size;        /* the struct_size field, first in every versioned struct */
    long double align;  /* aligned for any member */
} buffer;

/* The first byte at or after `from` that is not the sentinel, or -1. */
static long first_written(const buffer *b, size_t from, size_t to)
{
    size_t i;
    for (i = from; i < to; i++)
        if (b->bytes[i] != SENTINEL) return (long)i;
    return -1;
}

/* ------------------------------------------------------------- the macros ----- */

#define EXPECT_INIT(type, INIT)                                                        \
    do {                                                                               \
        static const type from_macro = INIT;                                           \
        static type zeroed; /* static: padding bytes are zero in both */               \
        zeroed.struct_size = sizeof(type);                                             \
        CHECK(memcmp(&from_macro, &zeroed, sizeof(type)) == 0, "%s differs from a zeroed " #type \
              " with struct_size set", #INIT);                                         \
    } while (0)

static void test_init_macros(void)
{
    EXPECT_INIT(lensrt_context_init, LENSRT_CONTEXT_INIT);
    EXPECT_INIT(lensrt_gl_info, LENSRT_GL_INFO_INIT);
    EXPECT_INIT(lensrt_analytic_lens, LENSRT_ANALYTIC_LENS_INIT);
    EXPECT_INIT(lensrt_lens_info, LENSRT_LENS_INFO_INIT);
    EXPECT_INIT(lensrt_light, LENSRT_LIGHT_INIT);
    EXPECT_INIT(lensrt_render_desc, LENSRT_RENDER_DESC_INIT);
    EXPECT_INIT(lensrt_render_stats, LENSRT_RENDER_STATS_INIT);
    EXPECT_INIT(lensrt_system_info, LENSRT_SYSTEM_INFO_INIT);
    EXPECT_INIT(lensrt_eval_desc, LENSRT_EVAL_DESC_INIT);
    EXPECT_INIT(lensrt_exr_layer, LENSRT_EXR_LAYER_INIT);
    EXPECT_INIT(lensrt_exr_options, LENSRT_EXR_OPTIONS_INIT);
    EXPECT_INIT(lensrt_bank_info, LENSRT_BANK_INFO_INIT);
    EXPECT_INIT(lensrt_bank_query, LENSRT_BANK_QUERY_INIT);
    EXPECT_INIT(lensrt_image_desc, LENSRT_IMAGE_DESC_INIT);
    EXPECT_INIT(lensrt_image_stats, LENSRT_IMAGE_STATS_INIT);
    EXPECT_INIT(lensrt_image_source, LENSRT_IMAGE_SOURCE_INIT);
}

static void test_version(void)
{
    char expect[64];
    snprintf(expect, sizeof expect, "%d.%d.%d", LENSRT_VERSION_MAJOR, LENSRT_VERSION_MINOR, LENSRT_VERSION_PATCH);
    CHECK(lensrt_version() == LENSRT_VERSION, "lensrt_version() %u, header %u", (unsigned)lensrt_version(),
          (unsigned)LENSRT_VERSION);
    CHECK(strcmp(lensrt_version_string(), expect) == 0, "version string %s, header %s", lensrt_version_string(),
          expect);
    CHECK(sizeof(lensrt_result) == 4, "lensrt_result is %zu bytes", sizeof(lensrt_result));
}

/* ---------------------------------------------------- what the library writes ----- */

/* A free-space analytic lens and a tiny render of it (one row, one wavelength). */
static lensrt_lens make_lens(lensrt_context ctx)
{
    lensrt_analytic_lens m = LENSRT_ANALYTIC_LENS_INIT;
    lensrt_lens lens = NULL;
    m.focal_length_mm = 50.0;
    m.sensor_distance_mm = 50.0;
    CHECK(lensrt_lens_create_analytic(ctx, &m, &lens) == LENSRT_SUCCESS, "analytic lens: %s",
          lensrt_context_last_error(ctx));
    return lens;
}

static const double WAVELENGTH = 550.0;

static void fill_desc(lensrt_render_desc *d, lensrt_lens lens)
{
    static const lensrt_render_desc init = LENSRT_RENDER_DESC_INIT;
    *d = init;
    d->lens = lens;
    d->aperture.f_number = 8.0;
    d->sensor.width = 8;
    d->sensor.height = 8;
    d->sensor.width_mm = 0.02;
    d->wavelengths_nm = &WAVELENGTH;
    d->n_wavelengths = 1;
    d->seed = 7;
}

static void test_outputs_stop_at_struct_size(lensrt_context ctx, lensrt_lens lens)
{
    buffer b;
    lensrt_render_desc d;
    lensrt_render render = NULL;
    // An older lensrt_lens_info: up to and including f_number_min
    size_t old_info = offsetof(lensrt_lens_info, f_number_min) + sizeof(double);
    size_t old_stats = offsetof(lensrt_render_stats, samples_per_wavelength) + sizeof(uint64_t);
    long at;

    memset(&b, SENTINEL, sizeof b);
    b.size = old_info;
    CHECK(lensrt_lens_get_info(lens, (lensrt_lens_info *)(void *)b.bytes) == LENSRT_SUCCESS, "get_info (older)");
    at = first_written(&b, old_info, sizeof b.bytes);
    CHECK(at < 0, "lensrt_lens_get_info wrote byte %ld past the caller's struct_size %zu", at, old_info);
    CHECK(((lensrt_lens_info *)(void *)b.bytes)->analytic == 1 && b.size == old_info,
          "older lens info: analytic %d, struct_size %zu", ((lensrt_lens_info *)(void *)b.bytes)->analytic, b.size);

    // lensrt_lens_info before the ghost fields (0.2.0): nothing written past psf_vs_exact_cell
    old_info = offsetof(lensrt_lens_info, ghost);
    memset(&b, SENTINEL, sizeof b);
    b.size = old_info;
    CHECK(lensrt_lens_get_info(lens, (lensrt_lens_info *)(void *)b.bytes) == LENSRT_SUCCESS, "get_info (no ghost fields)");
    at = first_written(&b, old_info, sizeof b.bytes);
    CHECK(at < 0, "lensrt_lens_get_info wrote byte %ld past the caller's struct_size %zu (before the ghost fields)", at,
          old_info);

    fill_desc(&d, lens);
    CHECK(lensrt_render_create(ctx, &d, &render) == LENSRT_SUCCESS, "render: %s", lensrt_context_last_error(ctx));
    if (!render) return;
    CHECK(lensrt_render_run(render, 256, NULL, NULL) == LENSRT_SUCCESS, "run: %s", lensrt_context_last_error(ctx));
    memset(&b, SENTINEL, sizeof b);
    b.size = old_stats;
    CHECK(lensrt_render_get_stats(render, (lensrt_render_stats *)(void *)b.bytes) == LENSRT_SUCCESS, "get_stats (older)");
    at = first_written(&b, old_stats, sizeof b.bytes);
    CHECK(at < 0, "lensrt_render_get_stats wrote byte %ld past the caller's struct_size %zu", at, old_stats);
    CHECK(((lensrt_render_stats *)(void *)b.bytes)->samples_per_wavelength == 256 &&
              ((lensrt_render_stats *)(void *)b.bytes)->width == 8,
          "older stats: %llu samples, width %d",
          (unsigned long long)((lensrt_render_stats *)(void *)b.bytes)->samples_per_wavelength,
          ((lensrt_render_stats *)(void *)b.bytes)->width);
    // A newer caller's stats: the bytes past ours are zeroed (their defaults)
    memset(&b, SENTINEL, sizeof b);
    b.size = sizeof(lensrt_render_stats) + 16;
    CHECK(lensrt_render_get_stats(render, (lensrt_render_stats *)(void *)b.bytes) == LENSRT_SUCCESS, "get_stats (newer)");
    at = first_written(&b, sizeof(lensrt_render_stats) + 16, sizeof b.bytes);
    CHECK(at < 0, "stats of a newer caller: byte %ld past its struct_size written", at);
    CHECK(b.bytes[sizeof(lensrt_render_stats)] == 0 && b.bytes[sizeof(lensrt_render_stats) + 15] == 0,
          "stats of a newer caller: its extra fields not zeroed");
    // struct_size 0: refused, nothing written
    memset(&b, SENTINEL, sizeof b);
    b.size = 0;
    CHECK(lensrt_render_get_stats(render, (lensrt_render_stats *)(void *)b.bytes) == LENSRT_ERROR_INVALID_ARGUMENT,
          "stats with struct_size 0 accepted");
    CHECK(first_written(&b, sizeof(size_t), sizeof b.bytes) < 0, "stats with struct_size 0: bytes written");
    CHECK(strstr(lensrt_context_last_error(ctx), "LENSRT_*_INIT") != NULL, "message: %s",
          lensrt_context_last_error(ctx));
    lensrt_render_destroy(render);
}

/* ----------------------------------------------------- what the library reads ----- */

/* The image of a render made from `desc` (n floats). */
static int image_of(lensrt_context ctx, const void *desc, float *img, size_t n)
{
    lensrt_render render = NULL;
    lensrt_result res = lensrt_render_create(ctx, (const lensrt_render_desc *)desc, &render);
    if (res != LENSRT_SUCCESS) return (int)res;
    res = lensrt_render_run(render, 1024, NULL, NULL);
    if (res == LENSRT_SUCCESS) res = lensrt_render_image(render, img, n);
    lensrt_render_destroy(render);
    return (int)res;
}

static void test_inputs_stop_at_struct_size(lensrt_context ctx, lensrt_lens lens)
{
    enum { N = 64 };
    float ref[N], img[N];
    buffer b;
    lensrt_render_desc d;
    size_t old_desc = offsetof(lensrt_render_desc, seed); /* no seed, tolerance or device */
    lensrt_light lights[2];
    struct newer_light { lensrt_light light; double extra; } newer[1];
    int res;

    // The reference: seed 0 (the default an older caller gets), default tolerance
    fill_desc(&d, lens);
    d.seed = 0;
    CHECK(image_of(ctx, &d, ref, N) == LENSRT_SUCCESS, "reference render: %s", lensrt_context_last_error(ctx));
    // An older caller's desc with garbage behind it: the garbage must not be read
    fill_desc(&d, lens);
    memset(&b, 0xFF, sizeof b);
    memcpy(b.bytes, &d, old_desc);
    b.size = old_desc;
    res = image_of(ctx, b.bytes, img, N);
    CHECK(res == LENSRT_SUCCESS, "older desc: %s", lensrt_context_last_error(ctx));
    CHECK(res != LENSRT_SUCCESS || memcmp(ref, img, sizeof ref) == 0,
          "an older caller's desc read the bytes past its struct_size");
    // A newer caller's desc: zero extra bytes are its defaults; anything else is refused
    memset(&b, 0, sizeof b);
    fill_desc(&d, lens);
    d.seed = 0;
    memcpy(b.bytes, &d, sizeof d);
    b.size = sizeof d + 32;
    res = image_of(ctx, b.bytes, img, N);
    CHECK(res == LENSRT_SUCCESS && memcmp(ref, img, sizeof ref) == 0, "newer desc with zero extra fields: %s",
          lensrt_context_last_error(ctx));
    b.bytes[sizeof d + 8] = 1;
    res = image_of(ctx, b.bytes, img, N);
    CHECK(res == LENSRT_ERROR_UNSUPPORTED && strstr(lensrt_context_last_error(ctx), "lensrt_render_desc"),
          "newer desc with a set extra field: %d, %s", res, lensrt_context_last_error(ctx));
    // struct_size 0 (zeroed without the macro): refused with a message saying what to do
    fill_desc(&d, lens);
    d.struct_size = 0;
    CHECK(image_of(ctx, &d, img, N) == LENSRT_ERROR_INVALID_ARGUMENT &&
              strstr(lensrt_context_last_error(ctx), "LENSRT_*_INIT"),
          "desc with struct_size 0: %s", lensrt_context_last_error(ctx));
    // Lights: the stride is the first element's struct_size (a newer caller's lights)
    fill_desc(&d, lens);
    d.seed = 0;
    {
        const lensrt_light init = LENSRT_LIGHT_INIT;
        lights[0] = lights[1] = init;
    }
    lights[0].field_x_deg = -0.002;
    d.lights = lights;
    d.n_lights = 1;
    CHECK(image_of(ctx, &d, ref, N) == LENSRT_SUCCESS, "one light: %s", lensrt_context_last_error(ctx));
    memset(newer, 0, sizeof newer);
    newer[0].light = lights[0];
    newer[0].light.struct_size = sizeof newer[0];
    d.lights = &newer[0].light;
    CHECK(image_of(ctx, &d, img, N) == LENSRT_SUCCESS && memcmp(ref, img, sizeof ref) == 0,
          "a newer caller's light: %s", lensrt_context_last_error(ctx));
    // Elements of different sizes in one array: refused, naming the element
    lights[1].struct_size = sizeof(lensrt_light) - sizeof(double);
    d.lights = lights;
    d.n_lights = 2;
    CHECK(image_of(ctx, &d, img, N) == LENSRT_ERROR_INVALID_ARGUMENT &&
              strstr(lensrt_context_last_error(ctx), "lights[1]"),
          "lights of two sizes: %s", lensrt_context_last_error(ctx));
    // The context init: struct_size 0 refused, an older one accepted
    {
        lensrt_context_init init = LENSRT_CONTEXT_INIT;
        lensrt_context other = NULL;
        init.struct_size = 0;
        CHECK(lensrt_context_create(&init, &other) == LENSRT_ERROR_INVALID_ARGUMENT && other == NULL,
              "context init with struct_size 0 accepted");
        init.struct_size = offsetof(lensrt_context_init, threads); /* no threads, no GL platform */
        CHECK(lensrt_context_create(&init, &other) == LENSRT_SUCCESS && other != NULL, "older context init refused");
        lensrt_context_destroy(other);
    }
}

int main(void)
{
    lensrt_context ctx = NULL;
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_lens lens;
    init.threads = 1;
    test_init_macros();
    test_version();
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) {
        fprintf(stderr, "test_abi: cannot make a context\n");
        return 1;
    }
    lens = make_lens(ctx);
    if (lens) {
        test_outputs_stop_at_struct_size(ctx, lens);
        test_inputs_stop_at_struct_size(ctx, lens);
    }
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    printf("test_abi: %d checks, %d failed\n", g_checks, g_failures);
    return g_failures ? 1 : 0;
}
