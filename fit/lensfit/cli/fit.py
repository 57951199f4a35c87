"""``lensfit fit``, ``report``, ``scene``, ``regenerate`` and ``upgrade-table``: a lens's
polynomial fit, its report and its generated folder.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from lensfit.cli.common import EXIT_MISS, _check_folder, _coated, _generated, _glass_policy, _pair
from lensfit.common.atomic import write_files
from lensfit.common.errors import InputError


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
                     aperture_points=64, field_degrees=(4, 6), aperture_degree=8,
                     stop_pilot=False)
    try:  # FitOptions checks its values (--psf-target) and says which is wrong
        return FitOptions(**extra)
    except ValueError as e:
        raise InputError(str(e)) from None


def _miss_note(o: dict) -> str:
    """'' for an output within its target; else why it is not."""
    from lensfit.trust.report import LIMIT_WORDS

    if o["reached"]:
        return ""
    why = LIMIT_WORDS.get(o.get("limit") or "degree", o.get("limit"))
    return f"  (target {o['target']:.3g} not reached: limited by {why})"


def _print_trust(fig: dict) -> None:
    from lensfit.trust.check import cell_label

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
    from lensfit.prescription.ranges import out_of_range

    for o in out_of_range(lens, domain["wavelength_min_nm"], domain["wavelength_max_nm"]):
        print(f"  glass extrapolated: {o.describe()}")


def _resumable(args: argparse.Namespace) -> dict:
    """stage.run's keywords of `lensfit fit`: checkpoints (lensfit.pipeline.cache: a rerun
    resumes) and the progress bar, on a terminal unless --no-progress."""
    return {"checkpoints": True, "progress": not args.no_progress and sys.stderr.isatty()}


def cmd_fit(args: argparse.Namespace) -> int:
    from lensfit.codegen.generate import lens_folder_name
    from lensfit.pipeline import stage
    from lensfit.prescription import load_lens

    # Outputs first: a bad folder must not surface after the whole fit
    if args.generated:
        _check_folder(args.generated, "--generated")
    if args.report:
        _check_folder(args.report, "--report")
    lens = _glass_policy(_coated(load_lens(args.lens), args), args)
    gen = _generated(args)
    if args.scene:
        from lensfit.codegen.scene import load_scene, scene_domain, scene_wavelengths

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
    from lensfit.codegen.generate import lens_folder_name
    from lensfit.pipeline import stage
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
    from lensfit.codegen import emit_c
    from lensfit.codegen import scene as sc
    from lensfit.codegen.generate import (
        lens_folder_name,
        lens_prefix,
        read_fit_json,
        scene_files,
    )
    from lensfit.prescription import load_lens
    from lensfit.trust.report import ns_per_eval

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
    from lensfit.codegen.generate import lens_folder_name, regenerate
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
    from lensfit.codegen.generate import upgrade_table

    for name in args.files:
        path = Path(name)
        if not path.is_file():
            raise InputError(f"{path}: no such table file")
        done = upgrade_table(path)
        print(f"{path}: {'upgraded to version 5' if done else 'not version 3 or 4: unchanged'}")
    return 0
