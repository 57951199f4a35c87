"""The bank of PSFs a frame needs: the lens's field over the frame, built once and cached.

A frame's bank (:func:`frame_bank_spec`) has

* field points on a grid uniform in the tangent of the field angle (the sensor's own
  scale), from the frame's outer edges inwards, ``nodes`` per axis (the x count, with
  y's from the frame's aspect, odd so that the axis is a node);
* one f-number, one focus offset, the distances the frame needs (infinity, or those of
  its depth channel);
* the frame's pixel pitch, and a window an odd number of pixels wide (the chief point on
  a pixel centre) that holds the geometric footprint of every corner's rays (at least
  PSF_MIN_HALF_FRAME_PX of the frame's own pixels either side);
* the aperture, wavelengths and each node's target error as asked.

It is rendered by :func:`lensfit.banks.run.run_bank` (Dask, resumable) in a cache folder
named after the spec's digest, so the same frame geometry and lens reuse it.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from lensfit.image.frame import FrameError, Geometry

# Frame pixels either side of the chief point at least (times oversample at the bank's
# pitch): the Airy skirt beyond the geometric footprint. Lens 0001 at f/8, oversample 4:
# 2 frame pixels (8 of the bank's) left the direct layer 1.96% from every lit pixel's own
# PSF, 3 pixels 1.54% (650 nm: 2.54% and 1.65%; docs/image.md)
PSF_MIN_HALF_FRAME_PX = 3
PSF_MAX_HALF = 96  # at most (a window of 193 px: a PSF wider than that is a defocus)
FOOTPRINT_MARGIN_PX = 3  # beyond the geometric footprint: the diffraction's skirt
RGB_WAVELENGTHS_NM = (420.0, 470.0, 510.0, 550.0, 590.0, 630.0, 670.0, 700.0)
CACHE_ENV = "LENSFIT_IMAGE_CACHE"
DEFAULT_CACHE = Path("build") / "image-cache"


def tan_grid(lo_deg: float, hi_deg: float, n: int) -> tuple[float, ...]:
    """n field angles uniform in tan between lo and hi (degrees), rounded to 1e-9 deg
    (the bank index writes repr floats; rounding keeps the spec's digest stable)."""
    t = np.linspace(math.tan(math.radians(lo_deg)), math.tan(math.radians(hi_deg)), n)
    return tuple(round(float(v), 9) + 0.0 for v in np.degrees(np.arctan(t)))


def node_counts(geometry: Geometry, nodes_x: int) -> tuple[int, int]:
    """Nodes along x and y: nodes_x (odd), and y's spacing about x's on the sensor."""
    if nodes_x < 2:
        raise FrameError(f"--nodes = {nodes_x}: expected at least 2 field points per axis")
    w, h = geometry.size_mm
    ny = max(2, int(round((nodes_x - 1) * h / w)) + 1)
    if nodes_x % 2 == 1 and ny % 2 == 0:
        ny += 1  # odd: the axis is a node of both
    return nodes_x, ny


def window_half_px(rt: Any, lens: Any, geometry: Geometry, fields: list[tuple[float, float]],
                   wavelengths: tuple[float, ...], f_number: float, focus_offset_mm: float,
                   distance_mm: float, aperture: dict[str, Any], min_half_px: float) -> int:
    """Half the window (pixels of ``geometry``) that holds every given field point's rays
    at the shortest and longest wavelengths, about each one's chief point, and at least
    ``min_half_px``."""
    half = float(min_half_px)
    for fx, fy in fields:
        for lam in (wavelengths[0], wavelengths[-1]):
            light = (fx, fy, 0.0 if math.isinf(distance_mm) else distance_mm, 1.0)
            cx, cy = rt.image_point(lens, light, lam, focus_offset_mm)
            r = rt.create(lens, width=1, height=1, width_mm=geometry.pitch_mm,
                          center=(cx, cy), focus_offset_mm=focus_offset_mm,
                          f_number=f_number, lights=[light], wavelengths=[lam], **aperture)
            x0, x1, y0, y1 = r.footprint()
            if x0 <= x1:
                reach = max(cx - x0, x1 - cx, cy - y0, y1 - cy) / geometry.pitch_mm
                half = max(half, reach + FOOTPRINT_MARGIN_PX)
    if half > PSF_MAX_HALF:
        raise FrameError(f"the PSF reaches {half:.0f} pixels from its chief point (more than "
                         f"{PSF_MAX_HALF}): the sensor is far out of focus for this pitch; "
                         "give a focus offset nearer the lens's focus or a coarser pitch")
    return int(math.ceil(half))


def frame_mirror(geometry: Geometry, aperture: dict[str, Any]) -> tuple[bool, bool]:
    """Whether a frame's bank can leave the sign of field x (and of y) to lensrt_image's
    mirror (lensrt_image_desc.mirror): on each axis the frame spans both signs of, when
    the aperture is a circle (lensfit's lenses are mirror-symmetric about both axes; a
    polygon of blades may not be)."""
    if aperture.get("shape", "circle") != "circle":
        return False, False
    (x0, x1), (y0, y1) = geometry.edge_fields_deg()
    return x0 < 0.0 < x1, y0 < 0.0 < y1


def _half_grid(lo_deg: float, hi_deg: float, n: int) -> list[float]:
    """Field points from 0 to the farther of lo and hi, at most the spacing in tan(field)
    of n points across [lo, hi] (a centred frame's own half grid: its nodes >= 0)."""
    step = (math.tan(math.radians(hi_deg)) - math.tan(math.radians(lo_deg))) / (n - 1)
    far = max(abs(lo_deg), abs(hi_deg))
    count = int(math.ceil(math.tan(math.radians(far)) / step - 1e-9)) + 1
    return list(tan_grid(0.0, far, max(count, 2)))


def frame_bank_spec(name: str, table: Path, geometry: Geometry, *, f_number: float,
                    focus_offset_mm: float, distances_mm: tuple[float, ...],
                    wavelengths_nm: tuple[float, ...], half_px: int, nodes_x: int,
                    aperture: dict[str, Any], target_error: float,
                    mirror: tuple[bool, bool] = (False, False)) -> dict[str, Any]:
    """The bank spec (as lensfit.banks.spec reads it) for a frame; along the axes of
    ``mirror`` (:func:`frame_mirror`) only its field points >= 0 (lensrt_image mirrors
    them: a centred frame's bank is a quarter of the renders)."""
    (x0, x1), (y0, y1) = geometry.edge_fields_deg()
    nx, ny = node_counts(geometry, nodes_x)
    pixels = 2 * half_px + 1
    # The axis is a node too (lensrt_image divides by the axis PSF's power): a frame off
    # the axis gets one more field point there
    fx = _half_grid(x0, x1, nx) if mirror[0] else list(tan_grid(x0, x1, nx))
    fy = _half_grid(y0, y1, ny) if mirror[1] else list(tan_grid(y0, y1, ny))
    fx = sorted(set(fx) | ({0.0} if not x0 <= 0.0 <= x1 else set()))
    fy = sorted(set(fy) | ({0.0} if not y0 <= 0.0 <= y1 else set()))
    spec: dict[str, Any] = {
        "name": name, "lens": str(table),
        "grid": {"field_x_deg": fx, "field_y_deg": fy,
                 "f_numbers": [f_number], "focus_offsets_mm": [focus_offset_mm],
                 "distances_mm": ["inf" if math.isinf(d) else d for d in distances_mm],
                 "wavelengths_nm": list(wavelengths_nm)},
        "window": {"pixels": [pixels, pixels],
                   "size_mm": [pixels * geometry.pitch_mm, pixels * geometry.pitch_mm]},
        "render": {"integrator": "cells", "target_error": target_error},
    }
    shape = aperture.get("shape", "circle")
    if shape != "circle":
        spec["aperture"] = {"shape": shape, "blades": int(aperture.get("blades", 0)),
                            "blade_curvature": float(aperture.get("blade_curvature", 0.0)),
                            "rotation_deg": float(aperture.get("rotation_deg", 0.0))}
    return spec


def _toml_value(v: Any) -> str:
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def spec_toml(spec: dict[str, Any]) -> str:
    """A bank spec dict as TOML (only the shapes frame_bank_spec makes)."""
    top = [f"{k} = {_toml_value(v)}" for k, v in spec.items() if not isinstance(v, dict)]
    tables = [f"\n[{k}]\n" + "\n".join(f"{kk} = {_toml_value(vv)}" for kk, vv in v.items())
              for k, v in spec.items() if isinstance(v, dict)]
    return "\n".join(top) + "\n" + "\n".join(tables) + "\n"


def table_name(table: Path) -> str:
    """The name a table goes by in the cache: its generated folder's (lens0001.table in
    generated/0001-angenieux-double-gauss/ is 0001-angenieux-double-gauss.table)."""
    stem = table.parent.name if table.stem.startswith("lens") else table.stem
    return f"{stem}.table"


def cache_folder(cache: str | Path | None, spec: dict[str, Any], table_bytes: bytes) -> Path:
    """The spec's folder in the cache: <cache>/<digest of the spec with its table's CRC-32
    in place of its path> (the same frame and table reuse it from any checkout)."""
    import zlib

    from lensfit.banks.spec import BankSpec

    keyed = dict(spec, lens=f"{spec['lens']}:{zlib.crc32(table_bytes):08x}")
    root = Path(cache or os.environ.get(CACHE_ENV) or DEFAULT_CACHE)
    return root / BankSpec.from_dict(keyed).digest()[:20]


def ensure_bank(spec: dict[str, Any], table: Path, cache: str | Path | None, *,
                scheduler: str | None, workers: int | None, progress: bool, say: Any = None
                ) -> tuple[Path, dict[str, Any]]:
    """The bank's index, rendering the nodes not yet in the cache (Dask): its path and
    what it cost ({'rendered': nodes, 'cpu_seconds', 'wall_seconds'}). The table is
    copied beside the spec, which names it by a relative path."""
    from lensfit.banks.run import run_bank
    from lensfit.common.atomic import make_folder, write_atomic

    data = table.read_bytes()
    spec = dict(spec, lens=table_name(table))
    folder = cache_folder(cache, spec, data)
    make_folder(folder, "image bank cache folder")
    copy = folder / spec["lens"]
    if not copy.is_file() or copy.read_bytes() != data:
        write_atomic(copy, data)
    spec_path = folder / "spec.toml"
    text = spec_toml(spec)
    if not spec_path.is_file() or spec_path.read_text() != text:
        write_atomic(spec_path, text)
    summary = run_bank(spec_path, folder / "bank", scheduler=scheduler, workers=workers,
                       progress=progress, sheet=False, check=False, say=say)
    return summary.index, {"nodes": summary.nodes, "rendered": summary.rendered,
                           "cpu_seconds": summary.cpu_seconds,
                           "wall_seconds": summary.wall_seconds,
                           "worst_error": summary.worst_error}
