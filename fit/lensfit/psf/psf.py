"""Point spread functions summed over aperture points: the exact-trace reference and the
same sum with the fitted polynomials.

For one point light, one wavelength and a sensor window, the field at pixel centre s is

    U(s) = sum_j sqrt(tau_o(a_j) tau_i(a_j, s)) exp(i 2 pi / lambda (phi_o(a_j) + phi_i(a_j, s)))

over the aperture points a_j that pass (below). :func:`exact_psf` takes phi, tau and the
pupil positions from exactly traced rays, aimed by the very functions that produced the
fitting data (:func:`lensfit.sample.aim.aim_object_side` and ``aim_sensor_side``), so
its phi_o, phi_i are exactly what P_o and P_s approximate:

* phi_o = OPL(scene point -> stop point) - d_O, with (x_O, y_O) the direction cosines of
  the light seen from the first vertex and u_O = 1/d_O its inverse distance from there
  (0 at infinity); phi_i = OPL(stop point -> sensor point) on the sensor moved by z_S
  (``focus_offset_mm``, + away from the lens);
* tau is the Fresnel power transmittance with the coatings; x_o, y_o are where the ray
  crosses the first surface, x_i, y_i the last.

:func:`poly_psf` is the same sum with ``System.evaluate`` of the fitted P_o and P_s, so a
test can tell "polynomial against trace" from "C against Python".

An aperture point passes when it lies in the stop disc, its object-side ray exists (no
miss, no total internal reflection, Newton converged) and x_o^2 + y_o^2 <= housing_first^2;
per pixel, its sensor-side ray must exist and x_i^2 + y_i^2 <= housing_last^2. The housing
radii are the first and last surfaces' semi-diameters (:func:`lensfit.paraxial.facts.lens_facts`):
the test a runtime can make with the polynomials' outputs. ``clip="housings"`` applies the
stricter exact test instead (every housing along both half paths, as the fitter's
``vignetting`` measures it).

Each stop point carries the light's flux through the stop per unit area (as lensrt
does, issue 26): tau_o times the front group's ray density |det dp/da| / |w . L|, p where
the ray crosses the first vertex plane z = 0, w the light's direction and L the ray's
leaving a near light (:func:`exact_front_flux` from the exact rays' p, by central
differences; :func:`poly_front_flux` from phi_o's mixed derivative by the light's
direction cosines, the fit's own mapping). No Huygens amplitude factor is applied:
neither the obliquity factor nor the 1/r falloff from the exit pupil to the pixel.
Across a window of a few Airy radii these factors are constant
to well under 1e-3 at moderate f-numbers, so compare *normalised* intensities |U|^2 over a
small window, not absolute values. Multiply U by the aperture area / (number of points)
for a Monte Carlo estimate of the integral if a scale is wanted.

Helpers: :func:`light_direction` (the scenes' (x_O, y_O)), :func:`pixel_centres`,
:func:`sunflower_points` (an even, deterministic aperture sampling),
:func:`geometric_image_point` (the chief ray on the sensor), :func:`best_focus_offset`
and :func:`wavefront_rms_waves` (focus from exact traces), :func:`working_f_number`.

Lengths in mm, wavelengths in nm, angles in degrees. The pixel grid: column i at
x = center_x + (i + 0.5 - width/2) * width_mm/width, row j at
y = center_y + (height/2 - j - 0.5) * height_mm/height: row 0 is the top (largest y).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Generator, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from lensfit.paraxial.facts import LensFacts, lens_facts
from lensfit.paraxial.paraxial import image_distance, paraxial
from lensfit.poly import System, design_matrix
from lensfit.prescription.model import Lens
from lensfit.sample.aim import (
    FD_STEP,
    Aimed,
    _front_plane,
    _stop_sag,
    aim_object_side,
    aim_sensor_side,
)
from lensfit.sample.ghost import GhostHalf, StopShape, aim_ghost
from lensfit.sample.rays import OUTPUTS_O, OUTPUTS_S
from lensfit.trace.tracer import Rays, Status, Step, trace

BATCH_PAIRS = 1 << 17  # (aperture point, pixel) pairs traced at once: ~150 MB per worker
CLIPS = ("pupils", "housings")
GUESS_NODES = 5  # Chebyshev nodes per axis of the window for the sensor-side first guess


# --- inputs -------------------------------------------------------------------------------


def light_direction(field_x_deg: float, field_y_deg: float) -> tuple[float, float]:
    """P_o's (x_O, y_O) for a light at field angles (θx, θy) in degrees.

    Field angles follow the lens designers' convention (Zemax, Code V, Optiland; README
    "Conventions"): the light's chief ray travels along (tan θx, tan θy, 1), so +θy is a
    ray rising towards the lens (dy/dz > 0), from a light *below* the axis, imaged at +y
    by an ordinary lens. (x_O, y_O) are the direction cosines of the opposite direction:
    from the first vertex towards the light, (-tan θx, -tan θy, 1) normalised, so
    x_O = -tan θx / sqrt(1 + tan² θx + tan² θy), and the same for y. This is the one
    place lensfit turns field angles into P_o's inputs (lensrt: lensrt_light_direction)."""
    for name, v in (("field_x_deg", field_x_deg), ("field_y_deg", field_y_deg)):
        if not (math.isfinite(v) and abs(v) < 90.0):
            raise ValueError(f"{name} = {v!r}: expected an angle in (-90, 90) degrees")
    tx, ty = math.tan(math.radians(field_x_deg)), math.tan(math.radians(field_y_deg))
    norm = math.sqrt(1.0 + tx * tx + ty * ty)
    return -tx / norm, -ty / norm


