"""Dispersion formulas of the manufacturers' glass catalogs, as ``Medium`` objects.

Every formula takes λ in micrometres, as the catalogs publish it; the ``n`` method of
each medium takes nanometres, like every other ``Medium``. Coefficients are stored in
the order the catalogs print them (see ``FORMULAS`` and ``lensdb/glass/README.md``).

* ``sellmeier3`` (SCHOTT, OHARA; Zemax "Sellmeier 1"), coefficients B1 B2 B3 C1 C2 C3:
  n² = 1 + B1 λ²/(λ² − C1) + B2 λ²/(λ² − C2) + B3 λ²/(λ² − C3), C in µm².
* ``schott`` (the Schott/Laurent power series; HOYA, CDGM, SUMITA), A0 … A5:
  n² = A0 + A1 λ² + A2 λ⁻² + A3 λ⁻⁴ + A4 λ⁻⁶ + A5 λ⁻⁸.
* ``hikari`` (HIKARI's nine-term power series), A0 … A8:
  n² = A0 + A1 λ² + A2 λ⁴ + A3 λ⁻² + A4 λ⁻⁴ + A5 λ⁻⁶ + A6 λ⁻⁸ + A7 λ⁻¹⁰ + A8 λ⁻¹².
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from lensfit.glass.catalog import FloatArray, _wavelengths

#: Formula name -> (number of coefficients, the coefficients' names in order)
FORMULAS: dict[str, tuple[str, ...]] = {
    "sellmeier3": ("B1", "B2", "B3", "C1", "C2", "C3"),
    "schott": ("A0", "A1", "A2", "A3", "A4", "A5"),
    "hikari": ("A0", "A1", "A2", "A3", "A4", "A5", "A6", "A7", "A8"),
}

#: Spectral lines of the catalogs' nd, ne, vd and ve, nm (SCHOTT TIE-29 values).
LINE_NM = {
    "d": 587.5618,  # He
    "e": 546.0740,  # Hg
    "F": 486.1327,  # H
    "C": 656.2725,  # H
    "F'": 479.9914,  # Cd
    "C'": 643.8469,  # Cd
}


def formula_n_squared(formula: str, coefficients: tuple[float, ...],
                      lam_um: FloatArray) -> FloatArray:
    """n² of ``formula`` at wavelengths ``lam_um`` (µm); ValueError for an unknown
    formula or the wrong number of coefficients."""
    names = FORMULAS.get(formula)
    if names is None:
        raise ValueError(f"unknown dispersion formula {formula!r} "
                         f"(known: {', '.join(FORMULAS)})")
    if len(coefficients) != len(names):
        raise ValueError(f"formula {formula!r} takes {len(names)} coefficients "
                         f"({' '.join(names)}), found {len(coefficients)}")
    w2 = lam_um * lam_um
    c = coefficients
    if formula == "sellmeier3":
        return 1.0 + sum(c[i] * w2 / (w2 - c[i + 3]) for i in range(3))
    inv = 1.0 / w2
    if formula == "schott":
        # Horner in λ⁻²: A2 λ⁻² + A3 λ⁻⁴ + A4 λ⁻⁶ + A5 λ⁻⁸
        tail = inv * (c[2] + inv * (c[3] + inv * (c[4] + inv * c[5])))
        return c[0] + c[1] * w2 + tail
    # hikari: A0 + A1 λ² + A2 λ⁴ + Σ_{j=3..8} A_j λ^(-2 (j-2))
    tail = np.zeros_like(w2)
    for a in reversed(c[3:]):
        tail = inv * (a + tail)
    return c[0] + w2 * (c[1] + w2 * c[2]) + tail


@dataclass(frozen=True)
class FormulaGlass:
    """A glass given by a catalog dispersion formula (see the module docstring).

    ``range_nm`` is the published range of the formula; ``nd``, ``ne``, ``vd`` and ``ve``
    are the catalog's own values (NaN when it prints none), kept for checks and reports.
    ``reference`` is what a lens file's ``material`` says to get this glass back."""

    name: str
    maker: str
    formula: str
    coefficients: tuple[float, ...]
    range_nm: tuple[float, float]
    # Catalog values: kept for checks, not part of the medium's identity (NaN != NaN)
    nd: float = field(default=math.nan, compare=False)
    ne: float = field(default=math.nan, compare=False)
    vd: float = field(default=math.nan, compare=False)
    ve: float = field(default=math.nan, compare=False)
    source: str = field(default="", compare=False)
    reference: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "coefficients", tuple(float(c) for c in self.coefficients))
        # Checks the formula name and the number of coefficients
        formula_n_squared(self.formula, self.coefficients, np.ones(1))
        if not self.reference:
            object.__setattr__(self, "reference", f"{self.maker}:{self.name}")

    def n(self, wavelength_nm: npt.ArrayLike) -> FloatArray:
        """Refractive index at ``wavelength_nm`` (nm), float64, same shape."""
        lam_um = _wavelengths(wavelength_nm) * 1e-3
        return np.sqrt(formula_n_squared(self.formula, self.coefficients, lam_um))
