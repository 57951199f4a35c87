/* test_ghost: ghost tables (issue 13; the contract is /work/notes/ghost-table.md and
 * fit/lensfit/codegen/table.py): a ghost (i, j) is a lens of its own whose table carries
 * `ghost` lines and a third system P_clip (the ghost side's inputs, outputs in pairs).
 * Tables are made in memory from the committed lens0001.table (argv[1]): its P_o and P_s
 * stay as they are, so a ghost table with a hand-made P_clip has a closed-form answer.
 *
 *   1. The reader: a ghost table's info (ghost, first, second, label, clip pairs); every
 *      malformed variant refused with a message naming the file, the line, the key and
 *      the value (lines out of order, side not P_o / P_s, i >= j, P_clip inputs differing
 *      from the ghost side's, odd or more than 8 outputs, names and units not in pairs,
 *      P_clip in a table without ghost lines, P_clip before P_o or P_s).
 * Usage: test_ghost LENS_TABLE */
#include "lensrt.h"

#include "check.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------ table text ----- */

/* A growing string. */
typedef struct text_buf {
    char *s;
    size_t n, cap;
} text_buf;

static void put(text_buf *b, const char *s, size_t n)
{
    if (b->n + n + 1 > b->cap) {
        b->cap = 2 * (b->n + n + 1);
        b->s = realloc(b->s, b->cap);
        if (!b->s) abort();
    }
    memcpy(b->s + b->n, s, n);
    b->n += n;
    b->s[b->n] = '\0';
}

static void puts_(text_buf *b, const char *s) { put(b, s, strlen(s)); }

/* The direct table, cut where ghost lines and P_clip go. */
static const char *g_text;
static size_t g_size, g_head;      /* g_head: bytes up to the end of the trust psf_target line */
static const char *g_inputs[2];    /* the 6 input lines of P_o and P_s */
static size_t g_inputs_len[2];
static double g_xa_s;              /* x_a's normalisation s (mm): xhat_a = x_a / s */

static int cut_direct(const char *text, size_t size)
{
    const char *p = strstr(text, "\ntrust psf_target "), *q;
    int k;
    if (!p) return 0;
    p = strchr(p + 1, '\n');
    if (!p) return 0;
    g_text = text;
    g_size = size;
    g_head = (size_t)(p + 1 - text);
    for (k = 0; k < 2; k++) {
        int i;
        p = strstr(text, k == 0 ? "\nsystem P_o 6 4\n" : "\nsystem P_s 6 4\n");
        if (!p) return 0;
        p = strchr(p + 1, '\n') + 1;
        for (q = p, i = 0; i < 6; i++) q = strchr(q, '\n') + 1;
        g_inputs[k] = p;
        g_inputs_len[k] = (size_t)(q - p);
    }
    // input x_a UNIT LO HI affine C S: the last field of P_o's fourth input line
    p = g_inputs[0];
    for (k = 0; k < 3; k++) p = strchr(p, '\n') + 1;
    q = strchr(p, '\n');
    while (q > p && q[-1] != ' ') q--;
    g_xa_s = strtod(q, NULL);
    return g_xa_s > 0;
}

/* One clip output: name, unit, then terms "e0 e1 e2 e3 e4 e5 coef" separated by ';'. */
typedef struct clip_out {
    const char *name, *unit, *terms;
} clip_out;

/* A ghost table: ghost lines (NULL: none; else the whole block, lines ending in \n),
 * P_o and P_s from the direct table, then P_clip with `side`'s inputs (0 P_o, 1 P_s)
 * and the n outputs (n 0: no P_clip). `clip_header` replaces "system P_clip 6 <n>"
 * when not NULL. The caller frees the result. */
static char *ghost_table(const char *ghost_lines, int side, const clip_out *outs, int n, const char *clip_header,
                         size_t *size)
{
    text_buf b = {NULL, 0, 0};
    char line[256];
    int k;
    put(&b, g_text, g_head);
    if (ghost_lines) puts_(&b, ghost_lines);
    put(&b, g_text + g_head, g_size - g_head);
    if (g_text[g_size - 1] != '\n') puts_(&b, "\n");
    if (n > 0 || clip_header) {
        if (clip_header) puts_(&b, clip_header);
        else {
            snprintf(line, sizeof line, "system P_clip 6 %d\n", n);
            puts_(&b, line);
        }
        put(&b, g_inputs[side], g_inputs_len[side]);
        for (k = 0; k < n; k++) {
            const char *t = outs[k].terms;
            int n_terms = 1;
            const char *c;
            for (c = t; *c; c++) n_terms += *c == ';';
            snprintf(line, sizeof line, "output %s %s %d\n", outs[k].name, outs[k].unit, n_terms);
            puts_(&b, line);
            while (*t) {
                const char *e = strchr(t, ';');
                size_t len = e ? (size_t)(e - t) : strlen(t);
                put(&b, t, len);
                puts_(&b, "\n");
                t += len + (e != NULL);
            }
        }
        puts_(&b, "end\n");
    }
    *size = b.n;
    return b.s;
}

