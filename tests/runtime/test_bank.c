/* test_bank: reproducible EXRs and PSF banks (issue 23; lensrt.h, "PSF banks").
 *
 * Reproducible EXRs (lensrt_render_write_exr_with): two renders of the same scene written
 * with `reproducible` give the same bytes, without lensrt/seconds, lensrt/splatsPerSecond
 * and lensrt/lensFile; NULL options write what lensrt_render_write_exr writes; struct_size
 * 0 and a flag other than 0 or 1 are refused.
 *
 * Banks: a bank of 3 x 2 field points and 2 wavelengths of the analytic perfect lens
 * (focal length 50 mm, sensor at 50 mm: Airy patterns), each node rendered by the cells
 * integrator and written reproducible, its index written here with its checksum. Opened,
 * its info is the index's; the PSF at a node and one of its wavelengths is that channel
 * bit for bit (the node centred on its chief point), and a quarter-pixel shift of a node's
 * window is registered back (the bilinear taps); between nodes the centre is the blend of
 * the chief points; a node without an error estimate (-1) makes the worst unknown (-1);
 * `registration window` blends the nodes in place; a node EXR with layers is read.
 * Refused, each with a message naming the file: a flipped byte, a cut
 * or missing checksum line, an unknown or repeated key, a missing or repeated node, a
 * wrong node count, NaN, a path with '..', a list shorter than its count, CR line ends,
 * version 2; an EXR with a flipped byte (its CRC), and, with their right CRCs in the
 * index, one cut short, one of the wrong size and one missing a wavelength. Queries
 * outside the field or wavelength range, or at an f-number, focus or distance the bank
 * lacks: OUT_OF_DOMAIN.
 *
 * usage: test_bank LENS_TABLE SCRATCH_DIR */
#include "lensrt.h"

#include "check.h"
#include "bank_files.h"

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>

#ifndef LENSRT_TEST_EXR
#define LENSRT_TEST_EXR 1
#endif

static char g_scratch[4096];

/* The bank: 3 x 2 field points, 2 wavelengths, f/8, 16 x 16 pixels of 1.5 um (the
 * Airy pattern's first dark ring at 1.22 lambda N = 4.9-5.9 um). */
enum { NX = 3, NY = 2, NW = 2, W = 16, H = 16, NN = NX * NY, NP = W * H };
static const double FIELD_X[NX] = {-1.0, 0.0, 1.0}, FIELD_Y[NY] = {0.0, 0.5}, WAVELENGTHS[NW] = {500.0, 600.0};
/* The analytic lens's focal length (mm): its image point is FOCAL_MM tan(field) */
#define FOCAL_MM 50.0
static const double PITCH = 0.0015, F_NUMBER = 8.0;
/* Node 4's window is shifted by a quarter pixel in x from its chief point */
#define SHIFTED_NODE 4

typedef struct node_rec {
    int ix, iy;
    double center_x, center_y, error;
    uint32_t crc;
    char path[64];
    double chief[2 * NW];
    float image[NW * NP];
} node_rec;
static node_rec g_nodes[NN];
static char g_bank[4200]; /* the bank's folder */

/* Does the file hold the bytes of `text`? (EXR attribute names are plain text.) */
static int file_holds(const char *path, const char *text)
{
    size_t size, n = strlen(text), k;
    char *data = read_text(path, &size);
    int found = 0;
    for (k = 0; data && !found && k + n <= size; k++) found = memcmp(data + k, text, n) == 0;
    free(data);
    return found;
}

static int same_file(const char *a, const char *b)
{
    size_t na, nb;
    char *x = read_text(a, &na), *y = read_text(b, &nb);
    int same = x && y && na == nb && memcmp(x, y, na) == 0;
    free(x);
    free(y);
    return same;
}

/* ------------------------------------------------------- reproducible EXRs ----- */

/* A small Monte Carlo render of lens 0001 (a fitted lens: its EXR names the table). */
static lensrt_render small_render(lensrt_context ctx, lensrt_lens lens)
{
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    lensrt_render r = NULL;
    d.lens = lens;
    d.sensor.width = 8;
    d.sensor.height = 8;
    d.sensor.width_mm = 0.05;
    d.n_wavelengths = 2;
    d.seed = 7;
    if (lensrt_render_create(ctx, &d, &r) != LENSRT_SUCCESS) return NULL;
    if (lensrt_render_run(r, 512, NULL, NULL) != LENSRT_SUCCESS) {
        lensrt_render_destroy(r);
        return NULL;
    }
    return r;
}

