"""Tests for lensfit.poly.polynomial: inputs, monomial dictionaries and polynomial systems.

Tolerances: evaluations here involve a few dozen float64 operations on O(1) values
(eps = 2.2e-16), so 1e-12 relative is ~100x above the expected rounding while still failing on
any wrong term, coefficient or normalisation.
"""

from __future__ import annotations

import json
from math import comb

import numpy as np
import pytest

from lensfit.poly.polynomial import Input, Polynomial, System, design_matrix, monomials

# --- monomials and design matrices ------------------------------------------------------------


@pytest.mark.parametrize(("n", "d"), [(1, 0), (1, 12), (2, 2), (3, 5), (6, 6), (6, 7)])
def test_monomial_count_and_order(n, d):
    e = monomials(n, d)
    assert e.shape == (comb(n + d, d), n)
    assert e.dtype == np.int32
    assert len({tuple(r) for r in e.tolist()}) == len(e)  # no repeats
    deg = e.sum(axis=1)
    assert np.all(np.diff(deg) >= 0) and deg.max() == d  # by total degree
    np.testing.assert_array_equal(monomials(n, d), e)  # deterministic


def test_monomial_order_small_case():
    # Within a degree, by the variables used: x0^2 (0,0), x0 x1 (0,1), x1^2 (1,1)
    want = [[0, 0], [1, 0], [0, 1], [2, 0], [1, 1], [0, 2]]
    assert monomials(2, 2).tolist() == want
    with pytest.raises(ValueError, match="n_inputs >= 1"):
        monomials(0, 3)


def test_design_matrix_against_direct_products():
    rng = np.random.default_rng(0)
    x = rng.uniform(-1.0, 1.0, (200, 4))
    e = monomials(4, 5)[rng.permutation(126)]  # any order of rows
    direct = np.prod(x[:, None, :] ** e[None, :, :], axis=2)
    # Up to 5 multiplications per entry of values <= 1: a few ulps; 1e-14 relative is safe
    np.testing.assert_allclose(design_matrix(x, e), direct, rtol=1e-14, atol=0)
    assert design_matrix(x, e[:0]).shape == (200, 0)
    with pytest.raises(ValueError, match="3 columns for 4 inputs"):
        design_matrix(x, np.ones((2, 3), dtype=int))


# --- inputs -----------------------------------------------------------------------------------


def test_affine_input_maps_domain_to_unit_interval():
    inp = Input("h", "mm", -2.0, 6.0)
    np.testing.assert_array_equal(inp.normalise([-2.0, 2.0, 6.0]), [-1.0, 0.0, 1.0])
    assert inp.offset_scale == (2.0, 4.0)


def test_inverse_square_input_maps_lo_to_plus_one():
    # xhat is affine in 1/v^2, which is largest at lo: lo -> +1, hi -> -1
    inp = Input("lambda", "nm", 400.0, 700.0, "inverse_square")
    lo, hi = inp.normalise([400.0, 700.0])
    assert lo == pytest.approx(1.0, abs=1e-15)
    assert hi == pytest.approx(-1.0, abs=1e-15)
    w_mid = 0.5 * (1 / 400.0**2 + 1 / 700.0**2)  # midpoint in 1/v^2 maps to 0
    assert float(inp.normalise(w_mid**-0.5)) == pytest.approx(0.0, abs=1e-14)
    # ... and is strictly decreasing in v
    assert np.all(np.diff(inp.normalise(np.linspace(400.0, 700.0, 50))) < 0)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("u", "mm", 1.0, 1.0), "input u: empty or non-finite domain"),
        (("u", "mm", 2.0, 1.0), "input u: empty or non-finite domain"),
        (("u", "mm", 0.0, np.nan), "input u: empty or non-finite domain"),
        (("lam", "nm", 0.0, 700.0, "inverse_square"), "input lam: inverse_square needs lo > 0"),
        (("u", "mm", 0.0, 1.0, "log"), "input u: transform must be one of"),
    ],
)
def test_bad_inputs(args, message):
    with pytest.raises(ValueError, match=message):
        Input(*args)


# --- polynomials and systems ------------------------------------------------------------------


def random_system(rng: np.random.Generator, n_inputs: int = 4, n_outputs: int = 3) -> System:
    inputs = (
        Input("h", "mm", -3.0, 3.0),
        Input("lambda", "nm", 400.0, 700.0, "inverse_square"),
        Input("z", "mm", 10.0, 50.0),
        Input("f", "mm", 20.0, 80.0),
    )[:n_inputs]
    exps = monomials(n_inputs, 5)
    outputs = []
    for k in range(n_outputs):
        pick = rng.choice(len(exps), 30, replace=False)
        outputs.append(Polynomial(f"out{k}", "mm", exps[pick], rng.normal(size=30)))
    return System("P_test", inputs, tuple(outputs), {"lens": "test"})


def raw_samples(system: System, rng: np.random.Generator, n: int) -> np.ndarray:
    return np.column_stack([rng.uniform(i.lo, i.hi, n) for i in system.inputs])


