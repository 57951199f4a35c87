"""Training and held-out rays for P_o and P_s, found by aiming real rays at stop points.

Samples come in groups that share everything but the stop point (one scene point or
sensor point and one wavelength), so that the part of the OPL that is constant per pixel
can be removed when errors are measured.

The rays themselves are aimed by :mod:`lensfit.sample.aim` (:func:`aim_object_side`
and :func:`aim_sensor_side`: Newton's method on each ray's start, the stop point
on the stop surface, the relative OPL); the samplers here draw inputs and call
them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lensfit.prescription.model import Lens
from lensfit.sample.aim import (
    SamplingError,
    _front_plane,
    aim_object_side,
    aim_sensor_side,
)
from lensfit.sample.domain import Domain

# Rays are fitted up to 10% beyond a housing, so that the clip edge fits (both fitting
# methods train on them, lensfit.fitting; a pilot grid's dead rim is judged by it too)
TRAIN_VIGNETTING = 1.1
INFINITY_SHARE = 0.2  # share of P_o groups placed exactly at infinity (u_O = 0)

OUTPUTS_O = (("x_o", "mm"), ("y_o", "mm"), ("tau_o", "1"), ("phi_o", "mm"))
OUTPUTS_S = (("x_i", "mm"), ("y_i", "mm"), ("tau_i", "1"), ("phi_i", "mm"))


@dataclass
class Samples:
    """Rays for one system: raw inputs, exact outputs, and bookkeeping."""

    system: str  # "P_o" or "P_s"
    inputs: np.ndarray  # (N, 6) raw inputs in the domain's units
    outputs: np.ndarray  # (N, 4) exact outputs
    group: np.ndarray  # (N,) group id: samples sharing all but the stop point
    vignetting: np.ndarray  # (N,) max radius / housing radius along the half path
    requested: int  # samples asked for, before dropping failures
    dropped: dict[str, int] = field(default_factory=dict)  # reason -> count

    def __len__(self) -> int:
        return len(self.inputs)

    @property
    def passes(self) -> np.ndarray:
        """The exact ray gets through every housing of its half."""
        return self.vignetting <= 1.0

    def subset(self, mask: np.ndarray) -> Samples:
        return Samples(self.system, self.inputs[mask], self.outputs[mask], self.group[mask],
                       self.vignetting[mask], self.requested, dict(self.dropped))


def _disc(rng: np.random.Generator, n: int, radius: float) -> np.ndarray:
    """n points uniform on a disc."""
    r = radius * np.sqrt(rng.random(n))
    a = 2.0 * math.pi * rng.random(n)
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)


def _group_inputs(rng, groups: int, per_group: int, stop_r: float):
    """Aperture points for every group, and the group index of each sample."""
    gid = np.repeat(np.arange(groups), per_group)
    ap = _disc(rng, groups * per_group, stop_r)
    return gid, ap


def _wavelengths(rng, domain: Domain, n: int) -> np.ndarray:
    return rng.uniform(domain.wavelength_min_nm, domain.wavelength_max_nm, n)


def sample_object_side(lens: Lens, domain: Domain, groups: int, per_group: int,
                       seed: int) -> Samples:
    """Samples for P_o: scene point -> stop point."""
    rng = np.random.default_rng(seed)
    n = groups * per_group
    gid, ap = _group_inputs(rng, groups, per_group, domain.stop_radius_mm)

    # Scene points: directions on the field disc (in direction cosines, half of them
    # edge-weighted: _edge_disc), inverse
    # distances uniform in [0, u_max] with a share exactly at infinity, one wavelength each
    # (an ellipse when the field differs in x and y)
    sin_xy = np.array([math.sin(math.radians(f)) for f in domain.field_xy_deg])
    dirs = _edge_disc(rng, groups) * sin_xy
    u = rng.uniform(0.0, domain.inverse_distance_max, groups)
    u[rng.random(groups) < INFINITY_SHARE] = 0.0
    lam_g = _wavelengths(rng, domain, groups)
    xo, yo, ug, lam = dirs[gid, 0], dirs[gid, 1], u[gid], lam_g[gid]

    # The OPL counts the leg from the scene point to the start plane as +|S - scene|:
    # a scene point on or behind the plane would get the wrong sign (or lie in the glass)
    front = _front_plane(lens)
    nearest_z = -domain.close_focus_mm * math.cos(math.radians(max(domain.field_xy_deg)))
    if not nearest_z < front:
        raise SamplingError(
            f"{lens.source_file or lens.name}: P_o: close_focus_mm = "
            f"{domain.close_focus_mm:g} puts scene points at z = {nearest_z:g} mm, not in "
            f"front of the lens (its surfaces before the stop reach to z = {front + 1.0:g} "
            "mm; scene points must be at least 1 mm further out)"
        )
    aimed = aim_object_side(lens, xo, yo, ug, ap[:, 0], ap[:, 1], lam,
                            fd_scale_mm=max(domain.stop_radius_mm, 1.0))
    keep = aimed.ok
    inputs = np.stack([xo, yo, ug, ap[:, 0], ap[:, 1], lam], axis=1)
    dropped = {"not converged or missed": int(n - np.sum(keep))}
    return _finish("P_o", lens, inputs[keep], aimed.outputs[keep], gid[keep],
                   aimed.vignetting[keep], n, dropped)


def sample_sensor_side(lens: Lens, domain: Domain, groups: int, per_group: int,
                       seed: int) -> Samples:
    """Samples for P_s: stop point -> sensor point."""
    rng = np.random.default_rng(seed)
    n = groups * per_group
    gid, ap = _group_inputs(rng, groups, per_group, domain.stop_radius_mm)
    sens = _edge_disc(rng, groups) * domain.sensor_radius_mm
    zs_g = rng.uniform(domain.focus_min_mm, domain.focus_max_mm, groups)
    lam_g = _wavelengths(rng, domain, groups)
    xs, ys, zs, lam = sens[gid, 0], sens[gid, 1], zs_g[gid], lam_g[gid]
    if lens.sensor_z + domain.focus_min_mm <= lens.vertex_z[-1]:
        raise SamplingError(
            f"{lens.source_file or lens.name}: focus_min_mm = {domain.focus_min_mm:g} puts the "
            f"sensor in front of the last surface (it is {lens.sensor_z - lens.vertex_z[-1]:g}"
            " mm behind it)")
    aimed = aim_sensor_side(lens, xs, ys, zs, ap[:, 0], ap[:, 1], lam, fd_scale=1.0)
    keep = aimed.ok
    inputs = np.stack([xs, ys, zs, ap[:, 0], ap[:, 1], lam], axis=1)
    dropped = {"not converged or missed": int(n - np.sum(keep))}
    return _finish("P_s", lens, inputs[keep], aimed.outputs[keep], gid[keep],
                   aimed.vignetting[keep], n, dropped)


def _finish(system, lens, inputs, outputs, gid, vig, n, dropped) -> Samples:
    if len(inputs) == 0:
        raise SamplingError(
            f"{lens.source_file or lens.name}: {system}: none of {n} rays got through the "
            f"lens over the declared domain ({dropped})"
        )
    return Samples(system, inputs, outputs, gid, vig, n, dropped)


@dataclass
class GridSamples:
    """Rays on a grid: every field point (the inputs but the stop point, in the system's
    order without x_a, y_a) with every stop point of one mirror-symmetric set."""

    system: str  # "P_o" or "P_s"
    field: np.ndarray  # (G, 4) raw field inputs: x_O, y_O, u_O, lambda or x_S, y_S, z_S, lambda
    aperture: np.ndarray  # (K, 2) stop points (mm)
    outputs: np.ndarray  # (G, K, 4) exact outputs; NaN where not ok
    ok: np.ndarray  # (G, K) the ray exists (converged, no miss or TIR)
    vignetting: np.ndarray  # (G, K) max radius / housing radius along the half path
    stop_edge_share: float = 0.0  # the law the stop points were drawn from (more: the same)

    def __len__(self) -> int:
        return int(self.ok.size)

    @property
    def requested(self) -> int:
        return int(self.ok.size)

    @property
    def dropped(self) -> dict[str, int]:
        return {"not converged or missed": int(self.ok.size - np.count_nonzero(self.ok))}


GRID_CHUNK = 1 << 16  # rays aimed at once


def sample_grid(lens: Lens, domain: Domain, system: str, groups: int, points: int,
                seed: int) -> GridSamples:
    """Grid samples for ``system`` ("P_o" or "P_s"): ``groups`` field points drawn as the
    random samplers draw them (uniform on the field disc or image circle, focus or
    inverse distance with a share at infinity), wavelengths uniform in 1/lambda^2 (the
    fitted variable), and ``points`` stop points (a multiple of 4, mirror-symmetric,
    STOP_EDGE_SHARE of them denser towards the rim, the rest uniform on the stop disc;
    all uniform when the rim is dead: :func:`_dead_rim`)."""
    from lensfit.poly.tensor import symmetric_disc_points

    if system not in ("P_o", "P_s"):
        raise ValueError(f"sample_grid: system = {system!r}: expected P_o or P_s")
    r = domain.stop_radius_mm
    share = STOP_EDGE_SHARE if points >= MIN_EDGE_POINTS else 0.0
    rng = np.random.default_rng(seed)
    field = _grid_field(domain, system, groups, rng)
    ap = symmetric_disc_points(rng, points, share) * r
    if share > 0.0:
        # A pilot: the field points nearest the axis through these stop points. Where
        # rays near the stop's rim fail even there, the rim-weighted points would be
        # spent on holes: the grid is drawn again as uniform points (the same draws as
        # before the rim weighting, for the same seed)
        near = np.argsort(np.hypot(field[:, 0], field[:, 1]), kind="stable")[:PILOT_GROUPS]
        try:
            dead = _dead_rim(_trace_grid(lens, domain, system, field[near], ap), ap / r)
        except SamplingError:  # no ray near the axis: the whole grid says what is wrong
            dead = False
        if dead:
            share = 0.0
            rng = np.random.default_rng(seed)
            field = _grid_field(domain, system, groups, rng)
            ap = symmetric_disc_points(rng, points) * r
    grid = _trace_grid(lens, domain, system, field, ap)
    grid.stop_edge_share = share
    return grid


# Field points nearest the axis traced first, and the share of holes among their rays
# beyond 90% of the stop radius that makes the rim dead (sample_grid). Measured: lens
# 0004's P_s (f/2.64) loses 23% of its rays at 90-95% of the stop radius and 53% beyond,
# at every field point (they miss the rear group); rim-weighted points took its
# sensor-side phase from 1.1e-3 waves (uniform, field degree 10) to 0.18. Lens 0007's
# P_o near the axis loses 1% (its holes are vignetting at the field's edge), 0008 none
PILOT_GROUPS = 16
DEAD_RIM_SHARE = 0.1
# Fewer stop points than this are drawn uniform: half of 64 at the rim leave 8 per
# quadrant for the centre, and a cemented singlet's axis PSF at f/8 and 450 nm (small
# budgets, tests/fit/test_stop_placement.py) was 1.58% against 0.39% on uniform points,
# every output within its held-out target; the defaults draw 128
MIN_EDGE_POINTS = 128


def _dead_rim(pilot: GridSamples, unit_ap: np.ndarray) -> bool:
    """True when more than DEAD_RIM_SHARE of the ``pilot``'s rays through stop points
    beyond 90% of the radius (``unit_ap``: the stop points on the unit disc) fail or
    are vignetted past the training limit."""

    rim = np.hypot(unit_ap[:, 0], unit_ap[:, 1]) > 0.9
    if not np.any(rim):
        return False
    with np.errstate(invalid="ignore"):
        used = pilot.ok[:, rim] & (pilot.vignetting[:, rim] <= TRAIN_VIGNETTING)
    return float(1.0 - used.mean()) > DEAD_RIM_SHARE


def extend_grid(lens: Lens, domain: Domain, grid: GridSamples, *, points: int = 0,
                groups: int = 0, seed: int) -> GridSamples:
    """``grid`` with ``points`` more stop points (a multiple of 4, mirror-symmetric, for
    every field point) or ``groups`` more field points (with every stop point), drawn
    from ``seed`` as :func:`sample_grid` draws them: only the new rays are traced."""
    from lensfit.poly.tensor import symmetric_disc_points

    rng = np.random.default_rng(seed)
    if points:
        ap = (symmetric_disc_points(rng, points, grid.stop_edge_share)
              * domain.stop_radius_mm)
        more = _trace_grid(lens, domain, grid.system, grid.field, ap)
        return GridSamples(grid.system, grid.field, np.concatenate([grid.aperture, ap]),
                           np.concatenate([grid.outputs, more.outputs], axis=1),
                           np.concatenate([grid.ok, more.ok], axis=1),
                           np.concatenate([grid.vignetting, more.vignetting], axis=1),
                           grid.stop_edge_share)
    field = _grid_field(domain, grid.system, groups, rng)
    more = _trace_grid(lens, domain, grid.system, field, grid.aperture)
    return GridSamples(grid.system, np.concatenate([grid.field, field]), grid.aperture,
                       np.concatenate([grid.outputs, more.outputs]),
                       np.concatenate([grid.ok, more.ok]),
                       np.concatenate([grid.vignetting, more.vignetting]),
                       grid.stop_edge_share)


def _grid_field(domain: Domain, system: str, groups: int,
                rng: np.random.Generator) -> np.ndarray:
    """``groups`` field points (G, 4) of ``system``, as :func:`sample_grid` draws them:
    denser towards the domain's edges (:func:`_edge_disc`, :func:`_edge_uniform`), where
    a least-squares polynomial on uniform points is least constrained."""
    if system == "P_o":
        sin_xy = np.array([math.sin(math.radians(f)) for f in domain.field_xy_deg])
        dirs = _edge_disc(rng, groups) * sin_xy
        third = _edge_uniform(rng, 0.0, domain.inverse_distance_max, groups)
        third[rng.random(groups) < INFINITY_SHARE] = 0.0
    else:
        dirs = _edge_disc(rng, groups) * domain.sensor_radius_mm
        third = _edge_uniform(rng, domain.focus_min_mm, domain.focus_max_mm, groups)
    w_lo, w_hi = 1.0 / domain.wavelength_max_nm**2, 1.0 / domain.wavelength_min_nm**2
    lam = 1.0 / np.sqrt(_edge_uniform(rng, w_lo, w_hi, groups))
    return np.column_stack([dirs[:, 0], dirs[:, 1], third, lam])


# Share of the field points (the grid's, and the held-out rays' on the field's disc)
# drawn from the edge-weighted laws below, the rest uniform. Measured, worst PSF cell:
# a Cooke triplet over its 20 degree field 2.7% (at the field's corner) on uniform
# points, 0.49% all edge-weighted, 0.79% half and half; a singlet with the smallest
# budgets 1.9% on the axis all edge-weighted (the laws halve the density at the
# centre), 0.75% half and half
EDGE_SHARE = 0.5


# Share of the grid's stop points drawn denser towards the stop's rim (the law of
# _edge_disc), the rest uniform. Measured on 128 points, held-out phase RMS of the
# tensor fit (waves): lens 0007's P_o at f/2 over 35 degrees, field degree 10, 2.2
# uniform against 0.21 (uniform points left the rim so thin that the fit was right on
# the grid, 0.05, and wrong between: 12 waves within 5% of the rim); lens 0008's P_o
# at field degrees 10/12/14 1.2e-2/2.7e-3/9.6e-4 uniform, 3.8e-3/6.9e-4/1.7e-4 half
# and half, 4.4e-3/8.4e-4/2.4e-4 all edge-weighted; its P_s reached 5.6e-4 at field
# degree 12 (30828 terms) uniform, 10 (17031 terms) half and half
STOP_EDGE_SHARE = 0.5


def _edge_disc(rng: np.random.Generator, n: int) -> np.ndarray:
    """n points on the unit disc, EDGE_SHARE of them with density 1 / sqrt(1 - r^2)
    (uniform points of the hemisphere seen from above: the disc's analogue of Chebyshev
    points, the measure under which least-squares polynomials are as good at the rim as
    inside), the rest uniform."""
    from lensfit.poly.tensor import edge_radii

    r = edge_radii(rng, n, EDGE_SHARE)
    a = 2.0 * math.pi * rng.random(n)
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)


def _edge_uniform(rng: np.random.Generator, lo: float, hi: float, n: int) -> np.ndarray:
    """n points on [lo, hi], EDGE_SHARE of them with the arcsine (Chebyshev) density, the
    rest uniform."""
    u = rng.random(n)
    t = np.where(rng.random(n) < EDGE_SHARE, 0.5 * (1.0 - np.cos(math.pi * u)), u)
    return lo + (hi - lo) * t


def _trace_grid(lens: Lens, domain: Domain, system: str, field: np.ndarray,
                ap: np.ndarray) -> GridSamples:
    """Every field point of ``field`` (G, 4) with every stop point of ``ap`` (K, 2), aimed."""
    aim = aim_object_side if system == "P_o" else aim_sensor_side
    groups, points = len(field), len(ap)
    gid = np.repeat(np.arange(groups), points)
    aid = np.tile(np.arange(points), groups)
    n = groups * points
    outputs = np.full((n, 4), np.nan)
    ok = np.zeros(n, dtype=bool)
    vig = np.full(n, np.nan)
    unknowns = np.full((n, 2), np.nan)
    kw = ({"fd_scale_mm": max(domain.stop_radius_mm, 1.0)} if system == "P_o"
          else {"fd_scale": 1.0})

    def run(rows: np.ndarray, guess: np.ndarray | None) -> None:
        for a in range(0, len(rows), GRID_CHUNK):
            r = rows[a:a + GRID_CHUNK]
            f, k = field[gid[r]], aid[r]
            res = aim(lens, f[:, 0], f[:, 1], f[:, 2], ap[k, 0], ap[k, 1], f[:, 3], **kw,
                      guess=None if guess is None else guess[a:a + GRID_CHUNK])
            outputs[r], ok[r], vig[r], unknowns[r] = (res.outputs, res.ok, res.vignetting,
                                                      res.unknowns)

    run(np.arange(n), None)
    if not np.any(ok):
        raise SamplingError(f"{lens.source_file or lens.name}: {system}: none of {n} rays got "
                            "through the lens over the declared domain")
    return GridSamples(system, field, ap, outputs.reshape(groups, points, 4),
                       ok.reshape(groups, points), vig.reshape(groups, points))
