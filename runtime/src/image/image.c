/* An image through the lens (lensrt.h, "an image through the lens"; issue 38): the public
 * calls. The description is checked field by field (each message names the key and the
 * value), copied, and the shared object of image.h filled; direct.c and flare.c do the
 * work. */
#include "image.h"

#include "../internal.h"

#include <math.h>
#include <string.h>

#define IMAGE_PI 3.14159265358979323846
#define IMAGE_DEFAULT_SOURCES 16
#define IMAGE_DEFAULT_TARGET_ERROR 0.02
#define IMAGE_DEFAULT_DOWNSAMPLE 4
#define IMAGE_MAX_OVERSAMPLE 16

/* The field angle (deg) a pinhole of focal length f sees at sensor coordinate x (mm). */
static double pinhole_deg(double x, double f)
{
    return atan(x / f) * (180.0 / IMAGE_PI);
}

/* The scalar fields of the description, one by one (defaults filled into d). */
static lensrt_result check_numbers(lensrt_context ctx, lensrt_image_desc *d)
{
    if (d->width < 1 || d->width > LENSRT_MAX_RESOLUTION || d->height < 1 || d->height > LENSRT_MAX_RESOLUTION)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: width x height is %d x %d; each is "
                           "1 .. %d", (int)d->width, (int)d->height, LENSRT_MAX_RESOLUTION);
    if (!isfinite(d->center_x_mm) || !isfinite(d->center_y_mm))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: center (%g, %g) mm is not finite",
                           d->center_x_mm, d->center_y_mm);
    if (!(isfinite(d->focal_x_mm) && d->focal_x_mm > 0.0))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: focal_x_mm is %g; it must be finite "
                           "and > 0", d->focal_x_mm);
    if (!(isfinite(d->focal_y_mm) && d->focal_y_mm >= 0.0))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: focal_y_mm is %g; it must be finite "
                           "and > 0 (0: focal_x_mm)", d->focal_y_mm);
    if (!isfinite(d->f_number) || !isfinite(d->focus_offset_mm) || !isfinite(d->distance_mm))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: the slice (f_number %g, "
                           "focus_offset_mm %g, distance_mm %g) is not finite", d->f_number, d->focus_offset_mm,
                           d->distance_mm);
    if (d->n_channels < 1 || d->n_channels > LENSRT_MAX_WAVELENGTHS)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: n_channels is %d; it must be 1 .. %d",
                           (int)d->n_channels, LENSRT_MAX_WAVELENGTHS);
    if (d->n_ghosts < 0 || d->n_ghosts > LENSRT_MAX_LAYERS - 2)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: n_ghosts is %d; it must be 0 .. %d",
                           (int)d->n_ghosts, LENSRT_MAX_LAYERS - 2);
    if (!(isfinite(d->flare_threshold) && d->flare_threshold >= 0.0))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: flare_threshold is %g; it must be "
                           "finite and >= 0 (0: the largest channel sum / 16)", d->flare_threshold);
    if (d->max_sources < 0)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: max_sources is %d; it must be >= 0 "
                           "(0: %d)", (int)d->max_sources, IMAGE_DEFAULT_SOURCES);
    if (!(isfinite(d->flare_target_error) && d->flare_target_error >= 0.0))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: flare_target_error is %g; it must be "
                           "finite and >= 0 (0: %g)", d->flare_target_error, IMAGE_DEFAULT_TARGET_ERROR);
    if (d->flare_downsample < 0)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: flare_downsample is %d; it must be "
                           ">= 0 (0: %d)", (int)d->flare_downsample, IMAGE_DEFAULT_DOWNSAMPLE);
    if (d->oversample < 0 || d->oversample > IMAGE_MAX_OVERSAMPLE ||
        (d->oversample > 1 && ((int64_t)d->width * d->oversample > LENSRT_MAX_RESOLUTION ||
                               (int64_t)d->height * d->oversample > LENSRT_MAX_RESOLUTION)))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: oversample is %d; it must be 0 .. %d "
                           "(0: 1) with width and height times it at most %d", (int)d->oversample,
                           IMAGE_MAX_OVERSAMPLE, LENSRT_MAX_RESOLUTION);
    // The defaults zero stands for
    if (d->max_sources == 0) d->max_sources = IMAGE_DEFAULT_SOURCES;
    if (d->flare_target_error == 0.0) d->flare_target_error = IMAGE_DEFAULT_TARGET_ERROR;
    if (d->flare_downsample == 0) d->flare_downsample = IMAGE_DEFAULT_DOWNSAMPLE;
    return LENSRT_SUCCESS;
}

