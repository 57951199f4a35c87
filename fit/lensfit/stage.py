"""The whole fitting stage for one lens: sample, fit, generate code, report.

    prescription -> rays (sample) -> polynomials (fitting) -> code (generate) -> report
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from lensfit.fitting import FitOptions, SystemFit, fit_lens
from lensfit.generate import lens_files, lens_folder_name, write_folder
from lensfit.prescription.model import Lens
from lensfit.report import measure, write_report
from lensfit.sample.domain import Domain, default_domain


def run(lens: Lens, *, domain: Domain | None = None, options: FitOptions | None = None,
        generated_dir: Path | None = None, report_dir: Path | None = None,
        timing: bool = True) -> tuple[list[SystemFit], dict[str, Any]]:
    """Fit ``lens``; write ``generated_dir/<lens>/`` and ``report_dir`` when given."""
    domain = domain or default_domain(lens)
    options = options or FitOptions()
    t0 = time.perf_counter()
    fits = fit_lens(lens, domain, options)
    fit_seconds = time.perf_counter() - t0
    systems = [f.system for f in fits]
    if generated_dir is not None:
        meta = {"lens": lens.name, "lens_file": Path(lens.source_file).name,
                "domain": domain.to_dict(), "options": options.to_dict(),
                "held_out": [{k: v for k, v in o.to_dict().items()
                              if k not in ("ns_per_eval_double", "ns_per_eval_float")}
                             for f in fits for o in f.outputs]}
        write_folder(generated_dir / lens_folder_name(lens), lens_files(lens, systems, meta))
    figures = measure(lens, fits, timing=timing)
    figures["fit_seconds"] = fit_seconds
    figures["domain"] = domain.to_dict()
    if report_dir is not None:
        write_report(lens, fits, figures, report_dir)
    return fits, figures
