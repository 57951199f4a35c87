/* test_ghost: ghost tables (issue 13; the contract is /work/notes/ghost-table.md and
 * fit/lensfit/codegen/table.py): a ghost (i, j) is a lens of its own whose table carries
 * `ghost` lines and a third system P_clip (the ghost side's inputs, outputs in pairs).
 * Tables are made in memory from the committed lens0001.table (argv[1]): its P_o and P_s
 * stay as they are, so a ghost table with a hand-made P_clip has a closed-form answer.
 *
 *   1. The reader: a ghost table's info (ghost, first, second, label, clip pairs); every
 *      malformed variant refused with a message naming the file, the line, the key and
 *      the value (lines out of order, side not P_o / P_s, i >= j, P_clip inputs differing
 *      from the ghost side's, odd or more than 8 outputs, names and units not in pairs,
 *      P_clip in a table without ghost lines, P_clip before P_o or P_s).
 * Usage: test_ghost LENS_TABLE */
#include "lensrt.h"

#include "check.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------ table text ----- */

/* A growing string. */
typedef struct text_buf {
    char *s;
    size_t n, cap;
} text_buf;

static void put(text_buf *b, const char *s, size_t n)
{
    if (b->n + n + 1 > b->cap) {
        b->cap = 2 * (b->n + n + 1);
        b->s = realloc(b->s, b->cap);
        if (!b->s) abort();
    }
    memcpy(b->s + b->n, s, n);
    b->n += n;
    b->s[b->n] = '\0';
}

static void puts_(text_buf *b, const char *s) { put(b, s, strlen(s)); }

/* The direct table, cut where ghost lines and P_clip go. */
static const char *g_text;
static size_t g_size, g_head;      /* g_head: bytes up to the end of the trust psf_target line */
static const char *g_inputs[2];    /* the 6 input lines of P_o and P_s */
static size_t g_inputs_len[2];
static double g_xa_s;              /* x_a's normalisation s (mm): xhat_a = x_a / s */

static int cut_direct(const char *text, size_t size)
{
    const char *p = strstr(text, "\ntrust psf_target "), *q;
    int k;
    if (!p) return 0;
    p = strchr(p + 1, '\n');
    if (!p) return 0;
    g_text = text;
    g_size = size;
    g_head = (size_t)(p + 1 - text);
    for (k = 0; k < 2; k++) {
        int i;
        p = strstr(text, k == 0 ? "\nsystem P_o 6 4\n" : "\nsystem P_s 6 4\n");
        if (!p) return 0;
        p = strchr(p + 1, '\n') + 1;
        for (q = p, i = 0; i < 6; i++) q = strchr(q, '\n') + 1;
        g_inputs[k] = p;
        g_inputs_len[k] = (size_t)(q - p);
    }
    // input x_a UNIT LO HI affine C S: the last field of P_o's fourth input line
    p = g_inputs[0];
    for (k = 0; k < 3; k++) p = strchr(p, '\n') + 1;
    q = strchr(p, '\n');
    while (q > p && q[-1] != ' ') q--;
    g_xa_s = strtod(q, NULL);
    return g_xa_s > 0;
}

/* One clip output: name, unit, then terms "e0 e1 e2 e3 e4 e5 coef" separated by ';'. */
typedef struct clip_out {
    const char *name, *unit, *terms;
} clip_out;

/* A ghost table: ghost lines (NULL: none; else the whole block, lines ending in \n),
 * P_o and P_s from the direct table, then P_clip with `side`'s inputs (0 P_o, 1 P_s)
 * and the n outputs (n 0: no P_clip). `clip_header` replaces "system P_clip 6 <n>"
 * when not NULL. The caller frees the result. */
static char *ghost_table(const char *ghost_lines, int side, const clip_out *outs, int n, const char *clip_header,
                         size_t *size)
{
    text_buf b = {NULL, 0, 0};
    char line[256];
    int k;
    put(&b, g_text, g_head);
    if (ghost_lines) puts_(&b, ghost_lines);
    put(&b, g_text + g_head, g_size - g_head);
    if (g_text[g_size - 1] != '\n') puts_(&b, "\n");
    if (n > 0 || clip_header) {
        if (clip_header) puts_(&b, clip_header);
        else {
            snprintf(line, sizeof line, "system P_clip 6 %d\n", n);
            puts_(&b, line);
        }
        put(&b, g_inputs[side], g_inputs_len[side]);
        for (k = 0; k < n; k++) {
            const char *t = outs[k].terms;
            int n_terms = 1;
            const char *c;
            for (c = t; *c; c++) n_terms += *c == ';';
            snprintf(line, sizeof line, "output %s %s %d\n", outs[k].name, outs[k].unit, n_terms);
            puts_(&b, line);
            while (*t) {
                const char *e = strchr(t, ';');
                size_t len = e ? (size_t)(e - t) : strlen(t);
                put(&b, t, len);
                puts_(&b, "\n");
                t += len + (e != NULL);
            }
        }
        puts_(&b, "end\n");
    }
    *size = b.n;
    return b.s;
}

static const char *const GHOST_P_O = "ghost first 0\nghost second 2\nghost label 0-2\nghost side P_o\n";
static const char *const GHOST_P_S = "ghost first 4\nghost second 8\nghost label 4-8\nghost side P_s\n";

/* ----------------------------------------------------------------- reader ----- */

/* Load text (NUL-terminated, freed here) and expect a parse error naming the file and
 * holding n1 and n2 (NULL: no second needle). */
static void expect_parse_error(lensrt_context ctx, const char *what, char *text, const char *n1, const char *n2)
{
    lensrt_lens lens = NULL;
    lensrt_result res = load_stamped(ctx, text, strlen(text), "ghost_4_8.table", &lens);
    CHECK(res == LENSRT_ERROR_PARSE, "%s: expected a parse error, got %s", what, lensrt_result_string(res));
    CHECK(strstr(lensrt_context_last_error(ctx), "ghost_4_8.table") != NULL, "%s: message '%s' names no file", what,
          lensrt_context_last_error(ctx));
    CHECK(strstr(lensrt_context_last_error(ctx), n1) != NULL, "%s: message '%s' lacks '%s'", what,
          lensrt_context_last_error(ctx), n1);
    if (n2)
        CHECK(strstr(lensrt_context_last_error(ctx), n2) != NULL, "%s: message '%s' lacks '%s'", what,
              lensrt_context_last_error(ctx), n2);
    if (lens) lensrt_lens_destroy(ctx, lens);
    free(text);
}

