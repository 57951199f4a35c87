/* test_robust: no silent NaN or inf (issue 14, defects 2 and 7).
 *
 *   1. The table reader refuses what would overflow or misread: a coefficient of 1e308,
 *      an input transform that no longer maps the declared domain onto [-1, 1], an empty
 *      (zero) aperture range, domains that differ between P_o and P_s, coefficient sums
 *      above LENSRT_MAX_COEFFICIENT_SUM / LENSRT_MAX_TRANSMITTANCE_SUM; each message names
 *      the file, the line, the key and the value. Tables are edited in memory from the
 *      committed lens0001.table (argv[1]).
 *   2. Light intensities above LENSRT_MAX_INTENSITY are refused; at the bound the image is
 *      the intensity times the image at intensity 1.
 *   3. lensrt_render_splat_points with a point far outside the aperture: the point counts
 *      as a sample of zero contribution (same sums as without it).
 *   4. lensrt_render_image / _rgb / write_png refuse an image that does not fit in float
 *      (a thin lens with a huge stop at full intensity), naming pixel and wavelength.
 *   5. lensrt_lens_image_point refuses NaN and negative distances, NaN fields and
 *      wavelengths outside the fitted range.
 *   6. run(N1); run(N2) gives the sums of run(N1 + N2) bit for bit for any N1 (lensrt.h),
 *      also across a pass boundary (16384): N1 = 1 and N2 = 2047 (issue 39, item 4), a
 *      split inside a block after a whole pass, random splits into up to 6 runs, with the
 *      image read and the sums saved between runs (reading changes nothing).
 * Usage: test_robust LENS_TABLE SCRATCH_DIR */
#include "lensrt.h"

#include "check.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

/* A copy of text with the first `old` on line `line` (1-based) replaced by `new_text`
 * (malloc'd; NULL when the line does not hold `old`). */
static char *edit_line(const char *text, size_t size, int line, const char *old, const char *new_text, size_t *out_size)
{
    const char *p = text, *end = text + size, *eol, *hit;
    size_t lo = strlen(old), ln = strlen(new_text);
    char *out;
    int i;
    for (i = 1; i < line && p < end; i++) {
        eol = memchr(p, '\n', (size_t)(end - p));
        if (!eol) return NULL;
        p = eol + 1;
    }
    eol = memchr(p, '\n', (size_t)(end - p));
    if (!eol) eol = end;
    for (hit = p; hit + lo <= eol && memcmp(hit, old, lo) != 0; hit++) continue;
    if (hit + lo > eol) return NULL;
    out = malloc(size - lo + ln + 1);
    if (!out) return NULL;
    memcpy(out, text, (size_t)(hit - text));
    memcpy(out + (hit - text), new_text, ln);
    memcpy(out + (hit - text) + ln, hit + lo, (size_t)(end - hit - (long)lo));
    *out_size = size - lo + ln;
    out[*out_size] = '\0';
    return out;
}

/* The 1-based number of the `nth` (1-based) line that starts with `prefix`; 0 if none. */
static int line_starting(const char *text, size_t size, const char *prefix, int nth)
{
    const char *p = text, *end = text + size, *eol;
    size_t lp = strlen(prefix);
    int line = 1;
    while (p < end) {
        eol = memchr(p, '\n', (size_t)(end - p));
        if (!eol) eol = end;
        if ((size_t)(eol - p) >= lp && memcmp(p, prefix, lp) == 0 && --nth == 0) return line;
        p = eol + 1;
        line++;
    }
    return 0;
}

/* The last space-separated token of line `line` (1-based) into out (at most n bytes);
 * "" when there is no such line. */
static void last_token(const char *text, size_t size, int line, char *out, size_t n)
{
    const char *p = text, *end = text + size, *eol, *sp;
    int i;
    out[0] = '\0';
    for (i = 1; i < line && p < end; i++) {
        eol = memchr(p, '\n', (size_t)(end - p));
        if (!eol) return;
        p = eol + 1;
    }
    eol = memchr(p, '\n', (size_t)(end - p));
    if (!eol) eol = end;
    for (sp = eol; sp > p && sp[-1] != ' '; sp--) continue;
    if ((size_t)(eol - sp) + 1 > n) return;
    memcpy(out, sp, (size_t)(eol - sp));
    out[eol - sp] = '\0';
}

/* Load text edited at one line and expect a parse error whose message holds each of the
 * NULL-terminated needles. */
