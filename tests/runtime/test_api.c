/*
 * test_api: the public contract of lensrt (lensrt.h), through the library's exported
 * symbols only (one program over 600 lines: its sections share one context, lens and
 * failing-allocator harness, and each is a short list of contract checks): result strings, context hooks (allocator, log), argument checks and
 * their messages, lens tables (file and memory, errors with file and line), renders
 * (determinism across thread counts, save/load, cancellation, sample counts) and
 * atomic image writes.
 *
 *   test_api LENS_TABLE SCRATCH_DIR
 *
 * LENS_TABLE is generated/0001-angenieux-double-gauss/lens0001.table; SCRATCH_DIR is
 * created if needed and only written inside. A LENS_TABLE of format version 2 (written
 * before the trust lines existed) is converted to version 3 in SCRATCH_DIR, with made-up
 * trust figures, and that copy is used (see v3_table). The build defines LENSRT_TEST_EXR to 1 when
 * lensrt writes EXR (LENSRT_WITH_EXR=ON) and to 0 when write_exr must answer
 * LENSRT_ERROR_UNSUPPORTED. Prints every failed check with its line and returns
 * non-zero if any failed.
 */
#include "lensrt.h"

#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Zero a versioned struct and set its struct_size (what the LENSRT_*_INIT macros do). */
#define RESET(x) (memset(&(x), 0, sizeof(x)), (x).struct_size = sizeof(x))
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>

#ifndef LENSRT_TEST_EXR
#error "define LENSRT_TEST_EXR to 1 (EXR support built) or 0"
#endif


/* ------------------------------------------------------------- harness ----- */

#include "check.h"

static char g_scratch[2048];
static const char *g_table; /* path of lens 0001's table */

static void scratch_path(char *out, size_t size, const char *name)
{
    snprintf(out, size, "%s/%s", g_scratch, name);
}

static int file_exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0;
}

static long file_size(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 ? (long)st.st_size : -1;
}

/* Entries of `dir` whose name contains `needle` (e.g. ".tmp-": leftover temporary files). */
static int count_entries(const char *dir, const char *needle)
{
    DIR *d = opendir(dir);
    struct dirent *e;
    int n = 0;
    if (!d) return 0;
    while ((e = readdir(d)) != NULL)
        if (strstr(e->d_name, needle)) n++;
    closedir(d);
    return n;
}

/* Lens table text edits (malloc'd results, NULL when out of memory). Lines are found
 * with memchr: strchr over a table of megabytes per line is quadratic under ASan's
 * strict_string_checks. */

/* `text` without its `trust ...` lines and with the header's version set to `version`. */
static char *table_without_trust(const char *text, int version)
{
    size_t n = strlen(text);
    char *out = malloc(n + 32), *o = out;
    const char *p = text, *end = text + n;
    int first = 1;
    if (!out) return NULL;
    while (p < end) {
        const char *eol = memchr(p, '\n', (size_t)(end - p));
        size_t len = eol ? (size_t)(eol - p) + 1 : (size_t)(end - p);
        if (first && strncmp(p, "lensfit-poly-table ", 19) == 0)
            o += sprintf(o, "lensfit-poly-table %d\n", version);
        else if (strncmp(p, "trust ", 6) != 0) {
            memcpy(o, p, len);
            o += len;
        }
        first = 0;
        p += len;
    }
    *o = '\0';
    return out;
}

/* `text` with `block` inserted before its first line starting with `prefix` (at the end
 * when none does, or when prefix is NULL); *line: the line number of the block's first
 * line. */
static char *table_insert(const char *text, const char *prefix, const char *block, int *line)
{
    size_t n = strlen(text), nb = strlen(block), at = n;
    const char *p = text, *end = text + n;
    char *out;
    *line = 1;
    while (p < end) {
        const char *eol = memchr(p, '\n', (size_t)(end - p));
        if (prefix && strncmp(p, prefix, strlen(prefix)) == 0) {
            at = (size_t)(p - text);
            break;
        }
        if (!eol) break;
        p = eol + 1;
        ++*line;
    }
    out = malloc(n + nb + 1);
    if (!out) return NULL;
    memcpy(out, text, at);
    memcpy(out + at, block, nb);
    memcpy(out + at + nb, text + at, n - at + 1);
    return out;
}

/* `text` as version 3 with the trust lines `block` where the format puts them. */
static char *table_with_trust(const char *text, const char *block, int *line)
{
    char *bare = table_without_trust(text, 3), *out;
    if (!bare) return NULL;
    out = table_insert(bare, "system ", block, line);
    free(bare);
    return out;
}

/* Whether `s` contains ":<digits>:" (a file:line: location). */
static int has_line_location(const char *s)
{
    for (; (s = strchr(s, ':')) != NULL; s++) {
        const char *p = s + 1;
        while (*p >= '0' && *p <= '9') p++;
        if (p > s + 1 && *p == ':') return 1;
    }
    return 0;
}

/* ---------------------------------------------------------------- hooks ----- */

/* Allocator and log hooks share user_data. Every block carries a header with a marker and
 * its size, so frees of foreign pointers and double frees are noticed. */
typedef struct hooks {
    int quarantine;   /* keep freed blocks (poisoned) until hooks_flush: catches reads after free */
    unsigned char *held; /* the quarantined blocks, linked through their headers */
    long calls;       /* alloc_fn calls, failed ones included */
    long fail_from;   /* alloc_fn returns NULL from this call index on; -1: never */
    long failed;      /* NULLs returned on purpose */
    long allocs, frees, live;
    long bad_frees;   /* free_fn of a pointer that is not a live block of ours */
    long null_frees;
    size_t live_bytes;
    int n_logs, n_error_logs, n_warning_logs, n_info_logs;
    lensrt_log_level last_level;
    char last_log[2048];
    char last_warning[2048], last_info[2048]; /* the last message of each level */
} hooks;

#define HEADER 32 /* marker, size, quarantine link; keeps malloc's alignment */
#define POISON 0xA5 /* fills quarantined blocks: an int read from one is -1515870811 */
#define POISON_INT "-1515870811"
static const uint32_t LIVE_MARK = 0x6c656e73u, DEAD_MARK = 0x64656164u;

static void hooks_reset(hooks *h)
{
    memset(h, 0, sizeof *h);
    h->fail_from = -1;
}

static void *hook_alloc(size_t size, void *user_data)
{
    hooks *h = user_data;
    unsigned char *p;
    if (h->fail_from >= 0 && h->calls >= h->fail_from) {
        h->calls++;
        h->failed++;
        return NULL;
    }
    h->calls++;
    p = malloc(size + HEADER);
    if (!p) return NULL;
    memcpy(p, &LIVE_MARK, sizeof LIVE_MARK);
    memcpy(p + 8, &size, sizeof size);
    h->allocs++;
    h->live++;
    h->live_bytes += size;
    return p + HEADER;
}

static void hook_free(void *ptr, void *user_data)
{
    hooks *h = user_data;
    unsigned char *p;
    uint32_t mark;
    size_t size;
    if (!ptr) {
        h->null_frees++;
        return;
    }
    p = (unsigned char *)ptr - HEADER;
    memcpy(&mark, p, sizeof mark);
    if (mark != LIVE_MARK) {
        h->bad_frees++; /* leak it rather than crash */
        return;
    }
    memcpy(&size, p + 8, sizeof size);
    memcpy(p, &DEAD_MARK, sizeof DEAD_MARK);
    h->frees++;
    h->live--;
    h->live_bytes -= size;
    if (h->quarantine) {
        memset(p + HEADER, POISON, size);
        memcpy(p + 16, &h->held, sizeof h->held);
        h->held = p;
        return;
    }
    free(p);
}

/* Really free the quarantined blocks. */
static void hooks_flush(hooks *h)
{
    while (h->held) {
        unsigned char *p = h->held;
        memcpy(&h->held, p + 16, sizeof h->held);
        free(p);
    }
}

static void hook_log(lensrt_log_level level, const char *message, void *user_data)
{
    hooks *h = user_data;
    h->n_logs++;
    if (level == LENSRT_LOG_ERROR) h->n_error_logs++;
    h->last_level = level;
    snprintf(h->last_log, sizeof h->last_log, "%s", message ? message : "(NULL)");
    if (level == LENSRT_LOG_WARNING) {
        h->n_warning_logs++;
        snprintf(h->last_warning, sizeof h->last_warning, "%s", message ? message : "(NULL)");
    }
    if (level == LENSRT_LOG_INFO) {
        h->n_info_logs++;
        snprintf(h->last_info, sizeof h->last_info, "%s", message ? message : "(NULL)");
    }
}

static lensrt_context hooked_context(hooks *h, int threads)
{
    lensrt_context_init init;
    lensrt_context ctx = NULL;
    lensrt_result res;
    RESET(init);
    init.alloc_fn = hook_alloc;
    init.free_fn = hook_free;
    init.log_fn = hook_log;
    init.user_data = h;
    init.threads = threads;
    res = lensrt_context_create(&init, &ctx);
    CHECK(res == LENSRT_SUCCESS && ctx, "context with hooks: %s", lensrt_result_string(res));
    return ctx;
}

/* ---------------------------------------------------------------- scenes ----- */

static const double TWO_WAVELENGTHS[2] = {486.1, 656.3};
static lensrt_light g_two_lights[2];

