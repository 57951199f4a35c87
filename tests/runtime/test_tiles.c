/*
 * test_tiles: host-scheduled tiles (lensrt_render_tiles_begin, _tile, _end) against
 * lensrt_render_run of the same scene.
 *
 *   test_tiles LENS_TABLE SCRATCH_DIR
 *
 * A pixel's phasor sums do not depend on who splats it, so tiles that cover the window
 * once must give run()'s sums bit for bit: the two renders' phasor files are compared
 * byte for byte (all but the header's wall-time field), for tiles of several shapes (the
 * whole window, uneven grids, rows, columns, single pixels, a mixture) on 1 and 4
 * threads, for a fitted lens in float (two passes of samples), in double, and an
 * analytic lens with the unbiased estimator (sums of squares). Then: run() after tiles
 * continues the sequence, tiles after run() do too, uncovered and doubly covered pixels
 * and rectangles outside the window are refused with the sums left as before
 * tiles_begin, calls out of order are refused, and the GL device refuses tiles. Prints
 * every failed check with its line; returns non-zero if any failed.
 */
#include "lensrt.h"

#include <errno.h>
#include <limits.h>
#include <stdint.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

/* ------------------------------------------------------------- harness ----- */

static int g_checks = 0, g_failures = 0;
static char g_scratch[4096];

static void check_at(int ok, int line, const char *fmt, ...)
{
    ++g_checks;
    if (!ok) {
        va_list args;
        ++g_failures;
        fprintf(stderr, "test_tiles.c:%d: FAILED: ", line);
        va_start(args, fmt);
        vfprintf(stderr, fmt, args);
        va_end(args);
        fputc('\n', stderr);
    }
}
#define CHECK(cond, ...) check_at((cond) ? 1 : 0, __LINE__, __VA_ARGS__)

/* A result and, when it is not the expected one, the context's message. */
#define CHECK_RES(ctx, expr, want)                                                                        \
    do {                                                                                                  \
        lensrt_result res_ = (expr);                                                                      \
        CHECK(res_ == (want), "%s: %s, expected %s (%s)", #expr, lensrt_result_string(res_),              \
              lensrt_result_string(want), lensrt_context_last_error(ctx));                                \
    } while (0)

/* The bytes of a file (malloc'd, NULL if unreadable). */
static unsigned char *read_all(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    unsigned char *data;
    long n;
    if (!f) return NULL;
    if (fseek(f, 0, SEEK_END) != 0 || (n = ftell(f)) < 0 || fseek(f, 0, SEEK_SET) != 0) {
        fclose(f);
        return NULL;
    }
    data = malloc((size_t)n + 1);
    if (data && fread(data, 1, (size_t)n, f) != (size_t)n) {
        free(data);
        data = NULL;
    }
    fclose(f);
    *size = (size_t)n;
    return data;
}

/* The phasor file layout (io/phasor_file.c, format `lensrt-phasors 2`): magic[16], u32
 * version and marker, u64 scene, seed, samples, splats, then f64 seconds at bytes 56..63
 * (the wall time, which differs between any two renders), then the sizes, the checksum
 * at bytes 88..95 (over the whole file, so it covers the wall time too), then the sums. */
#define SECONDS_AT 56
#define SECONDS_END 64
#define CHECKSUM_AT 88
#define CHECKSUM_END 96

/* Save both renders' sums and compare every byte but the wall time (and the checksum
 * over it): scene, seed, sample and splat counts, every phasor sum and sum of squares. */
static int same_sums(lensrt_context ctx, lensrt_render a, lensrt_render b, const char *what)
{
    char pa[4200], pb[4200];
    unsigned char *da, *db;
    size_t na = 0, nb = 0, i;
    int same;
    snprintf(pa, sizeof pa, "%s/a.phasors", g_scratch);
    snprintf(pb, sizeof pb, "%s/b.phasors", g_scratch);
    CHECK_RES(ctx, lensrt_render_save(a, pa), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_save(b, pb), LENSRT_SUCCESS);
    da = read_all(pa, &na);
    db = read_all(pb, &nb);
    same = da && db && na == nb && na > CHECKSUM_END && memcmp(da, db, SECONDS_AT) == 0 &&
           memcmp(da + SECONDS_END, db + SECONDS_END, CHECKSUM_AT - SECONDS_END) == 0 &&
           memcmp(da + CHECKSUM_END, db + CHECKSUM_END, na - CHECKSUM_END) == 0;
    if (!same && da && db && na == nb) {
        for (i = SECONDS_END; i < na && (da[i] == db[i] || (i >= CHECKSUM_AT && i < CHECKSUM_END)); i++) continue;
        if (memcmp(da, db, SECONDS_AT) != 0) i = 0;
        CHECK(0, "%s: the phasor files differ from byte %zu of %zu", what, i, na);
    } else {
        CHECK(same, "%s: phasor files missing or of different sizes (%zu, %zu bytes)", what, na, nb);
    }
    free(da);
    free(db);
    return same;
}

/* ------------------------------------------------------------- tilings ----- */

typedef struct rect {
    int x0, y0, w, h;
} rect;

typedef struct tiling {
    rect *r;
    int n;
} tiling;

