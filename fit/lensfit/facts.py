"""First-order facts of a lens that a runtime needs besides its polynomials.

They travel as the ``lens`` lines of a coefficient table (``lensfit-poly-table 2``, see
:mod:`lensfit.codegen.table`). Lengths in mm; paraxial figures in the y-z meridian at
the d line (587.56 nm), as :func:`lensfit.paraxial.paraxial` computes them.
"""

from __future__ import annotations

import math
from dataclasses import astuple, dataclass, fields

from lensfit.errors import InputError
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


_POSITIVE = ("stop_radius_max_mm", "stop_radius_f1_mm", "housing_first_mm", "housing_last_mm",
             "squeeze")


def fact_problem(key: str, value: object) -> str | None:
    """What is wrong with a numeric fact (None when nothing is)."""
    if not (isinstance(value, int | float) and math.isfinite(value)):
        return "expected a finite number"
    if key in _POSITIVE and not value > 0:
        return "expected a positive number"
    if key == "focal_length_mm" and value == 0:
        return "expected a non-zero focal length"
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
