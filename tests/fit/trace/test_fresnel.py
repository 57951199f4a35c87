"""Tests for lensfit.trace.fresnel: bare Fresnel interfaces and thin-film coatings.

Unless stated otherwise, tolerances are set a factor of ~10-100 above the float64 rounding
expected from the handful of operations involved (eps = 2.2e-16), so they fail on any real
error in the physics while staying robust to the order of floating-point operations.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from numpy.typing import ArrayLike

from lensfit.trace.fresnel import (
    coated_power_reflectance,
    coated_reflectance,
    fresnel_amplitudes,
    fresnel_reflectance,
    quarter_wave_thickness_nm,
    reflect_direction,
)

try:  # reference implementation for the cross-checks; the other tests do not need it
    import tmm
except ImportError:  # pragma: no cover
    tmm = None
needs_tmm = pytest.mark.skipif(tmm is None, reason="the tmm package is not installed")

# Coating-like indices: MgF2, ZrO2, Al2O3, SiO2 and a BK7-like substrate
N_MGF2, N_ZRO2, N_AL2O3, N_SIO2, N_GLASS = 1.38, 2.05, 1.62, 1.46, 1.52

WAVELENGTHS = np.linspace(380.0, 780.0, 21)


def cauchy(a: float, b_nm2: float) -> Callable[[ArrayLike], np.ndarray]:
    """Dispersive index n(lambda) = a + b / lambda^2 (lambda in nm)."""
    return lambda lam: a + b_nm2 / np.asarray(lam, dtype=np.float64) ** 2


# Dispersive MgF2-like layer and glass-like substrate, both about right at 550 nm
N_LAYER_DISP = cauchy(1.370, 3000.0)
N_GLASS_DISP = cauchy(1.505, 4200.0)


def textbook_rs_rp(n1: float, n2: float, cos_i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Straightforward Fresnel amplitudes (propagating case only), as an independent reference."""
    sin_i = np.sqrt(1.0 - cos_i**2)
    cos_t = np.sqrt(1.0 - (n1 / n2 * sin_i) ** 2)
    rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)
    return rs, rp


def tmm_rt(n_list: list[float], d_list: list[float], theta: float, lam: float):
    """Unpolarised R, T from the reference `tmm` package (mean of s and p)."""
    # Semi-infinite incident and exit media get infinite thickness
    d_full = [np.inf, *d_list, np.inf]
    res = [tmm.coh_tmm(pol, n_list, d_full, theta, lam) for pol in ("s", "p")]
    return 0.5 * (res[0]["R"] + res[1]["R"]), 0.5 * (res[0]["T"] + res[1]["T"])


# 1. Normal incidence -----------------------------------------------------------------------


@pytest.mark.parametrize(("n1", "n2"), [(1.0, 1.52), (1.52, 1.0), (1.0, 2.05), (1.7, 1.33)])
def test_normal_incidence_bare(n1: float, n2: float) -> None:
    expected = ((n1 - n2) / (n1 + n2)) ** 2
    # A few roundings on each side: relative error of a few eps, so 1e-14 relative is ample
    assert fresnel_reflectance(n1, n2, 1.0) == pytest.approx(expected, rel=1e-14, abs=0)
    r, t = coated_reflectance(n1, n2, 1.0, [], [], 550.0)
    assert r == pytest.approx(expected, rel=1e-14, abs=0)
    # Bare T at normal incidence: 4 n1 n2 / (n1 + n2)^2
    assert t == pytest.approx(4 * n1 * n2 / (n1 + n2) ** 2, rel=1e-14, abs=0)


def test_bare_matches_textbook_formula_over_angles() -> None:
    cos_i = np.cos(np.radians(np.linspace(0.0, 89.0, 90)))
    rs, rp = textbook_rs_rp(1.0, N_GLASS, cos_i)
    # The textbook form cancels near Brewster; both are within ~1e-16 absolute of the truth
    np.testing.assert_allclose(
        fresnel_reflectance(1.0, N_GLASS, cos_i), 0.5 * (rs**2 + rp**2), rtol=0, atol=1e-14
    )


# 2. Brewster angle -------------------------------------------------------------------------


