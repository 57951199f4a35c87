/*
 * PNG preview writer for lensrt, with no dependency: no zlib, no libpng.
 *
 * The file is an 8-bit RGB PNG (ISO/IEC 15948, W3C PNG specification): the signature,
 * IHDR, an sRGB chunk (the pixels are sRGB encoded), the image data as a zlib stream
 * (RFC 1950) made of stored, uncompressed deflate blocks (RFC 1951, section 3.2.4) of at
 * most 65535 bytes, one IDAT chunk per block, then IEND. Stored blocks make the file
 * about as large as the raw pixels (3 bytes each), which is fine for a preview and keeps
 * the writer small enough to check by hand. CRC-32 (PNG chunks) and Adler-32 (zlib)
 * are computed here.
 *
 * Tone map (image_io.h), per pixel of the linear sRGB input (R, G, B):
 *
 *   1. Luminance Y = 0.2126 R + 0.7152 G + 0.0722 B; pixels with Y not positive and
 *      finite are black. Y_peak = the largest finite Y of the image.
 *   2. Displayed luminance v = clamp(1 + log10(Y / Y_peak) / decades, 0, 1): the peak
 *      is 1, `decades` decades below it 0.
 *   3. Chroma c = (R, G, B) / Y - (1, 1, 1): the colour's offset from the grey of the
 *      same luminance (its own luminance is 0, so the hue is the direction of c). The
 *      displayed colour is v (1 + s c), with s in [0, 1] chosen as
 *        s = min(s_fade, the largest s with every channel of v (1 + s c) in [0, 1]).
 *      Mixing with the grey (v, v, v) keeps the luminance v exactly and keeps the hue
 *      (the point moves on the line from the white point towards the colour), so a
 *      colour outside the sRGB gamut, or one with a negative component (a spectral
 *      colour purer than the sRGB primaries), is desaturated only as much as needed,
 *      never clamped channel by channel (clamping shifts hue and luminance: a dim
 *      fringe that is slightly negative in G and scaled far up turns saturated magenta).
 *      Grey (s c = 0) is always in gamut since v is in [0, 1].
 *   4. s_fade = v: chroma fades with the displayed luminance, from full at the peak to
 *      grey at the bottom of the range. A log map lifts parts of a PSF thousands of times
 *      dimmer than its peak to mid-grey, and there Monte Carlo noise and the
 *      non-overlapping rings of distant wavelengths decide the colour; at full strength
 *      they read as saturated speckle and candy-coloured rings. Fading by v keeps the
 *      colour of the bright core and first fringes and lets the faint tails fall back
 *      towards grey (chosen by eye on the `make demo` PSFs against fading over the
 *      bottom two decades only, which left the f/2 noise floor purple and green).
 *   5. The sRGB transfer curve, then rounding to 8 bits.
 *
 * The write is atomic: a temporary file next to the target, renamed over it only when
 * every byte is written and flushed to disk; on failure the temporary file is removed.
 */
#ifndef _POSIX_C_SOURCE
#define _POSIX_C_SOURCE 200809L /* open, fdopen, fsync, getpid, clock_gettime */
#endif

#include "image_io.h"
#include "../c_numbers.h"
#include "../core/crc32.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

/* Rec. 709 / sRGB luminance weights of linear R, G, B. */
#define PNG_LUMA_R 0.2126
#define PNG_LUMA_G 0.7152
#define PNG_LUMA_B 0.0722
/* Decades of luminance below the peak mapped to [0, 1] when the caller passes <= 0. */
#define PNG_DEFAULT_DECADES 5.0
/* Largest payload of one stored deflate block (bytes): LEN is 16 bits. */
#define PNG_STORED_BLOCK_MAX 65535u

/* ------------------------------------------------------------------ errors ----- */

static void png_set_error(char *err, size_t err_size, const char *fmt, ...)
{
    va_list args;
    if (!err || err_size == 0)
        return;
    va_start(args, fmt);
    lensrt_vsnprintf_c(err, err_size, fmt, args); /* numbers with a point, any locale */
    va_end(args);
}

/* ------------------------------------------------------------ checksums ----- */

/* CRC-32 as PNG uses it: core/crc32.h (shared with the coefficient tables), its table
 * in the writer's state, built once per file. */
typedef struct png_crc {
    uint32_t table[256];
} png_crc;

/* Adler-32 (RFC 1950, section 8.2): two sums modulo 65521, the largest prime below 2^16.
 * 5552 is the most bytes that can be summed before a 32-bit sum may overflow. */
