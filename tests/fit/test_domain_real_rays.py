"""The default domain holds only what real rays reach (issue 41): a fisheye's image circle
is the real image of its fitted field, not the frame's (lens 0014: 54% of the sensor-side
grid had no ray), and an anamorphic lens's field ends where its chief ray stops passing
in either meridian (lens 2003: 30% holes, its y field beyond what its rear anamorphic
group passes). Both rest on aiming a lone wide-field ray, which failed from its paraxial
first guess.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lensfit.paraxial import paraxial
from lensfit.prescription import load_lens
from lensfit.sample.aim import aim_object_side, aim_sensor_side
from lensfit.sample.domain import (
    IMAGE_MARGIN,
    anamorphic_image_radius,
    chief_image_radius,
    default_domain,
    passing_field,
)
from lensfit.sample.rays import sample_grid


@pytest.fixture(scope="module")
def fisheye():
    return load_lens("0014")


def test_a_lone_wide_field_ray_is_aimed_as_in_a_fan(fisheye):
    """0014's chief ray at 60 degrees, aimed alone, converges (its paraxial start misses
    surface 7; it used to fail) to the ray that a fan of angles from the axis reaches by
    continuation. Tolerance: both are Newton solutions to NEWTON_TOL_MM = 1e-9 mm on the
    stop, so their starts agree to far better than 1e-6 mm."""
    x = math.sin(math.radians(60.0))
    lone = aim_object_side(fisheye, x, 0.0, 0.0, 0.0, 0.0, 550.0)
    assert lone.ok[0]
    fan = np.sin(np.radians(np.linspace(0.0, 60.0, 121)))
    ramp = aim_object_side(fisheye, fan, 0.0, 0.0, 0.0, 0.0, 550.0)
    assert ramp.ok.all()
    assert np.allclose(lone.unknowns[0], ramp.unknowns[-1], atol=1e-6)


def test_a_fisheye_s_image_circle_is_its_real_image(fisheye):
    """The field is capped at 60 degrees; its edge images at ~10 mm (paraxially 16.8 mm,
    the frame 21.6 mm), and the image circle is that plus IMAGE_MARGIN. Every sensor
    point of it is reached from the stop: a small grid has no hole (the 2000 x 128 grid
    of `lensfit fit` has none either; with the frame's circle it had 54%)."""
    d = default_domain(fisheye)
    r = chief_image_radius(fisheye, d.field_deg)
    assert r is not None and 9.0 < r < 11.0
    assert d.sensor_radius_mm == pytest.approx(IMAGE_MARGIN * r, rel=1e-12)
    assert r < paraxial(fisheye).efl_mm * math.tan(math.radians(d.field_deg))
    grid = sample_grid(fisheye, d, "P_s", 40, 16, seed=2)
    assert grid.ok.all()
    # The frame's corner is reached by no ray, even through the centre of the stop
    corner = aim_sensor_side(fisheye, 21.6, 0.0, 0.0, 0.0, 0.0, 550.0)
    assert not corner.ok[0]


def test_an_anamorphic_field_ends_where_its_chief_rays_pass():
    """2003 (a double Gauss behind which sits a rear anamorphic group): the frame's field
    would be 8.7 x 11.8 degrees, but the chief ray is clipped at surface 18 beyond 7.3
    degrees in y. The default field is narrowed, keeping the squeeze's ratio
    (tan y / tan x = EFL_x / EFL_y), until both meridians pass; the image circle is the
    real image of the field's edge plus IMAGE_MARGIN. Tolerances: passing_field bisects
    to 0.1 degree; the ratio is exact up to rounding."""
    lens = load_lens("2003")
    d = default_domain(lens)
    fx, fy = d.field_xy_deg
    ex, ey = (abs(paraxial(lens, meridian=m).efl_mm) for m in ("x", "y"))
    assert math.tan(math.radians(fy)) / math.tan(math.radians(fx)) == pytest.approx(
        ex / ey, rel=1e-12)
    assert fy < 8.0 < 11.8 and fx < 8.7
    assert passing_field(lens, fx, "x") == fx and passing_field(lens, fy, "y") == fy
    assert passing_field(lens, fy + 0.2, "y") < fy + 0.2  # and no further
    r = anamorphic_image_radius(lens, fx, fy)
    assert r is not None and d.sensor_radius_mm == pytest.approx(IMAGE_MARGIN * r)
    assert d.sensor_radius_mm < 0.75 * 21.63
