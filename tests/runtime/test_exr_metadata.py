"""The EXR header tells the truth (issue 40): the units once (lensrt/units; no
emissiveUnits, whose only value in the spectral layout is radiance), the integrator that
made the image with its own parameters and nothing of another's: a cells or Fourier image
has no samples, sampler, estimator or seed; a Monte Carlo image has no rings, nodes or
error estimate. Tiny renders of lens 0001 (8 x 8 pixels, one wavelength): seconds.
"""

from __future__ import annotations

import math
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
LENS0001 = ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table"
PSF = Path(os.environ.get("LENSRT_PSF", ROOT / "build" / "runtime" / "runtime" / "lensrt-psf"))

MONTE_CARLO = ("lensrt/samplesPerWavelength", "lensrt/sampler", "lensrt/estimator",
               "lensrt/seed", "lensrt/splatsPerSecond", "lensrt/phaseToleranceWaves",
               "lensrt/sampleRuns")
DETERMINISTIC = ("lensrt/cellsRings", "lensrt/fourierNodes", "lensrt/fourierTolerance",
                 "lensrt/errorEstimate", "lensrt/errorEstimateMethod")
UNITS = "relative irradiance, dimensionless"


def header(path: Path) -> dict[str, object]:
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        return dict(f.header())


def scalar(v: object) -> float:
    return float(np.ravel(v)[0])


def render(rt, **kw):
    lens = rt.load(LENS0001)
    args = dict(width=8, height=8, width_mm=0.04, f_number=8.0, wavelengths=[550.0],
                pixel_filter="point")
    args.update(kw)
    return rt.create(lens, **args)


def common(h: dict[str, object]) -> None:
    assert "emissiveUnits" not in h
    assert str(h["lensrt/units"]).startswith(UNITS)
    assert "lensrt/lights" in h and "lensrt/pixelFilter" in h


def test_monte_carlo_header(rt1, tmp_path: Path) -> None:
    r = render(rt1, seed=7, sampler="random")
    r.run(512)
    r.write_exr(tmp_path / "mc.exr")
    h = header(tmp_path / "mc.exr")
    common(h)
    assert h["lensrt/integrator"] == "montecarlo"
    assert h["lensrt/samplesPerWavelength"] == "512"
    assert h["lensrt/sampler"] == "random" and h["lensrt/seed"] == "7"
    assert h["lensrt/estimator"] == "paper"
    assert scalar(h["lensrt/phaseToleranceWaves"]) == pytest.approx(3e-3)
    assert "lensrt/sampleRuns" not in h  # one sequence from sample 0: the seed says it
    for name in DETERMINISTIC:
        assert name not in h, name
    assert "Monte Carlo, 512 samples per wavelength" in str(h["comments"])


def test_merged_monte_carlo_lists_its_runs(rt1, tmp_path: Path) -> None:
    a, b = render(rt1, seed=1), render(rt1, seed=2)
    a.run(256)
    b.run(256)
    b.save(tmp_path / "b.phasors")
    a.merge(tmp_path / "b.phasors")
    a.write_exr(tmp_path / "ab.exr")
    h = header(tmp_path / "ab.exr")
    assert h["lensrt/samplesPerWavelength"] == "512" and h["lensrt/seed"] == "1"
    runs = sorted(str(h["lensrt/sampleRuns"]).split("; "))
    assert runs == ["1 0 256", "2 0 256"]


def test_cells_header(rt1, tmp_path: Path) -> None:
    r = render(rt1)
    est = r.integrate(8)
    r.write_exr(tmp_path / "cells.exr")
    h = header(tmp_path / "cells.exr")
    common(h)
    assert h["lensrt/integrator"] == "cells" and h["lensrt/cellsRings"] == 8
    assert scalar(h["lensrt/errorEstimate"]) == pytest.approx(est, rel=1e-15)
    assert "8 and 4 rings" in str(h["lensrt/errorEstimateMethod"])
    for name in MONTE_CARLO + ("lensrt/fourierNodes", "lensrt/fourierTolerance"):
        assert name not in h, name
    assert "cells integrator, 8 rings" in str(h["comments"])
    assert "samples" not in str(h["comments"])
    # Without an estimate: no estimate in the file either
    r2 = render(rt1)
    r2.integrate(4, estimate=False)
    r2.write_exr(tmp_path / "cells-noest.exr")
    h2 = header(tmp_path / "cells-noest.exr")
    assert h2["lensrt/cellsRings"] == 4
    assert "lensrt/errorEstimate" not in h2 and "lensrt/errorEstimateMethod" not in h2


