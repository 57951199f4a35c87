"""The cells integrator against Monte Carlo (issue 22): seconds to a given error.

    python runtime/bench/cells_bench.py --out build/bench [--quick]

Scenes (lens 0001, light at (-6, -4) deg): the demo's PSFs at f/2, f/8 and f/32 (7 curved
blades, sensor 0.2 mm behind focus, windows of 0.2, 0.1 and 0.16 mm) at 64 x 64 pixels and
4 wavelengths, and ghost 0-2 at f/8 on a 3 mm window over its footprint, 64 x 64 pixels
and 16 wavelengths. For each, both integrators in the same run, interleaved point by
point, each point the median of --repeats timings (lensrt_render_get_stats' seconds: the
integration alone, not the render's set-up): Monte Carlo (sobol, one sequence) at
2^10 .. 2^17 samples per wavelength, cells at 4 .. 64 rings (with its error estimate,
which costs the meshes of half and a quarter the rings). Errors are relative L2 against a
reference: cells at 4 times the finest mesh tried (its own estimate is reported, and is
below 1e-4 on every scene). Seconds to 1% are interpolated on each curve (log-log,
between the two points that bracket 1%); their ratio is the claim, absolute seconds are
context (2 shared cores).

Then the cost of a pixel against defocus: a perfect lens f = 50 mm at f/8, a 16 x 16
window over the blur, defocus 0 to 320 waves at the rim: the rings the cells integrator
needs for 1% (its estimate) and its seconds per pixel, against Monte Carlo's error at
2^16 samples.

Then the issue's flare target: every kept ghost of 0001 at f/8, light at (-6, -4) deg,
full frame 36 x 24 mm at 1440 x 960 (25 um pixels), 16 wavelengths, each rendered in the
window of its footprint (runtime/tools/flare_figure.py) and refined to a 1% error estimate.

Then the box pixel filter's cost (issue 26): box with its automatic sub-pixel points against
the point filter, same scenes, interleaved (`--pixel-area-only` runs this part alone and
writes pixel_area.json).

Then the figure tool's full frame at its defaults (issue 39): `flare_figure.py --panel
generated/0001-angenieux-double-gauss 8 ...` and nothing else (1440 x 960, 16 wavelengths,
integrator auto to 1%, the box filter at lensrt's automatic counts for every image),
seconds and CPU-seconds (this process's, every thread's) against the flare row above
(the same frame, lens, light and stop at pixel centres by cells) measured in the same run;
the target is 2x. `--figure-only` runs the flare row and this alone (figure.json).

Writes cells.json and cells.md (and cells.png, error against time) into --out.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT / "runtime" / "python"))
sys.path.insert(0, str(ROOT / "runtime" / "tools"))

import flare_figure  # noqa: E402
from lensrt_ctypes import Lensrt  # noqa: E402

LENS = ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table"
GHOST = ROOT / "generated" / "0001-angenieux-double-gauss" / "ghosts" / "ghost_0_2.table"
LIGHT = (-6.0, -4.0, 0.0, 0.0)


def scenes(rt: Lensrt) -> list[dict[str, Any]]:
    lens = rt.load(LENS)
    out = []
    for f_number, size in ((2.0, 0.2), (8.0, 0.1), (32.0, 0.16)):
        c = rt.image_point(lens, LIGHT[:2], 550.0, 0.2)
        out.append({"name": f"0001 f/{f_number:g} PSF", "table": LENS, "kw": dict(
            pixel_filter="point",
            width=64, height=64, width_mm=size, center=tuple(c), focus_offset_mm=0.2,
            f_number=f_number, shape="blades", blades=7, blade_curvature=0.3, rotation_deg=10.0,
            lights=[LIGHT], wavelengths=4)})
    out.append({"name": "ghost 0-2, f/8", "table": GHOST, "kw": dict(
        pixel_filter="point",
        width=64, height=64, width_mm=3.0, center=(-9.74, -6.34), f_number=8.0,
        lights=[LIGHT], wavelengths=16)})
    return out


def mc_point(rt: Lensrt, lens: Any, kw: dict, samples: int) -> tuple[np.ndarray, float]:
    r = rt.create(lens, **kw)
    r.run(samples)
    return r.image().astype(np.float64), float(r.stats().seconds)


def cells_point(rt: Lensrt, lens: Any, kw: dict, rings: int) -> tuple[np.ndarray, float, float]:
    r = rt.create(lens, **kw)
    est = r.integrate(rings)
    return r.image().astype(np.float64), float(r.stats().seconds), float(est)


def rel(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.linalg.norm(a - ref) / np.linalg.norm(ref))


def seconds_to(points: list[dict[str, float]], target: float) -> tuple[float | None, bool]:
    """Seconds to `target`: log-log interpolation between the two points around it; when
    no point reaches it, extrapolated along the slope of the last three (then True)."""
    pts = sorted(points, key=lambda p: p["seconds"])
    for a, b in zip(pts, pts[1:], strict=False):
        if a["error"] >= target >= b["error"] and a["error"] > b["error"]:
            la, lb = math.log(a["error"]), math.log(b["error"])
            t = (la - math.log(target)) / (la - lb)
            sa, sb = math.log(a["seconds"]), math.log(b["seconds"])
            return math.exp(sa + t * (sb - sa)), False
    below = [p["seconds"] for p in pts if p["error"] <= target]
    if below:
        return min(below), False
    tail = pts[-3:]
    x = np.log([p["seconds"] for p in tail])
    y = np.log([p["error"] for p in tail])
    k, c = np.polyfit(x, y, 1)
    if k >= 0:
        return None, True
    return float(math.exp((math.log(target) - c) / k)), True


def compare(rt: Lensrt, scene: dict, args: argparse.Namespace) -> dict[str, Any]:
    lens = rt.load(scene["table"])
    kw = scene["kw"]
    rings = [4, 8, 16, 32] if args.quick else [4, 8, 16, 32, 64]
    samples = [1 << k for k in (range(10, 16) if args.quick else range(10, 18))]
    ref, _, ref_est = cells_point(rt, lens, kw, 4 * rings[-1])
    mc, cells = [], []
    # Interleaved: the k-th Monte Carlo point, then the k-th cells point, repeated
    for k in range(max(len(rings), len(samples))):
        if k < len(samples):
            times, img = [], None
            for _ in range(args.repeats):
                img, t = mc_point(rt, lens, kw, samples[k])
                times.append(t)
            mc.append({"samples": samples[k], "seconds": statistics.median(times),
                       "error": rel(img, ref)})
        if k < len(rings):
            times, img, est = [], None, 0.0
            for _ in range(args.repeats):
                img, t, est = cells_point(rt, lens, kw, rings[k])
                times.append(t)
            cells.append({"rings": rings[k], "seconds": statistics.median(times),
                          "error": rel(img, ref), "estimate": est})
        print(f"  {scene['name']}: {mc[-1] if k < len(samples) else ''} "
              f"{cells[-1] if k < len(rings) else ''}", flush=True)
    return summarise(scene["name"], 4 * rings[-1], ref_est, mc, cells)


def summarise(name: str, ref_rings: int, ref_est: float, mc: list, cells: list) -> dict[str, Any]:
    (t_mc, mc_x), (t_cells, cells_x) = seconds_to(mc, 0.01), seconds_to(cells, 0.01)
    return {"scene": name, "reference_rings": ref_rings, "reference_estimate": ref_est,
            "montecarlo": mc, "cells": cells, "mc_seconds_to_1pct": t_mc,
            "mc_extrapolated": mc_x, "cells_seconds_to_1pct": t_cells,
            "cells_extrapolated": cells_x, "ratio": (t_mc / t_cells) if t_mc and t_cells else None}


def defocus_cost(rt: Lensrt, args: argparse.Namespace) -> list[dict[str, Any]]:
    """A perfect lens (f = 50 mm, f/8) against defocus: a 16 x 16 window over the blur."""
    f, n_f, lam = 50.0, 8.0, 550e-6
    lens = rt.analytic(sensor_distance_mm=f, focal_length_mm=f)
    rows = []
    for waves in (0, 10, 40, 160, 320):
        dz = waves * lam * 8 * n_f * n_f
        kw = dict(pixel_filter="point",
                  width=16, height=16, width_mm=12 * lam * n_f + 1.2 * dz / n_f, focus_offset_mm=dz,
                  f_number=n_f, wavelengths=[550.0])
        rings, est, t = 4, 1.0, 0.0
        while rings <= 1024:
            _, t, est = cells_point(rt, lens, kw, rings)
            if est <= 0.01:
                break
            rings *= 2
        ref, _, _ = cells_point(rt, lens, kw, 2 * rings)
        mc_img, _ = mc_point(rt, lens, kw, 1 << 16)
        rows.append({"defocus_waves": waves, "rings_for_1pct": rings, "estimate": est,
                     "seconds_per_pixel": t / 256, "mc_error_at_65536": rel(mc_img, ref)})
        print(f"  defocus {waves} waves: {rows[-1]}", flush=True)
    return rows


def flare_frame(rt: Lensrt, args: argparse.Namespace) -> dict[str, Any]:
    """Every kept ghost of 0001 over the full frame, each in its footprint's window."""
    folder = ROOT / "generated" / "0001-angenieux-double-gauss"
    # Pixel centres, as before 0.8.0: this row compares integrators (the box filter's
    # cost is pixel_area_cost's)
    ns = argparse.Namespace(integrator="cells", target_error=0.01, pixel_filter="point",
                            wavelengths=8 if args.quick else 16, floor=0.03, splats=1e10)
    # 36 x 24 mm at 25 um (flare_figure takes square pixels: 1440 x 960, not 1440 x 1080)
    frame = flare_figure.Frame((36.0, 24.0), (1440, 960))
    t0, c0 = time.perf_counter(), time.process_time()
    _, _, record = flare_figure.render_panel(rt, folder, 8.0, LIGHT[:2], frame, ns)
    return {"seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
            "wavelengths": ns.wavelengths, "images": record}


