/* The flare layers of an image through the lens (runtime/src/image/flare.c, issue 38),
 * driven through image.h's internal calls on an image object filled here by hand (the
 * public lensrt_image_create lives in image.c): a bank index written here for its pitch,
 * wavelengths and f-number (its node is never read), and lens 0001's ghost table 0-2.
 *
 *   sources   two blobs (one joined only diagonally) and a single pixel above the
 *             threshold: three sources, brightest first, with their pixel counts,
 *             powers and power-weighted field points in closed form; max_sources 2
 *             keeps the two brightest; ghosts that miss the frame are not rendered
 *   identity  at flare_downsample 1 a ghost layer equals a render of the same ghost
 *             made here with the public API, times V / the axis power, to 1e-5
 *   weights   two channels, each weighting one wavelength: each channel is the ghost's
 *             image at its wavelength times V_c / axis_power there
 *   resample  at flare_downsample 4 the layer's sum is the coarse image's times 16
 *             (bilinear between coarse centres keeps the energy), and the ghost's power
 *             is within 0.5% of a full-resolution render's (measured 0.10%: its light
 *             beyond the footprint's diffraction margin)
 *   domain    a source outside the ghost's fitted field: LENSRT_ERROR_OUT_OF_DOMAIN
 *             naming the source, its field point and the ghost, with the library's
 *             message
 *
 * argv: the ghost table, a scratch folder. In a shared build flare.c is compiled into
 * the test (its functions are hidden in the library) with the internals it takes from
 * the library given below, on the library's own context. */
#include "lensrt.h"

#include "../../runtime/src/image/image.h"
#include "../../runtime/src/internal.h"
#include "check.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#if LENSRT_TEST_FLARE_STUBS
void *lensrt_alloc(lensrt_context ctx, size_t size)
{
    (void)ctx;
    return malloc(size ? size : 1);
}

void *lensrt_calloc(lensrt_context ctx, size_t count, size_t size)
{
    (void)ctx;
    return calloc(count ? count : 1, size ? size : 1);
}

void lensrt_free(lensrt_context ctx, void *ptr)
{
    (void)ctx;
    free(ptr);
}

/* As the library's: the message into the context's last error. */
lensrt_result lensrt_fail(lensrt_context ctx, lensrt_result result, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(ctx->error, sizeof ctx->error, fmt, ap);
    va_end(ap);
    return result;
}

void lensrt_log(lensrt_context ctx, lensrt_log_level level, const char *fmt, ...)
{
    va_list ap;
    (void)ctx;
    if (level > LENSRT_LOG_WARNING && !getenv("LENSRT_TEST_VERBOSE")) return;
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fputc('\n', stderr);
}

double lensrt_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}
#endif

#define PITCH 0.01875
#define F_NUMBER 8.0
#define N_WL 3
static const double g_wl[N_WL] = {450.0, 550.0, 650.0};
static const double g_axis[N_WL] = {2.0, 3.0, 5.0}; /* made up: only their use matters */
#define DEG 57.295779513082320876798

/* A bank index of one node (its EXR an empty file that is never read): the bank's
 * pitch, wavelengths and f-number are all the flare takes from it. */