/* Lens 0001 at f/8, two lights a few microns apart on the sensor, a 16 x 16 window of
 * 50 um around the first one's image point, two wavelengths. */
static int fitted_desc(lensrt_context ctx, lensrt_lens lens, lensrt_render_desc *d)
{
    double xy[2] = {0, 0};
    lensrt_result res;
    RESET(g_two_lights[0]);
    RESET(g_two_lights[1]);
    g_two_lights[0].field_x_deg = -2.0;
    g_two_lights[0].field_y_deg = -1.0;
    g_two_lights[1].field_x_deg = -2.004;
    g_two_lights[1].field_y_deg = -1.0;
    g_two_lights[1].intensity = 0.5;
    res = lensrt_lens_image_point(ctx, lens, &g_two_lights[0], 550.0, 0.0, xy);
    CHECK(res == LENSRT_SUCCESS && isfinite(xy[0]) && isfinite(xy[1]) && fabs(xy[0]) < 10 && fabs(xy[1]) < 10,
          "image point of lens 0001 for (2, 1) deg: %s, (%g, %g) mm; %s", lensrt_result_string(res), xy[0], xy[1],
          lensrt_context_last_error(ctx));
    RESET(*d);
    d->lens = lens;
    d->sensor.width = 16;
    d->sensor.height = 16;
    d->sensor.width_mm = 0.05;
    d->sensor.center_x_mm = xy[0];
    d->sensor.center_y_mm = xy[1];
    d->aperture.f_number = 8.0;
    d->lights = g_two_lights;
    d->n_lights = 2;
    d->wavelengths_nm = TWO_WAVELENGTHS;
    d->n_wavelengths = 2;
    d->seed = 7;
    return res == LENSRT_SUCCESS;
}

/* A perfect lens f = 50 mm at f/8 on the axis, in focus, 8 x 8 pixels of 2 um. */
static lensrt_lens perfect_lens(lensrt_context ctx)
{
    lensrt_analytic_lens m;
    lensrt_lens lens = NULL;
    lensrt_result res;
    RESET(m);
    m.focal_length_mm = 50.0;
    m.sensor_distance_mm = 50.0;
    res = lensrt_lens_create_analytic(ctx, &m, &lens);
    CHECK(res == LENSRT_SUCCESS && lens, "perfect lens: %s; %s", lensrt_result_string(res), lensrt_context_last_error(ctx));
    return lens;
}

static const double ONE_WAVELENGTH[1] = {550.0};

static void perfect_desc(lensrt_lens lens, lensrt_render_desc *d)
{
    RESET(*d);
    d->lens = lens;
    d->sensor.width = 8;
    d->sensor.height = 8;
    d->sensor.width_mm = 0.016;
    d->aperture.f_number = 8.0;
    d->wavelengths_nm = ONE_WAVELENGTH;
    d->n_wavelengths = 1;
    d->seed = 3;
}

static size_t image_count(lensrt_render r)
{
    lensrt_render_stats s = LENSRT_RENDER_STATS_INIT;
    if (lensrt_render_get_stats(r, &s) != LENSRT_SUCCESS) return 0;
    return (size_t)s.width * (size_t)s.height * (size_t)s.n_wavelengths;
}

/* The spectral image (malloc'd), or NULL with a failed check. */
static float *image_of(lensrt_context ctx, lensrt_render r, size_t *count)
{
    size_t n = image_count(r);
    float *img = n ? malloc(sizeof(float) * n) : NULL;
    lensrt_result res;
    *count = n;
    if (!img) {
        CHECK(0, "image_of: no image size");
        return NULL;
    }
    res = lensrt_render_image(r, img, n);
    CHECK(res == LENSRT_SUCCESS, "render_image: %s; %s", lensrt_result_string(res), lensrt_context_last_error(ctx));
    if (res != LENSRT_SUCCESS) {
        free(img);
        return NULL;
    }
    return img;
}

/* ------------------------------------------------------------- 1. results ----- */

static void test_result_strings(void)
{
    const lensrt_result all[] = {LENSRT_SUCCESS, LENSRT_ERROR_INVALID_ARGUMENT, LENSRT_ERROR_OUT_OF_MEMORY,
                                 LENSRT_ERROR_IO, LENSRT_ERROR_PARSE, LENSRT_ERROR_OUT_OF_DOMAIN,
                                 LENSRT_ERROR_INCOMPATIBLE, LENSRT_ERROR_UNSUPPORTED, LENSRT_ERROR_CANCELLED,
                                 LENSRT_ERROR_NO_DEVICE, LENSRT_ERROR_DEVICE};
    const int n = (int)(sizeof all / sizeof all[0]);
    int i, j;
    CHECK(LENSRT_SUCCESS == 0, "LENSRT_SUCCESS must be 0");
    CHECK(n == LENSRT_ERROR_DEVICE + 1, "result codes are not 0..LENSRT_ERROR_DEVICE");
    for (i = 0; i < n; i++) {
        const char *s = lensrt_result_string(all[i]);
        CHECK(s != NULL && s[0] != '\0', "result %d has an empty name", (int)all[i]);
        for (j = 0; j < i && s; j++) {
            const char *t = lensrt_result_string(all[j]);
            CHECK(t == NULL || strcmp(s, t) != 0, "results %d and %d share the name '%s'", (int)all[i], (int)all[j], s);
        }
    }
    CHECK(lensrt_result_string((lensrt_result)99) != NULL && lensrt_result_string((lensrt_result)99)[0] != '\0',
          "an unknown result code needs a name too");
}

/* ------------------------------------------------------------- 2. context ----- */

static void test_context(void)
{
    lensrt_context_init init;
    lensrt_context ctx = NULL;
    hooks h;
    const char *e;

    // A zero-initialised init means the defaults
    RESET(init);
    CHECK_RES(NULL, LENSRT_SUCCESS, lensrt_context_create(&init, &ctx));
    CHECK(ctx != NULL, "zero init: no context");
    if (ctx) {
        e = lensrt_context_last_error(ctx);
        CHECK(e != NULL && e[0] == '\0', "a new context has last error '%s', expected ''", e ? e : "(NULL)");
        lensrt_context_destroy(ctx);
    }
    ctx = NULL;
    e = lensrt_context_last_error(NULL);
    CHECK(e != NULL, "last_error(NULL) must be a string");

    // Bad inits
    CHECK_RES(NULL, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_context_create(&init, NULL));
    init.alloc_fn = hook_alloc;
    CHECK_RES(NULL, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_context_create(&init, &ctx));
    init.alloc_fn = NULL;
    init.free_fn = hook_free;
    CHECK_RES(NULL, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_context_create(&init, &ctx));
    init.free_fn = NULL;
    init.threads = -1;
    CHECK_RES(NULL, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_context_create(&init, &ctx));
    init.threads = 0;
    init.gl_platform = (lensrt_gl_platform)9;
    CHECK_RES(NULL, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_context_create(&init, &ctx));
    init.gl_platform = LENSRT_GL_PLATFORM_AUTO;
    {
        lensrt_gl_info gi = LENSRT_GL_INFO_INIT;
        CHECK_RES(NULL, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_context_gl_info(NULL, &gi));
    }

    // The context itself comes from the hooks, and goes back to them
    hooks_reset(&h);
    ctx = hooked_context(&h, 0);
    CHECK(h.allocs >= 1 && h.live >= 1, "the context was not allocated through alloc_fn (%ld allocs)", h.allocs);
    lensrt_context_destroy(ctx);
    CHECK(h.live == 0 && h.frees == h.allocs && h.bad_frees == 0,
          "context: %ld allocs, %ld frees, %ld foreign frees", h.allocs, h.frees, h.bad_frees);

    // An allocator that fails at once: out of memory, nothing kept
    hooks_reset(&h);
    h.fail_from = 0;
    RESET(init);
    init.alloc_fn = hook_alloc;
    init.free_fn = hook_free;
    init.user_data = &h;
    ctx = NULL;
    CHECK_RES(NULL, LENSRT_ERROR_OUT_OF_MEMORY, lensrt_context_create(&init, &ctx));
    CHECK(h.live == 0, "failed context create keeps %ld blocks", h.live);
}

/* ------------------------------------------------------- 3. NULL arguments ----- */