static void test_reader(lensrt_context ctx)
{
    const clip_out two[2] = {{"x_h0", "1", "0 0 0 1 0 0 0.5"}, {"y_h0", "1", "0 0 0 0 1 0 0.5"}};
    const clip_out four[4] = {{"x_h0", "1", "0 0 0 1 0 0 0.5"}, {"y_h0", "1", "0 0 0 0 1 0 0.5"},
                              {"x_s1", "mm", "0 0 0 1 0 0 3"}, {"y_s1", "mm%20(on%20the%20stop)", "0 0 0 0 1 0 3"}};
    lensrt_lens lens = NULL;
    lensrt_lens_info info = LENSRT_LENS_INFO_INIT;
    size_t n;
    char *t;

    // A ghost table on side P_s with a housing pair and a stop pair
    t = ghost_table(GHOST_P_S, 1, four, 4, NULL, &n);
    CHECK_OK(ctx, load_stamped(ctx, t, n, "ghost_4_8.table", &lens));
    if (lens) {
        CHECK_OK(ctx, lensrt_lens_get_info(lens, &info));
        CHECK(info.ghost == 1 && info.ghost_first == 4 && info.ghost_second == 8 && info.ghost_clip_pairs == 2 &&
                  info.ghost_label && strcmp(info.ghost_label, "4-8") == 0,
              "ghost info: ghost %d, first %d, second %d, label '%s', pairs %d", info.ghost, info.ghost_first,
              info.ghost_second, info.ghost_label ? info.ghost_label : "(null)", info.ghost_clip_pairs);
        lensrt_lens_destroy(ctx, lens);
    }
    free(t);
    // A ghost without P_clip (K = 0) on side P_o; the direct table reads as no ghost
    t = ghost_table(GHOST_P_O, 0, NULL, 0, NULL, &n);
    CHECK_OK(ctx, load_stamped(ctx, t, n, "ghost_0_2.table", &lens));
    if (lens) {
        CHECK_OK(ctx, lensrt_lens_get_info(lens, &info));
        CHECK(info.ghost == 1 && info.ghost_first == 0 && info.ghost_second == 2 && info.ghost_clip_pairs == 0 &&
                  strcmp(info.ghost_label, "0-2") == 0,
              "ghost without P_clip: ghost %d, first %d, second %d, pairs %d", info.ghost, info.ghost_first,
              info.ghost_second, info.ghost_clip_pairs);
        lensrt_lens_destroy(ctx, lens);
    }
    free(t);
    CHECK_OK(ctx, load_stamped(ctx, g_text, g_size, "lens0001.table", &lens));
    if (lens) {
        CHECK_OK(ctx, lensrt_lens_get_info(lens, &info));
        CHECK(info.ghost == 0 && info.ghost_clip_pairs == 0 && info.ghost_label && info.ghost_label[0] == '\0',
              "direct table: ghost %d, pairs %d", info.ghost, info.ghost_clip_pairs);
        lensrt_lens_destroy(ctx, lens);
    }

    // Ghost lines: order, values, place
    expect_parse_error(ctx, "out of order",
                       ghost_table("ghost second 8\nghost first 4\nghost label 4-8\nghost side P_s\n", 1, two, 2, NULL,
                                   &n),
                       "expected 'ghost first <i>'", "found ghost second '8'");
    expect_parse_error(ctx, "bad side",
                       ghost_table("ghost first 4\nghost second 8\nghost label 4-8\nghost side P_x\n", 1, two, 2, NULL,
                                   &n),
                       "ghost side 'P_x'", "neither P_o nor P_s");
    expect_parse_error(ctx, "i = j",
                       ghost_table("ghost first 4\nghost second 4\nghost label 4-4\nghost side P_s\n", 1, two, 2, NULL,
                                   &n),
                       "ghost second '4'", "i < j");
    expect_parse_error(ctx, "i > j",
                       ghost_table("ghost first 8\nghost second 4\nghost label 8-4\nghost side P_s\n", 1, two, 2, NULL,
                                   &n),
                       "ghost second '4'", "ghost first 8");
    expect_parse_error(ctx, "negative index",
                       ghost_table("ghost first -1\nghost second 4\nghost label x\nghost side P_s\n", 1, two, 2, NULL,
                                   &n),
                       "ghost first '-1'", "surface index");
    expect_parse_error(ctx, "missing side",
                       ghost_table("ghost first 4\nghost second 8\nghost label 4-8\n", 1, two, 2, NULL, &n),
                       "missing ghost line", "ghost side <P_o|P_s>");
    expect_parse_error(ctx, "twice",
                       ghost_table("ghost first 4\nghost first 4\n", 1, two, 2, NULL, &n), "ghost first '4' appears twice",
                       NULL);
    expect_parse_error(ctx, "extra field",
                       ghost_table("ghost first 4 5\n", 1, two, 2, NULL, &n), "expected 'ghost first <i>' (3 fields)",
                       NULL);
    {
        // Ghost lines before the trust lines
        text_buf b = {NULL, 0, 0};
        const char *trust = strstr(g_text, "\ntrust psf_vs_exact ") + 1;
        put(&b, g_text, (size_t)(trust - g_text));
        puts_(&b, GHOST_P_S);
        put(&b, trust, g_size - (size_t)(trust - g_text));
        expect_parse_error(ctx, "before trust", b.s, "ghost first '4' before the trust lines end", NULL);
    }
    {
        // Ghost lines after a system
        char *u = ghost_table(NULL, 1, NULL, 0, NULL, &n);
        text_buf b = {NULL, 0, 0};
        put(&b, u, n);
        puts_(&b, GHOST_P_S);
        free(u);
        expect_parse_error(ctx, "after a system", b.s, "ghost first '4' after a system", NULL);
    }

    // P_clip: only in a ghost table, third, with the ghost side's inputs, in pairs
    expect_parse_error(ctx, "P_clip without ghost lines", ghost_table(NULL, 1, two, 2, NULL, &n),
                       "system P_clip '2' in a table without ghost lines", NULL);
    expect_parse_error(ctx, "P_clip inputs of the other side", ghost_table(GHOST_P_S, 0, two, 2, NULL, &n),
                       "input 0 'x_O'", "differs from the ghost side P_s's 'x_S'");
    {
        // One input's domain changed (x_a's hi and s on side P_o)
        const clip_out o[2] = {{"x_h0", "1", "0 0 0 1 0 0 0.5"}, {"y_h0", "1", "0 0 0 0 1 0 0.5"}};
        char *u = ghost_table(GHOST_P_O, 0, o, 2, NULL, &n);
        char *clip = strstr(u, "system P_clip");
        char *xa = strstr(clip, "\ninput x_a ");
        char *hi;
        char old[128];
        text_buf b = {NULL, 0, 0};
        // x_a's domain and normalisation (lo hi transform c s) widened to 15 mm
        snprintf(old, sizeof old, "%.17g %.17g affine 0 %.17g", -g_xa_s, g_xa_s, g_xa_s);
        hi = strstr(xa, old);
        CHECK(hi != NULL, "x_a's line '%s' not found", old);
        if (hi) {
            put(&b, u, (size_t)(hi - u));
            puts_(&b, "-15 15 affine 0 15");
            put(&b, hi + strlen(old), n - (size_t)(hi + strlen(old) - u));
            expect_parse_error(ctx, "P_clip domain", b.s, "input 3 'x_a' [-15, 15]",
                               "differs from the ghost side P_o's 'x_a'");
        } else {
            free(b.s);
        }
        free(u);
    }
    expect_parse_error(ctx, "odd outputs", ghost_table(GHOST_P_S, 1, two, 1, NULL, &n), "system P_clip: 1 outputs",
                       "even count");
    expect_parse_error(ctx, "more than 8 outputs", ghost_table(GHOST_P_S, 1, two, 0, "system P_clip 6 10\n", &n),
                       "system P_clip: 10 outputs", "at most 4 clip tests");
    {
        const clip_out bad_name[2] = {{"x_q0", "1", "0 0 0 1 0 0 0.5"}, {"y_q0", "1", "0 0 0 0 1 0 0.5"}};
        const clip_out bad_pair[2] = {{"x_h0", "1", "0 0 0 1 0 0 0.5"}, {"y_h1", "1", "0 0 0 0 1 0 0.5"}};
        const clip_out mixed[2] = {{"x_h0", "1", "0 0 0 1 0 0 0.5"}, {"y_s0", "mm", "0 0 0 0 1 0 0.5"}};
        const clip_out bad_unit[2] = {{"x_s2", "1", "0 0 0 1 0 0 0.5"}, {"y_s2", "1", "0 0 0 0 1 0 0.5"}};
        const clip_out bad_unit_h[2] = {{"x_h3", "mm", "0 0 0 1 0 0 0.5"}, {"y_h3", "mm", "0 0 0 0 1 0 0.5"}};
        const clip_out swapped[2] = {{"y_h0", "1", "0 0 0 1 0 0 0.5"}, {"x_h0", "1", "0 0 0 0 1 0 0.5"}};
        expect_parse_error(ctx, "output name", ghost_table(GHOST_P_S, 1, bad_name, 2, NULL, &n), "output 0 'x_q0'",
                           "expected x_h<k>");
        expect_parse_error(ctx, "pair index", ghost_table(GHOST_P_S, 1, bad_pair, 2, NULL, &n), "output 1 'y_h1'",
                           "expected its pair y_h0");
        expect_parse_error(ctx, "pair kind", ghost_table(GHOST_P_S, 1, mixed, 2, NULL, &n), "output 1 'y_s0'",
                           "expected its pair y_h0");
        expect_parse_error(ctx, "stop unit", ghost_table(GHOST_P_S, 1, bad_unit, 2, NULL, &n),
                           "pair x_s2, y_s2 has units '1', '1'", "expected 'mm'");
        expect_parse_error(ctx, "housing unit", ghost_table(GHOST_P_S, 1, bad_unit_h, 2, NULL, &n),
                           "pair x_h3, y_h3 has units 'mm', 'mm'", "expected '1'");
        expect_parse_error(ctx, "y before x", ghost_table(GHOST_P_S, 1, swapped, 2, NULL, &n), "output 0 'y_h0'",
                           NULL);
    }
    {
        // P_clip before P_s
        char *u = ghost_table(GHOST_P_S, 1, two, 2, NULL, &n);
        char *clip = strstr(u, "system P_clip");
        char *ps = strstr(u, "\nsystem P_s ") + 1;
        text_buf b = {NULL, 0, 0};
        put(&b, u, (size_t)(ps - u));
        put(&b, clip, n - (size_t)(clip - u));
        put(&b, ps, (size_t)(clip - ps));
        free(u);
        expect_parse_error(ctx, "P_clip before P_s", b.s, "system P_clip before system P_s", "comes third");
    }
    {
        // Two P_clip systems
        char *u = ghost_table(GHOST_P_S, 1, two, 2, NULL, &n);
        char *clip = strstr(u, "system P_clip");
        text_buf b = {NULL, 0, 0};
        put(&b, u, n);
        put(&b, clip, n - (size_t)(clip - u));
        free(u);
        expect_parse_error(ctx, "P_clip twice", b.s, "system P_clip appears twice", NULL);
    }
}

