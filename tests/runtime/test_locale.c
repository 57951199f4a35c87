/*
 * test_locale: lensrt reads and writes numbers the same whatever the host's locale
 * (just over 600 lines: one section per place lensrt reads or writes text).
 *
 * A renderer that calls setlocale(LC_ALL, "") under de_DE.UTF-8 gets a comma as the
 * decimal point: strtod stops at the '.' of "1.5" and "%g" writes "1,5". lensrt's text
 * (lens tables, GLSL constants, EXR metadata, lens names hashed into phasor files, its
 * messages) must not change with it. Every check below compares what lensrt does under
 * the comma locale with what it does under "C", bit for bit:
 *   - the number formatter and parser (c_numbers.h, compiled into this test) against
 *     the C library under "C", and the thread's own locale left as it was;
 *   - the table reader: lens info, fitted domains and the polynomials' values;
 *   - the reader's tokenizer does not disturb a caller's strtok;
 *   - messages, and the trust figures logged on load;
 *   - phasor sums saved under one locale load under the other (analytic lens names
 *     carry a number and go into the scene hash);
 *   - EXR metadata text;
 *   - the GL path's shaders (GLSL constants): the same image under both locales;
 *   - lensrt-psf's number options under LC_ALL=de_DE.UTF-8.
 *
 *   test_locale LENS_TABLE LENSRT_PSF SCRATCH_DIR
 *
 * The comma locale must exist (scripts/setup-system.sh generates it): without it the
 * test is skipped (exit 77), or fails when LENSRT_REQUIRE_LOCALE=1 (CI). A missing GL
 * device skips the GL part, or fails it when LENSRT_REQUIRE_GL=1. LENSRT_TEST_EXR is 1
 * when the build writes EXR.
 */
#include "c_numbers.h"
#include "lensrt.h"

#include <errno.h>
#include <locale.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>

#ifndef LENSRT_TEST_EXR
#error "define LENSRT_TEST_EXR to 1 (EXR support built) or 0"
#endif

#define COMMA_LOCALE "de_DE.UTF-8"
#define SKIP 77 /* ctest's SKIP_RETURN_CODE */

/* ------------------------------------------------------------- harness ----- */

#include "check.h"

static char g_scratch[2048];
static const char *g_table, *g_psf;

/* Switch the whole process (this test is single-threaded) to "C" or the comma locale. */
static void use_c(void) { setlocale(LC_ALL, "C"); }
static void use_comma(void) { setlocale(LC_ALL, COMMA_LOCALE); }

/* Bit-for-bit equality of doubles (0.0 and -0.0 differ, as any NaN from itself does not). */
static int same_bits(const double *a, const double *b, size_t n) { return memcmp(a, b, n * sizeof *a) == 0; }

static lensrt_context new_context(void (*log_fn)(lensrt_log_level, const char *, void *), void *user_data)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    init.log_fn = log_fn;
    init.user_data = user_data;
    init.threads = 2;
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) {
        fprintf(stderr, "test_locale: lensrt_context_create failed\n");
        exit(1);
    }
    return ctx;
}

/* ----------------------------------------------------- number formatting ----- */

/* Values whose shortest round-trip text needs every kind of digit string: a point, an
 * exponent, subnormals, the largest double, negative zero. */
static const double VALUES[] = {1.5, 0.1, -2.0 / 3.0, 1e-300, 4.9406564584124654e-324, 1.7976931348623157e308,
                                -0.0, 123456789.125, 3e-3, 1e22};
#define N_VALUES (sizeof VALUES / sizeof VALUES[0])

