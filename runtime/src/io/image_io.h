/*
 * Image output for lensrt (internal): CIE 1931 colour, EXR (OpenEXRCore) and PNG.
 *
 * Every writer is atomic: it writes `<path>.tmp-<random>` next to the target and
 * renames it over `path` only when everything succeeded; on failure no file is left.
 * Errors are written to `err` (at most `err_size` bytes, NUL-terminated) naming the
 * path and what failed.
 */
#ifndef LENSRT_IMAGE_IO_H
#define LENSRT_IMAGE_IO_H

#include "lensrt.h"

#include <stddef.h>
#include <stdio.h>
#include <stdint.h>

/* The context's allocator (never NULL members once set up by core/context.c). */
typedef struct lensrt_allocator {
    void *(*alloc_fn)(size_t size, void *user_data);
    void (*free_fn)(void *ptr, void *user_data);
    void *user_data;
} lensrt_allocator;

/* NULL when `path` may be replaced (absent or a regular file); otherwise what it is, a
 * phrase for a message ("is a symbolic link; ...", "is a directory, not a file", ...).
 * Every writer asks before it creates its temporary file. */
const char *lensrt_target_refusal(const char *path);

/* Create `<path>.tmp-<pid>-<clock>-<attempt>` exclusively, with the permission bits of
 * an existing `path` (after removing such files of processes no longer running), and
 * return its descriptor, its name in *out_name (free with the allocator) and 0 in
 * *out_errno; -1 and the errno on failure (ENOMEM when the name cannot be allocated). */
int lensrt_open_temporary(const lensrt_allocator *allocator, const char *path, char **out_name,
                          int *out_errno);
/* The same as a stdio stream opened "wb" (NULL, no file left and *out_name NULL on failure). */
FILE *lensrt_fopen_temporary(const lensrt_allocator *allocator, const char *path, char **out_name, int *out_errno);

/* What a pixel of lensrt's EXR is: "lensrt/units" (there is no "emissiveUnits": the
 * spectral layout's one value, radiance in W.m^-2.sr^-1, would be false). */
#define LENSRT_EXR_UNITS                                                                                  \
    "relative irradiance, dimensionless: each spectral channel S0.<lambda>nm is the irradiance on the "   \
    "sensor at that wavelength in units of the lights' irradiance on the plane of the lens's first "      \
    "vertex (a light's intensity, default 1; an analytic lens: its aperture plane), the lights added, "  \
    "so that the sum over pixels times the pixel area (mm^2) is the power the lens passes per unit "      \
    "irradiance (mm^2); a pixel is the mean over its area (lensrt/pixelFilter box) or the value at its "  \
    "centre (point). R, G, B: linear sRGB (D65) of X, Y, Z = the sum over the spectral channels of the "  \
    "value x the CIE 1931 2-degree colour matching function x the channel's span (nm)"

/* What a render records in its image files. Strings may be NULL (left out). */
typedef struct lensrt_image_meta {
    const char *lens_name;      /* e.g. "Angenieux double Gauss 100 mm f/1.1 (1953)" */
    const char *lens_file;      /* the table path, or NULL for an analytic lens */
    double focal_length_mm;
    double f_number;
    double stop_radius_mm;
    double focus_offset_mm;     /* z_S */
    double pixel_pitch_x_mm, pixel_pitch_y_mm;
    double center_x_mm, center_y_mm;
    /* The integrator is Monte Carlo unless cells_rings or fourier_nodes is set; the
     * Monte Carlo fields (samples_per_wavelength, splats_per_second, sampler, estimator,
     * seed, sample_runs, phase_tolerance_waves) are written only for Monte Carlo, the
     * cells and Fourier ones only for theirs. */
    uint64_t samples_per_wavelength;
    double seconds;
    double splats_per_second;
    const char *sampler;        /* "sobol", "random", "stratified" */
    const char *estimator;      /* "paper", "unbiased" */
    const char *sample_runs;    /* "<seed> <first> <end>; ..." when the sums hold more than
                                   one run (merged, resumed), or NULL */
    double phase_tolerance_waves; /* Monte Carlo's pruning tolerance (> 0: written) */
    const char *aperture;       /* e.g. "circle", "7 blades, curvature 0.3, rotation 10 deg" */
    const char *layers;         /* what each layer holds (EXR "lensrt/layers"), or NULL */
    const char *renders;        /* each render's integrator when the file adds several, or NULL */
    int cells_rings;            /* the cells integrator's mesh (0: Monte Carlo samples) */
    int fourier_nodes;          /* the Fourier integrator's rule (0: none) */
    double fourier_tolerance;   /* its interpolation and NUFFT tolerance (> 0: written) */
    double error_estimate;      /* its estimated relative L2 error (< 0: none) */
    const char *pixel_filter;   /* "box" or "point" (NULL: left out) */
    int pixel_samples_x, pixel_samples_y; /* the box filter's points per pixel and axis */
    uint64_t seed;
    int n_lights;
    const lensrt_light *lights;
    /* Non-zero: leave out what differs between two runs of the same render (seconds,
     * splats_per_second, lens_file), so that the same render gives the same bytes */
    int reproducible;
} lensrt_image_meta;

