"""Training and held-out rays for P_o and P_s, found by aiming real rays at stop points.

Each sample joins a scene point (or a sensor point) to a point on the stop. The ray that
does so is found by Newton's method on its start (P_o: where it crosses the plane of the
first vertex; P_s: its slope at the stop), with a finite-difference Jacobian, starting
from the paraxial solution. Rays are traced without clipping so that the polynomials are
smooth across the housing edges; whether the exact ray is blocked is recorded per sample
(``vignetting``: the largest radius over housing radius along the half path; > 1 means
blocked), and the outputs x_o, y_o (x_i, y_i) let a renderer clip at the outer (inner)
pupil. Rays that miss a surface, reflect totally, or do not converge are dropped and
counted.

A stop point (x_a, y_a) is the x, y where the ray meets the stop surface: the stop plane,
or, for a stop on a refracting surface, that curved surface itself (the loader's stop
surface coincides with it, lensdb/README.md "The aperture stop"). So P_o ends on, and
P_s starts from, the point (x_a, y_a, z_stop + sag(x_a, y_a)), and the disc
x_a^2 + y_a^2 <= r^2 is the aperture clipped on the surface as design programs clip it.

Samples come in groups that share everything but the stop point (one scene point or
sensor point and one wavelength), so that the part of the OPL that is constant per pixel
can be removed when errors are measured.

OPL of P_o is relative: phi_o = OPL(scene point -> stop) - d_O, computed without
cancellation as (u|S|^2 - 2 S.w) / (|u S - w| + 1) for the start point S of the traced
ray and the unit direction w to the scene point; it has a finite limit at u_O = 0.

The aiming itself is :func:`aim_object_side` and :func:`aim_sensor_side`: the exact value
of P_o and P_s at any inputs, one ray per row. The samplers draw inputs and call them;
so does :mod:`lensfit.psf`, so the fitted data and the exact reference cannot drift apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lensfit.paraxial.paraxial import D_LINE_NM, system_matrix
from lensfit.prescription.model import Lens
from lensfit.sample.domain import Domain
from lensfit.trace.tracer import Rays, Status, Step, trace

NEWTON_MAX_ITER = 30
NEWTON_TOL_MM = 1e-9  # stop-point miss that counts as converged (1 pm)
FD_STEP = 1e-6  # relative finite-difference step for the Jacobian
INFINITY_SHARE = 0.2  # share of P_o groups placed exactly at infinity (u_O = 0)

OUTPUTS_O = (("x_o", "mm"), ("y_o", "mm"), ("tau_o", "1"), ("phi_o", "mm"))
OUTPUTS_S = (("x_i", "mm"), ("y_i", "mm"), ("tau_i", "1"), ("phi_i", "mm"))


class SamplingError(ValueError):
    """No usable rays, or a domain the lens cannot serve."""


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


@dataclass
class Aimed:
    """Exactly traced rays, one per row of the inputs, each joining its scene point
    (P_o) or sensor point (P_s) to its stop point."""

    outputs: np.ndarray  # (N, 4): OUTPUTS_O or OUTPUTS_S; NaN where not ok
    vignetting: np.ndarray  # (N,) max radius / housing radius along the half path; NaN
    ok: np.ndarray  # (N,) converged, no miss or TIR, finite outputs
    unknowns: np.ndarray  # (N, 2) the solution: P_o where the ray crosses z = 0 (mm);
    #                       P_s its slopes dx/dz, dy/dz leaving the stop
    pos: np.ndarray  # (N, 3) where the ray ends: P_o on the stop, P_s on the sensor (mm)
    dir: np.ndarray  # (N, 3) its unit direction there
    # (N, steps, 3) where the ray is after each step of its path (mm), when asked for
    # (``history=True`` of the aiming functions); NaN where not ok
    history: np.ndarray | None = None

    @classmethod
    def empty(cls, n: int, steps: int | None = None) -> Aimed:
        nan = np.full((n, 3), np.nan)
        hist = None if steps is None else np.full((n, steps, 3), np.nan)
        return cls(np.full((n, 4), np.nan), np.full(n, np.nan), np.zeros(n, dtype=bool),
                   np.full((n, 2), np.nan), nan, nan.copy(), hist)


def _converge(aimed: Aimed, residual, final, p0: np.ndarray, scale: float,
              warm: bool, features: np.ndarray | None = None) -> Aimed:
    """Newton on every row from ``p0``, then the final trace of the converged rows into
    ``aimed``. ``final(idx, p)`` returns (miss (n, 2), valid, outputs, vignetting, pos,
    dir, history (n, steps, 3) or None). With ``warm`` (a first guess that may already
    be the solution) the final trace is tried at ``p0`` first, with the acceptance
    Newton's rays get in the final trace (a miss of at most 10 NEWTON_TOL_MM), and
    Newton runs only for the rows it does not settle."""
    todo = np.arange(len(p0))

    def keep(idx, q, r, valid, outputs, vig, pos, dirs, hist):
        good = (valid & (np.hypot(r[:, 0], r[:, 1]) <= 10 * NEWTON_TOL_MM)
                & np.all(np.isfinite(outputs), 1))
        i = idx[good]
        aimed.outputs[i], aimed.vignetting[i], aimed.ok[i] = outputs[good], vig[good], True
        aimed.unknowns[i], aimed.pos[i], aimed.dir[i] = q[good], pos[good], dirs[good]
        if aimed.history is not None:
            aimed.history[i] = hist[good]
        return good

    if warm:
        todo = todo[~keep(todo, p0, *final(todo, p0))]
    if todo.size:
        q, ok = _newton(lambda i, x: residual(todo[i], x), p0[todo], scale)
        idx = todo[ok]
        keep(idx, q[ok], *final(idx, q[ok]))
    # Rays Newton did not reach from the first guess: again from the solution of the
    # nearest ray that converged (nearest in ``features``). Measured on the anamorphic
    # lens 2004 at f/2: 95% of its object-side failures converge so, most of them rays
    # that pass the lens
    bad, good = np.nonzero(~aimed.ok)[0], np.nonzero(aimed.ok)[0]
    if features is not None and bad.size and good.size:
        from scipy.spatial import cKDTree

        _, near = cKDTree(features[good]).query(features[bad])
        q, ok = _newton(lambda i, x: residual(bad[i], x), aimed.unknowns[good[near]], scale)
        idx = bad[ok]
        keep(idx, q[ok], *final(idx, q[ok]))
    return aimed


def _features(aperture: np.ndarray, *others: np.ndarray) -> np.ndarray:
    """Where rays are near each other, for the retry of :func:`_converge`: the stop point
    (mm), and the other inputs scaled so far apart that rays of the same scene or
    sensor point and wavelength are always nearer to each other than to any other."""
    return np.column_stack([aperture] + [1e6 * np.asarray(o) for o in others])


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


# A Jacobian is kept from one step to the next while each step it gives cuts the miss at
# least this much (the chord method: one trace a step instead of three; near the solution
# a ray's miss is nearly linear in its start, and the kept Jacobian cuts it by 1e-2 to
# 1e-4 a step); a step that cuts less gets a fresh finite-difference Jacobian
CHORD_GAIN = 0.25


# Broyden's update of the kept Jacobian after each chord step. Measured on 0007 (P_s,
# 64k rays): the rays converge in 9 Newton steps instead of 17, the same rays
BROYDEN = True


def _broyden(jac: np.ndarray, rows: np.ndarray, dp: np.ndarray, dr: np.ndarray) -> None:
    """Broyden's rank-one update of ``jac[rows]`` (n, 2, 2) in place, after steps ``dp``
    (n, 2) that changed the residual by ``dr``: J += (dr - J dp) dp^T / |dp|^2."""
    j = jac[rows]
    miss = dr - np.einsum("nij,nj->ni", j, dp)
    jac[rows] = j + miss[:, :, None] * (dp / np.einsum("ni,ni->n", dp, dp)[:, None])[:, None, :]


def _newton(residual, p0: np.ndarray, scale: float):
    """Solve residual(p) = 0 for each row of p (N, 2), vectorised; returns (p, ok).

    ``residual`` returns (r (N, 2), valid (N,)) for any subset of rows it is given, via
    an index array. Newton's method with finite-difference Jacobians, each kept while
    its steps cut the miss CHORD_GAIN-fold (the chord method, the kept Jacobian
    corrected by Broyden's update after each step); a step with a fresh Jacobian that
    increases the miss is halved (up to 8 times)."""
    p = p0.copy()
    n = len(p)
    done = np.zeros(n, dtype=bool)
    failed = np.zeros(n, dtype=bool)
    h = FD_STEP * scale
    idx = np.arange(n)
    r, valid = residual(idx, p)
    failed |= ~valid
    jac = np.zeros((n, 2, 2))
    stale = np.ones(n, dtype=bool)  # no Jacobian yet, or one to be computed afresh
    for _ in range(NEWTON_MAX_ITER):
        act = np.nonzero(~done & ~failed)[0]
        if act.size == 0:
            break
        miss = np.hypot(r[act, 0], r[act, 1])
        conv = miss <= NEWTON_TOL_MM
        done[act[conv]] = True
        act = act[~conv]
        if act.size == 0:
            break
        # Finite-difference Jacobians d r / d p where there is none to keep
        fresh = np.zeros(n, dtype=bool)
        need = act[stale[act]]
        if need.size:
            rx, vx = residual(need, p[need] + [h, 0.0])
            ry, vy = residual(need, p[need] + [0.0, h])
            jac[need] = np.stack([(rx - r[need]) / h, (ry - r[need]) / h], axis=2)
            fresh[need], stale[need] = vx & vy, False
            failed[need[~(vx & vy)]] = True
        # Determinants of the active rows' Jacobians; a singular one fails its ray
        j = jac[act]
        d = j[:, 0, 0] * j[:, 1, 1] - j[:, 0, 1] * j[:, 1, 0]
        singular = ~((np.abs(d) > 0) & np.isfinite(d))
        failed[act[singular]] = True
        regular = ~failed[act]
        act, j, d = act[regular], j[regular], d[regular]
        ra = r[act]
        miss = np.hypot(ra[:, 0], ra[:, 1])
        step = np.stack([
            (j[:, 1, 1] * ra[:, 0] - j[:, 0, 1] * ra[:, 1]) / d,
            (-j[:, 1, 0] * ra[:, 0] + j[:, 0, 0] * ra[:, 1]) / d,
        ], axis=1)
        # The full step; kept with its Jacobian when it cuts the miss CHORD_GAIN-fold
        trial = p[act] - step
        rt, vt = residual(act, trial)
        mt = np.hypot(rt[:, 0], rt[:, 1])
        quick = vt & (mt <= CHORD_GAIN * miss)
        # Broyden's update of the kept Jacobian from the step it gave (no trace: the
        # secant condition J dp = dr along dp), so that it follows the ray as it
        # converges and the steps cut the miss ever faster
        if BROYDEN:
            q = act[quick]
            _broyden(jac, q, -step[quick], rt[quick] - r[q])
        p[act[quick]], r[act[quick]] = trial[quick], rt[quick]
        # A kept Jacobian whose step cut less: a fresh one next time, from where it is
        slow = ~quick & ~fresh[act]
        stale[act[slow]] = True
        # A fresh Jacobian whose step cut less: damped, accepted if it reduces the miss
        # at all (halved up to 8 times), and a fresh Jacobian after it
        pend = np.nonzero(~quick & fresh[act])[0]
        stale[act[pend]] = True
        lam = np.ones(len(act))
        better = vt[pend] & (mt[pend] < miss[pend])
        sel = pend[better]
        p[act[sel]], r[act[sel]] = trial[sel], rt[sel]
        pend = pend[~better]
        for _ in range(8):
            if pend.size == 0:
                break
            lam[pend] *= 0.5
            trial_p = p[act[pend]] - lam[pend, None] * step[pend]
            rt_p, vt_p = residual(act[pend], trial_p)
            better = vt_p & (np.hypot(rt_p[:, 0], rt_p[:, 1]) < miss[pend])
            sel = pend[better]
            p[act[sel]], r[act[sel]] = trial_p[better], rt_p[better]
            pend = pend[~better]
        failed[act[pend]] = True
    failed |= ~done
    return p, ~failed


def _vignetting(lens: Lens, history: list[np.ndarray], path: list[Step],
                n: int) -> np.ndarray:
    """Largest radius / housing radius over the surfaces of the half path (not the stop);
    0 for the n rays of a half path without surfaces (the stop is the last surface)."""
    v = np.zeros(n)
    for pos, step in zip(history, path, strict=True):
        s = lens.surfaces[step.surface]
        if s.stop:
            continue
        v = np.maximum(v, np.hypot(pos[:, 0], pos[:, 1]) / s.semi_diameter_mm)
    return v


def _front_plane(lens: Lens) -> float:
    """z of the plane P_o rays start on: 1 mm in front of all the lens puts before the stop."""
    s = lens.stop_index
    return min(0.0, float(np.min(lens.vertex_z[: s + 1]))) - _front_bulge(lens) - 1.0


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


def aim_object_side(lens: Lens, x_O: np.ndarray, y_O: np.ndarray, u_O: np.ndarray,
                    x_a: np.ndarray, y_a: np.ndarray, wavelength_nm: np.ndarray, *,
                    fd_scale_mm: float | None = None,
                    guess: np.ndarray | None = None, path: list[Step] | None = None,
                    history: bool = False) -> Aimed:
    """P_o exactly, one row per ray: the ray from the scene point (direction cosines x_O,
    y_O from the first vertex, inverse distance u_O in 1/mm, 0 = infinity) through the
    stop point (x_a, y_a) (mm) at ``wavelength_nm``. Inputs broadcast to one length.

    Outputs x_o, y_o (on the first surface), tau_o (Fresnel power transmittance, with
    coatings), phi_o = OPL(scene point -> stop point) - d_O (mm). Rays that miss, reflect
    totally or do not converge have ``ok`` False. ``fd_scale_mm`` sets Newton's
    finite-difference step (default: the largest |stop point|, at least 1 mm); ``guess``
    (N, 2) where each ray crosses z = 0, NaN rows for the paraxial guess.

    ``path`` (default: every surface up to the stop) is the list of steps the ray takes
    from the start plane to the stop plane, e.g. a ghost's half that reflects twice
    before it reaches the stop (:mod:`lensfit.ghosts.sample`); the start plane, the
    paraxial guess and the retry are those of the direct path. With ``history``,
    ``Aimed.history`` holds the ray's position after each step."""
    s = lens.stop_index  # 0: P_o is the straight line to the stop plane, traced as any
    xo, yo, ug, xa, ya, lam = (np.array(v, dtype=np.float64) for v in np.broadcast_arrays(
        x_O, y_O, u_O, x_a, y_a, wavelength_nm))
    xo, yo, ug, xa, ya, lam = (v.reshape(-1) for v in (xo, yo, ug, xa, ya, lam))
    n = len(xo)
    path = [Step(k) for k in range(s + 1)] if path is None else list(path)
    aimed = Aimed.empty(n, len(path) if history else None)
    if n == 0:
        return aimed
    ap = np.stack([xa, ya], axis=1)
    w = np.stack([xo, yo, -np.sqrt(1.0 - xo * xo - yo * yo)], axis=1)  # towards the scene
    if not np.all(np.isfinite(w)):
        raise ValueError("P_o: direction cosines (x_O, y_O) must satisfy x_O^2 + y_O^2 <= 1")

    # Start every ray on a plane in front of everything the lens puts before the stop
    front = _front_plane(lens)
    with np.errstate(divide="ignore"):
        scene_z = np.where(ug > 0, w[:, 2] / np.where(ug > 0, ug, 1.0), -np.inf)
    if np.any(ug < 0) or not np.all(scene_z < front):
        bad = int(np.argmax((ug < 0) | ~(scene_z < front)))
        raise SamplingError(
            f"{lens.source_file or lens.name}: P_o: u_O = {ug[bad]:g} 1/mm puts the scene "
            f"point at z = {scene_z[bad]:g} mm, not in front of the lens (scene points "
            f"must lie before z = {front:g} mm)")

    def launch(idx, p):
        """Ray from the scene point through (p, 0), started on the plane z = front."""
        # Direction from the scene point to (p, 0): u (p, 0) - w, made unit
        wi = w[idx]
        d = np.empty((len(p), 3))
        d[:, :2] = ug[idx, None] * p - wi[:, :2]
        d[:, 2] = -wi[:, 2]
        d /= np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]
        start = d * (front / d[:, 2])[:, None]  # back from z = 0 to z = front
        start[:, :2] += p
        return start, d

    def residual(idx, p, hist=None, fresnel=False):
        start, d = launch(idx, p)
        rays = Rays(start, d, lam[idx])
        out = trace(lens, rays, path, clip=False, fresnel_loss=fresnel, history=hist)
        ok = out.status == Status.OK
        return out.pos[:, :2] - ap[idx], ok, out, start

    def final(idx, p):
        """The converged rays again, with Fresnel loss and the history."""
        hist: list[np.ndarray] = []
        r, valid, out, start = residual(idx, p, hist, fresnel=True)
        vig = _vignetting(lens, hist, path, len(idx))
        # OPL relative to d_O, without cancellation
        ui = ug[idx, None]
        wi = w[idx]
        rel = (ui[:, 0] * np.einsum("ij,ij->i", start, start)
               - 2 * np.einsum("ij,ij->i", start, wi))
        rel /= np.linalg.norm(ui * start - wi, axis=1) + 1.0
        phi = out.opl_mm + rel
        outputs = np.stack([hist[0][:, 0], hist[0][:, 1], out.transmittance, phi], axis=1)
        steps = np.stack(hist, axis=1) if history else None
        return r, valid, outputs, vig, out.pos, out.dir, steps

    # Paraxial first guess: the ray through the image of the stop point in the
    # entrance pupil (per meridian, at the d line)
    p0 = np.empty((n, 2))
    for j, mer in enumerate(("x", "y")):
        (fa, fb), _ = system_matrix(lens, 0, s - 1, mer, D_LINE_NM, end_gap=True)
        # entrance pupil: z_E = fb/fa from the first vertex, height a / fa
        z_e = fb / fa
        e = ap[:, j] / fa
        # The ray from the scene point to (e, z_E), where does it cross z = 0?
        dj = ug * e - w[:, j]
        dz = ug * z_e - w[:, 2]
        p0[:, j] = e - dj * z_e / dz
    warm = guess is not None
    if warm:
        g = np.asarray(guess, dtype=np.float64).reshape(n, 2)
        p0 = np.where(np.all(np.isfinite(g), axis=1)[:, None], g, p0)
    scale = fd_scale_mm if fd_scale_mm is not None else max(float(np.max(np.abs(ap))), 1.0)
    return _converge(aimed, lambda i, q: residual(i, q)[:2], final, p0, scale, warm,
                     _features(ap, xo, yo, ug, lam))


