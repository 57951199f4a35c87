/*
 * test_compiled: compiled-in lenses (lensrt_lens_load_compiled, lensrt_add_lens).
 *
 *   test_compiled LENS_TABLE
 *
 * The build links the lens of LENS_TABLE into this program with lensrt_add_lens
 * (cmake/lensrt_add_lens.cmake) as lensrt_lens_0001_demo: the scene fit
 * generated/0001-angenieux-double-gauss/scene-fits/demo/ (0.5 MB of C, about 1 s to
 * compile at -O0 and 5 s at -O3). Checks:
 *   1. the compiled lens and lensrt_lens_load of the same table file describe the same
 *      lens, and render the same image bit for bit (renders read only coefficients);
 *   2. per ray, lensrt_lens_eval of the compiled lens (the generated Horner code) agrees
 *      with the table's sums within the rounding of a different evaluation order, in
 *      double and in float; Jacobians come from the table on both;
 *   3. malformed structs are refused with messages.
 * Prints the measured differences; returns non-zero if any check failed.
 */
#include "lensrt.h"
#include "lensrt_lens_0001_demo.h"

#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define RAYS 4096         /* random rays per system */
#define N_IN 6            /* inputs of P_o and P_s */
#define N_OUT 4           /* outputs of P_o and P_s */
#define MAX_EXP 64        /* exponents this test's table reader accepts */

/* ------------------------------------------------------------- harness ----- */

#include "check.h"

static uint64_t splitmix64(uint64_t *state)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}
static double uniform01(uint64_t *state) { return (double)(splitmix64(state) >> 11) * (1.0 / 9007199254740992.0); }

/* ---------------------------------------------- the table, read independently ----- */

/* What the rounding bounds need of one output, from the table's terms: the sum of
 * |coefficient| (every monomial of normalised inputs is at most 1 in magnitude inside
 * the domain, so it bounds the sum of |term|), the term count, the highest exponent of
 * each input and the highest total degree. */
typedef struct output_facts {
    double abs_sum;
    int n_terms, max_exp[N_IN], degree;
} output_facts;

/* Read the systems' output facts from the table text (format: fit/lensfit/codegen/table.py:
 * `system <name> <n_in> <n_out>`, `input ...` lines, then per output
 * `output <name> <unit> <n_terms>` and n_terms lines of n_in exponents and a coefficient). */
static int read_facts(const char *path, output_facts facts[2][N_OUT])
{
    FILE *f = fopen(path, "r");
    char line[4096], name[64];
    int system = -1, output = -1, left = 0, ok = 1;
    memset(facts, 0, sizeof(output_facts) * 2 * N_OUT);
    if (!f) return 0;
    while (ok && fgets(line, sizeof line, f)) {
        int n_in, n_out, n, e[N_IN], i, degree = 0;
        double c;
        if (left > 0) {
            output_facts *o = &facts[system][output];
            ok = sscanf(line, "%d %d %d %d %d %d %lf", &e[0], &e[1], &e[2], &e[3], &e[4], &e[5], &c) == 7;
            for (i = 0; ok && i < N_IN; i++) {
                ok = e[i] >= 0 && e[i] <= MAX_EXP;
                if (e[i] > o->max_exp[i]) o->max_exp[i] = e[i];
                degree += e[i];
            }
            if (degree > o->degree) o->degree = degree;
            o->abs_sum += fabs(c);
            left--;
        } else if (sscanf(line, "system %63s %d %d", name, &n_in, &n_out) == 3) {
            system = strcmp(name, "P_o") == 0 ? 0 : strcmp(name, "P_s") == 0 ? 1 : -1;
            ok = system >= 0 && n_in == N_IN && n_out == N_OUT;
            output = -1;
        } else if (sscanf(line, "output %63s %*s %d", name, &n) == 2) {
            ok = system >= 0 && ++output < N_OUT && n > 0;
            if (ok) facts[system][output].n_terms = left = n;
        }
    }
    fclose(f);
    return ok && left == 0 && facts[0][N_OUT - 1].n_terms > 0 && facts[1][N_OUT - 1].n_terms > 0;
}

