/* An image through the lens (lensrt_image_*, issue 38): the object shared by its parts.
 *
 *   image.c   the public calls: checks, layers, stats, sources
 *   direct.c  the direct layer: light moved to its chief points, split over the bank's
 *             nodes, each node's PSF applied by FFT convolution
 *   flare.c   the flare layers: sources found, their ghosts rendered and resampled
 *   fft.c     the complex FFT the convolutions use */
#ifndef LENSRT_IMAGE_IMAGE_H
#define LENSRT_IMAGE_IMAGE_H

#include "lensrt.h"

struct image_direct; /* direct.c's state */
struct image_flare;  /* flare.c's state */

struct lensrt_image_s {
    lensrt_context ctx;
    lensrt_image_desc desc;      /* a full copy; its pointers point at the copies below */
    double *channel_weights;     /* n_channels x n_wavelengths (owned) */
    lensrt_lens *ghosts;         /* n_ghosts (owned array, borrowed lenses) */
    int n_wavelengths;           /* the bank's */
    const double *wavelengths_nm; /* the bank's (valid while it lives) */
    double focal_y_mm;           /* desc.focal_y_mm, or focal_x_mm when 0 */
    int oversample;              /* desc.oversample, or 1 when 0 */
    double pitch_x_mm, pitch_y_mm; /* the frame's pixels: the bank's times oversample */
    double *axis_power;          /* n_wavelengths: the sum of the bank's PSF pixels at field
                                    (0, 0) over oversample^2 (owned; image.c), the power of
                                    the axis PSF in frame pixels: both layers are divided by
                                    it, so a lossless axis keeps a pixel's value */
    /* The frame's field grid (image.c, check_bank): the bank's field_x_deg (field_y_deg)
     * with its mirror image where desc.mirror asks; grid node i takes the bank's node
     * bank_x[i], mirrored in x when sign_x[i] < 0 (one owned block; the fine object
     * shares it) */
    int grid_nx, grid_ny;
    double *grid_x_deg, *grid_y_deg;
    int *bank_x, *bank_y, *sign_x, *sign_y;
    size_t plane;                /* width x height */
    int n_layers;                /* 2 + n_ghosts */
    float *layers;               /* n_layers x n_channels x plane, zero before a run */
    int has_run;
    lensrt_image_stats stats;
    lensrt_image_source *sources; /* max_sources */
    struct image_direct *direct;
    struct image_flare *flare;
    /* With oversample > 1, the direct layer's own object: this one on the finer grid
     * (width, height and plane times oversample, the bank's pitch, axis power per fine
     * pixel), and its input and output there */
    struct lensrt_image_s *fine;
    float *fine_input, *fine_direct;
};

/* direct.c: set up after the description is checked (bank slice, field grid covering
 * the frame); run writes the direct layer (n_channels planes) and its stats fields. */
lensrt_result image_direct_create(struct lensrt_image_s *im);
void image_direct_destroy(struct lensrt_image_s *im);
lensrt_result image_direct_run(struct lensrt_image_s *im, const float *input, float *direct);
/* Irradiance is >= 0. The sharpened kernels (direct.c, sharpen) dip below 0 beside a PSF
 * narrower than about a pixel of the bank's pitch, so the finer grid of an oversampled
 * run holds small negative values between its sub-pixels that its pixel means (the
 * sensor's box) average out, and a lone point of light with such a PSF can leave a faint
 * negative ring where nothing else lands: the direct layer is clamped to 0 once, on the
 * frame's own pixels (clamping the finer grid added 0.3% to lens 0001's 450 nm power at
 * f/8 and oversample 3; on the frame's pixels the clamp changes it by 0.01%:
 * docs/image.md). */
void image_direct_clamp(float *layer, size_t n);

/* flare.c: run finds the sources (im->sources, stats.n_sources) and writes one layer per
 * ghost (n_ghosts x n_channels planes, zeroed first) and its stats fields; nothing
 * when n_ghosts is 0. */
lensrt_result image_flare_create(struct lensrt_image_s *im);
void image_flare_destroy(struct lensrt_image_s *im);
lensrt_result image_flare_run(struct lensrt_image_s *im, const float *input, float *ghosts);

#endif