typedef struct png_adler {
    uint32_t a, b;
} png_adler;

static void png_adler_update(png_adler *adler, const unsigned char *data, size_t size)
{
    const uint32_t base = 65521u;
    while (size > 0) {
        size_t chunk = size < 5552u ? size : 5552u;
        size_t i;
        for (i = 0; i < chunk; ++i) {
            adler->a += data[i];
            adler->b += adler->a;
        }
        adler->a %= base;
        adler->b %= base;
        data += chunk;
        size -= chunk;
    }
}

/* ------------------------------------------------------------ tone map ----- */

/* sRGB transfer curve (IEC 61966-2-1) of a linear value in [0, 1]. */
static double png_srgb_encode(double linear)
{
    return linear <= 0.0031308 ? 12.92 * linear : 1.055 * pow(linear, 1.0 / 2.4) - 0.055;
}

static double png_luminance(const float *px)
{
    return PNG_LUMA_R * (double)px[0] + PNG_LUMA_G * (double)px[1] + PNG_LUMA_B * (double)px[2];
}

/* One 8-bit channel from a linear value in [0, 1] (rounding can leave a few ulps
 * outside, which are clamped). */
static unsigned char png_quantise(double linear)
{
    double e;
    if (!(linear > 0.0))
        return 0;
    if (linear > 1.0)
        linear = 1.0;
    e = png_srgb_encode(linear) * 255.0 + 0.5;
    return (unsigned char)(e >= 255.0 ? 255 : (int)e);
}

/* The displayed linear colour of one pixel (steps 1-4 of the header): out in [0, 1]^3. */
static void png_tone_map_pixel(const float *px, double y_peak, double decades, double out[3])
{
    double lum = png_luminance(px), v, s, c[3];
    int k;
    out[0] = out[1] = out[2] = 0.0;
    if (!(y_peak > 0.0 && lum > 0.0 && lum <= y_peak)) /* black, negative, NaN, infinite */
        return;
    v = 1.0 + log10(lum / y_peak) / decades;
    if (v <= 0.0)
        return;
    if (v > 1.0)
        v = 1.0;
    s = v; /* step 4: the chroma fades with the displayed luminance */
    for (k = 0; k < 3; ++k) {
        c[k] = (double)px[k] / lum - 1.0;
        /* v (1 + s c_k) <= 1 when c_k > 0 and >= 0 when c_k < 0; both bounds are >= 0. */
        if (c[k] > 0.0 && s * c[k] > 1.0 / v - 1.0)
            s = (1.0 / v - 1.0) / c[k];
        else if (c[k] < 0.0 && s * -c[k] > 1.0)
            s = 1.0 / -c[k];
    }
    for (k = 0; k < 3; ++k)
        out[k] = v * (1.0 + s * c[k]);
}

/* Tone map row y into `row` (filter byte 0 = None, then R G B per pixel). Pixels whose
 * luminance is not positive and finite (black, negative, NaN, infinite) are black, and
 * so is every pixel when no pixel has positive finite luminance. */
static void png_tone_map_row(const float *rgb, size_t width, size_t y, double y_peak,
                             double decades, unsigned char *row)
{
    size_t x;
    row[0] = 0;
    for (x = 0; x < width; ++x) {
        double lin[3];
        unsigned char *out = row + 1 + 3 * x;
        png_tone_map_pixel(rgb + 3 * (y * width + x), y_peak, decades, lin);
        out[0] = png_quantise(lin[0]);
        out[1] = png_quantise(lin[1]);
        out[2] = png_quantise(lin[2]);
    }
}

/* ------------------------------------------------------------- file out ----- */

/* The state of one write: the temporary file and the checksums. */
typedef struct png_writer {
    FILE *file;
    png_crc crc;
    int failed; /* an fwrite failed; errno kept in saved_errno */
    int saved_errno;
} png_writer;

static void png_put(png_writer *w, const void *data, size_t size)
{
    if (w->failed || size == 0)
        return;
    if (fwrite(data, 1, size, w->file) != size) {
        w->failed = 1;
        w->saved_errno = errno;
    }
}

static void png_put_u32(unsigned char *out, uint32_t v)
{
    out[0] = (unsigned char)(v >> 24);
    out[1] = (unsigned char)(v >> 16);
    out[2] = (unsigned char)(v >> 8);
    out[3] = (unsigned char)v;
}