static void expect_refused(lensrt_context ctx, const char *text, size_t size, int line, const char *old,
                           const char *new_text, const char *what, ...)
{
    size_t n;
    char *t = edit_line(text, size, line, old, new_text, &n);
    lensrt_lens lens = NULL;
    va_list args;
    const char *needle;
    CHECK(t != NULL, "%s: line %d holds '%s'", what, line, old);
    if (!t) return;
    CHECK_RES(ctx, LENSRT_ERROR_PARSE, load_stamped(ctx, t, n, "lens0001.table", &lens));
    CHECK(lens == NULL, "%s: no lens handed out", what);
    va_start(args, what);
    while ((needle = va_arg(args, const char *)) != NULL)
        CHECK(strstr(lensrt_context_last_error(ctx), needle) != NULL, "%s: message '%s' lacks '%s'", what,
              lensrt_context_last_error(ctx), needle);
    va_end(args);
    lensrt_lens_destroy(ctx, lens);
    free(t);
}

/* Load text edited at one line and expect success. */
static void expect_loaded(lensrt_context ctx, const char *text, size_t size, int line, const char *old,
                          const char *new_text, const char *what)
{
    size_t n;
    char *t = edit_line(text, size, line, old, new_text, &n);
    lensrt_lens lens = NULL;
    CHECK(t != NULL, "%s: line %d holds '%s'", what, line, old);
    if (!t) return;
    CHECK_OK(ctx, load_stamped(ctx, t, n, "lens0001.table", &lens));
    lensrt_lens_destroy(ctx, lens);
    free(t);
}

static void test_table(lensrt_context ctx, const char *text, size_t size)
{
    // Lines of the committed table, found by their keys (a refit moves them): P_o's
    // x_a and lambda, output x_o and tau_o and each first term, P_s's x_a
    const int xa = line_starting(text, size, "input x_a ", 1);
    const int lambda = line_starting(text, size, "input lambda ", 1);
    const int xo = line_starting(text, size, "output x_o ", 1);
    const int tau = line_starting(text, size, "output tau_o ", 1);
    const int xa_s = line_starting(text, size, "input x_a ", 2);
    char x0[64], t0[64], at_xo[64], at_tau[64], at_xa[64], at_lambda[64];
    CHECK(xa && lambda && xo && tau && xa_s, "the committed table's keys: x_a %d, lambda %d, x_o %d, tau_o %d, P_s x_a %d",
          xa, lambda, xo, tau, xa_s);
    last_token(text, size, xo + 1, x0, sizeof x0);
    last_token(text, size, tau + 1, t0, sizeof t0);
    snprintf(at_xo, sizeof at_xo, "lens0001.table:%d:", xo);
    snprintf(at_tau, sizeof at_tau, "lens0001.table:%d:", tau);
    snprintf(at_xa, sizeof at_xa, "lens0001.table:%d:", xa);
    snprintf(at_lambda, sizeof at_lambda, "lens0001.table:%d:", lambda);
    expect_loaded(ctx, text, size, xo + 1, x0, x0, "the table as committed");
    expect_refused(ctx, text, size, xo + 1, x0, "1e308", "a coefficient of 1e308", at_xo, "output x_o", "1e+308",
                   (const char *)NULL);
    // The bound is where lensrt.h says: 5e5 more in x_o loads, 2e6 does not
    expect_loaded(ctx, text, size, xo + 1, x0, "5e5", "x_o's sum at half the bound");
    expect_refused(ctx, text, size, xo + 1, x0, "2e6", "x_o's sum above LENSRT_MAX_COEFFICIENT_SUM", at_xo, "x_o",
                   (const char *)NULL);
    expect_refused(ctx, text, size, tau + 1, t0, "200", "tau_o's sum above LENSRT_MAX_TRANSMITTANCE_SUM", at_tau,
                   "output tau_o", (const char *)NULL);
    // A transform scale changed (x_a over +-14.5 mm normalised by 1.45: [-10, 10])
    expect_refused(ctx, text, size, xa, "affine 0 14.527703294396176", "affine 0 1.4527703294396176",
                   "a changed input transform", at_xa, "input x_a", "1.4527703294396176", "not [-1, 1]",
                   (const char *)NULL);
    expect_refused(ctx, text, size, lambda, "inverse_square", "affine", "lambda's transform changed to affine",
                   at_lambda, "input lambda", (const char *)NULL);
    // A zero aperture range
    expect_refused(ctx, text, size, xa, "-14.527703294396176 14.527703294396176", "0 0", "a zero aperture range",
                   at_xa, "input x_a", "is empty", (const char *)NULL);
    // P_s's stop domain no longer P_o's (each consistent with its own transform)
    expect_refused(ctx, text, size, xa_s, "-14.527703294396176 14.527703294396176 affine 0 14.527703294396176",
                   "-10 10 affine 0 10", "P_s's stop domain differs from P_o's", "lens0001.table", "x_a",
                   "differs", (const char *)NULL);
}