static lensrt_bank open_bank(lensrt_context ctx, const char *dir, int n_wl, const double *wl)
{
    char path[4096], text[4096], list[1024] = "", chief[1024] = "";
    size_t n, size, at = 0, at_chief = 0;
    int k;
    char *stamped;
    FILE *f;
    lensrt_bank bank = NULL;
    mkdir(dir, 0777);
    snprintf(path, sizeof path, "%s/nodes", dir);
    mkdir(path, 0777);
    snprintf(path, sizeof path, "%s/nodes/n.exr", dir);
    if ((f = fopen(path, "wb"))) fclose(f);
    for (k = 0; k < n_wl; k++) {
        at += (size_t)snprintf(list + at, sizeof list - at, " %.17g", wl[k]);
        at_chief += (size_t)snprintf(chief + at_chief, sizeof chief - at_chief, " 0.0 0.0");
    }
    n = (size_t)snprintf(text, sizeof text,
                         "lensrt-bank 1\nlens 0001-angenieux-double-gauss\ntable_crc32 00000000\nwidth 8\nheight 8\n"
                         "pixel_mm %.17g %.17g\nregistration channel\nwavelengths_nm %d%s\n"
                         "f_numbers 1 8.0\nfocus_offsets_mm 1 0.0\ndistances_mm 1 0.0\nfield_x_deg 1 0.0\n"
                         "field_y_deg 1 0.0\nnodes 1\nnode 0 0 0 0 0 0 0.0 0.0 -1 00000000 nodes/n.exr\n"
                         "chief 0%s\n", PITCH, PITCH, n_wl, list, chief);
    stamped = stamp_crc(text, n, &size);
    snprintf(path, sizeof path, "%s/bank.index", dir);
    if (stamped && (f = fopen(path, "wb"))) {
        fwrite(stamped, 1, size, f);
        fclose(f);
    }
    free(stamped);
    CHECK_OK(ctx, lensrt_bank_open(ctx, path, &bank));
    return bank;
}

/* An image object as image.c fills it: the description copied (defaults not applied),
 * the weights (n_channels x N_WL), the ghosts, the bank's wavelengths, the axis power. */
typedef struct scene {
    struct lensrt_image_s im;
    lensrt_lens ghost;
    float *input, *layers;
} scene;

static void scene_init(scene *s, lensrt_context ctx, lensrt_bank bank, lensrt_lens *ghost, int width, int height,
                       double cx, double cy, double fx, double fy, int n_channels, double *weights, int max_sources)
{
    lensrt_image_desc d = LENSRT_IMAGE_DESC_INIT;
    memset(s, 0, sizeof *s);
    d.bank = bank;
    d.width = width;
    d.height = height;
    d.center_x_mm = cx;
    d.center_y_mm = cy;
    d.focal_x_mm = fx;
    d.focal_y_mm = fy;
    d.n_channels = n_channels;
    d.channel_weights = weights;
    d.ghosts = ghost;
    d.n_ghosts = 1;
    d.max_sources = max_sources;
    s->im.ctx = ctx;
    s->im.desc = d;
    s->im.channel_weights = weights;
    s->im.ghosts = ghost;
    s->im.n_wavelengths = N_WL;
    s->im.wavelengths_nm = g_wl;
    s->im.focal_y_mm = fy;
    s->im.axis_power = (double *)g_axis;
    s->im.plane = (size_t)width * (size_t)height;
    s->im.n_layers = 3;
    s->im.sources = calloc(max_sources ? (size_t)max_sources : 16, sizeof *s->im.sources);
    s->im.stats.struct_size = sizeof s->im.stats;
    s->input = calloc((size_t)n_channels * s->im.plane, sizeof *s->input);
    s->layers = calloc((size_t)n_channels * s->im.plane, sizeof *s->layers);
}

static void scene_free(scene *s)
{
    image_flare_destroy(&s->im);
    free(s->im.sources);
    free(s->input);
    free(s->layers);
}

/* A pixel's centre on the sensor (lensrt.h's convention). */
static double pixel_x(const scene *s, int i) { return s->im.desc.center_x_mm + (i + 0.5 - 0.5 * s->im.desc.width) * PITCH; }
static double pixel_y(const scene *s, int j) { return s->im.desc.center_y_mm + (0.5 * s->im.desc.height - j - 0.5) * PITCH; }

/* ------------------------------------------------------------------- sources ----- */

/* Two channels: a 3 x 3 blob of rising values, a diagonal chain of three pixels, and a
 * single bright pixel, on a dim background below the threshold. The frame sits far
 * from the axis and the fields are tiny (a long pinhole focal length): every ghost lands
 * near the axis, off the frame, and none is rendered. */