def _front_bulge(lens: Lens) -> float:
    """How far any surface before the stop reaches in front of z = 0 (mm, >= 0)."""
    reach = 0.0
    s = lens.stop_index
    # With the stop at zero distance in front of a surface, that surface too (it may
    # bulge in front)
    last = s + 1 if s + 1 < len(lens.surfaces) and lens.virtual_gap(s + 1) else s
    for k in range(last + 1):
        surf = lens.surfaces[k]
        h = np.linspace(0.0, surf.semi_diameter_mm, 33)
        z = lens.vertex_z[k] + np.nan_to_num(surf.sag(h, np.zeros_like(h)))
        reach = max(reach, -float(np.min(z)))
    return reach


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


def aim_sensor_side(lens: Lens, x_S: np.ndarray, y_S: np.ndarray, z_S: np.ndarray,
                    x_a: np.ndarray, y_a: np.ndarray, wavelength_nm: np.ndarray, *,
                    fd_scale: float = 1.0, guess: np.ndarray | None = None,
                    vignetting: bool = True, path: list[Step] | None = None,
                    history: bool = False) -> Aimed:
    """P_s exactly, one row per ray: the ray from the stop point (x_a, y_a) (mm) to the
    sensor point (x_S, y_S) (mm) of the sensor shifted by z_S (mm, + away from the lens)
    at ``wavelength_nm``. Inputs broadcast to one length.

    Outputs x_i, y_i (on the last surface), tau_i (Fresnel power transmittance, with
    coatings), phi_i = OPL(stop point -> sensor point) (mm). Rays that miss, reflect
    totally or do not converge have ``ok`` False. ``fd_scale`` sets Newton's
    finite-difference step in slope; ``guess`` (N, 2) the slopes dx/dz, dy/dz leaving
    the stop, NaN rows for the paraxial guess. Without ``vignetting`` the rays' history
    is not kept (faster) and ``Aimed.vignetting`` is NaN.

    ``path`` (default: every surface after the stop) is the list of steps the ray takes
    from the stop plane to the last surface, e.g. a ghost's half that reflects twice
    behind the stop (:mod:`lensfit.ghosts.sample`); the paraxial guess and the retry are
    those of the direct path. With ``history`` (which implies ``vignetting``),
    ``Aimed.history`` holds the ray's position after each step."""
    s = lens.stop_index
    n_surf = len(lens.surfaces)
    z_stop = float(lens.vertex_z[s])
    xs, ys, zs, xa, ya, lam = (np.array(v, dtype=np.float64).reshape(-1)
                               for v in np.broadcast_arrays(x_S, y_S, z_S, x_a, y_a,
                                                            wavelength_nm))
    n = len(xs)
    path = [Step(k) for k in range(s + 1, n_surf)] if path is None else list(path)
    vignetting = vignetting or history
    aimed = Aimed.empty(n, len(path) if history else None)
    if n == 0:
        return aimed
    ap = np.stack([xa, ya], axis=1)
    sens = np.stack([xs, ys], axis=1)
    z_sensor = lens.sensor_z + zs
    if not np.all(z_sensor > lens.vertex_z[-1]):
        bad = float(zs[np.argmin(z_sensor)])
        raise SamplingError(
            f"{lens.source_file or lens.name}: z_S = {bad:g} mm puts the sensor in front "
            f"of the last surface (it is {lens.sensor_z - lens.vertex_z[-1]:g} mm behind it)")

    # The stop point on the stop surface: its vertex plane for a stop plane, the curved
    # surface itself for a stop on a refracting surface (lensdb/README.md, The aperture stop)
    z_start = z_stop + _stop_sag(lens, ap)
    if not np.all(np.isfinite(z_start)):
        bad = int(np.argmin(np.isfinite(z_start)))
        raise SamplingError(
            f"{lens.source_file or lens.name}: stop point ({xa[bad]:g}, {ya[bad]:g}) mm is "
            "beyond the edge of the stop surface")

    def shoot(idx, slope, hist=None, fresnel=False):
        """Ray from the stop point with slopes (dx/dz, dy/dz), to the sensor plane."""
        start = np.concatenate([ap[idx], z_start[idx, None]], axis=1)
        d = np.concatenate([slope, np.ones((len(idx), 1))], axis=1)
        out = trace(lens, Rays(start, d, lam[idx]), path, clip=False, fresnel_loss=fresnel,
                    history=hist)
        ok = (out.status == Status.OK) & (out.dir[:, 2] > 0)
        t = (z_sensor[idx] - out.pos[:, 2]) / np.where(ok, out.dir[:, 2], 1.0)
        end = out.pos + t[:, None] * out.dir
        out.opl_mm = out.opl_mm + t  # behind the last surface: air
        miss = end[:, :2] - sens[idx]
        return np.where(ok[:, None], miss, 0.0), ok, out, end

    def final(idx, q):
        """The converged rays again, with Fresnel loss and the history."""
        hist: list[np.ndarray] | None = [] if vignetting else None
        r, valid, out, end = shoot(idx, q, hist, fresnel=True)
        if hist:
            vig, last_pos = _vignetting(lens, hist, path, len(idx)), hist[-1]
        elif hist is not None:  # the stop is the last surface: x_i, y_i are on it
            vig, last_pos = np.zeros(len(idx)), out.pos
        else:  # the trace ends on the last surface: the same positions
            vig, last_pos = np.full(len(idx), np.nan), out.pos
        outputs = np.stack([last_pos[:, 0], last_pos[:, 1], out.transmittance, out.opl_mm],
                           axis=1)
        steps = np.stack(hist, axis=1) if history and hist else (
            np.zeros((len(idx), 0, 3)) if history else None)
        return r, valid, outputs, vig, end, out.dir, steps

    # Paraxial first guess from the transfer matrix stop -> sensor, per meridian; it acts
    # on (y, n u), n the index at the stop (the stop may lie in glass)
    n_stop = float(lens.surfaces[s].medium.n(D_LINE_NM))
    q0 = np.empty((n, 2))
    for j, mer in enumerate(("x", "y")):
        m = system_matrix(lens, s + 1, n_surf - 1, mer, D_LINE_NM)
        if s < n_surf - 1:  # else the stop is the last surface: its gap is `last` below
            gap = np.array([[1.0, lens.surfaces[s].thickness_mm / n_stop], [0.0, 1.0]])
            m = m @ gap
        last = z_sensor - lens.vertex_z[-1]
        a = m[0, 0] + last * m[1, 0]
        b = m[0, 1] + last * m[1, 1]
        target = sens[:, j]
        with np.errstate(divide="ignore", invalid="ignore"):
            q0[:, j] = np.where(b != 0, (target - a * ap[:, j]) / b, 0.0) / n_stop
    q0 = np.nan_to_num(q0)
    warm = guess is not None
    if warm:
        g = np.asarray(guess, dtype=np.float64).reshape(n, 2)
        q0 = np.where(np.all(np.isfinite(g), axis=1)[:, None], g, q0)
    return _converge(aimed, lambda i, q: shoot(i, q)[:2], final, q0, fd_scale, warm,
                     _features(ap, xs, ys, zs, lam))


def _stop_sag(lens: Lens, ap: np.ndarray) -> np.ndarray:
    """z of the stop surface relative to its vertex at stop points ``ap`` (N, 2) (mm): 0
    on a stop plane, the sag of the refracting surface the stop lies on otherwise."""
    stop = lens.surfaces[lens.stop_index]
    if stop.curvature == 0.0 and not stop.aspheric:
        return np.zeros(len(ap))
    return np.asarray(stop.sag(ap[:, 0], ap[:, 1]), dtype=np.float64)


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
    from lensfit.fitting.options import TRAIN_VIGNETTING

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
