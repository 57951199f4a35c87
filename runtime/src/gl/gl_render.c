/* The GL path of a render: the paper's two compute shaders plus the pixel set-up.
 *
 * Per wavelength and pass of LENSRT_PASS samples:
 *   1. samples.comp: P_o per sample and light (phase reduced in double), and the
 *      window's basis rows per sample;
 *   2. pixels.comp:  P_s specialised to each pixel in double, in the window's basis;
 *   3. splat.comp:   every sample to every pixel, phasors added to the sums.
 * Pixels are processed in chunks that bound the per-pixel records. The number of basis
 * terms each output needs per wavelength is found once, by a first run of pixels.comp
 * that folds every pixel's need into ranks[] (atomicMax), and compiled into splat.comp
 * as constants, so its inner loops unroll with the coefficients in registers. */
#include "gl_render.h"

#include "../core/basis.h"
#include "../core/specialise.h"
#include "../lens/lens.h"
#include "gl_device.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

extern const char lensrt_samples_comp[], lensrt_pixels_comp[], lensrt_splat_comp[];

/* Buffers, by binding point (the shaders' `binding = N`) */
enum {
    B_XY, B_INSIDE, B_PO, B_BASIS, B_LIGHTS, B_LAMBDA, B_ROWS, B_LSAMPLE, B_PIXX, B_PIXY,
    B_PSCOEF, B_PSCODE, B_PSOFF, B_RECORDS, B_RANKS, B_SUMS, B_SUMSQ, B_NORM1, B_COUNT
};

#define GROUP 64           /* local_size_x of every shader */
#define MAX_VARIANTS 64    /* splat programs kept (one per set of term counts) */
#define RECORD_BYTES (256u << 20) /* per-pixel records of one chunk, at most */

typedef struct lensrt_gl_render_s lensrt_gl_render_s;

typedef struct splat_variant {
    int k[4];
    GLuint program;
} splat_variant;

struct lensrt_gl_render_s {
    lensrt_gl *gl;
    GLuint buffers[B_COUNT];
    GLuint samples, pixels;
    splat_variant variants[MAX_VARIANTS];
    int n_variants;
    int *k;                /* [w][4]: basis terms per output (-1: not yet known) */
    int nb;                /* basis functions per output (n_slots - 1) */
    long npix, chunk;      /* pixels, pixels per chunk */
    /* A ghost's P_clip pairs on side P_s: per pixel record, per pair a flag (tested) and
     * both outputs' stop-monomial coefficients; 0 floats for every other render */
    int clip_rec;
    char defines[4096];    /* the scene's constants, for every shader */
    char *stop_text;       /* a bladed or slit stop's test for samples.comp and pixels.comp (NULL: none) */
    float *inside;         /* [LENSRT_PASS] aperture-shape mask of the pass */
};

/* The render's GL state (r->device_data). */
#define GLR(r) ((lensrt_gl_render_s *)(r)->device_data)

/* Free space after the stop (analytic lenses): no P_s, no pixel set-up, no basis. */
static int free_space(const lensrt_render r) { return r->lens_ops->transport == LENSRT_TRANSPORT_FREE_SPACE; }

/* ------------------------------------------------------------ programs ----- */

/* A double constant as a GLSL literal (always with a point or an exponent): 17
 * significant digits round-trip every double; the "C" locale, so that a host's
 * LC_NUMERIC (de_DE writes 1,5) neither breaks the shader nor changes its numbers. */
static void append_double(char *buf, size_t size, const char *name, double v)
{
    char num[64];
    size_t used = strlen(buf);
    lensrt_snprintf_c(num, sizeof num, "%.17g", v);
    if (!strpbrk(num, ".e")) strcat(num, ".0");
    snprintf(buf + used, size - used, "#define %s %sLF\n", name, num);
}

static void append_int(char *buf, size_t size, const char *name, long v)
{
    size_t used = strlen(buf);
    snprintf(buf + used, size - used, "#define %s %ld\n", name, v);
}

static lensrt_result compile(lensrt_render r, const char *name, const char *body, const char *extra, GLuint *out)
{
    lensrt_gl *gl = GLR(r)->gl;
    const char *parts[4];
    GLuint shader, program;
    GLint ok = 0;
    char log[1024] = "";
    parts[0] = "#version 430 core\n";
    parts[1] = GLR(r)->defines;
    parts[2] = extra;
    parts[3] = body;
    shader = gl->CreateShader(GL_COMPUTE_SHADER);
    gl->ShaderSource(shader, 4, parts, NULL);
    gl->CompileShader(shader);
    gl->GetShaderiv(shader, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        gl->GetShaderInfoLog(shader, sizeof log, NULL, log);
        gl->DeleteShader(shader);
        return lensrt_fail(r->ctx, LENSRT_ERROR_DEVICE, "GL: %s does not compile on %s: %s", name, gl->renderer, log);
    }
    program = gl->CreateProgram();
    gl->AttachShader(program, shader);
    gl->LinkProgram(program);
    gl->DeleteShader(shader);
    gl->GetProgramiv(program, GL_LINK_STATUS, &ok);
    if (!ok) {
        gl->GetProgramInfoLog(program, sizeof log, NULL, log);
        gl->DeleteProgram(program);
        return lensrt_fail(r->ctx, LENSRT_ERROR_DEVICE, "GL: %s does not link on %s: %s", name, gl->renderer, log);
    }
    *out = program;
    return LENSRT_SUCCESS;
}