static const char *const GHOST_P_O = "ghost first 0\nghost second 2\nghost label 0-2\nghost side P_o\n";
static const char *const GHOST_P_S = "ghost first 4\nghost second 8\nghost label 4-8\nghost side P_s\n";

/* ----------------------------------------------------------------- reader ----- */

/* Load text (NUL-terminated, freed here) and expect a parse error naming the file and
 * holding n1 and n2 (NULL: no second needle). */
static void expect_parse_error(lensrt_context ctx, const char *what, char *text, const char *n1, const char *n2)
{
    lensrt_lens lens = NULL;
    lensrt_result res = lensrt_lens_load_text(ctx, text, strlen(text), "ghost_4_8.table", &lens);
    CHECK(res == LENSRT_ERROR_PARSE, "%s: expected a parse error, got %s", what, lensrt_result_string(res));
    CHECK(strstr(lensrt_context_last_error(ctx), "ghost_4_8.table") != NULL, "%s: message '%s' names no file", what,
          lensrt_context_last_error(ctx));
    CHECK(strstr(lensrt_context_last_error(ctx), n1) != NULL, "%s: message '%s' lacks '%s'", what,
          lensrt_context_last_error(ctx), n1);
    if (n2)
        CHECK(strstr(lensrt_context_last_error(ctx), n2) != NULL, "%s: message '%s' lacks '%s'", what,
              lensrt_context_last_error(ctx), n2);
    if (lens) lensrt_lens_destroy(ctx, lens);
    free(text);
}