static void test_formatter(void)
{
    char c_text[N_VALUES][64], text[64];
    size_t i;
    char *end;
    double v;
    locale_t comma;
    // References: the C library itself under "C"
    use_c();
    for (i = 0; i < N_VALUES; i++) snprintf(c_text[i], sizeof c_text[i], "%.17g", VALUES[i]);
    // Under the comma locale the C library changes, the formatter does not
    use_comma();
    snprintf(text, sizeof text, "%g", 1.5);
    CHECK(strcmp(text, "1,5") == 0, "the comma locale writes 1.5 as '%s', not '1,5': the test would prove nothing",
          text);
    for (i = 0; i < N_VALUES; i++) {
        lensrt_snprintf_c(text, sizeof text, "%.17g", VALUES[i]);
        CHECK(strcmp(text, c_text[i]) == 0, "lensrt_snprintf_c(%%.17g) under %s: '%s', under C: '%s'", COMMA_LOCALE,
              text, c_text[i]);
        // The text reads back to the same double (17 digits round-trip), past the point
        errno = 0;
        v = lensrt_strtod_c(text, &end);
        CHECK(*end == '\0' && same_bits(&v, &VALUES[i], 1), "lensrt_strtod_c('%s') = %.17g (stopped at '%s')", text,
              v, end);
    }
    // The comma is no decimal point for lensrt: "1,5" is 1 followed by ",5"
    v = lensrt_strtod_c("1,5", &end);
    CHECK(v == 1.0 && strcmp(end, ",5") == 0, "lensrt_strtod_c('1,5') = %g, rest '%s'", v, end);
    // errno from strtod survives the locale switch back (overflow: ERANGE)
    errno = 0;
    v = lensrt_strtod_c("1e999", &end);
    CHECK(errno == ERANGE, "lensrt_strtod_c('1e999'): errno %d, expected ERANGE", errno);
    // ... and the process's locale is the comma one still
    snprintf(text, sizeof text, "%g", 2.5);
    CHECK(strcmp(text, "2,5") == 0, "after lensrt_snprintf_c the process writes 2.5 as '%s'", text);
    // A thread's own locale (uselocale) is restored exactly, not replaced by the global one
    use_c();
    comma = newlocale(LC_ALL_MASK, COMMA_LOCALE, (locale_t)0);
    CHECK(comma != (locale_t)0, "newlocale(%s) failed", COMMA_LOCALE);
    if (comma) {
        uselocale(comma);
        lensrt_snprintf_c(text, sizeof text, "%.17g", 1.5);
        CHECK(strcmp(text, "1.5") == 0, "lensrt_snprintf_c under the thread's %s: '%s'", COMMA_LOCALE, text);
        lensrt_strtod_c("1.5", &end);
        CHECK(uselocale((locale_t)0) == comma, "the thread's locale was not restored");
        snprintf(text, sizeof text, "%g", 1.5);
        CHECK(strcmp(text, "1,5") == 0, "after lensrt's calls the thread writes 1.5 as '%s'", text);
        uselocale(LC_GLOBAL_LOCALE);
        freelocale(comma);
    }
}

/* ------------------------------------------------------------ lens table ----- */

/* What a lens loaded from the table says, to compare across locales. */
typedef struct lens_digest {
    lensrt_lens_info info;
    char name[256], cell[256];
    lensrt_system_info systems[2];
    double outputs[2][5 * 4];
    char log[4][1024]; /* the first messages logged while loading */
    int n_log;
} lens_digest;

static void capture_log(lensrt_log_level level, const char *message, void *user_data)
{
    lens_digest *d = user_data;
    (void)level;
    if (d->n_log < 4) snprintf(d->log[d->n_log++], sizeof d->log[0], "%s", message);
}

/* Five rays per system spread over its fitted domain (fractions of each input's range). */
static void domain_rays(const lensrt_system_info *s, double *in)
{
    static const double FRACTIONS[5] = {0.5, 0.1, 0.9, 0.3, 0.7};
    int k, i;
    for (k = 0; k < 5; k++)
        for (i = 0; i < s->n_inputs; i++)
            in[k * s->n_inputs + i] =
                s->input_min[i] + FRACTIONS[(k + i) % 5] * (s->input_max[i] - s->input_min[i]);
}