@pytest.mark.parametrize("seed", range(3))
def test_specialise_equals_general_system(seed):
    rng = np.random.default_rng(seed)
    system = random_system(rng)
    fixed = {"lambda": float(rng.uniform(400.0, 700.0)), "f": float(rng.uniform(20.0, 80.0))}
    spec = system.specialise(fixed, name="P_fixed")
    assert spec.name == "P_fixed"
    assert spec.input_names == ["h", "z"]
    assert spec.info["fixed"] == fixed and spec.info["lens"] == "test"

    x = raw_samples(spec, rng, 100)
    full = np.column_stack([x[:, 0], np.full(100, fixed["lambda"]), x[:, 1],
                            np.full(100, fixed["f"])])
    want = system.evaluate(full)
    # Relative to the size of the terms (30 terms of O(1) coefficients and |xhat| <= 1)
    scale = np.array([np.abs(p.coefficients).sum() for p in system.outputs])
    np.testing.assert_allclose(spec.evaluate(x), want, rtol=0, atol=1e-12 * scale.max())

    for p in spec.outputs:  # merged: no two terms share an exponent vector
        assert len({tuple(r) for r in p.exponents.tolist()}) == p.terms
        assert p.terms < 30  # 30 terms in 4 variables collapse onto fewer in 2


def test_specialise_merges_terms():
    inputs = (Input("a", "1", -1.0, 1.0), Input("b", "1", -1.0, 1.0))
    p = Polynomial("u", "mm", [[1, 1], [1, 0], [0, 2], [0, 0]], [2.0, 3.0, 4.0, 1.0])
    spec = System("S", inputs, (p,)).specialise({"b": 0.5})
    # 2 a (0.5) + 3 a -> 4 a ; 4 (0.25) + 1 -> 2; order of first appearance
    q = spec.output("u")
    assert q.exponents.tolist() == [[1], [0]]
    np.testing.assert_array_equal(q.coefficients, [4.0, 2.0])
    with pytest.raises(KeyError, match=r"cannot fix \['c'\]"):
        System("S", inputs, (p,)).specialise({"c": 0.0})


def test_select():
    system = random_system(np.random.default_rng(4))
    sub = system.select(["out2", "out0"])
    assert sub.output_names == ["out2", "out0"]
    assert sub.output("out2") is system.output("out2")
    assert sub.inputs == system.inputs
    x = raw_samples(system, np.random.default_rng(5), 20)
    np.testing.assert_array_equal(sub.evaluate(x), system.evaluate(x)[:, [2, 0]])
    with pytest.raises(KeyError, match="has no output 'nope'"):
        system.select(["nope"])


def test_dict_round_trip_is_exact():
    system = random_system(np.random.default_rng(6))
    for d in (system.to_dict(), json.loads(json.dumps(system.to_dict()))):
        back = System.from_dict(d)
        assert back.name == system.name and back.info == system.info
        assert back.inputs == system.inputs
        for p, q in zip(system.outputs, back.outputs, strict=True):
            assert (q.output, q.unit) == (p.output, p.unit)
            np.testing.assert_array_equal(q.exponents, p.exponents)
            np.testing.assert_array_equal(q.coefficients, p.coefficients)  # bit-exact
            assert q.exponents.dtype == np.int32
        assert back.to_dict() == system.to_dict()


def test_polynomial_evaluation_and_degree():
    p = Polynomial("u", "mm", [[2, 0], [1, 3], [0, 0]], [1.5, -2.0, 0.25])
    x = np.array([[0.5, -0.5], [1.0, 1.0]])
    want = 1.5 * x[:, 0] ** 2 - 2.0 * x[:, 0] * x[:, 1] ** 3 + 0.25
    np.testing.assert_allclose(p.evaluate_normalised(x), want, rtol=1e-15)
    assert p.max_degree == 4 and p.terms == 3


def test_bad_polynomials_and_systems():
    inputs = (Input("a", "1", -1.0, 1.0), Input("b", "1", -1.0, 1.0))
    with pytest.raises(ValueError, match="output u: non-finite coefficient"):
        Polynomial("u", "mm", [[1, 0]], [np.nan])
    with pytest.raises(ValueError, match="output u: negative exponent"):
        Polynomial("u", "mm", [[1, -1]], [1.0])
    with pytest.raises(ValueError, match="output u: 2 coefficients for 1 terms"):
        Polynomial("u", "mm", [[1, 0]], [1.0, 2.0])
    wide = Polynomial("u", "mm", [[1, 0, 0]], [1.0])
    with pytest.raises(ValueError, match="S: output u has 3 exponent columns for 2 inputs"):
        System("S", inputs, (wide,))
    # The same mistake in a stored system, in its three shapes
    d = System("S", inputs, (Polynomial("u", "mm", [[1, 0], [0, 1]], [1.0, 2.0]),)).to_dict()
    for exps in ([[1, 0, 0], [0, 1, 0]], [[1, 0, 0]], [[1, 0], [1]]):
        d["outputs"][0]["exponents"] = exps
        d["outputs"][0]["coefficients"] = [1.0] * len(exps)
        with pytest.raises(ValueError, match="output u: exponents must be rows of 2"):
            System.from_dict(d)
    d = System("S", inputs, ()).to_dict()
    d["inputs"][1]["hi"] = -1.0
    with pytest.raises(ValueError, match="input b: empty"):
        System.from_dict(d)
