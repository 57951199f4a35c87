"""Shared helpers for the lensfit tests: synthetic lenses built from surface lists, and one
quick run of the whole fitting stage shared by the folder and trust tests."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from lensfit.fitting import FitOptions, SystemFit
from lensfit.prescription import Lens, load_lens, make_lens
from lensfit.sample import Domain, default_domain

# Small pursuit budgets: the stage's plumbing (files, tables, the PSF check), not the
# quality of the fit, is what the tests of a quick run look at
QUICK_PURSUIT = FitOptions(method="pursuit", max_degree=5, phase_degree=6, max_terms=30,
                           piston_terms=10, train_groups=200, train_per_group=8,
                           test_groups=40, test_per_group=8)
# f/8: stage.run measures the PSF against exact rays after every fit; its table at f/2
# has cells of 2048 stop points (~40 s on a busy 2-core machine), at f/8 ~10 s
QUICK_F_NUMBER = 8.0


@dataclass
class QuickRun:
    """What lensfit.stage.run gave and wrote for lens 0001."""

    lens: Lens
    domain: Domain
    options: FitOptions
    fits: list[SystemFit]
    figures: dict[str, Any]
    generated: Path  # the generated_dir passed to stage.run
    folder: Path  # generated/<lens folder>/


@pytest.fixture
def build_lens() -> Callable[..., Lens]:
    """``build_lens(surfaces, coating=None, **lens_info)`` -> validated Lens."""

    def build(surfaces, coating=None, **info) -> Lens:
        return make_lens(surfaces, coating=coating, file="<test>", **info)

    return build


@pytest.fixture(scope="session")
def quick_run(tmp_path_factory) -> QuickRun:
    """stage.run as `lensfit fit 0001 --f-number 8` runs it, with small budgets, without
    timing and report (~12 s: the fit ~0.5 s, the PSF table the rest)."""
    from lensfit.codegen.generate import lens_folder_name
    from lensfit.pipeline import stage

    lens = load_lens("0001")
    domain = default_domain(lens, QUICK_F_NUMBER)
    gen = tmp_path_factory.mktemp("generated")
    fits, figures = stage.run(lens, domain=domain, options=QUICK_PURSUIT, generated_dir=gen,
                              timing=False)
    return QuickRun(lens, domain, QUICK_PURSUIT, fits, figures, gen,
                    gen / lens_folder_name(lens))