static void digest_lens(lens_digest *d)
{
    lensrt_context ctx;
    lensrt_lens lens = NULL;
    int s;
    memset(d, 0, sizeof *d);
    ctx = new_context(capture_log, d);
    CHECK_OK(ctx, lensrt_lens_load(ctx, g_table, &lens));
    if (lens) {
        d->info.struct_size = sizeof d->info;
        CHECK_OK(ctx, lensrt_lens_get_info(lens, &d->info));
        snprintf(d->name, sizeof d->name, "%s", d->info.name ? d->info.name : "");
        snprintf(d->cell, sizeof d->cell, "%s", d->info.psf_vs_exact_cell ? d->info.psf_vs_exact_cell : "");
        d->info.name = d->info.psf_vs_exact_cell = NULL; /* pointers differ; the texts are compared */
        for (s = 0; s < 2; s++) {
            lensrt_system_info si = LENSRT_SYSTEM_INFO_INIT;
            lensrt_eval_desc e = LENSRT_EVAL_DESC_INIT;
            double in[5 * LENSRT_MAX_SYSTEM_INPUTS];
            CHECK_OK(ctx, lensrt_lens_system_info(lens, s, &si));
            memset(si.input_names, 0, sizeof si.input_names); /* pointers: not compared */
            memset(si.output_names, 0, sizeof si.output_names);
            d->systems[s] = si;
            if (si.n_inputs < 1 || si.n_inputs > LENSRT_MAX_SYSTEM_INPUTS || si.n_outputs != 4) continue;
            domain_rays(&si, in);
            e.system = s;
            e.type = LENSRT_TYPE_DOUBLE;
            e.n_rays = 5;
            e.inputs = in;
            e.outputs = d->outputs[s];
            CHECK_OK(ctx, lensrt_lens_eval(ctx, lens, &e));
        }
        lensrt_lens_destroy(ctx, lens);
    }
    lensrt_context_destroy(ctx);
}

static void test_table(void)
{
    lens_digest *c = calloc(1, sizeof *c), *comma = calloc(1, sizeof *comma);
    int i;
    if (!c || !comma) {
        CHECK(0, "out of memory");
        free(c);
        free(comma);
        return;
    }
    use_c();
    digest_lens(c);
    use_comma();
    digest_lens(comma);
    use_c();
    // Every number the table gave, bit for bit
    {
        const double cv[] = {c->info.focal_length_mm, c->info.f_number_min, c->info.stop_radius_max_mm,
                             c->info.wavelength_min_nm, c->info.wavelength_max_nm, c->info.focus_offset_min_mm,
                             c->info.focus_offset_max_mm, c->info.field_x, c->info.field_y,
                             c->info.distance_min_mm, c->info.sensor_radius_mm, c->info.psf_vs_exact,
                             c->info.psf_target};
        const double dv[] = {comma->info.focal_length_mm, comma->info.f_number_min, comma->info.stop_radius_max_mm,
                             comma->info.wavelength_min_nm, comma->info.wavelength_max_nm,
                             comma->info.focus_offset_min_mm, comma->info.focus_offset_max_mm, comma->info.field_x,
                             comma->info.field_y, comma->info.distance_min_mm, comma->info.sensor_radius_mm,
                             comma->info.psf_vs_exact, comma->info.psf_target};
        CHECK(same_bits(cv, dv, sizeof cv / sizeof cv[0]) && c->info.analytic == comma->info.analytic,
              "lens info differs under %s: focal length %.17g vs %.17g, psf_vs_exact %.17g vs %.17g", COMMA_LOCALE,
              cv[0], dv[0], cv[11], dv[11]);
    }
    CHECK(c->info.focal_length_mm > 0 && c->info.psf_target > 0, "the lens under C has no focal length or target");
    CHECK(strcmp(c->name, comma->name) == 0 && strcmp(c->cell, comma->cell) == 0, "names differ: '%s'/'%s' vs '%s'/'%s'",
          c->name, c->cell, comma->name, comma->cell);
    for (i = 0; i < 2; i++) {
        const lensrt_system_info *a = &c->systems[i], *b = &comma->systems[i];
        CHECK(a->n_inputs == 6 && a->n_inputs == b->n_inputs && a->n_outputs == b->n_outputs &&
                  same_bits(a->input_min, b->input_min, LENSRT_MAX_SYSTEM_INPUTS) &&
                  same_bits(a->input_max, b->input_max, LENSRT_MAX_SYSTEM_INPUTS) &&
                  memcmp(a->n_terms, b->n_terms, sizeof a->n_terms) == 0,
              "system %d: fitted domain or term counts differ under %s", i, COMMA_LOCALE);
    }
    CHECK(same_bits(c->outputs[0], comma->outputs[0], 5 * 4) && same_bits(c->outputs[1], comma->outputs[1], 5 * 4),
          "polynomial values differ under %s (P_o x_o of ray 0: %.17g vs %.17g)", COMMA_LOCALE, c->outputs[0][0],
          comma->outputs[0][0]);
    // The trust figures logged on load: the same text, with points
    CHECK(c->n_log > 0 && c->n_log == comma->n_log, "%d messages logged under C, %d under %s", c->n_log, comma->n_log,
          COMMA_LOCALE);
    for (i = 0; i < c->n_log && i < comma->n_log; i++)
        CHECK(strcmp(c->log[i], comma->log[i]) == 0, "log message %d under %s: '%s', under C: '%s'", i, COMMA_LOCALE,
              comma->log[i], c->log[i]);
    free(c);
    free(comma);
}