static void add_rect(tiling *t, int x0, int y0, int w, int h)
{
    t->r = realloc(t->r, sizeof *t->r * (size_t)(t->n + 1));
    if (!t->r) abort();
    t->r[t->n].x0 = x0;
    t->r[t->n].y0 = y0;
    t->r[t->n].w = w;
    t->r[t->n].h = h;
    t->n++;
}

/* An nx x ny grid whose cell edges fall at uneven places (i * W / nx, rounded down). */
static tiling grid(int W, int H, int nx, int ny)
{
    tiling t = {NULL, 0};
    int i, j;
    for (j = 0; j < ny; j++)
        for (i = 0; i < nx; i++) {
            int x0 = i * W / nx, x1 = (i + 1) * W / nx, y0 = j * H / ny, y1 = (j + 1) * H / ny;
            if (x1 > x0 && y1 > y0) add_rect(&t, x0, y0, x1 - x0, y1 - y0);
        }
    return t;
}

/* A mixture: single pixels in the top-left 3 x 3 corner, a 1-pixel-high strip to its
 * right, a 2-pixel-wide column under it, and the rest cut once across and once down at
 * uneven places. */
static tiling mixture(int W, int H)
{
    tiling t = {NULL, 0};
    int x, y, cx = 3 + (W - 3) / 3, cy = 3 + (H - 3) * 2 / 3;
    for (y = 0; y < 3; y++)
        for (x = 0; x < 3; x++) add_rect(&t, x, y, 1, 1);
    add_rect(&t, 3, 0, W - 3, 1);       /* row 0 right of the corner */
    add_rect(&t, 0, 3, 2, H - 3);       /* columns 0-1 under the corner */
    add_rect(&t, 2, 3, 1, H - 3);       /* column 2 under the corner */
    add_rect(&t, 3, 1, cx - 3, cy - 1); /* the rest, in four uneven pieces */
    add_rect(&t, cx, 1, W - cx, cy - 1);
    add_rect(&t, 3, cy, cx - 3, H - cy);
    add_rect(&t, cx, cy, W - cx, H - cy);
    return t;
}

/* ------------------------------------------------------------- threads ----- */

typedef struct pool {
    lensrt_render render;
    const tiling *tiles;
    int next;
    lensrt_result first_error;
    pthread_mutex_t lock;
} pool;

static void *worker(void *arg)
{
    pool *p = arg;
    for (;;) {
        int k;
        lensrt_result res;
        pthread_mutex_lock(&p->lock);
        k = p->next < p->tiles->n ? p->next++ : -1;
        pthread_mutex_unlock(&p->lock);
        if (k < 0) return NULL;
        res = lensrt_render_tile(p->render, p->tiles->r[k].x0, p->tiles->r[k].y0, p->tiles->r[k].w, p->tiles->r[k].h);
        if (res != LENSRT_SUCCESS) {
            pthread_mutex_lock(&p->lock);
            if (p->first_error == LENSRT_SUCCESS) p->first_error = res;
            pthread_mutex_unlock(&p->lock);
        }
    }
}

/* tiles_begin (of n samples; with rings > 0 tiles_begin_cells of that many rings, with
 * nodes >= 0 tiles_begin_fourier of that many nodes, with the estimate), every tile on
 * `threads` threads (in the tiling's order, taken from a shared counter), tiles_end.
 * Returns the first tile failure, else tiles_end's result. */
static lensrt_result render_tiles_of(lensrt_render r, uint64_t n, int rings, int nodes, const tiling *t, int threads)
{
    pthread_t th[8];
    pool p;
    lensrt_result res;
    int i;
    res = nodes >= 0  ? lensrt_render_tiles_begin_fourier(r, nodes, 1)
          : rings > 0 ? lensrt_render_tiles_begin_cells(r, rings, 1)
                      : lensrt_render_tiles_begin(r, n);
    if (res != LENSRT_SUCCESS) return res;
    p.render = r;
    p.tiles = t;
    p.next = 0;
    p.first_error = LENSRT_SUCCESS;
    pthread_mutex_init(&p.lock, NULL);
    for (i = 0; i < threads; i++) pthread_create(&th[i], NULL, worker, &p);
    for (i = 0; i < threads; i++) pthread_join(th[i], NULL);
    pthread_mutex_destroy(&p.lock);
    res = lensrt_render_tiles_end(r);
    return p.first_error != LENSRT_SUCCESS ? p.first_error : res;
}

static lensrt_result render_tiles(lensrt_render r, uint64_t n, const tiling *t, int threads)
{
    return render_tiles_of(r, n, 0, -1, t, threads);
}

/* -------------------------------------------------------------- scenes ----- */

typedef struct scene {
    const char *name;
    lensrt_render_desc desc;
    lensrt_light lights[2];
    double wavelengths[3];
    uint64_t n;            /* samples per wavelength of the compared renders */
} scene;

/* The fitted lens in float: two lights, 7 curved blades, three wavelengths, an odd-sized
 * window around the first light's image, and more samples than one pass (16384). */