static void set_uint(lensrt_gl *gl, GLuint program, const char *name, unsigned v)
{
    GLint at = gl->GetUniformLocation(program, name);
    if (at >= 0) gl->Uniform1ui(at, v);
}

static void set_ivec4(lensrt_gl *gl, GLuint program, const char *name, const int *v)
{
    GLint at = gl->GetUniformLocation(program, name);
    if (at >= 0) gl->Uniform4i(at, v[0], v[1], v[2], v[3]);
}

/* A ghost's P_clip tests on side P_s for splat.comp, as straight-line code (a macro
 * the shader expands in clip_weight(b, s)): per pair q, when the pixel's record says it
 * is tested, x and y as dot products of its coefficients (records[b + ...]) with the
 * sample's stop monomials (rows after the basis rows), and w = 0 when x^2 + y^2 exceeds
 * the pair's limit or, for a stop crossing of a bladed or slit stop, when the point
 * fails one of its edges or lies in no slit (r->stop's float constants, one line each). No loop: llvmpipe ends an invocation after 65,535 loop iterations in
 * all, and the splat loop over a pass's samples already takes 16,384 of them. The text,
 * allocated through the context; NULL when out of memory. */
static char *clip_code(lensrt_render r)
{
    const int ns = r->n_slots, nb = r->n_slots - 1, K = r->n_clip_pairs;
    const size_t size = 256 + (size_t)K * (2 * (size_t)ns * 48 + 512 + (size_t)r->stop.n * 160);
    char *t = lensrt_alloc(r->ctx, size);
    size_t used;
    int q, a, k;
    if (!t) return NULL;
    used = (size_t)snprintf(t, size, "#define CLIP_WEIGHT_BODY ");
    for (q = 0; q < K; q++) {
        const int at = q * (1 + 2 * ns);
        used += (size_t)snprintf(t + used, size - used, "if (records[b + %du] != 0.0) { ", at);
        for (a = 0; a < 2; a++) {
            used += (size_t)snprintf(t + used, size - used, "%s = 0.0", a ? "hy" : "hx");
            for (k = 0; k < ns; k++)
                used += (size_t)snprintf(t + used, size - used, " + records[b + %du] * rows[%luu + s]",
                                         at + 1 + a * ns + k, (unsigned long)(4 * nb + k) * LENSRT_PASS);
            used += (size_t)snprintf(t + used, size - used, "; ");
        }
        if (!r->clip_shaped[q]) {
            used += (size_t)snprintf(t + used, size - used, "if (hx * hx + hy * hy > float(CLIP_LIMIT2_%d)) w = 0.0; } ", q);
            continue;
        }
        // A stop crossing of a bladed or slit stop (core/render.h): its circle, then each
        // edge (a r^2 + gx x + gy y <= c) or the slits, with the host's float constants
        used += (size_t)snprintf(t + used, size - used, "float r2 = hx * hx + hy * hy; if (r2 > float(CLIP_LIMIT2_%d)) w = 0.0; ", q);
        if (r->stop.kind == LENSRT_STOP_BLADES) {
            for (k = 0; k < r->stop.n; k++) {
                lensrt_snprintf_c(t + used, size - used, "if (%.9e * r2 + %.9e * hx + %.9e * hy > %.9e) w = 0.0; ",
                                  (double)r->stop.f_a, (double)r->stop.f_gx[k], (double)r->stop.f_gy[k],
                                  (double)r->stop.f_c[k]);
                used += strlen(t + used);
            }
        } else {
            lensrt_snprintf_c(t + used, size - used,
                              "if (abs(hy) > %.9e || (abs(hx - %.9e) > %.9e && (%d == 1 || abs(hx - %.9e) > %.9e))) w = 0.0; ",
                              (double)r->stop.f_half_y, (double)r->stop.f_centre[0], (double)r->stop.f_half_x, r->stop.n,
                              (double)r->stop.f_centre[1], (double)r->stop.f_half_x);
            used += strlen(t + used);
        }
        used += (size_t)snprintf(t + used, size - used, "} ");
    }
    snprintf(t + used, size - used, "\n");
    return t;
}

/* A bladed or slit stop's test of a ghost's stop crossings for samples.comp (side P_o,
 * per sample) and pixels.comp (side P_s, the per-pixel decision), in double: the
 * constants of r->stop (core/render.h) and two functions, stop_inside(x, y) and
 * stop_box(cx, bx, cy, by) (1 every point of the box passes, 0 none, 2 test each), the
 * same as lensrt_stop_shape_contains and lensrt_stop_shape_box. With STOP_SHAPED_q, which
 * pairs are such crossings. NULL (no text) when there are none; else allocated through
 * the context, and *oom set when that fails. */