static void test_reproducible_exr(lensrt_context ctx, const char *table)
{
    lensrt_lens lens = NULL;
    lensrt_render a = NULL, b = NULL;
    lensrt_exr_options o = LENSRT_EXR_OPTIONS_INIT;
    char pa[4200], pb[4200], plain[4200], with_null[4200];
    const lensrt_result want = LENSRT_TEST_EXR ? LENSRT_SUCCESS : LENSRT_ERROR_UNSUPPORTED;
    CHECK_OK(ctx, lensrt_lens_load(ctx, table, &lens));
    if (!lens) return;
    a = small_render(ctx, lens);
    b = small_render(ctx, lens);
    CHECK(a && b, "renders: %s", lensrt_context_last_error(ctx));
    if (a && b) {
        snprintf(pa, sizeof pa, "%s/repro-a.exr", g_scratch);
        snprintf(pb, sizeof pb, "%s/repro-b.exr", g_scratch);
        snprintf(plain, sizeof plain, "%s/plain.exr", g_scratch);
        snprintf(with_null, sizeof with_null, "%s/null-options.exr", g_scratch);
        // Two renders of one scene, written reproducible: the same bytes, no timings or path
        o.reproducible = 1;
        CHECK_RES(ctx, want, lensrt_render_write_exr_with(a, pa, &o));
        CHECK_RES(ctx, want, lensrt_render_write_exr_with(b, pb, &o));
        // NULL options: lensrt_render_write_exr's file, timings and path included
        CHECK_RES(ctx, want, lensrt_render_write_exr(a, plain));
        CHECK_RES(ctx, want, lensrt_render_write_exr_with(a, with_null, NULL));
        if (LENSRT_TEST_EXR) {
            CHECK(same_file(pa, pb), "two reproducible EXRs of the same render differ (%s, %s)", pa, pb);
            CHECK(!file_holds(pa, "lensrt/seconds") && !file_holds(pa, "lensrt/splatsPerSecond") &&
                      !file_holds(pa, "lensrt/lensFile"),
                  "a reproducible EXR holds a timing or the table's path");
            CHECK(file_holds(pa, "lensrt/focalLengthMm") && file_holds(pa, "lensrt/seed"),
                  "a reproducible EXR lost other metadata");
            CHECK(file_holds(plain, "lensrt/seconds") && file_holds(plain, "lensrt/splatsPerSecond") &&
                      file_holds(plain, "lensrt/lensFile"),
                  "lensrt_render_write_exr left out a timing or the table's path");
            CHECK(same_file(plain, with_null), "write_exr_with(NULL) differs from write_exr");
        }
        // Refused: struct_size 0, a flag other than 0 or 1
        o.struct_size = 0;
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_write_exr_with(a, pa, &o));
        CHECK_MSG(ctx, "LENSRT_*_INIT");
        o.struct_size = sizeof o;
        o.reproducible = 2;
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_write_exr_with(a, pa, &o));
        CHECK_MSG(ctx, "reproducible is 2");
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_render_write_exr_with(NULL, pa, NULL));
        o.reproducible = 1;

        // Layered files (a flare bank's nodes) alike: lensrt_layers_write_exr_with
        {
            lensrt_exr_layer layers[2] = {LENSRT_EXR_LAYER_INIT, LENSRT_EXR_LAYER_INIT};
            char la[4200], lb[4200], lplain[4200];
            layers[0].name = "direct";
            layers[0].renders = &a;
            layers[0].n_renders = 1;
            layers[1].name = "flare";
            layers[1].renders = &b;
            layers[1].n_renders = 1;
            snprintf(la, sizeof la, "%s/layers-a.exr", g_scratch);
            snprintf(lb, sizeof lb, "%s/layers-b.exr", g_scratch);
            snprintf(lplain, sizeof lplain, "%s/layers-plain.exr", g_scratch);
            CHECK_RES(ctx, want, lensrt_layers_write_exr_with(layers, 2, la, &o));
            CHECK_RES(ctx, want, lensrt_layers_write_exr_with(layers, 2, lb, &o));
            CHECK_RES(ctx, want, lensrt_layers_write_exr_with(layers, 2, lplain, NULL));
            if (LENSRT_TEST_EXR) {
                CHECK(same_file(la, lb), "two reproducible layered EXRs of the same renders differ");
                CHECK(!file_holds(la, "lensrt/seconds") && !file_holds(la, "lensrt/lensFile") &&
                          file_holds(la, "lensrt/layers"),
                      "a reproducible layered EXR holds a timing or the table's path, or lost its layers");
                CHECK(file_holds(lplain, "lensrt/seconds"), "layers_write_exr_with(NULL) left out the timings");
            }
            o.reproducible = 3;
            CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_layers_write_exr_with(layers, 2, la, &o));
            CHECK_MSG(ctx, "reproducible is 3");
        }
    }
    lensrt_render_destroy(a);
    lensrt_render_destroy(b);
    lensrt_lens_destroy(ctx, lens);
}

/* ------------------------------------------------------------------ banks ----- */

/* A render of the analytic lens for a light at (fx, fy) deg: w x h pixels of PITCH
 * centred on (cx, cy), at `n_wl` of the bank's wavelengths, by the cells integrator. */
static lensrt_render node_render(lensrt_context ctx, lensrt_lens lens, double fx, double fy, double cx, double cy, int w,
                                 int h, int n_wl, double *error)
{
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    lensrt_light light = LENSRT_LIGHT_INIT;
    lensrt_render r = NULL;
    light.field_x_deg = fx;
    light.field_y_deg = fy;
    d.lens = lens;
    d.sensor.width = w;
    d.sensor.height = h;
    d.sensor.width_mm = w * PITCH;
    d.sensor.center_x_mm = cx;
    d.sensor.center_y_mm = cy;
    d.aperture.f_number = F_NUMBER;
    d.lights = &light;
    d.n_lights = 1;
    d.wavelengths_nm = WAVELENGTHS;
    d.n_wavelengths = n_wl;
    if (lensrt_render_create(ctx, &d, &r) != LENSRT_SUCCESS) return NULL;
    if (lensrt_render_integrate(r, 8, error, NULL, NULL) != LENSRT_SUCCESS) {
        lensrt_render_destroy(r);
        return NULL;
    }
    return r;
}