@pytest.mark.parametrize(("n1", "n2"), [(1.0, 1.52), (1.0, 2.05), (1.52, 1.0)])
def test_brewster_angle_p_vanishes(n1: float, n2: float) -> None:
    # tan(theta_B) = n2 / n1  ->  cos(theta_B) = n1 / sqrt(n1^2 + n2^2)
    cos_b = n1 / np.hypot(n1, n2)
    rs, rp, _, _ = fresnel_amplitudes(n1, n2, cos_b)
    # rp's numerator is a rounding-level difference: |rp| ~ eps; 1e-14 leaves room for it
    assert abs(rp) < 1e-14
    assert abs(rs) > 0.1  # s is strongly reflected there, so the test is not vacuous
    rs_ref, _ = textbook_rs_rp(n1, n2, np.array(cos_b))
    # Unpolarised R is then exactly half the s reflectance
    assert fresnel_reflectance(n1, n2, cos_b) == pytest.approx(0.5 * rs_ref**2, rel=1e-13)
    r_coat, _ = coated_reflectance(n1, n2, cos_b, [], [], 500.0)
    assert r_coat == pytest.approx(0.5 * rs_ref**2, rel=1e-13)


def test_amplitudes_conserve_energy() -> None:
    cos_i = np.linspace(0.0, 1.0, 101)
    for n1, n2 in [(1.0, 1.52), (1.52, 1.0)]:
        rs, rp, ts, tp = fresnel_amplitudes(n1, n2, cos_i)
        sin_i_sq = 1.0 - cos_i**2
        cos_t = np.sqrt((1.0 - (n1 / n2) ** 2 * sin_i_sq).astype(complex))
        # Transmitted power = flux ratio Re(n2 cos_t)/(n1 cos_i) times |t|^2 (0 under TIR).
        # Exact identities; a few eps of rounding, hence 1e-14
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(cos_i > 0, (n2 * cos_t).real / (n1 * cos_i), 0.0)
        np.testing.assert_allclose(np.abs(rs) ** 2 + ratio * np.abs(ts) ** 2, 1.0, atol=1e-14)
        np.testing.assert_allclose(np.abs(rp) ** 2 + ratio * np.abs(tp) ** 2, 1.0, atol=1e-14)


@needs_tmm
@pytest.mark.parametrize(("n1", "n2"), [(1.0, N_GLASS), (N_GLASS, 1.0)])
def test_amplitudes_agree_with_tmm(n1: float, n2: float) -> None:
    # Includes TIR for glass -> air, where the decaying branch of cos_t fixes the phases
    for theta in np.radians(np.linspace(0.0, 89.0, 90)):
        rs, rp, ts, tp = fresnel_amplitudes(n1, n2, np.cos(theta))
        th_t = tmm.snell(n1, n2, theta)
        ref = [tmm.interface_r(pol, n1, n2, theta, th_t) for pol in ("s", "p")]
        ref += [tmm.interface_t(pol, n1, n2, theta, th_t) for pol in ("s", "p")]
        # tmm goes through arcsin/cos of angles; agreement is ~1e-15, 1e-12 allows for that
        np.testing.assert_allclose([rs, rp, ts, tp], ref, rtol=0, atol=1e-12)


# 3. Total internal reflection, critical and grazing incidence -------------------------------


def test_total_internal_reflection() -> None:
    n1, n2 = N_GLASS, 1.0
    cos_crit = np.sqrt(1.0 - (n2 / n1) ** 2)
    beyond = np.cos(np.radians(np.linspace(42.0, 90.0, 49)))  # critical angle is 41.1 deg
    assert np.all(beyond < cos_crit)
    assert np.all(fresnel_reflectance(n1, n2, beyond) == 1.0)

    # Just below the critical angle: steep but finite, and still < 1
    just_below = np.cos(np.arcsin(n2 / n1) - 1e-6)
    r = fresnel_reflectance(n1, n2, just_below)
    assert np.isfinite(r)
    assert 0.5 < r < 1.0

    # Exactly at the critical angle, the neighbouring floats, and grazing: finite, in [0, 1]
    edge = np.array([cos_crit, np.nextafter(cos_crit, 0), np.nextafter(cos_crit, 1), 0.0])
    with np.errstate(divide="raise", invalid="raise", over="raise"):
        r_edge = fresnel_reflectance(n1, n2, edge)
        r_coat, t_coat = coated_reflectance(n1, n2, edge, [N_MGF2], [100.0], 550.0)
    assert np.all(np.isfinite(r_edge)) and np.all((r_edge >= 0) & (r_edge <= 1))
    # At the critical angle itself the transmitted wave runs along the surface: R = 1
    assert r_edge[0] == pytest.approx(1.0, abs=1e-15)
    assert np.all(np.isfinite(r_coat)) and np.all(np.isfinite(t_coat))
    # Stack R + T is exact up to rounding (~1e-15), 1e-12 is the coating-test tolerance
    np.testing.assert_allclose(r_coat + t_coat, 1.0, atol=1e-12)


