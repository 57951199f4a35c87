"""Ray-surface intersection and surface normals, vectorised over rays (float64).

Every function works in the surface's local frame: the vertex at the origin, the
optical axis along +z. ``q`` are ray origins and ``d`` unit directions, arrays of
shape (N, 3). An intersection returns the ray parameter ``t`` (mm) and a boolean
``hit``; rays that miss get ``hit = False`` and a finite placeholder ``t = 0`` so that
no NaN travels on.
"""

from __future__ import annotations

import numpy as np

from lensfit.prescription.model import Surface

# Rays may start on the surface they are traced to (t = 0); allow rounding below it.
T_MIN_MM = -1e-9
# Newton iterations for aspheres: quadratic convergence from the conic start needs a
# handful; the cap only stops rays that do not converge (they are reported as missed).
NEWTON_MAX_ITER = 50
NEWTON_TOL_MM = 1e-13


def quadric_intersect(
    surface: Surface, q: np.ndarray, d: np.ndarray, virtual: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Intersect the base quadric c(x^2 + y^2) + c(1 + k) z^2 - 2z = 0 (planes included).

    The two roots are formed without cancellation (t1 = C/s, t2 = s/A with
    s = -h - sign(h) sqrt(h^2 - AC)); the root kept is the nearest one ahead of the ray
    that lies on the sheet through the vertex (checked against the sag). With
    ``virtual`` (a ray on a stop plane at the surface's vertex, the sequential
    convention) the root may lie behind the ray: the one on the vertex sheet nearest to
    it, t of either sign.
    """
    c, k = surface.curvature, surface.conic_k
    mx, my = surface.meridian_mask
    qx, qy, qz = q[:, 0], q[:, 1], q[:, 2]
    dx, dy, dz = d[:, 0], d[:, 1], d[:, 2]
    if c == 0.0:
        # Plane z = 0
        ok = dz != 0.0
        t = np.where(ok, -qz / np.where(ok, dz, 1.0), 0.0)
        hit = ok if virtual else ok & (t >= T_MIN_MM)
        return np.where(hit, t, 0.0), hit
    a = c * (mx * dx * dx + my * dy * dy + (1.0 + k) * dz * dz)
    h = c * (mx * qx * dx + my * qy * dy + (1.0 + k) * qz * dz) - dz
    cc = c * (mx * qx * qx + my * qy * qy + (1.0 + k) * qz * qz) - 2.0 * qz
    disc = h * h - a * cc
    real = disc >= 0.0
    s = -h - np.copysign(np.sqrt(np.where(real, disc, 0.0)), h)
    s_safe = np.where(s != 0.0, s, 1.0)
    a_safe = np.where(a != 0.0, a, 1.0)
    t1 = np.where(s != 0.0, cc / s_safe, np.inf)
    t2 = np.where(a != 0.0, s / a_safe, np.inf)
    best = np.full(len(q), np.inf)
    # Keep the nearest root ahead of the ray on the sheet through the vertex: the points
    # with c (1 + k) z < 1 (the near half of a sphere or ellipsoid, the vertex sheet of
    # a hyperboloid, all of a paraboloid)
    ck = c * (1.0 + k)
    with np.errstate(invalid="ignore"):  # inf * 0 for a root at infinity: not on sheet
        for t in (t1, t2):
            on_sheet = ck * (qz + t * dz) < 1.0
            if virtual:
                valid = real & on_sheet & np.isfinite(t)
                best = np.where(valid & (np.abs(t) < np.abs(best)), t, best)
            else:
                valid = real & (t >= T_MIN_MM) & on_sheet & np.isfinite(t)
                best = np.where(valid & (t < best), t, best)
    hit = np.isfinite(best)
    return np.where(hit, best, 0.0), hit


def intersect(surface: Surface, q: np.ndarray, d: np.ndarray,
              virtual: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameter t and hit flag for any supported surface shape; ``virtual`` as in
    :func:`quadric_intersect` (t may be negative)."""
    t, hit = quadric_intersect(surface, q, d, virtual)
    if surface.shape != "asphere" or not surface.aspheric:
        return t, hit
    # Refine on the full asphere by Newton's method on f(t) = z(t) - sag(x(t), y(t)),
    # starting from the conic intersection.
    active = hit.copy()
    converged = np.zeros(len(q), dtype=bool)
    for _ in range(NEWTON_MAX_ITER):
        idx = np.nonzero(active & ~converged)[0]
        if idx.size == 0:
            break
        p = q[idx] + t[idx, None] * d[idx]
        z, zx, zy = surface.sag_and_slope(p[:, 0], p[:, 1])
        f = p[:, 2] - z
        fp = d[idx, 2] - zx * d[idx, 0] - zy * d[idx, 1]
        bad = ~np.isfinite(f) | ~np.isfinite(fp) | (fp == 0.0)
        step = np.where(bad, 0.0, f / np.where(bad, 1.0, fp))
        t[idx] -= step
        active[idx[bad]] = False
        converged[idx[~bad & (np.abs(step) <= NEWTON_TOL_MM * (1.0 + np.abs(t[idx])))]] = True
    hit = active & converged & (virtual | (t >= T_MIN_MM))
    return np.where(hit, t, 0.0), hit


def normal(surface: Surface, p: np.ndarray) -> np.ndarray:
    """Unit surface normal at local points p (pointing towards -z at the vertex)."""
    if surface.shape == "asphere" and surface.aspheric:
        _, zx, zy = surface.sag_and_slope(p[:, 0], p[:, 1])
        n = np.stack([zx, zy, -np.ones(len(p))], axis=1)
    else:
        # Gradient of the quadric c(x^2 + y^2) + c(1 + k) z^2 - 2z, halved
        c, k = surface.curvature, surface.conic_k
        mx, my = surface.meridian_mask
        n = np.stack([c * mx * p[:, 0], c * my * p[:, 1], c * (1.0 + k) * p[:, 2] - 1.0], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)
