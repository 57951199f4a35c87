"""The runtime's PSF of a fitted real lens against the same sum in Python.

Two comparisons, each with the same aperture points on both sides (so Monte Carlo noise
cancels and only the transport differs):

* C against ``lensfit.psf.poly_psf`` (the same polynomials evaluated in float64 numpy):
  checks the runtime's per-pixel specialisation, phase basis, pruning, float kernel and
  clipping, for the committed fit of the default lens (its version-3 table) at f/2, f/8
  and f/32;
* C against ``lensfit.psf.exact_psf`` (exactly traced rays, no polynomials): checks the
  whole chain prescription -> fit -> table -> runtime. This test fits the scene's own
  domain (f/8, 530-570 nm, 4 deg field, focus 0.1-0.35 mm) with the sparse pursuit (the
  method of the first fits, ``method="pursuit"``) to 5e-4 waves, as a user wanting a 2%
  PSF would, and asserts 2%. The fitting stage also measures the fit's PSF against
  exact rays (lensfit.trust) and writes it into the table the runtime loads; the test
  checks the runtime's PSF against that figure too. (The committed fit, by the tensor
  method over the whole f/2 domain, is tested against exact rays in
  tests/fit/test_trust.py.)

Intensities are compared normalised to unit sum over the window: lensfit.psf applies no
Huygens amplitude factor, and the runtime's (constant across a window of a few Airy
radii to 1e-5) would only scale the image.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from lensfit.codegen.table import read_table
from lensfit.fitting import FitOptions
from lensfit.paraxial.paraxial import stop_radius_for_f_number
from lensfit.pipeline.stage import run
from lensfit.prescription import load_lens
from lensfit.psf import psf
from lensfit.sample.domain import default_domain

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table"
LAMBDA = 550.0
FIELD = (-3.0, -2.0)


def normalised(image: np.ndarray) -> np.ndarray:
    a = np.abs(image) ** 2 if np.iscomplexobj(image) else np.asarray(image, dtype=float)
    return a / a.sum()


def rel_l2(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.linalg.norm(a - ref) / np.linalg.norm(ref))


def scene(rt, lens_c, lens, f_number: float, n: int = 24):
    """Stop radius, best focus, window and aperture points for an off-axis light."""
    radius = stop_radius_for_f_number(lens, f_number)
    focus = psf.best_focus_offset(lens, radius, LAMBDA)
    center = rt.image_point(lens_c, FIELD, LAMBDA, focus)
    window = 6 * 1.22 * LAMBDA * 1e-6 * max(f_number, 8)  # three Airy radii each side
    points = psf.sunflower_points(600, radius)
    python = dict(stop_radius_mm=radius, aperture_xy_mm=points, field_deg=FIELD,
                  wavelength_nm=LAMBDA, focus_offset_mm=focus, width=n, height=n,
                  width_mm=window, center_x_mm=center[0], center_y_mm=center[1])
    c = dict(width=n, height=n, width_mm=window, center=center, focus_offset_mm=focus,
             radius_mm=radius, wavelengths=[LAMBDA], lights=[FIELD])
    return points, python, c


def render_points(rt, lens_c, points: np.ndarray, precision: str, **kwargs) -> np.ndarray:
    # Pixel centres, as the Python sums are (the box filter would average sub-pixels)
    r = rt.create(lens_c, precision=precision, pixel_filter="point", **kwargs)
    r.splat_points(points)
    return r.image()[0]


@pytest.fixture(scope="module")
def lens():
    return load_lens("0001")


@pytest.mark.parametrize("f_number", [2.0, 8.0, 32.0])
def test_runtime_matches_python_polynomials(rt, lens, f_number):
    lens_c = rt.load(TABLE)
    systems = read_table(TABLE.read_text(encoding="utf-8"))
    points, python, c = scene(rt, lens_c, lens, f_number)
    ref = normalised(psf.poly_psf(systems, **python))
    # Double precision, nothing pruned: only rounding and the runtime's Huygens factor,
    # which varies by < 1e-5 across the window, separate the two sums
    assert rel_l2(normalised(render_points(rt, lens_c, points, "double", **c)), ref) < 1e-4
    # Default: float kernel, phase basis and pruning. The pruning drops at most 3e-3
    # waves of phase per splat, which bounds the field error by 2 pi 3e-3 = 1.9e-2 and
    # the relative L2 of the intensity by about twice that; measured 3e-5 - 2e-4
    assert rel_l2(normalised(render_points(rt, lens_c, points, "default", **c)), ref) < 4e-2


@pytest.fixture(scope="module")
def scene_fit(tmp_path_factory, lens):
    """Fit the scene's own domain by the pursuit: f/8, 530-570 nm, a 4 deg field (about
    10 s on 1000 x 8 training rays per system, which reach every target; and ~10 s for
    the stage's PSF table: two stops, two lights, three wavelengths)."""
    domain = dataclasses.replace(default_domain(lens, f_number=8.0), field_deg=4.0,
                                 sensor_radius_mm=7.5, wavelength_min_nm=530.0,
                                 wavelength_max_nm=570.0, focus_min_mm=0.1, focus_max_mm=0.35)
    options = FitOptions(method="pursuit", target_waves=5e-4, target_position_um=0.02,
                         target_tau=1e-5, train_groups=1000, test_groups=200)
    out = tmp_path_factory.mktemp("scene-fit")
    fits, _ = run(lens, domain=domain, options=options, generated_dir=out, timing=False)
    assert all(o.reached for f in fits for o in f.outputs)  # the premise of the 2% below
    return next(out.glob("*/lens0001.table"))


def test_runtime_matches_exact_trace(rt, lens, scene_fit):
    lens_c = rt.load(scene_fit)
    points, python, c = scene(rt, lens_c, lens, 8.0)
    exact = normalised(psf.exact_psf(lens, **python))
    got = rel_l2(normalised(render_points(rt, lens_c, points, "default", **c)), exact)
    # The fit reaches 5e-4 waves and 0.02 um; 2 pi 5e-4 bounds the field error at 0.3%,
    # well inside the 2% (measured 0.24%; the table claims 0.59%)
    assert got < 0.02
    # The table the runtime loaded says how far its PSF is from exact rays (the worst of
    # lensfit.trust's cells over this domain). This light, window and point set are not
    # one of its cells, and the runtime adds its float kernel and pruning (< 4e-2 of the
    # polynomial PSF at worst, measured 3e-5 - 2e-4 above): within twice the claim plus
    # the pruning's measured share (5e-4)
    claimed = read_table(scene_fit.read_text(encoding="utf-8")).trust["psf_vs_exact"]
    print(f"runtime against exact rays {got:.3g}, the table claims {claimed:.3g}")
    assert got <= 2 * claimed + 5e-4
