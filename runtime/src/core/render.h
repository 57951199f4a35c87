/* The render object (internal): the scene, what was prepared from it, the phasor sums.
 *
 * Every part of a render reads it: core/ (create, run, results), lens/ (the lens kinds),
 * the devices (cpu/, gl/) and io/. What differs by lens kind goes through the render's
 * lens ops (lens/lens.h), what differs by device through its device ops (core/device.h). */
#ifndef LENSRT_RENDER_H
#define LENSRT_RENDER_H

#include "../internal.h"

#define LENSRT_PASS 16384 /* samples per wavelength and pass (a multiple of LENSRT_BLOCK) */
/* Samples summed together before they reach the double sums, on every device (the CPU
 * kernel's block, the GL path's float partial sums): runs split at multiples of it give
 * the same sums bit for bit, and runs split inside a block too, since the next run
 * draws that block again whole (lensrt_render_run, lensrt_tail_rewind). */
#define LENSRT_BLOCK 256
#define LENSRT_NM_PER_MM 1e6

/* The render's aperture as a test of a ghost's further stop crossings (P_clip pairs
 * x_s<c>, y_s<c>), exactly the set lensrt_aperture_contains (core/sampler.c) defines,
 * written so that a kernel tests it with a few multiply-adds per point and no atan2:
 *   every shape:  x^2 + y^2 <= r2 (the stop radius squared; the slits: a circle around
 *                 them, which every point of theirs passes);
 *   blades:       for each edge k, a r^2 + gx[k] x + gy[k] y <= c[k]. A straight edge is
 *                 the half-plane n_k . p <= apothem (a = 0, g = n_k, c = apothem); a
 *                 curved one the disc through the edge's two vertices whose centre lies
 *                 on its normal at d = apothem + sag - rho, |p - d n_k| <= rho, divided
 *                 by 2 rho so that it stays well conditioned as rho grows:
 *                 a = 1 / (2 rho), g = (1 - (apothem + sag) / rho) n_k,
 *                 c = (apothem + sag)(1 - (apothem + sag) / (2 rho)).
 *                 The polygon is the intersection of the R-disc and the n edges' sets
 *                 (each edge's disc reaches beyond the R-disc only inside its own sector,
 *                 which is the sector lensrt_aperture_contains tests it in);
 *   slits:        |y| <= half_y and |x - centre[i]| <= half_x for one of n slits.
 * Float copies (f_*) serve the float kernels. */
#define LENSRT_STOP_CIRCLE 0
#define LENSRT_STOP_BLADES 1
#define LENSRT_STOP_SLIT 2
typedef struct lensrt_stop_shape {
    int kind, n;
    double r2, a, gx[LENSRT_MAX_BLADES], gy[LENSRT_MAX_BLADES], c[LENSRT_MAX_BLADES];
    double nx[LENSRT_MAX_BLADES], ny[LENSRT_MAX_BLADES]; /* blades: outward edge normals */
    double apothem, reach;  /* blades: the straight polygon's apothem; apothem + sag (the edges' farthest) */
    double half_x, half_y, centre[2];
    double scale;           /* the shape's smallest size (mm): the slit's half width, else the radius */
    float f_r2, f_a, f_gx[LENSRT_MAX_BLADES], f_gy[LENSRT_MAX_BLADES], f_c[LENSRT_MAX_BLADES];
    float f_half_x, f_half_y, f_centre[2];
} lensrt_stop_shape;

/* The stop test of `ap` with stop radius `radius_mm` (core/stop_shape.c). */
void lensrt_stop_shape_init(const lensrt_aperture *ap, double radius_mm, lensrt_stop_shape *s);

/* Whether (x, y) passes the stop test, in double. */
int lensrt_stop_shape_contains(const lensrt_stop_shape *s, double x, double y);

/* What the stop test says of every point of the box |x - cx| <= bx, |y - cy| <= by:
 * 1 every point passes, 0 none does, 2 it cannot tell (test each point). */
int lensrt_stop_shape_box(const lensrt_stop_shape *s, double cx, double bx, double cy, double by);