static void test_sources(lensrt_context ctx, lensrt_bank bank, lensrt_lens *ghost)
{
    static double w[2 * N_WL] = {1, 0, 0, 0, 0, 1};
    const int W = 64, H = 48, chain[3][2] = {{30, 20}, {31, 21}, {32, 22}};
    int keep, i, j, k;
    for (keep = 3; keep >= 2; keep--) {
        scene s;
        double want_p[3] = {0, 0, 0}, want_x[3] = {0, 0, 0}, want_y[3] = {0, 0, 0};
        int want_n[3] = {9, 3, 1}, order[3];
        scene_init(&s, ctx, bank, ghost, W, H, 15.0, 10.0, 1e4, 2e4, 2, w, keep);
        s.im.desc.flare_threshold = 0.5;
        for (k = 0; k < 2 * W * H; k++) s.input[k] = 0.2f; /* channel sum 0.4: below */
#define PUT(src, i_, j_, a, b)                                                                     \
    do {                                                                                           \
        const double p_ = (double)(float)(a) + (double)(float)(b);                                 \
        s.input[(size_t)(j_) * W + (i_)] = (float)(a);                                             \
        s.input[s.im.plane + (size_t)(j_) * W + (i_)] = (float)(b);                                \
        want_p[src] += p_;                                                                         \
        want_x[src] += p_ * pixel_x(&s, i_) / 1e4;                                                 \
        want_y[src] += p_ * pixel_y(&s, j_) / 2e4;                                                 \
    } while (0)
        for (j = 0; j < 3; j++)
            for (i = 0; i < 3; i++) PUT(0, 10 + i, 10 + j, 1.0 + i, 0.5 + 2.0 * j); /* power 40.5: first */
        for (k = 0; k < 3; k++) PUT(1, chain[k][0], chain[k][1], 4.0, 1.0);        /* 15: third */
        PUT(2, 50, 40, 20.0, 5.0);                                                  /* 25: second */
#undef PUT
        order[0] = 0, order[1] = 2, order[2] = 1;
        CHECK_OK(ctx, image_flare_create(&s.im));
        CHECK_OK(ctx, image_flare_run(&s.im, s.input, s.layers));
        CHECK(s.im.stats.n_sources == keep, "max_sources %d: %d sources", keep, (int)s.im.stats.n_sources);
        for (k = 0; k < keep && k < s.im.stats.n_sources; k++) {
            const lensrt_image_source *o = &s.im.sources[k];
            const int src = order[k];
            const double fx = atan(want_x[src] / want_p[src]) * DEG, fy = atan(want_y[src] / want_p[src]) * DEG;
            CHECK(o->pixels == want_n[src], "source %d: %d pixels, expected %d", k, (int)o->pixels, want_n[src]);
            CHECK(fabs(o->power - want_p[src]) <= 1e-12 * want_p[src], "source %d: power %.17g, expected %.17g", k,
                  o->power, want_p[src]);
            CHECK(fabs(o->field_x_deg - fx) <= 1e-12 * fabs(fx) && fabs(o->field_y_deg - fy) <= 1e-12 * fabs(fy),
                  "source %d: field (%.17g, %.17g), expected (%.17g, %.17g)", k, o->field_x_deg, o->field_y_deg, fx, fy);
        }
        CHECK(s.im.stats.n_ghost_renders == 0 && s.im.stats.worst_flare_error == -1.0,
              "ghosts off the frame: %d renders, worst error %g", (int)s.im.stats.n_ghost_renders,
              s.im.stats.worst_flare_error);
        for (k = 0; k < 2 * W * H; k++)
            if (s.layers[k] != 0.0f) break;
        CHECK(k == 2 * W * H, "ghosts off the frame: the layer is not zero at %d", k);
        scene_free(&s);
    }
}

/* --------------------------------------------------------------- ghost layers ----- */

/* The ghost at field (fx, fy) deg rendered here with the public API, as the flare
 * renders it: a unit light, the bank's wavelengths, a circle at the bank's f-number, the
 * box filter, on a window of w x h pixels of `pitch` centred at (cx, cy), by the
 * Fourier rule for the target (the flare's first step; the flare's windows here reach
 * the target with it), refined by LENSRT_FOURIER_FINER until it does (the whole frame
 * at full resolution). N_WL planes (malloc'd); *err its estimate. */
