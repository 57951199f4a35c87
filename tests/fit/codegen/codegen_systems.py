"""Random sparse polynomial systems shaped like the lens systems P_o and P_s, and the
error scales the agreement tests divide by."""

from __future__ import annotations

import numpy as np

from lensfit.poly import Input, Polynomial, System, design_matrix, monomials

WAVELENGTH = Input("λ", "nm", 380.0, 780.0, "inverse_square")


def random_terms(rng: np.random.Generator, n_inputs: int, n_terms: int,
                 max_degree: int) -> tuple[np.ndarray, np.ndarray]:
    """``n_terms`` distinct exponent rows, degree drawn uniformly in 0..max_degree (so low
    degrees are not swamped by the many high-degree monomials), and coefficients of mixed
    sign and magnitude (1e-6 .. 1e3)."""
    table = monomials(n_inputs, max_degree)
    degree = table.sum(axis=1)
    chosen: set[int] = set()
    while len(chosen) < n_terms:
        d = int(rng.integers(0, max_degree + 1))
        chosen.add(int(rng.choice(np.flatnonzero(degree == d))))
    rows = table[sorted(chosen)]
    rows = rows[rng.permutation(len(rows))]
    coefs = rng.choice([-1.0, 1.0], n_terms) * 10.0 ** rng.uniform(-6, 3, n_terms)
    return rows, coefs


def make_systems(seed: int = 2024) -> list[System]:
    """Three systems covering the shapes code generation must handle.

    P_o: 6 inputs with a wavelength (inverse_square, 380-780 nm); outputs with 150 terms
    of degree <= 10, 5 terms, a single constant term, and only degree-0 rows (duplicates
    that must be summed). P_s: 6 inputs, one of which no output uses; 40-150 terms with a
    repeated row and a zero coefficient. clip: 2 inputs and constant outputs, one of them
    without any term, so no input is used at all."""
    rng = np.random.default_rng(seed)
    p_o_in = (Input("x_O", "mm", -12.0, 12.0), Input("y_O", "mm", -8.0, 16.0),
              Input("1/d_O", "1/mm", 0.0, 0.01), Input("x_a", "", -1.0, 1.0),
              Input("y_a", "", -1.0, 1.0), WAVELENGTH)
    e1, c1 = random_terms(rng, 6, 150, 10)
    e2, c2 = random_terms(rng, 6, 5, 10)
    zero_degree = np.zeros((3, 6), dtype=np.int32)
    p_o = System("P_o", p_o_in, (
        Polynomial("x_o", "mm", e1, c1),
        Polynomial("y_o", "mm", e2, c2),
        Polynomial("τ_o", "1", np.zeros((1, 6), dtype=np.int32), [0.87]),
        Polynomial("φ_o", "mm", zero_degree, [101.25, -1e-3, 3.5e-9]),
    ))
    p_s_in = (Input("x_S", "mm", -18.0, 18.0), Input("y_S", "mm", -12.0, 12.0),
              Input("z_S", "mm", 99.5, 100.5), Input("x_a", "mm", -20.0, 20.0),
              Input("y_a", "mm", -20.0, 20.0), WAVELENGTH)
    outs = []
    for name, k in (("x_i", 150), ("y_i", 97), ("τ_i", 40), ("φ_i", 120)):
        e, c = random_terms(rng, 5, k, 10)
        e = np.insert(e, 2, 0, axis=1)  # z_S (column 2) is used by no output
        e = np.vstack([e, e[:1]])  # a repeated row: its coefficients add
        c = np.append(c, 0.25)
        c[3] = 0.0  # a zero coefficient: dropped
        outs.append(Polynomial(name, "mm" if name != "τ_i" else "1", e, c))
    p_s = System("P_s", p_s_in, tuple(outs))
    clip = System("clip", (Input("u", "1", -1.0, 1.0), Input("v", "1", -2.0, 3.0)), (
        Polynomial("x_clip", "1", np.zeros((0, 2), dtype=np.int32), []),
        Polynomial("y_clip", "1", np.zeros((1, 2), dtype=np.int32), [-0.5]),
    ))
    return [p_o, p_s, clip]


def sample_inputs(system: System, n: int, seed: int = 7) -> np.ndarray:
    """Raw inputs uniform in the domain, plus its corners' extremes (xhat = +-1)."""
    rng = np.random.default_rng(seed)
    lo = np.array([i.lo for i in system.inputs])
    hi = np.array([i.hi for i in system.inputs])
    x = lo + (hi - lo) * rng.random((n, len(lo)))
    return np.vstack([x, lo, hi])


def term_scale(system: System, x: np.ndarray) -> np.ndarray:
    """(N, n_out): sum over terms of |c_k prod xhat^e|, the natural scale of rounding
    errors of any evaluation order (plus a tiny floor for outputs without terms)."""
    xhat = system.normalise(x)
    cols = [np.abs(design_matrix(xhat, p.exponents) * p.coefficients).sum(axis=1)
            for p in system.outputs]
    return np.stack(cols, axis=1) + 1e-300


def coefficient_scale(system: System) -> np.ndarray:
    """(n_out,): sum_k |c_k|, a bound of |P| over the whole domain (|xhat| <= 1)."""
    return np.array([np.abs(p.coefficients).sum() for p in system.outputs]) + 1e-300