/* ---------------------------------------------------------------- renders ----- */

#define RES 20              /* pixels per side of the test window */
#define R_STOP 7.0          /* the ghost's stop radius (mm; lens 0001 opens to 14.5) */
#define R_SMALL 4.5         /* the stop P_clip makes (mm) */
#define N_POINTS 2048

/* A lens from table text (NUL-terminated; freed here). */
static lensrt_lens load(lensrt_context ctx, const char *what, char *text)
{
    lensrt_lens lens = NULL;
    lensrt_result res = load_stamped(ctx, text, strlen(text), "ghost_test.table", &lens);
    CHECK(res == LENSRT_SUCCESS, "%s: load: %s", what, lensrt_context_last_error(ctx));
    free(text);
    return lens;
}

/* A render of the test scene: light (-6, -4) deg at infinity, a window of RES x RES
 * pixels (0.05 mm) on its image point, 0.2 mm of defocus, one wavelength (550 nm) or
 * three, aperture `ap`. NULL (and a failed check unless `quiet`) when creation fails. */
static lensrt_render make_render_ap(lensrt_context ctx, lensrt_lens lens, const lensrt_aperture *ap, int precision,
                                    int n_wl, int quiet)
{
    static const double wl[3] = {480.0, 550.0, 620.0};
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    lensrt_light light = LENSRT_LIGHT_INIT;
    lensrt_render r = NULL;
    double centre[2] = {0, 0};
    lensrt_result res;
    light.field_x_deg = -6.0;
    light.field_y_deg = -4.0;
    CHECK_OK(ctx, lensrt_lens_image_point(ctx, lens, &light, 550.0, 0.2, centre));
    d.lens = lens;
    d.sensor.width = d.sensor.height = RES;
    d.sensor.width_mm = 0.05;
    d.sensor.center_x_mm = centre[0];
    d.sensor.center_y_mm = centre[1];
    d.sensor.focus_offset_mm = 0.2;
    d.aperture = *ap;
    d.lights = &light;
    d.n_lights = 1;
    d.wavelengths_nm = n_wl == 1 ? wl + 1 : wl;
    d.n_wavelengths = n_wl;
    d.precision = precision;
    d.seed = 11;
    // The point filter (issue 26): these checks compare the clips' images between renders
    // of different stops at the same points, bit for bit, where the box filter's
    // automatic sub-pixel count would follow each stop's spread of ray directions
    // (tests/runtime/test_pixel_area.py checks the box filter, ghosts included)
    d.pixel_filter = LENSRT_PIXEL_FILTER_POINT;
    res = lensrt_render_create(ctx, &d, &r);
    if (!quiet) CHECK(res == LENSRT_SUCCESS, "render create: %s", lensrt_context_last_error(ctx));
    return res == LENSRT_SUCCESS ? r : NULL;
}

/* The same with a round stop of `radius`, or 7 straight blades (shape BLADES). */
static lensrt_render make_render(lensrt_context ctx, lensrt_lens lens, double radius, int precision, int n_wl,
                                 int shape)
{
    lensrt_aperture ap;
    memset(&ap, 0, sizeof ap);
    ap.radius_mm = radius;
    ap.shape = shape;
    ap.blades = shape == LENSRT_APERTURE_BLADES ? 7 : 0;
    return make_render_ap(ctx, lens, &ap, precision, n_wl, shape != LENSRT_APERTURE_CIRCLE);
}

static float *image_of(lensrt_context ctx, lensrt_render r, int n_wl)
{
    float *img = calloc((size_t)n_wl * RES * RES, sizeof(float));
    if (!img) abort();
    if (r) CHECK_OK(ctx, lensrt_render_image(r, img, (size_t)n_wl * RES * RES));
    return img;
}

/* The image (one wavelength) of render r after splatting the N_POINTS stop points xy. */
static float *splatted(lensrt_context ctx, lensrt_render r, const double *xy)
{
    if (r) CHECK_OK(ctx, lensrt_render_splat_points(r, 0, xy, N_POINTS));
    return image_of(ctx, r, 1);
}

static double total(const float *a, size_t n)
{
    double s = 0;
    size_t i;
    for (i = 0; i < n; i++) s += a[i];
    return s;
}

/* Relative L2 distance of a from b * scale. */
static double rel_l2(const float *a, const float *b, double scale, size_t n)
{
    double num = 0, den = 0;
    size_t i;
    for (i = 0; i < n; i++) {
        double d = (double)a[i] - scale * (double)b[i];
        num += d * d;
        den += scale * scale * (double)b[i] * (double)b[i];
    }
    return sqrt(num / den);
}

/* N_POINTS points uniform over the disc of radius R_STOP (a fixed LCG), none within 1e-6
 * of the radius R_SMALL (relative): there a test in float and one in double could differ
 * by rounding, which is not what these tests are about. */
static void disc_points_band(double *xy, double band);

static void disc_points(double *xy) { disc_points_band(xy, R_SMALL); }

/* The same keeping 1e-6 (relative) from the radius `band`, or 1e-3 for a band other
 * than R_SMALL (a P_clip whose per-splat test may be approximated: see test_basis_clip). */
static void disc_points_band(double *xy, double band)
{
    const double margin = band == R_SMALL ? 1e-6 : 1e-3;
    unsigned long long s = 0x9E3779B97F4A7C15ull;
    int j = 0;
    while (j < N_POINTS) {
        double u, v, rr;
        s = s * 6364136223846793005ull + 1442695040888963407ull;
        u = (double)(s >> 11) / 9007199254740992.0 * 2.0 - 1.0;
        s = s * 6364136223846793005ull + 1442695040888963407ull;
        v = (double)(s >> 11) / 9007199254740992.0 * 2.0 - 1.0;
        rr = sqrt(u * u + v * v) * R_STOP;
        if (u * u + v * v > 1.0 || fabs(rr - band) < margin * band) continue;
        xy[2 * j] = u * R_STOP;
        xy[2 * j + 1] = v * R_STOP;
        j++;
    }
}

