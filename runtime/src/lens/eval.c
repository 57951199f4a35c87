/* Per-ray evaluation of a lens's fitted systems (lensrt_lens_eval) and their description
 * (lensrt_lens_system_info), for a renderer's own rays.
 *
 * A system's output is sum_t c_t prod_i xhat_i^e_ti over its terms, xhat_i the normalised
 * input i (lens/table.c, lensrt_normalise). Rays are evaluated in blocks of BLOCK: per
 * block, the powers xhat^0 .. xhat^LENSRT_MAX_DEGREE of every input are tabulated once,
 * ray index innermost, and each term is then one pass over the block's rays, which the
 * compiler vectorises (the rays of a block share the term's exponents). The fits write
 * terms in runs that share the exponents of the field inputs (a field monomial F, then its
 * stop monomials), so a run is summed as F (sum_t c_t x_a^e y_a^f): two multiplications and
 * an addition per term and ray. Jacobians come from the same tables, e xhat^(e-1) being
 * e times the power below. A block's last rays (a batch that is not a multiple of BLOCK)
 * go LANES at a time. A ray's arithmetic does not depend on the block or lane it falls in,
 * nor on whether Jacobians are asked for: values are the same bits either way.
 *
 * Numbers: inputs, outputs and Jacobians are double or float in the caller's memory; the
 * sums are always done in double. A float sum of the 17031 phase terms would lose about
 * sqrt(17031) float ulps of phi (~100 mm), a few nanometres, while double costs the same
 * per term here and gives float outputs correctly rounded but for the double sum's own
 * error (~1e-14 relative). The float type is about the caller's memory layout, not speed.
 * Compiled-in lenses (lensrt_lens_load_compiled) evaluate the values of batches shorter
 * than a block (BLOCK rays) through their generated Horner code instead (float in float),
 * which is 10x faster for one ray and 2x slower per ray for long batches; the two agree
 * within rounding (tests/runtime/test_compiled.c), and which is used depends only on
 * the batch's length.
 *
 * No allocation (about 30 KB of stack), no writes to the lens: a lens may be evaluated
 * from any number of threads at once. */
#include "../internal.h"

#include <math.h>
#include <stddef.h>
#include <string.h>

#define BLOCK 32                         /* rays per block */
#define LANES 4                          /* a short block is summed in multiples of this */
#define POWERS (LENSRT_MAX_DEGREE + 1)   /* xhat^0 .. xhat^LENSRT_MAX_DEGREE */
#define N_IN 6                           /* inputs of every system lensrt loads */

/* The oldest struct layouts that have these functions (lensrt 0.2): a smaller
 * struct_size is not a struct of this API. */
#define EVAL_DESC_MIN_SIZE (offsetof(lensrt_eval_desc, jacobians) + sizeof(void *))
#define SYSTEM_INFO_MIN_SIZE (offsetof(lensrt_system_info, n_terms) + \
                              sizeof(int32_t) * LENSRT_MAX_SYSTEM_OUTPUTS)

#define STOP_X 3                         /* x_a, y_a: the inputs of the stop monomials */
#define STOP_Y 4

/* One block of rays: the power tables of its normalised inputs. */
typedef struct block {
    double pw[N_IN][POWERS][BLOCK];   /* xhat_i^e */
    double dxdv[N_IN][BLOCK];         /* d xhat_i / d raw input i */
} block;

/* P_o, P_s, or a ghost table's P_clip (NULL when the lens has none). */
static const lensrt_system *system_of(lensrt_lens lens, int32_t system)
{
    if (system == LENSRT_SYSTEM_CLIP) return lens->p_clip.n_outputs ? &lens->p_clip : NULL;
    return system == LENSRT_SYSTEM_OBJECT ? &lens->p_o : system == LENSRT_SYSTEM_SENSOR ? &lens->p_s : NULL;
}

/* ------------------------------------------------------------ system info ----- */

