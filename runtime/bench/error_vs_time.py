"""Error against run time of lensrt's samplers, and the `make bench` summary.

    python runtime/bench/error_vs_time.py --out build/bench [--lensrt-json build/bench/lensrt.json]

For the default lens (0001) and the scene of lensrt-bench (light at field (-6, -4) deg at
infinity, sensor shift 0.2 mm, window centred on the light's image point), at f/8 and f/2,
64 x 64 pixels and 4 wavelengths: renders with the random, stratified and sobol samplers
and 2^8 .. 2^16 samples per wavelength, each a fresh render, several seeds each. For each
the run time (lensrt_render_get_stats: seconds spent in run()) and the relative L2 error
of the spectral image against a converged reference:

    error = ||I - I_ref||_2 / ||I_ref||_2   over every pixel and wavelength

The reference is the mean of two independent sobol renders (other seeds) of 2^19 samples
per wavelength each, in the default precision. Its own error is measured, not assumed:
with A and B independent, ||A - B|| / 2 estimates ||(A + B) / 2 - I||. The default
precision (float splat kernel, pruned per-pixel terms) is checked against the all-double
path on the same samples (same sampler and seed, so the difference is the precision's
alone, without Monte Carlo noise): that is the floor below which the reference could not
tell errors apart. Both floors are drawn on the plot.

Writes into --out: error_vs_time.json, error_vs_time.md, error_vs_time.png; then merges
lensrt-bench's JSON (--lensrt-json) with these numbers into results.json and summary.md
(--merge-only does just that from the JSON files already there).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT / "runtime" / "python"))

from lensrt_ctypes import Lensrt  # noqa: E402

TABLE = ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table"
SAMPLERS = ("random", "stratified", "sobol")
FIELD = (-6.0, -4.0)
FOCUS_MM = 0.2
# Window per f-number: the PSF (defocus blur and Airy core) with a margin; mm
WINDOW_MM = {2.0: 0.1, 8.0: 0.04}


def rel_l2(img: np.ndarray, ref: np.ndarray) -> float:
    return float(np.linalg.norm((img - ref).ravel()) / np.linalg.norm(ref.ravel()))


def render(rt: Lensrt, lens: Any, scene: dict[str, Any], samples: int, sampler: str, seed: int,
           precision: str = "default") -> tuple[np.ndarray, float]:
    r = rt.create(lens, sampler=sampler, seed=seed, precision=precision, **scene)
    r.run(samples)
    img = r.image().astype(np.float64)
    return img, float(r.stats().seconds)


def slope(samples: list[int], errors: list[float]) -> float:
    """Least-squares slope of log(error) against log(samples)."""
    x, y = np.log(np.asarray(samples, float)), np.log(np.asarray(errors, float))
    return float(np.polyfit(x, y, 1)[0])


def study(rt: Lensrt, lens: Any, f_number: float, args: argparse.Namespace) -> dict[str, Any]:
    center = rt.image_point(lens, FIELD, 580.0, FOCUS_MM)
    width_mm = args.window_mm or WINDOW_MM.get(f_number, 0.1)
    scene: dict[str, Any] = dict(pixel_filter="point",
                                 width=args.pixels, height=args.pixels, width_mm=width_mm,
                                 center=center, focus_offset_mm=FOCUS_MM, f_number=f_number,
                                 lights=[FIELD], wavelengths=args.wavelengths,
                                 estimator=args.estimator)
    t0 = time.perf_counter()
    ref_n = 1 << args.reference_log2
    a, ta = render(rt, lens, scene, ref_n, "sobol", 1001)
    b, tb = render(rt, lens, scene, ref_n, "sobol", 1002)
    ref = 0.5 * (a + b)
    ref_error = 0.5 * rel_l2(a, b)  # estimate of ||ref - I|| / ||I||
    print(f"f/{f_number:g}: reference 2 x 2^{args.reference_log2} sobol samples per wavelength "
          f"in {ta + tb:.1f} s, its own relative L2 error ~ {ref_error:.2e}", flush=True)
    # The default precision against all-double on the very same samples
    pn = 1 << args.precision_log2
    d_def, t_def = render(rt, lens, scene, pn, "sobol", 7)
    d_dbl, t_dbl = render(rt, lens, scene, pn, "sobol", 7, precision="double")
    precision_error = rel_l2(d_def, d_dbl)
    print(f"f/{f_number:g}: default precision vs double on the same 2^{args.precision_log2} "
          f"samples: relative L2 {precision_error:.2e} ({t_def:.2f} s vs {t_dbl:.2f} s)",
          flush=True)
    rows: list[dict[str, Any]] = []
    for k in range(args.min_log2, args.max_log2 + 1):
        n = 1 << k
        errs: dict[str, list[float]] = {s: [] for s in SAMPLERS}
        secs: dict[str, list[float]] = {s: [] for s in SAMPLERS}
        # Samplers interleaved, so that the machine's changing load falls on all alike
        for seed in range(1, args.seeds + 1):
            for sampler in SAMPLERS:
                img, sec = render(rt, lens, scene, n, sampler, seed)
                errs[sampler].append(rel_l2(img, ref))
                secs[sampler].append(sec)
        for sampler in SAMPLERS:
            e, t = errs[sampler], secs[sampler]
            row = dict(sampler=sampler, samples=n, seconds=float(np.median(t)),
                       seconds_all=t, error=float(np.mean(e)), error_min=float(np.min(e)),
                       error_max=float(np.max(e)), seeds=args.seeds)
            rows.append(row)
            print(f"  f/{f_number:g} {sampler:10s} 2^{k:<2d} {row['seconds']:8.4f} s  "
                  f"error {row['error']:.3e} [{row['error_min']:.2e}, {row['error_max']:.2e}]",
                  flush=True)
    slopes = {}
    for sampler in SAMPLERS:
        pts = [(r["samples"], r["error"]) for r in rows if r["sampler"] == sampler]
        if sum(n >= 1 << 10 for n, _ in pts) >= 2:
            pts = [(n, e) for n, e in pts if n >= 1 << 10]  # past the stratified partial blocks
        slopes[sampler] = slope([p[0] for p in pts], [p[1] for p in pts])
    return dict(f_number=f_number, pixels=[args.pixels, args.pixels], window_mm=width_mm,
                center_mm=list(center), wavelengths=args.wavelengths,
                reference=dict(sampler="sobol", samples_per_wavelength=2 * ref_n,
                               renders=2, seeds=[1001, 1002], seconds=ta + tb,
                               relative_l2_error_estimate=ref_error),
                precision_check=dict(samples_per_wavelength=pn, sampler="sobol", seed=7,
                                     relative_l2_default_vs_double=precision_error,
                                     seconds_default=t_def, seconds_double=t_dbl),
                slopes_log_error_vs_log_samples=slopes, rows=rows,
                wall_seconds=time.perf_counter() - t0)


def plot(studies: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(studies), figsize=(6.2 * len(studies), 4.8), squeeze=False)
    for ax, st in zip(axes[0], studies, strict=True):
        for sampler, marker in zip(SAMPLERS, "osD", strict=True):
            rs = [r for r in st["rows"] if r["sampler"] == sampler]
            sl = st["slopes_log_error_vs_log_samples"][sampler]
            ax.loglog([r["seconds"] for r in rs], [r["error"] for r in rs], marker=marker,
                      label=f"{sampler} (error ~ N^{sl:.2f})")
        ax.axhline(st["reference"]["relative_l2_error_estimate"], color="gray", ls="--", lw=1,
                   label="reference's own error (estimate)")
        ax.axhline(st["precision_check"]["relative_l2_default_vs_double"], color="gray", ls=":",
                   lw=1, label="default precision vs double")
        ax.set_xlabel("seconds in lensrt_render_run (median over seeds)")
        ax.set_ylabel("relative L2 error")
        ax.set_title(f"lens 0001, f/{st['f_number']:g}, {st['pixels'][0]}x{st['pixels'][1]} px, "
                     f"{st['wavelengths']} wavelengths")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    counts = sorted({r["samples"] for r in studies[0]["rows"]})
    fig.suptitle(f"Error against run time: 2^{int(math.log2(counts[0]))} .. "
                 f"2^{int(math.log2(counts[-1]))} samples per wavelength N, error: mean over "
                 f"{studies[0]['rows'][0]['seeds']} seeds")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def error_table(st: dict[str, Any]) -> list[str]:
    lines = [f"#### f/{st['f_number']:g}: {st['pixels'][0]}x{st['pixels'][1]} pixels over "
             f"{st['window_mm']:g} mm, {st['wavelengths']} wavelengths",
             "",
             "| samples / wavelength | "
             + " | ".join(f"{s} error | {s} s" for s in SAMPLERS) + " |",
             "|---:|" + "---:|---:|" * len(SAMPLERS)]
    counts = sorted({r["samples"] for r in st["rows"]})
    for n in counts:
        cells = []
        for s in SAMPLERS:
            r = next(r for r in st["rows"] if r["sampler"] == s and r["samples"] == n)
            cells += [f"{r['error']:.2e}", f"{r['seconds']:.3f}"]
        lines.append(f"| 2^{int(math.log2(n))} | " + " | ".join(cells) + " |")
    sl = st["slopes_log_error_vs_log_samples"]
    ref, prec = st["reference"], st["precision_check"]
    counts_all = [r["samples"] for r in st["rows"]]
    fit_from = min(n for n in counts_all if n >= 1 << 10) if sum(
        n >= 1 << 10 for n in set(counts_all)) >= 2 else min(counts_all)
    fit_to = max(r["samples"] for r in st["rows"])
    lines += ["",
              f"Slope of log error against log samples (2^{int(math.log2(fit_from))} .. "
              f"2^{int(math.log2(fit_to))}): "
              + ", ".join(f"{s} {sl[s]:.2f}" for s in SAMPLERS) + ".",
              f"Reference: mean of 2 sobol renders of {ref['samples_per_wavelength'] // 2} "
              f"samples per wavelength ({ref['seconds']:.1f} s); its own relative L2 error, "
              f"estimated from their difference: {ref['relative_l2_error_estimate']:.1e}. "
              "Default precision against all-double on the same "
              f"{prec['samples_per_wavelength']} samples: relative L2 "
              f"{prec['relative_l2_default_vs_double']:.1e}.",
              ""]
    return lines


def git_state() -> dict[str, Any]:
    def run(*cmd: str) -> str:
        try:
            return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True,
                                  check=True).stdout.strip()
        except (OSError, subprocess.CalledProcessError):
            return ""
    return dict(commit=run("git", "rev-parse", "HEAD"),
                dirty=bool(run("git", "status", "--porcelain", "--untracked-files=no")))


def gl_table(gl: dict | None) -> list[str]:
    """The GL path's splats per second (same run, same lens and scene) as markdown."""
    if not gl:
        return []
    if "skipped" in gl:
        return ["## GL compute path", "", f"Not measured: {gl['skipped']}", ""]
    md = ["## GL compute path", "",
          f"`GL_RENDERER` {gl['renderer']}, `GL_VERSION` {gl['version']} ({gl['platform']}"
          + (", a software renderer" if gl["software"] else "") + "). Same lens, light and "
          f"window; {gl['rendered_resolution'][0]}x{gl['rendered_resolution'][1]} pixels "
          f"(one per {gl['stride']}x{gl['stride']} block), {gl['samples']} samples per "
          f"wavelength, timed on {gl['timing']}.", "",
          "| f/N | GL splats/s | seconds | set-up seconds (create, compile, warm-up run) "
          "| vs baseline | vs CPU path |",
          "|---:|---:|---:|---:|---:|---:|"]
    for r in gl["results"]:
        cpu = "" if r.get("ratio_vs_cpu") is None else f"{r['ratio_vs_cpu']:.3g}x"
        md.append(f"| {r['f_number']:g} | {r['splats_per_second']:.3g} | {r['seconds']:.2f} | "
                  f"{r['setup_seconds']:.2f} | {r['ratio_vs_baseline']:.3g}x | {cpu} |")
    return md + [""]