def figure_frame(out: Path, flare: dict[str, Any]) -> dict[str, Any]:
    """The figure tool's full frame at its defaults (one panel of 0001 at f/8, as the
    flare row), timed whole (set-up, enumeration, every image, the PNG), against the
    flare row of the same run."""
    folder = ROOT / "generated" / "0001-angenieux-double-gauss"
    png = out / "figure-default.png"
    t0, c0 = time.perf_counter(), time.process_time()
    flare_figure.main(["-o", str(png), "--panel", str(folder), "8", "0001 coated"])
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    images = json.loads(png.with_suffix(".json").read_text())["panels"][0]["images"]
    row = {"seconds": seconds, "cpu_seconds": cpu, "images": images,
           "flare_row_seconds": flare["seconds"],
           "flare_row_cpu_seconds": flare.get("cpu_seconds"),
           "ratio": seconds / flare["seconds"],
           "cpu_ratio": None if not flare.get("cpu_seconds") else cpu / flare["cpu_seconds"],
           "target_ratio": 2.0}
    print(f"  figure at defaults: {seconds:.1f} s ({cpu:.1f} CPU-s) against the flare row's "
          f"{flare['seconds']:.1f} s ({flare.get('cpu_seconds', float('nan')):.1f} CPU-s): "
          f"{row['ratio']:.2f}x wall, {row['cpu_ratio'] or float('nan'):.2f}x CPU (target "
          "2x)", flush=True)
    for r in images:
        if r.get("window"):
            print(f"    {r['image']}: {r.get('integrator')} "
                  f"{r.get('nodes', r.get('rings'))}, box {r['pixel_samples'][0]}x"
                  f"{r['pixel_samples'][1]}, {r['seconds']:.1f} s", flush=True)
    return row


