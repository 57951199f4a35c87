"""Least squares on a tensor grid: polynomials in (field, aperture) fitted in one solve.

The data of a lens fit come as a grid: G *groups* (a scene or sensor point, a focus and a
wavelength: the inputs a renderer fixes per pixel and wavelength) times the same K points
on the stop. The model is a sum over aperture monomials b_j(a) and field monomials
d_m(v) with a coefficient matrix W:

    f(a, v) = sum_j sum_m W[j, m] b_j(a) d_m(v)

with the output's mirror parity: a term is allowed when its total exponent of the
x-like inputs (x_a and x_O or x_S) and of the y-like inputs has the output's parity.

On a complete grid the least-squares problem separates (a Kronecker product): with B = Q_B
R_B (K x n_a) and D = Q_D R_D (G x n_v) the solution is W = R_B^-1 Q_B^T Y^T Q_D R_D^-T,
two small QRs whatever the number of terms. Rays that failed (missed, reflected totally)
or are far outside a housing leave holes in the grid; the masked problem is then solved
by conjugate gradients on its normal equations in the orthonormal coordinates of Q_B and
Q_D, where the complete-grid operator is the identity, so a few holes cost a few
iterations. Every step is a QR or a product with orthonormal columns: no normal
equations of the raw monomials are ever formed.

The aperture points are mirror-symmetric (each point with its three mirror images), so
the four parity classes of aperture monomials are orthogonal on the point set and the
complete-grid problem also separates by class.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from lensfit.poly.polynomial import design_matrix, monomials

CG_TOL = 1e-12  # relative residual of the normal equations at which CG stops
CG_MAX_ITER = 300
# Smallest |diag R| / largest of a class's QR before its monomials count as dependent:
# measured 7e-6 at stop degree 12 on 128 points and 1e-5 at field degree 12 on 4000
# groups; 1e-17 when dependent (stop degree 14 on 128 points, 10 on 64)
RANK_TOL = 1e-12


@contextmanager
def single_blas() -> Iterator[None]:
    """BLAS and LAPACK on one thread inside the block. The tensor fits' QRs and products
    are small (hundreds of columns): OpenBLAS's threads only synchronise, and on a busy
    machine they wait for each other's time slices. Measured with OpenBLAS 0.3.31 on 2
    loaded cores, a QR of 500 x 175: 3 ms on one thread, 50-2000 ms on two; one ghost
    fit of lens 0001 (ghost 0-2) 48 s -> 8 s. One thread also makes the rounding, and so
    a table's bytes, independent of the machine's core count."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


def aperture_exponents(degree: int) -> np.ndarray:
    """(i, j) of x_a^i y_a^j with i + j <= degree, by total degree: (n, 2) int32."""
    return np.array([(d - j, j) for d in range(degree + 1) for j in range(d + 1)],
                    dtype=np.int32)


def field_exponents(n_vars: int, degree: int, caps: tuple[int, ...] | None = None
                    ) -> np.ndarray:
    """Exponent rows of the field variables with total degree <= degree and each
    variable's exponent <= its cap: (n, n_vars) int32, ordered by total degree."""
    e = monomials(n_vars, degree)
    if caps is not None:
        e = e[np.all(e <= np.asarray(caps), axis=1)]
    return e


def symmetric_disc_points(rng: np.random.Generator, n: int) -> np.ndarray:
    """n points (a multiple of 4) on the unit disc, uniform in area, as n/4 random points
    of the first quadrant with their mirror images in x, in y and in both: (n, 2)."""
    if n % 4 or n <= 0:
        raise ValueError(f"symmetric_disc_points: n = {n} must be a positive multiple of 4")
    q = n // 4
    r = np.sqrt(rng.random(q))
    t = 0.5 * np.pi * rng.random(q)
    x, y = r * np.cos(t), r * np.sin(t)
    return np.concatenate([np.stack(p, axis=1) for p in ((x, y), (-x, y), (x, -y), (-x, -y))])


