/* bench.h: what the parts of lensrt-bench share: its options, the results per f-number
 * (the CPU repetitions and their tiles) and of the GL renders, timing, medians, render
 * stats and JSON helpers; and what bench_tiles.c (host-scheduled tiles) and bench_gl.c
 * (the GL device) offer lensrt-bench.c. */
#ifndef LENSRT_BENCH_H
#define LENSRT_BENCH_H

#include "lensrt.h"
#include "baseline.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define PI 3.14159265358979323846
#define MAX_F 8
#define MAX_WL 256
#define MAX_REP 32

/* The command line, with what follows from it (rw x rh: lensrt's pixels, gw x gh: GL's). */
typedef struct bench_options {
    const char *json, *table, *device_arg;
    long width, height, stride, rw, rh, gx, gy, n_wl, reps;
    double size_x, size_y, field_x, field_y, focus, base_seconds;
    double f_numbers[MAX_F];
    int n_f, head, threads;                  /* head: the headline f-number's index */
    long long samples, seed;
    /* GL: what to measure, where its context comes from, its pixel grid and sample counts */
    int do_cpu, do_gl;
    long gl_stride, gw, gh;
    long tile_w, tile_h;                     /* host-scheduled tiles (0 x 0: not measured) */
    long long gl_samples, gl_warmup;
    lensrt_gl_platform gl_platform;
} bench_options;

typedef struct f_result {
    double f_number;
    int reps;
    lensrt_render_stats stats;               /* of the last repetition */
    double sps[MAX_REP], seconds[MAX_REP];   /* lensrt, per repetition */
    baseline_result baseN[MAX_REP];          /* the baseline bracketing each repetition */
    double ratio[MAX_REP];
    baseline_result base1;                   /* single thread, before and after the repetitions */
    double sps_med, baseN_med, ratio_med;
    /* host-scheduled tiles, per repetition: splats per second, / run() of the repetition */
    double tile_sps[MAX_REP], tile_seconds[MAX_REP], tile_ratio[MAX_REP];
    int tile_identical;                      /* every repetition's image equal to run()'s */
    double tile_sps_med, tile_ratio_med, one_tile_seconds;
} f_result;

/* The GL measurement of one f-number. */
typedef struct gl_result {
    double f_number;
    double sps, seconds, splats;             /* of the timed run() */
    double setup_seconds;                    /* render_create and the warm-up run() */
    lensrt_render_stats stats;               /* after the timed run */
    baseline_result base;                    /* the baseline that bracketed it */
    double ratio_base, ratio_cpu;            /* ratio_cpu < 0: no CPU figure */
} gl_result;

/* The GL device and its measurements. */
typedef struct gl_bench {
    int ok;                                  /* a GL device to measure */
    lensrt_gl_info info;
    char why[1024];                          /* why GL was skipped or failed */
    gl_result res[MAX_F];
    int n, failed;                           /* GL results so far; a GL render failed */
} gl_bench;

/* ------------------------------------------------------------------ helpers ----- */

static inline double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static inline int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

static inline double median(const double *v, int n)
{
    double s[MAX_REP];
    int i;
    for (i = 0; i < n; i++) s[i] = v[i];
    qsort(s, (size_t)n, sizeof(double), cmp_double);
    return n % 2 ? s[n / 2] : 0.5 * (s[n / 2 - 1] + s[n / 2]);
}

/* The render's stats into a struct that may have been zeroed with its holder. */
static inline lensrt_result bench_stats(lensrt_render render, lensrt_render_stats *st)
{
    st->struct_size = sizeof *st;
    return lensrt_render_get_stats(render, st);
}

static inline int fail(lensrt_context ctx, const char *what, lensrt_result r)
{
    fprintf(stderr, "lensrt-bench: %s: %s: %s\n", what, lensrt_result_string(r), ctx ? lensrt_context_last_error(ctx) : "");
    return 1;
}

static inline void json_string(FILE *f, const char *s)
{
    fputc('"', f);
    for (; *s; s++) {
        if (*s == '"' || *s == '\\') fprintf(f, "\\%c", *s);
        else if ((unsigned char)*s < 0x20) fprintf(f, "\\u%04x", (unsigned)(unsigned char)*s);
        else fputc(*s, f);
    }
    fputc('"', f);
}

/* A number, or null where there is none (`--device gl` has no lensrt cpu figures). */
static inline void json_num(FILE *f, double v, int valid)
{
    if (valid && isfinite(v)) fprintf(f, "%.17g", v);
    else fputs("null", f);
}

static inline void json_list(FILE *f, const double *v, int n)
{
    int i;
    fputc('[', f);
    for (i = 0; i < n; i++) fprintf(f, "%s%.17g", i ? ", " : "", v[i]);
    fputc(']', f);
}

/* ------------------------------------------------ host-scheduled tiles (bench_tiles.c) ----- */

/* Repetition k's render `run` once more as tiles (same desc, same seed): its figures
 * into fr, "; N tiles ..." on stdout. Not LENSRT_SUCCESS: failed, and said so on stderr. */
lensrt_result tiles_repetition(lensrt_context ctx, const lensrt_render_desc *desc, lensrt_render run,
                               const bench_options *o, f_result *fr, int k);
/* After the repetitions of one f-number: one tile's cost and the medians. */
void tiles_f_number(lensrt_context ctx, const lensrt_render_desc *desc, const bench_options *o, f_result *fr);
void tiles_print(const bench_options *o, const f_result *res);
void tiles_json(FILE *f, const bench_options *o, const f_result *res);

/* ------------------------------------------------------------ the GL device (bench_gl.c) ----- */

/* Whether there is a GL device to measure (g->ok), else why not (g->why). Returns 0, or the
 * exit status when the bench cannot go on. */
int gl_probe(lensrt_context ctx, const bench_options *o, gl_bench *g);
void gl_print_setup(const bench_options *o, const gl_bench *g);
/* The GL render of one f-number, bracketed by the baseline; nonzero: out of memory in the
 * baseline. A failing GL render is recorded in g, not returned. */
int gl_f_number(lensrt_context ctx, const lensrt_render_desc *desc, const baseline_scene *sc, const bench_options *o,
                int center_pixel, const f_result *fr, gl_bench *g);
void gl_print(const bench_options *o, const gl_bench *g, const f_result *res);
void gl_json(FILE *f, const bench_options *o, const gl_bench *g);

#endif