static void test_reader(lensrt_context ctx)
{
    const clip_out two[2] = {{"x_h0", "1", "0 0 0 1 0 0 0.5"}, {"y_h0", "1", "0 0 0 0 1 0 0.5"}};
    const clip_out four[4] = {{"x_h0", "1", "0 0 0 1 0 0 0.5"}, {"y_h0", "1", "0 0 0 0 1 0 0.5"},
                              {"x_s1", "mm", "0 0 0 1 0 0 3"}, {"y_s1", "mm%20(on%20the%20stop)", "0 0 0 0 1 0 3"}};
    lensrt_lens lens = NULL;
    lensrt_lens_info info = LENSRT_LENS_INFO_INIT;
    size_t n;
    char *t;

    // A ghost table on side P_s with a housing pair and a stop pair
    t = ghost_table(GHOST_P_S, 1, four, 4, NULL, &n);
    CHECK_OK(ctx, lensrt_lens_load_text(ctx, t, n, "ghost_4_8.table", &lens));
    if (lens) {
        CHECK_OK(ctx, lensrt_lens_get_info(lens, &info));
        CHECK(info.ghost == 1 && info.ghost_first == 4 && info.ghost_second == 8 && info.ghost_clip_pairs == 2 &&
                  info.ghost_label && strcmp(info.ghost_label, "4-8") == 0,
              "ghost info: ghost %d, first %d, second %d, label '%s', pairs %d", info.ghost, info.ghost_first,
              info.ghost_second, info.ghost_label ? info.ghost_label : "(null)", info.ghost_clip_pairs);
        lensrt_lens_destroy(ctx, lens);
    }
    free(t);
    // A ghost without P_clip (K = 0) on side P_o; the direct table reads as no ghost
    t = ghost_table(GHOST_P_O, 0, NULL, 0, NULL, &n);
    CHECK_OK(ctx, lensrt_lens_load_text(ctx, t, n, "ghost_0_2.table", &lens));
    if (lens) {
        CHECK_OK(ctx, lensrt_lens_get_info(lens, &info));
        CHECK(info.ghost == 1 && info.ghost_first == 0 && info.ghost_second == 2 && info.ghost_clip_pairs == 0 &&
                  strcmp(info.ghost_label, "0-2") == 0,
              "ghost without P_clip: ghost %d, first %d, second %d, pairs %d", info.ghost, info.ghost_first,
              info.ghost_second, info.ghost_clip_pairs);
        lensrt_lens_destroy(ctx, lens);
    }
    free(t);
    CHECK_OK(ctx, lensrt_lens_load_text(ctx, g_text, g_size, "lens0001.table", &lens));
    if (lens) {
        CHECK_OK(ctx, lensrt_lens_get_info(lens, &info));
        CHECK(info.ghost == 0 && info.ghost_clip_pairs == 0 && info.ghost_label && info.ghost_label[0] == '\0',
              "direct table: ghost %d, pairs %d", info.ghost, info.ghost_clip_pairs);
        lensrt_lens_destroy(ctx, lens);
    }

    // Ghost lines: order, values, place
    expect_parse_error(ctx, "out of order",
                       ghost_table("ghost second 8\nghost first 4\nghost label 4-8\nghost side P_s\n", 1, two, 2, NULL,
                                   &n),
                       "expected 'ghost first <i>'", "found ghost second '8'");
    expect_parse_error(ctx, "bad side",
                       ghost_table("ghost first 4\nghost second 8\nghost label 4-8\nghost side P_x\n", 1, two, 2, NULL,
                                   &n),
                       "ghost side 'P_x'", "neither P_o nor P_s");
    expect_parse_error(ctx, "i = j",
                       ghost_table("ghost first 4\nghost second 4\nghost label 4-4\nghost side P_s\n", 1, two, 2, NULL,
                                   &n),
                       "ghost second '4'", "i < j");
    expect_parse_error(ctx, "i > j",
                       ghost_table("ghost first 8\nghost second 4\nghost label 8-4\nghost side P_s\n", 1, two, 2, NULL,
                                   &n),
                       "ghost second '4'", "ghost first 8");
    expect_parse_error(ctx, "negative index",
                       ghost_table("ghost first -1\nghost second 4\nghost label x\nghost side P_s\n", 1, two, 2, NULL,
                                   &n),
                       "ghost first '-1'", "surface index");
    expect_parse_error(ctx, "missing side",
                       ghost_table("ghost first 4\nghost second 8\nghost label 4-8\n", 1, two, 2, NULL, &n),
                       "missing ghost line", "ghost side <P_o|P_s>");
    expect_parse_error(ctx, "twice",
                       ghost_table("ghost first 4\nghost first 4\n", 1, two, 2, NULL, &n), "ghost first '4' appears twice",
                       NULL);
    expect_parse_error(ctx, "extra field",
                       ghost_table("ghost first 4 5\n", 1, two, 2, NULL, &n), "expected 'ghost first <i>' (3 fields)",
                       NULL);
    {
        // Ghost lines before the trust lines
        text_buf b = {NULL, 0, 0};
        const char *trust = strstr(g_text, "\ntrust psf_vs_exact ") + 1;
        put(&b, g_text, (size_t)(trust - g_text));
        puts_(&b, GHOST_P_S);
        put(&b, trust, g_size - (size_t)(trust - g_text));
        expect_parse_error(ctx, "before trust", b.s, "ghost first '4' before the trust lines end", NULL);
    }
    {
        // Ghost lines after a system
        char *u = ghost_table(NULL, 1, NULL, 0, NULL, &n);
        text_buf b = {NULL, 0, 0};
        put(&b, u, n);
        puts_(&b, GHOST_P_S);
        free(u);
        expect_parse_error(ctx, "after a system", b.s, "ghost first '4' after a system", NULL);
    }

    // P_clip: only in a ghost table, third, with the ghost side's inputs, in pairs
    expect_parse_error(ctx, "P_clip without ghost lines", ghost_table(NULL, 1, two, 2, NULL, &n),
                       "system P_clip '2' in a table without ghost lines", NULL);
    expect_parse_error(ctx, "P_clip inputs of the other side", ghost_table(GHOST_P_S, 0, two, 2, NULL, &n),
                       "input 0 'x_O'", "differs from the ghost side P_s's 'x_S'");
    {
        // One input's domain changed (x_a's hi and s on side P_o)
        const clip_out o[2] = {{"x_h0", "1", "0 0 0 1 0 0 0.5"}, {"y_h0", "1", "0 0 0 0 1 0 0.5"}};
        char *u = ghost_table(GHOST_P_O, 0, o, 2, NULL, &n);
        char *clip = strstr(u, "system P_clip");
        char *xa = strstr(clip, "\ninput x_a ");
        char *hi;
        char old[128];
        text_buf b = {NULL, 0, 0};
        // x_a's domain and normalisation (lo hi transform c s) widened to 15 mm
        snprintf(old, sizeof old, "%.17g %.17g affine 0 %.17g", -g_xa_s, g_xa_s, g_xa_s);
        hi = strstr(xa, old);
        CHECK(hi != NULL, "x_a's line '%s' not found", old);
        if (hi) {
            put(&b, u, (size_t)(hi - u));
            puts_(&b, "-15 15 affine 0 15");
            put(&b, hi + strlen(old), n - (size_t)(hi + strlen(old) - u));
            expect_parse_error(ctx, "P_clip domain", b.s, "input 3 'x_a' [-15, 15]",
                               "differs from the ghost side P_o's 'x_a'");
        } else {
            free(b.s);
        }
        free(u);
    }
    expect_parse_error(ctx, "odd outputs", ghost_table(GHOST_P_S, 1, two, 1, NULL, &n), "system P_clip: 1 outputs",
                       "even count");
    expect_parse_error(ctx, "more than 8 outputs", ghost_table(GHOST_P_S, 1, two, 0, "system P_clip 6 10\n", &n),
                       "system P_clip: 10 outputs", "at most 4 clip tests");
    {
        const clip_out bad_name[2] = {{"x_q0", "1", "0 0 0 1 0 0 0.5"}, {"y_q0", "1", "0 0 0 0 1 0 0.5"}};
        const clip_out bad_pair[2] = {{"x_h0", "1", "0 0 0 1 0 0 0.5"}, {"y_h1", "1", "0 0 0 0 1 0 0.5"}};
        const clip_out mixed[2] = {{"x_h0", "1", "0 0 0 1 0 0 0.5"}, {"y_s0", "mm", "0 0 0 0 1 0 0.5"}};
        const clip_out bad_unit[2] = {{"x_s2", "1", "0 0 0 1 0 0 0.5"}, {"y_s2", "1", "0 0 0 0 1 0 0.5"}};
        const clip_out bad_unit_h[2] = {{"x_h3", "mm", "0 0 0 1 0 0 0.5"}, {"y_h3", "mm", "0 0 0 0 1 0 0.5"}};
        const clip_out swapped[2] = {{"y_h0", "1", "0 0 0 1 0 0 0.5"}, {"x_h0", "1", "0 0 0 0 1 0 0.5"}};
        expect_parse_error(ctx, "output name", ghost_table(GHOST_P_S, 1, bad_name, 2, NULL, &n), "output 0 'x_q0'",
                           "expected x_h<k>");
        expect_parse_error(ctx, "pair index", ghost_table(GHOST_P_S, 1, bad_pair, 2, NULL, &n), "output 1 'y_h1'",
                           "expected its pair y_h0");
        expect_parse_error(ctx, "pair kind", ghost_table(GHOST_P_S, 1, mixed, 2, NULL, &n), "output 1 'y_s0'",
                           "expected its pair y_h0");
        expect_parse_error(ctx, "stop unit", ghost_table(GHOST_P_S, 1, bad_unit, 2, NULL, &n),
                           "pair x_s2, y_s2 has units '1', '1'", "expected 'mm'");
        expect_parse_error(ctx, "housing unit", ghost_table(GHOST_P_S, 1, bad_unit_h, 2, NULL, &n),
                           "pair x_h3, y_h3 has units 'mm', 'mm'", "expected '1'");
        expect_parse_error(ctx, "y before x", ghost_table(GHOST_P_S, 1, swapped, 2, NULL, &n), "output 0 'y_h0'",
                           NULL);
    }
    {
        // P_clip before P_s
        char *u = ghost_table(GHOST_P_S, 1, two, 2, NULL, &n);
        char *clip = strstr(u, "system P_clip");
        char *ps = strstr(u, "\nsystem P_s ") + 1;
        text_buf b = {NULL, 0, 0};
        put(&b, u, (size_t)(ps - u));
        put(&b, clip, n - (size_t)(clip - u));
        put(&b, ps, (size_t)(clip - ps));
        free(u);
        expect_parse_error(ctx, "P_clip before P_s", b.s, "system P_clip before system P_s", "comes third");
    }
    {
        // Two P_clip systems
        char *u = ghost_table(GHOST_P_S, 1, two, 2, NULL, &n);
        char *clip = strstr(u, "system P_clip");
        text_buf b = {NULL, 0, 0};
        put(&b, u, n);
        put(&b, clip, n - (size_t)(clip - u));
        free(u);
        expect_parse_error(ctx, "P_clip twice", b.s, "system P_clip appears twice", NULL);
    }
}

int main(int argc, char **argv)
{
    lensrt_context_init init = LENSRT_CONTEXT_INIT;
    lensrt_context ctx = NULL;
    char *text;
    size_t size;
    if (argc != 2) {
        fprintf(stderr, "usage: test_ghost LENS_TABLE\n");
        return 2;
    }
    text = read_text(argv[1], &size);
    if (!text || !cut_direct(text, size)) {
        fprintf(stderr, "test_ghost: cannot read or cut %s\n", argv[1]);
        return 1;
    }
    if (lensrt_context_create(&init, &ctx) != LENSRT_SUCCESS) return 1;
    test_reader(ctx);
    lensrt_context_destroy(ctx);
    free(text);
    printf("test_ghost: %d checks, %d failures\n", g_checks, g_failures);
    return g_failures != 0;
}
