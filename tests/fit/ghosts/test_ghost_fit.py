"""Ghost half-systems (issue 13, part 2): the split of a ghost path at its first stop
crossing, exact aiming along it against a plain forward trace of the whole ghost path,
and the fit of a ghost half with its clip outputs against held-out exact rays."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from lensfit.ghosts.fit import GHOST_OPTIONS, fit_ghost, select_housings
from lensfit.prescription import load_lens
from lensfit.sample import aim_object_side, aim_sensor_side, default_domain
from lensfit.sample.aim import NEWTON_TOL_MM, _front_plane
from lensfit.sample.ghost import aim_ghost, ghost_half
from lensfit.trace.tracer import Rays, Status, Step, ghost_path, trace

# The aiming accepts a ray whose miss is at most 10 NEWTON_TOL_MM (lensfit.sample.rays:
# the final trace's acceptance), so that is how close a converged ray lands
LANDING_MM = 10 * NEWTON_TOL_MM


@pytest.fixture(scope="module")
def lens0001():
    return load_lens("0001")


def test_ghost_half_split_at_the_first_stop_crossing(lens0001):
    lens = lens0001
    s = lens.stop_index
    assert s == 7  # 0001: the stop plane between surfaces 6 and 8
    direct_o = [Step(k) for k in range(s + 1)]
    for (i, j), case in (((1, 4), "A"), ((8, 10), "B"), ((3, 11), "C"), ((6, 8), "C")):
        half = ghost_half(lens, i, j)
        full = ghost_path(lens, i, j)
        assert half.case == case
        system, steps, crossings = half
        assert (system, steps, crossings) == (half.system, half.steps, half.stop_crossings)
        if case == "A":  # the half ends at the first stop crossing; P_s is direct
            assert half.system == "P_o" and half.steps[-1] == Step(s)
            assert list(half.steps) + [Step(k) for k in range(s + 1, len(lens.surfaces))] == full
            assert half.stop_crossings == ()
        else:  # the direct P_o, then the half
            assert half.system == "P_s"
            assert direct_o + list(half.steps) == full
            n_stop = sum(st.surface == s for st in full)
            assert len(half.stop_crossings) == n_stop - 1 == (2 if case == "C" else 0)
            assert all(half.steps[k].surface == s for k in half.stop_crossings)
        # every step but the stop plane's is a housing test
        assert all(half.steps[k].surface != s for k in half.housings)
        assert len(half.housings) + len(half.stop_crossings) + (case == "A") == len(half.steps)
    with pytest.raises(ValueError, match="stop plane"):
        ghost_half(lens, 3, s)
    with pytest.raises(ValueError, match="0 <= i < j"):
        ghost_half(lens, 4, 4)


def _start_o(lens, x_O, y_O, u_O, unknowns):
    """The start of a P_o ray as lensfit.sample.rays launches it: from the scene point
    through (p, 0), on the plane z = front."""
    w = np.column_stack([x_O, y_O, -np.sqrt(1.0 - x_O**2 - y_O**2)])
    pz = np.column_stack([unknowns, np.zeros(len(unknowns))])
    d = u_O[:, None] * pz - w
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return pz + d * (_front_plane(lens) / d[:, 2])[:, None], d, w


def _relative_opl(start, w, u_O):
    """What phi_o adds to the traced OPL: -d_O + |S - scene| (lensfit.sample.rays)."""
    u = u_O[:, None]
    rel = u[:, 0] * np.einsum("ij,ij->i", start, start) - 2 * np.einsum("ij,ij->i", start, w)
    return rel / (np.linalg.norm(u * start - w, axis=1) + 1.0)


def _inputs(lens, n, seed):
    dom = default_domain(lens)
    rng = np.random.default_rng(seed)
    r = dom.stop_radius_mm * np.sqrt(rng.random(n))
    a = 2 * np.pi * rng.random(n)
    sin_f = np.sin(np.radians(dom.field_deg))
    x_O, y_O = rng.uniform(-0.7, 0.7, (2, n)) * sin_f
    u_O = np.where(rng.random(n) < 0.5, 0.0, rng.uniform(0, dom.inverse_distance_max, n))
    lam = rng.uniform(420.0, 700.0, n)
    return dom, x_O, y_O, u_O, r * np.cos(a), r * np.sin(a), lam


def test_case_a_ghost_half_is_the_full_ghost_ray(lens0001):
    """0001's ghost (1, 4): the aimed ghost P_o traced on along the whole ghost path
    crosses the stop at the requested point; with the direct P_s aimed at where it
    lands, OPL and transmittance are the sum and product of the halves'."""
    lens = lens0001
    i, j = 1, 4
    half = ghost_half(lens, i, j)
    _, x_O, y_O, u_O, xa, ya, lam = _inputs(lens, 64, 1)
    gh = aim_ghost(lens, half, x_O, y_O, u_O, xa, ya, lam)
    assert gh.ok.all()
    start, d, w = _start_o(lens, x_O, y_O, u_O, gh.aimed.unknowns)
    hist: list[np.ndarray] = []
    full = trace(lens, Rays(start, d, lam), ghost_path(lens, i, j), clip=False,
                 fresnel_loss=True, end_z=lens.sensor_z, history=hist)
    assert np.all(full.status == Status.OK)
    at_stop = hist[len(half.steps) - 1]
    assert np.max(np.hypot(at_stop[:, 0] - xa, at_stop[:, 1] - ya)) <= LANDING_MM
    # the same trace, so the same positions at every housing (to rounding)
    for col, k in enumerate(half.housings):
        R = lens.surfaces[half.steps[k].surface].semi_diameter_mm
        np.testing.assert_allclose(gh.clip[:, col], hist[k][:, :2] / R, rtol=0, atol=1e-12)
    # the direct P_s from the stop point to where the ghost lands is the same ray
    land = full.pos
    ps = aim_sensor_side(lens, land[:, 0], land[:, 1], 0.0, xa, ya, lam)
    assert ps.ok.all()
    opl = full.opl_mm + _relative_opl(start, w, u_O)
    # OPL is stationary in the stop point (Fermat), so the two halves' 1e-8 mm misses
    # change the sum at second order: 1e-9 mm is 2e-6 waves
    np.testing.assert_allclose(gh.outputs[:, 3] + ps.outputs[:, 3], opl, rtol=0, atol=1e-9)
    # transmittance: products of the same Fresnel factors (rounding only)
    np.testing.assert_allclose(gh.outputs[:, 2] * ps.outputs[:, 2], full.transmittance,
                               rtol=1e-12)
    # both reflectances are in: the ghost is dimmer than R_max^2 of any coating here
    assert np.all(gh.outputs[:, 2] < 0.05**2)