/* A copy of text with lines a and b (1-based, a < b) exchanged (malloc'd; NULL if out of
 * range). */
static char *swap_lines(const char *text, size_t size, int a, int b)
{
    const char *start[2] = {NULL, NULL}, *stop[2] = {NULL, NULL}, *p = text, *end = text + size;
    char *out, *o;
    int line = 1;
    while (p < end) {
        const char *eol = memchr(p, '\n', (size_t)(end - p));
        if (!eol) break;
        if (line == a || line == b) {
            start[line == b] = p;
            stop[line == b] = eol;
        }
        p = eol + 1;
        line++;
    }
    if (!start[0] || !start[1] || !(out = malloc(size + 1))) return NULL;
    o = out;
    memcpy(o, text, (size_t)(start[0] - text));
    o += start[0] - text;
    memcpy(o, start[1], (size_t)(stop[1] - start[1]));
    o += stop[1] - start[1];
    memcpy(o, stop[0], (size_t)(start[1] - stop[0]));
    o += start[1] - stop[0];
    memcpy(o, start[0], (size_t)(stop[0] - start[0]));
    o += stop[0] - start[0];
    memcpy(o, stop[1], (size_t)(end - stop[1]));
    o += end - stop[1];
    *o = '\0';
    return out;
}

/* An edited text loaded with its checksum made again but its probe lines as they were
 * (what a hand edit behind a valid checksum looks like): refused with each needle; and
 * with the probes made again too (stamp_table): loaded, so the probes are what refuse it
 * (issue 39). */
static void expect_probes_refuse(lensrt_context ctx, const char *t, const char *what, ...)
{
    size_t n;
    char *c = stamp_crc(t, strlen(t), &n);
    lensrt_lens lens = NULL;
    va_list args;
    const char *needle;
    CHECK(c != NULL, "%s: out of memory", what);
    if (!c) return;
    CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_lens_load_text(ctx, c, n, "lens0001.table", &lens));
    lensrt_lens_destroy(ctx, lens);
    lens = NULL;
    va_start(args, what);
    while ((needle = va_arg(args, const char *)) != NULL)
        CHECK(strstr(lensrt_context_last_error(ctx), needle) != NULL, "%s: message '%s' lacks '%s'", what,
              lensrt_context_last_error(ctx), needle);
    va_end(args);
    free(c);
    CHECK_OK(ctx, load_stamped(ctx, t, strlen(t), "lens0001.table", &lens));
    lensrt_lens_destroy(ctx, lens);
}

/* Semantic corruption behind a valid checksum (issue 39, item 3): swapped or edited
 * coefficients refused by the probe lines; lens and trust values out of their ranges,
 * hex floats, inf and nan, control bytes and a ghost label that does not number its
 * surfaces refused naming key and value. */