/* Linear sRGB (D65) of spectra sampled at `wavelengths_nm` (any order, any count >= 1):
 * XYZ = sum_w S_w * cmf(lambda_w) * dlambda_w with dlambda from the midpoints between
 * neighbouring wavelengths (25 nm each for 16 uniform ones over 380-780), then the
 * standard XYZ -> linear sRGB matrix. spectral[(w * n_pixels) + p], rgb[p * 3 + c]. */
void lensrt_spectrum_to_rgb(int n_wavelengths, const double *wavelengths_nm,
                            const float *spectral, size_t n_pixels, float *rgb);

/* CIE 1931 2-degree colour matching functions at one wavelength (nm). */
void lensrt_cie1931_xyz(double wavelength_nm, double xyz[3]);

/* EXR: scanline, ZIP compression, FLOAT channels: one per wavelength named
 * `S0.<lambda with comma decimal>nm` (spectral layout of Fichet et al. 2021, attribute
 * spectralLayoutVersion), plus R, G, B (linear sRGB preview), plus metadata attributes. */
lensrt_result lensrt_write_exr(const lensrt_allocator *allocator, const char *path,
                               int width, int height, int n_wavelengths,
                               const double *wavelengths_nm, const float *spectral,
                               const float *rgb, const lensrt_image_meta *meta,
                               char *err, size_t err_size);

/* The spectral layout's name of a wavelength's channel, "S0.<lambda>nm" with 6 decimals
 * and a comma ("S0.550,000000nm"), as lensrt_write_exr names them, into out (at least
 * LENSRT_EXR_SPECTRAL_NAME_SIZE bytes); wavelength_nm must be > 0 and below
 * LENSRT_EXR_MAX_WAVELENGTH_NM. */
#define LENSRT_EXR_SPECTRAL_NAME_SIZE 32
#define LENSRT_EXR_MAX_WAVELENGTH_NM 1.0e9
void lensrt_exr_spectral_name(double wavelength_nm, char *out);

/* One image of a layered EXR: a spectral image and its RGB preview, as for
 * lensrt_write_exr, and its layer's name (NULL: the unprefixed channels). */
typedef struct lensrt_exr_image {
    const char *name;
    const float *spectral;
    const float *rgb;
} lensrt_exr_image;

/* NULL when `name` may name an EXR layer: 1 to LENSRT_MAX_LAYER_NAME characters of
 * [A-Za-z0-9_-], not a channel group of the spectral layout (S0-S3, M00-M33, T);
 * otherwise why not, a phrase for a message ("is empty; ...", ...). */
const char *lensrt_exr_layer_name_refusal(const char *name);

/* The same EXR with several images: image i's channels are lensrt_write_exr's names
 * behind the prefix "<name>." (OpenEXR's layer convention), or unprefixed for the one
 * image whose name is NULL (at most one). Names must be valid and unique
 * (LENSRT_ERROR_INVALID_ARGUMENT naming the path and the name). lensrt_write_exr is this
 * with one unprefixed image. */
lensrt_result lensrt_write_exr_layers(const lensrt_allocator *allocator, const char *path,
                                      int width, int height, int n_wavelengths,
                                      const double *wavelengths_nm, int n_images,
                                      const lensrt_exr_image *images, const lensrt_image_meta *meta,
                                      char *err, size_t err_size);

/* PNG, 8-bit sRGB: luminance mapped by log10 over `decades` below the image's peak;
 * colours outside the sRGB gamut (or with a negative component) are desaturated towards
 * the grey of the same displayed luminance just enough to fit, never clamped per
 * channel, and chroma fades to grey in the dimmest part of the range (image_png.c says
 * exactly how); then the sRGB transfer curve. */
lensrt_result lensrt_write_png(const lensrt_allocator *allocator, const char *path,
                               int width, int height, const float *rgb, double decades,
                               char *err, size_t err_size);

#endif /* LENSRT_IMAGE_IO_H */
