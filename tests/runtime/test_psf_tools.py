"""lensrt-psf's Monte Carlo error estimate and --target-error, and the PSF sheet tool.

The estimate is checked against the true error of the image lensrt-psf wrote (its phasor
sums, loaded into a render of the same scene) measured against a reference render with
16 or 32 times the samples, before the Sobol points resolve the integrand (where the difference
of the halves alone is several times too low) and after.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
PSF = ROOT / "build" / "runtime" / "runtime" / "lensrt-psf"
LENS0001 = ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table"
sys.path.insert(0, str(ROOT / "runtime" / "tools"))

import psf_sheet  # noqa: E402  (needs the path above)

# Small versions of the demo's scenes: light (-6, -4) deg, 7 curved blades, defocused
F8 = dict(light=(-6.0, -4.0), focus=0.2, f_number=8.0, blades=7, curvature=0.3, rotation=10.0,
          size=0.1, pixels=32, wavelengths=4)
F2 = dict(F8, f_number=2.0, size=0.2)
SCENE = F8
HALF_SEED_STEP = 0x9E3779B97F4A7C15  # lensrt-psf.c: the second half's seed is seed + this
ESTIMATE = re.compile(r"Monte Carlo error estimate: ([0-9.e+-]+)% relative L2 "
                      r"\(two independent halves, (\d+) samples per wavelength\)")


def psf_args(out: Path, samples: int, *extra: str, scene: dict = SCENE) -> list[str]:
    s = scene
    return [str(PSF), "--lens", str(LENS0001), "--light", "{:g},{:g}".format(*s["light"]),
            "--focus", str(s["focus"]), "--f-number", str(s["f_number"]),
            "--blades", str(s["blades"]), "--curvature", str(s["curvature"]),
            "--rotation", str(s["rotation"]), "--size", str(s["size"]),
            "--resolution", f"{s['pixels']}x{s['pixels']}",
            "--wavelengths", str(s["wavelengths"]), "--samples", str(samples),
            "--pixel-filter", "point",  # the estimator's checks, at pixel centres
            "--save-phasors", str(out), "--quiet", *extra]


def render(rt, lens, scene: dict, seed: int = 1):
    """A render of a scene as lensrt-psf sets it up (window centred on the chief ray)."""
    s = scene
    info = rt.info(lens)
    centre = rt.image_point(lens, s["light"], 0.5 * (info["wavelength_min_nm"]
                                                      + info["wavelength_max_nm"]), s["focus"])
    return rt.create(lens, width=s["pixels"], height=s["pixels"], width_mm=s["size"],
                     center=centre, focus_offset_mm=s["focus"], f_number=s["f_number"],
                     shape="blades", blades=s["blades"], blade_curvature=s["curvature"],
                     rotation_deg=s["rotation"], lights=[s["light"]],
                     wavelengths=s["wavelengths"], seed=seed, pixel_filter="point")


@pytest.fixture(scope="module")
def lens(rt):
    if not PSF.exists():
        pytest.skip(f"{PSF} is not built")
    return rt.load(LENS0001)


def rel_l2(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.linalg.norm(a - ref) / np.linalg.norm(ref))


def run_psf(args: list[str]) -> subprocess.CompletedProcess:
    run = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return run


# f/2 at 32768 samples: the Sobol points do not resolve the integrand yet, and the
# difference of the halves alone is 3x too low (the check below shows it); f/8 at 2048:
# nearly resolved. References with 16 and 32 x the samples: their errors (0.3%, 0.1%)
# are far below those checked.
@pytest.mark.parametrize("scene, samples, ref_samples", [(F2, 1 << 15, 1 << 19),
                                                         (F8, 1 << 11, 1 << 16)],
                         ids=["f2-unresolved", "f8"])
def test_error_estimate_matches_the_true_error(rt, lens, tmp_path, scene, samples, ref_samples):
    r = render(rt, lens, scene, seed=1000)
    r.run(ref_samples)
    ref = r.image()
    run = run_psf(psf_args(tmp_path / "sums.phasors", samples, scene=scene))
    m = ESTIMATE.search(run.stdout)
    assert m, run.stdout
    estimate, n = float(m.group(1)) / 100.0, int(m.group(2))
    assert n == samples
    # The sums lensrt-psf saved are those of the image it wrote: both halves, N samples
    r = render(rt, lens, scene)
    r.load(tmp_path / "sums.phasors")
    assert r.stats().samples_per_wavelength == samples
    true = rel_l2(r.image(), ref)
    # The same halves again, for the difference-only formula ||I1 - I2|| / ||I1 + I2||
    halves = []
    for seed in (1, 1 + HALF_SEED_STEP):
        h = render(rt, lens, scene, seed=seed)
        h.run(samples // 2)
        halves.append(h.image())
    difference = np.linalg.norm(halves[0] - halves[1])
    diff_only = float(difference / np.linalg.norm(halves[0] + halves[1]))
    print(f"{samples} samples: estimate {estimate:.4f}, true {true:.4f}, "
          f"halves only {diff_only:.4f}")
    # The estimate is random (one draw of the halves' shifts per wavelength, 4 here) and
    # conservative by up to sqrt(2) where noise dominates (its bias term carries its own
    # fluctuation); on the demo scenes it was 0.6 to 1.4 times the truth. A factor 1.8
    # either way holds that and fails the difference-only formula where it is 3x low.
    assert true / 1.8 < estimate < true * 1.8
    if scene is F2:
        assert diff_only < true / 1.8, "this case no longer tests the bias term"
    assert not list(tmp_path.glob("*.mc-*")), "temporary phasor files left behind"


def test_target_error_doubles_until_reached(lens, tmp_path):
    run = run_psf(psf_args(tmp_path / "a.phasors", 256, "--target-error", "0.02"))
    m = ESTIMATE.search(run.stdout)
    assert m, run.stdout
    assert float(m.group(1)) <= 2.0 and int(m.group(2)) > 256
    n = int(m.group(2))
    assert n & (n - 1) == 0, f"{n} is not 256 doubled"
    # Not reachable within --max-samples: a warning, the last image still written
    run = run_psf(psf_args(tmp_path / "b.phasors", 256, "--target-error", "1e-6",
                           "--max-samples", "1024"))
    m = ESTIMATE.search(run.stdout)
    assert m and int(m.group(2)) == 1024 and float(m.group(1)) > 1e-4, run.stdout
    assert "not reached" in run.stderr and (tmp_path / "b.phasors").exists()
    assert not list(tmp_path.glob("*.mc-*")), "temporary phasor files left behind"


def test_bad_target_options(lens, tmp_path):
    out = tmp_path / "x.phasors"
    for extra in (["--target-error", "0"], ["--target-error", "0.01", "--no-estimate"],
                  ["--max-samples", "4096"], ["--target-error", "0.01", "--max-samples", "128"]):
        run = subprocess.run(psf_args(out, 256, *extra), capture_output=True, text=True,
                             timeout=60)
        assert run.returncode == 2 and "lensrt-psf:" in run.stderr, (extra, run.stderr)
        assert not out.exists()
    # --no-estimate: one sequence and no estimate line
    run = run_psf(psf_args(out, 256, "--no-estimate"))
    assert "Monte Carlo" not in run.stdout and out.exists()


# ------------------------------------------------------------------- the sheet -----

@pytest.mark.parametrize("width_um, bar_um", [(200, 50), (100, 20), (160, 50), (10, 2),
                                              (1000, 200), (400, 100), (3, 1)])
def test_scale_bar_is_a_round_quarter(width_um, bar_um):
    assert psf_sheet.scale_bar_um(width_um) == pytest.approx(bar_um)


def test_sheet_draws_the_bar_to_scale(tmp_path):
    # Plain grey panels on the black sheet: the panel is where the grey is, the bar the
    # longest white run in it. The bar must span bar/width of the panel's pixels.
    panels = []
    for k, (size, grey) in enumerate([(0.2, 60), (0.1, 90)]):
        path = tmp_path / f"p{k}.png"
        Image.fromarray(np.full((128, 128, 3), grey, np.uint8)).save(path)
        panels.append((path, size, f"f/{k}"))
    out = tmp_path / "sheet.png"
    psf_sheet.make_sheet(panels, out, title="test")
    sheet = np.asarray(Image.open(out).convert("RGB")).astype(int)
    for (_, size, _), grey in zip(panels, (60, 90), strict=True):
        # columns and rows mostly of this grey (anti-aliased text edges elsewhere can
        # pass through the same grey level, but only in a few pixels)
        mask = np.all(np.abs(sheet - grey) <= 2, axis=2)
        xs, ys = np.flatnonzero(mask.sum(0) > 100), np.flatnonzero(mask.sum(1) > 100)
        x0, x1, y0, y1 = xs.min(), xs.max() + 1, ys.min(), ys.max() + 1
        assert abs((x1 - x0) - (y1 - y0)) <= 2, "panel is not square"
        white = np.all(sheet[y0:y1, x0:x1] >= 250, axis=2)
        longest = 0
        for row in white:
            runs = np.diff(np.flatnonzero(np.diff(np.r_[0, row.astype(int), 0])))[::2]
            longest = max([longest, *runs])
        expected = psf_sheet.scale_bar_um(size * 1000) / (size * 1000) * (x1 - x0)
        # the bar's 1 pt black edge (2.2 px at 160 dpi) eats into the white at both ends
        assert expected - 6 <= longest <= expected + 1, (longest, expected)
    # The command line: labels and bars named, bad widths refused
    run = subprocess.run([sys.executable, str(ROOT / "runtime" / "tools" / "psf_sheet.py"),
                          "-o", str(out), "--panel", str(panels[0][0]), "0.2", "f/2"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and "f/2: 50 \u00b5m bar" in run.stdout, run.stderr
    run = subprocess.run([sys.executable, str(ROOT / "runtime" / "tools" / "psf_sheet.py"),
                          "-o", str(out), "--panel", str(panels[0][0]), "wide", "f/2"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "window width" in run.stderr
