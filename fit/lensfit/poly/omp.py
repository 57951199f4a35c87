"""Orthogonal matching pursuit (OMP): greedy sparse least squares over a dictionary of columns.

Given a dictionary ``A`` (N samples, M columns; here monomials evaluated at the samples) and
data ``y``, OMP grows a support one column at a time: it picks the column most correlated with
the current residual, ``argmax_j |a_j^T r| / ||a_j||``, and refits ``y`` by least squares on all
columns picked so far. The result is a *path*: for every k, the best-fitting k-term model along
the way, so that a caller can choose k afterwards (for instance by held-out error).

Numerics. The least-squares refit is kept as a QR factorisation grown by Gram-Schmidt with
re-orthogonalisation (classical Gram-Schmidt applied twice, "CGS2", which keeps ``Q``
orthonormal to working precision as long as each new column keeps a non-negligible component
outside the span of the previous ones). The residual is updated as ``r -= q (q^T r)``, which
is modified Gram-Schmidt on ``y`` and backward stable for the least-squares problem; the
normal equations ``A^T A`` are never formed, so monomial dictionaries whose condition number
is far beyond 1e8 are handled to the precision their conditioning allows. Coefficients come
from back-substitution with the triangular factor.

Cost per iteration, with m outputs fitted at once by :func:`omp_many` and k terms so far:
one pass over ``A`` for the correlations ``A^T R`` (2 N M m flops through BLAS, and in practice
bound by the memory bandwidth needed to read ``A`` once, shared by all outputs), plus
O(N k) per output for the two Gram-Schmidt passes and O(M) for the selection.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import solve_triangular

from lensfit.poly.polynomial import Polynomial, design_matrix, monomials

StopFn = Callable[[int, np.ndarray, np.ndarray], bool]
"""``stop(k, support_k, coef_k) -> bool``: end the path after k terms when it returns True."""

# A candidate column (scaled to unit norm) whose component orthogonal to the columns already
# selected has norm <= DEPENDENCE_TOL is treated as numerically dependent and never selected.
# Why 1e-10: after CGS2 that component is known to an absolute error of a few eps (2.2e-16)
# times sqrt(k), i.e. ~1e-15 to 1e-14 for up to a few hundred terms; at 1e-10 it still carries
# 4-5 significant digits, so the new direction q is meaningful and CGS2 keeps Q orthonormal
# (its analysis needs eps / component << 1). Below it, q would be mostly rounding noise and
# the fitted coefficients would grow by > 1e10 while cancelling each other, for no real gain.
DEPENDENCE_TOL = 1e-10
# OLS keeps 1 - sum_i (q_i^T a_j)^2 by subtraction, which carries rounding of ~1e-16 k; a
# column whose remaining squared norm is below 1e-10 (norm 1e-5) is treated as dependent,
# well above that rounding so the ratio that ranks columns stays meaningful.
OLS_RESIDUAL_FLOOR = 1e-10
CRITERIA = ("omp", "ols")


@dataclass
class OmpPath:
    """The OMP path for one output: the columns picked, in order, and the fits after each."""

    support: np.ndarray  # (k,) int, dictionary column indices in selection order
    train_rms: np.ndarray  # (k,) RMS training residual after 1..k terms
    r_factor: np.ndarray  # (k, k) upper triangular: A[:, support] / norms = Q @ r_factor
    qty: np.ndarray  # (k,) Q^T y, the data in the orthonormal basis
    norms: np.ndarray  # (k,) Euclidean norms of the selected columns of A
    initial_rms: float = 0.0  # RMS of y itself (the fit with no terms)
    dependent: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    # ^ columns rejected as zero or numerically dependent on the support, in rejection order
    reason: str = ""  # why the path ended: max_terms, tol, stop, zero_residual, exhausted
    # ("exhausted": every column left is selected, dependent, or orthogonal to the residual)

    @property
    def terms(self) -> int:
        """The path length (number of columns selected)."""
        return len(self.support)

    def coefficients(self, k: int) -> np.ndarray:
        """Least-squares coefficients of the first k selected columns, in A's own scale."""
        if not 0 <= k <= self.terms:
            raise ValueError(f"coefficients: k must be in [0, {self.terms}], got {k}")
        # Nested Gram-Schmidt: the leading k x k block of R factors the first k columns.
        # Back-substitution is insensitive to the column scaling, so solving for the unit-norm
        # columns and dividing by their norms loses nothing.
        z = solve_triangular(self.r_factor[:k, :k], self.qty[:k], lower=False)
        return z / self.norms[:k]