@pytest.mark.parametrize("pair", [(10, 13), (5, 8), (2, 12)], ids=["B", "C", "C-long"])
def test_sensor_side_ghost_half_is_the_full_ghost_ray(lens0001, pair):
    """The direct P_o from a scene point through a stop point, traced on along the whole
    ghost path; the ghost P_s aimed from that stop point at where it lands is the same
    ray: it lands there, crosses the stop where the full ray does (case C), and the
    halves' OPL and transmittance add up to the full ray's. The exact clip verdict of
    the halves is the tracer's with clipping on."""
    lens = lens0001
    i, j = pair
    half = ghost_half(lens, i, j)
    s = lens.stop_index
    dom, x_O, y_O, u_O, xa, ya, lam = _inputs(lens, 256, 2)
    po = aim_object_side(lens, x_O, y_O, u_O, xa, ya, lam)
    assert po.ok.all()
    start, d, w = _start_o(lens, x_O, y_O, u_O, po.unknowns)
    path = ghost_path(lens, i, j)
    hist: list[np.ndarray] = []
    full = trace(lens, Rays(start, d, lam), path, clip=False, fresnel_loss=True,
                 end_z=lens.sensor_z, history=hist)
    alive = full.status == Status.OK  # (5, 8): most direct rays miss on the way back
    land = full.pos
    gh = aim_ghost(lens, half, land[:, 0], land[:, 1], 0.0, xa, ya, lam)
    both = alive & gh.ok
    assert np.array_equal(both, alive)  # the ray exists, so the aiming must find it
    assert both.sum() >= 25
    # the ghost half traced forward from its solution lands on the requested point
    st = np.column_stack([xa, ya, np.full(len(xa), lens.vertex_z[s])])[both]
    q = gh.aimed.unknowns[both]
    end = trace(lens, Rays(st, np.column_stack([q, np.ones(len(q))]), lam[both]),
                list(half.steps), clip=False, end_z=lens.sensor_z)
    assert np.max(np.hypot(*(end.pos[:, :2] - land[both, :2]).T)) <= LANDING_MM
    # ... and is the full ray: its stop crossings are the full trace's (the ray differs
    # by the landing tolerance, magnified at most ~100x along the path: 1e-6 mm)
    offset = s + 1  # the half starts after the direct P_o's steps 0..s
    for c, k in enumerate(half.stop_crossings):
        assert path[offset + k].surface == s
        np.testing.assert_allclose(gh.stop[both, c], hist[offset + k][both, :2], rtol=0,
                                   atol=1e-6)
    opl = full.opl_mm + _relative_opl(start, w, u_O)
    np.testing.assert_allclose((po.outputs[:, 3] + gh.outputs[:, 3])[both], opl[both],
                               rtol=0, atol=1e-9)  # stationary: see the case A test
    np.testing.assert_allclose((po.outputs[:, 2] * gh.outputs[:, 2])[both],
                               full.transmittance[both], rtol=1e-9)
    # the verdict: the tracer with clipping at the domain's stop against the halves'
    clipped = trace(lens, Rays(start, d, lam), path, clip=True,
                    stop_radius_mm=dom.stop_radius_mm, end_z=lens.sensor_z)
    verdict = (po.vignetting <= 1.0) & gh.passes(dom.stop_radius_mm)
    assert np.array_equal((clipped.status == Status.OK)[both], verdict[both])
    if pair == (5, 8):  # this ghost's second and third stop crossings block some rays
        assert 0 < np.mean(verdict[both]) < 1
    # a stop shape given as a function: the round one is the default verdict, and a
    # square inscribed in it (a 4-blade stop) blocks more at the extra crossings only
    r = dom.stop_radius_mm
    assert np.array_equal(gh.passes(r, lambda x, y: np.hypot(x, y) <= r), gh.passes(r))
    square = gh.passes(r, lambda x, y: np.maximum(abs(x), abs(y)) <= r / math.sqrt(2))
    assert not np.any(square & ~gh.passes(r))
    if half.stop_crossings:
        assert np.sum(square[both]) < np.sum(verdict[both])
    else:
        assert np.array_equal(square, gh.passes(r))