def summarise(out: Path, lensrt_json: Path) -> int:
    evt = json.loads((out / "error_vs_time.json").read_text())
    if not lensrt_json.exists():
        print(f"error_vs_time: {lensrt_json}: not found; run lensrt-bench --json {lensrt_json} "
              "first (results.json and summary.md need both parts)", file=sys.stderr)
        return 1
    lb = json.loads(lensrt_json.read_text())
    results = dict(
        splats_per_second=lb["splats_per_second"],
        baseline_splats_per_second=lb["baseline_splats_per_second"],
        threads=lb["threads"], baseline_threads=lb["baseline_threads"], ratio=lb["ratio"],
        f_number=lb["f_number"], resolution=lb["resolution"], wavelengths=lb["wavelengths"],
        samples=lb["samples"], cpu=lb["cpu"], date=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        git=git_state(), lensrt_bench=lb, error_vs_time=evt)
    (out / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    stride = int(lb.get("stride", 1))
    rw, rh = lb.get("rendered_resolution", lb["resolution"])
    band = "" if stride == 1 else (
        f" (measured on {rw}x{rh} pixels over the same window, one per {stride}x{stride} block of "
        "the frame: lensrt's per-pixel work depends on the window, not on the pixel pitch, so "
        f"the splats per second are the frame's, in 1/{stride * stride} of the time)")
    counts = sorted({r["samples"] for r in evt["studies"][0]["rows"]})
    lo, hi = int(math.log2(counts[0])), int(math.log2(counts[-1]))
    md = ["# lensrt benchmark", "",
          f"{lb['date']}, {lb['cpu']}, {lb['threads']} threads, git {results['git']['commit'][:12]}"
          + (" (uncommitted changes)" if results["git"]["dirty"] else "") + ".",
          "These machines are shared and noisy: quote the ratios, which compare with a baseline "
          "measured in the same run; absolute figures are context.", "",
          "## Splats per second", "",
          f"Lens 0001 ({lb['lens']}), light at field ({lb['light_field_deg'][0]:g}, "
          f"{lb['light_field_deg'][1]:g}) deg at infinity, sensor shift "
          f"{lb['focus_offset_mm']:g} mm, "
          f"{lb['resolution'][0]}x{lb['resolution'][1]} pixels over {lb['window_mm'][0]:g} x "
          f"{lb['window_mm'][1]:g} mm centred on the light's image{band}, {lb['wavelengths']} "
          f"wavelengths, {lb['samples']} samples per wavelength. A splat is one aperture sample "
          "evaluated at one pixel (one wavelength); clipping at both pupils and transmittance are "
          "evaluated inside.", "",
          "Baseline: the paper's algorithm as a plain scalar double loop over the generated "
          "Horner code of the same lens (P_o once per sample, P_s per splat, housing clips, libm "
          "cos/sin), "
          f"over {lb['baseline']['pixels']} pixels spread over the frame, with OpenMP over pixels "
          f"at the same thread count as lensrt ({lb['baseline_threads']}), run right before and "
          f"right after each of {lb['repeats']} lensrt renders per f-number: the ratio is the "
          "median over the renders of lensrt against the baseline that bracketed it; splats per "
          "second are medians too.", "",
          "| f/N | lensrt splats/s | seconds per render | phase terms | clip | tau | baseline "
          f"splats/s ({lb['baseline_threads']} threads) | ratio | ratios of the renders | "
          "baseline 1 thread | lensrt vs 1 thread |",
          "|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|"]
    for f, p in lb["per_f_number"].items():
        single = p["splats_per_second"] / p["baseline_single_thread_splats_per_second"]
        reps = p["repetitions"]
        md.append(f"| {f} | {p['splats_per_second']:.3g} | {np.median(reps['seconds']):.1f} | "
                  f"{p['phase_terms']:.2f} | {p['clip_fraction']:.2f} | {p['tau_fraction']:.2f} | "
                  f"{p['baseline_splats_per_second']:.3g} | **{p['ratio']:.0f}x** | "
                  + ", ".join(f"{x:.0f}" for x in reps["ratio"]) + " | "
                  f"{p['baseline_single_thread_splats_per_second']:.3g} | {single:.0f}x |")
    if lb["splats_per_second"] is None:
        del md[-2:]  # no rows: drop the table's header
        md += ["", "The CPU path was not measured in this run (`lensrt-bench --device gl`).", ""]
    else:
        md += ["",
           f"**f/{lb['f_number']:g}: {lb['splats_per_second']:.3g} splats/s, "
           f"{lb['ratio']:.0f}x the "
           f"scalar double baseline ({lb['baseline_splats_per_second']:.3g} splats/s, "
           f"{lb['baseline_threads']} threads).** The target is 1e9 splats/s on this machine; the "
           "paper's GPU did about 1.1e9 (2.65 million samples per pixel per hour at 1440x1080).",
           "",
           "phase terms: phase terms per splat after per-pixel pruning; clip, tau: fractions of "
           "pixels that needed the inner-pupil clip or a varying transmittance (of the last "
           "render). Fraction of the baseline's splats clipped at a housing: "
           + ", ".join(f"f/{f} {100 * p['baseline_clipped_fraction']:.2g}%"
                       for f, p in lb["per_f_number"].items()) + ".", ""]
    md += gl_table(lb.get("gl"))
    md += ["## Error against run time", "",
           "Relative L2 error of the spectral image against a converged reference, for fresh "
           f"renders of 2^{lo} .. 2^{hi} samples per wavelength with each sampler (error: mean "
           f"over {evt['studies'][0]['rows'][0]['seeds']} seeds), against the seconds lensrt spent "
           "(median over the seeds; the samplers run interleaved). "
           f"Estimator: {evt['estimator']}. Plot: `error_vs_time.png`.", ""]
    for st in evt["studies"]:
        md += error_table(st)
    md += ["![error against run time](error_vs_time.png)", ""]
    (out / "summary.md").write_text("\n".join(md))
    print(f"wrote {out / 'results.json'} and {out / 'summary.md'}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "build" / "bench")
    ap.add_argument("--lensrt-json", type=Path, default=None,
                    help="lensrt-bench's JSON (default: OUT/lensrt.json)")
    ap.add_argument("--library", default=None, help="liblensrt.so (default: build/runtime)")
    ap.add_argument("--f-numbers", default="8,2")
    ap.add_argument("--pixels", type=int, default=64)
    ap.add_argument("--window-mm", type=float, default=0.0,
                    help="window width in mm (default: 0.04 at f/8, 0.1 at f/2)")
    ap.add_argument("--wavelengths", type=int, default=4)
    ap.add_argument("--min-log2", type=int, default=8)
    ap.add_argument("--max-log2", type=int, default=16)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--reference-log2", type=int, default=19,
                    help="each of the two reference renders has 2^this samples per wavelength")
    ap.add_argument("--precision-log2", type=int, default=14)
    ap.add_argument("--estimator", choices=("paper", "unbiased"), default="paper")
    ap.add_argument("--merge-only", action="store_true",
                    help="only merge OUT/error_vs_time.json and the lensrt JSON")
    args = ap.parse_args()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    lensrt_json = args.lensrt_json or out / "lensrt.json"
    if not args.merge_only:
        t0 = time.perf_counter()
        rt = Lensrt(args.library)
        lens = rt.load(TABLE)
        studies = [study(rt, lens, float(f), args) for f in args.f_numbers.split(",")]
        evt = dict(lens=str(TABLE.relative_to(ROOT)), field_deg=list(FIELD),
                   focus_offset_mm=FOCUS_MM, estimator=args.estimator,
                   error="||I - I_ref||_2 / ||I_ref||_2 over pixels and wavelengths",
                   python=platform.python_version(), studies=studies,
                   wall_seconds=time.perf_counter() - t0)
        (out / "error_vs_time.json").write_text(json.dumps(evt, indent=2) + "\n")
        plot(studies, out / "error_vs_time.png")
        md = ["# Error against run time (lensrt, lens 0001)", ""]
        for st in studies:
            md += error_table(st)
        md += ["![error against run time](error_vs_time.png)", ""]
        (out / "error_vs_time.md").write_text("\n".join(md))
        print(f"wrote {out / 'error_vs_time.json'}, .md and .png in {evt['wall_seconds']:.0f} s")
    return summarise(out, lensrt_json)


if __name__ == "__main__":
    sys.exit(main())
