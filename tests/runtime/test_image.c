/* test_image: an image through the lens (lensrt_image_*, issue 38), its direct layer
 * against references the test computes itself, on synthetic banks written here
 * (bank_files.h): node PSFs are Gaussians on odd or even windows, chief points at
 * f tan(field) (no distortion), or with distortion f tan(field) (1 + k r^2), or with
 * lateral colour; the frame is 64 x 64 pixels of 5 um behind a pinhole of 10 mm.
 *
 *   shift-invariant: every node the same PSF, 3 channels mixing 3 wavelengths: the
 *     direct layer is the plain convolution of the input with PSF / axis power, through
 *     the layer's own stencil at whole-pixel landings (direct_stencil: the splat's and the
 *     kernels' B-spline taps and the sharpening that undoes their spread; float
 *     rounding: 2e-6 of the largest value);
 *   axes: an off-centre frame of non-square pixels behind a pinhole of two focal lengths:
 *     the plain convolution again;
 *   energy: an even 16 x 16 PSF with lateral colour (sub-pixel shifts by B-spline taps): a
 *     point near the axis keeps its power in every channel to 1e-3 (issue 38's 0.1%: the
 *     taps and the sharpening keep it exactly; the clamp at 0 of a lone point's faint
 *     negative ring, where the sharpening turns a Gaussian's far tail, adds 3.2e-4), and
 *     a smooth frame, which leaves nothing to clamp, to 1e-6;
 *   seams: node PSFs of widths and powers varying with field: each point's output is its
 *     own PSF, the hat-weighted blend of the node PSFs on its chief point (through the
 *     stencil), to 1e-4 of the peak, beside the node lines (cell borders) and inside cells;
 *   distortion: a point's output has its centroid on the bank's interpolated chief point
 *     (lensrt_bank_psf's) within 0.02 px;
 *   threads: 1 and 3 threads give the same bits (distortion, lateral colour, 12 x 12);
 *   mirror: a lens symmetric about both axes (distortion, PSFs off their chief points
 *     away from the axis): a bank over the quadrant x, y >= 0 with LENSRT_IMAGE_MIRROR_X |
 *     _Y gives the whole grid's layer (1e-6 of the largest value); its refusals;
 *   refusals: a NaN or negative pixel, a wrong count, a frame wider than the field grid,
 *     a slice the bank lacks, bad weights, a direct lens as a ghost, a bad aperture, a
 *     bank of `registration chief`, struct_size 0,
 *     a layer or source out of range: the code, and a message naming the value.
 * Without OpenEXR the banks cannot be opened: the test checks that the open fails.
 *
 * usage: test_image SCRATCH_DIR */
#include "lensrt.h"

#include "check.h"
#include "bank_files.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifndef LENSRT_TEST_EXR
#define LENSRT_TEST_EXR 1
#endif

#define PI 3.14159265358979323846
#define FOCAL 10.0
#define PITCH 0.005
#define STENCIL 7 /* direct_stencil's taps */
enum { W = 64, H = 64 };
static const double FX[5] = {-1.2, -0.6, 0.0, 0.6, 1.2}, FY[5] = {-1.0, -0.5, 0.0, 0.5, 1.0};
static const double WL3[3] = {450.0, 550.0, 650.0}, WL1[1] = {550.0};
static char g_scratch[4096];

/* What a synthetic bank's nodes hold. */
typedef struct kind {
    double sigma;    /* the Gaussian's width (pixels) */
    int varying;     /* widths and powers varying with the node */
    double k_dist;   /* distortion: chief = f t (1 + k |t|^2) */
    double lateral;  /* lateral colour: pixels of x shift per wavelength step */
    double focal_y;  /* the chief points' focal length in y (0: FOCAL) */
    double coma;     /* the Gaussian's centre off the chief point: pixels per unit tan(field),
                        away from the axis (a PSF a mirror changes) */
} kind;

static double tan_deg(double deg)
{
    return tan(deg * (PI / 180.0));
}

static void kind_psf(const synth_bank *b, int ix, int iy, int l, float *out)
{
    const kind *k = b->user;
    const double sigma = k->sigma + (k->varying ? 0.3 * ix + 0.2 * iy : 0.0);
    const double power = k->varying ? 1.0 - 0.04 * ix - 0.03 * iy : 1.0;
    const double ox = k->coma != 0.0 ? k->coma * tan_deg(b->fx_deg[ix]) : 0.0;
    const double oy = k->coma != 0.0 ? k->coma * tan_deg(b->fy_deg[iy]) : 0.0;
    double sum = 0.0;
    int i, j;
    (void)l;
    // Centred on the window's centre (the chief point), or coma's offset from it (+x
    // right, +y up: row 0 at the top): pixel i at offset i + 0.5 - w / 2
    for (j = 0; j < b->h; j++)
        for (i = 0; i < b->w; i++) {
            const double x = i + 0.5 - 0.5 * b->w - ox, y = 0.5 * b->h - j - 0.5 - oy;
            sum += exp(-(x * x + y * y) / (2 * sigma * sigma));
        }
    for (j = 0; j < b->h; j++)
        for (i = 0; i < b->w; i++) {
            const double x = i + 0.5 - 0.5 * b->w - ox, y = 0.5 * b->h - j - 0.5 - oy;
            out[j * b->w + i] = (float)(power * exp(-(x * x + y * y) / (2 * sigma * sigma)) / sum);
        }
}

