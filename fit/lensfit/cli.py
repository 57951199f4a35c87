"""The ``lensfit`` command line.

    lensfit list                         lenses in lensdb with their paraxial focal length
    lensfit info LENS [--json]           paraxial table (--wavelength NM: not the d line)
    lensfit ghosts LENS [--json]         ghosts ranked by peak pixel, the visible ones kept
                                         (--fit: fitted, with the reason where one misses)
    lensfit draw LENS -o FILE.png        cross-section with ray fans
    lensfit import FILE [-o OUT]         convert a Zemax .zmx, an Optiland JSON or a lentil
                                         JSON lens table to lensfit's TOML
    lensfit export LENS -o OUT.zmx       write a lens as a Zemax .zmx file
    lensfit check [LENS ...]             validate prescriptions and their EFL
    lensfit fit LENS                     fit P_o and P_s, write generated/<lens>/ and a report
    lensfit regenerate LENS              rewrite generated/<lens>/ from its fit.json (no fit)
    lensfit upgrade-table FILE ...       rewrite version-3/4 tables as version 5 (probe lines
                                         added from their own polynomials, no fit)
    lensfit report LENS [--json]         fit and write the fit-error report only
    lensfit scene LENS SCENE.toml        specialise generated/<lens>/ for one scene

LENS is a lensdb id (``0001``), a file stem in lensdb, or a path to a TOML file.
Where lensdb and generated/ are (lensfit.data_folder): ``--generated DIR`` on the commands
that read or write generated folders (fit, regenerate, scene, ghosts, bank), else
$LENSFIT_GENERATED / $LENSFIT_LENSDB, else the checkout's folders when lensfit runs from
one, else ``generated/`` and ``lensdb/`` in the current directory.
Errors go to stderr as one line naming file, surface and key; the exit code is 2.
``lensfit fit`` and ``lensfit report`` exit 3 (EXIT_MISS) when the fit's PSF against
exactly traced rays misses its target: the table and report are written and flagged all
the same; ``--allow-miss`` makes that exit 0. A fit whose output cannot come within ten
times its target at the highest degree (lensfit.fitting.tensor.OutOfReach) is refused
with exit 2 and writes nothing.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import zlib
from pathlib import Path

import numpy as np

from lensfit.atomic import check_target, write_atomic, write_files
from lensfit.errors import InputError, LensError
from lensfit.ghosts.enumerate import (
    DEFAULT_OVEREXPOSURE_STOPS,
    DEFAULT_PIXEL_MM,
    DISPLAY_STOPS,
    black_level,
)
from lensfit.glass import UnknownGlassError

# `lensfit fit` / `lensfit report`: the fit missed its PSF target (written and flagged)
EXIT_MISS = 3

# lensfit draw --rays: rays per fan (a fan of 10^8 rays grew to 19 GB; 1000 rays are
# already finer than the 130 dpi drawing can show)
MAX_RAYS = 1000


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _check_folder(path: str | Path, option: str) -> Path:
    """An output folder that can be created or written, checked before any work."""
    p = Path(path)
    if str(path) == "":
        raise InputError(f"{option}: expected a folder, found an empty name")
    if p.exists() and not p.is_dir():
        raise InputError(f"{option} {p}: is a file, expected a folder")
    base = _nearest_existing(p)
    if not base.is_dir():
        raise InputError(f"{option} {p}: {base} is a file, not a folder")
    if not os.access(base, os.W_OK | os.X_OK):
        raise InputError(f"{option} {p}: {base} is not writable")
    _probe_folder(base, f"{option} {p}")
    return p


def _probe_folder(base: Path, what: str) -> None:
    """Create and remove a folder in ``base``: access() says yes to root anywhere, and
    /proc or a read-only mount refuse only when tried."""
    import tempfile

    try:
        os.rmdir(tempfile.mkdtemp(prefix=".lensfit-probe-", dir=base))
    except OSError as e:
        raise InputError(f"{what}: cannot write in {base}: {e.strerror or e}") from None


def _check_file(path: str | Path, option: str) -> Path:
    """An output file whose folder exists and is writable, checked before any work."""
    p = Path(path)
    if str(path) == "" or p.is_dir():
        raise InputError(f"{option} {str(path)!r}: expected a file name, found "
                         f"{'a folder' if str(path) else 'an empty name'}")
    parent = p.absolute().parent
    if not parent.is_dir():
        raise InputError(f"{option} {p}: the folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{option} {p}: the folder {parent} is not writable")
    # A link or special file is refused, and a temporary must be creatable (lensfit.atomic)
    return check_target(p, option)


def _fmt(v: float | None, unit: str = "", digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "inf"
    return f"{v:.{digits}f}{(' ' + unit) if unit else ''}"


# The field-sign convention, printed by `lensfit info` (README.md: Conventions)
CONVENTION_NOTE = ("conventions: z from surface 0's vertex towards the sensor; a light at "
                   "field +θ has a rising chief ray (dy/dz > 0) and is imaged at +y, as in "
                   "Zemax and Code V (README.md, Conventions)")


def _info_wavelengths(texts: list[str] | None, lens) -> list[float]:
    """``--wavelength NM`` (repeatable, or a comma list) checked against the lens's
    glasses before any work; none given: the d line."""
    from lensfit.paraxial import D_LINE_NM
    from lensfit.trace.tracer import _check_wavelengths

    if not texts:
        return [D_LINE_NM]
    out = []
    for text in texts:
        for part in text.split(","):
            try:
                lam = float(part)
            except ValueError:
                lam = math.nan
            if not (math.isfinite(lam) and lam > 0):
                raise InputError(f"--wavelength {text!r}: expected positive finite "
                                 f"wavelengths in nm, found {part.strip()!r}")
            try:  # the glasses' published ranges, as the tracer refuses them
                _check_wavelengths(lens, np.array([lam]))
            except ValueError as e:
                raise InputError(f"--wavelength {lam:g}: {e}") from None
            out.append(lam)
    return out


def _info_rows(t: dict) -> list[tuple[str, str]]:
    ep, xp = t["entrance_pupil"], t["exit_pupil"]
    on_surface = ", on the refracting surface" if t.get("stop_on_refracting_surface") else ""
    rows = [
        ("surfaces", f"{t['surfaces']} (stop at surface {t['stop_index']}{on_surface})"),
        ("EFL", f"{_fmt(t['efl_mm'], 'mm')}   (at {t['wavelength_nm']:.2f} nm)"),
    ]
    if t["anamorphic"]:
        for m, d in t["meridians"].items():
            efl, bfd = _fmt(d["efl_mm"], "mm"), _fmt(d["bfd_mm"], "mm")
            rows.append((f"  {m}-z meridian", f"EFL {efl}  BFD {bfd}"))
        rows.append(("  squeeze EFLy/EFLx", _fmt(t["anamorphic_squeeze"], "", 4)))
    widest = _fmt(t["stop_radius_max_mm"], "mm")
    rows += [
        ("BFD", _fmt(t["bfd_mm"], "mm")),
        ("FFD", _fmt(t["ffd_mm"], "mm")),
        ("stop radius", f"{_fmt(t['stop_radius_mm'], 'mm')}  (widest {widest})"),
        ("f-number", f"f/{_fmt(t['f_number'], '', 3)}"),
        (
            "entrance pupil",
            f"z = {_fmt(ep['position_mm'], 'mm')}, r = {_fmt(ep['radius_mm'], 'mm')}",
        ),
        ("exit pupil", f"z = {_fmt(xp['position_mm'], 'mm')}, r = {_fmt(xp['radius_mm'], 'mm')}"),
        ("total track", f"{_fmt(t['total_track_mm'], 'mm')} (first vertex to sensor)"),
        ("sensor defocus", f"{_fmt(t['sensor_defocus_mm'], 'mm')} (sensor minus paraxial focus)"),
    ]
    return rows


def cmd_info(args: argparse.Namespace) -> int:
    from lensfit.paraxial import stop_radius_for_f_number, table
    from lensfit.prescription import load_lens

    lens = _glass_policy(load_lens(args.lens), args)
    wavelengths = _info_wavelengths(args.wavelength, lens)
    stop = None
    if args.f_number is not None:  # the stop of f/N at the d line, at every wavelength
        try:
            stop = stop_radius_for_f_number(lens, args.f_number)
        except ValueError as e:
            raise LensError(str(e), file=lens.source_file, key="--f-number") from None
    tables = [table(lens, stop_radius_mm=stop, wavelength_nm=lam) for lam in wavelengths]
    if args.json:  # one object, or a list of them for several wavelengths
        for t in tables:
            t["semi_diameters"] = semi_diameter_kinds(lens)
        print(json.dumps(tables[0] if len(tables) == 1 else tables, indent=2))
        return 0
    print(f"{lens.name}  ({lens.source_file})")
    print(f"  {CONVENTION_NOTE}")
    for i, t in enumerate(tables):
        if i:
            print()
        for label, value in _info_rows(t):
            print(f"  {label:20s}{value}")
    for i, row in enumerate(_semi_diameter_rows(lens)):
        print(f"  {'semi-diameters' if i == 0 else '':20s}{row}")
    _print_glass_ranges(lens, getattr(args, "wavelength", None))
    _print_default_domain(lens)
    return 0


def semi_diameter_kinds(lens) -> list[dict]:
    """What each surface's semi-diameter is, in the lens file's numbering: ``stop`` (the
    aperture stop's, the widest it opens), ``fixed`` (an aperture: rays beyond it are
    blocked, as the design has them) or ``automatic`` (a housing a design program sized
    to its beam, widened by lensfit import to pass the design beam; ``design_mm`` the
    value in the design file, when it gave one). lensdb/README.md, ``aperture``."""
    out = []
    for k, s in enumerate(lens.surfaces):
        i = lens.file_index(k)
        if i is None:
            continue  # the loader's copy of a stop on a refracting surface
        stop = s.stop or (k > 0 and lens.surfaces[k - 1].inserted == "front") or (
            k + 1 < len(lens.surfaces) and lens.surfaces[k + 1].inserted == "back")
        row = {"surface": i, "semi_diameter_mm": s.semi_diameter_mm,
               "kind": "stop" if stop else s.aperture}
        if s.design_semi_diameter_mm is not None:
            row["design_mm"] = s.design_semi_diameter_mm
        out.append(row)
    return out


def _semi_diameter_rows(lens) -> list[str]:
    """One line per surface for ``lensfit info``: whether its semi-diameter clips as an
    aperture or is an automatic housing."""
    rows = []
    for r in semi_diameter_kinds(lens):
        sd = f"surface {r['surface']:2d}  {r['semi_diameter_mm']:10.4f} mm  "
        if r["kind"] == "stop":
            rows.append(sd + "the stop: its aperture (the widest it opens)")
        elif r["kind"] == "automatic":
            design = (f", {r['design_mm']:.4f} mm in the design file" if "design_mm" in r
                      else "")
            rows.append(sd + f"automatic: a housing that passes the design beam{design}")
        else:
            rows.append(sd + "fixed: an aperture (clips)")
    return rows


def _print_default_domain(lens) -> None:
    """The domain `lensfit fit` covers by default (lensfit.sample.domain.default_domain:
    the design's own where the lens file states it), or why it refuses the lens."""
    from lensfit.errors import LensError
    from lensfit.paraxial.paraxial import f_number_for_stop_radius
    from lensfit.sample.domain import default_domain, field_cap_note, stated_design

    try:
        d = default_domain(lens)
    except (InputError, LensError) as e:
        print(f"  {'default domain':20s}none: {e}")
        return
    source = ("the lens file's [fit]" if declared_fit_keys(lens) else
              "the design the lens file states" if stated_design(lens)
              else "a 36 x 24 mm frame, as far as the chief ray passes")
    field = f"{d.field_deg:.4g} deg" + (f" x {d.field_y_deg:.4g} deg" if d.field_y_deg else "")
    print(f"  {'default domain':20s}f/{abs(f_number_for_stop_radius(lens, d.stop_radius_mm)):.3g}, "
          f"half field {field}, image circle {d.sensor_radius_mm:.4g} mm, sensor travel "
          f"{d.focus_min_mm:.4g} to {d.focus_max_mm:.4g} mm ({source})")
    note = field_cap_note(lens, d)
    if note:
        print(f"  {'':20s}{note}")


def declared_fit_keys(lens) -> bool:
    """The lens file declares part of the domain in [fit]."""
    from lensfit.sample.domain import declared_fit

    return any(k in declared_fit(lens) for k in ("f_number", "field_deg"))


def _light_arg(text: str) -> tuple[float, float]:
    """``--light X,Y``: field angles in degrees (designers' sign, README Conventions)."""
    parts = text.split(",")
    try:
        x, y = (float(v) for v in parts)
    except ValueError:
        raise InputError(f"--light {text!r}: expected two field angles X,Y in degrees") from None
    return x, y


def _center_arg(text: str) -> tuple[float, float]:
    """``--center X,Y``: a point on the sensor in mm."""
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--center {text!r}: expected two sensor coordinates X,Y in mm"
                         ) from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise InputError(f"--center {text!r}: expected finite coordinates in mm")
    return x, y


