/* Files of PSF banks written by the C tests (lensrt.h, "PSF banks"): a bitwise CRC-32
 * independent of the library's, whole files written at once, and synthetic banks whose
 * node images the test chooses: `registration channel` node EXRs (uncompressed scanline
 * OpenEXR, written here byte by byte, FLOAT channels named as lensrt names them, the
 * lensrt/bankNode attribute) and their stamped index. One slice (f-number, focus 0,
 * distance 0). Include after check.h in one source of a test. */
#ifndef LENSRT_TEST_BANK_FILES_H
#define LENSRT_TEST_BANK_FILES_H

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>

/* A bitwise CRC-32 (zlib's), independent of the library's. */
static inline uint32_t test_crc32(const void *data, size_t size)
{
    const unsigned char *p = data;
    uint32_t crc = 0xFFFFFFFFu;
    size_t k;
    for (k = 0; k < size; k++) {
        int b;
        crc ^= p[k];
        for (b = 0; b < 8; b++) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return ~crc;
}

static inline int write_bytes(const char *path, const void *data, size_t size)
{
    FILE *f = fopen(path, "wb");
    int ok = f && fwrite(data, 1, size, f) == size;
    if (f) ok = fclose(f) == 0 && ok;
    return ok;
}

/* A growing byte buffer (little-endian numbers, as EXR stores them). */
typedef struct byte_buf {
    unsigned char *p;
    size_t n, cap;
    int failed;
} byte_buf;

static inline void buf_put(byte_buf *b, const void *data, size_t n)
{
    if (b->failed) return;
    if (b->n + n > b->cap) {
        size_t cap = b->cap ? b->cap : 4096;
        unsigned char *q;
        while (cap < b->n + n) cap *= 2;
        if (!(q = realloc(b->p, cap))) {
            b->failed = 1;
            return;
        }
        b->p = q;
        b->cap = cap;
    }
    memcpy(b->p + b->n, data, n);
    b->n += n;
}

static inline void buf_u32(byte_buf *b, uint32_t v)
{
    unsigned char c[4];
    c[0] = (unsigned char)v;
    c[1] = (unsigned char)(v >> 8);
    c[2] = (unsigned char)(v >> 16);
    c[3] = (unsigned char)(v >> 24);
    buf_put(b, c, 4);
}

static inline void buf_u64(byte_buf *b, uint64_t v)
{
    buf_u32(b, (uint32_t)v);
    buf_u32(b, (uint32_t)(v >> 32));
}

static inline void buf_f32(byte_buf *b, float f)
{
    uint32_t v;
    memcpy(&v, &f, 4);
    buf_u32(b, v);
}

static inline void buf_str(byte_buf *b, const char *s)
{
    buf_put(b, s, strlen(s) + 1);
}

/* An attribute's name, type and size (its value follows). */
static inline void buf_attr(byte_buf *b, const char *name, const char *type, uint32_t size)
{
    buf_str(b, name);
    buf_str(b, type);
    buf_u32(b, size);
}

/* lensrt's name of a spectral channel (io/image_exr.c): "S0.<nm>,<6 decimals>nm". */
static inline void spectral_name(double nm, char out[48])
{
    long long micro = (long long)floor(nm * 1.0e6 + 0.5);
    snprintf(out, 48, "S0.%lld,%06lldnm", micro / 1000000, micro % 1000000);
}

/* An uncompressed scanline EXR of n planes (w x h floats, row 0 first) named after the
 * wavelengths, with the string attribute lensrt/bankNode `identity`. 1: written. */
static inline int write_node_exr(const char *path, int w, int h, int n, const double *nm, const float *planes,
                          const char *identity)
{
    byte_buf b = {NULL, 0, 0, 0};
    char (*names)[48] = malloc((size_t)n * sizeof *names);
    int *order = malloc((size_t)n * sizeof(int));
    uint32_t chsize = 1;
    size_t table;
    int c, d, y, x, ok;
    if (!names || !order) {
        free(names);
        free(order);
        return 0;
    }
    // The channels in the alphabetical order EXR keeps them in
    for (c = 0; c < n; c++) {
        spectral_name(nm[c], names[c]);
        order[c] = c;
        chsize += (uint32_t)strlen(names[c]) + 1 + 16;
    }
    for (c = 1; c < n; c++)
        for (d = c; d > 0 && strcmp(names[order[d - 1]], names[order[d]]) > 0; d--) {
            const int t = order[d];
            order[d] = order[d - 1];
            order[d - 1] = t;
        }
    // Magic, version 2 (single-part scanline), the header
    buf_put(&b, "\x76\x2f\x31\x01\x02\x00\x00\x00", 8);
    buf_attr(&b, "channels", "chlist", chsize);
    for (c = 0; c < n; c++) {
        buf_str(&b, names[order[c]]);
        buf_u32(&b, 2); /* FLOAT */
        buf_u32(&b, 0); /* pLinear and reserved */
        buf_u32(&b, 1);
        buf_u32(&b, 1);
    }
    buf_put(&b, "", 1);
    buf_attr(&b, "compression", "compression", 1);
    buf_put(&b, "", 1); /* NO_COMPRESSION */
    for (c = 0; c < 2; c++) {
        buf_attr(&b, c ? "displayWindow" : "dataWindow", "box2i", 16);
        buf_u32(&b, 0);
        buf_u32(&b, 0);
        buf_u32(&b, (uint32_t)(w - 1));
        buf_u32(&b, (uint32_t)(h - 1));
    }
    buf_attr(&b, "lineOrder", "lineOrder", 1);
    buf_put(&b, "", 1);
    buf_attr(&b, "pixelAspectRatio", "float", 4);
    buf_f32(&b, 1.0f);
    buf_attr(&b, "screenWindowCenter", "v2f", 8);
    buf_f32(&b, 0.0f);
    buf_f32(&b, 0.0f);
    buf_attr(&b, "screenWindowWidth", "float", 4);
    buf_f32(&b, 1.0f);
    buf_attr(&b, "lensrt/bankNode", "string", (uint32_t)strlen(identity));
    buf_put(&b, identity, strlen(identity));
    buf_put(&b, "", 1);
    // The offset table (one scanline a chunk), then the chunks: y, size, each channel's row
    table = b.n;
    for (y = 0; y < h; y++) buf_u64(&b, 0);
    for (y = 0; y < h; y++) {
        const uint64_t at = b.n;
        if (!b.failed)
            for (c = 0; c < 8; c++) b.p[table + 8 * (size_t)y + (size_t)c] = (unsigned char)(at >> (8 * c));
        buf_u32(&b, (uint32_t)y);
        buf_u32(&b, (uint32_t)(4 * n * w));
        for (c = 0; c < n; c++)
            for (x = 0; x < w; x++)
                buf_f32(&b, planes[((size_t)order[c] * (size_t)h + (size_t)y) * (size_t)w + (size_t)x]);
    }
    ok = !b.failed && write_bytes(path, b.p, b.n);
    free(b.p);
    free(names);
    free(order);
    return ok;
}

/* A synthetic bank: the test's PSF (w x h floats, row 0 at +y) and chief point (mm) of
 * node (ix, iy) at wavelength l. */
typedef struct synth_bank {
    int w, h;
    double pitch_mm, pitch_y_mm; /* pixel pitch in x, and in y (0: the same) */
    int n_wl;
    const double *wl_nm;
    int nx, ny;
    const double *fx_deg, *fy_deg;
    double f_number;
    const char *registration; /* "channel" (the nodes carry lensrt/bankNode) or "chief" */
    void (*psf)(const struct synth_bank *b, int ix, int iy, int l, float *out);
    void (*chief)(const struct synth_bank *b, int ix, int iy, int l, double xy[2]);
    const void *user;
} synth_bank;

/* Write the bank in `folder` (made, with nodes/); its index's path into index_path. */
static inline int synth_bank_write(const synth_bank *sb, const char *folder, char *index_path, size_t size)
{
    const size_t plane = (size_t)sb->w * (size_t)sb->h;
    size_t cap = 65536 + (size_t)sb->nx * (size_t)sb->ny * (200 + 48 * (size_t)sb->n_wl), used = 0;
    char *text = malloc(cap), path[4400];
    float *planes = malloc(plane * (size_t)sb->n_wl * sizeof(float));
    double *chief = malloc(2 * (size_t)sb->n_wl * sizeof(double));
    int k, l, ok = text && planes && chief;
    snprintf(path, sizeof path, "%s/nodes", folder);
    ok = ok && (mkdir(folder, 0777) == 0 || errno == EEXIST) && (mkdir(path, 0777) == 0 || errno == EEXIST);
#define PUT(...) (used += (size_t)snprintf(text + used, cap - used, __VA_ARGS__))
    if (ok) {
        PUT("lensrt-bank 1\nlens synthetic\ntable_crc32 00000000\nwidth %d\nheight %d\npixel_mm %.17g %.17g\n"
            "registration %s\nwavelengths_nm %d", sb->w, sb->h, sb->pitch_mm,
            sb->pitch_y_mm > 0.0 ? sb->pitch_y_mm : sb->pitch_mm, sb->registration, sb->n_wl);
        for (l = 0; l < sb->n_wl; l++) PUT(" %.17g", sb->wl_nm[l]);
        PUT("\nf_numbers 1 %.17g\nfocus_offsets_mm 1 0\ndistances_mm 1 0\nfield_x_deg %d", sb->f_number, sb->nx);
        for (k = 0; k < sb->nx; k++) PUT(" %.17g", sb->fx_deg[k]);
        PUT("\nfield_y_deg %d", sb->ny);
        for (k = 0; k < sb->ny; k++) PUT(" %.17g", sb->fy_deg[k]);
        PUT("\nnodes %d\n", sb->nx * sb->ny);
    }
    for (k = 0; ok && k < sb->nx * sb->ny; k++) {
        const int ix = k % sb->nx, iy = k / sb->nx;
        char identity[512], rel[64];
        size_t n;
        char *bytes;
        for (l = 0; l < sb->n_wl; l++) {
            sb->psf(sb, ix, iy, l, planes + (size_t)l * plane);
            sb->chief(sb, ix, iy, l, chief + 2 * l);
        }
        snprintf(identity, sizeof identity, "0 0 0 %d %d %.17g 0 0 %.17g %.17g", iy, ix, sb->f_number, sb->fx_deg[ix],
                 sb->fy_deg[iy]);
        snprintf(rel, sizeof rel, "nodes/y%d-x%d.exr", iy, ix);
        snprintf(path, sizeof path, "%s/%s", folder, rel);
        ok = write_node_exr(path, sb->w, sb->h, sb->n_wl, sb->wl_nm, planes, identity);
        bytes = ok ? read_text(path, &n) : NULL;
        ok = bytes != NULL;
        if (ok) {
            // The window on the middle chief point (informative with `registration channel`)
            PUT("node %d 0 0 0 %d %d %.17g %.17g 0.001 %08x %s\nchief %d", k, iy, ix, chief[2 * (sb->n_wl / 2)],
                chief[2 * (sb->n_wl / 2) + 1], (unsigned)test_crc32(bytes, n), rel, k);
            for (l = 0; l < 2 * sb->n_wl; l++) PUT(" %.17g", chief[l]);
            PUT("\n");
        }
        free(bytes);
    }
    if (ok) {
        // The checksum of every byte before its line
        const uint32_t crc = test_crc32(text, used);
        PUT("checksum crc32 %08x\n", (unsigned)crc);
        snprintf(index_path, size, "%s/bank.index", folder);
        ok = used < cap && write_bytes(index_path, text, used);
    }
#undef PUT
    free(text);
    free(planes);
    free(chief);
    return ok;
}

#endif /* LENSRT_TEST_BANK_FILES_H */
