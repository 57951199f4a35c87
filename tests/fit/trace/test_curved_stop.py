"""A stop on a curved refracting surface clips where design programs clip it: on the
surface, at the radius of the ray's hit, sqrt(x^2 + y^2) <= r (lensdb/README.md, The
aperture stop). Checked against constructions that share nothing with lensfit's model
but the glass indices: a plain sequential trace of the file's surfaces written here
(sphere intersection, Snell, unpolarised Fresnel), and a brute-force Huygens sum of a
collimated beam sampled uniformly over the entrance side.

The lens is tests/fit/fixtures/lenses/cooke-curved-stop.toml: a 50 mm Cooke triplet with
`stop = true` on the concave front of its negative element (its sag at the f/5 stop
edge is -0.33 mm, so a vertex plane clips a bundle at 14 degrees ~0.09 mm off).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lensfit.codegen.scene import light_direction
from lensfit.paraxial import stop_radius_for_f_number
from lensfit.prescription import load_lens, make_lens
from lensfit.psf.psf import best_focus_offset, exact_psf_nodes, sunflower_points
from lensfit.sample.aim import aim_object_side
from lensfit.trace.tracer import Rays, Step, trace
from lensfit.trust.check import _window

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "lenses" / "cooke-curved-stop.toml"
STOP_FILE_INDEX = 2  # the file's surface with `stop = true`
F_NUMBER = 5.0
LAM = 550.0


def curved() -> object:
    return load_lens(FIXTURE)


def vertex_plane() -> object:
    """The same lens as lensfit modelled it before: the stop a plane tangent to the
    vertex of surface 2, written so in the file (a stop plane is kept as written)."""
    data = curved().to_dict()
    surf = data["surface"]
    stop = surf[STOP_FILE_INDEX]
    del stop["stop"]
    plane = {"shape": "plane", "thickness": 0.0, "material": "air",
             "semi_diameter": stop["semi_diameter"], "stop": True}
    surf.insert(STOP_FILE_INDEX, plane)
    return make_lens(surf, coating=data["coating"])


# --- an independent sequential trace of the file's surfaces ----------------------------------

def plain_trace(lens, pos: np.ndarray, d: np.ndarray, lam: float, z_end: float,
                stop_radius: float | None = None):
    """Trace rays (N, 3) through the *file's* surfaces (spheres only; lensfit's inserted
    stop surface skipped) to the plane z = z_end. Returns (position there, OPL, power
    transmittance (unpolarised Fresnel), alive, hits (N, surfaces, 3)). With
    ``stop_radius`` every surface clips at its semi-diameter and the file's stop surface
    at stop_radius; without, nothing clips."""
    surfaces = [s for s in lens.surfaces if not s.inserted]
    pos, d = pos.astype(np.float64).copy(), d / np.linalg.norm(d, axis=1, keepdims=True)
    n_pts = len(pos)
    opl, tau = np.zeros(n_pts), np.ones(n_pts)
    alive = np.ones(n_pts, dtype=bool)
    hits = np.full((n_pts, len(surfaces), 3), np.nan)
    z_vertex, n1 = 0.0, 1.0
    for k, s in enumerate(surfaces):
        n2 = float(s.medium.n(lam))
        o = pos - [0.0, 0.0, z_vertex]
        if s.shape == "plane":
            t = -o[:, 2] / d[:, 2]
            normal = np.tile([0.0, 0.0, -1.0], (n_pts, 1))
        else:  # the sphere through the vertex, centre at (0, 0, R)
            assert s.shape == "sphere"
            big_r = s.radius_mm
            oc = o - [0.0, 0.0, big_r]
            b = np.einsum("ij,ij->i", oc, d)
            disc = b * b - (np.einsum("ij,ij->i", oc, oc) - big_r * big_r)
            alive &= disc >= 0
            root = np.sqrt(np.maximum(disc, 0.0))
            # the near half of the sphere (through the vertex): z < R in local coordinates
            t = np.where(big_r > 0, -b - root, -b + root)
            p_loc = o + t[:, None] * d
            normal = (p_loc - [0.0, 0.0, big_r]) / -big_r  # unit, -z at the vertex
        pos = pos + t[:, None] * d
        opl += n1 * t
        hits[:, k] = pos - [0.0, 0.0, z_vertex]
        if stop_radius is not None:
            limit = stop_radius if k == lens.stop_file_index else s.semi_diameter_mm
            alive &= np.hypot(hits[:, k, 0], hits[:, k, 1]) <= limit
        # Snell, and the unpolarised Fresnel power transmittance
        cos_i = -np.einsum("ij,ij->i", d, normal)
        normal = np.where(cos_i[:, None] < 0, -normal, normal)
        cos_i = np.abs(cos_i)
        eta = n1 / n2
        k2 = 1.0 - eta * eta * (1.0 - cos_i * cos_i)
        alive &= k2 >= 0
        cos_t = np.sqrt(np.maximum(k2, 0.0))
        d = eta * d + (eta * cos_i - cos_t)[:, None] * normal
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        rs = ((n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)) ** 2
        rp = ((n1 * cos_t - n2 * cos_i) / (n1 * cos_t + n2 * cos_i)) ** 2
        tau *= 1.0 - 0.5 * (rs + rp)
        z_vertex += s.thickness_mm
        n1 = n2
    t = (z_end - pos[:, 2]) / d[:, 2]
    pos = pos + t[:, None] * d
    opl += t  # air behind the last surface
    return pos, opl, tau, alive, hits


def beam(field_deg: float, half_width: float, n: int, z0: float = -5.0):
    """A collimated beam at field angle (0, field_deg): an n x n uniform grid on the plane
    z = z0 around the line to the stop centre, the beam's direction, and the plane
    wave's OPL at each start point (relative to the plane through the first vertex
    perpendicular to the beam)."""
    x_o, y_o = light_direction(0.0, field_deg)
    d = -np.array([x_o, y_o, -math.sqrt(1.0 - x_o * x_o - y_o * y_o)])
    chief = aim_object_side(curved(), x_o, y_o, 0.0, 0.0, 0.0, LAM)
    centre = chief.unknowns[0] + d[:2] / d[2] * z0  # where the chief ray crosses z = z0
    g = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    gx, gy = np.meshgrid(g * half_width + centre[0], g * half_width + centre[1])
    pos = np.column_stack([gx.ravel(), gy.ravel(), np.full(n * n, z0)])
    return pos, np.tile(d, (n * n, 1)), pos @ d


# --- 1. the aperture is the set of rays whose hit on the surface is within the radius -----

@pytest.mark.parametrize("field_deg", [0.0, 18.0])
def test_stop_points_are_the_hits_on_the_curved_surface(field_deg):
    lens = curved()
    radius = stop_radius_for_f_number(lens, F_NUMBER)
    s = lens.stop_index
    assert lens.surfaces[s].inserted == "front" and lens.stop_file_index == STOP_FILE_INDEX
    # A grid well beyond the bundle the stop lets through (the entrance pupil at f/5 has
    # a radius of ~5.2 mm): 161 x 161 rays
    pos, d, _ = beam(field_deg, 8.0, 161)
    # Independent: the hit on the file's surface 2 of a plain trace of the whole lens
    _, _, _, exists, hits = plain_trace(lens, pos, d, LAM, lens.sensor_z)
    r_true = np.hypot(hits[:, STOP_FILE_INDEX, 0], hits[:, STOP_FILE_INDEX, 1])
    # Ours: the stop point (x_a, y_a) of each ray is where P_o's trace ends on the model's
    # stop surface; the model lets it through when it lies in the disc
    rays = trace(lens, Rays(pos, d, LAM), [Step(k) for k in range(s + 1)], clip=False)
    ok = exists & (rays.status == 0)
    assert ok.sum() > 0.9 * len(pos)
    # The stop point is the ray's x, y on the curved surface. Both traces are float64
    # arithmetic on ~10 mm coordinates: they agree to rounding (measured ~1e-14 mm)
    assert np.max(np.abs(rays.pos[ok, :2] - hits[ok, STOP_FILE_INDEX, :2])) < 1e-11
    r_model = np.hypot(rays.pos[:, 0], rays.pos[:, 1])
    # So the verdicts agree ray for ray (no ray of the grid lies within 1e-9 mm of the rim:
    # checked, so rounding cannot flip one)
    assert np.min(np.abs(r_true[ok] - radius)) > 1e-9
    passes = r_model[ok] <= radius
    assert np.array_equal(passes, r_true[ok] <= radius)
    assert 0.2 * ok.sum() < passes.sum() < 0.8 * ok.sum()  # the stop really clips here
    # The whole model (the tracer with every housing, the stop at its radius) clips the
    # rays the plain trace clips at every surface, and none other
    full = trace(lens, Rays(pos, d, LAM), stop_radius_mm=radius, end_z=lens.sensor_z)
    plain_alive = plain_trace(lens, pos, d, LAM, lens.sensor_z, stop_radius=radius)[3]
    assert np.array_equal(full.status == 0, plain_alive)
    # The fit's stop inputs are these points: P_o aimed at a stop point from the light is
    # the ray of the grid that reached it (where it crosses z = 0; Newton's tolerance on the
    # stop point is 1e-9 mm, magnified ~1.3x back to z = 0: 1e-8 mm)
    pick = np.nonzero(ok)[0][:: max(1, ok.sum() // 150)]
    x_o, y_o = light_direction(0.0, field_deg)
    aimed = aim_object_side(lens, x_o, y_o, 0.0, rays.pos[pick, 0], rays.pos[pick, 1], LAM)
    z0 = pos[0, 2]
    start_at_0 = pos[pick, :2] - d[pick, :2] / d[pick, 2:3] * z0
    assert aimed.ok.all() and np.max(np.abs(aimed.unknowns - start_at_0)) < 1e-8
    # The old model (the vertex plane) clips other rays: a real difference at 18 degrees
    old = vertex_plane()
    at_plane = trace(old, Rays(pos, d, LAM), [Step(k) for k in range(old.stop_index + 1)],
                     clip=False)
    old_passes = np.hypot(at_plane.pos[ok, 0], at_plane.pos[ok, 1]) <= radius
    changed = int(np.count_nonzero(old_passes != passes))
    print(f"field {field_deg}: {passes.sum()} rays pass, the vertex plane changes {changed}")
    if field_deg > 0.0:
        assert changed > 0.02 * passes.sum(), changed


# --- 2. the PSF against a brute-force Huygens sum --------------------------------------------

def huygens_psf(lens, field_deg: float, radius: float, focus: float, xs: np.ndarray,
                ys: np.ndarray, n: int = 300, weights: tuple[str, ...] = ("entrance",)
                ) -> dict[str, np.ndarray]:
    """|U|^2 on the pixel centres (len(ys), len(xs)) from a collimated beam at (0,
    field_deg), sampled on an n x n uniform grid over the entrance side, each ray traced
    by :func:`plain_trace` through every surface with clipping (housings, the stop on
    surface 2 at ``radius``) to the plane 0.5 mm behind the last vertex, then its phasor
    a sqrt(tau) exp(2 pi i (OPL + |pixel - q|) / lambda) from its point q there (Huygens'
    secondary source; no obliquity or 1/r factor, as lensfit), one PSF per weight a:

    * "entrance": a = 1, the beam's uniform amplitude over the entrance side;
    * "stop": a = sqrt(dA_stop / dA_entrance), dA_stop the grid cell's area on the stop
      surface (by differences over the grid). Per unit stop area the amplitude is then
      sqrt(dA_entrance / dA_stop), the square root of the light's flux through the stop:
      the weight lensfit gives its stop points (lensfit.psf, exact_front_flux), where
      "entrance" weighs them by the flux itself."""
    pos, d, opl0 = beam(field_deg, 6.5, n)
    z_plane = float(lens.vertex_z[-1]) + 0.5
    q, opl, tau, alive, hits = plain_trace(lens, pos, d, LAM, z_plane, stop_radius=radius)
    amps = {}
    for w in weights:
        amp = np.sqrt(tau)
        if w == "stop":
            sx, sy = (hits[:, STOP_FILE_INDEX, c].reshape(n, n) for c in (0, 1))
            step = 2 * 6.5 / n
            (dxdv, dxdu), (dydv, dydu) = np.gradient(sx, step), np.gradient(sy, step)
            amp = amp * np.sqrt(np.abs(dxdu * dydv - dxdv * dydu)).ravel()
        amps[w] = amp[alive]
    q, phase0 = q[alive], (opl0 + opl)[alive]
    k = 2 * math.pi / (LAM * 1e-6)
    px, py = np.meshgrid(xs, ys)
    pix = np.column_stack([px.ravel(), py.ravel(), np.full(px.size, lens.sensor_z + focus)])
    u = {w: np.zeros(len(pix), dtype=np.complex128) for w in weights}
    for a in range(0, len(q), 4096):
        sl = slice(a, a + 4096)
        dist = np.linalg.norm(pix[:, None, :] - q[None, sl, :], axis=2)
        phasor = np.exp(1j * k * (phase0[None, sl] + dist))
        for w in weights:
            u[w] += phasor @ amps[w][sl]
    return {w: (np.abs(u[w]) ** 2).reshape(len(ys), len(xs)) for w in weights}


def lensfit_psf(lens, field_deg, radius, focus, width, centre, pixels, points):
    pts = sunflower_points(points, radius)
    u, _ = exact_psf_nodes(lens, stop_radius_mm=radius, aperture_xy_mm=pts,
                           field_deg=(0.0, field_deg), wavelength_nm=LAM,
                           focus_offset_mm=focus, width=pixels, height=pixels, width_mm=width,
                           center_x_mm=centre[0], center_y_mm=centre[1], nodes=9)
    return np.abs(u) ** 2


def rel_l2(a: np.ndarray, b: np.ndarray) -> float:
    """Relative L2 difference of two PSFs, each normalised to unit power in the window."""
    a, b = a / a.sum(), b / b.sum()
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# The Huygens reference's grid: 300 x 300 over 13 mm, ~53000 rays through the f/5 stop; it
# agrees with 400 x 400 to 0.05% on axis and 0.2-0.3% at 14-18 degrees (measured)
POINTS = 6000  # lensfit's stop points (sunflower); 6000 against 12000: 0.04% / 0.6%
PIXELS = 32


# On axis 19 s: make bench (test_against_optiland.py checks curved stops on axis in make test)
@pytest.mark.parametrize("field_deg", [pytest.param(0.0, marks=pytest.mark.slow), 14.0])
def test_exact_psf_matches_a_brute_force_huygens_sum(field_deg):
    """lensfit's exact PSF (psf.exact_psf_nodes, as trust.psf_vs_exact takes it) against
    the Huygens sum of a collimated beam, both normalised to unit power in the trust
    check's window at best focus, f/5, 550 nm. Measured (relative L2; `PYTHONPATH=fit
    .venv/bin/python tests/fit/trace/test_curved_stop.py` prints these figures):

    ===========  =========================  ==========================
    field        ours (surface) vs "stop"   old vertex plane vs "stop"
    ===========  =========================  ==========================
    0 degrees    0.07%                      1.07%
    14 degrees   0.66%                      9.1%
    18 degrees   0.73%                      5.2%
    ===========  =========================  ==========================

    Against the "entrance" weight (uniform over the entrance pupil) ours are 0.4%, 2.8%
    and 1.9%, the old model 1.3%, 9.3% and 5.7%: the two references themselves differ by
    0.4%, 2.8% and 1.6% (the triplet's pupil distortion off axis), which bounds how close
    the "entrance" sum can come. The vertex plane, summed over its own aperture (the same
    construction with a plane stop), is as close to the old model as the surface is to
    ours (0.06%, 0.74%, 0.84%): the reference is right for each model, and the old model
    is wrong because it clips a different aperture."""
    from lensfit.psf.psf import pixel_centres

    new, old = curved(), vertex_plane()
    radius = stop_radius_for_f_number(new, F_NUMBER)
    focus = best_focus_offset(new, radius, LAM)
    width, centre = _window(new, radius, (0.0, field_deg), math.inf, LAM, focus, F_NUMBER)
    xs, ys = pixel_centres(PIXELS, PIXELS, width, 0.0, *centre)
    ref = huygens_psf(new, field_deg, radius, focus, xs, ys, weights=("stop", "entrance"))
    ours = lensfit_psf(new, field_deg, radius, focus, width, centre, PIXELS, POINTS)
    before = lensfit_psf(old, field_deg, radius, focus, width, centre, PIXELS, POINTS)
    got = {k: (rel_l2(ours, r), rel_l2(before, r)) for k, r in ref.items()}
    print(f"{field_deg} deg: ours, old vs stop-weighted {got['stop']}, "
          f"vs entrance-weighted {got['entrance']}")
    if field_deg == 0.0:
        # Bounds: ours within 0.3% (measured 0.07%: the grid's and the sunflower's
        # sampling); the old model's 1.07% at least 0.7%
        assert got["stop"][0] < 3e-3 and got["stop"][1] > 7e-3
        assert got["entrance"][0] < 1e-2
    else:
        # Ours within 1.5% (measured 0.66%, of which lensfit's 6000 points alone are
        # ~0.6% and the grid ~0.3%); the old model's 9.1% at least 5%: fails on it
        assert got["stop"][0] < 1.5e-2 and got["stop"][1] > 5e-2
        # Against the entrance weight: the 2.8% the two references differ by, plus
        # sampling (measured 2.75%); the old model at least 7% off (measured 9.3%)
        assert got["entrance"][0] < 4.5e-2 and got["entrance"][1] > 7e-2
        assert got["entrance"][1] > 2 * got["entrance"][0]


# --- 3. the fit ------------------------------------------------------------------------------

def test_lensfit_fit_of_the_curved_stop_lens_meets_its_psf_check(tmp_path, capsys):
    """`lensfit fit --quick` of the triplet at f/8 over a 10 degree field: its own PSF
    check (trust.psf_vs_exact: the fitted polynomials' PSF against exact rays, on axis
    and in the corner, 450-650 nm) is within the 1% target (measured 0.12%). At f/5 over
    14 degrees the quick budget falls short for this lens with either stop model
    (1.29% with the stop on the surface, 1.02% with the old vertex plane), as its phase
    RMS target is not reached: a budget matter, not the stop's."""
    from lensfit.cli import main

    argv = ["fit", str(FIXTURE), "--quick", "--f-number", "8", "--field", "10",
            "--no-timing", "--generated", str(tmp_path / "gen"),
            "--report", str(tmp_path / "report")]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "within the target" in out, out
    assert any((tmp_path / "gen").rglob("*.table"))


def main() -> None:
    """The figures of test_exact_psf_matches_a_brute_force_huygens_sum's table, at 0, 14
    and 18 degrees (~2 minutes on 2 cores):

        PYTHONPATH=fit .venv/bin/python tests/fit/trace/test_curved_stop.py
    """
    from lensfit.psf.psf import pixel_centres

    new, old = curved(), vertex_plane()
    radius = stop_radius_for_f_number(new, F_NUMBER)
    focus = best_focus_offset(new, radius, LAM)
    print(f"f/{F_NUMBER:g} (stop radius {radius:.4f} mm), {LAM:g} nm, focus {focus:+.5f} mm; "
          f"relative L2 of PSFs normalised to unit power in a {PIXELS}^2 window")
    for field in (0.0, 14.0, 18.0):
        width, centre = _window(new, radius, (0.0, field), math.inf, LAM, focus, F_NUMBER)
        xs, ys = pixel_centres(PIXELS, PIXELS, width, 0.0, *centre)
        w = ("stop", "entrance")
        ref = huygens_psf(new, field, radius, focus, xs, ys, weights=w)
        ref_plane = huygens_psf(old, field, radius, focus, xs, ys, weights=w)
        ours = lensfit_psf(new, field, radius, focus, width, centre, PIXELS, POINTS)
        before = lensfit_psf(old, field, radius, focus, width, centre, PIXELS, POINTS)
        print(f"{field:4g} deg (window {width * 1e3:.0f} um): "
              f"ours {rel_l2(ours, ref['stop']):.2%} / {rel_l2(ours, ref['entrance']):.2%}, "
              f"vertex plane {rel_l2(before, ref['stop']):.2%} / "
              f"{rel_l2(before, ref['entrance']):.2%} (stop / entrance weight); "
              f"the weights differ by {rel_l2(ref['entrance'], ref['stop']):.2%}; "
              f"vertex plane against its own aperture's sum "
              f"{rel_l2(before, ref_plane['stop']):.2%}")


if __name__ == "__main__":
    main()