static void kind_chief(const synth_bank *b, int ix, int iy, int l, double xy[2])
{
    const kind *k = b->user;
    const double tx = tan_deg(b->fx_deg[ix]), ty = tan_deg(b->fy_deg[iy]), d = 1.0 + k->k_dist * (tx * tx + ty * ty);
    xy[0] = FOCAL * tx * d + k->lateral * (l - 1) * PITCH;
    xy[1] = (k->focal_y > 0.0 ? k->focal_y : FOCAL) * ty * d - 0.5 * k->lateral * (l - 1) * PITCH;
}

/* Write a bank of this kind over the field grid fx x fy (nx x ny degrees) and open it
 * (NULL on failure, checked). */
static lensrt_bank make_bank_grid(lensrt_context ctx, const char *name, const kind *k, int size, int n_wl,
                                  const char *registration, double pitch_y, const double *fx, int nx,
                                  const double *fy, int ny)
{
    synth_bank sb;
    char folder[4200], index[4400];
    lensrt_bank bank = NULL;
    memset(&sb, 0, sizeof sb);
    sb.w = sb.h = size;
    sb.pitch_mm = PITCH;
    sb.pitch_y_mm = pitch_y;
    sb.n_wl = n_wl;
    sb.wl_nm = n_wl == 3 ? WL3 : WL1;
    sb.nx = nx;
    sb.ny = ny;
    sb.fx_deg = fx;
    sb.fy_deg = fy;
    sb.f_number = 8.0;
    sb.registration = registration;
    sb.psf = kind_psf;
    sb.chief = kind_chief;
    sb.user = k;
    snprintf(folder, sizeof folder, "%s/%s", g_scratch, name);
    CHECK(synth_bank_write(&sb, folder, index, sizeof index), "cannot write the bank %s", folder);
    CHECK_OK(ctx, lensrt_bank_open(ctx, index, &bank));
    return bank;
}

/* Write a bank of this kind over the 5 x 5 field grid FX x FY and open it. */
static lensrt_bank make_bank(lensrt_context ctx, const char *name, const kind *k, int size, int n_wl,
                             const char *registration, double pitch_y)
{
    return make_bank_grid(ctx, name, k, size, n_wl, registration, pitch_y, FX, 5, FY, 5);
}

/* An image of the bank (NULL on failure, checked). */
static lensrt_image make_image(lensrt_context ctx, lensrt_bank bank, int n_channels, const double *weights)
{
    lensrt_image_desc d = LENSRT_IMAGE_DESC_INIT;
    lensrt_image im = NULL;
    d.bank = bank;
    d.width = W;
    d.height = H;
    d.focal_x_mm = FOCAL;
    d.n_channels = n_channels;
    d.channel_weights = weights;
    CHECK_OK(ctx, lensrt_image_create(ctx, &d, &im));
    return im;
}

/* The sum of the bank's axis PSF (field 0, 0) at 550 nm, as the library sums it. */
static double axis_power(lensrt_bank bank, const float *psf, size_t n)
{
    double s = 0.0;
    size_t p;
    (void)bank;
    for (p = 0; p < n; p++) s += (double)psf[p];
    return s;
}

/* The direct layer's operator, per axis, on a light landing on a pixel centre and a
 * kernel needing no shift (src/image/direct.c): the splat's quadratic B-spline taps
 * B2(-1), B2(0), B2(1) = 1/8, 3/4, 1/8, the kernels' the same, and the sharpening that
 * undoes their spread less a pixel's box's to second order, 1 + (5/12)(1 - cos omega):
 * the taps -5/24, 1 + 5/12, -5/24. STENCIL taps, centre STENCIL / 2, into e. */
static void direct_stencil(double e[STENCIL])
{
    const double b2[3] = {0.125, 0.75, 0.125}, sharp[3] = {-5.0 / 24.0, 1.0 + 5.0 / 12.0, -5.0 / 24.0};
    double bb[5] = {0.0};
    int i, j;
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++) bb[i + j] += b2[i] * b2[j];
    for (i = 0; i < STENCIL; i++) e[i] = 0.0;
    for (i = 0; i < 5; i++)
        for (j = 0; j < 3; j++) e[i + j] += bb[i] * sharp[j];
}

/* psf (s x s) through direct_stencil on both axes into out ((s + 6) x (s + 6), its centre
 * pixel the psf's). */
static void stencil_psf(const double *psf, int s, double *out)
{
    double e[STENCIL];
    const int n = s + STENCIL - 1;
    int x, y, a, b;
    direct_stencil(e);
    for (y = 0; y < n; y++)
        for (x = 0; x < n; x++) {
            double v = 0.0;
            for (b = 0; b < STENCIL; b++)
                for (a = 0; a < STENCIL; a++) {
                    const int px = x - a, py = y - b;
                    if (px >= 0 && px < s && py >= 0 && py < s) v += e[a] * e[b] * psf[py * s + px];
                }
            out[y * n + x] = v;
        }
}

/* ------------------------------------------------------ shift-invariant ----- */