static float *reference(lensrt_context ctx, lensrt_lens ghost, double fx, double fy, int w, int h, double pitch,
                        double cx, double cy, double target, double *err)
{
    lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
    lensrt_light l = LENSRT_LIGHT_INIT;
    lensrt_render r = NULL;
    int32_t nodes = 0;
    const size_t n = (size_t)N_WL * (size_t)w * (size_t)h;
    float *img = malloc(n * sizeof *img);
    l.field_x_deg = fx;
    l.field_y_deg = fy;
    l.intensity = 1.0;
    d.lens = ghost;
    d.lights = &l;
    d.n_lights = 1;
    d.wavelengths_nm = g_wl;
    d.n_wavelengths = N_WL;
    d.aperture.f_number = F_NUMBER;
    d.sensor.width = w;
    d.sensor.height = h;
    d.sensor.width_mm = w * pitch;
    d.sensor.height_mm = h * pitch;
    d.sensor.center_x_mm = cx;
    d.sensor.center_y_mm = cy;
    *err = -1.0;
    CHECK_OK(ctx, lensrt_render_create(ctx, &d, &r));
    CHECK_OK(ctx, lensrt_render_fourier_nodes(r, target, &nodes));
    CHECK_OK(ctx, lensrt_render_integrate_fourier(r, nodes, err, NULL, NULL));
    while (*err > target && nodes < 2730) {
        nodes = (int32_t)ceil(LENSRT_FOURIER_FINER * nodes);
        CHECK_OK(ctx, lensrt_render_integrate_fourier(r, nodes, err, NULL, NULL));
    }
    CHECK(*err >= 0 && *err <= target, "reference: Fourier estimate %g at %d nodes, target %g", *err, (int)nodes, target);
    CHECK_OK(ctx, lensrt_render_image(r, img, n));
    lensrt_render_destroy(r);
    return img;
}

/* The ghost 0-2 scene: a source pixel whose light is at field (0.5, 0.3) deg, the frame
 * centred where the ghost lands (its footprint, lensrt_render_footprint, is x 0.63..1.02,
 * y 0.30..0.69 mm at f/8), the pinhole focal lengths set so that the source pixel sees
 * that field. */
#define GHOST_X 0.82
#define GHOST_Y 0.49
static void ghost_scene(scene *s, lensrt_context ctx, lensrt_bank bank, lensrt_lens *ghost, int size, double field_x,
                        int n_channels, double *weights, int downsample)
{
    const double x = GHOST_X + 0.5 * PITCH, y = GHOST_Y - 0.5 * PITCH; /* pixel (size / 2, size / 2) */
    scene_init(s, ctx, bank, ghost, size, size, GHOST_X, GHOST_Y, x / tan(field_x / DEG), y / tan(0.3 / DEG), n_channels,
               weights, 0);
    s->im.desc.flare_downsample = downsample;
}

/* Flare downsample 1: the coarse grid is the frame's, the resampling the identity, the
 * layer the reference render times V / the axis power (one channel of three weights,
 * then two channels each weighting one wavelength). The 32 x 32 frame lies within the
 * footprint widened by its diffraction margin, so the flare renders the whole frame, as
 * the reference does (the same window: the same Fourier rule). */
