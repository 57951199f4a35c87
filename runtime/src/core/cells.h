/* The deterministic aperture integrator (internal, issue 22): cells instead of samples.
 *
 * For one pixel, light and wavelength the field is U = integral over the aperture of
 * A(a) exp(i 2 pi Phi(a)) da, with A and Phi smooth. Monte Carlo needs ever more samples
 * as Phi swings over the aperture. Here the aperture is meshed into triangles that follow
 * its boundary (circle, straight or curved blades, slits), Phi and log A are interpolated
 * linearly on each triangle from their values at its vertices, and the integral of the
 * interpolant over the triangle is taken in closed form (a divided difference of the
 * exponential). A triangle may therefore span many waves of phase tilt: only the phase
 * curvature limits its size, and the error falls as h^2 (h: the triangle size).
 *
 * Clips that depend on the light or the pixel (outer and inner pupil, a ghost's P_clip)
 * are level functions, positive where a path passes, known at the vertices: a triangle
 * they cross is cut along the zero line of their linear interpolants, to the same order
 * h^2 as the interior, never dropped or kept whole. */
#ifndef LENSRT_CELLS_H
#define LENSRT_CELLS_H

#include "render.h"

/* Where lensrt_tri_integral's series take over (max norm of the differences): every
 * node within SERIES_G of z0 (the series of G), two within SERIES_D (phi1's series). */
#define LENSRT_CELLS_SERIES_G 0.1
#define LENSRT_CELLS_SERIES_D 0.03125

/* Level functions a triangle may be cut by: the outer pupil and P_clip pairs on side P_o
 * (per light), the inner pupil and P_clip pairs on side P_s (per pixel). */
#define LENSRT_CELLS_MAX_LEVELS (2 + 2 * LENSRT_MAX_CLIP_PAIRS)

/* A triangulation of the aperture in mm on the stop. The fan shapes (circle, blades) are
 * `sectors` triangles from the centre to the boundary, each mapped from the lattice of
 * `rings` rows by x = rho * B(theta) (rho = row / rings, B the boundary point at
 * parameter theta along the sector's edge: a chord, a blade's arc or the circle's), so
 * that the boundary vertices lie on the true boundary and the map is smooth; slits are
 * rectangles of right triangles. Vertices on the sectors' shared edges are repeated
 * (each sector's lattice is its own). */
typedef struct lensrt_mesh {
    int n_vertices, n_triangles, n_strips;
    double *xy;   /* [2 v]: mm */
    int *tri;     /* [3 t]: vertex indices */
    double *area; /* [t]: mm^2 */
    /* The triangles as strips: strip s holds triangles strip[5 s] + k, k < strip[5 s + 1],
     * of vertices (strip[5 s + 2] + k, strip[5 s + 3] + k, strip[5 s + 4] + k): a ring's
     * (or a slit row's) triangles of one orientation, whose vertices follow each other,
     * so that loops over them read memory in order (cpu/cells_kernel.c) */
    int *strip;
} lensrt_mesh;

/* One call of a device's cells integrator: up to 3 meshes (the render's, and those half
 * and a quarter as fine for the error estimate) integrated pixel by pixel with one
 * per-pixel set-up; mesh k's fields go to U[k][2 ((l n_wl + w) npix + p) + re/im]. */
#define LENSRT_CELLS_MAX_MESHES 3
typedef struct lensrt_cells_job {
    int n_mesh;
    const lensrt_mesh *mesh[LENSRT_CELLS_MAX_MESHES];
    double *U[LENSRT_CELLS_MAX_MESHES];
} lensrt_cells_job;

/* The mesh of `rings` rows for aperture `ap` of stop radius radius_mm (and slits of
 * half height radius_mm). LENSRT_ERROR_OUT_OF_MEMORY with a message; *m zeroed first. */
lensrt_result lensrt_mesh_build(lensrt_context ctx, const lensrt_aperture *ap, double radius_mm, int rings,
                                lensrt_mesh *m);
void lensrt_mesh_free(lensrt_context ctx, lensrt_mesh *m);

/* The triangle count of that mesh without building it (for progress and statistics). */
long lensrt_mesh_triangles(const lensrt_aperture *ap, double radius_mm, int rings);

/* integral over a triangle of area S of exp(i z), z linear on it with the complex values
 * z[k] = (re, im) at its vertices (re: phase in radians, -im: log amplitude) and
 * E[k] = exp(i z[k]) given (the caller has them per vertex): out = (re, im).
 * Exact for every z, stable at and near every removable singularity (equal or zero
 * differences: series), to a few units of rounding relative to S max|E|. */
void lensrt_tri_integral(double S, const double z[6], const double E[6], double out[2]);

/* The same over the part of the triangle where every level l (values lev[k * n_lev + l]
 * at vertex k) interpolated linearly is >= 0; adds to out. */
void lensrt_tri_integral_clipped(double S, const double z[6], const double E[6], const double *lev, int n_lev,
                                 double out[2]);

/* A level function of the render's stop shape (core/render.h), continuous, positive
 * inside, zero on the boundary (mm-like): for the stop crossings of a ghost's P_clip. */
double lensrt_stop_shape_level(const lensrt_stop_shape *s, double x, double y);

/* A quadrature of the aperture (the Fourier integrator's, cpu/fourier.c): nodes xy (mm
 * on the stop) and weights (mm^2). Each fan sector of the mesh above (circle, straight
 * or curved blades) is the image of the unit square under x = rho B(t), whose area
 * element is rho |B(t) x B'(t)| d rho dt, so that a Gauss-Legendre product rule of n x n
 * nodes in (rho, t) follows the true boundary and converges spectrally for a smooth
 * integrand; a slit is a rectangle with n nodes across and as many along as keep them
 * near square (at most 16 n). */
typedef struct lensrt_quadrature {
    int n;      /* nodes */
    double *xy; /* [2 j]: mm */
    double *w;  /* [j]: mm^2 */
    /* The product structure: `patches` patches (sectors, slits) of nb lines of na nodes,
     * node j = (patch nb + line) na + i, at the Gauss-Legendre parameters ua[i] along a
     * line (rho, or across a slit) and ub[line] across lines (t, or along a slit) */
    int na, nb, patches;
    double *ua, *ub;
} lensrt_quadrature;

/* The rule of n nodes per side for aperture `ap` of stop radius radius_mm (slits: half
 * height radius_mm). LENSRT_ERROR_OUT_OF_MEMORY or INVALID_ARGUMENT (beyond 2e8 nodes)
 * with a message; *q zeroed first. */
lensrt_result lensrt_quadrature_build(lensrt_context ctx, const lensrt_aperture *ap, double radius_mm, int n,
                                      lensrt_quadrature *q);
void lensrt_quadrature_free(lensrt_context ctx, lensrt_quadrature *q);

#endif /* LENSRT_CELLS_H */