/* The largest distance of out from the plain convolution of in (nc planes of w x h) with
 * psf through direct_stencil, / ap (psf s x s, odd: pixel (a, b) at offset (a - s / 2,
 * b - s / 2) from the light's pixel), and the convolution's largest value into *big. */
static double plain_convolution_error(const float *in, const float *out, int w, int h, int nc, const float *psf0,
                                      int s0, double ap, double *big)
{
    const int s = s0 + STENCIL - 1;
    double worst = 0.0, *psf = malloc((size_t)(s0 * s0 + s * s) * sizeof(double)), *p0 = psf + s * s;
    int c, x, y, a, b;
    *big = 0.0;
    if (!psf) return INFINITY;
    for (x = 0; x < s0 * s0; x++) p0[x] = psf0[x];
    stencil_psf(p0, s0, psf);
    for (c = 0; c < nc; c++)
        for (y = 0; y < h; y++)
            for (x = 0; x < w; x++) {
                double ref = 0.0, e;
                for (b = 0; b < s; b++)
                    for (a = 0; a < s; a++) {
                        const int sx = x - (a - s / 2), sy = y - (b - s / 2);
                        if (sx >= 0 && sx < w && sy >= 0 && sy < h)
                            ref += (double)in[(c * h + sy) * w + sx] * psf[b * s + a] / ap;
                    }
                e = fabs((double)out[(c * h + y) * w + x] - ref);
                worst = e > worst ? e : worst;
                *big = ref > *big ? ref : *big;
            }
    free(psf);
    return worst;
}


static void test_shift_invariant(lensrt_context ctx)
{
    static const double weights[9] = {1.0, 0.2, 0.0, 0.1, 1.0, 0.1, 0.0, 0.3, 1.0};
    const kind k = {1.3, 0, 0.0, 0.0, 0.0, 0.0};
    enum { S = 9, NC = 3 };
    synth_bank sb;
    float psf[S * S], *in = malloc(NC * W * H * sizeof(float)), *out = malloc(NC * W * H * sizeof(float));
    lensrt_bank bank = make_bank(ctx, "invariant", &k, S, 3, "channel", 0.0);
    lensrt_image im = bank ? make_image(ctx, bank, NC, weights) : NULL;
    lensrt_image_stats st = LENSRT_IMAGE_STATS_INIT;
    uint32_t seed = 12345;
    double ap, worst = 0.0, big = 0.0;
    int x;
    if (!im || !in || !out) goto done;
    memset(&sb, 0, sizeof sb);
    sb.w = sb.h = S;
    sb.user = &k;
    kind_psf(&sb, 2, 2, 1, psf);
    ap = axis_power(bank, psf, S * S);
    for (x = 0; x < NC * W * H; x++) {
        seed = seed * 1664525u + 1013904223u;
        in[x] = (float)(seed >> 8) / 16777216.0f;
    }
    CHECK_OK(ctx, lensrt_image_run(im, in, NC * W * H));
    CHECK_OK(ctx, lensrt_image_get_layer(im, LENSRT_IMAGE_DIRECT, out, NC * W * H));
    worst = plain_convolution_error(in, out, W, H, NC, psf, S, ap, &big);
    CHECK(worst <= 2e-6 * big, "shift-invariant: the direct layer is %g (of %g) from the plain convolution", worst, big);
    CHECK_OK(ctx, lensrt_image_get_stats(im, &st));
    CHECK(st.n_nodes == 25 && st.fft_width > 0 && st.fft_height > 0 && st.seconds_convolve >= 0.0,
          "stats: %d nodes, largest transform %d x %d", (int)st.n_nodes, (int)st.fft_width, (int)st.fft_height);
    printf("test_image: shift-invariant: %.3g of the largest value; %d nodes, transforms up to %d x %d\n",
           worst / big, (int)st.n_nodes, (int)st.fft_width, (int)st.fft_height);
done:
    lensrt_image_destroy(im);
    lensrt_bank_close(bank);
    free(in);
    free(out);
}

/* The frame's geometry on both axes: a frame off the axis (centre 0.03, -0.02 mm), 40 x
 * 50 pixels of 5 x 4 um, a pinhole of focal lengths 10 and 12 mm with the bank's chief
 * points at (10 tan field_x, 12 tan field_y): every pixel lands on itself, and the
 * direct layer is the plain convolution again. */
