"""Glass dispersion: Sellmeier catalog glasses, the nd/vd (Abbe) model and air.

Wavelengths are in nanometres at every public entry point. Catalog Sellmeier
coefficients are stored as published: ``n² = 1 + Σ B_i λ²/(λ² − C_i)`` with λ in
micrometres and C_i in µm² (see ``lensdb/glass/README.md``). All indices are
relative to air, the convention of glass catalogs and lens prescriptions.
"""

from __future__ import annotations

import functools
import math
import os
import pathlib
import tomllib
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from lensfit.common.errors import InputError, parse_problem

__all__ = [
    "AIR",
    "AbbeGlass",
    "Air",
    "LAMBDA_C_NM",
    "LAMBDA_D_NM",
    "LAMBDA_F_NM",
    "LAMBDA_G_NM",
    "MODEL_DPGF_MAX",
    "MODEL_ND_RANGE",
    "MODEL_VD_RANGE",
    "Medium",
    "SellmeierGlass",
    "UnknownGlassError",
    "abbe_glass",
    "abbe_number",
    "catalog_glass",
    "catalog_path",
    "known_glass_names",
    "normal_line_pgf",
    "partial_dispersion",
]

#: Fraunhofer/spectral lines used for nd, vd and partial dispersion, in nm.
LAMBDA_D_NM = 587.56  # He d
LAMBDA_F_NM = 486.13  # H F
LAMBDA_C_NM = 656.27  # H C
LAMBDA_G_NM = 435.83  # Hg g

#: Schott "normal line" of relative partial dispersion P_g,F = a + b * vd
#: (through K7 and F2; SCHOTT, Optical Glass: Properties, TIE-29).
_NORMAL_LINE_A = 0.6438
_NORMAL_LINE_B = -0.001682
#: vd is clipped to this value before entering the normal line, which keeps
#: P_g,F >= 0.4756; the model is monotonic over 380-780 nm for 0.323 <= P_g,F <= 1.028.
_NORMAL_LINE_VD_MAX = 100.0

#: What a lens file (and an importer) accepts for an nd/vd model glass. nd: 1-3; vd:
#: 5-150 (the 1002 glasses of the manufacturers' catalogs span 16.5-100.8); dPgF, the
#: deviation of P_g,F from the normal line: |dPgF| <= 0.1, twice the largest of those
#: glasses (-0.012 N-KZFS11 ... +0.058 K-FIR100UV), which keeps P_g,F within
#: 0.376-0.736 and so n(λ) strictly decreasing over 380-780 nm for every vd. A larger
#: value is more likely a P_g,F written where its deviation belongs.
MODEL_ND_RANGE = (1.0, 3.0)
MODEL_VD_RANGE = (5.0, 150.0)
MODEL_DPGF_MAX = 0.1

_ENV_CATALOG = "LENSFIT_GLASS_CATALOG"

FloatArray = npt.NDArray[np.float64]


@runtime_checkable
class Medium(Protocol):
    """Anything with a name and a refractive index n(λ) (λ in nm, relative to air)."""

    @property
    def name(self) -> str: ...

    def n(self, wavelength_nm: npt.ArrayLike) -> FloatArray:
        """Refractive index, float64, same shape as ``wavelength_nm``."""
        ...


def _wavelengths(wavelength_nm: npt.ArrayLike) -> FloatArray:
    """Validate and convert wavelengths (nm) to a float64 array."""
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    if not np.all(np.isfinite(lam)) or np.any(lam <= 0.0):
        raise ValueError("wavelengths must be finite and > 0 nm")
    return lam


@dataclass(frozen=True)
class Air:
    """The reference medium: n == 1.0 exactly (catalog indices are relative to air)."""

    name: str = "air"

    def n(self, wavelength_nm: npt.ArrayLike) -> FloatArray:
        """Return 1.0 at every wavelength."""
        return np.ones_like(_wavelengths(wavelength_nm))[()]


AIR = Air()


@dataclass(frozen=True)
class SellmeierGlass:
    """A catalog glass: 3-term Sellmeier with C in µm², plus its catalog nd/vd."""

    name: str
    maker: str
    B: tuple[float, float, float]
    C: tuple[float, float, float]  # µm²
    nd: float
    vd: float
    range_nm: tuple[float, float]
    source: str

    @property
    def reference(self) -> str:
        """What a lens file's ``material`` says to get this glass: its catalog name."""
        return self.name

    def n(self, wavelength_nm: npt.ArrayLike) -> FloatArray:
        """Refractive index at ``wavelength_nm`` (nm), float64, same shape."""
        lam_um2 = (_wavelengths(wavelength_nm) * 1e-3) ** 2
        n2 = np.ones_like(lam_um2)
        for b, c in zip(self.B, self.C, strict=True):
            n2 = n2 + b * lam_um2 / (lam_um2 - c)
        return np.sqrt(n2)


