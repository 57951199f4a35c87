/* PSF banks: the node images. Every node's EXR is checked against its CRC-32 in the
 * index, its size, its channels and its values. Everything is read from memory: each EXR
 * is read whole, checked, then parsed (OpenEXRCore reads the EXR from our buffer, so the
 * bytes decoded are the bytes whose CRC was checked); the index is read whole the same
 * way (lensrt_bank_read_whole). */
#include "../c_numbers.h"
#include "../core/crc32.h"
#include "bank.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#ifdef LENSRT_EXR
#include <OpenEXR/openexr.h>
#endif

/* ------------------------------------------------------------------ files ----- */

/* A whole regular file into memory (the context's allocator); `what` names it in messages. */
lensrt_result lensrt_bank_read_whole(lensrt_context ctx, const char *path, const char *what, unsigned char **out,
                                     size_t *size)
{
    struct stat st;
    FILE *f;
    long n;
    *out = NULL;
    *size = 0;
    // A regular file only, checked before opening (a FIFO would block the open)
    if (stat(path, &st) != 0) return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: cannot open %s: %s", path, what, strerror(errno));
    if (!S_ISREG(st.st_mode)) return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: not a regular file (%s)", path, what);
    if (!(f = fopen(path, "rb"))) return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: cannot open %s: %s", path, what, strerror(errno));
    if (fseek(f, 0, SEEK_END) != 0 || (n = ftell(f)) < 0 || fseek(f, 0, SEEK_SET) != 0) {
        fclose(f);
        return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: cannot read %s", path, what);
    }
    if (n > BANK_MAX_FILE_BYTES) {
        fclose(f);
        return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: %ld bytes is more than a %s may hold (%ld)", path, n, what,
                           BANK_MAX_FILE_BYTES);
    }
    // One byte more, for a terminating NUL
    if (!(*out = lensrt_alloc(ctx, (size_t)n + 1))) {
        fclose(f);
        return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_MEMORY, "%s: out of memory", path);
    }
    if (fread(*out, 1, (size_t)n, f) != (size_t)n) {
        fclose(f);
        lensrt_free(ctx, *out);
        *out = NULL;
        return lensrt_fail(ctx, LENSRT_ERROR_IO, "%s: short read of %s", path, what);
    }
    fclose(f);
    (*out)[n] = '\0';
    *size = (size_t)n;
    return LENSRT_SUCCESS;
}

#ifdef LENSRT_EXR

/* The EXR's bytes, which OpenEXRCore reads through read_memory and size_memory. */
typedef struct exr_memory {
    const unsigned char *data;
    size_t size;
} exr_memory;

static int64_t read_memory(exr_const_context_t ctxt, void *userdata, void *buffer, uint64_t sz, uint64_t offset,
                           exr_stream_error_func_ptr_t error_cb)
{
    const exr_memory *m = userdata;
    uint64_t n;
    (void)ctxt;
    (void)error_cb;
    // As pread: what there is from offset, 0 past the end
    if (offset >= m->size) return 0;
    n = m->size - offset < sz ? m->size - offset : sz;
    memcpy(buffer, m->data + offset, (size_t)n);
    return (int64_t)n;
}

static int64_t size_memory(exr_const_context_t ctxt, void *userdata)
{
    (void)ctxt;
    return (int64_t)((const exr_memory *)userdata)->size;
}

/* OpenEXRCore's own messages would go to stderr; ours name the file and the step. */
static void exr_quiet(exr_const_context_t ctxt, exr_result_t code, const char *msg)
{
    (void)ctxt;
    (void)code;
    (void)msg;
}

/* The node's identity in its EXR (attribute "lensrt/bankNode", written by lensfit's bank
 * nodes): "<i_f> <i_z> <i_d> <i_y> <i_x> <f_number> <focus_offset_mm> <distance_mm>
 * <field_x_deg> <field_y_deg>" (distance 0: infinity), equal to the index's. */
