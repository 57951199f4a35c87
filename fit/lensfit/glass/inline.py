"""A glass's dispersion written into a lens file (``material = { ... }``).

Three forms (see lensdb/README.md):

* a catalog formula: ``{ name, formula, coefficients, range_nm }`` with a formula of
  ``lensfit.glass.formulas.FORMULAS`` and its coefficients in the catalog's order;
* a table: ``{ name, table_nm, table_n }``, n at increasing wavelengths, interpolated by
  a cubic spline of n against u = 1/λ² (``TableGlass``);
* a constant index: ``{ name, n }``, a non-dispersive medium with n(λ) = n at every
  wavelength (``ConstantGlass``; what Zemax writes as a MODEL glass with vd = 0 and
  Optiland as an ``IdealMaterial``).

``inline_glass`` checks the table and raises ``InlineGlassError`` naming the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from lensfit.glass.catalog import MODEL_ND_RANGE, FloatArray, _wavelengths
from lensfit.glass.formulas import FORMULAS, FormulaGlass, formula_n_squared

__all__ = ["ConstantGlass", "InlineGlassError", "TableGlass", "inline_glass"]

#: Points at which a formula is checked over its range (finite, n >= 1): a pole of a
#: Sellmeier term inside the range shows as a sign change of n² - 1 between points.
_CHECK_POINTS = 401

_FORMULA_KEYS = {"formula", "coefficients", "range_nm"}
_TABLE_KEYS = {"table_nm", "table_n"}
_CONSTANT_KEYS = {"n"}


class InlineGlassError(ValueError):
    """A bad inline glass; ``key`` is the key inside the table ("coefficients")."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(message)
        self.key = key


@dataclass(frozen=True)
class TableGlass:
    """n(λ) from a table: a cubic spline of n against u = 1/λ² (λ in µm).

    In u the dispersion of a glass is close to a straight line (Cauchy: n ≈ A + B u), so
    the spline only has to follow a gentle curve. The end conditions are not-a-knot (the
    first two and the last two intervals are one cubic each): with 7 points over
    400-700 nm it follows N-BK7's Sellmeier curve to 1.5e-6 and N-SF6's to 8.6e-6, where
    natural end conditions (zero curvature at the ends) miss a flint's blue-end curvature
    by 2.3e-4. Two points give the straight line in u, three a parabola. Outside the
    table (used only when the lens allows extrapolation) n continues as the straight
    line in u tangent at the end point (value and slope continuous). ``range_nm`` is the
    table's span."""

    name: str
    table_nm: tuple[float, ...]
    table_n: tuple[float, ...]
    maker: str = "inline"
    _spline: Any = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        from scipy.interpolate import CubicSpline

        u = (np.asarray(self.table_nm) * 1e-3) ** -2
        order = np.argsort(u)
        spline = CubicSpline(u[order], np.asarray(self.table_n)[order], bc_type="not-a-knot")
        object.__setattr__(self, "_spline", spline)

    @property
    def range_nm(self) -> tuple[float, float]:
        return (min(self.table_nm), max(self.table_nm))

    @property
    def reference(self) -> str:
        return self.name

    def n(self, wavelength_nm: npt.ArrayLike) -> FloatArray:
        """Refractive index at ``wavelength_nm`` (nm), float64, same shape."""
        u = (_wavelengths(wavelength_nm) * 1e-3) ** -2
        s = self._spline
        lo, hi = s.x[0], s.x[-1]
        inside = np.clip(u, lo, hi)
        n = s(inside)
        # Outside the table: the tangent line in u at the end point
        n = n + np.where(u < lo, (u - lo) * s(lo, 1), 0.0)
        n = n + np.where(u > hi, (u - hi) * s(hi, 1), 0.0)
        return np.asarray(n, dtype=np.float64)[()]


@dataclass(frozen=True)
class ConstantGlass:
    """A non-dispersive medium: n(λ) = ``index`` at every wavelength. It has no published
    range (``range_nm`` is absent), so no wavelength is outside it: the default fit band
    stays 380-780 nm and no range check refuses it."""

    name: str
    index: float
    maker: str = "inline"

    @property
    def reference(self) -> str:
        return self.name

    def n(self, wavelength_nm: npt.ArrayLike) -> FloatArray:
        """``index`` at every wavelength (nm), float64, same shape."""
        return np.full_like(_wavelengths(wavelength_nm), self.index)[()]


def _numbers(spec: dict[str, Any], key: str) -> list[float]:
    values = spec[key]
    if not isinstance(values, list) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        raise InlineGlassError(key, f"expected a list of numbers, found {values!r}")
    out = [float(v) for v in values]
    if not all(math.isfinite(v) for v in out):
        raise InlineGlassError(key, f"expected finite numbers, found {values!r}")
    return out