def pixel_centres(width: int, height: int, width_mm: float, height_mm: float = 0.0,
                  center_x_mm: float = 0.0, center_y_mm: float = 0.0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Pixel centres (xs (width,), ys (height,)) in mm; row 0 is the top (largest y).
    ``height_mm`` 0 means square pixels: height_mm = height * width_mm / width."""
    for name, v in (("width", width), ("height", height)):
        if not (isinstance(v, int | np.integer) and v > 0):
            raise ValueError(f"{name} = {v!r}: expected a positive number of pixels")
    if not (math.isfinite(width_mm) and width_mm > 0):
        raise ValueError(f"width_mm = {width_mm!r}: expected a positive size in mm")
    if not (math.isfinite(height_mm) and height_mm >= 0):
        raise ValueError(f"height_mm = {height_mm!r}: expected a size in mm, 0 for square "
                         "pixels")
    for name, v in (("center_x_mm", center_x_mm), ("center_y_mm", center_y_mm)):
        if not math.isfinite(v):
            raise ValueError(f"{name} = {v!r}: expected a finite position in mm")
    if height_mm == 0:
        height_mm = height * width_mm / width
    xs = center_x_mm + (np.arange(width) + 0.5 - width / 2) * (width_mm / width)
    ys = center_y_mm + (height / 2 - np.arange(height) - 0.5) * (height_mm / height)
    return xs, ys


def _inverse_distance(distance_mm: float) -> float:
    if not distance_mm > 0:  # NaN too
        raise ValueError(f"distance_mm = {distance_mm!r}: expected a positive distance from "
                         "the first vertex (inf for a light at infinity)")
    return 0.0 if math.isinf(distance_mm) else 1.0 / distance_mm


def _aperture(aperture_xy_mm: np.ndarray, stop_radius_mm: float) -> tuple[np.ndarray,
                                                                          np.ndarray]:
    """The points (N, 2) and which of them lie in the stop disc."""
    if not (math.isfinite(stop_radius_mm) and stop_radius_mm > 0):
        raise ValueError(f"stop_radius_mm = {stop_radius_mm!r}: expected a positive radius")
    ap = np.asarray(aperture_xy_mm, dtype=np.float64)
    if ap.ndim != 2 or ap.shape[1] != 2 or not np.all(np.isfinite(ap)):
        raise ValueError(f"aperture_xy_mm: expected finite points of shape (N, 2), found "
                         f"shape {ap.shape}")
    return ap, ap[:, 0] ** 2 + ap[:, 1] ** 2 <= stop_radius_mm**2


def _wavelength(wavelength_nm: float) -> float:
    if not (math.isfinite(wavelength_nm) and wavelength_nm > 0):
        raise ValueError(f"wavelength_nm = {wavelength_nm!r}: expected a positive "
                         "wavelength in nm")
    return float(wavelength_nm)


def _batch(batch_pairs: int) -> int:
    if not (isinstance(batch_pairs, int) and batch_pairs > 0):
        raise ValueError(f"batch_pairs = {batch_pairs!r}: expected a positive count")
    return batch_pairs


def _check_focus(focus_offset_mm: float) -> float:
    if not math.isfinite(focus_offset_mm):
        raise ValueError(f"focus_offset_mm = {focus_offset_mm!r}: expected a finite sensor "
                         "shift z_S in mm")
    return float(focus_offset_mm)


def _workers(workers: int | None) -> int:
    if workers is None:
        try:
            return max(1, len(os.sched_getaffinity(0)))
        except AttributeError:  # not on Linux
            return max(1, os.cpu_count() or 1)
    if not (isinstance(workers, int) and workers > 0):
        raise ValueError(f"workers = {workers!r}: expected a positive number of threads")
    return workers


def _checked_inputs(stop_radius_mm, aperture_xy_mm, field_deg, distance_mm, wavelength_nm,
                    focus_offset_mm, width, height, width_mm, height_mm, center_x_mm,
                    center_y_mm):
    """The arguments every PSF sum shares, checked: (lambda, pixel xs, ys, aperture
    points, which lie in the stop disc, x_O, y_O, u_O, z_S)."""
    lam = _wavelength(wavelength_nm)
    xs, ys = pixel_centres(width, height, width_mm, height_mm, center_x_mm, center_y_mm)
    ap, inside = _aperture(aperture_xy_mm, stop_radius_mm)
    x_O, y_O = light_direction(*field_deg)
    return (lam, xs, ys, ap, inside, x_O, y_O, _inverse_distance(distance_mm),
            _check_focus(focus_offset_mm))


def sunflower_points(n: int, radius_mm: float) -> np.ndarray:
    """n points (n, 2) spread evenly over the disc of ``radius_mm`` (Vogel's spiral): a
    deterministic aperture sampling with far less noise than random points."""
    if not (isinstance(n, int) and n > 0):
        raise ValueError(f"n = {n!r}: expected a positive number of points")
    k = np.arange(n) + 0.5
    r = radius_mm * np.sqrt(k / n)
    a = k * math.pi * (3.0 - math.sqrt(5.0))  # the golden angle
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)


# --- the sum --------------------------------------------------------------------------------


def _sum_phasors(n_pairs: int, n_pixels: int, batch: int, workers: int,
                 phasors: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Sum over pairs k = j * n_pixels + p (aperture point j, pixel p) of the phasors
    ``phasors(k)`` returns for a batch (with the pixel of each), into U (n_pixels,).
    Batches run on ``workers`` threads (numpy releases the GIL); they are added in order,
    so the result does not depend on the number of threads."""
    starts = range(0, n_pairs, batch)

    def one(a: int) -> np.ndarray:
        pix, z = phasors(np.arange(a, min(a + batch, n_pairs)))
        return (np.bincount(pix, weights=z.real, minlength=n_pixels)
                + 1j * np.bincount(pix, weights=z.imag, minlength=n_pixels))

    total = np.zeros(n_pixels, dtype=np.complex128)
    if workers == 1 or len(starts) == 1:
        for a in starts:
            total += one(a)
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            for part in pool.map(one, starts):
                total += part
    return total


def _passes(aimed: Aimed, radius_mm: float, clip: str) -> np.ndarray:
    """Rays that exist and get past the housing test ``clip`` (see the module doc)."""
    if clip == "housings":
        with np.errstate(invalid="ignore"):
            return aimed.ok & (aimed.vignetting <= 1.0)
    x, y = aimed.outputs[:, 0], aimed.outputs[:, 1]
    with np.errstate(invalid="ignore"):
        return aimed.ok & (x * x + y * y <= radius_mm * radius_mm)


def _lagrange(t: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Lagrange basis weights (len(t), len(nodes)) of the polynomial through ``nodes``."""
    w = np.ones((len(t), len(nodes)))
    for a, ta in enumerate(nodes):
        for b, tb in enumerate(nodes):
            if a != b:
                w[:, a] *= (t - tb) / (ta - tb)
    return w


def _sensor_guess(lens: Lens, xs: np.ndarray, ys: np.ndarray, z_s: float, ap: np.ndarray,
                  lam: float, ghost: GhostHalf | None = None
                  ) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """First guesses of the sensor-side slopes for (point, pixel) pairs: per aperture
    point, exact rays to a 5 x 5 Chebyshev grid over the window, interpolated by the
    tensor-product polynomial through them. Measured on lens 0001 at f/2: the guess is
    within the exact rays' own Newton noise (~2e-11 in slope, ~1e-9 mm on the sensor)
    for windows up to 2 mm, so almost every pair costs one trace and no Newton step.

    With ``ghost`` (a ghost half on the sensor side) the node rays follow the ghost's
    half (:func:`lensfit.sample.ghost.aim_ghost`, with its continuation and scan): a
    point with a node ray that failed gets NaN guesses, so its pairs are aimed as
    without a guess. Measured on 0001's ghost 4-8 (f/8, 450 nm): the exact PSF's
    23 s of CPU, mostly Newton from the paraxial guess, fall to ~3 s."""
    (gx, wx), (gy, wy) = _chebyshev(xs, GUESS_NODES), _chebyshev(ys, GUESS_NODES)
    n, my, mx = len(ap), len(gy), len(gx)
    # Rows: point j, node row b (y), node column c (x)
    jj, bb, cc = (g.reshape(-1) for g in np.meshgrid(np.arange(n), np.arange(my),
                                                    np.arange(mx), indexing="ij"))
    if ghost is None:
        grid = aim_sensor_side(lens, gx[cc], gy[bb], z_s, ap[jj, 0], ap[jj, 1], lam,
                               vignetting=False)
    else:
        grid = aim_ghost(lens, ghost, gx[cc], gy[bb], z_s, ap[jj, 0], ap[jj, 1], lam).aimed
    slopes = grid.unknowns.reshape(n, my, mx, 2)  # NaN where a node failed: paraxial guess
    width = len(xs)

    def guess(j: np.ndarray, p: np.ndarray) -> np.ndarray:
        # The whole window for each point of the batch, then the pairs asked for
        j0 = int(j.min())
        full = np.einsum("hb,jbcd,wc->jhwd", wy, slopes[j0:int(j.max()) + 1], wx,
                         optimize=True)
        return full[j - j0, p // width, p % width]

    return guess


FLUX_STEP_MM = 1e-3  # stop-point step of the flux's differences (mm)
FLUX_STEP_COSINE = 1e-4  # light-direction step of phi_o's mixed differences


def _near_light(x_O: float, y_O: float, u_O: float, px: np.ndarray, py: np.ndarray
                ) -> np.ndarray:
    """1 / |w . L| for rays from a light at inverse distance u_O (1/mm) in direction
    (x_O, y_O) (towards the scene) through (px, py, 0); 1 at infinity."""
    if u_O == 0.0:
        return np.ones(np.shape(px))
    w = np.array([x_O, y_O, -math.sqrt(1.0 - x_O * x_O - y_O * y_O)])
    v = np.stack([px - w[0] / u_O, py - w[1] / u_O, np.full(np.shape(px), -w[2] / u_O)], -1)
    return np.linalg.norm(v, axis=-1) / np.abs(v @ w)


def _flux_offsets() -> np.ndarray:
    """The four neighbours' steps from a stop point (4, 2): +x, -x, +y, -y."""
    e = FLUX_STEP_MM
    return np.array([[e, 0.0], [-e, 0.0], [0.0, e], [0.0, -e]])


def exact_front_flux(aim: Callable[..., Aimed], x_O: float, y_O: float,
                     u_O: float, pts: np.ndarray, guess: np.ndarray | None = None
                     ) -> np.ndarray:
    """The light's flux through the stop per unit area at stop points ``pts`` (N, 2)
    relative to its irradiance on the first vertex plane, from exact rays: ``aim(x_a,
    y_a)`` traces them (``Aimed.unknowns``: where each crosses z = 0); dp/da by central
    differences of FLUX_STEP_MM. NaN where a neighbour ray fails. ``guess`` (4, N, 2),
    first guesses of the neighbours' p (:func:`_flux_guesses`), is passed on as
    ``aim(x_a, y_a, guess=...)``."""
    e = FLUX_STEP_MM
    q = (pts[None, :, :] + _flux_offsets()[:, None, :]).reshape(-1, 2)
    a = (aim(q[:, 0], q[:, 1]) if guess is None
         else aim(q[:, 0], q[:, 1], guess=guess.reshape(-1, 2)))
    p = np.where(a.ok[:, None], a.unknowns, np.nan).reshape(4, len(pts), 2)
    dx, dy = (p[0] - p[1]) / (2 * e), (p[2] - p[3]) / (2 * e)
    det = np.abs(dx[:, 0] * dy[:, 1] - dy[:, 0] * dx[:, 1])
    mid = 0.25 * p.sum(axis=0)
    return det * _near_light(x_O, y_O, u_O, mid[:, 0], mid[:, 1])


def _object_landing(lens: Lens, x_O: float, y_O: float, u_O: float, p: np.ndarray,
                    lam: float) -> tuple[np.ndarray, np.ndarray]:
    """Where the light's rays through ``p`` (N, 2) on the first vertex plane z = 0 cross
    the stop (N, 2), and which of them get there: the trace of
    :func:`lensfit.sample.aim.aim_object_side` (its start plane, its path) without its
    Newton."""
    s = lens.stop_index
    w = np.array([x_O, y_O, -math.sqrt(1.0 - x_O * x_O - y_O * y_O)])  # towards the scene
    d = np.empty((len(p), 3))
    d[:, :2] = u_O * p - w[:2]  # from the scene point to (p, 0), made unit
    d[:, 2] = -w[2]
    d /= np.linalg.norm(d, axis=1)[:, None]
    start = d * (_front_plane(lens) / d[:, 2])[:, None]  # back from z = 0 to the start plane
    start[:, :2] += p
    out = trace(lens, Rays(start, d, lam), [Step(k) for k in range(s + 1)], clip=False)
    return out.pos[:, :2], out.status == Status.OK


def _flux_guesses(lens: Lens, x_O: float, y_O: float, u_O: float, lam: float,
                  pts: np.ndarray, p0: np.ndarray) -> np.ndarray:
    """First guesses (4, N, 2) of where the neighbour rays of :func:`exact_front_flux`
    (stop points ``pts`` moved by :func:`_flux_offsets`) cross z = 0, from the central
    rays' crossings ``p0`` (N, 2): each central ray's Jacobian d(stop point)/dp (two
    plain rays by forward differences) aims the neighbours linearly, and one chord step
    with the same Jacobian corrects them, so that :func:`aim_object_side` accepts them
    with its final trace (Newton from the paraxial guess took ~7 traces a ray). NaN
    rows (the paraxial guess) where a ray fails."""
    n = len(pts)
    h = FD_STEP * max(float(np.max(np.abs(pts), initial=0.0)), 1.0)  # Newton's own step
    # The central ray and two steps of p: where they cross the stop
    steps = np.array([[0.0, 0.0], [h, 0.0], [0.0, h]])
    land, ok = _object_landing(lens, x_O, y_O, u_O,
                               (p0[:, None, :] + steps).reshape(-1, 2), lam)
    land, ok = land.reshape(n, 3, 2), ok.reshape(n, 3).all(axis=1)
    jac = np.stack([land[:, 1] - land[:, 0], land[:, 2] - land[:, 0]], axis=2) / h
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.linalg.inv(np.where(ok[:, None, None], jac, np.eye(2)))
    # Linear aim at each neighbour, then one chord step from where it lands
    target = pts[None, :, :] + _flux_offsets()[:, None, :]  # (4, N, 2)
    guess = p0 + np.einsum("nij,knj->kni", inv, target - land[:, 0])
    hit, fine = _object_landing(lens, x_O, y_O, u_O, guess.reshape(-1, 2), lam)
    guess -= np.einsum("nij,knj->kni", inv, hit.reshape(4, n, 2) - target)
    guess[~(fine.reshape(4, n) & ok)] = np.nan
    return guess


def poly_front_flux(p_o: System, light: dict[str, float], pts: np.ndarray,
                    x_o: np.ndarray, y_o: np.ndarray) -> np.ndarray:
    """:func:`exact_front_flux` from a fitted P_o: dp/da is phi_o's mixed derivative by
    the light's direction cosines and the stop point (p = d phi_o / d(x_O, y_O)), by
    central differences on the polynomial; (x_o, y_o) on the first surface stand in for
    p in the near light's 1 / |w . L| (their difference moves it by < 1e-6)."""
    d, e = FLUX_STEP_COSINE, FLUX_STEP_MM
    p_o = p_o.select(["phi_o"])  # the one output the differences take
    # The differences' centres moved inside the fitted domain by their steps where a
    # light or a stop point lies on its edge (a stop point on the rim of the stop disc:
    # x_a + e would be outside it), so no stencil leaves the domain
    inputs = {i.name: i for i in p_o.inputs}

    def inward(name: str, v, step: float):
        return np.clip(v, inputs[name].lo + step, inputs[name].hi - step)

    light = dict(light, x_O=float(inward("x_O", light["x_O"], d)),
                 y_O=float(inward("y_O", light["y_O"], d)))
    pts = np.column_stack([inward("x_a", pts[:, 0], e), inward("y_a", pts[:, 1], e)])
    # P_o specialised once per shifted light (four of them), evaluated at the four stop
    # shifts in one call (each row of a polynomial's evaluation is its own)
    n = len(pts)
    shifts = ((e, 0.0), (-e, 0.0), (0.0, e), (0.0, -e))
    shifted = np.concatenate([pts + s for s in shifts])
    values = {}
    for dx, dy in ((d, 0), (-d, 0), (0, d), (0, -d)):
        lit = p_o.specialise(dict(light, x_O=light["x_O"] + dx, y_O=light["y_O"] + dy))
        got = _evaluate(lit, {"x_a": shifted[:, 0], "y_a": shifted[:, 1]})[0]
        for k, (ex, ey) in enumerate(shifts):
            values[dx, dy, ex, ey] = got[k * n:(k + 1) * n]

    def phi(dx: float, dy: float, ex: float, ey: float) -> np.ndarray:
        return values[dx, dy, ex, ey]

    def mixed(dx: float, dy: float, ex: float, ey: float) -> np.ndarray:
        return (phi(dx, dy, ex, ey) - phi(dx, dy, -ex, -ey) - phi(-dx, -dy, ex, ey)
                + phi(-dx, -dy, -ex, -ey)) / (4 * d * e)

    h11, h12 = mixed(d, 0, e, 0), mixed(d, 0, 0, e)
    h21, h22 = mixed(0, d, e, 0), mixed(0, d, 0, e)
    return (np.abs(h11 * h22 - h12 * h21)
            * _near_light(light["x_O"], light["y_O"], light["u_O"], x_o, y_o))


def exact_psf(lens: Lens, *, stop_radius_mm: float, aperture_xy_mm: np.ndarray,
              field_deg: tuple[float, float] = (0.0, 0.0), distance_mm: float = math.inf,
              wavelength_nm: float, focus_offset_mm: float = 0.0, width: int, height: int,
              width_mm: float, height_mm: float = 0.0, center_x_mm: float = 0.0,
              center_y_mm: float = 0.0, clip: str = "pupils", workers: int | None = None,
              batch_pairs: int = BATCH_PAIRS, nodes: int = 0,
              ghost: GhostHalf | None = None,
              stop_shape: StopShape | None = None) -> np.ndarray:
    """U (height, width), complex: the sum of the module doc over ``aperture_xy_mm``
    (N, 2) stop points, with phi, tau and the pupil positions of exactly traced rays.

    ``field_deg`` (θx, θy) and ``distance_mm`` (from the first vertex) place the light;
    ``focus_offset_mm`` is z_S. ``clip``: "pupils" (the first and last surfaces' housing
    radii against x_o, y_o and x_i, y_i) or "housings" (every housing). ``workers``
    threads (default: the CPUs this process may use) trace batches of ``batch_pairs``.

    ``nodes`` > 0 traces, per stop point, only the rays to a ``nodes`` x ``nodes``
    Chebyshev grid over the window and interpolates the sensor-side outputs to the
    pixels (:func:`exact_psf_nodes`; "pupils" clipping only).

    ``ghost`` (:func:`lensfit.sample.ghost.ghost_half`) sums the ghost's image instead:
    its half is traced by :func:`lensfit.sample.ghost.aim_ghost` and always clipped
    exactly (every housing it crosses and, in case C, a round stop of ``stop_radius_mm``
    at its further stop crossings, or ``stop_shape`` (x, y) mm -> inside for a bladed or
    slit stop; the caller passes only ``aperture_xy_mm`` inside that shape); ``clip``
    then applies to the direct half. Its sensor side (the ghost's half, or the direct
    half with "pupils" clipping) is interpolated from node rays for every stop point
    whose checked pixels agree with exact rays (:func:`_interpolated_sensor`), the other
    points traced per pixel."""
    if nodes and ghost is not None:
        raise ValueError("nodes: the interpolated sensor side is for the direct path only")
    if stop_shape is not None and ghost is None:
        raise ValueError("stop_shape: tests a ghost's further stop crossings; the direct "
                         "path's stop points are the caller's aperture_xy_mm")
    if nodes:
        return exact_psf_nodes(lens, stop_radius_mm=stop_radius_mm,
                               aperture_xy_mm=aperture_xy_mm, field_deg=field_deg,
                               distance_mm=distance_mm, wavelength_nm=wavelength_nm,
                               focus_offset_mm=focus_offset_mm, width=width, height=height,
                               width_mm=width_mm, height_mm=height_mm,
                               center_x_mm=center_x_mm, center_y_mm=center_y_mm,
                               nodes=nodes)[0]
    if clip not in CLIPS:
        raise ValueError(f"clip = {clip!r}: expected one of {', '.join(CLIPS)}")
    lam, xs, ys, ap, inside, x_O, y_O, u_O, z_s = _checked_inputs(
        stop_radius_mm, aperture_xy_mm, field_deg, distance_mm, wavelength_nm,
        focus_offset_mm, width, height, width_mm, height_mm, center_x_mm, center_y_mm)
    facts = lens_facts(lens)
    workers = _workers(workers)

    # Object side: one exact ray per aperture point in the stop disc
    pts = ap[inside]
    ghost_o = ghost is not None and ghost.system == "P_o"
    ghost_s = ghost is not None and ghost.system == "P_s"
    if ghost_o:
        def aim(xa: np.ndarray, ya: np.ndarray) -> Aimed:
            return aim_ghost(lens, ghost, x_O, y_O, u_O, xa, ya, lam,
                             fd_scale=max(stop_radius_mm, 1.0)).aimed
        obj = aim_ghost(lens, ghost, x_O, y_O, u_O, pts[:, 0], pts[:, 1], lam,
                        fd_scale=max(stop_radius_mm, 1.0))
        pass_o = obj.passes(stop_radius_mm, stop_shape)
    else:
        def aim(xa: np.ndarray, ya: np.ndarray) -> Aimed:
            return aim_object_side(lens, x_O, y_O, u_O, xa, ya, lam)
        obj = aim(pts[:, 0], pts[:, 1])
        pass_o = _passes(obj, facts.housing_first_mm, clip)
    pts, phi_o, tau_o = pts[pass_o], obj.outputs[pass_o, 3], obj.outputs[pass_o, 2]
    flux = exact_front_flux(aim, x_O, y_O, u_O, pts)
    good = np.isfinite(flux)
    pts, phi_o, tau_o = pts[good], phi_o[good], tau_o[good] * flux[good]
    n_pix = width * height
    if len(pts) == 0:
        return np.zeros((height, width), dtype=np.complex128)

    k_wave = 2.0 * math.pi / (lam * 1e-6)  # 1/mm
    u = np.zeros(n_pix, dtype=np.complex128)
    if ghost_s or (ghost_o and clip == "pupils"):
        # A ghost's sensor side (its own half, or the direct one) is smooth across the
        # window: interpolated from node rays where checked rays agree
        u_nodes, exact = _interpolated_sensor(lens, xs, ys, z_s, pts, lam, k_wave,
                                              tau_o, phi_o, facts.housing_last_mm,
                                              ghost if ghost_s else None, stop_radius_mm,
                                              stop_shape)
        u += u_nodes.reshape(-1)
        pts, phi_o, tau_o = pts[exact], phi_o[exact], tau_o[exact]
        if len(pts) == 0:
            return u.reshape(height, width)

    # Sensor side: one exact ray per (point, pixel), warm-started from a grid per point
    guess = _sensor_guess(lens, xs, ys, z_s, pts, lam, ghost if ghost_s else None)

    def phasors(k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        j, p = k // n_pix, k % n_pix
        if ghost_s:
            sen = aim_ghost(lens, ghost, xs[p % width], ys[p // width], z_s, pts[j, 0],
                            pts[j, 1], lam, guess=guess(j, p))
            ok = sen.passes(stop_radius_mm, stop_shape)
        else:
            sen = aim_sensor_side(lens, xs[p % width], ys[p // width], z_s, pts[j, 0],
                                  pts[j, 1], lam, guess=guess(j, p),
                                  vignetting=clip == "housings")
            ok = _passes(sen, facts.housing_last_mm, clip)
        amp = np.sqrt(tau_o[j[ok]] * sen.outputs[ok, 2])
        return p[ok], amp * np.exp(1j * (k_wave * (phi_o[j[ok]] + sen.outputs[ok, 3])))

    u += _sum_phasors(len(pts) * n_pix, n_pix, _batch(batch_pairs), workers, phasors)
    return u.reshape(height, width)


# The sensor side of a ghost's exact PSF from node rays (_interpolated_sensor)
INTERP_NODES = 9  # Chebyshev nodes per axis of the window
INTERP_CHECK = 4  # pixels per axis traced exactly per stop point to check the interpolation
INTERP_TOL_WAVES = 1e-5  # largest phase error at a checked pixel (waves)
INTERP_TOL_MM = 1e-6  # largest position error (mm): last surface, stop crossings
INTERP_TOL_RATIO = 1e-7  # largest error of a housing ratio x_k / R_k (a ghost's half)
INTERP_TOL_TAU = 1e-7  # largest transmittance error


def _interpolated_sensor(lens: Lens, xs: np.ndarray, ys: np.ndarray, z_s: float,
                         pts: np.ndarray, lam: float, k_wave: float, tau_o: np.ndarray,
                         phi_o: np.ndarray, housing_mm: float, ghost: GhostHalf | None = None,
                         stop_radius_mm: float = 0.0, stop_shape: StopShape | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:
    """The sensor side of a ghost's :func:`exact_psf` from node rays: per stop point,
    exact rays to INTERP_NODES x INTERP_NODES Chebyshev nodes over the window (the direct
    half for an object-side ghost; with ``ghost``, its sensor-side half), their outputs
    and, for a ghost half, its housing ratios and stop crossings interpolated to the
    pixels (as :func:`exact_psf_nodes`) and the clip tests made on those. Only for the
    stop points where INTERP_CHECK x INTERP_CHECK pixels between the nodes, traced
    exactly, agree with the interpolation (INTERP_TOL_*: ~1e-5 waves in phase, ~1e-6 mm
    in position); the rest are left to the exact rays per pixel. Returns (U (height,
    width) of the interpolated points, exact (N,): the points left). Measured at f/8,
    1000 points, 32 x 32 pixels: on 0001's ghost 0-2 (window 0.27 mm) and 4-8 (0.18 mm)
    every point is interpolated and the PSF agrees with the one from every pair traced
    to ~1e-9, in 1/4 to 1/10 of the time."""
    width, height = len(xs), len(ys)
    n = len(pts)
    (gx, wx), (gy, wy) = _chebyshev(xs, INTERP_NODES), _chebyshev(ys, INTERP_NODES)
    my, mx = len(gy), len(gx)
    h = len(ghost.housings) if ghost is not None else 0
    c = len(ghost.stop_crossings) if ghost is not None else 0
    tol = np.array([INTERP_TOL_MM, INTERP_TOL_MM, INTERP_TOL_TAU,
                    INTERP_TOL_WAVES * lam * 1e-6] + [INTERP_TOL_RATIO] * (2 * h)
                   + [INTERP_TOL_MM] * (2 * c))

    def rays(x, y, j, guess, **kw):
        """(values (N, 4 + 2h + 2c), ok, slopes) of the rays from pts[j] to (x, y)."""
        if ghost is None:
            a = aim_sensor_side(lens, x, y, z_s, pts[j, 0], pts[j, 1], lam, guess=guess,
                                vignetting=False)
            return a.outputs, a.ok, a.unknowns
        g = aim_ghost(lens, ghost, x, y, z_s, pts[j, 0], pts[j, 1], lam, guess=guess, **kw)
        return (np.concatenate([g.outputs, g.clip.reshape(len(x), -1),
                                g.stop.reshape(len(x), -1)], axis=1), g.ok, g.aimed.unknowns)

    def passes(v: np.ndarray) -> np.ndarray:
        """The clip verdict of values v (..., 4 + 2h + 2c)."""
        if ghost is None:
            return v[..., 0] ** 2 + v[..., 1] ** 2 <= housing_mm**2
        ok = np.ones(v.shape[:-1], dtype=bool)
        for k in range(h):
            ok &= np.hypot(v[..., 4 + 2 * k], v[..., 5 + 2 * k]) <= 1.0
        for k in range(c):
            x, y = v[..., 4 + 2 * h + 2 * k], v[..., 5 + 2 * h + 2 * k]
            ok &= (np.asarray(stop_shape(x, y), dtype=bool) if stop_shape is not None
                   else np.hypot(x, y) <= stop_radius_mm)
        return ok

    jj, bb, cc = (g.reshape(-1) for g in np.meshgrid(np.arange(n), np.arange(my),
                                                    np.arange(mx), indexing="ij"))
    start = _sensor_guess(lens, gx, gy, z_s, pts, lam, ghost)(jj, bb * mx + cc)
    values, ok, slopes = rays(gx[cc], gy[bb], jj, start)
    good = ok.reshape(n, my, mx).all(axis=(1, 2))
    out = np.nan_to_num(values.reshape(n, my, mx, -1))
    slopes = np.nan_to_num(slopes.reshape(n, my, mx, 2))
    # Checked pixels: spread over the window, between the nodes
    cx = ((np.arange(INTERP_CHECK) + 0.5) * width / INTERP_CHECK).astype(int)
    cy = ((np.arange(INTERP_CHECK) + 0.5) * height / INTERP_CHECK).astype(int)
    want = np.einsum("hb,jbcd,wc->jhwd", wy[cy], out, wx[cx], optimize=True)
    start = np.einsum("hb,jbcd,wc->jhwd", wy[cy], slopes, wx[cx], optimize=True)
    kj, kh, kw = (g.reshape(-1) for g in np.meshgrid(np.arange(n), np.arange(len(cy)),
                                                    np.arange(len(cx)), indexing="ij"))
    got, ok, _ = rays(xs[cx[kw]], ys[cy[kh]], kj, start.reshape(-1, 2), retry_rounds=0,
                      scan=0)
    with np.errstate(invalid="ignore"):
        fine = np.all(np.abs(got.reshape(want.shape) - want) <= tol, axis=-1)
    use = good & ok.reshape(n, -1).all(axis=1) & fine.reshape(n, -1).all(axis=1)
    idx = np.nonzero(use)[0]
    u = np.zeros((height, width), dtype=np.complex128)
    for a in range(0, len(idx), 256):
        sl = idx[a:a + 256]
        full = np.einsum("hb,jbcd,wc->jhwd", wy, out[sl], wx, optimize=True)
        tau_i, phi_i = full[..., 2], full[..., 3]
        amp = np.sqrt(np.maximum(tau_o[sl, None, None] * tau_i, 0.0))
        phase = k_wave * (phi_o[sl, None, None] + phi_i)
        u += np.where(passes(full), amp * np.exp(1j * phase), 0.0).sum(axis=0)
    return u, ~use


def _chebyshev(v: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """m Chebyshev nodes spanning the pixel centres ``v`` and the Lagrange weights
    (len(v), m) that interpolate from them to every centre."""
    m = min(m, len(v))  # a line of pixels needs one node across it
    cheb = np.cos(math.pi * (np.arange(m) + 0.5) / m)[::-1]
    c, h = 0.5 * (v.max() + v.min()), 0.5 * (v.max() - v.min())
    t = (v - c) / h if h > 0 else np.zeros_like(v)
    if h > 0:
        cheb = cheb / cheb.max()  # the end nodes on the outermost pixel centres
    return c + h * cheb, _lagrange(t, cheb)


FD_SLOPE = 1e-6  # slope step of the node rays' first Jacobian (_node_rays)


def _shoot(lens: Lens, ap: np.ndarray, slopes: np.ndarray, lam: float, end_z: float
           ) -> tuple[np.ndarray, np.ndarray]:
    """Where rays leaving the stop points ``ap`` (N, 2) with ``slopes`` (N, 2) (dx/dz,
    dy/dz) meet the plane z = end_z behind the lens, (N, 2), and which of them get there:
    the trace of :func:`lensfit.sample.aim.aim_sensor_side` without its Newton."""
    s = lens.stop_index
    start = np.column_stack([ap, float(lens.vertex_z[s]) + _stop_sag(lens, ap)])
    out = trace(lens, Rays(start, np.column_stack([slopes, np.ones(len(ap))]), lam),
                [Step(k) for k in range(s + 1, len(lens.surfaces))], clip=False,
                end_z=end_z)
    return out.pos[:, :2], (out.status == Status.OK) & (out.dir[:, 2] > 0)


def _node_rays(lens: Lens, ap: np.ndarray, slopes: np.ndarray, xs: np.ndarray,
               ys: np.ndarray, gx: np.ndarray, gy: np.ndarray, z_s: float, lam: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact sensor-side rays from the stop points ``ap`` (N, 2) to the window, and their
    outputs (x_i, y_i, tau_i, phi_i, as :func:`aim_sensor_side` gives them) as tensor
    polynomials of the sensor position through them; ``slopes`` (N, 2) are those of the
    object-side rays leaving each stop point, whose continuations land in the window (it
    holds the spot). Returns (coefficients (4, N, len(gy), len(gx)), ok (N,), Tx
    (len(xs), len(gx)), Ty (len(ys), len(gy))): an output at the pixel centres (xs, ys)
    is Ty @ coefficients[q, j] @ Tx.T, Chebyshev polynomials of the pixel position
    scaled to [-1, 1] over the centres. ok: every ray of the point got there.

    Per stop point: the continuation's landing and its Jacobian d(landing)/d(slope) (3
    plain rays) aim one ray at each node of the grid (gx, gy) linearly, and that ray's
    own landing (near its node: the window is small next to the lens) and outputs are
    the interpolation's data. No Newton: the polynomial of degree len(gx) - 1 in x and
    len(gy) - 1 in y through those rays is the same interpolation as through rays
    landed on the nodes themselves, where they land being known exactly. It replaced
    aiming each node ray to 1e-8 mm from a model of 16 more rays (a third of the
    check's rays, 10% of its time), and is nearer the truth: on lens 0001's f/2 field
    corner at 650 nm (128 stop points, 48 x 48 pixels, window 473 um) the intensity
    moved 3.5e-7 relative L2 from every pair traced (Newton's own noise; 2.3e-6 with
    the node rays within the 1e-8 mm aim_sensor_side accepts), 0011's at 450 nm (2.7
    mm) 3.5e-7 both ways."""
    n, my, mx = len(ap), len(gy), len(gx)
    end_z = lens.sensor_z + z_s
    # The continuation and two slope steps: where it lands and how that moves
    h = FD_SLOPE
    steps = np.array([[0.0, 0.0], [h, 0.0], [0.0, h]])
    land, ok = _shoot(lens, np.repeat(ap, 3, axis=0),
                      (slopes[:, None, :] + steps).reshape(-1, 2), lam, end_z)
    land, ok = land.reshape(n, 3, 2), ok.reshape(n, 3).all(axis=1)
    jac = np.stack([land[:, 1] - land[:, 0], land[:, 2] - land[:, 0]], axis=2) / h
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.linalg.inv(np.where(ok[:, None, None], jac, np.eye(2)))
    # One ray per node, aimed linearly, traced as aim_sensor_side's final trace
    nodes = np.stack(np.meshgrid(gx, gy), axis=-1)  # (my, mx, 2)
    aim = slopes[:, None, None, :] + np.einsum("nij,nbcj->nbci", inv,
                                               nodes[None] - land[:, None, None, 0])
    ok &= np.all(np.isfinite(aim), axis=(1, 2, 3))
    aim[~ok] = 0.0
    q = aim.reshape(-1, 2)
    start = np.repeat(ap, my * mx, axis=0)
    start = np.column_stack([start, float(lens.vertex_z[lens.stop_index])
                             + _stop_sag(lens, start)])
    out = trace(lens, Rays(start, np.column_stack([q, np.ones(len(q))]), lam),
                [Step(k) for k in range(lens.stop_index + 1, len(lens.surfaces))],
                clip=False, fresnel_loss=True)
    good = (out.status == Status.OK) & (out.dir[:, 2] > 0)
    t = (end_z - out.pos[:, 2]) / np.where(good, out.dir[:, 2], 1.0)
    landing = out.pos[:, :2] + t[:, None] * out.dir[:, :2]
    values = np.column_stack([out.pos[:, 0], out.pos[:, 1], out.transmittance,
                              out.opl_mm + t])  # behind the last surface: air
    good &= np.all(np.isfinite(values), axis=1) & np.all(np.isfinite(landing), axis=1)
    ok &= good.reshape(n, -1).all(axis=1)
    # Chebyshev polynomials of the scaled position, at the pixel centres and the landings
    def scale(v: np.ndarray, centres: np.ndarray) -> np.ndarray:
        c, half = 0.5 * (centres.max() + centres.min()), 0.5 * (centres.max() - centres.min())
        return (v - c) / half if half > 0 else np.zeros_like(v)

    tx = np.polynomial.chebyshev.chebvander(scale(xs, xs), mx - 1)  # (width, mx)
    ty = np.polynomial.chebyshev.chebvander(scale(ys, ys), my - 1)  # (height, my)
    landing = landing.reshape(n, my * mx, 2)
    vx = np.polynomial.chebyshev.chebvander(scale(landing[..., 0], xs), mx - 1)
    vy = np.polynomial.chebyshev.chebvander(scale(landing[..., 1], ys), my - 1)
    v = (vy[..., :, None] * vx[..., None, :]).reshape(n, my * mx, my * mx)
    # Through each point's rays: each output less its mean (the constant term), so that
    # the solve's rounding is that of the output's change over the window
    values = values.reshape(n, my * mx, 4)
    mean = values.mean(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", over="ignore"):
        v[~ok] = np.eye(my * mx)
        coef = np.linalg.solve(v, np.where(ok[:, None, None], values - mean, 0.0))
    coef[:, 0] += mean[:, 0]  # T_0(y) T_0(x) = 1
    ok &= np.all(np.isfinite(coef), axis=(1, 2))
    coef = coef.reshape(n, my, mx, 4).transpose(3, 0, 1, 2)
    return np.ascontiguousarray(coef), ok, tx, ty


def exact_psf_nodes(lens: Lens, *, stop_radius_mm: float, aperture_xy_mm: np.ndarray,
                    field_deg: tuple[float, float] = (0.0, 0.0),
                    distance_mm: float = math.inf, wavelength_nm: float,
                    focus_offset_mm: float = 0.0, width: int, height: int, width_mm: float,
                    height_mm: float = 0.0, center_x_mm: float = 0.0,
                    center_y_mm: float = 0.0, nodes: int = 9,
                    facts: LensFacts | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`exact_psf` ("pupils" clipping) with exact rays from each stop point aimed at
    a ``nodes`` x ``nodes`` grid of Chebyshev nodes spanning the window, and the
    sensor-side outputs (x_i, y_i, tau_i, phi_i) interpolated to the pixels by the tensor
    polynomial through them, where they land (:func:`_node_rays`). Across a window of
    tens of micrometres these are polynomials of low degree in the pixel position
    (phi_i: a tilt, a curvature of ~1e-2 waves, then higher terms many decades
    smaller), so 9 nodes interpolate them to rounding
    (tests/fit/test_psf.py checks it against every pair traced).

    Returns (U (height, width), used (N,)): the stop points that entered the sum are
    those in the disc whose object-side ray passes and whose every node ray exists; a
    comparison with :func:`poly_psf` should pass it ``aperture_xy_mm[used]``. ``facts``:
    ``lens_facts(lens)``, when the caller has it."""
    if not (isinstance(nodes, int) and nodes >= 2):
        raise ValueError(f"nodes = {nodes!r}: expected at least 2 Chebyshev nodes per axis")
    lam, xs, ys, ap, inside, x_O, y_O, u_O, z_s = _checked_inputs(
        stop_radius_mm, aperture_xy_mm, field_deg, distance_mm, wavelength_nm,
        focus_offset_mm, width, height, width_mm, height_mm, center_x_mm, center_y_mm)
    facts = facts or lens_facts(lens)
    used = np.zeros(len(ap), dtype=bool)
    idx = np.nonzero(inside)[0]
    def neighbours(xa: np.ndarray, ya: np.ndarray, guess: np.ndarray | None = None
                   ) -> Aimed:
        """The flux's rays: only where they cross z = 0 counts (no Fresnel loss)."""
        return aim_object_side(lens, x_O, y_O, u_O, xa, ya, lam, guess=guess,
                               outputs=False)
    obj = aim_object_side(lens, x_O, y_O, u_O, ap[idx, 0], ap[idx, 1], lam)
    pass_o = _passes(obj, facts.housing_first_mm, "pupils")
    idx, phi_o, tau_o = idx[pass_o], obj.outputs[pass_o, 3], obj.outputs[pass_o, 2]
    slopes = obj.dir[pass_o, :2] / obj.dir[pass_o, 2:]  # leaving the stop
    # The flux's neighbour rays, aimed from each central ray's own Jacobian
    near = _flux_guesses(lens, x_O, y_O, u_O, lam, ap[idx], obj.unknowns[pass_o])
    flux = exact_front_flux(neighbours, x_O, y_O, u_O, ap[idx], guess=near)
    good = np.isfinite(flux)
    idx, phi_o, tau_o = idx[good], phi_o[good], tau_o[good] * flux[good]
    slopes = slopes[good]
    # Each point's rays to the window, its outputs as polynomials of the pixel position
    (gx, _), (gy, _) = _chebyshev(xs, nodes), _chebyshev(ys, nodes)
    out, good, wx, wy = _node_rays(lens, ap[idx], slopes, xs, ys, gx, gy, z_s, lam)
    out = np.ascontiguousarray(out[:, good])  # (outputs, points, rows, cols)
    idx, phi_o, tau_o = idx[good], phi_o[good], tau_o[good]
    used[idx] = True
    k_wave = 2.0 * math.pi / (lam * 1e-6)
    u = np.zeros((height, width), dtype=np.complex128)
    # The points whose x_i, y_i lie inside the last surface's housing at every pixel
    # skip its test: each polynomial's value is at most the sum of its coefficients'
    # magnitudes (|T_k| <= 1 over the window), and those bound (x_i, y_i) within the
    # housing (the margin: that sum's rounding)
    bound = np.abs(out[:2]).sum(axis=(2, 3)) * (1.0 + 1e-12)
    clear = bound[0] ** 2 + bound[1] ** 2 < facts.housing_last_mm**2
    step = max(1, SUM_PAIRS // (width * height))
    for points in (np.nonzero(clear)[0], np.nonzero(~clear)[0]):
        for a in range(0, len(points), step):
            sl = points[a:a + step]
            if clear[sl[0]]:
                # tau_i and phi_i at the pixel centres (outputs, points, rows, columns): the
                # polynomials' columns evaluated, then their rows (two matrix products)
                tau_i, phi_i = wy @ (out[2:, sl] @ wx.T)
                ok = None
            else:
                x_i, y_i, tau_i, phi_i = wy @ (out[:, sl] @ wx.T)
                ok = x_i**2 + y_i**2 <= facts.housing_last_mm**2
            _add_phasors(u, ok, tau_o[sl, None, None] * tau_i,
                         k_wave * (phi_o[sl, None, None] + phi_i), axis=0)
    return u, used


# (stop point, pixel) pairs summed at once, by both PSF sums of the check: the dozen
# arrays of a phasor sum (_add_phasors) then stay in the core's L2 cache. Measured on
# 2304 pixels x 1024 points (ns a pair, the least of five): 21.7 with 147k pairs, 18.6
# with 74k, 15.9 with 18k, 17.1 with 9k
SUM_PAIRS = 1 << 14


def _add_phasors(u: np.ndarray, ok: np.ndarray | None, power: np.ndarray,
                 phase: np.ndarray, axis: int) -> None:
    """u += the sum over the points' ``axis`` (0 or -1) of sqrt(power) exp(i phase)
    where ``ok`` (None: everywhere), as a real sum of cosines and one of sines (a
    complex exp and product cost twice as much). ``power`` and ``phase`` are
    overwritten."""
    amp = np.sqrt(np.maximum(power, 0.0, out=power), out=power)  # a fit may dip below 0
    if ok is not None:
        amp *= ok
    shape, spec = ((len(amp), -1), "jp,jp->p") if axis == 0 else ((-1, amp.shape[-1]),
                                                                  "pj,pj->p")
    amp, phase = amp.reshape(shape), phase.reshape(shape)
    cos, sin = _cos_sin(phase)
    re = np.einsum(spec, amp, cos)
    im = np.einsum(spec, amp, sin)
    u += (re + 1j * im).reshape(u.shape)


# cos and sin by a table of COS_SIN_TABLE angles 2 pi m / COS_SIN_TABLE and a Taylor
# step from the nearest (_cos_sin): numpy's cos and sin of float64 are scalar libm calls
# (~35 ns each here, the PSF check's largest cost); this is ~4 ns a pass
COS_SIN_TABLE = 4096
_TABLE_ANGLES = 2.0 * math.pi * np.arange(COS_SIN_TABLE) / COS_SIN_TABLE
_TABLE_COS, _TABLE_SIN = np.cos(_TABLE_ANGLES), np.sin(_TABLE_ANGLES)


def _cos_sin(phase: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cos(phase), sin(phase)), each within ~1e-15 + 2e-16 |phase| of numpy's (the
    phase's own rounding: at 1e6 rad a few 1e-10, while Newton's tolerance on the rays
    moves an exact phase by ~1e-5 rad). ``phase`` = 2 pi (m + f) / COS_SIN_TABLE with m
    an integer and |f| <= 1/2: the table holds cos and sin of 2 pi m / COS_SIN_TABLE
    (m modulo the table), and those of the rest r = 2 pi f / COS_SIN_TABLE (|r| <= 7.7e-4)
    are Taylor's 1 - r^2/2 + r^4/24 (error r^6/720 < 1e-21) and r - r^3/6 (r^5/120 <
    3e-18); the angle sum gives the phase's. ``phase`` is overwritten."""
    t = np.multiply(phase, COS_SIN_TABLE / (2.0 * math.pi), out=phase)
    m = np.rint(t)
    r = np.subtract(t, m, out=t)
    r *= 2.0 * math.pi / COS_SIN_TABLE
    i = m.astype(np.int64)
    np.bitwise_and(i, COS_SIN_TABLE - 1, out=i)  # m modulo the table (two's complement)
    tc, ts = np.take(_TABLE_COS, i), np.take(_TABLE_SIN, i)
    r2 = np.multiply(r, r, out=m)
    s = r2 * r  # sin r = r - r^3/6
    s *= -1.0 / 6.0
    s += r
    c = r2 * (1.0 / 24.0)  # cos r = 1 - r^2/2 + r^4/24
    c -= 0.5
    c *= r2
    c += 1.0
    cos = tc * c  # the angle sum
    cos -= ts * s
    ts *= c
    tc *= s
    ts += tc
    return cos, ts


def _system(systems: Sequence[System], name: str) -> System:
    for s in systems:
        if s.name == name:
            return s
    raise ValueError(f"systems: expected the general {name} (a lens's fit.json or table), "
                     f"found {[s.name for s in systems]}")


def _check_domain(system: System, values: dict[str, np.ndarray | float]) -> None:
    """Inputs outside the fitted domain are an error: the polynomials are not meant there."""
    for inp in system.inputs:
        if inp.name not in values:  # checked by the caller (before a specialisation)
            continue
        v = np.asarray(values[inp.name], dtype=np.float64)
        slack = 1e-12 * max(abs(inp.lo), abs(inp.hi))
        if v.size and (v.min() < inp.lo - slack or v.max() > inp.hi + slack):
            bad = float(v.min() if v.min() < inp.lo - slack else v.max())
            raise ValueError(f"{system.name}: input {inp.name} = {bad:.9g} {inp.unit} is "
                             f"outside the fitted domain [{inp.lo:.9g}, {inp.hi:.9g}]")


def _separable_parts(system: System, fixed: dict[str, float], rows: dict[str, np.ndarray],
                     cols: dict[str, np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """``system`` on the grid (rows x cols) as one matrix product per output: its inputs
    split into fixed values, inputs that vary over rows and inputs that vary over
    columns, each output's grid is ``row @ col.T`` for its (row (R, M), col (C, M)) in
    the list returned. Each term c prod xhat^e factors into (row part) (fixed part)
    (column part); M is the number of distinct row monomials: the same polynomial as
    System.evaluate, summed in another order (agreement to ~1e-15 of the sum of
    |terms|). A caller may take the product over slices of the columns."""
    _check_domain(system, {**fixed, **rows, **cols})
    names = system.input_names
    idx = {k: [names.index(n) for n in group] for k, group in
           (("f", fixed), ("r", rows), ("c", cols))}
    if sorted(idx["f"] + idx["r"] + idx["c"]) != list(range(len(names))):
        raise ValueError(f"{system.name}: inputs {names} are not split exactly into fixed "
                         f"{list(fixed)}, rows {list(rows)} and columns {list(cols)}")

    def normalised(group: dict[str, np.ndarray | float]) -> np.ndarray:
        if not group:
            return np.zeros((1, 0))
        return np.column_stack([system.inputs[names.index(n)].normalise(np.atleast_1d(v))
                                for n, v in group.items()])

    f_hat, r_hat, c_hat = normalised(fixed), normalised(rows), normalised(cols)
    out = []
    for p in system.outputs:
        w = (p.coefficients * design_matrix(f_hat, p.exponents[:, idx["f"]])[0] if fixed
             else p.coefficients)
        # Terms that share their row monomial are summed over the columns first: a
        # tensor fit has thousands of terms but tens of distinct monomials of the pixel
        # position, so the grid costs rows x columns x (distinct row monomials) rather
        # than x (terms) (the PSF check of lens 0001: 25x fewer products)
        rows_e, which = np.unique(p.exponents[:, idx["r"]], axis=0, return_inverse=True)
        which = which.reshape(-1)
        order = np.argsort(which, kind="stable")
        starts = np.searchsorted(which[order], np.arange(len(rows_e)))
        b = design_matrix(c_hat, p.exponents[order][:, idx["c"]]) * w[order]  # (C, T)
        out.append((design_matrix(r_hat, rows_e), np.add.reduceat(b, starts, axis=1)))
    return out


def _separable(system: System, fixed: dict[str, float], rows: dict[str, np.ndarray],
               cols: dict[str, np.ndarray]) -> np.ndarray:
    """``system`` on the grid (rows x cols), (n_outputs, R, C) (:func:`_separable_parts`)."""
    return np.stack([r @ c.T for r, c in _separable_parts(system, fixed, rows, cols)])


def poly_psf(systems: Sequence[System], *, facts: LensFacts | None = None,
             stop_radius_mm: float, aperture_xy_mm: np.ndarray,
             field_deg: tuple[float, float] = (0.0, 0.0), distance_mm: float = math.inf,
             wavelength_nm: float, focus_offset_mm: float = 0.0, width: int, height: int,
             width_mm: float, height_mm: float = 0.0, center_x_mm: float = 0.0,
             center_y_mm: float = 0.0, batch_pairs: int = SUM_PAIRS) -> np.ndarray:
    """:func:`exact_psf` with the fitted polynomials: ``systems`` holds the general P_o
    and P_s (``read_fit_json`` or ``read_table``); ``facts`` gives the housing radii
    (default: ``systems.lens`` of a version-2 table). Clipping is the "pupils" test, and
    for a ghost table (``read_table`` of one) its P_clip tests too (:func:`clip_passes`).
    Inputs outside the fitted domain raise ValueError.

    The polynomials are those of ``System.evaluate``; P_s is evaluated on the grid of
    pixels x points as one matrix product per output (:func:`_separable`), which sums
    the same terms in another order (tests/fit/test_psf.py checks the two agree)."""
    if facts is None:
        facts = getattr(systems, "lens", None)
        if facts is None:
            raise ValueError("facts: expected the lens facts (lensfit.paraxial.facts.lens_facts, "
                             "or read_table(...).lens of a version-2 table), found None")
    p_o, p_s = _system(systems, "P_o"), _system(systems, "P_s")
    lam, xs, ys, ap, inside, x_O, y_O, u_O, z_s = _checked_inputs(
        stop_radius_mm, aperture_xy_mm, field_deg, distance_mm, wavelength_nm,
        focus_offset_mm, width, height, width_mm, height_mm, center_x_mm, center_y_mm)

    # Object side (one light: P_o over the aperture points), then the first-surface test
    pts = ap[inside]
    light = {"x_O": x_O, "y_O": y_O, "u_O": u_O, "lambda": lam}
    _check_domain(p_o, light)
    o = _evaluate(p_o.specialise(light), {"x_a": pts[:, 0], "y_a": pts[:, 1]})
    x_o, y_o, tau_o, phi_o = (o[p_o.output_names.index(n)] for n, _ in OUTPUTS_O)
    pass_o = x_o**2 + y_o**2 <= facts.housing_first_mm**2
    ghost = getattr(systems, "ghost", None)
    clip = next((s for s in systems if s.name == "P_clip"), None)
    if clip is not None and ghost.side == "P_o":
        c = _evaluate(clip.specialise(light), {"x_a": pts[:, 0], "y_a": pts[:, 1]})
        pass_o &= clip_passes(clip, c, stop_radius_mm)
    tau_o = tau_o * poly_front_flux(p_o, light, pts, x_o, y_o)
    pts, tau_o, phi_o = pts[pass_o], tau_o[pass_o], phi_o[pass_o]
    cols = [p_s.output_names.index(n) for n, _ in OUTPUTS_S]  # x_i, y_i, tau_i, phi_i

    # Sensor side: pixels x points in tiles, then the last-surface test
    gx, gy = np.meshgrid(xs, ys)  # (height, width): row 0 at the top
    pix = {"x_S": gx.reshape(-1), "y_S": gy.reshape(-1)}
    k_wave = 2.0 * math.pi / (lam * 1e-6)
    u = np.zeros(width * height, dtype=np.complex128)
    # Tiles of up to TILE_POINTS points by as many pixels as make batch_pairs: each
    # matrix product below then reads both its factors' tiles once per thousands of
    # pairs (a chunk of a few points across every pixel read the pixels' whole factor)
    tile_pts = min(max(1, len(pts)), TILE_POINTS)
    tile_pix = max(1, _batch(batch_pairs) // tile_pts)
    # Fold z_S and lambda in first: a tensor fit's terms then merge ~15-fold
    _check_domain(p_s, {"z_S": z_s, "lambda": lam})
    p_s = p_s.specialise({"z_S": z_s, "lambda": lam})
    clip_s = (clip.specialise({"z_S": z_s, "lambda": lam})
              if clip is not None and ghost.side == "P_s" else None)
    # Each output's pixel and stop-point parts once per cell; per chunk of points only
    # their matrix products
    ap_cols = {"x_a": pts[:, 0], "y_a": pts[:, 1]}
    parts = _separable_parts(p_s, {}, pix, ap_cols)
    parts = [parts[c] for c in cols]
    clip_parts = _separable_parts(clip_s, {}, pix, ap_cols) if clip_s is not None else None
    for p0 in range(0, width * height, tile_pix):
        ps = slice(p0, p0 + tile_pix)
        # Bounds of |x_i| and |y_i| over the pixel tile, per point: the sum of its terms'
        # magnitudes, each column's largest over the tile (the margin: their rounding)
        bx, by = (np.abs(c) @ np.abs(r[ps]).max(axis=0) * (1.0 + 1e-12) for r, c in parts[:2])
        clear = bx**2 + by**2 < facts.housing_last_mm**2
        for a in range(0, len(pts), tile_pts):
            sl = slice(a, a + tile_pts)
            # (pixels, points) of the tile; where every point's bound lies inside the
            # last surface's housing, without its test
            if np.all(clear[sl]):
                tau_i, phi_i = (r[ps] @ c[sl].T for r, c in parts[2:])
                ok = None
            else:
                x_i, y_i, tau_i, phi_i = (r[ps] @ c[sl].T for r, c in parts)
                ok = x_i**2 + y_i**2 <= facts.housing_last_mm**2
            if clip_parts is not None:
                ok = np.ones(tau_i.shape, dtype=bool) if ok is None else ok
                ok &= clip_passes(clip_s, np.stack([r[ps] @ c[sl].T for r, c in clip_parts]),
                                  stop_radius_mm)
            _add_phasors(u[ps], ok, tau_o[sl] * tau_i, k_wave * (phi_o[sl] + phi_i), axis=-1)
    return u.reshape(height, width)


TILE_POINTS = 128  # stop points of a tile of poly_psf's sum (pixels: SUM_PAIRS over these)


def clip_passes(clip: System, values: np.ndarray, stop_radius_mm: float) -> np.ndarray:
    """The verdict of a ghost table's P_clip outputs ``values`` (2K, ...): every pair
    passes (x_h, y_h: norm <= 1, a housing; x_s, y_s: inside the round stop)."""
    ok = np.ones(values.shape[1:], dtype=bool)
    for k in range(0, len(clip.outputs), 2):
        limit = stop_radius_mm if clip.outputs[k].output.startswith("x_s") else 1.0
        ok &= values[k] ** 2 + values[k + 1] ** 2 <= limit * limit
    return ok


def _evaluate(system: System, values: dict[str, np.ndarray | float]) -> np.ndarray:
    """``system`` at raw inputs given by name (arrays of one length, or scalars):
    System.evaluate, outputs as rows (n_outputs, N)."""
    _check_domain(system, values)
    n = max(np.size(v) for v in values.values())
    x = np.column_stack([np.broadcast_to(values[name], (n,)) for name in system.input_names])
    return system.evaluate(x).T


# --- geometry: image points, focus, working f-number ---------------------------------------


def _rear_trace(lens: Lens, aimed: Aimed, lam: float, end_z: float) -> Rays:
    """Continue object-side rays (ending on the stop) through the rear half to z = end_z.
    Rays that did not reach the stop (not ``aimed.ok``: NaN where they failed) come back
    MISSED, traced from a stand-in (lens 0003's corner rays at f/2: its window in the
    PSF check stopped on them with "positions and directions must be finite")."""
    s, n = lens.stop_index, len(lens.surfaces)
    failed = ~(np.all(np.isfinite(aimed.pos), axis=1) & np.all(np.isfinite(aimed.dir), axis=1))
    pos = np.where(failed[:, None], [0.0, 0.0, float(lens.vertex_z[s])], aimed.pos)
    direction = np.where(failed[:, None], [0.0, 0.0, 1.0], aimed.dir)
    out = trace(lens, Rays(pos, direction, lam), [Step(k) for k in range(s + 1, n)],
                clip=False, end_z=end_z)
    if np.any(failed):
        out.status[failed] = Status.MISSED
    return out


def geometric_image_point(lens: Lens, field_deg: tuple[float, float],
                          distance_mm: float = math.inf, wavelength_nm: float = 550.0,
                          focus_offset_mm: float = 0.0) -> tuple[float, float]:
    """Where the chief ray (through the stop centre) of the light meets the sensor moved
    by ``focus_offset_mm`` (z_S): (x, y) in mm."""
    lam = _wavelength(wavelength_nm)
    chief = _chief_ray(lens, field_deg, distance_mm, lam)
    return _chief_image(lens, chief, field_deg, lam, focus_offset_mm)


def _chief_ray(lens: Lens, field_deg: tuple[float, float], distance_mm: float,
               lam: float) -> Aimed:
    """The light's ray through the stop centre, aimed on the object side."""
    x_O, y_O = light_direction(*field_deg)
    chief = aim_object_side(lens, x_O, y_O, _inverse_distance(distance_mm), 0.0, 0.0, lam)
    if not chief.ok[0]:
        raise ValueError(f"field_deg = {tuple(field_deg)!r}: the chief ray of {lens.name} "
                         "misses or does not converge")
    return chief


def _chief_image(lens: Lens, chief: Aimed, field_deg: tuple[float, float], lam: float,
                 focus_offset_mm: float) -> tuple[float, float]:
    """Where ``chief`` meets the sensor moved by ``focus_offset_mm``: (x, y) in mm."""
    out = _rear_trace(lens, chief, lam, lens.sensor_z + _check_focus(focus_offset_mm))
    if out.status[0] != Status.OK:
        raise ValueError(f"field_deg = {tuple(field_deg)!r}: the chief ray of {lens.name} "
                         f"fails behind the stop (status {Status(out.status[0]).name})")
    return float(out.pos[0, 0]), float(out.pos[0, 1])


def wavefront_rms_waves(lens: Lens, stop_radius_mm: float, wavelength_nm: float,
                        focus_offset_mm: float, *, field_deg: tuple[float, float] = (0.0, 0.0),
                        distance_mm: float = math.inf, points: int = 400) -> float:
    """RMS wavefront error (waves) over the stop disc, piston and tilt removed, of the
    exact OPL phi_o + phi_i to the chief ray's image point on the sensor at z_S."""
    return _wavefront(lens, stop_radius_mm, _wavelength(wavelength_nm), field_deg,
                      distance_mm, points)(_check_focus(focus_offset_mm))


def _wavefront(lens: Lens, stop_radius_mm: float, lam: float,
               field_deg: tuple[float, float], distance_mm: float,
               points: int) -> Callable[[float], float]:
    rms = _wavefronts(lens, [stop_radius_mm], lam, field_deg, distance_mm, points)
    return lambda z_s: rms([(0, z_s)])[0]


def _wavefronts(lens: Lens, stop_radii: Sequence[float], lam: float,
                field_deg: tuple[float, float], distance_mm: float, points: int
                ) -> Callable[[Sequence[tuple[int, float]]], list[float]]:
    """RMS wavefront error (waves) of :func:`wavefront_rms_waves` for stops ``stop_radii``:
    a function of [(stop index, z_S), ...] that aims the sensor-side rays of them all in
    one call (each ray is Newton's alone: the same rays as one call per stop)."""
    x_O, y_O = light_direction(*field_deg)
    stops = []
    for radius in stop_radii:
        ap = sunflower_points(points, radius)
        obj = aim_object_side(lens, x_O, y_O, _inverse_distance(distance_mm), ap[:, 0],
                              ap[:, 1], lam)
        stops.append((ap[obj.ok], obj.outputs[obj.ok, 3]))
    chief = _chief_ray(lens, field_deg, distance_mm, lam)  # the same for every z_S

    def rms(asked: Sequence[tuple[int, float]]) -> list[float]:
        # Each stop's rays to the chief ray's image on its sensor, all aimed together
        centres = [_chief_image(lens, chief, field_deg, lam, z_s) for _, z_s in asked]
        rows = [len(stops[k][0]) for k, _ in asked]
        ap = np.concatenate([stops[k][0] for k, _ in asked])
        xc, yc, zs = (np.repeat(v, rows) for v in (*np.transpose(centres), [z for _, z in asked]))
        # Without the vignetting's history: phi_i is the same, its trace cheaper
        sen = aim_sensor_side(lens, xc, yc, zs, ap[:, 0], ap[:, 1], lam, vignetting=False)
        out = []
        for (k, _), lo, hi in zip(asked, np.cumsum([0, *rows[:-1]]), np.cumsum(rows),
                                  strict=True):
            ok, phi_i = sen.ok[lo:hi], sen.outputs[lo:hi, 3]
            w = (stops[k][1] + phi_i)[ok]
            a = np.column_stack([np.ones(len(w)), stops[k][0][ok]])
            residual = w - a @ np.linalg.lstsq(a, w, rcond=None)[0]
            out.append(float(np.sqrt(np.mean(residual**2)) / (lam * 1e-6)))
        return out

    return rms


def _bounded_minimum(bounds: tuple[float, float], xatol: float
                     ) -> Generator[float, float, float]:
    """scipy.optimize.minimize_scalar(method="bounded") as a generator: it yields each x
    to evaluate, is sent f(x), and returns the minimum's x. The same steps, line for
    line (scipy 1.17's _minimize_scalar_bounded, maxiter 500), so that several searches
    can run side by side, their evaluations made together (tests/fit/test_psf.py
    checks it against scipy)."""
    sqrt_eps = math.sqrt(2.2e-16)
    golden_mean = 0.5 * (3.0 - math.sqrt(5.0))
    a, b = bounds
    fulc = a + golden_mean * (b - a)
    nfc, xf = fulc, fulc
    rat = e = 0.0
    x = xf
    fx = yield x
    num = 1
    ffulc = fnfc = fx
    xm = 0.5 * (a + b)
    tol1 = sqrt_eps * np.abs(xf) + xatol / 3.0
    tol2 = 2.0 * tol1
    while np.abs(xf - xm) > (tol2 - 0.5 * (b - a)):
        golden = 1
        # Check for parabolic fit
        if np.abs(e) > tol1:
            golden = 0
            r = (xf - nfc) * (fx - ffulc)
            q = (xf - fulc) * (fx - fnfc)
            p = (xf - fulc) * q - (xf - nfc) * r
            q = 2.0 * (q - r)
            if q > 0.0:
                p = -p
            q = np.abs(q)
            r = e
            e = rat
            # Check for acceptability of parabola
            if (np.abs(p) < np.abs(0.5 * q * r)) and (p > q * (a - xf)) and (p < q * (b - xf)):
                rat = (p + 0.0) / q
                x = xf + rat
                if ((x - a) < tol2) or ((b - x) < tol2):
                    si = np.sign(xm - xf) + ((xm - xf) == 0)
                    rat = tol1 * si
            else:  # a golden-section step
                golden = 1
        if golden:  # a golden-section step
            e = a - xf if xf >= xm else b - xf
            rat = golden_mean * e
        si = np.sign(rat) + (rat == 0)
        x = xf + si * np.maximum(np.abs(rat), tol1)
        fu = yield x
        num += 1
        if fu <= fx:
            if x >= xf:
                a = xf
            else:
                b = xf
            fulc, ffulc = nfc, fnfc
            nfc, fnfc = xf, fx
            xf, fx = x, fu
        else:
            if x < xf:
                a = x
            else:
                b = x
            if (fu <= fnfc) or (nfc == xf):
                fulc, ffulc = nfc, fnfc
                nfc, fnfc = x, fu
            elif (fu <= ffulc) or (fulc == xf) or (fulc == nfc):
                fulc, ffulc = x, fu
        xm = 0.5 * (a + b)
        tol1 = sqrt_eps * np.abs(xf) + xatol / 3.0
        tol2 = 2.0 * tol1
        if num >= 500:
            break
    return xf


def best_focus_offset(lens: Lens, stop_radius_mm: float, wavelength_nm: float, *,
                      field_deg: tuple[float, float] = (0.0, 0.0),
                      distance_mm: float = math.inf, points: int = 400) -> float:
    """The sensor shift z_S (mm) with the least RMS wavefront error over the stop disc
    (:func:`wavefront_rms_waves`: exact traces, piston and tilt removed), which for a
    nearly diffraction-limited image is the sharpest (Maréchal). Searched within 5% of
    the focal length around the paraxial image at ``wavelength_nm``."""
    return best_focus_offsets(lens, [stop_radius_mm], wavelength_nm, field_deg=field_deg,
                              distance_mm=distance_mm, points=points)[0]


def best_focus_offsets(lens: Lens, stop_radii: Sequence[float], wavelength_nm: float, *,
                       field_deg: tuple[float, float] = (0.0, 0.0),
                       distance_mm: float = math.inf, points: int = 400) -> list[float]:
    """:func:`best_focus_offset` of each stop radius, the searches run side by side: each
    round's wavefronts of every stop still searching are aimed in one call (the PSF
    check's three stops: 53 calls became 19). The same searches and rays, the same
    results."""
    lam = _wavelength(wavelength_nm)
    f = abs(paraxial(lens, wavelength_nm=lam).efl_mm)
    d_paraxial = image_distance(lens, distance_mm, wavelength_nm=lam)
    z_paraxial = float(lens.vertex_z[-1] + d_paraxial - lens.sensor_z)
    lo = max(z_paraxial - 0.05 * f, float(lens.vertex_z[-1] - lens.sensor_z) + 1e-3)
    rms = _wavefronts(lens, stop_radii, lam, field_deg, distance_mm, points)
    searches = [_bounded_minimum((lo, z_paraxial + 0.05 * f), 1e-7) for _ in stop_radii]
    asked = {k: next(search) for k, search in enumerate(searches)}
    best: dict[int, float] = {}
    while asked:
        order = sorted(asked)
        for k, value in zip(order, rms([(k, asked[k]) for k in order]), strict=True):
            try:
                asked[k] = searches[k].send(value)
            except StopIteration as done:
                best[k] = float(done.value)
                del asked[k]
    return [best[k] for k in range(len(stop_radii))]


def working_f_number(lens: Lens, stop_radius_mm: float, wavelength_nm: float,
                     distance_mm: float = math.inf) -> float:
    """1 / (2 NA) on axis, NA = sine of the angle of the marginal rays (through the edge of
    the stop disc) behind the last surface, averaged over four of them (±x, ±y)."""
    lam = _wavelength(wavelength_nm)
    r = float(stop_radius_mm)
    edge = np.array([[r, 0.0], [-r, 0.0], [0.0, r], [0.0, -r]])
    obj = aim_object_side(lens, 0.0, 0.0, _inverse_distance(distance_mm), edge[:, 0],
                          edge[:, 1], lam)
    if not np.all(obj.ok):
        raise ValueError(f"stop_radius_mm = {stop_radius_mm!r}: a marginal ray of "
                         f"{lens.name} misses or does not converge")
    out = _rear_trace(lens, obj, lam, lens.sensor_z)
    na = float(np.mean(np.hypot(out.dir[:, 0], out.dir[:, 1])))
    return 1.0 / (2.0 * na)