def normal_line_pgf(vd: float) -> float:
    """P_g,F of the model's normal line at Abbe number ``vd``: 0.6438 − 0.001682·min(vd,
    100) (Schott's line through K7 and F2, clipped at vd = 100, see README)."""
    return _NORMAL_LINE_A + _NORMAL_LINE_B * min(float(vd), _NORMAL_LINE_VD_MAX)


@dataclass(frozen=True)
class AbbeGlass:
    """A glass known only by nd and vd, and optionally dPgF (see README: "nd/vd model").

    n(λ) = A + B/λ² + C/λ⁴ (λ in µm), fixed by n(λd) = nd, (nd − 1)/(nF − nC) = vd and
    a relative partial dispersion P_g,F = (ng − nF)/(nF − nC) on the Schott normal line
    plus ``dpgf`` (the deviation from it, as Zemax's MODEL glass gives it):
    P_g,F = 0.6438 − 0.001682·min(vd, 100) + dpgf.
    """

    nd: float
    vd: float
    name: str = ""
    dpgf: float = 0.0
    _coef: tuple[float, float, float] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        nd, vd, dpgf = float(self.nd), float(self.vd), float(self.dpgf)
        if not (math.isfinite(nd) and math.isfinite(vd) and math.isfinite(dpgf)):
            raise ValueError(f"nd, vd and dPgF must be finite, got nd={self.nd!r}, "
                             f"vd={self.vd!r}, dpgf={self.dpgf!r}")
        if nd < 1.0:
            raise ValueError(f"nd must be >= 1 (index relative to air), got nd={nd!r}")
        if vd <= 0.0:
            raise ValueError(f"vd (Abbe number) must be > 0, got vd={vd!r}")
        if abs(dpgf) > MODEL_DPGF_MAX:
            raise ValueError(f"dPgF must be within ±{MODEL_DPGF_MAX:g} (the deviation of "
                             f"P_g,F from the normal line), got dpgf={dpgf!r}")
        object.__setattr__(self, "nd", nd)
        object.__setattr__(self, "vd", vd)
        object.__setattr__(self, "dpgf", dpgf)
        if not self.name:
            extra = f" dPgF={dpgf:+.4f}" if dpgf else ""
            object.__setattr__(self, "name", f"nd={nd:.5f} vd={vd:.2f}{extra}")
        object.__setattr__(self, "_coef", _abbe_coefficients(nd, vd, dpgf))

    def n(self, wavelength_nm: npt.ArrayLike) -> FloatArray:
        """Refractive index at ``wavelength_nm`` (nm), float64, same shape."""
        u = (_wavelengths(wavelength_nm) * 1e-3) ** -2
        a, b, c = self._coef
        return a + u * (b + u * c)


def _abbe_coefficients(nd: float, vd: float, dpgf: float = 0.0
                       ) -> tuple[float, float, float]:
    """Coefficients (A, B, C) of n = A + B u + C u², u = 1/λ² (λ in µm)."""
    ud, uf, uc, ug = (
        (1e3 / lam) ** 2 for lam in (LAMBDA_D_NM, LAMBDA_F_NM, LAMBDA_C_NM, LAMBDA_G_NM)
    )
    p_gf = normal_line_pgf(vd) + dpgf
    d_fc = (nd - 1.0) / vd  # nF - nC
    # nF - nC = (uF - uC) (B + C (uF + uC));  ng - nF = (ug - uF) (B + C (ug + uF))
    k1 = d_fc / (uf - uc)
    k2 = p_gf * d_fc / (ug - uf)
    c = (k2 - k1) / (ug - uc)
    b = k1 - c * (uf + uc)
    a = nd - ud * (b + ud * c)
    return a, b, c


def abbe_glass(nd: float, vd: float, dpgf: float = 0.0) -> AbbeGlass:
    """Model glass from catalog nd, vd (and dPgF, the deviation of P_g,F from the normal
    line); ValueError for nd < 1, vd <= 0, |dpgf| > MODEL_DPGF_MAX or non-finite."""
    return AbbeGlass(nd=nd, vd=vd, dpgf=dpgf)