/* A ghost table whose P_clip is a smaller stop of radius R_SMALL:
 *   side P_o: x_h0 = x_a / R_SMALL, y_h0 = y_a / R_SMALL (a housing pair, unit 1);
 *   side P_s: a housing pair that never blocks (1e-6 x_a / R_SMALL) and a stop pair
 *             x_s1 = (R_STOP / R_SMALL) x_a in mm, which the render tests against its stop
 *             radius R_STOP: it passes where |a| <= R_SMALL.
 * Raw x_a = s xhat_a, so x_a / r is the term (0 0 0 1 0 0) with coefficient s / r. */
static char *smaller_stop_table(int side, size_t *n)
{
    char t[4][64];
    clip_out o[4];
    snprintf(t[0], sizeof t[0], "0 0 0 1 0 0 %.17g", g_xa_s / R_SMALL);
    snprintf(t[1], sizeof t[1], "0 0 0 0 1 0 %.17g", g_xa_s / R_SMALL);
    if (side == 0) {
        o[0].name = "x_h0"; o[0].unit = "1"; o[0].terms = t[0];
        o[1].name = "y_h0"; o[1].unit = "1"; o[1].terms = t[1];
        return ghost_table(GHOST_P_O, 0, o, 2, NULL, n);
    }
    snprintf(t[2], sizeof t[2], "0 0 0 1 0 0 %.17g", 1e-6 * g_xa_s / R_SMALL);
    snprintf(t[3], sizeof t[3], "0 0 0 0 1 0 %.17g", 1e-6 * g_xa_s / R_SMALL);
    snprintf(t[0], sizeof t[0], "0 0 0 1 0 0 %.17g", g_xa_s * R_STOP / R_SMALL);
    snprintf(t[1], sizeof t[1], "0 0 0 0 1 0 %.17g", g_xa_s * R_STOP / R_SMALL);
    o[0].name = "x_h0"; o[0].unit = "1"; o[0].terms = t[2];
    o[1].name = "y_h0"; o[1].unit = "1"; o[1].terms = t[3];
    o[2].name = "x_s1"; o[2].unit = "mm"; o[2].terms = t[0];
    o[3].name = "y_s1"; o[3].unit = "mm"; o[3].terms = t[1];
    return ghost_table(GHOST_P_S, 1, o, 4, NULL, n);
}

/* 2. A P_clip that is a smaller stop (radius R_SMALL) inside a render of stop R_STOP, on
 *    side P_o (evaluated per sample on the host, in double) and on side P_s (per pixel
 *    and splat in the kernel: SIMD float, or the scalar kernel in a LENSRT_SCALAR_KERNEL
 *    build, and double), with the same points splatted:
 *    a. against the direct table at stop R_STOP splatting the same points, those beyond
 *       R_SMALL moved far outside the aperture (each still counts as a sample, with zero
 *       contribution): the same image bit for bit. Both renders have the same stop, so
 *       the same monomials, bases, pruning and pixel set-up; a clipped sample and an
 *       outside one both contribute exactly 0 to the block sums; the points keep 1e-6 from
 *       the radius R_SMALL, where the float test and the host's double test could differ.
 *    b. (precision double) against the direct table rendered with stop radius R_SMALL,
 *       the same points: the same sums up to rounding, and an image (R_STOP / R_SMALL)^4
 *       times as large (the Monte Carlo measure is the stop's area: pi R^2 per sample, in
 *       the image squared). The monomials u = x / R differ in their last bits between the
 *       two stops, and the phase reaches ~1e5 waves before its constant is dropped, so
 *       rounding moves phases by ~1e-11 waves; the images are floats (6e-8 relative per
 *       pixel: 2.8e-8 relative L2 measured), so 1e-6 relative L2 is far above rounding
 *       and far below any real difference (a clip that is off by one sample in 2048
 *       moves the image by ~1e-3). */
static void test_smaller_stop(lensrt_context ctx, lensrt_lens direct)
{
    double *xy = malloc(sizeof(double) * 2 * N_POINTS), *xy_in = malloc(sizeof(double) * 2 * N_POINTS);
    int side, prec, j, outside = 0;
    if (!xy || !xy_in) abort();
    disc_points(xy);
    for (j = 0; j < N_POINTS; j++) {
        int in = xy[2 * j] * xy[2 * j] + xy[2 * j + 1] * xy[2 * j + 1] <= R_SMALL * R_SMALL;
        xy_in[2 * j] = in ? xy[2 * j] : 1e3;
        xy_in[2 * j + 1] = in ? xy[2 * j + 1] : 0.0;
        outside += !in;
    }
    CHECK(outside > N_POINTS / 3, "only %d of %d points beyond R_SMALL", outside, N_POINTS);
    for (side = 0; side < 2; side++) {
        size_t n;
        char *text = smaller_stop_table(side, &n);
        lensrt_lens ghost = load(ctx, side ? "smaller stop, side P_s" : "smaller stop, side P_o", text);
        for (prec = 0; ghost && prec < 2; prec++) {
            const int precision = prec ? LENSRT_PRECISION_DOUBLE : LENSRT_PRECISION_DEFAULT;
            const char *what = prec ? "double" : "float";
            lensrt_render rg = make_render(ctx, ghost, R_STOP, precision, 1, LENSRT_APERTURE_CIRCLE);
            lensrt_render rd = make_render(ctx, direct, R_STOP, precision, 1, LENSRT_APERTURE_CIRCLE);
            lensrt_render rall = make_render(ctx, direct, R_STOP, precision, 1, LENSRT_APERTURE_CIRCLE);
            float *ig, *id, *iall;
            ig = splatted(ctx, rg, xy);
            id = splatted(ctx, rd, xy_in);
            iall = splatted(ctx, rall, xy);
            CHECK(memcmp(ig, id, sizeof(float) * RES * RES) == 0,
                  "side %s, %s: the ghost's image differs from the direct one with the same points inside R_SMALL "
                  "(relative L2 %.3g)", side ? "P_s" : "P_o", what, rel_l2(ig, id, 1.0, RES * RES));
            // The clip blocked something: the whole stop gives another image
            CHECK(total(id, RES * RES) > 0 && rel_l2(iall, id, 1.0, RES * RES) > 0.1,
                  "side %s, %s: the clip changed nothing (relative L2 to the full stop %.3g)", side ? "P_s" : "P_o",
                  what, rel_l2(iall, id, 1.0, RES * RES));
            if (prec) {
                // b. The direct table at stop R_SMALL, the same points
                lensrt_render rs = make_render(ctx, direct, R_SMALL, precision, 1, LENSRT_APERTURE_CIRCLE);
                float *is;
                const double scale = pow(R_STOP / R_SMALL, 4.0);
                double e;
                is = splatted(ctx, rs, xy);
                e = rel_l2(ig, is, scale, RES * RES);
                CHECK(e < 1e-6, "side %s, double: ghost against the direct table at stop %g mm: relative L2 %.3g",
                      side ? "P_s" : "P_o", R_SMALL, e);
                free(is);
                lensrt_render_destroy(rs);
            }
            free(ig);
            free(id);
            free(iall);
            lensrt_render_destroy(rg);
            lensrt_render_destroy(rd);
            lensrt_render_destroy(rall);
        }
        lensrt_lens_destroy(ctx, ghost);
    }
    free(xy);
    free(xy_in);
}