static lensrt_result check_identity(lensrt_bank b, const bank_node *node, const char *path, exr_context_t ctxt)
{
    // The values in the attribute's order, and which index of the tuple picks each
    const int value_axis[5] = {AXIS_F, AXIS_FOCUS, AXIS_DISTANCE, AXIS_FIELD_X, AXIS_FIELD_Y};
    const int value_slot[5] = {0, 1, 2, 4, 3};
    const char *text = NULL;
    char buf[512], *tok, *save = NULL;
    int32_t len = 0;
    long v;
    double x;
    int i, ok = 1;
    if (exr_attr_get_string(ctxt, 0, "lensrt/bankNode", &len, &text) != EXR_ERR_SUCCESS || !text)
        return lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                           "%s: node %d (bank index %s:%d): no string attribute 'lensrt/bankNode' (which node the "
                           "image is); a `registration channel` bank's nodes carry it", path, node->k, b->index_path,
                           node->line);
    snprintf(buf, sizeof buf, "%.*s", len > 0 && len < (int32_t)sizeof buf ? (int)len : (int)sizeof buf - 1, text);
    tok = strtok_r(buf, " ", &save);
    for (i = 0; i < 5 && ok; i++, tok = strtok_r(NULL, " ", &save))
        ok = tok && lensrt_bank_parse_integer(tok, 0, LENSRT_MAX_BANK_NODES, &v) && v == node->tuple[i];
    for (i = 0; i < 5 && ok; i++, tok = strtok_r(NULL, " ", &save))
        ok = tok && lensrt_bank_parse_number(tok, &x) && x == b->values[value_axis[i]][node->tuple[value_slot[i]]];
    if (!ok || tok)
        return lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                           "%s: node %d (bank index %s:%d): the image says it is node '%.200s' (lensrt/bankNode), not "
                           "this one (indices %ld %ld %ld %ld %ld): an EXR of another node or bank; refused", path,
                           node->k, b->index_path, node->line, text, node->tuple[0], node->tuple[1], node->tuple[2],
                           node->tuple[3], node->tuple[4]);
    return LENSRT_SUCCESS;
}

/* Decode node's EXR (bytes already checked against its CRC) into node->image: one
 * scanline part of width x height FLOAT pixels from (0, 0), exactly the index's spectral
 * channels plus R, G, B, every value finite and >= 0. */