struct lensrt_lens_ops;   /* lens/lens.h */
struct lensrt_device_ops; /* core/device.h */
struct lensrt_tiles;      /* core/tiles.h */
struct lensrt_mesh;       /* core/cells.h */
struct lensrt_cells_job;  /* core/cells.h */
struct lensrt_fourier_job; /* core/fourier.h */

/* A polynomial in (x_S, y_S) and the stop monomials, for one output and wavelength:
 * sum_t coef[t] * xS^ix[t] * yS^iy[t] * mono[slot[t]] (normalised x_S, y_S). */
typedef struct lensrt_pixel_poly {
    int n;
    unsigned char *ix, *iy;
    int *slot;
    double *coef;
} lensrt_pixel_poly;

struct lensrt_render_s {
    lensrt_context ctx;
    lensrt_lens lens;
    const struct lensrt_lens_ops *lens_ops;     /* the lens kind's behaviour */
    const struct lensrt_device_ops *device;     /* where passes run */
    void *device_data;                          /* the device's state for this render */
    lensrt_render_desc desc;      /* lights and wavelengths point at the copies below */
    lensrt_light *lights;
    double *wavelengths;
    int n_lights, n_wl;
    /* The grid of points the render computes (issue 26): every integrator, device and
     * tile works on it. With the box pixel filter each image pixel is sx x sy of its
     * points (the midpoint rule on the pixel's area: point (i sx + k, j sy + m) lies at
     * (k + 1/2) / sx, (m + 1/2) / sy of pixel (i, j)), and the image averages their
     * intensities (lensrt_render_image); sx = sy = 1 is the point filter's grid, the
     * pixel centres. width, height, pitch_x, pitch_y, xs, ys are the grid's;
     * out_width, out_height, pixel_x, pixel_y the image's. */
    int width, height;            /* grid points per row and column: out_width * sx, out_height * sy */
    double pitch_x, pitch_y;      /* mm between grid points: pixel_x / sx, pixel_y / sy */
    double *xs, *ys;              /* grid point centres (mm) */
    int pixel_filter, sx, sy;     /* lensrt_pixel_filter; sub-pixel points per pixel and axis */
    int out_width, out_height;    /* the image's pixels (the description's sensor) */
    double pixel_x, pixel_y;      /* the image's pixel pitch (mm) */
    double stop_radius, f_number;
    lensrt_region region;
    double measure;               /* area (or length) of the sampled region */
    double mono_radius;           /* stop monomials use u = x_a / mono_radius */
    /* stop monomials: slot k is u^m v^n, m = slot_m[k], n = slot_n[k] */
    int degree, n_slots;
    /* Rows of a sample block (set by the lens kind's prepare): fitted lenses, the stop
     * monomials, then (use_basis) the phase basis: g_j = sum_k V[k][j] u^m_k v^n_k over
     * the non-constant slots, where V holds the eigenvectors of the window's
     * phase-coefficient Gram matrix, so that a few g_j carry the phase of every pixel of
     * a small window; analytic lenses, the sample's x and y. double_rows: rows, phases
     * and amplitudes are kept in double (precision DOUBLE; free space always). */
    int n_rows, use_basis, double_rows;
    /* bases per wavelength and the output of each (4 + o: a ghost's P_clip output o on
     * side P_s, CPU only), and the first row of each basis's functions in a sample block
     * (the phase's at n_slots, the transmittance's after its n_slots - 1 rows, a clip
     * output's after the rows its predecessors compute at most) */
    int n_bases, basis_output[4 + 2 * LENSRT_MAX_CLIP_PAIRS], row_base[4 + 2 * LENSRT_MAX_CLIP_PAIRS];
    double *basis;                /* [w][b][(n_slots - 1)^2], V[(k - 1) * (n_slots - 1) + j];
                                     CPU: b = 0 phase (waves), 1 transmittance; GL: b = output */
    double *basis_t;              /* the same transposed: V_T[j * (n_slots - 1) + (k - 1)] */
    double *basis_l1;             /* [w][b][j]: the l1 norm of basis vector j */
    int *basis_rank;              /* [w][b]: rows computed per sample */
    int slot_m[136], slot_n[136];
    /* fitted lenses: P_s per wavelength and output (x_i, y_i, tau_i, phi_i), and P_o per
     * light, wavelength, output and slot (already specialised to the light) */
    lensrt_pixel_poly *ps;        /* [w * 4 + o] */
    lensrt_pixel_poly *ps_grad;   /* [w]: ps[w * 4 + 3]'s terms of slots 1 and 2, in order
                                     (the phase gradient of the Huygens amplitude) */
    double *po;                   /* [((l * n_wl + w) * LENSRT_PO_OUTPUTS + o) * n_slots + slot] */
    double *light_x, *light_y, *light_d; /* direction cosines and distance (mm, 0: inf) */
    /* ghost tables (issue 13): P_clip's pairs, on the ghost side (clip_side: 0 P_o, 1 P_s).
     * Pair q passes when x^2 + y^2 <= clip_limit[q]^2 (1 for a housing, the stop radius
     * for a stop crossing). Side P_o: clip_o per light, wavelength, output and slot like
     * po; side P_s: clip_s per wavelength and output like ps. n_clip_pairs 0: none (every
     * direct render), and nothing below is allocated. */
    int n_clip_pairs, clip_side;
    double clip_limit[LENSRT_MAX_CLIP_PAIRS];
    /* clip_shaped[q]: pair q is a stop crossing and the aperture is not a circle, so it
     * passes when `stop` says so (clip_limit[q] is then sqrt(stop.r2)); 0 for every
     * housing pair and for a round stop (the circle test above, as it always was) */
    int clip_shaped[LENSRT_MAX_CLIP_PAIRS];
    lensrt_stop_shape stop;
    double *clip_o;               /* [((l * n_wl + w) * 2 n_clip_pairs + o) * n_slots + slot] */
    lensrt_pixel_poly *clip_s;    /* [w * 2 n_clip_pairs + o] */
    /* phasor sums: [((l * n_wl + w) * npix + p) * 2 + re/im]; sum of |X|^2 per
     * (l, w, p) when the estimator needs it */
    double *sum, *sumsq;
    uint64_t samples;             /* N per wavelength */
    uint64_t splats;
    /* A run that ends inside a block of LENSRT_BLOCK samples (run() or a tile session,
     * core/render.c): the sums before that last, partial block (tail_sum, tail_sumsq),
     * the block's first sample index tail_first and the samples after it, tail_samples.
     * Valid while samples == tail_samples (0: none); the next run then puts those sums
     * back and draws the block again from tail_first, so that the block's samples are
     * added together, as one run adds them (run(N); run(M) equals run(N + M) bit for
     * bit). Everything else that changes the sums forgets it (lensrt_tail_forget). */
    double *tail_sum, *tail_sumsq;
    uint64_t tail_first, tail_samples;
    /* phasor_file.c's record of the samples the sums hold: runs[i] = {seed, first, end}
     * of sample indices; samples past runs_samples came from run() with desc.seed at
     * indices [runs_samples, samples) and are recorded on the next save or merge */
    uint64_t runs[64][3];
    int n_runs;
    uint64_t runs_samples;
    double seconds;
    /* The cells integrator (core/cells.h, lensrt_render_integrate): 0 while the sums
     * hold Monte Carlo samples (or none); else the rings of the mesh whose field the sums
     * hold (then samples is 1 and sum is the field divided by measure), its estimated
     * error (-1: none) and a copy of that field, the coarse level of the next, finer call */
    int cells_rings;
    double cells_error;
    double *cells_field, *cells_coarse; /* the fields of rings and rings / 2 (NULL: none) */
    /* The Fourier integrator (core/fourier.h, lensrt_render_integrate_fourier): the nodes
     * per side of the rule whose field the sums hold (0: none; cells_rings is then 0 and
     * cells_error holds its estimate), and the finer field of its estimate with its nodes
     * (the next, finer call's coarse level) */
    int fourier_nodes, fourier_fine_nodes;
    double *fourier_fine;
    struct lensrt_tiles *tiles;   /* the open tile session, or NULL */
    /* pruning statistics of the last pass: sums over (pixel, wavelength) */
    double stat_terms, stat_clip, stat_tau, stat_dark, stat_count;
};