@pytest.mark.parametrize(("n1", "n2"), [(1.0, 1.52), (1.52, 1.0), (1.0, 1.0 + 1e-12)])
def test_grazing_incidence_reflects_fully(n1: float, n2: float) -> None:
    assert fresnel_reflectance(n1, n2, 0.0) == 1.0
    r, t = coated_reflectance(n1, n2, 0.0, [N_MGF2], [100.0], 550.0)
    # |r| = 1 exactly in theory; only rounding in |num|/|den| remains
    assert r == pytest.approx(1.0, abs=1e-14)
    assert t == 0.0


def test_equal_indices_is_no_interface() -> None:
    cos_i = np.linspace(0.0, 1.0, 11)  # includes grazing, where 0/0 must not occur
    assert np.all(fresnel_reflectance(1.5, 1.5, cos_i) == 0.0)
    r, t = coated_reflectance(1.5, 1.5, cos_i, [], [], 550.0)
    # The stack path recomputes cos in the exit medium (n1 cos_i / n2), equal to cos_i only up
    # to rounding, so r ~ eps and R ~ eps^2 rather than exactly 0
    np.testing.assert_allclose(r, 0.0, rtol=0, atol=1e-30)
    np.testing.assert_allclose(t, 1.0, rtol=0, atol=1e-15)


def test_no_nan_over_random_inputs() -> None:
    rng = np.random.default_rng(1)
    n = 200_000
    n1 = rng.uniform(1.0, 2.5, n)
    n2 = rng.uniform(1.0, 2.5, n)
    cos_i = rng.uniform(0.0, 1.0, n)
    cos_i[::7] = 0.0
    cos_i[1::7] = 1.0
    # Put some samples exactly at their critical angle
    crit = n1 > n2
    cos_i[2::7] = np.where(crit[2::7], np.sqrt(np.abs(1.0 - (n2[2::7] / n1[2::7]) ** 2)), 0.5)
    with np.errstate(divide="raise", invalid="raise", over="raise"):
        r = fresnel_reflectance(n1, n2, cos_i)
        rc, tc = coated_reflectance(n1, n2, cos_i, [N_MGF2, 1.2], [90.0, 40.0], 550.0)
    assert np.all(np.isfinite(r)) and np.all((r >= 0.0) & (r <= 1.0))
    assert np.all(np.isfinite(rc)) and np.all(np.isfinite(tc))
    np.testing.assert_allclose(rc + tc, 1.0, atol=1e-12)


# 4. Quarter-wave antireflection layer -------------------------------------------------------


def test_quarter_wave_thickness() -> None:
    assert quarter_wave_thickness_nm(N_MGF2, 550.0) == pytest.approx(550.0 / (4 * 1.38), rel=1e-15)


def test_quarter_wave_single_layer() -> None:
    n1, n_layer, n_sub = 1.0, N_MGF2, N_GLASS
    d = quarter_wave_thickness_nm(n_layer, 550.0)
    r, t = coated_reflectance(n1, n_sub, 1.0, [n_layer], [d], 550.0)
    expected = ((n1 * n_sub - n_layer**2) / (n1 * n_sub + n_layer**2)) ** 2
    # Only rounding of delta ~ pi/2 (cos delta ~ 1e-16) and a dozen operations: 1e-12 is ample,
    # far tighter than the 1e-9 the design formula is usually quoted to
    assert r == pytest.approx(expected, abs=1e-12)
    assert r + t == pytest.approx(1.0, abs=1e-14)
    # The uncoated surface reflects about 4%; the layer must reduce that to about 1.3%
    assert r < fresnel_reflectance(n1, n_sub, 1.0) / 3


def test_quarter_wave_dispersive_layer() -> None:
    design = 550.0
    lam = np.linspace(400.0, 700.0, 31)  # contains 550 exactly
    i_design = int(np.argmin(np.abs(lam - design)))
    assert lam[i_design] == design
    d = quarter_wave_thickness_nm(float(N_LAYER_DISP(design)), design)
    r, _ = coated_reflectance(1.0, N_GLASS_DISP(lam), 1.0, [N_LAYER_DISP(lam)], [d], lam)
    n2, n3 = N_LAYER_DISP(design), N_GLASS_DISP(design)
    expected = ((n3 - n2**2) / (n3 + n2**2)) ** 2
    assert r[i_design] == pytest.approx(expected, abs=1e-12)
    # Away from the design wavelength the layer is no longer a quarter wave: R differs
    assert abs(r[0] - expected) > 1e-4 and abs(r[-1] - expected) > 1e-4