class _Pursuit:
    """The growing state of one output's path (used by :func:`omp_many`)."""

    def __init__(self, r: np.ndarray, available: np.ndarray, capacity: int,
                 ols: bool = False) -> None:
        n = len(r)
        # OLS only: squared norm of each unit column's part orthogonal to the support
        self.resid_sq = available.astype(np.float64) if ols else None
        self.r = r  # the residual, a row of omp_many's (m, N) array, updated in place
        self.available = available.copy()  # columns that may still be selected
        self.capacity = capacity  # max terms
        size = min(capacity, 32)  # buffers grow by doubling; paths often stop early
        self.qt = np.empty((size, n))  # rows: orthonormal basis vectors q_i
        self.rf = np.zeros((size, size))  # triangular factor
        self.qty: list[float] = []
        self.support: list[int] = []
        self.rms: list[float] = []
        self.dependent: list[int] = [int(j) for j in np.flatnonzero(~available)]
        self.initial_rms = float(np.linalg.norm(r) / np.sqrt(n))
        self.reason = ""
        self.checked = 0  # the last k at which the stop callback ran

    @property
    def k(self) -> int:
        return len(self.support)

    def _grow(self) -> None:
        size = min(2 * len(self.qt), self.capacity)
        qt = np.empty((size, self.qt.shape[1]))
        qt[: self.k] = self.qt[: self.k]
        rf = np.zeros((size, size))
        rf[: self.k, : self.k] = self.rf[: self.k, : self.k]
        self.qt, self.rf = qt, rf

    def step(self, A: np.ndarray, inv_norms: np.ndarray, corr: np.ndarray) -> bool:
        """Add the best usable column given ``corr = A^T r``; False if none is usable."""
        k = self.k
        score = np.abs(corr) * inv_norms
        if self.resid_sq is not None:
            # OLS: a column is judged by the part of it the support cannot already explain
            self.available &= self.resid_sq > OLS_RESIDUAL_FLOOR
            score /= np.sqrt(np.maximum(self.resid_sq, OLS_RESIDUAL_FLOOR))
        score[~self.available] = -1.0
        qk = self.qt[:k]
        while True:
            j = int(np.argmax(score))
            if score[j] < 0.0:
                self.reason = "exhausted"  # every column is selected or dependent
                return False
            if score[j] == 0.0:
                # The residual is orthogonal to every remaining column: no term can help
                self.reason = "zero_residual" if not np.any(self.r) else "exhausted"
                return False
            a = A[:, j] * inv_norms[j]
            # CGS2: project out span(Q) twice; the second pass removes what rounding left over
            h = qk @ a
            v = a - qk.T @ h
            h2 = qk @ v
            v -= qk.T @ h2
            h += h2
            nv = float(np.linalg.norm(v))
            if nv > DEPENDENCE_TOL:
                break
            self.available[j] = False
            self.dependent.append(j)
            score[j] = -1.0
        if k == len(self.qt):
            self._grow()
        q = v / nv
        self.qt[k] = q
        self.rf[:k, k] = h
        self.rf[k, k] = nv
        z = float(q @ self.r)  # = q^T y in exact arithmetic; MGS form is the stable one
        self.r -= z * q
        self.qty.append(z)
        self.support.append(j)
        self.available[j] = False
        self.rms.append(float(np.linalg.norm(self.r) / np.sqrt(len(self.r))))
        return True

    def coefficients(self, norms: np.ndarray) -> np.ndarray:
        k = self.k
        z = solve_triangular(self.rf[:k, :k], np.array(self.qty), lower=False)
        return z / norms[self.support]

    def path(self, norms: np.ndarray) -> OmpPath:
        k = self.k
        support = np.array(self.support, dtype=np.intp)
        return OmpPath(
            support=support,
            train_rms=np.array(self.rms, dtype=np.float64),
            r_factor=self.rf[:k, :k].copy(),
            qty=np.array(self.qty, dtype=np.float64),
            norms=norms[support].copy(),
            initial_rms=self.initial_rms,
            dependent=np.array(self.dependent, dtype=np.intp),
            reason=self.reason,
        )


