/* Lens kinds (internal): what a render does differently for each kind of lens.
 *
 * A fitted lens (lens/fitted.c) is the polynomials P_o and P_s of a coefficient table;
 * an analytic lens (lens/analytic.c) is free space after the stop, with a perfect thin
 * lens in it or not. Each kind is one table of operations; lensrt_lens_ops_of() is the
 * only place that asks which kind a lens is, and a render keeps the answer
 * (r->lens_ops). The scene checks, the choice of stop, the preparation, the host's
 * per-sample phase and amplitude and the chief ray go through the table.
 *
 * What happens after the stop, per pixel and splat, is the devices' work (the CPU
 * kernels, the GLSL shaders): a kind names the transport its devices evaluate, and a
 * device implements each transport once, whatever kinds share it. */
#ifndef LENSRT_LENS_H
#define LENSRT_LENS_H

#include "../core/render.h"

typedef enum lensrt_transport {
    /* P_s specialised per pixel to stop-monomial coefficients (rows: the monomials and
     * the window's basis functions); pruned terms, inner-pupil clip, Van Vleck amplitude */
    LENSRT_TRANSPORT_POLYNOMIAL = 0,
    /* free space from the stop to the sensor (rows: the sample's x and y, in double);
     * the Rayleigh-Sommerfeld kernel, or cos(theta) / sqrt(lambda r) in one dimension */
    LENSRT_TRANSPORT_FREE_SPACE = 1
} lensrt_transport;
#define LENSRT_TRANSPORT_COUNT 2

/* Where one sample's rows go: row k at f[k * stride], or at d[k * stride] when the
 * render keeps rows in double (r->double_rows). */
typedef struct lensrt_rows {
    float *f;
    double *d;
    size_t stride;
} lensrt_rows;

typedef struct lensrt_lens_ops {
    const char *kind;               /* "fitted", "analytic" */
    lensrt_transport transport;
    /* 1 when the lens holds only inside its stop radius (a fit): slits must lie within */
    int slits_within_stop;
    /* Whether the aperture is a line and the sensor one row. */
    int (*one_dimensional)(lensrt_lens lens);
    /* The range the default wavelengths are spread over (nm). */
    void (*wavelength_range)(lensrt_lens lens, double *lo_nm, double *hi_nm);
    /* Light i, already checked to be finite and in front (direction cosines x, y), against
     * what the lens covers. */
    lensrt_result (*check_light)(lensrt_render r, const lensrt_lens_info *info, int i, double x, double y);
    /* r->stop_radius and r->f_number from the aperture description. */
    lensrt_result (*choose_stop)(lensrt_render r, const lensrt_lens_info *info);
    /* The window of pixel centres (r->xs, r->ys) against what the lens covers. */
    lensrt_result (*check_window)(lensrt_render r, const lensrt_lens_info *info);
    /* Everything computed once per render (after the region is chosen): n_rows,
     * double_rows, and for fitted lenses the specialised polynomials and the bases. */
    lensrt_result (*prepare)(lensrt_render r);
    /* The rows of the sample at stop point (x, y) for wavelength w (padding: x = y = 0);
     * mono[0 .. n_slots) receives the stop monomials that sample_wave reads. */
    void (*sample_rows)(const lensrt_render r, int w, double x, double y, double *mono, const lensrt_rows *rows);
    /* Light l's wave at the sample: *amp (on entry the light's amplitude, 0 outside the
     * aperture) times what reaches the stop, and *opl the optical path (mm) whose
     * fraction of a wavelength is the phase (the whole path with precision NAIVE_FLOAT). */
    void (*sample_wave)(const lensrt_render r, int w, int l, double x, double y, const double *mono, double *amp,
                        double *opl);
    /* lensrt_lens_image_point once its arguments are checked (lx, ly: the light's
     * direction cosines). */
    lensrt_result (*image_point)(lensrt_context ctx, lensrt_lens lens, const lensrt_light *light, double lx, double ly,
                                 double wavelength_nm, double focus_offset_mm, double xy_mm[2]);
    /* The table file recorded in image metadata (NULL: none). */
    const char *(*table_file)(lensrt_lens lens);
    /* The cells integrator's view of light l's wave at a stop point (core/cells.h): as
     * sample_wave, but the amplitude is never zeroed by a clip; instead each clip before
     * the stop is a level function (>= 0: the path passes, continuous, mm-like) written
     * to levels[] (at most 1 + LENSRT_MAX_CLIP_PAIRS); returns their count. NULL: the
     * kind has no such clips, and sample_wave serves. */
    int (*sample_levels)(const lensrt_render r, int w, int l, const double *mono, double *amp, double *opl,
                         double *levels);
} lensrt_lens_ops;

extern const lensrt_lens_ops lensrt_lens_fitted, lensrt_lens_analytic;

/* The operations of the lens's kind (lens/kind.c). */
const lensrt_lens_ops *lensrt_lens_ops_of(lensrt_lens lens);

#endif /* LENSRT_LENS_H */
