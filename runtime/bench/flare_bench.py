"""Flare benchmark (issue 13): ghost renders against the direct render, in one run.

    python runtime/bench/flare_bench.py --out build/bench [--library PATH/liblensrt.so]
        [--lensrt-json build/bench/lensrt.json]

Lens 0001 with its ghost tables (generated/0001-angenieux-double-gauss/ghosts/,
listed in ghosts.json), light at field (-6, -4) deg at infinity, f/8, 16 wavelengths, the
sensor in focus (shift 0). A ghost is rendered as its own render (its own phasor sums) and
a flare's image is the direct image plus the ghosts' (intensities add), so each figure is
per render:

1. Splats per second on the full frame, 36 x 24 mm at 1440 x 1080, sampled as lensrt-bench
   samples its frame: one pixel per STRIDE x STRIDE block (a 120 x 90 render over the same
   36 x 24 mm), 16384 samples per wavelength. Renders interleaved in one process: direct,
   ghost 1, direct, ghost 2, ..., direct, --repeats times over (default 3, fewer when more
   ghosts are kept: MAX_SPLAT_RENDERS); each ghost's ratio is its rate
   over the mean of the two direct renders that bracket it, and the figure is the median
   over the repeats. Rates are lensrt_render_get_stats' splats (aperture samples x pixels x
   wavelengths, dark pixels included) over its seconds (time in run()). Also each rate
   over the scalar baseline's splats/s at f/8 from lensrt-bench's JSON of the same `make
   bench` run (the paper's algorithm as a scalar double loop over the direct lens's Horner
   C; skipped, with a note, when that file is absent).
2. Seconds to 1% Monte Carlo error, per ghost on a 64 x 64 window around its footprint
   (its energy is there: the footprint box from exactly traced ghost rays,
   lensfit.ghosts.enumerate.enumerate_ghosts, at 380, 580 and 780 nm, widened by 30
   lambda N as runtime/tools/flare_figure.py does) and for the direct PSF on a small window
   around its image points (380 and 780 nm) plus 0.04 mm. The error of ONE render of N
   samples per wavelength is estimated from two renders with different seeds A and B:

       error_one = ||A - B||_2 / (sqrt(2) ||(A + B) / 2||_2)   over pixels and wavelengths

   (A - B has twice one render's variance). From --error-samples, further pairs close in
   on 1% (next_samples) up to --max-error-samples; pairs on both sides of 1% are
   interpolated (log-log), else the error is scaled as 1/sqrt(N) from the pair nearest
   1% (estimate_target; beside it, the N from the slope measured between two pairs on
   that side), the seconds affine in N (the per-pixel set-up is the constant).
   Default sampler and estimator (Sobol, the paper's |sum|^2 / N^2, whose variance / N bias
   is second order at 1%). The ratio is a ghost's seconds over the direct PSF's.
3. Ghost enumeration of the lens (all its ghosts, f/8, the light above), timed live; every
   kept ghost fitted and checked against exact ghost rays as `lensfit ghosts --fit` does
   (lensfit.ghosts.tables.fit_with_trust over fit.json's domain), timed live, with the
   enumeration against the issue's target: all kept ghosts of one lens fitted in <= 5
   minutes on 2 cores (--fit-ghost I-J times one ghost's fit instead); and, for context,
   the seconds recorded in ghosts.json when the committed ghosts were fitted.

Prints the tables and writes --out/flares.json under the key "flares". The machines are
shared and noisy: quote the ratios (same run); absolute figures are context.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "runtime" / "python"))

from lensrt_ctypes import LIBRARY, Lensrt  # noqa: E402  (needs the path above)

LENS = "0001-angenieux-double-gauss"
FOLDER = ROOT / "generated" / LENS
FIELD = (-6.0, -4.0)
F_NUMBER = 8.0
WAVELENGTHS = 16
FRAME_MM = (36.0, 24.0)
FRAME_PIXELS = (1440, 1080)
TARGET_ERROR = 0.01
TARGET_FIT_SECONDS = 300.0  # issue 13: all kept ghosts of one lens in <= 5 minutes, 2 cores
FOOTPRINT_WAVELENGTHS_NM = (380.0, 580.0, 780.0)  # the ends of the render's range and its middle
WINDOW_MARGIN_LAMBDA_N = 30.0  # around a footprint, as runtime/tools/flare_figure.py
DIRECT_MARGIN_MM = 0.04  # the direct PSF's window: its image points' spread plus this
MIN_ERROR_SAMPLES = 64  # per wavelength, the fewest an error pair is rendered with
MAX_STEPS = 4  # error pairs per image at most
SLOPE_RANGE = (-1.5, -0.25)  # of log error against log N, for predicting the next N
# Budgets that keep the script near 3 minutes on 2 cores whatever the number of kept ghosts:
# part 1 renders at most this many (direct + ghost x 2 x repeats; 2 ghosts: 3 repeats) ...
MAX_SPLAT_RENDERS = 13
# ... and part 2's largest N shrinks with more ghosts (up to 4 ghosts: 2^17 each; 5-8: 2^16)
ERROR_SAMPLES_BUDGET = 1 << 19
MAX_ERROR_SAMPLES = 1 << 17
ROUGH_ERROR = 0.2  # above it the paper estimator's floor dominates: extrapolations are rough


def load_ghosts(folder: Path) -> list[dict[str, Any]]:
    """The committed kept ghosts: label, surfaces, table, recorded fit and trust seconds."""
    doc = json.loads((folder / "ghosts" / "ghosts.json").read_text(encoding="utf-8"))
    out = []
    for g in doc["ghosts"]:
        out.append(dict(label=g["label"], first=int(g["first"]), second=int(g["second"]),
                        side=g.get("side"),
                        table=folder / "ghosts" / f"ghost_{g['first']}_{g['second']}.table",
                        fit_seconds=float(g["fit_seconds"]),
                        exact_seconds=float(sum(c.get("exact_seconds", 0.0)
                                                for c in g.get("trust", [])))))
    return out


def lens_of(rt: Lensrt, g: dict[str, Any]) -> Any:
    """A ghost's table, loaded once (every part renders the same table)."""
    if g.get("lens") is None:
        g["lens"] = rt.load(g["table"])
    return g["lens"]