static void test_identity(lensrt_context ctx, lensrt_bank bank, lensrt_lens *ghost)
{
    static double w1[N_WL] = {0.2, 0.5, 0.3}, w2[2 * N_WL] = {1, 0, 0, 0, 0, 1};
    const int S = 32, c = S / 2;
    const size_t plane = (size_t)S * S;
    scene a, b;
    float *ref = NULL;
    double err = -1, top = 0, diff = 0;
    size_t p;
    int k;
    ghost_scene(&a, ctx, bank, ghost, S, 0.5, 1, w1, 1);
    a.input[(size_t)c * S + c] = 7.0f;
    CHECK_OK(ctx, image_flare_create(&a.im));
    CHECK_OK(ctx, image_flare_run(&a.im, a.input, a.layers));
    CHECK(a.im.stats.n_sources == 1 && a.im.stats.n_ghost_renders == 1, "identity: %d sources, %d renders",
          (int)a.im.stats.n_sources, (int)a.im.stats.n_ghost_renders);
    CHECK(fabs(a.im.sources[0].field_x_deg - 0.5) < 1e-12 && fabs(a.im.sources[0].field_y_deg - 0.3) < 1e-12,
          "identity: the source at (%.17g, %.17g) deg", a.im.sources[0].field_x_deg, a.im.sources[0].field_y_deg);
    ref = reference(ctx, *ghost, a.im.sources[0].field_x_deg, a.im.sources[0].field_y_deg, S, S, PITCH, GHOST_X, GHOST_Y,
                    0.02, &err);
    CHECK(fabs(a.im.stats.worst_flare_error - err) <= 1e-12, "identity: worst error %.17g, the reference's %.17g",
          a.im.stats.worst_flare_error, err);
    CHECK(a.im.stats.seconds_flares > 0, "identity: seconds_flares %g", a.im.stats.seconds_flares);
    for (p = 0; p < plane; p++) {
        double want = 0, den = 0;
        for (k = 0; k < N_WL; k++) {
            want += w1[k] * ref[(size_t)k * plane + p];
            den += w1[k] * g_axis[k];
        }
        want *= 7.0 / den;
        if (want > top) top = want;
        if (fabs(a.layers[p] - want) > diff) diff = fabs(a.layers[p] - want);
    }
    CHECK(top > 0 && diff <= 1e-5 * top, "identity: the layer differs from the reference by %g of its peak %g",
          diff / top, top);
    // Two channels, each weighting one wavelength
    ghost_scene(&b, ctx, bank, ghost, S, 0.5, 2, w2, 1);
    b.input[(size_t)c * S + c] = 3.0f;
    b.input[plane + (size_t)c * S + c] = 11.0f;
    CHECK_OK(ctx, image_flare_create(&b.im));
    CHECK_OK(ctx, image_flare_run(&b.im, b.input, b.layers));
    for (k = 0; k < 2; k++) {
        const int l = k ? 2 : 0;
        const double v = k ? 11.0 : 3.0;
        top = diff = 0;
        for (p = 0; p < plane; p++) {
            const double want = v * ref[(size_t)l * plane + p] / g_axis[l];
            if (want > top) top = want;
            if (fabs(b.layers[(size_t)k * plane + p] - want) > diff) diff = fabs(b.layers[(size_t)k * plane + p] - want);
        }
        CHECK(top > 0 && diff <= 1e-5 * top, "weights: channel %d differs from wavelength %d's image by %g of its peak",
              k, l, diff / top);
    }
    free(ref);
    scene_free(&a);
    scene_free(&b);
}

/* Flare downsample 4 on a 64 x 64 frame holding the whole ghost: the layer's sum is
 * the coarse image's times 4^2 (the coarse window found here as the flare finds it:
 * the footprint widened by 30 wavelengths x f-number at the longest wavelength, on the
 * 16 x 16 grid of 4-pixel cells), and the ghost's power is that of a render of the
 * whole frame at full resolution. */
