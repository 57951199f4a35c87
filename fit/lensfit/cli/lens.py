"""``lensfit info``, ``draw``, ``import``, ``export``, ``list`` and ``check``: a lens
prescription, its paraxial table, its drawing and its files.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path

import numpy as np

from lensfit.cli.common import (
    MAX_RAYS,
    _check_file,
    _check_folder,
    _fmt,
    _glass_policy,
    _print_glass_ranges,
)
from lensfit.common.atomic import write_atomic, write_files
from lensfit.common.errors import InputError, LensError

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
    from lensfit.common.errors import LensError
    from lensfit.paraxial.paraxial import f_number_for_stop_radius
    from lensfit.sample.domain import (
        declared_fit,
        default_domain,
        field_cap_note,
        stated_design,
    )

    try:
        d = default_domain(lens)
    except (InputError, LensError) as e:
        print(f"  {'default domain':20s}none: {e}")
        return
    stated = stated_design(lens)
    frame = "a 36 x 24 mm frame, as far as the chief ray passes"
    source = ("the lens file's [fit]" if declared_fit_keys(lens) else
              "the design the lens file states" if len(stated) == 2 else
              f"the f-number the lens file states; the field of {frame}"
              if "f_number" in stated else
              "the field of view the lens file states; f/2, or wide open if slower"
              if stated else frame)
    field = f"{d.field_deg:.4g} deg" + (f" x {d.field_y_deg:.4g} deg" if d.field_y_deg else "")
    f_n = abs(f_number_for_stop_radius(lens, d.stop_radius_mm))
    print(f"  {'default domain':20s}f/{f_n:.3g}, "
          f"half field {field}, image circle {d.sensor_radius_mm:.4g} mm, sensor travel "
          f"{d.focus_min_mm:.4g} to {d.focus_max_mm:.4g} mm ({source})")
    if ("f_number" in stated and "f_number" not in declared_fit(lens)
            and d.stop_radius_mm == lens.stop_radius_max_mm and stated["f_number"] < f_n):
        print(f"  {'':20s}the lens states f/{stated['f_number']:g}; its stop opens to "
              f"f/{f_n:.3g} (paraxial, d line): fitted wide open")
    note = field_cap_note(lens, d)
    if note:
        print(f"  {'':20s}{note}")


def declared_fit_keys(lens) -> bool:
    """The lens file declares part of the domain in [fit]."""
    from lensfit.sample.domain import declared_fit

    return any(k in declared_fit(lens) for k in ("f_number", "field_deg"))


def cmd_draw(args: argparse.Namespace) -> int:
    from lensfit.prescription import load_lens
    from lensfit.sample.draw import draw_lens

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
    from lensfit.paraxial.validate import efl_check
    from lensfit.prescription import list_lenses

    paths = args.lens or [str(p) for p in list_lenses()]
    bad = 0
    for p in paths:
        ok, msg = efl_check(p)
        bad += not ok
        print(("ok    " if ok else "FAIL  ") + msg)
    return 1 if bad else 0
