"""A frame through the lens: ``lensfit image LENS INPUT.exr -o OUTPUT.exr``.

1. Read and check the frame (:mod:`lensfit.image.frame`) and the lens's table, and check
   that the frame is inside what the lens was fitted for (field, image circle, f-number,
   focus, wavelengths, distances): one line naming the value and the range otherwise.
2. Build (or reuse from the cache) the bank of PSFs over the frame's field
   (:mod:`lensfit.image.bank`, Dask).
3. Put the frame through lensrt_image (C): the direct layer (every pixel's light by its
   own field point's PSF, moved to its chief point), and with ghost tables the flare
   layers of the frame's brightest sources. With a depth channel, the frame's light is
   split over the bank's distances (weights linear in 1/distance, a partition of unity)
   and each slice is put through on its own.
4. Write the layers as one EXR (written whole or not at all) and a preview PNG.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from lensfit.common.errors import InputError
from lensfit.image.bank import (
    PSF_MIN_HALF_FRAME_PX,
    RGB_WAVELENGTHS_NM,
    ensure_bank,
    frame_bank_spec,
    frame_mirror,
    window_half_px,
)
from lensfit.image.frame import FrameError, Geometry, frame_geometry, read_frame

DEFAULT_F_NUMBER = 8.0
# The direct layer on a grid 4 times finer per axis, over 17 field points across the
# frame: 1.5% from every lit pixel's own PSF on lens 0001's corner at f/8 and 18.75 um
# pixels (oversample 3: 2.4%; 2: 4.9-5.1%; docs/image.md, make bench)
DEFAULT_OVERSAMPLE = 4
DEFAULT_NODES = 17
DEFAULT_DEPTH_SLICES = 4
MAX_SPECTRAL_CHANNELS = 64


@dataclass
class Options:
    f_number: float = DEFAULT_F_NUMBER
    focus_offset_mm: float = 0.0
    pixel_mm: float | None = None
    center_mm: tuple[float, float] = (0.0, 0.0)  # the frame's centre on the sensor
    sensor_width_mm: float | None = None
    focal_mm: float | None = None
    aperture: dict[str, Any] = field(default_factory=dict)  # shape, blades, ...
    nodes_x: int = DEFAULT_NODES
    oversample: int = DEFAULT_OVERSAMPLE
    target_error: float = 0.01
    ghosts: str | None = None  # "kept": the lens folder's ghosts/, a folder, or None
    flare_threshold: float = 0.0
    max_sources: int = 4  # each source's ghosts are Huygens renders of minutes each
    flare_target_error: float = 0.0
    flare_downsample: int = 0
    depth_slices: int = DEFAULT_DEPTH_SLICES
    cache: str | None = None
    scheduler: str | None = None
    workers: int | None = None
    progress: bool = True


@dataclass
class Result:
    output: Path
    layers: dict[str, np.ndarray]  # name -> (channels, height, width)
    spectral_nm: tuple[float, ...]  # the channels' wavelengths; () for R, G, B
    geometry: Geometry
    seconds: dict[str, float]
    bank: dict[str, Any]
    stats: list[dict[str, Any]]
    sources: list[dict[str, Any]]
    ghost_labels: list[str]


def rgb_weights(rt: Any, wavelengths_nm: tuple[float, ...]) -> np.ndarray:
    """(3, n) spectral weights of linear sRGB's R, G, B over the wavelengths: each
    channel's response to each wavelength (lensrt_spectrum_rgb of a line there, negative
    lobes clipped). A channel's light is the bank's wavelengths in these proportions."""
    n = len(wavelengths_nm)
    lines = np.eye(n, dtype=np.float32).reshape(n, 1, n)  # pixel k: a line at wavelength k
    rgb = rt.spectrum_rgb(list(wavelengths_nm), lines)[0]  # (n, 3)
    w = np.clip(rgb.T.astype(np.float64), 0.0, None)
    for c, row in enumerate(w):
        if not row.sum() > 0:
            raise InputError(f"wavelengths {list(wavelengths_nm)} nm give sRGB channel "
                             f"{'RGB'[c]} no light: widen them")
    return w


def depth_weights(depth_mm: np.ndarray, distances_mm: tuple[float, ...]) -> np.ndarray:
    """(slices, height, width): each pixel's share of each distance, the hat functions in
    1/distance (a partition of unity)."""
    u = 1.0 / np.asarray(distances_mm, dtype=np.float64)
    q = 1.0 / depth_mm
    out = np.zeros((len(u),) + depth_mm.shape)
    for k in range(len(u)):
        lo = u[k - 1] if k > 0 else None
        hi = u[k + 1] if k + 1 < len(u) else None
        w = np.zeros_like(q)
        if lo is not None:  # u ascending: rising from u[k-1] to u[k]
            m = (q >= lo) & (q <= u[k])
            w[m] = (q[m] - lo) / (u[k] - lo)
        else:
            w[q <= u[k]] = 1.0
        if hi is not None:
            m = (q > u[k]) & (q <= hi)
            w[m] = (hi - q[m]) / (hi - u[k])
        else:
            w[q > u[k]] = 1.0
        out[k] = w
    return out


def slice_distances(depth_mm: np.ndarray, n: int, closest_mm: float) -> tuple[float, ...]:
    """n distances uniform in 1/distance over the frame's depths (the farthest first)."""
    near, far = float(depth_mm.min()), float(depth_mm.max())
    if closest_mm > 0 and near < closest_mm:
        raise InputError(f"depth channel: {near:g} mm is nearer than the lens was fitted for "
                         f"(its closest light: {closest_mm:g} mm)")
    if n < 1 or near == far:
        return (far,)
    u = np.linspace(1.0 / far, 1.0 / near, n)
    return tuple(float(1.0 / v) for v in u)