def test_sensor_side_ghost_half_12_14_is_two_valued_documented(lens0001):
    """Not every ghost half is a function of its inputs: for 0001's ghost (12, 14) two
    exact rays leave the same stop point for the same sensor point (both sheets of the
    map slope -> sensor point have the same orientation, so no sign tells them apart).
    Aimed from where full ghost rays land, Newton finds another ray for 29% of them
    (measured: 75 of these 256); both are exact. This is why the fits of such ghosts (12, 14),
    (10, 14), (0, 14) miss by millimetres (report of issue 13 part 2)."""
    lens = lens0001
    half = ghost_half(lens, 12, 14)
    s = lens.stop_index
    _, x_O, y_O, u_O, xa, ya, lam = _inputs(lens, 256, 2)
    po = aim_object_side(lens, x_O, y_O, u_O, xa, ya, lam)
    start, d, _ = _start_o(lens, x_O, y_O, u_O, po.unknowns)
    full = trace(lens, Rays(start, d, lam), ghost_path(lens, 12, 14), clip=False,
                 end_z=lens.sensor_z)
    assert np.all(full.status == Status.OK)
    gh = aim_ghost(lens, half, full.pos[:, 0], full.pos[:, 1], 0.0, xa, ya, lam)
    assert gh.ok.all()
    # the aimed rays land where the full rays do ...
    st = np.column_stack([xa, ya, np.full(len(xa), lens.vertex_z[s])])
    q = gh.aimed.unknowns
    end = trace(lens, Rays(st, np.column_stack([q, np.ones(len(q))]), lam), list(half.steps),
                clip=False, end_z=lens.sensor_z)
    assert np.max(np.hypot(*(end.pos[:, :2] - full.pos[:, :2]).T)) <= LANDING_MM
    # ... but leave the stop in another direction for a good share of them (the full
    # ray's slope there: from the stop point to where it meets the next surface)
    hist: list[np.ndarray] = []
    trace(lens, Rays(start, d, lam), ghost_path(lens, 12, 14), clip=False, history=hist)
    after = hist[s + 1]  # the full ray on the first surface behind the stop
    q_full = (after[:, :2] - np.column_stack([xa, ya])) / (after[:, 2:3] - lens.vertex_z[s])
    other = np.hypot(*(q - q_full).T) > 1e-6
    assert 0.1 < other.mean() < 0.9, other.mean()