/* 2c. A P_clip on side P_s with several stop terms: a stop that bulges,
 *     x_s1 = (R_STOP / R_SMALL) x_a (1 + B (x_a^2 + y_a^2) / s^2) (and y likewise), which
 *     passes where |a| (1 + B |a|^2 / s^2) <= R_SMALL, |a| <= r_b. Every pixel has the same
 *     three-term coefficients, which the window's basis of the clip output carries in one
 *     function (the kernel then tests g(a) u + c0, not three monomials: the float path's
 *     per-splat cost). Against the direct table at stop R_STOP splatting the points
 *     inside r_b (the others moved out): the same image bit for bit, float and double,
 *     the points keeping 1e-3 of r_b from it (the basis may move the tested x by at most
 *     1e-4 of the limit, i.e. 1e-4 R_SMALL in |a|). */
static void test_basis_clip(lensrt_context ctx, lensrt_lens direct)
{
    const double B = 0.2, k = R_STOP / R_SMALL;
    double rb = R_SMALL, *xy = malloc(sizeof(double) * 2 * N_POINTS), *xy_in = malloc(sizeof(double) * 2 * N_POINTS);
    char t[4][160];
    clip_out o[2];
    size_t n;
    int it, j, prec;
    lensrt_lens ghost;
    if (!xy || !xy_in) abort();
    // r_b: Newton on r (1 + B r^2 / s^2) = R_SMALL
    for (it = 0; it < 50; it++)
        rb -= (rb * (1 + B * rb * rb / (g_xa_s * g_xa_s)) - R_SMALL) / (1 + 3 * B * rb * rb / (g_xa_s * g_xa_s));
    // x_s1 = k s xhat_a + k B s (xhat_a^3 + xhat_a yhat_a^2), raw x_a = s xhat_a
    snprintf(t[0], sizeof t[0], "0 0 0 1 0 0 %.17g;0 0 0 3 0 0 %.17g;0 0 0 1 2 0 %.17g", k * g_xa_s, k * B * g_xa_s,
             k * B * g_xa_s);
    snprintf(t[1], sizeof t[1], "0 0 0 0 1 0 %.17g;0 0 0 0 3 0 %.17g;0 0 0 2 1 0 %.17g", k * g_xa_s, k * B * g_xa_s,
             k * B * g_xa_s);
    o[0].name = "x_s1"; o[0].unit = "mm"; o[0].terms = t[0];
    o[1].name = "y_s1"; o[1].unit = "mm"; o[1].terms = t[1];
    ghost = load(ctx, "bulging stop", ghost_table(GHOST_P_S, 1, o, 2, NULL, &n));
    disc_points_band(xy, rb);
    for (j = 0; j < N_POINTS; j++) {
        int in = hypot(xy[2 * j], xy[2 * j + 1]) <= rb;
        xy_in[2 * j] = in ? xy[2 * j] : 1e3;
        xy_in[2 * j + 1] = in ? xy[2 * j + 1] : 0.0;
    }
    for (prec = 0; ghost && prec < 2; prec++) {
        const int precision = prec ? LENSRT_PRECISION_DOUBLE : LENSRT_PRECISION_DEFAULT;
        lensrt_render rg = make_render(ctx, ghost, R_STOP, precision, 1, LENSRT_APERTURE_CIRCLE);
        lensrt_render rd = make_render(ctx, direct, R_STOP, precision, 1, LENSRT_APERTURE_CIRCLE);
        float *ig, *id;
        ig = splatted(ctx, rg, xy);
        id = splatted(ctx, rd, xy_in);
        CHECK(total(id, RES * RES) > 0 && memcmp(ig, id, sizeof(float) * RES * RES) == 0,
              "bulging stop (r_b %.6g mm), %s: the ghost's image differs from the direct one with the points inside "
              "r_b (relative L2 %.3g)", rb, prec ? "double" : "float", rel_l2(ig, id, 1.0, RES * RES));
        free(ig);
        free(id);
        lensrt_render_destroy(rg);
        lensrt_render_destroy(rd);
    }
    lensrt_lens_destroy(ctx, ghost);
    free(xy);
    free(xy_in);
}

/* 2d. Stop crossings of a bladed or slit stop (the issue: "a circle-only clip is wrong
 *     for a 7-blade stop"). A stop pair (x_s1, y_s1) = (F x_a, F y_a) passes where F a
 *     lies inside the render's aperture S, i.e. where a lies in S / F. Shapes: 7 straight
 *     blades rotated 10 deg, 7 blades of curvature 0.6 rotated 20 deg, one slit 3 mm wide,
 *     two 3 mm wide 3.5 mm apart (all at stop radius R_STOP; two slits are not
 *     star-shaped, so S / 2 and S overlap only in part: [0.25, 1.625] mm in |x|, which
 *     is what passes). Each side (P_o per sample on
 *     the host, P_s per splat: SIMD float, scalar float in a LENSRT_SCALAR_KERNEL build,
 *     double), the same points splatted:
 *     a. F = 1: the ghost's image is the direct image of S bit for bit (the crossing is
 *        the aperture point itself, so the pair never blocks a point S lets through);
 *     b. F = 2: the ghost's image is the direct image of S splatting only the points in
 *        S / 2 (decided here by an independent test: the polygon by the sign of cross
 *        products along its vertices, each curved blade as the circle through its two
 *        vertices with the sagitta curvature (R - apothem), the slits as boxes), the
 *        others moved far outside, bit for bit as in 2a; the points keep 1e-5 R_STOP
 *        from the boundary of S / 2 (float's rounding of F x_a is ~1e-7 of it);
 *     c. the circle-only test (what lensrt did before: |F a| <= R_STOP) would give
 *        another image: relative L2 to it > 0.05 (fixed points: measured 0.228,
 *        0.072, 1.66, 1.63 for the four shapes);
 *     d. (7 straight blades, double) the direct table rendered with the stop R_STOP / 2
 *        and the same blades (S / 2 exactly), the same points: the image
 *        (R_STOP / (R_STOP / 2))^4 = 16 times as large, relative L2 1e-6 as in 2b.
 *     Then a and b for the limits of valid apertures (bad ones are refused by the scene
 *     check): 3 blades, 64 curved blades, curvature 1, touching slits: no NaN, no crash
 *     (ASan/UBSan build), the same images bit for bit.
 */
static int poly_contains(const lensrt_aperture *ap, double R, double x, double y)
{
    const double pi = 3.14159265358979323846, rot = ap->rotation_deg * pi / 180.0;
    const int n = ap->blades;
    int k, beyond = -1, n_beyond = 0;
    if (ap->shape == LENSRT_APERTURE_SLIT) {
        const double h = 0.5 * ap->slit_width_mm, c = 0.5 * ap->slit_separation_mm;
        return fabs(y) <= R && (fabs(x - c) <= h || fabs(x + c) <= h);
    }
    if (x * x + y * y > R * R) return 0;
    // Vertices counter-clockwise at rot + 2 pi k / n; inside edge k when the cross product
    // (v_k+1 - v_k) x (p - v_k) is not negative
    for (k = 0; k < n; k++) {
        double ax = R * cos(rot + 2 * pi * k / n), ay = R * sin(rot + 2 * pi * k / n);
        double bx = R * cos(rot + 2 * pi * (k + 1) / n), by = R * sin(rot + 2 * pi * (k + 1) / n);
        if ((bx - ax) * (y - ay) - (by - ay) * (x - ax) < 0) {
            beyond = k;
            n_beyond++;
        }
    }
    if (n_beyond == 0) return 1;
    if (n_beyond > 1 || ap->blade_curvature <= 0) return 0;
    {
        // Beyond one straight edge, within the disc R: inside that blade's circle, which
        // passes through both vertices and bulges by the sagitta at the edge's middle
        double ax = R * cos(rot + 2 * pi * beyond / n), ay = R * sin(rot + 2 * pi * beyond / n);
        double bx = R * cos(rot + 2 * pi * (beyond + 1) / n), by = R * sin(rot + 2 * pi * (beyond + 1) / n);
        double mx = 0.5 * (ax + bx), my = 0.5 * (ay + by), ap_len = hypot(mx, my);
        double half_chord = 0.5 * hypot(bx - ax, by - ay), sag = ap->blade_curvature * (R - ap_len);
        double rho = (half_chord * half_chord + sag * sag) / (2 * sag);
        double cx = mx / ap_len * (ap_len + sag - rho), cy = my / ap_len * (ap_len + sag - rho);
        return (x - cx) * (x - cx) + (y - cy) * (y - cy) <= rho * rho;
    }
}