static void scene_fitted(lensrt_context ctx, lensrt_lens lens, scene *s)
{
    double c[2];
    lensrt_light l0 = LENSRT_LIGHT_INIT, l1 = LENSRT_LIGHT_INIT;
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    s->name = "fitted lens, float";
    l0.field_x_deg = -6.0;
    l0.field_y_deg = -4.0;
    l1.field_x_deg = -5.9;
    l1.field_y_deg = -4.1;
    l1.distance_mm = 5000.0;
    l1.intensity = 0.5;
    s->lights[0] = l0;
    s->lights[1] = l1;
    s->wavelengths[0] = 480.0;
    s->wavelengths[1] = 550.0;
    s->wavelengths[2] = 640.0;
    lensrt_lens_image_point(ctx, lens, &l0, 550.0, 0.2, c);
    d.lens = lens;
    d.sensor.width = 29;
    d.sensor.height = 17;
    d.sensor.width_mm = 0.06;
    d.sensor.focus_offset_mm = 0.2;
    d.sensor.center_x_mm = c[0];
    d.sensor.center_y_mm = c[1];
    d.aperture.shape = LENSRT_APERTURE_BLADES;
    d.aperture.blades = 7;
    d.aperture.blade_curvature = 0.3;
    d.aperture.f_number = 4.0;
    d.lights = s->lights;
    d.n_lights = 2;
    d.wavelengths_nm = s->wavelengths;
    d.n_wavelengths = 3;
    d.seed = 11;
    s->desc = d;
    s->n = 17000;
}

/* The fitted lens in double (rows, phases and sums in double, no pruning), on axis. */
static void scene_double(lensrt_lens lens, scene *s)
{
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    s->name = "fitted lens, double";
    s->wavelengths[0] = 550.0;
    d.lens = lens;
    d.sensor.width = 9;
    d.sensor.height = 7;
    d.sensor.width_mm = 0.03;
    d.aperture.f_number = 8.0;
    d.wavelengths_nm = s->wavelengths;
    d.n_wavelengths = 1;
    d.precision = LENSRT_PRECISION_DOUBLE;
    d.seed = 3;
    s->desc = d;
    s->n = 1000;
}

/* A perfect thin lens (free space after the stop) imaging two lights, with the unbiased
 * estimator (sums of squares) and independent random samples. */
static void scene_analytic(lensrt_lens lens, scene *s)
{
    lensrt_light l0 = LENSRT_LIGHT_INIT, l1 = LENSRT_LIGHT_INIT;
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    s->name = "perfect lens, unbiased";
    l1.field_x_deg = -0.01;
    l1.distance_mm = 2000.0;
    s->lights[0] = l0;
    s->lights[1] = l1;
    s->wavelengths[0] = 500.0;
    s->wavelengths[1] = 600.0;
    d.lens = lens;
    d.sensor.width = 11;
    d.sensor.height = 6;
    d.sensor.width_mm = 0.04;
    d.aperture.f_number = 8.0;
    d.lights = s->lights;
    d.n_lights = 2;
    d.wavelengths_nm = s->wavelengths;
    d.n_wavelengths = 2;
    d.sampler = LENSRT_SAMPLER_RANDOM;
    d.estimator = LENSRT_ESTIMATOR_UNBIASED;
    d.seed = 5;
    s->desc = d;
    s->n = 3000;
}

/* The box pixel filter (issue 26) with 3 x 2 sub-pixel points per pixel: tiles name the
 * image's pixels, and each covers its pixels' points of the render's grid. */
static void scene_box(lensrt_lens lens, scene *s)
{
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    s->name = "fitted lens, box filter 3 x 2";
    s->wavelengths[0] = 480.0;
    s->wavelengths[1] = 620.0;
    d.lens = lens;
    d.sensor.width = 9;
    d.sensor.height = 7;
    d.sensor.width_mm = 0.045;
    d.sensor.center_x_mm = 0.0021; /* off the axis by a fraction of a pixel */
    d.sensor.center_y_mm = -0.0013;
    d.aperture.f_number = 8.0;
    d.wavelengths_nm = s->wavelengths;
    d.n_wavelengths = 2;
    d.pixel_filter = LENSRT_PIXEL_FILTER_BOX;
    d.pixel_samples_x = 3;
    d.pixel_samples_y = 2;
    d.seed = 7;
    s->desc = d;
    s->n = 1500;
}

/* ---------------------------------------------------------------- tests ----- */

/* run(n) against tiles of the shapes in `shapes_mask` (bit k: names[k]) on 1 and 4
 * threads; the statistics too. */
