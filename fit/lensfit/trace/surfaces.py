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
    """Intersect the base quadric c(x^2 + y^2) + c(1 + k) z^2 - 2z = 0 (planes included):
    :func:`quadric_intersect_xyz` on (N, 3) arrays."""
    return quadric_intersect_xyz(surface, *_columns(q), *_columns(d), virtual)


def quadric_intersect_xyz(
    surface: Surface, qx: np.ndarray, qy: np.ndarray, qz: np.ndarray,
    dx: np.ndarray, dy: np.ndarray, dz: np.ndarray, virtual: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Intersect the base quadric c(x^2 + y^2) + c(1 + k) z^2 - 2z = 0 (planes included),
    for origins (qx, qy, qz) and directions (dx, dy, dz), one 1-D array per component.

    The two roots are formed without cancellation (t1 = C/s, t2 = s/A with
    s = -h - sign(h) sqrt(h^2 - AC)); the root kept is the nearest one ahead of the ray
    that lies on the sheet through the vertex (checked against the sag). With
    ``virtual`` (a ray on a stop plane at the surface's vertex, the sequential
    convention) the root may lie behind the ray: the one on the vertex sheet nearest to
    it, t of either sign.
    """
    c, k = surface.curvature, surface.conic_k
    mx, my = surface.meridian_mask
    if c == 0.0:
        # Plane z = 0
        ok = dz != 0.0
        t = np.where(ok, -qz / np.where(ok, dz, 1.0), 0.0)
        hit = ok if virtual else ok & (t >= T_MIN_MM)
        return np.where(hit, t, 0.0), hit
    # The quadratic A t^2 + 2 h t + C = 0; a factor that is exactly 1.0 (the meridian
    # masks of a rotationally symmetric surface, 1 + k of a sphere) is left out, which
    # leaves every result bit for bit as it was
    a: float | np.ndarray = c  # a sphere: c |d|^2, and the directions are unit
    if k != 0.0 or mx != 1.0 or my != 1.0:
        a = _quadric_form(mx, my, 1.0 + k, dx, dx, dy, dy, dz, dz)
        a *= c
    h = _quadric_form(mx, my, 1.0 + k, qx, dx, qy, dy, qz, dz)
    h *= c
    h -= dz
    cc = _quadric_form(mx, my, 1.0 + k, qx, qx, qy, qy, qz, qz)
    cc *= c
    cc -= 2.0 * qz
    # Roots without cancellation; where the discriminant is negative (no real root), or
    # s or A is 0 (a root at infinity), they come out NaN or infinite and are not kept
    with np.errstate(invalid="ignore", divide="ignore"):
        disc = h * h - a * cc
        s = np.sqrt(disc)
        np.copysign(s, h, out=s)
        s += h
        np.negative(s, out=s)
        t1 = cc / s
        t2 = s / a
        # Keep the nearest root ahead of the ray on the sheet through the vertex: the
        # points with c (1 + k) z < 1 (the near half of a sphere or ellipsoid, the vertex
        # sheet of a hyperboloid, all of a paraboloid); inf * 0 is NaN: not on the sheet
        ck = c * (1.0 + k)
        v1, v2 = (_root_ok(t, qz, dz, ck, virtual) for t in (t1, t2))
        if virtual:  # t of either sign: the root nearer to the ray
            v2 &= ~v1 | (np.abs(t2) < np.abs(t1))
        else:
            v2 &= ~v1 | (t2 < t1)
    hit = v1 | v2
    t = np.where(v2, t2, np.where(v1, t1, 0.0))
    return t, hit


def _quadric_form(mx: float, my: float, mz: float, ux: np.ndarray, vx: np.ndarray,
                  uy: np.ndarray, vy: np.ndarray, uz: np.ndarray,
                  vz: np.ndarray) -> np.ndarray:
    """mx ux vx + my uy vy + mz uz vz, summed and rounded in that order; a factor 1.0
    is left out and a term with factor 0.0 too (so bit for bit the same)."""
    out = _term(mx, ux, vx)
    if my != 0.0:
        out += _term(my, uy, vy)
    out += _term(mz, uz, vz)
    return out


def _term(m: float, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(m u) v, or u v for m = 1 (the same bits); zeros for m = 0."""
    if m == 1.0:
        return u * v
    out = m * u
    out *= v
    return out


def _root_ok(t: np.ndarray, qz: np.ndarray, dz: np.ndarray, ck: float,
             virtual: bool) -> np.ndarray:
    """Root t is finite, on the vertex sheet (c (1 + k) z < 1) and, unless ``virtual``,
    not behind the ray (NaN fails every test)."""
    z = t * dz
    z += qz
    z *= ck
    ok = z < 1.0
    if virtual:
        ok &= np.isfinite(t)
    else:
        ok &= t >= T_MIN_MM
        ok &= t < np.inf
    return ok


def _columns(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The x, y, z columns of an (N, 3) array, each contiguous."""
    a = np.asarray(a, dtype=np.float64)
    return (np.ascontiguousarray(a[:, 0]), np.ascontiguousarray(a[:, 1]),
            np.ascontiguousarray(a[:, 2]))


def intersect(surface: Surface, q: np.ndarray, d: np.ndarray,
              virtual: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameter t and hit flag for any supported surface shape; ``virtual`` as in
    :func:`quadric_intersect_xyz` (t may be negative). (N, 3) arrays; see
    :func:`intersect_xyz`."""
    return intersect_xyz(surface, *_columns(q), *_columns(d), virtual)


def intersect_xyz(surface: Surface, qx: np.ndarray, qy: np.ndarray, qz: np.ndarray,
                  dx: np.ndarray, dy: np.ndarray, dz: np.ndarray,
                  virtual: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameter t and hit flag for any supported surface shape, one 1-D array per
    component of the origins and directions; ``virtual`` as in
    :func:`quadric_intersect_xyz` (t may be negative)."""
    t, hit = quadric_intersect_xyz(surface, qx, qy, qz, dx, dy, dz, virtual)
    if surface.shape != "asphere" or not surface.aspheric:
        return t, hit
    # Refine on the full asphere by Newton's method on f(t) = z(t) - sag(x(t), y(t)),
    # starting from the conic intersection.
    active = hit.copy()
    converged = np.zeros(len(qx), dtype=bool)
    for _ in range(NEWTON_MAX_ITER):
        idx = np.nonzero(active & ~converged)[0]
        if idx.size == 0:
            break
        ti, ex, ey, ez = t[idx], dx[idx], dy[idx], dz[idx]
        z, zx, zy = surface.sag_and_slope(qx[idx] + ti * ex, qy[idx] + ti * ey)
        f = (qz[idx] + ti * ez) - z
        fp = ez - zx * ex - zy * ey
        bad = ~np.isfinite(f) | ~np.isfinite(fp) | (fp == 0.0)
        step = np.where(bad, 0.0, f / np.where(bad, 1.0, fp))
        t[idx] -= step
        active[idx[bad]] = False
        converged[idx[~bad & (np.abs(step) <= NEWTON_TOL_MM * (1.0 + np.abs(t[idx])))]] = True
    hit = active & converged & (virtual | (t >= T_MIN_MM))
    return np.where(hit, t, 0.0), hit


def normal(surface: Surface, p: np.ndarray) -> np.ndarray:
    """Unit surface normal at local points p (N, 3) (pointing towards -z at the vertex)."""
    return np.stack(normal_xyz(surface, *_columns(p)), axis=1)


def normal_xyz(surface: Surface, px: np.ndarray, py: np.ndarray,
               pz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit surface normal (x, y, z components) at local points (px, py, pz), pointing
    towards -z at the vertex."""
    if surface.shape == "asphere" and surface.aspheric:
        _, nx, ny = surface.sag_and_slope(px, py)
        nz = np.full(len(px), -1.0)
    else:
        # Gradient of the quadric c(x^2 + y^2) + c(1 + k) z^2 - 2z, halved
        c, k = surface.curvature, surface.conic_k
        mx, my = surface.meridian_mask
        nx, ny = (c * mx) * px, (c * my) * py
        nz = (c * (1.0 + k)) * pz
        nz -= 1.0
        if k == 0.0:
            # On a sphere or cylinder |n|^2 = 1 + c F(p), F the quadric: unit already,
            # to rounding (c F is of the order of 1e-16)
            return nx, ny, nz
    # Divided by its length
    norm = nx * nx
    norm += ny * ny
    norm += nz * nz
    np.sqrt(norm, out=norm)
    return nx / norm, ny / norm, nz / norm
