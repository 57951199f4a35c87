/* The cells integrator's vectorised loops (internal; cpu/cells_kernel.c). */
#ifndef LENSRT_CELLS_KERNEL_H
#define LENSRT_CELLS_KERNEL_H

#include "../core/cells.h"

/* Vertex phasors of one pixel and light: w = ph + sph - ref (waves), z = (2 pi w,
 * -(lna + lnt)), E = samp st exp(2 pi i w) (the amplitude and its log kept apart, so
 * that no exp or log is taken here); vertex v's at [v * stride] (LENSRT_CELLS_LANES: the
 * pixel's lane of a block). */
void lensrt_cells_vertices(int n, const double *restrict ph, const double *restrict sph, double ref, const double *restrict lna,
                           const double *restrict samp, const double *restrict lnt, const double *restrict st, double *restrict zr, double *restrict zi,
                           double *restrict er, double *restrict ei, size_t stride);

/* st[v] (a transmittance t) becomes its amplitude sqrt(t) (0 where t <= 0 or NaN) and
 * lnt[v] the log of that amplitude, 0.5 log t, no lower than floor_ (floor_ where t is
 * below 1e-300, <= 0 or NaN), within 2 ulp of libm's; vectorised. */
void lensrt_cells_log_amplitude(int n, double *restrict st, double *restrict lnt, double floor_);

/* Pixels integrated at once by lensrt_cells_triangles: a block's vertex values are
 * interleaved, value of vertex v for the block's pixel k at [v * LANES + k], so that the
 * loop over the block's pixels runs along contiguous memory in full vectors (a mesh's
 * strips are a few triangles long near the centre: too short to vectorise along). */
#define LENSRT_CELLS_LANES 8

/* The integral over every triangle t of strips s0 .. s1 - 1 of mesh m whose nodes are
 * apart (lensrt_tri_integral's one-division branch, bit for bit) and that lies inside
 * every clip (in: per vertex, 1 inside, 0 not) into cr, ci [(t - t_s0) * LANES + k], t_s0
 * the first strip's first triangle; the others get 0 and rest 1, for the caller's scalar
 * pass. Every array interleaved for the LANES pixels of a block. */
void lensrt_cells_triangles(const lensrt_mesh *m, int s0, int s1, const double *zr, const double *zi,
                            const double *er, const double *ei, const double *in, double *cr, double *ci,
                            double *rest);

#endif /* LENSRT_CELLS_KERNEL_H */
