"""Paraxial analysis against thick-lens closed forms and against real rays."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lensfit.glass import catalog_glass
from lensfit.paraxial import (
    D_LINE_NM,
    f_number_for_stop_radius,
    image_distance,
    paraxial,
    stop_radius_for_f_number,
    table,
)
from lensfit.prescription import load_lens
from lensfit.trace.tracer import Rays, forward_path, trace

R1, R2, D, GAP, STOP_R = 50.0, -80.0, 6.0, 10.0, 4.0


@pytest.fixture
def singlet(build_lens):
    """A stop 10 mm in front of a thick biconvex N-BK7 singlet."""
    return build_lens(
        [
            {
                "shape": "plane",
                "thickness": GAP,
                "material": "air",
                "semi_diameter": STOP_R,
                "stop": True,
            },
            {
                "shape": "sphere",
                "radius": R1,
                "thickness": D,
                "material": "N-BK7",
                "semi_diameter": 15.0,
            },
            {
                "shape": "sphere",
                "radius": R2,
                "thickness": 90.0,
                "material": "air",
                "semi_diameter": 15.0,
            },
        ]
    )


def thick_lens():
    """Lensmaker's equation and principal planes of the singlet (closed forms)."""
    n = float(catalog_glass("N-BK7").n(D_LINE_NM))
    power = (n - 1) * (1 / R1 - 1 / R2 + (n - 1) * D / (n * R1 * R2))
    f = 1 / power
    delta1 = -f * (n - 1) * D / (n * R2)  # front principal plane from the first vertex
    delta2 = -f * (n - 1) * D / (n * R1)  # rear principal plane from the second vertex
    return f, delta1, delta2


# Closed forms and matrices differ only by round-off of ~1e-16 relative per operation
REL = 1e-12


def test_focal_lengths_match_the_thick_lens_formulae(singlet):
    f, d1, d2 = thick_lens()
    p = paraxial(singlet)
    assert p.efl_mm == pytest.approx(f, rel=REL)
    assert p.bfd_mm == pytest.approx(f + d2, rel=REL)
    # Front focal distance is measured from surface 0, the stop plane GAP in front
    assert p.ffd_mm == pytest.approx(f - d1 - GAP, rel=REL)


def test_pupils_and_f_number_match_gaussian_imaging_of_the_stop(singlet):
    f, d1, d2 = thick_lens()
    p = paraxial(singlet)
    # Nothing in front of the stop: the entrance pupil is the stop itself
    assert p.entrance_pupil.position_mm == pytest.approx(0.0, abs=1e-12)
    assert p.entrance_pupil.radius_mm == pytest.approx(STOP_R, rel=REL)
    assert p.f_number == pytest.approx(f / (2 * STOP_R), rel=REL)
    # Exit pupil: the stop imaged by the lens (object distance s from H, image s' from H')
    s = GAP + d1
    s_img = 1 / (1 / f - 1 / s)
    z_rear_h = GAP + D + d2
    assert p.exit_pupil.position_mm == pytest.approx(z_rear_h + s_img, rel=REL)
    assert p.exit_pupil.radius_mm == pytest.approx(STOP_R * abs(s_img / s), rel=REL)


@pytest.mark.parametrize("distance", [150.0, 500.0, 1e4, math.inf])
def test_image_distance_follows_the_lens_equation(singlet, distance):
    f, d1, d2 = thick_lens()
    if math.isinf(distance):
        expected = f + d2
    else:
        # The object is `distance` in front of surface 0 (the stop, z = 0), so
        # distance + GAP in front of the lens's first vertex and s from its front
        # principal plane
        s = distance + GAP + d1
        expected = 1 / (1 / f - 1 / s) + d2
    got = image_distance(singlet, distance)
    assert got == pytest.approx(expected, rel=REL)


def test_stop_radius_and_f_number_are_inverse():
    lens = load_lens("0001")
    for n in (1.2, 2.0, 8.0, 64.0):
        r = stop_radius_for_f_number(lens, n)
        assert f_number_for_stop_radius(lens, r) == pytest.approx(n, rel=1e-12)
    with pytest.raises(ValueError, match="f/0.5 is wider than"):
        stop_radius_for_f_number(lens, 0.5)
    with pytest.raises(ValueError):
        stop_radius_for_f_number(lens, float("nan"))


def test_f_number_within_relative_tolerance_of_the_widest_is_the_widest():
    """Issue 15, item 5: an f-number 1e-6 (relative) short of the widest stop's is that
    stop; beyond the tolerance it is refused with digits that tell the two apart."""
    from lensfit.paraxial.paraxial import F_NUMBER_REL_TOL

    lens = load_lens("0001")
    widest = lens.stop_radius_max_mm
    n_widest = f_number_for_stop_radius(lens, widest)
    # Inside: 0.5 of the tolerance wider (a typed f/1.1399994 for f/1.14) -> the widest
    inside = n_widest / (1 + 0.5 * F_NUMBER_REL_TOL)
    assert stop_radius_for_f_number(lens, inside) == widest
    # Outside: 3 times the tolerance; both f-numbers printed, and they differ
    outside = n_widest / (1 + 3 * F_NUMBER_REL_TOL)
    with pytest.raises(ValueError, match="wider than") as info:
        stop_radius_for_f_number(lens, outside)
    msg = str(info.value)
    shown = [msg.split()[0], msg.split()[-4]]  # "f/REQUESTED is wider ... which is f/WIDEST (...)"
    assert shown[1].startswith("f/") and shown[0] != shown[1], msg
    assert float(shown[0][2:]) == pytest.approx(outside, rel=1e-9)


@pytest.mark.parametrize("lens_id", ["0001", "0004", "0014", "2004"])
def test_paraxial_efl_agrees_with_small_real_rays(lens_id):
    """An independent route: the slope of a real ray at 1e-3 mm height behind the lens
    gives EFL = h / tan(u'). Third-order terms scale with h^2: 1e-6 relative is ample."""
    lens = load_lens(lens_id)
    h = 1e-3
    for axis, meridian in ((1, "y"), (0, "x")):
        start = np.zeros((1, 3))
        start[0, axis] = h
        start[0, 2] = -1.0
        out = trace(lens, Rays(start, [[0.0, 0.0, 1.0]], D_LINE_NM), forward_path(lens), clip=False)
        assert out.ok[0]
        efl_real = -h * out.dir[0, 2] / out.dir[0, axis]
        efl = paraxial(lens, meridian=meridian).efl_mm
        assert efl_real == pytest.approx(efl, rel=1e-6)


def test_anamorphic_table_reports_both_meridians():
    t = table(load_lens("2004"))
    assert t["anamorphic"]
    ex, ey = t["meridians"]["x"]["efl_mm"], t["meridians"]["y"]["efl_mm"]
    assert ex != pytest.approx(ey, rel=0.1)
    assert t["anamorphic_squeeze"] == pytest.approx(ey / ex, rel=1e-12)
    assert t["anamorphic_squeeze"] == pytest.approx(1.92, abs=0.01)  # the patent's "2x" lens


def test_table_has_the_documented_keys():
    t = table(load_lens("0001"))
    for k in ("efl_mm", "bfd_mm", "stop_radius_mm", "f_number"):
        assert isinstance(t[k], float) and math.isfinite(t[k])
    for pupil in ("entrance_pupil", "exit_pupil"):
        assert set(t[pupil]) == {"position_mm", "radius_mm"}
