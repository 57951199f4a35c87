"""Tensor least squares on a ray grid (lensfit.poly.tensor): exact recovery of synthetic
tensor polynomials on a complete grid and with holes (the conjugate-gradient path), the
output's mirror parity, the mirror-symmetric stop points and the quadratic hole filling.

Tolerances: the synthetic problems have ~500 unknowns on 120 x 64 cells with monomials
of degree <= 6 in the stop point and <= 4 in the field on [-1, 1]. The direct solve
(two QRs per parity class) is exact to rounding times the R factors' condition numbers
(~1e2-1e3): measured 2-6e-13 of the largest coefficient; bound 1e-10. With holes, CG
stops at a normal-equation residual of 1e-12 of the right-hand side (CG_TOL), which the
conditioning amplifies in W: measured 1-4e-10 after 14-15 iterations; bound 1e-8.
"""

from __future__ import annotations

import numpy as np
import pytest

from lensfit.poly.polynomial import design_matrix
from lensfit.poly.tensor import (
    CG_MAX_ITER,
    TensorFit,
    aperture_exponents,
    field_exponents,
    fill_holes,
    fit_tensor,
    prune_support,
    staircase_levels,
    symmetric_disc_points,
)

G, K = 120, 64  # field points, stop points (16 distinct per parity class)
A_EXPS = aperture_exponents(6)  # 28 monomials, at most 10 per parity class
F_EXPS = field_exponents(4, 4)  # 70 monomials of (x-like, y-like, third, wavelength)


def allowed(parity: tuple[int, int]) -> np.ndarray:
    """(n_a, n_v) True where x_a^i y_a^j times a field monomial has the output's parity:
    exponents of the x-like inputs (x_a and field variable 0) sum to px mod 2, the same
    for y (y_a and field variable 1)."""
    px = (A_EXPS[:, None, 0] + F_EXPS[None, :, 0]) % 2 == parity[0]
    py = (A_EXPS[:, None, 1] + F_EXPS[None, :, 1]) % 2 == parity[1]
    return px & py