lensrt_result lensrt_lens_system_info(lensrt_lens lens, int32_t system, lensrt_system_info *out)
{
    lensrt_system_info info;
    const lensrt_system *sys;
    size_t size;
    int i;
    if (!lens || !out) return LENSRT_ERROR_INVALID_ARGUMENT;
    memcpy(&size, out, sizeof size);
    if (size < SYSTEM_INFO_MIN_SIZE) return LENSRT_ERROR_INVALID_ARGUMENT;
    if (system != LENSRT_SYSTEM_OBJECT && system != LENSRT_SYSTEM_SENSOR && system != LENSRT_SYSTEM_CLIP)
        return LENSRT_ERROR_INVALID_ARGUMENT;
    if (lens->analytic) return LENSRT_ERROR_UNSUPPORTED;
    if (!(sys = system_of(lens, system))) return LENSRT_ERROR_UNSUPPORTED; /* no P_clip */
    // Build the whole struct here, then copy what the caller's struct_size covers
    memset(&info, 0, sizeof info);
    info.struct_size = sizeof info;
    info.n_inputs = sys->n_inputs;
    info.n_outputs = sys->n_outputs;
    for (i = 0; i < sys->n_inputs && i < LENSRT_MAX_SYSTEM_INPUTS; i++) {
        info.input_names[i] = sys->inputs[i].name;
        info.input_min[i] = sys->inputs[i].lo;
        info.input_max[i] = sys->inputs[i].hi;
    }
    for (i = 0; i < sys->n_outputs && i < LENSRT_MAX_SYSTEM_OUTPUTS; i++) {
        info.output_names[i] = sys->outputs[i].name;
        info.n_terms[i] = sys->outputs[i].n_terms;
    }
    return lensrt_struct_out(NULL, "lensrt_system_info", out, &info, sizeof info);
}

/* ------------------------------------------------------------ power tables ----- */

/* Raw input i of ray k (of the caller's type) as a double. */
static double raw_input(const void *inputs, int is_float, size_t k, int i)
{
    size_t at = k * N_IN + (size_t)i;
    return is_float ? (double)((const float *)inputs)[at] : ((const double *)inputs)[at];
}

/* Fill the tables of rays first .. first + n - 1 (n <= BLOCK); lanes n .. BLOCK - 1 get
 * xhat = 0 so that every lane holds finite numbers (they are never stored). */
static void fill_block(block *b, const lensrt_system *sys, const void *inputs, int is_float, size_t first,
                       int n)
{
    int i, r, e;
    for (i = 0; i < N_IN; i++) {
        const lensrt_input *in = &sys->inputs[i];
        for (r = 0; r < BLOCK; r++) {
            double v = r < n ? raw_input(inputs, is_float, first + (size_t)r, i) : 0.0;
            double x = 0.0, d = 0.0;
            // xhat = (w - c) / s with w = v (affine) or 1/v^2 (inverse_square), and its
            // derivative 1/s or d/dv (1/v^2 - c)/s = -2/(s v^3)
            if (r < n) {
                x = lensrt_normalise(in, v);
                d = in->transform == LENSRT_TRANSFORM_INVERSE_SQUARE ? -2.0 / (in->s * v * v * v) : 1.0 / in->s;
            }
            b->pw[i][0][r] = 1.0;
            for (e = 1; e < POWERS; e++) b->pw[i][e][r] = b->pw[i][e - 1][r] * x;
            b->dxdv[i][r] = d;
        }
    }
}

/* ------------------------------------------------------------------- sums ----- */

/* A run is a stretch of consecutive terms with the same exponents of the field inputs
 * (x_S, y_S, z_S, lambda or x_O, y_O, u_O, lambda): the fits write each field monomial's
 * stop monomials together, about 17 terms per run for the phase. Whether term exponents
 * e have the same field exponents as r. */
static int same_field(const unsigned char *e, const unsigned char *r)
{
    return e[0] == r[0] && e[1] == r[1] && e[2] == r[2] && e[5] == r[5];
}

/* The sums for a whole block, and for LANES rays at a time (the end of a batch). */
#define W BLOCK
#define SUM_VALUES sum_values_block
#define SUM_GRADIENTS sum_gradients_block
#include "eval_sums.h"
#undef W
#undef SUM_VALUES
#undef SUM_GRADIENTS
#define W LANES
#define SUM_VALUES sum_values_lanes
#define SUM_GRADIENTS sum_gradients_lanes
#include "eval_sums.h"
#undef W
#undef SUM_VALUES
#undef SUM_GRADIENTS

static void store(void *dst, int is_float, size_t at, double v)
{
    if (is_float) ((float *)dst)[at] = (float)v;
    else ((double *)dst)[at] = v;
}

/* ----------------------------------------------------------------- checks ----- */

static lensrt_result check_inputs(lensrt_context ctx, const lensrt_system *sys, const void *inputs, int is_float,
                                  size_t n_rays)
{
    size_t k;
    int i;
    for (k = 0; k < n_rays; k++)
        for (i = 0; i < N_IN; i++) {
            double v = raw_input(inputs, is_float, k, i);
            if (!isfinite(v))
                return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                                   "lensrt_lens_eval: %s ray %zu: input %s is %g (not a finite number); "
                                   "nothing was written", sys->name, k, sys->inputs[i].name, v);
            if (sys->inputs[i].transform == LENSRT_TRANSFORM_INVERSE_SQUARE && !(v > 0))
                return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                                   "lensrt_lens_eval: %s ray %zu: input %s is %g; it must be > 0 (fitted over "
                                   "[%g, %g]); nothing was written", sys->name, k, sys->inputs[i].name, v,
                                   sys->inputs[i].lo, sys->inputs[i].hi);
        }
    return LENSRT_SUCCESS;
}

