"""Spectral float64 sequential ray tracer, vectorised over rays.

A trace follows a *path*: an ordered list of steps, each naming a surface, the side
the ray arrives from and whether it refracts or reflects there. The ordinary path runs
through every surface from scene to sensor; the reverse path from sensor to scene; a
ghost path reflects at two surfaces (``ghost_path``).

Each ray carries a status. A ray that fails (misses a surface, is totally internally
reflected, or is clipped by a housing or the stop) keeps the status and the index of
the surface where it failed, stops moving, and never produces a NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from lensfit.prescription.model import Lens
from lensfit.prescription.ranges import check_glass_ranges
from lensfit.trace import fresnel, surfaces

# Rays traced at once: arrays of this many float64 stay in a core's cache, measured
# 1.3x faster than 64k-ray arrays on the sampler's rays
TRACE_BLOCK = 8192


class Status(IntEnum):
    OK = 0
    MISSED = 1  # no intersection with the surface (or an asphere that did not converge)
    TIR = 2  # total internal reflection where the path wants refraction
    CLIPPED = 3  # outside the housing or the stop at ``Rays.surface``


@dataclass(frozen=True)
class Step:
    surface: int
    from_front: bool = True  # arriving from the scene side of the surface
    reflect: bool = False


@dataclass
class Rays:
    """A bundle of N rays. Positions in mm, unit directions, wavelengths in nm."""

    pos: np.ndarray  # (N, 3)
    dir: np.ndarray  # (N, 3), unit length
    wavelength_nm: np.ndarray  # (N,)
    opl_mm: np.ndarray = field(default=None)  # (N,) optical path length so far
    transmittance: np.ndarray = field(default=None)  # (N,) power transmittance so far
    status: np.ndarray = field(default=None)  # (N,) Status values (int8)
    surface: np.ndarray = field(default=None)  # (N,) index where status was set, or -1

    def __post_init__(self) -> None:
        self.pos = np.array(self.pos, dtype=np.float64, copy=True).reshape(-1, 3)
        n = len(self.pos)
        d = np.array(self.dir, dtype=np.float64).reshape(-1, 3)
        if d.shape != self.pos.shape:
            raise ValueError(f"Rays: {len(d)} directions for {n} positions")
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        if not (np.all(np.isfinite(self.pos)) and np.all(np.isfinite(d)) and np.all(norm > 0)):
            raise ValueError("Rays: positions and directions must be finite, directions non-zero")
        self.dir = d / norm
        self.wavelength_nm = np.broadcast_to(
            np.asarray(self.wavelength_nm, dtype=np.float64), (n,)
        ).copy()
        lam = self.wavelength_nm
        if not np.all(np.isfinite(lam) & (lam > 0)):
            raise ValueError("Rays: wavelengths must be finite and positive (nm)")
        if self.opl_mm is None:
            self.opl_mm = np.zeros(n)
        if self.transmittance is None:
            self.transmittance = np.ones(n)
        if self.status is None:
            self.status = np.zeros(n, dtype=np.int8)
        if self.surface is None:
            self.surface = np.full(n, -1, dtype=np.int16)

    def __len__(self) -> int:
        return len(self.pos)

    @property
    def ok(self) -> np.ndarray:
        return self.status == Status.OK

    def copy(self) -> Rays:
        """A copy with arrays of its own (already validated: not checked again)."""
        new = object.__new__(Rays)
        new.pos, new.dir, new.wavelength_nm = (self.pos.copy(), self.dir.copy(),
                                               self.wavelength_nm.copy())
        new.opl_mm, new.transmittance = self.opl_mm.copy(), self.transmittance.copy()
        new.status, new.surface = self.status.copy(), self.surface.copy()
        return new


def forward_path(lens: Lens) -> list[Step]:
    """Scene to sensor through every surface."""
    return [Step(k) for k in range(len(lens.surfaces))]


def backward_path(lens: Lens) -> list[Step]:
    """Sensor to scene through every surface."""
    return [Step(k, from_front=False) for k in reversed(range(len(lens.surfaces)))]


def ghost_path(lens: Lens, first: int, second: int) -> list[Step]:
    """The two-bounce ghost: reflect at ``second`` going back, then at ``first``
    (``first < second``) going forward again, then on to the sensor."""
    n = len(lens.surfaces)
    if not 0 <= first < second < n:
        raise ValueError(f"ghost needs 0 <= first < second < {n}, got {first}, {second}")
    path = [Step(k) for k in range(second)]
    path.append(Step(second, reflect=True))
    path += [Step(k, from_front=False) for k in range(second - 1, first, -1)]
    path.append(Step(first, from_front=False, reflect=True))
    path += [Step(k) for k in range(first + 1, n)]
    return path


def trace(
    lens: Lens,
    rays: Rays,
    path: list[Step] | None = None,
    *,
    stop_radius_mm: float | None = None,
    clip: bool = True,
    fresnel_loss: bool = False,
    end_z: float | None = None,
    history: list[np.ndarray] | None = None,
) -> Rays:
    """Trace ``rays`` along ``path`` (default: scene to sensor) and return new rays.

    ``stop_radius_mm`` sets the stop opening (default: the widest the housing allows).
    With ``clip`` every housing and the stop clip; without, only misses and total
    internal reflection stop a ray. With ``fresnel_loss`` the power transmittance of each
    interface (with its coating) multiplies ``Rays.transmittance``; a reflecting step
    always multiplies by the reflectance. ``end_z`` propagates the survivors to the plane
    z = end_z at the end (default: the sensor for the forward path). When ``history``
    is a list, the positions of all rays after each step are appended to it (for
    drawing; a failed ray keeps the position where it failed).
    """
    if path is None:
        path = forward_path(lens)
        if end_z is None:
            end_z = lens.sensor_z
    out = rays.copy()
    stop_r = lens.stop_radius_max_mm if stop_radius_mm is None else float(stop_radius_mm)
    if not stop_r > 0:
        raise ValueError(f"stop radius must be positive, got {stop_radius_mm}")

    _check_wavelengths(lens, out.wavelength_nm)

    # In blocks of TRACE_BLOCK rays, whose arrays stay in the processor's cache
    n = len(out)
    steps: list[np.ndarray] | None = (
        None if history is None else [np.empty((n, 3)) for _ in path])
    for lo in range(0, n, TRACE_BLOCK):
        _trace_rows(lens, out, path, slice(lo, min(n, lo + TRACE_BLOCK)), stop_r, clip,
                    fresnel_loss, steps)
    if history is not None and steps is not None:
        history.extend(steps)
    if end_z is not None:
        propagate_to_plane(out, end_z)
        if history is not None:
            history.append(out.pos.copy())
    return out


def _trace_rows(lens: Lens, out: Rays, path: list[Step], rows: slice, stop_r: float,
                clip: bool, fresnel_loss: bool, steps: list[np.ndarray] | None) -> None:
    """:func:`trace` of the rays ``rows`` of ``out`` (in place); with ``steps``, the
    positions of those rays after each step go into its rows ``rows``."""
    vz = lens.vertex_z
    # The living rays, compacted, one 1-D array per component: idx maps them back to the
    # bundle. Refractive indices are computed once per medium and kept with them
    live = _Live(out, rows)
    for j, step in enumerate(path):
        k = step.surface
        surf = lens.surfaces[k]
        if live.n == 0:
            if steps is not None:
                steps[j][rows] = out.pos[rows]
            continue
        m_front, m_back = lens.medium_before(k), lens.medium_after(k)
        n1 = live.index(m_front if step.from_front else m_back)
        n2 = live.index(m_back if step.from_front else m_front)

        # Compute t at the surface, in its local frame (across a zero gap at the stop
        # plane, the sequential convention: t may be negative, see Lens.virtual_gap)
        zk = float(vz[k])
        dx, dy, dz = live.dx, live.dy, live.dz
        qz = live.z - zk
        t, hit = surfaces.intersect_xyz(surf, live.x, live.y, qz, dx, dy, dz,
                                        lens.virtual_gap(k, step.from_front))
        px, py, pz = live.x + t * dx, live.y + t * dy, qz + t * dz

        # Clip at the housing, and at the stop opening
        keep = hit
        clipped = None
        if clip:
            limit = stop_r if surf.stop else surf.semi_diameter_mm
            clipped = hit & (px * px + py * py > limit * limit)
            keep = hit & ~clipped
        if not keep.all():
            live.fail(~hit, Status.MISSED, k)
            if clipped is not None and clipped.any():
                # A clipped ray stays where it met the (extended) surface
                live.x[clipped], live.y[clipped] = px[clipped], py[clipped]
                live.z[clipped] = pz[clipped] + zk
                live.fail(clipped, Status.CLIPPED, k)
            live.compact(keep)
            n1, n2 = live.index(m_front if step.from_front else m_back), live.index(
                m_back if step.from_front else m_front)
            px, py, pz, t = px[keep], py[keep], pz[keep], t[keep]
            dx, dy, dz = live.dx, live.dy, live.dz

        # Move the ray and add the optical path in the medium it crossed
        live.x, live.y, live.z = px, py, pz + zk
        live.opl += n1 * t

        # Refract or reflect, with the interface's power transmittance
        nx, ny, nz = surfaces.normal_xyz(surf, px, py, pz)
        cos_i = dx * nx
        cos_i += dy * ny
        cos_i += dz * nz
        np.negative(cos_i, out=cos_i)
        flip = cos_i < 0.0
        if flip.any():  # face the incoming ray
            nx, ny, nz = (np.where(flip, -v, v) for v in (nx, ny, nz))
            np.abs(cos_i, out=cos_i)
        if fresnel_loss or step.reflect:
            layers = surf.coating.layers if step.from_front else surf.coating.layers[::-1]
            r = _reflectance(n1, n2, cos_i, [live.index(ly.medium) for ly in layers],
                             [ly.thickness_nm for ly in layers], live.lam)
        if step.reflect:
            live.dx, live.dy, live.dz = _reflect_xyz(dx, dy, dz, nx, ny, nz)
            live.tr *= r
        else:
            eta = n1 / n2
            # k2 = 1 - eta^2 (1 - cos_i^2): the squared cosine of the refracted ray
            k2 = cos_i * cos_i
            np.subtract(1.0, k2, out=k2)
            k2 *= eta * eta
            np.subtract(1.0, k2, out=k2)
            tir = k2 < 0.0
            if tir.any():
                live.fail(tir, Status.TIR, k)
                ok = ~tir
                live.compact(ok)
                dx, dy, dz, nx, ny, nz = (v[ok] for v in (dx, dy, dz, nx, ny, nz))
                cos_i, eta, k2 = cos_i[ok], eta[ok], k2[ok]
                if fresnel_loss:
                    r = r[ok]
            # new d = eta d + (eta cos_i - sqrt(k2)) n, made unit
            g = eta * cos_i
            g -= np.sqrt(k2)
            ex, ey, ez = eta * dx, eta * dy, eta * dz
            ex += g * nx
            ey += g * ny
            ez += g * nz
            live.dx, live.dy, live.dz = _unit(ex, ey, ez)
            if fresnel_loss:
                live.tr *= 1.0 - r
        if steps is not None:
            live.store()
            steps[j][rows] = out.pos[rows]

    live.store()


def _unit(x: np.ndarray, y: np.ndarray,
          z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The vectors (x, y, z) divided by their lengths."""
    norm = x * x
    norm += y * y
    norm += z * z
    np.sqrt(norm, out=norm)
    x /= norm
    y /= norm
    z /= norm
    return x, y, z