static lensrt_result decode_node(lensrt_bank b, bank_node *node, const char *path, const unsigned char *bytes,
                                 size_t size)
{
    const int nw = b->n[AXIS_WAVELENGTH], w = b->width, h = b->height;
    const size_t plane = (size_t)w * (size_t)h;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    exr_context_t ctxt = NULL;
    exr_decode_pipeline_t decoder;
    exr_memory mem;
    const exr_attr_chlist_t *chlist = NULL;
    exr_attr_box2i_t dw;
    exr_storage_t storage;
    char (*names)[LENSRT_EXR_SPECTRAL_NAME_SIZE] = NULL;
    int *seen = NULL, parts = 0, decoder_live = 0, c, i, y;
    int32_t lines = 0;
    const char *step = "";
    exr_result_t rv;
    lensrt_result res = LENSRT_SUCCESS;
    size_t p;

    names = lensrt_alloc(b->ctx, (size_t)nw * sizeof *names);
    seen = lensrt_calloc(b->ctx, (size_t)nw, sizeof(int));
    node->image = lensrt_calloc(b->ctx, plane * (size_t)nw, sizeof(float));
    if (!names || !seen || !node->image) {
        res = lensrt_fail(b->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "%s: out of memory for node %d's image", path, node->k);
        goto done;
    }
    for (i = 0; i < nw; i++) lensrt_exr_spectral_name(b->values[AXIS_WAVELENGTH][i], names[i]);
    // Open the EXR from memory
    mem.data = bytes;
    mem.size = size;
    init.error_handler_fn = &exr_quiet;
    init.user_data = &mem;
    init.read_fn = &read_memory;
    init.size_fn = &size_memory;
    step = "reading the header";
    if ((rv = exr_start_read(&ctxt, path, &init)) != EXR_ERR_SUCCESS) goto exr_failed;
    // One scanline part of the index's size, from (0, 0)
    step = "reading the parts";
    if ((rv = exr_get_count(ctxt, &parts)) != EXR_ERR_SUCCESS) goto exr_failed;
    if ((rv = exr_get_storage(ctxt, 0, &storage)) != EXR_ERR_SUCCESS) goto exr_failed;
    if (parts != 1 || storage != EXR_STORAGE_SCANLINE) {
        res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE, "%s: node %d (bank index %s:%d): %d part%s%s; a node is one "
                                                      "scanline image", path, node->k, b->index_path, node->line, parts,
                          parts == 1 ? "" : "s", storage != EXR_STORAGE_SCANLINE ? ", not scanlines" : "");
        goto done;
    }
    step = "reading the data window";
    if ((rv = exr_get_data_window(ctxt, 0, &dw)) != EXR_ERR_SUCCESS) goto exr_failed;
    if (dw.min.x != 0 || dw.min.y != 0 || (int64_t)dw.max.x + 1 != w || (int64_t)dw.max.y + 1 != h) {
        res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                          "%s: node %d (bank index %s:%d): the image is %lld x %lld pixels from (%d, %d); the index "
                          "says %d x %d from (0, 0)", path, node->k, b->index_path, node->line,
                          (long long)dw.max.x - dw.min.x + 1, (long long)dw.max.y - dw.min.y + 1, dw.min.x, dw.min.y, w,
                          h);
        goto done;
    }
    // A node of a `registration channel` bank says which node it is: its index tuple and
    // coordinates must be the index's (an EXR of another node, with the CRC in the index
    // updated to match, is refused)
    if (b->registration == REGISTRATION_CHANNEL && (res = check_identity(b, node, path, ctxt)) != LENSRT_SUCCESS)
        goto done;
    // The channels: each of the index's wavelengths once, FLOAT, full resolution; R, G, B ignored
    step = "reading the channels";
    if ((rv = exr_get_channels(ctxt, 0, &chlist)) != EXR_ERR_SUCCESS) goto exr_failed;
    for (c = 0; c < chlist->num_channels; c++) {
        const exr_attr_chlist_entry_t *e = &chlist->entries[c];
        const char *name = e->name.str;
        const char *dot = strchr(name, '.');
        char layer[LENSRT_MAX_LAYER_NAME + 2];
        if (strcmp(name, "R") == 0 || strcmp(name, "G") == 0 || strcmp(name, "B") == 0) continue;
        // A layer's channels ("direct.S0.550,000000nm", lensrt_layers_write_exr) are left to
        // other readers: the unprefixed ones hold the image, the layers' sum
        if (dot && dot - name <= LENSRT_MAX_LAYER_NAME) {
            snprintf(layer, sizeof layer, "%.*s", (int)(dot - name), name);
            if (!lensrt_exr_layer_name_refusal(layer)) continue;
        }
        for (i = 0; i < nw && strcmp(name, names[i]) != 0; i++) continue;
        if (i == nw) {
            res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                              "%s: node %d (bank index %s:%d): channel '%.64s' is none of the index's wavelengths (%s "
                              "... %s) nor R, G, B", path, node->k, b->index_path, node->line, name, names[0],
                              names[nw - 1]);
            goto done;
        }
        if (e->pixel_type != EXR_PIXEL_FLOAT || e->x_sampling != 1 || e->y_sampling != 1) {
            res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                              "%s: node %d (bank index %s:%d): channel '%s' is %s%s; node channels are FLOAT at every "
                              "pixel", path, node->k, b->index_path, node->line, name,
                              e->pixel_type == EXR_PIXEL_HALF ? "HALF" : e->pixel_type == EXR_PIXEL_UINT ? "UINT" : "FLOAT",
                              e->x_sampling != 1 || e->y_sampling != 1 ? ", subsampled" : "");
            goto done;
        }
        seen[i] = 1;
    }
    for (i = 0; i < nw; i++)
        if (!seen[i]) {
            res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                              "%s: node %d (bank index %s:%d): no channel '%s' (the index's wavelength %.17g nm)", path,
                              node->k, b->index_path, node->line, names[i], b->values[AXIS_WAVELENGTH][i]);
            goto done;
        }
    // Decode every chunk, the spectral channels into their planes
    step = "decoding the pixels";
    if ((rv = exr_get_scanlines_per_chunk(ctxt, 0, &lines)) != EXR_ERR_SUCCESS) goto exr_failed;
    if (lines < 1) {
        rv = EXR_ERR_CORRUPT_CHUNK;
        goto exr_failed;
    }
    for (y = 0; y < h; y += lines) {
        exr_chunk_info_t chunk;
        if ((rv = exr_read_scanline_chunk_info(ctxt, 0, y, &chunk)) != EXR_ERR_SUCCESS) goto exr_failed;
        if (chunk.start_y < 0 || chunk.height < 1 || chunk.start_y + chunk.height > h) {
            rv = EXR_ERR_CORRUPT_CHUNK;
            goto exr_failed;
        }
        if (!decoder_live) {
            memset(&decoder, 0, sizeof decoder);
            if ((rv = exr_decoding_initialize(ctxt, 0, &chunk, &decoder)) != EXR_ERR_SUCCESS) goto exr_failed;
            decoder_live = 1;
        } else if ((rv = exr_decoding_update(ctxt, 0, &chunk, &decoder)) != EXR_ERR_SUCCESS) {
            goto exr_failed;
        }
        for (c = 0; c < decoder.channel_count; c++) {
            exr_coding_channel_info_t *ch = &decoder.channels[c];
            for (i = 0; i < nw && strcmp(ch->channel_name, names[i]) != 0; i++) continue;
            ch->decode_to_ptr = i < nw ? (uint8_t *)(node->image + (size_t)i * plane + (size_t)chunk.start_y * (size_t)w)
                                       : NULL;
            ch->user_pixel_stride = (int32_t)sizeof(float);
            ch->user_line_stride = (int32_t)(sizeof(float) * (size_t)w);
            ch->user_bytes_per_element = (int16_t)sizeof(float);
            ch->user_data_type = (uint16_t)EXR_PIXEL_FLOAT;
        }
        if (y == 0 && (rv = exr_decoding_choose_default_routines(ctxt, 0, &decoder)) != EXR_ERR_SUCCESS)
            goto exr_failed;
        if ((rv = exr_decoding_run(ctxt, 0, &decoder)) != EXR_ERR_SUCCESS) goto exr_failed;
    }
    // Every value finite and >= 0
    for (i = 0; i < nw; i++)
        for (p = 0; p < plane; p++) {
            const float v = node->image[(size_t)i * plane + p];
            if (!(isfinite(v) && v >= 0.0f)) {
                res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                                  "%s: node %d (bank index %s:%d): pixel (%d, %d) of channel '%s' is %g; node values are "
                                  "finite and >= 0", path, node->k, b->index_path, node->line, (int)(p % (size_t)w),
                                  (int)(p / (size_t)w), names[i], (double)v);
                goto done;
            }
        }
    goto done;