def pixel_area_cost(rt: Lensrt, args: argparse.Namespace) -> list[dict[str, Any]]:
    """The box pixel filter's cost (issue 26): the same scene with the box filter's
    automatic sub-pixel points against the point filter, interleaved, medians of
    --repeats timings of the integration alone (cells, 16 rings, with its estimate). Lens
    0001 at f/8, light at (-6, -4) deg, 4 wavelengths (380-780 nm): the demo's PSF window
    (0.1 mm over 64 x 64: 1.6 um pixels, finer than lambda / D) and 32 x 32 sensor pixels
    of 25 um around the same image point (an Airy core narrower than a pixel)."""
    lens = rt.load(LENS)
    c = rt.image_point(lens, LIGHT[:2], 550.0, 0.2)
    rows = []
    windows = (("PSF window, 1.6 um pixels", 64, 0.1), ("25 um pixels", 32, 32 * 0.025))
    for name, n, size in windows:
        kw = dict(width=n, height=n, width_mm=size, center=tuple(c), focus_offset_mm=0.2,
                  f_number=8.0, lights=[LIGHT], wavelengths=4)
        times: dict[str, list[float]] = {"box": [], "point": []}
        counts = (1, 1)
        for _ in range(args.repeats):
            for filt in ("box", "point"):
                r = rt.create(lens, pixel_filter=filt, **kw)
                r.integrate(16)
                st = r.stats()
                times[filt].append(st.seconds)
                if filt == "box":
                    counts = (st.pixel_samples_x, st.pixel_samples_y)
        box, point = statistics.median(times["box"]), statistics.median(times["point"])
        rows.append({"scene": name, "pixels": n, "pixel_um": 1e3 * size / n,
                     "points_per_pixel": counts, "box_seconds": box, "point_seconds": point,
                     "ratio": box / point})
        print(f"  pixel area, {name}: box {counts[0]} x {counts[1]} points {box:.3f} s, "
              f"point {point:.3f} s: {box / point:.2f}x", flush=True)
    return rows