/* Whether (x, y) lies at least m from the boundary of the shape (its 8 neighbours at
 * distance m agree with it). */
static int clear_of_boundary(const lensrt_aperture *ap, double R, double x, double y, double m)
{
    int k, in = poly_contains(ap, R, x, y);
    for (k = 0; k < 8; k++)
        if (poly_contains(ap, R, x + m * cos(k * 0.785398163397448), y + m * sin(k * 0.785398163397448)) != in)
            return 0;
    return 1;
}

/* A ghost table whose P_clip is one stop pair (x_s1, y_s1) = (F x_a, F y_a) mm on `side`. */
static char *scaled_pair_table(int side, double F, size_t *n)
{
    char t[2][64];
    clip_out o[2];
    snprintf(t[0], sizeof t[0], "0 0 0 1 0 0 %.17g", F * g_xa_s);
    snprintf(t[1], sizeof t[1], "0 0 0 0 1 0 %.17g", F * g_xa_s);
    o[0].name = "x_s1"; o[0].unit = "mm"; o[0].terms = t[0];
    o[1].name = "y_s1"; o[1].unit = "mm"; o[1].terms = t[1];
    return ghost_table(side ? GHOST_P_S : GHOST_P_O, side, o, 2, NULL, n);
}

static void test_shaped_stop(lensrt_context ctx, lensrt_lens direct)
{
    /* The four shapes above, then the limits of valid apertures (a and b only: these are
     * circles or nearly, where the circle-only test is right or nearly): 3 straight
     * blades, 64 blades of curvature 0.3, 5 of curvature 1 (the circle itself: each
     * edge's disc is the R-disc, g = 0), two slits that touch (separation = width) */
    static const struct { int shape, blades; double rot, curv, width, sep; const char *name; } shapes[8] = {
        {LENSRT_APERTURE_BLADES, 7, 10.0, 0.0, 0, 0, "7 straight blades"},
        {LENSRT_APERTURE_BLADES, 7, 20.0, 0.6, 0, 0, "7 curved blades"},
        {LENSRT_APERTURE_SLIT, 0, 0, 0, 3.0, 0.0, "one slit"},
        {LENSRT_APERTURE_SLIT, 0, 0, 0, 3.0, 3.5, "two slits"},
        {LENSRT_APERTURE_BLADES, 3, 33.0, 0.0, 0, 0, "3 straight blades"},
        {LENSRT_APERTURE_BLADES, 64, 1.0, 0.3, 0, 0, "64 curved blades"},
        {LENSRT_APERTURE_BLADES, 5, 0.0, 1.0, 0, 0, "5 blades of curvature 1"},
        {LENSRT_APERTURE_SLIT, 0, 0, 0, 2.0, 2.0, "two touching slits"}};
    double *xy = malloc(sizeof(double) * 2 * N_POINTS), *xy_in = malloc(sizeof(double) * 2 * N_POINTS);
    double *xy_c = malloc(sizeof(double) * 2 * N_POINTS);
    int shape, side, prec, j;
    if (!xy || !xy_in || !xy_c) abort();
    for (shape = 0; shape < 8; shape++) {
        lensrt_aperture ap;
        int kept = 0, inside = 0;
        memset(&ap, 0, sizeof ap);
        ap.radius_mm = R_STOP;
        ap.shape = shapes[shape].shape;
        ap.blades = shapes[shape].blades;
        ap.rotation_deg = shapes[shape].rot;
        ap.blade_curvature = shapes[shape].curv;
        ap.slit_width_mm = shapes[shape].width;
        ap.slit_separation_mm = shapes[shape].sep;
        // Points clear of the boundary of S / 2 (F = 2: 2 a clear of the boundary of S)
        {
            // Uniform over the disc R_STOP (a fixed LCG)
            unsigned long long st = 0x2545F4914F6CDD1Dull;
            int tries;
            for (tries = 0; tries < 16 * N_POINTS && kept < N_POINTS; tries++) {
                double u, v;
                st = st * 6364136223846793005ull + 1442695040888963407ull;
                u = (double)(st >> 11) / 9007199254740992.0 * 2.0 - 1.0;
                st = st * 6364136223846793005ull + 1442695040888963407ull;
                v = (double)(st >> 11) / 9007199254740992.0 * 2.0 - 1.0;
                if (u * u + v * v > 1.0 || !clear_of_boundary(&ap, R_STOP, 2 * u * R_STOP, 2 * v * R_STOP, 1e-5 * R_STOP))
                    continue;
                xy[2 * kept] = u * R_STOP;
                xy[2 * kept + 1] = v * R_STOP;
                kept++;
            }
        }
        CHECK(kept == N_POINTS, "%s: only %d points clear of the boundary", shapes[shape].name, kept);
        for (j = 0; j < N_POINTS; j++) {
            int in = poly_contains(&ap, R_STOP, 2 * xy[2 * j], 2 * xy[2 * j + 1]);
            int in_c = 4 * (xy[2 * j] * xy[2 * j] + xy[2 * j + 1] * xy[2 * j + 1]) <= R_STOP * R_STOP;
            xy_in[2 * j] = in ? xy[2 * j] : 1e3;
            xy_in[2 * j + 1] = in ? xy[2 * j + 1] : 0.0;
            xy_c[2 * j] = in_c ? xy[2 * j] : 1e3;
            xy_c[2 * j + 1] = in_c ? xy[2 * j + 1] : 0.0;
            inside += in;
        }
        CHECK(inside > 20 && inside < N_POINTS / 2, "%s: %d of %d points in S / 2", shapes[shape].name, inside,
              N_POINTS);
        for (side = 0; side < 2; side++) {
            size_t n;
            lensrt_lens g1 = load(ctx, "F = 1", scaled_pair_table(side, 1.0, &n));
            lensrt_lens g2 = load(ctx, "F = 2", scaled_pair_table(side, 2.0, &n));
            for (prec = 0; g1 && g2 && prec < 2; prec++) {
                const int precision = prec ? LENSRT_PRECISION_DOUBLE : LENSRT_PRECISION_DEFAULT;
                const char *what = prec ? "double" : "float", *sd = side ? "P_s" : "P_o";
                lensrt_render r1 = make_render_ap(ctx, g1, &ap, precision, 1, 0);
                lensrt_render r2 = make_render_ap(ctx, g2, &ap, precision, 1, 0);
                lensrt_render rd = make_render_ap(ctx, direct, &ap, precision, 1, 0);
                lensrt_render rin = make_render_ap(ctx, direct, &ap, precision, 1, 0);
                lensrt_render rc = make_render_ap(ctx, direct, &ap, precision, 1, 0);
                float *i1, *i2, *id, *iin, *ic;
                i1 = splatted(ctx, r1, xy);
                i2 = splatted(ctx, r2, xy);
                id = splatted(ctx, rd, xy);
                iin = splatted(ctx, rin, xy_in);
                ic = splatted(ctx, rc, xy_c);
                CHECK(total(id, RES * RES) > 0 && memcmp(i1, id, sizeof(float) * RES * RES) == 0,
                      "%s, side %s, %s: F = 1 differs from the direct image (relative L2 %.3g)", shapes[shape].name, sd, what,
                      rel_l2(i1, id, 1.0, RES * RES));
                CHECK(total(iin, RES * RES) > 0 && memcmp(i2, iin, sizeof(float) * RES * RES) == 0,
                      "%s, side %s, %s: F = 2 differs from the direct image of the points in S / 2 (relative L2 %.3g)",
                      shapes[shape].name, sd, what, rel_l2(i2, iin, 1.0, RES * RES));
                CHECK(shape >= 4 || rel_l2(ic, iin, 1.0, RES * RES) > 0.05,
                      "%s, side %s, %s: the circle-only test gives the same image (relative L2 %.3g)", shapes[shape].name, sd,
                      what, rel_l2(ic, iin, 1.0, RES * RES));
                if (prec && side && shape < 4) printf("  circle-only against S / 2, %s: relative L2 %.3g\n", shapes[shape].name,
                                                       rel_l2(ic, iin, 1.0, RES * RES));
                if (shape == 0 && prec) {
                    // d. The direct table with the stop S / 2
                    lensrt_aperture half = ap;
                    lensrt_render rh;
                    float *ih;
                    half.radius_mm = 0.5 * R_STOP;
                    rh = make_render_ap(ctx, direct, &half, precision, 1, 0);
                    ih = splatted(ctx, rh, xy);
                    CHECK(rel_l2(i2, ih, 16.0, RES * RES) < 1e-6,
                          "%s, side %s, double: F = 2 against the direct stop S / 2: relative L2 %.3g", shapes[shape].name, sd,
                          rel_l2(i2, ih, 16.0, RES * RES));
                    free(ih);
                    lensrt_render_destroy(rh);
                }
                free(i1);
                free(i2);
                free(id);
                free(iin);
                free(ic);
                lensrt_render_destroy(r1);
                lensrt_render_destroy(r2);
                lensrt_render_destroy(rd);
                lensrt_render_destroy(rin);
                lensrt_render_destroy(rc);
            }
            lensrt_lens_destroy(ctx, g1);
            lensrt_lens_destroy(ctx, g2);
        }
    }
    free(xy);
    free(xy_in);
    free(xy_c);
}