def test_fourier_header(rt1, tmp_path: Path) -> None:
    r = render(rt1)
    est = r.integrate_fourier(24)
    nodes = int(r.stats().fourier_nodes)
    r.write_exr(tmp_path / "fourier.exr")
    h = header(tmp_path / "fourier.exr")
    common(h)
    assert nodes == 24
    assert h["lensrt/integrator"] == "fourier" and h["lensrt/fourierNodes"] == 24
    assert scalar(h["lensrt/fourierTolerance"]) == pytest.approx(1e-3)
    assert scalar(h["lensrt/errorEstimate"]) == pytest.approx(est, rel=1e-15)
    assert f"{math.ceil(1.25 * 24)} nodes per side" in str(h["lensrt/errorEstimateMethod"])
    for name in MONTE_CARLO + ("lensrt/cellsRings",):
        assert name not in h, name
    assert "Fourier integrator, 24 nodes per side" in str(h["comments"])


def test_layers_name_every_render_integrator(rt1, tmp_path: Path) -> None:
    # Two renders of one window in one file: the first one's attributes, and each one's
    # integrator in lensrt/renders
    f, c = render(rt1), render(rt1)
    f.integrate_fourier(16)
    c.integrate(4)
    rt1.write_exr_layers(tmp_path / "layers.exr", {"direct": [f], "flare": [c]})
    h = header(tmp_path / "layers.exr")
    common(h)
    assert h["lensrt/integrator"] == "fourier" and h["lensrt/fourierNodes"] == 16
    said = str(h["lensrt/renders"]).split("; ")
    assert len(said) == 2
    assert "fourier, 16 nodes per side, error estimate" in said[0]
    assert "cells, 4 rings, error estimate" in said[1]
    # One render: no lensrt/renders
    f.write_exr(tmp_path / "one.exr")
    assert "lensrt/renders" not in header(tmp_path / "one.exr")


@pytest.mark.skipif(not PSF.exists(), reason=f"{PSF} is not built")
@pytest.mark.parametrize("integrator", ["cells", "fourier", "auto"])
def test_lensrt_psf_deterministic_header(tmp_path: Path, integrator: str) -> None:
    # The command's deterministic integrators (auto: whichever it kept) write no
    # samples, sampler or seed, and their own parameters as the command printed them
    out = tmp_path / f"{integrator}.exr"
    extra = {"cells": ["--rings", "4"], "fourier": ["--nodes", "16"], "auto": []}[integrator]
    r = subprocess.run([str(PSF), "--lens", str(LENS0001), "--f-number", "8", "--resolution",
                        "8x8", "--size", "0.04", "--wavelength", "550", "--quiet",
                        "--integrator", integrator, *extra, "-o", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    h = header(out)
    common(h)
    kind = h["lensrt/integrator"]
    assert kind == (integrator if integrator != "auto" else kind) and kind in ("cells", "fourier")
    for name in MONTE_CARLO:
        assert name not in h, name
    printed = r.stdout
    if kind == "cells":
        assert f"({h['lensrt/cellsRings']} rings against" in printed
        assert "lensrt/fourierNodes" not in h
    else:
        assert f"({h['lensrt/fourierNodes']} nodes against" in printed
        assert "lensrt/cellsRings" not in h
    est = scalar(h["lensrt/errorEstimate"])
    assert f"{100 * est:.3g}%" in printed


@pytest.mark.skipif(not PSF.exists(), reason=f"{PSF} is not built")
def test_lensrt_psf_monte_carlo_header(tmp_path: Path) -> None:
    out = tmp_path / "mc.exr"
    r = subprocess.run([str(PSF), "--lens", str(LENS0001), "--f-number", "8", "--resolution",
                        "8x8", "--size", "0.04", "--wavelength", "550", "--quiet",
                        "--samples", "512", "--seed", "3", "-o", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    h = header(out)
    common(h)
    assert h["lensrt/integrator"] == "montecarlo"
    assert h["lensrt/samplesPerWavelength"] == "512" and h["lensrt/seed"] == "3"
    # Two halves of 256 (seeds 3 and 3 + 0x9E3779B97F4A7C15), merged: both runs listed
    runs = str(h["lensrt/sampleRuns"]).split("; ")
    assert sorted(runs) == sorted(["3 0 256", f"{3 + 0x9E3779B97F4A7C15} 0 256"])
    for name in DETERMINISTIC:
        assert name not in h, name
