/* libFuzzer target: coefficient tables (lensrt_lens_load_text) from arbitrary bytes, then
 * a tiny render of every table that loads. Any result code is fine; a crash, leak,
 * sanitizer report or a NaN in an image is a defect.
 *
 * Each input is parsed up to three times: as given (the checksum check of version 5 and what
 * comes before it); stamped, its last line replaced by the checksum of the rest as
 * lensfit would write it (issue 25), so that mutations reach the parser rather than
 * stopping at the checksum: crafted tables behind a valid checksum, which the probe
 * lines must refuse when they change a coefficient (issue 39); and, when that does not
 * load, with each system's probe lines made again too (tests/runtime/check.h,
 * stamp_table), so that mutations of the coefficients reach the renderers. The library is linked statically, so its
 * own CRC-32 (core/crc32.h) stamps. */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lensrt.h"
#include "../../runtime/src/core/crc32.h"
#include "../runtime/check.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* A render of 4 x 4 pixels, one wavelength over the lens's range, the default light:
 * Monte Carlo (16 samples) and the cells integrator (2 rings), each image checked. */
static void render_tiny(lensrt_context ctx, lensrt_lens lens)
{
    int integrator;
    for (integrator = 0; integrator < 2; integrator++) {
        lensrt_render_desc desc = LENSRT_RENDER_DESC_INIT;
        lensrt_render render = NULL;
        float image[16];
        size_t k;
        lensrt_result res;
        desc.lens = lens;
        desc.sensor.width = 4;
        desc.sensor.height = 4;
        desc.sensor.width_mm = 0.05;
        desc.n_wavelengths = 1;
        if (lensrt_render_create(ctx, &desc, &render) != LENSRT_SUCCESS) return;
        res = integrator ? lensrt_render_integrate(render, 2, NULL, NULL, NULL)
                         : lensrt_render_run(render, 16, NULL, NULL);
        if (res == LENSRT_SUCCESS && lensrt_render_image(render, image, 16) == LENSRT_SUCCESS)
            for (k = 0; k < 16; k++)
                if (!isfinite(image[k]) || image[k] < 0.0f) {
                    fprintf(stderr, "fuzz_table: pixel %zu is %g\n", k, (double)image[k]);
                    abort();
                }
        lensrt_render_destroy(render);
    }
}

/* Whether the text loaded (then rendered). */
static int load_and_render(lensrt_context ctx, const char *text, size_t size)
{
    lensrt_lens lens = NULL;
    if (lensrt_lens_load_text(ctx, text, size, "fuzz.table", &lens) != LENSRT_SUCCESS) return 0;
    render_tiny(ctx, lens);
    lensrt_lens_destroy(ctx, lens);
    return 1;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    char *stamped, *reprobed;
    size_t body = size, n = 0, m = 0;
    int loaded = 0;
    /* A context with one thread and no log */
    init.threads = 1;
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) return 0;
    load_and_render(ctx, (const char *)data, size);
    /* The body: up to the last line (the checksum line of a table), then stamped */
    if (body > 0 && data[body - 1] == '\n') body--;
    while (body > 0 && data[body - 1] != '\n') body--;
    stamped = malloc(body + 32);
    if (stamped) {
        memcpy(stamped, data, body);
        n = body + (size_t)sprintf(stamped + body, "checksum crc32 %08x\n", (unsigned)lensrt_crc32(data, body));
        loaded = load_and_render(ctx, stamped, n);
        free(stamped);
    }
    /* Probes made again (and the checksum), when the stamped text did not load (the
     * renders of a valid table, the seeds, are the slow part) */
    reprobed = loaded ? NULL : stamp_table((const char *)data, body, &m);
    if (reprobed) load_and_render(ctx, reprobed, m);
    free(reprobed);
    lensrt_context_destroy(ctx);
    return 0;
}