/* 3. P_clip that never blocks (tiny coefficients: the bounds show every pair passes) gives
 *    the direct image of the same P_o and P_s bit for bit (run() with the same seed, three
 *    wavelengths, float and double); one that always blocks (x_h0 = 2) gives zeros, every
 *    pixel dark on side P_s. */
static void test_never_always(lensrt_context ctx, lensrt_lens direct)
{
    const clip_out never[2] = {{"x_h0", "1", "0 0 0 1 0 0 1e-6;1 0 0 0 0 0 1e-7"}, {"y_h0", "1", "0 0 0 0 1 0 1e-6"}};
    const clip_out always[2] = {{"x_h0", "1", "0 0 0 0 0 0 2;0 0 0 1 0 0 0.1"}, {"y_h0", "1", "0 0 0 0 1 0 0.1"}};
    int side, prec;
    for (side = 0; side < 2; side++)
        for (prec = 0; prec < 2; prec++) {
            const int precision = prec ? LENSRT_PRECISION_DOUBLE : LENSRT_PRECISION_DEFAULT;
            size_t n;
            lensrt_lens gn = load(ctx, "never", ghost_table(side ? GHOST_P_S : GHOST_P_O, side, never, 2, NULL, &n));
            lensrt_lens ga = load(ctx, "always", ghost_table(side ? GHOST_P_S : GHOST_P_O, side, always, 2, NULL, &n));
            lensrt_render rn = make_render(ctx, gn, R_STOP, precision, 3, LENSRT_APERTURE_CIRCLE);
            lensrt_render ra = make_render(ctx, ga, R_STOP, precision, 3, LENSRT_APERTURE_CIRCLE);
            lensrt_render rd = make_render(ctx, direct, R_STOP, precision, 3, LENSRT_APERTURE_CIRCLE);
            lensrt_render_stats st = LENSRT_RENDER_STATS_INIT;
            float *in, *ia, *id;
            if (rn) CHECK_OK(ctx, lensrt_render_run(rn, 1024, NULL, NULL));
            if (ra) CHECK_OK(ctx, lensrt_render_run(ra, 1024, NULL, NULL));
            if (rd) CHECK_OK(ctx, lensrt_render_run(rd, 1024, NULL, NULL));
            in = image_of(ctx, rn, 3);
            ia = image_of(ctx, ra, 3);
            id = image_of(ctx, rd, 3);
            CHECK(total(id, 3 * RES * RES) > 0 && memcmp(in, id, sizeof(float) * 3 * RES * RES) == 0,
                  "side %s, %s: a P_clip that never blocks changed the image (relative L2 %.3g)", side ? "P_s" : "P_o",
                  prec ? "double" : "float", rel_l2(in, id, 1.0, 3 * RES * RES));
            CHECK(total(ia, 3 * RES * RES) == 0.0, "side %s, %s: a P_clip that always blocks left %g",
                  side ? "P_s" : "P_o", prec ? "double" : "float", total(ia, 3 * RES * RES));
            if (ra && side) {
                CHECK_OK(ctx, lensrt_render_get_stats(ra, &st));
                CHECK(st.dark_fraction == 1.0, "side P_s: always blocking: dark fraction %g, expected 1 (decided from "
                                               "the bounds)", st.dark_fraction);
            }
            free(in);
            free(ia);
            free(id);
            lensrt_render_destroy(rn);
            lensrt_render_destroy(ra);
            lensrt_render_destroy(rd);
            lensrt_lens_destroy(ctx, gn);
            lensrt_lens_destroy(ctx, ga);
        }
}

/* 4. Stop-crossing pairs render with any aperture shape (blades, 2d), and a ghost with
 *    housing pairs only likewise. Host-scheduled tiles of a side-P_s ghost equal run()
 *    bit for bit. */
static void test_shapes_and_tiles(lensrt_context ctx)
{
    const clip_out housing[2] = {{"x_h0", "1", "0 0 0 1 0 0 0.9"}, {"y_h0", "1", "0 0 0 0 1 0 0.9"}};
    size_t n;
    char *text = smaller_stop_table(1, &n);
    lensrt_lens stop = load(ctx, "stop pair", text);
    lensrt_lens hous = load(ctx, "housing pair", ghost_table(GHOST_P_S, 1, housing, 2, NULL, &n));
    lensrt_render r;
    if (!stop || !hous) return;
    r = make_render(ctx, stop, R_STOP, LENSRT_PRECISION_DEFAULT, 1, LENSRT_APERTURE_BLADES);
    CHECK(r != NULL, "blades with a stop-crossing pair: %s", lensrt_context_last_error(ctx));
    lensrt_render_destroy(r);
    r = make_render(ctx, hous, R_STOP, LENSRT_PRECISION_DEFAULT, 1, LENSRT_APERTURE_BLADES);
    CHECK(r != NULL, "blades with housing pairs only: %s", lensrt_context_last_error(ctx));
    lensrt_render_destroy(r);
    {
        // Tiles of 7 x 7 (uneven at the edges) against run()
        lensrt_render a = make_render(ctx, stop, R_STOP, LENSRT_PRECISION_DEFAULT, 3, LENSRT_APERTURE_CIRCLE);
        lensrt_render b = make_render(ctx, stop, R_STOP, LENSRT_PRECISION_DEFAULT, 3, LENSRT_APERTURE_CIRCLE);
        float *ia, *ib;
        int x, y;
        if (a) CHECK_OK(ctx, lensrt_render_run(a, 512, NULL, NULL));
        if (b) {
            CHECK_OK(ctx, lensrt_render_tiles_begin(b, 512));
            for (y = 0; y < RES; y += 7)
                for (x = 0; x < RES; x += 7)
                    CHECK_OK(ctx, lensrt_render_tile(b, x, y, x + 7 <= RES ? 7 : RES - x, y + 7 <= RES ? 7 : RES - y));
            CHECK_OK(ctx, lensrt_render_tiles_end(b));
        }
        ia = image_of(ctx, a, 3);
        ib = image_of(ctx, b, 3);
        CHECK(total(ia, 3 * RES * RES) > 0 && memcmp(ia, ib, sizeof(float) * 3 * RES * RES) == 0,
              "tiles of a ghost differ from run() (relative L2 %.3g)", rel_l2(ib, ia, 1.0, 3 * RES * RES));
        free(ia);
        free(ib);
        lensrt_render_destroy(a);
        lensrt_render_destroy(b);
    }
    lensrt_lens_destroy(ctx, stop);
    lensrt_lens_destroy(ctx, hous);
}

