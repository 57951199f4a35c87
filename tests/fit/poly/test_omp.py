"""Tests for lensfit.poly.omp: orthogonal matching pursuit over polynomial dictionaries.

Float64 rounding is eps = 2.2e-16. A least-squares fit computed by a backward-stable method
(Householder or Gram-Schmidt with re-orthogonalisation) has coefficient errors of order
eps * cond(A_S) relative, and residual errors of order eps * cond(A_S) * ||y||; tolerances
below are set one to three orders of magnitude above those estimates for the problems at hand.
"""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.linear_model import OrthogonalMatchingPursuit

from lensfit.poly.omp import DEPENDENCE_TOL, OmpPath, fit_polynomial, omp, omp_many
from lensfit.poly.polynomial import design_matrix, monomials

EPS = np.finfo(np.float64).eps


def rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(v))))


def random_dictionary(seed: int, n: int = 400, n_inputs: int = 3, degree: int = 5):
    """Monomials of degree <= ``degree`` at n uniform points of [-1, 1]^n_inputs."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 1.0, (n, n_inputs))
    return rng, x, design_matrix(x, monomials(n_inputs, degree))


def assert_paths_equal(a: OmpPath, b: OmpPath) -> None:
    np.testing.assert_array_equal(a.support, b.support)
    # Same arithmetic up to the BLAS blocking of one product: agreement to ~1e3 eps
    np.testing.assert_allclose(a.train_rms, b.train_rms, rtol=1e-12, atol=0)
    np.testing.assert_allclose(a.coefficients(a.terms), b.coefficients(b.terms), rtol=1e-12)
    assert a.reason == b.reason


# --- exact recovery ---------------------------------------------------------------------------


def test_sparse_polynomial_recovered_exactly():
    # Seed 0 draws a problem on which greedy selection meets the true terms first (OMP has no
    # such guarantee for correlated monomials; about a quarter of the seeds first pick a
    # spurious term, which test_spurious_terms_get_zero_coefficients covers)
    rng = np.random.default_rng(0)
    x = rng.uniform(-1.0, 1.0, (3000, 6))
    exps = monomials(6, 6)
    true = rng.choice(len(exps), 12, replace=False)
    coef = rng.choice([-1.0, 1.0], 12) * 10.0 ** rng.uniform(-3.0, 1.0, 12)
    y = design_matrix(x, exps[true]) @ coef

    poly, path = fit_polynomial(x, y, output="u", unit="mm", max_degree=6, max_terms=12)

    assert sorted(path.support.tolist()) == sorted(true.tolist())
    assert path.reason == "max_terms"
    got = dict(zip(map(tuple, poly.exponents.tolist()), poly.coefficients, strict=True))
    want = dict(zip(map(tuple, exps[true].tolist()), coef, strict=True))
    assert got.keys() == want.keys()
    # Unit-scale monomials on 3000 uniform points are well conditioned (cond(A_S) ~ 10-100):
    # each coefficient, even the 1e-3 ones, is exact to ~1e-14 relative; 1e-10 leaves room
    for e, c in want.items():
        assert got[e] == pytest.approx(c, rel=1e-10, abs=0)
    # Residual at rounding level: ~eps * ||y|| (the RMS of y is ~1), 100x margin
    assert path.train_rms[-1] < 100 * EPS * rms(y)
    np.testing.assert_allclose(poly.evaluate_normalised(x), y, rtol=0, atol=1e-12 * rms(y))


@pytest.mark.parametrize("seed", [1, 7])
def test_spurious_terms_get_zero_coefficients(seed):
    # Seeds on which OMP picks a wrong monomial first: run on to a tolerance; the true support
    # is then included and the extra terms come out zero (to rounding, coefficients ~1..10)
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 1.0, (3000, 6))
    exps = monomials(6, 6)
    A = design_matrix(x, exps)
    true = rng.choice(len(exps), 12, replace=False)
    coef = rng.choice([-1.0, 1.0], 12) * 10.0 ** rng.uniform(-3.0, 1.0, 12)
    y = A[:, true] @ coef
    path = omp(A, y, max_terms=40, tol=1e-12 * rms(y))
    assert path.reason == "tol"
    assert 12 < path.terms < 40  # these seeds do select spurious terms before finishing
    assert set(true) <= set(path.support)
    c = dict(zip(path.support.tolist(), path.coefficients(path.terms), strict=True))
    for j in set(path.support.tolist()) - set(true.tolist()):
        assert abs(c[j]) < 1e-12
    for j, cj in zip(true, coef, strict=True):
        assert c[j] == pytest.approx(cj, rel=1e-10)


# --- agreement with scikit-learn --------------------------------------------------------------


@pytest.mark.parametrize("seed", range(4))
def test_matches_sklearn_on_unit_norm_columns(seed):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(60, 40))
    A /= np.linalg.norm(A, axis=0)  # unit columns: both selection rules are then the same
    y = rng.normal(size=60)
    path = omp(A, y, max_terms=30)
    for k in (1, 2, 5, 15, 30):
        ref = OrthogonalMatchingPursuit(n_nonzero_coefs=k, fit_intercept=False).fit(A, y)
        assert set(np.flatnonzero(ref.coef_)) == set(path.support[:k].tolist())
        mine = np.zeros(A.shape[1])
        mine[path.support[:k]] = path.coefficients(k)
        # Gaussian 60 x k submatrices have cond <~ 10; different stable algorithms (sklearn:
        # Cholesky of the Gram matrix) agree to ~1e-15 relative, 1e-10 leaves ample margin
        np.testing.assert_allclose(mine, ref.coef_, rtol=0, atol=1e-10 * np.abs(ref.coef_).max())
        fit = A[:, path.support[:k]] @ path.coefficients(k)
        assert path.train_rms[k - 1] == pytest.approx(rms(y - fit), rel=1e-10)


def test_prefix_coefficients_are_least_squares_fits():
    rng, _, A = random_dictionary(3)
    y = rng.normal(size=A.shape[0])
    path = omp(A, y, max_terms=20)
    for k in (1, 7, 20):
        sub = A[:, path.support[:k]]
        ref = np.linalg.lstsq(sub, y, rcond=None)[0]
        # cond(sub) here stays below ~1e3: 1e-10 is far above eps * cond
        np.testing.assert_allclose(path.coefficients(k), ref, rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError, match=r"k must be in \[0, 20\]"):
        path.coefficients(21)


# --- several outputs ---------------------------------------------------------------------------


def test_omp_many_equals_separate_runs():
    rng, _, A = random_dictionary(5)
    Y = np.stack([rng.normal(size=A.shape[0]), A[:, 3] - 0.5 * A[:, 17],
                  np.cos(3 * A[:, 1]), rng.normal(size=A.shape[0])], axis=1)
    # Different tolerances per output: the outputs finish at different iterations, so the
    # shared product runs on a shrinking set of residuals
    tols = [None, 1e-12, 0.0142, 0.95]
    paths = omp_many(A, Y, max_terms=25, tol=tols)
    assert len(paths) == 4
    assert len({p.terms for p in paths}) > 2
    for i, p in enumerate(paths):
        assert_paths_equal(p, omp(A, Y[:, i], max_terms=25, tol=tols[i]))
    # A scalar tol applies to all outputs alike
    for i, p in enumerate(omp_many(A, Y, max_terms=25, tol=1e-3)):
        assert_paths_equal(p, omp(A, Y[:, i], max_terms=25, tol=1e-3))


def test_omp_many_per_output_stop_and_length_check():
    rng, _, A = random_dictionary(6)
    Y = rng.normal(size=(A.shape[0], 2))
    paths = omp_many(A, Y, max_terms=10, stop=[None, lambda k, s, c: k >= 4])
    assert [p.terms for p in paths] == [10, 4]
    assert [p.reason for p in paths] == ["max_terms", "stop"]
    with pytest.raises(ValueError, match="tol has 3 entries for 2 outputs"):
        omp_many(A, Y, max_terms=3, tol=[1.0, 2.0, 3.0])


def test_inputs_are_not_modified():
    rng, _, A = random_dictionary(2)
    y = rng.normal(size=A.shape[0])
    A0, y0 = A.copy(), y.copy()
    omp(A, y, max_terms=5)
    omp_many(A, y[:, None], max_terms=5)
    np.testing.assert_array_equal(A, A0)
    np.testing.assert_array_equal(y, y0)


def test_fortran_ordered_and_strided_dictionaries():
    rng, _, A = random_dictionary(8)
    y = rng.normal(size=A.shape[0])
    ref = omp(A, y, max_terms=12)
    assert_paths_equal(omp(np.asfortranarray(A), y, max_terms=12), ref)
    wide = np.repeat(A, 2, axis=1)[:, ::2]  # a non-contiguous view equal to A
    assert_paths_equal(omp(wide, y, max_terms=12), ref)


# --- stopping ---------------------------------------------------------------------------------


def test_tol_ends_path_at_first_k_below():
    rng, _, A = random_dictionary(4)
    y = np.sin(2 * A[:, 1]) + A[:, 2] * A[:, 3]
    full = omp(A, y, max_terms=40)
    tol = full.train_rms[14] * 1.0001  # just above the 15-term residual
    path = omp(A, y, max_terms=40, tol=tol)
    assert path.reason == "tol"
    assert path.terms == 15
    assert path.train_rms[-1] <= tol < path.train_rms[-2]
    np.testing.assert_array_equal(path.support, full.support[:15])
    # A tolerance already met by y itself selects nothing
    empty = omp(A, y, max_terms=5, tol=2 * rms(y))
    assert empty.terms == 0 and empty.reason == "tol"
    assert empty.coefficients(0).shape == (0,)


def test_stop_callback_schedule_and_early_end():
    rng, _, A = random_dictionary(9)
    y = rng.normal(size=A.shape[0])
    seen: list[int] = []

    def record(k, support, coef):
        seen.append(k)
        assert support.shape == coef.shape == (k,)
        return False

    path = omp(A, y, max_terms=10, stop=record, check_every=3)
    assert seen == [3, 6, 9, 10]  # every third term, and the last one
    assert path.terms == 10 and path.reason == "max_terms"

    seen.clear()
    path = omp(A, y, max_terms=10, stop=lambda k, s, c: record(k, s, c) or k == 6,
               check_every=3)
    assert seen == [3, 6]
    assert path.terms == 6 and path.reason == "stop"

    # When tol ends the path between checks, the callback still sees the last term
    seen.clear()
    full = omp(A, y, max_terms=10)
    path = omp(A, y, max_terms=10, tol=full.train_rms[4], stop=record, check_every=3)
    assert path.terms == 5 and seen == [3, 5]


def test_held_out_stopping():
    # The intended use: fit on a training split, stop when the held-out RMS stops improving
    rng = np.random.default_rng(11)
    x = rng.uniform(-1.0, 1.0, (1200, 2))
    y = np.exp(x[:, 0]) * np.cos(2 * x[:, 1]) + 1e-3 * rng.normal(size=len(x))
    A = design_matrix(x, monomials(2, 12))
    train, held = slice(0, 800), slice(800, None)
    history: dict[int, float] = {}

    def held_out(k, support, coef):
        history[k] = rms(A[held][:, support] @ coef - y[held])
        best = min(history, key=history.get)
        return k - best >= 5  # no improvement over the last 5 terms

    path = omp(A[train], y[train], max_terms=80, stop=held_out)
    assert path.reason == "stop"
    assert path.terms < 80
    best = min(history, key=history.get)
    assert path.terms == best + 5
    # The callback saw exactly the path's coefficients
    c = path.coefficients(best)
    assert history[best] == rms(A[held][:, path.support[:best]] @ c - y[held])
    # Noise level 1e-3: the best held-out model is at the noise floor, within a factor 1.5
    assert history[best] < 1.5e-3


def test_exact_zero_residual_stops():
    A = np.eye(8)[:, :6] * 2.0  # orthogonal columns; exact arithmetic throughout
    y = np.zeros(8)
    y[0], y[2] = 3.0, -5.0
    path = omp(A, y, max_terms=5)
    assert path.support.tolist() == [2, 0]
    assert path.reason == "zero_residual"
    assert path.train_rms[-1] == 0.0
    np.testing.assert_array_equal(path.coefficients(2), [-2.5, 1.5])
    zero = omp(A, np.zeros(8), max_terms=5)
    assert zero.terms == 0 and zero.reason == "zero_residual"


# --- ill-conditioned dictionaries -------------------------------------------------------------


def check_sane(path: OmpPath, A: np.ndarray, y: np.ndarray) -> None:
    """No NaN, no repeats, dependent columns never selected, residual never increasing."""
    assert np.all(np.isfinite(path.train_rms))
    assert np.all(np.isfinite(path.r_factor))
    assert len(set(path.support.tolist())) == path.terms
    assert not set(path.dependent.tolist()) & set(path.support.tolist())
    # ||r_new||^2 = ||r||^2 - (q^T r)^2 in exact arithmetic; computed norms may only wobble by
    # a few ulps of ||r||, hence the 1e-14 relative slack
    rms_path = np.concatenate([[path.initial_rms], path.train_rms])
    assert np.all(np.diff(rms_path) <= 1e-14 * rms_path[:-1])
    for k in range(1, path.terms + 1):
        sub = A[:, path.support[:k]]
        c = path.coefficients(k)
        assert np.all(np.isfinite(c))
        # Residual of the back-substituted coefficients vs the recursively updated one: they
        # differ by O(eps * cond(A_S) * ||y||) for a backward-stable fit; factor 100 margin
        slack = 100 * EPS * np.linalg.cond(sub) * rms(y)
        assert abs(rms(sub @ c - y) - path.train_rms[k - 1]) <= slack


def test_clustered_high_degree_monomials():
    # 1, x, ..., x^12 on x in [0.99, 1]: the columns agree to ~1e-2 and the full matrix has
    # cond ~ 1e30; only a handful of columns are numerically independent
    rng = np.random.default_rng(0)
    x = rng.uniform(0.99, 1.0, (400, 1))
    A = design_matrix(x, monomials(1, 12))
    y = np.exp(3.0 * x[:, 0])
    path = omp(A, y, max_terms=13)
    check_sane(path, A, y)
    assert path.reason == "exhausted"
    assert 3 <= path.terms < 13
    assert path.terms + len(path.dependent) == 13
    # A five-term polynomial on a 0.01-wide interval fits exp to ~(0.005)^5 / 5! ~ 1e-14
    # relative in exact arithmetic; the conditioning (cond ~ 1e10) limits it to ~1e-9
    assert path.train_rms[-1] < 1e-9 * rms(y)


def test_duplicated_and_zero_columns():
    rng = np.random.default_rng(1)
    B = rng.normal(size=(50, 6))
    # Columns: B0..B5, a copy of B0, -3 * B2, zeros, B1 + B4 (dependent combination)
    A = np.column_stack([B, B[:, 0], -3.0 * B[:, 2], np.zeros(50), B[:, 1] + B[:, 4]])
    y = B @ rng.normal(size=6) + 0.1 * rng.normal(size=50)
    path = omp(A, y, max_terms=A.shape[1])
    check_sane(path, A, y)
    assert path.reason == "exhausted"
    assert path.terms == 6  # rank of A
    assert 8 in path.dependent.tolist()  # the zero column is never a candidate
    assert len(path.dependent) == A.shape[1] - 6
    # The selected columns span range(B): the fit equals the least-squares fit on B
    ref = B @ np.linalg.lstsq(B, y, rcond=None)[0]
    fit = A[:, path.support] @ path.coefficients(path.terms)
    np.testing.assert_allclose(fit, ref, atol=1e-12 * rms(y))  # cond(B) ~ 3: 1e-12 ample
    # All-zero dictionary: nothing is usable
    empty = omp(np.zeros((5, 3)), np.ones(5), max_terms=3)
    assert empty.terms == 0 and empty.reason == "exhausted"
    assert empty.dependent.tolist() == [0, 1, 2]


def test_nearly_dependent_column_is_rejected():
    # A column equal to another up to a relative 1e-13 perturbation lies below the
    # dependence threshold and is never selected; one perturbed by 1e-6 is usable
    rng = np.random.default_rng(2)
    B = rng.normal(size=(100, 4))
    b0 = B[:, 0] / np.linalg.norm(B[:, 0])
    u = rng.normal(size=100)
    u /= np.linalg.norm(u)
    assert DEPENDENCE_TOL == 1e-10
    A = np.column_stack([B, b0 + 1e-13 * u, b0 + 1e-6 * u])
    y = B @ np.ones(4) + 1e-6 * u
    path = omp(A, y, max_terms=6)
    check_sane(path, A, y)
    assert 4 in path.dependent.tolist()
    assert 5 in path.support.tolist()


# --- errors -----------------------------------------------------------------------------------


def test_bad_inputs():
    A = np.ones((20, 6))
    y = np.ones(20)
    with pytest.raises(ValueError, match=r"A must be a 2-D"):
        omp(np.ones(20), y, max_terms=2)
    with pytest.raises(ValueError, match=r"y has shape \(19,\), expected \(20,\)"):
        omp(A, np.ones(19), max_terms=2)
    with pytest.raises(ValueError, match=r"max_terms must be an integer >= 1, got 0"):
        omp(A, y, max_terms=0)
    with pytest.raises(ValueError, match=r"check_every must be an integer >= 1"):
        omp(A, y, max_terms=2, check_every=0)
    with pytest.raises(ValueError, match=r"N == 0"):
        omp(np.ones((0, 6)), np.ones(0), max_terms=2)
    with pytest.raises(ValueError, match=r"Y has shape \(19, 2\)"):
        omp_many(A, np.ones((19, 2)), max_terms=2)

    bad = A.copy()
    bad[10, 4] = np.nan
    bad[12, 0] = np.inf
    bad[15, 5] = -np.inf
    with pytest.raises(ValueError, match=r"A has 3 non-finite entries \(first at row 10, "
                                         r"column 4\)"):
        omp(bad, y, max_terms=2)
    bad_y = y.copy()
    bad_y[5] = np.inf
    with pytest.raises(ValueError, match=r"y has 1 non-finite entry \(first at row 5\)"):
        omp(A, bad_y, max_terms=2)
    Y = np.ones((20, 3))
    Y[7, 2] = np.nan
    with pytest.raises(ValueError, match=r"Y has 1 non-finite entry \(first at row 7, "
                                         r"column 2\)"):
        omp_many(A, Y, max_terms=2)


def test_fit_polynomial_rejects_bad_xhat():
    with pytest.raises(ValueError, match="output u: xhat must be"):
        fit_polynomial(np.ones(5), np.ones(5), output="u", unit="mm", max_degree=2,
                       max_terms=2)
