/*
 * A fitted lens compiled into the program by lensrt_add_lens (from the installed CMake
 * package): its table and Horner code are part of the executable, nothing is read from
 * files. Loads it, prints its facts, and evaluates one ray through P_o both with the
 * compiled Horner function and with lensrt_lens_eval (which uses it for values); exits
 * non-zero unless the lens loads and the two agree.
 *
 * Built by examples/find_package/CMakeLists.txt when LENSRT_EXAMPLE_LENS names a lens
 * folder (generated/<lens>/ or a scene fit's generated/<lens>/scene-fits/<scene>/).
 */
#include <lensrt.h>

#include "example_lens.h" /* made by lensrt_add_lens(... SYMBOL example_lens) */

#include <math.h>
#include <stdio.h>
#include <string.h>

int main(void)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    lensrt_lens lens = NULL;
    lensrt_lens_info info = LENSRT_LENS_INFO_INIT;
    lensrt_eval_desc eval = LENSRT_EVAL_DESC_INIT;
    /* P_o inputs: a light on the axis at infinity, the stop centre, 550 nm */
    const double in[6] = {0.0, 0.0, 0.0, 0.0, 0.0, 550.0};
    double direct[4], through[4];
    int status = 1;
    lensrt_result res;

    if ((res = lensrt_context_create(&init, &ctx)) != LENSRT_SUCCESS) return 1;
    if ((res = lensrt_lens_load_compiled(ctx, &example_lens, &lens)) != LENSRT_SUCCESS ||
        (res = lensrt_lens_get_info(lens, &info)) != LENSRT_SUCCESS) {
        fprintf(stderr, "lensrt-example-compiled: %s: %s\n", lensrt_result_string(res),
                lensrt_context_last_error(ctx));
        goto done;
    }
    example_lens.object_d(in, direct);
    eval.system = LENSRT_SYSTEM_OBJECT;
    eval.type = LENSRT_TYPE_DOUBLE;
    eval.n_rays = 1;
    eval.inputs = in;
    eval.outputs = through;
    if ((res = lensrt_lens_eval(ctx, lens, &eval)) != LENSRT_SUCCESS) {
        fprintf(stderr, "lensrt-example-compiled: eval: %s: %s\n", lensrt_result_string(res),
                lensrt_context_last_error(ctx));
        goto done;
    }
    printf("compiled-in %s (%s, %zu bytes of table): f = %.3f mm, f/%.2f; chief ray at 550 nm: "
           "tau_o %.6f, phi_o %.6f mm\n", example_lens.name, info.name, example_lens.table_size,
           info.focal_length_mm, info.f_number_min, direct[2], direct[3]);
    /* Inputs inside the domain: finite outputs, and eval gives the Horner values */
    if (isfinite(direct[3]) && direct[2] > 0.0 && memcmp(direct, through, sizeof direct) == 0) {
        status = 0;
    } else {
        fprintf(stderr, "lensrt-example-compiled: the Horner values and lensrt_lens_eval disagree\n");
    }
done:
    lensrt_lens_destroy(ctx, lens);
    lensrt_context_destroy(ctx);
    return status;
}