/* Render and write every node; 1 when all went well. */
static int build_nodes(lensrt_context ctx, lensrt_lens lens)
{
    lensrt_exr_options o = LENSRT_EXR_OPTIONS_INIT;
    int k, w;
    o.reproducible = 1;
    for (k = 0; k < NN; k++) {
        node_rec *n = &g_nodes[k];
        lensrt_light light = LENSRT_LIGHT_INIT;
        lensrt_render r;
        char path[4400];
        size_t size;
        char *bytes;
        n->ix = k % NX;
        n->iy = k / NX;
        light.field_x_deg = FIELD_X[n->ix];
        light.field_y_deg = FIELD_Y[n->iy];
        // The chief point at each wavelength (the same for a perfect lens); the window on it
        for (w = 0; w < NW; w++)
            CHECK_OK(ctx, lensrt_lens_image_point(ctx, lens, &light, WAVELENGTHS[w], 0.0, &n->chief[2 * w]));
        n->center_x = n->chief[0] + (k == SHIFTED_NODE ? 0.25 * PITCH : 0.0);
        n->center_y = n->chief[1];
        r = node_render(ctx, lens, light.field_x_deg, light.field_y_deg, n->center_x, n->center_y, W, H, NW, &n->error);
        CHECK(r != NULL, "node %d: %s", k, lensrt_context_last_error(ctx));
        if (!r) return 0;
        CHECK_OK(ctx, lensrt_render_image(r, n->image, NW * NP));
        snprintf(n->path, sizeof n->path, "nodes/f8-z0-d0-y%d-x%d.exr", n->iy, n->ix);
        snprintf(path, sizeof path, "%s/%s", g_bank, n->path);
        CHECK_OK(ctx, lensrt_render_write_exr_with(r, path, &o));
        lensrt_render_destroy(r);
        bytes = read_text(path, &size);
        CHECK(bytes != NULL, "cannot read %s back", path);
        if (!bytes) return 0;
        n->crc = test_crc32(bytes, size);
        free(bytes);
    }
    return 1;
}

/* The index's body (everything before the checksum line), malloc'd. */
static char *index_body(void)
{
    size_t size = 1 << 16, used = 0;
    char *s = malloc(size);
    int k, w;
    if (!s) return NULL;
#define PUT(...) (used += (size_t)snprintf(s + used, size - used, __VA_ARGS__))
    PUT("lensrt-bank 1\nlens analytic-f50\ntable_crc32 0badf00d\nwidth %d\nheight %d\npixel_mm %.17g %.17g\n", W, H,
        PITCH, PITCH);
    PUT("wavelengths_nm %d %.17g %.17g\n", NW, WAVELENGTHS[0], WAVELENGTHS[1]);
    PUT("f_numbers 1 8\nfocus_offsets_mm 1 0\ndistances_mm 1 0\n");
    PUT("field_x_deg %d %.17g %.17g %.17g\n", NX, FIELD_X[0], FIELD_X[1], FIELD_X[2]);
    PUT("field_y_deg %d %.17g %.17g\n", NY, FIELD_Y[0], FIELD_Y[1]);
    PUT("nodes %d\n", NN);
    for (k = 0; k < NN; k++) {
        const node_rec *n = &g_nodes[k];
        PUT("node %d 0 0 0 %d %d %.17g %.17g %.17g %08x %s\nchief %d", k, n->iy, n->ix, n->center_x, n->center_y,
            n->error, (unsigned)n->crc, n->path, k);
        for (w = 0; w < 2 * NW; w++) PUT(" %.17g", n->chief[w]);
        PUT("\n");
    }
#undef PUT
    return s;
}

/* `s` with its first `a` replaced by `b` (malloc'd; a copy when `a` is absent, which
 * the caller checks). */
static char *replace_once(const char *s, const char *a, const char *b)
{
    const char *at = strstr(s, a);
    size_t n = strlen(s), na = strlen(a), nb = strlen(b);
    char *out = malloc(n + nb + 1);
    if (!out) return NULL;
    if (!at) {
        memcpy(out, s, n + 1);
        return out;
    }
    memcpy(out, s, (size_t)(at - s));
    memcpy(out + (at - s), b, nb);
    memcpy(out + (at - s) + nb, at + na, n - (size_t)(at - s) - na + 1);
    return out;
}

/* Write `body` and its checksum line (stamp 1) or the body alone (stamp 0) as
 * <bank>/<name>; the path in `path`. */
static void write_index(const char *body, const char *name, int stamp, char *path, size_t size)
{
    size_t n = strlen(body);
    char *text = malloc(n + 32);
    snprintf(path, size, "%s/%s", g_bank, name);
    if (!text) return;
    memcpy(text, body, n);
    if (stamp) n += (size_t)sprintf(text + n, "checksum crc32 %08x\n", (unsigned)test_crc32(body, n));
    CHECK(write_bytes(path, text, n), "cannot write %s", path);
    free(text);
}

/* The index `body` with `a` replaced by `b`, stamped, must be refused with `result` and a
 * message holding the index's name and `needle`. */
static void expect_refused(lensrt_context ctx, const char *body, const char *a, const char *b, lensrt_result result,
                           const char *needle)
{
    char path[4400], *edited = replace_once(body, a, b);
    lensrt_bank bank = NULL;
    lensrt_result got;
    if (!edited) return;
    CHECK(strstr(body, a) != NULL, "the index has no '%s' to replace", a);
    write_index(edited, "bad.index", 1, path, sizeof path);
    got = lensrt_bank_open(ctx, path, &bank);
    // A node's EXR is read when first needed (lensrt_bank_load_nodes: all of them now)
    if (got == LENSRT_SUCCESS) {
        got = lensrt_bank_load_nodes(bank);
        lensrt_bank_close(bank);
        bank = NULL;
    }
    CHECK_RES(ctx, result, got);
    CHECK(bank == NULL, "a refused bank was handed out");
    CHECK_MSG(ctx, needle);
    CHECK_MSG(ctx, "bad.index");
    lensrt_bank_close(bank);
    free(edited);
}

/* The PSF at a node and one of its wavelengths is the node's channel; shifted a quarter
 * pixel, the taps register it back; between nodes the centre is the blend. */
