"""The lens prescription: surfaces from scene to sensor, resolved media and coatings.

Units: millimetres for every length, nanometres for wavelengths. The optical axis is
+z, light from the scene travels towards +z, the vertex of surface 0 is at z = 0 and
the sensor is a plane at ``Lens.sensor_z`` (the last surface's thickness behind it).

A ``Surface`` owns the medium that *follows* it (towards the sensor), as in a patent
table: the medium before surface 0 is air.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lensfit.glass import AIR, Medium

SHAPES = ("sphere", "asphere", "cylinder-x", "cylinder-y", "plane")
"""Surface shapes. ``cylinder-x`` has its cylinder axis along x: it is straight along x
and curved in the y-z plane, so it has power in y only. ``cylinder-y`` is the same turned
by 90 degrees (power in x only)."""


@dataclass(frozen=True)
class Layer:
    """One thin homogeneous film of a coating stack."""

    medium: Medium
    thickness_nm: float

    def to_dict(self) -> dict[str, Any]:
        return {"material": self.medium.name, "thickness_nm": self.thickness_nm}


@dataclass(frozen=True)
class Coating:
    """A thin-film stack on a surface, listed from the scene side. Empty means bare."""

    layers: tuple[Layer, ...] = ()
    label: str = "none"

    @property
    def bare(self) -> bool:
        return not self.layers


BARE = Coating()


@dataclass(frozen=True)
class Surface:
    """One refracting surface and the medium behind it."""

    shape: str
    radius_mm: float  # signed vertex radius of curvature; inf for a plane
    thickness_mm: float  # axial distance to the next vertex (or to the sensor)
    medium: Medium  # medium behind the surface
    semi_diameter_mm: float  # clear radius of the housing at this surface
    conic: float = 0.0  # conic constant k (asphere only)
    aspheric: tuple[float, ...] = ()  # even coefficients A4, A6, ... in mm^(1-2j)
    stop: bool = False
    coating: Coating = BARE
    material_spec: dict[str, Any] = field(default_factory=dict, compare=False)
    inserted: str = ""  # "" for a surface of the file; "front" or "back" for the stop
    #                     surface the loader put on a refracting surface marked `stop =
    #                     true`: a zero-thickness copy of its shape with the same medium
    #                     on both sides, in front of that surface (the next) or behind it
    # What the semi-diameter is (lensdb/README.md, `aperture`): "fixed", an aperture of
    # the lens; "automatic", a housing sized to pass the design beam (a design program's
    # automatic semi-diameter, widened by lensfit import), whose value in the design file
    # was ``design_semi_diameter_mm`` (None: the file gave none). The tracer clips at
    # ``semi_diameter_mm`` either way; these only say what it is.
    aperture: str = field(default="fixed", compare=False)
    design_semi_diameter_mm: float | None = field(default=None, compare=False)

    @property
    def curvature(self) -> float:
        """Vertex curvature c = 1/R in 1/mm (0 for a plane)."""
        if self.shape == "plane" or not math.isfinite(self.radius_mm):
            return 0.0
        return 1.0 / self.radius_mm

    @property
    def meridian_mask(self) -> tuple[float, float]:
        """Whether the surface curves along x and along y (1.0 or 0.0 each): a cylinder
        is straight along its axis."""
        if self.shape == "cylinder-x":
            return 0.0, 1.0
        if self.shape == "cylinder-y":
            return 1.0, 0.0
        return 1.0, 1.0

    @property
    def conic_k(self) -> float:
        """The conic constant in effect (0 for every shape but an asphere)."""
        return self.conic if self.shape == "asphere" else 0.0

    @property
    def curvature_xy(self) -> tuple[float, float]:
        """Paraxial curvature in the x-z and in the y-z meridian (1/mm)."""
        mx, my = self.meridian_mask
        return self.curvature * mx, self.curvature * my

    def sag_and_slope(
        self, x: np.ndarray | float, y: np.ndarray | float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sag z(x, y) relative to the vertex (mm) and its slopes dz/dx, dz/dy; NaN
        outside the conic. With u = mx x^2 + my y^2 (the masks of ``meridian_mask``):
        z = c u / (1 + sqrt(1 - (1 + k) c^2 u)) + sum_j A_j u^(j + 2)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        c, k = self.curvature, self.conic_k
        mx, my = self.meridian_mask
        u = mx * x * x + my * y * y
        with np.errstate(invalid="ignore", divide="ignore"):
            root = np.sqrt(1.0 - (1.0 + k) * c * c * u)
            z = c * u / (1.0 + root)
            dz_du = c / (2.0 * root)
        for j, a in enumerate(self.aspheric):
            z = z + a * u ** (j + 2)
            dz_du = dz_du + a * (j + 2) * u ** (j + 1)
        return z, 2.0 * mx * x * dz_du, 2.0 * my * y * dz_du

    def sag(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Surface height z(x, y) relative to the vertex, in mm (NaN outside the conic)."""
        return self.sag_and_slope(x, y)[0]

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"shape": self.shape}
        if self.shape != "plane":
            d["radius"] = self.radius_mm
        d["thickness"] = self.thickness_mm
        d.update(self.material_spec)
        d["semi_diameter"] = self.semi_diameter_mm
        if self.aperture != "fixed":
            d["aperture"] = self.aperture
        if self.design_semi_diameter_mm is not None:
            d["design_semi_diameter"] = self.design_semi_diameter_mm
        if self.shape == "asphere":
            d["conic"] = self.conic
            d["aspheric"] = list(self.aspheric)
        if self.stop:
            d["stop"] = True
        return d


