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

from lensfit.codegen.table import read_table
from lensfit.ghosts.enumerate import enumerate_ghosts
from lensfit.prescription import load_lens
from lensfit.psf import psf
from lensfit.sample.ghost import ghost_half

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
                  pixel_filter="point",  # the exact sums are at pixel centres
                  focus_offset_mm=0.0, radius_mm=radius, wavelengths=[LAMBDA],
                  lights=[light])
    r.splat_points(points)
    return r.image()[0]


def against_exact(rt, lens, folder: Path, g: dict, f_number: float) -> tuple[float, Path]:
    """Ghost ``g`` (a ghosts.json entry of ``folder``) rendered by lensrt at
    ``f_number`` with the same 1000 sunflower stop points as exactly traced ghost rays
    on the window of its 550 nm trust cell: the relative L2 of the normalised
    intensities, and the table."""
    cell = next(c for c in g["trust"] if c["wavelength_nm"] == LAMBDA)
    table = folder / "ghosts" / f"ghost_{g['first']}_{g['second']}.table"
    radius = read_table(table.read_text()).lens.stop_radius_f1_mm / f_number
    points = psf.sunflower_points(1000, radius)
    cx, cy, width = cell["window"]
    light = tuple(cell["field_deg"])
    exact = psf.exact_psf(lens, ghost=ghost_half(lens, g["first"], g["second"]),
                          stop_radius_mm=radius, aperture_xy_mm=points, wavelength_nm=LAMBDA,
                          width=32, height=32, width_mm=width, center_x_mm=cx, center_y_mm=cy,
                          field_deg=light)
    got = _render(rt, table, points, radius, (cx, cy, width), 32, light)
    return float(np.linalg.norm(normalised(got) - normalised(exact))
                 / np.linalg.norm(normalised(exact))), table


@pytest.mark.parametrize("label", ["0-2", "2-6", "4-8"])
def test_runtime_ghost_matches_exact_ghost_rays(rt, lens, report, label):
    g = next(x for x in report["ghosts"] if x["label"] == label)
    # The table's own trust figure at this cell is 0.04% (0-2) and 0.9% (4-8) (measured
    # here after normalising: 4.5e-5 and 0.85%); the
    # runtime adds its float kernel and pruning (<= 4e-2 of the field at worst, measured
    # 3e-5 - 2e-4 on the direct path: tests/runtime/test_lens_psf.py)
    err, _ = against_exact(rt, lens, FOLDER, g, F_NUMBER)
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
                      pixel_filter="point",
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


def _seven_blades(radius: float, rotation_deg: float):
    """The inside of a regular 7-gon with vertices on the circle of ``radius`` at
    ``rotation_deg`` + k 360/7 deg (straight blades), (x, y) mm arrays -> bool: on the
    inner side of every edge v_k -> v_k+1 (counter-clockwise), by the sign of the cross
    product. An implementation independent of lensrt's (edge normals at the apothem)."""
    ang = np.radians(rotation_deg) + 2 * np.pi * np.arange(8) / 7
    vx, vy = radius * np.cos(ang), radius * np.sin(ang)

    def inside(x, y):
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        ok = np.ones(np.broadcast(x, y).shape, dtype=bool)
        for k in range(7):
            ok &= (vx[k + 1] - vx[k]) * (y - vy[k]) - (vy[k + 1] - vy[k]) * (x - vx[k]) >= 0
        return ok

    return inside