static void test_downsample(lensrt_context ctx, lensrt_bank bank, lensrt_lens *ghost)
{
    static double w1[N_WL] = {0.2, 0.5, 0.3};
    const int S = 64, c = S / 2, ds = 4, G = S / ds;
    const double P = ds * PITCH;
    const size_t plane = (size_t)S * S;
    scene a;
    float *fine, *coarse;
    double err, box[4], m = 30.0 * 650e-6 * F_NUMBER, den = 0, layer = 0, sum_fine = 0, sum_coarse = 0;
    int x0, x1, y0, y1, k;
    size_t p;
    ghost_scene(&a, ctx, bank, ghost, S, 0.5, 1, w1, ds);
    a.input[(size_t)c * S + c] = 7.0f;
    CHECK_OK(ctx, image_flare_create(&a.im));
    CHECK_OK(ctx, image_flare_run(&a.im, a.input, a.layers));
    CHECK(a.im.stats.n_ghost_renders == 1, "downsample: %d renders", (int)a.im.stats.n_ghost_renders);
    for (p = 0; p < plane; p++) layer += a.layers[p];
    for (k = 0; k < N_WL; k++) den += w1[k] * g_axis[k];
    // The coarse window, from the footprint
    {
        lensrt_render_desc d = LENSRT_RENDER_DESC_INIT;
        lensrt_light l = LENSRT_LIGHT_INIT;
        lensrt_render r = NULL;
        l.field_x_deg = a.im.sources[0].field_x_deg;
        l.field_y_deg = a.im.sources[0].field_y_deg;
        d.lens = *ghost;
        d.lights = &l;
        d.n_lights = 1;
        d.wavelengths_nm = g_wl;
        d.n_wavelengths = N_WL;
        d.aperture.f_number = F_NUMBER;
        d.sensor.width = d.sensor.height = 1;
        d.sensor.width_mm = P;
        CHECK_OK(ctx, lensrt_render_create(ctx, &d, &r));
        CHECK_OK(ctx, lensrt_render_footprint(r, box));
        lensrt_render_destroy(r);
    }
    x0 = (int)floor((box[0] - m - GHOST_X) / P + 0.5 * G);
    x1 = (int)floor((box[1] + m - GHOST_X) / P + 0.5 * G);
    y0 = (int)floor(0.5 * G - (box[3] + m - GHOST_Y) / P);
    y1 = (int)floor(0.5 * G - (box[2] - m - GHOST_Y) / P);
    CHECK(x0 > 0 && y0 > 0 && x1 < G - 1 && y1 < G - 1, "downsample: the ghost's window %d..%d x %d..%d is not inside "
          "the frame's %d x %d coarse pixels", x0, x1, y0, y1, G, G);
    coarse = reference(ctx, *ghost, a.im.sources[0].field_x_deg, a.im.sources[0].field_y_deg, x1 - x0 + 1, y1 - y0 + 1,
                       P, GHOST_X + (0.5 * (x0 + x1 + 1) - 0.5 * G) * P, GHOST_Y + (0.5 * G - 0.5 * (y0 + y1 + 1)) * P,
                       0.02, &err);
    CHECK(fabs(a.im.stats.worst_flare_error - err) <= 1e-12, "downsample: worst error %.17g, the coarse render's %.17g",
          a.im.stats.worst_flare_error, err);
    for (k = 0; k < N_WL; k++)
        for (p = 0; p < (size_t)(x1 - x0 + 1) * (size_t)(y1 - y0 + 1); p++)
            sum_coarse += 7.0 * w1[k] / den * coarse[(size_t)k * (size_t)(x1 - x0 + 1) * (size_t)(y1 - y0 + 1) + p];
    // Bilinear weights between coarse centres sum to ds per axis over a coarse pixel's
    // hat, for each coarse pixel inside the frame's: the energy is kept to rounding
    CHECK(fabs(layer - ds * ds * sum_coarse) <= 1e-5 * layer, "downsample: the layer sums to %.9g, the coarse image "
          "times %d to %.9g", layer, ds * ds, ds * ds * sum_coarse);
    fine = reference(ctx, *ghost, a.im.sources[0].field_x_deg, a.im.sources[0].field_y_deg, S, S, PITCH, GHOST_X, GHOST_Y,
                     0.02, &err);
    for (k = 0; k < N_WL; k++)
        for (p = 0; p < plane; p++) sum_fine += 7.0 * w1[k] / den * fine[(size_t)k * plane + p];
    // The full-resolution render over the coarse window's pixels: the same power as the
    // coarse image (box filters: a coarse pixel's mean is its 16 pixels' mean; measured
    // 8e-6 apart, the two renders' integration errors)
    {
        double inside = 0;
        int i, j;
        for (k = 0; k < N_WL; k++)
            for (j = ds * y0; j < ds * (y1 + 1); j++)
                for (i = ds * x0; i < ds * (x1 + 1); i++) inside += 7.0 * w1[k] / den * fine[(size_t)k * plane + (size_t)j * S + i];
        CHECK(fabs(inside - ds * ds * sum_coarse) <= 1e-4 * inside, "downsample: the full-resolution render holds %.9g "
              "over the coarse window, the coarse one %.9g", inside, ds * ds * sum_coarse);
    }
    // The whole frame's: the layer misses the ghost's light beyond its footprint's
    // diffraction margin, measured 0.10% here; 0.5% (within the 2% asked) leaves room
    // for another build's rounding of the integrals
    printf("downsample 4: the ghost's power %.9g, at full resolution %.9g (%+.3g%%)\n", layer, sum_fine,
           100.0 * (layer / sum_fine - 1.0));
    CHECK(fabs(layer - sum_fine) <= 0.005 * sum_fine, "downsample: the ghost's power %.9g, at full resolution %.9g", layer,
          sum_fine);
    free(fine);
    free(coarse);
    scene_free(&a);
}

