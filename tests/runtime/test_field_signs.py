"""Issue 15, item 6: lensrt's field angles follow the designers' convention (README
"Conventions", lensrt.h lensrt_light): a light at +θ is imaged at +f tan θ, and lensrt
turns field angles into P_o's inputs exactly as lensfit does."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from lensrt_ctypes import LensrtError

ROOT = Path(__file__).resolve().parents[2]
LENS0001 = ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table"
WL_NM = 550.0


def test_direction_cosines_are_lensfits(rt):
    """One conversion on both sides: lensrt_light_direction_cosines against
    lensfit.scene.light_direction (the same float64 formula: equal to 1 ulp)."""
    from lensfit.codegen.scene import light_direction

    for field in [(0.0, 0.0), (-6.0, -4.0), (3.0, -2.0), (0.0, 5.0), (60.0, -45.0)]:
        got, want = rt.light_direction_cosines(field), light_direction(*field)
        assert got == pytest.approx(want, rel=2.3e-16, abs=1e-300), field
    x, y = rt.light_direction_cosines((0.0, 5.0))
    assert x == 0.0 and y < 0.0  # +θy: the light is below the axis
    # Behind the lens or not a number: refused, naming the angles
    for bad in [(90.0, 0.0), (0.0, -95.0), (math.nan, 0.0)]:
        with pytest.raises(LensrtError, match=r"light_direction_cosines: field .*within \+-90"):
            rt.light_direction_cosines(bad)


@pytest.mark.parametrize("field", [(0.0, 3.0), (3.0, 0.0), (-2.0, 1.5)])
def test_perfect_lens_images_plus_theta_at_plus_f_tan_theta(rt, field):
    """A perfect thin lens focused at infinity: the image point is exactly f tan θ per
    axis (the light's direction (-tan θx, -tan θy, 1) turned round by the lens), in
    image_point and in the render (its peak at the window's centre)."""
    f, f_number = 50.0, 8.0
    lens = rt.analytic(sensor_distance_mm=f, focal_length_mm=f)
    cx, cy = rt.image_point(lens, field, WL_NM, 0.0)
    assert (cx, cy) == pytest.approx(tuple(f * math.tan(math.radians(t)) for t in field),
                                     abs=1e-12)
    # The rendered PSF peaks there: a 9 x 9 window of Airy/4 pixels centred on (+x, +y)
    n_px, pitch = 9, 1.22 * WL_NM * 1e-6 * f_number / 4
    img = rt.render(lens, width=n_px, height=n_px, width_mm=n_px * pitch, center=(cx, cy),
                    f_number=f_number, lights=[field], wavelengths=[WL_NM], samples=4096)[0]
    assert np.unravel_index(np.argmax(img), img.shape) == (n_px // 2, n_px // 2)


@pytest.mark.skipif(not LENS0001.exists(), reason="needs generated/0001's table")
@pytest.mark.parametrize("field", [(0.0, 1.0), (1.0, 0.0), (-2.0, 3.0)])
def test_fitted_lens_images_where_the_exact_trace_does(rt, field):
    """0001's table against lensfit's exactly traced chief ray (which tests/fit/
    test_conventions.py holds to EFL tan θ): the same point, sign included. Measured
    difference 9e-8 mm (Newton on the fitted phase); bound 1e-5 mm, 1% of the Airy
    radius at f/2; a mirrored light would be off by 3.5 mm."""
    from lensfit.prescription import load_lens
    from lensfit.psf import psf

    lens = rt.load(LENS0001)
    focus = 0.2866  # about the paraxial focus for infinity (inside the fitted range)
    got = rt.image_point(lens, field, WL_NM, focus)
    want = psf.geometric_image_point(load_lens("0001"), field, math.inf, WL_NM, focus)
    assert got == pytest.approx(want, abs=1e-5)
    for g, t in zip(got, field, strict=True):
        assert t == 0.0 or math.copysign(1.0, g) == math.copysign(1.0, t)
