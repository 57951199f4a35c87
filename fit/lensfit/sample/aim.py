"""Exact rays for P_o and P_s, found by aiming real rays at stop points: the exact value
of P_o and P_s at any inputs, one ray per row (:func:`aim_object_side`,
:func:`aim_sensor_side`).

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

OPL of P_o is relative: phi_o = OPL(scene point -> stop) - d_O, computed without
cancellation as (u|S|^2 - 2 S.w) / (|u S - w| + 1) for the start point S of the traced
ray and the unit direction w to the scene point; it has a finite limit at u_O = 0.

The samplers of :mod:`lensfit.sample.rays` draw inputs and call these functions; so
does :mod:`lensfit.psf.psf`, so the fitted data and the exact reference cannot drift
apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lensfit.paraxial.paraxial import D_LINE_NM, system_matrix
from lensfit.prescription.model import Lens
from lensfit.trace.tracer import Rays, Status, Step, trace

NEWTON_MAX_ITER = 30
NEWTON_TOL_MM = 1e-9  # stop-point miss that counts as converged (1 pm)
FD_STEP = 1e-6  # relative finite-difference step for the Jacobian


class SamplingError(ValueError):
    """No usable rays, or a domain the lens cannot serve."""


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


# Fractions of the first guess tried, in turn, where the first guess's own ray fails
START_SHRINK = (0.875, 0.75, 0.625, 0.5)


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
    # A start whose ray fails (misses a surface, or TIR) is moved towards the origin of
    # the unknowns (P_o: the ray through the first vertex; P_s: the ray leaving the stop
    # parallel to the axis) until its ray passes: the paraxial guess overshoots where
    # the real pupil is far from the paraxial one (lens 0014, a fisheye: the chief ray's
    # paraxial start at 55-64 degrees misses surface 7; at 0.75 of it Newton converges)
    for f in START_SHRINK:
        bad = np.nonzero(~valid)[0]
        if bad.size == 0:
            break
        p[bad] = f * p0[bad]
        r[bad], valid[bad] = residual(bad, p[bad])
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


def aim_object_side(lens: Lens, x_O: np.ndarray, y_O: np.ndarray, u_O: np.ndarray,
                    x_a: np.ndarray, y_a: np.ndarray, wavelength_nm: np.ndarray, *,
                    fd_scale_mm: float | None = None,
                    guess: np.ndarray | None = None, path: list[Step] | None = None,
                    history: bool = False, outputs: bool = True) -> Aimed:
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
    before it reaches the stop (:mod:`lensfit.sample.ghost`); the start plane, the
    paraxial guess and the retry are those of the direct path. With ``history``,
    ``Aimed.history`` holds the ray's position after each step. Without ``outputs`` the
    final trace has no Fresnel loss and no history, for a caller that wants only where
    the rays go (``ok``, ``unknowns``, ``pos``, ``dir``): ``Aimed.outputs`` then hold only
    phi_o (x_o, y_o 0 and tau_o 1) and ``vignetting`` is NaN."""
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
        """The converged rays again, with Fresnel loss and the history (with
        ``outputs``)."""
        hist: list[np.ndarray] = []
        r, valid, out, start = residual(idx, p, hist if outputs or history else None,
                                        fresnel=outputs)
        if outputs or history:
            vig = _vignetting(lens, hist, path, len(idx))
        else:
            vig = np.full(len(idx), np.nan)
            hist = [np.zeros((len(idx), 3))]  # x_o, y_o: 0
        # OPL relative to d_O, without cancellation
        ui = ug[idx, None]
        wi = w[idx]
        rel = (ui[:, 0] * np.einsum("ij,ij->i", start, start)
               - 2 * np.einsum("ij,ij->i", start, wi))
        rel /= np.linalg.norm(ui * start - wi, axis=1) + 1.0
        phi = out.opl_mm + rel
        values = np.stack([hist[0][:, 0], hist[0][:, 1], out.transmittance, phi], axis=1)
        steps = np.stack(hist, axis=1) if history else None
        return r, valid, values, vig, out.pos, out.dir, steps

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
    behind the stop (:mod:`lensfit.sample.ghost`); the paraxial guess and the retry are
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