def _non_finite_message(name: str, x: np.ndarray) -> str | None:
    bad = ~np.isfinite(x)
    count = int(np.count_nonzero(bad))
    if count == 0:
        return None
    first = np.unravel_index(int(np.argmax(bad)), x.shape)
    where = f"row {first[0]}" if x.ndim == 1 else f"row {first[0]}, column {first[1]}"
    entries = "entry" if count == 1 else "entries"
    return f"{name} has {count} non-finite {entries} (first at {where})"


def _per_output(value: object, m: int, what: str) -> list:
    """A scalar (or None) shared by all outputs, or one value per output."""
    if value is None or callable(value) or np.isscalar(value):
        return [value] * m
    values = list(value)
    if len(values) != m:
        raise ValueError(f"omp_many: {what} has {len(values)} entries for {m} outputs")
    return values


def omp_many(
    A: np.ndarray,
    Y: np.ndarray,
    *,
    max_terms: int,
    tol: float | Sequence[float | None] | None = None,
    stop: StopFn | Sequence[StopFn | None] | None = None,
    check_every: int = 1,
    criterion: str = "omp",
) -> list[OmpPath]:
    """Independent OMP for each column of Y (N, m), sharing the A^T R products.

    All outputs still running are served by one BLAS product ``R^T A`` per iteration, so ``A``
    is read once per iteration whatever m is. ``tol`` and ``stop`` may be single values for all
    outputs or sequences with one entry per output (outputs usually differ in units). An
    output's path ends after k terms when its training RMS is <= its ``tol``, when its
    ``stop(k, support_k, coef_k)`` returns True (evaluated every ``check_every`` terms and at
    the last term), when its residual is exactly zero, or when no usable column is left (all
    selected, numerically dependent or orthogonal to the residual); otherwise after
    ``max_terms`` terms (fewer when A has fewer columns or rows).

    ``criterion="omp"`` picks the column most correlated with the residual (classic OMP,
    as scikit-learn). ``"ols"`` (orthogonal least squares, also called order-recursive
    matching pursuit) divides that correlation by the norm of the column's part orthogonal
    to the support, i.e. picks the column whose addition lowers the residual most; it
    costs a second pass over A per iteration and chooses far better among strongly
    correlated columns such as monomials of high degree.
    """
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {criterion!r}")
    ols = criterion == "ols"
    A = np.asarray(A, dtype=np.float64)
    if A.ndim != 2:
        raise ValueError(f"A must be a 2-D (N, M) array, got shape {A.shape}")
    n, m_cols = A.shape
    if n == 0:
        raise ValueError("A has no rows (N == 0): nothing to fit")
    if m_cols == 0:
        raise ValueError("A has no columns (M == 0): nothing to select")
    Y = np.asarray(Y, dtype=np.float64)
    if Y.ndim == 1:
        Y = Y[:, None]
    if Y.ndim != 2 or Y.shape[0] != n:
        raise ValueError(f"Y has shape {Y.shape}, expected ({n}, m) to match A's {n} rows")
    if isinstance(max_terms, bool) or not isinstance(max_terms, int | np.integer) \
            or max_terms < 1:
        raise ValueError(f"max_terms must be an integer >= 1, got {max_terms!r}")
    if isinstance(check_every, bool) or not isinstance(check_every, int | np.integer) \
            or check_every < 1:
        raise ValueError(f"check_every must be an integer >= 1, got {check_every!r}")
    for name, x in (("A", A), ("Y", Y)):
        msg = _non_finite_message(name, x)
        if msg:
            raise ValueError(msg)
    m = Y.shape[1]
    tols = _per_output(tol, m, "tol")
    stops = _per_output(stop, m, "stop")
    if not (A.flags.c_contiguous or A.flags.f_contiguous):
        A = np.ascontiguousarray(A)  # once: BLAS would otherwise copy A at every product

    norms = np.sqrt(np.einsum("ij,ij->j", A, A))
    if not np.all(np.isfinite(norms)):
        raise ValueError("A has columns whose norm overflows float64; rescale A")
    nonzero = norms > 0.0
    inv_norms = np.zeros_like(norms)
    inv_norms[nonzero] = 1.0 / norms[nonzero]
    capacity = min(int(max_terms), m_cols, n)  # more than N columns cannot be independent

    # Residuals as rows of one C-ordered (m, N) array: ``res @ A`` then streams through A
    # row by row, the fastest way to read a C-ordered A (and no copy of an F-ordered one).
    res = np.array(Y.T, dtype=np.float64, order="C")  # a copy: updated in place
    runs = [_Pursuit(res[i], nonzero, capacity, ols) for i in range(m)]
    active = []
    for i, run in enumerate(runs):
        if not np.any(run.r):
            run.reason = "zero_residual"
        elif tols[i] is not None and run.initial_rms <= tols[i]:
            run.reason = "tol"
        else:
            active.append(i)

    def finish(i: int, reason: str | None) -> None:
        run = runs[i]
        if reason is not None:
            run.reason = reason
        # The caller sees the last term too, whatever ended the path
        if stops[i] is not None and run.k > run.checked and run.reason != "stop":
            run.checked = run.k
            stops[i](run.k, np.array(run.support, dtype=np.intp), run.coefficients(norms))

    # Per iteration: one O(N M m_active) pass over A here, then per output O(M) to select and
    # O(N k) for CGS2 and the residual update (more only when a candidate proves dependent).
    while active:
        # The one pass over A for this iteration, shared by all outputs still running
        corr = (res if len(active) == m else res[active]) @ A  # (m_active, M)
        stepped = []
        for row, i in zip(corr, active, strict=True):
            if runs[i].step(A, inv_norms, row):
                stepped.append(i)
            else:
                finish(i, None)
        if ols and stepped:
            # The second pass: how much of every column each new basis vector explains
            qs = np.stack([runs[i].qt[runs[i].k - 1] for i in stepped]) @ A
            for row, i in zip(qs, stepped, strict=True):
                runs[i].resid_sq -= (row * inv_norms) ** 2
        still = []
        for i in stepped:
            run = runs[i]
            k = run.k
            if not np.any(run.r):
                finish(i, "zero_residual")
                continue
            if tols[i] is not None and run.rms[-1] <= tols[i]:
                finish(i, "tol")
                continue
            last = k == capacity
            if stops[i] is not None and (k % check_every == 0 or last):
                run.checked = k
                support = np.array(run.support, dtype=np.intp)
                if stops[i](k, support, run.coefficients(norms)):
                    finish(i, "stop")
                    continue
            if last:
                finish(i, "max_terms" if capacity == max_terms else "exhausted")
                continue
            still.append(i)
        active = still
    return [run.path(norms) for run in runs]