/* The ghost renders' aperture, as a render checks it (core/scene.c), and the ghosts:
 * each a ghost table (its own info says so). */
static lensrt_result check_flares(lensrt_context ctx, const lensrt_image_desc *d)
{
    const lensrt_aperture *a = &d->aperture;
    int g;
    if ((unsigned)a->shape > LENSRT_APERTURE_SLIT)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: aperture.shape is %d; it must be "
                           "circle (0), blades (1) or slit (2)", (int)a->shape);
    if (!(isfinite(a->radius_mm) && a->radius_mm >= 0.0) || !(isfinite(a->f_number) && a->f_number >= 0.0) ||
        !isfinite(a->rotation_deg))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: aperture radius_mm %g, f_number %g, "
                           "rotation_deg %g: each must be finite and the first two >= 0", a->radius_mm, a->f_number,
                           a->rotation_deg);
    if (a->shape == LENSRT_APERTURE_BLADES &&
        (a->blades < 3 || a->blades > LENSRT_MAX_BLADES || !(a->blade_curvature >= 0.0 && a->blade_curvature <= 1.0)))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: aperture blades %d, blade_curvature "
                           "%g; blades are 3 .. %d, curvature in [0, 1]", (int)a->blades, a->blade_curvature,
                           LENSRT_MAX_BLADES);
    if (a->shape == LENSRT_APERTURE_SLIT &&
        (!(a->slit_width_mm > 0.0) || !(a->slit_separation_mm >= 0.0) ||
         (a->slit_separation_mm > 0.0 && a->slit_separation_mm < a->slit_width_mm)))
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: aperture slit_width_mm %g, "
                           "slit_separation_mm %g; a slit needs width > 0 and a separation of 0 or at least the "
                           "width", a->slit_width_mm, a->slit_separation_mm);
    if (d->n_ghosts > 0 && !d->ghosts)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: ghosts is NULL with n_ghosts %d",
                           (int)d->n_ghosts);
    for (g = 0; g < d->n_ghosts; g++) {
        lensrt_lens_info info = LENSRT_LENS_INFO_INIT;
        lensrt_result res;
        if (!d->ghosts[g])
            return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: ghosts[%d] is NULL", g);
        if ((res = lensrt_lens_get_info(d->ghosts[g], &info)) != LENSRT_SUCCESS) return res;
        if (!info.ghost)
            return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: ghosts[%d] (%s) is not a ghost "
                               "table (a lens's direct table)", g, info.name ? info.name : "");
    }
    return LENSRT_SUCCESS;
}

/* The channel weights: n_channels rows over the bank's wavelengths, each finite, >= 0 and
 * summing to > 0; NULL is one channel per wavelength (the identity). Copied into im. */
static lensrt_result copy_weights(struct lensrt_image_s *im, const double *w)
{
    const int nc = im->desc.n_channels, nl = im->n_wavelengths;
    int c, l;
    if (!w && nc != nl)
        return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: channel_weights is NULL (one "
                           "channel per bank wavelength) but n_channels is %d and the bank has %d wavelengths", nc, nl);
    im->channel_weights = lensrt_calloc(im->ctx, (size_t)nc * (size_t)nl, sizeof(double));
    if (!im->channel_weights)
        return lensrt_fail(im->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "lensrt_image_create: out of memory for %d x %d "
                           "channel weights", nc, nl);
    for (c = 0; c < nc; c++) {
        double sum = 0.0;
        for (l = 0; l < nl; l++) {
            const double v = w ? w[(size_t)c * (size_t)nl + (size_t)l] : (double)(c == l);
            if (!(isfinite(v) && v >= 0.0))
                return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: channel_weights[%d][%d] "
                                   "(channel %d, %g nm) is %g; weights are finite and >= 0", c, l, c,
                                   im->wavelengths_nm[l], v);
            im->channel_weights[(size_t)c * (size_t)nl + (size_t)l] = v;
            sum += v;
        }
        if (!(sum > 0.0) || !isfinite(sum))
            return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: channel_weights row %d sums "
                               "to %g; each row must sum to > 0", c, sum);
    }
    im->desc.channel_weights = im->channel_weights;
    return LENSRT_SUCCESS;
}