static void test_null_arguments(void)
{
    hooks h;
    lensrt_context ctx;
    lensrt_lens lens, fitted = NULL, out_lens = NULL;
    lensrt_analytic_lens m;
    lensrt_lens_info info = LENSRT_LENS_INFO_INIT;
    lensrt_render_desc d;
    lensrt_render r = NULL, out_r = NULL;
    lensrt_render_stats stats = LENSRT_RENDER_STATS_INIT;
    lensrt_light light;
    double xy[2], pts[2] = {0, 0};
    float img[64 * 3];
    char path[4096];
    const char *text = "lensfit-poly-table 3\n";

    hooks_reset(&h);
    ctx = hooked_context(&h, 0);
    lens = perfect_lens(ctx);
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_load(ctx, g_table, &fitted));
    perfect_desc(lens, &d);
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_create(ctx, &d, &r));
    if (!ctx || !lens || !fitted || !r) {
        CHECK(0, "NULL argument tests need a context, lenses and a render");
        goto done;
    }
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_run(r, 64, NULL, NULL));
    RESET(m);
    m.sensor_distance_mm = 10;
    RESET(light);
    scratch_path(path, sizeof path, "null-args.out");

    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_load(NULL, g_table, &out_lens));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_load(ctx, NULL, &out_lens));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_load(ctx, g_table, NULL));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_load_text(NULL, text, strlen(text), "t", &out_lens));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, load_stamped(ctx, NULL, 10, "t", &out_lens));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, load_stamped(ctx, text, strlen(text), "t", NULL));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_create_analytic(NULL, &m, &out_lens));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_create_analytic(ctx, NULL, &out_lens));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_create_analytic(ctx, &m, NULL));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_get_info(NULL, &info));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_get_info(lens, NULL));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_image_point(NULL, fitted, &light, 550, 0, xy));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_image_point(ctx, NULL, &light, 550, 0, xy));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_image_point(ctx, fitted, NULL, 550, 0, xy));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_image_point(ctx, fitted, &light, 550, 0, NULL));
    CHECK(out_lens == NULL, "a failed lens call returned a lens");

    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_create(NULL, &d, &out_r));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_create(ctx, NULL, &out_r));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_create(ctx, &d, NULL));
    d.lens = NULL;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_create(ctx, &d, &out_r));
    d.lens = lens;
    CHECK(out_r == NULL, "a failed render_create returned a render");
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_run(NULL, 64, NULL, NULL));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_splat_points(NULL, 0, pts, 1));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_splat_points(r, 0, NULL, 1));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_get_stats(NULL, &stats));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_get_stats(r, NULL));
    CHECK(lensrt_render_wavelengths(NULL) == NULL, "render_wavelengths(NULL) must be NULL");
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_image(NULL, img, 64));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_image(r, NULL, 64));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_rgb(NULL, img, 64 * 3));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_rgb(r, NULL, 64 * 3));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_save(NULL, path));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_save(r, NULL));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_load(NULL, path));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_load(r, NULL));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_merge(NULL, path));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_merge(r, NULL));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_write_exr(NULL, path));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_write_exr(r, NULL));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_write_png(NULL, path, 5));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_write_png(r, NULL, 5));
    CHECK(!file_exists(path), "a call with NULL arguments wrote %s", path);

    // Destroying nothing is a no-op
    lensrt_render_destroy(NULL);
    lensrt_lens_destroy(ctx, NULL);
    lensrt_lens_destroy(NULL, NULL);
    lensrt_context_destroy(NULL);
done:
    lensrt_render_destroy(r);
    lensrt_lens_destroy(ctx, fitted);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    CHECK(h.live == 0 && h.bad_frees == 0, "NULL argument tests: %ld blocks left, %ld foreign frees", h.live, h.bad_frees);
}

/* --------------------------------------------- 4. messages name the parameter ----- */

/* render_create on a changed copy of `base` fails with `want` and a message with `needle`;
 * the log hook saw the same message as an error. */
static void expect_create_error(int line, lensrt_context ctx, hooks *h, const lensrt_render_desc *d,
                                lensrt_result want, const char *needle)
{
    lensrt_render r = NULL;
    lensrt_result res;
    const char *e;
    int logs = h->n_error_logs;
    res = lensrt_render_create(ctx, d, &r);
    e = lensrt_context_last_error(ctx);
    check_at(res == want, __FILE__, line, "render_create: got %s, expected %s; last error '%s'", lensrt_result_string(res),
             lensrt_result_string(want), e);
    check_at(strstr(e, needle) != NULL, __FILE__, line, "render_create: last error '%s' does not name '%s'", e, needle);
    check_at(h->n_error_logs == logs + 1 && strcmp(h->last_log, e) == 0 && h->last_level == LENSRT_LOG_ERROR, __FILE__,
             line,
             "render_create: the log hook got %d error(s), last '%s', expected '%s'", h->n_error_logs - logs,
             h->last_log, e);
    check_at(r == NULL, __FILE__, line, "a failed render_create returned a render");
    lensrt_render_destroy(r);
}
#define EXPECT_CREATE_ERROR(d, want, needle) expect_create_error(__LINE__, ctx, &h, (d), (want), (needle))

static void test_messages(void)
{
    hooks h;
    lensrt_context ctx;
    lensrt_lens lens = NULL, fitted = NULL, out = NULL;
    lensrt_render_desc base, d;
    lensrt_analytic_lens m;
    lensrt_render r = NULL;
    double bad_wl = 1000.0;
    int logs;

    hooks_reset(&h);
    ctx = hooked_context(&h, 0);
    lens = perfect_lens(ctx);
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_load(ctx, g_table, &fitted));
    if (!lens || !fitted) goto done;
    CHECK(h.n_error_logs == 0, "the log hook got an error before any failure: '%s'", h.last_log);

    // Analytic lens descriptions
    RESET(m);
    logs = h.n_error_logs;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_create_analytic(ctx, &m, &out));
    CHECK_MSG(ctx, "sensor_distance_mm");
    CHECK(h.n_error_logs == logs + 1 && strcmp(h.last_log, lensrt_context_last_error(ctx)) == 0,
          "log hook: got '%s', expected the error '%s'", h.last_log, lensrt_context_last_error(ctx));
    m.sensor_distance_mm = 50;
    m.focal_length_mm = -1;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_create_analytic(ctx, &m, &out));
    CHECK_MSG(ctx, "focal_length_mm");

    // Render descriptions: every message names what was wrong
    perfect_desc(lens, &base);
    d = base;
    d.sensor.width = 0;
    EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_INVALID_ARGUMENT, "resolution");
    d = base;
    d.sensor.height = -3;
    EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_INVALID_ARGUMENT, "-3");
    d = base;
    d.sensor.width_mm = 0;
    EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_INVALID_ARGUMENT, "width_mm");
    d = base;
    d.n_lights = 2;
    d.lights = NULL;
    EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_INVALID_ARGUMENT, "lights");
    d = base;
    d.n_wavelengths = -1;
    d.wavelengths_nm = NULL;
    EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_INVALID_ARGUMENT, "wavelengths");
    d = base;
    d.aperture.shape = LENSRT_APERTURE_BLADES;
    d.aperture.blades = 2;
    EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_INVALID_ARGUMENT, "blades");
    d = base;
    d.phase_tolerance_waves = 0.7;
    EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_INVALID_ARGUMENT, "phase_tolerance_waves");
    d = base;
    d.aperture.f_number = 0;
    d.aperture.radius_mm = 0;
    {
        lensrt_analytic_lens free_space;
        lensrt_lens fs = NULL;
        RESET(free_space);
        free_space.sensor_distance_mm = 100;
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_create_analytic(ctx, &free_space, &fs));
        d.lens = fs;
        if (fs) EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_INVALID_ARGUMENT, "radius_mm");
        lensrt_lens_destroy(ctx, fs);
    }

    // The fitted lens's domain: out of domain, with the value and the lens's range
    if (fitted_desc(ctx, fitted, &base)) {
        d = base;
        d.wavelengths_nm = &bad_wl;
        d.n_wavelengths = 1;
        EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_OUT_OF_DOMAIN, "1000 nm");
        d = base;
        d.sensor.focus_offset_mm = 50;
        EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_OUT_OF_DOMAIN, "focus offset");
        d = base;
        d.aperture.f_number = 1.0;
        EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_OUT_OF_DOMAIN, "f/");
        d = base;
        d.sensor.center_x_mm = 40;
        EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_OUT_OF_DOMAIN, "sensor");
        d = base;
        g_two_lights[1].field_x_deg = -40;
        EXPECT_CREATE_ERROR(&d, LENSRT_ERROR_OUT_OF_DOMAIN, "light 1");
        g_two_lights[1].field_x_deg = -2.004;
    }

    // run() with no samples
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_create(ctx, &base, &r));
    if (r) {
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_run(r, 0, NULL, NULL));
        CHECK_MSG(ctx, "samples");
    }
    // A success leaves the hooks' error count alone
    logs = h.n_error_logs;
    lensrt_render_destroy(r);
    r = NULL;
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_create(ctx, &base, &r));
    CHECK(h.n_error_logs == logs, "a successful render_create logged an error: '%s'", h.last_log);
done:
    lensrt_render_destroy(r);
    lensrt_lens_destroy(ctx, lens);
    lensrt_lens_destroy(ctx, fitted);
    lensrt_context_destroy(ctx);
    CHECK(h.live == 0 && h.bad_frees == 0, "message tests: %ld blocks left, %ld foreign frees", h.live, h.bad_frees);
}

/* ---------------------------------------------------------- 5. lens tables ----- */

