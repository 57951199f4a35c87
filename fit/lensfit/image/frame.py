"""The input frame: a linear HDR pinhole render of the scene, read from an EXR and checked.

What a frame holds (:class:`Frame`):

* its channels: linear ``R``, ``G``, ``B`` (three channels of light whose spectra are the
  bank wavelengths weighted by each sRGB channel's response: :func:`rgb_weights`), or
  spectral channels ``S0.<lambda>nm`` (the layout lensrt writes; one channel per
  wavelength, each its own light);
* an optional depth channel ``Z`` (mm from the first vertex, as Mitsuba's and most
  renderers' depth AOVs: distance along the view axis), for defocus;
* its geometry (:class:`Geometry`): pixels, pitch on the sensor, the pinhole's focal
  length. The pinhole sees the scene direction of field angles (atan(x / f), atan(y /
  f)) at the sensor point (x, y) of a pixel's centre, row 0 at the top (+y): the lens
  designers' convention lensrt uses.

A file that cannot be used is refused in one line naming the file and the value
(:class:`FrameError`): not an EXR, no usable channels, integer channels or a colour space
tag that says the values are not linear light, a value that is NaN, infinite or
negative (naming the channel and the pixel), a depth that is not positive.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lensfit.common.errors import InputError, regular_file_problem

RGB = ("R", "G", "B")
DEPTH = "Z"
FULL_FRAME_WIDTH_MM = 36.0
# Colour-space tags some writers put in an EXR header (OpenImageIO, Nuke, Blender); a
# value naming a non-linear encoding means the pixels are not light
COLOUR_SPACE_KEYS = ("oiio:ColorSpace", "colorSpace", "colorspace", "ColorSpace",
                     "interpretation")
NON_LINEAR = re.compile(r"srgb|rec\.?709|gamma|log|display|filmic|agx|output", re.I)
LINEAR = re.compile(r"linear|lin_|scene.?linear|acescg|aces2065|raw", re.I)
# EXR attributes the demo's scene script writes (scenes/night_street.py)
FOCAL_ATTRIBUTE = "lensfit/pinholeFocalMm"
SENSOR_WIDTH_ATTRIBUTE = "lensfit/sensorWidthMm"


class FrameError(InputError):
    """An input frame that cannot be used, naming the file and the value."""


@dataclass(frozen=True)
class Geometry:
    """Where the frame's pixels are on the sensor and what the pinhole sees there."""

    width: int
    height: int
    pitch_mm: float  # square pixels
    focal_x_mm: float
    focal_y_mm: float
    center_x_mm: float = 0.0
    center_y_mm: float = 0.0

    @property
    def size_mm(self) -> tuple[float, float]:
        return self.width * self.pitch_mm, self.height * self.pitch_mm

    def pixel_xy_mm(self) -> tuple[np.ndarray, np.ndarray]:
        """Sensor x of each column and y of each row (row 0 at the top, +y)."""
        x = self.center_x_mm + (np.arange(self.width) + 0.5 - self.width / 2) * self.pitch_mm
        y = self.center_y_mm + (self.height / 2 - np.arange(self.height) - 0.5) * self.pitch_mm
        return x, y

    def field_deg(self, x_mm: np.ndarray | float, y_mm: np.ndarray | float
                  ) -> tuple[np.ndarray, np.ndarray]:
        """The pinhole's field angles (degrees) at sensor points."""
        return (np.degrees(np.arctan(np.asarray(x_mm) / self.focal_x_mm)),
                np.degrees(np.arctan(np.asarray(y_mm) / self.focal_y_mm)))

    def edge_fields_deg(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """(min, max) field x and y over the frame's outer edges (not pixel centres)."""
        w, h = self.size_mm
        fx, fy = self.field_deg(np.array([self.center_x_mm - w / 2, self.center_x_mm + w / 2]),
                                np.array([self.center_y_mm - h / 2, self.center_y_mm + h / 2]))
        return (float(fx[0]), float(fx[1])), (float(fy[0]), float(fy[1]))

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class Frame:
    path: Path
    kind: str  # "rgb" or "spectral"
    planes: np.ndarray  # (channels, height, width) float32, linear, finite, >= 0
    wavelengths_nm: tuple[float, ...] = ()  # spectral frames: each channel's
    depth_mm: np.ndarray | None = None  # (height, width) > 0, or None
    attributes: dict[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.planes.shape[2]), int(self.planes.shape[1])  # width, height


def _fail(path: Path, what: str) -> FrameError:
    return FrameError(f"{path}: {what}")


def _first_bad(plane: np.ndarray, ok: np.ndarray) -> tuple[int, int, float]:
    j, i = np.argwhere(~ok)[0]
    return int(i), int(j), float(plane[j, i])


def _check_values(path: Path, name: str, plane: np.ndarray, *, positive: bool = False) -> None:
    ok = np.isfinite(plane) & ((plane > 0) if positive else (plane >= 0))
    if not ok.all():
        i, j, v = _first_bad(plane, ok)
        want = "a positive distance (mm)" if positive else "finite light >= 0"
        raise _fail(path, f"channel '{name}' pixel (x {i}, y {j}) = {v!r}: expected {want}"
                          f" ({int((~ok).sum())} such pixels)")


def _check_linear(path: Path, header: dict[str, Any]) -> None:
    for key in COLOUR_SPACE_KEYS:
        value = header.get(key)
        if isinstance(value, bytes):
            value = value.decode("latin-1")
        if isinstance(value, str) and NON_LINEAR.search(value) and not LINEAR.search(value):
            raise _fail(path, f"attribute '{key}' = {value!r}: the pixels are not linear "
                              "light (a display or log encoding); give a scene-linear EXR")
    gamma = header.get("gamma")
    if isinstance(gamma, (int, float)) and not math.isclose(float(gamma), 1.0):
        raise _fail(path, f"attribute 'gamma' = {gamma!r}: the pixels are not linear light")


def read_frame(path: str | Path) -> Frame:
    """Read and check an input frame (module doc)."""
    import OpenEXR
    from lensrt_exr import _wavelength_nm

    path = Path(path)
    problem = regular_file_problem(path)
    if problem or not path.exists():
        raise _fail(path, problem or "no such file")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            header = dict(f.header())
            channels = dict(f.channels().items())
            planes = {name: np.asarray(c.pixels) for name, c in channels.items()}
    except Exception as exc:  # the bindings raise RuntimeError and others
        raise _fail(path, f"not an EXR OpenEXR can read ({type(exc).__name__}: {exc})"
                    ) from None
    _check_linear(path, header)
    for name, plane in planes.items():
        if plane.dtype.kind in "ui" and (name in RGB or name == DEPTH
                                         or _wavelength_nm(name) is not None):
            raise _fail(path, f"channel '{name}' holds integers ({plane.dtype}): not linear "
                              "light; give HALF or FLOAT channels")
    spectral = {w: n for n in planes if (w := _wavelength_nm(n)) is not None}
    if spectral:
        lams = tuple(sorted(spectral))
        data = np.stack([planes[spectral[w]] for w in lams]).astype(np.float32)
        kind = "spectral"
    elif all(c in planes for c in RGB):
        lams = ()
        data = np.stack([planes[c] for c in RGB]).astype(np.float32)
        kind = "rgb"
    else:
        shown = ", ".join(sorted(planes)) or "none"
        raise _fail(path, f"no usable channels (channels: {shown}): expected R, G, B or "
                          "spectral S0.<lambda>nm, and optionally Z (depth, mm)")
    if data.ndim != 3 or min(data.shape[1:]) < 1:
        raise _fail(path, f"image of {data.shape[1:]} pixels")
    names = list(RGB) if kind == "rgb" else [spectral[w] for w in lams]
    for name, plane in zip(names, data, strict=True):
        _check_values(path, name, plane)
    depth = None
    if DEPTH in planes:
        depth = np.asarray(planes[DEPTH], dtype=np.float64)
        _check_values(path, DEPTH, depth, positive=True)
    return Frame(path=path, kind=kind, planes=np.ascontiguousarray(data),
                 wavelengths_nm=lams, depth_mm=depth, attributes=header)


def frame_geometry(frame: Frame, lens_focal_mm: float, *, pixel_mm: float | None = None,
                   sensor_width_mm: float | None = None, focal_mm: float | None = None
                   ) -> Geometry:
    """The frame on the sensor: the pitch from ``pixel_mm``, else ``sensor_width_mm`` /
    width, else the file's SENSOR_WIDTH_ATTRIBUTE, else a 36 mm wide sensor; the pinhole's
    focal length from ``focal_mm``, else the file's FOCAL_ATTRIBUTE, else the lens's own
    (the scale of its chief points near the axis)."""
    width, height = frame.shape
    attr_w = frame.attributes.get(SENSOR_WIDTH_ATTRIBUTE)
    attr_f = frame.attributes.get(FOCAL_ATTRIBUTE)
    if pixel_mm is None:
        sw = sensor_width_mm if sensor_width_mm is not None else (
            float(np.ravel(attr_w)[0]) if attr_w is not None else FULL_FRAME_WIDTH_MM)
        if not (math.isfinite(sw) and sw > 0):
            raise _fail(frame.path, f"sensor width = {sw!r} mm: expected a positive width")
        pixel_mm = sw / width
    if not (math.isfinite(pixel_mm) and pixel_mm > 0):
        raise FrameError(f"pixel pitch = {pixel_mm!r} mm: expected a positive pitch")
    if focal_mm is None and attr_f is not None:
        focal_mm = float(np.ravel(attr_f)[0])
        if not (math.isfinite(focal_mm) and focal_mm > 0):
            raise _fail(frame.path, f"attribute '{FOCAL_ATTRIBUTE}' = {attr_f!r}: expected "
                                    "a positive focal length (mm)")
    f = lens_focal_mm if focal_mm is None else focal_mm
    if not (math.isfinite(f) and f > 0):
        raise FrameError(f"pinhole focal length = {f!r} mm: expected a positive length")
    return Geometry(width=width, height=height, pitch_mm=float(pixel_mm),
                    focal_x_mm=float(f), focal_y_mm=float(f))