static void test_axes(lensrt_context ctx)
{
    const kind k = {1.1, 0, 0.0, 0.0, 12.0, 0.0};
    enum { S = 9, AW = 40, AH = 50 };
    synth_bank sb;
    float psf[S * S], *in = malloc(AW * AH * sizeof(float)), *out = malloc(AW * AH * sizeof(float));
    lensrt_bank bank = make_bank(ctx, "axes", &k, S, 1, "channel", 0.004);
    lensrt_image_desc d = LENSRT_IMAGE_DESC_INIT;
    lensrt_image im = NULL;
    uint32_t seed = 777;
    double big = 0.0, worst;
    int x;
    if (!bank || !in || !out) goto done;
    d.bank = bank;
    d.width = AW;
    d.height = AH;
    d.center_x_mm = 0.03;
    d.center_y_mm = -0.02;
    d.focal_x_mm = FOCAL;
    d.focal_y_mm = 12.0;
    d.n_channels = 1;
    CHECK_OK(ctx, lensrt_image_create(ctx, &d, &im));
    if (!im) goto done;
    memset(&sb, 0, sizeof sb);
    sb.w = sb.h = S;
    sb.user = &k;
    kind_psf(&sb, 2, 2, 0, psf);
    for (x = 0; x < AW * AH; x++) {
        seed = seed * 1664525u + 1013904223u;
        in[x] = (float)(seed >> 8) / 16777216.0f;
    }
    CHECK_OK(ctx, lensrt_image_run(im, in, AW * AH));
    CHECK_OK(ctx, lensrt_image_get_layer(im, LENSRT_IMAGE_DIRECT, out, AW * AH));
    worst = plain_convolution_error(in, out, AW, AH, 1, psf, S, axis_power(bank, psf, S * S), &big);
    CHECK(worst <= 2e-6 * big, "axes: the direct layer is %g (of %g) from the plain convolution", worst, big);
    printf("test_image: axes (off-centre, 5 x 4 um, focal 10 x 12 mm): %.3g of the largest value\n", worst / big);
done:
    lensrt_image_destroy(im);
    lensrt_bank_close(bank);
    free(in);
    free(out);
}

/* --------------------------------------------------------------- energy ----- */

static void test_energy(lensrt_context ctx)
{
    static const double weights[9] = {1.0, 0.5, 0.0, 0.2, 1.0, 0.2, 0.0, 0.5, 1.0};
    const kind k = {1.5, 0, 0.0, 0.37, 0.0, 0.0};
    enum { NC = 3 };
    float *in = calloc(NC * W * H, sizeof(float)), *out = malloc(NC * W * H * sizeof(float));
    lensrt_bank bank = make_bank(ctx, "energy", &k, 16, 3, "channel", 0.0);
    lensrt_image im = bank ? make_image(ctx, bank, NC, weights) : NULL;
    int c, p;
    if (!im || !in || !out) goto done;
    // A point of power 2 in every channel, a few pixels off the axis
    for (c = 0; c < NC; c++) in[(c * H + 29) * W + 35] = 2.0f;
    CHECK_OK(ctx, lensrt_image_run(im, in, NC * W * H));
    CHECK_OK(ctx, lensrt_image_get_layer(im, LENSRT_IMAGE_DIRECT, out, NC * W * H));
    for (c = 0; c < NC; c++) {
        double sum = 0.0;
        for (p = 0; p < W * H; p++) sum += out[c * W * H + p];
        CHECK(fabs(sum / 2.0 - 1.0) < 1e-3, "energy: channel %d keeps %.9g of the point's power", c, sum / 2.0);
        printf("test_image: energy: channel %d keeps %.9f\n", c, sum / 2.0);
    }
    // A smooth blob (a Gaussian of 4 pixels, its power far from the frame's edges): every
    // output value is covered by light from around it, nothing is clamped, and the power
    // is kept to float rounding
    for (c = 0; c < NC; c++)
        for (p = 0; p < W * H; p++) {
            const double dx = p % W - 31.5, dy = p / W - 30.5;
            in[c * W * H + p] = (float)exp(-(dx * dx + dy * dy) / 32.0);
        }
    CHECK_OK(ctx, lensrt_image_run(im, in, NC * W * H));
    CHECK_OK(ctx, lensrt_image_get_layer(im, LENSRT_IMAGE_DIRECT, out, NC * W * H));
    for (c = 0; c < NC; c++) {
        double sum = 0.0, want = 0.0;
        for (p = 0; p < W * H; p++) {
            sum += out[c * W * H + p];
            want += in[c * W * H + p];
        }
        CHECK(fabs(sum / want - 1.0) < 1e-6, "energy: channel %d keeps %.9g of a smooth blob's power", c, sum / want);
    }
done:
    lensrt_image_destroy(im);
    lensrt_bank_close(bank);
    free(in);
    free(out);
}

/* ---------------------------------------------------------------- seams ----- */

/* The hat weights of t over a grid of tan angles (n values, ascending). */
static void hat(const double *deg, int n, double t, double *w)
{
    int a;
    for (a = 0; a < n; a++) w[a] = 0.0;
    for (a = 0; a + 1 < n; a++) {
        const double t0 = tan_deg(deg[a]), t1 = tan_deg(deg[a + 1]);
        if (t >= t0 && t <= t1) {
            w[a] = (t1 - t) / (t1 - t0);
            w[a + 1] = (t - t0) / (t1 - t0);
            return;
        }
    }
}