def _direct_fit(lens, args: argparse.Namespace, lens_arg: str):
    """For `lensfit ghosts --fit`: the lens folder, its direct table and domain, read
    before any work (the ghosts are fitted over the direct fit's domain)."""
    from lensfit.generate import lens_folder_name, read_fit_json
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


def _generated(args: argparse.Namespace, must_exist: bool = False) -> Path:
    """The generated folder of a command: --generated, else $LENSFIT_GENERATED, else the
    checkout's, else the current directory's (lensfit.data_folder); with ``must_exist``
    an InputError naming the folder and the settings when it is missing."""
    from lensfit import data_folder, require_data_folder

    if must_exist:
        return require_data_folder("generated", args.generated)
    return data_folder("generated", args.generated)


def _generated_arg(p: argparse.ArgumentParser, what: str) -> None:
    """--generated DIR: the generated folder the command reads (or writes)."""
    p.add_argument("--generated", default=None, metavar="DIR",
                   help=f"the generated folder {what} (default: $LENSFIT_GENERATED, else "
                        "the checkout's generated/ when lensfit runs from one, else "
                        "./generated)")


def _check_dask_args(args: argparse.Namespace) -> None:
    """--workers and --scheduler (lensfit.banks.engine) of bank and ghosts --fit."""
    if args.workers is not None and args.workers < 0:
        raise InputError(f"--workers {args.workers}: expected 0 (this process) or more")
    if args.scheduler is not None and args.workers is not None:
        raise InputError("--workers and --scheduler: the cluster at the address has its own "
                         "workers; give one of them")


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
    from lensfit.generate import lens_folder_name
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