# 5. Energy conservation R + T = 1 ------------------------------------------------------------

STACKS_RT = {
    "1 layer": ([N_MGF2], [99.6]),
    "2 layers": ([N_ZRO2, N_MGF2], [67.1, 99.6]),
    "3 layers": ([N_AL2O3, N_ZRO2, N_MGF2], [84.9, 134.1, 99.6]),
    "frustrated TIR gap": ([1.0], [120.0]),
}


@pytest.mark.parametrize("stack", list(STACKS_RT), ids=list(STACKS_RT))
@pytest.mark.parametrize(("n1", "n2"), [(1.0, N_GLASS), (N_GLASS, 1.0), (N_GLASS, N_GLASS)])
def test_energy_conservation(stack: str, n1: float, n2: float) -> None:
    layer_n, layer_d = STACKS_RT[stack]
    lam = WAVELENGTHS[:, None]
    cos_i = np.cos(np.radians(np.linspace(0.0, 89.0, 90)))[None, :]
    r, t = coated_reflectance(n1, n2, cos_i, layer_n, layer_d, lam)
    assert r.shape == t.shape == (WAVELENGTHS.size, 90)
    # T comes from the transmitted amplitude, so R + T = 1 is a genuine check. The matrix
    # products lose at most a few hundred eps here; 1e-12 leaves margin but catches any
    # admittance or sign error (those give errors of order 1e-2 or more)
    np.testing.assert_allclose(r + t, 1.0, rtol=0, atol=1e-12)
    assert np.all((r >= -1e-15) & (t >= 0.0))


def test_tir_in_exit_medium() -> None:
    # Glass -> air at 60 deg is beyond the 41.1 deg critical angle, whatever the layers
    cos_60 = np.cos(np.radians(60.0))
    for layer_n, layer_d in STACKS_RT.values():
        r, t = coated_reflectance(N_GLASS, 1.0, cos_60, layer_n, layer_d, WAVELENGTHS)
        # The exit admittance is purely imaginary, so T is exactly 0 and |r| = 1 up to rounding
        assert np.all(t == 0.0)
        np.testing.assert_allclose(r, 1.0, rtol=0, atol=1e-12)


# 6. Agreement with the tmm package -----------------------------------------------------------

STACKS_TMM = {
    "1 layer": ([N_MGF2], [99.6]),
    "2 layers": ([N_ZRO2, N_MGF2], [67.1, 99.6]),
    "4 layers": ([N_AL2O3, N_ZRO2, N_SIO2, N_MGF2], [84.9, 134.1, 30.0, 99.6]),
}


@needs_tmm
@pytest.mark.parametrize("stack", list(STACKS_TMM), ids=list(STACKS_TMM))
def test_agrees_with_tmm(stack: str) -> None:
    layer_n, layer_d = STACKS_TMM[stack]
    lam = np.linspace(380.0, 780.0, 11)
    theta = np.radians(np.linspace(0.0, 80.0, 9))
    r, t = coated_reflectance(1.0, N_GLASS, np.cos(theta)[None, :], layer_n, layer_d, lam[:, None])
    for i, wl in enumerate(lam):
        for j, th in enumerate(theta):
            r_ref, t_ref = tmm_rt([1.0, *layer_n, N_GLASS], layer_d, th, wl)
            # Two independent float64 implementations (tmm goes through arcsin/cos of angles):
            # observed agreement is ~1e-15, 1e-10 is the required tolerance
            assert r[i, j] == pytest.approx(r_ref, abs=1e-10)
            assert t[i, j] == pytest.approx(t_ref, abs=1e-10)