static void test_psf(lensrt_context ctx, lensrt_bank bank)
{
    lensrt_bank_query q = LENSRT_BANK_QUERY_INIT;
    static float psf[NP];
    double chief[2];
    int k, w, p, exact = 1, close = 1;
    for (k = 0; k < NN; k++)
        for (w = 0; w < NW; w++) {
            const node_rec *n = &g_nodes[k];
            q.field_x_deg = FIELD_X[n->ix];
            q.field_y_deg = FIELD_Y[n->iy];
            q.wavelength_nm = WAVELENGTHS[w];
            CHECK_OK(ctx, lensrt_bank_psf(bank, &q, psf, NP, chief));
            CHECK(chief[0] == n->chief[2 * w] && chief[1] == n->chief[2 * w + 1],
                  "node %d at %g nm: centre (%.17g, %.17g), its chief point (%.17g, %.17g)", k, WAVELENGTHS[w], chief[0],
                  chief[1], n->chief[2 * w], n->chief[2 * w + 1]);
            for (p = 0; p < NP; p++) {
                const float *img = n->image + (size_t)w * NP;
                if (k != SHIFTED_NODE) {
                    exact = exact && psf[p] == img[p];
                } else {
                    // The window is a quarter pixel right of the chief point: pixel i takes
                    // 1/4 of node pixel i - 1 and 3/4 of node pixel i
                    const int i = p % W;
                    const double want = 0.75 * img[p] + (i > 0 ? 0.25 * img[p - 1] : 0.0);
                    close = close && fabs(psf[p] - want) <= 1e-6 * (fabs(want) + 1e-30) + 1e-7 * img[NP / 2];
                }
            }
        }
    CHECK(exact, "the PSF at a node centred on its chief point is not its channel bit for bit");
    CHECK(close, "the PSF at node %d (a quarter pixel off its chief point) is not the registered image", SHIFTED_NODE);
    // Between two nodes (x) and two wavelengths: the centre is the chief points interpolated
    // in tan(field), which for the perfect lens (its image point f tan(field) at every
    // wavelength) is its image point there, to the weights' rounding
    q.field_x_deg = -0.5;
    q.field_y_deg = 0.0;
    q.wavelength_nm = 550.0;
    CHECK_OK(ctx, lensrt_bank_psf(bank, &q, psf, NP, chief));
    {
        const double cx = FOCAL_MM * tan(-0.5 * 3.14159265358979323846 / 180.0), cy = 0.0;
        double sum = 0.0, node_sum = 0.0;
        CHECK(fabs(chief[0] - cx) < 1e-12 && fabs(chief[1] - cy) < 1e-12, "centre (%.17g, %.17g), expected (%.17g, %.17g)",
              chief[0], chief[1], cx, cy);
        for (p = 0; p < NP; p++) {
            sum += psf[p];
            node_sum += 0.5 * (g_nodes[0].image[p] + g_nodes[0].image[NP + p]);
        }
        CHECK(fabs(sum - node_sum) < 0.02 * node_sum, "PSF sum between nodes %g, a node's %g", sum, node_sum);
    }
    // The NULL centre is allowed; the count must be the image's
    CHECK_OK(ctx, lensrt_bank_psf(bank, &q, psf, NP, NULL));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_bank_psf(bank, &q, psf, NP - 1, NULL));
    CHECK_MSG(ctx, "count must be 256");
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_bank_psf(bank, &q, NULL, NP, NULL));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_bank_psf(NULL, &q, psf, NP, NULL));
    // Out of the bank: field, wavelength, and a slice it does not hold
    q.field_x_deg = 1.5;
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_bank_psf(bank, &q, psf, NP, chief));
    CHECK_MSG(ctx, "field_x_deg 1.5 is outside the bank's range [-1, 1]");
    q.field_x_deg = 0.0;
    q.field_y_deg = -0.1;
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_bank_psf(bank, &q, psf, NP, chief));
    CHECK_MSG(ctx, "field_y_deg -0.10000000000000001 is outside the bank's range [0, 0.5]");
    q.field_y_deg = 0.25;
    q.wavelength_nm = 450.0;
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_bank_psf(bank, &q, psf, NP, chief));
    CHECK_MSG(ctx, "wavelength_nm 450 is outside the bank's range [500, 600]");
    q.wavelength_nm = 600.0;
    q.f_number = 5.6;
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_bank_psf(bank, &q, psf, NP, chief));
    CHECK_MSG(ctx, "f_number 5.5999999999999996 is not one of the bank's: 8");
    q.f_number = 8.0;
    CHECK_OK(ctx, lensrt_bank_psf(bank, &q, psf, NP, chief));
    q.focus_offset_mm = 0.1;
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_bank_psf(bank, &q, psf, NP, chief));
    CHECK_MSG(ctx, "focus_offset_mm");
    q.focus_offset_mm = 0.0;
    q.distance_mm = 1000.0;
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_bank_psf(bank, &q, psf, NP, chief));
    CHECK_MSG(ctx, "distance_mm 1000 is not one of the bank's: 0");
    q.distance_mm = NAN;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_bank_psf(bank, &q, psf, NP, chief));
    q.distance_mm = 0.0;
    q.struct_size = 0;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_bank_psf(bank, &q, psf, NP, chief));
    CHECK_MSG(ctx, "LENSRT_*_INIT");
}

static void test_info(lensrt_context ctx, lensrt_bank bank)
{
    lensrt_bank_info info = LENSRT_BANK_INFO_INIT;
    double worst = 0.0;
    int k;
    for (k = 0; k < NN; k++) worst = g_nodes[k].error > worst ? g_nodes[k].error : worst;
    CHECK_OK(ctx, lensrt_bank_get_info(bank, &info));
    CHECK(info.lens_name && strcmp(info.lens_name, "analytic-f50") == 0, "lens name '%s'",
          info.lens_name ? info.lens_name : "(null)");
    CHECK(info.table_crc32 == 0x0badf00du, "table_crc32 %08x", (unsigned)info.table_crc32);
    CHECK(info.width == W && info.height == H && info.pixel_x_mm == PITCH && info.pixel_y_mm == PITCH,
          "size %d x %d, pitch %g x %g", info.width, info.height, info.pixel_x_mm, info.pixel_y_mm);
    CHECK(info.n_wavelengths == NW && info.wavelengths_nm[0] == 500.0 && info.wavelengths_nm[1] == 600.0,
          "wavelengths");
    CHECK(info.n_f_numbers == 1 && info.f_numbers[0] == 8.0 && info.n_focus_offsets == 1 &&
              info.focus_offsets_mm[0] == 0.0 && info.n_distances == 1 && info.distances_mm[0] == 0.0,
          "f-numbers, focus offsets, distances");
    CHECK(info.n_field_x == NX && info.field_x_deg[0] == -1.0 && info.field_x_deg[2] == 1.0 && info.n_field_y == NY &&
              info.field_y_deg[1] == 0.5,
          "field grid");
    CHECK(info.n_nodes == NN && info.worst_error_estimate == worst && worst > 0.0,
          "%d nodes, worst estimate %g (expected %g)", info.n_nodes, info.worst_error_estimate, worst);
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_bank_get_info(NULL, &info));
}