def _finite(v: float) -> float | None:
    """A number for JSON: None where it is not finite (a ghost no ray of which reaches
    the sensor is -inf stops from black; JSON has no infinity)."""
    return v if math.isfinite(v) else None


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


def _coated(lens, args: argparse.Namespace):
    """The lens, or its uncoated variant with --coating none."""
    from lensfit.prescription import with_coating

    return with_coating(lens, getattr(args, "coating", "file"))


def _coating_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--coating", choices=("file", "none"), default="file",
                   help="the coatings of the lens file (default), or none: the uncoated "
                        "variant, written to <lens folder>-uncoated")


def _glass_policy(lens, args: argparse.Namespace):
    """The lens with glass extrapolation allowed when --allow-glass-extrapolation."""
    from lensfit.glass.ranges import allow_extrapolation

    return allow_extrapolation(lens) if args.allow_glass_extrapolation else lens


def _print_glass_ranges(lens, wavelengths: list[str] | None) -> None:
    """The band `lensfit fit` covers by default (380-780 nm narrowed to the range every
    glass supports, or why there is none), then, when extrapolation is allowed, the
    glasses extrapolated over it and any --wavelength."""
    from lensfit.errors import LensError
    from lensfit.glass.ranges import allows_extrapolation, out_of_range
    from lensfit.sample.domain import fit_wavelengths

    try:
        band = fit_wavelengths(lens)
        print(f"  {'default fit':20s}{band.line()}")
        lams = list(band.range_nm)
    except LensError as e:  # no band every glass supports: say why, as `lensfit fit` will
        print(f"  {'default fit':20s}none: {e.detail}")
        lams = []
    for text in wavelengths or []:
        lams += [float(v) for v in text.split(",")]
    if not lams or not allows_extrapolation(lens):
        return  # the --wavelength values were checked against every glass already
    for o in out_of_range(lens, min(lams), max(lams)):
        print(f"  {'glass range':20s}{o.describe()}: allowed (glass_extrapolation)")


def cmd_draw(args: argparse.Namespace) -> int:
    from lensfit.draw import draw_lens
    from lensfit.prescription import load_lens

    if not 2 <= args.rays <= MAX_RAYS:
        raise InputError(f"--rays {args.rays}: expected 2 to {MAX_RAYS} rays per fan")
    out = _check_file(args.output, "-o")
    if out.suffix.lower() != ".png":
        raise LensError(f"expected a .png output file, found {out.name!r}", key="-o")
    lens = load_lens(args.lens)
    draw_lens(lens, out, field_deg=args.field, rays=args.rays, f_number=args.f_number)
    print(f"wrote {out}")
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    from lensfit.interchange import file_kind
    from lensfit.prescription import lens_from_dict
    from lensfit.prescription.lentil import convert_entry, load_lentil_json, slug, to_toml

    kind = file_kind(args.json_file)
    if kind in ("zmx", "optiland"):
        return _import_lens_file(args, kind)
    if kind == "unknown":
        raise InputError(f"{args.json_file}: expected a Zemax .zmx file or a .json file "
                         "(Optiland or lentil)")
    outdir = _check_folder(args.output or "lensdb", "-o")
    data = load_lentil_json(args.json_file)
    ids = args.id or sorted(data)
    files: dict[str, str] = {}
    for lens_id in ids:  # every entry converted and validated before the first write
        if lens_id not in data:
            raise LensError(f"no entry with id {lens_id!r}", file=args.json_file, key="--id")
        conv = convert_entry(lens_id, data[lens_id], source=args.json_file)
        with np.errstate(over="ignore", invalid="ignore"):  # an inf is refused, not warned
            lens_from_dict(conv, file=f"{args.json_file}#{lens_id}")
        files[f"{slug(conv)}.toml"] = to_toml(conv)
    for path in write_files(outdir, files, option="-o"):
        print(f"wrote {path}")
    return 0