def _reflect_xyz(dx: np.ndarray, dy: np.ndarray, dz: np.ndarray, nx: np.ndarray,
                 ny: np.ndarray, nz: np.ndarray) -> tuple[np.ndarray, ...]:
    """Mirror directions about unit normals: :func:`fresnel.reflect_direction` on
    components."""
    r = fresnel.reflect_direction(np.stack([dx, dy, dz], axis=1), np.stack([nx, ny, nz], axis=1))
    return (np.ascontiguousarray(r[:, 0]), np.ascontiguousarray(r[:, 1]),
            np.ascontiguousarray(r[:, 2]))


def _check_wavelengths(lens: Lens, lam: np.ndarray) -> None:
    """Refuse wavelengths outside a glass's published range (no silent extrapolation of
    dispersion formulas) unless the lens allows it: ``lensfit.prescription.ranges`` decides."""
    if lam.size == 0:
        return
    check_glass_ranges(lens, float(lam.min()), float(lam.max()))


def _reflectance(n1: np.ndarray, n2: np.ndarray, cos_i: np.ndarray,
                 layer_n: list[np.ndarray], layer_nm: list[float],
                 lam: np.ndarray) -> np.ndarray:
    """Unpolarised power reflectance of a bare or coated interface (layers' indices
    ``layer_n`` and thicknesses ``layer_nm`` from the incident side)."""
    if not layer_n:
        return fresnel.fresnel_reflectance(n1, n2, cos_i)
    return fresnel.coated_power_reflectance(n1, n2, cos_i, layer_n, layer_nm, lam)