/* The reader splits lines itself: a caller's strtok loop survives a load in its middle. */
static void test_strtok_untouched(void)
{
    char words[] = "alpha beta gamma";
    char *w;
    lensrt_context ctx = new_context(NULL, NULL);
    lensrt_lens lens = NULL;
    w = strtok(words, " ");
    CHECK(w && strcmp(w, "alpha") == 0, "strtok: '%s'", w ? w : "(null)");
    CHECK_OK(ctx, lensrt_lens_load(ctx, g_table, &lens));
    w = strtok(NULL, " ");
    CHECK(w && strcmp(w, "beta") == 0, "the caller's strtok after lensrt_lens_load gave '%s', expected 'beta'",
          w ? w : "(null)");
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
}

/* --------------------------------------------------------------- renders ----- */

typedef struct scene {
    lensrt_lens lens;
    lensrt_light light;
    double f_number, width_mm, focus_mm;
    int device, blades, size;
} scene;

static lensrt_result make_render(lensrt_context ctx, const scene *s, lensrt_render *out)
{
    static const double WAVELENGTHS[2] = {450.5, 650.25};
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    d.lens = s->lens;
    d.sensor.width = d.sensor.height = s->size;
    d.sensor.width_mm = s->width_mm;
    d.sensor.focus_offset_mm = s->focus_mm;
    d.aperture.f_number = s->f_number;
    if (s->blades) {
        d.aperture.shape = LENSRT_APERTURE_BLADES;
        d.aperture.blades = s->blades;
        d.aperture.blade_curvature = 0.3;
        d.aperture.rotation_deg = 12.5;
    }
    d.lights = &s->light;
    d.n_lights = 1;
    d.wavelengths_nm = WAVELENGTHS;
    d.n_wavelengths = 2;
    d.seed = 7;
    d.device = s->device;
    return lensrt_render_create(ctx, &d, out);
}

/* Render s with `samples` per wavelength; the image (2 * size * size floats) or NULL. */
static float *render_image(lensrt_context ctx, const scene *s, uint64_t samples)
{
    lensrt_render r = NULL;
    size_t n = 2 * (size_t)s->size * (size_t)s->size;
    float *img = malloc(n * sizeof *img);
    lensrt_result res = img ? make_render(ctx, s, &r) : LENSRT_ERROR_OUT_OF_MEMORY;
    if (res == LENSRT_SUCCESS) res = lensrt_render_run(r, samples, NULL, NULL);
    if (res == LENSRT_SUCCESS) res = lensrt_render_image(r, img, n);
    CHECK(res == LENSRT_SUCCESS, "render (device %d): %s (%s)", s->device, lensrt_result_string(res),
          lensrt_context_last_error(ctx));
    lensrt_render_destroy(r);
    if (res != LENSRT_SUCCESS) {
        free(img);
        return NULL;
    }
    return img;
}