def _import_lens_file(args: argparse.Namespace, kind: str) -> int:
    """lensfit import of a .zmx or Optiland file: every problem on its own line (exit 2,
    nothing written), the notes on what was not mapped on stderr, the TOML atomically."""
    from lensfit.interchange import ImportProblems, read_optiland, read_zmx
    from lensfit.prescription.lentil import to_toml

    src = Path(args.json_file)
    if args.id and len(args.id) > 1:
        raise InputError(f"--id: one id for a {kind} file, found {len(args.id)}")
    out = Path(args.output) if args.output else Path(src.stem + ".toml")
    if out.is_dir():
        out = out / (src.stem + ".toml")
    out = _check_file(out, "-o")
    if out.suffix != ".toml":
        raise InputError(f"-o {out}: expected a .toml file or a folder")
    # The id names C symbols: the file stem with anything else turned into '_'
    lens_id = args.id[0] if args.id else re.sub(r"[^A-Za-z0-9_]", "_", src.stem)
    try:
        result = (read_zmx if kind == "zmx" else read_optiland)(src, lens_id=lens_id)
    except ImportProblems as e:
        for line in e.problems:
            print(f"lensfit: error: {line}", file=sys.stderr)
        print(f"lensfit: error: {len(e.problems)} problem(s); nothing written", file=sys.stderr)
        return 2
    for line in result.notes:
        print(f"lensfit: note: {line}", file=sys.stderr)
    text = to_toml(result.data)
    # What was done with each surface's semi-diameter: an aperture kept, an automatic one
    # widened to pass the design beam (lensfit.interchange.housings)
    for line in result.semi_diameters:
        print(line)
    write_atomic(out, text, option="-o")
    print(f"wrote {out}")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from lensfit.interchange import write_zmx
    from lensfit.prescription import load_lens

    out = _check_file(args.output, "-o")
    if out.suffix.lower() != ".zmx":
        raise InputError(f"-o {out}: expected a .zmx file")
    lens = load_lens(args.lens)
    try:
        text, notes = write_zmx(lens)
    except ValueError as e:
        raise LensError(f"cannot export: {e}", file=lens.source_file) from None
    for line in notes:
        print(f"lensfit: note: {lens.source_file}: {line}", file=sys.stderr)
    write_atomic(out, text, option="-o")
    print(f"wrote {out}")
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    from lensfit.paraxial import paraxial
    from lensfit.prescription import list_lenses, load_lens

    for p in list_lenses():
        lens = load_lens(p)
        efl = paraxial(lens).efl_mm
        print(f"{p.stem:48s} EFL {_fmt(efl, 'mm', 2):>12s}  {lens.name}")
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    from lensfit.prescription import list_lenses
    from lensfit.validate import efl_check

    paths = args.lens or [str(p) for p in list_lenses()]
    bad = 0
    for p in paths:
        ok, msg = efl_check(p)
        bad += not ok
        print(("ok    " if ok else "FAIL  ") + msg)
    return 1 if bad else 0


def _pair(text: str | None, what: str) -> tuple[float, float] | None:
    """'LO,HI' -> (lo, hi) with lo < hi, both finite."""
    if text is None:
        return None
    parts = text.split(",")
    try:
        lo, hi = (float(v) for v in parts)
    except ValueError:
        raise InputError(f"{what} = {text!r}: expected two numbers LO,HI") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise InputError(f"{what} = {text!r}: expected finite numbers with LO < HI")
    return lo, hi


def _domain_and_options(args: argparse.Namespace, lens):
    """(domain, fit options, wavelengths): the wavelengths are the domain's band and
    why (:func:`lensfit.sample.domain.fit_wavelengths`): --wavelengths as given, else
    380-780 nm narrowed to the range every glass of the lens supports."""
    from lensfit.sample import default_domain
    from lensfit.sample.domain import fit_wavelengths

    pair = _pair(args.wavelengths, "--wavelengths")
    wavelengths = fit_wavelengths(lens, pair, f"--wavelengths {args.wavelengths}")
    close = args.close_focus
    domain = default_domain(lens, f_number=args.f_number, field_deg=args.field,
                            close_focus_mm=close, wavelengths_nm=wavelengths.range_nm,
                            focus_mm=_pair(args.focus, "--focus"),
                            image_circle_mm=args.image_circle)
    return domain, _options(args), wavelengths


def _options(args: argparse.Namespace):
    from lensfit.fitting import FitOptions

    extra = {"psf_target": args.psf_target, "method": args.method}
    if args.quick:
        extra.update(retry=False, max_terms=60, piston_terms=20, max_degree=7, phase_degree=8,
                     train_groups=600, train_per_group=8, test_groups=100, groups=1000,
                     aperture_points=64, field_degrees=(4, 6), aperture_degree=8)
    try:  # FitOptions checks its values (--psf-target) and says which is wrong
        return FitOptions(**extra)
    except ValueError as e:
        raise InputError(str(e)) from None


def _miss_note(o: dict) -> str:
    """'' for an output within its target; else why it is not."""
    from lensfit.report import LIMIT_WORDS

    if o["reached"]:
        return ""
    why = LIMIT_WORDS.get(o.get("limit") or "degree", o.get("limit"))
    return f"  (target {o['target']:.3g} not reached: limited by {why})"


def _print_trust(fig: dict) -> None:
    from lensfit.trust import cell_label

    again = fig.get("retried")
    if again:
        print(f"  the first fit's worst PSF cell was {again['first_worst']:.3%} "
              f"({cell_label(again['first_cell'])}): fitted again with the phase target "
              f"{again['target_waves']:.3g} waves, the {again['kept']} kept")
    worst = fig["psf_vs_exact"]["worst"]
    rel, target = worst["relative_l2"], fig["psf_target"]
    verdict = "within" if rel <= target else "ABOVE"
    print(f"  PSF against exactly traced rays: worst cell {rel:.3%} relative L2 "
          f"({cell_label(worst)}), {verdict} the target {target:.3%}")
    if rel > target:
        missed = [o for o in fig["outputs"] if not o["reached"]]
        print(f"  MISSES the target at {cell_label(worst)}: "
              + ("; ".join(f"{o['system']} {o['name']} {o['rms']:.3g} {o['unit']} RMS on "
                           f"held-out rays against {o['target']:.3g}{_miss_note(o)[1:]}"
                           .replace(f" (target {o['target']:.3g} not reached: ", " (")
                           for o in missed)
                 or "every output is within its held-out target, so the cell's error is "
                    "between the held-out rays (lensfit report shows every cell)"))


def _print_field_cap(lens, domain) -> None:
    """One line when the field fitted is narrower than the one the lens file states."""
    from lensfit.sample.domain import field_cap_note

    note = field_cap_note(lens, domain)
    if note:
        print(f"field: {note}")


def _miss_status(fig: dict, args: argparse.Namespace) -> int:
    """The exit status of a finished fit: EXIT_MISS when its worst PSF cell is above the
    target (unless --allow-miss), else 0."""
    missed = fig["psf_vs_exact"]["worst"]["relative_l2"] > fig["psf_target"]
    if missed and not args.allow_miss:
        print(f"lensfit: the fit misses its PSF target (exit {EXIT_MISS}; the table is "
              "written and flagged; --allow-miss exits 0)", file=sys.stderr)
        return EXIT_MISS
    return 0


def _print_extrapolated(lens, domain: dict) -> None:
    """The glasses the fit used outside their published range (allowed), one line each."""
    from lensfit.glass.ranges import out_of_range

    for o in out_of_range(lens, domain["wavelength_min_nm"], domain["wavelength_max_nm"]):
        print(f"  glass extrapolated: {o.describe()}")


def _resumable(args: argparse.Namespace) -> dict:
    """stage.run's keywords of `lensfit fit`: checkpoints (lensfit.fit_cache: a rerun
    resumes) and the progress bar, on a terminal unless --no-progress."""
    return {"checkpoints": True, "progress": not args.no_progress and sys.stderr.isatty()}