static void test_seams(lensrt_context ctx)
{
    /* Beside the node lines (columns 10, 11 | 31, 32 | 52, 53; rows 14, 15 | 48, 49) and
     * inside cells */
    static const int points[][2] = {{10, 14}, {11, 15}, {31, 31}, {32, 32}, {52, 48}, {53, 49}, {20, 40}, {42, 22},
                                    {3, 60}, {60, 3}};
    const kind k = {1.0, 1, 0.0, 0.0, 0.0, 0.0};
    enum { S = 11, SE = S + STENCIL - 1 };
    synth_bank sb;
    float node[25][S * S], *in = calloc(W * H, sizeof(float)), *out = malloc(W * H * sizeof(float));
    double blend[S * S], own[SE * SE];
    lensrt_bank bank = make_bank(ctx, "seams", &k, S, 1, "channel", 0.0);
    lensrt_image im = bank ? make_image(ctx, bank, 1, NULL) : NULL;
    double ap, worst = 0.0;
    size_t q;
    int n;
    if (!im || !in || !out) goto done;
    memset(&sb, 0, sizeof sb);
    sb.w = sb.h = S;
    sb.user = &k;
    for (n = 0; n < 25; n++) kind_psf(&sb, n % 5, n / 5, 0, node[n]);
    ap = axis_power(bank, node[2 * 5 + 2], S * S);
    for (q = 0; q < sizeof points / sizeof points[0]; q++) {
        const int i = points[q][0], j = points[q][1];
        const double tx = (i + 0.5 - 0.5 * W) * PITCH / FOCAL, ty = (0.5 * H - j - 0.5) * PITCH / FOCAL;
        double wx[5], wy[5], peak = 0.0, err = 0.0;
        int x, y;
        in[j * W + i] = 1.0f;
        CHECK_OK(ctx, lensrt_image_run(im, in, W * H));
        CHECK_OK(ctx, lensrt_image_get_layer(im, LENSRT_IMAGE_DIRECT, out, W * H));
        in[j * W + i] = 0.0f;
        // The point's own PSF: the hat-weighted blend of the node PSFs, through the
        // stencil, on its pixel
        hat(FX, 5, tx, wx);
        hat(FY, 5, ty, wy);
        for (x = 0; x < S * S; x++) {
            int ix, iy;
            blend[x] = 0.0;
            for (iy = 0; iy < 5; iy++)
                for (ix = 0; ix < 5; ix++) blend[x] += wx[ix] * wy[iy] * node[iy * 5 + ix][x] / ap;
        }
        stencil_psf(blend, S, own);
        for (y = 0; y < H; y++)
            for (x = 0; x < W; x++) {
                const int a = x - i + SE / 2, b = y - j + SE / 2;
                // (a lone point: where the sharpening of the widest node PSFs, cut off by
                // their 11-pixel windows, dips below 0, the layer's clamp at 0 holds)
                const double ref = a >= 0 && a < SE && b >= 0 && b < SE && own[b * SE + a] > 0.0 ? own[b * SE + a] : 0.0;
                peak = ref > peak ? ref : peak;
                err = fabs(out[y * W + x] - ref) > err ? fabs(out[y * W + x] - ref) : err;
            }
        CHECK(err <= 1e-4 * peak, "seams: the point at pixel (%d, %d) is %g (of its peak %g) from its own PSF", i, j,
              err, peak);
        worst = err / peak > worst ? err / peak : worst;
    }
    printf("test_image: seams: each point within %.3g of its own PSF's peak\n", worst);
done:
    lensrt_image_destroy(im);
    lensrt_bank_close(bank);
    free(in);
    free(out);
}

/* ----------------------------------------------------------- distortion ----- */

static void test_distortion(lensrt_context ctx)
{
    static const int points[][2] = {{5, 6}, {58, 7}, {32, 32}, {12, 50}, {55, 57}, {40, 20}};
    const kind k = {1.2, 0, 150.0, 0.0, 0.0, 0.0};
    enum { S = 11 };
    float *in = calloc(W * H, sizeof(float)), *out = malloc(W * H * sizeof(float)), psf[S * S];
    lensrt_bank bank = make_bank(ctx, "distortion", &k, S, 1, "channel", 0.0);
    lensrt_image im = bank ? make_image(ctx, bank, 1, NULL) : NULL;
    double worst = 0.0, moved = 0.0;
    size_t q;
    if (!im || !in || !out) goto done;
    for (q = 0; q < sizeof points / sizeof points[0]; q++) {
        const int i = points[q][0], j = points[q][1];
        lensrt_bank_query bq = LENSRT_BANK_QUERY_INIT;
        double chief[2], sx = 0.0, sy = 0.0, s = 0.0, u, v, e;
        int x, y;
        in[j * W + i] = 1.0f;
        CHECK_OK(ctx, lensrt_image_run(im, in, W * H));
        CHECK_OK(ctx, lensrt_image_get_layer(im, LENSRT_IMAGE_DIRECT, out, W * H));
        in[j * W + i] = 0.0f;
        for (y = 0; y < H; y++)
            for (x = 0; x < W; x++) {
                sx += x * (double)out[y * W + x];
                sy += y * (double)out[y * W + x];
                s += out[y * W + x];
            }
        // Where the bank's own interpolation puts the pixel's field point
        bq.field_x_deg = atan((i + 0.5 - 0.5 * W) * PITCH / FOCAL) * 180.0 / PI;
        bq.field_y_deg = atan((0.5 * H - j - 0.5) * PITCH / FOCAL) * 180.0 / PI;
        bq.wavelength_nm = 550.0;
        CHECK_OK(ctx, lensrt_bank_psf(bank, &bq, psf, S * S, chief));
        u = chief[0] / PITCH + 0.5 * W - 0.5;
        v = 0.5 * H - 0.5 - chief[1] / PITCH;
        e = hypot(sx / s - u, sy / s - v);
        CHECK(e < 0.02, "distortion: the point at pixel (%d, %d) has its centroid at (%.4f, %.4f), %.4f px from the "
              "chief point's (%.4f, %.4f)", i, j, sx / s, sy / s, e, u, v);
        worst = e > worst ? e : worst;
        moved = hypot(u - i, v - j) > moved ? hypot(u - i, v - j) : moved;
    }
    CHECK(moved > 1.0, "distortion: the points moved %g px at most; the test needs more", moved);
    printf("test_image: distortion: centroids within %.2g px of the chief points (moved up to %.2f px)\n", worst,
           moved);
done:
    lensrt_image_destroy(im);
    lensrt_bank_close(bank);
    free(in);
    free(out);
}