static void test_lens_tables(void)
{
    hooks h;
    lensrt_context ctx;
    lensrt_lens lens = NULL, again = NULL;
    lensrt_lens_info info = LENSRT_LENS_INFO_INIT, info2 = LENSRT_LENS_INFO_INIT;
    char missing[4096];
    char *text;
    size_t size;
    static const char *const bad_tables[][2] = {
        /* text, what the message must contain besides the name and a line */
        {"lensfit-poly-table 3\n# a comment\nbogus line here\n", "bad.table:3:"},
        {"lensfit-poly-table 3\nlens focal_length_mm twelve\n", "bad.table:2:"},
        {"not a table\n", "bad.table:1:"},
        {"lensfit-poly-table 3\nlens name x\ntrust psf_vs_exact 0.001\ntrust psf_vs_exact_cell -\n"
         "trust psf_target 0.01\nsystem P_o 6 4\ninput x_O 1 -1 1 affine 0 1\ninput y_O 1 -1 1 "
         "cubic 0 1\n", "bad.table:8:"},
    };
    int i;

    long base;

    hooks_reset(&h);
    ctx = hooked_context(&h, 0);
    base = h.live; /* the context's own blocks */

    // A missing file: IO, with the path in the message
    scratch_path(missing, sizeof missing, "no-such-folder/lens9999.table");
    CHECK_RES(ctx, LENSRT_ERROR_IO, lensrt_lens_load(ctx, missing, &lens));
    CHECK_MSG(ctx, missing);
    CHECK(lens == NULL, "a failed load returned a lens");

    // Malformed text: PARSE, with name:line: in the message
    for (i = 0; i < (int)(sizeof bad_tables / sizeof bad_tables[0]); i++) {
        lensrt_lens bad = NULL;
        CHECK_RES(ctx, LENSRT_ERROR_PARSE,
                  load_stamped(ctx, bad_tables[i][0], strlen(bad_tables[i][0]), "bad.table", &bad));
        CHECK(has_line_location(lensrt_context_last_error(ctx)) || strstr(lensrt_context_last_error(ctx), "line"),
              "bad table %d: no line in '%s'", i, lensrt_context_last_error(ctx));
        CHECK_MSG(ctx, bad_tables[i][1]);
        CHECK(bad == NULL, "a failed load_text returned a lens");
        lensrt_lens_destroy(ctx, bad);
    }
    {
        const char *v1 = "lensfit-poly-table 1\n";
        CHECK_RES(ctx, LENSRT_ERROR_PARSE, load_stamped(ctx, v1, strlen(v1), "old.table", &lens));
        CHECK_MSG(ctx, "version 1");
        CHECK_MSG(ctx, "regenerate");
    }
    CHECK(h.live == base, "failed loads keep %ld blocks", h.live - base);

    // The real table
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_load(ctx, g_table, &lens));
    if (lens) {
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_get_info(lens, &info));
        CHECK(info.name && strstr(info.name, "Angenieux"), "lens 0001 name '%s'", info.name ? info.name : "(NULL)");
        CHECK(!info.analytic, "a fitted lens says analytic");
        CHECK(fabs(info.f_number_min - 2.0) < 0.02, "lens 0001: f_number_min %g, expected ~2", info.f_number_min);
        CHECK(fabs(info.wavelength_min_nm - 380) < 1e-9 && fabs(info.wavelength_max_nm - 780) < 1e-9,
              "lens 0001: wavelengths %g..%g nm, expected 380..780", info.wavelength_min_nm, info.wavelength_max_nm);
        CHECK(fabs(info.focal_length_mm - 100) < 1, "lens 0001: focal length %g mm, expected ~100", info.focal_length_mm);
        CHECK(info.focus_offset_min_mm < 0 && info.focus_offset_max_mm > 0 && info.sensor_radius_mm > 0 &&
                  info.field_x > 0 && info.field_y > 0 && info.stop_radius_max_mm > 0,
              "lens 0001: info ranges are not sensible");
        // The same table from memory gives the same lens
        text = read_text(g_table, &size);
        CHECK(text != NULL, "cannot read %s", g_table);
        if (text) {
            CHECK_RES(ctx, LENSRT_SUCCESS, load_stamped(ctx, text, size, "memory.table", &again));
            if (again) {
                CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_get_info(again, &info2));
                CHECK(info2.f_number_min == info.f_number_min && info2.focal_length_mm == info.focal_length_mm &&
                          info2.sensor_radius_mm == info.sensor_radius_mm,
                      "load_text and load differ");
            }
            // Truncated at half: a parse error with a line
            {
                lensrt_lens half = NULL;
                CHECK_RES(ctx, LENSRT_ERROR_PARSE, load_stamped(ctx, text, size / 2, "half.table", &half));
                CHECK(has_line_location(lensrt_context_last_error(ctx)) || strstr(lensrt_context_last_error(ctx), "line"),
                      "truncated table: no line in '%s'", lensrt_context_last_error(ctx));
                lensrt_lens_destroy(ctx, half);
            }
            free(text);
        }
    }
    lensrt_lens_destroy(ctx, again);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    CHECK(h.live == 0 && h.bad_frees == 0, "lens tests: %ld blocks left, %ld foreign frees", h.live, h.bad_frees);
}

/* ---------------------------------------------- 5b. table version 3 trust ----- */

/* load_text of `text` as `name` fails with PARSE naming name:line: and `needle`. */
static void expect_table_error(int line, lensrt_context ctx, const char *text, const char *name, int want_line,
                               const char *needle)
{
    lensrt_lens lens = NULL;
    lensrt_result res;
    char where[512];
    const char *e;
    if (!text) {
        check_at(0, __FILE__, line, "out of memory making a table");
        return;
    }
    res = load_stamped(ctx, text, strlen(text), name, &lens);
    e = lensrt_context_last_error(ctx);
    check_at(res == LENSRT_ERROR_PARSE, __FILE__, line, "load_text: got %s, expected parse error; last error '%s'",
             lensrt_result_string(res), e);
    check_at(lens == NULL, __FILE__, line, "a failed load_text returned a lens");
    if (want_line > 0) {
        snprintf(where, sizeof where, "%s:%d:", name, want_line);
        check_at(strstr(e, where) != NULL, __FILE__, line, "last error '%s' does not name '%s'", e, where);
    }
    check_at(strstr(e, needle) != NULL, __FILE__, line, "last error '%s' does not contain '%s'", e, needle);
    lensrt_lens_destroy(ctx, lens);
}
#define EXPECT_TABLE_ERROR(text, name, want_line, needle) \
    expect_table_error(__LINE__, ctx, (text), (name), (want_line), (needle))