def render_once(rt: Lensrt, lens: Any, scene: dict[str, Any], samples: int,
                seed: int = 0) -> tuple[Any, dict[str, Any]]:
    """One fresh render of ``samples`` per wavelength: (the render, its stats)."""
    r = rt.create(lens, seed=seed, **scene)
    r.run(samples)
    st = r.stats()
    rec = dict(samples=int(st.samples_per_wavelength), pixels=int(st.width * st.height),
               wavelengths=int(st.n_wavelengths), splats=int(st.splats),
               seconds=float(st.seconds), splats_per_second=float(st.splats) / float(st.seconds),
               phase_terms=float(st.phase_terms), clip_fraction=float(st.clip_fraction),
               tau_fraction=float(st.tau_fraction), dark_fraction=float(st.dark_fraction))
    return r, rec


def frame_scene(stride: int) -> dict[str, Any]:
    """The full frame, one pixel per stride x stride block, over the same 36 x 24 mm."""
    return dict(width=FRAME_PIXELS[0] // stride, height=FRAME_PIXELS[1] // stride,
                pixel_filter="point",
                width_mm=FRAME_MM[0], height_mm=FRAME_MM[1], center=(0.0, 0.0),
                f_number=F_NUMBER, lights=[FIELD], wavelengths=WAVELENGTHS)


def baseline_rate(lensrt_json: Path) -> dict[str, Any]:
    """The scalar baseline's splats/s at f/8 from lensrt-bench's JSON, or why not."""
    if not lensrt_json.is_file():
        return dict(skipped=f"{lensrt_json}: not found (run lensrt-bench --json first)")
    lb = json.loads(lensrt_json.read_text(encoding="utf-8"))
    per = lb.get("per_f_number", {}).get(f"{F_NUMBER:g}")
    if per and per.get("baseline_splats_per_second"):
        rate = float(per["baseline_splats_per_second"])
    elif lb.get("f_number") == F_NUMBER and lb.get("baseline_splats_per_second"):
        rate = float(lb["baseline_splats_per_second"])
    else:
        return dict(skipped=f"{lensrt_json}: no baseline at f/{F_NUMBER:g}")
    return dict(source=str(lensrt_json), splats_per_second=rate,
                threads=lb.get("baseline_threads"), date=lb.get("date"),
                algorithm=lb.get("baseline", {}).get("algorithm"))


