"""The ray tracer against closed forms, independent root finding and invariants."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from lensfit.glass import catalog_glass
from lensfit.paraxial import image_distance, paraxial, stop_radius_for_f_number
from lensfit.prescription import load_lens
from lensfit.trace import surfaces
from lensfit.trace.tracer import (
    Rays,
    Status,
    Step,
    backward_path,
    forward_path,
    ghost_path,
    trace,
)

BK7 = catalog_glass("N-BK7")


def all_finite(r: Rays) -> bool:
    """No NaN or inf anywhere, failed rays included."""
    return all(np.all(np.isfinite(a)) for a in (r.pos, r.dir, r.opl_mm, r.transmittance))


def plate(build_lens, t=10.0, gap=5.0, back=20.0, material="N-BK7", sd=40.0):
    return build_lens(
        [
            {
                "shape": "plane",
                "thickness": gap,
                "material": "air",
                "semi_diameter": sd,
                "stop": True,
            },
            {"shape": "plane", "thickness": t, "material": material, "semi_diameter": sd},
            {"shape": "plane", "thickness": back, "material": "air", "semi_diameter": sd},
        ]
    )


def pupil_disc(radius: float, n: int = 21) -> np.ndarray:
    """Points of a square grid inside a disc, the centre included."""
    g = np.linspace(-radius, radius, n)
    x, y = np.meshgrid(g, g)
    keep = x**2 + y**2 <= radius**2
    return np.stack([x[keep], y[keep]], axis=1)


# --- closed forms -------------------------------------------------------------------------


def test_plate_opl_and_displacement_closed_form(build_lens):
    lens = plate(build_lens)
    lam = 550.0
    n = float(BK7.n(lam))
    th = np.radians(np.linspace(0.0, 60.0, 13))
    rays = Rays(np.zeros((len(th), 3)), np.stack([0 * th, np.sin(th), np.cos(th)], 1), lam)
    out = trace(lens, rays)
    assert np.all(out.ok)
    th_glass = np.arcsin(np.sin(th) / n)
    # OPL from the stop plane (z = 0) to the sensor: air, glass, air
    opl = 5.0 / np.cos(th) + n * 10.0 / np.cos(th_glass) + 20.0 / np.cos(th)
    y = 5.0 * np.tan(th) + 10.0 * np.tan(th_glass) + 20.0 * np.tan(th)
    # float64 round-off over ~50 mm of path: a few 1e-14 mm; 1e-11 leaves room
    np.testing.assert_allclose(out.opl_mm, opl, rtol=0, atol=1e-11)
    np.testing.assert_allclose(out.pos[:, 1], y, rtol=0, atol=1e-11)
    np.testing.assert_allclose(out.dir, rays.dir, atol=1e-14)  # a plate does not deviate


def test_single_sphere_aplanatic_points_image_perfectly(build_lens):
    """A sphere of radius R between glass n and air images the point R/n from its centre
    to a virtual point nR from it (same side) without any aberration: refracted rays
    point away from the image and OPL(O->P) - |P - I| is the same for every ray."""
    R, lam = 20.0, 550.0
    lens = build_lens(
        [
            {
                "shape": "plane",
                "thickness": 60.0,
                "material": "air",
                "semi_diameter": 19.0,
                "stop": True,
            },
            {"shape": "plane", "thickness": 60.0, "material": "N-BK7", "semi_diameter": 19.0},
            {
                "shape": "sphere",
                "radius": -R,
                "thickness": 10.0,
                "material": "air",
                "semi_diameter": 19.0,
            },
        ]
    )
    n = float(BK7.n(lam))
    z_vertex = lens.vertex_z[2]
    centre = z_vertex - R
    obj = np.array([0.0, 0.0, centre - R / n])
    img = np.array([0.0, 0.0, centre - n * R])
    ang = np.radians(np.linspace(-35, 35, 41))  # all within the 19 mm clear aperture
    d = np.stack([0.3 * np.sin(ang), np.sin(ang), np.cos(ang)], 1)
    out = trace(lens, Rays(np.tile(obj, (len(ang), 1)), d, lam), [Step(2)])
    assert np.all(out.ok)
    away = out.pos - img
    away /= np.linalg.norm(away, axis=1, keepdims=True)
    # Directions are unit vectors built from ~20 mm quantities: 1e-13 is ~100 ulp
    np.testing.assert_allclose(out.dir, away, atol=1e-13)
    w = out.opl_mm - np.linalg.norm(out.pos - img, axis=1)
    # Path lengths ~ 30 mm: 1e-12 mm is ~100 ulp and 1e-6 of a wavelength
    assert np.ptp(w) < 1e-12


def test_quarter_wave_mgf2_reflectance_through_the_tracer(build_lens):
    lam = 550.0
    lens = build_lens(
        [
            {
                "shape": "plane",
                "thickness": 5.0,
                "material": "air",
                "semi_diameter": 10.0,
                "stop": True,
            },
            {"shape": "plane", "thickness": 5.0, "material": "N-BK7", "semi_diameter": 10.0},
            {"shape": "plane", "thickness": 5.0, "material": "air", "semi_diameter": 10.0},
        ],
        coating={"default": "mgf2", "design_wavelength_nm": lam},
    )
    rays = Rays([[0.0, 0.0, -1.0]], [[0.0, 0.0, 1.0]], lam)
    out = trace(lens, rays, [Step(0), Step(1, reflect=True)])
    assert out.ok[0]
    n1, n2, n3 = 1.0, float(catalog_glass("MgF2").n(lam)), float(BK7.n(lam))
    expected = ((n1 * n3 - n2**2) / (n1 * n3 + n2**2)) ** 2
    assert out.transmittance[0] == pytest.approx(expected, abs=1e-9)
    assert out.dir[0, 2] == pytest.approx(-1.0, abs=1e-15)


def test_ghost_of_a_plate_closed_form(build_lens):
    """Normal incidence on a bare plate: the two-bounce ghost carries T1 R2 R1 T2 of the
    power and 2 n t more optical path than the direct ray."""
    lam, t = 600.0, 10.0
    lens = plate(build_lens, t=t)
    n = float(BK7.n(lam))
    r = ((n - 1) / (n + 1)) ** 2
    rays = Rays([[1.0, 2.0, 0.0]], [[0.0, 0.0, 1.0]], lam)
    direct = trace(lens, rays, fresnel_loss=True)
    ghost = trace(lens, rays, ghost_path(lens, 1, 2), fresnel_loss=True, end_z=lens.sensor_z)
    assert ghost.ok[0]
    assert direct.transmittance[0] == pytest.approx((1 - r) ** 2, rel=1e-13)
    assert ghost.transmittance[0] == pytest.approx((1 - r) ** 2 * r * r, rel=1e-13)
    assert ghost.opl_mm[0] - direct.opl_mm[0] == pytest.approx(2 * n * t, abs=1e-12)


# --- reversibility and Fermat on real lenses -----------------------------------------------


@pytest.mark.parametrize("lens_id", ["0001", "0014", "2004"])
def test_forward_then_backward_returns_the_same_ray(lens_id):
    lens = load_lens(lens_id)
    rng = np.random.default_rng(7)
    n = 4000
    z0 = -30.0
    # Rays from a field of object points towards the middle of the front element (the
    # fisheye's deep meniscus loses rays aimed at its rim)
    sd0 = lens.surfaces[0].semi_diameter_mm
    start = np.c_[rng.uniform(-0.25, 0.25, (n, 2)) * sd0, np.full(n, z0)]
    aim = np.c_[rng.uniform(-0.15, 0.15, (n, 2)) * sd0, np.zeros(n)]
    lam = rng.uniform(380, 780, n)
    # Housings are not what is tested here: without them far more rays get through
    fwd = trace(lens, Rays(start, aim - start, lam), clip=False)
    assert all_finite(fwd)
    ok = fwd.ok
    assert ok.sum() > 500  # enough rays get through to make the test meaningful
    back_in = Rays(fwd.pos[ok], -fwd.dir[ok], lam[ok])
    back = trace(lens, back_in, backward_path(lens), end_z=z0, clip=False)
    assert np.all(back.ok)
    # The acceptance bound: the same ray to 1e-9 mm
    assert np.max(np.abs(back.pos - start[ok])) < 1e-9
    d0 = (aim - start)[ok] / np.linalg.norm((aim - start)[ok], axis=1, keepdims=True)
    assert np.max(np.abs(back.dir + d0)) < 1e-11
    # and the same optical path both ways (nm-scale agreement needs ~1e-9 mm)
    assert np.max(np.abs(back.opl_mm - fwd.opl_mm[ok])) < 1e-9


def _fermat_spread_waves(lens, f_number: float, lam: float, object_distance: float) -> float:
    stop = stop_radius_for_f_number(lens, f_number)
    z_last = lens.vertex_z[-1]
    ep = paraxial(lens, stop_radius_mm=stop).entrance_pupil
    if math.isinf(object_distance):
        # A plane wave filling the entrance pupil (the stop trims its rim)
        pts = pupil_disc(ep.radius_mm * 1.02, 41)
        start = np.c_[pts, np.full(len(pts), -10.0)]
        rays = Rays(start, np.tile([0.0, 0.0, 1.0], (len(pts), 1)), lam)
    else:
        # A spherical wave from the axial object point, filling the entrance pupil
        slope = pupil_disc(1.02, 41) * ep.radius_mm / (object_distance + ep.position_mm)
        d = np.c_[slope, np.ones(len(slope))]
        rays = Rays(np.tile([0.0, 0.0, -object_distance], (len(slope), 1)), d, lam)
    out = trace(lens, rays, forward_path(lens), stop_radius_mm=stop)
    ok = out.ok
    assert ok.sum() > 100
    focus = np.array([0.0, 0.0, z_last + image_distance(lens, object_distance, wavelength_nm=lam)])
    total = out.opl_mm[ok] + np.linalg.norm(focus - out.pos[ok], axis=1)
    return float(np.ptp(total) / (lam * 1e-6))


@pytest.mark.parametrize("object_distance", [math.inf, 2000.0])
def test_fermat_equal_optical_path_at_the_diffraction_limit(object_distance):
    """Stopped down to f/64 the double Gauss is diffraction-limited: the optical path
    from the object (or a plane wave) to the paraxial image point is the same over the
    pupil to lambda/100."""
    lens = load_lens("0001")
    spread = _fermat_spread_waves(lens, 64.0, 550.0, object_distance)
    assert spread < 0.01
    # The check can fail: wide open the same lens is far from diffraction-limited
    assert _fermat_spread_waves(lens, 2.0, 550.0, object_distance) > 0.1


# --- intersections against brute-force root finding ----------------------------------------


def _brute_force_t(surface, q, d, t_max):
    """First root of z(t) - sag(x(t), y(t)) along the ray, bracketed on a fine grid."""

    def f(t):
        p = q + t * d
        z = surface.sag(p[0], p[1])
        return p[2] - float(z)

    ts = np.linspace(0.0, t_max, 20001)
    p = q[None, :] + ts[:, None] * d[None, :]
    with np.errstate(invalid="ignore"):
        vals = p[:, 2] - surface.sag(p[:, 0], p[:, 1])
    ok = np.isfinite(vals)
    for i in range(len(ts) - 1):
        if ok[i] and ok[i + 1] and np.sign(vals[i]) != np.sign(vals[i + 1]):
            return brentq(f, ts[i], ts[i + 1], xtol=1e-14, rtol=1e-15)
    return None


@pytest.mark.parametrize(
    "spec",
    [
        {"shape": "asphere", "radius": 25.0, "conic": -0.6, "aspheric": [2e-5, -3e-8, 1e-11]},
        {"shape": "asphere", "radius": -18.0, "conic": 0.5, "aspheric": [-4e-5, 2e-7]},
        {"shape": "asphere", "radius": 40.0, "conic": -2.0, "aspheric": [1e-6]},
        {"shape": "cylinder-x", "radius": 30.0},
        {"shape": "cylinder-y", "radius": -22.0},
        {"shape": "sphere", "radius": 15.0},
    ],
)
def test_intersection_matches_brute_force_root_finding(build_lens, spec):
    lens = build_lens(
        [
            {
                "shape": "plane",
                "thickness": 10.0,
                "material": "air",
                "semi_diameter": 12.0,
                "stop": True,
            },
            {**spec, "thickness": 10.0, "material": "N-BK7", "semi_diameter": 12.0},
            {"shape": "plane", "thickness": 10.0, "material": "air", "semi_diameter": 12.0},
        ]
    )
    surf = lens.surfaces[1]
    rng = np.random.default_rng(3)
    n = 40
    q = np.c_[rng.uniform(-8, 8, (n, 2)), np.full(n, -6.0)]
    d = np.c_[rng.uniform(-0.3, 0.3, (n, 2)), np.ones(n)]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, hit = surfaces.intersect(surf, q, d)
    checked = 0
    for i in range(n):
        tb = _brute_force_t(surf, q[i], d[i], 30.0)
        if tb is None:
            assert not hit[i]
            continue
        assert hit[i]
        # brentq to 1e-14; Newton converges to 1e-13: agreement to 1e-10 mm (0.1 pm)
        assert t[i] == pytest.approx(tb, abs=1e-10)
        checked += 1
    assert checked > n // 2


def test_cylindrical_lens_focuses_in_one_axis_only(build_lens):
    lens = build_lens(
        [
            {
                "shape": "plane",
                "thickness": 2.0,
                "material": "air",
                "semi_diameter": 10.0,
                "stop": True,
            },
            {
                "shape": "cylinder-x",
                "radius": 50.0,
                "thickness": 4.0,
                "material": "N-BK7",
                "semi_diameter": 10.0,
            },
            {"shape": "plane", "thickness": 90.0, "material": "air", "semi_diameter": 10.0},
        ]
    )
    lam = 587.56
    f_y = image_distance(lens, math.inf, meridian="y", wavelength_nm=lam)
    f_x = image_distance(lens, math.inf, meridian="x", wavelength_nm=lam)
    assert math.isinf(f_x) or abs(f_x) > 1e12  # no power in x
    pts = pupil_disc(0.5, 11)
    rays = Rays(np.c_[pts, np.zeros(len(pts))], np.tile([0.0, 0.0, 1.0], (len(pts), 1)), lam)
    out = trace(lens, rays, end_z=lens.vertex_z[-1] + f_y)
    assert np.all(out.ok)
    # x is untouched: every surface is flat along x
    np.testing.assert_array_equal(out.pos[:, 0], pts[:, 0])
    np.testing.assert_array_equal(out.dir[:, 0], 0.0)
    # y focuses: at 0.5 mm aperture on f ~ 97 mm the spherical aberration blur is
    # ~ h^3/f^2 ~ 1e-5 mm, a 1e-4 bound is 5000x smaller than the 0.5 mm input spread
    assert np.max(np.abs(out.pos[:, 1])) < 1e-4


# --- stiff and extreme cases ----------------------------------------------------------------


def test_grazing_incidence_stays_finite(build_lens):
    lens = plate(build_lens, gap=1.0, sd=1e6)
    th = np.radians([80.0, 89.0, 89.99, 89.9999, 90.0])
    rays = Rays(np.zeros((len(th), 3)), np.stack([0 * th, np.sin(th), np.cos(th)], 1), 550.0)
    out = trace(lens, rays, fresnel_loss=True)
    assert all_finite(out)
    assert np.all(out.status[:-1] == Status.OK)
    assert out.status[-1] == Status.MISSED  # parallel to the planes: never reaches them
    # Transmittance falls towards zero at grazing incidence, monotonically
    tr = out.transmittance[:-1]
    assert np.all(np.diff(tr) < 0) and tr[-1] < 1e-3


def test_edge_of_total_internal_reflection(build_lens):
    """Glass to air through a plane: below the critical angle refraction, above it TIR,
    with the status set and nothing NaN on either side."""
    lam = 550.0
    n = float(BK7.n(lam))
    lens = build_lens(
        [
            {
                "shape": "plane",
                "thickness": 1.0,
                "material": "air",
                "semi_diameter": 1e3,
                "stop": True,
            },
            {"shape": "plane", "thickness": 5.0, "material": "N-BK7", "semi_diameter": 1e3},
            {"shape": "plane", "thickness": 5.0, "material": "air", "semi_diameter": 1e3},
        ]
    )
    crit = math.asin(1.0 / n)
    th = crit + np.array([-1e-3, -1e-9, 1e-9, 1e-3, 0.5])
    start = np.zeros((len(th), 3))
    start[:, 2] = 3.0  # inside the glass
    rays = Rays(start, np.stack([0 * th, np.sin(th), np.cos(th)], 1), lam)
    out = trace(lens, rays, [Step(2)], fresnel_loss=True)
    assert all_finite(out)
    assert list(out.status) == [Status.OK, Status.OK, Status.TIR, Status.TIR, Status.TIR]
    assert np.all(out.surface[2:] == 2)
    # Just below the critical angle the refracted ray grazes and carries little power
    assert out.transmittance[1] < out.transmittance[0] < 1.0


def test_fisheye_fields_beyond_90_degrees():
    """The 0014 fisheye takes rays from behind its front vertex plane. Rays from 85 to
    100 degrees off axis: every one either reaches the sensor or has a clear status;
    no NaN anywhere."""
    lens = load_lens("0014")
    out_ok = {}
    for field in (85.0, 90.5, 95.0, 100.0):
        th = math.radians(field)
        d = np.array([0.0, math.sin(th), math.cos(th)])
        # Aim at points on the front surface, start 50 mm back along the ray
        h = np.linspace(-1.0, 1.0, 201) * lens.surfaces[0].semi_diameter_mm
        target = np.c_[np.zeros_like(h), h, lens.surfaces[0].sag(0 * h, h)]
        rays = Rays(target - 50.0 * d, np.tile(d, (len(h), 1)), 550.0)
        out = trace(lens, rays, fresnel_loss=True)
        assert all_finite(out)
        assert set(np.unique(out.status)) <= {s.value for s in Status}
        failed = out.status != Status.OK
        assert np.all(out.surface[failed] >= 0)
        out_ok[field] = int(out.ok.sum())
    assert out_ok[85.0] > 0  # the fisheye does image 85 degrees


def test_stops_from_f0_7_to_f64():
    lens = load_lens("0001")
    with pytest.raises(ValueError, match="wider than"):
        stop_radius_for_f_number(lens, 0.7)
    r64 = stop_radius_for_f_number(lens, 64.0)
    pts = pupil_disc(lens.surfaces[0].semi_diameter_mm, 61)
    rays = Rays(np.c_[pts, np.full(len(pts), -5.0)], np.tile([0, 0, 1.0], (len(pts), 1)), 550.0)
    out = trace(lens, rays, stop_radius_mm=r64)
    assert all_finite(out)
    assert 0 < out.ok.sum() < len(pts)
    assert np.all(out.surface[out.status == Status.CLIPPED] >= 0)


@pytest.mark.parametrize("lam", [380.0, 780.0])
def test_spectral_extremes_agree_with_paraxial_focus(lam):
    """At 380 and 780 nm small-aperture real rays focus where the paraxial trace at the
    same wavelength says: dispersion is applied the same way in both."""
    lens = load_lens("0001")
    h = np.linspace(0.01, 0.05, 5)
    rays = Rays(np.c_[0 * h, h, np.full(len(h), -5.0)], np.tile([0, 0, 1.0], (len(h), 1)), lam)
    out = trace(lens, rays, forward_path(lens))
    assert all_finite(out) and np.all(out.ok)
    z_cross = out.pos[:, 2] - out.pos[:, 1] / out.dir[:, 1] * out.dir[:, 2]
    bfd = lens.vertex_z[-1] + image_distance(lens, math.inf, wavelength_nm=lam)
    # Spherical aberration at h <= 0.05 mm on this f/1.1 design shifts focus by < 1e-4 mm
    np.testing.assert_allclose(z_cross, bfd, atol=1e-4)


def test_axial_colour_has_the_sign_of_normal_dispersion():
    lens = load_lens("0001")
    blue = image_distance(lens, math.inf, wavelength_nm=380.0)
    red = image_distance(lens, math.inf, wavelength_nm=780.0)
    assert blue != red and all(map(math.isfinite, (blue, red)))


def test_rays_start_status_survives_and_failed_rays_do_not_move(build_lens):
    lens = plate(build_lens, sd=5.0)
    rays = Rays([[0.0, 0.0, 0.0], [0.0, 6.0, 0.0]], [[0, 0, 1.0], [0, 0, 1.0]], 550.0)
    out = trace(lens, rays)
    assert out.status[0] == Status.OK
    assert out.status[1] == Status.CLIPPED and out.surface[1] == 0
    # The clipped ray stays where it met the stop plane
    np.testing.assert_array_equal(out.pos[1], [0.0, 6.0, 0.0])


@pytest.mark.parametrize(
    ("pos", "direction", "lam", "match"),
    [
        ([[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]], 550.0, "non-zero"),
        ([[np.nan, 0.0, 0.0]], [[0.0, 0.0, 1.0]], 550.0, "finite"),
        ([[0.0, 0.0, 0.0]], [[0.0, np.inf, 1.0]], 550.0, "finite"),
        ([[0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]], -1.0, "wavelengths"),
        ([[0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]], np.nan, "wavelengths"),
        ([[0.0, 0.0, 0.0]] * 2, [[0.0, 0.0, 1.0]], 550.0, "directions for 2"),
    ],
)
def test_bad_rays_are_refused_before_any_nan_is_made(pos, direction, lam, match):
    with pytest.raises(ValueError, match=match):
        Rays(pos, direction, lam)


def test_wavelengths_outside_a_glass_range_are_refused():
    lens = load_lens("2002")  # Ohara catalog glasses, published from 290-370 nm up
    rays = Rays([[0.0, 0.0, -5.0]], [[0.0, 0.0, 1.0]], 250.0)
    with pytest.raises(ValueError, match=r"outside the .* nm range of glass S-"):
        trace(lens, rays)