/* One axis of the frame's field grid: the bank's n angles deg (ascending), with their
 * mirror images (the negatives of those > 0, in front) when mirror; into im's block. */
static int grid_axis(const double *deg, int n, int mirror, double *grid, int *bank, int *sign)
{
    int m = 0, i;
    if (mirror)
        for (i = n - 1; i >= 0; i--)
            if (deg[i] > 0.0) {
                grid[m] = -deg[i];
                bank[m] = i;
                sign[m] = -1;
                m++;
            }
    for (i = 0; i < n; i++) {
        grid[m + i] = deg[i];
        bank[m + i] = i;
        sign[m + i] = 1;
    }
    return m + n;
}

/* The frame's field grid (image.h) from the bank's and desc.mirror. */
static lensrt_result make_grid(struct lensrt_image_s *im, const lensrt_bank_info *info)
{
    const int mx = (im->desc.mirror & LENSRT_IMAGE_MIRROR_X) != 0, my = (im->desc.mirror & LENSRT_IMAGE_MIRROR_Y) != 0;
    const size_t n = 2 * ((size_t)info->n_field_x + (size_t)info->n_field_y);
    unsigned char *block;
    if (im->desc.mirror & ~(LENSRT_IMAGE_MIRROR_X | LENSRT_IMAGE_MIRROR_Y))
        return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: mirror is %d; it must be 0 or "
                           "LENSRT_IMAGE_MIRROR_X (1) | LENSRT_IMAGE_MIRROR_Y (2)", (int)im->desc.mirror);
    if (mx && info->field_x_deg[0] < 0.0)
        return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: mirror asks for LENSRT_IMAGE_MIRROR_X "
                           "but the bank's field_x_deg starts at %g (< 0): a bank with both signs needs no mirror",
                           info->field_x_deg[0]);
    if (my && info->field_y_deg[0] < 0.0)
        return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: mirror asks for LENSRT_IMAGE_MIRROR_Y "
                           "but the bank's field_y_deg starts at %g (< 0): a bank with both signs needs no mirror",
                           info->field_y_deg[0]);
    block = lensrt_alloc(im->ctx, n * (sizeof(double) + 2 * sizeof(int)));
    if (!block) return lensrt_fail(im->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "lensrt_image_create: out of memory");
    im->grid_x_deg = (double *)block;
    im->grid_y_deg = im->grid_x_deg + 2 * (size_t)info->n_field_x;
    im->bank_x = (int *)(im->grid_y_deg + 2 * (size_t)info->n_field_y);
    im->bank_y = im->bank_x + 2 * (size_t)info->n_field_x;
    im->sign_x = im->bank_y + 2 * (size_t)info->n_field_y;
    im->sign_y = im->sign_x + 2 * (size_t)info->n_field_x;
    im->grid_nx = grid_axis(info->field_x_deg, info->n_field_x, mx, im->grid_x_deg, im->bank_x, im->sign_x);
    im->grid_ny = grid_axis(info->field_y_deg, info->n_field_y, my, im->grid_y_deg, im->bank_y, im->sign_y);
    return LENSRT_SUCCESS;
}

/* The bank: registration channel, the slice present, the frame's pinhole fields inside
 * the field grid, and the axis's power at each wavelength. */