def cmd_fit(args: argparse.Namespace) -> int:
    from lensfit import stage
    from lensfit.generate import lens_folder_name
    from lensfit.prescription import load_lens

    # Outputs first: a bad folder must not surface after the whole fit
    if args.generated:
        _check_folder(args.generated, "--generated")
    if args.report:
        _check_folder(args.report, "--report")
    lens = _glass_policy(_coated(load_lens(args.lens), args), args)
    gen = _generated(args)
    if args.scene:
        from lensfit.scene import load_scene, scene_domain, scene_wavelengths

        given = [f"--{k.replace('_', '-')}" for k in ("f_number", "field", "image_circle",
                                                       "wavelengths", "close_focus", "focus")
                 if getattr(args, k) is not None]
        if given:
            raise InputError(f"--scene {args.scene}: the scene sets the domain (its lights, "
                             f"wavelengths, f_number and focus); drop {', '.join(given)}")
        scene = load_scene(args.scene)
        domain, options = scene_domain(lens, scene), _options(args)
        wavelengths = scene_wavelengths(lens, scene)
        print(wavelengths.line())
        folder = gen / lens_folder_name(lens) / "scene-fits" / scene.name
        report_dir = (Path(args.report) if args.report
                      else Path("build/report") / lens_folder_name(lens) / scene.name)
        _, fig = stage.run(lens, domain=domain, options=options, generated_dir=folder,
                           report_dir=report_dir, timing=args.timing,
                           flat=True, scene=scene, glsl=args.glsl, wavelengths=wavelengths,
                           **_resumable(args))
        out = folder
    else:
        domain, options, wavelengths = _domain_and_options(args, lens)
        print(wavelengths.line())
        _print_field_cap(lens, domain)
        report_dir = (Path(args.report) if args.report
                      else Path("build/report") / lens_folder_name(lens))
        _, fig = stage.run(lens, domain=domain, options=options, generated_dir=gen,
                           report_dir=report_dir, timing=args.timing, glsl=args.glsl,
                           wavelengths=wavelengths, **_resumable(args))
        out = gen / lens_folder_name(lens)
    print(f"wrote {out}/ and {report_dir / 'report.md'} (fit {fig['fit_seconds']:.1f} s, "
          f"PSF check {fig['psf_vs_exact']['seconds']:.1f} s)")
    for o in fig["outputs"]:
        print(f"  {o['system']} {o['name']:6s} {o['terms']:5d} terms  RMS {o['rms']:.4g} "
              f"{o['unit']}{_miss_note(o)}")
    _print_trust(fig)
    _print_extrapolated(lens, fig["domain"])
    return _miss_status(fig, args)


def cmd_report(args: argparse.Namespace) -> int:
    from lensfit import stage
    from lensfit.generate import lens_folder_name
    from lensfit.prescription import load_lens

    if args.out:
        _check_folder(args.out, "-o")  # before the fit, not after it
    lens = _glass_policy(_coated(load_lens(args.lens), args), args)
    domain, options, wavelengths = _domain_and_options(args, lens)
    report_dir = Path(args.out) if args.out else Path("build/report") / lens_folder_name(lens)
    if not args.json:  # --json: the figures carry it (key "wavelengths")
        print(wavelengths.line())
        _print_field_cap(lens, domain)
    _, fig = stage.run(lens, domain=domain, options=options, report_dir=report_dir,
                       timing=args.timing, wavelengths=wavelengths)
    if args.json:
        print(json.dumps(fig, indent=1, allow_nan=False))
    else:
        print(f"wrote {report_dir / 'report.md'}")
        _print_trust(fig)
        _print_extrapolated(lens, fig["domain"])
    return _miss_status(fig, args)


def cmd_scene(args: argparse.Namespace) -> int:
    from lensfit import scene as sc
    from lensfit.codegen import emit_c
    from lensfit.generate import (
        lens_folder_name,
        lens_prefix,
        read_fit_json,
        scene_files,
    )
    from lensfit.prescription import load_lens
    from lensfit.report import ns_per_eval

    if args.out:
        _check_folder(args.out, "-o")
    lens = load_lens(args.lens)
    gen = _generated(args, must_exist=True) / lens_folder_name(lens)
    fit_file = gen / "fit.json"
    if not fit_file.exists():
        raise InputError(f"{fit_file}: no fit for {lens.name}; run `lensfit fit {args.lens}`")
    systems, _ = read_fit_json(fit_file)
    scene = sc.load_scene(args.scene)
    special = sc.specialise(systems, scene)
    files = scene_files(lens, special, scene.name, args.scene, systems.trust, glsl=args.glsl)
    c_files = {name: text for name, text in files.items() if name.endswith((".c", ".h"))}
    out = Path(args.out) if args.out else gen / "scenes" / scene.name
    ghost_files: dict[str, str] = {}
    if scene.flares:
        # The fitted ghosts the scene keeps, each specialised as the direct systems are
        from lensfit.ghosts.scene import choose_ghosts, fitted_ghosts

        fitted = fitted_ghosts(gen, args.lens)
        chosen = choose_ghosts(lens, scene, fitted)
        for label in chosen:
            table = fitted[label]
            ghost_files |= scene_files(lens, sc.specialise(table, scene), scene.name,
                                       args.scene, table.trust, table.ghost, glsl=args.glsl)
    write_files(out, files, option="-o")
    if ghost_files or (out / "ghosts").exists():
        write_files(out / "ghosts", ghost_files, option="-o")
        for old in (out / "ghosts").iterdir():  # ghosts the scene no longer keeps
            if old.name not in ghost_files:
                old.unlink()
    general = emit_c(systems, lens_prefix(lens))
    rows = {
        "general_terms": sc.terms(systems),
        "scene_terms": sc.terms(special),
        "general_c_bytes": sum(len(t) for t in general.values()),
        "scene_c_bytes": sum(len(t) for t in c_files.values()),
        "systems": [],
        "ghosts": chosen if scene.flares else [],
    }
    if not args.no_timing:
        by = {s.name: s for s in systems}
        for s in special:
            base = by["P_o" if s.name.startswith("P_o") else "P_s"]
            rows["systems"].append({
                "system": s.name, "terms": sum(p.terms for p in s.outputs),
                "general_terms": sum(p.terms for p in base.outputs),
                "ns_general": ns_per_eval(base, "d"), "ns_scene": ns_per_eval(s, "d")})
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"wrote {out}/")
    print(f"  terms  {rows['general_terms']} general -> {rows['scene_terms']} for this scene")
    print(f"  C      {rows['general_c_bytes']} bytes -> {rows['scene_c_bytes']} bytes")
    if scene.flares:
        print(f"  flares ghosts {', '.join(chosen)} in {out / 'ghosts'}/")
    for r in rows["systems"]:
        print(f"  {r['system']:10s} {r['general_terms']:4d} -> {r['terms']:4d} terms, "
              f"{r['ns_general']:.0f} -> {r['ns_scene']:.0f} ns per evaluation (double)")
    return 0