static void test_table_trust(void)
{
    static const char *const good = "trust psf_vs_exact 0.0041\n"
                                    "trust psf_vs_exact_cell f/2%20axis%20450%20nm\n"
                                    "trust psf_target 0.01\n";
    /* Malformed trust blocks, put where the format wants them: the line of the block
     * the error must name (1: its first line) and what the message must contain */
    static const struct {
        const char *block;
        int line;
        const char *needle;
    } bad[] = {
        {"", 1, "missing trust line: expected 'trust psf_vs_exact <real>'"},
        {"trust psf_vs_exact 0.0041\ntrust psf_vs_exact_cell x\n", 3, "missing trust line: expected 'trust psf_target <real>' (trust line 3 of 3"},
        {"trust psf_vs_exact 0.0041\ntrust psf_vs_exact 0.0041\ntrust psf_target 0.01\n", 2, "psf_vs_exact '0.0041' appears twice"},
        {"trust psf_vs_exact_cell x\ntrust psf_vs_exact 0.0041\ntrust psf_target 0.01\n", 1,
         "expected 'trust psf_vs_exact <real>' (trust line 1 of 3"},
        {"trust psf_vs_exact 0.0041\ntrust psf_target 0.01\ntrust psf_vs_exact_cell x\n", 2,
         "found trust psf_target '0.01'"},
        {"trust psf_vs_exact lots\ntrust psf_vs_exact_cell x\ntrust psf_target 0.01\n", 1,
         "trust psf_vs_exact 'lots' is not a finite number"},
        {"trust psf_vs_exact 0.0041\ntrust psf_vs_exact_cell x\ntrust psf_target -0.01\n", 3,
         "trust psf_target -0.01 is out of range: expected a number in [1e-06, 1]"},
        {"trust psf_vs_exact inf\ntrust psf_vs_exact_cell x\ntrust psf_target 0.01\n", 1, "'inf'"},
        {"trust psf_vs_exact nan\ntrust psf_vs_exact_cell x\ntrust psf_target 0.01\n", 1, "'nan'"},
        {"trust psf_vs_exact 0.0041 0.005\ntrust psf_vs_exact_cell x\ntrust psf_target 0.01\n", 1, "found 4 fields"},
        {"trust psf_vs_exact\ntrust psf_vs_exact_cell x\ntrust psf_target 0.01\n", 1, "found 2 fields"},
        {"trust psf_vs_exact 0.0041\ntrust psf_vs_exact_cell x\ntrust psf_target 0.01\ntrust psf_extra 1\n", 4,
         "unknown trust key 'psf_extra'"},
        {"trust psf_vs_exact 0.0041\ntrust psf_vs_exact_cell x\ntrust psf_target 0.01\nlens squeeze 1\n", 4,
         "lens squeeze '1' after the trust lines"},
    };
    hooks h;
    lensrt_context ctx;
    lensrt_lens lens = NULL, analytic = NULL;
    lensrt_lens_info info = LENSRT_LENS_INFO_INIT;
    lensrt_analytic_lens m;
    char *real, *text, *tmp, name[64];
    size_t size;
    int i, line, n_warnings;

    hooks_reset(&h);
    ctx = hooked_context(&h, 0);
    real = read_text(g_table, &size);
    CHECK(real != NULL, "cannot read %s", g_table);
    if (!ctx || !real) goto done;

    // Older and newer versions are refused with what to do
    text = table_without_trust(real, 2);
    EXPECT_TABLE_ERROR(text, "generated/0042-x/lens0042.table", 0, "table version 2 predates the trust figures");
    CHECK_MSG(ctx, "generated/0042-x/lens0042.table: ");
    CHECK_MSG(ctx, "regenerate it with `lensfit fit 0042`");
    EXPECT_TABLE_ERROR(text, "v2.table", 0, "regenerate it with `lensfit fit LENS`");
    free(text);
    text = table_without_trust(real, 6);
    EXPECT_TABLE_ERROR(text, "v6.table", 0, "table version 6 is newer than this lensrt reads (5)");
    free(text);

    // Version 4's checksum (issue 25), unstamped here: a version-3 table is refused with
    // the command that rewrites its folder, a changed byte and a missing checksum line
    // (a table cut short) are refused naming the line
    {
        lensrt_lens lens3 = NULL;
        size_t n = strlen(real), k;
        char *copy = malloc(n + 1);
        CHECK(copy != NULL, "out of memory");
        if (copy) {
            memcpy(copy, real, n + 1);
            copy[19] = '3'; /* "lensfit-poly-table 3" */
            CHECK_RES(ctx, LENSRT_ERROR_PARSE,
                      lensrt_lens_load_text(ctx, copy, n, "generated/0042-x/ghosts/ghost_1_2.table", &lens3));
            CHECK_MSG(ctx, "table version 3 carries no checksum");
            CHECK_MSG(ctx, "`lensfit regenerate 0042-x`");
            // Version 4 (no probe lines, issue 39): refused with the commands that add them
            copy[19] = '4';
            CHECK_RES(ctx, LENSRT_ERROR_PARSE,
                      lensrt_lens_load_text(ctx, copy, n, "generated/0042-x/lens0042.table", &lens3));
            CHECK_MSG(ctx, "generated/0042-x/lens0042.table: table version 4 carries no probe lines");
            CHECK_MSG(ctx, "`lensfit regenerate 0042-x` (adds them from the table's own polynomials, no refit)");
            CHECK_MSG(ctx, "`lensfit upgrade-table generated/0042-x/lens0042.table`");
            copy[19] = '5';
            for (k = n - 2; k > 0 && copy[k - 1] != '\n'; k--) continue; /* the checksum line */
            copy[k / 2] ^= 0x01;
            CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_lens_load_text(ctx, copy, n, "flip.table", &lens3));
            CHECK_MSG(ctx, "does not match the content");
            copy[k / 2] ^= 0x01;
            CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_lens_load_text(ctx, copy, k, "cut.table", &lens3));
            CHECK_MSG(ctx, "expected the last line 'checksum crc32 <8 lowercase hex digits>'");
            copy[n - 2] = (char)(copy[n - 2] >= 'a' ? copy[n - 2] - 32 : copy[n - 2]); /* upper case: refused */
            if (copy[n - 2] >= 'A' && copy[n - 2] <= 'F') {
                CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_lens_load_text(ctx, copy, n, "upper.table", &lens3));
            }
            free(copy);
        }
    }

    // A version 3 table: the figures arrive in the info, the log says them
    text = table_with_trust(real, good, &line);
    CHECK(text != NULL, "out of memory");
    n_warnings = h.n_warning_logs;
    if (text) CHECK_RES(ctx, LENSRT_SUCCESS, load_stamped(ctx, text, strlen(text), "lens0001.table", &lens));
    if (lens) {
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_get_info(lens, &info));
        CHECK(info.psf_vs_exact == 0.0041 && info.psf_target == 0.01, "trust figures %g, %g: expected 0.0041, 0.01",
              info.psf_vs_exact, info.psf_target);
        CHECK(info.psf_vs_exact_cell && strcmp(info.psf_vs_exact_cell, "f/2 axis 450 nm") == 0,
              "worst cell '%s', expected 'f/2 axis 450 nm'", info.psf_vs_exact_cell ? info.psf_vs_exact_cell : "(NULL)");
        CHECK(strcmp(h.last_info, "lens0001.table: PSF against exactly traced rays: worst 0.41% relative L2 "
                                  "(f/2 axis 450 nm), target 1%") == 0,
              "INFO log on load: '%s'", h.last_info);
        CHECK(h.n_warning_logs == n_warnings, "a table within its target logged a warning: '%s'", h.last_warning);
    }
    lensrt_lens_destroy(ctx, lens);
    lens = NULL;
    free(text);

    // Worse than its target: a WARNING too, with the same figures and what to do
    text = table_with_trust(real, "trust psf_vs_exact 0.023\ntrust psf_vs_exact_cell f/2%20edge\ntrust psf_target 0.01\n", &line);
    n_warnings = h.n_warning_logs;
    if (text) CHECK_RES(ctx, LENSRT_SUCCESS, load_stamped(ctx, text, strlen(text), "worse.table", &lens));
    CHECK(h.n_warning_logs == n_warnings + 1, "%d warnings on loading a table worse than its target", h.n_warning_logs - n_warnings);
    CHECK(strstr(h.last_warning, "worse.table: PSF against exactly traced rays: worst 2.3% relative L2 (f/2 edge), target 1%") &&
              strstr(h.last_warning, "exceeds the fit's target: regenerate with a tighter `lensfit fit --psf-target` "
                                     "or a narrower domain"),
          "WARNING log on load: '%s'", h.last_warning);
    CHECK(strstr(h.last_info, "worst 2.3% relative L2 (f/2 edge), target 1%") != NULL, "INFO log on load: '%s'", h.last_info);
    if (lens) {
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_get_info(lens, &info));
        CHECK(info.psf_vs_exact == 0.023 && strcmp(info.psf_vs_exact_cell, "f/2 edge") == 0, "trust figures %g, '%s'",
              info.psf_vs_exact, info.psf_vs_exact_cell);
    }
    lensrt_lens_destroy(ctx, lens);
    lens = NULL;
    free(text);

    // Malformed trust lines: file:line, key and value
    for (i = 0; i < (int)(sizeof bad / sizeof bad[0]); i++) {
        snprintf(name, sizeof name, "bad-trust-%d.table", i);
        text = table_with_trust(real, bad[i].block, &line);
        EXPECT_TABLE_ERROR(text, name, line + bad[i].line - 1, bad[i].needle);
        free(text);
    }
    // Trust lines before the lens lines, or after a system
    tmp = table_without_trust(real, 3);
    text = tmp ? table_insert(tmp, "lens ", good, &line) : NULL;
    EXPECT_TABLE_ERROR(text, "early.table", line, "trust psf_vs_exact '0.0041' before the lens lines");
    free(text);
    free(tmp);
    tmp = table_with_trust(real, good, &line);
    text = tmp ? table_insert(tmp, NULL, "trust psf_target 0.01\n", &line) : NULL;
    EXPECT_TABLE_ERROR(text, "late.table", line, "trust psf_target '0.01' after a system");
    free(text);
    free(tmp);

    // Analytic lenses: no figures
    RESET(m);
    m.sensor_distance_mm = 50.0;
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_create_analytic(ctx, &m, &analytic));
    if (analytic) {
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_get_info(analytic, &info));
        CHECK(info.psf_vs_exact == 0 && info.psf_target == 0 && info.psf_vs_exact_cell &&
                  info.psf_vs_exact_cell[0] == '\0',
              "analytic lens trust figures %g, %g, '%s'", info.psf_vs_exact, info.psf_target,
              info.psf_vs_exact_cell ? info.psf_vs_exact_cell : "(NULL)");
    }
done:
    free(real);
    lensrt_lens_destroy(ctx, analytic);
    lensrt_context_destroy(ctx);
    CHECK(h.live == 0 && h.bad_frees == 0, "trust tests: %ld blocks left, %ld foreign frees", h.live, h.bad_frees);
}

/* The committed tables are version 2 until they are regenerated: test with a version 3
 * copy in the scratch folder (made-up trust figures within their target) meanwhile. */
static char g_table_v3[4096];

static const char *v3_table(const char *path)
{
    size_t size;
    char *text = read_text(path, &size), *v3;
    const char *base = strrchr(path, '/');
    FILE *f;
    int line;
    if (!text || strncmp(text, "lensfit-poly-table 2\n", 21) != 0) {
        free(text);
        return path;
    }
    v3 = table_with_trust(text, "trust psf_vs_exact 0.004\ntrust psf_vs_exact_cell f/2%20axis%20550%20nm\n"
                                "trust psf_target 0.01\n", &line);
    free(text);
    snprintf(g_table_v3, sizeof g_table_v3, "%s/%s", g_scratch, base ? base + 1 : path);
    f = v3 ? fopen(g_table_v3, "wb") : NULL;
    if (!f || fputs(v3, f) < 0 || fclose(f) != 0) {
        fprintf(stderr, "test_api: cannot write %s\n", g_table_v3);
        free(v3);
        return path;
    }
    free(v3);
    printf("test_api: %s is a version 2 table; testing with the version 3 copy %s\n", path, g_table_v3);
    return g_table_v3;
}

/* ------------------------------------------------- 6. failing allocators ----- */

/* Run `what` with alloc_fn failing from its k-th call on, for k = 0, 1, ... until it
 * succeeds: every failure must be OUT_OF_MEMORY and leave no block behind. */
typedef lensrt_result (*oom_step)(lensrt_context ctx, void *arg, void **made);
typedef void (*oom_undo)(lensrt_context ctx, void *made);