static void test_equal_to_run(lensrt_context ctx, const scene *s, uint64_t n, unsigned shapes_mask)
{
    const int W = s->desc.sensor.width, H = s->desc.sensor.height;
    tiling shapes[6];
    const char *names[6] = {"one tile", "uneven 5 x 3 grid", "rows", "columns", "mixture", "single pixels"};
    lensrt_render ref, r;
    lensrt_render_stats a = LENSRT_RENDER_STATS_INIT, b = LENSRT_RENDER_STATS_INIT;
    int k, threads, n_shapes = 0;
    shapes[0] = grid(W, H, 1, 1);
    shapes[1] = grid(W, H, 5, 3);
    shapes[2] = grid(W, H, 1, H);
    shapes[3] = grid(W, H, W, 1);
    shapes[4] = mixture(W, H);
    shapes[5] = grid(W, H, W, H);
    CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &ref), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_run(ref, n, NULL, NULL), LENSRT_SUCCESS);
    lensrt_render_get_stats(ref, &a);
    for (k = 0; k < 6; k++) {
        if (!(shapes_mask >> k & 1)) continue;
        n_shapes++;
        for (threads = 1; threads <= 4; threads += 3) {
            char what[256];
            snprintf(what, sizeof what, "%s: %s (%d tiles) on %d thread(s) against run(%llu)", s->name, names[k],
                     shapes[k].n, threads, (unsigned long long)n);
            CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &r), LENSRT_SUCCESS);
            CHECK_RES(ctx, render_tiles(r, n, &shapes[k], threads), LENSRT_SUCCESS);
            same_sums(ctx, ref, r, what);
            lensrt_render_get_stats(r, &b);
            CHECK(a.samples_per_wavelength == b.samples_per_wavelength && a.splats == b.splats &&
                      a.phase_terms == b.phase_terms && a.clip_fraction == b.clip_fraction &&
                      a.tau_fraction == b.tau_fraction && a.dark_fraction == b.dark_fraction,
                  "%s: statistics differ (samples %llu, %llu; terms %.17g, %.17g; tau %.17g, %.17g)", what,
                  (unsigned long long)a.samples_per_wavelength, (unsigned long long)b.samples_per_wavelength,
                  a.phase_terms, b.phase_terms, a.tau_fraction, b.tau_fraction);
            lensrt_render_destroy(r);
        }
    }
    printf("test_tiles: %s: %d tilings x 1 and 4 threads equal run(%llu) (%d x %d pixels; terms %.3g, tau %.3g)\n",
           s->name, n_shapes, (unsigned long long)n, W, H, a.phase_terms, a.tau_fraction);
    lensrt_render_destroy(ref);
    for (k = 0; k < 6; k++) free(shapes[k].r);
}

/* Cells tiles (lensrt_render_tiles_begin_cells) against lensrt_render_integrate on a
 * fresh render: every tiling on 1 and 4 threads gives the same image bit for bit and
 * the same error estimate. */
static void test_cells_equal_to_integrate(lensrt_context ctx, const scene *scene_in, int rings)
{
    scene copy = *scene_in, *s = &copy;
    const int W = s->desc.sensor.width, H = s->desc.sensor.height;
    const size_t n = (size_t)W * (size_t)H * (size_t)s->desc.n_wavelengths;
    tiling shapes[4];
    const char *names[4] = {"one tile", "uneven 5 x 3 grid", "mixture", "single pixels"};
    lensrt_render ref, r;
    lensrt_render_stats a = LENSRT_RENDER_STATS_INIT, b = LENSRT_RENDER_STATS_INIT;
    float *ia = malloc(n * sizeof *ia), *ib = malloc(n * sizeof *ib);
    double est = -1.0;
    int k, threads;
    if (!ia || !ib) abort();
    copy.desc.lights = copy.desc.lights ? copy.lights : NULL; /* the copy's own */
    copy.desc.wavelengths_nm = copy.desc.wavelengths_nm ? copy.wavelengths : NULL;
    copy.desc.estimator = LENSRT_ESTIMATOR_DEFAULT; /* the unbiased one is Monte Carlo's */
    shapes[0] = grid(W, H, 1, 1);
    shapes[1] = grid(W, H, 5, 3);
    shapes[2] = mixture(W, H);
    shapes[3] = grid(W, H, W, H);
    CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &ref), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_integrate(ref, rings, &est, NULL, NULL), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_image(ref, ia, n), LENSRT_SUCCESS);
    lensrt_render_get_stats(ref, &a);
    for (k = 0; k < 4; k++)
        for (threads = 1; threads <= 4; threads += 3) {
            CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &r), LENSRT_SUCCESS);
            CHECK_RES(ctx, render_tiles_of(r, 0, rings, -1, &shapes[k], threads), LENSRT_SUCCESS);
            CHECK_RES(ctx, lensrt_render_image(r, ib, n), LENSRT_SUCCESS);
            lensrt_render_get_stats(r, &b);
            CHECK(memcmp(ia, ib, n * sizeof *ia) == 0, "%s: cells, %s on %d thread(s): the image differs from "
                  "lensrt_render_integrate's", s->name, names[k], threads);
            CHECK(b.cells_rings == rings && b.cells_error_estimate == est && a.cells_error_estimate == est,
                  "%s: cells, %s on %d thread(s): estimate %.17g against %.17g", s->name, names[k], threads,
                  b.cells_error_estimate, est);
            // The session is over: samples and files are refused, a finer integral is not
            CHECK_RES(ctx, lensrt_render_run(r, 256, NULL, NULL), LENSRT_ERROR_INVALID_ARGUMENT);
            lensrt_render_destroy(r);
        }
    // A cells session with an estimate needs 2 rings, as integrate does; a samples
    // session over an integral is refused
    CHECK_RES(ctx, lensrt_render_tiles_begin_cells(ref, 1, 1), LENSRT_ERROR_INVALID_ARGUMENT);
    CHECK_RES(ctx, lensrt_render_tiles_begin(ref, 256), LENSRT_ERROR_INVALID_ARGUMENT);
    printf("test_tiles: %s: cells tiles of %d rings equal lensrt_render_integrate (4 tilings x 1 and 4 threads, "
           "estimate %.3g)\n", s->name, rings, est);
    lensrt_render_destroy(ref);
    for (k = 0; k < 4; k++) free(shapes[k].r);
    free(ia);
    free(ib);
}