static char *stop_text(lensrt_render r, int *oom)
{
    const lensrt_stop_shape *st = &r->stop;
    const int n = st->kind == LENSRT_STOP_BLADES ? st->n : 1;
    const size_t size = 4096 + (size_t)n * 5 * 32;
    char *t, num[64];
    size_t used = 0;
    int q, k, any = 0;
    const char *arrays[5] = {"STOP_GX", "STOP_GY", "STOP_C", "STOP_NX", "STOP_NY"};
    *oom = 0;
    for (q = 0; q < r->n_clip_pairs; q++) any |= r->clip_shaped[q];
    if (!any) return NULL;
    if (!(t = lensrt_alloc(r->ctx, size))) {
        *oom = 1;
        return NULL;
    }
    t[0] = '\0';
    append_int(t, size, "STOP_SHAPED", 1);
    append_int(t, size, "STOP_KIND", st->kind);
    append_int(t, size, "STOP_N", n);
    for (q = 0; q < LENSRT_MAX_CLIP_PAIRS; q++) {
        snprintf(num, sizeof num, "STOP_SHAPED_%d", q);
        append_int(t, size, num, q < r->n_clip_pairs && r->clip_shaped[q]);
    }
    append_double(t, size, "STOP_R2", st->r2);
    append_double(t, size, "STOP_A", st->a);
    append_double(t, size, "STOP_APOTHEM", st->apothem);
    append_double(t, size, "STOP_REACH", st->reach);
    append_double(t, size, "STOP_HALF_X", st->half_x);
    append_double(t, size, "STOP_HALF_Y", st->half_y);
    append_double(t, size, "STOP_C0", st->centre[0]);
    append_double(t, size, "STOP_C1", st->centre[1]);
    // Per edge (blades; one zero entry otherwise): const double arrays
    for (q = 0; q < 5; q++) {
        const double *v = q == 0 ? st->gx : q == 1 ? st->gy : q == 2 ? st->c : q == 3 ? st->nx : st->ny;
        used = strlen(t);
        used += (size_t)snprintf(t + used, size - used, "const double %s[%d] = double[%d](", arrays[q], n, n);
        for (k = 0; k < n; k++) {
            lensrt_snprintf_c(num, sizeof num, "%.17e", v[k]);
            used += (size_t)snprintf(t + used, size - used, "%s%sLF", k ? ", " : "", num);
        }
        used += (size_t)snprintf(t + used, size - used, ");\n");
    }
    used = strlen(t);
    snprintf(t + used, size - used, "%s",
             "bool stop_inside(double x, double y)\n"
             "{\n"
             "    double r2 = x * x + y * y;\n"
             "    if (r2 > STOP_R2) return false;\n"
             "#if STOP_KIND == 1\n"
             "    for (int k = 0; k < STOP_N; k++)\n"
             "        if (STOP_A * r2 + STOP_GX[k] * x + STOP_GY[k] * y > STOP_C[k]) return false;\n"
             "    return true;\n"
             "#else\n"
             "    if (abs(y) > STOP_HALF_Y) return false;\n"
             "    return abs(x - STOP_C0) <= STOP_HALF_X || (STOP_N == 2 && abs(x - STOP_C1) <= STOP_HALF_X);\n"
             "#endif\n"
             "}\n"
             "int stop_box(double cx, double bx, double cy, double by)\n"
             "{\n"
             "    double lo_x = abs(cx) - bx, lo_y = abs(cy) - by, R = sqrt(STOP_R2);\n"
             "    if (lo_x > R || lo_y > R || (lo_x > 0.0LF && lo_y > 0.0LF && length(dvec2(lo_x, lo_y)) > R)) return 0;\n"
             "#if STOP_KIND == 1\n"
             "    bool all = true;\n"
             "    for (int k = 0; k < STOP_N; k++) {\n"
             "        double mid = STOP_NX[k] * cx + STOP_NY[k] * cy, spread = abs(STOP_NX[k]) * bx + abs(STOP_NY[k]) * by;\n"
             "        if (mid - spread > STOP_REACH) return 0;\n"
             "        if (mid + spread > STOP_APOTHEM) all = false;\n"
             "    }\n"
             "    return all || length(dvec2(abs(cx) + bx, abs(cy) + by)) <= STOP_REACH ? 1 : 2;\n"
             "#else\n"
             "    if (abs(cy) - by > STOP_HALF_Y) return 0;\n"
             "    bool in_x = false, out_x = true;\n"
             "    for (int k = 0; k < STOP_N; k++) {\n"
             "        double dx = abs(cx - (k == 0 ? STOP_C0 : STOP_C1));\n"
             "        if (dx + bx <= STOP_HALF_X) in_x = true;\n"
             "        if (dx - bx <= STOP_HALF_X) out_x = false;\n"
             "    }\n"
             "    if (out_x) return 0;\n"
             "    return in_x && abs(cy) + by <= STOP_HALF_Y ? 1 : 2;\n"
             "#endif\n"
             "}\n");
    return t;
}