static void oom_sweep(const char *what, hooks *h, lensrt_context ctx, oom_step step, oom_undo undo, void *arg)
{
    long k, before = h->live;
    int succeeded = 0, reads_after_free = 0;
    for (k = 0; k < 10000 && !succeeded; k++) {
        void *made = NULL;
        lensrt_result res;
        h->fail_from = h->calls + k;
        h->failed = 0;
        // Freed blocks stay mapped and poisoned during the step, so that a read after
        // free shows up in the message instead of aborting the whole test under ASan
        h->quarantine = 1;
        res = step(ctx, arg, &made);
        h->quarantine = 0;
        h->fail_from = -1;
        if (!reads_after_free) { /* reported once per step */
            reads_after_free = strstr(lensrt_context_last_error(ctx), POISON_INT) != NULL;
            CHECK(!reads_after_free, "%s with allocation %ld failing reads freed memory: its message is '%s' "
                  "(%s is the poison of freed blocks)", what, k, lensrt_context_last_error(ctx), POISON_INT);
        }
        hooks_flush(h);
        if (res == LENSRT_SUCCESS) {
            succeeded = 1;
            CHECK(h->failed == 0, "%s: succeeded although %ld allocations failed", what, h->failed);
            if (undo) undo(ctx, made);
            CHECK(h->live == before, "%s: %ld blocks left after destroy", what, h->live - before);
        } else {
            CHECK(res == LENSRT_ERROR_OUT_OF_MEMORY, "%s with allocation %ld failing: %s, expected out of memory; %s",
                  what, k, lensrt_result_string(res), lensrt_context_last_error(ctx));
            CHECK(h->live == before, "%s with allocation %ld failing: leaks %ld blocks", what, k, h->live - before);
            CHECK(made == NULL, "%s with allocation %ld failing: returned an object", what, k);
        }
    }
    CHECK(succeeded && k > 1, "%s: never succeeded or never allocated (%ld tries)", what, k);
    CHECK(h->bad_frees == 0, "%s: %ld foreign frees", what, h->bad_frees);
}

typedef struct oom_args {
    const char *text;
    size_t size;
    lensrt_render_desc desc;
    lensrt_render render;
    char path[4096];
} oom_args;

static lensrt_result step_load_text(lensrt_context ctx, void *arg, void **made)
{
    oom_args *a = arg;
    lensrt_lens lens = NULL;
    lensrt_result res = load_stamped(ctx, a->text, a->size, "oom.table", &lens);
    *made = lens;
    return res;
}
static void undo_lens(lensrt_context ctx, void *made) { lensrt_lens_destroy(ctx, (lensrt_lens)made); }

static lensrt_result step_render_create(lensrt_context ctx, void *arg, void **made)
{
    oom_args *a = arg;
    lensrt_render r = NULL;
    lensrt_result res = lensrt_render_create(ctx, &a->desc, &r);
    *made = r;
    return res;
}
static void undo_render(lensrt_context ctx, void *made)
{
    (void)ctx;
    lensrt_render_destroy((lensrt_render)made);
}

static lensrt_result step_run(lensrt_context ctx, void *arg, void **made)
{
    oom_args *a = arg;
    (void)ctx;
    *made = NULL;
    return lensrt_render_run(a->render, 256, NULL, NULL);
}

/* A run that ends inside a block keeps a copy of the sums (lensrt_render_run) with the
 * render: a fresh render each step, destroyed by undo_render. */
static lensrt_result step_run_partial(lensrt_context ctx, void *arg, void **made)
{
    oom_args *a = arg;
    lensrt_render r = NULL;
    lensrt_result res;
    *made = NULL;
    if ((res = lensrt_render_create(ctx, &a->desc, &r)) != LENSRT_SUCCESS) return res;
    if ((res = lensrt_render_run(r, 100, NULL, NULL)) == LENSRT_SUCCESS) {
        // A second run that fails leaves the first one's samples (and sums) as they were
        lensrt_render_stats st = LENSRT_RENDER_STATS_INIT;
        res = lensrt_render_run(r, 100, NULL, NULL);
        lensrt_render_get_stats(r, &st);
        CHECK(st.samples_per_wavelength == (res == LENSRT_SUCCESS ? 200u : 100u),
              "run(100); run(100) (%s): %llu samples", lensrt_result_string(res),
              (unsigned long long)st.samples_per_wavelength);
    }
    if (res != LENSRT_SUCCESS) {
        lensrt_render_destroy(r);
        return res;
    }
    *made = r;
    return res;
}

static lensrt_result step_rgb(lensrt_context ctx, void *arg, void **made)
{
    oom_args *a = arg;
    float rgb[8 * 8 * 3];
    (void)ctx;
    *made = NULL;
    return lensrt_render_rgb(a->render, rgb, sizeof rgb / sizeof rgb[0]);
}

static lensrt_result step_png(lensrt_context ctx, void *arg, void **made)
{
    oom_args *a = arg;
    lensrt_result res = lensrt_render_write_png(a->render, a->path, 5);
    (void)ctx;
    *made = NULL;
    // A failed write leaves no file (and no temporary file)
    if (res != LENSRT_SUCCESS) {
        CHECK(!file_exists(a->path), "a failed write_png (out of memory) left %s", a->path);
        CHECK(count_entries(g_scratch, ".tmp-") == 0, "a failed write_png (out of memory) left a temporary file");
    }
    return res;
}

static lensrt_result step_load(lensrt_context ctx, void *arg, void **made)
{
    oom_args *a = arg;
    (void)ctx;
    *made = NULL;
    return lensrt_render_load(a->render, a->path);
}

static void test_failing_allocator(void)
{
    hooks h;
    lensrt_context ctx;
    lensrt_lens fitted = NULL, lens = NULL;
    oom_args a;
    char *text;

    memset(&a, 0, sizeof a);
    text = read_text(g_table, &a.size);
    a.text = text;
    CHECK(text != NULL, "cannot read %s", g_table);
    hooks_reset(&h);
    ctx = hooked_context(&h, 0);
    if (!text || !ctx) goto done;

    oom_sweep("lens_load_text", &h, ctx, step_load_text, undo_lens, &a);
    CHECK_RES(ctx, LENSRT_SUCCESS, load_stamped(ctx, a.text, a.size, "lens0001", &fitted));
    lens = perfect_lens(ctx);
    if (!fitted || !lens) goto done;

    // render_create, fitted and analytic (the brief's core case)
    if (fitted_desc(ctx, fitted, &a.desc)) oom_sweep("render_create (fitted lens)", &h, ctx, step_render_create, undo_render, &a);
    a.desc.estimator = LENSRT_ESTIMATOR_UNBIASED; /* allocates the sums of squares too */
    oom_sweep("render_create (fitted lens, unbiased)", &h, ctx, step_render_create, undo_render, &a);
    perfect_desc(lens, &a.desc);
    oom_sweep("render_create (perfect lens)", &h, ctx, step_render_create, undo_render, &a);

    // run, rgb, write_png and load on a live render
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_create(ctx, &a.desc, &a.render));
    if (a.render) {
        lensrt_render_stats s = LENSRT_RENDER_STATS_INIT;
        oom_sweep("render_run", &h, ctx, step_run, NULL, &a);
        oom_sweep("render_run twice inside a block", &h, ctx, step_run_partial, undo_render, &a);
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_get_stats(a.render, &s));
        CHECK(s.samples_per_wavelength == 256, "runs that failed for memory added samples: %llu, expected 256",
              (unsigned long long)s.samples_per_wavelength);
        oom_sweep("render_rgb", &h, ctx, step_rgb, NULL, &a);
        scratch_path(a.path, sizeof a.path, "oom.png");
        remove(a.path);
        oom_sweep("render_write_png", &h, ctx, step_png, NULL, &a);
        CHECK(file_exists(a.path), "write_png wrote no %s", a.path);
        scratch_path(a.path, sizeof a.path, "oom.phasors");
        // save with its first allocation failing: out of memory (not an I/O error), no file
        remove(a.path);
        h.fail_from = h.calls;
        CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_MEMORY, lensrt_render_save(a.render, a.path));
        h.fail_from = -1;
        CHECK(!file_exists(a.path), "a save that ran out of memory wrote %s", a.path);
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_save(a.render, a.path));
        oom_sweep("render_load", &h, ctx, step_load, NULL, &a);
        lensrt_render_destroy(a.render);
    }
done:
    lensrt_lens_destroy(ctx, fitted);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    free(text);
    CHECK(h.live == 0 && h.bad_frees == 0, "failing allocator tests: %ld blocks left (%lu bytes), %ld foreign frees",
          h.live, (unsigned long)h.live_bytes, h.bad_frees);
}

/* ------------------------------------------- 7. threads, save and load ----- */

/* The fitted scene rendered in a context with `threads` threads; returns the render. */
static lensrt_render render_fitted(lensrt_context ctx, lensrt_lens lens, uint64_t samples)
{
    lensrt_render_desc d;
    lensrt_render r = NULL;
    if (!fitted_desc(ctx, lens, &d)) return NULL;
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_create(ctx, &d, &r));
    if (r && samples) CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_run(r, samples, NULL, NULL));
    return r;
}

