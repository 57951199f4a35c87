/*
 * Spectral EXR writer for lensrt, through OpenEXRCore (the C API of OpenEXR 3).
 *
 * Layout: "An OpenEXR Layout for Spectral Images", A. Fichet, R. Pacanowski, A. Wilkie,
 * Journal of Computer Graphics Techniques (JCGT) 10(3), 2021,
 * http://jcgt.org/published/0010/03/01/. What we follow, as confirmed against the
 * authors' reference implementation (github.com/afichet/spectral-exr,
 * lib/EXRSpectralImage.cpp and lib/EXRBiSpectralImage.cpp, read in 2024):
 *
 *   - an emissive (unpolarised) spectral channel is named "S0." + the wavelength with a
 *     comma as decimal separator + the unit, "nm" here. The reader accepts
 *     ^S[0-3]\.(\d*,?\d*([Ee][+-]?\d+)?)(SI prefix)?(m|Hz)$ ; the reference writer prints
 *     the wavelength with std::to_string (6 decimals), e.g. "S0.550,000000nm". We
 *     write exactly that: 6 decimals, comma separator, "nm".
 *   - header attribute "spectralLayoutVersion", type string, value "1.0";
 *   - header attribute "emissiveUnits": left out. The layout wants it for emissive
 *     images and its reference reader knows one value, "W.m^-2.sr^-1" (radiance); it
 *     reads a file without it all the same, with a warning that it assumes that unit.
 *     lensrt's values are not radiance and not absolute: each is a sensor irradiance
 *     relative to the light's irradiance on the lens's first vertex plane (dimensionless;
 *     LENSRT_EXR_UNITS below), which "lensrt/units" says in words. Writing the radiance
 *     unit would be false (lensrt before 0.11 did).
 *   - an RGB preview in channels R, G, B next to the spectral channels (the reference
 *     writer does the same).
 *
 * Layers (lensrt_write_exr_layers): OpenEXR groups channels by name, "channel C in layer L
 * is called L.C" (OpenEXR's Technical Introduction, "Layers"; the split is at the last
 * period, so layers nest). The spectral layout defines unprefixed names only, and the
 * reference reader's pattern is anchored at the start (^S[0-3]\. ...): it reads the
 * unprefixed channels and ignores every prefixed one. So the unprefixed channels hold
 * the image every spectral reader and viewer should see (lensrt writes the sum of the
 * layers there), and each named layer repeats the same channel set behind its prefix:
 * "direct.S0.550,000000nm", "direct.R", ... A layer name is 1 to LENSRT_MAX_LAYER_NAME
 * characters of [A-Za-z0-9_-] (no period: a period would nest it in another layer),
 * not a name of the spectral layout's own (S0-S3, M00-M33, T), unique in the file.
 * Channel names longer than 31 bytes need OpenEXR's long-name flag (OpenEXR 1.7 and
 * later read it), which we set only then (exr_set_longname_support).
 *
 * Standard OpenEXR attributes (OpenEXR "Standard Optional Attributes", and
 * ImfStandardAttributes.h of OpenEXR 3.1): "chromaticities" (sRGB primaries, D65 white:
 * the R, G, B channels are linear sRGB), "aperture" (float, the lens's f-number),
 * "comments" (string, a one-line summary). "focus" (focus distance in metres) is left
 * out: a render knows the sensor shift, not a focus distance.
 *
 * lensrt metadata, namespaced "lensrt/...": strings, doubles, v2d (x, y pairs) and ints;
 * 64-bit counts (samples per wavelength, seed) are decimal strings because EXR has no
 * 64-bit integer attribute. "lensrt/integrator" is "montecarlo", "cells" or "fourier"
 * and only that integrator's parameters follow (since 0.11; before, every file had the
 * Monte Carlo ones, a deterministic render's "1 sample" among them):
 *   montecarlo: "lensrt/samplesPerWavelength", "lensrt/sampler", "lensrt/estimator",
 *     "lensrt/seed", "lensrt/splatsPerSecond", "lensrt/phaseToleranceWaves" (fitted
 *     lenses) and "lensrt/sampleRuns" when the sums hold several runs (merged, resumed);
 *   cells: "lensrt/cellsRings", and "lensrt/errorEstimate" with
 *     "lensrt/errorEstimateMethod" when one was asked for;
 *   fourier: "lensrt/fourierNodes", "lensrt/fourierTolerance", and the estimate likewise.
 * "lensrt/pixelFilter" ("box": each pixel the mean intensity over its area, "point":
 * the intensity at its centre), "lensrt/pixelSamplesX" and "lensrt/pixelSamplesY" (ints:
 * the box filter's points per pixel and axis, 1 for point; since 0.8.0). A file that adds
 * several renders (layers, lensrt_renders_write_exr) has the first render's integrator
 * attributes and "lensrt/renders", each render's integrator in words. Every name is at
 * most 31 characters, so the file needs no long-name support. The whole list, with
 * types and units, is docs' EXR metadata table. A reproducible file (lensrt_image_meta.reproducible,
 * lensrt_render_write_exr_with) leaves out "lensrt/seconds", "lensrt/splatsPerSecond" and
 * "lensrt/lensFile": nothing else in the file depends on the run, so the same render
 * gives the same bytes.
 *
 * Memory: OpenEXRCore's allocator hooks (exr_context_initializer_t alloc_fn / free_fn)
 * take no user pointer in 3.1, so they cannot forward to a lensrt_allocator; OpenEXRCore
 * allocates its own context, attributes and compression buffers with malloc. Every
 * buffer of ours goes through the lensrt allocator.
 *
 * Atomic write: we create `<path>.tmp-<pid>-<clock>-<attempt>` (O_EXCL) next to the
 * target and hand OpenEXRCore a custom write function on that file descriptor, so
 * OpenEXRCore never opens a file itself; only when the header, every chunk and the
 * chunk offset table are written and flushed to disk is the temporary file renamed
 * over `path`. On any failure it is removed and `path` is left untouched.
 */