/* The splat program for basis term counts k (per output), compiled on first use. */
static lensrt_result splat_program(lensrt_render r, const int k[4], GLuint *out)
{
    lensrt_gl_render_s *g = GLR(r);
    char defines[256], *extra, *clip = NULL;
    size_t n;
    lensrt_result res;
    int i;
    for (i = 0; i < g->n_variants; i++)
        if (!memcmp(g->variants[i].k, k, sizeof g->variants[i].k)) {
            *out = g->variants[i].program;
            return LENSRT_SUCCESS;
        }
    if (g->n_variants == MAX_VARIANTS)
        return lensrt_fail(r->ctx, LENSRT_ERROR_DEVICE, "GL: more than %d splat programs", MAX_VARIANTS);
    snprintf(defines, sizeof defines, "#define KX %d\n#define KY %d\n#define KT %d\n#define KP %d\n", k[0], k[1], k[2], k[3]);
    if (g->clip_rec && !(clip = clip_code(r))) return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "GL: out of memory");
    n = strlen(defines) + (clip ? strlen(clip) : 0) + 1;
    if (!(extra = lensrt_alloc(r->ctx, n))) {
        lensrt_free(r->ctx, clip);
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "GL: out of memory");
    }
    snprintf(extra, n, "%s%s", defines, clip ? clip : "");
    lensrt_free(r->ctx, clip);
    res = compile(r, "splat.comp", lensrt_splat_comp, extra, out);
    lensrt_free(r->ctx, extra);
    if (res != LENSRT_SUCCESS) return res;
    memcpy(g->variants[g->n_variants].k, k, sizeof g->variants[0].k);
    g->variants[g->n_variants++].program = *out;
    return LENSRT_SUCCESS;
}

/* ------------------------------------------------------------- buffers ----- */

static void upload(lensrt_gl *gl, GLuint buffer, size_t bytes, const void *data)
{
    gl->BindBuffer(GL_SHADER_STORAGE_BUFFER, buffer);
    gl->BufferData(GL_SHADER_STORAGE_BUFFER, (GLsizeiptr)(bytes ? bytes : 16), NULL, GL_STATIC_DRAW);
    if (data && bytes) gl->BufferSubData(GL_SHADER_STORAGE_BUFFER, 0, (GLsizeiptr)bytes, data);
}

static lensrt_result check_gl(lensrt_render r, const char *what)
{
    GLenum e = GLR(r)->gl->GetError();
    if (e == GL_NO_ERROR) return LENSRT_SUCCESS;
    return lensrt_fail(r->ctx, LENSRT_ERROR_DEVICE, "GL: %s failed on %s (%s)", what, GLR(r)->gl->renderer,
                       e == GL_OUT_OF_MEMORY ? "out of device memory" : "GL error");
}

/* The fitted lens's P_s terms per (wavelength, output) and P_o coefficients. */
static lensrt_result upload_polynomials(lensrt_render r)
{
    lensrt_gl *gl = GLR(r)->gl;
    size_t n = 0, i, at = 0;
    double *coef;
    GLuint *code, *off;
    int t;
    // Entries (w, o) of P_s, then those of a ghost's P_clip on side P_s (w, o < 2K), one
    // list: entry e's terms are [off[e], off[e + 1])
    const size_t n_ps = (size_t)r->n_wl * 4, n_clip = r->clip_s ? (size_t)r->n_wl * 2 * (size_t)r->n_clip_pairs : 0;
    const size_t n_po = (size_t)r->n_lights * (size_t)r->n_wl * LENSRT_PO_OUTPUTS * (size_t)r->n_slots;
    const size_t n_clip_o = r->clip_o ? (size_t)r->n_lights * (size_t)r->n_wl * 2 * (size_t)r->n_clip_pairs * (size_t)r->n_slots : 0;
    double *po;
    for (i = 0; i < n_ps + n_clip; i++) n += (size_t)(i < n_ps ? r->ps[i].n : r->clip_s[i - n_ps].n);
    coef = lensrt_calloc(r->ctx, n + 1, sizeof *coef);
    code = lensrt_calloc(r->ctx, n + 1, sizeof *code);
    off = lensrt_calloc(r->ctx, n_ps + n_clip + 1, sizeof *off);
    po = lensrt_calloc(r->ctx, n_po + n_clip_o + 1, sizeof *po);
    if (!coef || !code || !off || !po) {
        lensrt_free(r->ctx, coef);
        lensrt_free(r->ctx, code);
        lensrt_free(r->ctx, off);
        lensrt_free(r->ctx, po);
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "GL: out of memory");
    }
    for (i = 0; i < n_ps + n_clip; i++) {
        const lensrt_pixel_poly *p = i < n_ps ? &r->ps[i] : &r->clip_s[i - n_ps];
        off[i] = (GLuint)at;
        for (t = 0; t < p->n; t++, at++) {
            coef[at] = p->coef[t];
            code[at] = (GLuint)p->ix[t] | (GLuint)p->iy[t] << 8 | (GLuint)p->slot[t] << 16;
        }
    }
    off[n_ps + n_clip] = (GLuint)at;
    upload(gl, GLR(r)->buffers[B_PSCOEF], n * sizeof *coef, coef);
    upload(gl, GLR(r)->buffers[B_PSCODE], n * sizeof *code, code);
    upload(gl, GLR(r)->buffers[B_PSOFF], (n_ps + n_clip + 1) * sizeof *off, off);
    lensrt_free(r->ctx, coef);
    lensrt_free(r->ctx, code);
    lensrt_free(r->ctx, off);
    // P_o per light and wavelength, then a ghost's P_clip on side P_o likewise
    memcpy(po, r->po, n_po * sizeof *po);
    if (n_clip_o) memcpy(po + n_po, r->clip_o, n_clip_o * sizeof *po);
    upload(gl, GLR(r)->buffers[B_PO], (n_po + n_clip_o) * sizeof *po, po);
    lensrt_free(r->ctx, po);
    upload(gl, GLR(r)->buffers[B_BASIS], (size_t)r->n_wl * 4 * (size_t)GLR(r)->nb * (size_t)GLR(r)->nb * sizeof(double), r->basis);
    // l1 norms of the basis vectors (core/basis.c): |V_j|_1 bounds how much a dropped u_j
    // can change
    upload(gl, GLR(r)->buffers[B_NORM1], (size_t)r->n_wl * 4 * (size_t)GLR(r)->nb * sizeof(double), r->basis_l1);
    return LENSRT_SUCCESS;
}