@dataclass
class TensorFit:
    """W (n_a, n_v) on aperture exponents (n_a, 2) and field exponents (n_v, n_fv), and
    how the masked solve went."""

    aperture_exps: np.ndarray
    field_exps: np.ndarray
    W: np.ndarray
    cg_iterations: int
    holes: int  # grid cells left out

    def terms(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The nonzero terms: (aperture exponents (T, 2), field exponents (T, n_fv),
        coefficients (T,)), field-major (the runtime specialises field inputs first)."""
        j, m = np.nonzero(self.W.T)  # ordered by field term, then aperture term
        m, j = j, m
        return self.aperture_exps[j], self.field_exps[m], self.W[j, m]

    def grid(self, a_hat: np.ndarray, v_hat: np.ndarray) -> np.ndarray:
        """f on the grid of field points v_hat (G, n_fv) times stop points a_hat (K, 2)."""
        return (design_matrix(v_hat, self.field_exps) @ self.W.T
                @ design_matrix(a_hat, self.aperture_exps).T)

    def evaluate(self, a_hat: np.ndarray, v_hat: np.ndarray) -> np.ndarray:
        """f at rows (a_hat (N, 2), v_hat (N, n_fv)) of normalised inputs: (N,)."""
        out = np.empty(len(a_hat))
        step = 4096
        for s in range(0, len(a_hat), step):
            b = design_matrix(a_hat[s:s + step], self.aperture_exps)
            d = design_matrix(v_hat[s:s + step], self.field_exps)
            out[s:s + step] = np.einsum("nj,jm,nm->n", b, self.W, d, optimize=True)
        return out


def fill_holes(a_hat: np.ndarray, values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``values`` with each group's holes filled by the quadratic in the stop point that
    fits the group's valid cells (its mean if it has fewer than 6): a starting guess
    for the masked solve that already has each group's piston, tilt and focus."""
    B = design_matrix(a_hat, aperture_exponents(2))  # (K, 6)
    m = mask.astype(np.float64)
    normal = np.einsum("gk,ki,kj->gij", m, B, B)  # per group B^T M B
    rhs = np.einsum("gk,ki,gk->gi", m, B, np.where(mask, values, 0.0))
    count = m.sum(axis=1)
    enough = count >= 12
    out = np.where(mask, values, 0.0)
    if np.any(enough):
        coef = np.linalg.solve(normal[enough], rhs[enough][..., None])[..., 0]
        out[enough] = np.where(mask[enough], values[enough], coef @ B.T)
    few = ~enough
    mean = np.where(count > 0, rhs[:, 0] / np.maximum(count, 1.0), 0.0)
    out[few] = np.where(mask[few], values[few], mean[few, None])
    return out


def fit_tensor(a_hat: np.ndarray, v_hat: np.ndarray, values: np.ndarray, mask: np.ndarray,
               aperture_exps: np.ndarray, field_exps: np.ndarray, *,
               parity: tuple[int, int], fill: np.ndarray | None = None) -> TensorFit:
    """Least-squares W for ``values`` (G, K) on the grid of field points ``v_hat`` (G, n_fv)
    times aperture points ``a_hat`` (K, 2), both normalised, over the cells where ``mask``
    (G, K) is True. ``parity`` (px, py): the output's parity in x and in y (field
    variable 0 is x-like, 1 is y-like). ``fill`` (G, K): guesses for the holes (default:
    :func:`fill_holes`), where conjugate gradients start."""
    with single_blas():
        return _fit_tensor(a_hat, v_hat, values, mask, aperture_exps, field_exps,
                           parity=parity, fill=fill)


def _fit_tensor(a_hat: np.ndarray, v_hat: np.ndarray, values: np.ndarray, mask: np.ndarray,
                aperture_exps: np.ndarray, field_exps: np.ndarray, *,
                parity: tuple[int, int], fill: np.ndarray | None) -> TensorFit:
    values = np.asarray(values, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    G, K = values.shape
    if a_hat.shape != (K, 2) or len(v_hat) != G or mask.shape != (G, K):
        raise ValueError(f"fit_tensor: shapes do not match: values {values.shape}, "
                         f"a_hat {a_hat.shape}, v_hat {v_hat.shape}, mask {mask.shape}")
    if not np.all(np.isfinite(values[mask])):
        raise ValueError("fit_tensor: non-finite values in the cells to fit")
    B = design_matrix(a_hat, aperture_exps)  # (K, n_a)
    D = design_matrix(v_hat, field_exps)  # (G, n_v)
    # Orthonormal bases per parity class of the aperture monomials, with the field
    # monomials that class may pair with
    blocks = []
    for cx in (0, 1):
        for cy in (0, 1):
            rows = np.nonzero((aperture_exps[:, 0] % 2 == cx) & (aperture_exps[:, 1] % 2 == cy))[0]
            cols = np.nonzero((field_exps[:, 0] % 2 == (parity[0] + cx) % 2)
                              & (field_exps[:, 1] % 2 == (parity[1] + cy) % 2))[0]
            if rows.size == 0 or cols.size == 0:
                continue
            if cols.size > G or rows.size > K:
                raise ValueError(f"fit_tensor: {cols.size} field terms for {G} groups or "
                                 f"{rows.size} aperture terms for {K} points: too few data")
            qb, rb = np.linalg.qr(B[:, rows])
            qd, rd = np.linalg.qr(D[:, cols])
            # More monomials than the points tell apart (K mirror-symmetric points are only
            # K/4 distinct points per parity class): R is singular and W would be garbage
            for r, what in ((rb, "aperture"), (rd, "field")):
                d = np.abs(np.diag(r))
                if d.min() <= RANK_TOL * d.max():
                    raise ValueError(f"fit_tensor: the {what} monomials of one parity class "
                                     "are linearly dependent on the grid's points: too few "
                                     "data")
            blocks.append((rows, cols, qb, rb, qd, rd))
    holes = int(mask.size - np.count_nonzero(mask))
    if holes and fill is None:
        fill = fill_holes(a_hat, values, mask)
    P = np.where(mask, values, 0.0 if fill is None else fill).T  # (K, G)
    Mt = mask.T

    def forward(Z: list[np.ndarray]) -> np.ndarray:
        out = np.zeros((K, G))
        for z, (_, _, qb, _, qd, _) in zip(Z, blocks, strict=True):
            out += qb @ (z @ qd.T)  # (n_a x G) first: n_a is the smaller side
        return out

    def adjoint(R: np.ndarray) -> list[np.ndarray]:
        return [qb.T @ R @ qd for (_, _, qb, _, qd, _) in blocks]

    def dot(a: list[np.ndarray], b: list[np.ndarray]) -> float:
        return float(sum(np.vdot(x, y) for x, y in zip(a, b, strict=True)))

    Z = adjoint(P)  # exact on a complete grid; else the fit to the filled grid
    iterations = 0
    if holes:
        # Conjugate gradients on adjoint(mask * forward(Z)) = adjoint(mask * values),
        # from the fit to the filled grid. The slow directions are polynomials that live
        # in the holes; CG_MAX_ITER stops it before it chases them far (measured on lens
        # 0004's P_s, 9% holes: phi 3.4e-3 waves held-out after 300 iterations, 2.7e-3
        # after 1000)
        rhs = adjoint(np.where(Mt, P, 0.0))
        r = [b - a for b, a in zip(rhs, adjoint(np.where(Mt, forward(Z), 0.0)), strict=True)]
        p = [x.copy() for x in r]
        rr = dot(r, r)
        rr0 = dot(rhs, rhs)
        while iterations < CG_MAX_ITER and rr > CG_TOL**2 * rr0:
            Ap = adjoint(np.where(Mt, forward(p), 0.0))
            alpha = rr / dot(p, Ap)
            Z = [z + alpha * x for z, x in zip(Z, p, strict=True)]
            r = [x - alpha * y for x, y in zip(r, Ap, strict=True)]
            rr_new = dot(r, r)
            p = [x + (rr_new / rr) * y for x, y in zip(r, p, strict=True)]
            rr = rr_new
            iterations += 1
    W = np.zeros((len(aperture_exps), len(field_exps)))
    for z, (rows, cols, _, rb, _, rd) in zip(Z, blocks, strict=True):
        # W_c = R_B^-1 Z R_D^-T
        w = np.linalg.solve(rb, z)
        W[np.ix_(rows, cols)] = np.linalg.solve(rd, w.T).T
    return TensorFit(aperture_exps, field_exps, W, iterations, holes)
