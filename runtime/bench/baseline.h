/* baseline.h: the baseline lensrt-bench measures lensrt against, the paper's algorithm
 * (section 3.2) as a plain scalar double loop over the generated Horner code of lens0001
 * (baseline.c). */
#ifndef LENSRT_BENCH_BASELINE_H
#define LENSRT_BENCH_BASELINE_H

#include <stdint.h>

typedef struct baseline_scene {
    double light_x, light_y;     /* direction cosines of the light */
    double focus_mm;             /* z_S */
    double stop_radius_mm;
    double housing_first_mm, housing_last_mm;
    int n_wl;
    const double *wavelengths_nm;
    int n_pix;
    const double *pix_xy;        /* sensor points (mm), x y pairs */
} baseline_scene;

typedef struct baseline_result {
    double seconds, splats, splats_per_second;
    long samples;
    int threads;
    double coherence_center;     /* |sum X| / sum |X| at the window centre, mean over wavelengths */
    double clipped;              /* splats clipped at either housing */
} baseline_result;

/* The paper's algorithm on `threads` OpenMP threads, `chunk` samples per round until
 * `min_seconds` have passed; seconds < 0 in the result: out of memory. */
baseline_result run_baseline(const baseline_scene *sc, int threads, int chunk, double min_seconds, uint64_t seed,
                             int center_pixel);

/* Two measurements of the same baseline as one. */
baseline_result combine(const baseline_result *a, const baseline_result *b);

/* A `lens KEY VALUE` line of a lensfit-poly-table (version 2): the lens facts the baseline
 * needs (housing_first_mm, housing_last_mm, stop_radius_f1_mm). 0: no such line or value. */
int table_lens_value(const char *path, const char *key, double *out);

/* The baseline's pixels: a gx x gy grid of the centres of a width x height frame of
 * size_x x size_y mm around center (mm, x y pairs; caller frees); the index of the pixel
 * at the window centre in *center_pixel. NULL: out of memory. */
double *baseline_grid(long gx, long gy, long width, long height, double size_x, double size_y, const double center[2],
                      int *center_pixel);

#endif