def omp(
    A: np.ndarray,
    y: np.ndarray,
    *,
    max_terms: int,
    tol: float | None = None,
    stop: StopFn | None = None,
    check_every: int = 1,
    criterion: str = "omp",
) -> OmpPath:
    """Select up to max_terms columns of A (N, M) to fit y (N,).

    See :func:`omp_many` for the stopping rules; ``tol`` is an RMS in y's units."""
    A = np.asarray(A)
    y = np.asarray(y)
    if A.ndim != 2:
        raise ValueError(f"A must be a 2-D (N, M) array, got shape {A.shape}")
    if y.ndim != 1 or len(y) != A.shape[0]:
        raise ValueError(f"y has shape {y.shape}, expected ({A.shape[0]},) to match A's rows")
    msg = _non_finite_message("y", np.asarray(y, dtype=np.float64))
    if msg:
        raise ValueError(msg)
    return omp_many(A, y[:, None], max_terms=max_terms, tol=tol, stop=stop, criterion=criterion,
                    check_every=check_every)[0]


def fit_polynomial(
    xhat: np.ndarray,
    y: np.ndarray,
    *,
    output: str,
    unit: str,
    max_degree: int,
    max_terms: int,
    tol: float | None = None,
    stop: StopFn | None = None,
) -> tuple[Polynomial, OmpPath]:
    """Fit y (N,) over normalised inputs xhat (N, n) by OMP on all monomials of degree <=
    ``max_degree``; the Polynomial holds the whole path's terms, in selection order."""
    xhat = np.asarray(xhat, dtype=np.float64)
    if xhat.ndim != 2:
        raise ValueError(f"output {output}: xhat must be (N, n_inputs), got shape {xhat.shape}")
    exponents = monomials(xhat.shape[1], max_degree)
    A = design_matrix(xhat, exponents)
    path = omp(A, y, max_terms=max_terms, tol=tol, stop=stop)
    poly = Polynomial(output, unit, exponents[path.support], path.coefficients(path.terms))
    return poly, path
