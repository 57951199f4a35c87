/* lensrt internals shared by the sources (not installed). */
#ifndef LENSRT_INTERNAL_H
#define LENSRT_INTERNAL_H

#include "io/image_io.h"
#include "lensrt.h"

#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#define LENSRT_ERROR_SIZE 1024

struct lensrt_context_s {
    lensrt_allocator allocator;
    void (*log_fn)(lensrt_log_level level, const char *message, void *user_data);
    void *user_data;
    int threads;
    lensrt_gl_platform gl_platform;
    /* The context's device (the GL device of gl/gl_device.c, made on first use) and
     * how to tear it down: both set by the device when it is made, and the hook called
     * once by lensrt_context_destroy. The context knows nothing of what a device is. */
    void *device;
    void (*device_destroy)(lensrt_context ctx, void *device);
    char error[LENSRT_ERROR_SIZE];
};

/* Allocation through the context's hooks (zeroed by lensrt_calloc). */
void *lensrt_alloc(lensrt_context ctx, size_t size);
void *lensrt_calloc(lensrt_context ctx, size_t count, size_t size);
void lensrt_free(lensrt_context ctx, void *ptr);

/* Record an error message in ctx and return `result` (printf-style). */
lensrt_result lensrt_fail(lensrt_context ctx, lensrt_result result, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;
void lensrt_log(lensrt_context ctx, lensrt_log_level level, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;
double lensrt_seconds(void);

/* ------------------------------------------------------------- polynomials ----- */

enum { LENSRT_TRANSFORM_AFFINE = 0, LENSRT_TRANSFORM_INVERSE_SQUARE = 1 };

typedef struct lensrt_input {
    char name[32];
    double lo, hi;        /* declared domain, raw units */
    int transform;        /* xhat = (w - c) / s with w = v or 1/v^2 */
    double c, s;
} lensrt_input;

typedef struct lensrt_poly {
    char name[32];
    char unit[32];            /* decoded, as the table writes it */
    int n_terms;
    unsigned char *exponents; /* n_terms * n_inputs */
    double *coefficients;     /* n_terms */
} lensrt_poly;

typedef struct lensrt_system {
    char name[16];            /* "P_o", "P_s" */
    int n_inputs, n_outputs;
    lensrt_input inputs[8];
    lensrt_poly outputs[8];
} lensrt_system;

/* P_clip's pairs (K <= 4: at most 8 outputs, as any system). */
#define LENSRT_MAX_CLIP_PAIRS 4

typedef struct lensrt_lens_s {
    lensrt_context ctx;       /* the context that owns the lens's memory */
    char name[256];
    char file[1024];
    int analytic;
    lensrt_analytic_lens model;
    /* fitted lenses */
    lensrt_system p_o, p_s;
    double focal_length_mm, stop_radius_max_mm, stop_radius_f1_mm;
    double housing_first_mm, housing_last_mm;
    double sensor_defocus_mm, front_focal_distance_mm, squeeze;
    /* trust lines (table version 3): worst PSF error against exact tracing, its cell */
    double psf_vs_exact, psf_target;
    char psf_vs_exact_cell[256];
    lensrt_lens_info info;
    /* ghost tables (issue 13, /work/notes/ghost-table.md): the two reflecting surfaces,
     * the file's label, which system is the ghost half (LENSRT_SYSTEM_OBJECT or _SENSOR),
     * and P_clip: the same inputs as that half, outputs in pairs (x, y), pair q passing
     * when x^2 + y^2 <= 1 (clip_stop[q] 0: a housing crossing over its radius) or when
     * (x, y) in mm lies inside the render's aperture (clip_stop[q] 1: a stop crossing).
     * n_clip_pairs 0: no P_clip (direct tables, and ghosts without clip outputs). */
    int ghost, ghost_first, ghost_second, ghost_side;
    char ghost_label[256];
    lensrt_system p_clip;
    int n_clip_pairs, n_stop_pairs;
    int clip_stop[LENSRT_MAX_CLIP_PAIRS];
    /* compiled-in lenses (lensrt_lens_load_compiled): the generated Horner evaluators;
     * NULL for lenses read from a table */
    const lensrt_compiled_lens *compiled;
} lensrt_lens_s;

/* --------------------------------------------------------------------- ABI ----- */

/* Read a caller's versioned struct (see the ABI rules in lensrt.h) into `full`, a
 * struct of this library's size: zeroed, then the bytes the caller's struct_size
 * covers. `what` names the argument in messages. */
lensrt_result lensrt_struct_in(lensrt_context ctx, const char *what, const void *src, void *full,
                               size_t full_size);
/* The same for an array of `count` versioned structs whose stride is the first
 * element's struct_size, into an array of this library's structs. */
lensrt_result lensrt_array_in(lensrt_context ctx, const char *what, const void *src, size_t count, void *full,
                              size_t full_size);
/* Write `full` into the caller's versioned struct, only as far as its struct_size. */
lensrt_result lensrt_struct_out(lensrt_context ctx, const char *what, void *dst, const void *full,
                                size_t full_size);

/* A bank's `registration` as its index names it: "chief", "window" or "channel". */
const char *lensrt_bank_registration(lensrt_bank bank);

/* Normalised value of input `in` for raw value v. */
double lensrt_normalise(const lensrt_input *in, double v);

/* ------------------------------------------------------------------ samples ----- */

/* Where aperture points are drawn from, uniformly: a disc (radius rx), a box
 * (|x| <= rx, |y| <= ry) or an interval on x (one-dimensional lenses). */
enum { LENSRT_REGION_DISC = 0, LENSRT_REGION_BOX = 1, LENSRT_REGION_INTERVAL = 2 };
typedef struct lensrt_region {
    int kind;
    double rx, ry;
} lensrt_region;

/* Area (or length) of the region: the Monte Carlo measure of one sample is this / N. */
double lensrt_region_measure(const lensrt_region *region);
/* Points first .. first + count - 1 of the sample sequence of (seed, wavelength), in
 * the region: xy[2 k], xy[2 k + 1] in mm. The same index always gives the same point. */
void lensrt_sample_aperture(lensrt_sampler sampler, uint64_t seed, int wavelength,
                            uint64_t first, uint64_t count, const lensrt_region *region,
                            double *xy);
/* Whether a stop point lies inside the aperture shape of bounding radius radius_mm. */
int lensrt_aperture_contains(const lensrt_aperture *ap, double radius_mm, double x, double y);

#endif /* LENSRT_INTERNAL_H */
