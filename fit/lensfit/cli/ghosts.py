"""``lensfit ghosts``: a lens's ghosts ranked by their peak pixel, and with ``--fit``
their tables over the direct fit's domain.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import zlib
from pathlib import Path

import numpy as np

from lensfit.cli.common import _check_dask_args, _coated, _finite, _generated, _light_arg
from lensfit.common.errors import InputError, LensError
from lensfit.ghosts.enumerate import (
    DISPLAY_STOPS,
    black_level,
)


def _direct_fit(lens, args: argparse.Namespace, lens_arg: str):
    """For `lensfit ghosts --fit`: the lens folder, its direct table and domain, read
    before any work (the ghosts are fitted over the direct fit's domain)."""
    from lensfit.codegen.generate import lens_folder_name, read_fit_json
    from lensfit.sample.domain import Domain

    gen = _generated(args)
    folder = gen / lens_folder_name(lens)
    fit_file = folder / "fit.json"
    if not fit_file.is_file():
        raise InputError(f"{fit_file}: not found: the ghosts are fitted over the direct "
                         f"fit's domain; run `lensfit fit {lens_arg} --generated "
                         f"{gen}` first")
    direct, meta = read_fit_json(fit_file)
    try:
        domain = Domain.from_dict(meta["domain"])
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{fit_file}: key 'domain': {e}") from None
    return folder, direct, domain


def cmd_ghosts(args: argparse.Namespace) -> int:
    """The ghosts of each lens named, ranked by peak irradiance relative to the direct
    PSF's (lensfit.ghosts.enumerate): every check before the trace, the table or JSON
    after; with --fit every kept ghost of every lens fitted as one task on Dask
    (lensfit.ghosts.tasks)."""
    if args.count is not None and args.count < 1:
        raise InputError(f"--count {args.count}: expected a positive number of ghosts")
    for flag in ("add", "c", "glsl", "scheduler", "workers"):
        if getattr(args, flag) not in (None, False) and not args.fit:
            what = {"add": "adds fitted ghosts to a lens folder", "c": "writes fitted ghosts' C",
                    "glsl": "writes fitted ghosts' GLSL"}.get(flag, "runs the fits on Dask")
            raise InputError(f"--{flag}: {what}, so it needs --fit")
    _check_dask_args(args)
    if args.threshold is not None and not (math.isfinite(args.threshold)
                                           and args.threshold > 0):
        raise InputError(f"--threshold {args.threshold}: expected a positive relative peak")
    if not (math.isfinite(args.overexposure) and 0 <= args.overexposure <= 60):
        raise InputError(f"--overexposure {args.overexposure}: expected 0 to 60 stops of "
                         "the light's peak pixel over white")
    if not (math.isfinite(args.pixel_um) and 0.1 <= args.pixel_um <= 1000):
        raise InputError(f"--pixel-um {args.pixel_um}: expected a pixel pitch of 0.1 to "
                         "1000 um")
    if not 100 <= args.rays <= 10**7:
        raise InputError(f"--rays {args.rays}: expected 100 to 10^7 rays per wavelength")
    lens_args = list(args.lens)
    if args.all:
        if not args.fit:
            raise InputError("--all: fits the ghosts of every fitted lens, so it needs --fit")
        lens_args += _fitted_lenses(_generated(args, must_exist=True))
    if not lens_args:
        raise InputError("no lens: name one or more, or --all with --fit")
    plans = [_ghost_plan(lens_arg, args) for lens_arg in dict.fromkeys(lens_args)]
    if not args.fit:
        return 0
    return _fit_ghost_plans([p for p in plans if p is not None], args)


def _fitted_lenses(generated: Path) -> list[str]:
    """--all: every lens file of lensdb with a direct fit (fit.json) in ``generated``."""
    from lensfit.codegen.generate import lens_folder_name
    from lensfit.prescription import list_lenses, load_lens

    out = []
    for path in list_lenses():
        if (generated / lens_folder_name(load_lens(path)) / "fit.json").is_file():
            out.append(str(path))
    return out


def _ghost_plan(lens_arg: str, args: argparse.Namespace):
    """One lens: checks, enumeration and ranking; the listing (without --fit: every
    ghost, kept or not, even with none kept) or the plan of its fits (an error when
    none is kept)."""
    from lensfit.ghosts.enumerate import (
        check_light,
        enumerate_ghosts,
        mark_ghosts,
        none_kept_message,
        parse_ghost,
    )
    from lensfit.ghosts.tasks import LensPlan
    from lensfit.paraxial import stop_radius_for_f_number
    from lensfit.prescription import load_lens

    lens = _coated(load_lens(lens_arg), args)
    light = _light_arg(args.light)
    if args.f_number is not None:
        try:
            stop_radius_for_f_number(lens, args.f_number)
        except ValueError as e:
            raise LensError(str(e), file=lens.source_file, key="--f-number") from None
    check_light(lens, light, "--light")
    try:  # a light inside the lens's front is refused before the trace
        from lensfit.ghosts.enumerate import _launch

        if not args.distance > 0:
            raise InputError("expected a positive distance or inf")
        _launch(lens, light, 100, np.array([550.0]), args.distance)
    except InputError as e:
        raise InputError(f"--distance {args.distance:g}: {e}") from None
    pairs = ([parse_ghost(lens, name, "--ghost") for arg in args.ghost
              for name in arg.split(",")] if args.ghost else None)
    source = _direct_fit(lens, args, lens_arg) if args.fit else None
    ghosts = enumerate_ghosts(lens, f_number=args.f_number, light=light, pairs=pairs,
                              distance_mm=args.distance, rays=args.rays,
                              fine_rays=max(100, args.rays // 5),
                              pixel_mm=args.pixel_um * 1e-3)
    if not ghosts:
        raise InputError(f"{lens.source_file}: {none_kept_message([])}")
    # The listing shows every ghost, kept or not; only --fit needs one kept
    keep = mark_ghosts(ghosts, count=args.count, threshold=args.threshold,
                       overexposure=args.overexposure)
    why = none_kept_message(ghosts, args.threshold, args.overexposure)
    if source is not None and not keep:
        raise InputError(f"--fit: no ghost to fit: {why}; raise --overexposure, or give "
                         "--count or --ghost")
    info = ghosts[0].info
    if source is not None:
        folder, direct, domain = source
        fit_file = folder / "fit.json"
        return LensPlan(lens=lens, ghosts=[g for g in ghosts if g.kept], info=info,
                        light=light, folder=folder, direct=direct, domain=domain,
                        lens_bytes=Path(lens.source_file).read_bytes(),
                        fit_json_crc=zlib.crc32(fit_file.read_bytes()),
                        distance_mm=args.distance, rays=args.rays)
    if args.json:
        print(json.dumps({**info, "threshold": None if args.count else args.threshold,
                          "count": args.count, "overexposure_stops": args.overexposure,
                          "display_stops": DISPLAY_STOPS,
                          "ghosts": [{**g.to_dict(), "visibility_stops": _finite(
                                      g.visibility_stops(args.overexposure))}
                                     for g in ghosts]}, indent=2))
        return None
    lams = info["wavelengths_nm"]
    at = "/".join(f"{v:g}" for v in lams)
    print(f"{lens.name}  ({lens.source_file})")
    print(f"  f/{info['f_number']:.3g}, light ({light[0]:g}, {light[1]:g}) deg at "
          f"{args.distance:g} mm, "
          f"{info['rays_per_wavelength']} rays per wavelength, {len(ghosts)} ghosts "
          "(file's surface numbers i-j: reflect at j, then at i)")
    strehl = " ".join(f"{s:.3g}" for s in info["strehl_estimate"])
    print(f"  direct PSF peak: Airy x Strehl estimate {strehl} at {at} nm")
    print(f"  visible: a ghost's peak pixel ({args.pixel_um:g} um) at least "
          f"{black_level(args.overexposure):.3g} of the light's, which is "
          f"{args.overexposure:g} stops over white ({DISPLAY_STOPS:g} stops shown below "
          "white); 'stops' above that black level")
    kept = ("count " + str(args.count) if args.count else f"peak > {args.threshold:g}"
            if args.threshold is not None else "visible")
    print(f"  {'ghost':>7s} case  {'energy / direct at ' + at + ' nm':36s}"
          f"{'centre x,y mm':>17s} {'r mm':>7s} {'peak/PSF':>9s} {'pixel':>9s} "
          f"{'stops':>6s}  kept ({kept})")
    for g in ghosts:
        k = int(np.argmax(g.peak))  # footprint at the wavelength of the highest peak
        c = g.centre_mm[k]
        centre = "-" if c is None else f"{c[0]:+8.3f},{c[1]:+8.3f}"
        energy = " ".join(f"{e:9.2e}" for e in g.energy)
        print(f"  {g.name:>7s} {g.case:4s}  {energy:36s}{centre:>17s} {g.radius_mm[k]:7.3f} "
              f"{g.relative_peak:9.2e} {g.exposure_peak:9.2e} "
              f"{g.visibility_stops(args.overexposure):+6.1f}  {'yes' if g.kept else 'no'}")
    if not keep:
        print(f"  none kept: {why}")
    return None


def _fit_ghost_plans(plans: list, args: argparse.Namespace) -> int:
    """`lensfit ghosts LENS... --fit`: every kept ghost of every lens as one task on Dask
    (by default a LocalCluster; --workers 0 in this process), then each lens's
    <generated>/<lens folder>/ghosts/ written from the tasks' records. The folder then
    holds exactly the kept ghosts; with --add, the kept ones are added or replaced and the
    others fitted before stay. A failed ghost leaves its lens unwritten and the finished
    ghosts' records for the next run of the same command."""
    from lensfit.banks.engine import TaskError, run_tasks
    from lensfit.ghosts.tasks import fit_ghost_task, plan_jobs, write_lens

    jobs = [j for p in plans for j in plan_jobs(p, c=args.c, glsl=args.glsl)]
    failed = None
    try:
        run_tasks(fit_ghost_task, jobs, [j.pop("key") for j in jobs],
                  scheduler=args.scheduler, workers=args.workers, retries=0,
                  progress=sys.stderr.isatty(), label="ghost fits")
    except TaskError as e:
        failed = e
    for p in plans:
        try:
            lines = write_lens(p, c=args.c, glsl=args.glsl, add=args.add)
        except InputError:
            if failed is None:
                raise
            continue  # a ghost of this lens failed: its records stay for the next run
        print("\n".join(lines), flush=True)
    if failed is not None:
        print(f"lensfit: error: {failed}; run the same command again to fit only those",
              file=sys.stderr)
        return 1
    return 0