/* Fourier tiles (lensrt_render_tiles_begin_fourier) against
 * lensrt_render_integrate_fourier on a fresh render: every tiling on 1 and 4 threads
 * gives the same image bit for bit, the same estimate and nodes (0: chosen). */
static void test_fourier_equal_to_integrate(lensrt_context ctx, const scene *scene_in, int nodes)
{
    scene copy = *scene_in, *s = &copy;
    const int W = s->desc.sensor.width, H = s->desc.sensor.height;
    const size_t n = (size_t)W * (size_t)H * (size_t)s->desc.n_wavelengths;
    tiling shapes[2];
    /* few host tiles: each renders every tile of the window's own that it meets, whole */
    const char *names[2] = {"one tile", "uneven 3 x 2 grid"};
    lensrt_render ref, r;
    lensrt_render_stats a = LENSRT_RENDER_STATS_INIT, b = LENSRT_RENDER_STATS_INIT;
    float *ia = malloc(n * sizeof *ia), *ib = malloc(n * sizeof *ib);
    double est = -1.0;
    int k, threads;
    if (!ia || !ib) abort();
    copy.desc.lights = copy.desc.lights ? copy.lights : NULL; /* the copy's own */
    copy.desc.wavelengths_nm = copy.desc.wavelengths_nm ? copy.wavelengths : NULL;
    copy.desc.estimator = LENSRT_ESTIMATOR_DEFAULT; /* the unbiased one is Monte Carlo's */
    shapes[0] = grid(W, H, 1, 1);
    shapes[1] = grid(W, H, 3, 2);
    CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &ref), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_integrate_fourier(ref, nodes, &est, NULL, NULL), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_image(ref, ia, n), LENSRT_SUCCESS);
    lensrt_render_get_stats(ref, &a);
    for (k = 0; k < 2; k++)
        for (threads = 1; threads <= 4; threads += 3) {
            CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &r), LENSRT_SUCCESS);
            CHECK_RES(ctx, render_tiles_of(r, 0, 0, nodes, &shapes[k], threads), LENSRT_SUCCESS);
            CHECK_RES(ctx, lensrt_render_image(r, ib, n), LENSRT_SUCCESS);
            lensrt_render_get_stats(r, &b);
            CHECK(memcmp(ia, ib, n * sizeof *ia) == 0, "%s: Fourier, %s on %d thread(s): the image differs from "
                  "lensrt_render_integrate_fourier's", s->name, names[k], threads);
            CHECK(b.fourier_nodes == a.fourier_nodes && b.cells_error_estimate == est && b.cells_rings == 0,
                  "%s: Fourier, %s on %d thread(s): nodes %d against %d, estimate %.17g against %.17g", s->name,
                  names[k], threads, b.fourier_nodes, a.fourier_nodes, b.cells_error_estimate, est);
            CHECK_RES(ctx, lensrt_render_run(r, 256, NULL, NULL), LENSRT_ERROR_INVALID_ARGUMENT);
            lensrt_render_destroy(r);
        }
    // Bad nodes, and a samples session over the integral, are refused
    CHECK_RES(ctx, lensrt_render_tiles_begin_fourier(ref, -1, 1), LENSRT_ERROR_INVALID_ARGUMENT);
    CHECK_RES(ctx, lensrt_render_tiles_begin(ref, 256), LENSRT_ERROR_INVALID_ARGUMENT);
    printf("test_tiles: %s: Fourier tiles of %d nodes equal lensrt_render_integrate_fourier (2 tilings x 1 and 4 "
           "threads, estimate %.3g)\n", s->name, a.fourier_nodes, est);
    lensrt_render_destroy(ref);
    for (k = 0; k < 2; k++) free(shapes[k].r);
    free(ia);
    free(ib);
}

/* Tiles then run() equal run() then run(); run() then tiles too. */
static void test_sequences(lensrt_context ctx, const scene *s)
{
    const uint64_t m = 700;
    tiling t = grid(s->desc.sensor.width, s->desc.sensor.height, 4, 3);
    lensrt_render ref, r;
    CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &ref), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_run(ref, s->n, NULL, NULL), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_run(ref, m, NULL, NULL), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &r), LENSRT_SUCCESS);
    CHECK_RES(ctx, render_tiles(r, s->n, &t, 4), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_run(r, m, NULL, NULL), LENSRT_SUCCESS);
    same_sums(ctx, ref, r, "tiles(N) then run(M) against run(N) then run(M)");
    lensrt_render_destroy(r);
    CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &r), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_run(r, s->n, NULL, NULL), LENSRT_SUCCESS);
    CHECK_RES(ctx, render_tiles(r, m, &t, 4), LENSRT_SUCCESS);
    same_sums(ctx, ref, r, "run(N) then tiles(M) against run(N) then run(M)");
    lensrt_render_destroy(r);
    lensrt_render_destroy(ref);
    // Splits inside a block (issue 39, item 4): run(1) then tiles(2047), and tiles(300),
    // tiles(500), run(77), against one run of the sum
    CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &ref), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_run(ref, 2048, NULL, NULL), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &r), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_run(r, 1, NULL, NULL), LENSRT_SUCCESS);
    CHECK_RES(ctx, render_tiles(r, 2047, &t, 4), LENSRT_SUCCESS);
    same_sums(ctx, ref, r, "run(1) then tiles(2047) against run(2048)");
    lensrt_render_destroy(r);
    lensrt_render_destroy(ref);
    CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &ref), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_run(ref, 877, NULL, NULL), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &r), LENSRT_SUCCESS);
    CHECK_RES(ctx, render_tiles(r, 300, &t, 4), LENSRT_SUCCESS);
    CHECK_RES(ctx, render_tiles(r, 500, &t, 2), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_run(r, 77, NULL, NULL), LENSRT_SUCCESS);
    same_sums(ctx, ref, r, "tiles(300), tiles(500), run(77) against run(877)");
    lensrt_render_destroy(r);
    lensrt_render_destroy(ref);
    free(t.r);
}