/* Damaged indexes, each refused naming the index. */
static void test_index_refusals(lensrt_context ctx, const char *body)
{
    char path[4400], line[512], to[512], *text, *cut;
    size_t n = strlen(body);
    lensrt_bank bank = NULL;
    // The checksum line: a flipped byte, cut short, missing
    write_index(body, "bad.index", 1, path, sizeof path);
    text = read_text(path, &n);
    if (text) {
        text[n / 2] ^= 0x01;
        CHECK(write_bytes(path, text, n), "cannot write %s", path);
        CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_bank_open(ctx, path, &bank));
        CHECK_MSG(ctx, "bad.index");
        CHECK_MSG(ctx, "does not match the content");
        CHECK(write_bytes(path, text, n / 2), "cannot write %s", path);
        CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_bank_open(ctx, path, &bank));
        CHECK_MSG(ctx, "bad.index");
        CHECK_MSG(ctx, "expected the last line 'checksum crc32");
        free(text);
    }
    write_index(body, "bad.index", 0, path, sizeof path);
    CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_bank_open(ctx, path, &bank));
    CHECK_MSG(ctx, "bad.index");
    CHECK_MSG(ctx, "expected the last line 'checksum crc32");
    // Keys: unknown, repeated, the version
    expect_refused(ctx, body, "table_crc32", "colour red\ntable_crc32", LENSRT_ERROR_PARSE,
                   "bad.index:3: unknown key 'colour'");
    expect_refused(ctx, body, "height", "width 16\nheight", LENSRT_ERROR_PARSE,
                   "bad.index:5: key 'width' is out of order or repeated");
    expect_refused(ctx, body, "lensrt-bank 1", "lensrt-bank 2", LENSRT_ERROR_PARSE, "version 2");
    expect_refused(ctx, body, "lens analytic-f50\n", "lens analytic-f50\r\n", LENSRT_ERROR_PARSE, "carriage return");
    expect_refused(ctx, body, "height 16\n", "height 16\n\n", LENSRT_ERROR_PARSE, "blank line");
    expect_refused(ctx, body, "height 16", "height  16", LENSRT_ERROR_PARSE, "two spaces");
    // Counts and values
    expect_refused(ctx, body, "wavelengths_nm 2", "wavelengths_nm 3", LENSRT_ERROR_PARSE,
                   "'wavelengths_nm' says 3 values and gives 2");
    expect_refused(ctx, body, "wavelengths_nm 2 500 600", "wavelengths_nm 2 600 500", LENSRT_ERROR_PARSE,
                   "strictly increasing");
    expect_refused(ctx, body, "nodes 6", "nodes 5", LENSRT_ERROR_PARSE, "'nodes 5': expected 1 x 1 x 1 x 2 x 3 = 6");
    snprintf(line, sizeof line, "pixel_mm %.17g", PITCH);
    expect_refused(ctx, body, line, "pixel_mm nan", LENSRT_ERROR_PARSE,
                   "'pixel_mm': value 1 'nan' is not a finite decimal number");
    snprintf(line, sizeof line, "node 2 0 0 0 %d %d %.17g", g_nodes[2].iy, g_nodes[2].ix, g_nodes[2].center_x);
    snprintf(to, sizeof to, "node 2 0 0 0 %d %d NaN", g_nodes[2].iy, g_nodes[2].ix);
    expect_refused(ctx, body, line, to, LENSRT_ERROR_PARSE, "'node': value 7 'NaN' is not a finite");
    // Nodes: a path with '..', a tuple twice, one missing
    expect_refused(ctx, body, g_nodes[1].path, "../nodes/x.exr", LENSRT_ERROR_PARSE, "holds '..'");
    expect_refused(ctx, body, g_nodes[1].path, "/tmp/x.exr", LENSRT_ERROR_PARSE, "starts with '/'");
    snprintf(line, sizeof line, "node 1 0 0 0 %d %d ", g_nodes[1].iy, g_nodes[1].ix);
    expect_refused(ctx, body, line, "node 1 0 0 0 0 0 ", LENSRT_ERROR_PARSE,
                   "node 1 has the indices (0, 0, 0, 0, 0) of the node at line 14");
    cut = malloc(n + 1);
    if (cut) {
        // The body without its last node and chief lines
        const char *last = strstr(body, "node 5 ");
        memcpy(cut, body, (size_t)(last - body));
        cut[last - body] = '\0';
        write_index(cut, "bad.index", 1, path, sizeof path);
        CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_bank_open(ctx, path, &bank));
        CHECK_MSG(ctx, "bad.index:24: the index ends before its 'node' line");
        free(cut);
    }
    // A line after the last node
    if ((text = malloc(n + 16)) != NULL) {
        snprintf(text, n + 16, "%sextra 1\n", body);
        write_index(text, "bad.index", 1, path, sizeof path);
        CHECK_RES(ctx, LENSRT_ERROR_PARSE, lensrt_bank_open(ctx, path, &bank));
        CHECK_MSG(ctx, "bad.index:26: 'extra' after the last node (6 nodes)");
        free(text);
    }
}

