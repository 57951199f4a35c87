/* libFuzzer target: coefficient tables (lensrt_lens_load_text) from arbitrary bytes.
 * Any result code is fine; a crash, leak or sanitizer report is a defect. */
#include <stddef.h>
#include <stdint.h>
#include "lensrt.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    lensrt_lens lens = NULL;
    /* A context with one thread and no log */
    init.threads = 1;
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) return 0;
    /* Parse; destroy the lens when the table was accepted */
    if (lensrt_lens_load_text(ctx, (const char *)data, size, "fuzz.table", &lens) == LENSRT_SUCCESS)
        lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    return 0;
}