static lensrt_result check_bank(struct lensrt_image_s *im, const lensrt_bank_info *info)
{
    const lensrt_image_desc *d = &im->desc;
    const char *reg = lensrt_bank_registration(d->bank);
    lensrt_bank_query q = LENSRT_BANK_QUERY_INIT;
    const size_t count = (size_t)info->width * (size_t)info->height;
    double half_x, half_y, fx[2], fy[2];
    float *psf;
    lensrt_result res = LENSRT_SUCCESS;
    int l;
    if (strcmp(reg, "channel") != 0)
        return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: the bank's registration is '%s'; "
                           "an image needs a bank of `registration channel` (each channel on its own chief point)",
                           reg);
    // The frame's corner (sub-)pixel centres through the pinhole, against the field grid
    half_x = 0.5 * ((double)d->width * im->oversample - 1.0) * info->pixel_x_mm;
    half_y = 0.5 * ((double)d->height * im->oversample - 1.0) * info->pixel_y_mm;
    fx[0] = pinhole_deg(d->center_x_mm - half_x, d->focal_x_mm);
    fx[1] = pinhole_deg(d->center_x_mm + half_x, d->focal_x_mm);
    fy[0] = pinhole_deg(d->center_y_mm - half_y, im->focal_y_mm);
    fy[1] = pinhole_deg(d->center_y_mm + half_y, im->focal_y_mm);
    if ((res = make_grid(im, info)) != LENSRT_SUCCESS) return res;
    if (fx[0] < im->grid_x_deg[0] || fx[1] > im->grid_x_deg[im->grid_nx - 1])
        return lensrt_fail(im->ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "lensrt_image_desc: the frame's field_x spans [%.9g, "
                           "%.9g] deg (corner pixel centres through the pinhole, focal_x_mm %g); the bank's field_x_deg "
                           "grid covers [%.9g, %.9g]%s", fx[0], fx[1], d->focal_x_mm, im->grid_x_deg[0],
                           im->grid_x_deg[im->grid_nx - 1],
                           d->mirror & LENSRT_IMAGE_MIRROR_X ? " with its mirror image" : "");
    if (fy[0] < im->grid_y_deg[0] || fy[1] > im->grid_y_deg[im->grid_ny - 1])
        return lensrt_fail(im->ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "lensrt_image_desc: the frame's field_y spans [%.9g, "
                           "%.9g] deg (corner pixel centres through the pinhole, focal_y_mm %g); the bank's field_y_deg "
                           "grid covers [%.9g, %.9g]%s", fy[0], fy[1], im->focal_y_mm, im->grid_y_deg[0],
                           im->grid_y_deg[im->grid_ny - 1],
                           d->mirror & LENSRT_IMAGE_MIRROR_Y ? " with its mirror image" : "");
    // The slice (the bank's message names the value and lists its own) and the axis's
    // power: the sum of the PSF's pixels at field (0, 0), each wavelength
    im->axis_power = lensrt_calloc(im->ctx, (size_t)im->n_wavelengths, sizeof(double));
    psf = lensrt_alloc(im->ctx, count * sizeof(float));
    if (!im->axis_power || !psf) {
        lensrt_free(im->ctx, psf);
        return lensrt_fail(im->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "lensrt_image_create: out of memory for the axis PSF");
    }
    q.f_number = d->f_number;
    q.focus_offset_mm = d->focus_offset_mm;
    q.distance_mm = d->distance_mm;
    for (l = 0; l < im->n_wavelengths && res == LENSRT_SUCCESS; l++) {
        size_t p;
        double sum = 0.0;
        q.wavelength_nm = im->wavelengths_nm[l];
        if ((res = lensrt_bank_psf(d->bank, &q, psf, count, NULL)) != LENSRT_SUCCESS) break;
        for (p = 0; p < count; p++) sum += (double)psf[p];
        im->axis_power[l] = sum;
    }
    lensrt_free(im->ctx, psf);
    if (res != LENSRT_SUCCESS) return res;
    // Every channel's spectrum must carry power on the axis (its kernels are divided by it)
    for (l = 0; l < d->n_channels; l++) {
        double norm = 0.0;
        int k;
        for (k = 0; k < im->n_wavelengths; k++)
            norm += im->channel_weights[(size_t)l * (size_t)im->n_wavelengths + (size_t)k] * im->axis_power[k];
        if (!(norm > 0.0))
            return lensrt_fail(im->ctx, LENSRT_ERROR_OUT_OF_DOMAIN, "lensrt_image_desc: channel %d's spectrum has power "
                               "%g in the bank's axis PSF (field 0, 0); it must be > 0", l, norm);
    }
    return LENSRT_SUCCESS;
}

/* The direct layer's object on the finer grid (image.h): a copy of this one with the
 * sizes times oversample and the axis power per fine pixel; this one's axis power
 * becomes per frame pixel (over oversample^2), which the flares use. */