static void test_threads_and_files(void)
{
    hooks h1, h2;
    lensrt_context c1, c2;
    lensrt_lens l1 = NULL, l2 = NULL;
    lensrt_render r1 = NULL, r2 = NULL, r3 = NULL, r4 = NULL;
    float *i1 = NULL, *i2 = NULL, *i3 = NULL, *i4 = NULL;
    size_t n1 = 0, n2 = 0, n3 = 0, n4 = 0, k;
    lensrt_render_stats s1 = LENSRT_RENDER_STATS_INIT, s3 = LENSRT_RENDER_STATS_INIT;
    char path[4096], other[4096];
    double sum = 0, peak = 0;

    hooks_reset(&h1);
    hooks_reset(&h2);
    c1 = hooked_context(&h1, 1);
    c2 = hooked_context(&h2, 2);
    CHECK_RES(c1, LENSRT_SUCCESS, lensrt_lens_load(c1, g_table, &l1));
    CHECK_RES(c2, LENSRT_SUCCESS, lensrt_lens_load(c2, g_table, &l2));
    if (!l1 || !l2) goto done;

    // One thread and two threads: the same bits
    r1 = render_fitted(c1, l1, 512);
    r2 = render_fitted(c2, l2, 512);
    if (!r1 || !r2) goto done;
    i1 = image_of(c1, r1, &n1);
    i2 = image_of(c2, r2, &n2);
    if (!i1 || !i2) goto done;
    CHECK(n1 == 16 * 16 * 2 && n2 == n1, "image counts %zu and %zu, expected 512", n1, n2);
    for (k = 0; k < n1; k++) {
        CHECK(isfinite(i1[k]) && i1[k] >= 0, "pixel value %zu is %g", k, (double)i1[k]);
        sum += i1[k];
        if (i1[k] > peak) peak = i1[k];
    }
    CHECK(sum > 0 && peak > 0, "the fitted render is black");
    CHECK(memcmp(i1, i2, sizeof(float) * n1) == 0, "threads=1 and threads=2 renders differ");
    CHECK_RES(c1, LENSRT_SUCCESS, lensrt_render_get_stats(r1, &s1));
    CHECK(s1.width == 16 && s1.height == 16 && s1.n_wavelengths == 2 && s1.n_lights == 2 &&
              s1.samples_per_wavelength == 512 && s1.splats > 0,
          "stats: %d x %d, %d wavelengths, %d lights, %llu samples", s1.width, s1.height, s1.n_wavelengths,
          s1.n_lights, (unsigned long long)s1.samples_per_wavelength);
    CHECK(fabs(s1.f_number - 8) < 1e-9, "stats: f/%g, expected f/8", s1.f_number);
    CHECK(lensrt_render_wavelengths(r1) && lensrt_render_wavelengths(r1)[0] == TWO_WAVELENGTHS[0] &&
              lensrt_render_wavelengths(r1)[1] == TWO_WAVELENGTHS[1],
          "render_wavelengths is not the given list");

    // Save, then load into a fresh render of the same scene: the same bits
    scratch_path(path, sizeof path, "fitted.phasors");
    remove(path);
    CHECK_RES(c1, LENSRT_SUCCESS, lensrt_render_save(r1, path));
    CHECK(file_size(path) > 0, "save wrote no %s", path);
    CHECK(count_entries(g_scratch, ".tmp-") == 0, "save left a temporary file in %s", g_scratch);
    r3 = render_fitted(c1, l1, 0);
    if (r3) {
        CHECK_RES(c1, LENSRT_SUCCESS, lensrt_render_load(r3, path));
        i3 = image_of(c1, r3, &n3);
        CHECK(i3 && n3 == n1 && memcmp(i1, i3, sizeof(float) * n1) == 0, "save -> load changed the image");
        CHECK_RES(c1, LENSRT_SUCCESS, lensrt_render_get_stats(r3, &s3));
        CHECK(s3.samples_per_wavelength == 512, "load: %llu samples, expected 512",
              (unsigned long long)s3.samples_per_wavelength);
        // Merging sums of the same seed would count samples twice
        CHECK_RES(c1, LENSRT_ERROR_INCOMPATIBLE, lensrt_render_merge(r3, path));
        // Continuing after load equals one longer run (up to the order of float sums)
        CHECK_RES(c1, LENSRT_SUCCESS, lensrt_render_run(r3, 512, NULL, NULL));
        r4 = render_fitted(c1, l1, 1024);
        if (r4) {
            i4 = image_of(c1, r4, &n4);
            free(i3);
            i3 = image_of(c1, r3, &n3);
            if (i3 && i4) {
                double worst = 0;
                for (k = 0; k < n4; k++) {
                    double diff = fabs((double)i3[k] - (double)i4[k]) / (peak > 0 ? peak : 1);
                    if (diff > worst) worst = diff;
                }
                CHECK(worst < 1e-4, "load + run(512) differs from run(1024) by %g of the peak", worst);
            }
        }
    }
    // A different scene refuses the file
    {
        lensrt_render_desc d;
        lensrt_render other_r = NULL;
        if (fitted_desc(c1, l1, &d)) {
            d.aperture.f_number = 11;
            CHECK_RES(c1, LENSRT_SUCCESS, lensrt_render_create(c1, &d, &other_r));
            if (other_r) CHECK_RES(c1, LENSRT_ERROR_INCOMPATIBLE, lensrt_render_load(other_r, path));
            lensrt_render_destroy(other_r);
        }
    }
    // Not a phasor file, and a missing one
    scratch_path(other, sizeof other, "not-phasors.bin");
    {
        FILE *f = fopen(other, "wb");
        if (f) {
            fputs("hello, this is not a phasor file at all, just text long enough for a header\n", f);
            fclose(f);
        }
    }
    if (r3) {
        CHECK_RES(c1, LENSRT_ERROR_PARSE, lensrt_render_load(r3, other));
        CHECK_MSG(c1, other);
        scratch_path(other, sizeof other, "no-such-folder/x.phasors");
        CHECK_RES(c1, LENSRT_ERROR_IO, lensrt_render_load(r3, other));
        CHECK_MSG(c1, other);
        CHECK_RES(c1, LENSRT_ERROR_IO, lensrt_render_save(r3, other));
        CHECK(!file_exists(other), "a failed save left %s", other);
    }
done:
    free(i1);
    free(i2);
    free(i3);
    free(i4);
    lensrt_render_destroy(r1);
    lensrt_render_destroy(r2);
    lensrt_render_destroy(r3);
    lensrt_render_destroy(r4);
    lensrt_lens_destroy(c1, l1);
    lensrt_lens_destroy(c2, l2);
    lensrt_context_destroy(c1);
    lensrt_context_destroy(c2);
    CHECK(h1.live == 0 && h2.live == 0 && h1.bad_frees == 0 && h2.bad_frees == 0,
          "thread/file tests: %ld and %ld blocks left", h1.live, h2.live);
}

/* ----------------------------------------------------------- 8. image files ----- */

static void test_image_files(void)
{
    hooks h;
    lensrt_context ctx;
    lensrt_lens lens;
    lensrt_render_desc d;
    lensrt_render r = NULL;
    char path[4096], dir[4096];
    lensrt_result res;

    hooks_reset(&h);
    ctx = hooked_context(&h, 0);
    lens = perfect_lens(ctx);
    if (!lens) goto done;
    perfect_desc(lens, &d);
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_create(ctx, &d, &r));
    if (!r) goto done;

    // Before any run there is no image, and no file is written
    {
        float img[64];
        scratch_path(path, sizeof path, "early.png");
        remove(path);
        res = lensrt_render_image(r, img, 64);
        CHECK(res != LENSRT_SUCCESS, "render_image before any run succeeded");
        CHECK(res == LENSRT_ERROR_INVALID_ARGUMENT, "render_image before any run: %s", lensrt_result_string(res));
        CHECK_MSG(ctx, "samples");
        res = lensrt_render_write_png(r, path, 5);
        CHECK(res != LENSRT_SUCCESS && !file_exists(path), "write_png before any run: %s, file %s",
              lensrt_result_string(res), file_exists(path) ? "written" : "not written");
    }
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_run(r, 256, NULL, NULL));
    // Wrong counts
    {
        float img[64];
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_image(r, img, 63));
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_rgb(r, img, 64));
    }

    // A missing folder: IO, no file
    scratch_path(path, sizeof path, "no-such-folder/psf.png");
    CHECK_RES(ctx, LENSRT_ERROR_IO, lensrt_render_write_png(r, path, 5));
    CHECK_MSG(ctx, "psf.png");
    CHECK(!file_exists(path), "a failed write_png left %s", path);
    scratch_path(path, sizeof path, "no-such-folder/psf.exr");
    CHECK_RES(ctx, LENSRT_TEST_EXR ? LENSRT_ERROR_IO : LENSRT_ERROR_UNSUPPORTED, lensrt_render_write_exr(r, path));
    CHECK_MSG(ctx, "psf.exr");
    CHECK(!file_exists(path), "a failed write_exr left %s", path);

    // The target is a folder: the rename fails, and the temporary file must go too
    scratch_path(dir, sizeof dir, "a-folder.png");
    mkdir(dir, 0777);
    CHECK_RES(ctx, LENSRT_ERROR_IO, lensrt_render_write_png(r, dir, 5));
    CHECK(count_entries(g_scratch, ".tmp-") == 0, "a failed write_png over a folder left a temporary file");
    scratch_path(dir, sizeof dir, "a-folder.exr");
    mkdir(dir, 0777);
    CHECK_RES(ctx, LENSRT_TEST_EXR ? LENSRT_ERROR_IO : LENSRT_ERROR_UNSUPPORTED, lensrt_render_write_exr(r, dir));
    CHECK(count_entries(g_scratch, ".tmp-") == 0, "a failed write_exr over a folder left a temporary file");

    // Successful writes: the file, and nothing else
    scratch_path(path, sizeof path, "psf.png");
    remove(path);
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_write_png(r, path, 5));
    CHECK(file_size(path) > 8, "write_png wrote no %s", path);
    scratch_path(path, sizeof path, "psf.exr");
    remove(path);
    CHECK_RES(ctx, LENSRT_TEST_EXR ? LENSRT_SUCCESS : LENSRT_ERROR_UNSUPPORTED, lensrt_render_write_exr(r, path));
    CHECK(LENSRT_TEST_EXR ? file_size(path) > 0 : !file_exists(path), "write_exr: %s %s", path,
          file_exists(path) ? "exists" : "does not exist");
    if (!LENSRT_TEST_EXR) CHECK_MSG(ctx, "OpenEXR");
    CHECK(count_entries(g_scratch, ".tmp-") == 0, "writes left a temporary file in %s", g_scratch);