/* A source at 20 deg, beyond the ghost's fitted field (12.2 deg). */
static void test_domain(lensrt_context ctx, lensrt_bank bank, lensrt_lens *ghost)
{
    static double w1[N_WL] = {0.2, 0.5, 0.3};
    scene a;
    ghost_scene(&a, ctx, bank, ghost, 32, 20.0, 1, w1, 4);
    a.input[(size_t)16 * 32 + 16] = 1.0f;
    CHECK_OK(ctx, image_flare_create(&a.im));
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, image_flare_run(&a.im, a.input, a.layers));
    CHECK_MSG(ctx, "source 0 (field 20, 0.3 deg)");
    CHECK_MSG(ctx, "ghost 0 (0-2)");
    CHECK_MSG(ctx, "light 0");
    printf("out of domain: %s\n", lensrt_context_last_error(ctx));
    scene_free(&a);
}

/* ---------------------------------------------------------------------- bench ----- */

/* Not a test: the time of a run on a 1920 x 1080 frame of lens 0001 (the pitch above,
 * the lens's EFL as the pinhole's focal length, f/8, a bank of 8 wavelengths, RGB
 * weights), three 3 x 3 sources (at about (-7.4, 3.9), (2.9, -1.7) and (9.1, 5.1) deg)
 * through every ghost table of `dir`, at the given downsample. Each render's window,
 * integrator and estimate are logged with LENSRT_TEST_VERBOSE=1.
 *   test_image_flare --bench generated/0001-angenieux-double-gauss SCRATCH 4 */
