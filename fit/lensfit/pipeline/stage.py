"""The whole fitting stage for one lens: sample, fit, generate code, report.

    prescription -> rays (sample) -> polynomials (fitting) -> trust (PSF against exact
    traces) -> code (generate) -> report

Deterministic: the same lens, domain and options give the same bytes in the generated
folder (no timings there; the fits and the PSF check use fixed seeds and single-threaded
BLAS). Each folder is replaced as a whole or not at all (:func:`lensfit.common.atomic
.replacing_folder`), so an interrupted run leaves the previous folders as they were.
With ``checkpoints`` each finished system and the PSF check are kept
(:mod:`lensfit.pipeline.cache`) and a rerun of the same fit resumes from them.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from lensfit.codegen.generate import fit_folder_keep, lens_files, lens_folder_name
from lensfit.codegen.scene import Scene, scene_wavelengths
from lensfit.common.atomic import replace_folder, replacing_folder
from lensfit.fitting import FitOptions, SystemFit, fit_lens
from lensfit.fitting.lens import SYSTEMS
from lensfit.fitting.tensor import OutOfReach
from lensfit.poly.tensor import single_blas
from lensfit.prescription.model import Lens
from lensfit.prescription.ranges import Wavelengths
from lensfit.sample.domain import Domain, default_domain, fit_wavelengths
from lensfit.trust.check import psf_vs_exact, trust_figures
from lensfit.trust.report import measure, write_report


@contextlib.contextmanager
def _sigterm_exits() -> Iterator[None]:
    """SIGTERM raises SystemExit(143) inside the block (in the main thread), so that
    the cleanup of an interrupted write runs as for Ctrl-C."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        raise SystemExit(128 + signum)

    old = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def _psf_args(scene: Scene | None) -> dict[str, Any]:
    """psf_vs_exact's keywords for a scene fit (its lights, wavelengths, focus)."""
    if scene is None:
        return {}
    lams = sorted(scene.wavelengths_nm)
    return {"wavelengths": sorted({lams[0], lams[len(lams) // 2], lams[-1]}),
            "fields": [(f"light{i}", (lt.field_x_deg, lt.field_y_deg), lt.distance_mm)
                       for i, lt in enumerate(scene.lights)],
            "focus_mm": scene.focus_offset_mm}


def run(lens: Lens, *, domain: Domain | None = None, options: FitOptions | None = None,
        generated_dir: Path | None = None, report_dir: Path | None = None,
        timing: bool = True, flat: bool = False, scene: Scene | None = None,
        glsl: bool = False, wavelengths: Wavelengths | None = None,
        progress: bool = False, checkpoints: bool = False,
        cache_root: Path | None = None) -> tuple[list[SystemFit], dict[str, Any]]:
    """Fit ``lens``; measure its PSF against exactly traced rays (:mod:`lensfit.trust.check`);
    write ``generated_dir/<lens>/`` (``generated_dir`` itself with ``flat``) and
    ``report_dir`` when given, each replaced as a whole. With ``scene`` (a scene fit)
    the PSF check uses the scene's lights, wavelengths and focus. ``glsl`` adds the
    GLSL source to the folder. ``progress``: a bar with ETA on stderr
    (:mod:`lensfit.pipeline.progress`). ``checkpoints``: keep each finished step in
    ``cache_root`` (default :func:`lensfit.pipeline.cache.cache_root`) and resume from the
    steps kept there; removed once everything is written.

    ``wavelengths``: the domain's band and why (:func:`lensfit.sample.fit_wavelengths`),
    recorded in fit.json, the table's comment and the report. By default: the default
    band without ``domain``, else the scene's when the domain is the scene's
    (:func:`lensfit.codegen.scene.scene_wavelengths`), else the domain's, "asked for"."""
    from lensfit.pipeline.cache import FitCache, fit_key
    from lensfit.pipeline.progress import FitProgress, step_weights

    if wavelengths is None and domain is None:
        wavelengths = fit_wavelengths(lens)
    elif wavelengths is None:
        band = (domain.wavelength_min_nm, domain.wavelength_max_nm)
        wavelengths = scene_wavelengths(lens, scene) if scene is not None else None
        if wavelengths is None or wavelengths.range_nm != band:
            wavelengths = fit_wavelengths(lens, band, "the domain given")
    domain = domain or default_domain(lens, wavelengths_nm=wavelengths.range_nm)
    if wavelengths.range_nm != (domain.wavelength_min_nm, domain.wavelength_max_nm):
        raise ValueError(f"stage.run: wavelengths {wavelengths.range_nm} are not the "
                         f"domain's {domain.wavelength_min_nm}-{domain.wavelength_max_nm}")
    # Glasses outside their published range: refused before any work unless the lens
    # allows extrapolation (lensfit.prescription.ranges; the report then lists them)
    wavelengths.check(lens)
    options = options or FitOptions()
    psf_args = _psf_args(scene)
    cache = None
    done: list[str] = []
    if checkpoints:
        label = lens_folder_name(lens) + (f"-{scene.name}" if scene is not None else "")
        cache = FitCache(fit_key(lens, domain, options, psf_args), label, cache_root)
        kept = [name for name, _ in SYSTEMS if cache.load_system(name) is not None]
        for name, outs in SYSTEMS:
            if name in kept:
                done += [f"{name} sampled"] + [f"{name} {o}" for o, _ in outs]
        fitted = [cache.load_system(name) for name, _ in SYSTEMS]
        if all(fitted) and cache.load_psf([f.system for f in fitted]) is not None:
            done.append("psf")
            kept.append("the PSF check")
        if kept:
            print(f"lensfit: resuming from {cache.folder}: {', '.join(kept)} done",
                  file=sys.stderr)
    bar = FitProgress(step_weights((n, [o for o, _ in outs]) for n, outs in SYSTEMS), done,
                      enabled=progress, desc=f"fit {lens_folder_name(lens)}")
    try:
        with _sigterm_exits():
            fits, figures = _run(lens, domain, options, generated_dir, report_dir, timing,
                                 flat, scene, glsl, psf_args, cache, bar, wavelengths)
    except OutOfReach:
        # Refused (exit 2): a rerun of the same fit would be refused again, so no
        # checkpoint is kept for it
        bar.close()
        if cache is not None:
            cache.clear()
        raise
    except (KeyboardInterrupt, SystemExit):
        bar.close()
        if cache is not None and cache.folder.is_dir():
            print(f"lensfit: interrupted; the finished steps are kept in {cache.folder}: "
                  "the same command resumes from them", file=sys.stderr)
        raise
    finally:
        bar.close()
    if cache is not None:
        cache.clear()
    return fits, figures


# A fit whose worst PSF cell misses the target by at most this factor is fitted once
# more with a tighter phase target (stage._run); beyond it the degrees, not the target,
# are the limit and a second fit would only double the time
RETRY_WITHIN = 3.0
RETRY_MARGIN = 0.7  # the tighter target aims at this share of the PSF target


def _tighter(options: FitOptions, table: dict[str, Any],
             fits: Sequence[SystemFit] = ()) -> FitOptions | None:
    """The options of a second fit after a PSF table that missed its target by at most
    RETRY_WITHIN (the phase target scaled by RETRY_MARGIN target / worst, as the PSF's
    error scales with the phase's), or None: within target, beyond RETRY_WITHIN,
    options that do not allow it (``retry`` off, as --quick sets, or a target in waves
    given outright), or ``fits`` whose phases are all already within that tighter
    target (a second fit would stop where they did, or short of it: lens 0003's phases
    at 8.7e-5 and 1.2e-4 waves against a retry's 2.3e-4, its PSF miss at 1.65% both
    times, 70 CPU-s spent on the second)."""
    worst = table["worst"]["relative_l2"]
    if (not options.retry or options.target_waves is not None
            or not options.psf_target < worst <= RETRY_WITHIN * options.psf_target):
        return None
    scale = RETRY_MARGIN * options.psf_target / worst
    target = options.phase_target_waves * scale
    phases = [o.rms for f in fits for o in f.outputs if o.name.startswith("phi")]
    if phases and max(phases) <= target:
        return None
    return replace(options, target_waves=target, retry=False)


def _run(lens, domain, options, generated_dir, report_dir, timing, flat, scene, glsl,
         psf_args, cache, bar, wavelengths) -> tuple[list[SystemFit], dict[str, Any]]:
    # BLAS on one thread: the sums' rounding, and so the files' bytes, do not depend on
    # the machine's core count (the tensor fits already do this, lensfit.poly.tensor);
    # measured on 2 loaded cores it is faster too (PSF check of a --quick --f-number 8
    # fit of lens 0001: 5.4 s against 7.8 s), with the same table bit for bit
    with single_blas():
        t0 = time.perf_counter()
        fits = fit_lens(lens, domain, options, progress=bar, checkpoints=cache)
        fit_seconds = time.perf_counter() - t0
        systems = [f.system for f in fits]
        table = cache.load_psf(systems) if cache is not None else None
        if table is None:
            table = psf_vs_exact(lens, systems, domain, **psf_args)
            if cache is not None:
                cache.save_psf(table, systems)
        retry = _tighter(options, table, fits)
        if retry is not None:
            # The held-out RMS met its goal but a cell of the PSF table did not (the
            # PSF's error follows the phase error's RMS only on average: a triplet's
            # field edge or a singlet's axis at 450 nm reached 1.1-1.9% with every
            # output within its target): once more with the phase target cut by what
            # the worst cell missed, and the better table of the two kept
            t1 = time.perf_counter()
            retried = {"first_worst": table["worst"]["relative_l2"],
                       "first_cell": table["worst"], "target_waves": retry.target_waves,
                       "kept": "first"}
            try:
                again = fit_lens(lens, domain, retry)
            except OutOfReach:  # the tighter target is beyond the degrees: the first stays
                again = None
            if again is not None:
                table2 = psf_vs_exact(lens, [f.system for f in again], domain, **psf_args)
                if table2["worst"]["relative_l2"] < table["worst"]["relative_l2"]:
                    retried["kept"] = "second"
            fit_seconds += time.perf_counter() - t1
            if retried["kept"] == "second":
                # The polynomials written are the ones the kept table judged
                fits, table, options = again, table2, retry
                systems = [f.system for f in fits]
        else:
            retried = None
    bar("psf")
    trust = trust_figures(table, options.psf_target)
    if generated_dir is not None:
        meta = {"lens": lens.name, "lens_file": Path(lens.source_file).name,
                "domain": domain.to_dict(), "wavelengths": wavelengths.to_dict(),
                "options": options.to_dict(),
                "held_out": [{k: v for k, v in o.to_dict().items()
                              if k not in ("ns_per_eval_double", "ns_per_eval_float")}
                             for f in fits for o in f.outputs],
                "psf_vs_exact": {k: v for k, v in table.items() if k != "seconds"}}
        if glsl:
            meta["glsl"] = True
        if lens.variant == "uncoated":
            meta["coating"] = "none"  # regenerate() makes the same variant
        folder = generated_dir if flat else generated_dir / lens_folder_name(lens)
        files = lens_files(lens, systems, meta, trust)
        # Replaced as a whole; what other commands keep there (ghosts/, scenes/,
        # scene-fits/) is carried over, an earlier fit's files are not
        replace_folder(folder, files, keep=fit_folder_keep(files), mode=0o644)
    figures = measure(lens, fits, timing=timing)
    figures["fit_seconds"] = fit_seconds
    figures["domain"] = domain.to_dict()
    figures["wavelengths"] = wavelengths.to_dict()
    figures["psf_vs_exact"] = table
    figures["psf_target"] = options.psf_target
    if retried is not None:
        figures["retried"] = retried
    figures["method"] = options.method
    if report_dir is not None:
        with replacing_folder(report_dir) as tmp:
            write_report(lens, fits, figures, tmp)
    bar("write")
    return fits, figures