def splat_rates(rt: Lensrt, direct_table: Path, ghosts: list[dict[str, Any]], stride: int,
                samples: int, repeats: int, baseline: dict[str, Any]) -> dict[str, Any]:
    """Part 1: direct, ghost 1, direct, ghost 2, ..., direct, `repeats` times over."""
    scene = frame_scene(stride)
    direct = rt.load(direct_table)
    lenses = {g["label"]: lens_of(rt, g) for g in ghosts}
    renders: list[dict[str, Any]] = []

    def one(image: str, lens: Any, repeat: int) -> dict[str, Any]:
        r, rec = render_once(rt, lens, scene, samples)
        del r
        rec = dict(image=image, repeat=repeat, **rec)
        renders.append(rec)
        return rec

    render_once(rt, direct, scene, 16)  # warm up (page in the library and the table)
    ratios: dict[str, list[float]] = {g["label"]: [] for g in ghosts}
    before = one("direct", direct, 0)
    for rep in range(repeats):
        for g in ghosts:
            rec = one(g["label"], lenses[g["label"]], rep)
            after = one("direct", direct, rep)
            ratios[g["label"]].append(rec["splats_per_second"] / (
                0.5 * (before["splats_per_second"] + after["splats_per_second"])))
            before = after
    d_rates = [r["splats_per_second"] for r in renders if r["image"] == "direct"]
    base = baseline.get("splats_per_second")
    out_direct = dict(splats_per_second=float(np.median(d_rates)),
                      seconds=float(np.median([r["seconds"] for r in renders
                                               if r["image"] == "direct"])),
                      ratio_vs_baseline=None if base is None else float(np.median(d_rates)) / base)
    per_ghost = {}
    for g in ghosts:
        recs = [r for r in renders if r["image"] == g["label"]]
        rate = float(np.median([r["splats_per_second"] for r in recs]))
        per_ghost[g["label"]] = dict(
            side=g["side"], splats_per_second=rate,
            seconds=float(np.median([r["seconds"] for r in recs])),
            ratio_vs_direct=float(np.median(ratios[g["label"]])),
            ratios_vs_direct=ratios[g["label"]],
            ratio_vs_baseline=None if base is None else rate / base,
            dark_fraction=recs[-1]["dark_fraction"], phase_terms=recs[-1]["phase_terms"])
    # The whole flare (direct + every ghost, one render each): splats over median seconds
    splats = renders[0]["splats"] + sum(r["splats"] for r in renders[1:2 * len(ghosts):2])
    secs = out_direct["seconds"] + sum(g["seconds"] for g in per_ghost.values())
    flare = dict(renders=1 + len(ghosts), splats=splats, seconds=secs,
                 splats_per_second=splats / secs,
                 ratio_vs_direct=splats / secs / out_direct["splats_per_second"],
                 ratio_vs_baseline=None if base is None else splats / secs / base)
    return dict(frame_mm=list(FRAME_MM), resolution=list(FRAME_PIXELS), stride=stride,
                rendered_resolution=[scene["width"], scene["height"]], samples=samples,
                repeats=repeats, order="direct, ghost 1, direct, ghost 2, ..., direct; "
                "ratio: the ghost over the mean of its two bracketing direct renders; medians",
                baseline=baseline, direct=out_direct, ghosts=per_ghost, flare=flare,
                renders=renders)


def pair_error(rt: Lensrt, lens: Any, scene: dict[str, Any], samples: int,
               seeds: tuple[int, int] = (1, 2)) -> dict[str, Any]:
    """The error of one render of `samples` from two renders with different seeds."""
    imgs, secs = [], []
    for seed in seeds:
        r, rec = render_once(rt, lens, scene, samples, seed=seed)
        imgs.append(r.image().astype(np.float64))
        secs.append(rec["seconds"])
        del r
    a, b = imgs
    level = float(np.linalg.norm((0.5 * (a + b)).ravel()))
    diff = float(np.linalg.norm((a - b).ravel()))
    if not level > 0:
        return dict(samples=samples, seconds=secs, error_one=None, error_mean_of_two=None)
    return dict(samples=samples, seconds=secs, error_one=diff / (math.sqrt(2.0) * level),
                error_mean_of_two=diff / (2.0 * level), seeds=list(seeds))


def _slope(lo: dict[str, Any], hi: dict[str, Any]) -> float:
    """d log(error) / d log(N) between two error pairs."""
    return math.log(hi["error_one"] / lo["error_one"]) / math.log(hi["samples"] / lo["samples"])