static void test_semantic(lensrt_context ctx, const char *text, size_t size)
{
    static const struct {
        const char *key, *value, *needle;
    } ranges[] = {
        {"lens focal_length_mm ", "1e308", "lens focal_length_mm 1e308 is out of range"},
        {"lens focal_length_mm ", "0", "lens focal_length_mm 0 is out of range"},
        {"lens stop_radius_max_mm ", "1e-300", "lens stop_radius_max_mm 1e-300 is out of range"},
        {"lens stop_radius_f1_mm ", "2e6", "lens stop_radius_f1_mm 2e6 is out of range"},
        {"lens housing_first_mm ", "-54", "lens housing_first_mm -54 is out of range"},
        {"lens housing_last_mm ", "0", "lens housing_last_mm 0 is out of range"},
        {"lens sensor_defocus_mm ", "1e30", "lens sensor_defocus_mm 1e30 is out of range"},
        {"lens front_focal_distance_mm ", "-2e6", "lens front_focal_distance_mm -2e6 is out of range"},
        {"lens squeeze ", "1e6", "lens squeeze 1e6 is out of range"},
        {"lens squeeze ", "0.01", "lens squeeze 0.01 is out of range"},
        {"trust psf_vs_exact ", "1e308", "trust psf_vs_exact 1e308 is out of range"},
        {"trust psf_vs_exact ", "1e-300", "trust psf_vs_exact 1e-300 is out of range"},
        {"trust psf_target ", "0", "trust psf_target 0 is out of range"},
        {"trust psf_target ", "2", "trust psf_target 2 is out of range"},
        {"lens focal_length_mm ", "0x1p3", "lens focal_length_mm '0x1p3' is not a finite number"},
        {"lens squeeze ", "inf", "lens squeeze 'inf' is not a finite number"},
        {"trust psf_target ", "nan", "trust psf_target 'nan' is not a finite number"},
    };
    const int xo = line_starting(text, size, "output x_o ", 1);
    const int yo = line_starting(text, size, "output y_o ", 1);
    const int probe = line_starting(text, size, "probe ", 1);
    char a[64], b[64], *t, *u;
    size_t n, m;
    int i;
    CHECK(xo && yo && probe, "the committed table's keys: x_o %d, y_o %d, probe %d", xo, yo, probe);
    // Two term lines swapped between outputs x_o and y_o (each output then has a term
    // of the other): the probes of P_o refuse it, naming system, output and values
    t = swap_lines(text, size, xo + 1, yo + 1);
    CHECK(t != NULL, "swap x_o's and y_o's first terms");
    if (t) expect_probes_refuse(ctx, t, "x_o's and y_o's first terms swapped", "system P_o: output x_o: probe 1 of 6",
                                "the polynomials give", "the probe line says", "behind a valid checksum",
                                (const char *)NULL);
    free(t);
    // Two coefficients of x_o exchanged (the exponents stay)
    last_token(text, size, xo + 1, a, sizeof a);
    last_token(text, size, xo + 2, b, sizeof b);
    t = edit_line(text, size, xo + 1, a, b, &n);
    u = t ? edit_line(t, n, xo + 2, b, a, &m) : NULL;
    CHECK(u != NULL, "exchange x_o's first two coefficients");
    if (u) expect_probes_refuse(ctx, u, "x_o's first two coefficients exchanged", "system P_o: output x_o",
                                (const char *)NULL);
    free(t);
    free(u);
    // A probe output edited (the polynomials kept): refused the same way
    last_token(text, size, probe, a, sizeof a);
    t = edit_line(text, size, probe, a, "1", &n);
    if (t) {
        u = stamp_crc(t, n, &m);
        if (u) {
            lensrt_lens lens = NULL;
            CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_lens_load_text(ctx, u, m, "lens0001.table", &lens));
            CHECK_MSG(ctx, "output phi_o: probe 1 of 6");
            lensrt_lens_destroy(ctx, lens);
        }
        free(u);
    }
    free(t);
    // Each key out of its range, hex floats, inf and nan: key and value named
    for (i = 0; i < (int)(sizeof ranges / sizeof ranges[0]); i++) {
        const int line = line_starting(text, size, ranges[i].key, 1);
        last_token(text, size, line, a, sizeof a);
        expect_refused(ctx, text, size, line, a, ranges[i].value, ranges[i].needle, ranges[i].needle,
                       (const char *)NULL);
    }
    // A coefficient as a hex float or inf (strtod reads both)
    last_token(text, size, xo + 1, a, sizeof a);
    expect_refused(ctx, text, size, xo + 1, a, "0x1p3", "a hex float coefficient", "coefficient '0x1p3' is not a finite number",
                   (const char *)NULL);
    expect_refused(ctx, text, size, xo + 1, a, "infinity", "an infinite coefficient", "coefficient 'infinity'",
                   (const char *)NULL);
    // A line of NUL bytes inside x_o's terms, and a NUL inside a term line
    {
        char nul[] = "0 0 0 1 0 0 1\n";
        size_t k;
        t = malloc(size + sizeof nul);
        if (t) {
            const int at = xo + 2;
            char where[64];
            const char *p = text;
            for (i = 1; i < at; i++) p = (const char *)memchr(p, '\n', (size_t)(text + size - p)) + 1;
            for (k = 0; k < sizeof nul - 2; k++) nul[k] = '\0';
            memcpy(t, text, (size_t)(p - text));
            memcpy(t + (p - text), nul, sizeof nul - 1);
            memcpy(t + (p - text) + sizeof nul - 1, p, size - (size_t)(p - text));
            u = stamp_table(t, size + sizeof nul - 1, &m);
            snprintf(where, sizeof where, "lens0001.table:%d: control byte 0x00 at column 1", at);
            if (u) {
                lensrt_lens lens = NULL;
                CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_lens_load_text(ctx, u, m, "lens0001.table", &lens));
                CHECK_MSG(ctx, where);
                lensrt_lens_destroy(ctx, lens);
            }
            free(u);
            free(t);
        }
    }
    // Ghost lines whose label does not number ghost first and second: refused; the
    // label of a ghost behind an inserted stop surface (one less) loads
    {
        const int trust_end = line_starting(text, size, "trust psf_target ", 1);
        static const char *const labels[][2] = {
            {"4-8-9", "ghost label '4-8-9' does not number ghost first 4 and ghost second 8"},
            {"4-9", "ghost label '4-9'"},
            {"3-8", "ghost label '3-8'"},
            {"04-8", "ghost label '04-8'"},
            {"4-7", NULL},
            {"3-7", NULL},
        };
        last_token(text, size, trust_end, a, sizeof a);
        for (i = 0; i < (int)(sizeof labels / sizeof labels[0]); i++) {
            char block[160];
            snprintf(block, sizeof block, "%s\nghost first 4\nghost second 8\nghost label %s\nghost side P_s", a,
                     labels[i][0]);
            if (labels[i][1])
                expect_refused(ctx, text, size, trust_end, a, block, labels[i][1], labels[i][1], (const char *)NULL);
            else
                expect_loaded(ctx, text, size, trust_end, a, block, "a label one less than first and second");
        }
    }
}

