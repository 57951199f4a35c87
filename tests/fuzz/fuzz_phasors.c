/* libFuzzer target: phasor-sum files (lensrt_render_load and lensrt_render_merge) from
 * arbitrary bytes, written to a temporary file in /tmp that is removed afterwards. */
#define _POSIX_C_SOURCE 200809L
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>
#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[] = "/tmp/lensrt-fuzz-XXXXXX";
    lensrt_context ctx;
    lensrt_lens lens;
    lensrt_render render;
    size_t done = 0;
    int fd;
    /* The bytes into a temporary file */
    fd = mkstemp(path);
    if (fd < 0) abort();
    while (done < size) {
        ssize_t n = write(fd, data + done, size - done);
        if (n <= 0) abort();
        done += (size_t)n;
    }
    close(fd);
    /* Load (replace) into a fresh render, then merge (add) into another */
    if (fuzz_make_render(&ctx, &lens, &render) != LENSRT_SUCCESS) abort();
    (void)lensrt_render_load(render, path);
    fuzz_free_render(ctx, lens, render);
    if (fuzz_make_render(&ctx, &lens, &render) != LENSRT_SUCCESS) abort();
    (void)lensrt_render_merge(render, path);
    fuzz_free_render(ctx, lens, render);
    unlink(path);
    return 0;
}