/* A session that fails must leave the sums (and the sample count) as they were, and the
 * render must then work as if it had never been tried. */
static void test_refusals(lensrt_context ctx, const scene *s)
{
    const int W = s->desc.sensor.width, H = s->desc.sensor.height;
    tiling t = grid(W, H, 3, 2), most = {NULL, 0};
    lensrt_render before, r;
    lensrt_render_stats st = LENSRT_RENDER_STATS_INIT;
    const char *msg;
    int k, x, y;
    CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &before), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_run(before, 300, NULL, NULL), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_create(ctx, &s->desc, &r), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_run(r, 300, NULL, NULL), LENSRT_SUCCESS);

    // Calls out of order
    CHECK_RES(ctx, lensrt_render_tile(r, 0, 0, 1, 1), LENSRT_ERROR_INVALID_ARGUMENT);
    CHECK_RES(ctx, lensrt_render_tiles_end(r), LENSRT_ERROR_INVALID_ARGUMENT);
    CHECK_RES(ctx, lensrt_render_tiles_begin(r, 0), LENSRT_ERROR_INVALID_ARGUMENT);
    CHECK_RES(ctx, lensrt_render_tiles_begin(r, 200), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_tiles_begin(r, 200), LENSRT_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(lensrt_context_last_error(ctx), "tile session is open") != NULL, "tiles_begin twice: '%s'",
          lensrt_context_last_error(ctx));
    CHECK_RES(ctx, lensrt_render_run(r, 10, NULL, NULL), LENSRT_ERROR_INVALID_ARGUMENT);
    {
        char path[4200];
        float one;
        snprintf(path, sizeof path, "%s/during.phasors", g_scratch);
        CHECK_RES(ctx, lensrt_render_save(r, path), LENSRT_ERROR_INVALID_ARGUMENT);
        CHECK_RES(ctx, lensrt_render_image(r, &one, 1), LENSRT_ERROR_INVALID_ARGUMENT);
    }

    // One pixel left out: end names it; the sums are as before begin
    for (y = 0; y < H; y++)
        for (x = 0; x < W; x++)
            if (!(x == 5 && y == 3)) add_rect(&most, x, y, 1, 1);
    for (k = 0; k < most.n; k += 7) /* a few single pixels, then rows of the rest */
        CHECK_RES(ctx, lensrt_render_tile(r, most.r[k].x0, most.r[k].y0, 1, 1), LENSRT_SUCCESS);
    for (k = 0; k < most.n; k++)
        if (k % 7) CHECK_RES(ctx, lensrt_render_tile(r, most.r[k].x0, most.r[k].y0, 1, 1), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_tiles_end(r), LENSRT_ERROR_INVALID_ARGUMENT);
    msg = lensrt_context_last_error(ctx);
    CHECK(strstr(msg, "pixel (5, 3) was not covered") != NULL, "uncovered pixel: '%s'", msg);
    lensrt_render_get_stats(r, &st);
    CHECK(st.samples_per_wavelength == 300, "after a failed session: %llu samples, expected 300",
          (unsigned long long)st.samples_per_wavelength);
    same_sums(ctx, before, r, "sums after a session with an uncovered pixel");

    // A rectangle over pixels another tile has: it renders nothing and fails; end names
    // the first doubly covered pixel in row-major order
    CHECK_RES(ctx, render_tiles(r, 200, &t, 4), LENSRT_SUCCESS); /* a good session, for the sums */
    CHECK_RES(ctx, lensrt_render_run(before, 200, NULL, NULL), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_tiles_begin(r, 200), LENSRT_SUCCESS);
    for (k = 0; k < t.n; k++)
        CHECK_RES(ctx, lensrt_render_tile(r, t.r[k].x0, t.r[k].y0, t.r[k].w, t.r[k].h), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_tile(r, 2, 1, 3, 2), LENSRT_ERROR_INVALID_ARGUMENT);
    CHECK_RES(ctx, lensrt_render_tiles_end(r), LENSRT_ERROR_INVALID_ARGUMENT);
    msg = lensrt_context_last_error(ctx);
    CHECK(strstr(msg, "pixel (2, 1) was covered 2 times") != NULL, "doubly covered pixel: '%s'", msg);
    same_sums(ctx, before, r, "sums after a session with a doubly covered pixel");

    // The whole tiling twice, on 4 threads at once: for each rectangle one call renders
    // and the other renders nothing (no two threads write one pixel's sums; the
    // ThreadSanitizer build has no race to report), and end refuses the session
    {
        tiling twice = {NULL, 0};
        for (k = 0; k < 2 * t.n; k++) add_rect(&twice, t.r[k % t.n].x0, t.r[k % t.n].y0, t.r[k % t.n].w, t.r[k % t.n].h);
        CHECK_RES(ctx, render_tiles(r, 200, &twice, 4), LENSRT_ERROR_INVALID_ARGUMENT);
        msg = lensrt_context_last_error(ctx);
        CHECK(strstr(msg, "pixel (0, 0) was covered 2 times") != NULL, "every tile twice: '%s'", msg);
        same_sums(ctx, before, r, "sums after a session with every tile twice on 4 threads");
        free(twice.r);
    }

    // A rectangle outside the window: refused, and end reports it
    CHECK_RES(ctx, lensrt_render_tiles_begin(r, 200), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_tile(r, W - 1, 0, 2, 1), LENSRT_ERROR_INVALID_ARGUMENT);
    CHECK_RES(ctx, lensrt_render_tile(r, 0, -1, 1, 1), LENSRT_ERROR_INVALID_ARGUMENT);
    CHECK_RES(ctx, lensrt_render_tile(r, 0, 0, 0, 1), LENSRT_ERROR_INVALID_ARGUMENT);
    // At INT_MAX the refusal's pixel range is formatted in 64 bits (UBSan: no overflow)
    CHECK_RES(ctx, lensrt_render_tile(r, INT_MAX, INT_MAX, INT_MAX, INT_MAX), LENSRT_ERROR_INVALID_ARGUMENT);
    for (k = 0; k < t.n; k++)
        CHECK_RES(ctx, lensrt_render_tile(r, t.r[k].x0, t.r[k].y0, t.r[k].w, t.r[k].h), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_tiles_end(r), LENSRT_ERROR_INVALID_ARGUMENT);
    msg = lensrt_context_last_error(ctx);
    CHECK(strstr(msg, "not inside the") != NULL && strstr(msg, "(2 x 1 at (") != NULL,
          "rectangle outside the window: '%s' (the first failing tile's message)", msg);
    same_sums(ctx, before, r, "sums after a session with a rectangle outside the window");

    // After all that, a good session still equals run()
    CHECK_RES(ctx, render_tiles(r, 500, &t, 4), LENSRT_SUCCESS);
    CHECK_RES(ctx, lensrt_render_run(before, 500, NULL, NULL), LENSRT_SUCCESS);
    same_sums(ctx, before, r, "a good session after failed ones");
    printf("test_tiles: uncovered, doubly covered and outside rectangles refused; sums kept\n");
    lensrt_render_destroy(r);
    lensrt_render_destroy(before);
    free(t.r);
    free(most.r);
}