/* ------------------------------------------------------ 1. lens and render ----- */

/* A small render: 24 x 24 pixels around the image point of a light at (2, 1) deg (inside
 * the demo scene fit's 7.6 deg field), f/8, 450/550/650 nm (the fit covers 449-651 nm),
 * 16384 samples per wavelength. Writes the image into `image` (3 * 24 * 24 floats). */
#define PIX 24
static int render_image(lensrt_context ctx, lensrt_lens lens, float *image)
{
    static const double wavelengths[3] = {450.0, 550.0, 650.0};
    lensrt_light light = LENSRT_LIGHT_INIT;
    lensrt_render_desc desc = LENSRT_RENDER_DESC_INIT;
    lensrt_render render = NULL;
    double xy[2];
    int ok;
    light.field_x_deg = -2.0;
    light.field_y_deg = -1.0;
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_image_point(ctx, lens, &light, 550.0, 0.0, xy));
    desc.lens = lens;
    desc.sensor.width = desc.sensor.height = PIX;
    desc.sensor.width_mm = 0.06; /* the f/8 Airy disc's first dark ring is 5.4 um at 550 nm */
    desc.sensor.center_x_mm = xy[0];
    desc.sensor.center_y_mm = xy[1];
    desc.aperture.f_number = 8.0;
    desc.lights = &light;
    desc.n_lights = 1;
    desc.wavelengths_nm = wavelengths;
    desc.n_wavelengths = 3;
    desc.seed = 7;
    ok = lensrt_render_create(ctx, &desc, &render) == LENSRT_SUCCESS &&
         lensrt_render_run(render, 16384, NULL, NULL) == LENSRT_SUCCESS &&
         lensrt_render_image(render, image, 3 * PIX * PIX) == LENSRT_SUCCESS;
    CHECK(ok, "render: %s", lensrt_context_last_error(ctx));
    lensrt_render_destroy(render);
    return ok;
}

static void test_lens_and_render(lensrt_context ctx, lensrt_lens compiled, lensrt_lens table)
{
    lensrt_lens_info a = LENSRT_LENS_INFO_INIT, b = LENSRT_LENS_INFO_INIT;
    static float image_a[3 * PIX * PIX], image_b[3 * PIX * PIX];
    int s, i;
    double peak = 0.0;
    // The same name (the table's), lens facts, domain and trust figures
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_get_info(compiled, &a));
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_get_info(table, &b));
    CHECK(strcmp(a.name, b.name) == 0, "names: compiled '%s', table '%s'", a.name, b.name);
    CHECK(a.analytic == 0 && b.analytic == 0, "analytic %d %d", (int)a.analytic, (int)b.analytic);
#define SAME(field) CHECK(a.field == b.field, #field ": compiled %.17g, table %.17g", a.field, b.field)
    SAME(focal_length_mm); SAME(f_number_min); SAME(stop_radius_max_mm); SAME(wavelength_min_nm);
    SAME(wavelength_max_nm); SAME(focus_offset_min_mm); SAME(focus_offset_max_mm); SAME(field_x);
    SAME(field_y); SAME(distance_min_mm); SAME(sensor_radius_mm); SAME(psf_vs_exact); SAME(psf_target);
