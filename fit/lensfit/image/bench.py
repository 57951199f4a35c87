"""make bench: a whole frame through the lens (issue 38).

1. A 1920 x 1080 RGB frame (:func:`synthetic_frame`: a dim street-like scene, fine
   stripes, and a few bright lamps) through lens 0001 at f/8: the bank built cold (its
   own cache folder), then again from the cache, then with the brightest lamp's ghosts;
   seconds per stage (read, bank, lensrt_image's warp, kernels, convolutions and
   flares, write) and CPU seconds.
2. A small frame's direct layer against the per-pixel reference
   (:mod:`lensfit.image.reference`: every lit pixel's own PSF rendered from the table,
   as 4 x 4 and as 8 x 8 point lights over the pixel, extrapolated to the pixel's box:
   (4 R_8 - R_4) / 3, the lights' midpoint rule erring as the square of their spacing):
   relative L2 over the frame, next to the bank's cell borders and inside the cells, and
   the time of each (the ratio is the claim: the reference's per lit pixel cost is what
   a renderer without banks would pay).

Writes build/bench/image.md and image.json.

    python -m lensfit.image.bench --out build/bench
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
LENS = "0001"
F_NUMBER = 8.0
LAMP = 2.0e4  # a lamp's pixels over the scene's brightest lit surface (about 1)


def synthetic_frame(width: int, height: int, lamps: list[tuple[float, float]],
                    seed: int = 0) -> np.ndarray:
    """(3, height, width) linear RGB: a dim gradient sky over a lit facade of windows
    and a striped pavement, fine diagonal lines, and 3 x 3 pixel lamps at the given
    fractions of the frame (x right, y down), each LAMP times the surfaces."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    v = y / height
    img = np.zeros((3, height, width))
    sky = v < 0.35
    img[:, sky] = (np.array([0.01, 0.015, 0.04])[:, None] * (1 + v[sky])[None])
    facade = (v >= 0.35) & (v < 0.7)
    windows = ((x // 12) % 3 == 0) & ((y // 10) % 2 == 0) & facade
    img[:, facade] = np.array([0.05, 0.04, 0.03])[:, None]
    lit = rng.random(windows.sum()) < 0.6
    img[:, np.where(windows)[0][lit], np.where(windows)[1][lit]] = np.array([1.0, 0.8, 0.45]
                                                                             )[:, None]
    ground = v >= 0.7
    stripes = ((x + 2 * y) // 3) % 2 == 0
    img[:, ground & stripes] = np.array([0.08, 0.08, 0.09])[:, None]
    img[:, ground & ~stripes] = np.array([0.02, 0.02, 0.025])[:, None]
    for fx, fy in lamps:
        i, j = int(fx * width), int(fy * height)
        img[:, max(j - 1, 0):j + 2, max(i - 1, 0):i + 2] = LAMP * np.array([1.0, 0.85, 0.6]
                                                                           )[:, None, None]
    return img.astype(np.float32)


def write_frame(path: Path, planes: np.ndarray, **attributes: Any) -> Path:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              **{k: np.array([float(v)]) for k, v in attributes.items()}}
    with OpenEXR.File(header, {c: np.ascontiguousarray(p) for c, p in zip("RGB", planes,
                                                                          strict=True)}) as f:
        f.write(str(path))
    return path


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime + c.ru_utime + c.ru_stime


def full_frame(out: Path, workers: int | None) -> dict[str, Any]:
    """Part 1 of the module doc."""
    from lensfit.image.through import Options, through_lens

    frame = write_frame(out / "frame-1080p.exr", synthetic_frame(
        1920, 1080, [(0.5, 0.5), (0.15, 0.2), (0.85, 0.25), (0.3, 0.8), (0.92, 0.9)]))
    cache = out / "image-cache"
    shutil.rmtree(cache, ignore_errors=True)
    runs = {}
    for label, flares in (("cold", {}), ("cached", {}),
                          ("cached, the brightest lamp's ghosts", {"ghosts": "kept",
                                                                   "max_sources": 1})):
        t, c = time.perf_counter(), _cpu()
        r = through_lens(LENS, frame, out / "frame-1080p-through.exr",
                         Options(f_number=F_NUMBER, cache=str(cache), workers=workers,
                                 progress=False, **flares))
        runs[label] = {"wall_s": time.perf_counter() - t, "cpu_s": _cpu() - c,
                       "stages_s": r.seconds, "image_stats": r.stats[0],
                       "bank": r.bank, "sources": len(r.sources),
                       "ghosts": r.ghost_labels}
    return runs


CROP_CENTER_MM = (13.0, 7.0)  # a window near the 1080p frame's corner
CROP_PIXELS = (96, 64)
CROP_POINTS = [(47, 20), (49, 44), (24, 30), (72, 40), (10, 52), (86, 12), (60, 8), (30, 58)]
SETTINGS = [(1, 9), (2, 17), (3, 17), (4, 17)]  # (oversample, field points across)


def small_frame(out: Path) -> dict[str, Any]:
    """Part 2 of the module doc: an RGB window of the 1080p frame (18.75 um pixels) near
    its corner, lit at CROP_POINTS, through the lens at each of SETTINGS (banks over the
    window, cached), against the per-pixel reference (4 x 4 lights a pixel)."""
    sys.path.insert(0, str(ROOT / "runtime" / "python"))
    from lensrt_ctypes import LIBRARY, Lensrt

    from lensfit.banks.run import resolve_table
    from lensfit.image.bank import RGB_WAVELENGTHS_NM
    from lensfit.image.reference import per_pixel_reference, window_error
    from lensfit.image.through import Options, rgb_weights, through_lens

    w, h = CROP_PIXELS
    planes = np.zeros((3, h, w), np.float32)
    for i, j in CROP_POINTS:
        planes[:, j, i] = 1.0
    frame = write_frame(out / "window.exr", planes)
    rows = []
    ref = None
    for oversample, nodes in SETTINGS:
        opts = dict(f_number=F_NUMBER, pixel_mm=36.0 / 1920, center_mm=CROP_CENTER_MM,
                    nodes_x=nodes, oversample=oversample, ghosts=None,
                    cache=str(out / "image-cache"), workers=0, progress=False)
        through_lens(LENS, frame, out / "window-through.exr", Options(**opts))  # the bank
        t = time.perf_counter()
        r = through_lens(LENS, frame, out / "window-through.exr", Options(**opts))
        seconds = time.perf_counter() - t
        if ref is None:
            rt = Lensrt(LIBRARY, threads=0)
            lens = rt.load(resolve_table(LENS, ROOT))
            t = time.perf_counter()
            refs = {sub: per_pixel_reference(rt, lens, r.geometry, planes,
                                             rgb_weights(rt, RGB_WAVELENGTHS_NM),
                                             RGB_WAVELENGTHS_NM, f_number=F_NUMBER, half=8,
                                             target=0.002, sub=sub) for sub in (4, 8)}
            ref = (4.0 * refs[8] - refs[4]) / 3.0
            ref_seconds = time.perf_counter() - t
            ref_gap = float(np.linalg.norm(refs[8] - ref) / np.linalg.norm(ref))
        d = r.layers["direct"].astype(np.float64)
        err = float(np.linalg.norm(d - ref) / np.linalg.norm(ref))

        rows.append({"oversample": oversample, "nodes_x": nodes, "relative_l2": err,
                     "beside_node_line_worst": max(window_error(d, ref, i, j)
                                                   for i, j in CROP_POINTS[:2]),
                     "inside_cells_worst": max(window_error(d, ref, i, j)
                                               for i, j in CROP_POINTS[2:]),
                     "seconds": seconds, "bank_nodes": r.bank["nodes"]})
    return {"rows": rows, "reference_seconds": ref_seconds, "lit_pixels": len(CROP_POINTS),
            "reference_8x8_from_extrapolated": ref_gap}


def markdown(result: dict[str, Any]) -> str:
    from lensfit.image.through import DEFAULT_NODES, DEFAULT_OVERSAMPLE

    ff, sf = result["full_frame"], result["small_frame"]
    lines = ["# A frame through the lens (issue 38)", "",
             f"`python -m lensfit.image.bench` on {result['cores']} cores; lens {LENS}, "
             f"f/{F_NUMBER:g}, defaults (oversample {DEFAULT_OVERSAMPLE}, {DEFAULT_NODES} "
             "field points across).",
             "", "## 1920 x 1080 RGB, 5 lamps", "",
             "| run | wall s | CPU s | bank s | lensrt_image: warp / kernels / convolve / "
             "flares s | write s | bank nodes rendered | sources | ghosts |",
             "|---|---|---|---|---|---|---|---|---|"]
    for label, r in ff.items():
        st = r["image_stats"]
        lines.append(f"| {label} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | "
                     f"{r['stages_s']['bank']:.1f} | {st['seconds_warp']:.1f} / "
                     f"{st['seconds_kernels']:.1f} / {st['seconds_convolve']:.1f} / "
                     f"{st['seconds_flares']:.1f} | {r['stages_s']['write']:.1f} | "
                     f"{r['bank']['rendered']} of {r['bank']['nodes']} | {r['sources']} | "
                     f"{len(r['ghosts'])} |")
    lines += ["", f"## Against every lit pixel's own PSF ({sf['lit_pixels']} lit pixels of a "
              f"{CROP_PIXELS[0]} x {CROP_PIXELS[1]} RGB window at {CROP_CENTER_MM} mm)", "",
              f"The reference took {sf['reference_seconds']:.1f} s (8 x 8 lights a pixel are "
              f"{100 * sf['reference_8x8_from_extrapolated']:.2f}% from it).", "",
              "| oversample | field points across | relative L2 | worst beside a node line "
              "| worst inside a cell | seconds (bank cached) | reference / this |",
              "|---|---|---|---|---|---|---|"]
    for r in sf["rows"]:
        lines.append(f"| {r['oversample']} | {r['nodes_x']} | {100 * r['relative_l2']:.1f}% | "
                     f"{100 * r['beside_node_line_worst']:.1f}% | "
                     f"{100 * r['inside_cells_worst']:.1f}% | {r['seconds']:.2f} | "
                     f"{sf['reference_seconds'] / r['seconds']:.0f}x |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="build/bench")
    ap.add_argument("--workers", type=int, default=None)
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    result = {"full_frame": full_frame(out, args.workers), "cores": os.cpu_count(),
              "small_frame": small_frame(out)}
    (out / "image.json").write_text(json.dumps(result, indent=1, default=str))
    text = markdown(result)
    (out / "image.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
