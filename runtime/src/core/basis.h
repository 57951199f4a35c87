/* The window's bases and the pruning limits (internal, core/basis.c), shared by the CPU
 * and GL devices so that both drop the same amount per pixel. */
#ifndef LENSRT_BASIS_H
#define LENSRT_BASIS_H

#include "render.h"

/* The largest l1 norm of the non-constant coefficients output o (x_i, y_i, tau_i, phi_i)
 * may drop at a pixel whose constant term is c0. */
double lensrt_output_limit(const lensrt_render r, int o, double c0);

/* The window's bases per wavelength (r->basis, r->basis_rank, r->n_rows; nothing when
 * the precision does not use them). */
lensrt_result lensrt_prepare_basis(lensrt_render r);

/* Coordinates u[0 .. R) of the non-constant coefficients c[1 .. n] (n = n_slots - 1) in
 * the leading R vectors of the render's orthonormal basis b (r->basis[b], b = w n_bases
 * + basis), and the fewest of them whose dropped tail (the residual) has an l1 norm
 * <= limit; R + 1 when even R vectors are not enough. */
int lensrt_basis_keep(const lensrt_render r, int b, int R, const double *c, double limit, double *u);

#endif /* LENSRT_BASIS_H */