#undef SAME
    CHECK(strcmp(a.psf_vs_exact_cell, b.psf_vs_exact_cell) == 0, "cells '%s' '%s'", a.psf_vs_exact_cell,
          b.psf_vs_exact_cell);
    for (s = 0; s < 2; s++) {
        lensrt_system_info x = LENSRT_SYSTEM_INFO_INIT, y = LENSRT_SYSTEM_INFO_INIT;
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_system_info(compiled, s, &x));
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_system_info(table, s, &y));
        CHECK(x.n_inputs == y.n_inputs && x.n_outputs == y.n_outputs, "system %d sizes", s);
        for (i = 0; i < x.n_inputs && i < LENSRT_MAX_SYSTEM_INPUTS; i++)
            CHECK(strcmp(x.input_names[i], y.input_names[i]) == 0 && x.input_min[i] == y.input_min[i] &&
                  x.input_max[i] == y.input_max[i], "system %d input %d", s, i);
        for (i = 0; i < x.n_outputs && i < LENSRT_MAX_SYSTEM_OUTPUTS; i++)
            CHECK(strcmp(x.output_names[i], y.output_names[i]) == 0 && x.n_terms[i] == y.n_terms[i],
                  "system %d output %d", s, i);
    }
    // Renders read coefficients only: the same image bit for bit
    if (!render_image(ctx, compiled, image_a) || !render_image(ctx, table, image_b)) return;
    for (i = 0; i < 3 * PIX * PIX; i++)
        if (image_a[i] > peak) peak = image_a[i];
    CHECK(peak > 0.0 && isfinite(peak), "the compiled lens's image has no finite positive peak (%g)", peak);
    CHECK(memcmp(image_a, image_b, sizeof image_a) == 0, "the renders of the compiled and the table lens differ");
    printf("render 24x24, 3 wavelengths, 16384 samples, f/8, light (2, 1) deg: peak %.6g, images %s\n", peak,
           memcmp(image_a, image_b, sizeof image_a) == 0 ? "identical" : "DIFFERENT");
}

/* ----------------------------------------------------------- 2. per ray ----- */

/* lensrt_lens_eval in batches of SHORT rays: a compiled-in lens evaluates batches of
 * fewer than 32 rays through its Horner code, longer ones through the table. */
#define SHORT 16
static lensrt_result eval_short_batches(lensrt_context ctx, lensrt_lens lens, const lensrt_eval_desc *d)
{
    size_t k, in_size = d->type == LENSRT_TYPE_FLOAT ? sizeof(float) : sizeof(double);
    lensrt_result res = LENSRT_SUCCESS;
    for (k = 0; k < d->n_rays && res == LENSRT_SUCCESS; k += SHORT) {
        lensrt_eval_desc part = *d;
        part.n_rays = d->n_rays - k < SHORT ? d->n_rays - k : SHORT;
        part.inputs = (const char *)d->inputs + k * N_IN * in_size;
        part.outputs = (char *)d->outputs + k * N_OUT * in_size;
        res = lensrt_lens_eval(ctx, lens, &part);
    }
    return res;
}