/* --------------------------------------------------------------- mirror ----- */

/* A lens mirror-symmetric about both axes (distortion, PSFs whose centres lie off the
 * chief point away from the axis, widths growing with the field): the frame through the
 * bank over the whole grid, and through the bank over its quadrant x, y >= 0 with
 * LENSRT_IMAGE_MIRROR_X | _Y: the same layer (the mirrored nodes' kernels are the
 * others' exactly, so the same sums: float rounding at most). And the refusals. */
static void test_mirror(lensrt_context ctx)
{
    static const double weights[9] = {1.0, 0.2, 0.0, 0.1, 1.0, 0.1, 0.0, 0.3, 1.0};
    static const double QX[3] = {0.0, 0.6, 1.2}, QY[3] = {0.0, 0.5, 1.0};
    const kind k = {1.1, 0, 60.0, 0.0, 0.0, 40.0};
    enum { NC = 3, S = 13 };
    float *in = malloc(NC * W * H * sizeof(float)), *a = malloc(NC * W * H * sizeof(float)),
          *b = malloc(NC * W * H * sizeof(float));
    lensrt_bank full = make_bank_grid(ctx, "mirror-full", &k, S, 3, "channel", 0.0, FX, 5, FY, 5);
    lensrt_bank quad = make_bank_grid(ctx, "mirror-quadrant", &k, S, 3, "channel", 0.0, QX, 3, QY, 3);
    lensrt_image_desc d = LENSRT_IMAGE_DESC_INIT;
    lensrt_image ia = NULL, ib = NULL;
    double worst = 0.0, big = 0.0;
    uint32_t seed = 4242;
    int x;
    if (!full || !quad || !in || !a || !b) goto done;
    for (x = 0; x < NC * W * H; x++) {
        seed = seed * 1664525u + 1013904223u;
        in[x] = (seed >> 28) == 0 ? 50.0f : (float)(seed >> 8) / 16777216.0f; // points over a floor
    }
    ia = make_image(ctx, full, NC, weights);
    d.bank = quad;
    d.width = W;
    d.height = H;
    d.focal_x_mm = FOCAL;
    d.n_channels = NC;
    d.channel_weights = weights;
    // Without the mirror, the quadrant's bank does not cover the frame
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_image_create(ctx, &d, &ib));
    CHECK_MSG(ctx, "field_x spans");
    d.mirror = LENSRT_IMAGE_MIRROR_X | LENSRT_IMAGE_MIRROR_Y;
    CHECK_OK(ctx, lensrt_image_create(ctx, &d, &ib));
    if (!ia || !ib) goto done;
    CHECK_OK(ctx, lensrt_image_run(ia, in, NC * W * H));
    CHECK_OK(ctx, lensrt_image_run(ib, in, NC * W * H));
    CHECK_OK(ctx, lensrt_image_get_layer(ia, LENSRT_IMAGE_DIRECT, a, NC * W * H));
    CHECK_OK(ctx, lensrt_image_get_layer(ib, LENSRT_IMAGE_DIRECT, b, NC * W * H));
    for (x = 0; x < NC * W * H; x++) {
        worst = fabs((double)a[x] - b[x]) > worst ? fabs((double)a[x] - b[x]) : worst;
        big = a[x] > big ? a[x] : big;
    }
    CHECK(worst <= 1e-6 * big, "mirror: the quadrant's bank mirrored is %g (of %g) from the whole grid's", worst, big);
    printf("test_image: mirror: a quadrant's bank mirrored gives the whole grid's layer to %.3g of its largest "
           "value\n", worst / big);
    // A bank with both signs needs no mirror; unknown bits
    lensrt_image_destroy(ib);
    ib = NULL;
    d.bank = full;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &ib));
    CHECK_MSG(ctx, "field_x_deg starts at -1.2");
    d.bank = quad;
    d.mirror = 4;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &ib));
    CHECK_MSG(ctx, "mirror is 4");
done:
    lensrt_image_destroy(ia);
    lensrt_image_destroy(ib);
    lensrt_bank_close(full);
    lensrt_bank_close(quad);
    free(in);
    free(a);
    free(b);
}

/* --------------------------------------------------------------- threads ----- */

/* The same frame through contexts of 1 and 3 threads: the same bits (nodes in batches,
 * added in node order). */
