/* Seed corpus for fuzz_phasors: the phasor sums of the fuzz render after a short run
 * (argv[1]) and of a fresh one (argv[2]), saved with lensrt_render_save. */
#include <stdio.h>
#include "fuzz_common.h"

int main(int argc, char **argv)
{
    lensrt_context ctx;
    lensrt_lens lens;
    lensrt_render render;
    if (argc != 3) { fprintf(stderr, "usage: fuzz_seed RUN.phasors EMPTY.phasors\n"); return 2; }
    if (fuzz_make_render(&ctx, &lens, &render) != LENSRT_SUCCESS) { fprintf(stderr, "fuzz_seed: render: %s\n", lensrt_context_last_error(ctx)); return 1; }
    if (lensrt_render_save(render, argv[2]) != LENSRT_SUCCESS
        || lensrt_render_run(render, 256, NULL, NULL) != LENSRT_SUCCESS
        || lensrt_render_save(render, argv[1]) != LENSRT_SUCCESS) {
        fprintf(stderr, "fuzz_seed: %s\n", lensrt_context_last_error(ctx));
        return 1;
    }
    fuzz_free_render(ctx, lens, render);
    return 0;
}