static void test_per_ray(lensrt_context ctx, lensrt_lens compiled, lensrt_lens table, const char *table_path)
{
    static double in_d[RAYS * N_IN], out_c[RAYS * N_OUT], out_t[RAYS * N_OUT];
    static double jac_c[RAYS * N_OUT * N_IN], jac_t[RAYS * N_OUT * N_IN];
    static float in_f[RAYS * N_IN], outf_c[RAYS * N_OUT], outf_t[RAYS * N_OUT];
    output_facts facts[2][N_OUT];
    uint64_t rng = 12345;
    int s;
    CHECK(read_facts(table_path, facts), "%s: cannot read its systems' terms", table_path);
    for (s = 0; s < 2; s++) {
        lensrt_system_info info = LENSRT_SYSTEM_INFO_INIT;
        lensrt_eval_desc d = LENSRT_EVAL_DESC_INIT;
        lensrt_horner_d horner = s == 0 ? lensrt_lens_0001_demo.object_d : lensrt_lens_0001_demo.sensor_d;
        size_t k;
        int o, i, differ = 0;
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_system_info(table, s, &info));
        // Random rays inside the fitted domain (the box of the inputs' ranges)
        for (k = 0; k < RAYS; k++)
            for (i = 0; i < N_IN; i++) {
                double lo = info.input_min[i], hi = info.input_max[i];
                in_d[k * N_IN + i] = lo + (hi - lo) * uniform01(&rng);
                in_f[k * N_IN + i] = (float)in_d[k * N_IN + i];
            }
        // Double: the Horner code (compiled) against the table's sums
        d.system = s;
        d.type = LENSRT_TYPE_DOUBLE;
        d.n_rays = RAYS;
        d.inputs = in_d;
        d.outputs = out_c;
        // A long batch of the compiled lens is the table's sums, bit for bit
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_eval(ctx, compiled, &d));
        d.outputs = out_t;
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_eval(ctx, table, &d));
        CHECK(memcmp(out_c, out_t, sizeof out_c) == 0, "system %d: a long batch of the compiled lens is not the "
              "table's evaluation", s);
        d.outputs = out_c;
        CHECK_RES(ctx, LENSRT_SUCCESS, eval_short_batches(ctx, compiled, &d));
        // lensrt_lens_eval of a compiled lens in short batches is its Horner function, bit for bit
        for (k = 0; k < RAYS; k += 97) {
            double direct[N_OUT];
            horner(in_d + k * N_IN, direct);
            CHECK(memcmp(direct, out_c + k * N_OUT, sizeof direct) == 0, "system %d ray %zu: eval is not the "
                  "compiled Horner function", s, k);
        }
        for (o = 0; o < N_OUT; o++) {
            const output_facts *fo = &facts[s][o];
            int nest = 0;
            double max_abs = 0.0, max_rel = 0.0, tol;
            for (i = 0; i < N_IN; i++) nest += fo->max_exp[i];
            // Tolerance: first-order rounding bounds in units of eps * sum|c| (every
            // monomial is at most 1 in the domain, so sum|c| bounds the sum of |terms|):
            // the table's sum rounds n_terms times in sequence (n - 1), each term after
            // at most degree + N_IN products of powers; the Horner form rounds at most twice
            // per power of each nesting level (2 * the sum of the highest exponents); both
            // normalise the inputs, an error of a few eps in xhat that a monomial turns
            // into at most its exponent times that (4 * degree).
            tol = (double)(fo->n_terms + fo->degree + N_IN + 2 * nest + 4 * fo->degree) * DBL_EPSILON * fo->abs_sum;
            for (k = 0; k < RAYS; k++) {
                double c = out_c[k * N_OUT + o], t = out_t[k * N_OUT + o], diff = fabs(c - t);
                if (c != t) differ = 1;
                if (diff > max_abs || !(diff == diff)) max_abs = diff;
                if (fabs(t) > 1e-3 * fo->abs_sum && diff / fabs(t) > max_rel) max_rel = diff / fabs(t);
            }
            CHECK(max_abs <= tol, "system %d output %d (%s): double Horner and table differ by %.3g, more than "
                  "%.3g", s, o, info.output_names[o], max_abs, tol);
            printf("%s %-6s double: %5d terms, sum|c| %-9.4g max |diff| %.3g = %.3g eps sum|c| (bound %.0f), "
                   "max relative %.3g\n", s ? "P_s" : "P_o", info.output_names[o], fo->n_terms, fo->abs_sum, max_abs,
                   max_abs / (DBL_EPSILON * fo->abs_sum), tol / (DBL_EPSILON * fo->abs_sum), max_rel);
        }
        // The two evaluations are different code: some outputs of 4096 rays differ by
        // rounding (if none did, eval would not be using the Horner code)
        CHECK(differ, "system %d: every compiled value equals the table's bit for bit", s);

        // Float: the Horner code in float against the table (summed in double, rounded)
        d.type = LENSRT_TYPE_FLOAT;
        d.inputs = in_f;
        d.outputs = outf_c;
        CHECK_RES(ctx, LENSRT_SUCCESS, eval_short_batches(ctx, compiled, &d));
        d.outputs = outf_t;
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_eval(ctx, table, &d));
        for (o = 0; o < N_OUT; o++) {
            const output_facts *fo = &facts[s][o];
            int nest = 0;
            double max_abs = 0.0, tol;
            for (i = 0; i < N_IN; i++) nest += fo->max_exp[i];
            // Tolerance in units of float eps * sum|c|: the Horner form's roundings in
            // float (2 * nest, as above), the inputs normalised in float (xhat off by up to
            // about 11 eps for lambda's 1/v^2 - c, whose terms nearly cancel; a monomial
            // turns that into at most its degree times it: 11 * degree), the double sum's
            // rounding to float (1) and the double sum's own error (negligible in float).
            tol = (double)(2 * nest + 11 * fo->degree + 8) * FLT_EPSILON * fo->abs_sum;
            for (k = 0; k < RAYS; k++) {
                double diff = fabs((double)outf_c[k * N_OUT + o] - (double)outf_t[k * N_OUT + o]);
                if (diff > max_abs || !(diff == diff)) max_abs = diff;
            }
            CHECK(max_abs <= tol, "system %d output %d (%s): float Horner and table differ by %.3g, more than %.3g",
                  s, o, info.output_names[o], max_abs, tol);
            printf("%s %-6s float:  max |diff| %.3g = %.3g float-eps sum|c| (bound %.0f)\n", s ? "P_s" : "P_o",
                   info.output_names[o], max_abs, max_abs / (FLT_EPSILON * fo->abs_sum),
                   tol / (FLT_EPSILON * fo->abs_sum));
        }

        // Jacobians come from the table for both lenses: values and Jacobians equal bit for bit
        d.type = LENSRT_TYPE_DOUBLE;
        d.inputs = in_d;
        d.n_rays = 256;
        d.outputs = out_c;
        d.jacobians = jac_c;
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_eval(ctx, compiled, &d));
        d.outputs = out_t;
        d.jacobians = jac_t;
        CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_eval(ctx, table, &d));
        CHECK(memcmp(jac_c, jac_t, sizeof(double) * 256 * N_OUT * N_IN) == 0 &&
              memcmp(out_c, out_t, sizeof(double) * 256 * N_OUT) == 0,
              "system %d: Jacobians (and values with them) of the compiled lens differ from the table's", s);
    }
}