/* ------------------------------------------------------------- create ----- */

static void scene_defines(lensrt_render r)
{
    lensrt_gl_render_s *g = GLR(r);
    char *d = g->defines;
    const size_t size = sizeof g->defines;
    const lensrt_lens lens = r->lens;
    d[0] = '\0';
    append_int(d, size, "NL", r->n_lights);
    append_int(d, size, "NW", r->n_wl);
    append_int(d, size, "PASS", LENSRT_PASS);
    append_int(d, size, "BLOCK", LENSRT_BLOCK); /* samples summed in float before the double sums */
    append_int(d, size, "W", r->width);
    append_int(d, size, "NAIVE", r->desc.precision == LENSRT_PRECISION_NAIVE_FLOAT);
    append_int(d, size, "UNBIASED", r->desc.estimator == LENSRT_ESTIMATOR_UNBIASED);
    append_int(d, size, "ANALYTIC", free_space(r));
    append_int(d, size, "NCLIP_O", r->clip_o ? r->n_clip_pairs : 0);
    append_int(d, size, "NCLIP_S", r->clip_s ? r->n_clip_pairs : 0);
    if (free_space(r)) {
        // Placeholders keep the fitted-lens declarations valid
        append_int(d, size, "NS", 2);
        append_int(d, size, "NB", 1);
        append_int(d, size, "DEGREE", 1);
        append_int(d, size, "FOCAL_MM_SET", lens->model.focal_length_mm > 0);
        append_double(d, size, "FOCAL_MM", lens->model.focal_length_mm);
        append_int(d, size, "ONE_D", lens->model.one_dimensional);
        append_double(d, size, "SENSOR_Z_MM", lens->model.sensor_distance_mm + r->desc.sensor.focus_offset_mm);
        return;
    }
    append_int(d, size, "NS", r->n_slots);
    append_int(d, size, "NB", r->n_slots - 1);
    append_int(d, size, "DEGREE", r->degree);
    append_double(d, size, "MONO_RADIUS", r->mono_radius);
    append_double(d, size, "HOUSING_FIRST", lens->housing_first_mm);
    append_double(d, size, "HOUSING_LAST", lens->housing_last_mm);
    append_double(d, size, "SENSOR_CX", lens->p_s.inputs[0].c);
    append_double(d, size, "SENSOR_SX", lens->p_s.inputs[0].s);
    append_double(d, size, "SENSOR_CY", lens->p_s.inputs[1].c);
    append_double(d, size, "SENSOR_SY", lens->p_s.inputs[1].s);
    // The largest l1 norm each output may drop (lensrt_output_limit: one definition for
    // both devices); the transmittance's is relative to its constant term
    append_double(d, size, "LIMIT_PUPIL", lensrt_output_limit(r, 0, 0.0));
    append_double(d, size, "LIMIT_TAU_REL", lensrt_output_limit(r, 2, 1.0));
    append_double(d, size, "TOL_PHASE", lensrt_output_limit(r, 3, 0.0));
    // The Huygens amplitude's finite-difference step, as on the CPU
    append_double(d, size, "STEP_MM", lensrt_huygens_step(r));
    // A ghost's P_clip pairs (NCLIP_O, NCLIP_S above; none for direct renders: the code
    // is compiled out): on side P_o tested per sample (samples.comp), on side P_s decided
    // per pixel and tested per splat (pixels.comp, splat.comp); pair q passes when
    // x^2 + y^2 <= CLIP_LIMIT2_q
    {
        int q;
        char name[32];
        for (q = 0; q < LENSRT_MAX_CLIP_PAIRS; q++) {
            snprintf(name, sizeof name, "CLIP_LIMIT2_%d", q);
            append_double(d, size, name, q < r->n_clip_pairs ? r->clip_limit[q] * r->clip_limit[q] : 1.0);
        }
    }
}

