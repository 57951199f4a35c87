"""Sampled rays of P_o and P_s against closed forms, independent re-traces and optics.

Tolerances rest on how the sampler finds a ray: Newton's method stops once the ray
misses the stop point (P_o) or the sensor point (P_s) by at most NEWTON_TOL_MM = 1e-9 mm,
and the recorded outputs are those of that converged ray. An OPL measured to a point that
is off by that much changes by |grad OPL| * 1e-9 mm, and |grad OPL| is the sine of the
ray's angle there (Hamilton's point characteristic in air), so at most 1e-9 mm.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lensfit.glass import catalog_glass
from lensfit.paraxial import D_LINE_NM, image_distance, paraxial, stop_radius_for_f_number
from lensfit.prescription import load_lens
from lensfit.sample import (
    Domain,
    SamplingError,
    default_domain,
    sample_object_side,
    sample_sensor_side,
)
from lensfit.sample.aim import NEWTON_TOL_MM
from lensfit.trace.tracer import Rays, Status, Step, trace

BK7 = catalog_glass("N-BK7")
EPS = np.finfo(np.float64).eps


@pytest.fixture(scope="module")
def lens0001():
    return load_lens("0001")


def plate_before_stop(build_lens, t=10.0, gap=5.0):
    """A bare N-BK7 plate of thickness t at z = 0, the stop gap mm behind it."""
    return build_lens([
        {"shape": "plane", "thickness": t, "material": "N-BK7", "semi_diameter": 30.0},
        {"shape": "plane", "thickness": gap, "material": "air", "semi_diameter": 30.0},
        {"shape": "plane", "thickness": 20.0, "material": "air", "semi_diameter": 10.0,
         "stop": True},
    ])


def small_domain(**kw) -> Domain:
    base = dict(field_deg=40.0, close_focus_mm=math.inf, stop_radius_mm=8.0,
                sensor_radius_mm=5.0, focus_min_mm=-1.0, focus_max_mm=1.0)
    base.update(kw)
    return Domain(**base)


def fresnel_unpolarised(n1, n2, cos_i):
    """Textbook Fresnel power reflectance, the mean of s and p."""
    sin_t = n1 / n2 * np.sqrt(1.0 - cos_i**2)
    cos_t = np.sqrt(1.0 - sin_t**2)
    rs = ((n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)) ** 2
    rp = ((n1 * cos_t - n2 * cos_i) / (n1 * cos_t + n2 * cos_i)) ** 2
    return 0.5 * (rs + rp)


# --- exactness against closed forms and re-traces -----------------------------------------


def test_plate_in_front_of_the_stop_matches_the_closed_form(build_lens):
    """Plane wave (u_O = 0) with unit propagation vector k = (-x_O, -y_O, k_z) through a
    plate of thickness t and index n to the stop point A. The OPL from the wavefront
    through the first vertex is k.P0 + OPL(P0 -> A); eliminating the entry point gives
    phi_o = k.A + t (sqrt(n^2 - s^2) - k_z), s^2 = x_O^2 + y_O^2, and the entry point
    P0 = A - k_perp g / k_z - (k_perp / n) t / cos(theta_glass)."""
    t, gap = 10.0, 5.0
    lens = plate_before_stop(build_lens, t, gap)
    s = sample_object_side(lens, small_domain(), groups=20, per_group=8, seed=3)
    assert len(s) == s.requested == 160  # nothing is lost through a plate
    x, o = s.inputs, s.outputs
    assert np.all(x[:, 2] == 0.0)  # close_focus inf: every scene point at infinity
    n = BK7.n(x[:, 5])
    s2 = x[:, 0] ** 2 + x[:, 1] ** 2
    kz = np.sqrt(1.0 - s2)
    z_stop = lens.vertex_z[2]
    phi = -(x[:, 0] * x[:, 3] + x[:, 1] * x[:, 4]) + kz * z_stop + t * (np.sqrt(n * n - s2) - kz)
    # The sampled ray ends within NEWTON_TOL_MM of A, where |d phi / dA| <= sin(40 deg);
    # the rest is rounding of ~20 mm paths (1e-14)
    np.testing.assert_allclose(o[:, 3], phi, rtol=0, atol=NEWTON_TOL_MM)
    cos_g = np.sqrt(1.0 - s2 / n**2)
    k_perp = -x[:, :2]
    entry = x[:, 3:5] - k_perp * (gap / kz)[:, None] - k_perp / n[:, None] * (t / cos_g)[:, None]
    # A miss of 1e-9 mm at the stop maps back to the same shift of the entry point
    np.testing.assert_allclose(o[:, :2], entry, rtol=0, atol=2 * NEWTON_TOL_MM)
    # Bare plate: the same unpolarised reflectance at both faces (Stokes), tau = (1 - R)^2
    r = fresnel_unpolarised(1.0, n, kz)
    np.testing.assert_allclose(o[:, 2], (1.0 - r) ** 2, rtol=1e-13, atol=0)


def test_plate_at_normal_incidence_has_a_flat_phase(build_lens):
    """Along the axis every stop point sees the same OPL z_A + t (n - 1)."""
    t = 10.0
    lens = plate_before_stop(build_lens, t)
    s = sample_object_side(lens, small_domain(field_deg=1e-12), groups=3, per_group=16, seed=1)
    for g in np.unique(s.group):
        m = s.group == g
        n = float(BK7.n(s.inputs[m, 5][0]))
        # x_O <= sin(1e-12 deg) = 2e-14: a tilt of 2e-14 * 8 mm; rounding of ~30 mm paths
        assert np.ptp(s.outputs[m, 3]) < 1e-12
        assert s.outputs[m, 3][0] == pytest.approx(lens.vertex_z[2] + t * (n - 1.0),
                                                   abs=1e-12)


def test_object_side_rays_retrace_from_the_scene_point(lens0001):
    """Trace afresh the ray from the finite scene point d_O w through the recorded entry
    point (x_o, y_o on the first surface): it must reach the stop point, its OPL must be
    phi_o + d_O and its transmittance tau_o."""
    s = sample_object_side(lens0001, default_domain(lens0001), groups=30, per_group=4, seed=5)
    x, o = s.inputs, s.outputs
    fin = x[:, 2] > 0
    assert fin.sum() >= 40  # most groups are at a finite distance
    x, o = x[fin], o[fin]
    d_o = 1.0 / x[:, 2]
    w = np.stack([x[:, 0], x[:, 1], -np.sqrt(1.0 - x[:, 0] ** 2 - x[:, 1] ** 2)], axis=1)
    first = lens0001.surfaces[0]
    entry = np.stack([o[:, 0], o[:, 1], first.sag(o[:, 0], o[:, 1])], axis=1)
    leg = entry - d_o[:, None] * w  # scene point -> entry point, in air
    # The trace starts on the first surface (the tracer's own intersection from 1e5 mm
    # away would add ~1e-13 d_O of rounding); the air leg is added by hand
    st = lens0001.stop_index
    out = trace(lens0001, Rays(entry, leg, x[:, 5]), [Step(k) for k in range(st + 1)],
                clip=False, fresnel_loss=True)
    assert np.all(out.status == Status.OK)
    # Newton's miss (1e-9) plus the rounding of the direction, magnified by the lens
    np.testing.assert_allclose(out.pos[:, :2], x[:, 3:5], rtol=0, atol=1e-8)
    # |leg| ~ d_O (up to 2e5 mm here) is rounded to a few ulp of d_O; phi_o itself to the
    # 1e-9 mm of Newton's miss
    err = np.abs(out.opl_mm + np.linalg.norm(leg, axis=1) - d_o - o[:, 3])
    assert np.all(err <= 1e-9 + 8 * EPS * d_o), err.max()
    # Same ray, same coatings: only rounding
    # The 1e-9 mm miss tilts the retraced ray by ~1e-11 rad; the transmittance follows by
    # ~1e-12 (the chord method stops just inside the miss: 1.5e-12 measured)
    np.testing.assert_allclose(out.transmittance, o[:, 2], rtol=1e-11, atol=0)


def test_sensor_side_rays_retrace_backwards_from_the_sensor(lens0001):
    """Reversibility: from the sensor point through (x_i, y_i) on the last surface,
    backwards through the rear group, the ray reaches the stop point, with OPL phi_i and
    (lossless coatings are reciprocal) transmittance tau_i."""
    lens = lens0001
    s = sample_sensor_side(lens, default_domain(lens), groups=30, per_group=4, seed=6)
    x, o = s.inputs, s.outputs
    last = lens.surfaces[-1]
    exit_pt = np.stack([o[:, 0], o[:, 1], lens.vertex_z[-1] + last.sag(o[:, 0], o[:, 1])],
                       axis=1)
    sensor = np.stack([x[:, 0], x[:, 1], lens.sensor_z + x[:, 2]], axis=1)
    st, n_surf = lens.stop_index, len(lens.surfaces)
    path = [Step(k, from_front=False) for k in range(n_surf - 1, st, -1)]
    out = trace(lens, Rays(sensor, exit_pt - sensor, x[:, 5]), path, clip=False,
                fresnel_loss=True, end_z=float(lens.vertex_z[st]))
    assert np.all(out.status == Status.OK)
    # The sensor-point miss (1e-9) scaled by the rear group's angular magnification
    np.testing.assert_allclose(out.pos[:, :2], x[:, 3:5], rtol=0, atol=1e-8)
    # |grad OPL| <= 1 at the sensor times the 1e-9 mm miss, plus rounding of ~100 mm
    np.testing.assert_allclose(out.opl_mm, o[:, 3], rtol=0, atol=2e-9)
    # The 1e-9 mm miss tilts the retraced ray by ~1e-11 rad; the transmittance follows by
    # ~1e-12 (the chord method stops just inside the miss: 1.5e-12 measured)
    np.testing.assert_allclose(out.transmittance, o[:, 2], rtol=1e-11, atol=0)


def test_phase_is_continuous_at_infinity(lens0001):
    """phi_o at u_O <= 1e-12 (d_O >= 1e12 mm) equals phi_o at u_O = 0 for the same
    direction and stop point. Computed naively (|S - d_O w| - d_O) the float64 rounding
    of 1e12 mm alone would be ~1e-4 mm."""
    dom = default_domain(lens0001)
    at_inf = sample_object_side(lens0001, dom.with_(close_focus_mm=math.inf), 40, 4, seed=9)
    near = sample_object_side(lens0001, dom.with_(close_focus_mm=1e12), 40, 4, seed=9)
    # Same seed: the same directions, stop points and wavelengths, only u_O differs
    assert len(at_inf) == len(near) == 160
    np.testing.assert_array_equal(at_inf.inputs[:, [0, 1, 3, 4, 5]],
                                  near.inputs[:, [0, 1, 3, 4, 5]])
    assert np.all(at_inf.inputs[:, 2] == 0.0)
    u = near.inputs[:, 2]
    assert 0.0 < u.max() <= 1e-12
    # The true change: the sag u |S|^2 / 2 of the incoming spherical wave over the first
    # surface (|S| = entry height); plus both rays' stop-point misses (<= 1e-9 mm each,
    # |grad phi| <= 1)
    sag = 0.5 * u * (near.outputs[:, 0] ** 2 + near.outputs[:, 1] ** 2)
    diff = np.abs(near.outputs[:, 3] - at_inf.outputs[:, 3])
    assert np.all(diff <= sag + 2 * NEWTON_TOL_MM), diff.max()


def test_on_axis_wavefront_at_paraxial_focus_is_spherical_aberration(lens0001):
    """Fermat: phi_o + phi_i for an axial point at infinity and the axial sensor point at
    the paraxial focus (z_S = -sensor defocus, d line) is the OPL object -> image, whose
    spread over the stop is the wavefront error. Stopped down, it is third-order
    spherical aberration W040 r^4: a fraction of a wave at f/8 for this double Gauss,
    and 16 times less when the stop radius halves."""
    lens = lens0001
    z_s = -paraxial(lens).sensor_defocus_mm
    tiny = 1e-9
    spread = {}
    for f_number in (8.0, 16.0):
        dom = Domain(field_deg=tiny, close_focus_mm=math.inf,
                     stop_radius_mm=stop_radius_for_f_number(lens, f_number),
                     sensor_radius_mm=tiny, focus_min_mm=z_s - tiny, focus_max_mm=z_s + tiny,
                     wavelength_min_nm=D_LINE_NM - 1e-6, wavelength_max_nm=D_LINE_NM + 1e-6)
        o = sample_object_side(lens, dom, groups=1, per_group=200, seed=3)
        s = sample_sensor_side(lens, dom, groups=1, per_group=200, seed=3)
        assert len(o) == len(s) == 200
        # Both samplers draw the stop points first from the same seed: pair them
        np.testing.assert_array_equal(o.inputs[:, 3:5], s.inputs[:, 3:5])
        spread[f_number] = np.ptp(o.outputs[:, 3] + s.outputs[:, 3]) / (D_LINE_NM * 1e-6)
    # Measured 0.019 waves at f/8; an OPL error in either half that varies by 1e-4 mm
    # over the stop would show as 0.17 waves, and a sensor 0.1 mm off focus as ~0.3
    assert spread[8.0] < 0.1
    # r^4 scaling (higher orders add ~1% here); 6th order alone would give 64
    assert spread[8.0] / spread[16.0] == pytest.approx(16.0, rel=0.05)


# --- bad input -------------------------------------------------------------------------------


@pytest.mark.parametrize(("key", "value"), [
    ("field_deg", 0.0),
    ("field_deg", 90.0),
    ("field_deg", math.nan),
    ("close_focus_mm", -100.0),
    ("close_focus_mm", 0.0),
    ("stop_radius_mm", 0.0),
    ("stop_radius_mm", math.inf),
    ("sensor_radius_mm", -1.0),
    ("focus_min_mm", 1.0),  # == focus_max_mm
    ("focus_min_mm", 2.0),  # > focus_max_mm
    ("wavelength_min_nm", 780.0),  # == wavelength_max_nm
    ("wavelength_min_nm", 900.0),
    ("wavelength_min_nm", -10.0),
])
def test_domain_rejects_bad_values_naming_the_key(key, value):
    with pytest.raises(ValueError, match=rf"domain: {key} = "):
        small_domain(**{key: value})


def test_domain_from_dict_rejects_unknown_keys():
    d = small_domain().to_dict()
    d["fov"] = 3.0
    with pytest.raises(ValueError, match="unknown keys.*fov"):
        Domain.from_dict(d)


def test_stop_as_first_surface_samples_a_straight_p_o(build_lens):
    """P_o of a stop in front of everything is the straight line to the stop (issue 15;
    tests/fit/test_stop_placement.py checks its OPL against the closed form)."""
    lens = build_lens([
        {"shape": "plane", "thickness": 5.0, "material": "air", "semi_diameter": 10.0,
         "stop": True},
        {"shape": "plane", "thickness": 10.0, "material": "N-BK7", "semi_diameter": 20.0},
        {"shape": "plane", "thickness": 20.0, "material": "air", "semi_diameter": 20.0},
    ])
    got = sample_object_side(lens, small_domain(), 4, 4, seed=0)
    assert len(got) == 16
    # x_o, y_o lie on the first surface, the stop: the stop point to Newton's tolerance
    assert np.max(np.abs(got.outputs[:, :2] - got.inputs[:, 3:5])) <= 10 * NEWTON_TOL_MM
    assert len(sample_sensor_side(lens, small_domain(), 4, 4, seed=0)) == 16


def relay(build_lens, back: float):
    """The stop 120 mm before a biconvex N-BK7 singlet, the sensor ``back`` mm behind."""
    return build_lens([
        {"shape": "plane", "thickness": 120.0, "material": "air", "semi_diameter": 5.0,
         "stop": True},
        {"shape": "sphere", "radius": 60.0, "thickness": 4.0, "material": "N-BK7",
         "semi_diameter": 10.0},
        {"shape": "sphere", "radius": -60.0, "thickness": back, "material": "air",
         "semi_diameter": 10.0},
    ])


def test_sensor_at_the_image_of_the_stop_cannot_be_served(build_lens):
    """With the sensor conjugate to the stop, every ray from a stop point lands (up to
    aberrations) on that point's image: other sensor points are out of reach, and the
    sampler must say so, naming the file, instead of returning nothing."""
    dom = small_domain(field_deg=10.0, stop_radius_mm=5.0, sensor_radius_mm=10.0,
                       focus_min_mm=-0.01, focus_max_mm=0.01)
    conjugate = image_distance(relay(build_lens, 50.0), 1e-9)  # the stop's image
    assert 100.0 < conjugate < 130.0
    with pytest.raises(SamplingError, match=r"<test>: P_s: none of 80 rays"):
        sample_sensor_side(relay(build_lens, conjugate), dom, 20, 4, seed=1)
    # The same lens with the sensor elsewhere serves part of that domain
    ok = sample_sensor_side(relay(build_lens, 50.0), dom, 20, 4, seed=1)
    assert 0 < len(ok) < ok.requested


def test_scene_points_inside_the_lens_are_refused(build_lens):
    """A close focus nearer than the front of the lens (+1 mm, where rays start) would
    put scene points on the wrong side of the launch plane: refused with the key."""
    lens = plate_before_stop(build_lens)
    with pytest.raises(SamplingError, match=r"<test>: P_o: close_focus_mm = 0\.5 "):
        sample_object_side(lens, small_domain(close_focus_mm=0.5, field_deg=5.0), 4, 4, 0)
    # 2 mm (cos 5 deg * 2 > 1): allowed, and the OPL is right to the scene point
    s = sample_object_side(lens, small_domain(close_focus_mm=2.0, field_deg=5.0), 20, 4, 2)
    x, o = s.inputs[s.inputs[:, 2] > 0], s.outputs[s.inputs[:, 2] > 0]
    d_o = 1.0 / x[:, 2]
    w = np.stack([x[:, 0], x[:, 1], -np.sqrt(1.0 - x[:, 0] ** 2 - x[:, 1] ** 2)], axis=1)
    entry = np.concatenate([o[:, :2], np.zeros((len(o), 1))], axis=1)
    out = trace(lens, Rays(d_o[:, None] * w, entry - d_o[:, None] * w, x[:, 5]),
                [Step(0), Step(1), Step(2)], clip=False)
    np.testing.assert_allclose(out.pos[:, :2], x[:, 3:5], rtol=0, atol=1e-8)
    np.testing.assert_allclose(out.opl_mm - d_o, o[:, 3], rtol=0, atol=2e-9)


# --- default domain --------------------------------------------------------------------------


def test_default_domain_caps_a_fast_lens_at_f2(lens0001):
    d = default_domain(lens0001)
    assert d.stop_radius_mm < lens0001.stop_radius_max_mm
    # Independent of how it was found: the paraxial f-number at that stop is 2
    assert paraxial(lens0001, stop_radius_mm=d.stop_radius_mm).f_number == pytest.approx(
        2.0, rel=1e-12)
    efl = paraxial(lens0001).efl_mm
    # The field fills the full-frame image circle (21.63 mm), focus reaches 10 EFL
    assert efl * math.tan(math.radians(d.field_deg)) == pytest.approx(
        math.hypot(36, 24) / 2, rel=1e-12)
    assert d.close_focus_mm == pytest.approx(10 * efl, rel=1e-12)
    travel = image_distance(lens0001, d.close_focus_mm) - image_distance(lens0001, math.inf)
    assert d.focus_min_mm < 0.0 < travel < d.focus_max_mm
    # An explicit f-number
    d8 = default_domain(lens0001, f_number=8.0)
    assert paraxial(lens0001, stop_radius_mm=d8.stop_radius_mm).f_number == pytest.approx(8.0)


def test_default_domain_opens_a_slow_lens_wide():
    lens = load_lens("0003")  # a Petzval lens at f/3.4
    assert paraxial(lens).f_number > 2.0
    assert default_domain(lens).stop_radius_mm == lens.stop_radius_max_mm
    with pytest.raises(ValueError, match="wider than"):
        default_domain(lens, f_number=1.0)


def test_default_domain_field_is_capped_at_60_degrees():
    fisheye = load_lens("0014")  # EFL 9.7 mm: the image circle would need 66 degrees
    assert math.degrees(math.atan(21.63 / paraxial(fisheye).efl_mm)) > 60.0
    assert default_domain(fisheye).field_deg == 60.0


@pytest.mark.parametrize("close", [math.inf, 1234.5])
def test_domain_round_trips_through_dict(lens0001, close):
    d = default_domain(lens0001).with_(close_focus_mm=close)
    back = Domain.from_dict(d.to_dict())
    assert back == d
    assert back.to_dict() == d.to_dict()
    if math.isinf(close):
        assert d.to_dict()["close_focus_mm"] == "inf"  # JSON has no infinity
        assert back.inverse_distance_max == 0.0


def test_sensor_shift_in_front_of_the_last_surface_is_refused(lens0001):
    # The back gap of 0001 is 55.7 mm: a shift of -60 mm puts the sensor inside the lens,
    # where P_s would silently follow rays backwards
    gap = lens0001.sensor_z - lens0001.vertex_z[-1]
    dom = default_domain(lens0001).with_(focus_min_mm=-(gap + 1.0))
    with pytest.raises(SamplingError, match="focus_min_mm"):
        sample_sensor_side(lens0001, dom, 2, 4, seed=0)


def test_the_grid_s_stop_points_are_rim_weighted_unless_the_rim_is_dead():
    """sample_grid's pilot (issue 41): lens 0001's rays pass near the stop's rim, so its
    stop points are rim-weighted (STOP_EDGE_SHARE); lens 0004's sensor-side rays beyond
    90% of its f/2.8 stop (its stated design's) miss the rear group (a dead rim), so its
    grid is drawn uniform: exactly the points and field points of the uniform draw of
    the same seed. A grown grid draws its new stop points by the same law."""
    from lensfit.poly.tensor import symmetric_disc_points
    from lensfit.sample import default_domain
    from lensfit.sample.rays import STOP_EDGE_SHARE, _grid_field, extend_grid, sample_grid

    lens = load_lens("0001")
    domain = default_domain(lens)
    g = sample_grid(lens, domain, "P_s", 40, 128, seed=5)
    assert g.stop_edge_share == STOP_EDGE_SHARE > 0.0
    rng = np.random.default_rng(5)
    _grid_field(domain, "P_s", 40, rng)
    np.testing.assert_array_equal(
        g.aperture, symmetric_disc_points(rng, 128, STOP_EDGE_SHARE) * domain.stop_radius_mm)
    assert extend_grid(lens, domain, g, points=8, seed=9).stop_edge_share == STOP_EDGE_SHARE
    # Fewer than MIN_EDGE_POINTS: uniform, no pilot
    assert sample_grid(lens, domain, "P_s", 40, 64, seed=5).stop_edge_share == 0.0

    lens = load_lens("0004")
    domain = default_domain(lens)
    g = sample_grid(lens, domain, "P_s", 40, 128, seed=5)
    assert g.stop_edge_share == 0.0
    rng = np.random.default_rng(5)
    np.testing.assert_array_equal(g.field, _grid_field(domain, "P_s", 40, rng))
    np.testing.assert_array_equal(g.aperture,
                                  symmetric_disc_points(rng, 128) * domain.stop_radius_mm)
    rim = np.hypot(g.aperture[:, 0], g.aperture[:, 1]) > 0.9 * domain.stop_radius_mm
    assert np.mean(~g.ok[:, rim]) > 0.1  # what the pilot saw, on the whole grid