/* Messages carry numbers with a point under any locale. */
static void test_messages(void)
{
    lensrt_context ctx = new_context(NULL, NULL);
    lensrt_analytic_lens a = LENSRT_ANALYTIC_LENS_INIT;
    lensrt_lens lens = NULL;
    lensrt_lens_info info = LENSRT_LENS_INFO_INIT;
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    lensrt_render r = NULL;
    use_comma();
    // An analytic lens's name holds its sensor distance (and goes into EXR files and the
    // phasor files' scene hash)
    a.focal_length_mm = 50.25;
    a.sensor_distance_mm = 50.5;
    CHECK_OK(ctx, lensrt_lens_create_analytic(ctx, &a, &lens));
    if (lens) {
        CHECK_OK(ctx, lensrt_lens_get_info(lens, &info));
        CHECK(info.name && strstr(info.name, "sensor at 50.5 mm"), "analytic lens name under %s: '%s'", COMMA_LOCALE,
              info.name ? info.name : "(null)");
        d.lens = lens;
        d.sensor.width = d.sensor.height = 4;
        d.sensor.width_mm = 0.01;
        d.phase_tolerance_waves = 0.75;
        CHECK(lensrt_render_create(ctx, &d, &r) == LENSRT_ERROR_INVALID_ARGUMENT, "a tolerance of 0.75 was accepted");
        CHECK(strstr(lensrt_context_last_error(ctx), "0.75") != NULL, "the message under %s: '%s'", COMMA_LOCALE,
              lensrt_context_last_error(ctx));
        lensrt_render_destroy(r);
    }
    use_c();
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
}

/* Phasor sums saved under one locale load under the other, and give the same image. */
static void test_phasors(void)
{
    lensrt_context ctx = new_context(NULL, NULL);
    lensrt_analytic_lens a = LENSRT_ANALYTIC_LENS_INIT;
    lensrt_light light = LENSRT_LIGHT_INIT;
    scene s;
    lensrt_render saved = NULL, loaded = NULL;
    float img_saved[2 * 16 * 16], img_loaded[2 * 16 * 16];
    char path[2300];
    int pass;
    memset(&s, 0, sizeof s);
    a.focal_length_mm = 50.25;
    a.sensor_distance_mm = 50.5;
    light.distance_mm = 2000.5;
    s.light = light;
    s.f_number = 8.5;
    s.width_mm = 0.02;
    s.size = 16;
    s.device = LENSRT_DEVICE_CPU;
    snprintf(path, sizeof path, "%s/sums.phasors", g_scratch);
    for (pass = 0; pass < 2; pass++) {
        // Pass 0: save under C, load under the comma locale; pass 1 the other way
        lensrt_result res;
        s.lens = NULL;
        pass == 0 ? use_c() : use_comma();
        CHECK_OK(ctx, lensrt_lens_create_analytic(ctx, &a, &s.lens));
        CHECK_OK(ctx, make_render(ctx, &s, &saved));
        if (saved) {
            CHECK_OK(ctx, lensrt_render_run(saved, 1024, NULL, NULL));
            CHECK_OK(ctx, lensrt_render_save(saved, path));
            CHECK_OK(ctx, lensrt_render_image(saved, img_saved, 2 * 16 * 16));
            lensrt_render_destroy(saved);
        }
        lensrt_lens_destroy(ctx, s.lens);
        s.lens = NULL;
        pass == 0 ? use_comma() : use_c();
        CHECK_OK(ctx, lensrt_lens_create_analytic(ctx, &a, &s.lens));
        CHECK_OK(ctx, make_render(ctx, &s, &loaded));
        if (loaded) {
            res = lensrt_render_load(loaded, path);
            CHECK(res == LENSRT_SUCCESS, "phasor sums saved under %s do not load under %s: %s (%s)",
                  pass == 0 ? "C" : COMMA_LOCALE, pass == 0 ? COMMA_LOCALE : "C", lensrt_result_string(res),
                  lensrt_context_last_error(ctx));
            CHECK_OK(ctx, lensrt_render_image(loaded, img_loaded, 2 * 16 * 16));
            CHECK(res != LENSRT_SUCCESS || memcmp(img_saved, img_loaded, sizeof img_saved) == 0,
                  "the loaded sums give another image");
            lensrt_render_destroy(loaded);
        }
        lensrt_lens_destroy(ctx, s.lens);
    }
    use_c();
    remove(path);
    lensrt_context_destroy(ctx);
}

/* Whether the file holds the bytes of `text` (EXR header attributes are stored as is). */
static int file_contains(const char *path, const char *text)
{
    FILE *f = fopen(path, "rb");
    char *data;
    long size, i;
    size_t n = strlen(text);
    int found = 0;
    if (!f) return 0;
    fseek(f, 0, SEEK_END);
    size = ftell(f);
    fseek(f, 0, SEEK_SET);
    data = size > 0 ? malloc((size_t)size) : NULL;
    if (data && fread(data, 1, (size_t)size, f) == (size_t)size)
        for (i = 0; !found && i + (long)n <= size; i++) found = memcmp(data + i, text, n) == 0;
    free(data);
    fclose(f);
    return found;
}