def cmd_regenerate(args: argparse.Namespace) -> int:
    from lensfit.generate import lens_folder_name, regenerate
    from lensfit.prescription import load_lens

    gen = _generated(args, must_exist=True)
    # A generated folder's whole name (e.g. a coating variant's), else a lens id or file
    if "/" not in args.lens and (gen / args.lens / "fit.json").is_file():
        folder = gen / args.lens
    else:
        folder = gen / lens_folder_name(load_lens(args.lens))
    _, names = regenerate(folder)
    print(f"wrote {folder}/ from its fit.json ({', '.join(names)})")
    return 0


def cmd_upgrade_table(args: argparse.Namespace) -> int:
    from lensfit.generate import upgrade_table

    for name in args.files:
        path = Path(name)
        if not path.is_file():
            raise InputError(f"{path}: no such table file")
        done = upgrade_table(path)
        print(f"{path}: {'upgraded to version 5' if done else 'not version 3 or 4: unchanged'}")
    return 0


def cmd_bank(args: argparse.Namespace) -> int:
    from lensfit.banks.engine import TaskError
    from lensfit.banks.run import run_bank
    from lensfit.banks.spec import SpecError

    _check_dask_args(args)
    out = Path(args.out) if args.out else Path("build") / "banks" / Path(args.spec).stem
    gen = _generated(args)
    try:
        summary = run_bank(args.spec, out, scheduler=args.scheduler, workers=args.workers,
                           restart=args.restart, progress=not args.no_progress,
                           sheet=not args.no_sheet, generated=gen,
                           check=not args.no_check, verbose=args.verbose,
                           say=lambda line: print(line, file=sys.stderr, flush=True))
    except SpecError as e:
        # A lens id looked up in a generated folder that is not there: say which folder
        # the rule chose and how to choose another
        if "key 'lens'" not in str(e) or gen.is_dir():
            raise
        from lensfit import missing_data_folder

        raise InputError(f"{e}; {missing_data_folder('generated', args.generated)}") from None
    except TaskError as e:
        print(f"lensfit: error: {e}; rerun the same command to resume", file=sys.stderr)
        return 1
    print(summary.line())
    return 0