static lensrt_render fitted_render(lensrt_context ctx, lensrt_lens lens, double intensity, int estimator)
{
    static const double wl[1] = {550.0};
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    lensrt_light light = LENSRT_LIGHT_INIT;
    lensrt_render r = NULL;
    double c[2] = {0, 0};
    lensrt_lens_image_point(ctx, lens, &light, 550.0, 0.0, c);
    light.intensity = intensity;
    d.lens = lens;
    d.sensor.width = 8;
    d.sensor.height = 8;
    d.sensor.width_mm = 0.02;
    d.sensor.center_x_mm = c[0];
    d.sensor.center_y_mm = c[1];
    d.aperture.f_number = 8.0;
    d.lights = &light;
    d.n_lights = 1;
    d.wavelengths_nm = wl;
    d.n_wavelengths = 1;
    d.estimator = estimator;
    d.seed = 5;
    lensrt_render_create(ctx, &d, &r);
    return r;
}

static void test_intensity(lensrt_context ctx, lensrt_lens lens)
{
    float one[64], big[64];
    lensrt_render r;
    int p, bad = 0;
    // Above the bound: refused at create, with the bound in the message
    CHECK(fitted_render(ctx, lens, 1e31, LENSRT_ESTIMATOR_PAPER) == NULL, "intensity 1e31 refused");
    CHECK_MSG(ctx, "LENSRT_MAX_INTENSITY");
    CHECK(fitted_render(ctx, lens, 1e35, LENSRT_ESTIMATOR_UNBIASED) == NULL, "intensity 1e35 refused");
    // At the bound: the image scales with the intensity (float rounding of sqrt(I) in the
    // samples' amplitudes and the kernel's float sums: 1e-5 relative is 100 float ulps)
    r = fitted_render(ctx, lens, 1.0, LENSRT_ESTIMATOR_PAPER);
    CHECK(r != NULL, "intensity 1: %s", lensrt_context_last_error(ctx));
    if (!r) return;
    CHECK_OK(ctx, lensrt_render_run(r, 1024, NULL, NULL));
    CHECK_OK(ctx, lensrt_render_image(r, one, 64));
    lensrt_render_destroy(r);
    r = fitted_render(ctx, lens, LENSRT_MAX_INTENSITY, LENSRT_ESTIMATOR_PAPER);
    CHECK(r != NULL, "intensity at the bound: %s", lensrt_context_last_error(ctx));
    if (!r) return;
    CHECK_OK(ctx, lensrt_render_run(r, 1024, NULL, NULL));
    CHECK_OK(ctx, lensrt_render_image(r, big, 64));
    for (p = 0; p < 64; p++)
        if (!(fabs(big[p] - 1e30 * (double)one[p]) <= 1e-5 * 1e30 * fabs((double)one[p]) + 1e-30)) bad++;
    CHECK(bad == 0, "intensity 1e30: %d of 64 pixels are not 1e30 x the image at 1 (pixel 0: %g vs %g)", bad,
          (double)big[0], (double)one[0]);
    lensrt_render_destroy(r);
}