/* ------------------------------------------------------ 3. bad structs ----- */

static void test_refusals(lensrt_context ctx)
{
    lensrt_compiled_lens c;
    lensrt_lens lens = (lensrt_lens)&c; /* must come back NULL */
    struct {
        lensrt_compiled_lens c;
        size_t extra; /* a field of a newer header */
    } newer;
#define BAD(want, needle)                                                                          \
    do {                                                                                           \
        lens = (lensrt_lens)&c;                                                                    \
        CHECK_RES(ctx, (want), lensrt_lens_load_compiled(ctx, &c, &lens));                         \
        CHECK_MSG(ctx, (needle));                                                                  \
        CHECK(lens == NULL, "a refused struct left *out set");                                     \
        c = lensrt_lens_0001_demo;                                                                 \
    } while (0)
    c = lensrt_lens_0001_demo;
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_load_compiled(ctx, NULL, &lens));
    CHECK_RES(ctx, LENSRT_ERROR_INVALID_ARGUMENT, lensrt_lens_load_compiled(ctx, &c, NULL));
    c.struct_size = 0;
    BAD(LENSRT_ERROR_INVALID_ARGUMENT, "struct_size is 0");
    c.struct_size = sizeof(size_t) + sizeof(char *);
    BAD(LENSRT_ERROR_INVALID_ARGUMENT, "expected sizeof(lensrt_compiled_lens)");
    c.table_text = NULL;
    BAD(LENSRT_ERROR_INVALID_ARGUMENT, "table_text is NULL");
    c.table_size = 0;
    BAD(LENSRT_ERROR_INVALID_ARGUMENT, "table_size 0");
    c.name = NULL;
    BAD(LENSRT_ERROR_INVALID_ARGUMENT, "name is NULL");
    c.name = "";
    BAD(LENSRT_ERROR_INVALID_ARGUMENT, "no name");
    c.sensor_f = NULL;
    BAD(LENSRT_ERROR_INVALID_ARGUMENT, "sensor_f is NULL");
    // A truncated table: half of it ends inside the first system (its checksum line gone)
    c.table_size = lensrt_lens_0001_demo.table_size / 2;
    BAD(LENSRT_ERROR_PARSE, "0001-angenieux-double-gauss/scene-fits/demo");
    c.table_size = lensrt_lens_0001_demo.table_size / 2;
    BAD(LENSRT_ERROR_PARSE, "expected the last line 'checksum crc32");
    // The embedded table with one bit flipped (a binary patched, memory corrupted): its
    // checksum refuses it as a file's would (issue 25)
    {
        char *flipped = malloc(lensrt_lens_0001_demo.table_size);
        CHECK(flipped != NULL, "out of memory");
        if (flipped) {
            memcpy(flipped, lensrt_lens_0001_demo.table_text, lensrt_lens_0001_demo.table_size);
            flipped[lensrt_lens_0001_demo.table_size / 3] ^= 0x04;
            c.table_text = flipped;
            BAD(LENSRT_ERROR_PARSE, "does not match the content");
            free(flipped);
        }
    }
    // Not a table at all
    c.table_text = "not a lens table\n";
    c.table_size = strlen(c.table_text);
    BAD(LENSRT_ERROR_PARSE, "not a lens table");
    // A newer header's struct: accepted when what this library does not know is zero
    newer.c = lensrt_lens_0001_demo;
    newer.c.struct_size = sizeof newer;
    newer.extra = 1;
    CHECK_RES(ctx, LENSRT_ERROR_UNSUPPORTED, lensrt_lens_load_compiled(ctx, &newer.c, &lens));
    newer.extra = 0;
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_load_compiled(ctx, &newer.c, &lens));
    lensrt_lens_destroy(ctx, lens);