static lensrt_result create_fine(struct lensrt_image_s *im)
{
    const int s = im->oversample, nl = im->n_wavelengths;
    struct lensrt_image_s *f = lensrt_alloc(im->ctx, sizeof *f);
    int l;
    if (!f) return lensrt_fail(im->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "lensrt_image_create: out of memory");
    *f = *im;
    f->desc.width = im->desc.width * s;
    f->desc.height = im->desc.height * s;
    f->plane = (size_t)f->desc.width * (size_t)f->desc.height;
    f->oversample = 1;
    f->pitch_x_mm = im->pitch_x_mm / s;
    f->pitch_y_mm = im->pitch_y_mm / s;
    f->layers = NULL;
    f->direct = NULL;
    f->flare = NULL;
    f->fine = NULL;
    f->axis_power = lensrt_alloc(im->ctx, (size_t)nl * sizeof(double));
    im->fine = f;
    if (!f->axis_power) return lensrt_fail(im->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "lensrt_image_create: out of memory");
    for (l = 0; l < nl; l++) {
        f->axis_power[l] = im->axis_power[l];
        im->axis_power[l] /= (double)s * (double)s;
    }
    im->fine_input = lensrt_alloc(im->ctx, (size_t)im->desc.n_channels * f->plane * sizeof(float));
    im->fine_direct = lensrt_alloc(im->ctx, (size_t)im->desc.n_channels * f->plane * sizeof(float));
    if (!im->fine_input || !im->fine_direct)
        return lensrt_fail(im->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "lensrt_image_create: out of memory for the %d x %d "
                           "grid of oversample %d", (int)f->desc.width, (int)f->desc.height, s);
    return image_direct_create(f);
}

/* The direct layer on the finer grid: each pixel's value on its oversample^2 sub-pixels
 * (the same value: the light per area is the pixel's), put through, then each pixel the
 * mean of its sub-pixels (the sensor's box filter over the pixel). */