#ifndef _POSIX_C_SOURCE
#define _POSIX_C_SOURCE 200809L /* open, pwrite, fsync, getpid, clock_gettime */
#endif

#include "../c_numbers.h"
#include "image_io.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

static void exr_set_error(char *err, size_t err_size, const char *fmt, ...)
{
    va_list args;
    if (!err || err_size == 0)
        return;
    va_start(args, fmt);
    lensrt_vsnprintf_c(err, err_size, fmt, args); /* numbers with a point, any locale */
    va_end(args);
}

const char *lensrt_exr_layer_name_refusal(const char *name)
{
    size_t n, i;
    if (!name || !name[0])
        return "is empty; a layer needs a name";
    n = strlen(name);
    if (n > LENSRT_MAX_LAYER_NAME)
        return "is longer than LENSRT_MAX_LAYER_NAME (64) characters";
    for (i = 0; i < n; ++i) {
        char c = name[i];
        if (!((c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' ||
              c == '-'))
            return "has a character other than A-Z, a-z, 0-9, '_' and '-' (a '.' would nest it in "
                   "another layer)";
    }
    // The spectral layout's own channel groups: S0-S3 (Stokes), M00-M33 (Mueller), T
    if ((n == 2 && name[0] == 'S' && name[1] >= '0' && name[1] <= '3') ||
        (n == 3 && name[0] == 'M' && name[1] >= '0' && name[1] <= '3' && name[2] >= '0' && name[2] <= '3') ||
        (n == 1 && name[0] == 'T'))
        return "is a channel group of the spectral layout (S0-S3, M00-M33, T)";
    return NULL;
}

void lensrt_exr_spectral_name(double wavelength_nm, char *out)
{
    // From integers (units of 1e-6 nm), so that the locale's decimal point cannot leak in
    long long micro = (long long)floor(wavelength_nm * 1.0e6 + 0.5);
    snprintf(out, LENSRT_EXR_SPECTRAL_NAME_SIZE, "S0.%lld,%06lldnm", micro / 1000000, micro % 1000000);
}

#ifndef LENSRT_EXR

/* Built without OpenEXR (LENSRT_WITH_EXR=OFF): say so. */
lensrt_result lensrt_write_exr_layers(const lensrt_allocator *allocator, const char *path,
                                      int width, int height, int n_wavelengths,
                                      const double *wavelengths_nm, int n_images,
                                      const lensrt_exr_image *images, const lensrt_image_meta *meta,
                                      char *err, size_t err_size)
{
    (void)allocator;
    (void)width;
    (void)height;
    (void)n_wavelengths;
    (void)wavelengths_nm;
    (void)n_images;
    (void)images;
    (void)meta;
    exr_set_error(err, err_size,
                  "EXR '%s': this lensrt was built without OpenEXR (configure with "
                  "-DLENSRT_WITH_EXR=ON and libopenexr-dev installed); write a PNG instead",
                  path ? path : "(null)");
    return LENSRT_ERROR_UNSUPPORTED;
}

#else /* LENSRT_EXR */

#include <OpenEXR/openexr.h>

#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

/* Room for one spectral channel name "S0.<digits>,<6 digits>nm" (bytes, with the NUL). */
#define EXR_SPECTRAL_NAME_SIZE LENSRT_EXR_SPECTRAL_NAME_SIZE
/* Room for one channel name: "<layer>." and a spectral name (bytes, with the NUL). */
#define EXR_CHANNEL_NAME_SIZE (LENSRT_MAX_LAYER_NAME + 1 + EXR_SPECTRAL_NAME_SIZE)
/* Largest wavelength we format (nm): keeps the integer part of a name to 9 digits. */
#define EXR_MAX_WAVELENGTH_NM LENSRT_EXR_MAX_WAVELENGTH_NM
/* Room for one light in the "lensrt/lights" string (bytes). */
#define EXR_LIGHT_TEXT_SIZE 128
/* Room for the "comments" summary (bytes). */
#define EXR_COMMENT_SIZE 512

/* The state our write callback sees through the context's user data. */
typedef struct exr_sink {
    int fd;            /* the temporary file */
    int write_errno;   /* errno of a failed pwrite, 0 if none */
    char message[256]; /* what the failed write was ("" if none) */
} exr_sink;

/* OpenEXRCore reports errors through this callback; the default prints to stderr, which
 * a library must not do. It gets no user pointer, and exr_get_user_data() cannot be
 * called from here: it takes the context's lock, which OpenEXRCore already holds when
 * it reports an error from inside a call (that deadlocks, seen with 3.1.5 in
 * exr_write_header). So the message is dropped; ours names the failing step, the path,
 * OpenEXRCore's result code, and for write errors the byte range and errno, kept by
 * exr_write_to_fd below. */
static void exr_silent_error(exr_const_context_t ctxt, exr_result_t code, const char *msg)
{
    (void)ctxt;
    (void)code;
    (void)msg;
}

/* OpenEXRCore's ZIP step (3.1 to 3.4.7, Debian 12 ships 3.1.5) keeps a chunk whose zlib
 * stream is exactly as long as its packed pixels as the zlib stream, while readers take a
 * chunk of that size for the raw pixels: they decode the zlib bytes as floats (NaN and
 * -1e38 in a node of a bank whose render was finite: lens 0001, field (0, -3.25) deg,
 * 670 nm, 48 x 48 pixels; OpenEXR issue #2306). The format stores a chunk that does not
 * compress raw, so such a chunk is stored raw here: the library's compressor, then, when
 * its output is as long as the input and is not the input, the input. */
typedef struct zip_guard {
    exr_result_t (*compress)(exr_encode_pipeline_t *encode);
} zip_guard;

static exr_result_t compress_or_store(exr_encode_pipeline_t *encode)
{
    const zip_guard *guard = encode->encoding_user_data;
    exr_result_t rv = guard->compress(encode);
    if (rv == EXR_ERR_SUCCESS && encode->compressed_buffer && encode->packed_buffer &&
        encode->compressed_buffer != encode->packed_buffer && encode->compressed_bytes == encode->packed_bytes &&
        encode->compressed_alloc_size >= encode->packed_bytes &&
        memcmp(encode->compressed_buffer, encode->packed_buffer, (size_t)encode->packed_bytes) != 0)
        memcpy(encode->compressed_buffer, encode->packed_buffer, (size_t)encode->packed_bytes);
    return rv;
}

/* pwrite-like write callback: OpenEXRCore gives absolute offsets (it writes the chunk
 * offset table last, at its reserved place after the header). */
static int64_t exr_write_to_fd(exr_const_context_t ctxt, void *userdata, const void *buffer,
                               uint64_t sz, uint64_t offset, exr_stream_error_func_ptr_t error_cb)
{
    exr_sink *sink = (exr_sink *)userdata;
    const unsigned char *bytes = (const unsigned char *)buffer;
    uint64_t done = 0;
    while (done < sz) {
        ssize_t n = pwrite(sink->fd, bytes + done, (size_t)(sz - done), (off_t)(offset + done));
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0) {
            sink->write_errno = n < 0 ? errno : EIO;
            if (sink->message[0] == '\0')
                snprintf(sink->message, sizeof sink->message,
                         "writing %llu bytes at offset %llu failed: %s", (unsigned long long)sz,
                         (unsigned long long)offset, strerror(sink->write_errno));
            if (error_cb)
                error_cb(ctxt, EXR_ERR_WRITE_IO, "%s", sink->message);
            return -1;
        }
        done += (uint64_t)n;
    }
    return (int64_t)done;
}