@dataclass(frozen=True)
class Lens:
    """A validated prescription. Build one with ``lensfit.prescription.load_lens``."""

    name: str
    surfaces: tuple[Surface, ...]
    provenance: dict[str, Any]
    design_wavelength_nm: float = 550.0
    source_file: str = "<memory>"
    raw: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)
    variant: str = ""  # "uncoated" for with_coating(lens, "none"); names its folders

    @property
    def stop_index(self) -> int:
        return next(i for i, s in enumerate(self.surfaces) if s.stop)

    def file_index(self, k: int) -> int | None:
        """The number surface ``k`` has in the lens file (None for an inserted stop plane):
        messages and reports use the file's numbering."""
        if self.surfaces[k].inserted:
            return None
        return k - sum(1 for s in self.surfaces[:k] if s.inserted)

    @property
    def stop_file_index(self) -> int:
        """The file's surface marked ``stop = true`` (the refracting surface the stop lies
        on when the loader inserted a stop surface)."""
        s = self.stop_index
        k = {"": s, "front": s + 1, "back": s - 1}[self.surfaces[s].inserted]
        return self.file_index(k)  # type: ignore[return-value]

    def virtual_gap(self, k: int, from_front: bool = True) -> bool:
        """The ray reaches surface ``k`` across a zero-thickness gap that borders the stop
        (a stop plane written at a surface's vertex, or the stop surface the loader puts
        on a refracting surface): the sequential convention then traces the straight line
        to the surface even where it lies behind the ray (t < 0, the OPL counted
        negative), as design programs do. For the loader's stop surface, which coincides
        with its refracting surface, t is rounding-small."""
        j = k - 1 if from_front else k + 1
        if not 0 <= j < len(self.surfaces):
            return False
        gap = self.surfaces[min(j, k)].thickness_mm
        return gap == 0.0 and (self.surfaces[j].stop or self.surfaces[k].stop)

    @property
    def stop_radius_max_mm(self) -> float:
        """The widest stop radius the housing allows."""
        return self.surfaces[self.stop_index].semi_diameter_mm

    @property
    def vertex_z(self) -> np.ndarray:
        """z of each surface vertex (mm); surface 0 at 0."""
        t = np.array([s.thickness_mm for s in self.surfaces], dtype=np.float64)
        return np.concatenate([[0.0], np.cumsum(t[:-1])])

    @property
    def sensor_z(self) -> float:
        return float(sum(s.thickness_mm for s in self.surfaces))

    @property
    def anamorphic(self) -> bool:
        return any(s.shape.startswith("cylinder") for s in self.surfaces)

    def medium_before(self, k: int) -> Medium:
        return AIR if k == 0 else self.surfaces[k - 1].medium

    def medium_after(self, k: int) -> Medium:
        return self.surfaces[k].medium

    def to_dict(self) -> dict[str, Any]:
        """The prescription as plain data (the TOML layout, see lensdb/README.md)."""
        return copy.deepcopy(self.raw)
