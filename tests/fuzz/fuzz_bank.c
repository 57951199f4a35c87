/* libFuzzer target: PSF bank indexes (lensrt_bank_open) from arbitrary bytes. Any result
 * code is fine; a crash, leak or sanitizer report is a defect.
 *
 * The input is written as <dir>/bank.index in a folder of its own, next to two node files
 * (nodes/n0.exr, nodes/n1.exr, fixed bytes that the seed index names with their CRC-32),
 * and opened twice: as given (the checksum line and what comes before it), and stamped,
 * its last line replaced by the checksum of the rest as a bank writer would write it, so
 * that mutations reach the index parser and the node checks rather than stopping at the
 * checksum. The fuzz build has no OpenEXR: a bank whose index passes opens (its nodes are
 * read on first use), and a query and lensrt_bank_load_nodes then end, for node files that
 * match their CRCs, in LENSRT_ERROR_UNSUPPORTED. */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "lensrt.h"
#include "../../runtime/src/core/crc32.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* The node files' bytes (CRC-32 c81e6737, which tests/fuzz/seeds/bank/ names) */
static const char NODE_BYTES[] = "lensrt fuzz node\n";

/* The fuzzer's folder, made on the first input: mkdtemp under $TMPDIR or /tmp. */
static const char *bank_folder(void)
{
    static char dir[4096];
    char path[4200];
    const char *tmp = getenv("TMPDIR");
    int k;
    if (dir[0]) return dir;
    snprintf(dir, sizeof dir, "%s/lensrt-fuzz-bank-XXXXXX", tmp && tmp[0] ? tmp : "/tmp");
    if (!mkdtemp(dir)) abort();
    snprintf(path, sizeof path, "%s/nodes", dir);
    if (mkdir(path, 0700) != 0) abort();
    for (k = 0; k < 2; k++) {
        FILE *f;
        snprintf(path, sizeof path, "%s/nodes/n%d.exr", dir, k);
        if (!(f = fopen(path, "wb")) || fwrite(NODE_BYTES, 1, sizeof NODE_BYTES - 1, f) != sizeof NODE_BYTES - 1)
            abort();
        fclose(f);
    }
    return dir;
}

/* Write the index and open it; a bank that opens is queried once and closed. */
static void open_index(lensrt_context ctx, const char *path, const void *text, size_t size)
{
    FILE *f = fopen(path, "wb");
    lensrt_bank bank = NULL;
    if (!f) abort();
    if (size && fwrite(text, 1, size, f) != size) abort();
    fclose(f);
    if (lensrt_bank_open(ctx, path, &bank) == LENSRT_SUCCESS) {
        lensrt_bank_info info = LENSRT_BANK_INFO_INIT;
        lensrt_bank_query q = LENSRT_BANK_QUERY_INIT;
        float *psf;
        if (lensrt_bank_get_info(bank, &info) != LENSRT_SUCCESS) abort();
        // Nodes are read on first use: a query at the grid's first values (its chief
        // point interpolated over the index's nodes), then every node
        q.field_x_deg = info.field_x_deg[0];
        q.field_y_deg = info.field_y_deg[0];
        q.wavelength_nm = info.wavelengths_nm[0];
        q.f_number = info.f_numbers[0];
        q.focus_offset_mm = info.focus_offsets_mm[0];
        q.distance_mm = info.distances_mm[0];
        if ((size_t)info.width * (size_t)info.height <= ((size_t)1 << 20) &&
            (psf = malloc(sizeof(float) * (size_t)info.width * (size_t)info.height)) != NULL) {
            (void)lensrt_bank_psf(bank, &q, psf, (size_t)info.width * (size_t)info.height, NULL);
            free(psf);
        }
        (void)lensrt_bank_load_nodes(bank);
        lensrt_bank_close(bank);
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    char path[4200], *stamped;
    size_t body = size, n;
    snprintf(path, sizeof path, "%s/bank.index", bank_folder());
    /* A context with one thread and no log */
    init.threads = 1;
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) return 0;
    open_index(ctx, path, data, size);
    /* The body: up to the last line (the checksum line of an index), then stamped */
    if (body > 0 && data[body - 1] == '\n') body--;
    while (body > 0 && data[body - 1] != '\n') body--;
    stamped = malloc(body + 32);
    if (stamped) {
        memcpy(stamped, data, body);
        n = body + (size_t)sprintf(stamped + body, "checksum crc32 %08x\n", (unsigned)lensrt_crc32(data, body));
        open_index(ctx, path, stamped, n);
        free(stamped);
    }
    lensrt_context_destroy(ctx);
    return 0;
}
