"""Vectorised Fresnel and thin-film coating optics in float64 / complex128.

All functions take broadcastable numpy arrays, so the ray tracer can hand them one
array per quantity for millions of rays at once. Media are lossless (real indices).

Conventions
-----------
* ``cos_i`` is the cosine of the angle of incidence in the incident medium ``n1``, in [0, 1].
* The angle in medium ``n_j`` follows from Snell's law; its cosine is taken from
  ``cos_j**2 = ((n_j - n1)(n_j + n1) + n1**2 cos_i**2) / n_j**2`` which has no cancellation
  near normal incidence and is exactly zero at the critical angle. Where that is negative the
  wave is evanescent and ``cos_j = +i sqrt(-cos_j**2)`` (the branch that decays away from the
  interface).
* Amplitude coefficients use ``rp = (n2 cos_i - n1 cos_t) / (n2 cos_i + n1 cos_t)``, so
  ``rs = rp = (n1 - n2) / (n1 + n2)`` at normal incidence.
* A surface between two media of exactly equal index is no interface: R = 0 at every angle,
  grazing included (the limit along cos_i -> 0). Otherwise grazing incidence gives R = 1.

Thin films use the characteristic-matrix method with tilted admittances. For s the
tangential fields are (E, H) and the admittance is ``eta = n cos``; for p the tangential
fields are taken as (H, E) with the dual admittance ``zeta = cos / n``. Both lead to
identically shaped 2x2 layer matrices, and the p form never divides by a cosine, so the
critical angle (cos = 0) in a layer or in the exit medium needs no special case.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "coated_reflectance",
    "coated_power_reflectance",
    "fresnel_amplitudes",
    "fresnel_reflectance",
    "quarter_wave_thickness_nm",
    "reflect_direction",
]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

# Below this |delta| the layer phase uses the Taylor series for sin(delta)/delta
_SINC_SERIES_LIMIT = 1e-3


def _cos_sq_in_medium(n1: FloatArray, n_j: FloatArray, cos_i: FloatArray) -> FloatArray:
    """Squared cosine of the refracted angle in medium ``n_j`` (negative when evanescent).

    ``1 - (n1/n_j)**2 (1 - cos_i**2)`` rewritten so that the index difference is formed
    first: it is then exact at normal incidence and exactly zero at the critical angle.
    """
    return ((n_j - n1) * (n_j + n1) + (n1 * cos_i) ** 2) / (n_j * n_j)


def _complex_cos(cos_sq: FloatArray) -> ComplexArray:
    """Cosine from its square: real when propagating, +i*real when evanescent."""
    root = np.sqrt(np.abs(cos_sq))
    return np.where(cos_sq >= 0.0, root + 0j, 1j * root)


def _safe_divide(num: FloatArray, den: FloatArray, fill: float) -> FloatArray:
    """num / den, with ``fill`` where den is exactly zero."""
    nonzero = den != 0.0
    return np.where(nonzero, num / np.where(nonzero, den, 1.0), fill)


def _as_float(x: ArrayLike) -> FloatArray:
    return np.asarray(x, dtype=np.float64)


def fresnel_amplitudes(
    n1: ArrayLike, n2: ArrayLike, cos_i: ArrayLike
) -> tuple[ComplexArray, ComplexArray, ComplexArray, ComplexArray]:
    """Complex amplitude coefficients ``(rs, rp, ts, tp)`` of a bare interface n1 -> n2.

    All four are ratios of electric-field amplitudes (reflected or transmitted over incident),
    the convention of Born & Wolf and of the ``tmm`` package's ``interface_r``/``interface_t``.
    Under total internal reflection |rs| = |rp| = 1 and the t's describe the evanescent wave.
    ``(a - b)/(a + b)`` is evaluated as ``(a**2 - b**2)/(a + b)**2`` with ``a**2 - b**2``
    reduced analytically, which avoids the cancellation in ``a - b`` near normal incidence
    and near Brewster's angle.
    """
    n1, n2, cos_i = np.broadcast_arrays(_as_float(n1), _as_float(n2), _as_float(cos_i))
    cos_t_sq = _cos_sq_in_medium(n1, n2, cos_i)
    cos_t = _complex_cos(cos_t_sq)
    diff_sq = (n2 - n1) * (n2 + n1)

    # s: a = n1 cos_i, b = n2 cos_t, a^2 - b^2 = n1^2 - n2^2
    den_s = n1 * cos_i + n2 * cos_t
    # p: a = n2 cos_i, b = n1 cos_t, a^2 - b^2 = (n2^2 - n1^2)(cos_i^2 (n1^2 + n2^2) - n1^2)/n2^2
    den_p = n2 * cos_i + n1 * cos_t
    num_p = diff_sq * (cos_i**2 * (n1 * n1 + n2 * n2) - n1 * n1) / (n2 * n2)

    # Zero denominators only occur for n1 == n2 at grazing incidence: no interface
    ok_s = den_s != 0
    ok_p = den_p != 0
    den_s1 = np.where(ok_s, den_s, 1.0)
    den_p1 = np.where(ok_p, den_p, 1.0)
    rs = np.where(ok_s, -diff_sq / den_s1**2, 0.0)
    rp = np.where(ok_p, num_p / den_p1**2, 0.0)
    ts = np.where(ok_s, 2.0 * n1 * cos_i / den_s1, 1.0)
    tp = np.where(ok_p, 2.0 * n1 * cos_i / den_p1, 1.0)
    return (
        rs.astype(np.complex128),
        rp.astype(np.complex128),
        ts.astype(np.complex128),
        tp.astype(np.complex128),
    )


def fresnel_reflectance(n1: ArrayLike, n2: ArrayLike, cos_i: ArrayLike) -> FloatArray:
    """Unpolarised power reflectance (mean of Rs and Rp) of a bare interface n1 -> n2.

    Total internal reflection and grazing incidence give exactly 1.0 (except n1 == n2,
    which is no interface and gives 0). Real arithmetic only, no NaN for cos_i in [0, 1].
    """
    n1, n2, cos_i = np.broadcast_arrays(_as_float(n1), _as_float(n2), _as_float(cos_i))
    cos_t_sq = _cos_sq_in_medium(n1, n2, cos_i)
    tir = cos_t_sq < 0.0
    # Clamp the evanescent case to the critical angle; it is overwritten below
    cos_t = np.sqrt(np.where(tir, 0.0, cos_t_sq))
    diff_sq = (n2 - n1) * (n2 + n1)

    # Stable forms (a^2 - b^2)/(a + b)^2 of rs and rp, see fresnel_amplitudes
    rs = _safe_divide(-diff_sq, (n1 * cos_i + n2 * cos_t) ** 2, 0.0)
    num_p = diff_sq * (cos_i**2 * (n1 * n1 + n2 * n2) - n1 * n1) / (n2 * n2)
    rp = _safe_divide(num_p, (n2 * cos_i + n1 * cos_t) ** 2, 0.0)

    # Near the critical angle rs and rp approach -1 and +1 and rounding can lift their squares a
    # few eps above 1 (more when n1 ~ n2); reflectance is physically bounded, so clip
    reflectance = np.minimum(0.5 * (rs * rs + rp * rp), 1.0)
    return np.where(tir, 1.0, reflectance)


def _sinc(delta: ComplexArray, sin_delta: ComplexArray) -> ComplexArray:
    """sin(delta)/delta for complex delta (given its sine), finite at delta = 0."""
    small = np.abs(delta) < _SINC_SERIES_LIMIT
    d2 = delta * delta
    # Taylor series: the next term delta^6/5040 is < 2e-22 below the limit
    series = 1.0 - d2 / 6.0 + d2 * d2 / 120.0
    return np.where(small, series, sin_delta / np.where(small, 1.0, delta))


def _abs_sq(z: ComplexArray) -> FloatArray:
    return z.real * z.real + z.imag * z.imag


def _power_rt(
    eta_in: FloatArray, eta_out: ComplexArray, b: ComplexArray, c: ComplexArray
) -> tuple[FloatArray, FloatArray]:
    """Power R and T of one polarisation from the front-of-stack fields (B, C)."""
    den = eta_in * b + c
    # Amplitudes relative to the incident tangential field: r = (eta0 B - C)/(eta0 B + C) and
    # t = 2 eta0 / (eta0 B + C); a zero den only happens for an invisible stack at grazing
    ok = den != 0
    den1 = np.where(ok, den, 1.0)
    r = (eta_in * b - c) / den1
    t = 2.0 * eta_in / den1
    reflect = np.where(ok, _abs_sq(r), 0.0)
    # Power transmittance from the transmitted amplitude: T = Re(eta_out)/eta_in |t|^2.
    # An evanescent exit medium has purely imaginary eta_out, hence T = 0 exactly;
    # grazing incidence (eta_in = 0, so t = 0) gives T = 0.
    transmit = _safe_divide(eta_out.real * _abs_sq(t), eta_in, 0.0)
    return reflect, np.where(ok, transmit, 1.0)


def coated_reflectance(
    n1: ArrayLike,
    n2: ArrayLike,
    cos_i: ArrayLike,
    layer_n: Sequence[ArrayLike],
    layer_thickness_nm: Sequence[ArrayLike],
    wavelength_nm: ArrayLike,
) -> tuple[FloatArray, FloatArray]:
    """Unpolarised power reflectance R and transmittance T of a thin-film stack.

    The lossless homogeneous layers ``layer_n[k]`` with physical thicknesses
    ``layer_thickness_nm[k]`` lie between the incident medium ``n1`` and the exit medium ``n2``,
    listed from the n1 side. Every index may be an array broadcastable with ``wavelength_nm``
    (dispersion) and with ``cos_i``. s and p are computed separately and averaged.

    T comes from the transmitted amplitude and the admittance ratio, not from 1 - R, so
    R + T = 1 is an independent check. TIR in the exit medium gives R = 1, T = 0; evanescent
    waves inside layers (frustrated TIR) are handled with complex phases. An empty stack
    reproduces the bare interface.
    """
    return _coated(n1, n2, cos_i, layer_n, layer_thickness_nm, wavelength_nm, True)


def coated_power_reflectance(
    n1: ArrayLike,
    n2: ArrayLike,
    cos_i: ArrayLike,
    layer_n: Sequence[ArrayLike],
    layer_thickness_nm: Sequence[ArrayLike],
    wavelength_nm: ArrayLike,
) -> FloatArray:
    """R of :func:`coated_reflectance`, bit for bit, without computing T (the tracer's
    Fresnel loss takes R alone)."""
    return _coated(n1, n2, cos_i, layer_n, layer_thickness_nm, wavelength_nm, False)[0]


def _coated(n1: ArrayLike, n2: ArrayLike, cos_i: ArrayLike, layer_n: Sequence[ArrayLike],
            layer_thickness_nm: Sequence[ArrayLike], wavelength_nm: ArrayLike,
            with_t: bool) -> tuple[FloatArray, FloatArray]:
    """:func:`coated_reflectance`; without ``with_t`` T is not computed (returned as R)."""
    if len(layer_n) != len(layer_thickness_nm):
        raise ValueError(
            f"coated_reflectance: {len(layer_n)} layer indices but "
            f"{len(layer_thickness_nm)} layer thicknesses"
        )
    ns = [_as_float(n) for n in layer_n]
    ds = [_as_float(d) for d in layer_thickness_nm]
    n1_a, n2_a, cos_a, lam = (_as_float(x) for x in (n1, n2, cos_i, wavelength_nm))
    shape = np.broadcast_shapes(
        n1_a.shape,
        n2_a.shape,
        cos_a.shape,
        lam.shape,
        *(n.shape for n in ns),
        *(d.shape for d in ds),
    )
    n1_a, n2_a, cos_a, lam = (np.broadcast_to(x, shape) for x in (n1_a, n2_a, cos_a, lam))
    # Vacuum wavenumber in 1/nm, matching thicknesses in nm
    k0 = 2.0 * np.pi / lam

    # Where the wave propagates in every layer and in the exit medium (all the rays but
    # for frustrated or total internal reflection), the same in real arithmetic
    cos_out_sq = _cos_sq_in_medium(n1_a, n2_a, cos_a)
    cos_sq = [_cos_sq_in_medium(n1_a, n_k, cos_a) for n_k in ns]
    if np.all(cos_out_sq >= 0.0) and all(np.all(c >= 0.0) for c in cos_sq):
        return _coated_propagating(n1_a, n2_a, cos_a, k0, ns, ds, cos_out_sq, cos_sq, with_t)

    # Admittances of the outer media: s uses eta = n cos (fields E, H), p uses the dual
    # zeta = cos / n (fields H, E). The incident medium is lossless and propagating.
    cos_out = _complex_cos(cos_out_sq)
    eta_in_s, eta_in_p = n1_a * cos_a, cos_a / n1_a
    eta_out_s, eta_out_p = n2_a * cos_out, cos_out / n2_a

    # Tangential fields (B, C) in front of each layer, normalised to unit field at the exit
    b_s = np.ones(shape, dtype=np.complex128)
    b_p = b_s
    c_s, c_p = eta_out_s, eta_out_p
    for n_k, d_k, cos_sq_k in zip(reversed(ns), reversed(ds), reversed(cos_sq), strict=True):
        cos_k = _complex_cos(cos_sq_k)
        # Phase thickness of layer k; the matrix is even in cos_k, so its branch is irrelevant
        k0d = k0 * d_k
        delta = k0d * n_k * cos_k
        cos_d = np.cos(delta)
        sin_d = np.sin(delta)
        # i sin(delta)/eta through sinc, finite when cos_k = 0 (layer at its critical angle):
        # s: delta/eta = k0 d;  p: delta/zeta = k0 d n^2
        m12_s = 1j * k0d * _sinc(delta, sin_d)
        m12_p = m12_s * (n_k * n_k)
        m21_s = 1j * (n_k * cos_k) * sin_d
        m21_p = 1j * (cos_k / n_k) * sin_d
        # Characteristic matrix of layer k applied to the fields behind it
        b_s, c_s = cos_d * b_s + m12_s * c_s, m21_s * b_s + cos_d * c_s
        b_p, c_p = cos_d * b_p + m12_p * c_p, m21_p * b_p + cos_d * c_p

    r_s, t_s = _power_rt(eta_in_s, eta_out_s, b_s, c_s)
    r_p, t_p = _power_rt(eta_in_p, eta_out_p, b_p, c_p)
    return 0.5 * (r_s + r_p), 0.5 * (t_s + t_p)


def _coated_propagating(
    n1: FloatArray, n2: FloatArray, cos_i: FloatArray, k0: FloatArray,
    ns: list[FloatArray], ds: list[FloatArray], cos_out_sq: FloatArray,
    cos_sq: list[FloatArray], with_t: bool = True,
) -> tuple[FloatArray, FloatArray]:
    """:func:`coated_reflectance` where every cosine is real (no evanescent wave): the
    same characteristic matrices, with B = br + i bi and C = cr + i ci in real arrays
    (the matrices' diagonal is real, their off-diagonal purely imaginary). Without
    ``with_t`` T is not computed (R is returned in its place)."""
    cos_out = np.sqrt(cos_out_sq)
    r_sum = np.zeros(np.shape(cos_i))
    t_sum = np.zeros(np.shape(cos_i)) if with_t else r_sum
    # Each layer's phase thickness and its cosine, sine and sinc, once for both
    # polarisations (the trigonometry is most of this function's time)
    layers = []
    for n_k, d_k, cos_sq_k in zip(reversed(ns), reversed(ds), reversed(cos_sq), strict=True):
        cos_k = np.sqrt(cos_sq_k)
        k0d = k0 * d_k
        delta = k0d * n_k * cos_k
        cos_d, sin_d = np.cos(delta), np.sin(delta)
        # Off-diagonal elements over i, as in coated_reflectance (sinc finite at 0)
        small = np.abs(delta) < _SINC_SERIES_LIMIT
        d2 = delta * delta
        sinc = np.where(small, 1.0 - d2 / 6.0 + d2 * d2 / 120.0,
                        sin_d / np.where(small, 1.0, delta))
        layers.append((n_k, cos_k, k0d, cos_d, sin_d, sinc))
    for pol in ("s", "p"):
        # Admittances: s eta = n cos, p zeta = cos / n
        eta_in = n1 * cos_i if pol == "s" else cos_i / n1
        eta_out = n2 * cos_out if pol == "s" else cos_out / n2
        br = bi = cr = ci = None  # (B, C) = (1, eta_out) behind the stack
        for n_k, cos_k, k0d, cos_d, sin_d, sinc in layers:
            m12 = k0d * sinc if pol == "s" else k0d * sinc * (n_k * n_k)
            m21 = (n_k * cos_k) * sin_d if pol == "s" else (cos_k / n_k) * sin_d
            # (B, C) <- [[cos, i m12], [i m21, cos]] (B, C); the first layer's product
            # with (1, eta_out) written out (the same values: x * 1 and x -/+ 0 are x, up
            # to the sign of a zero, which R and T square away)
            if br is None:
                br, bi, cr, ci = cos_d, m12 * eta_out, cos_d * eta_out, m21
            else:
                br, bi, cr, ci = (cos_d * br - m12 * ci, cos_d * bi + m12 * cr,
                                  cos_d * cr - m21 * bi, cos_d * ci + m21 * br)
        if br is None:  # no layer
            br, bi = np.ones(np.shape(cos_i)), np.zeros(np.shape(cos_i))
            cr, ci = eta_out, np.zeros(np.shape(cos_i))
        # R = |eta_in B - C|^2 / |eta_in B + C|^2, T = 4 eta_in eta_out / |eta_in B + C|^2
        # (zero den: an invisible stack at grazing incidence, R = 0 and T = 1)
        den = (eta_in * br + cr) ** 2 + (eta_in * bi + ci) ** 2
        ok = den != 0.0
        den1 = np.where(ok, den, 1.0)
        num = (eta_in * br - cr) ** 2 + (eta_in * bi - ci) ** 2
        r_sum += np.where(ok, num / den1, 0.0)
        if with_t:
            t_sum += np.where(ok, np.where(eta_in != 0.0, 4.0 * eta_in * eta_out / den1, 0.0),
                              1.0)
    return 0.5 * r_sum, 0.5 * t_sum


def quarter_wave_thickness_nm(n_layer_at_design: float, design_wavelength_nm: float) -> float:
    """Physical thickness of a quarter-wave layer at normal incidence: lambda / (4 n)."""
    return float(design_wavelength_nm) / (4.0 * float(n_layer_at_design))


def reflect_direction(d: ArrayLike, normal: ArrayLike) -> FloatArray:
    """Mirror reflection ``d - 2 (d . n) n`` of directions about unit normals, shape (..., 3).

    Works for either orientation of the normal; the result has the length of ``d``.
    """
    d = _as_float(d)
    normal = _as_float(normal)
    d_dot_n = np.sum(d * normal, axis=-1, keepdims=True)
    return d - 2.0 * d_dot_n * normal