def test_select_housings_is_greedy():
    """Housing 2 blocks most, housing 0 the rest; housing 1 never decides."""
    rng = np.random.default_rng(0)
    ratio = rng.uniform(0.0, 0.9, (1000, 3))
    ratio[:300, 2] = 1.5
    ratio[300:310, 0] = 1.2
    exact = np.all(ratio <= 1.0, axis=1)
    assert select_housings(ratio, exact, np.ones(1000, dtype=bool)) == [2, 0]
    assert select_housings(ratio, exact, np.ones(1000, dtype=bool), share=0.99) == [2]


# Small budgets for the suite (a few seconds per ghost: every ray of these two converges
# at the first try); lensfit.ghosts.fit.GHOST_OPTIONS are the report's
SMALL = replace(GHOST_OPTIONS, groups=300, aperture_points=64, aperture_degree=8,
                field_degrees=(4, 6, 8), test_groups=75, test_per_group=16)


def test_fitted_ghost_half_meets_held_out_tolerances(lens0001):
    """0001's ghost (10, 13) (case B, a smooth ghost: per field point a degree-6
    polynomial in the stop point fits x_i to 0.02 um). Measured with SMALL: x_i 0.18,
    y_i 0.17 um RMS, tau 6.4e-4 relative, phi 2.7e-3 waves after piston removal; the
    bounds are about twice that, far below what a wrong path or a lost reflectance
    gives (tau of a wrong coating is off by tens of percent)."""
    fit = fit_ghost(lens0001, 10, 13, options=SMALL)
    assert fit.converged_train == 1.0 and fit.converged_test == 1.0
    rms = {o.name: o.rms for o in fit.outputs}
    assert rms["x_i"] < 0.4 and rms["y_i"] < 0.4  # um
    assert rms["tau_i"] < 1.5e-3
    assert rms["phi_i"] < 6e-3  # waves at 550 nm
    # every held-out ray passes this ghost's housings at f/2: both clip fits agree
    assert fit.blocked_share == 0.0
    assert fit.agreement_max == 1.0 and fit.agreement_housings == 1.0


def test_clip_agreement_per_housing_reaches_target_the_max_ratio_does_not(lens0001):
    """0001's ghost (5, 8) (case C: it crosses the stop twice more, and those crossings
    block 30% of the held-out rays). The greedy per-housing outputs with the fitted stop
    crossings reproduce the exact verdict on >= 99.5% of held-out rays (measured 100%
    with SMALL: no housing needs testing, the stop crossings decide); the paper's
    single max-ratio output falls short of the target (measured 99.33%: its value jumps
    where the binding housing changes, and it wrongly blocks rays there)."""
    fit = fit_ghost(lens0001, 5, 8, options=SMALL)
    assert fit.half.case == "C" and fit.held_out_rays > 1000
    assert 0.1 < fit.blocked_share < 0.9
    assert fit.agreement_housings >= 0.995
    assert fit.agreement_max < fit.agreement_housings