static lensrt_result run_fine(struct lensrt_image_s *im, const float *input)
{
    struct lensrt_image_s *f = im->fine;
    const int s = im->oversample, w = im->desc.width, h = im->desc.height, fw = f->desc.width;
    const size_t nc = (size_t)im->desc.n_channels;
    size_t c;
    int i, j, a, b;
    lensrt_result res;
    for (c = 0; c < nc; c++)
        for (j = 0; j < h; j++)
            for (i = 0; i < w; i++) {
                const float v = input[c * im->plane + (size_t)j * (size_t)w + (size_t)i];
                for (b = 0; b < s; b++) {
                    float *row = im->fine_input + c * f->plane + (size_t)(j * s + b) * (size_t)fw + (size_t)i * s;
                    for (a = 0; a < s; a++) row[a] = v;
                }
            }
    memset(&f->stats, 0, sizeof f->stats);
    memset(im->fine_direct, 0, nc * f->plane * sizeof(float)); // the direct run adds into it
    if ((res = image_direct_run(f, im->fine_input, im->fine_direct)) != LENSRT_SUCCESS) {
        // its message is in the shared context already
        return res;
    }
    for (c = 0; c < nc; c++)
        for (j = 0; j < h; j++)
            for (i = 0; i < w; i++) {
                double sum = 0.0;
                for (b = 0; b < s; b++) {
                    const float *row = im->fine_direct + c * f->plane + (size_t)(j * s + b) * (size_t)fw + (size_t)i * s;
                    for (a = 0; a < s; a++) sum += (double)row[a];
                }
                im->layers[c * im->plane + (size_t)j * (size_t)w + (size_t)i] = (float)(sum / ((double)s * s));
            }
    im->stats.seconds_warp = f->stats.seconds_warp;
    im->stats.seconds_kernels = f->stats.seconds_kernels;
    im->stats.seconds_convolve = f->stats.seconds_convolve;
    im->stats.n_nodes = f->stats.n_nodes;
    im->stats.fft_width = f->stats.fft_width;
    im->stats.fft_height = f->stats.fft_height;
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_image_create(lensrt_context ctx, const lensrt_image_desc *desc, lensrt_image *out)
{
    struct lensrt_image_s *im;
    lensrt_bank_info info = LENSRT_BANK_INFO_INIT;
    lensrt_image_desc d;
    lensrt_result res;
    if (!ctx || !desc || !out) {
        if (ctx) lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_create: desc or out is NULL");
        return LENSRT_ERROR_INVALID_ARGUMENT;
    }
    *out = NULL;
    // The caller's struct as this library's, then its numbers
    if ((res = lensrt_struct_in(ctx, "lensrt_image_desc", desc, &d, sizeof d)) != LENSRT_SUCCESS) return res;
    if (!d.bank) return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_desc: bank is NULL");
    if ((res = check_numbers(ctx, &d)) != LENSRT_SUCCESS) return res;
    if ((res = check_flares(ctx, &d)) != LENSRT_SUCCESS) return res;
    if ((res = lensrt_bank_get_info(d.bank, &info)) != LENSRT_SUCCESS) return res;
    im = lensrt_calloc(ctx, 1, sizeof *im);
    if (!im) return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "lensrt_image_create: out of memory");
    im->ctx = ctx;
    im->desc = d;
    im->desc.ghosts = NULL;
    im->desc.channel_weights = NULL;
    im->n_wavelengths = info.n_wavelengths;
    im->wavelengths_nm = info.wavelengths_nm;
    im->focal_y_mm = d.focal_y_mm > 0.0 ? d.focal_y_mm : d.focal_x_mm;
    im->oversample = d.oversample > 0 ? d.oversample : 1;
    im->pitch_x_mm = info.pixel_x_mm * im->oversample;
    im->pitch_y_mm = info.pixel_y_mm * im->oversample;
    im->plane = (size_t)d.width * (size_t)d.height;
    im->n_layers = 2 + d.n_ghosts;
    im->stats.struct_size = sizeof im->stats;
    im->stats.worst_flare_error = -1.0;
    // The copies: weights, the ghost array (the lenses stay the caller's)
    if ((res = copy_weights(im, d.channel_weights)) != LENSRT_SUCCESS) goto failed;
    if (d.n_ghosts > 0) {
        im->ghosts = lensrt_alloc(ctx, (size_t)d.n_ghosts * sizeof *im->ghosts);
        if (!im->ghosts) {
            res = lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "lensrt_image_create: out of memory for the ghosts");
            goto failed;
        }
        memcpy(im->ghosts, d.ghosts, (size_t)d.n_ghosts * sizeof *im->ghosts);
        im->desc.ghosts = im->ghosts;
    }
    // The bank: registration, the frame inside its field grid, the slice and the axis's power
    if ((res = check_bank(im, &info)) != LENSRT_SUCCESS) goto failed;
    // The layers (zero until a run) and the sources
    im->layers = lensrt_calloc(ctx, (size_t)im->n_layers * (size_t)d.n_channels * im->plane, sizeof(float));
    im->sources = lensrt_calloc(ctx, (size_t)im->desc.max_sources, sizeof *im->sources);
    if (!im->layers || !im->sources) {
        res = lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "lensrt_image_create: out of memory for %d layers of %d x %d "
                          "x %d floats", im->n_layers, (int)d.n_channels, (int)d.width, (int)d.height);
        goto failed;
    }
    // The parts: the direct layer here, or on its finer grid
    if (im->oversample > 1) {
        if ((res = create_fine(im)) != LENSRT_SUCCESS) goto failed;
    } else if ((res = image_direct_create(im)) != LENSRT_SUCCESS) {
        goto failed;
    }
    if ((res = image_flare_create(im)) != LENSRT_SUCCESS) goto failed;
    *out = im;
    return LENSRT_SUCCESS;
failed:
    lensrt_image_destroy(im);
    return res;
}

void lensrt_image_destroy(lensrt_image im)
{
    lensrt_context ctx;
    if (!im) return;
    ctx = im->ctx;
    image_flare_destroy(im);
    if (im->fine) {
        image_direct_destroy(im->fine);
        lensrt_free(ctx, im->fine->axis_power);
        lensrt_free(ctx, im->fine);
    } else {
        image_direct_destroy(im);
    }
    lensrt_free(ctx, im->fine_input);
    lensrt_free(ctx, im->fine_direct);
    lensrt_free(ctx, im->channel_weights);
    lensrt_free(ctx, im->ghosts);
    lensrt_free(ctx, im->axis_power);
    lensrt_free(ctx, im->grid_x_deg); /* the grid's block */
    lensrt_free(ctx, im->layers);
    lensrt_free(ctx, im->sources);
    lensrt_free(ctx, im);
}