/* The GL device renders whole passes: tiles_begin says so. */
static void test_gl_refused(lensrt_context ctx, const scene *s)
{
    lensrt_render_desc d = s->desc;
    lensrt_render r;
    lensrt_result res;
    const char *require = getenv("LENSRT_REQUIRE_GL");
    d.device = LENSRT_DEVICE_GL;
    res = lensrt_render_create(ctx, &d, &r);
    // A build without the GL path (LENSRT_WITH_GL=OFF: UNSUPPORTED) has nothing to require;
    // a build with it must find a device where LENSRT_REQUIRE_GL=1 (CI)
    if (res == LENSRT_ERROR_NO_DEVICE || res == LENSRT_ERROR_UNSUPPORTED) {
        CHECK(!(require && strcmp(require, "1") == 0 && res == LENSRT_ERROR_NO_DEVICE),
              "LENSRT_REQUIRE_GL=1 but no GL render: %s",
              lensrt_context_last_error(ctx));
        printf("test_tiles: no GL device (%s): the GL refusal is not tested\n", lensrt_context_last_error(ctx));
        return;
    }
    CHECK_RES(ctx, res, LENSRT_SUCCESS);
    if (res != LENSRT_SUCCESS) return;
    CHECK_RES(ctx, lensrt_render_tiles_begin(r, 100), LENSRT_ERROR_UNSUPPORTED);
    CHECK(strstr(lensrt_context_last_error(ctx), "device cpu") != NULL, "GL refusal: '%s'", lensrt_context_last_error(ctx));
    // The cells integrator too: refused with a message, never a silent fallback
    CHECK_RES(ctx, lensrt_render_integrate(r, 8, NULL, NULL, NULL), LENSRT_ERROR_UNSUPPORTED);
    CHECK(strstr(lensrt_context_last_error(ctx), "device cpu") != NULL, "GL cells refusal: '%s'",
          lensrt_context_last_error(ctx));
    CHECK_RES(ctx, lensrt_render_tiles_begin_cells(r, 8, 1), LENSRT_ERROR_UNSUPPORTED);
    // The Fourier integrator likewise: a message, never a silent fallback
    CHECK_RES(ctx, lensrt_render_integrate_fourier(r, 8, NULL, NULL, NULL), LENSRT_ERROR_UNSUPPORTED);
    CHECK(strstr(lensrt_context_last_error(ctx), "no Fourier integrator") != NULL, "GL Fourier refusal: '%s'",
          lensrt_context_last_error(ctx));
    CHECK_RES(ctx, lensrt_render_tiles_begin_fourier(r, 8, 1), LENSRT_ERROR_UNSUPPORTED);
    CHECK_RES(ctx, lensrt_render_tile(r, 0, 0, 1, 1), LENSRT_ERROR_INVALID_ARGUMENT);
    CHECK_RES(ctx, lensrt_render_run(r, 100, NULL, NULL), LENSRT_SUCCESS); /* the render is untouched */
    printf("test_tiles: the GL device refuses tiles\n");
    lensrt_render_destroy(r);
}