static void test_splat_far(lensrt_context ctx, lensrt_lens lens)
{
    enum { N = 512 };
    double xy[2 * (N + 2)];
    float a[64], b[64];
    lensrt_render r1 = fitted_render(ctx, lens, 1.0, LENSRT_ESTIMATOR_PAPER);
    lensrt_render r2 = fitted_render(ctx, lens, 1.0, LENSRT_ESTIMATOR_PAPER);
    lensrt_render_stats st = LENSRT_RENDER_STATS_INIT;
    int i, bad = 0;
    CHECK(r1 && r2, "renders for splat_points: %s", lensrt_context_last_error(ctx));
    if (r1 && r2 && lensrt_render_get_stats(r1, &st) == LENSRT_SUCCESS) {
        // N points on a spiral inside the stop, then the same with one far outside the
        // aperture (1e6 mm) and one just outside it (1.5 stop radii) in the middle
        for (i = 0; i < N; i++) {
            double rad = 0.95 * st.stop_radius_mm * sqrt((i + 0.5) / N), t = 2.39996323 * i;
            xy[2 * i] = rad * cos(t);
            xy[2 * i + 1] = rad * sin(t);
        }
        CHECK_OK(ctx, lensrt_render_splat_points(r1, 0, xy, N));
        memmove(xy + 2 * (N / 2 + 2), xy + 2 * (N / 2), sizeof(double) * 2 * (N - N / 2));
        xy[N] = 1e6;
        xy[N + 1] = -1e6;
        xy[N + 2] = 1.5 * st.stop_radius_mm;
        xy[N + 3] = 0.0;
        CHECK_OK(ctx, lensrt_render_splat_points(r2, 0, xy, N + 2));
        CHECK_OK(ctx, lensrt_render_image(r1, a, 64));
        CHECK_OK(ctx, lensrt_render_image(r2, b, 64));
        // The outside points add zero to the sums, but count as samples: the image is
        // scaled by (N / (N + 2))^2 (the paper estimator's 1/N^2); float rounding: 1e-5
        for (i = 0; i < 64; i++) {
            double want = (double)a[i] * ((double)N / (N + 2)) * ((double)N / (N + 2));
            if (!(fabs((double)b[i] - want) <= 1e-5 * fabs(want) + 1e-30)) bad++;
        }
        CHECK(bad == 0, "splat_points with a far point: %d of 64 pixels differ (pixel 0: %g, expected %g)", bad,
              (double)b[0], (double)a[0] * ((double)N / (N + 2)) * ((double)N / (N + 2)));
        // Points that are not numbers are refused
        xy[0] = NAN;
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_splat_points(r2, 0, xy, 1));
        CHECK_MSG(ctx, "not finite");
    }
    lensrt_render_destroy(r1);
    lensrt_render_destroy(r2);
}

static void test_result_check(lensrt_context ctx, const char *scratch)
{
    // A thin lens (f = 50 mm) with a 2 m stop at full intensity: the focus's irradiance
    // is about intensity x (pi R^2 / (lambda z))^2 = 1e30 x 1e22, beyond float
    static const double wl[1] = {550.0};
    lensrt_analytic_lens m = LENSRT_ANALYTIC_LENS_INIT;
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    lensrt_light light = LENSRT_LIGHT_INIT;
    lensrt_lens lens = NULL;
    lensrt_render r = NULL;
    float img[16], rgb[48];
    char png[1024];
    struct stat sb;
    m.focal_length_mm = 50.0;
    m.sensor_distance_mm = 50.0;
    CHECK_OK(ctx, lensrt_lens_create_analytic(ctx, &m, &lens));
    light.intensity = LENSRT_MAX_INTENSITY;
    d.lens = lens;
    d.sensor.width = 4;
    d.sensor.height = 4;
    d.sensor.width_mm = 1e-6;
    d.aperture.radius_mm = 1000.0;
    d.lights = &light;
    d.n_lights = 1;
    d.wavelengths_nm = wl;
    d.n_wavelengths = 1;
    CHECK_OK(ctx, lensrt_render_create(ctx, &d, &r));
    if (!r) {
        lensrt_lens_destroy(ctx, lens);
        return;
    }
    CHECK_OK(ctx, lensrt_render_run(r, 256, NULL, NULL));
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_render_image(r, img, 16));
    CHECK_MSG(ctx, "pixel (0, 0) at 550 nm");
    CHECK_MSG(ctx, "not a finite float");
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_render_rgb(r, rgb, 48));
    snprintf(png, sizeof png, "%s/overflow.png", scratch);
    remove(png);
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_render_write_png(r, png, 0));
    CHECK(stat(png, &sb) != 0, "no PNG written for an image that is not finite");
    lensrt_render_destroy(r);
    lensrt_lens_destroy(ctx, lens);
}