done:
    lensrt_render_destroy(r);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    CHECK(h.live == 0 && h.bad_frees == 0, "image file tests: %ld blocks left, %ld foreign frees", h.live, h.bad_frees);
}

/* ------------------------------------------------ 9. run: progress, cancel ----- */

/* run() works in passes of P samples per wavelength (P is internal: 4096 at first, 16384
 * now), calls the progress callback after each pass (and, with several wavelengths,
 * after each wavelength of a pass), and a request to stop takes effect at the end of
 * the pass, so that every wavelength holds the same samples. The test finds P from the
 * first cancelled pass and checks everything else against it. */
typedef struct progress_log {
    int calls, stop_at; /* return non-zero from call stop_at (1-based) on; 0: never */
    double last_fraction;
    int monotonic, sane;
} progress_log;

static void progress_reset(progress_log *p, int stop_at)
{
    memset(p, 0, sizeof *p);
    p->monotonic = p->sane = 1;
    p->stop_at = stop_at;
}

static int on_progress(double fraction, double eta_seconds, void *user_data)
{
    progress_log *p = user_data;
    p->calls++;
    if (!(fraction > p->last_fraction && fraction <= 1.0)) p->monotonic = 0;
    if (!(eta_seconds >= 0 && isfinite(eta_seconds))) p->sane = 0;
    p->last_fraction = fraction;
    return p->stop_at > 0 && p->calls >= p->stop_at;
}

static uint64_t samples_of(lensrt_context ctx, lensrt_render r)
{
    lensrt_render_stats s = LENSRT_RENDER_STATS_INIT;
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_get_stats(r, &s));
    return s.samples_per_wavelength;
}

/* Images of two renders are bit-identical. */
static int same_image(lensrt_context ctx, lensrt_render a, lensrt_render b)
{
    size_t na = 0, nb = 0;
    float *ia = image_of(ctx, a, &na), *ib = image_of(ctx, b, &nb);
    int same = ia && ib && na == nb && memcmp(ia, ib, sizeof(float) * na) == 0;
    free(ia);
    free(ib);
    return same;
}

static void test_run_and_cancel(void)
{
    static const double wl2[2] = {500.0, 600.0};
    hooks h;
    lensrt_context ctx;
    lensrt_lens lens;
    lensrt_render_desc d;
    lensrt_render r = NULL, ref = NULL;
    progress_log p;
    uint64_t pass = 0, n;
    int logs;

    hooks_reset(&h);
    ctx = hooked_context(&h, 0);
    lens = perfect_lens(ctx);
    if (!lens) goto done;
    perfect_desc(lens, &d);

    // Stop at the first call of a long run: CANCELLED, one whole pass kept
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_create(ctx, &d, &r));
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_create(ctx, &d, &ref));
    if (!r || !ref) goto done;
    progress_reset(&p, 1);
    logs = h.n_error_logs;
    CHECK_RES(ctx, LENSRT_ERROR_CANCELLED, lensrt_render_run(r, (uint64_t)1 << 24, on_progress, &p));
    CHECK(h.n_error_logs == logs + 1, "cancel was not logged");
    CHECK_MSG(ctx, "cancel");
    CHECK(p.calls == 1, "progress called %d times after asking to stop", p.calls);
    pass = samples_of(ctx, r);
    CHECK(pass > 0 && pass < ((uint64_t)1 << 24), "cancelled at the first callback: %llu samples kept, expected one pass",
          (unsigned long long)pass);
    printf("test_api: run() passes are %llu samples per wavelength\n", (unsigned long long)pass);
    if (!(pass > 0 && pass < ((uint64_t)1 << 20))) goto done;
    // ... and they are the samples a plain run of one pass adds
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_run(ref, pass, NULL, NULL));
    CHECK(same_image(ctx, r, ref), "the cancelled render's kept pass differs from a run of %llu samples",
          (unsigned long long)pass);

    // Stop at the second call: two more passes kept; the render keeps going afterwards
    progress_reset(&p, 2);
    CHECK_RES(ctx, LENSRT_ERROR_CANCELLED, lensrt_render_run(r, 5 * pass, on_progress, &p));
    n = samples_of(ctx, r);
    CHECK(n == 3 * pass, "cancelled after 1 + 2 passes: %llu samples, expected %llu", (unsigned long long)n,
          (unsigned long long)(3 * pass));
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_run(ref, 2 * pass, NULL, NULL));
    CHECK(same_image(ctx, r, ref), "cancelled runs differ from uncancelled runs of the same passes");
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_run(r, 10, NULL, NULL));
    n = samples_of(ctx, r);
    CHECK(n == 3 * pass + 10, "run after a cancel: %llu samples, expected %llu", (unsigned long long)n,
          (unsigned long long)(3 * pass + 10));
    lensrt_render_destroy(r);
    r = NULL;

    // A full run: progress after each pass, fractions rising to 1
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_create(ctx, &d, &r));
    if (!r) goto done;
    progress_reset(&p, 0);
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_run(r, 2 * pass + 100, on_progress, &p));
    CHECK(p.calls == 3, "progress: %d calls for 2 passes and a part (one wavelength), expected 3", p.calls);
    CHECK(p.monotonic && p.sane && p.last_fraction == 1.0, "progress fractions not rising to 1 (last %g) or bad eta",
          p.last_fraction);
    CHECK(samples_of(ctx, r) == 2 * pass + 100, "full run: wrong sample count");
    lensrt_render_destroy(r);
    lensrt_render_destroy(ref);
    r = ref = NULL;

    // Two wavelengths: a stop asked for in the middle of a pass takes effect at its end
    d.wavelengths_nm = wl2;
    d.n_wavelengths = 2;
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_create(ctx, &d, &r));
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_create(ctx, &d, &ref));
    if (!r || !ref) goto done;
    progress_reset(&p, 1);
    CHECK_RES(ctx, LENSRT_ERROR_CANCELLED, lensrt_render_run(r, 4 * pass, on_progress, &p));
    n = samples_of(ctx, r);
    CHECK(n == pass, "two wavelengths, stop at the first callback: %llu samples, expected one pass (%llu)",
          (unsigned long long)n, (unsigned long long)pass);
    CHECK(p.monotonic && p.sane, "two wavelengths: progress fractions not rising or bad eta");
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_render_run(ref, pass, NULL, NULL));
    CHECK(same_image(ctx, r, ref), "two wavelengths: the cancelled pass differs from a run of one pass");
    {
        size_t k, na = 0;
        float *img = image_of(ctx, r, &na), peak = 0;
        for (k = 0; img && k < na; k++)
            if (!(img[k] <= peak)) peak = img[k];
        CHECK(img && isfinite(peak) && peak > 0, "perfect lens: peak %g", (double)peak);
        free(img);
    }
done:
    lensrt_render_destroy(r);
    lensrt_render_destroy(ref);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    CHECK(h.live == 0 && h.bad_frees == 0, "run tests: %ld blocks left, %ld foreign frees", h.live, h.bad_frees);
}

/* ------------------------------------------------------------------ main ----- */

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: %s LENS_TABLE SCRATCH_DIR\n", argv[0]);
        return 2;
    }
    snprintf(g_scratch, sizeof g_scratch, "%s", argv[2]);
    if (mkdir(g_scratch, 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "test_api: cannot create %s: %s\n", g_scratch, strerror(errno));
        return 2;
    }
    g_table = v3_table(argv[1]);
    printf("test_api: lensrt %d.%d.%d, EXR %s, table %s\n", LENSRT_VERSION_MAJOR, LENSRT_VERSION_MINOR,
           LENSRT_VERSION_PATCH, LENSRT_TEST_EXR ? "on" : "off", g_table);

    test_result_strings();
    test_context();
    test_null_arguments();
    test_messages();
    test_lens_tables();
    test_table_trust();
    test_failing_allocator();
    test_threads_and_files();
    test_image_files();
    test_run_and_cancel();

    printf("test_api: %d checks, %d failed\n", g_checks, g_failures);
    return g_failures ? 1 : 0;
}
