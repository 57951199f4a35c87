"""The runtime's image of a fitted ghost against exactly traced ghost rays (issue 13,
deliverable 5): lens 0001's committed ghost tables (generated/.../ghosts/) rendered by
lensrt with the same stop points as :func:`lensfit.psf.exact_psf` with ``ghost=`` sums
over (so Monte Carlo noise cancels), and the ghost's power against the direct image's.

* Shape: relative L2 of the normalised intensities <= 3% (the issue's bound) on the
  window of the table's trust cell at 550 nm.
* Energy: the ghost's power over the direct image's power, both from lensrt renders
  (pixel sums times the pixel area: lensrt's image is calibrated irradiance), against
  the enumeration's exact-ray estimate (:func:`lensfit.ghosts.enumerate.enumerate_ghosts`,
  Fresnel and coatings on every surface, a grid of rays): within 3% (the estimate's own
  spread is 1.2% against an independent full-disc grid, tests/fit/ghosts/test_enumerate.py).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lensfit import psf
from lensfit.codegen.table import read_table
from lensfit.ghosts.enumerate import enumerate_ghosts
from lensfit.ghosts.sample import ghost_half
from lensfit.prescription import load_lens

ROOT = Path(__file__).resolve().parents[2]
FOLDER = ROOT / "generated" / "0001-angenieux-double-gauss"
LAMBDA = 550.0
F_NUMBER = 8.0


def normalised(image: np.ndarray) -> np.ndarray:
    a = np.abs(image) ** 2 if np.iscomplexobj(image) else np.asarray(image, dtype=float)
    return a / a.sum()


@pytest.fixture(scope="module")
def lens():
    return load_lens("0001")


@pytest.fixture(scope="module")
def report():
    return json.loads((FOLDER / "ghosts" / "ghosts.json").read_text())


def _render(rt, table: Path, points: np.ndarray, radius: float, window: tuple, n: int,
            light: tuple[float, float]):
    lens_c = rt.load(table)
    r = rt.create(lens_c, width=n, height=n, width_mm=window[2], center=window[:2],
                  focus_offset_mm=0.0, radius_mm=radius, wavelengths=[LAMBDA],
                  lights=[light])
    r.splat_points(points)
    return r.image()[0]


@pytest.mark.parametrize("label", ["0-2", "2-6", "4-8"])
def test_runtime_ghost_matches_exact_ghost_rays(rt, lens, report, label):
    g = next(x for x in report["ghosts"] if x["label"] == label)
    cell = next(c for c in g["trust"] if c["wavelength_nm"] == LAMBDA)
    table = FOLDER / "ghosts" / f"ghost_{g['first']}_{g['second']}.table"
    radius = read_table(table.read_text()).lens.stop_radius_f1_mm / F_NUMBER
    points = psf.sunflower_points(1000, radius)
    cx, cy, width = cell["window"]
    light = tuple(cell["field_deg"])
    exact = psf.exact_psf(lens, ghost=ghost_half(lens, g["first"], g["second"]),
                          stop_radius_mm=radius, aperture_xy_mm=points, wavelength_nm=LAMBDA,
                          width=32, height=32, width_mm=width, center_x_mm=cx, center_y_mm=cy,
                          field_deg=light)
    got = _render(rt, table, points, radius, (cx, cy, width), 32, light)
    # The table's own trust figure at this cell is 0.04% (0-2) and 0.9% (4-8) (measured
    # here after normalising: 4.5e-5 and 0.85%); the
    # runtime adds its float kernel and pruning (<= 4e-2 of the field at worst, measured
    # 3e-5 - 2e-4 on the direct path: tests/runtime/test_lens_psf.py)
    err = float(np.linalg.norm(normalised(got) - normalised(exact))
                / np.linalg.norm(normalised(exact)))
    print(f"{label}: runtime against exact ghost rays {err:.2e}")
    assert err <= 0.03, err


def test_ghost_power_against_the_exact_estimate(rt, lens, report):
    """The runtime's 4-8 power over its direct power at f/8 on axis, 550 nm, against the
    enumeration. Random samples with the unbiased estimator: the paper's estimator adds
    variance / N to every pixel, which over the ghost's 96 x 96 window added +9% at
    N = 2^14 and +0.3% at 2^16 (measured); unbiased, 2^17 samples leave ~0.5% noise.
    Measured 8.43e-6 against the estimate's 8.32e-6 (1.3%)."""
    g = next(x for x in report["ghosts"] if x["label"] == "4-8")
    table = FOLDER / "ghosts" / "ghost_4_8.table"
    radius = read_table(table.read_text()).lens.stop_radius_f1_mm / F_NUMBER
    est = enumerate_ghosts(lens, f_number=F_NUMBER, wavelengths_nm=(LAMBDA,),
                           pairs=[(g["first"], g["second"])])[0]

    def power(path: Path, width: float, n: int) -> float:
        lens_c = rt.load(path)
        r = rt.create(lens_c, width=n, height=n, width_mm=width, center=(0.0, 0.0),
                      focus_offset_mm=0.0, radius_mm=radius, wavelengths=[LAMBDA],
                      lights=[(0.0, 0.0)], sampler="random", estimator="unbiased")
        r.run(1 << 17)
        return float(r.image()[0].sum()) * (width / n) ** 2

    # Windows that hold each image's power to well under 1%: the direct PSF at f/8 is
    # ~5 um across (0.2 mm holds its halo), the ghost's footprint radius is 0.06 mm
    ghost = power(table, 8 * est.radius_mm[0], 96)
    direct = power(FOLDER / "lens0001.table", 0.2, 96)
    print(f"4-8 power over direct: runtime {ghost / direct:.4g}, estimate {est.energy[0]:.4g}")
    assert ghost / direct == pytest.approx(est.energy[0], rel=0.03)