static void test_image_point(lensrt_context ctx, lensrt_lens lens)
{
    lensrt_light light = LENSRT_LIGHT_INIT;
    double xy[2];
    CHECK_OK(ctx, lensrt_lens_image_point(ctx, lens, &light, 550.0, 0.0, xy));
    light.distance_mm = NAN;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_image_point(ctx, lens, &light, 550.0, 0.0, xy));
    CHECK_MSG(ctx, "distance nan mm");
    light.distance_mm = -1000.0;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_image_point(ctx, lens, &light, 550.0, 0.0, xy));
    CHECK_MSG(ctx, "distance -1000 mm");
    light.distance_mm = 0.0;
    light.field_x_deg = NAN;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_image_point(ctx, lens, &light, 550.0, 0.0, xy));
    light.field_x_deg = 0.0;
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_lens_image_point(ctx, lens, &light, 300.0, 0.0, xy));
    CHECK_MSG(ctx, "300 nm is outside the fitted range [380, 780]");
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_lens_image_point(ctx, lens, &light, 900.0, 0.0, xy));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_image_point(ctx, lens, &light, NAN, 0.0, xy));
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_lens_image_point(ctx, lens, &light, 550.0, 50.0, xy));
    // Closer than the fitted range (1 / u_O's upper end, about 1 m for lens 0001)
    light.distance_mm = 100.0;
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_lens_image_point(ctx, lens, &light, 550.0, 0.0, xy));
    CHECK_MSG(ctx, "closer than the fitted");
}

/* The last `tail` bytes of a file (malloc'd), NULL when shorter. */
static unsigned char *file_tail(const char *path, size_t tail, size_t *size)
{
    size_t n;
    char *text = read_text(path, &n);
    unsigned char *out = NULL;
    *size = n;
    if (text && n >= tail && (out = malloc(tail + 1)) != NULL) memcpy(out, text + (n - tail), tail);
    free(text);
    return out;
}

/* Sums of run(n1); run(n2) against run(n1 + n2), bit for bit: both renders are saved
 * and the files' last bytes compared, which hold the phasor sums (and the sums of
 * squares) as raw doubles, 64 pixels x 16 (+ 8) bytes. The header before them holds the
 * wall time, which differs; images would hide a 1-ulp difference in float. */
static void split_list(lensrt_context ctx, lensrt_lens lens, const char *scratch, int estimator, const uint64_t *parts,
                       int n_parts, int peek);

static void split_runs(lensrt_context ctx, lensrt_lens lens, const char *scratch, int estimator, uint64_t n1,
                       uint64_t n2)
{
    const uint64_t parts[2] = {n1, n2};
    split_list(ctx, lens, scratch, estimator, parts, 2, 0);
}

/* run(parts[0]); run(parts[1]); ... against one run of their sum, bit for bit; with peek
 * the image is read and the sums saved after every run but the last. */