static void test_threads(lensrt_context ctx)
{
    const kind k = {1.0, 1, 40.0, 0.3, 0.0, 0.0};
    enum { NC = 3 };
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context one = NULL, three = NULL;
    lensrt_bank bank = make_bank(ctx, "threads", &k, 12, 3, "channel", 0.0);
    lensrt_image a = NULL, b = NULL;
    float *in = malloc(NC * W * H * sizeof(float)), *oa = malloc(NC * W * H * sizeof(float));
    float *ob = malloc(NC * W * H * sizeof(float));
    uint32_t seed = 99;
    int p;
    init.threads = 1;
    CHECK_OK(NULL, lensrt_context_create(&init, &one));
    init.threads = 3;
    CHECK_OK(NULL, lensrt_context_create(&init, &three));
    if (!bank || !one || !three || !in || !oa || !ob) goto done;
    a = make_image(one, bank, NC, NULL);
    b = make_image(three, bank, NC, NULL);
    if (!a || !b) goto done;
    for (p = 0; p < NC * W * H; p++) {
        seed = seed * 1664525u + 1013904223u;
        in[p] = (seed >> 28) == 0 ? (float)(seed >> 8) / 65536.0f : 0.0f;
    }
    CHECK_OK(one, lensrt_image_run(a, in, NC * W * H));
    CHECK_OK(three, lensrt_image_run(b, in, NC * W * H));
    CHECK_OK(one, lensrt_image_get_layer(a, LENSRT_IMAGE_DIRECT, oa, NC * W * H));
    CHECK_OK(three, lensrt_image_get_layer(b, LENSRT_IMAGE_DIRECT, ob, NC * W * H));
    CHECK(memcmp(oa, ob, NC * W * H * sizeof(float)) == 0, "threads: 1 and 3 threads give different direct layers");
done:
    lensrt_image_destroy(a);
    lensrt_image_destroy(b);
    lensrt_bank_close(bank);
    lensrt_context_destroy(one);
    lensrt_context_destroy(three);
    free(in);
    free(oa);
    free(ob);
}

/* ------------------------------------------------------------- refusals ----- */

static void test_refusals(lensrt_context ctx)
{
    const kind k = {1.0, 0, 0.0, 0.0, 0.0, 0.0};
    lensrt_bank bank = make_bank(ctx, "refusals", &k, 9, 3, "channel", 0.0);
    lensrt_bank chief_bank = make_bank(ctx, "chief", &k, 9, 3, "chief", 0.0);
    lensrt_image_desc d = LENSRT_IMAGE_DESC_INIT;
    lensrt_image im = NULL;
    lensrt_image_source src = LENSRT_IMAGE_SOURCE_INIT;
    lensrt_image_stats st = LENSRT_IMAGE_STATS_INIT;
    double weights[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    float *in = calloc(3 * W * H, sizeof(float));
    if (!bank || !chief_bank || !in) goto done;
    d.bank = bank;
    d.width = W;
    d.height = H;
    d.focal_x_mm = FOCAL;
    d.n_channels = 3;
    // A frame wider than the field grid (+-1.2 deg: 10 mm x tan 1.2 deg = 41.9 pixels)
    d.width = 100;
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "field_x spans [-1.4");
    CHECK_MSG(ctx, "[-1.2, 1.2]");
    d.width = W;
    d.center_y_mm = 0.1;
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "field_y spans");
    d.center_y_mm = 0.0;
    // A slice the bank lacks
    d.f_number = 5.5;
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "f_number 5.5 is not one of the bank's: 8");
    d.f_number = 0.0;
    d.distance_mm = 1000.0;
    CHECK_RES(ctx, LENSRT_ERROR_OUT_OF_DOMAIN, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "distance_mm 1000");
    d.distance_mm = 0.0;
    // Bad weights: negative, NaN, a row of zeros; NULL with a channel count not the bank's
    d.channel_weights = weights;
    weights[3] = -0.5;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "channel_weights[1][0] (channel 1, 450 nm) is -0.5");
    weights[3] = NAN;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "channel_weights[1][0]");
    weights[3] = 0.0;
    weights[4] = 0.0;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "row 1 sums to 0");
    weights[4] = 1.0;
    d.channel_weights = NULL;
    d.n_channels = 2;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "n_channels is 2 and the bank has 3 wavelengths");
    d.n_channels = 3;
    // Other fields, each named with its value
    d.focal_x_mm = -1.0;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "focal_x_mm is -1");
    d.focal_x_mm = FOCAL;
    d.width = 0;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "width x height is 0 x 64");
    d.width = W;
    d.max_sources = -2;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "max_sources is -2");
    d.max_sources = 0;
    // The flares' description: a direct lens as a ghost, an unknown aperture shape
    {
        lensrt_analytic_lens al = LENSRT_ANALYTIC_LENS_INIT;
        lensrt_lens lens = NULL;
        al.focal_length_mm = FOCAL;
        al.sensor_distance_mm = FOCAL;
        CHECK_OK(ctx, lensrt_lens_create_analytic(ctx, &al, &lens));
        d.ghosts = &lens;
        d.n_ghosts = 1;
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
        CHECK_MSG(ctx, "ghosts[0] (");
        CHECK_MSG(ctx, "is not a ghost table");
        d.ghosts = NULL;
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
        CHECK_MSG(ctx, "ghosts is NULL with n_ghosts 1");
        d.n_ghosts = 0;
        d.aperture.shape = 7;
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
        CHECK_MSG(ctx, "aperture.shape is 7");
        d.aperture.shape = 0;
        d.aperture.radius_mm = -1.0;
        CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
        CHECK_MSG(ctx, "aperture radius_mm -1");
        d.aperture.radius_mm = 0.0;
        lensrt_lens_destroy(ctx, lens);
    }
    // A bank of `registration chief`
    d.bank = chief_bank;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "registration is 'chief'");
    d.bank = bank;
    // struct_size 0
    d.struct_size = 0;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_create(ctx, &d, &im));
    CHECK_MSG(ctx, "LENSRT_*_INIT");
    d.struct_size = sizeof d;
    CHECK(im == NULL, "a refused create left an image");
    // Then a good one, and its run's refusals
    CHECK_OK(ctx, lensrt_image_create(ctx, &d, &im));
    if (!im) goto done;
    in[(2 * H + 7) * W + 5] = NAN;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_run(im, in, 3 * W * H));
    CHECK_MSG(ctx, "input channel 2 pixel (5, 7) is nan");
    in[(2 * H + 7) * W + 5] = -1.0f;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_run(im, in, 3 * W * H));
    CHECK_MSG(ctx, "input channel 2 pixel (5, 7) is -1");
    in[(2 * H + 7) * W + 5] = INFINITY;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_run(im, in, 3 * W * H));
    CHECK_MSG(ctx, "is inf");
    in[(2 * H + 7) * W + 5] = 1.0f;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_run(im, in, 3 * W * H - 1));
    CHECK_MSG(ctx, "count must be 12288");
    CHECK_OK(ctx, lensrt_image_run(im, in, 3 * W * H));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_get_layer(im, 2, in, 3 * W * H));
    CHECK_MSG(ctx, "layer 2; the image has 0 .. 1");
    CHECK_OK(ctx, lensrt_image_get_layer(im, LENSRT_IMAGE_FLARE, in, 3 * W * H));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_image_get_source(im, 0, &src));
    CHECK_MSG(ctx, "source 0; the last run found 0");
    CHECK_OK(ctx, lensrt_image_get_stats(im, &st));
    CHECK(st.n_sources == 0 && st.worst_flare_error == -1.0 && st.n_nodes == 4, "stats after one point: %d sources, "
          "worst flare error %g, %d nodes", (int)st.n_sources, st.worst_flare_error, (int)st.n_nodes);
