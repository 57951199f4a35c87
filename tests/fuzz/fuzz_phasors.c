/* libFuzzer target: phasor-sum files (lensrt_render_load and lensrt_render_merge) from
 * arbitrary bytes, written to a temporary file in /tmp that is removed afterwards.
 *
 * A mutated file almost never matches its checksum, so the readers would stop there and
 * the checks behind it (counts, runs, sums) would go unfuzzed. Each input is therefore
 * read twice: as it is (the checksum check itself), and with its checksum recomputed the
 * way the writer computes it (io/phasor_file.c, format `lensrt-phasors 2`: FNV-1a 64 over
 * the whole file with the u64 checksum field, at byte 88 of the 96-byte header, zero). */
#define _POSIX_C_SOURCE 200809L
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* The header's layout (io/phasor_file.c): magic[16], u32 version, u32 marker, u64 scene,
 * seed, samples, splats, f64 seconds, i32 x 6, u64 checksum. */
#define CHECKSUM_AT 88u
#define HEADER_SIZE 96u

/* FNV-1a 64, as the phasor file's writer and reader compute it. */
static uint64_t fnv1a64(const uint8_t *p, size_t n)
{
    uint64_t h = 0xcbf29ce484222325ULL;
    size_t i;
    for (i = 0; i < n; i++) h = (h ^ p[i]) * 0x100000001b3ULL;
    return h;
}

/* Load (replace) the file at `path` into a fresh render, then merge (add) it into another. */
static void read_both_ways(const char *path)
{
    lensrt_context ctx;
    lensrt_lens lens;
    lensrt_render render;
    if (fuzz_make_render(&ctx, &lens, &render) != LENSRT_SUCCESS) abort();
    (void)lensrt_render_load(render, path);
    fuzz_free_render(ctx, lens, render);
    if (fuzz_make_render(&ctx, &lens, &render) != LENSRT_SUCCESS) abort();
    (void)lensrt_render_merge(render, path);
    fuzz_free_render(ctx, lens, render);
}

static void write_file(const char *path, const uint8_t *data, size_t size)
{
    FILE *f = fopen(path, "wb");
    if (!f) abort();
    if (size && fwrite(data, 1, size, f) != size) abort();
    if (fclose(f) != 0) abort();
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[] = "/tmp/lensrt-fuzz-XXXXXX";
    int fd = mkstemp(path);
    if (fd < 0) abort();
    close(fd);
    /* 1. The bytes as they are */
    write_file(path, data, size);
    read_both_ways(path);
    /* 2. The same bytes with a valid checksum, to reach the checks behind it */
    if (size >= HEADER_SIZE) {
        uint8_t *copy = malloc(size);
        uint64_t sum;
        if (!copy) abort();
        memcpy(copy, data, size);
        memset(copy + CHECKSUM_AT, 0, 8);
        sum = fnv1a64(copy, size);
        memcpy(copy + CHECKSUM_AT, &sum, 8); /* native byte order, as the writer stores it */
        write_file(path, copy, size);
        free(copy);
        read_both_ways(path);
    }
    unlink(path);
    return 0;
}