/* Damaged or wrong node EXRs, each refused naming the EXR. */
static void test_exr_refusals(lensrt_context ctx, lensrt_lens lens, const char *body)
{
    lensrt_exr_options o = LENSRT_EXR_OPTIONS_INIT;
    char path[4400], from[128], to[128], *bytes;
    size_t size;
    lensrt_render r;
    double err;
    o.reproducible = 1;
    snprintf(from, sizeof from, "%08x %s", (unsigned)g_nodes[0].crc, g_nodes[0].path);
    // A flipped byte: the CRC in the index no longer matches
    snprintf(path, sizeof path, "%s/%s", g_bank, g_nodes[0].path);
    bytes = read_text(path, &size);
    if (bytes) {
        bytes[size / 2] ^= 0x10;
        snprintf(path, sizeof path, "%s/nodes/flipped.exr", g_bank);
        CHECK(write_bytes(path, bytes, size), "cannot write %s", path);
        free(bytes);
        snprintf(to, sizeof to, "%08x nodes/flipped.exr", (unsigned)g_nodes[0].crc);
        expect_refused(ctx, body, from, to, LENSRT_ERROR_PARSE, "nodes/flipped.exr: node 0 (bank index");
        CHECK_MSG(ctx, "the EXR was changed or damaged");
    }
    // A cut EXR whose CRC the index has: OpenEXRCore's refusal, naming the file
    snprintf(path, sizeof path, "%s/%s", g_bank, g_nodes[0].path);
    if ((bytes = read_text(path, &size)) != NULL) {
        snprintf(path, sizeof path, "%s/nodes/cut.exr", g_bank);
        CHECK(write_bytes(path, bytes, size / 2), "cannot write %s", path);
        snprintf(to, sizeof to, "%08x nodes/cut.exr", (unsigned)test_crc32(bytes, size / 2));
        expect_refused(ctx, body, from, to, LENSRT_ERROR_PARSE, "nodes/cut.exr: node 0 (bank index");
        CHECK_MSG(ctx, "not a readable EXR");
        free(bytes);
    }
    // A layered EXR (lensrt_layers_write_exr): its layers are ignored, the unprefixed sum read
    r = node_render(ctx, lens, FIELD_X[0], FIELD_Y[0], g_nodes[0].center_x, g_nodes[0].center_y, W, H, NW, &err);
    snprintf(path, sizeof path, "%s/nodes/layered.exr", g_bank);
    if (r) {
        lensrt_exr_layer layer = LENSRT_EXR_LAYER_INIT;
        lensrt_bank bank = NULL;
        char index[4400], *edited;
        layer.name = "direct";
        layer.renders = &r;
        layer.n_renders = 1;
        CHECK_OK(ctx, lensrt_layers_write_exr(&layer, 1, path));
        if ((bytes = read_text(path, &size)) != NULL) {
            snprintf(to, sizeof to, "%08x nodes/layered.exr", (unsigned)test_crc32(bytes, size));
            if ((edited = replace_once(body, from, to)) != NULL) {
                write_index(edited, "layered.index", 1, index, sizeof index);
                CHECK_OK(ctx, lensrt_bank_open(ctx, index, &bank));
                lensrt_bank_close(bank);
                free(edited);
            }
            free(bytes);
        }
    }
    lensrt_render_destroy(r);
    // A missing file
    snprintf(to, sizeof to, "%08x nodes/absent.exr", (unsigned)g_nodes[0].crc);
    expect_refused(ctx, body, from, to, LENSRT_ERROR_IO, "nodes/absent.exr: cannot open");
    // A valid EXR of the wrong size, and one without the second wavelength, with their CRCs
    r = node_render(ctx, lens, 0.0, 0.0, g_nodes[1].center_x, g_nodes[1].center_y, 8, 8, NW, &err);
    snprintf(path, sizeof path, "%s/nodes/small.exr", g_bank);
    CHECK(r != NULL, "small render: %s", lensrt_context_last_error(ctx));
    if (r) CHECK_OK(ctx, lensrt_render_write_exr_with(r, path, &o));
    lensrt_render_destroy(r);
    if ((bytes = read_text(path, &size)) != NULL) {
        snprintf(to, sizeof to, "%08x nodes/small.exr", (unsigned)test_crc32(bytes, size));
        expect_refused(ctx, body, from, to, LENSRT_ERROR_PARSE, "nodes/small.exr: node 0 (bank index");
        CHECK_MSG(ctx, "the image is 8 x 8 pixels from (0, 0); the index says 16 x 16");
        free(bytes);
    }
    r = node_render(ctx, lens, 0.0, 0.0, g_nodes[1].center_x, g_nodes[1].center_y, W, H, 1, &err);
    snprintf(path, sizeof path, "%s/nodes/mono.exr", g_bank);
    CHECK(r != NULL, "one-wavelength render: %s", lensrt_context_last_error(ctx));
    if (r) CHECK_OK(ctx, lensrt_render_write_exr_with(r, path, &o));
    lensrt_render_destroy(r);
    if ((bytes = read_text(path, &size)) != NULL) {
        snprintf(to, sizeof to, "%08x nodes/mono.exr", (unsigned)test_crc32(bytes, size));
        expect_refused(ctx, body, from, to, LENSRT_ERROR_PARSE, "nodes/mono.exr: node 0 (bank index");
        CHECK_MSG(ctx, "no channel 'S0.600,000000nm'");
        free(bytes);
    }
}