def grid(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return symmetric_disc_points(rng, K), rng.uniform(-1.0, 1.0, (G, 4))


def synthetic(a_hat: np.ndarray, v_hat: np.ndarray, W: np.ndarray) -> np.ndarray:
    """sum_jm W[j, m] b_j(a) d_m(v) on the grid (G, K), term by term with plain powers
    (not the design matrices fit_tensor uses)."""
    out = np.zeros((len(v_hat), len(a_hat)))
    for j, m in zip(*np.nonzero(W), strict=True):
        b = a_hat[:, 0] ** A_EXPS[j, 0] * a_hat[:, 1] ** A_EXPS[j, 1]
        d = np.prod(v_hat ** F_EXPS[m], axis=1)
        out += W[j, m] * np.outer(d, b)
    return out


def random_w(parity: tuple[int, int], seed: int, wrong_parity: float = 0.0) -> np.ndarray:
    """Random coefficients on the allowed terms (and ``wrong_parity`` times random ones on
    the others)."""
    rng = np.random.default_rng(seed)
    ok = allowed(parity)
    return rng.normal(size=ok.shape) * np.where(ok, 1.0, wrong_parity)


PARITIES = [(0, 0), (1, 0), (0, 1), (1, 1)]


@pytest.mark.parametrize("parity", PARITIES)
def test_complete_grid_recovers_the_polynomial(parity):
    a_hat, v_hat = grid()
    W = random_w(parity, seed=1)
    values = synthetic(a_hat, v_hat, W)
    tf = fit_tensor(a_hat, v_hat, values, np.ones((G, K), dtype=bool), A_EXPS, F_EXPS,
                    parity=parity)
    assert (tf.holes, tf.cg_iterations) == (0, 0)  # the direct solve, no CG
    assert tf.W.shape == W.shape
    assert np.max(np.abs(tf.W - W)) <= 1e-10 * np.max(np.abs(W))
    # grid() and evaluate() give the fitted polynomial back on the grid's cells
    np.testing.assert_allclose(tf.grid(a_hat, v_hat), values, rtol=0,
                               atol=1e-10 * np.max(np.abs(values)))
    g, k = np.repeat(np.arange(G), K), np.tile(np.arange(K), G)
    np.testing.assert_allclose(tf.evaluate(a_hat[k], v_hat[g]), values.reshape(-1), rtol=0,
                               atol=1e-10 * np.max(np.abs(values)))


@pytest.mark.parametrize("parity", [(0, 0), (1, 0)])
def test_grid_with_holes_recovers_the_polynomial_by_cg(parity):
    """10% of the cells missing at random (the rays that failed): conjugate gradients from
    the filled grid. The holes hold NaN: fit_tensor must never read them."""
    a_hat, v_hat = grid()
    W = random_w(parity, seed=2)
    values = synthetic(a_hat, v_hat, W)
    mask = np.random.default_rng(3).random((G, K)) > 0.1
    values[~mask] = np.nan
    tf = fit_tensor(a_hat, v_hat, values, mask, A_EXPS, F_EXPS, parity=parity)
    assert tf.holes == np.count_nonzero(~mask) > 0.05 * G * K
    assert 0 < tf.cg_iterations < CG_MAX_ITER  # converged, not stopped by the cap
    assert np.all(np.isfinite(tf.W))
    assert np.max(np.abs(tf.W - W)) <= 1e-8 * np.max(np.abs(W))


@pytest.mark.parametrize("parity", PARITIES)
def test_terms_of_the_wrong_parity_are_zero(parity):
    """Data with a large part of the wrong parity (as a slightly asymmetric trace would
    give): no term of the wrong parity gets a coefficient, not even a rounding one, with
    and without holes, and terms() lists only terms of the output's parity."""
    a_hat, v_hat = grid()
    values = synthetic(a_hat, v_hat, random_w(parity, seed=4, wrong_parity=0.5))
    ok = allowed(parity)
    for mask in (np.ones((G, K), dtype=bool), np.random.default_rng(5).random((G, K)) > 0.1):
        tf = fit_tensor(a_hat, v_hat, values, mask, A_EXPS, F_EXPS, parity=parity)
        assert np.all(tf.W[~ok] == 0.0)
        assert np.count_nonzero(tf.W[ok]) > 0.9 * np.count_nonzero(ok)
        a_e, f_e, coef = tf.terms()
        assert len(coef) == np.count_nonzero(tf.W) and np.all(coef != 0)
        assert np.all((a_e[:, 0] + f_e[:, 0]) % 2 == parity[0])
        assert np.all((a_e[:, 1] + f_e[:, 1]) % 2 == parity[1])


def test_terms_are_field_major():
    """terms() orders by field monomial first (a runtime folds the field inputs in first),
    and its coefficients are W's entries."""
    a_hat, v_hat = grid()
    tf = fit_tensor(a_hat, v_hat, synthetic(a_hat, v_hat, random_w((1, 0), seed=6)),
                    np.ones((G, K), dtype=bool), A_EXPS, F_EXPS, parity=(1, 0))
    a_e, f_e, coef = tf.terms()
    rows = {tuple(e): i for i, e in enumerate(A_EXPS.tolist())}
    cols = {tuple(e): i for i, e in enumerate(F_EXPS.tolist())}
    j = np.array([rows[tuple(e)] for e in a_e.tolist()])
    m = np.array([cols[tuple(e)] for e in f_e.tolist()])
    assert np.all(np.diff(m) >= 0)
    assert np.all(np.diff(j)[np.diff(m) == 0] > 0)
    np.testing.assert_array_equal(coef, tf.W[j, m])


def test_fit_tensor_refuses_what_it_cannot_fit():
    a_hat, v_hat = grid()
    values = np.zeros((G, K))
    full = np.ones((G, K), dtype=bool)
    with pytest.raises(ValueError, match="shapes do not match"):
        fit_tensor(a_hat[:-4], v_hat, values, full, A_EXPS, F_EXPS, parity=(0, 0))
    with pytest.raises(ValueError, match="non-finite values in the cells to fit"):
        fit_tensor(a_hat, v_hat, np.full((G, K), np.nan), full, A_EXPS, F_EXPS,
                   parity=(0, 0))
    with pytest.raises(ValueError, match="too few data"):  # 70 field terms for 10 points
        fit_tensor(a_hat, v_hat[:10], values[:10], full[:10], A_EXPS, F_EXPS, parity=(0, 0))


def test_dependent_stop_monomials_are_refused():
    """32 points are 8 distinct points per parity class; the even-even class of stop
    degree 6 has 10 monomials: the problem is singular and must be refused."""
    rng = np.random.default_rng(0)
    a_hat, v_hat = symmetric_disc_points(rng, 32), rng.uniform(-1.0, 1.0, (G, 4))
    values = synthetic(a_hat, v_hat, random_w((0, 0), seed=1))
    with pytest.raises(ValueError):
        tf = fit_tensor(a_hat, v_hat, values, np.ones((G, 32), dtype=bool), A_EXPS, F_EXPS,
                        parity=(0, 0))
        print(np.abs(tf.W).max())  # what comes back instead: coefficients ~1e17


# --- exponents and stop points -----------------------------------------------------------


def test_exponent_sets():
    e = aperture_exponents(4)
    assert e.shape == (15, 2) and e.dtype == np.int32
    assert e.tolist()[:6] == [[0, 0], [1, 0], [0, 1], [2, 0], [1, 1], [0, 2]]
    assert np.all(np.diff(e.sum(axis=1)) >= 0) and e.sum(axis=1).max() == 4
    f = field_exponents(4, 3)
    assert f.shape == (35, 4) and f.sum(axis=1).max() == 3
    capped = field_exponents(4, 3, (3, 3, 0, 1))  # a variable capped at 0 drops out
    assert np.all(capped[:, 2] == 0) and np.all(capped[:, 3] <= 1)
    assert len(capped) == 10 + 6  # degree <= 3 in two variables, times 1 or the fourth


def test_symmetric_disc_points():
    rng = np.random.default_rng(7)
    n = 4000
    p = symmetric_disc_points(rng, n)
    q = n // 4
    assert p.shape == (n, 2)
    assert np.all(p[:q] >= 0)  # the first quarter is the first quadrant ...
    np.testing.assert_array_equal(p[q:2 * q], p[:q] * [-1, 1])  # ... then its mirrors
    np.testing.assert_array_equal(p[2 * q:3 * q], p[:q] * [1, -1])
    np.testing.assert_array_equal(p[3 * q:], -p[:q])
    r2 = np.sum(p**2, axis=1)
    assert np.all(r2 <= 1.0)
    # Uniform in area: r^2 is uniform on [0, 1]: mean 1/2, standard error of the mean of
    # 1000 independent radii 0.29 / sqrt(1000) = 0.009; bound 0.04 (4 sigma)
    assert abs(r2[:q].mean() - 0.5) < 0.04
    # ... and in angle: the mean angle in the quadrant is pi/4 (s.e. 0.45 / sqrt(1000))
    assert abs(np.arctan2(p[:q, 1], p[:q, 0]).mean() - np.pi / 4) < 0.06
    # Same seed, same points
    np.testing.assert_array_equal(symmetric_disc_points(np.random.default_rng(7), n), p)
    for bad in (6, 0, -4):
        with pytest.raises(ValueError, match=f"n = {bad} must be a positive multiple of 4"):
            symmetric_disc_points(rng, bad)


def test_edge_weighted_disc_points_follow_their_radial_law():
    """The grid's stop points (lensfit.sample.rays.STOP_EDGE_SHARE): a share of the
    radii with density r / sqrt(1 - r^2), the rest uniform in area, so the radial CDF is
    share (1 - sqrt(1 - r^2)) + (1 - share) r^2. Kolmogorov-Smirnov on the 1000
    independent radii of the first quadrant: the law's own points pass at p > 1e-3, and
    uniform points (what the grid had) fail it; mirrors as for uniform points; share 0
    draws exactly the uniform points of the same seed."""
    from scipy.stats import kstest

    share, n = 0.5, 4000

    def cdf(r):
        return share * (1.0 - np.sqrt(1.0 - r * r)) + (1.0 - share) * r * r

    p = symmetric_disc_points(np.random.default_rng(11), n, share)
    q = n // 4
    r = np.hypot(p[:q, 0], p[:q, 1])
    assert np.all(r <= 1.0)
    np.testing.assert_array_equal(p[3 * q:], -p[:q])
    assert kstest(r, cdf).pvalue > 1e-3
    uniform = symmetric_disc_points(np.random.default_rng(11), n)
    assert kstest(np.hypot(uniform[:q, 0], uniform[:q, 1]), cdf).pvalue < 1e-3
    # Denser at the rim: the outer 5% of the radius holds 0.5 x 31.2% + 0.5 x 9.75% =
    # 20.5% of the points (sqrt(1 - 0.95^2) = 0.312), against 9.75% for uniform points;
    # binomial s.e. of 1000 radii 1.3%, bounds 4 sigma
    assert 0.155 < np.mean(r > 0.95) < 0.255
    np.testing.assert_array_equal(symmetric_disc_points(np.random.default_rng(11), n, 0.0),
                                  uniform)


def test_parity_classes_are_orthogonal_on_symmetric_points():
    """What the separation by class relies on: two stop monomials of different parity
    classes sum to zero over a mirror-symmetric set (to rounding of the sum of |terms|)."""
    p = symmetric_disc_points(np.random.default_rng(8), 256)
    B = design_matrix(p, A_EXPS)
    gram = B.T @ B
    scale = np.abs(B).T @ np.abs(B)
    cls = (A_EXPS % 2) @ [1, 2]
    different = cls[:, None] != cls[None, :]
    assert np.all(np.abs(gram[different]) <= 1e-14 * scale[different])
    assert np.all(np.abs(gram[~different & np.eye(len(cls), dtype=bool)]) > 0)


# --- filling the holes ------------------------------------------------------------------


def test_fill_holes_is_exact_on_quadratics():
    """Each group's values a quadratic in the stop point: its holes come back as that
    quadratic (a 6 x 6 least-squares solve: 1e-12 of the values), the valid cells
    untouched bit for bit; a group with fewer than 12 valid cells gets its valid cells'
    mean, one with none 0."""
    rng = np.random.default_rng(9)
    a_hat = symmetric_disc_points(rng, K)
    B2 = design_matrix(a_hat, aperture_exponents(2))
    coef = rng.normal(size=(10, 6))
    values = coef @ B2.T  # (10, K)
    mask = rng.random((10, K)) > 0.3
    mask[7] = False
    mask[7, :8] = True  # 8 valid cells
    mask[8] = False  # none
    values_in = np.where(mask, values, np.nan)
    out = fill_holes(a_hat, values_in, mask)
    assert np.array_equal(out[mask], values[mask])
    quad = np.ones(10, dtype=bool)
    quad[[7, 8]] = False
    np.testing.assert_allclose(out[quad], values[quad], rtol=0,
                               atol=1e-12 * np.abs(values).max())
    np.testing.assert_allclose(out[7, 8:], values[7, :8].mean(), rtol=1e-14)
    assert np.all(out[8] == 0.0)


def test_tensor_fit_dataclass_is_what_fit_tensor_returns():
    a_hat, v_hat = grid()
    tf = fit_tensor(a_hat, v_hat, np.zeros((G, K)), np.ones((G, K), dtype=bool), A_EXPS,
                    F_EXPS, parity=(0, 0))
    assert isinstance(tf, TensorFit)
    assert np.all(tf.W == 0.0) and len(tf.terms()[2]) == 0


# --- Fits on a staircase support, and the cut (prune_support) -----------------------------

def staircase(levels: np.ndarray) -> np.ndarray:
    """(n_a, n_v): field monomial m with every stop monomial up to degree levels[m]."""
    return A_EXPS.sum(axis=1)[:, None] <= levels[None, :]


def random_levels(seed: int) -> np.ndarray:
    """Per field monomial a stop degree in -1..6, lower for higher field degrees (as the
    cut makes them), so the support is a staircase but not a rectangle."""
    rng = np.random.default_rng(seed)
    top = 6 - F_EXPS.sum(axis=1)
    return np.minimum(top + rng.integers(-1, 3, len(F_EXPS)), 6)


@pytest.mark.parametrize("parity", PARITIES)
def test_a_staircase_fit_is_the_least_squares_over_its_monomials(parity):
    """On a complete grid of data that are NOT in the support's span, fit_tensor(support=)
    must equal the plain least squares over the support's monomials (their tensor design
    matrix, np.linalg.lstsq): the reordered QRs are an exact change of basis. W is exactly
    zero outside the support (triangular solves of a staircase Z). Both solves are
    rounding-exact on these well-conditioned problems: measured ~1e-12 relative; bound
    1e-8."""
    a_hat, v_hat = grid()
    values = synthetic(a_hat, v_hat, random_w(parity, seed=5))  # every allowed term
    support = staircase(random_levels(6))
    tf = fit_tensor(a_hat, v_hat, values, np.ones((G, K), dtype=bool), A_EXPS, F_EXPS,
                    parity=parity, support=support)
    assert np.all(tf.W[~(support & allowed(parity))] == 0.0)
    j, m = np.nonzero(support & allowed(parity))
    B = design_matrix(a_hat, A_EXPS)
    D = design_matrix(v_hat, F_EXPS)
    X = (D[:, None, m] * B[None, :, j]).reshape(G * K, len(j))  # rows: (group, stop point)
    coef, *_ = np.linalg.lstsq(X, values.reshape(-1), rcond=None)
    np.testing.assert_allclose(tf.W[j, m], coef, rtol=0, atol=1e-8 * np.max(np.abs(coef)))
    assert tf.energy is None  # energies belong to the full, degree-ordered fit


def test_a_staircase_fit_with_holes_matches_the_complete_one():
    """The same support by conjugate gradients on 10% holes, of data inside the support's
    span: the coefficients come back (measured ~1e-10; bound 1e-7, as for holes above)."""
    a_hat, v_hat = grid()
    support = staircase(random_levels(7))
    W = random_w((0, 0), seed=8) * support
    values = synthetic(a_hat, v_hat, W)
    mask = np.random.default_rng(9).random((G, K)) > 0.1
    values[~mask] = np.nan
    tf = fit_tensor(a_hat, v_hat, values, mask, A_EXPS, F_EXPS, parity=(0, 0),
                    support=support)
    assert 0 < tf.cg_iterations < CG_MAX_ITER
    assert np.max(np.abs(tf.W - W)) <= 1e-7 * np.max(np.abs(W))


def test_a_support_that_is_not_a_staircase_is_refused():
    support = staircase(random_levels(6))
    j = int(np.nonzero(A_EXPS.sum(axis=1) == 1)[0][0])
    m = int(np.nonzero(support[j])[0][0])
    support[j, m] = False  # a hole under a kept pair
    a_hat, v_hat = grid()
    with pytest.raises(ValueError, match="staircase"):
        fit_tensor(a_hat, v_hat, np.zeros((G, K)), np.ones((G, K), dtype=bool), A_EXPS,
                   F_EXPS, parity=(0, 0), support=support)


@pytest.mark.parametrize("parity", [(0, 0), (1, 0)])
def test_the_cut_costs_the_energy_it_leaves_out(parity):
    """The invariant the cut's budget rests on. On a complete grid the orthonormal
    coordinates are independent: a support whose field monomials per stop degree are all
    those up to a total degree (a prefix of the order the energies were taken in) raises
    the sum of squared residuals by exactly the energy it leaves out (rounding of sums of
    ~7700 squares: measured ~1e-13 relative, bound 1e-8). prune_support's supports cap
    variables apart, so the kept field monomials are no longer such a prefix and the
    energy is an estimate: the true rise measured 0.98-1.27 times it here, bound 0.7-1.5
    (the fit checks every cut on held-out rays). Budgets from nothing to everything; the cut never
    leaves out more than its budget."""
    a_hat, v_hat = grid()
    rng = np.random.default_rng(10)
    W = random_w(parity, seed=11) * 0.5 ** (A_EXPS.sum(1)[:, None] + F_EXPS.sum(1)[None, :])
    values = synthetic(a_hat, v_hat, W) + 1e-3 * rng.normal(size=(G, K))  # plus noise
    ones = np.ones((G, K), dtype=bool)
    full = fit_tensor(a_hat, v_hat, values, ones, A_EXPS, F_EXPS, parity=parity)
    base = float(np.sum((full.grid(a_hat, v_hat) - values) ** 2))
    total = float(np.sum(full.energy))
    assert total == pytest.approx(float(np.sum(full.grid(a_hat, v_hat) ** 2)), rel=1e-8)

    def rise(support: np.ndarray) -> float:
        cut = fit_tensor(a_hat, v_hat, values, ones, A_EXPS, F_EXPS, parity=parity,
                         support=support)
        return float(np.sum((cut.grid(a_hat, v_hat) - values) ** 2)) - base

    # Exact: per stop degree a, every field monomial of total degree <= 4 - a
    prefix = staircase(4 - F_EXPS.sum(axis=1))
    left_out = float(np.sum(np.where(prefix, 0.0, full.energy)))
    assert rise(prefix) == pytest.approx(left_out, rel=1e-8)
    sizes = []
    for share in (0.0, 1e-6, 1e-3, 0.1, 1.0):
        support = prune_support(A_EXPS, F_EXPS, full.energy, share * total)
        staircase_levels(A_EXPS, support)  # a staircase: raises if not
        left_out = float(np.sum(np.where(support, 0.0, full.energy)))
        assert left_out <= share * total * (1 + 1e-12)
        assert 0.7 * left_out - 1e-8 * total <= rise(support) <= 1.5 * left_out + 1e-8 * total
        sizes.append(int(np.count_nonzero(support & allowed(parity))))
    assert sizes[0] == np.count_nonzero(full.W)  # no budget: nothing goes
    assert sizes == sorted(sizes, reverse=True) and sizes[-1] == 0  # all of it: all goes


def test_the_cut_keeps_a_down_set_and_drops_the_weakest_first():
    """Energies that fall with degree: the kept blocks form a down-set in the stop degree
    and in each field variable (a kept monomial's divisors are kept), and a block with
    more energy than all it would leave out is never dropped before a weaker one above
    it. The piston budget is separate: with no room for the piston, every stop-free pair
    stays while the rest is cut."""
    deg_a = A_EXPS.sum(1)[:, None]
    energy = (10.0 ** -(deg_a + F_EXPS.sum(1)[None, :])) * allowed((0, 0))
    budget = 1e-5 * energy.sum()
    support = prune_support(A_EXPS, F_EXPS, energy, budget)
    levels = staircase_levels(A_EXPS, support)
    index = {tuple(e): i for i, e in enumerate(F_EXPS.tolist())}
    for m, e in enumerate(F_EXPS.tolist()):
        for v in range(4):
            if e[v]:
                f = list(e)
                f[v] -= 1
                assert levels[index[tuple(f)]] >= levels[m], (e, f)
    kept = energy[support].sum()
    assert energy.sum() - kept <= budget
    # Everything of total degree <= 2 carries more than the whole budget: kept
    assert np.all(support[(deg_a + F_EXPS.sum(1)[None, :] <= 2) & allowed((0, 0))])
    no_piston = prune_support(A_EXPS, F_EXPS, energy, 0.5 * energy.sum(), piston_budget=0.0)
    assert np.all(no_piston[deg_a[:, 0] == 0][:, energy[deg_a[:, 0] == 0].max(0) > 0])
    assert np.count_nonzero(no_piston) < np.count_nonzero(support)


@pytest.mark.parametrize("parity", [(0, 0), (1, 1)])
def test_a_weighted_fit_is_the_weighted_least_squares(parity):
    """Cells of weight w in (0, 1] (a lens fit's rays beyond the housings, FAR_WEIGHT)
    and holes: fit_tensor(weights=) must equal the plain least squares of the weighted
    rows (w times the tensor design matrix's rows and the data, np.linalg.lstsq), on data
    that are NOT in the polynomial's span, so the weights change the answer. Measured
    ~1e-11 relative after CG on these well-conditioned problems (CG_TOL 1e-12 of the
    normal equations' right-hand side); bound 1e-7, as for holes above."""
    a_hat, v_hat = grid()
    rng = np.random.default_rng(11)
    values = synthetic(a_hat, v_hat, random_w(parity, seed=12, wrong_parity=0.3))
    values += 0.1 * rng.normal(size=values.shape)  # outside any polynomial's span
    mask = rng.random((G, K)) > 0.1
    weights = np.where(rng.random((G, K)) < 0.3, 0.3, 1.0)  # 30% of the cells "far"
    values[~mask] = np.nan
    tf = fit_tensor(a_hat, v_hat, values, mask, A_EXPS, F_EXPS, parity=parity,
                    weights=weights)
    assert 0 < tf.cg_iterations < CG_MAX_ITER
    j, m = np.nonzero(allowed(parity))
    B = design_matrix(a_hat, A_EXPS)
    D = design_matrix(v_hat, F_EXPS)
    X = (D[:, None, m] * B[None, :, j]).reshape(G * K, len(j))
    w = np.where(mask, weights, 0.0).reshape(-1)
    rows = w > 0
    coef, *_ = np.linalg.lstsq(X[rows] * w[rows, None], values.reshape(-1)[rows] * w[rows],
                               rcond=None)
    np.testing.assert_allclose(tf.W[j, m], coef, rtol=0, atol=1e-7 * np.max(np.abs(coef)))
    # and it differs from the unweighted fit by far more than that: the weights act
    plain = fit_tensor(a_hat, v_hat, values, mask, A_EXPS, F_EXPS, parity=parity)
    assert np.max(np.abs(plain.W[j, m] - coef)) > 1e-3 * np.max(np.abs(coef))


def test_weights_outside_0_1_or_of_another_shape_are_refused():
    a_hat, v_hat = grid()
    values = synthetic(a_hat, v_hat, random_w((0, 0), seed=1))
    mask = np.ones((G, K), dtype=bool)
    for bad in (np.zeros((G, K)), np.full((G, K), 1.5), np.ones((G, K - 1))):
        with pytest.raises(ValueError, match="weights"):
            fit_tensor(a_hat, v_hat, values, mask, A_EXPS, F_EXPS, parity=(0, 0),
                       weights=bad)