@needs_tmm
def test_agrees_with_tmm_dispersive() -> None:
    lam = np.linspace(380.0, 780.0, 11)
    theta = np.radians(np.linspace(0.0, 80.0, 9))
    n_hi = cauchy(2.00, 15000.0)
    layers = [n_hi(lam)[:, None], N_LAYER_DISP(lam)[:, None]]
    d = [67.1, 99.6]
    sub = N_GLASS_DISP(lam)[:, None]
    r, t = coated_reflectance(1.0, sub, np.cos(theta)[None, :], layers, d, lam[:, None])
    for i, wl in enumerate(lam):
        n_list = [1.0, float(n_hi(wl)), float(N_LAYER_DISP(wl)), float(N_GLASS_DISP(wl))]
        for j, th in enumerate(theta):
            r_ref, t_ref = tmm_rt(n_list, d, th, wl)
            assert r[i, j] == pytest.approx(r_ref, abs=1e-10)  # as in test_agrees_with_tmm
            assert t[i, j] == pytest.approx(t_ref, abs=1e-10)


@needs_tmm
def test_agrees_with_tmm_frustrated_tir() -> None:
    # Glass / 150 nm low-index gap / glass: evanescent in the gap beyond 52.1 deg
    n_gap, d_gap = 1.2, 150.0
    theta = np.radians(np.linspace(0.0, 80.0, 17))
    lam = np.array([400.0, 550.0, 700.0])
    r, t = coated_reflectance(N_GLASS, N_GLASS, np.cos(theta), [n_gap], [d_gap], lam[:, None])
    # The evanescent regime must be exercised and transmit a noticeable fraction
    evanescent = N_GLASS * np.sin(theta) > n_gap
    assert evanescent.sum() >= 5
    assert np.all(t[:, evanescent] > 1e-3) and np.all(r[:, evanescent] < 1.0)
    for i, wl in enumerate(lam):
        for j, th in enumerate(theta):
            r_ref, t_ref = tmm_rt([N_GLASS, n_gap, N_GLASS], [d_gap], th, wl)
            assert r[i, j] == pytest.approx(r_ref, abs=1e-10)  # as in test_agrees_with_tmm
            assert t[i, j] == pytest.approx(t_ref, abs=1e-10)


@needs_tmm
def test_layer_at_its_critical_angle() -> None:
    # cos = 0 exactly inside the layer: delta = 0 and i sin(delta)/eta must stay finite
    n1, n_layer = 1.5, 1.2
    cos_c = np.sqrt(1.0 - (n_layer / n1) ** 2)
    cos_i = np.array([np.nextafter(cos_c, 0.0), cos_c, np.nextafter(cos_c, 1.0)])
    with np.errstate(divide="raise", invalid="raise", over="raise"):
        r, t = coated_reflectance(n1, 1.6, cos_i, [n_layer], [100.0], 550.0)
    # The response is continuous through the layer's critical angle: neighbours agree closely
    # (the cosine changes by ~1e-8 per ulp of cos_i there; the result by far less than 1e-6)
    assert np.all(np.isfinite(r))
    np.testing.assert_allclose(r, r[1], atol=1e-6)
    np.testing.assert_allclose(r + t, 1.0, atol=1e-12)
    th = np.arccos(cos_c)
    r_ref, _ = tmm_rt([n1, n_layer, 1.6], [100.0], th * (1 - 1e-9), 550.0)
    assert r[1] == pytest.approx(r_ref, abs=1e-6)  # tmm a hair off the singular angle


# 7. Empty stack ------------------------------------------------------------------------------


@pytest.mark.parametrize(("n1", "n2"), [(1.0, N_GLASS), (N_GLASS, 1.0), (1.33, N_ZRO2)])
def test_empty_stack_is_bare_interface(n1: float, n2: float) -> None:
    cos_i = np.linspace(0.0, 1.0, 1001)
    r, t = coated_reflectance(n1, n2, cos_i, [], [], 550.0)
    # Two algebraically equal forms; the difference is a few eps of absolute rounding
    np.testing.assert_allclose(r, fresnel_reflectance(n1, n2, cos_i), rtol=0, atol=1e-14)
    np.testing.assert_allclose(r + t, 1.0, rtol=0, atol=1e-14)


def test_mismatched_layer_lists_raise() -> None:
    with pytest.raises(ValueError, match="layer"):
        coated_reflectance(1.0, N_GLASS, 1.0, [N_MGF2, N_ZRO2], [100.0], 550.0)


# 8. Vectorised shapes ------------------------------------------------------------------------