exr_failed:
    res = lensrt_fail(b->ctx, rv == EXR_ERR_OUT_OF_MEMORY ? LENSRT_ERROR_OUT_OF_MEMORY : LENSRT_ERROR_PARSE,
                      "%s: node %d (bank index %s:%d): not a readable EXR: %s failed: OpenEXRCore says %s (%s)", path,
                      node->k, b->index_path, node->line, step, exr_get_error_code_as_string(rv),
                      exr_get_default_error_message(rv));
done:
    if (decoder_live) exr_decoding_destroy(ctxt, &decoder);
    if (ctxt) exr_finish(&ctxt);
    lensrt_free(b->ctx, names);
    lensrt_free(b->ctx, seen);
    return res;
}

#endif /* LENSRT_EXR */

/* Read node's EXR: its bytes against the index's CRC-32, then its image. */
static lensrt_result read_node(lensrt_bank b, bank_node *node)
{
    char path[2 * BANK_PATH_SIZE];
    unsigned char *bytes = NULL;
    size_t size = 0;
    uint32_t crc;
    lensrt_result res;
    snprintf(path, sizeof path, "%s%s", b->folder, node->path);
    if ((res = lensrt_bank_read_whole(b->ctx, path, "node image (EXR)", &bytes, &size)) != LENSRT_SUCCESS) {
        char why[LENSRT_ERROR_SIZE];
        snprintf(why, sizeof why, "%s", lensrt_context_last_error(b->ctx));
        return lensrt_fail(b->ctx, res, "%s (node %d, bank index %s:%d)", why, node->k, b->index_path, node->line);
    }
    // The bytes the index was written with, before anything is decoded
    crc = lensrt_crc32(bytes, size);
    if (crc != node->crc) {
        res = lensrt_fail(b->ctx, LENSRT_ERROR_PARSE,
                          "%s: node %d (bank index %s:%d): the file's CRC-32 is %08x, the index says %08x: the EXR was "
                          "changed or damaged after the bank was written; refused", path, node->k, b->index_path,
                          node->line, (unsigned)crc, (unsigned)node->crc);
    } else {
#ifdef LENSRT_EXR
        res = decode_node(b, node, path, bytes, size);
#else
        res = lensrt_fail(b->ctx, LENSRT_ERROR_UNSUPPORTED,
                          "%s: node %d (bank index %s): this lensrt was built without OpenEXR (configure with "
                          "-DLENSRT_WITH_EXR=ON), so it cannot read a bank's node images", path, node->k, b->index_path);
#endif
    }
    lensrt_free(b->ctx, bytes);
    return res;
}

/* A node's EXR is there and is a regular file (its bytes are read on first use). */
lensrt_result lensrt_bank_stat_node(lensrt_bank b, const bank_node *node)
{
    char path[2 * BANK_PATH_SIZE];
    struct stat st;
    snprintf(path, sizeof path, "%s%s", b->folder, node->path);
    if (stat(path, &st) != 0)
        return lensrt_fail(b->ctx, LENSRT_ERROR_IO, "%s: cannot open node image (EXR): %s (node %d, bank index %s:%d)",
                           path, strerror(errno), node->k, b->index_path, node->line);
    if (!S_ISREG(st.st_mode))
        return lensrt_fail(b->ctx, LENSRT_ERROR_IO, "%s: not a regular file (node image (EXR)) (node %d, bank index %s:%d)",
                           path, node->k, b->index_path, node->line);
    return LENSRT_SUCCESS;
}

/* The node's image, read on its first use. */
lensrt_result lensrt_bank_need_node(lensrt_bank b, bank_node *node)
{
    lensrt_result res;
    if (node->image) return LENSRT_SUCCESS;
    if ((res = read_node(b, node)) != LENSRT_SUCCESS) {
        lensrt_free(b->ctx, node->image);
        node->image = NULL;
    }
    return res;
}