static lensrt_result gl_create(lensrt_render r)
{
    lensrt_gl_render_s *g;
    lensrt_gl *gl;
    lensrt_result res;
    double *lights, *lambda;
    size_t nsum;
    int i;
    // What the GL path does not do, said before any device work
    if (r->desc.precision == LENSRT_PRECISION_DOUBLE)
        return lensrt_fail(r->ctx, LENSRT_ERROR_INVALID_ARGUMENT,
                           "device gl: precision double is CPU-only (GLSL has no double sine or cosine; the GL path "
                           "reduces the phase in double and evaluates the trigonometry in float)");
    if (!free_space(r)) {
        if (r->n_slots < 2)
            return lensrt_fail(r->ctx, LENSRT_ERROR_UNSUPPORTED, "device gl: %s has no stop dependence", r->lens->file);
        if (r->lens->p_s.inputs[0].transform != LENSRT_TRANSFORM_AFFINE ||
            r->lens->p_s.inputs[1].transform != LENSRT_TRANSFORM_AFFINE)
            return lensrt_fail(r->ctx, LENSRT_ERROR_UNSUPPORTED, "device gl: %s: sensor inputs must be affine", r->lens->file);
    }
    if ((res = lensrt_gl_get(r->ctx, &gl)) != LENSRT_SUCCESS) return res;
    g = lensrt_calloc(r->ctx, 1, sizeof *g);
    if (!g) return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "GL: out of memory");
    r->device_data = g;
    g->gl = gl;
    g->nb = free_space(r) ? 1 : r->n_slots - 1;
    g->npix = (long)r->width * r->height;
    g->clip_rec = r->clip_s ? r->n_clip_pairs * (1 + 2 * r->n_slots) : 0;
    // Chunks: records of at most RECORD_BYTES, and a dispatch within the group limit
    g->chunk = (long)(RECORD_BYTES / ((6u + 4u * (unsigned)g->nb + (unsigned)g->clip_rec) * sizeof(float)));
    if (g->chunk > (long)gl->max_groups_x * GROUP) g->chunk = (long)gl->max_groups_x * GROUP;
    if (g->chunk > g->npix) g->chunk = g->npix;
    g->k = lensrt_calloc(r->ctx, (size_t)r->n_wl * 4, sizeof(int));
    g->inside = lensrt_calloc(r->ctx, LENSRT_PASS, sizeof(float));
    lights = lensrt_calloc(r->ctx, (size_t)r->n_lights * 4, sizeof(double));
    lambda = lensrt_calloc(r->ctx, (size_t)r->n_wl, sizeof(double));
    if (!g->k || !g->inside || !lights || !lambda) {
        lensrt_free(r->ctx, lights);
        lensrt_free(r->ctx, lambda);
        return lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "GL: out of memory");
    }
    for (i = 0; i < r->n_wl * 4; i++) g->k[i] = -1;
    for (i = 0; i < r->n_lights; i++) {
        lights[4 * i + 0] = sqrt(r->lights[i].intensity);
        lights[4 * i + 1] = r->light_d[i];
        lights[4 * i + 2] = r->light_x[i];
        lights[4 * i + 3] = r->light_y[i];
    }
    for (i = 0; i < r->n_wl; i++) lambda[i] = r->wavelengths[i] * 1e-6;
    scene_defines(r);
    if ((res = lensrt_gl_acquire(r->ctx, gl)) != LENSRT_SUCCESS) {
        lensrt_free(r->ctx, lights);
        lensrt_free(r->ctx, lambda);
        return res;
    }
    // Programs: the sample shader, and the pixel set-up for fitted lenses (with a bladed
    // or slit stop's test of a ghost's stop crossings)
    {
        int oom = 0;
        g->stop_text = free_space(r) ? NULL : stop_text(r, &oom);
        res = oom ? lensrt_fail(r->ctx, LENSRT_ERROR_OUT_OF_MEMORY, "GL: out of memory") : LENSRT_SUCCESS;
    }
    if (res == LENSRT_SUCCESS)
        res = compile(r, "samples.comp", lensrt_samples_comp, g->stop_text ? g->stop_text : "", &g->samples);
    if (res == LENSRT_SUCCESS && !free_space(r))
        res = compile(r, "pixels.comp", lensrt_pixels_comp, g->stop_text ? g->stop_text : "", &g->pixels);
    if (res == LENSRT_SUCCESS) {
        // What stays fixed: lights, wavelengths, pixel centres, polynomials; then space
        // for the pass's samples and rows, the chunk's records and the phasor sums
        gl->GenBuffers(B_COUNT, g->buffers);
        upload(gl, g->buffers[B_LIGHTS], (size_t)r->n_lights * 4 * sizeof(double), lights);
        upload(gl, g->buffers[B_LAMBDA], (size_t)r->n_wl * sizeof(double), lambda);
        upload(gl, g->buffers[B_PIXX], (size_t)r->width * sizeof(double), r->xs);
        upload(gl, g->buffers[B_PIXY], (size_t)r->height * sizeof(double), r->ys);
        upload(gl, g->buffers[B_XY], 2 * LENSRT_PASS * sizeof(double), NULL);
        upload(gl, g->buffers[B_INSIDE], LENSRT_PASS * sizeof(float), NULL);
        upload(gl, g->buffers[B_LSAMPLE], (size_t)r->n_lights * LENSRT_PASS * 2 * sizeof(float), NULL);
        nsum = (size_t)r->n_lights * (size_t)r->n_wl * (size_t)g->npix;
        upload(gl, g->buffers[B_SUMS], nsum * 2 * sizeof(double), NULL);
        upload(gl, g->buffers[B_SUMSQ], r->sumsq ? nsum * sizeof(double) : 0, NULL);
        if (!free_space(r)) {
            // Rows: the basis functions of the four outputs, then (a ghost's P_clip on side
            // P_s) the stop monomials themselves
            upload(gl, g->buffers[B_ROWS],
                   (4 * (size_t)g->nb + (r->clip_s ? (size_t)r->n_slots : 0)) * LENSRT_PASS * sizeof(float), NULL);
            upload(gl, g->buffers[B_RECORDS], (size_t)g->chunk * (6 + 4 * (size_t)g->nb + (size_t)g->clip_rec) * sizeof(float),
                   NULL);
            upload(gl, g->buffers[B_RANKS], ((size_t)r->n_wl * 4 + 3) * sizeof(GLuint), NULL);
            res = upload_polynomials(r);
        }
        if (res == LENSRT_SUCCESS) res = check_gl(r, "allocating the render's buffers");
    }
    lensrt_free(r->ctx, lights);
    lensrt_free(r->ctx, lambda);
    lensrt_gl_release(gl);
    if (res == LENSRT_SUCCESS)
        lensrt_log(r->ctx, LENSRT_LOG_INFO, "render: device gl (%s, %s), %ld-pixel chunks", gl->renderer, gl->version, g->chunk);
    return res;
}