/* "S0.<lambda>nm" with 6 decimals and a comma, formatted from integers so that the
 * locale's decimal point cannot leak in. */
static void exr_channel_name(double wavelength_nm, char *out)
{
    lensrt_exr_spectral_name(wavelength_nm, out);
}

/* A channel's name in a layer: "<layer>.<name>", or `name` itself for the unprefixed image. */
static void exr_layer_channel_name(const char *layer, const char *name, char *out)
{
    if (layer)
        snprintf(out, EXR_CHANNEL_NAME_SIZE, "%s.%s", layer, name);
    else
        snprintf(out, EXR_CHANNEL_NAME_SIZE, "%s", name);
}

static lensrt_result exr_map_result(exr_result_t rv)
{
    switch (rv) {
    case EXR_ERR_OUT_OF_MEMORY:
        return LENSRT_ERROR_OUT_OF_MEMORY;
    case EXR_ERR_INVALID_ARGUMENT:
    case EXR_ERR_ARGUMENT_OUT_OF_RANGE:
    case EXR_ERR_NAME_TOO_LONG:
    case EXR_ERR_INVALID_ATTR:
        return LENSRT_ERROR_INVALID_ARGUMENT;
    default:
        return LENSRT_ERROR_IO;
    }
}

/* The lights as readable text: "2 lights: (field 0, 0 deg, distance inf, intensity 1);
 * ...", numbers in the "C" locale whatever the host's (c_numbers.h). Returns NULL when
 * out of memory. */
static char *exr_lights_text(const lensrt_allocator *allocator, const lensrt_image_meta *meta)
{
    int n = meta->lights ? meta->n_lights : 0;
    size_t size = 128 + (size_t)(n > 0 ? n : 0) * EXR_LIGHT_TEXT_SIZE, used;
    char *text = (char *)allocator->alloc_fn(size, allocator->user_data);
    int i;
    if (!text)
        return NULL;
    // The field angles' sign convention travels with them (lensrt.h, lensrt_light)
    used = (size_t)snprintf(text, size, "%d light%s (field angles of the chief ray: +y is imaged at +y)",
                            meta->n_lights, meta->n_lights == 1 ? "" : "s");
    for (i = 0; i < n && used < size; ++i) {
        const lensrt_light *l = &meta->lights[i];
        char distance[48];
        if (l->distance_mm > 0.0)
            lensrt_snprintf_c(distance, sizeof distance, "%.17g mm", l->distance_mm);
        else
            snprintf(distance, sizeof distance, "infinity");
        used += (size_t)lensrt_snprintf_c(text + used, size - used,
                                          "%s (field %.9g, %.9g deg; distance %s; intensity %.9g)",
                                          i == 0 ? ":" : ";", l->field_x_deg, l->field_y_deg, distance,
                                          l->intensity > 0.0 ? l->intensity : 1.0);
    }
    return text;
}