lensrt_result lensrt_image_run(lensrt_image im, const float *input, size_t count)
{
    const size_t nc = im ? (size_t)im->desc.n_channels : 0, plane = im ? im->plane : 0;
    float *flare;
    size_t p, c;
    int g;
    lensrt_result res;
    if (!im) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (!input) return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_run: input is NULL");
    if (count != nc * plane)
        return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_run: count must be %zu (%zu channels x "
                           "%d x %d pixels), got %zu", nc * plane, nc, (int)im->desc.width, (int)im->desc.height,
                           count);
    // Every value finite and >= 0 (light)
    for (c = 0; c < nc; c++)
        for (p = 0; p < plane; p++) {
            const float v = input[c * plane + p];
            if (!(isfinite(v) && v >= 0.0f))
                return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_run: input channel %zu pixel "
                                   "(%zu, %zu) is %g; values are finite and >= 0", c,
                                   p % (size_t)im->desc.width, p / (size_t)im->desc.width, (double)v);
        }
    // Zero the layers and the stats of the last run; then the direct layer, the ghosts
    memset(im->layers, 0, (size_t)im->n_layers * nc * plane * sizeof(float));
    im->has_run = 0;
    memset(&im->stats, 0, sizeof im->stats);
    im->stats.struct_size = sizeof im->stats;
    im->stats.worst_flare_error = -1.0;
    if (im->fine) {
        if ((res = run_fine(im, input)) != LENSRT_SUCCESS) return res;
    } else if ((res = image_direct_run(im, input, im->layers)) != LENSRT_SUCCESS) {
        return res;
    }
    image_direct_clamp(im->layers, nc * plane);
    if ((res = image_flare_run(im, input, im->layers + 2 * nc * plane)) != LENSRT_SUCCESS) return res;
    // LENSRT_IMAGE_FLARE: the ghost layers' sum, in ghost order
    flare = im->layers + nc * plane;
    for (g = 0; g < im->desc.n_ghosts; g++) {
        const float *ghost = im->layers + (size_t)(2 + g) * nc * plane;
        for (p = 0; p < nc * plane; p++) flare[p] += ghost[p];
    }
    im->has_run = 1;
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_image_get_layer(lensrt_image im, int32_t layer, float *out, size_t count)
{
    const size_t n = im ? (size_t)im->desc.n_channels * im->plane : 0;
    if (!im) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (!out) return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_get_layer: out is NULL");
    if (layer < 0 || layer >= im->n_layers)
        return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_get_layer: layer %d; the image has 0 .. "
                           "%d (direct, flare, then %d ghosts)", (int)layer, im->n_layers - 1, (int)im->desc.n_ghosts);
    if (count != n)
        return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_get_layer: count must be %zu (%d "
                           "channels x %d x %d pixels), got %zu", n, (int)im->desc.n_channels, (int)im->desc.width,
                           (int)im->desc.height, count);
    // Zero before the first run (the layers are zeroed at creation)
    memcpy(out, im->layers + (size_t)layer * n, n * sizeof(float));
    return LENSRT_SUCCESS;
}

lensrt_result lensrt_image_get_stats(lensrt_image im, lensrt_image_stats *out)
{
    if (!im) return LENSRT_ERROR_INVALID_ARGUMENT;
    return lensrt_struct_out(im->ctx, "lensrt_image_stats", out, &im->stats, sizeof im->stats);
}

lensrt_result lensrt_image_get_source(lensrt_image im, int32_t i, lensrt_image_source *out)
{
    lensrt_image_source s;
    if (!im) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (i < 0 || i >= im->stats.n_sources)
        return lensrt_fail(im->ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_image_get_source: source %d; the last run "
                           "found %d", (int)i, (int)im->stats.n_sources);
    s = im->sources[i];
    s.struct_size = sizeof s;
    return lensrt_struct_out(im->ctx, "lensrt_image_source", out, &s, sizeof s);
}
