/* Lenses of every kind: destruction, information and input normalisation (which kind a
 * lens is: lens/kind.c). */
#include "lens.h"

static void free_system(lensrt_context ctx, lensrt_system *sys)
{
    int k;
    for (k = 0; k < 8; k++) {
        lensrt_free(ctx, sys->outputs[k].exponents);
        lensrt_free(ctx, sys->outputs[k].coefficients);
    }
}

void lensrt_lens_destroy(lensrt_context ctx, lensrt_lens lens)
{
    if (!lens) return;
    (void)ctx;
    ctx = lens->ctx; /* the context that allocated it */
    free_system(ctx, &lens->p_o);
    free_system(ctx, &lens->p_s);
    free_system(ctx, &lens->p_clip);
    lensrt_free(ctx, lens);
}

lensrt_result lensrt_lens_get_info(lensrt_lens lens, lensrt_lens_info *out)
{
    // A lens is shared between threads: no message is recorded in its context
    if (!lens || !out) return LENSRT_ERROR_INVALID_ARGUMENT;
    return lensrt_struct_out(NULL, "lensrt_lens_info", out, &lens->info, sizeof lens->info);
}

double lensrt_normalise(const lensrt_input *in, double v)
{
    double w = in->transform == LENSRT_TRANSFORM_INVERSE_SQUARE ? 1.0 / (v * v) : v;
    return (w - in->c) / in->s;
}