/* 6. lensrt_lens_eval and lensrt_lens_system_info of P_clip (LENSRT_SYSTEM_CLIP): the
 *    hand-made x_h0 = x_a / R_SMALL, y_h0 = y_a / R_SMALL at a few rays, to rounding
 *    (one term: (s / r) * (x_a / s)); a direct table has no P_clip (UNSUPPORTED). */
static void test_eval_clip(lensrt_context ctx, lensrt_lens direct)
{
    size_t n;
    lensrt_lens g = load(ctx, "eval", smaller_stop_table(0, &n));
    lensrt_system_info si = LENSRT_SYSTEM_INFO_INIT;
    lensrt_eval_desc d = LENSRT_EVAL_DESC_INIT;
    double in[3 * 6] = {0.05, -0.02, 0.0, 1.0, -2.0, 550.0, 0.0, 0.0, 0.0, -4.0, 3.5, 450.0,
                        -0.1, 0.1, 0.0, 10.0, 0.5, 700.0};
    double out[3 * 2];
    int k;
    if (!g) return;
    CHECK_OK(ctx, lensrt_lens_system_info(g, LENSRT_SYSTEM_CLIP, &si));
    CHECK(si.n_inputs == 6 && si.n_outputs == 2 && strcmp(si.input_names[0], "x_O") == 0 &&
              strcmp(si.output_names[1], "y_h0") == 0,
          "P_clip info: %d inputs, %d outputs", si.n_inputs, si.n_outputs);
    d.system = LENSRT_SYSTEM_CLIP;
    d.n_rays = 3;
    d.inputs = in;
    d.outputs = out;
    CHECK_OK(ctx, lensrt_lens_eval(ctx, g, &d));
    for (k = 0; k < 3; k++)
        CHECK(fabs(out[2 * k] - in[6 * k + 3] / R_SMALL) < 1e-14 && fabs(out[2 * k + 1] - in[6 * k + 4] / R_SMALL) < 1e-14,
              "P_clip ray %d: (%.17g, %.17g), expected (%.17g, %.17g)", k, out[2 * k], out[2 * k + 1],
              in[6 * k + 3] / R_SMALL, in[6 * k + 4] / R_SMALL);
    CHECK_RES(ctx, LENSRT_ERROR_UNSUPPORTED, lensrt_lens_eval(ctx, direct, &d));
    CHECK_MSG(ctx, "has no system P_clip");
    CHECK(lensrt_lens_system_info(direct, LENSRT_SYSTEM_CLIP, &si) == LENSRT_ERROR_UNSUPPORTED,
          "system_info of a direct table's P_clip");
    lensrt_lens_destroy(ctx, g);
}

/* 5. lensrt_renders_image: the sum of renders' images (a direct image plus a ghost's) is
 *    each image summed (in double, then rounded to float: exactly a + b when a and b are
 *    floats whose sum is representable to rounding; checked to 1 float ulp); one render
 *    gives its own image bit for bit; another window or other wavelengths are refused
 *    (LENSRT_ERROR_INCOMPATIBLE naming the render's lens file). */
static void test_image_sum(lensrt_context ctx, lensrt_lens direct)
{
    const clip_out housing[2] = {{"x_h0", "1", "0 0 0 1 0 0 0.9"}, {"y_h0", "1", "0 0 0 0 1 0 0.9"}};
    size_t n, k;
    lensrt_lens g = load(ctx, "sum", ghost_table(GHOST_P_S, 1, housing, 2, NULL, &n));
    lensrt_render rs[3];
    float *a, *b, *sum = calloc(3 * RES * RES, sizeof(float)), *one = calloc(3 * RES * RES, sizeof(float));
    int worst_ok = 1;
    if (!g || !sum || !one) abort();
    rs[0] = make_render(ctx, direct, R_STOP, LENSRT_PRECISION_DEFAULT, 3, LENSRT_APERTURE_CIRCLE);
    rs[1] = make_render(ctx, g, R_STOP, LENSRT_PRECISION_DEFAULT, 3, LENSRT_APERTURE_CIRCLE);
    rs[2] = make_render(ctx, g, R_STOP, LENSRT_PRECISION_DEFAULT, 1, LENSRT_APERTURE_CIRCLE);
    if (rs[0] && rs[1] && rs[2]) {
        CHECK_OK(ctx, lensrt_render_run(rs[0], 256, NULL, NULL));
        CHECK_OK(ctx, lensrt_render_run(rs[1], 256, NULL, NULL));
        CHECK_OK(ctx, lensrt_render_run(rs[2], 256, NULL, NULL));
        a = image_of(ctx, rs[0], 3);
        b = image_of(ctx, rs[1], 3);
        CHECK_OK(ctx, lensrt_renders_image(rs, 2, sum, 3 * RES * RES));
        for (k = 0; k < 3 * RES * RES; k++)
            if (fabs((double)sum[k] - ((double)a[k] + (double)b[k])) > 1.2e-7 * ((double)a[k] + (double)b[k])) worst_ok = 0;
        CHECK(worst_ok && total(b, 3 * RES * RES) > 0, "renders_image: not the sum of the images");
        CHECK_OK(ctx, lensrt_renders_image(rs, 1, one, 3 * RES * RES));
        CHECK(memcmp(one, a, sizeof(float) * 3 * RES * RES) == 0, "renders_image of one render: not its image");
        {
            lensrt_render pair[2];
            pair[0] = rs[0];
            pair[1] = rs[2];
            CHECK_RES(ctx, LENSRT_ERROR_INCOMPATIBLE, lensrt_renders_image(pair, 2, sum, 3 * RES * RES));
            CHECK_MSG(ctx, "render 1 (ghost_test.table) has 1 wavelengths");
        }
        free(a);
        free(b);
    }
    lensrt_render_destroy(rs[0]);
    lensrt_render_destroy(rs[1]);
    lensrt_render_destroy(rs[2]);
    lensrt_lens_destroy(ctx, g);
    free(sum);
    free(one);
}

int main(int argc, char **argv)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    char *text;
    size_t size;
    if (argc != 2) {
        fprintf(stderr, "usage: test_ghost LENS_TABLE\n");
        return 2;
    }
    text = read_text(argv[1], &size);
    if (!text || !cut_direct(text, size)) {
        fprintf(stderr, "test_ghost: cannot read or cut %s\n", argv[1]);
        return 1;
    }
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) return 1;
    test_reader(ctx);
    {
        lensrt_lens direct = NULL;
        CHECK_OK(ctx, load_stamped(ctx, g_text, g_size, "lens0001.table", &direct));
        if (direct) {
            test_smaller_stop(ctx, direct);
            test_basis_clip(ctx, direct);
            test_shaped_stop(ctx, direct);
            test_never_always(ctx, direct);
            test_shapes_and_tiles(ctx);
            test_image_sum(ctx, direct);
            test_eval_clip(ctx, direct);
            lensrt_lens_destroy(ctx, direct);
        }
    }
    lensrt_context_destroy(ctx);
    free(text);
    printf("test_ghost: %d checks, %d failures\n", g_checks, g_failures);
    return g_failures != 0;
}
