"""Published ranges of glasses: the one place that decides about extrapolation.

Every glass with a ``range_nm`` (catalog formulas, inline formulas and tables) is valid
only inside it. Wavelengths outside are refused unless the lens allows extrapolation:
the lens file's top-level ``glass_extrapolation = "allow"``, or the command line's
``--allow-glass-extrapolation`` (which sets the same key on the loaded lens). When it is
allowed, ``lensfit info`` and the fit report list each glass used outside its range.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

from lensfit.errors import LensError

if TYPE_CHECKING:
    from lensfit.prescription.model import Lens

#: The lens-file key and its values
KEY = "glass_extrapolation"
ALLOW, REFUSE = "allow", "refuse"


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


def out_of_range(lens: Lens, lo_nm: float, hi_nm: float) -> list[OutOfRange]:
    """The glasses of ``lens`` (surface media and coating layers) whose published range
    does not cover ``lo_nm``-``hi_nm``, in surface order."""
    found: dict[object, list[int]] = {}
    inserted = 0  # surfaces the loader added (a stop plane): not in the file's numbering
    for k, s in enumerate(lens.surfaces):
        if getattr(s, "inserted", None):
            inserted += 1
            continue
        i = k - inserted
        for m in (s.medium, *(layer.medium for layer in s.coating.layers)):
            valid = getattr(m, "range_nm", None)
            if valid is not None and (lo_nm < valid[0] or hi_nm > valid[1]):
                found.setdefault(m, [])
                if i not in found[m]:
                    found[m].append(i)
    return [OutOfRange(getattr(m, "reference", m.name), tuple(m.range_nm), (lo_nm, hi_nm),
                       tuple(idx)) for m, idx in found.items()]


def check_glass_ranges(lens: Lens, lo_nm: float, hi_nm: float) -> list[OutOfRange]:
    """The glasses used outside their range (see ``out_of_range``); LensError naming the
    first one unless the lens allows extrapolation."""
    bad = out_of_range(lens, lo_nm, hi_nm)
    if bad and not allows_extrapolation(lens):
        b = bad[0]
        lo, hi = b.range_nm
        asked = (f"wavelength {lo_nm:g} nm is" if lo_nm == hi_nm
                 else f"wavelengths {lo_nm:g}-{hi_nm:g} nm are")
        a, z = max(lo, lo_nm), min(hi, hi_nm)
        inside = f"--wavelengths {a:g},{z:g}" if a < z else "wavelengths inside it"
        raise LensError(
            f"{asked} outside the {lo:g}-{hi:g} nm range of glass {b.glass}; use {inside} "
            f"or allow extrapolation (top-level {KEY} = \"{ALLOW}\" in the lens file, or "
            "--allow-glass-extrapolation)",
            file=lens.source_file, surface=b.surfaces[0], key="material")
    return bad