def check_domain(info: dict[str, Any], rt: Any, geometry: Geometry, options: Options,
                 wavelengths: tuple[float, ...], table: Path) -> None:
    """The frame inside the lens's fitted domain, or one line naming the value."""
    (x0, x1), (y0, y1) = geometry.edge_fields_deg()
    for fx in (x0, x1):
        for fy in (y0, y1):
            dx, dy = rt.light_direction_cosines((fx, fy))
            if abs(dx) > info["field_x"] * (1 + 1e-12) or abs(dy) > info["field_y"] * (1 + 1e-12):
                raise FrameError(
                    f"the frame ({geometry.width} x {geometry.height} pixels of "
                    f"{geometry.pitch_mm * 1e3:g} um, a pinhole of {geometry.focal_x_mm:g} mm) "
                    f"reaches field ({fx:.3f}, {fy:.3f}) deg, direction cosines "
                    f"({dx:.4f}, {dy:.4f}): beyond {table}'s fitted field (+-{info['field_x']:.4f}"
                    f", +-{info['field_y']:.4f}); give a smaller frame or --pixel-um")
    w, h = geometry.size_mm
    corner = math.hypot(abs(geometry.center_x_mm) + w / 2, abs(geometry.center_y_mm) + h / 2)
    if corner > info["sensor_radius_mm"]:
        raise FrameError(f"the frame ({w:g} x {h:g} mm) reaches {corner:.3f} mm from the axis: "
                         f"beyond {table}'s fitted image circle ({info['sensor_radius_mm']:.3f}"
                         " mm); give a smaller frame or --pixel-um")
    if options.f_number < info["f_number_min"] * (1 - 1e-9):
        raise InputError(f"--f-number {options.f_number:g}: wider than {table} was fitted "
                         f"for (f/{info['f_number_min']:.3g})")
    lo, hi = info["focus_offset_min_mm"], info["focus_offset_max_mm"]
    if not lo <= options.focus_offset_mm <= hi:
        raise InputError(f"--focus-offset {options.focus_offset_mm:g} mm: outside {table}'s "
                         f"fitted sensor travel [{lo:g}, {hi:g}] mm")
    wl0, wl1 = info["wavelength_min_nm"], info["wavelength_max_nm"]
    bad = [lam for lam in wavelengths if not wl0 <= lam <= wl1]
    if bad:
        raise InputError(f"wavelength {bad[0]:g} nm: outside {table}'s fitted range "
                         f"[{wl0:g}, {wl1:g}] nm")


def ghost_tables(table: Path, ghosts: str | None) -> list[Path]:
    """The ghost tables to render: the lens folder's ghosts/ ("kept"; none there: none),
    a folder's ghost_*.table, or none (None)."""
    if ghosts is None:
        return []
    folder = table.parent / "ghosts" if ghosts == "kept" else Path(ghosts)
    if ghosts != "kept" and not folder.is_dir():
        raise InputError(f"--ghosts {ghosts}: not a folder of ghost tables")
    return sorted(folder.glob("ghost_*.table")) if folder.is_dir() else []