/* The partial block's sums of the last run are no longer the sums' past (load, merge,
 * splat_points, an integral): the next run starts its blocks where the sums end. */
static inline void lensrt_tail_forget(lensrt_render r) { r->tail_samples = 0; }
/* When the last run ended inside a block and the sums are still its: the sums put back
 * as they were before that block, samples set back to its first index, and the block's
 * samples returned (to be drawn again); else 0, nothing changed. The tail is forgotten. */
uint64_t lensrt_tail_rewind(lensrt_render r);

/* The sums' length in doubles: re and im per light, wavelength and grid point. */
static inline size_t lensrt_sums_count(const lensrt_render r)
{
    return 2 * (size_t)r->n_lights * (size_t)r->n_wl * (size_t)r->width * (size_t)r->height;
}

/* What the integrals share with tile sessions (core/integral.c). */

/* LENSRT_SUCCESS unless the sums hold a cells integral (lensrt_render_integrate), which
 * samples cannot be added to, saved or merged with: then the refusal naming `what`. */
lensrt_result lensrt_cells_idle(lensrt_render r, const char *what);

/* The checks of a cells integral (lensrt_render_integrate, a cells tile session) of
 * `rings` rings, with or without an estimate: a failure with its message naming what. */
lensrt_result lensrt_cells_check(lensrt_render r, const char *what, int rings, int estimate);

