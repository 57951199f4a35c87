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

import heapq
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular

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


def symmetric_disc_points(rng: np.random.Generator, n: int, edge_share: float = 0.0
                          ) -> np.ndarray:
    """n points (a multiple of 4) on the unit disc as n/4 random points of the first
    quadrant with their mirror images in x, in y and in both: (n, 2). Uniform in area,
    or with ``edge_share`` of the quadrant's points drawn with radial density
    r / sqrt(1 - r^2) (:func:`edge_radii`: denser towards the rim, where least-squares
    polynomials on uniform points are least constrained). With ``edge_share`` 0 the
    random draws are those of uniform points alone (the same points for a seed)."""
    if n % 4 or n <= 0:
        raise ValueError(f"symmetric_disc_points: n = {n} must be a positive multiple of 4")
    q = n // 4
    r = edge_radii(rng, q, edge_share) if edge_share > 0.0 else np.sqrt(rng.random(q))
    t = 0.5 * np.pi * rng.random(q)
    x, y = r * np.cos(t), r * np.sin(t)
    return np.concatenate([np.stack(p, axis=1) for p in ((x, y), (-x, y), (x, -y), (-x, -y))])


def edge_radii(rng: np.random.Generator, n: int, edge_share: float) -> np.ndarray:
    """n radii on [0, 1]: ``edge_share`` of them with the density of uniform points of the
    hemisphere seen from above (r = sqrt(1 - u^2): the disc's analogue of Chebyshev
    points), the rest uniform in area (r = sqrt(u))."""
    u = rng.random(n)
    return np.where(rng.random(n) < edge_share, np.sqrt(1.0 - u**2), np.sqrt(u))


@dataclass
class TensorFit:
    """W (n_a, n_v) on aperture exponents (n_a, 2) and field exponents (n_v, n_fv), and
    how the masked solve went."""

    aperture_exps: np.ndarray
    field_exps: np.ndarray
    W: np.ndarray
    cg_iterations: int
    holes: int  # grid cells left out
    # Squared coefficients in the orthonormal bases of monomials taken by degree (n_a, n_v):
    # each (aperture monomial, field monomial) pair's share of the fitted function's sum of
    # squares over the complete grid, the part its monomials add to those before them.
    # None for a fit on a given support
    energy: np.ndarray | None = None

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
               parity: tuple[int, int], fill: np.ndarray | None = None,
               support: np.ndarray | None = None,
               weights: np.ndarray | None = None) -> TensorFit:
    """Least-squares W for ``values`` (G, K) on the grid of field points ``v_hat`` (G, n_fv)
    times aperture points ``a_hat`` (K, 2), both normalised, over the cells where ``mask``
    (G, K) is True. ``parity`` (px, py): the output's parity in x and in y (field
    variable 0 is x-like, 1 is y-like). ``fill`` (G, K): guesses for the holes (default:
    :func:`fill_holes`), where conjugate gradients start. ``weights`` (G, K), in (0, 1]
    on the cells of ``mask``: each cell's residual is multiplied by its weight (default
    1 everywhere); cells weighted below 1 are solved for by conjugate gradients as holes
    are.

    ``support`` (n_a, n_v) bool: the pairs (aperture monomial, field monomial) allowed,
    a *staircase* (:func:`staircase_levels`): each field monomial is allowed with every
    aperture monomial up to a degree of its own. The fit is then the exact least squares
    over those pairs alone, and W is zero outside them."""
    with single_blas():
        return _fit_tensor(a_hat, v_hat, values, mask, aperture_exps, field_exps,
                           parity=parity, fill=fill, support=support, weights=weights)


def staircase_levels(aperture_exps: np.ndarray, support: np.ndarray) -> np.ndarray:
    """Per field monomial, the highest aperture degree ``support`` pairs it with (-1:
    none), after checking that ``support`` is a staircase: a field monomial allowed with
    an aperture monomial of degree a is allowed with every aperture monomial of degree up
    to a. ValueError if not."""
    deg = aperture_exps.sum(axis=1)
    level = np.where(support.any(axis=0), np.max(np.where(support, deg[:, None], -1), axis=0),
                     -1)
    if not np.array_equal(support, deg[:, None] <= level[None, :]):
        raise ValueError("fit_tensor: the support is not a staircase (each field monomial "
                         "with every aperture monomial up to a degree)")
    return level


