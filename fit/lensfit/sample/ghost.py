"""Exact rays of a ghost's half-system: the path, the aiming, and the clip data.

A ghost (i, j), i < j, reflects at j going back and at i going forward again
(:func:`lensfit.trace.tracer.ghost_path`). Its aperture point is where the path FIRST
crosses the stop (index s), which splits it into two halves as the direct path is split
(/work/notes/ghost-design.md, issue 13 part 2):

* case A, j < s: both reflections come before the stop: the ghost half is P_o
  (scene -> ... -> j, back to i, forward -> stop); P_s is the direct one.
* case B, i > s: both come after: P_o is the direct one, the ghost half is P_s
  (stop -> ... -> j, back to i, forward -> last surface -> sensor).
* case C, i < s < j: P_o is the direct one; the ghost half is P_s, and it crosses the
  stop twice more (backwards after j, forwards again after i). Those crossings are
  outputs in mm, so that a renderer can test them against the stop's real shape.

A ghost half has the inputs of the half it replaces and its four outputs (x, y on the
first surface for P_o or the last for P_s, tau with the lens's coatings including both
reflectances, phi), found by the same Newton aiming as the direct halves
(:func:`lensfit.sample.aim.aim_object_side` / ``aim_sensor_side`` along the ghost's
steps), plus clip data: for every surface step of the half (each crossing of a housing
counted apart) the position over the housing's radius (x_k / R_k, y_k / R_k).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lensfit.poly.tensor import symmetric_disc_points
from lensfit.prescription.model import Lens
from lensfit.sample.aim import Aimed, SamplingError, aim_object_side, aim_sensor_side
from lensfit.sample.domain import Domain
from lensfit.sample.rays import INFINITY_SHARE, GridSamples, Samples, _disc
from lensfit.trace.tracer import Step, ghost_path

# A stop's shape: (x, y) mm arrays on the stop surface (the stop plane, or the refracting
# surface a stop lies on) -> True inside the opening
StopShape = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class GhostHalf:
    """The half of ghost (i, j) that differs from the direct path."""

    first: int  # i (model surface index)
    second: int  # j
    system: str  # "P_o" (case A) or "P_s" (cases B and C)
    steps: tuple[Step, ...]  # P_o: start plane -> stop plane; P_s: stop plane -> last surface
    stop_crossings: tuple[int, ...]  # indices into steps of the stop plane (case C: two)
    stop_index: int  # the model's stop surface (a plane, or the copy of a refracting
    #                   surface the stop lies on: stop points are x, y on it)

    def __iter__(self):
        """Unpacks as (system, steps, stop_crossings)."""
        return iter((self.system, self.steps, self.stop_crossings))

    @property
    def case(self) -> str:
        return "A" if self.system == "P_o" else ("C" if self.stop_crossings else "B")

    @property
    def housings(self) -> tuple[int, ...]:
        """Indices into ``steps`` of the steps at a housing: every step but those at the
        stop plane (on P_o its last step, in case C the two extra crossings)."""
        return tuple(k for k, st in enumerate(self.steps) if st.surface != self.stop_index)


def ghost_half(lens: Lens, i: int, j: int) -> GhostHalf:
    """The ghost half of (i, j): system, steps and stop crossings (module doc). ``i`` and
    ``j`` are model surface indices of refracting surfaces, never the stop plane."""
    n = len(lens.surfaces)
    s = lens.stop_index
    if not 0 <= i < j < n:
        raise ValueError(f"{lens.source_file or lens.name}: ghost ({i}, {j}): expected "
                         f"0 <= i < j < {n} (model surface indices)")
    for k in (i, j):
        if lens.surfaces[k].stop:
            raise ValueError(f"{lens.source_file or lens.name}: ghost ({i}, {j}): surface {k}"
                             " is the stop plane, which reflects nothing")
    full = ghost_path(lens, i, j)
    first = next(k for k, st in enumerate(full) if st.surface == s)
    if j < s:  # case A: the half ends on the stop plane
        steps = tuple(full[:first + 1])
        return GhostHalf(i, j, "P_o", steps, (), s)
    steps = tuple(full[first + 1:])
    crossings = tuple(k for k, st in enumerate(steps) if st.surface == s)
    return GhostHalf(i, j, "P_s", steps, crossings, s)


@dataclass
class GhostAimed:
    """Exactly traced rays of a ghost half, one per row of the inputs."""

    half: GhostHalf
    aimed: Aimed  # outputs (N, 4), ok, unknowns, history ... as the direct aiming gives
    clip: np.ndarray  # (N, H, 2) x_k / R_k, y_k / R_k at each housing step (NaN: not ok)
    stop: np.ndarray  # (N, C, 2) x, y (mm) at the extra stop crossings (case C: C = 2)

    @property
    def ok(self) -> np.ndarray:
        return self.aimed.ok

    @property
    def outputs(self) -> np.ndarray:
        return self.aimed.outputs

    @property
    def ratio(self) -> np.ndarray:
        """(N, H) radius over housing radius at each housing step."""
        return np.hypot(self.clip[..., 0], self.clip[..., 1])

    @property
    def vignetting(self) -> np.ndarray:
        """Largest radius over housing radius along the half (> 1: blocked)."""
        r = self.ratio
        return r.max(axis=1) if r.shape[1] else np.zeros(len(r))

    def max_clip(self) -> np.ndarray:
        """(N, 2): the paper's single clip output, (x_k, y_k) / R_k at the housing step
        where the ratio is largest."""
        r = np.nan_to_num(self.ratio, nan=-1.0)
        k = np.argmax(r, axis=1)
        return self.clip[np.arange(len(r)), k]

    def passes(self, stop_radius_mm: float, stop_shape: StopShape | None = None) -> np.ndarray:
        """The exact verdict: through every housing of the half and, in case C, inside the
        stop at both extra crossings: ``stop_shape(x, y)`` (mm, arrays; True inside) for a
        bladed or slit stop, else a round stop of ``stop_radius_mm``."""
        ok = self.ok & (self.vignetting <= 1.0)
        if self.stop.shape[1]:
            x, y = self.stop[..., 0], self.stop[..., 1]
            inside = (np.asarray(stop_shape(x, y), dtype=bool) if stop_shape is not None
                      else np.hypot(x, y) <= stop_radius_mm)
            ok &= np.all(inside, 1)
        return ok


RETRY_ROUNDS = 6  # rounds of restarts from converged neighbours (aim_ghost)
RETRY_NEIGHBOURS = 3  # converged neighbours tried per ray and round
# ... until one Newton pass of the continuation solves fewer than this share of the rays
# it tried: the rest lie where the ghost's rays do not exist (0001's 3-13: 30% of its
# rays over the direct domain; its passes solved 21%, 8%, 10%, 4%, 2%, then 0.8%, 0.5%
# and 0 for 40% of the aiming's time)
RETRY_MIN_GAIN = 0.01
SCAN = 21  # scan of SCAN x SCAN rays per field point for the rays still unsolved (aim_ghost)
SCAN_REACH = 1.2  # the scan covers this times the first (P_o) or last (P_s) housing


def aim_ghost(lens: Lens, half: GhostHalf, a: np.ndarray, b: np.ndarray, c: np.ndarray,
              x_a: np.ndarray, y_a: np.ndarray, wavelength_nm: np.ndarray, *,
              fd_scale: float | None = None, guess: np.ndarray | None = None,
              retry_rounds: int | None = None, scan: int | None = None) -> GhostAimed:
    """The ghost half exactly, one row per ray. Inputs as the half it replaces: P_o
    (x_O, y_O, u_O, x_a, y_a, lambda), P_s (x_S, y_S, z_S, x_a, y_a, lambda).

    The direct aiming (damped finite-difference Newton from the direct path's paraxial
    guess, then once from the nearest converged ray) reaches far fewer ghost rays: the
    paraxial guess of the direct path is far from a ghost's rays, and one restart only
    reaches the neighbours of the rays that converged at first. Two measured additions:

    1. Continuation across the stop disc: in each of ``retry_rounds`` rounds (default
       RETRY_ROUNDS) every ray still unsolved starts again from each of its
       RETRY_NEIGHBOURS nearest converged rays (nearest in the stop point within its
       field point and wavelength), until a pass solves fewer than RETRY_MIN_GAIN of
       the rays it tried.
    2. A scan per field point for the rays still unsolved: ``scan`` x ``scan`` rays
       (default SCAN; 0: none) traced along the half, P_o from the scene point through
       a grid on the plane z = 0, P_s backwards from the sensor point through a grid on
       the last vertex plane, both over SCAN_REACH times that housing; each unsolved ray
       starts Newton from the scan ray that crosses the stop plane nearest its stop
       point, then the continuation runs once more.

    Converged shares of requested rays: the report of issue 13 part 2 (e.g. 0001's ghost
    (3, 11): 24% direct aiming, 78% with the continuation)."""
    from scipy.spatial import cKDTree

    steps = list(half.steps)
    args = [np.array(v, dtype=np.float64).reshape(-1) for v in
            np.broadcast_arrays(a, b, c, x_a, y_a, wavelength_nm)]
    n = len(args[0])

    def aim(rows: np.ndarray, g: np.ndarray | None) -> Aimed:
        v = [arg[rows] for arg in args]
        if half.system == "P_o":
            kw = {} if fd_scale is None else {"fd_scale_mm": fd_scale}
            return aim_object_side(lens, *v, path=steps, history=True, guess=g, **kw)
        return aim_sensor_side(lens, *v, path=steps, history=True, guess=g,
                               fd_scale=1.0 if fd_scale is None else fd_scale)

    def merge(rows: np.ndarray, again: Aimed) -> int:
        i = rows[again.ok]
        for name in ("outputs", "vignetting", "ok", "unknowns", "pos", "dir", "history"):
            getattr(aimed, name)[i] = getattr(again, name)[again.ok]
        return int(again.ok.sum())

    def continuation(rounds: int) -> None:
        feat = np.column_stack([args[3], args[4]] + [1e6 * args[k] for k in (0, 1, 2, 5)])
        for _ in range(rounds):
            good, bad = np.nonzero(aimed.ok)[0], np.nonzero(~aimed.ok)[0]
            if not (good.size and bad.size):
                return
            k = min(RETRY_NEIGHBOURS, good.size)
            near = cKDTree(feat[good]).query(feat[bad], k=k)[1].reshape(len(bad), k)
            for col in range(k):
                todo = ~aimed.ok[bad]
                if not np.any(todo):
                    return
                added = merge(bad[todo], aim(bad[todo], aimed.unknowns[good[near[todo, col]]]))
                if added < RETRY_MIN_GAIN * int(todo.sum()):
                    return

    aimed = aim(np.arange(n), guess)
    rounds = RETRY_ROUNDS if retry_rounds is None else retry_rounds
    continuation(rounds)
    m = SCAN if scan is None else scan
    bad = np.nonzero(~aimed.ok)[0]
    if m and bad.size:
        g = _scan_guess(lens, half, [arg[bad] for arg in args], m)
        found = np.all(np.isfinite(g), axis=1)
        if np.any(found):
            merge(bad[found], aim(bad[found], g[found]))
            continuation(rounds)
    hist = aimed.history
    h = list(half.housings)
    radii = np.array([lens.surfaces[steps[k].surface].semi_diameter_mm for k in h])
    clip = hist[:, h, :2] / radii[None, :, None] if h else np.zeros((n, 0, 2))
    stop = hist[:, list(half.stop_crossings), :2]
    return GhostAimed(half, aimed, clip, stop)


def _scan_guess(lens: Lens, half: GhostHalf, args: list[np.ndarray], m: int) -> np.ndarray:
    """Newton's start for each ray (rows of ``args``: the six inputs) from a scan of its
    field point (:func:`aim_ghost`, item 2): (N, 2) unknowns of the aiming (P_o: where
    the ray crosses z = 0; P_s: its slopes leaving the stop), NaN where no scan ray
    reached the stop plane."""
    from lensfit.sample.aim import _front_plane
    from lensfit.trace.tracer import Rays, Status, trace

    field = np.column_stack([args[k] for k in (0, 1, 2, 5)])
    uniq, inv = np.unique(field, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    g = len(uniq)
    t = np.linspace(-1.0, 1.0, m)
    grid = np.stack(np.meshgrid(t, t), -1).reshape(-1, 2)  # (m^2, 2) on [-1, 1]^2
    k = len(grid)
    s = lens.stop_index
    z_stop = float(lens.vertex_z[s])
    lam = np.repeat(uniq[:, 3], k)
    if half.system == "P_o":
        # From each scene point through a grid on z = 0, started on the aiming's plane
        p = np.tile(grid * SCAN_REACH * lens.surfaces[0].semi_diameter_mm, (g, 1))
        x_o, y_o, u_o = (np.repeat(uniq[:, c], k) for c in range(3))
        w = np.column_stack([x_o, y_o, -np.sqrt(1.0 - x_o * x_o - y_o * y_o)])
        pz = np.column_stack([p, np.zeros(len(p))])
        d = u_o[:, None] * pz - w
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        front = _front_plane(lens)
        start = pz + d * (front / d[:, 2])[:, None]
        out = trace(lens, Rays(start, d, lam), list(half.steps), clip=False)
        land, unknown = out.pos[:, :2], p
    else:
        # Backwards from each sensor point through a grid on the last vertex plane,
        # along the half reversed, to the stop surface (the stop plane, or the curved
        # surface a stop on a refracting surface lies on: where the stop points are)
        last = len(lens.surfaces) - 1
        q = np.tile(grid * SCAN_REACH * lens.surfaces[last].semi_diameter_mm, (g, 1))
        sens = np.column_stack([np.repeat(uniq[:, 0], k), np.repeat(uniq[:, 1], k),
                                lens.sensor_z + np.repeat(uniq[:, 2], k)])
        d = np.column_stack([q, np.full(len(q), lens.vertex_z[last])]) - sens
        back = [Step(st.surface, not st.from_front, st.reflect) for st in half.steps[::-1]]
        if lens.surfaces[s].curvature == 0.0 and not lens.surfaces[s].aspheric:
            out = trace(lens, Rays(sens, d, lam), back, clip=False, end_z=z_stop)
        else:
            out = trace(lens, Rays(sens, d, lam), [*back, Step(s, from_front=False)],
                        clip=False)
        land = out.pos[:, :2]
        with np.errstate(divide="ignore", invalid="ignore"):
            unknown = out.dir[:, :2] / out.dir[:, 2:3]  # the same line, either way along
    ok = (out.status == Status.OK) & np.all(np.isfinite(unknown), axis=1)
    land = np.where(ok[:, None], land, np.inf).reshape(g, k, 2)
    unknown = unknown.reshape(g, k, 2)
    ap = np.column_stack([args[3], args[4]])
    dist = np.hypot(land[inv, :, 0] - ap[:, None, 0], land[inv, :, 1] - ap[:, None, 1])
    best = np.argmin(dist, axis=1)
    res = unknown[inv, best]
    res[~np.isfinite(dist[np.arange(len(inv)), best])] = np.nan
    return res


def _field(rng: np.random.Generator, domain: Domain, system: str, n: int,
           uniform_in_inverse_square: bool) -> np.ndarray:
    """n field points (x, y, third, lambda) drawn as the direct samplers draw them."""
    if system == "P_o":
        sin_xy = np.array([math.sin(math.radians(f)) for f in domain.field_xy_deg])
        dirs = _disc(rng, n, 1.0) * sin_xy
        third = rng.uniform(0.0, domain.inverse_distance_max, n)
        third[rng.random(n) < INFINITY_SHARE] = 0.0
    else:
        dirs = _disc(rng, n, domain.sensor_radius_mm)
        third = rng.uniform(domain.focus_min_mm, domain.focus_max_mm, n)
    if uniform_in_inverse_square:
        w_lo, w_hi = 1.0 / domain.wavelength_max_nm**2, 1.0 / domain.wavelength_min_nm**2
        lam = 1.0 / np.sqrt(rng.uniform(w_lo, w_hi, n))
    else:
        lam = rng.uniform(domain.wavelength_min_nm, domain.wavelength_max_nm, n)
    return np.column_stack([dirs[:, 0], dirs[:, 1], third, lam])


def _fd_scale(domain: Domain, system: str) -> float:
    return max(domain.stop_radius_mm, 1.0) if system == "P_o" else 1.0


@dataclass
class GhostSamples:
    """Exact ghost-half rays with their clip data, flat (held-out) or on a grid
    (training: ``grid`` holds the GridSamples of the four outputs)."""

    half: GhostHalf
    inputs: np.ndarray  # (N, 6) raw inputs
    group: np.ndarray  # (N,) samples sharing all but the stop point
    rays: GhostAimed  # every requested ray (ok says which exist)
    grid: GridSamples | None = None

    @property
    def requested(self) -> int:
        return len(self.inputs)

    @property
    def converged(self) -> float:
        return float(np.mean(self.rays.ok))

    def samples(self) -> Samples:
        """The rays that exist, as the direct fits take held-out data."""
        ok = self.rays.ok
        return Samples(self.half.system, self.inputs[ok], self.rays.outputs[ok],
                       self.group[ok], self.rays.vignetting[ok], len(ok),
                       {"not converged or missed": int(np.sum(~ok))})


def sample_ghost(lens: Lens, domain: Domain, half: GhostHalf, groups: int, per_group: int,
                 seed: int) -> GhostSamples:
    """Random rays of the ghost half: ``groups`` field points with ``per_group`` stop
    points each, uniform on the stop disc (held-out data)."""
    rng = np.random.default_rng(seed)
    field = _field(rng, domain, half.system, groups, False)
    gid = np.repeat(np.arange(groups), per_group)
    ap = _disc(rng, groups * per_group, domain.stop_radius_mm)
    return _aim_rows(lens, domain, half, field[gid], ap, gid)


def sample_ghost_grid(lens: Lens, domain: Domain, half: GhostHalf, groups: int, points: int,
                      seed: int) -> GhostSamples:
    """Grid rays of the ghost half as :func:`lensfit.sample.rays.sample_grid` draws them:
    ``groups`` field points (wavelengths uniform in 1/lambda^2) times one mirror-symmetric
    set of ``points`` stop points."""
    rng = np.random.default_rng(seed)
    field = _field(rng, domain, half.system, groups, True)
    ap = symmetric_disc_points(rng, points) * domain.stop_radius_mm
    gid = np.repeat(np.arange(groups), points)
    aid = np.tile(np.arange(points), groups)
    out = _aim_rows(lens, domain, half, field[gid], ap[aid], gid)
    r = out.rays
    if not np.any(r.ok):
        raise SamplingError(f"{lens.source_file or lens.name}: ghost ({half.first}, "
                            f"{half.second}): none of {len(gid)} rays exists over the domain")
    out.grid = GridSamples(half.system, field, ap, r.outputs.reshape(groups, points, 4),
                           r.ok.reshape(groups, points), r.vignetting.reshape(groups, points))
    return out


def _aim_rows(lens, domain, half, field, ap, gid) -> GhostSamples:
    rays = aim_ghost(lens, half, field[:, 0], field[:, 1], field[:, 2], ap[:, 0], ap[:, 1],
                     field[:, 3], fd_scale=_fd_scale(domain, half.system))
    inputs = np.column_stack([field[:, :3], ap, field[:, 3]])
    return GhostSamples(half, inputs, gid, rays)