def through_lens(lens: str, input_path: str | Path, output: str | Path,
                 options: Options | None = None, *, library: str | None = None,
                 generated: Path | None = None,
                 say: Callable[[str], None] | None = None) -> Result:
    """Put the frame at ``input_path`` through ``lens`` (a lens id, a generated folder
    or a .table) and write ``output`` (module doc)."""
    import os

    from lensrt_ctypes import (
        IMAGE_MIRROR_X,
        IMAGE_MIRROR_Y,
        LIBRARY,
        Bank,
        Image,
        Lensrt,
        LensrtError,
    )

    from lensfit.banks.run import resolve_table
    from lensfit.banks.spec import SpecError
    from lensfit.common.atomic import check_target
    from lensfit.image.layers import write_layers

    o = options or Options()
    seconds: dict[str, float] = {}
    t = time.perf_counter()
    out = check_target(output, "-o")
    frame = read_frame(input_path)
    try:
        table = resolve_table(lens, Path.cwd(), generated)
    except SpecError as e:
        raise InputError(f"lens {lens!r}: {e}") from None
    lib = str(Path(library or os.environ.get("LENSRT_LIBRARY") or LIBRARY).resolve())
    rt = Lensrt(lib, threads=0)
    try:
        handle = rt.load(table)
    except LensrtError as e:
        raise InputError(f"{table}: {e}") from None
    info = rt.info(handle)
    geometry = replace(frame_geometry(frame, info["focal_length_mm"], pixel_mm=o.pixel_mm,
                                      sensor_width_mm=o.sensor_width_mm, focal_mm=o.focal_mm),
                       center_x_mm=float(o.center_mm[0]), center_y_mm=float(o.center_mm[1]))
    if frame.kind == "spectral":
        wavelengths = frame.wavelengths_nm
        if len(wavelengths) > MAX_SPECTRAL_CHANNELS:
            raise FrameError(f"{frame.path}: {len(wavelengths)} spectral channels: at most "
                             f"{MAX_SPECTRAL_CHANNELS}")
        weights = None
    else:
        lo, hi = info["wavelength_min_nm"], info["wavelength_max_nm"]
        wavelengths = tuple(lam for lam in RGB_WAVELENGTHS_NM if lo <= lam <= hi)
        weights = rgb_weights(rt, wavelengths)
    check_domain(info, rt, geometry, o, wavelengths, table)
    distances: tuple[float, ...] = (math.inf,)
    if frame.depth_mm is not None:
        distances = slice_distances(frame.depth_mm, o.depth_slices, info["distance_min_mm"])
    seconds["read"] = time.perf_counter() - t

    # 2. The bank over the frame's field, at the pitch of the finer grid
    t = time.perf_counter()
    if not 1 <= o.oversample <= 16:
        raise InputError(f"--oversample {o.oversample}: expected 1 .. 16")
    fine = replace(geometry, width=geometry.width * o.oversample,
                   height=geometry.height * o.oversample,
                   pitch_mm=geometry.pitch_mm / o.oversample)
    (x0, x1), (y0, y1) = geometry.edge_fields_deg()
    corners = [(x, y) for x in (x0, x1) for y in (y0, y1)] + [(0.0, 0.0)]
    try:
        half = max(window_half_px(rt, handle, fine, corners, wavelengths, o.f_number,
                                  o.focus_offset_mm, d, o.aperture,
                                  min_half_px=PSF_MIN_HALF_FRAME_PX * o.oversample)
                   for d in distances)
    except LensrtError as e:
        raise InputError(f"{table}: {e}") from None
    mirror = frame_mirror(geometry, o.aperture)
    spec = frame_bank_spec("image", table, fine, f_number=o.f_number,
                           focus_offset_mm=o.focus_offset_mm, distances_mm=distances,
                           wavelengths_nm=wavelengths, half_px=half, nodes_x=o.nodes_x,
                           aperture=o.aperture, target_error=o.target_error, mirror=mirror)
    index, bank_cost = ensure_bank(spec, table, o.cache, scheduler=o.scheduler, workers=o.workers,
                                   progress=o.progress, say=say)
    seconds["bank"] = time.perf_counter() - t

    # 3. Through lensrt_image, one distance slice at a time
    t = time.perf_counter()
    ghost_paths = ghost_tables(table, o.ghosts)
    ghosts = []
    for g in ghost_paths:
        try:
            ghosts.append(rt.load(g))
        except LensrtError as e:
            raise InputError(f"{g}: {e}") from None
    labels = [rt.info(g)["ghost_label"] or p.stem for g, p in zip(ghosts, ghost_paths, strict=True)]
    shares = (depth_weights(frame.depth_mm, distances) if frame.depth_mm is not None
              else np.ones((1,) + frame.planes.shape[1:]))
    total: list[np.ndarray] | None = None
    stats, sources = [], []
    with Bank(rt, index) as bank:
        for k, d in enumerate(distances):
            planes = np.ascontiguousarray(frame.planes * shares[k], dtype=np.float32)
            if not planes.any():
                continue
            try:
                img = Image(bank, width=geometry.width, height=geometry.height,
                            center=(geometry.center_x_mm, geometry.center_y_mm),
                            focal_x_mm=geometry.focal_x_mm, focal_y_mm=geometry.focal_y_mm,
                            f_number=o.f_number, focus_offset_mm=o.focus_offset_mm,
                            distance_mm=0.0 if math.isinf(d) else d,
                            channel_weights=weights, ghosts=ghosts,
                            aperture={"f_number": o.f_number, **o.aperture},
                            flare_threshold=o.flare_threshold, max_sources=o.max_sources,
                            flare_target_error=o.flare_target_error,
                            flare_downsample=o.flare_downsample, oversample=o.oversample,
                            mirror=(IMAGE_MIRROR_X if mirror[0] else 0)
                            | (IMAGE_MIRROR_Y if mirror[1] else 0))
                img.run(planes)
            except LensrtError as e:
                raise InputError(f"{frame.path} through {table}: {e}") from None
            layers = [img.layer(i) for i in range(2 + len(ghosts))]
            stats.append(img.stats())
            sources.extend(img.sources())
            img.close()
            total = layers if total is None else [a + b for a, b in zip(total, layers, strict=True)]
    seconds["image"] = time.perf_counter() - t
    if total is None:  # a black frame: black layers
        total = [np.zeros_like(frame.planes) for _ in range(2 + len(ghosts))]
    named = {"direct": total[0], "flare": total[1]}
    for label, plane in zip(labels, total[2:], strict=True):
        named["ghost_" + label.replace("-", "_")] = plane

    # 4. The EXR (and its attributes: what was done, in what units)
    t = time.perf_counter()
    write_layers(out, named, frame, geometry, wavelengths, attributes={
        "lensfit/lens": str(table), "lensfit/input": str(frame.path),
        "lensfit/fNumber": o.f_number, "lensfit/focusOffsetMm": o.focus_offset_mm,
        "lensfit/pinholeFocalMm": geometry.focal_x_mm, "lensfit/pitchMm": geometry.pitch_mm,
        "lensfit/bank": str(index),
        "lensfit/units": "the input's: a pixel's light on the axis keeps its value when the "
                         "lens loses none (each PSF's power is relative to the axis PSF's)"},
        rt=rt)
    seconds["write"] = time.perf_counter() - t
    return Result(output=out, layers=named, spectral_nm=frame.wavelengths_nm,
                  geometry=geometry, seconds=seconds, bank=bank_cost, stats=stats,
                  sources=sources, ghost_labels=labels)