def next_samples(steps: list[dict[str, Any]], target: float, max_samples: int) -> int | None:
    """The next pair's N (a power of two), or None when the steps already bracket the
    target between neighbouring powers of two or the next N was measured or is out of
    bounds. The first prediction uses the 1/sqrt(N) law; later ones the slope measured
    between the last two pairs (Sobol points converge up to ~1/N), clamped to
    SLOPE_RANGE."""
    last = steps[-1]
    above = [st for st in steps if st["error_one"] > target]
    below = [st for st in steps if st["error_one"] <= target]
    if above and below and max(st["samples"] for st in above) * 2 >= min(
            st["samples"] for st in below):
        return None
    slope = -0.5 if len(steps) < 2 else min(SLOPE_RANGE[1], max(SLOPE_RANGE[0], _slope(
        *sorted(steps[-2:], key=lambda st: st["samples"]))))
    want = last["samples"] * (target / last["error_one"]) ** (1.0 / slope)
    nxt = int(min(max_samples, max(MIN_ERROR_SAMPLES, 2 ** round(math.log2(want)))))
    if any(st["samples"] == nxt for st in steps):
        return None
    return nxt


def estimate_target(steps: list[dict[str, Any]], target: float) -> dict[str, Any]:
    """N and seconds of one render to `target` from the measured pairs.

    Pairs on both sides of the target: log-log interpolation of the error between the
    nearest two (no convergence law assumed), seconds affine in N between them. Else the
    brief's law from the pair nearest the target: error ~ 1/sqrt(N), seconds affine in N
    through the two pairs of largest N (the per-pixel set-up is the constant) when that
    line rises from a non-negative set-up, else proportional to N."""
    def secs(st: dict[str, Any]) -> float:
        return float(np.mean(st["seconds"]))

    def affine(a: dict[str, Any], b: dict[str, Any], n: float) -> float:
        return secs(a) + (secs(b) - secs(a)) * (n - a["samples"]) / (b["samples"] - a["samples"])

    above = [st for st in steps if st["error_one"] > target]
    below = [st for st in steps if st["error_one"] <= target]
    if above and below:
        lo = max(above, key=lambda st: st["samples"])
        hi = min(below, key=lambda st: st["samples"])
        if lo["samples"] < hi["samples"]:
            n = lo["samples"] * (target / lo["error_one"]) ** (1.0 / _slope(lo, hi))
            return dict(samples_to_target=n, seconds_to_target=affine(lo, hi, n),
                        method=f"interpolated between N = {lo['samples']} and {hi['samples']}",
                        from_samples=lo["samples"], from_error=lo["error_one"])
    best = min(steps, key=lambda st: abs(math.log(st["error_one"] / target)))
    big = sorted(steps, key=lambda st: st["samples"])[-2:]

    def seconds_at(n: float) -> float:
        if len(big) == 2 and big[0]["samples"] < big[1]["samples"]:
            rate = (secs(big[1]) - secs(big[0])) / (big[1]["samples"] - big[0]["samples"])
            if rate > 0 and secs(big[0]) - rate * big[0]["samples"] >= 0:  # else noise
                return affine(big[0], big[1], n)
        return secs(best) * n / best["samples"]

    n = best["samples"] * (best["error_one"] / target) ** 2
    out = dict(samples_to_target=n, seconds_to_target=seconds_at(n),
               method=f"1/sqrt(N) from N = {best['samples']}",
               from_samples=best["samples"], from_error=best["error_one"])
    # Beside it, the slope measured between the two pairs nearest the target on this side
    # (Sobol points converge faster than 1/sqrt(N) where the integrand is smooth)
    side = sorted(steps, key=lambda st: abs(math.log(st["error_one"] / target)))[:2]
    if len(side) == 2 and side[0]["samples"] != side[1]["samples"]:
        slope = _slope(*sorted(side, key=lambda st: st["samples"]))
        # Shallower than SLOPE_RANGE's: the floor dominates both pairs (or noise); no figure
        if slope <= SLOPE_RANGE[1]:
            n2 = best["samples"] * math.exp(math.log(target / best["error_one"]) / slope)
            out.update(measured_slope=slope, samples_to_target_measured_slope=n2,
                       seconds_to_target_measured_slope=seconds_at(n2))
    return out


def seconds_to_error(rt: Lensrt, lens: Any, scene: dict[str, Any], samples: int,
                     max_samples: int, target: float = TARGET_ERROR) -> dict[str, Any]:
    """Part 2 for one image: N and seconds of one render to `target` relative L2 error,
    from up to MAX_STEPS error pairs whose N close in on the target (next_samples,
    estimate_target)."""
    steps = [pair_error(rt, lens, scene, samples)]
    if steps[-1]["error_one"] is None:
        return dict(steps=steps, samples_to_target=None, seconds_to_target=None,
                    note="the image is zero in its window")
    while len(steps) < MAX_STEPS:
        nxt = next_samples(steps, target, max_samples)
        if nxt is None:
            break
        steps.append(pair_error(rt, lens, scene, nxt))
    est = estimate_target(steps, target)
    return dict(steps=steps, **est, rough=bool(est["from_error"] > ROUGH_ERROR))