def cmd_image(args: argparse.Namespace) -> int:
    from lensfit.banks.engine import TaskError
    from lensfit.image.through import Options, summary_lines, through_lens, write_preview

    _check_dask_args(args)
    aperture: dict[str, object] = {}
    if args.blades:
        aperture = {"shape": "blades", "blades": args.blades,
                    "blade_curvature": args.blade_curvature, "rotation_deg": args.rotation}
    o = Options(f_number=args.f_number, focus_offset_mm=args.focus_offset,
                pixel_mm=None if args.pixel_um is None else args.pixel_um * 1e-3,
                center_mm=args.center,
                sensor_width_mm=args.sensor_width, focal_mm=args.focal, aperture=aperture,
                nodes_x=args.nodes, oversample=args.oversample, target_error=args.target_error,
                ghosts=None if args.ghosts == "none" else args.ghosts,
                flare_threshold=args.threshold, max_sources=args.max_sources,
                flare_target_error=args.flare_target_error,
                flare_downsample=args.flare_downsample, depth_slices=args.depth_slices,
                cache=args.cache, scheduler=args.scheduler, workers=args.workers,
                progress=not args.no_progress)
    try:
        result = through_lens(args.lens, args.input, args.out, o, generated=_generated(args),
                              say=lambda line: print(line, file=sys.stderr, flush=True))
    except TaskError as e:
        print(f"lensfit: error: {e}; rerun the same command to resume the bank",
              file=sys.stderr)
        return 1
    if args.png:
        write_preview(result, args.png)
    print("\n".join(summary_lines(result)))
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="lensfit", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)

    p = sub.add_parser("info", help="paraxial table of a lens")
    p.add_argument("lens")
    p.add_argument("--json", action="store_true", help="print a JSON object")
    p.add_argument("--f-number", type=float, help="stop the lens down to this f-number")
    p.add_argument("--allow-glass-extrapolation", action="store_true",
                   help="use glasses outside their published range (as the lens file's "
                        "glass_extrapolation = \"allow\"); each is listed")
    p.add_argument("--wavelength", action="append", metavar="NM",
                   help="first-order facts at this wavelength in nm instead of the d line "
                        "(repeatable or a comma list; the stop of --f-number stays that of "
                        "the d line)")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("ghosts", help="ghosts of a lens ranked by their peak pixel relative "
                       "to the light's; the visible ones kept (issues 13, 26)")
    p.add_argument("lens", nargs="*", help="lens ids or files (one or more)")
    p.add_argument("--f-number", type=float, default=None,
                   help="stop the lens down to this f-number (default: wide open)")
    p.add_argument("--light", default="0,0", metavar="X,Y",
                   help="field angles of a light at infinity in degrees, designers' sign "
                        "(README Conventions; default 0,0)")
    p.add_argument("--distance", type=float, default=math.inf, metavar="MM",
                   help="the light's distance from the first vertex in mm (default inf)")
    p.add_argument("--json", action="store_true", help="print the estimates as JSON")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--threshold", type=float, default=None,
                       help="keep ghosts whose peak is above this share of the PSF peak "
                            "(default: keep the visible ones, --overexposure)")
    group.add_argument("--count", type=int, default=None, help="keep the K brightest ghosts")
    p.add_argument("--overexposure", type=float, default=DEFAULT_OVEREXPOSURE_STOPS,
                   metavar="STOPS",
                   help="a ghost is visible (and kept by default) when its peak pixel "
                        "shows in a photograph whose exposure puts the light's peak pixel "
                        f"this many stops over white (default {DEFAULT_OVEREXPOSURE_STOPS:g}: "
                        f"the sun over a sunlit white; {DISPLAY_STOPS:g} stops shown below "
                        "white)")
    p.add_argument("--pixel-um", type=float, default=DEFAULT_PIXEL_MM * 1e3, metavar="UM",
                   help="the pixel pitch both peaks are averaged over for visibility "
                        f"(default {DEFAULT_PIXEL_MM * 1e3:g} um)")
    p.add_argument("--rays", type=int, default=20000,
                   help="rays per wavelength over the front (default 20000; a fifth of "
                        "that per ghost in the second pass)")
    p.add_argument("--ghost", action="append", default=[], metavar="I-J",
                   help="only these ghosts, in the lens file's numbering (repeatable or a "
                        "comma list)")
    _coating_arg(p)
    p.add_argument("--fit", action="store_true",
                   help="fit the kept ghosts over the direct fit's domain and write their "
                        "tables to <generated>/<lens folder>/ghosts/")
    p.add_argument("--c", action="store_true",
                   help="with --fit: also write each ghost's Horner C (2-3 MB a ghost; lensrt "
                        "loads the tables, `lensfit scene` writes a scene's ghosts as C)")
    p.add_argument("--glsl", action="store_true",
                   help="with --fit: also write each ghost's GLSL (P_o, P_s and P_clip, "
                        "float and double)")
    p.add_argument("--add", action="store_true",
                   help="with --fit: keep the ghosts fitted before (replacing those fitted "
                        "again) instead of writing exactly the kept ones")
    _generated_arg(p, "of the lens folders (with --fit)")
    p.add_argument("--all", action="store_true",
                   help="with --fit: also every lens of lensdb with a direct fit in "
                        "--generated")
    p.add_argument("--scheduler", default=None,
                   help="with --fit: a running Dask scheduler's address (default: a "
                        "LocalCluster here), one ghost per task")
    p.add_argument("--workers", type=int, default=None,
                   help="with --fit: LocalCluster worker processes (default: one per core; "
                        "0: fit in this process without Dask)")
    p.set_defaults(func=cmd_ghosts)

    p = sub.add_parser("draw", help="draw the cross-section with ray fans")
    p.add_argument("lens")
    p.add_argument("-o", "--output", required=True, help="PNG file to write")
    p.add_argument("--field", type=float, default=None, help="off-axis field angle in degrees")
    p.add_argument("--rays", type=int, default=11, help="rays per fan")
    p.add_argument("--f-number", type=float, default=None, help="stop down to this f-number")
    p.set_defaults(func=cmd_draw)

    p = sub.add_parser("import", help="convert a Zemax .zmx, Optiland JSON or lentil JSON "
                       "lens to lensfit TOML")
    p.add_argument("json_file", metavar="FILE")
    p.add_argument("--id", action="append", help="lentil: entry id to convert (repeatable; "
                   "default all); .zmx/Optiland: the lens id (default: the file stem)")
    p.add_argument("-o", "--output", default=None, help="lentil: output folder (default "
                   "lensdb); .zmx/Optiland: the .toml file or a folder (default "
                   "./FILE-stem.toml)")
    p.set_defaults(func=cmd_import)

    p = sub.add_parser("export", help="write a lens as a Zemax .zmx file")
    p.add_argument("lens")
    p.add_argument("-o", "--output", required=True, help=".zmx file to write")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("list", help="list the lenses in lensdb")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("check", help="validate lenses and check EFL against the patent")
    p.add_argument("lens", nargs="*")
    p.set_defaults(func=cmd_check)

    for name, func, help_ in (
        ("fit", cmd_fit, "fit P_o and P_s, write generated/<lens>/ and the report"),
        ("report", cmd_report, "fit and write the fit-error report (Markdown, PNG, JSON)"),
    ):
        p = sub.add_parser(name, help=help_)
        p.add_argument("lens")
        p.add_argument("--f-number", type=float, default=None,
                       help="widest aperture fitted (default: the lens file's [fit] or "
                            "[lens] f_number, else f/2, or wide open if slower)")
        p.add_argument("--field", type=float, default=None, metavar="DEG",
                       help="half field angle in x (default: the lens file's [fit] "
                            "field_deg or half its [lens] field_of_view_deg, else the field "
                            "of a 36 x 24 mm frame; at most 60 and as far as the chief ray "
                            "passes); the image circle follows")
        p.add_argument("--image-circle", type=float, default=None, metavar="MM",
                       help="radius of the sensor disc fitted (default: follows --field)")
        p.add_argument("--wavelengths", default=None, metavar="LO,HI",
                       help="wavelength range in nm (default: 380,780 narrowed to the "
                            "range every glass of the lens supports)")
        p.add_argument("--close-focus", type=float, default=None, metavar="MM",
                       help="closest scene point from the first vertex in mm, or inf "
                            "(default: ten focal lengths); the sensor travel follows")
        p.add_argument("--focus", default=None, metavar="LO,HI",
                       help="sensor shift range z_S in mm (default: what focuses from "
                            "infinity to the close focus)")
        p.add_argument("--psf-target", type=float, default=0.01, metavar="REL",
                       help="PSF error the fit aims at, relative L2 against exactly "
                            "traced rays (default 0.01); the phase target follows")
        p.add_argument("--method", choices=("tensor", "pursuit"), default="tensor",
                       help="tensor least squares on a ray grid (default) or the sparse "
                            "pursuit of the first fits")
        p.add_argument("--quick", action="store_true",
                       help="small budgets and samples (for tests and trials)")
        timing = p.add_mutually_exclusive_group()
        timing.add_argument("--timing", action="store_true",
                            help="compile and time the generated C and casadi's C (the "
                                 "report's Speed table; minutes for a large table)")
        timing.add_argument("--no-timing", action="store_true",
                            help="no compiling and timing (the default; kept for scripts)")
        p.add_argument("--allow-miss", action="store_true",
                       help=f"exit 0 even when the PSF check misses the target (the "
                            f"table is written and flagged either way; without this the "
                            f"exit status is {EXIT_MISS})")
        p.add_argument("--allow-glass-extrapolation", action="store_true",
                       help="use glasses outside their published range (as the lens "
                            "file's glass_extrapolation = \"allow\"); the report lists each")
        _coating_arg(p)
        if name == "fit":
            _generated_arg(p, "to write the lens folder to")
            p.add_argument("--report", default=None, help="folder for the report")
            p.add_argument("--glsl", action="store_true",
                           help="also write the GLSL source (megabytes for a full fit; "
                                "lensrt's GL path loads the table)")
            p.add_argument("--no-progress", action="store_true",
                           help="no progress bar (there is none when stderr is not a "
                                "terminal)")
            p.add_argument("--scene", default=None, metavar="SCENE.toml",
                           help="fit only what this scene needs (its lights, wavelengths, "
                                "stop and focus): generated/<lens>/scene-fits/<name>/")
        else:
            p.add_argument("--json", action="store_true", help="print the figures as JSON")
            p.add_argument("-o", "--out", default=None, help="folder for the report")
        p.set_defaults(func=func)

    p = sub.add_parser("regenerate",
                       help="rewrite generated/<lens>/ from its fit.json, without fitting")
    p.add_argument("lens", help="lens id or file, or a generated folder's name "
                   "(e.g. 0001-angenieux-double-gauss-uncoated)")
    _generated_arg(p, "of the lens folder")
    p.set_defaults(func=cmd_regenerate)

    p = sub.add_parser("upgrade-table",
                       help="rewrite version-3 or -4 lensfit-poly-table files as version 5 "
                            "in place: probe lines from their own polynomials, no fit (a "
                            "ghost table's ghosts.json keeps its old CRC: use regenerate "
                            "for a generated folder)")
    p.add_argument("files", nargs="+", help="table files")
    p.set_defaults(func=cmd_upgrade_table)

    p = sub.add_parser("bank", help="render a bank of PSFs (field points x focus x stops x "
                       "wavelengths) on Dask; a rerun resumes")
    p.add_argument("spec", help="bank spec TOML (see lensfit.banks.spec; banks/demo.toml)")
    p.add_argument("-o", "--out", default=None,
                   help="bank folder (default: build/banks/<spec file's stem>)")
    p.add_argument("--scheduler", default=None,
                   help="address of a running Dask scheduler (default: a LocalCluster here)")
    p.add_argument("--workers", type=int, default=None,
                   help="LocalCluster worker processes (default: one per core, at most two "
                        "per core; 0: render in this process without Dask)")
    p.add_argument("--restart", action="store_true",
                   help="discard the nodes of a bank of another spec or table, or of a "
                        "damaged bank.json, in the folder (the same bank resumes either way)")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="show the Dask cluster's logs (INFO; default: errors only)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-sheet", action="store_true", help="no contact-sheet PNG")
    p.add_argument("--no-check", action="store_true",
                   help="do not measure the reader between nodes against direct renders "
                        "(check.json; a few seconds)")
    _generated_arg(p, "where the spec's lens id is looked up")
    p.set_defaults(func=cmd_bank)

    p = sub.add_parser("image", help="put a linear HDR frame (EXR) through a lens: direct, "
                       "flare and ghost layers")
    p.add_argument("lens", help="lens id, generated folder or .table")
    p.add_argument("input", help="linear EXR: R, G, B or spectral S0.<lambda>nm channels, "
                   "optional Z (depth, mm from the first vertex)")
    p.add_argument("-o", "--out", required=True, help="output EXR (layers direct, flare, "
                   "ghost_<i>_<j>; unprefixed channels: their total)")
    p.add_argument("--png", default=None, help="also a tone-mapped preview PNG of the total")
    p.add_argument("--f-number", type=float, default=8.0, help="the stop (default 8)")
    p.add_argument("--focus-offset", type=float, default=0.0,
                   help="sensor shift z_S in mm, + away from the lens (default 0)")
    p.add_argument("--pixel-um", type=float, default=None,
                   help="pixel pitch in um (default: sensor width / frame width)")
    p.add_argument("--sensor-width", type=float, default=None,
                   help="sensor width in mm (default: the EXR's lensfit/sensorWidthMm, "
                        "else 36)")
    p.add_argument("--focal", type=float, default=None,
                   help="the input's pinhole focal length in mm (default: the EXR's "
                        "lensfit/pinholeFocalMm, else the lens's)")
    p.add_argument("--center", type=_center_arg, default=(0.0, 0.0), metavar="X,Y",
                   help="the frame's centre on the sensor in mm (a window of the sensor; "
                        "write --center=X,Y when X is negative)")
    p.add_argument("--blades", type=int, default=0, help="aperture blades (0: a circle)")
    p.add_argument("--blade-curvature", type=float, default=0.0)
    p.add_argument("--rotation", type=float, default=0.0, help="blade rotation, degrees")
    p.add_argument("--nodes", type=int, default=17,
                   help="bank field points across the frame (y's from its aspect; default 17)")
    p.add_argument("--oversample", type=int, default=3,
                   help="the direct layer on a grid this many times finer per axis (1-16; "
                        "default 3: about 3%% from every pixel's own PSF, 1: about 12%%)")
    p.add_argument("--target-error", type=float, default=0.01,
                   help="each bank node's relative L2 error estimate (default 0.01)")
    p.add_argument("--ghosts", default="none",
                   help="flares: ghost tables 'kept' (the lens folder's ghosts/) or a folder "
                        "of them; default 'none' (each ghost of each source is a Huygens "
                        "render of 1-7 minutes of CPU: docs/image.md)")
    p.add_argument("--threshold", type=float, default=0.0,
                   help="a pixel whose channels sum above this is a light source (default: "
                        "the frame's brightest / 16)")
    p.add_argument("--max-sources", type=int, default=4,
                   help="the brightest sources given flares (default 4)")
    p.add_argument("--flare-target-error", type=float, default=0.0,
                   help="each ghost render's error estimate (default 0.02)")
    p.add_argument("--flare-downsample", type=int, default=0,
                   help="frame pixels per ghost-render pixel per axis (default 4)")
    p.add_argument("--depth-slices", type=int, default=4,
                   help="distances the depth channel is split over (default 4)")
    p.add_argument("--cache", default=None,
                   help="bank cache folder (default: $LENSFIT_IMAGE_CACHE, else "
                        "build/image-cache)")
    p.add_argument("--scheduler", default=None,
                   help="address of a running Dask scheduler for the bank")
    p.add_argument("--workers", type=int, default=None,
                   help="LocalCluster workers for the bank (0: in this process)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _generated_arg(p, "where the lens id is looked up")
    p.set_defaults(func=cmd_image)

    p = sub.add_parser("scene", help="specialise a fitted lens for one scene")
    p.add_argument("lens")
    p.add_argument("scene", help="scene TOML file (see lensfit.scene)")
    _generated_arg(p, "of the fitted lens (to read)")
    p.add_argument("-o", "--out", default=None,
                   help="folder to write (default: generated/<lens>/scenes/<name>)")
    p.add_argument("--json", action="store_true", help="print the comparison as JSON")
    p.add_argument("--no-timing", action="store_true", help="skip timing the C")
    p.add_argument("--glsl", action="store_true",
                   help="also write the specialised systems' GLSL (and each kept ghost's)")
    p.set_defaults(func=cmd_scene)
    return ap


def main(argv: list[str] | None = None) -> int:
    from lensfit.sample.rays import SamplingError
    from lensfit.scene import SceneError

    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (InputError, LensError, SceneError, SamplingError, UnknownGlassError) as e:
        # The project's own errors, about the input: one line and exit 2. Anything else
        # (a ValueError from numpy, say) is a bug and keeps its traceback.
        print(f"lensfit: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # Ctrl-C: what was written is whole (lensfit.atomic), and `lensfit fit` says
        # where its checkpoints are; no traceback
        print("lensfit: interrupted", file=sys.stderr)
        return 130  # 128 + SIGINT
    except BrokenPipeError:
        # The reader went away (`lensfit info 0001 | head -3`): stop quietly, as Unix tools
        # do; stdout goes to /dev/null so the flush at exit does not raise again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, what a shell reports for such a tool


if __name__ == "__main__":
    sys.exit(main())