def _fit_tensor(a_hat: np.ndarray, v_hat: np.ndarray, values: np.ndarray, mask: np.ndarray,
                aperture_exps: np.ndarray, field_exps: np.ndarray, *,
                parity: tuple[int, int], fill: np.ndarray | None,
                support: np.ndarray | None = None,
                weights: np.ndarray | None = None) -> TensorFit:
    values = np.asarray(values, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    G, K = values.shape
    if a_hat.shape != (K, 2) or len(v_hat) != G or mask.shape != (G, K):
        raise ValueError(f"fit_tensor: shapes do not match: values {values.shape}, "
                         f"a_hat {a_hat.shape}, v_hat {v_hat.shape}, mask {mask.shape}")
    if not np.all(np.isfinite(values[mask])):
        raise ValueError("fit_tensor: non-finite values in the cells to fit")
    if weights is not None:
        weights = np.asarray(weights, dtype=np.float64)
        if weights.shape != mask.shape or not np.all((weights[mask] > 0) & (weights[mask] <= 1)):
            raise ValueError("fit_tensor: weights must have the grid's shape and lie in "
                             "(0, 1] on the cells to fit")
    B = design_matrix(a_hat, aperture_exps)  # (K, n_a)
    D = design_matrix(v_hat, field_exps)  # (G, n_v)
    a_deg = aperture_exps.sum(axis=1)
    level = None if support is None else staircase_levels(aperture_exps, support)
    # Orthonormal bases per parity class of the aperture monomials, with the field
    # monomials that class may pair with
    blocks = []
    for cx in (0, 1):
        for cy in (0, 1):
            rows = np.nonzero((aperture_exps[:, 0] % 2 == cx) & (aperture_exps[:, 1] % 2 == cy))[0]
            cols = np.nonzero((field_exps[:, 0] % 2 == (parity[0] + cx) % 2)
                              & (field_exps[:, 1] % 2 == (parity[1] + cy) % 2))[0]
            allowed = None
            if level is not None:
                # Field monomials by the highest aperture degree they pair with, highest
                # first: each aperture monomial's allowed field monomials are then a
                # prefix, so W = R_B^-1 Z R_D^-T stays inside the staircase
                cols = cols[level[cols] >= 0]
                cols = cols[np.lexsort((cols, -level[cols]))]
                allowed = a_deg[rows][:, None] <= level[cols][None, :]
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
            blocks.append((rows, cols, qb, rb, qd, rd, allowed))
    holes = int(mask.size - np.count_nonzero(mask))
    if holes and fill is None:
        fill = fill_holes(a_hat, values, mask)
    P = np.where(mask, values, 0.0 if fill is None else fill).T  # (K, G)
    # Each cell's weight in the normal equations (the square of its residual's weight)
    Mt = mask.T.astype(np.float64)
    partial = 0  # cells fitted with a weight below 1
    if weights is not None:
        Mt = np.where(mask, weights, 0.0).T ** 2
        partial = int(np.count_nonzero(mask & (weights < 1.0)))

    def forward(Z: list[np.ndarray]) -> np.ndarray:
        out = np.zeros((K, G))
        for z, (_, _, qb, _, qd, _, _) in zip(Z, blocks, strict=True):
            out += qb @ (z @ qd.T)  # (n_a x G) first: n_a is the smaller side
        return out

    def adjoint(R: np.ndarray) -> list[np.ndarray]:
        # Restricted to the support: the coordinates outside it stay zero
        return [qb.T @ R @ qd if allowed is None else np.where(allowed, qb.T @ R @ qd, 0.0)
                for (_, _, qb, _, qd, _, allowed) in blocks]

    def dot(a: list[np.ndarray], b: list[np.ndarray]) -> float:
        return float(sum(np.vdot(x, y) for x, y in zip(a, b, strict=True)))

    Z = adjoint(P)  # exact on a complete grid; else the fit to the filled grid
    iterations = 0
    if holes or partial:
        # Conjugate gradients on adjoint(M * forward(Z)) = adjoint(M * values) (M: the
        # cells' weights squared, 0 in holes), from the fit to the filled grid. The slow
        # directions are polynomials that live in the holes; CG_MAX_ITER stops it before
        # it chases them far (measured on lens 0004's P_s, 9% holes: phi 3.4e-3 waves
        # held-out after 300 iterations, 2.7e-3 after 1000)
        rhs = adjoint(Mt * P)
        r = [b - a for b, a in zip(rhs, adjoint(Mt * forward(Z)), strict=True)]
        p = [x.copy() for x in r]
        rr = dot(r, r)
        rr0 = dot(rhs, rhs)
        while iterations < CG_MAX_ITER and rr > CG_TOL**2 * rr0:
            Ap = adjoint(Mt * forward(p))
            alpha = rr / dot(p, Ap)
            Z = [z + alpha * x for z, x in zip(Z, p, strict=True)]
            r = [x - alpha * y for x, y in zip(r, Ap, strict=True)]
            rr_new = dot(r, r)
            p = [x + (rr_new / rr) * y for x, y in zip(r, p, strict=True)]
            rr = rr_new
            iterations += 1
    W = np.zeros((len(aperture_exps), len(field_exps)))
    energy = None if support is not None else np.zeros_like(W)
    for z, (rows, cols, _, rb, _, rd, _) in zip(Z, blocks, strict=True):
        # W_c = R_B^-1 Z R_D^-T (triangular solves: zeros of a staircase Z stay exact)
        w = solve_triangular(rb, z)
        W[np.ix_(rows, cols)] = solve_triangular(rd, w.T).T
        if energy is not None:
            energy[np.ix_(rows, cols)] = z * z
    return TensorFit(aperture_exps, field_exps, W, iterations, holes, energy)


def prune_support(aperture_exps: np.ndarray, field_exps: np.ndarray, energy: np.ndarray,
                  budget: float, piston_budget: float | None = None) -> np.ndarray:
    """The smallest staircase of (aperture monomial, field monomial) pairs found greedily
    whose left-out ``energy`` (:attr:`TensorFit.energy`, the squared orthonormal
    coefficients) sums to at most ``budget``: (n_a, n_v) bool for ``fit_tensor(support=)``.

    The units are *blocks*: one field monomial with all aperture monomials of one total
    degree a. The kept blocks always form a down-set (with a block, every block of lower
    aperture degree and every block of a field monomial that divides its own), so each
    field monomial pairs with the aperture monomials up to a degree of its own, a
    staircase, and the polynomial hierarchy has no gaps. A maximal block (nothing kept
    above it) is dropped while the budget lasts, the one with the least energy per
    monomial first. ``piston_budget``, when given, is a separate budget for the blocks
    without the stop point (a = 0), which for a phase is the piston: the error measure
    that sets ``budget`` does not see it (by default they share ``budget``).

    On a complete grid the refitted sum of squares rises by exactly the energy left out
    when the kept field monomials of each stop degree are all those up to a total degree
    (the order the energies were taken in); capping variables apart makes the energy an
    estimate (the true rise measured 0.98-1.27 times it, tests/fit/poly/test_tensor.py),
    so a cut is checked on held-out rays."""
    a_deg = aperture_exps.sum(axis=1)
    n_deg = int(a_deg.max()) + 1
    n_v = len(field_exps)
    block_e = np.zeros((n_deg, n_v))
    block_n = np.zeros((n_deg, n_v), dtype=np.int64)
    for a in range(n_deg):
        rows = a_deg == a
        block_e[a] = energy[rows].sum(axis=0)
        block_n[a] = np.count_nonzero(energy[rows] > 0, axis=0)
    # Every block starts kept, the empty ones too (a field monomial pairs only with the
    # stop degrees of one parity): they cost nothing and go first once nothing is above
    kept = np.ones((n_deg, n_v), dtype=bool)
    index = {tuple(e): i for i, e in enumerate(field_exps.tolist())}
    # Each block's neighbours in the down-set order: up (one degree more in the stop or
    # in one field variable) and down
    ups: list[list[int]] = []
    downs: list[list[int]] = []
    for e in field_exps.tolist():
        up, down = [], []
        for v in range(len(e)):
            f = list(e)
            f[v] += 1
            if (k := index.get(tuple(f))) is not None:
                up.append(k)
            if e[v] > 0:
                f[v] -= 2
                down.append(index[tuple(f)])
        ups.append(up)
        downs.append(down)

    def upper(a: int, m: int) -> list[tuple[int, int]]:
        return ([(a + 1, m)] if a + 1 < n_deg else []) + [(a, k) for k in ups[m]]

    def lower(a: int, m: int) -> list[tuple[int, int]]:
        return ([(a - 1, m)] if a > 0 else []) + [(a, k) for k in downs[m]]

    above = np.zeros((n_deg, n_v), dtype=np.int64)  # kept blocks directly above
    for a, m in zip(*np.nonzero(kept), strict=True):
        above[a, m] = sum(bool(kept[u]) for u in upper(a, m))
    left = [budget, 0.0 if piston_budget is None else piston_budget]  # a >= 1, a = 0

    def key(a: int, m: int) -> tuple[float, int, int]:
        return (block_e[a, m] / max(int(block_n[a, m]), 1), a, m)

    heap = [key(a, m) for a, m in zip(*np.nonzero(kept & (above == 0)), strict=True)]
    heapq.heapify(heap)
    while heap:
        _, a, m = heapq.heappop(heap)
        pool = 1 if a == 0 and piston_budget is not None else 0
        if block_e[a, m] > left[pool]:
            continue  # kept, and so is everything below it
        left[pool] -= block_e[a, m]
        kept[a, m] = False
        for b in lower(a, m):
            if kept[b]:
                above[b] -= 1
                if above[b] == 0:
                    heapq.heappush(heap, key(*b))
    return kept[a_deg]