def inline_glass(spec: dict[str, Any]) -> FormulaGlass | TableGlass | ConstantGlass:
    """The medium of an inline ``material`` table; InlineGlassError naming the key."""
    name = spec.get("name", "inline glass")
    if not isinstance(name, str) or not name.strip():
        raise InlineGlassError("name", f"expected a non-empty name, found {name!r}")
    if name.strip().lower() == "air":
        raise InlineGlassError("name", "'air' is not a glass name (write material = 'air')")
    keys = set(spec) - {"name"}
    unknown = keys - _FORMULA_KEYS - _TABLE_KEYS - _CONSTANT_KEYS
    if unknown:
        raise InlineGlassError(sorted(unknown)[0], "unknown key (allowed: name, formula, "
                                                   "coefficients, range_nm, table_nm, table_n, "
                                                   "n)")
    forms = [(f, what) for f, what in (
        (_FORMULA_KEYS, "a formula (formula, coefficients, range_nm)"),
        (_TABLE_KEYS, "a table (table_nm, table_n)"),
        (_CONSTANT_KEYS, "a constant index (n)")) if keys & f]
    if len(forms) > 1:
        (_, first), (second_keys, second) = forms[:2]
        raise InlineGlassError(sorted(keys & second_keys)[0],
                               f"give {first} or {second}, not both")
    if keys & _TABLE_KEYS:
        return _table(name, spec)
    if keys & _CONSTANT_KEYS:
        return _constant(spec)
    missing = sorted(_FORMULA_KEYS - keys)
    if missing:
        raise InlineGlassError(missing[0], "missing key (an inline glass needs formula, "
                                           "coefficients and range_nm, table_nm and "
                                           "table_n, or n)")
    formula = spec["formula"]
    if formula not in FORMULAS:
        raise InlineGlassError("formula", f"expected one of {', '.join(FORMULAS)}, "
                                          f"found {formula!r}")
    coef = _numbers(spec, "coefficients")
    want = FORMULAS[formula]
    if len(coef) != len(want):
        raise InlineGlassError("coefficients", f"formula {formula!r} takes {len(want)} "
                                               f"coefficients ({' '.join(want)}), found "
                                               f"{len(coef)}")
    rng = _numbers(spec, "range_nm")
    if len(rng) != 2 or not 0.0 < rng[0] < rng[1]:
        raise InlineGlassError("range_nm", f"expected [lo, hi] in nm with 0 < lo < hi, "
                                           f"found {spec['range_nm']!r}")
    lam_um = np.linspace(rng[0], rng[1], _CHECK_POINTS) * 1e-3
    with np.errstate(all="ignore"):
        n2 = formula_n_squared(formula, tuple(coef), lam_um)
    bad = ~(np.isfinite(n2) & (n2 >= 1.0))
    # A pole between two check points flips the sign of n² - 1 through infinity
    flips = np.diff(np.sign(n2 - 1.0)) != 0
    if bad.any() or flips.any():
        at = float(lam_um[np.argmax(bad)] if bad.any() else lam_um[np.argmax(flips)]) * 1e3
        raise InlineGlassError("coefficients", f"the {formula} formula gives no index >= 1 "
                                               f"near {at:.1f} nm, inside range_nm "
                                               f"{rng[0]:g}-{rng[1]:g}")
    return FormulaGlass(name=name, maker="inline", formula=formula, coefficients=tuple(coef),
                        range_nm=(rng[0], rng[1]), source="lens file", reference=name)


def _table(name: str, spec: dict[str, Any]) -> TableGlass:
    for key in sorted(_TABLE_KEYS):
        if key not in spec:
            raise InlineGlassError(key, "missing key (table_nm and table_n go together)")
    lam = _numbers(spec, "table_nm")
    n = _numbers(spec, "table_n")
    if len(lam) < 2:
        raise InlineGlassError("table_nm", f"expected at least 2 wavelengths, found {len(lam)}")
    if len(n) != len(lam):
        raise InlineGlassError("table_n", f"expected {len(lam)} indices (one per table_nm "
                                          f"entry), found {len(n)}")
    if lam[0] <= 0 or any(b <= a for a, b in zip(lam, lam[1:], strict=False)):
        raise InlineGlassError("table_nm", "expected positive wavelengths in increasing order, "
                                           f"found {lam!r}")
    if any(v < 1.0 for v in n):
        raise InlineGlassError("table_n", f"expected indices >= 1, found {min(n)!r}")
    return TableGlass(name=name, table_nm=tuple(lam), table_n=tuple(n))


def _constant(spec: dict[str, Any]) -> ConstantGlass:
    n = spec["n"]
    if isinstance(n, bool) or not isinstance(n, int | float):
        raise InlineGlassError("n", f"expected a number, found {n!r}")
    lo, hi = MODEL_ND_RANGE
    if not lo <= n <= hi:  # also NaN and inf
        raise InlineGlassError("n", f"expected a constant index {lo:g} <= n <= {hi:g} (the "
                                    f"range of an nd/vd glass's nd), found {n!r}")
    # Named after its index unless the file names it ("n=1.5" in reports and messages)
    name = spec.get("name", f"n={float(n):g}")
    return ConstantGlass(name=name, index=float(n))