static void gl_destroy(lensrt_render r)
{
    lensrt_gl_render_s *g = GLR(r);
    int i;
    if (!g) return;
    if (g->gl && lensrt_gl_acquire(r->ctx, g->gl) == LENSRT_SUCCESS) {
        lensrt_gl *gl = g->gl;
        if (g->buffers[0]) gl->DeleteBuffers(B_COUNT, g->buffers);
        if (g->samples) gl->DeleteProgram(g->samples);
        if (g->pixels) gl->DeleteProgram(g->pixels);
        for (i = 0; i < g->n_variants; i++) gl->DeleteProgram(g->variants[i].program);
        lensrt_gl_release(gl);
    }
    lensrt_free(r->ctx, g->k);
    lensrt_free(r->ctx, g->inside);
    lensrt_free(r->ctx, g->stop_text);
    lensrt_free(r->ctx, g);
    r->device_data = NULL;
}

/* -------------------------------------------------------------- passes ----- */

/* pixels.comp over every chunk for wavelength w, writing k[] coefficients per output. */
static void dispatch_pixels(lensrt_render r, int w, long first, long count, const int *k)
{
    lensrt_gl_render_s *g = GLR(r);
    lensrt_gl *gl = g->gl;
    gl->UseProgram(g->pixels);
    set_uint(gl, g->pixels, "u_w", (unsigned)w);
    set_uint(gl, g->pixels, "u_nw", (unsigned)r->n_wl);
    set_uint(gl, g->pixels, "u_first", (unsigned)first);
    set_uint(gl, g->pixels, "u_count", (unsigned)count);
    set_uint(gl, g->pixels, "u_stride", (unsigned)(6 + k[0] + k[1] + k[2] + k[3] + g->clip_rec));
    set_ivec4(gl, g->pixels, "u_k", k);
    gl->DispatchCompute((GLuint)((count + GROUP - 1) / GROUP), 1, 1);
    gl->MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
}

/* Zero the ranks and the per-pass counters. */
static void clear_ranks(lensrt_render r)
{
    lensrt_gl *gl = GLR(r)->gl;
    size_t n = (size_t)r->n_wl * 4 + 3;
    GLuint zero[4096 * 4 + 3];
    memset(zero, 0, n * sizeof(GLuint));
    gl->BindBuffer(GL_SHADER_STORAGE_BUFFER, GLR(r)->buffers[B_RANKS]);
    gl->BufferSubData(GL_SHADER_STORAGE_BUFFER, 0, (GLsizeiptr)(n * sizeof(GLuint)), zero);
}

/* The basis terms each output needs, per wavelength: the largest need of any pixel. */
static lensrt_result find_ranks(lensrt_render r)
{
    lensrt_gl_render_s *g = GLR(r);
    lensrt_gl *gl = g->gl;
    static const int none[4] = {0, 0, 0, 0};
    GLuint ranks[4096 * 4 + 3];
    long first;
    int w, o;
    if (free_space(r) || g->k[0] >= 0) return LENSRT_SUCCESS;
    clear_ranks(r);
    for (w = 0; w < r->n_wl; w++)
        for (first = 0; first < g->npix; first += g->chunk)
            dispatch_pixels(r, w, first, g->npix - first < g->chunk ? g->npix - first : g->chunk, none);
    gl->MemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    gl->BindBuffer(GL_SHADER_STORAGE_BUFFER, g->buffers[B_RANKS]);
    gl->GetBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, (GLsizeiptr)((size_t)r->n_wl * 4 * sizeof(GLuint)), ranks);
    for (w = 0; w < r->n_wl; w++)
        for (o = 0; o < 4; o++) g->k[4 * w + o] = (int)ranks[4 * w + o] < g->nb ? (int)ranks[4 * w + o] : g->nb;
    clear_ranks(r);
    return check_gl(r, "the pixel set-up");
}

static lensrt_result gl_begin(lensrt_render r)
{
    lensrt_gl_render_s *g = GLR(r);
    lensrt_gl *gl = g->gl;
    size_t nsum = (size_t)r->n_lights * (size_t)r->n_wl * (size_t)g->npix;
    lensrt_result res;
    int i;
    if ((res = lensrt_gl_acquire(r->ctx, gl)) != LENSRT_SUCCESS) return res;
    // Binding points are the GL context's, shared by every render made from it
    for (i = 0; i < B_COUNT; i++) gl->BindBufferBase(GL_SHADER_STORAGE_BUFFER, (GLuint)i, g->buffers[i]);
    // The sums may have changed on the host (load, merge): the host copy is the truth
    gl->BindBuffer(GL_SHADER_STORAGE_BUFFER, g->buffers[B_SUMS]);
    gl->BufferSubData(GL_SHADER_STORAGE_BUFFER, 0, (GLsizeiptr)(nsum * 2 * sizeof(double)), r->sum);
    if (r->sumsq) {
        gl->BindBuffer(GL_SHADER_STORAGE_BUFFER, g->buffers[B_SUMSQ]);
        gl->BufferSubData(GL_SHADER_STORAGE_BUFFER, 0, (GLsizeiptr)(nsum * sizeof(double)), r->sumsq);
    }
    if ((res = find_ranks(r)) != LENSRT_SUCCESS) lensrt_gl_release(gl);
    return res;
}

