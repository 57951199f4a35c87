"""Ray-tracer benchmark: ray-surface intersections per second (``make bench``).

Every figure comes with a baseline measured in the same run, because the machines are
shared and noisy: the same tracer called one ray at a time (what a scalar loop over
rays costs in Python). Ratios are what to compare between runs; absolute figures are
printed for context. Results go to ``<out>/trace.json`` and ``<out>/trace.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

from lensfit.prescription import load_lens, make_lens
from lensfit.prescription.model import Lens
from lensfit.trace.tracer import Rays, trace
from lensfit.trust.check import cell_label


def _bundle(lens: Lens, n: int, seed: int = 1) -> Rays:
    """Rays from a spread of field points through the front element, 380-780 nm."""
    rng = np.random.default_rng(seed)
    sd0 = lens.surfaces[0].semi_diameter_mm
    start = np.c_[rng.uniform(-0.3, 0.3, (n, 2)) * sd0, np.full(n, -20.0)]
    aim = np.c_[rng.uniform(-0.6, 0.6, (n, 2)) * sd0, np.zeros(n)]
    return Rays(start, aim - start, rng.uniform(380.0, 780.0, n))


def _best_of(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _intersections(out: Rays, n_surfaces: int) -> np.ndarray:
    """Intersections actually computed, per ray: a ray stops being traced where it fails."""
    return np.where(out.surface >= 0, out.surface + 1, n_surfaces)


def bench_lens(lens: Lens, n_rays: int, n_scalar: int, fresnel_loss: bool) -> dict[str, Any]:
    rays = _bundle(lens, n_rays)
    out = trace(lens, rays, fresnel_loss=fresnel_loss, clip=True)
    per_ray = _intersections(out, len(lens.surfaces))
    count = int(per_ray.sum())
    t_vec = _best_of(lambda: trace(lens, rays, fresnel_loss=fresnel_loss), 3)

    # Baseline: the same tracer, one ray per call
    singles = [
        Rays(rays.pos[i : i + 1], rays.dir[i : i + 1], rays.wavelength_nm[i : i + 1])
        for i in range(n_scalar)
    ]
    count_s = int(per_ray[:n_scalar].sum())  # the intersections of these very rays

    def scalar() -> None:
        for r in singles:
            trace(lens, r, fresnel_loss=fresnel_loss)

    t_s = _best_of(scalar, 2)
    vec = count / t_vec
    base = count_s / t_s
    return {
        "lens": lens.name,
        "surfaces": len(lens.surfaces),
        "rays": n_rays,
        "fresnel_and_coatings": fresnel_loss,
        "survivors": int(out.ok.sum()),
        "intersections_per_second": vec,
        "baseline_intersections_per_second": base,
        "speedup_vs_baseline": vec / base,
        "seconds": t_vec,
    }


def _shape_lens(spec: dict[str, Any]) -> Lens:
    """A stop and one surface of the given shape, for per-shape intersection figures."""
    return make_lens(
        [
            {
                "shape": "plane",
                "thickness": 5.0,
                "material": "air",
                "semi_diameter": 30.0,
                "stop": True,
            },
            {**spec, "thickness": 12.0, "material": "N-BK7", "semi_diameter": 30.0},
            {"shape": "plane", "thickness": 50.0, "material": "air", "semi_diameter": 30.0},
        ],
        name=f"{spec['shape']} singlet",
        file="<bench>",
    )


# The adaptive fit (the defaults), and the method before it: every term of the degrees
# that reach the target, 4000 field points x 128 stop points, no growth of the grid
FIT_METHODS = (("adaptive", {}),
               ("full", {"prune": False, "groups": 4000, "max_groups": 4000,
                         "max_aperture_points": 128, "field_degrees": (4, 6, 8, 10, 12)}))


def _lensrt_setup(tables: list[Path], rounds: int = 7) -> list[dict[str, float]] | None:
    """Seconds lensrt takes to load each of ``tables`` and to set up one render of it:
    create() and a first run() of one stop sample per wavelength (the demo's frame's
    window at 80 x 60 pixels, 16 wavelengths, wide open, the pixel centres: the
    per-wavelength specialisation and the per-pixel term search are nearly all of it;
    the box filter's sub-pixel points cost seconds per run whatever the table, so they
    are left out). The tables take turns, ``rounds`` times, and each keeps its best: on a
    shared machine a neighbour's load then falls on both alike. None without the library
    (LENSRT_LIBRARY or the build's)."""
    try:
        from lensrt_ctypes import Lensrt
        rt = Lensrt()
    except (ImportError, OSError):
        return None
    best = [{"load_seconds": math.inf, "setup_seconds": math.inf} for _ in tables]
    light = (-6.0, -4.0, 0.0, 1.0)  # distance 0: at infinity
    for _ in range(rounds):
        for table, b in zip(tables, best, strict=True):
            t0 = time.perf_counter()
            lens = rt.load(table)
            t1 = time.perf_counter()
            r = rt.create(lens, width=80, height=60, width_mm=0.3, height_mm=0.225,
                          center=tuple(rt.image_point(lens, light, 550.0)), lights=[light],
                          f_number=rt.info(lens)["f_number_min"], wavelengths=16,
                          pixel_filter="point")
            r.run(1)
            t2 = time.perf_counter()
            b["load_seconds"] = min(b["load_seconds"], t1 - t0)
            b["setup_seconds"] = min(b["setup_seconds"], t2 - t1)
    return best


def bench_fits(outdir: Path, lenses: list[str]) -> int:
    """Fit time, table size, lensrt set-up time and the worst cell of the PSF table
    against exactly traced rays (lensfit.trust.check) for each lens, with the default adaptive
    fit and, as the baseline measured in the same run, the method before it (every term
    of the degrees that reach the target on the fixed grid: FIT_METHODS); the committed
    table's figure beside them. The tables go to build/bench/fit-tables/ (for
    lensrt-bench --table); build/bench/fits.json and fits.md."""
    import shutil
    import tempfile

    from lensfit.codegen.generate import GENERATED_DIR, lens_folder_name, read_fit_json
    from lensfit.fitting import FitOptions
    from lensfit.pipeline.stage import run
    from lensfit.sample.domain import default_domain

    tables = outdir / "fit-tables"
    tables.mkdir(parents=True, exist_ok=True)
    rows = []
    for lens_id in lenses:
        lens = load_lens(lens_id)
        domain = default_domain(lens)
        row: dict[str, Any] = {"lens": lens.name, "id": lens_id}
        for method, extra in FIT_METHODS:
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                _, fig = run(lens, domain=domain, options=FitOptions(**extra),
                             generated_dir=Path(tmp), timing=False)
                total = time.perf_counter() - t0
                table = next((Path(tmp) / lens_folder_name(lens)).glob("*.table"))
                kept = tables / f"{lens_id}-{method}.table"
                shutil.copyfile(table, kept)
            terms = sum(o["terms"] for o in fig["outputs"])
            row[method] = {"fit_seconds": fig["fit_seconds"],
                           "psf_check_seconds": fig["psf_vs_exact"]["seconds"],
                           "total_seconds": total, "terms": terms,
                           "table_bytes": kept.stat().st_size,
                           "worst_psf_vs_exact": fig["psf_vs_exact"]["worst"]["relative_l2"],
                           "worst_cell": cell_label(fig["psf_vs_exact"]["worst"])}
            print(f"fit {lens_id} {method}: {row[method]}", flush=True)
        setups = _lensrt_setup([tables / f"{lens_id}-{m}.table" for m, _ in FIT_METHODS])
        for (method, _), setup in zip(FIT_METHODS, setups or [None] * len(FIT_METHODS),
                                      strict=True):
            row[method]["lensrt"] = setup
        committed = GENERATED_DIR / lens_folder_name(lens) / "fit.json"
        if committed.is_file():
            row["committed_worst_psf_vs_exact"] = read_fit_json(committed)[0].trust[
                "psf_vs_exact"]
        rows.append(row)
    (outdir / "fits.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = ["# Fits: time, table size, lensrt set-up and PSF against exactly traced rays",
             "",
             "The default adaptive fit (degrees grown until the held-out error leaves room, "
             "then the terms the target does not need cut) against the baseline measured in "
             "the same run: every term of the degrees that reach the target on a fixed grid "
             "of 4000 x 128 rays (the method before it), same domain. Fit seconds (sampling and "
             "fitting), and the whole `lensfit fit` with the PSF check; the worst cell of "
             "the PSF table (`lensfit.trust`, relative L2, target 1%); the .table's size; "
             "lensrt's load and set-up of an 80 x 60 frame wide open, 16 wavelengths, one "
             "sample at each pixel centre (the two tables in turn, 7 times, the best of each).", "",
             "| lens | method | fit s | total s | worst cell | terms | table KB | lensrt load "
             "s | lensrt set-up s |",
             "|---|---|---:|---:|---|---:|---:|---:|---:|"]
    for r in rows:
        for method, _ in FIT_METHODS:
            m = r[method]
            rt = m["lensrt"] or {"load_seconds": math.nan, "setup_seconds": math.nan}
            lines.append(
                f"| {r['id']} | {method} | {m['fit_seconds']:.1f} | {m['total_seconds']:.1f} | "
                f"{m['worst_psf_vs_exact']:.2%} ({m['worst_cell']}) | {m['terms']} | "
                f"{m['table_bytes'] / 1024:.0f} | {rt['load_seconds']:.3f} | "
                f"{rt['setup_seconds']:.3f} |")
    lines += ["", "Ratios, adaptive over full, same run:", "",
              "| lens | fit s | table size | lensrt set-up |", "|---|---:|---:|---:|"]
    for r in rows:
        a, f = r["adaptive"], r["full"]
        ra = (a["lensrt"] or {}).get("setup_seconds", math.nan)
        rf = (f["lensrt"] or {}).get("setup_seconds", math.nan)
        lines.append(f"| {r['id']} | {a['fit_seconds'] / f['fit_seconds']:.2f} | "
                     f"{a['table_bytes'] / f['table_bytes']:.3f} | {ra / rf:.3f} |")
    text = "\n".join(lines) + "\n"
    (outdir / "fits.md").write_text(text)
    print(text)
    missed = [r["id"] for r in rows if not r["adaptive"]["worst_psf_vs_exact"] <= 0.01]
    return 1 if missed else 0


def _committed_ghosts() -> list[tuple[str, list[str], tuple[float, float], float]]:
    """(lens id, kept ghosts, light, f-number) of every lens folder in generated/ with a
    ghosts.json (coated variants only)."""
    from lensfit.codegen.generate import GENERATED_DIR

    out = []
    for folder in sorted(GENERATED_DIR.iterdir()):
        report = folder / "ghosts" / "ghosts.json"
        if folder.name.endswith("-uncoated") or not report.is_file():
            continue
        entries = json.loads(report.read_text())["ghosts"]
        if entries:
            e = entries[0]
            out.append((folder.name.split("-")[0], [g["label"] for g in entries],
                        tuple(e["light_deg"]), float(e["f_number"])))
    return out


# Where `make bench` fits every visible ghost (lensfit.ghosts.enumerate, "Visibility",
# at the default overexposure): the committed flares' settings, 0001 on the axis too, and
# the Biotar 0009, whose uncoated glass makes the brightest ghosts of lensdb's fitted lenses
VISIBLE_SETTINGS = (("0001", 8.0, (-6.0, -4.0)), ("0001", 8.0, (0.0, 0.0)),
                    ("0009", 8.0, (-6.0, -4.0)), ("2004", 4.0, (-6.0, -4.0)),
                    ("2004", 16.0, (-6.0, -4.0)))


def _visible_ghosts() -> list[tuple[str, list[str], tuple[float, float], float]]:
    """(lens id, visible ghosts, light, f-number) at each of VISIBLE_SETTINGS."""
    from lensfit.ghosts.enumerate import enumerate_ghosts, mark_ghosts

    out = []
    for lens_id, fn, light in VISIBLE_SETTINGS:
        ghosts = enumerate_ghosts(load_lens(lens_id), f_number=fn, light=light)
        out.append((lens_id, [g.name for g in mark_ghosts(ghosts)], light, fn))
    return out


def bench_ghosts(outdir: Path, specs: list[str], light: tuple[float, float],
                 f_number: float) -> int:
    """Seconds per ghost of ``lensfit ghosts <lens> --fit`` (``fit_with_trust``: the
    sampling, the tensor and clip fits, the trust cells' exact PSFs), wall and CPU, in
    this process, and each table's PSF against exact ghost rays (target 3%), the
    committed figure beside it, with the reason where it misses. ``specs``: LENS:I-J,...
    (at ``light`` and ``f_number``); none: every kept ghost of the lenses with a
    ghosts.json in generated/, at their light and f-number, then every visible ghost at
    VISIBLE_SETTINGS. build/bench/ghosts.json and ghosts.md."""
    import hashlib

    from lensfit.cli.ghosts import _direct_fit
    from lensfit.codegen.generate import GENERATED_DIR, lens_folder_name
    from lensfit.codegen.table import write_table
    from lensfit.ghosts.enumerate import enumerate_ghosts, mark_ghosts, parse_ghost
    from lensfit.ghosts.tables import TRUST_TARGET, fit_with_trust, miss_reason

    jobs = ([(sp.split(":")[0], sp.split(":")[1].split(","), light, f_number)
             for sp in specs] if specs else _committed_ghosts() + _visible_ghosts())
    rows, done = [], set()
    for lens_id, labels, at, fn in jobs:
        labels = [la for la in labels if (lens_id, la, at, fn) not in done]
        done |= {(lens_id, la, at, fn) for la in labels}
        if not labels:
            continue
        lens = load_lens(lens_id)
        _, direct, domain = _direct_fit(lens, argparse.Namespace(generated=GENERATED_DIR),
                                        lens_id)
        report = GENERATED_DIR / lens_folder_name(lens) / "ghosts" / "ghosts.json"
        committed = ({g["label"]: g for g in json.loads(report.read_text())["ghosts"]}
                     if report.is_file() else {})
        pairs = [parse_ghost(lens, label, "--ghosts") for label in labels]
        # As the CLI enumerates (20000 rays per wavelength, the light at infinity)
        estimates = enumerate_ghosts(lens, f_number=fn, light=at, pairs=pairs, rays=20000,
                                     fine_rays=4000)
        mark_ghosts(estimates, count=len(estimates))  # sets each one's visibility
        for g in estimates:
            w0, c0 = time.perf_counter(), time.process_time()
            fit, table, cells = fit_with_trust(lens, g, direct, domain, at, fn)
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            digest = hashlib.sha256(write_table(table).encode()).hexdigest()[:16]
            worst = max(cells, key=lambda c: c.rel_l2)
            old = committed.get(g.name, {})
            rows.append({"lens": lens_id, "ghost": g.name, "side": fit.half.system,
                         "case": fit.half.case, "f_number": fn, "light_deg": list(at),
                         "wall_seconds": wall, "cpu_seconds": cpu, "fit_seconds": fit.seconds,
                         "exact_psf_seconds": sum(c.exact_seconds for c in cells),
                         "groups": fit.options.groups if fit.options else None,
                         "psf_vs_exact": worst.rel_l2,
                         "psf_vs_exact_cell": f"{worst.wavelength_nm:g} nm",
                         "psf_target": TRUST_TARGET,
                         "visibility_stops": (g.visibility_stops()
                                              if g.exposure_peak > 0 else None),
                         "miss_reason": miss_reason(fit, cells),
                         "committed_psf_vs_exact": old.get("psf_vs_exact"),
                         "committed_fit_seconds": old.get("fit_seconds"),
                         "table_sha256": digest})  # the same inputs: the same bytes
            print(f"ghost {lens_id} {g.name}: {wall:.1f} s wall, {cpu:.1f} s CPU, PSF vs "
                  f"exact {worst.rel_l2:.2%}", flush=True)
    (outdir / "ghosts.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = ["# Ghost fits: seconds per ghost and PSF against exact ghost rays", "",
             f"`fit_with_trust` per ghost in one process ({os.cpu_count()} CPUs; wall "
             "and CPU seconds: sampling, tensor and clip fits, trust cells); the table's "
             f"worst trust cell (target {TRUST_TARGET:.0%}), the committed table's beside it. "
             "The committed ghosts at their light and f-number, then every visible ghost "
             "(stops above a photograph's black level, the light 16 stops over white: "
             "lensfit.ghosts.enumerate, \"Visibility\") at each setting of VISIBLE_SETTINGS.",
             "", "| lens | f/N | light | ghost | side | stops | wall s | CPU s | exact PSFs s | "
             "groups | PSF vs exact | committed |",
             "|---|---:|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        c, v = r["committed_psf_vs_exact"], r["visibility_stops"]
        lines.append(f"| {r['lens']} | {r['f_number']:g} | {r['light_deg'][0]:g}, "
                     f"{r['light_deg'][1]:g} | {r['ghost']} | {r['side']} | "
                     f"{'-' if v is None else format(v, '+.1f')} | "
                     f"{r['wall_seconds']:.1f} | "
                     f"{r['cpu_seconds']:.1f} | {r['exact_psf_seconds']:.1f} | {r['groups']} | "
                     f"{r['psf_vs_exact']:.2%} ({r['psf_vs_exact_cell']}) | "
                     f"{'' if c is None else f'{c:.2%}'} |")
    missed = [r for r in rows if r["miss_reason"]]
    if missed:
        lines += ["", "Missing the target:", ""]
        lines += [f"* {r['lens']} {r['ghost']} (f/{r['f_number']:g}): {r['miss_reason']}"
                  for r in missed]
    text = "\n".join(lines) + "\n"
    (outdir / "ghosts.md").write_text(text)
    print(text)
    # A committed ghost that no longer meets the target fails the bench; a visible one
    # that misses is named above with its reason
    regressed = [r for r in rows if r["committed_psf_vs_exact"] is not None
                 and not r["psf_vs_exact"] <= TRUST_TARGET]
    return 1 if regressed else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="build/bench")
    ap.add_argument("--rays", type=int, default=400_000)
    ap.add_argument("--scalar-rays", type=int, default=300)
    ap.add_argument("--fits", nargs="*", metavar="LENS", default=None,
                    help="instead: fit time and worst PSF cell of these lenses (none "
                         "named: every lens in generated/)")
    ap.add_argument("--ghosts", nargs="*", metavar="LENS:I-J,...", default=None,
                    help="instead: seconds per ghost fit and its PSF against exact ghost "
                         "rays (none named: the kept ghosts of every lens with a "
                         "ghosts.json in generated/)")
    ap.add_argument("--light", default="-6,-4", help="with --ghosts LENS:I-J: the light's "
                    "field angles X,Y in degrees")
    ap.add_argument("--f-number", type=float, default=8.0,
                    help="with --ghosts LENS:I-J: the f-number")
    args = ap.parse_args(argv)
    outdir = Path(args.out)
    outdir.mkdir(parents=True, exist_ok=True)
    if args.ghosts is not None:
        x, y = (float(v) for v in args.light.split(","))
        return bench_ghosts(outdir, args.ghosts, (x, y), args.f_number)
    if args.fits is not None:
        from lensfit.codegen.generate import GENERATED_DIR

        # One row per lens: an uncoated variant's folder (<lens>-uncoated) is the same id
        ids = args.fits or sorted({p.name.split("-")[0] for p in GENERATED_DIR.iterdir()
                                   if (p / "fit.json").is_file()})
        return bench_fits(outdir, ids)

    results: list[dict[str, Any]] = []
    for lens_id in ("0001", "0014", "2004"):
        lens = load_lens(lens_id)
        for fl in (False, True):
            results.append(bench_lens(lens, args.rays, args.scalar_rays, fl))
    shapes = [
        {"shape": "sphere", "radius": 60.0},
        {"shape": "asphere", "radius": 60.0, "conic": -0.8, "aspheric": [1e-6, -2e-10, 1e-14]},
        {"shape": "cylinder-x", "radius": 60.0},
    ]
    for spec in shapes:
        results.append(bench_lens(_shape_lens(spec), args.rays, args.scalar_rays, False))

    meta = {
        "machine": platform.machine(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "cpus": os.cpu_count(),
        "baseline": "the same tracer called one ray at a time",
    }
    (outdir / "trace.json").write_text(json.dumps({"meta": meta, "results": results}, indent=2))
    lines = [
        "# Ray tracer benchmark",
        "",
        f"numpy {meta['numpy']}, {meta['cpus']} CPUs. Baseline: {meta['baseline']}, "
        "measured in the same run.",
        "",
        "| lens | surfaces | Fresnel + coatings | intersections/s | baseline/s | ratio |",
        "|---|---:|:---:|---:|---:|---:|",
    ]
    for r in results:
        lines.append(
            f"| {r['lens']} | {r['surfaces']} | {'yes' if r['fresnel_and_coatings'] else 'no'} "
            f"| {r['intersections_per_second']:.3g} | {r['baseline_intersections_per_second']:.3g}"
            f" | {r['speedup_vs_baseline']:.0f}x |"
        )
    text = "\n".join(lines) + "\n"
    (outdir / "trace.md").write_text(text)
    print(text)
    print(f"wrote {outdir / 'trace.json'} and {outdir / 'trace.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
