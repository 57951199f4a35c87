"""The box pixel filter (issue 26): a pixel's value is its mean intensity over its area.

A feature narrower than a pixel (an Airy core at f/8 on 25 um pixels, a slit's streak a
few um tall) aliases when each pixel samples its centre: its rendered power changes with
its position against the pixel grid. With the box filter's automatic sub-pixel points
(runtime/src/core/pixel_area.c: h < lambda / D, D the spread of the rays' directions) the
midpoint sums integrate any intensity the aperture can make exactly over the plane
(Poisson summation), so the power must not depend on the sub-pixel position. Each test
also shows that the point filter does vary, so that it can fail.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from lensrt_ctypes import NO_DEVICE, Lensrt, LensrtError, Result

ROOT = Path(__file__).resolve().parents[2]
LENS_0001 = ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table"
GHOST_0001 = ROOT / "generated" / "0001-angenieux-double-gauss" / "ghosts" / "ghost_0_2.table"
SHIFTS = (0.0, 0.125, 0.25, 0.375, 0.5)  # of a pixel
PITCH = 0.025  # mm: a sensor's coarse pixels


def spread(powers: list[float]) -> float:
    return max(powers) / min(powers) - 1.0


def airy_powers(rt, lens, filt: str, *, integrator: str = "cells", n: int = 12,
                **extra) -> tuple[list[float], tuple[int, int]]:
    """Lens 0001 at f/8, light on the axis, in focus, 550 nm: an Airy core of 5.4 um
    radius to its first dark ring on 25 um pixels, the window shifted by SHIFTS of a
    pixel along (1, 0.37). The power in the window (sum of pixels x pixel area)."""
    powers, counts = [], (0, 0)
    for s in SHIFTS:
        r = rt.create(lens, width=n, height=n, width_mm=n * PITCH,
                      center=(s * PITCH, 0.37 * s * PITCH), f_number=8.0, wavelengths=[550.0],
                      pixel_filter=filt, **extra)
        if integrator == "cells":
            r.integrate(16, estimate=False)
        else:
            r.integrate_fourier(0, estimate=False)
        st = r.stats()
        counts = (st.pixel_samples_x, st.pixel_samples_y)
        powers.append(float(r.image().astype(np.float64).sum()) * PITCH * PITCH)
    return powers, counts


def test_airy_core_power_does_not_depend_on_position(rt):
    # Tolerance 1%: the issue's. What is left is the window's edge (the Airy pattern's
    # power beyond 0.15 mm, ~1%, moves by its derivative: < 0.05% over half a pixel) and
    # the cells mesh's error, the same function of position at every shift (measured:
    # 1.6e-4 spread with the box filter against 3.2 (a factor 4.2) with the point filter).
    lens = rt.load(LENS_0001)
    box, counts = airy_powers(rt, lens, "box")
    point, pcounts = airy_powers(rt, lens, "point")
    print(f"Airy core, box {counts}: {box}; point: {point}")
    # The automatic rule: D ~ 1 / N_w = 1 / 8, lambda / D = 4.4 um, 25 um pixels: 6 points
    assert counts == (6, 6) and pcounts == (1, 1)
    assert spread(box) < 0.01
    assert spread(point) > 0.5  # the point filter aliases (this is what the box fixes)
    # Both see the same light where the point samples happen to land well: the box's
    # power is the light's (the point filter's mean over shifts is a crude estimate)
    assert abs(np.mean(box) / np.mean(point) - 1.0) < 0.5


def test_airy_core_fourier(rt):
    # The Fourier integrator on a window of 24 x 24 pixels (its grid 144 x 144 points,
    # one NUFFT for all): the same independence, tolerance 1% as above.
    lens = rt.load(LENS_0001)
    box, counts = airy_powers(rt, lens, "box", integrator="fourier", n=24)
    print(f"Airy core, Fourier, box {counts}: {box}")
    assert counts == (6, 6)
    assert spread(box) < 0.01


def slit_streak_powers(rt, filt: str) -> tuple[list[float], tuple[int, int]]:
    """A perfect lens f = 50 mm with a slit 0.5 mm wide (x) and 6.25 mm long (y), light on
    the axis, in focus, 550 nm: a horizontal streak 4.4 um tall to its first zeros in y
    (lambda f / 6.25 mm) and 110 um wide in x, on 25 um pixels; the window shifted by
    SHIFTS of a pixel in y, across the streak."""
    lens = rt.analytic(sensor_distance_mm=50.0, focal_length_mm=50.0)
    powers, counts = [], (0, 0)
    for s in SHIFTS:
        r = rt.create(lens, width=16, height=8, width_mm=16 * PITCH, center=(0.0, s * PITCH),
                      radius_mm=3.125, shape="slit", slit_width_mm=0.5, wavelengths=[550.0],
                      pixel_filter=filt)
        r.integrate(16, estimate=False)
        st = r.stats()
        counts = (st.pixel_samples_x, st.pixel_samples_y)
        powers.append(float(r.image().astype(np.float64).sum()) * PITCH * PITCH)
    return powers, counts


def test_thin_streak_power_does_not_depend_on_position(rt):
    # Tolerance 1%: the streak's sinc^2 tail in x beyond the window (a few %) does not
    # move with a shift in y; in y the window holds all but ~0.1% at every shift.
    box, counts = slit_streak_powers(rt, "box")
    point, _ = slit_streak_powers(rt, "point")
    print(f"slit streak, box {counts}: {box}; point: {point}")
    # Per axis: the slit's directions spread 0.5 / 50 in x (one point: the streak is
    # wide there), 6.25 / 50 in y (lambda / D = 4.4 um: 6 points)
    assert counts == (1, 6)
    assert spread(box) < 0.01
    assert spread(point) > 0.5


def test_box_is_the_mean_of_a_finer_point_render(rt):
    # The box filter's 3 x 3 points of a pixel are the centres of a point render with 3
    # times the pixels over the same window: binning that image in 3 x 3 blocks gives the
    # box image to float rounding (the images are floats: 1e-6 relative is rounding).
    lens = rt.load(LENS_0001)
    kw = dict(width_mm=0.03, center=(0.0011, -0.0007), f_number=8.0, wavelengths=[500.0, 600.0])
    box = rt.create(lens, width=8, height=6, pixel_filter="box", pixel_samples=3, **kw)
    box.integrate(12, estimate=False)
    fine = rt.create(lens, width=24, height=18, pixel_filter="point", **kw)
    fine.integrate(12, estimate=False)
    a = box.image().astype(np.float64)
    b = fine.image().astype(np.float64).reshape(2, 6, 3, 8, 3).mean(axis=(2, 4))
    assert a.shape == b.shape
    assert np.abs(a - b).max() <= 1e-6 * np.abs(b).max()


def test_fine_pixels_keep_one_point(rt):
    # Pixels finer than lambda / D (1 um at f/8) keep one point, their centre: the box
    # filter's image is the point filter's bit for bit, at no cost
    lens = rt.load(LENS_0001)
    kw = dict(width=16, height=16, width_mm=0.016, f_number=8.0, wavelengths=[450.0, 650.0])
    a = rt.create(lens, pixel_filter="box", **kw)
    b = rt.create(lens, pixel_filter="point", **kw)
    a.run(4096)
    b.run(4096)
    assert (a.stats().pixel_samples_x, a.stats().pixel_samples_y) == (1, 1)
    assert np.array_equal(a.image(), b.image())


def test_ghost_power_does_not_depend_on_position(rt):
    # A ghost (0001's ghost 0-2, side P_s terms on the grid's points) at f/8 on 25 um
    # pixels: its power over shifts of the window, box against point. The ghost is a
    # blur far wider than a pixel, so even the point filter varies little; the box must
    # stay within 1% (tolerance as above; measured below 0.1%).
    ghost = rt.load(GHOST_0001)
    cx, cy = rt.image_point(ghost, (0.0, 0.0), 550.0)
    box = []
    counts = (0, 0)
    for s in SHIFTS[::2]:
        r = rt.create(ghost, width=24, height=24, width_mm=24 * 4 * PITCH,
                      center=(cx + s * 4 * PITCH, cy + 0.37 * s * 4 * PITCH), f_number=8.0,
                      wavelengths=[550.0])
        r.integrate(16, estimate=False)
        counts = (r.stats().pixel_samples_x, r.stats().pixel_samples_y)
        box.append(float(r.image().astype(np.float64).sum()))
    print(f"ghost 0-2, box {counts}: {box}")
    assert counts[0] > 1 and counts[1] > 1
    assert spread(box) < 0.01


def test_refusals_and_records(rt, tmp_path):
    lens = rt.load(LENS_0001)
    kw = dict(width=8, height=8, width_mm=0.2, f_number=8.0, wavelengths=[550.0])
    with pytest.raises(LensrtError, match="point filter"):
        rt.create(lens, pixel_filter="point", pixel_samples=2, **kw)
    with pytest.raises(LensrtError, match="1..16"):
        rt.create(lens, pixel_samples=17, **kw)
    # Phasor sums of a box render (its grid of 8 x 8 pixels of 6 x 6 points) refused by
    # a point render of the same window, naming the filter
    a = rt.create(lens, **kw)
    a.run(256)
    a.save(tmp_path / "a.phasors")
    b = rt.create(lens, pixel_filter="point", **kw)
    with pytest.raises(LensrtError, match="pixel filter"):
        b.load(tmp_path / "a.phasors")
    c = rt.create(lens, **kw)
    c.load(tmp_path / "a.phasors")  # the same filter and counts: fine
    assert np.array_equal(c.image(), a.image())
    # The EXR records the filter and the counts
    import OpenEXR

    a.write_exr(tmp_path / "a.exr")
    header = OpenEXR.InputFile(str(tmp_path / "a.exr")).header()
    assert header["lensrt/pixelFilter"] in (b"box", "box")
    assert (header["lensrt/pixelSamplesX"], header["lensrt/pixelSamplesY"]) == (6, 6)


def gl_or_skip() -> Lensrt:
    from lensrt_ctypes import LIBRARY

    rt = Lensrt(LIBRARY)
    try:
        rt.gl_info()
    except LensrtError as e:
        if e.code in (NO_DEVICE, Result.UNSUPPORTED):
            if os.environ.get("LENSRT_REQUIRE_GL"):
                pytest.fail(f"LENSRT_REQUIRE_GL is set but there is no GL device: {e}")
            pytest.skip(f"no OpenGL 4.3 device on this machine: {e}")
        raise
    return rt


def test_gl_equals_cpu_with_the_box_filter():
    # The same samples on both devices with the box filter's automatic points (Airy core,
    # 25 um pixels: 6 x 6): the images agree as test_gl.py's do (within 3x the CPU
    # default's distance from the CPU in double plus the float floor 2e-4), and the power
    # is the same at two sub-pixel positions on GL too (tolerance 1%, as above).
    rt = gl_or_skip()
    lens = rt.load(LENS_0001)
    powers = []
    for s in (0.0, 0.5):
        kw = dict(width=8, height=8, width_mm=8 * PITCH, center=(s * PITCH, 0.37 * s * PITCH),
                  f_number=8.0, wavelengths=[550.0], seed=3)
        images = {}
        runs = (("gl", dict(device="gl")), ("cpu", {}), ("double", dict(precision="double")))
        for name, extra in runs:
            r = rt.create(lens, **kw, **extra)
            r.run(4096)
            st = r.stats()
            assert (st.pixel_samples_x, st.pixel_samples_y) == (6, 6), name
            images[name] = r.image().astype(np.float64)

        ref = images["double"]

        def dist(x, ref=ref):
            return np.linalg.norm(x - ref) / np.linalg.norm(ref)

        print(f"shift {s}: GL {dist(images['gl']):.2e}, CPU {dist(images['cpu']):.2e}")
        assert dist(images["gl"]) <= 3.0 * dist(images["cpu"]) + 2e-4
        powers.append(images["gl"].sum())
    # 4096 Sobol samples resolve the f/8 integrand (the image's own error ~1e-3)
    assert spread(powers) < 0.01