/* Far outside the fitted domain a polynomial overflows (inputs of 1e100, a wavelength
 * of 1e-300 whose 1 / lambda^2 is inf, values beyond float): no NaN or inf leaves the
 * library. A batch with a non-finite output or Jacobian entry fails as a whole, its
 * outputs and Jacobians zeroed, naming the ray, the output and the input farthest from
 * its fitted range (in units of that range). */
static lensrt_result check_outputs(lensrt_context ctx, const lensrt_system *sys, const lensrt_eval_desc *d)
{
    const int is_float = d->type == LENSRT_TYPE_FLOAT;
    const size_t n_out = (size_t)sys->n_outputs, n_val = d->n_rays * n_out;
    const size_t size = is_float ? sizeof(float) : sizeof(double);
    size_t at, bad = (size_t)-1, k;
    int i, far = 0;
    double worst = -1.0;
    for (at = 0; at < n_val && bad == (size_t)-1; at++)
        if (!isfinite(is_float ? (double)((const float *)d->outputs)[at] : ((const double *)d->outputs)[at])) bad = at;
    for (at = 0; d->jacobians && at < n_val * N_IN && bad == (size_t)-1; at++)
        if (!isfinite(is_float ? (double)((const float *)d->jacobians)[at] : ((const double *)d->jacobians)[at]))
            bad = (at / N_IN);
    if (bad == (size_t)-1) return LENSRT_SUCCESS;
    k = bad / n_out;
    for (i = 0; i < N_IN; i++) {
        const lensrt_input *in = &sys->inputs[i];
        const double v = raw_input(d->inputs, is_float, k, i), span = in->hi > in->lo ? in->hi - in->lo : 1.0;
        const double out = v < in->lo ? (in->lo - v) / span : v > in->hi ? (v - in->hi) / span : 0.0;
        if (out > worst) {
            worst = out;
            far = i;
        }
    }
    memset(d->outputs, 0, n_val * size);
    if (d->jacobians) memset(d->jacobians, 0, n_val * N_IN * size);
    return lensrt_fail(ctx, LENSRT_ERROR_OUT_OF_DOMAIN,
                       "lensrt_lens_eval: %s ray %zu: output %s is not finite in %s: input %s = %g is outside its "
                       "fitted range [%g, %g]; the batch's outputs were zeroed", sys->name, k,
                       sys->outputs[bad % n_out].name, is_float ? "float" : "double", sys->inputs[far].name,
                       raw_input(d->inputs, is_float, k, far), sys->inputs[far].lo, sys->inputs[far].hi);
}

/* ------------------------------------------------------------- evaluation ----- */

