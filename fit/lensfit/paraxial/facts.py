"""First-order facts of a lens that a runtime needs besides its polynomials.

They travel as the ``lens`` lines of a coefficient table (``lensfit-poly-table 2``, see
:mod:`lensfit.codegen.table`). Lengths in mm; paraxial figures in the y-z meridian at
the d line (587.56 nm), as :func:`lensfit.paraxial.paraxial` computes them.
"""

from __future__ import annotations

import math
from dataclasses import astuple, dataclass, fields

from lensfit.common.errors import InputError
from lensfit.paraxial.paraxial import paraxial, stop_radius_f1_mm
from lensfit.prescription.model import Lens


@dataclass(frozen=True)
class LensFacts:
    """What a renderer needs to know of a lens besides P_o and P_s (fields in table order)."""

    name: str
    focal_length_mm: float  # paraxial EFL, y meridian, d line (signed)
    stop_radius_max_mm: float  # the widest the physical stop opens
    stop_radius_f1_mm: float  # f/N at infinity needs stop radius stop_radius_f1_mm / N
    housing_first_mm: float  # clip radius at the first surface: keep x_o^2 + y_o^2 <= r^2
    housing_last_mm: float  # clip radius at the last surface: keep x_i^2 + y_i^2 <= r^2
    sensor_defocus_mm: float  # the z_S = 0 sensor minus the paraxial focus for infinity
    front_focal_distance_mm: float  # front focal point to the first vertex (+ in front)
    squeeze: float  # anamorphic squeeze EFL_y / EFL_x (1 for a rotationally symmetric lens)

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    def values(self) -> tuple[str | float, ...]:
        return astuple(self)

    def check(self) -> LensFacts:
        """Raise ValueError naming the key when a number is not finite or out of range."""
        for key, value in zip(self.keys()[1:], self.values()[1:], strict=True):
            problem = fact_problem(key, value)
            if problem:
                raise InputError(f"lens {key} = {value!r}: {problem}")
        return self


# The ranges of the numeric facts (lensfit.codegen.table's module doc, "Ranges"; lensrt's
# reader, runtime/src/lens/table.c, holds the same numbers). Lengths in mm: a length
# (radius, |focal length|) in [LENGTH_MIN_MM, LENGTH_MAX_MM], from 1 um to 1 km, wider
# than any camera lens or telescope; a signed distance (sensor defocus, front focal
# distance) at most LENGTH_MAX_MM either way; an anamorphic squeeze in [SQUEEZE_MIN,
# SQUEEZE_MAX] (cinema anamorphics squeeze 1.3 to 2).
LENGTH_MIN_MM = 1e-3
LENGTH_MAX_MM = 1e6
SQUEEZE_MIN, SQUEEZE_MAX = 0.1, 10.0
_LENGTHS = ("focal_length_mm", "stop_radius_max_mm", "stop_radius_f1_mm", "housing_first_mm",
            "housing_last_mm")
_DISTANCES = ("sensor_defocus_mm", "front_focal_distance_mm")


def fact_problem(key: str, value: object) -> str | None:
    """What is wrong with a numeric fact (None when nothing is): not finite, or outside
    its range (above)."""
    if not (isinstance(value, int | float) and math.isfinite(value)):
        return "expected a finite number"
    if key == "focal_length_mm" and not LENGTH_MIN_MM <= abs(value) <= LENGTH_MAX_MM:
        return (f"expected a focal length of {LENGTH_MIN_MM:g} to {LENGTH_MAX_MM:g} mm "
                "either sign")
    if key in _LENGTHS and key != "focal_length_mm" and not (
            LENGTH_MIN_MM <= value <= LENGTH_MAX_MM):
        return f"expected a length in [{LENGTH_MIN_MM:g}, {LENGTH_MAX_MM:g}] mm"
    if key in _DISTANCES and not abs(value) <= LENGTH_MAX_MM:
        return f"expected a distance in [{-LENGTH_MAX_MM:g}, {LENGTH_MAX_MM:g}] mm"
    if key == "squeeze" and not SQUEEZE_MIN <= value <= SQUEEZE_MAX:
        return f"expected a squeeze in [{SQUEEZE_MIN:g}, {SQUEEZE_MAX:g}]"
    return None


def lens_facts(lens: Lens) -> LensFacts:
    """The facts of ``lens``. The housing radii are the ones the fitter's clip test uses
    for the outputs x_o, y_o (first surface) and x_i, y_i (last surface): the surfaces'
    semi-diameters (``lensfit.sample.rays``)."""
    py = paraxial(lens, meridian="y")
    squeeze = 1.0
    if lens.anamorphic:  # rotationally symmetric lenses get exactly 1
        squeeze = py.efl_mm / paraxial(lens, meridian="x").efl_mm
    return LensFacts(
        name=lens.name,
        focal_length_mm=py.efl_mm,
        stop_radius_max_mm=lens.stop_radius_max_mm,
        stop_radius_f1_mm=stop_radius_f1_mm(lens),
        housing_first_mm=lens.surfaces[0].semi_diameter_mm,
        housing_last_mm=lens.surfaces[-1].semi_diameter_mm,
        sensor_defocus_mm=py.sensor_defocus_mm,
        front_focal_distance_mm=py.ffd_mm,
        squeeze=squeeze,
    ).check()