/* EXR metadata written under the comma locale: the lights and the aperture with points. */
static void test_exr_metadata(lensrt_context ctx, lensrt_lens lens0001)
{
    scene s;
    lensrt_render r = NULL;
    char path[2300];
    lensrt_result res;
    memset(&s, 0, sizeof s);
    s.lens = lens0001;
    s.light.struct_size = sizeof s.light;
    s.light.field_x_deg = -6.5;
    s.light.field_y_deg = -4.25;
    s.light.distance_mm = 1500.25;
    s.f_number = 8.5;
    s.width_mm = 0.03;
    s.focus_mm = 0.125;
    s.blades = 7;
    s.size = 8;
    snprintf(path, sizeof path, "%s/meta.exr", g_scratch);
    use_comma();
    CHECK_OK(ctx, make_render(ctx, &s, &r));
    if (r) {
        CHECK_OK(ctx, lensrt_render_run(r, 256, NULL, NULL));
        res = lensrt_render_write_exr(r, path);
        if (LENSRT_TEST_EXR) {
            CHECK(res == LENSRT_SUCCESS, "write_exr: %s (%s)", lensrt_result_string(res), lensrt_context_last_error(ctx));
            CHECK(file_contains(path, "(field -6.5, -4.25 deg; distance 1500.25 mm; intensity 1)"),
                  "%s: the lights attribute does not hold the light with points", path);
            CHECK(file_contains(path, "7 blades, curvature 0.3, rotation 12.5 deg"),
                  "%s: the aperture attribute does not hold the blades with points", path);
            CHECK(file_contains(path, "f/8.5, 2 wavelengths 450.5-650.25 nm"),
                  "%s: the comments attribute does not hold the f-number and wavelengths with points", path);
        } else {
            CHECK(res == LENSRT_ERROR_UNSUPPORTED, "write_exr without EXR support: %s", lensrt_result_string(res));
        }
        lensrt_render_destroy(r);
    }
    use_c();
    remove(path);
}

/* The GL path's shaders carry the scene's doubles as GLSL constants: the same image
 * under both locales (a comma would not even compile). */
static void test_gl(lensrt_context ctx, lensrt_lens lens0001)
{
    lensrt_gl_info info = LENSRT_GL_INFO_INIT;
    lensrt_result res = lensrt_context_gl_info(ctx, &info);
    const char *require = getenv("LENSRT_REQUIRE_GL");
    scene s;
    float *c_img, *comma_img;
    if (res != LENSRT_SUCCESS) {
        int required = require && require[0] && strcmp(require, "0") != 0 && res == LENSRT_ERROR_NO_DEVICE;
        CHECK(!required, "LENSRT_REQUIRE_GL is set but there is no GL device: %s", lensrt_context_last_error(ctx));
        printf("test_locale: GL part skipped: %s\n", lensrt_context_last_error(ctx));
        return;
    }
    memset(&s, 0, sizeof s);
    s.lens = lens0001;
    s.light.struct_size = sizeof s.light;
    s.light.field_x_deg = -1.5;
    s.light.field_y_deg = -0.75;
    s.f_number = 8.5;
    s.width_mm = 0.03;
    s.focus_mm = 0.125;
    s.size = 12;
    s.device = LENSRT_DEVICE_GL;
    use_c();
    c_img = render_image(ctx, &s, 4096);
    use_comma();
    comma_img = render_image(ctx, &s, 4096);
    use_c();
    CHECK(c_img && comma_img && memcmp(c_img, comma_img, 2 * 12 * 12 * sizeof(float)) == 0,
          "GL images differ between C and %s (on %s)", COMMA_LOCALE, info.renderer);
    CHECK(c_img && c_img[6 * 12 + 6] > 0, "the GL image is dark");
    free(c_img);
    free(comma_img);
}

/* ------------------------------------------------------------ lensrt-psf ----- */