#undef BAD
}

/* Whether the file's bytes are text[0 .. size) and text[size] is NUL. */
static int same_as_file(const char *path, const char *text, size_t size)
{
    FILE *f = fopen(path, "rb");
    size_t i = 0;
    int ch, same = f != NULL && text[size] == '\0';
    while (same && (ch = fgetc(f)) != EOF) same = i < size && (unsigned char)text[i++] == (unsigned char)ch;
    if (f) fclose(f);
    return same && i == size;
}

int main(int argc, char **argv)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    lensrt_lens compiled = NULL, table = NULL;
    if (argc != 2) {
        fprintf(stderr, "usage: test_compiled LENS_TABLE\n");
        return 2;
    }
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) return 1;
    // The generated struct: its size, and the table file's bytes, NUL-terminated
    CHECK(lensrt_lens_0001_demo.struct_size == sizeof(lensrt_compiled_lens), "struct_size %zu",
          lensrt_lens_0001_demo.struct_size);
    CHECK(same_as_file(argv[1], lensrt_lens_0001_demo.table_text, lensrt_lens_0001_demo.table_size),
          "the embedded table (%zu bytes) is not the bytes of %s", lensrt_lens_0001_demo.table_size, argv[1]);
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_load_compiled(ctx, &lensrt_lens_0001_demo, &compiled));
    CHECK_RES(ctx, LENSRT_SUCCESS, lensrt_lens_load(ctx, argv[1], &table));
    if (compiled && table) {
        test_lens_and_render(ctx, compiled, table);
        test_per_ray(ctx, compiled, table, argv[1]);
    }
    test_refusals(ctx);
    lensrt_lens_destroy(ctx, compiled);
    lensrt_lens_destroy(ctx, table);
    lensrt_context_destroy(ctx);
    printf("test_compiled: %d checks, %d failed\n", g_checks, g_failures);
    return g_failures ? 1 : 0;
}