static lensrt_result gl_pass(lensrt_render r, int w, const double *xy, int n)
{
    lensrt_gl_render_s *g = GLR(r);
    lensrt_gl *gl = g->gl;
    static const int zero4[4] = {0, 0, 0, 0};
    const int *k = free_space(r) ? zero4 : g->k + 4 * w;
    GLuint splat;
    lensrt_result res;
    long first;
    int j;
    // The pass's samples: positions and whether each lies inside the aperture shape
    for (j = 0; j < LENSRT_PASS; j++)
        g->inside[j] = j < n && lensrt_aperture_contains(&r->desc.aperture, r->stop_radius, xy[2 * j], xy[2 * j + 1]);
    gl->BindBuffer(GL_SHADER_STORAGE_BUFFER, g->buffers[B_XY]);
    gl->BufferSubData(GL_SHADER_STORAGE_BUFFER, 0, 2 * LENSRT_PASS * sizeof(double), xy);
    gl->BindBuffer(GL_SHADER_STORAGE_BUFFER, g->buffers[B_INSIDE]);
    gl->BufferSubData(GL_SHADER_STORAGE_BUFFER, 0, LENSRT_PASS * sizeof(float), g->inside);
    // Shader 1: per sample
    gl->UseProgram(g->samples);
    set_uint(gl, g->samples, "u_w", (unsigned)w);
    set_uint(gl, g->samples, "u_n", (unsigned)n);
    set_ivec4(gl, g->samples, "u_rows", k);
    gl->DispatchCompute(LENSRT_PASS / GROUP, 1, 1);
    gl->MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    if ((res = splat_program(r, k, &splat)) != LENSRT_SUCCESS) return res;
    // Per chunk of pixels: set-up, then shader 2
    for (first = 0; first < g->npix; first += g->chunk) {
        long count = g->npix - first < g->chunk ? g->npix - first : g->chunk;
        if (!free_space(r)) dispatch_pixels(r, w, first, count, k);
        gl->UseProgram(splat);
        set_uint(gl, splat, "u_w", (unsigned)w);
        set_uint(gl, splat, "u_n", (unsigned)n);
        set_uint(gl, splat, "u_first", (unsigned)first);
        set_uint(gl, splat, "u_count", (unsigned)count);
        set_uint(gl, splat, "u_stride", (unsigned)(6 + k[0] + k[1] + k[2] + k[3] + g->clip_rec));
        set_uint(gl, splat, "u_npix", (unsigned)g->npix);
        gl->DispatchCompute((GLuint)((count + GROUP - 1) / GROUP), 1, 1);
        gl->MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    }
    // Statistics of the pass, once every wavelength is done
    if (!free_space(r) && w == r->n_wl - 1) {
        GLuint counts[3];
        double terms = 0.0;
        gl->MemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
        gl->BindBuffer(GL_SHADER_STORAGE_BUFFER, g->buffers[B_RANKS]);
        gl->GetBufferSubData(GL_SHADER_STORAGE_BUFFER, (GLintptr)((size_t)r->n_wl * 4 * sizeof(GLuint)),
                             sizeof counts, counts);
        clear_ranks(r);
        for (j = 0; j < r->n_wl; j++) terms += g->k[4 * j + 3];
        r->stat_count = (double)g->npix * r->n_wl;
        r->stat_dark = counts[0];
        r->stat_clip = counts[1];
        r->stat_tau = counts[2];
        r->stat_terms = terms / r->n_wl * (r->stat_count - r->stat_dark);
    }
    gl->Finish();
    return check_gl(r, "a pass");
}

static lensrt_result gl_end(lensrt_render r, lensrt_result status)
{
    lensrt_gl_render_s *g = GLR(r);
    lensrt_gl *gl = g->gl;
    size_t nsum = (size_t)r->n_lights * (size_t)r->n_wl * (size_t)g->npix;
    lensrt_result res;
    // Bring the sums home whatever happened: completed passes stay counted
    gl->MemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    gl->BindBuffer(GL_SHADER_STORAGE_BUFFER, g->buffers[B_SUMS]);
    gl->GetBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, (GLsizeiptr)(nsum * 2 * sizeof(double)), r->sum);
    if (r->sumsq) {
        gl->BindBuffer(GL_SHADER_STORAGE_BUFFER, g->buffers[B_SUMSQ]);
        gl->GetBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, (GLsizeiptr)(nsum * sizeof(double)), r->sumsq);
    }
    res = check_gl(r, "reading the phasor sums back");
    lensrt_gl_release(gl);
    return status != LENSRT_SUCCESS ? status : res;
}

const lensrt_device_ops lensrt_device_gl = {"gl", gl_create, gl_begin, gl_pass, gl_end, gl_destroy, NULL /* no tiles */,
                                       NULL /* no cells integrator */, NULL,
                                       NULL /* no Fourier integrator */, NULL};