static void split_list(lensrt_context ctx, lensrt_lens lens, const char *scratch, int estimator, const uint64_t *parts,
                       int n_parts, int peek)
{
    const size_t payload = 64 * (estimator == LENSRT_ESTIMATOR_UNBIASED ? 24 : 16);
    lensrt_render ra = fitted_render(ctx, lens, 1.0, estimator), rb = fitted_render(ctx, lens, 1.0, estimator);
    char pa[1024], pb[1024];
    unsigned char *da = NULL, *db = NULL;
    size_t na = 0, nb = 0, i;
    int differ = 0;
    CHECK(ra && rb, "renders for run(): %s", lensrt_context_last_error(ctx));
    snprintf(pa, sizeof pa, "%s/split-a.phasors", scratch);
    snprintf(pb, sizeof pb, "%s/split-b.phasors", scratch);
    if (ra && rb) {
        char said[256];
        size_t at = 0;
        uint64_t total = 0;
        float img[64];
        int k;
        for (k = 0; k < n_parts; k++) {
            CHECK_OK(ctx, lensrt_render_run(ra, parts[k], NULL, NULL));
            if (peek && k + 1 < n_parts) {
                CHECK_OK(ctx, lensrt_render_image(ra, img, 64));
                CHECK_OK(ctx, lensrt_render_save(ra, pa));
            }
            total += parts[k];
            at += (size_t)snprintf(said + at, sizeof said - at, "%srun(%llu)", k ? "; " : "",
                                   (unsigned long long)parts[k]);
            if (at >= sizeof said) at = sizeof said - 1;
        }
        CHECK_OK(ctx, lensrt_render_run(rb, total, NULL, NULL));
        CHECK_OK(ctx, lensrt_render_save(ra, pa));
        CHECK_OK(ctx, lensrt_render_save(rb, pb));
        da = file_tail(pa, payload, &na);
        db = file_tail(pb, payload, &nb);
        CHECK(da && db && na == nb, "phasor files of %zu and %zu bytes", na, nb);
        for (i = 0; da && db && i < payload; i += 8) differ += memcmp(da + i, db + i, 8) != 0;
        CHECK(differ == 0, "estimator %d: %s differs from run(%llu) in %d of %zu sums", estimator, said,
              (unsigned long long)total, differ, payload / 8);
        {
            // The sample counts agree too (the image's normalisation)
            lensrt_render_stats sa = LENSRT_RENDER_STATS_INIT, sb = LENSRT_RENDER_STATS_INIT;
            lensrt_render_get_stats(ra, &sa);
            lensrt_render_get_stats(rb, &sb);
            CHECK(sa.samples_per_wavelength == sb.samples_per_wavelength && sa.splats == sb.splats,
                  "%s: %llu samples and %llu splats against %llu and %llu", said,
                  (unsigned long long)sa.samples_per_wavelength, (unsigned long long)sa.splats,
                  (unsigned long long)sb.samples_per_wavelength, (unsigned long long)sb.splats);
        }
    }
    free(da);
    free(db);
    lensrt_render_destroy(ra);
    lensrt_render_destroy(rb);
}

int main(int argc, char **argv)
{
    lensrt_context ctx = NULL;
    lensrt_context_init cd = LENSRT_CONTEXT_INIT;
    lensrt_lens lens = NULL;
    size_t size;
    char *text;
    if (argc != 3) {
        fprintf(stderr, "usage: test_robust LENS_TABLE SCRATCH_DIR\n");
        return 2;
    }
    mkdir(argv[2], 0777);
    text = read_text(argv[1], &size);
    CHECK(text != NULL, "read %s", argv[1]);
    cd.threads = 2;
    CHECK_OK(NULL, lensrt_context_create(&cd, &ctx));
    if (!text || !ctx) return 1;
    test_table(ctx, text, size);
    test_semantic(ctx, text, size);
    CHECK_OK(ctx, load_stamped(ctx, text, size, "lens0001.table", &lens));
    if (lens) {
        test_intensity(ctx, lens);
        test_splat_far(ctx, lens);
        test_image_point(ctx, lens);
        split_runs(ctx, lens, argv[2], LENSRT_ESTIMATOR_PAPER, 1024, 1024);
        split_runs(ctx, lens, argv[2], LENSRT_ESTIMATOR_PAPER, 256, 16384);  /* the second run crosses a pass */
        split_runs(ctx, lens, argv[2], LENSRT_ESTIMATOR_UNBIASED, 768, 512);
        split_runs(ctx, lens, argv[2], LENSRT_ESTIMATOR_PAPER, 16384, 300);
        // Any N (issue 39, item 4): inside a block, after a partial block, across a pass
        split_runs(ctx, lens, argv[2], LENSRT_ESTIMATOR_PAPER, 1, 2047);
        split_runs(ctx, lens, argv[2], LENSRT_ESTIMATOR_UNBIASED, 1, 2047);
        split_runs(ctx, lens, argv[2], LENSRT_ESTIMATOR_PAPER, 100, 100);
        split_runs(ctx, lens, argv[2], LENSRT_ESTIMATOR_PAPER, 16500, 300);
        {
            // Random splits (a fixed LCG: the same cases every time), the image read and
            // the sums saved between runs
            uint64_t parts[6], state = 39;
            int c, k;
            for (c = 0; c < 6; c++) {
                const int n = 2 + c % 5;
                for (k = 0; k < n; k++) {
                    state = state * 6364136223846793005ull + 1442695040888963407ull;
                    parts[k] = 1 + (state >> 33) % (c < 3 ? 700 : 17000);
                }
                split_list(ctx, lens, argv[2], c % 2 ? LENSRT_ESTIMATOR_UNBIASED : LENSRT_ESTIMATOR_PAPER, parts, n,
                           1);
            }
        }
    }
    test_result_check(ctx, argv[2]);
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    free(text);
    printf("test_robust: %d checks, %d failures\n", g_checks, g_failures);
    return g_failures != 0;
}