lensrt_result lensrt_write_exr_layers(const lensrt_allocator *allocator, const char *path,
                                      int width, int height, int n_wavelengths,
                                      const double *wavelengths_nm, int n_images,
                                      const lensrt_exr_image *images, const lensrt_image_meta *meta,
                                      char *err, size_t err_size)
{
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    exr_context_t ctxt = NULL;
    exr_encode_pipeline_t encoder;
    zip_guard guard = {NULL};
    int encoder_live = 0;
    exr_sink sink;
    char (*names)[EXR_CHANNEL_NAME_SIZE] = NULL;
    char (*base)[EXR_SPECTRAL_NAME_SIZE] = NULL; /* the unprefixed names: n spectral, R G B */
    /* encoder channel -> our channel: image i's k-th at i * per_image + k (k < n spectral,
     * n..n+2 R G B) */
    int *channel_of = NULL;
    char *tmp_name = NULL, *lights = NULL;
    const char *step = "", *refusal;
    exr_result_t rv = EXR_ERR_SUCCESS;
    lensrt_result result = LENSRT_SUCCESS;
    size_t n_pixels;
    int part = 0, n_channels, per_image, lines_per_chunk = 0, i, j, y, open_errno = 0;

    memset(&sink, 0, sizeof sink);
    sink.fd = -1;
    if (err && err_size > 0)
        err[0] = '\0';

    /* Step 1: check the arguments before touching the file system. `meta` may be NULL
     * (no lensrt metadata); everything else is required. */
    if (!path) {
        exr_set_error(err, err_size, "EXR: the path is NULL");
        return LENSRT_ERROR_INVALID_ARGUMENT;
    }
    if (!allocator || !allocator->alloc_fn || !allocator->free_fn) {
        exr_set_error(err, err_size, "EXR '%s': no allocator", path);
        return LENSRT_ERROR_INVALID_ARGUMENT;
    }
    if (!wavelengths_nm || !images || n_images < 1) {
        exr_set_error(err, err_size, "EXR '%s': %s", path,
                      !wavelengths_nm ? "the wavelength list is NULL" : "no image to write");
        return LENSRT_ERROR_INVALID_ARGUMENT;
    }
    /* Each image: its arrays, and a layer name that is valid and unique (at most one
     * unprefixed image). */
    for (i = 0; i < n_images; ++i) {
        const char *name = images[i].name;
        if (!images[i].spectral || !images[i].rgb) {
            exr_set_error(err, err_size, "EXR '%s': %s%s%sthe %s is NULL", path, name ? "layer '" : "",
                          name ? name : "", name ? "': " : "", !images[i].spectral ? "spectral image" : "RGB image");
            return LENSRT_ERROR_INVALID_ARGUMENT;
        }
        if (name && (refusal = lensrt_exr_layer_name_refusal(name)) != NULL) {
            exr_set_error(err, err_size, "EXR '%s': layer name '%.80s' %s", path, name, refusal);
            return LENSRT_ERROR_INVALID_ARGUMENT;
        }
        for (j = 0; j < i; ++j)
            if ((!name && !images[j].name) || (name && images[j].name && strcmp(name, images[j].name) == 0)) {
                exr_set_error(err, err_size, "EXR '%s': images %d and %d are both %s%s%s", path, j, i,
                              name ? "layer '" : "unprefixed", name ? name : "", name ? "'" : "");
                return LENSRT_ERROR_INVALID_ARGUMENT;
            }
    }
    if (width <= 0 || height <= 0 || n_wavelengths <= 0) {
        exr_set_error(err, err_size,
                      "EXR '%s': size %d x %d with %d wavelengths, expected all > 0", path, width,
                      height, n_wavelengths);
        return LENSRT_ERROR_INVALID_ARGUMENT;
    }
    /* OpenEXRCore indexes channels with int16 and lines with int32; 4-byte pixels. */
    if (n_wavelengths > 32000 / n_images - 3 || (size_t)width > ((size_t)-1) / 12 / (size_t)height ||
        width > INT32_MAX / 12) {
        exr_set_error(err, err_size, "EXR '%s': size %d x %d with %d wavelengths is too large", path,
                      width, height, n_wavelengths);
        return LENSRT_ERROR_INVALID_ARGUMENT;
    }
    n_pixels = (size_t)width * (size_t)height;
    per_image = n_wavelengths + 3;
    n_channels = n_images * per_image;

    /* Step 2: channel names, each wavelength positive, finite and distinct at 6 decimals;
     * then each image's, behind its layer's prefix. */
    names = (char (*)[EXR_CHANNEL_NAME_SIZE])allocator->alloc_fn(
        (size_t)n_channels * EXR_CHANNEL_NAME_SIZE, allocator->user_data);
    base = (char (*)[EXR_SPECTRAL_NAME_SIZE])allocator->alloc_fn(
        (size_t)per_image * EXR_SPECTRAL_NAME_SIZE, allocator->user_data);
    channel_of = (int *)allocator->alloc_fn((size_t)n_channels * sizeof(int), allocator->user_data);
    if (!names || !base || !channel_of) {
        exr_set_error(err, err_size, "EXR '%s': out of memory", path);
        result = LENSRT_ERROR_OUT_OF_MEMORY;
        goto cleanup;
    }
    for (i = 0; i < n_wavelengths; ++i) {
        double l = wavelengths_nm[i];
        if (!(l > 0.0) || !(l < EXR_MAX_WAVELENGTH_NM)) {
            exr_set_error(err, err_size, "EXR '%s': wavelength %d is %g nm, expected > 0 and < %g",
                          path, i, l, EXR_MAX_WAVELENGTH_NM);
            result = LENSRT_ERROR_INVALID_ARGUMENT;
            goto cleanup;
        }
        exr_channel_name(l, base[i]);
        for (j = 0; j < i; ++j)
            if (strcmp(base[i], base[j]) == 0) {
                exr_set_error(err, err_size,
                              "EXR '%s': wavelengths %d and %d (%.9g and %.9g nm) give the same "
                              "channel name '%s'",
                              path, j, i, wavelengths_nm[j], l, base[i]);
                result = LENSRT_ERROR_INVALID_ARGUMENT;
                goto cleanup;
            }
    }
    strcpy(base[n_wavelengths + 0], "R");
    strcpy(base[n_wavelengths + 1], "G");
    strcpy(base[n_wavelengths + 2], "B");
    for (i = 0; i < n_images; ++i)
        for (j = 0; j < per_image; ++j)
            exr_layer_channel_name(images[i].name, base[j], names[i * per_image + j]);

    /* Step 3: the temporary file (a regular target or none), and an OpenEXRCore write
     * context on it. */
    if ((refusal = lensrt_target_refusal(path)) != NULL) {
        exr_set_error(err, err_size, "EXR '%s' %s", path, refusal);
        result = LENSRT_ERROR_IO;
        goto cleanup;
    }
    sink.fd = lensrt_open_temporary(allocator, path, &tmp_name, &open_errno);
    if (sink.fd < 0) {
        exr_set_error(err, err_size, "EXR '%s': cannot create a temporary file next to it: %s", path,
                      strerror(open_errno));
        result = open_errno == ENOMEM ? LENSRT_ERROR_OUT_OF_MEMORY : LENSRT_ERROR_IO;
        goto cleanup;
    }
    init.error_handler_fn = &exr_silent_error;
    init.user_data = &sink;
    init.write_fn = &exr_write_to_fd;
    init.max_image_width = width;
    init.max_image_height = height;
    /* With a custom write function the file name is informational (used in messages). */
    step = "starting the write context";
    rv = exr_start_write(&ctxt, path, EXR_WRITE_FILE_DIRECTLY, &init);
    if (rv != EXR_ERR_SUCCESS)
        goto exr_failed;
    /* Channel names past 31 bytes (long layer names) need the long-name flag; files
     * without them keep the flag off, as every file before layers had it. */
    for (i = 0; i < n_channels; ++i)
        if (strlen(names[i]) > 31) {
            step = "enabling long names";
            rv = exr_set_longname_support(ctxt, 1);
            if (rv != EXR_ERR_SUCCESS)
                goto exr_failed;
            break;
        }

    /* Step 4: one scanline part: data and display window 0..width-1 x 0..height-1 (row 0
     * at the top), ZIP compression (16 scanlines per chunk), increasing y. */
    step = "adding the image part";
    rv = exr_add_part(ctxt, "", EXR_STORAGE_SCANLINE, &part);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_initialize_required_attr_simple(ctxt, part, width, height, EXR_COMPRESSION_ZIP);
    if (rv != EXR_ERR_SUCCESS)
        goto exr_failed;
    /* FLOAT channels; the spectral and RGB values are linear (not perceptual). The
     * channel list is kept sorted by name (bytes), so R, G, B come before the S0.
     * channels, and the unprefixed ones before the layers (capitals sort first). */
    step = "adding the channels";
    for (i = 0; i < n_channels; ++i) {
        rv = (exr_result_t)exr_add_channel(ctxt, part, names[i], EXR_PIXEL_FLOAT,
                                           EXR_PERCEPTUALLY_LINEAR, 1, 1);
        if (rv != EXR_ERR_SUCCESS)
            goto exr_failed;
    }

    /* Step 5: attributes: the spectral layout, standard ones, then lensrt metadata. */
    step = "setting the attributes";
    rv = exr_attr_set_string(ctxt, part, "spectralLayoutVersion", "1.0");
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_attr_set_string(ctxt, part, "lensrt/units", LENSRT_EXR_UNITS);
    if (rv == EXR_ERR_SUCCESS) {
        /* sRGB / Rec. 709 primaries and the D65 white point, CIE xy. */
        exr_attr_chromaticities_t srgb;
        srgb.red_x = 0.64f;
        srgb.red_y = 0.33f;
        srgb.green_x = 0.30f;
        srgb.green_y = 0.60f;
        srgb.blue_x = 0.15f;
        srgb.blue_y = 0.06f;
        srgb.white_x = 0.3127f;
        srgb.white_y = 0.3290f;
        rv = exr_attr_set_chromaticities(ctxt, part, "chromaticities", &srgb);
    }
    if (rv == EXR_ERR_SUCCESS) {
        char version[32];
        snprintf(version, sizeof version, "%d.%d.%d", LENSRT_VERSION_MAJOR, LENSRT_VERSION_MINOR,
                 LENSRT_VERSION_PATCH);
        rv = exr_attr_set_string(ctxt, part, "lensrt/version", version);
    }
    if (rv == EXR_ERR_SUCCESS && meta) {
        char text[EXR_COMMENT_SIZE];
        exr_attr_v2d_t v2;
        /* Standard: the lens aperture in f-stops. */
        if (meta->f_number > 0.0)
            rv = exr_attr_set_float(ctxt, part, "aperture", (float)meta->f_number);
        /* Standard: a one-line summary for people. */
        if (rv == EXR_ERR_SUCCESS) {
            double lo = wavelengths_nm[0], hi = wavelengths_nm[0];
            char how[96];
            for (i = 1; i < n_wavelengths; ++i) {
                lo = wavelengths_nm[i] < lo ? wavelengths_nm[i] : lo;
                hi = wavelengths_nm[i] > hi ? wavelengths_nm[i] : hi;
            }
            if (meta->cells_rings)
                snprintf(how, sizeof how, "cells integrator, %d rings", meta->cells_rings);
            else if (meta->fourier_nodes)
                snprintf(how, sizeof how, "Fourier integrator, %d nodes per side", meta->fourier_nodes);
            else
                snprintf(how, sizeof how, "Monte Carlo, %llu samples per wavelength",
                         (unsigned long long)meta->samples_per_wavelength);
            lensrt_snprintf_c(text, sizeof text, "lensrt spectral PSF: %s, f/%.3g, %d wavelengths %.6g-%.6g nm, %s",
                              meta->lens_name ? meta->lens_name : "unnamed lens", meta->f_number, n_wavelengths, lo,
                              hi, how);
            rv = exr_attr_set_string(ctxt, part, "comments", text);
        }
        if (rv == EXR_ERR_SUCCESS && meta->lens_name)
            rv = exr_attr_set_string(ctxt, part, "lensrt/lens", meta->lens_name);
        // A reproducible file leaves out the table's path (the same table may lie elsewhere)
        if (rv == EXR_ERR_SUCCESS && meta->lens_file && !meta->reproducible)
            rv = exr_attr_set_string(ctxt, part, "lensrt/lensFile", meta->lens_file);
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_attr_set_double(ctxt, part, "lensrt/focalLengthMm", meta->focal_length_mm);
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_attr_set_double(ctxt, part, "lensrt/fNumber", meta->f_number);
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_attr_set_double(ctxt, part, "lensrt/stopRadiusMm", meta->stop_radius_mm);
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_attr_set_double(ctxt, part, "lensrt/focusOffsetMm", meta->focus_offset_mm);
        if (rv == EXR_ERR_SUCCESS) {
            v2.x = meta->pixel_pitch_x_mm;
            v2.y = meta->pixel_pitch_y_mm;
            rv = exr_attr_set_v2d(ctxt, part, "lensrt/pixelPitchMm", &v2);
        }
        if (rv == EXR_ERR_SUCCESS) {
            v2.x = meta->center_x_mm;
            v2.y = meta->center_y_mm;
            rv = exr_attr_set_v2d(ctxt, part, "lensrt/centerMm", &v2);
        }
        // ... and the timings, which differ from run to run
        if (rv == EXR_ERR_SUCCESS && !meta->reproducible)
            rv = exr_attr_set_double(ctxt, part, "lensrt/seconds", meta->seconds);
        if (rv == EXR_ERR_SUCCESS && meta->aperture)
            rv = exr_attr_set_string(ctxt, part, "lensrt/aperture", meta->aperture);
        if (rv == EXR_ERR_SUCCESS && meta->layers)
            rv = exr_attr_set_string(ctxt, part, "lensrt/layers", meta->layers);
        if (rv == EXR_ERR_SUCCESS && meta->renders)
            rv = exr_attr_set_string(ctxt, part, "lensrt/renders", meta->renders);
        // How the image was integrated, with that integrator's parameters only (issue 40):
        // Monte Carlo's samples, or the cells integrator's mesh or the Fourier
        // integrator's rule, and their error estimate (issue 22)
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_attr_set_string(ctxt, part, "lensrt/integrator",
                                     meta->cells_rings ? "cells" : meta->fourier_nodes ? "fourier" : "montecarlo");
        if (!meta->cells_rings && !meta->fourier_nodes) {
            if (rv == EXR_ERR_SUCCESS) {
                snprintf(text, sizeof text, "%llu", (unsigned long long)meta->samples_per_wavelength);
                rv = exr_attr_set_string(ctxt, part, "lensrt/samplesPerWavelength", text);
            }
            if (rv == EXR_ERR_SUCCESS && meta->sampler)
                rv = exr_attr_set_string(ctxt, part, "lensrt/sampler", meta->sampler);
            if (rv == EXR_ERR_SUCCESS && meta->estimator)
                rv = exr_attr_set_string(ctxt, part, "lensrt/estimator", meta->estimator);
            if (rv == EXR_ERR_SUCCESS) {
                snprintf(text, sizeof text, "%llu", (unsigned long long)meta->seed);
                rv = exr_attr_set_string(ctxt, part, "lensrt/seed", text);
            }
            if (rv == EXR_ERR_SUCCESS && meta->sample_runs)
                rv = exr_attr_set_string(ctxt, part, "lensrt/sampleRuns", meta->sample_runs);
            if (rv == EXR_ERR_SUCCESS && meta->phase_tolerance_waves > 0.0)
                rv = exr_attr_set_double(ctxt, part, "lensrt/phaseToleranceWaves", meta->phase_tolerance_waves);
            if (rv == EXR_ERR_SUCCESS && !meta->reproducible)
                rv = exr_attr_set_double(ctxt, part, "lensrt/splatsPerSecond", meta->splats_per_second);
        } else {
            if (rv == EXR_ERR_SUCCESS && meta->cells_rings)
                rv = exr_attr_set_int(ctxt, part, "lensrt/cellsRings", meta->cells_rings);
            if (rv == EXR_ERR_SUCCESS && meta->fourier_nodes)
                rv = exr_attr_set_int(ctxt, part, "lensrt/fourierNodes", meta->fourier_nodes);
            if (rv == EXR_ERR_SUCCESS && meta->fourier_nodes && meta->fourier_tolerance > 0.0)
                rv = exr_attr_set_double(ctxt, part, "lensrt/fourierTolerance", meta->fourier_tolerance);
            if (rv == EXR_ERR_SUCCESS && meta->error_estimate >= 0.0)
                rv = exr_attr_set_double(ctxt, part, "lensrt/errorEstimate", meta->error_estimate);
            if (rv == EXR_ERR_SUCCESS && meta->error_estimate >= 0.0) {
                if (meta->cells_rings)
                    snprintf(text, sizeof text,
                             "relative L2 error over every pixel and wavelength, from the difference of the "
                             "images of %d and %d rings (lensrt_render_integrate)",
                             meta->cells_rings, meta->cells_rings / 2);
                else
                    snprintf(text, sizeof text,
                             "relative L2 distance over every pixel and wavelength from the image of %d nodes "
                             "per side (lensrt_render_integrate_fourier)",
                             (int)ceil(LENSRT_FOURIER_FINER * meta->fourier_nodes));
                rv = exr_attr_set_string(ctxt, part, "lensrt/errorEstimateMethod", text);
            }
        }
        if (rv == EXR_ERR_SUCCESS && meta->pixel_filter)
            rv = exr_attr_set_string(ctxt, part, "lensrt/pixelFilter", meta->pixel_filter);
        if (rv == EXR_ERR_SUCCESS && meta->pixel_filter)
            rv = exr_attr_set_int(ctxt, part, "lensrt/pixelSamplesX", meta->pixel_samples_x);
        if (rv == EXR_ERR_SUCCESS && meta->pixel_filter)
            rv = exr_attr_set_int(ctxt, part, "lensrt/pixelSamplesY", meta->pixel_samples_y);
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_attr_set_int(ctxt, part, "lensrt/nLights", meta->n_lights);
        if (rv == EXR_ERR_SUCCESS) {
            lights = exr_lights_text(allocator, meta);
            if (!lights) {
                exr_set_error(err, err_size, "EXR '%s': out of memory", path);
                result = LENSRT_ERROR_OUT_OF_MEMORY;
                goto cleanup;
            }
            rv = exr_attr_set_string(ctxt, part, "lensrt/lights", lights);
        }
    }
    if (rv != EXR_ERR_SUCCESS)
        goto exr_failed;

    /* Step 6: the header (this fixes the chunk count and reserves the offset table). */
    step = "writing the header";
    rv = exr_write_header(ctxt);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_get_scanlines_per_chunk(ctxt, part, &lines_per_chunk);
    if (rv != EXR_ERR_SUCCESS)
        goto exr_failed;

    /* Step 7: the chunks, top to bottom. Each channel is read straight from the caller's
     * arrays: spectral planes (4-byte stride) and interleaved RGB (12-byte stride). */
    step = "encoding the pixels";
    for (y = 0; y < height; y += lines_per_chunk) {
        exr_chunk_info_t chunk;
        int c;
        rv = exr_write_scanline_chunk_info(ctxt, part, y, &chunk);
        if (rv != EXR_ERR_SUCCESS)
            goto exr_failed;
        if (!encoder_live) {
            memset(&encoder, 0, sizeof encoder);
            rv = exr_encoding_initialize(ctxt, part, &chunk, &encoder);
            if (rv != EXR_ERR_SUCCESS)
                goto exr_failed;
            encoder_live = 1;
            /* Match OpenEXRCore's (sorted) channels to ours, once. */
            if (encoder.channel_count != n_channels) {
                exr_set_error(err, err_size, "EXR '%s': OpenEXRCore has %d channels, expected %d",
                              path, (int)encoder.channel_count, n_channels);
                result = LENSRT_ERROR_IO;
                goto cleanup;
            }
            for (c = 0; c < n_channels; ++c) {
                channel_of[c] = -1;
                for (i = 0; i < n_channels; ++i)
                    if (strcmp(encoder.channels[c].channel_name, names[i]) == 0)
                        channel_of[c] = i;
                if (channel_of[c] < 0) {
                    exr_set_error(err, err_size, "EXR '%s': unexpected channel '%s'", path,
                                  encoder.channels[c].channel_name);
                    result = LENSRT_ERROR_IO;
                    goto cleanup;
                }
            }
        } else {
            rv = exr_encoding_update(ctxt, part, &chunk, &encoder);
            if (rv != EXR_ERR_SUCCESS)
                goto exr_failed;
        }
        for (c = 0; c < n_channels; ++c) {
            exr_coding_channel_info_t *ch = &encoder.channels[c];
            const lensrt_exr_image *im = &images[channel_of[c] / per_image];
            int k = channel_of[c] % per_image;
            const float *first;
            if (k < n_wavelengths) {
                first = im->spectral + (size_t)k * n_pixels + (size_t)chunk.start_y * (size_t)width;
                ch->user_pixel_stride = (int32_t)sizeof(float);
            } else {
                first = im->rgb + (size_t)chunk.start_y * (size_t)width * 3 + (size_t)(k - n_wavelengths);
                ch->user_pixel_stride = (int32_t)(3 * sizeof(float));
            }
            ch->user_line_stride = ch->user_pixel_stride * width;
            ch->user_bytes_per_element = (int16_t)sizeof(float);
            ch->user_data_type = (uint16_t)EXR_PIXEL_FLOAT;
            ch->encode_from_ptr = (const uint8_t *)first;
        }
        if (y == 0) {
            rv = exr_encoding_choose_default_routines(ctxt, part, &encoder);
            if (rv != EXR_ERR_SUCCESS)
                goto exr_failed;
            // Every compressed chunk through compress_or_store (above)
            if (encoder.compress_fn) {
                guard.compress = encoder.compress_fn;
                encoder.encoding_user_data = &guard;
                encoder.compress_fn = &compress_or_store;
            }
        }
        rv = exr_encoding_run(ctxt, part, &encoder);
        if (rv != EXR_ERR_SUCCESS)
            goto exr_failed;
    }
    if (encoder_live) {
        encoder_live = 0;
        rv = exr_encoding_destroy(ctxt, &encoder);
        if (rv != EXR_ERR_SUCCESS)
            goto exr_failed;
    }

    /* Step 8: finish (writes the chunk offset table), flush to disk, rename. */
    step = "finishing the file";
    rv = exr_finish(&ctxt);
    ctxt = NULL;
    if (rv != EXR_ERR_SUCCESS)
        goto exr_failed;
    if (fsync(sink.fd) != 0) {
        exr_set_error(err, err_size, "EXR '%s': flushing '%s' to disk failed: %s", path, tmp_name,
                      strerror(errno));
        result = LENSRT_ERROR_IO;
        goto cleanup;
    }
    {
        int fd = sink.fd;
        sink.fd = -1;
        if (close(fd) != 0) {
            exr_set_error(err, err_size, "EXR '%s': closing '%s' failed: %s", path, tmp_name,
                          strerror(errno));
            result = LENSRT_ERROR_IO;
            goto cleanup;
        }
    }
    if (rename(tmp_name, path) != 0) {
        exr_set_error(err, err_size, "EXR '%s': cannot rename '%s' over it: %s", path, tmp_name,
                      strerror(errno));
        result = LENSRT_ERROR_IO;
        goto cleanup;
    }
    allocator->free_fn(tmp_name, allocator->user_data);
    tmp_name = NULL;
    goto cleanup;

exr_failed:
    /* An OpenEXRCore call failed: name the step, the path and OpenEXRCore's words. */
    if (sink.write_errno != 0)
        result = LENSRT_ERROR_IO;
    else
        result = exr_map_result(rv);
    if (sink.message[0])
        exr_set_error(err, err_size, "EXR '%s': %s failed: %s", path, step, sink.message);
    else
        exr_set_error(err, err_size, "EXR '%s': %s failed: OpenEXRCore says %s (%s)", path, step,
                      exr_get_error_code_as_string(rv), exr_get_default_error_message(rv));

cleanup:
    if (encoder_live && ctxt)
        exr_encoding_destroy(ctxt, &encoder);
    if (ctxt)
        exr_finish(&ctxt); /* the failed file is ours to delete, below */
    if (sink.fd >= 0)
        close(sink.fd);
    if (tmp_name) {
        remove(tmp_name);
        allocator->free_fn(tmp_name, allocator->user_data);
    }
    if (lights)
        allocator->free_fn(lights, allocator->user_data);
    if (names)
        allocator->free_fn(names, allocator->user_data);
    if (base)
        allocator->free_fn(base, allocator->user_data);
    if (channel_of)
        allocator->free_fn(channel_of, allocator->user_data);
    return result;
}

#endif /* LENSRT_EXR */

lensrt_result lensrt_write_exr(const lensrt_allocator *allocator, const char *path,
                               int width, int height, int n_wavelengths,
                               const double *wavelengths_nm, const float *spectral,
                               const float *rgb, const lensrt_image_meta *meta,
                               char *err, size_t err_size)
{
    /* One unprefixed image: the spectral layout as it is. */
    lensrt_exr_image image;
    image.name = NULL;
    image.spectral = spectral;
    image.rgb = rgb;
    return lensrt_write_exr_layers(allocator, path, width, height, n_wavelengths, wavelengths_nm, 1,
                                   &image, meta, err, err_size);
}