done:
    lensrt_image_destroy(im);
    lensrt_bank_close(bank);
    lensrt_bank_close(chief_bank);
    free(in);
}

/* Without OpenEXR: the bank's index opens, its nodes do not, so nor does an image. */
static void test_without_exr(lensrt_context ctx)
{
    const kind k = {1.0, 0, 0.0, 0.0, 0.0, 0.0};
    synth_bank sb;
    char folder[4200], index[4400];
    lensrt_bank bank = NULL;
    lensrt_image_desc d = LENSRT_IMAGE_DESC_INIT;
    lensrt_image im = NULL;
    memset(&sb, 0, sizeof sb);
    sb.w = sb.h = 9;
    sb.pitch_mm = PITCH;
    sb.n_wl = 1;
    sb.wl_nm = WL1;
    sb.nx = sb.ny = 5;
    sb.fx_deg = FX;
    sb.fy_deg = FY;
    sb.f_number = 8.0;
    sb.registration = "channel";
    sb.psf = kind_psf;
    sb.chief = kind_chief;
    sb.user = &k;
    snprintf(folder, sizeof folder, "%s/no-exr", g_scratch);
    CHECK(synth_bank_write(&sb, folder, index, sizeof index), "cannot write %s", folder);
    CHECK_OK(ctx, lensrt_bank_open(ctx, index, &bank));
    if (!bank) return;
    d.bank = bank;
    d.width = W;
    d.height = H;
    d.focal_x_mm = FOCAL;
    d.n_channels = 1;
    CHECK_RES(ctx, LENSRT_ERROR_UNSUPPORTED, lensrt_image_create(ctx, &d, &im));
    lensrt_bank_close(bank);
}

int main(int argc, char **argv)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    if (argc < 2) {
        fprintf(stderr, "usage: %s SCRATCH_DIR\n", argv[0]);
        return 2;
    }
    snprintf(g_scratch, sizeof g_scratch, "%s", argv[1]);
    if (mkdir(g_scratch, 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "cannot create the scratch folder '%s': %s\n", g_scratch, strerror(errno));
        return 2;
    }
    init.threads = 2;
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) {
        fprintf(stderr, "lensrt_context_create failed\n");
        return 1;
    }
    CHECK(lensrt_version() >= 11000u, "lensrt %s: the image calls are 0.11.0's", lensrt_version_string());
    if (LENSRT_TEST_EXR) {
        test_shift_invariant(ctx);
        test_axes(ctx);
        test_energy(ctx);
        test_seams(ctx);
        test_distortion(ctx);
        test_threads(ctx);
        test_mirror(ctx);
        test_refusals(ctx);
    } else {
        test_without_exr(ctx);
    }
    lensrt_context_destroy(ctx);
    printf("test_image: %d checks, %d failed\n", g_checks, g_failures);
    return g_failures == 0 ? 0 : 1;
}