def window_scene(center: tuple[float, float], width_mm: float, pixels: int) -> dict[str, Any]:
    return dict(pixel_filter="point", width=pixels, height=pixels, width_mm=width_mm, center=center,
                f_number=F_NUMBER, lights=[FIELD], wavelengths=WAVELENGTHS)


def footprints(ghosts: list[dict[str, Any]], rays: int | None) -> dict[str, Any]:
    """Each ghost's footprint box (x0, x1, y0, y1) in mm from exactly traced ghost rays,
    or None when no ray of it reaches the sensor for this light and stop."""
    from lensfit.ghosts.enumerate import enumerate_ghosts
    from lensfit.prescription import load_lens

    lens = load_lens(LENS)
    kw = {} if rays is None else dict(rays=rays, fine_rays=max(100, rays // 5))
    est = enumerate_ghosts(lens, f_number=F_NUMBER, light=FIELD,
                           wavelengths_nm=FOOTPRINT_WAVELENGTHS_NM,
                           pairs=[(g["first"], g["second"]) for g in ghosts], **kw)
    boxes: dict[str, Any] = {}
    for e in est:
        pts = [(c, r) for c, r in zip(e.centre_mm, e.extent_mm, strict=True) if c is not None]
        boxes[e.name] = None if not pts else (
            min(c[0] - r for c, r in pts), max(c[0] + r for c, r in pts),
            min(c[1] - r for c, r in pts), max(c[1] + r for c, r in pts))
    return boxes


def mc_errors(rt: Lensrt, direct_table: Path, ghosts: list[dict[str, Any]], pixels: int,
              samples: int, max_samples: int, rays: int | None) -> dict[str, Any]:
    """Part 2: seconds to 1% per ghost on its footprint window and for the direct PSF."""
    direct = rt.load(direct_table)
    pts = [rt.image_point(direct, FIELD, lam) for lam in (380.0, 780.0)]
    xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    spread = max(max(xs) - min(xs), max(ys) - min(ys))
    d_center = (0.5 * (min(xs) + max(xs)), 0.5 * (min(ys) + max(ys)))
    d_width = spread + DIRECT_MARGIN_MM
    d = seconds_to_error(rt, direct, window_scene(d_center, d_width, pixels), samples,
                         max_samples)
    d.update(center_mm=list(d_center), width_mm=d_width)
    boxes = footprints(ghosts, rays)
    margin = WINDOW_MARGIN_LAMBDA_N * FOOTPRINT_WAVELENGTHS_NM[-1] * 1e-6 * F_NUMBER
    per_ghost: dict[str, Any] = {}
    for g in ghosts:
        box = boxes.get(g["label"])
        if box is None:
            per_ghost[g["label"]] = dict(skipped="no exactly traced ray of this ghost reaches "
                                         "the sensor for this light and stop (no footprint)")
            continue
        center = (0.5 * (box[0] + box[1]), 0.5 * (box[2] + box[3]))
        width = max(box[1] - box[0], box[3] - box[2]) + 2 * margin
        res = seconds_to_error(rt, lens_of(rt, g), window_scene(center, width, pixels),
                               samples, max_samples)
        res.update(center_mm=list(center), width_mm=width, footprint_box_mm=list(box))
        if res["seconds_to_target"] is not None and d["seconds_to_target"]:
            res["ratio_vs_direct"] = res["seconds_to_target"] / d["seconds_to_target"]
        per_ghost[g["label"]] = res
    return dict(target=TARGET_ERROR, pixels=[pixels, pixels], max_samples=max_samples,
                error="error of ONE render of N samples per wavelength: ||A - B||_2 / "
                      "(sqrt(2) ||(A + B) / 2||_2) over pixels and wavelengths, A and B two "
                      "renders with seeds 1 and 2; N to the target scaled as 1/sqrt(N), "
                      "seconds linearly in N from the last measured pair",
                footprint_wavelengths_nm=list(FOOTPRINT_WAVELENGTHS_NM),
                window_margin_mm=margin, direct=d, ghosts=per_ghost)


def fit_all_live(lens, est: list, ghosts: list[dict[str, Any]]) -> dict[str, Any]:
    """Every kept ghost fitted and checked live, as `lensfit ghosts --fit` does
    (lensfit.ghosts.tables.fit_with_trust: the fit, its trust cells against exact ghost
    rays, and the refit with larger budgets where the first misses 3%), from the live
    enumeration's estimates; the fits' and the exact rays' seconds apart."""
    from lensfit.codegen.generate import read_fit_json
    from lensfit.codegen.table import read_table
    from lensfit.ghosts.tables import fit_with_trust
    from lensfit.sample.domain import Domain

    _, meta = read_fit_json(FOLDER / "fit.json")
    domain = Domain.from_dict(meta["domain"])
    direct = read_table((FOLDER / "lens0001.table").read_text(encoding="utf-8"))
    by_pair = {(e.first, e.second): e for e in est}
    per_ghost, t0 = {}, time.perf_counter()
    for g in ghosts:
        t = time.perf_counter()
        fit, _, cells = fit_with_trust(lens, by_pair[(g["first"], g["second"])], direct,
                                       domain, FIELD, F_NUMBER)
        per_ghost[g["label"]] = dict(seconds=time.perf_counter() - t, fit_seconds=fit.seconds,
                                     psf_vs_exact=max(c.rel_l2 for c in cells))
    return dict(ghost="all", seconds=time.perf_counter() - t0, per_ghost=per_ghost)


def fit_times(ghosts: list[dict[str, Any]], fit_ghost: tuple[int, int] | str | None,
              rays: int | None) -> dict[str, Any]:
    """Part 3: enumeration and the kept ghosts' fits (or one ghost's), live; the recorded
    fits of the kept ghosts."""
    from lensfit.ghosts.enumerate import enumerate_ghosts
    from lensfit.prescription import load_lens

    lens = load_lens(LENS)
    kw = {} if rays is None else dict(rays=rays, fine_rays=max(100, rays // 5))
    t0 = time.perf_counter()
    est = enumerate_ghosts(lens, f_number=F_NUMBER, light=FIELD, **kw)
    enum_s = time.perf_counter() - t0
    live = None
    if fit_ghost == "all":
        live = fit_all_live(lens, est, ghosts)
    elif fit_ghost is not None:
        from lensfit.codegen.generate import read_fit_json
        from lensfit.ghosts.fit import fit_ghost as fit_one
        from lensfit.sample.domain import Domain

        _, meta = read_fit_json(FOLDER / "fit.json")
        domain = Domain.from_dict(meta["domain"])
        t0 = time.perf_counter()
        fit_one(lens, fit_ghost[0], fit_ghost[1], domain)
        sec = time.perf_counter() - t0
        rec = next((g for g in ghosts if (g["first"], g["second"]) == fit_ghost), None)
        live = dict(ghost=list(fit_ghost), seconds=sec,
                    recorded_fit_seconds=None if rec is None else rec["fit_seconds"],
                    ratio_live_vs_recorded=None if rec is None else sec / rec["fit_seconds"])
    fit_s = sum(g["fit_seconds"] for g in ghosts)
    exact_s = sum(g["exact_seconds"] for g in ghosts)
    return dict(enumeration=dict(ghosts=len(est), seconds=enum_s,
                                 rays_per_wavelength=rays or "lensfit's default"),
                fit_live=live,
                recorded=dict(kept=len(ghosts), fit_seconds=fit_s, trust_exact_seconds=exact_s,
                              total_seconds=fit_s + exact_s,
                              per_ghost={g["label"]: dict(fit_seconds=g["fit_seconds"],
                                                          trust_exact_seconds=g["exact_seconds"])
                                         for g in ghosts},
                              source=str((FOLDER / "ghosts" / "ghosts.json").relative_to(ROOT))),
                target_seconds=TARGET_FIT_SECONDS,
                recorded_plus_live_enumeration_seconds=fit_s + exact_s + enum_s)


def report_splats(sp: dict[str, Any]) -> None:
    """Part 1's table on stdout."""
    w, h = sp["rendered_resolution"]
    print(f"1. splats/s, full frame {FRAME_MM[0]:g} x {FRAME_MM[1]:g} mm at "
          f"{FRAME_PIXELS[0]} x {FRAME_PIXELS[1]} sampled one pixel per {sp['stride']} x "
          f"{sp['stride']} block ({w} x {h} rendered over the same frame), {sp['samples']} "
          f"samples/wavelength, medians of {sp['repeats']} interleaved repeats:")
    base = sp["baseline"]
    bnote = (f"x baseline ({base['splats_per_second']:.3g} splats/s, "
             f"{base.get('threads')} threads)" if "splats_per_second" in base else "x baseline")
    print(f"  {'image':8s} {'side':5s} {'splats/s':>10s} {'s/render':>9s} {'dark':>5s} "
          f"{'x direct':>9s} {bnote}")

    def xb(v: float | None) -> str:
        return "-" if v is None else f"{v:.0f}"

    d = sp["direct"]
    print(f"  {'direct':8s} {'':5s} {d['splats_per_second']:10.3g} {d['seconds']:9.2f} "
          f"{'':5s} {1.0:9.2f} {xb(d['ratio_vs_baseline'])}")
    for label, g in sp["ghosts"].items():
        print(f"  {label:8s} {g['side'] or '':5s} {g['splats_per_second']:10.3g} "
              f"{g['seconds']:9.2f} {g['dark_fraction']:5.2f} {g['ratio_vs_direct']:9.2f} "
              f"{xb(g['ratio_vs_baseline'])}")
    f = sp["flare"]
    print(f"  {'flare':8s} {'all':5s} {f['splats_per_second']:10.3g} {f['seconds']:9.2f} "
          f"{'':5s} {f['ratio_vs_direct']:9.2f} {xb(f['ratio_vs_baseline'])}   (direct + "
          f"{f['renders'] - 1} ghosts, one render each)")
    if "skipped" in base:
        print(f"  baseline ratio skipped: {base['skipped']}")
    sys.stdout.flush()


def report_errors(er: dict[str, Any]) -> None:
    """Part 2's table on stdout."""
    print(f"2. seconds to {er['target']:.0%} Monte Carlo error (one render; "
          f"{er['pixels'][0]} x {er['pixels'][1]} window):")
    print(f"  {'image':8s} {'window mm':>9s} {'N from':>10s} {'error':>8s} "
          f"{'N to 1%':>9s} {'s to 1%':>8s} {'x direct':>8s}")

    def row(label: str, r: dict[str, Any]) -> None:
        if "skipped" in r:
            print(f"  {label:8s} skipped: {r['skipped']}")
            return
        if r["seconds_to_target"] is None:
            print(f"  {label:8s} {r['width_mm']:9.3f} {r['steps'][-1]['samples']:10d}  "
                  f"{r['note']}")
            return
        ratio = r.get("ratio_vs_direct", 1.0 if label == "direct" else None)
        flag = f"  {r['method']}" + ("" if "measured_slope" not in r else (
            f"; with the measured slope {r['measured_slope']:.2f}: "
            f"{r['samples_to_target_measured_slope']:.3g} samples, "
            f"{r['seconds_to_target_measured_slope']:.3g} s")) + (
            f" (rough: error above {ROUGH_ERROR:.0%}, the estimator's floor dominates)"
            if r["rough"] else "")
        print(f"  {label:8s} {r['width_mm']:9.3f} {r['from_samples']:10d} "
              f"{r['from_error']:8.2e} {r['samples_to_target']:9.3g} "
              f"{r['seconds_to_target']:8.3g} {'-' if ratio is None else f'{ratio:8.3g}'}"
              + flag)

    row("direct", er["direct"])
    for label, r in er["ghosts"].items():
        row(label, r)
    sys.stdout.flush()


def report_fitting(ft: dict[str, Any]) -> None:
    """Part 3's lines on stdout."""
    en, rec = ft["enumeration"], ft["recorded"]
    print(f"3. ghost enumeration (all {en['ghosts']} ghosts, live): {en['seconds']:.1f} s")
    fl = ft["fit_live"]
    if fl and fl["ghost"] == "all":
        total = fl["seconds"] + en["seconds"]
        print(f"  all {len(fl['per_ghost'])} kept ghosts fitted and checked against exact rays "
              f"(live, as `lensfit ghosts --fit`): {fl['seconds']:.1f} s ("
              + ", ".join(f"{k} {v['seconds']:.0f} s" for k, v in fl["per_ghost"].items())
              + f"); with the enumeration {total:.1f} s against the target "
              f"{ft['target_seconds']:.0f} s ({total / ft['target_seconds']:.2f} of it)")
    elif fl:
        extra = ("" if fl["recorded_fit_seconds"] is None else
                 f" (recorded {fl['recorded_fit_seconds']:.1f} s, live/recorded "
                 f"{fl['ratio_live_vs_recorded']:.2f})")
        print(f"  fit of ghost {fl['ghost'][0]}-{fl['ghost'][1]} (live): {fl['seconds']:.1f} s"
              + extra)
    print(f"  recorded, {rec['kept']} kept ghosts: fits {rec['fit_seconds']:.1f} s + exact-ray "
          f"trust {rec['trust_exact_seconds']:.1f} s = {rec['total_seconds']:.1f} s; with the "
          f"live enumeration {ft['recorded_plus_live_enumeration_seconds']:.1f} s against the "
          f"target {ft['target_seconds']:.0f} s "
          f"({ft['recorded_plus_live_enumeration_seconds'] / ft['target_seconds']:.2f} of it)")


def parse_ghost(text: str) -> tuple[int, int] | str | None:
    if text.lower() in ("none", "all"):
        return None if text.lower() == "none" else "all"
    a, b = text.replace(",", "-").split("-")
    return int(a), int(b)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "build" / "bench")
    ap.add_argument("--library", type=Path, default=LIBRARY)
    ap.add_argument("--lensrt-json", type=Path, default=None,
                    help="lensrt-bench's JSON for the baseline (default: OUT/lensrt.json)")
    ap.add_argument("--stride", type=int, default=12, help="one pixel per STRIDE x STRIDE")
    ap.add_argument("--samples", type=int, default=16384, help="per wavelength (part 1)")
    ap.add_argument("--repeats", type=int, default=0,
                    help="default: 3, fewer with more ghosts (MAX_SPLAT_RENDERS)")
    ap.add_argument("--error-pixels", type=int, default=64)
    ap.add_argument("--error-samples", type=int, default=4096,
                    help="first N of the error pairs (part 2)")
    ap.add_argument("--max-error-samples", type=int, default=0,
                    help="largest N of an error pair (default: 2^17 for up to 4 ghosts, "
                         "less with more: ERROR_SAMPLES_BUDGET)")
    ap.add_argument("--rays", type=int, default=None,
                    help="exact rays per wavelength of the enumeration (default lensfit's)")
    ap.add_argument("--fit-ghost", default="all",
                    help="fit live: all (every kept ghost with its trust, as `lensfit "
                         "ghosts --fit`), one ghost I-J (its fit only), or none")
    args = ap.parse_args(argv)

    t_all = time.perf_counter()
    ghosts = load_ghosts(FOLDER)
    k = max(1, len(ghosts))
    repeats = args.repeats or max(1, min(3, (MAX_SPLAT_RENDERS - 1) // (2 * k)))
    max_n = args.max_error_samples or max(args.error_samples, min(
        MAX_ERROR_SAMPLES, 2 ** int(math.log2(ERROR_SAMPLES_BUDGET / k))))
    rt = Lensrt(args.library)
    for g in ghosts:  # every table read before any work
        lens_of(rt, g)
    direct_table = FOLDER / "lens0001.table"
    lensrt_json = args.lensrt_json or args.out / "lensrt.json"
    res: dict[str, Any] = dict(
        benchmark="flare_bench", lens=LENS, library=str(args.library),
        date=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        machine=platform.processor() or platform.machine(), cpu_count=os.cpu_count(),
        light_field_deg=list(FIELD), f_number=F_NUMBER, wavelengths=WAVELENGTHS,
        focus_offset_mm=0.0, ghosts=[g["label"] for g in ghosts])
    print(f"Flares of {LENS}: light ({FIELD[0]:g}, {FIELD[1]:g}) deg, f/{F_NUMBER:g}, "
          f"{WAVELENGTHS} wavelengths, in focus; {len(ghosts)} ghost tables "
          f"({', '.join(res['ghosts'])})", flush=True)
    res["splats"] = splat_rates(rt, direct_table, ghosts, args.stride, args.samples,
                                repeats, baseline_rate(lensrt_json))
    report_splats(res["splats"])
    res["error"] = mc_errors(rt, direct_table, ghosts, args.error_pixels, args.error_samples,
                             max_n, args.rays)
    report_errors(res["error"])
    res["fitting"] = fit_times(ghosts, parse_ghost(args.fit_ghost), args.rays)
    report_fitting(res["fitting"])
    res["wall_seconds"] = time.perf_counter() - t_all
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "flares.json"
    path.write_text(json.dumps({"flares": res}, indent=2, allow_nan=False) + "\n")
    print(f"  -> {path} ({res['wall_seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