def test_runtime_ghost_with_bladed_stop_matches_exact_ghost_rays(rt, lens, report):
    """Ghost 4-8 of 0001 (case C: its path crosses the stop plane twice more) at f/8 with
    a 7-blade stop (straight blades, rotated 15 deg): lensrt's render, which tests both
    crossings against the blades, against exactly traced ghost rays whose crossings are
    tested against the same polygon (``exact_psf(stop_shape=)``, the polygon written
    here in numpy), the same stop points (the 868 of 1000 sunflower points inside the
    polygon) on both sides. Bound: the issue's 3% relative L2; measured 1.6e-2 (the
    round stop's figure for this ghost is 0.9%: the polygon's corners add edge
    diffraction the fit was not trusted on).

    The circle-only test of the crossings (lensrt before: a round stop at the
    crossings, the blades only at the aperture point) is measurably wrong: the same
    render with a round aperture is 0.33 relative L2 from the bladed exact image and
    carries 1.16x its power (the exact round-stop image has 1.164x the bladed one's);
    asserted beyond 3x the bound and 5% of power."""
    g = next(x for x in report["ghosts"] if x["label"] == "4-8")
    cell = next(c for c in g["trust"] if c["wavelength_nm"] == LAMBDA)
    table = FOLDER / "ghosts" / f"ghost_{g['first']}_{g['second']}.table"
    radius = read_table(table.read_text()).lens.stop_radius_f1_mm / F_NUMBER
    inside = _seven_blades(radius, 15.0)
    points = psf.sunflower_points(1000, radius)
    points = points[inside(points[:, 0], points[:, 1])]
    cx, cy, width = cell["window"]
    light = tuple(cell["field_deg"])
    exact = psf.exact_psf(lens, ghost=ghost_half(lens, g["first"], g["second"]),
                          stop_radius_mm=radius, aperture_xy_mm=points, wavelength_nm=LAMBDA,
                          width=32, height=32, width_mm=width, center_x_mm=cx, center_y_mm=cy,
                          field_deg=light, stop_shape=inside)

    def render(**aperture) -> np.ndarray:
        r = rt.create(rt.load(table), width=32, height=32, width_mm=width, center=(cx, cy),
                      pixel_filter="point",
                      focus_offset_mm=0.0, radius_mm=radius, wavelengths=[LAMBDA],
                      lights=[light], **aperture)
        r.splat_points(points)
        return r.image()[0]

    def err(image: np.ndarray) -> float:
        return float(np.linalg.norm(normalised(image) - normalised(exact))
                     / np.linalg.norm(normalised(exact)))

    bladed = render(shape="blades", blades=7, rotation_deg=15.0)
    round_ = render()
    power = float(round_.sum() / bladed.sum())
    print(f"4-8, 7 blades: runtime against exact ghost rays {err(bladed):.2e}; circle-only "
          f"{err(round_):.2e}, power {power:.3f}x")
    assert len(points) > 800
    assert err(bladed) <= 0.03, err(bladed)
    assert err(round_) > 0.09, err(round_)
    assert power > 1.05, power


# --- 0009's visible ghosts (fitted over the f/8 stop) and 2004's kept ones --------------

GENERATED = ROOT / "generated"


@pytest.mark.parametrize("lens_id, folder, label, f_number", [
    ("0009", "0009-zeiss-biotar", "4-8", 8.0),
    ("0009", "0009-zeiss-biotar", "0-2", 8.0),
    ("2004", "2004-schneider-anamorphic", "2-5", 4.0),
    ("2004", "2004-schneider-anamorphic", "0-2", 4.0),
])
def test_committed_ghosts_against_exact_ghost_rays(rt, lens_id, folder, label, f_number):
    """lensrt's render of a committed ghost table, with the exact sums' stop points,
    against exactly traced ghost rays on the window of its 550 nm trust cell, within the
    issue's 3%. 0009's two visible ghosts at f/8 from (-6, -4) deg (`lensfit ghosts 0009
    --f-number 8 --light=-6,-4 --fit`: 6.5 and 1.7 stops above a photograph's black level)
    are fitted over the f/8 stop (over the f/2 stop they missed at 16.7% and 98%): a wider
    stop is refused with a message naming the fitted f-number, never rendered from
    polynomials beyond their stop. 2004's kept ghosts at f/4: 2-5, its brightest, and
    0-2, the reflection at its outer cylindrical element. Measured: 1.2e-2, 1.6e-3 (0009);
    8.9e-3, 3.4e-3 (2004)."""
    from lensrt_ctypes import LensrtError

    report = json.loads((GENERATED / folder / "ghosts" / "ghosts.json").read_text())
    g = next(x for x in report["ghosts"] if x["label"] == label)
    err, table = against_exact(rt, load_lens(lens_id), GENERATED / folder, g, f_number)
    print(f"{lens_id} {label}: runtime against exact ghost rays {err:.2e}")
    assert err <= 0.03, err
    def stop_of(path: Path) -> float:  # the stop radius a table's P_s was fitted over
        p_s = next(x for x in read_table(path.read_text()) if x.name == "P_s")
        return next(i.hi for i in p_s.inputs if i.name == "x_a")

    narrowed = stop_of(table) < 0.99 * stop_of(GENERATED / folder / f"lens{lens_id}.table")
    assert narrowed == (lens_id == "0009")
    if narrowed:
        radius = read_table(table.read_text()).lens.stop_radius_f1_mm / f_number
        assert g["fit_stop_radius_mm"] == pytest.approx(radius, rel=1e-12)
        cx, cy, width = g["trust"][0]["window"]
        with pytest.raises(LensrtError, match=r"f/2 .*wider than .*fitted for: f/8"):
            rt.create(rt.load(table), width=8, height=8, width_mm=width, center=(cx, cy),
                      f_number=2.0, wavelengths=[LAMBDA],
                      lights=[tuple(g["trust"][0]["field_deg"])])