def abbe_number(medium: Medium) -> float:
    """vd = (nd − 1)/(nF − nC) of ``medium`` evaluated from its n(λ)."""
    nd, nf, nc = medium.n(np.array([LAMBDA_D_NM, LAMBDA_F_NM, LAMBDA_C_NM]))
    return float((nd - 1.0) / (nf - nc))


def partial_dispersion(medium: Medium) -> float:
    """P_g,F = (ng − nF)/(nF − nC) of ``medium`` evaluated from its n(λ)."""
    ng, nf, nc = medium.n(np.array([LAMBDA_G_NM, LAMBDA_F_NM, LAMBDA_C_NM]))
    return float((ng - nf) / (nf - nc))


class UnknownGlassError(KeyError):
    """Raised for a glass name that is not in the catalog; ``.name`` is the name asked for."""

    def __init__(self, name: str, known: list[str], message: str | None = None) -> None:
        super().__init__(name)
        self.name = name
        self.known = list(known)
        self.message = message

    def __str__(self) -> str:
        if self.message is not None:
            return self.message
        hint = ""
        if _normalise(self.name) == "AIR":
            hint = " (air is not a catalog glass; use lensfit.glass.AIR)"
        return f"unknown glass {self.name!r}{hint}; known glasses: {', '.join(self.known)}"


def catalog_path() -> pathlib.Path:
    """Path of the catalog TOML ($LENSFIT_GLASS_CATALOG, else glass/catalog.toml of the
    lensdb folder that lensfit.data_folder finds: $LENSFIT_LENSDB, the checkout's, the
    current directory's)."""
    env = os.environ.get(_ENV_CATALOG)
    if env:
        return pathlib.Path(env)
    from lensfit import data_folder

    return data_folder("lensdb") / "glass" / "catalog.toml"


def _normalise(name: str) -> str:
    """Lookup key: upper case, hyphens, underscores and blanks removed."""
    return "".join(ch for ch in name.upper() if ch not in "-_ \t")


def _number(entry: dict[str, object], key: str, value: object) -> float:
    """A catalog number; booleans are not numbers (float(true) would be 1)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        shown = str(value).lower() if isinstance(value, bool) else repr(value)
        raise ValueError(f"{catalog_path()}: glass {entry.get('name')!r}: key '{key}': "
                         f"expected a number, found {shown}")
    return float(value)


def _triple(entry: dict[str, object], key: str) -> tuple[float, float, float]:
    values = entry[key]
    if not isinstance(values, list) or len(values) != 3:
        raise ValueError(f"glass {entry.get('name')!r}: {key} must be a list of 3 numbers")
    a, b, c = (_number(entry, key, v) for v in values)
    return a, b, c


@functools.cache
def _load_catalog(path: pathlib.Path) -> dict[str, SellmeierGlass]:
    """Parse the catalog once per path; keys are normalised names."""
    with path.open("rb") as fh:
        try:
            data = tomllib.load(fh)
        except ValueError as e:  # TOMLDecodeError, or an integer of over 4300 digits
            raise InputError(f"{path}: cannot read the glass catalog: {parse_problem(e)}"
                             ) from None
    glasses: dict[str, SellmeierGlass] = {}
    for entry in data.get("glass", []):
        lo, hi = (_number(entry, "range_nm", v) for v in entry["range_nm"])
        glass = SellmeierGlass(
            name=str(entry["name"]),
            maker=str(entry["maker"]),
            B=_triple(entry, "B"),
            C=_triple(entry, "C"),
            nd=_number(entry, "nd", entry["nd"]),
            vd=_number(entry, "vd", entry["vd"]),
            range_nm=(lo, hi),
            source=str(entry["source"]),
        )
        key = _normalise(glass.name)
        if key in glasses:
            raise ValueError(
                f"{path}: glass names {glasses[key].name!r} and "
                f"{glass.name!r} collide after normalisation"
            )
        glasses[key] = glass
    return glasses


def known_glass_names() -> list[str]:
    """Catalog glass names, as spelled in the catalog, in catalog order."""
    return [g.name for g in _load_catalog(catalog_path()).values()]


def catalog_glass(name: str) -> SellmeierGlass:
    """Look up a catalog glass, case-insensitively and ignoring hyphens ("slah59").

    Raises UnknownGlassError for names not in the catalog (never falls back to air).
    """
    glasses = _load_catalog(catalog_path())
    try:
        return glasses[_normalise(name)]
    except KeyError:
        raise UnknownGlassError(name, [g.name for g in glasses.values()]) from None
