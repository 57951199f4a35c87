"""The whole fitting stage for one lens: sample, fit, generate code, report.

    prescription -> rays (sample) -> polynomials (fitting) -> trust (PSF against exact
    traces) -> code (generate) -> report
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from lensfit.fitting import FitOptions, SystemFit, fit_lens
from lensfit.generate import lens_files, lens_folder_name, write_folder
from lensfit.glass.ranges import Wavelengths
from lensfit.prescription.model import Lens
from lensfit.report import measure, write_report
from lensfit.sample.domain import Domain, default_domain, fit_wavelengths
from lensfit.scene import Scene, scene_wavelengths
from lensfit.trust import psf_vs_exact, trust_figures


def run(lens: Lens, *, domain: Domain | None = None, options: FitOptions | None = None,
        generated_dir: Path | None = None, report_dir: Path | None = None,
        timing: bool = True, flat: bool = False, scene: Scene | None = None,
        glsl: bool = False, wavelengths: Wavelengths | None = None,
        ) -> tuple[list[SystemFit], dict[str, Any]]:
    """Fit ``lens``; measure its PSF against exactly traced rays (:mod:`lensfit.trust`);
    write ``generated_dir/<lens>/`` (``generated_dir`` itself with ``flat``) and
    ``report_dir`` when given. With ``scene`` (a scene fit) the PSF check uses the
    scene's lights, wavelengths and focus. ``glsl`` adds the GLSL source to the folder.

    ``wavelengths``: the domain's band and why (:func:`lensfit.sample.fit_wavelengths`),
    recorded in fit.json, the table's comment and the report. By default: the default
    band without ``domain``, else the scene's when the domain is the scene's
    (:func:`lensfit.scene.scene_wavelengths`), else the domain's, "asked for"."""
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
    # allows extrapolation (lensfit.glass.ranges; the report then lists them)
    wavelengths.check(lens)
    options = options or FitOptions()
    t0 = time.perf_counter()
    fits = fit_lens(lens, domain, options)
    fit_seconds = time.perf_counter() - t0
    systems = [f.system for f in fits]
    if scene is None:
        table = psf_vs_exact(lens, systems, domain)
    else:
        lams = sorted(scene.wavelengths_nm)
        table = psf_vs_exact(
            lens, systems, domain, wavelengths=sorted({lams[0], lams[len(lams) // 2],
                                                       lams[-1]}),
            fields=[(f"light{i}", (lt.field_x_deg, lt.field_y_deg), lt.distance_mm)
                    for i, lt in enumerate(scene.lights)],
            focus_mm=scene.focus_offset_mm)
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
        write_folder(folder, lens_files(lens, systems, meta, trust))
    figures = measure(lens, fits, timing=timing)
    figures["fit_seconds"] = fit_seconds
    figures["domain"] = domain.to_dict()
    figures["wavelengths"] = wavelengths.to_dict()
    figures["psf_vs_exact"] = table
    figures["psf_target"] = options.psf_target
    figures["method"] = options.method
    if report_dir is not None:
        write_report(lens, fits, figures, report_dir)
    return fits, figures