class _Live:
    """The rays still travelling, as compact 1-D arrays (x, y, z, dx, dy, dz, ...);
    failures are written back at once. ``index`` keeps each medium's refractive index at
    the living rays' wavelengths, computed once per trace."""

    def __init__(self, rays: Rays, rows: slice) -> None:
        self.rays = rays
        self.idx = rows.start + np.nonzero(rays.status[rows] == Status.OK)[0]
        pos, d = rays.pos[self.idx], rays.dir[self.idx]
        self.x, self.y, self.z = (np.ascontiguousarray(pos[:, j]) for j in range(3))
        self.dx, self.dy, self.dz = (np.ascontiguousarray(d[:, j]) for j in range(3))
        self.lam = rays.wavelength_nm[self.idx]
        self.opl = rays.opl_mm[self.idx]
        self.tr = rays.transmittance[self.idx]
        self._n: dict[int, tuple[object, np.ndarray]] = {}

    @property
    def n(self) -> int:
        return len(self.idx)

    def index(self, medium) -> np.ndarray:
        """Refractive index of ``medium`` at the living rays' wavelengths (cached: the
        caller must not write into it)."""
        got = self._n.get(id(medium))
        if got is None:
            got = (medium, np.broadcast_to(medium.n(self.lam), self.lam.shape))
            self._n[id(medium)] = got  # the medium is kept so that its id stays unique
        return got[1]

    def fail(self, mask: np.ndarray, status: Status, k: int) -> None:
        """Record the final state of the rays in ``mask`` (they stop here)."""
        i = self.idx[mask]
        r = self.rays
        r.pos[i] = np.stack([self.x[mask], self.y[mask], self.z[mask]], axis=1)
        r.dir[i] = np.stack([self.dx[mask], self.dy[mask], self.dz[mask]], axis=1)
        r.opl_mm[i], r.transmittance[i] = self.opl[mask], self.tr[mask]
        r.status[i] = status
        r.surface[i] = k

    def compact(self, keep: np.ndarray) -> None:
        self.idx = self.idx[keep]
        self.x, self.y, self.z = self.x[keep], self.y[keep], self.z[keep]
        self.dx, self.dy, self.dz = self.dx[keep], self.dy[keep], self.dz[keep]
        self.lam, self.opl, self.tr = self.lam[keep], self.opl[keep], self.tr[keep]
        self._n = {key: (m, n[keep]) for key, (m, n) in self._n.items()}

    def store(self) -> None:
        """Write the living rays back into the bundle."""
        r, i = self.rays, self.idx
        r.pos[i] = np.stack([self.x, self.y, self.z], axis=1)
        r.dir[i] = np.stack([self.dx, self.dy, self.dz], axis=1)
        r.opl_mm[i], r.transmittance[i] = self.opl, self.tr


def propagate_to_plane(rays: Rays, z: float) -> None:
    """Move the surviving rays to the plane at ``z`` in air (in place), adding the OPL."""
    alive = np.nonzero(rays.status == Status.OK)[0]
    dz = rays.dir[alive, 2]
    ok = dz != 0.0
    _fail(rays, alive[~ok], Status.MISSED, -1)
    alive, dz = alive[ok], dz[ok]
    t = (z - rays.pos[alive, 2]) / dz
    rays.pos[alive] += t[:, None] * rays.dir[alive]
    rays.pos[alive, 2] = z
    rays.opl_mm[alive] += t


def _fail(rays: Rays, idx: np.ndarray, status: Status, k: int) -> None:
    rays.status[idx] = status
    rays.surface[idx] = k