lensrt_result lensrt_lens_eval(lensrt_context ctx, lensrt_lens lens, const lensrt_eval_desc *desc_in)
{
    lensrt_eval_desc d;
    const lensrt_system *sys;
    lensrt_horner_d horner_d = NULL;
    lensrt_horner_f horner_f = NULL;
    lensrt_result res;
    size_t size, k, n_out, per_ray;
    int is_float;
    // The descriptor: at least the 0.2 layout, newer fields this library does not know zero
    if (!lens || !desc_in)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_lens_eval: %s is NULL", lens ? "desc" : "lens");
    memcpy(&size, desc_in, sizeof size);
    if (size < EVAL_DESC_MIN_SIZE)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "lensrt_eval_desc: struct_size is %zu, expected at least %zu (use LENSRT_EVAL_DESC_INIT)",
                           size, (size_t)EVAL_DESC_MIN_SIZE);
    if ((res = lensrt_struct_in(ctx, "lensrt_eval_desc", desc_in, &d, sizeof d)) != LENSRT_SUCCESS) return res;
    if (d.system != LENSRT_SYSTEM_OBJECT && d.system != LENSRT_SYSTEM_SENSOR && d.system != LENSRT_SYSTEM_CLIP)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "lensrt_eval_desc: system is %d, expected LENSRT_SYSTEM_OBJECT (0), LENSRT_SYSTEM_SENSOR (1) "
                           "or LENSRT_SYSTEM_CLIP (2)", (int)d.system);
    if (d.type != LENSRT_TYPE_DOUBLE && d.type != LENSRT_TYPE_FLOAT)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "lensrt_eval_desc: type is %d, expected LENSRT_TYPE_DOUBLE (0) or LENSRT_TYPE_FLOAT (1)",
                           (int)d.type);
    if (lens->analytic)
        return lensrt_fail(ctx, LENSRT_ERROR_UNSUPPORTED,
                           "lensrt_lens_eval: %s is an analytic lens; it has no fitted systems", lens->name);
    if (!(sys = system_of(lens, d.system)))
        return lensrt_fail(ctx, LENSRT_ERROR_UNSUPPORTED, "lensrt_lens_eval: %s (%s) has no system P_clip (a ghost "
                           "table's clip tests; info.ghost_clip_pairs is 0)", lens->file, lens->name);
    if (sys->n_inputs != N_IN || sys->n_outputs > LENSRT_MAX_SYSTEM_OUTPUTS)
        return lensrt_fail(ctx, LENSRT_ERROR_UNSUPPORTED, "lensrt_lens_eval: %s of %s has %d inputs (expected %d)",
                           sys->name, lens->name, sys->n_inputs, N_IN);
    n_out = (size_t)sys->n_outputs;
    per_ray = n_out * (N_IN + 1) * sizeof(double);
    if (d.n_rays > (size_t)-1 / per_ray)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_eval_desc: n_rays %zu is too large", d.n_rays);
    if (d.n_rays == 0) return LENSRT_SUCCESS;
    if (!d.inputs || !d.outputs)
        return lensrt_fail(ctx, LENSRT_ERROR_INVALID_ARGUMENT, "lensrt_eval_desc: %s is NULL with n_rays %zu",
                           d.inputs ? "outputs" : "inputs", d.n_rays);
    is_float = d.type == LENSRT_TYPE_FLOAT;
    // Every input is checked before anything is written
    if ((res = check_inputs(ctx, sys, d.inputs, is_float, d.n_rays)) != LENSRT_SUCCESS) return res;

    // Values only of fewer rays than a block, of a compiled-in lens: its generated Horner
    // code, one ray at a time. Measured on 0001 (P_s, one thread): Horner 5.6-7.5 us per
    // ray at any batch size; the table 73 us for one ray (a block's set-up and every
    // term's pass are paid whatever the count), 17 us per ray at 8, 2.9 us at 256
    if (lens->compiled && !d.jacobians && d.n_rays < BLOCK && d.system != LENSRT_SYSTEM_CLIP) {
        const lensrt_compiled_lens *c = lens->compiled;
        horner_d = d.system == LENSRT_SYSTEM_OBJECT ? c->object_d : c->sensor_d;
        horner_f = d.system == LENSRT_SYSTEM_OBJECT ? c->object_f : c->sensor_f;
        if (!is_float && horner_d) {
            for (k = 0; k < d.n_rays; k++)
                horner_d((const double *)d.inputs + k * N_IN, (double *)d.outputs + k * n_out);
            return check_outputs(ctx, sys, &d);
        }
        if (is_float && horner_f) {
            for (k = 0; k < d.n_rays; k++)
                horner_f((const float *)d.inputs + k * N_IN, (float *)d.outputs + k * n_out);
            return check_outputs(ctx, sys, &d);
        }
    }

    // The table, block by block; a block's last rays LANES at a time
    for (k = 0; k < d.n_rays; k += BLOCK) {
        block b;
        double v[BLOCK], g[N_IN][BLOCK];
        int n = d.n_rays - k < BLOCK ? (int)(d.n_rays - k) : BLOCK, o, r, i, l;
        fill_block(&b, sys, d.inputs, is_float, k, n);
        for (o = 0; o < sys->n_outputs; o++) {
            const lensrt_poly *p = &sys->outputs[o];
            if (n == BLOCK) {
                if (d.jacobians) sum_gradients_block(&b, 0, p, v, g);
                else sum_values_block(&b, 0, p, v);
            } else {
                for (l = 0; l < n; l += LANES) {
                    if (d.jacobians) sum_gradients_lanes(&b, l, p, v + l, g);
                    else sum_values_lanes(&b, l, p, v + l);
                }
            }
            // Chain rule through the normalisation: d out / d raw = d out / d xhat * d xhat / d raw
            if (d.jacobians)
                for (r = 0; r < n; r++)
                    for (i = 0; i < N_IN; i++)
                        store(d.jacobians, is_float, ((k + (size_t)r) * n_out + (size_t)o) * N_IN + (size_t)i,
                              g[i][r] * b.dxdv[i][r]);
            for (r = 0; r < n; r++) store(d.outputs, is_float, (k + (size_t)r) * n_out + (size_t)o, v[r]);
        }
    }
    return check_outputs(ctx, sys, &d);
}