static int bench(const char *lens_dir, const char *scratch, int downsample)
{
    static const char *names[5] = {"ghost_0_2", "ghost_0_4", "ghost_2_4", "ghost_2_6", "ghost_4_8"};
    static const double wl[8] = {420, 470, 510, 550, 590, 630, 670, 700}, axis[8] = {1, 1, 1, 1, 1, 1, 1, 1};
    static double weights[3 * 8] = {0, 0, 0, 0, 0.2, 1, 1, 1, 0, 0, 1, 1, 1, 0.2, 0, 0, 1, 1, 0.5, 0, 0, 0, 0, 0};
    static const int at[3][2] = {{266, 177}, {1226, 700}, {1813, 60}};
    static const float value[3] = {100.0f, 50.0f, 20.0f};
    const int W = 1920, H = 1080;
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    lensrt_lens ghosts[5] = {NULL, NULL, NULL, NULL, NULL}, lens = NULL;
    lensrt_lens_info li = LENSRT_LENS_INFO_INIT;
    lensrt_image_desc d = LENSRT_IMAGE_DESC_INIT;
    struct lensrt_image_s im;
    lensrt_image_source sources[16];
    lensrt_bank bank;
    char path[4096];
    float *input, *layers;
    int g, k, i, j, c;
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) return 1;
    bank = open_bank(ctx, scratch, 8, wl);
    snprintf(path, sizeof path, "%s/lens0001.table", lens_dir);
    CHECK_OK(ctx, lensrt_lens_load(ctx, path, &lens));
    lensrt_lens_get_info(lens, &li);
    for (g = 0; g < 5; g++) {
        snprintf(path, sizeof path, "%s/ghosts/%s.table", lens_dir, names[g]);
        CHECK_OK(ctx, lensrt_lens_load(ctx, path, &ghosts[g]));
    }
    input = calloc((size_t)3 * W * H, sizeof *input);
    layers = calloc((size_t)5 * 3 * W * H, sizeof *layers);
    if (g_failures || !bank || !input || !layers) return 1;
    for (k = 0; k < 3 * W * H; k++) input[k] = 0.01f;
    for (k = 0; k < 3; k++)
        for (c = 0; c < 3; c++)
            for (j = -1; j <= 1; j++)
                for (i = -1; i <= 1; i++) input[((size_t)c * H + at[k][1] + j) * W + at[k][0] + i] = value[k];
    d.bank = bank;
    d.f_number = F_NUMBER;
    d.width = W;
    d.height = H;
    d.focal_x_mm = li.focal_length_mm;
    d.n_channels = 3;
    d.channel_weights = weights;
    d.ghosts = ghosts;
    d.n_ghosts = 5;
    d.flare_downsample = downsample;
    memset(&im, 0, sizeof im);
    im.ctx = ctx;
    im.desc = d;
    im.channel_weights = weights;
    im.ghosts = ghosts;
    im.n_wavelengths = 8;
    im.wavelengths_nm = wl;
    im.focal_y_mm = li.focal_length_mm;
    im.axis_power = (double *)axis;
    im.plane = (size_t)W * H;
    im.sources = sources;
    CHECK_OK(ctx, image_flare_create(&im));
    CHECK_OK(ctx, image_flare_run(&im, input, layers));
    printf("bench: %d x %d, focal %.4f mm, f/%g, downsample %d: %d sources, %d ghost renders, worst error %.3g%%, "
           "%.2f s\n", W, H, li.focal_length_mm, F_NUMBER, downsample, (int)im.stats.n_sources,
           (int)im.stats.n_ghost_renders, 100.0 * im.stats.worst_flare_error, im.stats.seconds_flares);
    for (k = 0; k < im.stats.n_sources; k++)
        printf("  source %d: field (%.3f, %.3f) deg, %d pixels, power %g\n", k, sources[k].field_x_deg,
               sources[k].field_y_deg, (int)sources[k].pixels, sources[k].power);
    image_flare_destroy(&im);
    for (g = 0; g < 5; g++) lensrt_lens_destroy(ctx, ghosts[g]);
    lensrt_lens_destroy(ctx, lens);
    lensrt_bank_close(bank);
    lensrt_context_destroy(ctx);
    free(input);
    free(layers);
    return g_failures != 0;
}

int main(int argc, char **argv)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    lensrt_bank bank;
    lensrt_lens ghost = NULL;
    if (argc == 5 && strcmp(argv[1], "--bench") == 0) return bench(argv[2], argv[3], atoi(argv[4]));
    if (argc != 3) {
        fprintf(stderr, "usage: test_image_flare GHOST_TABLE SCRATCH_DIR\n");
        return 2;
    }
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) return 1;
    bank = open_bank(ctx, argv[2], N_WL, g_wl);
    CHECK_OK(ctx, lensrt_lens_load(ctx, argv[1], &ghost));
    if (bank && ghost) {
        test_sources(ctx, bank, &ghost);
        test_identity(ctx, bank, &ghost);
        test_downsample(ctx, bank, &ghost);
        test_domain(ctx, bank, &ghost);
    }
    lensrt_lens_destroy(ctx, ghost);
    lensrt_bank_close(bank);
    lensrt_context_destroy(ctx);
    printf("%d checks, %d failures\n", g_checks, g_failures);
    return g_failures != 0;
}
