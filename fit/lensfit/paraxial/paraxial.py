"""First-order (paraxial) analysis: focal lengths, pupils, f-number, focusing.

Paraxial rays are traced with 2x2 transfer matrices acting on (y, n u): height y (mm)
and reduced slope n u. Anamorphic lenses have a different first-order system in the
x-z and y-z meridians, so everything is computed per meridian.

All lengths in mm, positions along z measured from the vertex of surface 0 (scene
side negative) unless a name says otherwise. Wavelength: the d line (587.56 nm).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from lensfit.common.errors import InputError
from lensfit.prescription.model import Lens

D_LINE_NM = 587.5618

# An f-number (or stop radius) this little wider, relatively, than the widest stop (or a
# fit's) is taken as the widest: f/4.9999988 typed for a lens fitted at f/5 is f/5.
# Clamping moves the stop radius by at most 1e-6 of itself: the PSF's power changes by
# 2e-6 and its width by 1e-6, far below a fit's PSF error (0.18% for 0001) or any Monte
# Carlo error, and no polynomial is evaluated beyond its domain. lensrt uses the same
# tolerance (runtime/src/lens/fitted.c).
F_NUMBER_REL_TOL = 1e-6


def _indices(lens: Lens, wavelength_nm: float) -> list[float]:
    """Index in front of each surface, then behind the last: len = surfaces + 1."""
    out = [float(lens.medium_before(0).n(wavelength_nm))]
    out += [float(s.medium.n(wavelength_nm)) for s in lens.surfaces]
    return out


def system_matrix(
    lens: Lens,
    first: int,
    last: int,
    meridian: str = "y",
    wavelength_nm: float = D_LINE_NM,
    end_gap: bool = False,
) -> np.ndarray:
    """Transfer matrix from just before surface ``first`` to just after surface ``last``
    (inclusive), acting on (y, n u). With ``end_gap`` it also includes the thickness
    after ``last``."""
    idx = _indices(lens, wavelength_nm)
    m = np.eye(2)
    axis = 0 if meridian == "x" else 1
    for k in range(first, last + 1):
        s = lens.surfaces[k]
        c = s.curvature_xy[axis]
        power = (idx[k + 1] - idx[k]) * c
        m = np.array([[1.0, 0.0], [-power, 1.0]]) @ m
        if k < last or end_gap:
            m = np.array([[1.0, s.thickness_mm / idx[k + 1]], [0.0, 1.0]]) @ m
    return m


@dataclass(frozen=True)
class Pupil:
    position_mm: float  # z of the pupil, from the vertex of surface 0
    radius_mm: float

    def to_dict(self) -> dict[str, float]:
        return {"position_mm": self.position_mm, "radius_mm": self.radius_mm}


@dataclass(frozen=True)
class Paraxial:
    """First-order data of one meridian at one wavelength, for a given stop radius."""

    meridian: str
    wavelength_nm: float
    efl_mm: float  # effective focal length (inf when afocal)
    bfd_mm: float  # back focal distance: last vertex to the rear focal point
    ffd_mm: float  # front focal distance: front focal point to first vertex (positive in front)
    stop_radius_mm: float
    entrance_pupil: Pupil
    exit_pupil: Pupil
    f_number: float  # EFL / entrance pupil diameter (object at infinity)
    sensor_defocus_mm: float  # sensor position minus the paraxial focus for infinity

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        return {
            k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()
        }


def paraxial(
    lens: Lens,
    *,
    meridian: str = "y",
    stop_radius_mm: float | None = None,
    wavelength_nm: float = D_LINE_NM,
) -> Paraxial:
    """Paraxial table of ``lens`` in one meridian."""
    if meridian not in ("x", "y"):
        raise ValueError(f"meridian must be 'x' or 'y', got {meridian!r}")
    n_surf = len(lens.surfaces)
    s = lens.stop_index
    r_stop = lens.stop_radius_max_mm if stop_radius_mm is None else float(stop_radius_mm)
    zs = lens.vertex_z
    z_last = zs[-1]

    # Whole lens: a parallel ray at height 1 gives the focal lengths
    (a, b), (c, d) = system_matrix(lens, 0, n_surf - 1, meridian, wavelength_nm)
    efl = -1.0 / c if c != 0 else math.inf
    bfd = -a / c if c != 0 else math.inf
    ffd = -d / c if c != 0 else math.inf  # n_object = 1

    # Entrance pupil: the stop seen through the surfaces in front of it
    if s == 0:
        ep = Pupil(0.0, r_stop)
        front = np.eye(2)
    else:
        front = system_matrix(lens, 0, s - 1, meridian, wavelength_nm, end_gap=True)
        fa, fb = front[0]
        ep = Pupil(fb / fa if fa != 0 else math.inf, abs(r_stop / fa) if fa != 0 else math.inf)

    # Exit pupil: the stop seen through the surfaces behind it
    if s == n_surf - 1:
        xp = Pupil(zs[s], r_stop)
    else:
        rear = system_matrix(lens, s + 1, n_surf - 1, meridian, wavelength_nm)
        # (y, n u): the gap behind the stop in reduced form (the stop may lie in glass)
        n_stop = float(lens.surfaces[s].medium.n(wavelength_nm))
        gap = np.array([[1.0, lens.surfaces[s].thickness_mm / n_stop], [0.0, 1.0]])
        (ra, rb), (rc, rd) = rear @ gap
        if rd != 0:
            xp = Pupil(z_last - rb / rd, abs(r_stop * (ra * rd - rb * rc) / rd))
        else:
            xp = Pupil(math.inf, math.inf)
    f_number = abs(efl) / (2.0 * ep.radius_mm) if math.isfinite(efl) else math.inf
    defocus = lens.sensor_z - (z_last + bfd) if math.isfinite(bfd) else math.inf
    return Paraxial(
        meridian=meridian,
        wavelength_nm=wavelength_nm,
        efl_mm=efl,
        bfd_mm=bfd,
        ffd_mm=ffd,
        stop_radius_mm=r_stop,
        entrance_pupil=ep,
        exit_pupil=xp,
        f_number=f_number,
        sensor_defocus_mm=defocus,
    )


def _stop_radius(
    lens: Lens, f_number: float, meridian: str, wavelength_nm: float
) -> tuple[float, Paraxial]:
    """Stop radius for ``f_number`` at infinity, unchecked, and the unit-stop table."""
    p = paraxial(lens, meridian=meridian, stop_radius_mm=1.0, wavelength_nm=wavelength_nm)
    # The entrance pupil radius is proportional to the stop radius
    return abs(p.efl_mm) / (2.0 * f_number) / p.entrance_pupil.radius_mm, p


def stop_radius_f1_mm(
    lens: Lens, *, meridian: str = "y", wavelength_nm: float = D_LINE_NM
) -> float:
    """Stop radius (mm) that would give f/1 for an object at infinity, so that f/N needs
    ``stop_radius_f1_mm / N`` (the relation of :func:`stop_radius_for_f_number`, without
    its check that the stop can open that wide)."""
    return _stop_radius(lens, 1.0, meridian, wavelength_nm)[0]


def stop_radius_for_f_number(
    lens: Lens, f_number: float, *, meridian: str = "y", wavelength_nm: float = D_LINE_NM
) -> float:
    """Stop radius (mm) that gives ``f_number`` for an object at infinity.

    Raises ValueError when the lens cannot open that wide. A stop up to
    ``F_NUMBER_REL_TOL`` wider than the widest is the widest (see there)."""
    if not (f_number > 0 and math.isfinite(f_number)):
        raise InputError(f"f-number must be a positive finite number, got {f_number}")
    r, p = _stop_radius(lens, f_number, meridian, wavelength_nm)
    widest = lens.stop_radius_max_mm
    if r > widest * (1 + F_NUMBER_REL_TOL):
        fastest = p.efl_mm / (2.0 * p.entrance_pupil.radius_mm * widest)
        # Refused values differ by more than 1e-6 relative: 9 digits always tell them apart
        raise InputError(
            f"f/{f_number:.9g} is wider than {lens.name} allows: its stop opens to "
            f"{widest:.9g} mm, which is f/{abs(fastest):.9g} (tolerance "
            f"{F_NUMBER_REL_TOL:g} relative)"
        )
    return min(r, widest)


def f_number_for_stop_radius(lens: Lens, stop_radius_mm: float, *, meridian: str = "y") -> float:
    return paraxial(lens, meridian=meridian, stop_radius_mm=stop_radius_mm).f_number


def image_distance(
    lens: Lens,
    object_distance_mm: float,
    *,
    meridian: str = "y",
    wavelength_nm: float = D_LINE_NM,
) -> float:
    """Distance from the last vertex to the paraxial image of an axial point
    ``object_distance_mm`` in front of the first vertex (inf for the object at infinity)."""
    n_surf = len(lens.surfaces)
    (a, b), (c, d) = system_matrix(lens, 0, n_surf - 1, meridian, wavelength_nm)
    if math.isinf(object_distance_mm):
        return -a / c if c != 0 else math.inf
    if not object_distance_mm > 0:
        raise InputError(f"object distance must be positive, got {object_distance_mm}")
    # A ray from the axial object point with slope 1 reaches the first vertex at height L
    y, nu = a * object_distance_mm + b, c * object_distance_mm + d
    if nu == 0:
        return math.inf
    return -y / nu


def table(lens: Lens, *, stop_radius_mm: float | None = None,
          wavelength_nm: float = D_LINE_NM) -> dict[str, Any]:
    """The ``lensfit info --json`` object: first-order data of the lens at
    ``wavelength_nm`` (the stop radius is physical: the same at every wavelength)."""
    py = paraxial(lens, meridian="y", stop_radius_mm=stop_radius_mm,
                  wavelength_nm=wavelength_nm)
    out: dict[str, Any] = {
        "name": lens.name,
        "file": lens.source_file,
        # The file's numbering: a stop on a refracting surface clips on that surface,
        # through a copy of it the loader inserts as a surface of its own (lensdb/README.md,
        # The aperture stop)
        "surfaces": sum(1 for s in lens.surfaces if not s.inserted),
        "stop_index": lens.stop_file_index,
        "stop_on_refracting_surface": bool(lens.surfaces[lens.stop_index].inserted),
        "total_track_mm": lens.sensor_z,
        "wavelength_nm": py.wavelength_nm,
        "anamorphic": lens.anamorphic,
        "efl_mm": py.efl_mm,
        "bfd_mm": py.bfd_mm,
        "ffd_mm": py.ffd_mm,
        "stop_radius_mm": py.stop_radius_mm,
        "stop_radius_max_mm": lens.stop_radius_max_mm,
        "f_number": py.f_number,
        "entrance_pupil": py.entrance_pupil.to_dict(),
        "exit_pupil": py.exit_pupil.to_dict(),
        "sensor_defocus_mm": py.sensor_defocus_mm,
        "patent_focal_length_mm": lens.provenance.get("focal_length_mm"),
        "scale": lens.provenance.get("scale", 1.0),
    }
    if lens.anamorphic:
        out["meridians"] = {
            m: paraxial(lens, meridian=m, stop_radius_mm=stop_radius_mm,
                        wavelength_nm=wavelength_nm).to_dict() for m in "xy"
        }
        # Squeeze: how much wider the x field is than the y field (EFL_y / EFL_x)
        ex = out["meridians"]["x"]["efl_mm"]
        ok = ex not in (None, 0.0) and math.isfinite(py.efl_mm)
        out["anamorphic_squeeze"] = py.efl_mm / ex if ok else None
    return _finite(out)


def _finite(obj: Any) -> Any:
    """Infinite or NaN numbers become None (JSON null)."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