/* One chunk: length (big endian), type, data, CRC-32 of type and data. */
static void png_chunk(png_writer *w, const char type[4], const unsigned char *data, size_t size)
{
    unsigned char head[8], tail[4];
    uint32_t crc = 0xFFFFFFFFu;
    png_put_u32(head, (uint32_t)size);
    memcpy(head + 4, type, 4);
    crc = lensrt_crc32_update(w->crc.table, crc, head + 4, 4);
    crc = lensrt_crc32_update(w->crc.table, crc, data, size);
    png_put_u32(tail, ~crc);
    png_put(w, head, 8);
    png_put(w, data, size);
    png_put(w, tail, 4);
}

lensrt_result lensrt_write_png(const lensrt_allocator *allocator, const char *path,
                               int width, int height, const float *rgb, double decades,
                               char *err, size_t err_size)
{
    png_writer w;
    png_adler adler;
    char *tmp_name = NULL;
    unsigned char *row = NULL, *idat = NULL;
    size_t row_bytes, total_raw, emitted = 0, row_pos, y, n_pixels, i;
    double y_peak = 0.0;
    unsigned char ihdr[13];
    static const unsigned char signature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
    lensrt_result result = LENSRT_SUCCESS;
    int open_errno = 0;
    const char *refusal;

    if (err && err_size > 0)
        err[0] = '\0';

    /* Step 1: check the arguments before touching the file system. */
    if (!path) {
        png_set_error(err, err_size, "PNG: the path is NULL");
        return LENSRT_ERROR_INVALID_ARGUMENT;
    }
    if (!allocator || !allocator->alloc_fn || !allocator->free_fn) {
        png_set_error(err, err_size, "PNG '%s': no allocator", path);
        return LENSRT_ERROR_INVALID_ARGUMENT;
    }
    if (!rgb) {
        png_set_error(err, err_size, "PNG '%s': the RGB image is NULL", path);
        return LENSRT_ERROR_INVALID_ARGUMENT;
    }
    if (width <= 0 || height <= 0) {
        png_set_error(err, err_size, "PNG '%s': size %d x %d, expected both > 0", path, width,
                      height);
        return LENSRT_ERROR_INVALID_ARGUMENT;
    }
    /* Raw image bytes (one filter byte plus 3 bytes per pixel per row) must fit in a size_t. */
    if ((size_t)width > (((size_t)-1) / 3 - 1) ||
        (size_t)height > ((size_t)-1) / (3 * (size_t)width + 1)) {
        png_set_error(err, err_size, "PNG '%s': size %d x %d is too large", path, width, height);
        return LENSRT_ERROR_INVALID_ARGUMENT;
    }
    /* 0 asks for the default; NaN, a negative or an infinite range has no tone map. */
    if (decades == 0.0)
        decades = PNG_DEFAULT_DECADES;
    else if (!(decades > 0.0) || !isfinite(decades)) {
        png_set_error(err, err_size, "PNG '%s': decades %g, expected a finite number > 0 (0: %g)", path, decades,
                      (double)PNG_DEFAULT_DECADES);
        return LENSRT_ERROR_INVALID_ARGUMENT;
    }
    row_bytes = 1 + 3 * (size_t)width;
    total_raw = row_bytes * (size_t)height;
    n_pixels = (size_t)width * (size_t)height;

    /* Step 2: the peak luminance (finite values only). */
    for (i = 0; i < n_pixels; ++i) {
        double lum = png_luminance(rgb + 3 * i);
        if (lum > y_peak && isfinite(lum))
            y_peak = lum;
    }

    /* Step 3: buffers (one tone-mapped row, one IDAT payload) and the temporary file. */
    row = (unsigned char *)allocator->alloc_fn(row_bytes, allocator->user_data);
    /* IDAT payload: zlib header (2), block header (5), data, Adler-32 (4). */
    idat = (unsigned char *)allocator->alloc_fn(2 + 5 + PNG_STORED_BLOCK_MAX + 4,
                                                allocator->user_data);
    if (!row || !idat) {
        png_set_error(err, err_size, "PNG '%s': out of memory", path);
        result = LENSRT_ERROR_OUT_OF_MEMORY;
        goto cleanup;
    }
    memset(&w, 0, sizeof w);
    lensrt_crc32_table(w.crc.table);
    if ((refusal = lensrt_target_refusal(path)) != NULL) {
        png_set_error(err, err_size, "PNG '%s' %s", path, refusal);
        result = LENSRT_ERROR_IO;
        goto cleanup;
    }
    w.file = lensrt_fopen_temporary(allocator, path, &tmp_name, &open_errno);
    if (!w.file) {
        png_set_error(err, err_size, "PNG '%s': cannot create a temporary file next to it: %s", path,
                      strerror(open_errno));
        result = open_errno == ENOMEM ? LENSRT_ERROR_OUT_OF_MEMORY : LENSRT_ERROR_IO;
        goto cleanup;
    }

    /* Step 4: signature, IHDR (width, height, bit depth 8, colour type 2 = RGB,
     * compression 0 = deflate, filter method 0, no interlace), sRGB (intent 0,
     * perceptual). */
    png_put(&w, signature, sizeof signature);
    png_put_u32(ihdr, (uint32_t)width);
    png_put_u32(ihdr + 4, (uint32_t)height);
    ihdr[8] = 8;
    ihdr[9] = 2;
    ihdr[10] = 0;
    ihdr[11] = 0;
    ihdr[12] = 0;
    png_chunk(&w, "IHDR", ihdr, sizeof ihdr);
    {
        const unsigned char intent = 0;
        png_chunk(&w, "sRGB", &intent, 1);
    }

    /* Step 5: the zlib stream, one stored block per IDAT chunk. The raw bytes are the
     * rows top to bottom (row 0 of `rgb` first), produced one row at a time. */
    adler.a = 1;
    adler.b = 0;
    y = 0;
    row_pos = row_bytes; /* no row produced yet */
    for (;;) {
        size_t head = 0, block = total_raw - emitted, filled = 0;
        int final;
        if (block > PNG_STORED_BLOCK_MAX)
            block = PNG_STORED_BLOCK_MAX;
        final = emitted + block == total_raw;
        if (emitted == 0) {
            /* zlib header: CM = 8 (deflate), CINFO = 7 (32 KiB window); FLG = 0x01 makes
             * (CMF * 256 + FLG) a multiple of 31, no dictionary, level "fastest". */
            idat[head++] = 0x78;
            idat[head++] = 0x01;
        }
        /* Stored block header: BFINAL, BTYPE = 00, then LEN and NLEN (little endian). */
        idat[head++] = (unsigned char)(final ? 1 : 0);
        idat[head++] = (unsigned char)(block & 0xFFu);
        idat[head++] = (unsigned char)(block >> 8);
        idat[head++] = (unsigned char)(~block & 0xFFu);
        idat[head++] = (unsigned char)((~block >> 8) & 0xFFu);
        while (filled < block) {
            size_t take;
            if (row_pos == row_bytes) {
                png_tone_map_row(rgb, (size_t)width, y++, y_peak, decades, row);
                row_pos = 0;
            }
            take = row_bytes - row_pos;
            if (take > block - filled)
                take = block - filled;
            memcpy(idat + head + filled, row + row_pos, take);
            row_pos += take;
            filled += take;
        }
        png_adler_update(&adler, idat + head, block);
        emitted += block;
        if (final) {
            png_put_u32(idat + head + block, (adler.b << 16) | adler.a);
            png_chunk(&w, "IDAT", idat, head + block + 4);
            break;
        }
        png_chunk(&w, "IDAT", idat, head + block);
    }
    png_chunk(&w, "IEND", NULL, 0);

    /* Step 6: flush to disk, close, then rename over the target. */
    if (!w.failed && fflush(w.file) != 0) {
        w.failed = 1;
        w.saved_errno = errno;
    }
    if (!w.failed && fsync(fileno(w.file)) != 0) {
        w.failed = 1;
        w.saved_errno = errno;
    }
    if (fclose(w.file) != 0 && !w.failed) {
        w.failed = 1;
        w.saved_errno = errno;
    }
    w.file = NULL;
    if (w.failed) {
        png_set_error(err, err_size, "PNG '%s': writing '%s' failed: %s", path, tmp_name,
                      strerror(w.saved_errno));
        result = LENSRT_ERROR_IO;
        goto cleanup;
    }
    if (rename(tmp_name, path) != 0) {
        png_set_error(err, err_size, "PNG '%s': cannot rename '%s' over it: %s", path, tmp_name,
                      strerror(errno));
        result = LENSRT_ERROR_IO;
        goto cleanup;
    }
    allocator->free_fn(tmp_name, allocator->user_data);
    tmp_name = NULL;

cleanup:
    if (tmp_name) {
        /* Any failure after the temporary file exists: remove it, leave `path` alone. */
        remove(tmp_name);
        allocator->free_fn(tmp_name, allocator->user_data);
    }
    if (row)
        allocator->free_fn(row, allocator->user_data);
    if (idat)
        allocator->free_fn(idat, allocator->user_data);
    return result;
}