static void test_bank(lensrt_context ctx)
{
    lensrt_analytic_lens m = LENSRT_ANALYTIC_LENS_INIT;
    lensrt_lens lens = NULL;
    lensrt_bank bank = NULL;
    char path[4400], nodes[4400], *body;
    snprintf(g_bank, sizeof g_bank, "%s/bank", g_scratch);
    snprintf(nodes, sizeof nodes, "%s/nodes", g_bank);
    CHECK((mkdir(g_bank, 0777) == 0 || errno == EEXIST) && (mkdir(nodes, 0777) == 0 || errno == EEXIST),
          "cannot create %s", nodes);
    m.focal_length_mm = 50.0;
    m.sensor_distance_mm = 50.0;
    CHECK_OK(ctx, lensrt_lens_create_analytic(ctx, &m, &lens));
    if (!lens || !build_nodes(ctx, lens) || !(body = index_body())) {
        lensrt_lens_destroy(ctx, lens);
        return;
    }
    // The bank as written opens, and says what its index says
    write_index(body, "bank.index", 1, path, sizeof path);
    CHECK_OK(ctx, lensrt_bank_open(ctx, path, &bank));
    if (bank) {
        test_info(ctx, bank);
        test_psf(ctx, bank);
        lensrt_bank_close(bank);
    }
    // A node without an error estimate (-1): the worst is unknown; below -1 is refused
    {
        char a[128], b[128], *edited;
        lensrt_bank_info info = LENSRT_BANK_INFO_INIT;
        snprintf(a, sizeof a, " %.17g %08x ", g_nodes[3].error, (unsigned)g_nodes[3].crc);
        snprintf(b, sizeof b, " -1 %08x ", (unsigned)g_nodes[3].crc);
        if ((edited = replace_once(body, a, b)) != NULL) {
            CHECK(strcmp(edited, body) != 0, "no '%s' in the index", a);
            write_index(edited, "unknown.index", 1, path, sizeof path);
            CHECK_OK(ctx, lensrt_bank_open(ctx, path, &bank));
            if (bank) CHECK_OK(ctx, lensrt_bank_get_info(bank, &info));
            CHECK(info.worst_error_estimate == -1.0, "worst estimate %g with a node of none",
                  info.worst_error_estimate);
            lensrt_bank_close(bank);
            bank = NULL;
            free(edited);
        }
        snprintf(b, sizeof b, " -0.5 %08x ", (unsigned)g_nodes[3].crc);
        expect_refused(ctx, body, a, b, LENSRT_ERROR_PARSE, "node 3: error_estimate -0.5 is negative");
    }
    // Registration: chief said explicitly is the default; window blends the nodes in place
    {
        static float psf[NP];
        char *edited;
        lensrt_bank_query q = LENSRT_BANK_QUERY_INIT;
        const node_rec *n = &g_nodes[SHIFTED_NODE];
        double chief[2];
        char pixel[128], with[160];
        int p, same = 1;
        snprintf(pixel, sizeof pixel, "pixel_mm %.17g %.17g\n", PITCH, PITCH);
        snprintf(with, sizeof with, "%sregistration chief\n", pixel);
        if ((edited = replace_once(body, pixel, with)) != NULL) {
            write_index(edited, "chief.index", 1, path, sizeof path);
            CHECK_OK(ctx, lensrt_bank_open(ctx, path, &bank));
            lensrt_bank_close(bank);
            bank = NULL;
            free(edited);
        }
        snprintf(with, sizeof with, "%sregistration window\n", pixel);
        if ((edited = replace_once(body, pixel, with)) != NULL) {
            write_index(edited, "window.index", 1, path, sizeof path);
            CHECK_OK(ctx, lensrt_bank_open(ctx, path, &bank));
            q.field_x_deg = FIELD_X[n->ix];
            q.field_y_deg = FIELD_Y[n->iy];
            q.wavelength_nm = WAVELENGTHS[1];
            if (bank) CHECK_OK(ctx, lensrt_bank_psf(bank, &q, psf, NP, chief));
            for (p = 0; bank && p < NP; p++) same = same && psf[p] == n->image[NP + p];
            CHECK(bank && same, "registration window: the PSF at node %d is not its image in place", SHIFTED_NODE);
            lensrt_bank_close(bank);
            bank = NULL;
            free(edited);
        }
        snprintf(with, sizeof with, "%sregistration both\n", pixel);
        expect_refused(ctx, body, pixel, with, LENSRT_ERROR_PARSE,
                       "bad.index:7: 'registration' takes 'chief', 'window' or 'channel'");
    }
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_bank_open(ctx, NULL, &bank));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_bank_open(ctx, path, NULL));
    lensrt_bank_close(NULL);
    test_index_refusals(ctx, body);
    test_exr_refusals(ctx, lens, body);
    free(body);
    lensrt_lens_destroy(ctx, lens);
}

/* Without OpenEXR: the index is read and checked, then the node images are refused. */
static void test_bank_without_exr(lensrt_context ctx)
{
    char path[4400], nodes[4400], *body;
    static const char fake[] = "not an EXR";
    lensrt_bank bank = NULL;
    int k;
    snprintf(g_bank, sizeof g_bank, "%s/bank", g_scratch);
    snprintf(nodes, sizeof nodes, "%s/nodes", g_bank);
    CHECK((mkdir(g_bank, 0777) == 0 || errno == EEXIST) && (mkdir(nodes, 0777) == 0 || errno == EEXIST),
          "cannot create %s", nodes);
    for (k = 0; k < NN; k++) {
        node_rec *n = &g_nodes[k];
        n->ix = k % NX;
        n->iy = k / NX;
        n->error = 0.01;
        n->crc = test_crc32(fake, sizeof fake);
        snprintf(n->path, sizeof n->path, "nodes/n%d.exr", k);
        snprintf(path, sizeof path, "%s/%s", g_bank, n->path);
        CHECK(write_bytes(path, fake, sizeof fake), "cannot write %s", path);
    }
    if (!(body = index_body())) return;
    write_index(body, "bank.index", 1, path, sizeof path);
    // The index opens (nodes are read on first use); reading a node is unsupported
    CHECK_OK(ctx, lensrt_bank_open(ctx, path, &bank));
    CHECK_RES(ctx, LENSRT_ERROR_UNSUPPORTED, lensrt_bank_load_nodes(bank));
    CHECK_MSG(ctx, "without OpenEXR");
    lensrt_bank_close(bank);
    free(body);
}

/* The context's allocator, counting: the bytes live now and the most at once. Each block
 * carries its size in front (16 bytes, keeping malloc's alignment). */