def summary_lines(r: Result) -> list[str]:
    """What a person reads after a run: the layers, the sources, what cost what."""
    s = r.seconds
    st = r.stats[0] if r.stats else {}
    lines = [f"{r.output}: {r.geometry.width} x {r.geometry.height} pixels, layers "
             + ", ".join(r.layers),
             f"  bank {r.bank['nodes']} nodes ({r.bank['rendered']} rendered now, "
             f"{r.bank['cpu_seconds']:.1f} CPU-s), worst node error estimate "
             f"{100 * r.bank['worst_error']:.2f}%",
             f"  sources {len(r.sources)}"
             + "".join(f"; ({x['field_x_deg']:.2f}, {x['field_y_deg']:.2f}) deg power "
                       f"{x['power']:.3g}" for x in r.sources[:4])]
    if st:
        lines.append(f"  lensrt_image: warp {st.get('seconds_warp', 0):.2f} s, kernels "
                     f"{st.get('seconds_kernels', 0):.2f} s, convolve "
                     f"{st.get('seconds_convolve', 0):.2f} s, flares "
                     f"{st.get('seconds_flares', 0):.2f} s")
    lines.append("  seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in s.items())
                 + f"; total {sum(s.values()):.2f}")
    return lines


PREVIEW_DECADES = 3.0
PREVIEW_WHITE_PERCENTILE = 99.5


def preview_rgb(result: Result, layer: str | None = None) -> np.ndarray:
    """Linear sRGB (height, width, 3) of a layer (None: the total)."""
    planes = (result.layers["direct"] + result.layers["flare"] if layer is None
              else result.layers[layer])
    if not result.spectral_nm:
        return np.moveaxis(planes, 0, -1)
    from lensrt_ctypes import LIBRARY, Lensrt

    return Lensrt(LIBRARY).spectrum_rgb(list(result.spectral_nm), planes)


def write_preview(result: Result, path: str | Path) -> None:
    """A PNG of the total for a person: a log tone map over PREVIEW_DECADES below the
    PREVIEW_WHITE_PERCENTILE of the luminance (lensrt_exr.tone_map)."""
    import io

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.image as mpimg
    from lensrt_exr import tone_map

    from lensfit.common.atomic import check_target, write_atomic

    target = check_target(path, "--png")
    rgb = preview_rgb(result)
    lum = 0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]
    white = float(np.percentile(lum, PREVIEW_WHITE_PERCENTILE)) or float(lum.max()) or 1.0
    buf = io.BytesIO()
    mpimg.imsave(buf, tone_map(rgb, white, PREVIEW_DECADES), format="png")
    write_atomic(target, buf.getvalue())