/* The sums become field Uf of `rings` rings (checked finite), with the estimate from the
 * fields of rings / 2 and rings / 4 (Uc, Uc2; NULL: none) into *error_estimate. On
 * success the render owns Uf and Uc (kept for a later, doubled call); on failure the
 * caller still does. */
lensrt_result lensrt_cells_finish(lensrt_render r, int rings, double *Uf, double *Uc, const double *Uc2,
                                  double *error_estimate);

/* The sums become the Fourier integrator's field U of `nodes` nodes per side (checked
 * finite), with the estimate ||I(U) - I(Ufine)|| / ||I(Ufine)|| (Ufine NULL: none, -1)
 * into *error_estimate; on success the render owns Ufine (the next call's coarse level)
 * and U is the caller's still. */
lensrt_result lensrt_fourier_finish(lensrt_render r, int nodes, const double *U, double *Ufine, int fine_nodes,
                                    double *error_estimate);

/* The checks of a Fourier integral (lensrt_render_integrate_fourier, a Fourier tile
 * session) of `nodes` nodes, with or without an estimate: a failure naming what. */
lensrt_result lensrt_fourier_check(lensrt_render r, const char *what, int nodes, int estimate);
/* The Fourier integrator's nodes for nodes 0 (lensrt_render_integrate_fourier), for an
 * error target (0: the default rule; lensrt_render_fourier_nodes): a pilot rule's
 * measure of the phase, or the refusal (cells is the cheaper) with its message. */
lensrt_result lensrt_fourier_auto_nodes(lensrt_render r, double target, int *nodes);

/* The stop monomials of the render's slots at stop point (x, y) mm (mono, n_slots of them)
 * and, where dx and dy are not NULL, their derivatives by x and y per mm (image_point.c). */
void lensrt_stop_monomials(const lensrt_render r, double x, double y, double *mono, double *dx, double *dy);

/* The sub-pixel points per pixel and axis of the box filter (core/pixel_area.c): the
 * description's counts, or where 0 the automatic rule from the render's prepared lens
 * (README "The model"); 1 x 1 for the point filter. */
lensrt_result lensrt_pixel_samples_choose(lensrt_render r, int *sx, int *sy);

/* The largest spread of the ray directions (direction cosines, per axis) reaching the
 * window's pixels from the whole aperture, over the render's wavelengths: what bounds
 * the intensity's bandwidth (core/pixel_area.c). */
void lensrt_direction_spread(lensrt_render r, double spread[2]);

/* The grid index of sub-pixel point (k, m) of image pixel (i, j) (k < sx, m < sy). */
static inline size_t lensrt_grid_point(const struct lensrt_render_s *r, int i, int j, int k, int m)
{
    return (size_t)(j * r->sy + m) * (size_t)r->width + (size_t)(i * r->sx + k);
}

/* "sobol", "random" or "stratified" (core/sampler.c). */
const char *lensrt_sampler_name(lensrt_sampler s);

#endif /* LENSRT_RENDER_H */
