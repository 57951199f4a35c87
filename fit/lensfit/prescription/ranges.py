"""Published ranges of glasses: the one place that decides about extrapolation.

Every glass with a ``range_nm`` (catalog formulas, inline formulas and tables) is valid
only inside it. Wavelengths outside are refused unless the lens allows extrapolation:
the lens file's top-level ``glass_extrapolation = "allow"``, or the command line's
``--allow-glass-extrapolation`` (which sets the same key on the loaded lens). When it is
allowed, ``lensfit info`` and the fit report list each glass used outside its range.

The default fit band (:func:`default_wavelengths`) follows the glasses: 380-780 nm
narrowed to the range every glass of the lens supports, so that a lens with a glass
published over 400-700 nm fits 400-700 nm without being asked. Extrapolation stays
explicit: a lens that allows it keeps the full 380-780 nm, and ``--wavelengths`` (or a
scene's wavelengths) outside a glass's range is refused as before.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from lensfit.common.errors import LensError

if TYPE_CHECKING:
    from lensfit.prescription.model import Lens

#: The lens-file key and its values
KEY = "glass_extrapolation"
ALLOW, REFUSE = "allow", "refuse"

#: The band a fit covers by default (nm), before the glasses narrow it
DEFAULT_BAND_NM = (380.0, 780.0)
#: The narrowest default band a fit accepts (nm): below it the glasses leave too little
#: spectrum for a colour render, and the user must choose (--wavelengths or extrapolation)
MIN_BAND_NM = 50.0
#: How the command line and the lens file allow extrapolation, for messages
ALLOW_HOW = (f"top-level {KEY} = \"{ALLOW}\" in the lens file, or "
             "--allow-glass-extrapolation")


@dataclass(frozen=True)
class OutOfRange:
    """A glass asked for at wavelengths outside its published range."""

    glass: str  # what the lens file names (its reference)
    range_nm: tuple[float, float]  # published range
    requested_nm: tuple[float, float]  # the wavelengths asked for, lo and hi
    surfaces: tuple[int, ...]  # surfaces whose medium (or coating layer) it is

    def describe(self) -> str:
        lo, hi = self.range_nm
        a, b = self.requested_nm
        outside = []
        if a < lo:
            outside.append(f"{a:g}-{min(b, lo):g} nm")
        if b > hi:
            outside.append(f"{max(a, hi):g}-{b:g} nm")
        where = ", ".join(str(s) for s in self.surfaces)
        return (f"{self.glass} (surface {where}): published {lo:g}-{hi:g} nm, "
                f"extrapolated at {' and '.join(outside)}")


def allows_extrapolation(lens: Lens) -> bool:
    """Whether the lens allows its glasses outside their published ranges."""
    return (lens.raw or {}).get(KEY, REFUSE) == ALLOW


def allow_extrapolation(lens: Lens) -> Lens:
    """The same lens with extrapolation allowed (the command line's switch)."""
    return dataclasses.replace(lens, raw={**(lens.raw or {}), KEY: ALLOW})


def _ranged_media(lens: Lens) -> dict[object, list[int]]:
    """Every medium of ``lens`` with a published range (surface media and coating
    layers), with the file's numbers of the surfaces that use it, in surface order."""
    found: dict[object, list[int]] = {}
    inserted = 0  # surfaces the loader added (a stop plane): not in the file's numbering
    for k, s in enumerate(lens.surfaces):
        if getattr(s, "inserted", None):
            inserted += 1
            continue
        i = k - inserted
        for m in (s.medium, *(layer.medium for layer in s.coating.layers)):
            if getattr(m, "range_nm", None) is not None:
                found.setdefault(m, [])
                if i not in found[m]:
                    found[m].append(i)
    return found


def out_of_range(lens: Lens, lo_nm: float, hi_nm: float) -> list[OutOfRange]:
    """The glasses of ``lens`` (surface media and coating layers) whose published range
    does not cover ``lo_nm``-``hi_nm``, in surface order."""
    return [OutOfRange(getattr(m, "reference", m.name), tuple(m.range_nm), (lo_nm, hi_nm),
                       tuple(idx)) for m, idx in _ranged_media(lens).items()
            if lo_nm < m.range_nm[0] or hi_nm > m.range_nm[1]]


def common_range(lens: Lens) -> tuple[float, float]:
    """The range (nm) every glass of ``lens`` supports: the intersection of their
    published ranges ((0, inf) when none has one; lo >= hi when they share none)."""
    media = _ranged_media(lens)
    return (max((m.range_nm[0] for m in media), default=0.0),
            min((m.range_nm[1] for m in media), default=math.inf))


@dataclass(frozen=True)
class Wavelengths:
    """The wavelength band a fit covers and why (recorded in fit.json and the table).
    ``asked_by`` names what asked for it (``--wavelengths 400,700``, a scene file) when
    it is not the default: a refusal names it."""

    lo_nm: float
    hi_nm: float
    reason: str
    asked_by: str | None = None

    @classmethod
    def asked(cls, lo_nm: float, hi_nm: float, asked_by: str) -> Wavelengths:
        return cls(float(lo_nm), float(hi_nm), f"asked for ({asked_by})", asked_by)

    @property
    def range_nm(self) -> tuple[float, float]:
        return self.lo_nm, self.hi_nm

    def line(self) -> str:
        """One line for the command line's output and the table's comment."""
        return f"wavelengths {self.lo_nm:g}-{self.hi_nm:g} nm: {self.reason}"

    def to_dict(self) -> dict[str, float | str]:
        """fit.json's ``wavelengths``: the band and why."""
        return {"min_nm": self.lo_nm, "max_nm": self.hi_nm, "reason": self.reason}

    def check(self, lens: Lens) -> list[OutOfRange]:
        """:func:`check_glass_ranges` over this band, naming what asked for it."""
        return check_glass_ranges(lens, self.lo_nm, self.hi_nm, self.asked_by)


def _ranges_text(glasses: list[OutOfRange]) -> str:
    return ", ".join(f"{o.glass}: {o.range_nm[0]:g}-{o.range_nm[1]:g} nm" for o in glasses)


def default_wavelengths(lens: Lens) -> Wavelengths:
    """The band a fit covers when none is asked for: 380-780 nm (``DEFAULT_BAND_NM``)
    intersected with the published range of every glass of the lens (surface media and
    coating layers, as :func:`out_of_range` walks them). A lens that allows
    extrapolation keeps 380-780 nm (its glasses are then listed as extrapolated).

    LensError, naming the glasses and their ranges, when the intersection is empty or
    narrower than ``MIN_BAND_NM``."""
    lo, hi = DEFAULT_BAND_NM
    band = f"{lo:g}-{hi:g} nm"
    narrow = out_of_range(lens, lo, hi)
    if not narrow:
        return Wavelengths(lo, hi, "the default range, which every glass supports")
    if allows_extrapolation(lens):
        return Wavelengths(lo, hi, f"the default {band}, glasses extrapolated as the lens "
                                   f"allows ({_ranges_text(narrow)})")
    a = max(lo, *(o.range_nm[0] for o in narrow))
    b = min(hi, *(o.range_nm[1] for o in narrow))
    if b - a < MIN_BAND_NM:
        ranges = f"the published ranges of the glasses ({_ranges_text(narrow)})"
        if a < b:
            what = (f"{ranges} leave only {a:g}-{b:g} nm within {band}, less than the "
                    f"{MIN_BAND_NM:g} nm a default fit covers; ask for it with "
                    f"--wavelengths {a:g},{b:g} or allow extrapolation ({ALLOW_HOW})")
        else:
            what = (f"{ranges} have no wavelength in common within {band}; allow "
                    f"extrapolation ({ALLOW_HOW}) to fit them together")
        raise LensError(f"no default wavelength range: {what}", file=lens.source_file,
                        surface=narrow[0].surfaces[0], key="material")
    return Wavelengths(a, b, f"the range every glass supports ({_ranges_text(narrow)}) "
                             f"within {band}")


def check_glass_ranges(lens: Lens, lo_nm: float, hi_nm: float,
                       asked_by: str | None = None) -> list[OutOfRange]:
    """The glasses used outside their range (see ``out_of_range``); LensError naming the
    first one unless the lens allows extrapolation. ``asked_by`` says where the
    wavelengths come from (e.g. ``--wavelengths 380,780``): the message starts with it."""
    bad = out_of_range(lens, lo_nm, hi_nm)
    if bad and not allows_extrapolation(lens):
        b = bad[0]
        lo, hi = b.range_nm
        asked = (f"wavelength {lo_nm:g} nm is" if lo_nm == hi_nm
                 else f"wavelengths {lo_nm:g}-{hi_nm:g} nm are")
        a, z = max(lo, lo_nm), min(hi, hi_nm)
        inside = f"--wavelengths {a:g},{z:g}" if a < z else "wavelengths inside it"
        raise LensError(
            f"{asked_by + ': ' if asked_by else ''}{asked} outside the {lo:g}-{hi:g} nm "
            f"range of glass {b.glass}; use {inside} or allow extrapolation ({ALLOW_HOW})",
            file=lens.source_file, surface=b.surfaces[0], key="material")
    return bad