typedef struct counted {
    size_t live, peak;
} counted;

static void *counting_alloc(size_t size, void *user_data)
{
    counted *c = user_data;
    unsigned char *p = malloc(size + 16);
    if (!p) return NULL;
    memcpy(p, &size, sizeof size);
    c->live += size;
    if (c->live > c->peak) c->peak = c->live;
    return p + 16;
}

static void counting_free(void *ptr, void *user_data)
{
    counted *c = user_data;
    size_t size;
    if (!ptr) return;
    memcpy(&size, (unsigned char *)ptr - 16, sizeof size);
    c->live -= size;
    free((unsigned char *)ptr - 16);
}

/* A bank of LENSRT_MAX_BANK_NODES nodes (256 x 256 field points, 64 x 64 pixels, one
 * wavelength: 1 GiB of node images) opens in the memory of its index: node images are
 * read when first used. Every node names the same file, so the test writes one. */
static void test_largest_bank(void)
{
    enum { SIDE = 256, PIX = 64 };
    static const char fake[] = "not read until a query needs it";
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    lensrt_bank bank = NULL;
    lensrt_bank_info info = LENSRT_BANK_INFO_INIT;
    counted use = {0, 0};
    size_t before;
    char folder[4300], path[4400], *text;
    size_t n = 0, cap = (size_t)SIDE * SIDE * 96 + 65536;
    int k;
    init.alloc_fn = counting_alloc;
    init.free_fn = counting_free;
    init.user_data = &use;
    init.threads = 1;
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) {
        CHECK(0, "lensrt_context_create with a counting allocator failed");
        return;
    }
    snprintf(folder, sizeof folder, "%s/largest", g_scratch);
    snprintf(path, sizeof path, "%s/nodes", folder);
    CHECK((mkdir(folder, 0777) == 0 || errno == EEXIST) && (mkdir(path, 0777) == 0 || errno == EEXIST),
          "cannot create %s", path);
    snprintf(path, sizeof path, "%s/nodes/n.exr", folder);
    CHECK(write_bytes(path, fake, sizeof fake), "cannot write %s", path);
    if (!(text = malloc(cap))) {
        lensrt_context_destroy(ctx);
        return;
    }
    n += (size_t)sprintf(text + n, "lensrt-bank 1\nlens big\ntable_crc32 00000000\nwidth %d\nheight %d\n"
                         "pixel_mm 0.001 0.001\nregistration channel\nwavelengths_nm 1 550\nf_numbers 1 8\n"
                         "focus_offsets_mm 1 0\ndistances_mm 1 0\n", PIX, PIX);
    n += (size_t)sprintf(text + n, "field_x_deg %d", SIDE);
    for (k = 0; k < SIDE; k++) n += (size_t)sprintf(text + n, " %g", -12.8 + 0.1 * k);
    n += (size_t)sprintf(text + n, "\nfield_y_deg %d", SIDE);
    for (k = 0; k < SIDE; k++) n += (size_t)sprintf(text + n, " %g", -12.8 + 0.1 * k);
    n += (size_t)sprintf(text + n, "\nnodes %d\n", SIDE * SIDE);
    for (k = 0; k < SIDE * SIDE; k++)
        n += (size_t)sprintf(text + n, "node %d 0 0 0 %d %d 0 0 0.01 %08x nodes/n.exr\nchief %d %g %g\n", k, k / SIDE,
                             k % SIDE, (unsigned)test_crc32(fake, sizeof fake), k, 0.1 * (k % SIDE), 0.1 * (k / SIDE));
    n += (size_t)sprintf(text + n, "checksum crc32 %08x\n", (unsigned)test_crc32(text, n));
    snprintf(path, sizeof path, "%s/bank.index", folder);
    CHECK(write_bytes(path, text, n), "cannot write %s", path);
    free(text);
    before = use.live; /* the context's own */
    use.peak = before;
    CHECK_OK(ctx, lensrt_bank_open(ctx, path, &bank));
    if (bank) {
        CHECK_OK(ctx, lensrt_bank_get_info(bank, &info));
        CHECK(info.n_nodes == LENSRT_MAX_BANK_NODES, "%d nodes", info.n_nodes);
        // The index's bytes while it is read, then its nodes: tens of MB, not the images' GiB
        CHECK(use.peak < ((size_t)64 << 20), "opening took %zu bytes at most", use.peak);
        CHECK(use.live < ((size_t)16 << 20), "an open bank holds %zu bytes", use.live);
        printf("test_bank: %d nodes opened in %.1f MB at most, %.1f MB held (their images: %.0f MB)\n",
               info.n_nodes, (double)(use.peak - before) / 1e6, (double)(use.live - before) / 1e6,
               (double)LENSRT_MAX_BANK_NODES * PIX * PIX * sizeof(float) / 1e6);
        lensrt_bank_close(bank);
    }
    CHECK(use.live == before, "%zu bytes left after closing", use.live - before);
    lensrt_context_destroy(ctx);
}

int main(int argc, char **argv)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    if (argc < 3) {
        fprintf(stderr, "usage: %s LENS_TABLE SCRATCH_DIR\n", argv[0]);
        return 2;
    }
    snprintf(g_scratch, sizeof g_scratch, "%s", argv[2]);
    if (mkdir(g_scratch, 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "cannot create the scratch folder '%s': %s\n", g_scratch, strerror(errno));
        return 2;
    }
    init.threads = 2;
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) {
        fprintf(stderr, "lensrt_context_create failed\n");
        return 1;
    }
    test_reproducible_exr(ctx, argv[1]);
    test_largest_bank();
    if (LENSRT_TEST_EXR) test_bank(ctx);
    else test_bank_without_exr(ctx);
    lensrt_context_destroy(ctx);
    printf("test_bank: %d checks, %d failed\n", g_checks, g_failures);
    return g_failures == 0 ? 0 : 1;
}