int main(int argc, char **argv)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_analytic_lens am = LENSRT_ANALYTIC_LENS_INIT;
    lensrt_context ctx;
    lensrt_lens fitted, perfect;
    scene s;
    if (argc != 3) {
        fprintf(stderr, "usage: %s LENS_TABLE SCRATCH_DIR\n", argv[0]);
        return 2;
    }
    snprintf(g_scratch, sizeof g_scratch, "%s", argv[2]);
    if (mkdir(g_scratch, 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "test_tiles: cannot create %s: %s\n", g_scratch, strerror(errno));
        return 2;
    }
    init.threads = 2; /* run()'s OpenMP threads: sums do not depend on them either */
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) return 2;
    if (lensrt_lens_load(ctx, argv[1], &fitted) != LENSRT_SUCCESS) {
        fprintf(stderr, "test_tiles: %s\n", lensrt_context_last_error(ctx));
        return 2;
    }
    am.focal_length_mm = 50.0;
    am.sensor_distance_mm = 50.0;
    CHECK_RES(ctx, lensrt_lens_create_analytic(ctx, &am, &perfect), LENSRT_SUCCESS);

    // Tiles share each (pass, wavelength)'s prepared samples (or prepare privately past the
    // session's memory cap): the two-pass count (17000) with a few tilings, every tiling
    // with fewer samples
    scene_fitted(ctx, fitted, &s);
    test_equal_to_run(ctx, &s, s.n, 0x13);
    test_equal_to_run(ctx, &s, 1500, 0x1f);
    test_sequences(ctx, &s);
    test_refusals(ctx, &s);
    test_gl_refused(ctx, &s);
    test_cells_equal_to_integrate(ctx, &s, 8);
    test_fourier_equal_to_integrate(ctx, &s, 12);
    scene_double(fitted, &s);
    test_equal_to_run(ctx, &s, s.n, 0x3f);
    test_cells_equal_to_integrate(ctx, &s, 6);
    scene_box(fitted, &s);
    {
        lensrt_render r;
        lensrt_render_stats st = LENSRT_RENDER_STATS_INIT;
        CHECK_RES(ctx, lensrt_render_create(ctx, &s.desc, &r), LENSRT_SUCCESS);
        lensrt_render_get_stats(r, &st);
        CHECK(st.width == 9 && st.height == 7 && st.pixel_filter == LENSRT_PIXEL_FILTER_BOX &&
                  st.pixel_samples_x == 3 && st.pixel_samples_y == 2,
              "box scene: stats say %d x %d pixels, filter %d, %d x %d points", st.width, st.height, st.pixel_filter,
              st.pixel_samples_x, st.pixel_samples_y);
        // A pixel left out is named as the image's pixel, not a grid point
        CHECK_RES(ctx, lensrt_render_tiles_begin(r, 100), LENSRT_SUCCESS);
        CHECK_RES(ctx, lensrt_render_tile(r, 0, 0, 9, 3), LENSRT_SUCCESS);
        CHECK_RES(ctx, lensrt_render_tile(r, 0, 4, 9, 3), LENSRT_SUCCESS);
        CHECK_RES(ctx, lensrt_render_tile(r, 0, 9, 1, 1), LENSRT_ERROR_INVALID_ARGUMENT);
        CHECK_RES(ctx, lensrt_render_tiles_end(r), LENSRT_ERROR_INVALID_ARGUMENT);
        CHECK(strstr(lensrt_context_last_error(ctx), "pixel (0, 3) was not covered") != NULL,
              "box scene, a row left out: '%s'", lensrt_context_last_error(ctx));
        lensrt_render_destroy(r);
    }
    test_equal_to_run(ctx, &s, s.n, 0x3f);
    test_cells_equal_to_integrate(ctx, &s, 6);
    test_fourier_equal_to_integrate(ctx, &s, 0);
    scene_analytic(perfect, &s);
    test_equal_to_run(ctx, &s, s.n, 0x3f);
    test_sequences(ctx, &s);
    test_cells_equal_to_integrate(ctx, &s, 8);
    test_fourier_equal_to_integrate(ctx, &s, 0);

    lensrt_lens_destroy(ctx, perfect);
    lensrt_lens_destroy(ctx, fitted);
    lensrt_context_destroy(ctx);
    printf("test_tiles: %d checks, %d failed\n", g_checks, g_failures);
    return g_failures ? 1 : 0;
}