def test_shapes_and_broadcasting() -> None:
    n = 1000
    rng = np.random.default_rng(2)
    cos_i = rng.uniform(0.0, 1.0, n)
    lam = rng.uniform(380.0, 780.0, n)
    assert fresnel_reflectance(1.0, N_GLASS, cos_i).shape == (n,)
    assert fresnel_reflectance(np.full(n, 1.0), N_GLASS, 0.5).shape == (n,)
    # Per-ray dispersive indices mixed with scalar ones
    r, t = coated_reflectance(
        1.0, N_GLASS_DISP(lam), cos_i, [N_LAYER_DISP(lam), 2.0], [99.0, 60.0], lam
    )
    assert r.shape == t.shape == (n,)
    assert r.dtype == t.dtype == np.float64
    # Vectorised result equals ray-by-ray scalar calls
    for k in range(0, n, 97):
        rk, tk = coated_reflectance(
            1.0, N_GLASS_DISP(lam[k]), cos_i[k], [N_LAYER_DISP(lam[k]), 2.0], [99.0, 60.0], lam[k]
        )
        assert np.ndim(rk) == 0
        assert rk == pytest.approx(r[k], abs=1e-15) and tk == pytest.approx(t[k], abs=1e-15)
    # Outer-product broadcasting (wavelength x angle)
    r2, _ = coated_reflectance(1.0, N_GLASS, cos_i[None, :10], [N_MGF2], [99.6], lam[:7, None])
    assert r2.shape == (7, 10)


def test_million_rays() -> None:
    n = 1_000_000
    rng = np.random.default_rng(3)
    cos_i = rng.uniform(0.0, 1.0, n)
    lam = rng.uniform(380.0, 780.0, n)
    r_bare = fresnel_reflectance(N_GLASS, 1.0, cos_i)
    r, t = coated_reflectance(
        N_GLASS, N_GLASS_DISP(lam), cos_i, [N_LAYER_DISP(lam), N_ZRO2], [99.6, 67.1], lam
    )
    assert r_bare.shape == r.shape == t.shape == (n,)
    assert np.all(np.isfinite(r_bare)) and np.all(np.isfinite(r)) and np.all(np.isfinite(t))
    np.testing.assert_allclose(r + t, 1.0, rtol=0, atol=1e-12)  # as in test_energy_conservation


# 9. Mirror reflection of directions ---------------------------------------------------------


def test_reflect_direction() -> None:
    rng = np.random.default_rng(4)
    n = 10_000
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    out = reflect_direction(d, normal)
    assert out.shape == (n, 3)
    # A reflection is an isometry: unit length kept to a few eps
    np.testing.assert_allclose(np.linalg.norm(out, axis=-1), 1.0, rtol=0, atol=1e-14)
    # The angle with the normal is mirrored: out.n = -(d.n)
    d_n = np.sum(d * normal, axis=-1)
    np.testing.assert_allclose(np.sum(out * normal, axis=-1), -d_n, rtol=0, atol=1e-14)
    # The tangential part is unchanged, and reflecting twice gives back d
    np.testing.assert_allclose(out - d, -2.0 * d_n[:, None] * normal, rtol=0, atol=1e-14)
    np.testing.assert_allclose(reflect_direction(out, normal), d, rtol=0, atol=1e-14)
    # Normal incidence retro-reflects; broadcasting a single normal over many rays works
    z = np.array([0.0, 0.0, 1.0])
    np.testing.assert_array_equal(reflect_direction(np.array([0.0, 0.0, -1.0]), z), z)
    assert reflect_direction(d, z).shape == (n, 3)


@pytest.mark.parametrize("n1, n2, layers", [
    (1.0, 1.62, [(1.38, 99.6)]),  # one layer, the lensdb's coatings
    (1.62, 1.0, [(1.38, 99.6)]),  # from glass: total reflection beyond the critical angle
    (1.0, 1.7, [(1.38, 99.6), (2.1, 60.0), (1.46, 120.0)]),
    (1.5, 1.0, []),
])
def test_coated_power_reflectance_is_coated_reflectances_r(n1, n2, layers):
    """The tracer's R (coated_power_reflectance: T not computed, the first layer's
    product with the exit fields written out) is coated_reflectance's, bit for bit."""
    rng = np.random.default_rng(5)
    cos_i = np.concatenate([rng.uniform(0.0, 1.0, 5000), [0.0, 1.0]])
    lam = rng.uniform(400.0, 700.0, len(cos_i))
    ln, ld = [n for n, _ in layers], [d for _, d in layers]
    r, _ = coated_reflectance(n1, n2, cos_i, ln, ld, lam)
    assert np.array_equal(coated_power_reflectance(n1, n2, cos_i, ln, ld, lam), r)