/* Run lensrt-psf with LC_ALL=`locale`; its exit status, stdout in `out_path`. */
static int run_psf(const char *locale, const char *out_path, const char *exr_path)
{
    char cmd[8192];
    int status;
    snprintf(cmd, sizeof cmd,
             "LC_ALL=%s LANG=%s '%s' --lens '%s' --light -1.5,-0.75,1500.25 --focus 0.125 --f-number 8.5 "
             "--blades 7 --curvature 0.3 --rotation 12.5 --size 0.0375 --resolution 8x8 "
             "--wavelengths 450.5,650.25 --samples 2048 --threads 2 --quiet -o '%s' > '%s'",
             locale, locale, g_psf, g_table, exr_path, out_path);
    status = system(cmd);
    return status;
}

static void test_cli(void)
{
    char c_out[2300], comma_out[2300], exr[2300], c_text[512] = "", comma_text[512] = "";
    FILE *f;
    int status;
    if (!LENSRT_TEST_EXR) {
        printf("test_locale: lensrt-psf part skipped: this build writes no EXR (lensrt-psf needs -o)\n");
        return;
    }
    snprintf(c_out, sizeof c_out, "%s/psf-c.txt", g_scratch);
    snprintf(comma_out, sizeof comma_out, "%s/psf-comma.txt", g_scratch);
    snprintf(exr, sizeof exr, "%s/psf.exr", g_scratch);
    status = run_psf("C", c_out, exr);
    CHECK(status == 0, "lensrt-psf under LC_ALL=C: status %d", status);
    status = run_psf(COMMA_LOCALE, comma_out, exr);
    CHECK(status == 0, "lensrt-psf under LC_ALL=%s rejected its number options: status %d", COMMA_LOCALE, status);
    if ((f = fopen(c_out, "r"))) {
        if (!fgets(c_text, sizeof c_text, f)) c_text[0] = '\0';
        fclose(f);
    }
    if ((f = fopen(comma_out, "r"))) {
        if (!fgets(comma_text, sizeof comma_text, f)) comma_text[0] = '\0';
        fclose(f);
    }
    // The same scene gives the same error estimate (the options meant the same numbers)
    CHECK(strncmp(c_text, "Monte Carlo error estimate: ", 28) == 0 && strcmp(c_text, comma_text) == 0,
          "lensrt-psf printed '%s' under C and '%s' under %s", c_text, comma_text, COMMA_LOCALE);
    remove(c_out);
    remove(comma_out);
    remove(exr);
}

/* ------------------------------------------------------------------ main ----- */

int main(int argc, char **argv)
{
    const char *require = getenv("LENSRT_REQUIRE_LOCALE");
    lensrt_context ctx;
    lensrt_lens lens0001 = NULL;
    if (argc != 4) {
        fprintf(stderr, "usage: test_locale LENS_TABLE LENSRT_PSF SCRATCH_DIR\n");
        return 2;
    }
    g_table = argv[1];
    g_psf = argv[2];
    snprintf(g_scratch, sizeof g_scratch, "%s", argv[3]);
    mkdir(g_scratch, 0777);
    // The comma locale must exist, or there is nothing to test
    if (!setlocale(LC_ALL, COMMA_LOCALE)) {
        if (require && strcmp(require, "1") == 0) {
            fprintf(stderr, "test_locale: FAILED: LENSRT_REQUIRE_LOCALE=1 but the locale %s is missing "
                            "(scripts/setup-system.sh generates it: localedef -i de_DE -f UTF-8 de_DE.UTF-8)\n",
                    COMMA_LOCALE);
            return 1;
        }
        printf("test_locale: skipped: the locale %s is missing (scripts/setup-system.sh generates it)\n",
               COMMA_LOCALE);
        return SKIP;
    }
    use_c();
    test_formatter();
    test_table();
    test_strtok_untouched();
    test_messages();
    test_phasors();
    ctx = new_context(NULL, NULL);
    CHECK_OK(ctx, lensrt_lens_load(ctx, g_table, &lens0001));
    if (lens0001) {
        test_exr_metadata(ctx, lens0001);
        test_gl(ctx, lens0001);
    }
    lensrt_lens_destroy(ctx, lens0001);
    lensrt_context_destroy(ctx);
    test_cli();
    printf("test_locale: %d checks, %d failed\n", g_checks, g_failures);
    return g_failures ? 1 : 0;
}
