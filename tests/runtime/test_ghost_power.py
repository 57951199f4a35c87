"""A ghost's power (and the direct image's) against exactly traced rays counted on the
sensor (issue 26, deliverable 0).

The reference shares nothing with lensrt's model of the stop's irradiance: a square
grid of rays on a plane in front of the lens, each carrying the light's irradiance on
that plane times its cell, is traced exactly along the ghost's path (Fresnel and
coatings at every surface, every housing clipping) and the transmittances of the rays
that reach the sensor are summed (:func:`lensfit.ghosts.enumerate.enumerate_ghosts`:
``energy`` x ``direct_power``). lensrt's image is irradiance relative to the light's
irradiance on the first vertex plane, so its pixel sum times the pixel area is the
same power.

Before the front group's flux Jacobian (lensrt 0.8) lensrt took the irradiance on the
stop to be 1 for every path: 0001's ghosts came out at 0.36-0.78 of this reference and
2004's ghost 0-2 at 4.1 (the issue's 1.15-2.31x and 5.4x, relative to the direct
path's). Bound 2% (the issue's): the reference's grid of 1e5 rays per wavelength and
path counts the footprint's edge cells to ~0.3% (2e5 gave the same ratios within 0.2%),
the fits' transmittance agrees with exact rays to 0.05% (the tables' trust energy
ratios), and each render is integrated to an estimated 1%, on windows holding the whole
footprint; measured 0.1-1.2%.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lensfit.ghosts.enumerate import enumerate_ghosts
from lensfit.prescription import load_lens

ROOT = Path(__file__).resolve().parents[2]
GENERATED = ROOT / "generated"
WAVELENGTHS = (450.0, 550.0, 650.0)
LIGHT = (-6.0, -4.0)
BOUND = 0.02


def _window(est) -> tuple[tuple[float, float], float]:
    """Centre and half width (mm) of a square holding every wavelength's footprint."""
    spots = [(np.array(c), e) for c, e in zip(est.centre_mm, est.extent_mm, strict=True)
             if c is not None]
    lo = np.min([c - e for c, e in spots], axis=0)
    hi = np.max([c + e for c, e in spots], axis=0)
    centre = 0.5 * (lo + hi)
    return (float(centre[0]), float(centre[1])), 0.55 * float(np.max(hi - lo))


def _power(rt, table: Path, f_number: float, light, centre, half_x: float, half_y: float,
           pitch_y: float) -> np.ndarray:
    """Rendered power per wavelength over a window of 96 columns and rows of pitch_y."""
    rows = max(96, int(round(2 * half_y / pitch_y)))
    # Pixel centres: at these pitches (rows below lambda / D in the thin direction, the
    # long direction smooth over many columns) their sum is the power; the box filter's
    # automatic counts would take 16 x 16 points per 39 um column
    r = rt.create(rt.load(table), pixel_filter="point", width=96, height=rows, width_mm=2 * half_x,
                  height_mm=2 * half_y, center=centre, f_number=f_number,
                  lights=[(light[0], light[1], 0.0, 0.0)], wavelengths=list(WAVELENGTHS))
    r.integrate_auto_to(0.01)
    return r.image().astype(np.float64).sum(axis=(1, 2)) * (2 * half_x / 96) * (2 * half_y / rows)


def _check(rt, lens_name: str, folder: Path, f_number: float, labels: list[str],
           thin_half_y: float = 0.0, light: tuple[float, float] = LIGHT) -> None:
    lens = load_lens(lens_name)
    pairs = [tuple(int(v) for v in lab.split("-")) for lab in labels]
    estimates = enumerate_ghosts(lens, f_number=f_number, light=light,
                                 wavelengths_nm=WAVELENGTHS, rays=10000, fine_rays=100000,
                                 pairs=pairs)
    info = estimates[0].info
    direct = np.array(info["direct_power"])
    # The direct image: in focus, a few um across; 0.2 mm holds all but ~0.3% of its
    # halo, and a pitch below lambda N / 2 samples its power exactly (Poisson summation)
    table = next(folder.glob("lens*.table"))
    xy = rt.image_point(rt.load(table), (light[0], light[1], 0.0, 0.0), 550.0)
    got = _power(rt, table, f_number, light, xy, 0.1, 0.1, 0.1 / 64)
    ratios = {"direct": got / direct}
    for est in estimates:
        centre, half = _window(est)
        # A thin anamorphic streak: rows of 1 um (below lambda N at f/4) over its height
        half_y, pitch = (thin_half_y, 0.001) if thin_half_y else (half, 2 * half / 96)
        got = _power(rt, folder / "ghosts" / f"ghost_{est.first}_{est.second}.table",
                     f_number, light, centre, half, half_y, pitch)
        ratios[f"{est.first}-{est.second}"] = got / (np.array(est.energy) * direct)
    for name, q in ratios.items():
        print(f"{lens_name} {name} from {light}: rendered / traced rays per wavelength "
              f"{np.round(q, 4)}")
    for name, q in ratios.items():
        assert np.all(np.abs(q - 1.0) <= BOUND), (name, q)


@pytest.mark.slow  # 76 s; test_2004_ghosts_against_traced_rays checks the same in make test
def test_0001_ghosts_against_traced_rays(rt):
    # Every ghost table of 0001 whose path reaches the sensor from this light; 4-8 (its
    # reflections on both sides of the stop) is blocked here and seen on the axis
    folder = GENERATED / "0001-angenieux-double-gauss"
    _check(rt, "0001", folder, 8.0, ["0-2", "0-4", "2-4", "2-6"])
    _check(rt, "0001", folder, 8.0, ["4-8"], light=(0.0, 0.0))


def test_2004_ghosts_against_traced_rays(rt):
    # 2004's kept ghosts, streaks 2-3 mm long and a few um tall: 0-2 reflects at the
    # outer cylinder (the paper's Figure 10 ghost; 4.1x this reference before). The
    # uncoated variant's tables share these paths (measured the same to 0.4%)
    _check(rt, "2004", GENERATED / "2004-schneider-anamorphic", 4.0, ["0-2", "2-5"],
           thin_half_y=0.06)
