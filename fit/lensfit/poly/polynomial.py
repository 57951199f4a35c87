"""Sparse multivariate polynomial systems: the common currency of fitting and code generation.

A :class:`System` maps raw inputs (in their units) to outputs. Each input is first
normalised to [-1, 1] over its declared domain by an :class:`Input` (an affine map, or an
affine map of 1/v^2 for wavelengths, where dispersion is nearly linear); each output is a
:class:`Polynomial`: a sum of ``coefficient * prod(xhat_j ** exponent_j)`` over its terms.
Coefficients carry the output's unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from itertools import combinations_with_replacement
from typing import Any

import numpy as np

TRANSFORMS = ("affine", "inverse_square")


@dataclass(frozen=True)
class Input:
    """One input variable, its unit and its declared domain [lo, hi] in that unit."""

    name: str
    unit: str
    lo: float
    hi: float
    transform: str = "affine"  # "affine": v; "inverse_square": 1/v^2 (v > 0)

    def __post_init__(self) -> None:
        if self.transform not in TRANSFORMS:
            raise ValueError(f"input {self.name}: transform must be one of {TRANSFORMS}")
        if not (math.isfinite(self.lo) and math.isfinite(self.hi) and self.lo < self.hi):
            raise ValueError(
                f"input {self.name}: empty or non-finite domain [{self.lo}, {self.hi}] {self.unit}"
            )
        if self.transform == "inverse_square" and not self.lo > 0:
            raise ValueError(f"input {self.name}: inverse_square needs lo > 0, got {self.lo}")

    @property
    def offset_scale(self) -> tuple[float, float]:
        """(c, s) with xhat = (w - c) / s, w = v or 1/v^2."""
        if self.transform == "affine":
            a, b = self.lo, self.hi
        else:
            a, b = 1.0 / (self.hi * self.hi), 1.0 / (self.lo * self.lo)
        return 0.5 * (a + b), 0.5 * (b - a)

    def normalise(self, v: np.ndarray | float) -> np.ndarray:
        v = np.asarray(v, dtype=np.float64)
        w = v if self.transform == "affine" else 1.0 / (v * v)
        c, s = self.offset_scale
        return (w - c) / s

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "unit": self.unit,
            "lo": self.lo,
            "hi": self.hi,
            "transform": self.transform,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Input:
        lo, hi = float(d["lo"]), float(d["hi"])
        return cls(d["name"], d["unit"], lo, hi, d.get("transform", "affine"))


def monomials(n_inputs: int, max_degree: int) -> np.ndarray:
    """All exponent vectors of total degree <= ``max_degree``, (M, n_inputs) int32.

    Order: by total degree, then lexicographically by the variables used (deterministic)."""
    if n_inputs < 1 or max_degree < 0:
        raise ValueError(f"monomials: need n_inputs >= 1 and max_degree >= 0, got "
                         f"{n_inputs}, {max_degree}")
    rows = []
    for deg in range(max_degree + 1):
        for combo in combinations_with_replacement(range(n_inputs), deg):
            e = np.zeros(n_inputs, dtype=np.int32)
            for j in combo:
                e[j] += 1
            rows.append(e)
    return np.array(rows, dtype=np.int32).reshape(-1, n_inputs)


def design_matrix(xhat: np.ndarray, exponents: np.ndarray) -> np.ndarray:
    """Columns prod_j xhat[:, j] ** e[k, j] for each exponent row k: (N, K) float64."""
    xhat = np.asarray(xhat, dtype=np.float64)
    n, d = xhat.shape
    exponents = np.asarray(exponents, dtype=np.int32)
    if exponents.ndim == 2 and exponents.shape[1] != d:
        raise ValueError(f"design_matrix: exponents have {exponents.shape[1]} columns for "
                         f"{d} inputs")
    exponents = exponents.reshape(-1, d)
    top = int(exponents.max(initial=0))
    # powers[j][p] = xhat[:, j] ** p, built by repeated multiplication
    powers = np.empty((d, top + 1, n))
    powers[:, 0] = 1.0
    for p in range(1, top + 1):
        powers[:, p] = powers[:, p - 1] * xhat.T
    out = np.ones((n, len(exponents)))
    for j in range(d):
        col = exponents[:, j]
        if np.any(col):
            out *= powers[j, col].T
    return out


@dataclass
class Polynomial:
    """One output: ``sum_k coefficients[k] * prod_j xhat_j ** exponents[k, j]``."""

    output: str
    unit: str
    exponents: np.ndarray  # (K, n_inputs) int32
    coefficients: np.ndarray  # (K,) float64, in ``unit``

    def __post_init__(self) -> None:
        self.exponents = np.asarray(self.exponents, dtype=np.int32)
        if self.exponents.ndim != 2:
            raise ValueError(f"output {self.output}: exponents must be a (K, n_inputs) array")
        self.coefficients = np.asarray(self.coefficients, dtype=np.float64).reshape(-1)
        if len(self.coefficients) != len(self.exponents):
            raise ValueError(f"output {self.output}: {len(self.coefficients)} coefficients "
                             f"for {len(self.exponents)} terms")
        if np.any(self.exponents < 0):
            raise ValueError(f"output {self.output}: negative exponent")
        if not np.all(np.isfinite(self.coefficients)):
            raise ValueError(f"output {self.output}: non-finite coefficient")

    @property
    def terms(self) -> int:
        return len(self.coefficients)

    @property
    def max_degree(self) -> int:
        return int(self.exponents.sum(axis=1).max(initial=0))

    def evaluate_normalised(self, xhat: np.ndarray) -> np.ndarray:
        xhat = np.asarray(xhat, dtype=np.float64)
        # In row chunks: a tensor fit has tens of thousands of terms
        step = max(1, (1 << 22) // max(1, self.terms))
        if len(xhat) <= step:
            return design_matrix(xhat, self.exponents) @ self.coefficients
        return np.concatenate([design_matrix(xhat[s:s + step], self.exponents)
                               @ self.coefficients for s in range(0, len(xhat), step)])

    def to_dict(self) -> dict[str, Any]:
        return {
            "output": self.output,
            "unit": self.unit,
            "exponents": self.exponents.tolist(),
            "coefficients": [float(c) for c in self.coefficients],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], n_inputs: int) -> Polynomial:
        try:
            e = np.array(d["exponents"], dtype=np.int32).reshape(-1, n_inputs)
        except ValueError as err:  # ragged rows, or a width that does not divide the total
            raise ValueError(f"output {d['output']}: exponents must be rows of {n_inputs} "
                             f"integers ({err})") from err
        if len(d["exponents"]) != len(e):  # rows of the wrong width, reshaped into others
            raise ValueError(f"output {d['output']}: exponents must be rows of {n_inputs} "
                             f"integers")
        return cls(d["output"], d["unit"], e, np.array(d["coefficients"], dtype=np.float64))


@dataclass
class System:
    """A polynomial system: named inputs with domains, and one polynomial per output."""

    name: str  # "P_o", "P_s", or a specialisation's name
    inputs: tuple[Input, ...]
    outputs: tuple[Polynomial, ...]
    info: dict[str, Any] = field(default_factory=dict)  # provenance (lens, domain, fit)

    def __post_init__(self) -> None:
        self.inputs = tuple(self.inputs)
        self.outputs = tuple(self.outputs)
        for p in self.outputs:
            if p.exponents.shape[1] != len(self.inputs):
                raise ValueError(f"{self.name}: output {p.output} has {p.exponents.shape[1]} "
                                 f"exponent columns for {len(self.inputs)} inputs")

    @property
    def input_names(self) -> list[str]:
        return [i.name for i in self.inputs]

    @property
    def output_names(self) -> list[str]:
        return [p.output for p in self.outputs]

    def output(self, name: str) -> Polynomial:
        for p in self.outputs:
            if p.output == name:
                return p
        raise KeyError(f"{self.name} has no output {name!r}; it has {self.output_names}")

    def normalise(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64).reshape(-1, len(self.inputs))
        return np.stack([inp.normalise(x[:, j]) for j, inp in enumerate(self.inputs)], axis=1)

    def evaluate(self, x: np.ndarray) -> np.ndarray:
        """Raw inputs (N, n_inputs) in their units -> outputs (N, n_outputs)."""
        xhat = self.normalise(x)
        return np.stack([p.evaluate_normalised(xhat) for p in self.outputs], axis=1)

    def select(self, names: list[str]) -> System:
        """The same system with only the outputs ``names`` (in that order)."""
        return replace(self, outputs=tuple(self.output(n) for n in names))

    def specialise(self, fixed: dict[str, float], name: str | None = None) -> System:
        """Fold the inputs in ``fixed`` (raw values) into the coefficients and drop them.

        Terms that become equal are merged; the result equals this system at ``fixed``."""
        unknown = set(fixed) - set(self.input_names)
        if unknown:
            raise KeyError(f"{self.name}: cannot fix {sorted(unknown)}; inputs are "
                           f"{self.input_names}")
        keep = [j for j, i in enumerate(self.inputs) if i.name not in fixed]
        xhat = {j: float(self.inputs[j].normalise(fixed[i.name]))
                for j, i in enumerate(self.inputs) if i.name in fixed}
        outs = []
        for p in self.outputs:
            factor = np.ones(p.terms)
            for j, v in xhat.items():
                factor *= v ** p.exponents[:, j].astype(np.float64)
            reduced = p.exponents[:, keep]
            merged: dict[tuple[int, ...], float] = {}
            for e, c in zip(map(tuple, reduced.tolist()), p.coefficients * factor, strict=True):
                merged[e] = merged.get(e, 0.0) + c
            # Keep the order of first appearance (deterministic)
            exps = np.array(list(merged), dtype=np.int32).reshape(-1, len(keep))
            outs.append(Polynomial(p.output, p.unit, exps, np.array(list(merged.values()))))
        info = dict(self.info)
        info["fixed"] = {**info.get("fixed", {}), **{k: float(v) for k, v in fixed.items()}}
        return System(name or self.name, tuple(self.inputs[j] for j in keep), tuple(outs), info)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "inputs": [i.to_dict() for i in self.inputs],
            "outputs": [p.to_dict() for p in self.outputs],
            "info": self.info,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> System:
        inputs = tuple(Input.from_dict(i) for i in d["inputs"])
        outs = tuple(Polynomial.from_dict(p, len(inputs)) for p in d["outputs"])
        return cls(d["name"], inputs, outs, dict(d.get("info", {})))
