"""Ghost enumeration and ranking (issue 13, deliverable 1).

A ghost is the two-bounce path (i, j), i < j: forward to j, reflect there, back to i,
reflect there, forward to the sensor (``lensfit.trace.tracer.ghost_path``). Every pair of
surfaces of the model except stop planes is a ghost (/work/notes/ghost-design.md).

Each ghost is estimated from a quick exact trace with the lens's coatings, the stop at
the chosen f-number and every housing clipping at every crossing:

* **Bundle, pass 1.** A square grid of rays (``rays`` per wavelength) on a plane 1 mm
  in front of surface 0, over a disc that holds every ray of the light that can meet
  surface 0 inside its housing: parallel rays from a light at infinity, or rays from a
  point at ``distance_mm`` from the first vertex, each then weighted by the point's
  irradiance on the plane (cos / r^2, relative to the chief ray's). The paths share
  prefixes: the forward states before every surface are traced once, and for each j
  the reflected bundle is carried back one surface at a time, branching into the ghost
  (i, j) at each i. This pass only finds, per path, which launch points reach the
  sensor.
* **Bundle, pass 2.** Each path (the direct one and every ghost) is traced again with
  ``ghost_path`` / ``forward_path`` on a grid of ``fine_rays`` points per wavelength
  over the box of its pass-1 survivors grown by one pass-1 step (a path whose rays all
  enter through a region narrower than that step can be missed). Every ray stands for
  the area h^2 of its grid cell, so a path's power is h^2 times the sum of the rays'
  final transmittances (the light's irradiance on the launch plane is the unit): the
  ghost's energy relative to the direct image is the ratio of two such sums, and its
  throughput the ghost's power over the power entering (pass-1 rays inside surface 0's
  housing).
* **Footprint.** A 2-D histogram of the sensor hits weighted by their power; its bins
  are square, M per side of the hits' bounding box with M = sqrt(hits / 8) clamped to
  [4, 128] (about 8 rays per occupied bin). The footprint is the set of bins whose
  irradiance is above 1% of the mean irradiance of the lit bins (the issue's "area with
  irradiance above 1% of its mean"); ``radius_mm`` is the radius of the disc of that
  area; ``extent_mm`` the largest distance of a hit from the power centroid (the
  geometric blur radius); ``centre_mm`` the power centroid.
* **Peaks.** A ghost's peak irradiance is the largest power in one histogram bin over
  the bin's area (bins of the footprint size above but never finer than the ghost's own
  Airy radius 0.61 lambda / NA; the maximum of four grids shifted by half a bin, so a
  spot split by bin edges is not halved), and at most the ghost's diffraction limit
  P pi NA^2 / lambda^2 (the Cauchy-Schwarz bound on the irradiance of a field whose
  directions lie in a disc of radius NA; NA = the largest spread of the ghost's ray
  directions at the sensor plus lambda / D for a footprint of diameter D, so that a
  collimated ghost is not bounded to zero). A caustic (rays focused to a point) thus
  gives a finite peak.
  The direct image's peak is the Airy peak of the working f-number, P pi / (4 lambda^2
  N_x N_y) (N_x = N_y except for an anamorphic lens), times a Strehl estimate: the
  ratio of the direct image's geometric peak (the histogram above with bins of the
  Airy radius, or the footprint's bins where those are coarser) to the Airy peak, at
  most 1. Direction of error: the Airy peak is the highest the direct image can have;
  the Strehl estimate lowers it where the lens is aberrated, and coarse bins lower it
  further, so the direct peak is if anything underestimated and the ghosts' relative
  peaks overestimated: the ranking errs towards keeping a ghost. What errs the other
  way: a ghost's features finer than its bins (a sharp caustic rim on a large ghost)
  are averaged over a bin, and off axis a vignetted pupil has a lower Airy peak than
  the full one's for the same power.
* **Visibility** (issue 26), as a photograph of a bright light shows a ghost. Both peaks
  are taken again as a camera records them, averaged over a pixel of ``pixel_mm``
  (default 6 um, a 24-megapixel full-frame sensor): the ghost's from histogram bins no
  finer than a pixel; the direct image's likewise from its rays, but at most its
  diffraction limit's, P EE(r) / pixel^2, where EE(r) = 1 - J0(v)^2 - J1(v)^2 (v = pi r /
  (lambda sqrt(N_x N_y))) is the Airy pattern's power within the disc of the pixel's
  area, r = pixel / sqrt(pi) (a pixel centred on the peak; it tends to the Airy peak as
  the pixel shrinks). Against lensrt's Huygens PSF on the same pixels the direct one is
  0.6-1.1 of the rendered peak pixel on the axis (tests/runtime/test_ghost_visibility.py:
  a defocused core is spread further by diffraction than by its rays, so ghosts mostly
  err towards visible; 1.3 measured off axis, 0001 at f/8). Their ratio is
  ``pixel_peak``, and
  ``exposure_peak`` is its largest over the wavelengths. The photograph is exposed for
  the scene, so the light's own image is far above white: its peak pixel is
  ``overexposure`` stops over white (default 16: the sun's image over a sunlit white
  wall, 1.6e9 against about 3e4 cd/m^2), and the print or screen shows DISPLAY_STOPS = 8
  stops below white before black. A ghost is **visible** when its peak pixel reaches
  that black level: exposure_peak >= 2^-(overexposure + 8) (6.0e-8 by default).
  ``visibility_stops`` is how many stops above black it is.
* **Ranking.** By ``exposure_peak``, brightest first; :func:`mark_ghosts` keeps the
  visible ones by default, or the brightest few (``count``), or those whose
  ``relative_peak`` (ghost peak over the direct image's Airy x Strehl peak, unaveraged)
  is above a ``threshold``.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from lensfit.common.errors import InputError
from lensfit.paraxial import paraxial, stop_radius_for_f_number
from lensfit.prescription.model import Lens
from lensfit.psf.psf import light_direction
from lensfit.trace.tracer import Rays, Status, Step, forward_path, ghost_path, trace

DEFAULT_WAVELENGTHS_NM = (450.0, 550.0, 650.0)
# Rays per wavelength over the launch disc (pass 1, finding where each path's rays come
# from) and per path and wavelength over that region (pass 2, the estimate)
DEFAULT_RAYS = 20000
DEFAULT_FINE_RAYS = 4000
# Visibility (module doc): the pixel a photograph is taken with, how far the light's own
# peak pixel is above white, and how many stops below white a displayed photograph shows
DEFAULT_PIXEL_MM = 0.006
DEFAULT_OVEREXPOSURE_STOPS = 16.0
DISPLAY_STOPS = 8.0
# Footprint: bins whose irradiance is above this share of the lit bins' mean
FOOTPRINT_LEVEL = 0.01
# Histogram bins per side: about this many rays per occupied bin, within the bounds
RAYS_PER_BIN = 8
MIN_BINS, MAX_BINS = 4, 128


@dataclass
class GhostEstimate:
    """One ghost (i, j) of a lens: its estimate per wavelength, from exact rays.

    ``first``/``second`` are the model's surface indices (``ghost_path(lens, first,
    second)``), ``first_file``/``second_file`` the lens file's numbering. Per wavelength:
    ``energy`` the ghost's power on the sensor over the direct image's power,
    ``throughput`` its power over the power entering the lens (rays inside surface 0's
    housing), ``centre_mm`` (x, y), ``radius_mm`` (disc of the footprint's area),
    ``area_mm2``, ``extent_mm``, ``peak`` (ghost peak irradiance over the direct PSF's
    peak), ``rays`` (rays reaching the sensor), ``pixel_peak`` (both peaks averaged over
    a pixel, the visibility's ratio). ``relative_peak`` is the largest ``peak``,
    ``exposure_peak`` the largest ``pixel_peak``.
    """

    lens: str
    file: str
    first: int
    second: int
    first_file: int
    second_file: int
    case: str  # "A" both reflections in front of the stop, "B" behind, "C" astride
    wavelengths_nm: tuple[float, ...]
    energy: list[float]
    throughput: list[float]
    centre_mm: list[tuple[float, float] | None]
    radius_mm: list[float]
    area_mm2: list[float]
    extent_mm: list[float]
    peak: list[float]
    rays: list[int]
    pixel_peak: list[float] = field(default_factory=list)  # ghost's / direct's peak pixel
    relative_peak: float = 0.0
    exposure_peak: float = 0.0  # the largest pixel_peak
    kept: bool | None = None  # set by mark_ghosts
    visible: bool | None = None  # set by mark_ghosts (for its overexposure)
    info: dict = field(default_factory=dict, repr=False)  # the run's settings, shared

    @property
    def name(self) -> str:
        """The ghost in the file's numbering, as the table prints it."""
        return f"{self.first_file}-{self.second_file}"

    def visibility_stops(self, overexposure: float = DEFAULT_OVEREXPOSURE_STOPS) -> float:
        """Stops of the ghost's peak pixel above a photograph's black level when the
        light's peak pixel is ``overexposure`` stops over white (module doc); >= 0:
        visible."""
        if not self.exposure_peak > 0:
            return -math.inf
        return math.log2(self.exposure_peak) + overexposure + DISPLAY_STOPS

    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("info")
        d["name"] = self.name
        # The lens file's name, not the path it was given by (records and ghosts.json
        # travel: an absolute path would name one machine's folders)
        d["file"] = Path(self.file).name if self.file else self.file
        d["centre_mm"] = [None if c is None else list(c) for c in self.centre_mm]
        d["wavelengths_nm"] = list(self.wavelengths_nm)
        return d


def black_level(overexposure: float = DEFAULT_OVEREXPOSURE_STOPS) -> float:
    """A photograph's black level as a share of the light's peak pixel when that pixel is
    ``overexposure`` stops over white (module doc, "Visibility"): a ghost whose
    ``exposure_peak`` reaches it is visible."""
    return 2.0 ** -(overexposure + DISPLAY_STOPS)


def ghost_surfaces(lens: Lens) -> list[int]:
    """The surfaces a ghost can reflect at: every surface of the model except the stop
    surface (a stop plane, or for a stop on a refracting surface the bare copy of it the
    loader inserted, which reflects nothing; the refracting surface itself stays)."""
    return [k for k, s in enumerate(lens.surfaces) if not s.stop]


def ghost_pairs(lens: Lens) -> list[tuple[int, int]]:
    """Every ghost (i, j), i < j, of the model's surfaces: n (n - 1) / 2 of them."""
    ks = ghost_surfaces(lens)
    return [(i, j) for a, i in enumerate(ks) for j in ks[a + 1:]]


def parse_ghost(lens: Lens, name: str, where: str) -> tuple[int, int]:
    """Model indices (i, j) of a ghost named "i-j" in the lens file's numbering (as
    ``lensfit ghosts`` prints it). ``where`` starts the error message (the file and key,
    or the option)."""
    m = re.fullmatch(r"\s*([0-9]+)\s*-\s*([0-9]+)\s*", str(name))
    if not m:
        raise InputError(f"{where} {name!r}: expected a ghost as i-j, the lens file's "
                         f"surface numbers (as `lensfit ghosts` prints them)")
    by_file = {lens.file_index(k): k for k in ghost_surfaces(lens)}
    n_file = max(lens.file_index(k) or 0 for k in range(len(lens.surfaces))) + 1
    out = []
    for v in (int(m[1]), int(m[2])):
        if v >= n_file:
            raise InputError(f"{where} {name!r}: surface {v} is out of range: {lens.name} "
                             f"has surfaces 0..{n_file - 1}")
        if v not in by_file:
            raise InputError(f"{where} {name!r}: surface {v} is the stop, which reflects "
                             f"no ghost")
        out.append(by_file[v])
    i, j = out
    if not i < j:
        raise InputError(f"{where} {name!r}: expected i < j (reflect at j, then at i)")
    return i, j


def _case(lens: Lens, i: int, j: int) -> str:
    s = lens.stop_index
    return "A" if j < s else "B" if i > s else "C"


def check_light(lens: Lens, light: tuple[float, float], option: str = "light") -> None:
    """A light inside the lens's field (the default fit domain's: the field of a 36 x 24
    mm frame, or the lens file's [fit] field; an ellipse for an anamorphic lens)."""
    from lensfit.sample import default_domain

    lx, ly = (float(v) for v in light)
    if not (math.isfinite(lx) and math.isfinite(ly) and abs(lx) < 90 and abs(ly) < 90):
        raise InputError(f"{option} {lx:g},{ly:g}: expected angles in (-90, 90) degrees")
    fx, fy = default_domain(lens).field_xy_deg
    tx, ty = math.tan(math.radians(lx)), math.tan(math.radians(ly))
    # 1e-9 relative: a light typed at the field's edge is inside
    if (tx / math.tan(math.radians(fx))) ** 2 + (ty / math.tan(math.radians(fy))) ** 2 > 1 + 1e-9:
        raise InputError(f"{option} {lx:g},{ly:g}: outside the field of {lens.name} "
                         f"({lens.source_file}): half field {fx:.4g} degrees in x, "
                         f"{fy:.4g} in y")


def _source(light: tuple[float, float], distance_mm: float) -> tuple[np.ndarray, np.ndarray | None]:
    """The chief direction (unit, towards the lens) and the source point (None at
    infinity): a light at distance L from the first vertex lies at -L times that
    direction (its chief ray passes the first vertex)."""
    x_o, y_o = light_direction(*light)
    # The light travels opposite to (x_O, y_O, z_O): along (-x_O, -y_O, z_O)
    d = np.array([-x_o, -y_o, math.sqrt(max(0.0, 1.0 - x_o * x_o - y_o * y_o))])
    return d, (None if math.isinf(distance_mm) else -distance_mm * d)


def _rays_at(px: np.ndarray, py: np.ndarray, z0: float, lams: np.ndarray, chief: np.ndarray,
             src: np.ndarray | None) -> Rays:
    """Rays through the launch points (px, py, z0), every wavelength, from a light at
    infinity along ``chief`` or from the point ``src``. The initial transmittance is the
    light's irradiance on the launch plane relative to the chief's (1 at infinity; an
    isotropic point: cos / r^2), so every sum of transmittances times the grid cell is
    a power in the same unit."""
    n_lam = len(lams)
    pos = np.column_stack([np.tile(px, n_lam), np.tile(py, n_lam), np.full(px.size * n_lam, z0)])
    lam = np.repeat(lams, px.size)
    if src is None:
        return Rays(pos, np.broadcast_to(chief, pos.shape), lam)
    v = pos - src
    r2 = np.einsum("ij,ij->i", v, v)
    dz = v[:, 2] / np.sqrt(r2)
    weight = (dz / chief[2]) * float(np.dot(src, src)) / r2
    return Rays(pos, v, lam, transmittance=weight)


def _launch(lens: Lens, light: tuple[float, float], rays: int, wavelengths: np.ndarray,
            distance_mm: float = math.inf) -> tuple[Rays, float]:
    """The grid of rays over the disc (on a plane 1 mm in front of surface 0) that holds
    every ray of the light meeting surface 0 inside its housing, all wavelengths;
    returns the rays and the grid step h (mm)."""
    d, src = _source(light, distance_mm)
    s0 = lens.surfaces[0]
    sd = s0.semi_diameter_mm
    # The z range of surface 0 inside its housing (rim and vertex)
    phi = np.linspace(0.0, 2 * np.pi, 73)
    rim = np.concatenate([[0.0], np.nan_to_num(s0.sag(sd * np.cos(phi), sd * np.sin(phi)))])
    z_lo, z_hi = float(min(0.0, rim.min())), float(max(0.0, rim.max()))
    z0 = z_lo - 1.0
    if src is None:
        # A ray meeting surface 0 at (x, y, z) crossed z0 at (x, y) - t (z - z0)
        tx, ty = d[0] / d[2], d[1] / d[2]
        t = math.hypot(tx, ty)
        cx, cy = -tx * (0.5 * (z_lo + z_hi) - z0), -ty * (0.5 * (z_lo + z_hi) - z0)
        radius = sd + t * 0.5 * (z_hi - z_lo) + 1e-6 * sd
    else:
        if not src[2] < z0:
            raise InputError(f"light distance {distance_mm:g} mm: the light must lie in "
                             f"front of surface 0 (more than {-z0 / d[2]:.6g} mm from its "
                             "vertex)")
        # Seen from the source, the housing's circle at depth z shrinks onto the launch
        # plane by k(z) about the source's foot; the disc holding both extreme circles
        # holds every one between (centres and radii are affine in k)
        ks = [(z0 - src[2]) / (z - src[2]) for z in (z_lo, z_hi)]
        cs = [src[:2] * (1.0 - k) for k in ks]
        cx, cy = 0.5 * (cs[0] + cs[1])
        radius = max(math.hypot(c[0] - cx, c[1] - cy) + sd * k for c, k in zip(cs, ks, strict=True))
        radius *= 1 + 1e-6
    h = radius * math.sqrt(math.pi / rays)
    m = int(math.ceil(radius / h))
    g = np.arange(-m, m + 1) * h  # symmetric about the disc's centre
    gx, gy = np.meshgrid(g, g)
    inside = gx * gx + gy * gy <= radius * radius
    return _rays_at(gx[inside] + cx, gy[inside] + cy, z0, wavelengths, d, src), h


def _alive(r: Rays) -> Rays:
    """The rays still travelling, compacted (the dead ones are of no further use)."""
    ok = r.status == Status.OK
    return Rays(r.pos[ok], r.dir[ok], r.wavelength_nm[ok], r.opl_mm[ok],
                r.transmittance[ok], r.status[ok], r.surface[ok])


def _bins(n: int) -> int:
    return int(np.clip(int(math.sqrt(n / RAYS_PER_BIN)), MIN_BINS, MAX_BINS))


def _hist_peak(x: np.ndarray, y: np.ndarray, w: np.ndarray, b: float) -> float:
    """Largest power per area in square bins of side b, over four grids shifted by
    half a bin (a spot split by bin edges is not halved)."""
    best = 0.0
    for ox in (0.0, 0.5):
        for oy in (0.0, 0.5):
            ix = np.floor((x - x.min()) / b + ox).astype(np.int64)
            iy = np.floor((y - y.min()) / b + oy).astype(np.int64)
            key = ix * (int(iy.max()) + 1) + iy
            best = max(best, float(np.bincount(key, weights=w).max()))
    return best / (b * b)


def _footprint(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> dict:
    """Centroid, footprint (bins above 1% of the lit bins' mean irradiance) and the
    geometric extent of power-weighted hits."""
    p = float(w.sum())
    cx, cy = float(np.dot(w, x) / p), float(np.dot(w, y) / p)
    extent = float(np.sqrt(((x - cx) ** 2 + (y - cy) ** 2).max()))
    span = max(float(x.max() - x.min()), float(y.max() - y.min()))
    if span == 0.0:  # every hit at one point: a footprint of no area
        return {"centre": (cx, cy), "area": 0.0, "extent": extent, "bin": 0.0}
    b = span / _bins(len(x)) * (1 + 1e-9)
    ix = np.floor((x - x.min()) / b).astype(np.int64)
    iy = np.floor((y - y.min()) / b).astype(np.int64)
    power = np.bincount(ix * (int(iy.max()) + 1) + iy, weights=w)
    lit = power[power > 0]
    mean = lit.mean()
    area = float(np.count_nonzero(lit > FOOTPRINT_LEVEL * mean)) * b * b
    return {"centre": (cx, cy), "area": area, "extent": extent, "bin": b}


def _ghost_peak(x, y, dirs, w, lam_mm: float, fp: dict, pixel_mm: float = 0.0) -> float:
    """Peak irradiance of a ghost: histogram peak at bins no finer than its Airy radius
    (nor than ``pixel_mm``: the peak a pixel of that pitch records), at most its
    diffraction limit (see the module's docstring)."""
    p = float(w.sum())
    dx, dy = dirs[:, 0], dirs[:, 1]
    mx, my = 0.5 * (dx.max() + dx.min()), 0.5 * (dy.max() + dy.min())
    na_rays = float(np.sqrt(((dx - mx) ** 2 + (dy - my) ** 2).max()))
    diameter = 2.0 * fp["extent"]
    na = min(1.0, na_rays + (lam_mm / diameter if diameter > lam_mm else 1.0))
    diffraction = p * math.pi * na * na / (lam_mm * lam_mm)
    b = max(0.61 * lam_mm / na, fp["bin"], pixel_mm)
    return min(_hist_peak(x, y, w, b), diffraction)


def airy_pixel_share(pixel_mm: float, lam_mm: float, n_x: float, n_y: float) -> float:
    """The share of an aberration-free PSF's power that a pixel centred on it collects:
    the Airy pattern's encircled energy 1 - J0(v)^2 - J1(v)^2 within the disc of the
    pixel's area (v = pi r / (lambda sqrt(N_x N_y)), r = pixel / sqrt(pi); the
    geometric mean of an anamorphic lens's two f-numbers)."""
    from scipy.special import j0, j1

    v = math.pi * (pixel_mm / math.sqrt(math.pi)) / (lam_mm * math.sqrt(n_x * n_y))
    return float(1.0 - j0(v) ** 2 - j1(v) ** 2)


def enumerate_ghosts(
    lens: Lens,
    *,
    f_number: float | None = None,
    light: tuple[float, float] = (0.0, 0.0),
    distance_mm: float = math.inf,
    wavelengths_nm=DEFAULT_WAVELENGTHS_NM,
    rays: int = DEFAULT_RAYS,
    fine_rays: int = DEFAULT_FINE_RAYS,
    pairs: list[tuple[int, int]] | None = None,
    pixel_mm: float = DEFAULT_PIXEL_MM,
) -> list[GhostEstimate]:
    """Every ghost of ``lens`` (or the given ``pairs`` of model indices), estimated from
    exact rays, brightest first.

    ``f_number``: the stop (default: the widest the housing allows); ``light``: field
    angles (x, y) in degrees, designers' sign (``lensfit.psf.psf.light_direction``), at
    ``distance_mm`` from the first vertex (default infinity); ``rays``: rays per
    wavelength over the launch disc (pass 1), ``fine_rays`` per path (pass 2);
    ``pixel_mm``: the pixel the visibility's peaks are averaged over. The direct peak's
    Airy term uses the f-number for infinity also for a near light. See the module's
    docstring for the estimators. Sorted by ``exposure_peak``, brightest first."""
    lams = np.array([float(v) for v in wavelengths_nm], dtype=np.float64)
    if lams.size == 0 or not np.all(np.isfinite(lams) & (lams > 0)):
        raise InputError(f"wavelengths {list(wavelengths_nm)}: expected positive nm")
    if not (isinstance(pixel_mm, int | float) and math.isfinite(pixel_mm) and pixel_mm > 0):
        raise InputError(f"pixel = {pixel_mm!r} mm: expected a positive pixel pitch")
    for key, v in (("rays", rays), ("fine_rays", fine_rays)):
        if not (isinstance(v, int | np.integer) and v >= 100):
            raise InputError(f"{key} = {v!r}: expected at least 100 rays per wavelength")
    stop = (lens.stop_radius_max_mm if f_number is None
            else stop_radius_for_f_number(lens, float(f_number)))
    all_pairs = ghost_pairs(lens)
    if pairs is None:
        pairs = all_pairs
    for pr in pairs:
        if tuple(pr) not in all_pairs:
            raise InputError(f"ghost {pr[0]},{pr[1]}: no such ghost of {lens.name} (pairs "
                             f"i < j of surfaces 0..{len(lens.surfaces) - 1}, stop planes "
                             f"{[k for k, s in enumerate(lens.surfaces) if s.stop]} excluded)")
    want = set(map(tuple, pairs))

    # Working f-numbers of the stop in both meridians, for the Airy peak
    n_xy = [abs(paraxial(lens, meridian=m, stop_radius_mm=stop).f_number) for m in "xy"]
    if not (distance_mm > 0):
        raise InputError(f"light distance {distance_mm!r} mm: expected a positive distance "
                         "or inf")
    launch, h = _launch(lens, light, int(rays), lams, float(distance_mm))
    chief, src = _source(light, float(distance_mm))
    n = len(lens.surfaces)
    opts = {"stop_radius_mm": stop, "clip": True, "fresnel_loss": True}

    def step(r: Rays, idx: np.ndarray, path: list[Step], end_z: float | None = None):
        """Trace, keep the survivors and their launch indices."""
        t = trace(lens, r, path, end_z=end_z, **opts)
        ok = t.status == Status.OK
        return _alive(t), idx[ok]

    # Pass 1, coarse: which launch points reach the sensor along each path. The forward
    # states fwd[k] have met surfaces 0..k-1; for each j the reflected bundle is carried
    # back one surface at a time and branches into the ghost (i, j) at each i
    fwd = [(launch, np.arange(len(launch)))]
    for k in range(n):
        fwd.append(step(*fwd[-1], [Step(k)]))
    # The light entering: what arrives inside surface 0's housing (before its loss)
    w0 = launch.transmittance[fwd[1][1]]
    lam1 = launch.wavelength_nm[fwd[1][1]]
    entering_power = np.array([w0[lam1 == lam].sum() for lam in lams]) * h * h
    found: dict[tuple[int, int], np.ndarray] = {}
    for j in ghost_surfaces(lens):
        if not any(pj == j for _, pj in want):
            continue
        state = step(*fwd[j], [Step(j, reflect=True)])
        for i in range(j - 1, -1, -1):
            if (i, j) in want:
                tail = [Step(i, from_front=False, reflect=True)]
                tail += [Step(k) for k in range(i + 1, n)]
                found[(i, j)] = step(*state, tail, end_z=lens.sensor_z)[1]
            if i > 0 and any(pi < i and pj == j for pi, pj in want):
                state = step(*state, [Step(i, from_front=False)])
            else:
                break
    # Pass 2, fine: each path again on a grid of ``fine_rays`` points per wavelength over
    # the box of its coarse survivors (grown by one coarse step), traced in one go
    xy0 = launch.pos[:, :2]

    def refine(path: list[Step], idx: np.ndarray):
        """The path's rays on the sensor and the area each launch ray stands for."""
        if idx.size == 0:
            return None, 0.0
        lo, hi = xy0[idx].min(axis=0) - h, xy0[idx].max(axis=0) + h
        # At least the coarse density; about `rays` points per wavelength in the box
        h2 = min(h, math.sqrt(float(np.prod(hi - lo)) / fine_rays))
        gx = np.arange(lo[0] + 0.5 * h2, hi[0], h2)
        gy = np.arange(lo[1] + 0.5 * h2, hi[1], h2)
        px, py = (a.ravel() for a in np.meshgrid(gx, gy))
        r = _rays_at(px, py, float(launch.pos[0, 2]), lams, chief, src)
        return _alive(trace(lens, r, path, end_z=lens.sensor_z, **opts)), h2 * h2

    direct, d_cell = refine(forward_path(lens), fwd[n][1])
    if direct is None:
        raise InputError(f"{lens.source_file}: no ray of the light {light[0]:g},{light[1]:g} "
                         f"reaches the sensor through {lens.name}: no direct image to rank "
                         "ghosts against")

    # The direct image per wavelength: power and peak (Airy times the Strehl estimate)
    d_power, d_peak, strehl, d_pixel = [], [], [], []
    for lam in lams:
        sel = direct.wavelength_nm == lam
        w = direct.transmittance[sel] * d_cell
        p = float(w.sum())
        lam_mm = lam * 1e-6
        airy = p * math.pi / (4.0 * lam_mm * lam_mm * n_xy[0] * n_xy[1])
        # The same peak as a pixel records it (module doc, "Visibility"): the diffraction
        # limit's pixel average, or the rays' where they spread wider
        pixel = p * airy_pixel_share(pixel_mm, lam_mm, *n_xy) / pixel_mm**2
        if p > 0:
            # Bins of the Airy radius, or coarser where the rays are too few for those
            # (a bin holding one ray would overstate the peak)
            x, y = direct.pos[sel, 0], direct.pos[sel, 1]
            r_airy = 1.22 * lam_mm * math.sqrt(n_xy[0] * n_xy[1])
            b = _footprint(x, y, w)["bin"]
            geo = _hist_peak(x, y, w, max(r_airy, b))
            s = min(1.0, geo / airy)
            # Bins of the pixel itself: the direct image's core holds most of its rays
            pixel = min(pixel, _hist_peak(x, y, w, max(pixel_mm, r_airy)))
        else:
            s = 1.0
        d_power.append(p)
        d_peak.append(airy * s)
        strehl.append(s)
        d_pixel.append(pixel)

    info = {"lens": lens.name, "file": lens.source_file, "f_number": n_xy[1],
            "f_number_x": n_xy[0], "stop_radius_mm": stop, "light_deg": list(light),
            "distance_mm": None if math.isinf(distance_mm) else float(distance_mm),
            "wavelengths_nm": lams.tolist(), "rays_per_wavelength": int(rays),
            "fine_rays_per_wavelength": int(fine_rays),
            "grid_step_mm": h, "direct_power": d_power, "direct_peak": d_peak,
            "strehl_estimate": strehl, "entering_power": entering_power.tolist(),
            "pixel_mm": float(pixel_mm), "direct_pixel_peak": d_pixel}

    out: list[GhostEstimate] = []
    for (i, j), idx in found.items():
        hits, cell = refine(ghost_path(lens, i, j), idx)
        out.append(_estimate(lens, i, j, hits, lams, cell, entering_power, d_power,
                             d_peak, info))
    out.sort(key=lambda g: (-g.exposure_peak, g.first, g.second))
    return out


def _estimate(lens, i, j, hits: Rays, lams, cell, entering, d_power, d_peak,
              info) -> GhostEstimate:
    """One ghost's figures per wavelength from its rays on the sensor."""
    g = GhostEstimate(lens=lens.name, file=lens.source_file, first=i, second=j,
                      first_file=lens.file_index(i), second_file=lens.file_index(j),
                      case=_case(lens, i, j), wavelengths_nm=tuple(lams.tolist()),
                      energy=[], throughput=[], centre_mm=[], radius_mm=[], area_mm2=[],
                      extent_mm=[], peak=[], rays=[], info=info)
    for k, lam in enumerate(lams):
        if hits is None:
            sel = np.zeros(0, dtype=bool)
            w = np.zeros(0)
        else:
            sel = (hits.wavelength_nm == lam) & (hits.transmittance > 0)
            w = hits.transmittance[sel] * cell
        p = float(w.sum())
        g.rays.append(int(np.count_nonzero(sel)))
        g.energy.append(p / d_power[k] if d_power[k] > 0 else 0.0)
        g.throughput.append(p / entering[k] if entering[k] > 0 else 0.0)
        if p <= 0:
            g.centre_mm.append(None)
            g.radius_mm.append(0.0)
            g.area_mm2.append(0.0)
            g.extent_mm.append(0.0)
            g.peak.append(0.0)
            g.pixel_peak.append(0.0)
            continue
        x, y = hits.pos[sel, 0], hits.pos[sel, 1]
        fp = _footprint(x, y, w)
        g.centre_mm.append(fp["centre"])
        g.area_mm2.append(fp["area"])
        g.radius_mm.append(math.sqrt(fp["area"] / math.pi))
        g.extent_mm.append(fp["extent"])
        peak = _ghost_peak(x, y, hits.dir[sel], w, lam * 1e-6, fp)
        g.peak.append(peak / d_peak[k] if d_peak[k] > 0 else math.inf)
        d_pixel = info["direct_pixel_peak"][k]
        at_pixel = _ghost_peak(x, y, hits.dir[sel], w, lam * 1e-6, fp, info["pixel_mm"])
        g.pixel_peak.append(float(at_pixel / d_pixel) if d_pixel > 0 else math.inf)
    g.relative_peak = float(max(g.peak))
    g.exposure_peak = float(max(g.pixel_peak))
    return g


def mark_ghosts(estimates: list[GhostEstimate], count: int | None = None,
                threshold: float | None = None,
                overexposure: float = DEFAULT_OVEREXPOSURE_STOPS) -> list[GhostEstimate]:
    """Mark every estimate's ``visible`` (for ``overexposure``, module doc) and ``kept``:
    the ``count`` brightest (by exposure peak) when ``count`` is given, else those whose
    relative peak is above ``threshold`` when one is given, else the visible ones.
    Returns the kept ones, brightest first, possibly none (a listing shows every ghost
    whatever is kept; `select_ghosts` refuses none)."""
    if not (math.isfinite(overexposure) and 0 <= overexposure <= 60):
        raise InputError(f"overexposure = {overexposure!r} stops: expected 0 to 60 stops "
                         "of the light's peak pixel over white")
    ranked = sorted(estimates, key=lambda g: -g.exposure_peak)
    black = black_level(overexposure)
    for g in estimates:
        g.visible = g.exposure_peak >= black
    if count is not None:
        if not (isinstance(count, int | np.integer) and count >= 1):
            raise InputError(f"count = {count!r}: expected a positive number of ghosts")
        keep = ranked[:count]
    elif threshold is not None:
        if not (math.isfinite(threshold) and threshold > 0):
            raise InputError(f"threshold = {threshold!r}: expected a positive relative peak")
        keep = [g for g in ranked if g.relative_peak > threshold]
    else:
        keep = [g for g in ranked if g.visible]
    ids = {id(g) for g in keep}
    for g in estimates:
        g.kept = id(g) in ids
    return keep


def none_kept_message(estimates: list[GhostEstimate], threshold: float | None = None,
                      overexposure: float = DEFAULT_OVEREXPOSURE_STOPS) -> str:
    """Why `mark_ghosts` kept nothing: the lens, the rule (threshold, or visibility at
    ``overexposure``) and the brightest ghost's value (or that the lens has no ghost)."""
    if not estimates:
        return "no ghost to select: the lens has fewer than two surfaces that are not the stop"
    if threshold is not None:
        top = max(estimates, key=lambda g: g.relative_peak)
        return (f"{top.file}: {top.lens} has no ghost above the threshold {threshold:g} of "
                f"the PSF peak: the brightest, ghost {top.name}, peaks at "
                f"{top.relative_peak:.3g}")
    top = max(estimates, key=lambda g: g.exposure_peak)
    return (f"{top.file}: {top.lens} has no visible ghost with the light "
            f"{overexposure:g} stops over white (a ghost's peak pixel must reach "
            f"{black_level(overexposure):.3g} of the light's): the brightest, "
            f"ghost {top.name}, is {top.visibility_stops(overexposure):.1f} stops from "
            "that black level")


def select_ghosts(estimates: list[GhostEstimate], count: int | None = None,
                  threshold: float | None = None,
                  overexposure: float = DEFAULT_OVEREXPOSURE_STOPS) -> list[GhostEstimate]:
    """The ghosts a scene keeps, as `mark_ghosts` marks them. No ghost kept is an error
    naming the lens, the rule and the brightest ghost's value."""
    keep = mark_ghosts(estimates, count=count, threshold=threshold,
                       overexposure=overexposure)
    if not keep:
        raise InputError(none_kept_message(estimates, threshold, overexposure))
    return keep