def plot(results: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(4 * len(results), 3.6))
    for ax, r in zip(np.atleast_1d(axes), results, strict=True):
        for key, style in (("montecarlo", "o-"), ("cells", "s-")):
            pts = r[key]
            ax.loglog([p["seconds"] for p in pts], [p["error"] for p in pts], style, label=key)
        est = r["cells"]
        ax.loglog([p["seconds"] for p in est], [p["estimate"] for p in est], "s:",
                  label="cells estimate")
        ax.axhline(0.01, color="grey", lw=0.5)
        ax.set_title(r["scene"], fontsize=8)
        ax.set_xlabel("seconds (2 cores)")
        ax.set_ylabel("relative L2 error")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def markdown(data: dict[str, Any]) -> str:
    lines = ["# Cells integrator against Monte Carlo (runtime/bench/cells_bench.py)", "",
             "| scene | Monte Carlo s to 1% | cells s to 1% | ratio | reference estimate |",
             "|---|---:|---:|---:|---:|"]
    def f(x: float | None, extrapolated: bool = False) -> str:
        return (f"{x:.3g}" + (" (extrapolated)" if extrapolated else "")) if x else "not reached"

    for r in data["compare"]:
        t_mc = f(r["mc_seconds_to_1pct"], r.get("mc_extrapolated", False))
        t_cells = f(r["cells_seconds_to_1pct"], r.get("cells_extrapolated", False))
        lines.append(f"| {r['scene']} | {t_mc} | {t_cells} | "
                     f"{f(r['ratio'])}x | {r['reference_estimate']:.1e} |")
    lines += ["", "| defocus (waves at the rim) | rings for 1% | cells s per pixel | "
                  "Monte Carlo error at 2^16 |", "|---:|---:|---:|---:|"]
    for d in data["defocus"]:
        lines.append(f"| {d['defocus_waves']} | {d['rings_for_1pct']} | "
                     f"{d['seconds_per_pixel']:.2g} | {d['mc_error_at_65536']:.2g} |")
    fl = data.get("flare")
    if fl:
        worst = max((i.get("error_estimate", 0.0) for i in fl["images"] if i.get("window")),
                    default=0.0)
        lines += ["", "Every kept ghost of 0001 and the direct image, full frame 36 x 24 mm at "
                      f"1440 x 960, {fl['wavelengths']} wavelengths, f/8: {fl['seconds']:.1f} s "
                      f"({fl.get('cpu_seconds', float('nan')):.1f} CPU-s), worst estimate "
                      f"{worst:.2%}."]
    fg = data.get("figure")
    if fg:
        lines += ["", "The figure tool's full frame at its defaults (flare_figure.py, one "
                      f"panel of 0001 at f/8): {fg['seconds']:.1f} s ({fg['cpu_seconds']:.1f} "
                      f"CPU-s), {fg['ratio']:.2f}x the row above (target 2x)."]
    return "\n".join(lines) + "\n"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--quick", action="store_true", help="fewer points (for a smoke test)")
    p.add_argument("--library", default=None)
    p.add_argument("--pixel-area-only", action="store_true",
                   help="only the box pixel filter's cost against the point filter "
                   "(pixel_area.json)")
    p.add_argument("--figure-only", action="store_true",
                   help="only the flare row and the figure tool's default frame against it "
                   "(figure.json)")
    p.add_argument("--summary-only", action="store_true",
                   help="rewrite cells.md and cells.png from the cells.json already in --out")
    args = p.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.summary_only:
        data = json.loads((out / "cells.json").read_text())
        data["compare"] = [summarise(r["scene"], r["reference_rings"], r["reference_estimate"],
                                     r["montecarlo"], r["cells"]) for r in data["compare"]]
        (out / "cells.json").write_text(json.dumps(data, indent=1))
        (out / "cells.md").write_text(markdown(data))
        plot(data["compare"], out / "cells.png")
        print(markdown(data))
        return 0
    rt = Lensrt(args.library) if args.library else Lensrt()
    if args.pixel_area_only:
        rows = pixel_area_cost(rt, args)
        (out / "pixel_area.json").write_text(json.dumps(rows, indent=1))
        return 0
    if args.figure_only:
        flare = flare_frame(rt, args)
        print(f"  flare row (point filter, cells): {flare['seconds']:.1f} s "
              f"({flare['cpu_seconds']:.1f} CPU-s)", flush=True)
        (out / "figure.json").write_text(json.dumps({"flare": flare}, indent=1))
        row = figure_frame(out, flare)
        (out / "figure.json").write_text(json.dumps({"flare": flare, "figure": row}, indent=1))
        return 0
    todo = scenes(rt)
    if args.quick:
        todo = todo[1:2]
    # Each part written as soon as it is done, so that a failure later keeps it
    data: dict[str, Any] = {"compare": [compare(rt, s, args) for s in todo]}
    (out / "cells.json").write_text(json.dumps(data, indent=1))
    data["defocus"] = defocus_cost(rt, args)
    (out / "cells.json").write_text(json.dumps(data, indent=1))
    data["pixel_area"] = pixel_area_cost(rt, args)
    (out / "cells.json").write_text(json.dumps(data, indent=1))
    data["flare"] = None if args.quick else flare_frame(rt, args)
    (out / "cells.json").write_text(json.dumps(data, indent=1))
    data["figure"] = None if args.quick else figure_frame(out, data["flare"])
    (out / "cells.json").write_text(json.dumps(data, indent=1))
    (out / "cells.md").write_text(markdown(data))
    plot(data["compare"], out / "cells.png")
    print(markdown(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())
