"""Semi-diameters of an imported lens: apertures kept, automatic ones widened into
housings that pass the design beam (``lensfit import``; lensdb/README.md, ``aperture``).

A design file's semi-diameter is one of two things:

* an **aperture**, part of the lens: OpticStudio's fixed semi-diameter ("U", DIAM solve
  type 1), a circular aperture (CLAP, FLAP), Optiland's RadialAperture, and the stop's
  semi-diameter whatever its solve (with FLOA it is the system aperture). lensfit's
  ``semi_diameter`` is a hard clip, and so these stay exactly as written;
* **automatic**: what the design program computed to just pass its beam (DIAM solve 0;
  the pickup and maximum solves, 2 and 3, copy other surfaces' or take the largest of
  them; a surface without a semi-diameter, which the importers estimate from paraxial
  rays; an Optiland surface without a physical aperture). Taken as a housing exactly at
  the beam's edge it clips the beam lensfit fits: a design program sizes it with its own
  rays (its wavelengths, vignetting factors; a paraxial estimate can be smaller than the
  real beam), and lensfit fits a wider domain (380-780 nm, close focus, an image circle
  IMAGE_MARGIN beyond the field's edge, a sensor travel). On an off-axis field that moved
  a singlet's PSF by 2.8% and made lensrt refuse its Fourier integrator (issue 36).

The rule for an automatic semi-diameter: real rays are traced with lensfit's exact
tracer (:func:`trace_design_beam`) through the lens as the file gives it, where apertures
clip and automatic semi-diameters do not; the largest radial height h of a ray at the
surface (mm) gives

    semi_diameter = max(file value, h * (1 + AUTOMATIC_MARGIN)),

rounded up to 6 significant digits, but no wider than the surface's shape allows (within
a sphere's radius, a conic's edge) and its neighbours leave (surfaces must not cross
inside their common clear aperture): a housing so limited is reported with the height
the rays reach. The rays:

* the **design beam**: from scene points at half field angles 0 to F in FIELD_STEPS
  steps (F the file's largest field from the axis; 0 when the file has no angle field),
  along y (a rotationally symmetric lens: the stop's rim covers every azimuth) or along
  x, y and the diagonal (cylinders), at infinity and out to the default close focus
  (CLOSE_FOCUS_EFL focal lengths: three distances), through the stop filled to its
  semi-diameter (the widest the iris opens, so every f-number lensfit fits), at the ends
  and the middle of the default fit band (380-780 nm within every glass's range);
* the **default fit domain** (:func:`lensfit.sample.domain.default_domain`, found with
  the housings widened for the design beam, as its chief rays must pass them): the rays
  P_s is fitted with, from the stop's points to sensor points out to its image circle
  at the ends and the middle of its sensor travel, and where its field is wider than
  the file's (a file without angle fields: the frame's field as far as chief rays pass)
  the rays P_o is fitted with, as the design beam's over that field.

The surface keeps ``aperture = "automatic"`` and, where the file gave one,
``design_semi_diameter`` (its value there). ``lensfit import`` prints one line per
surface saying what it was and what was done.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from decimal import ROUND_CEILING, ROUND_FLOOR, Decimal
from typing import Any

import numpy as np

from lensfit.common.errors import InputError, LensError

# How much wider than the traced rays an automatic housing is. The rays are a sample of
# the domain: against 16,000 samples of lensfit's default fit (P_o and P_s) of lenses
# 0004, 0007, 0013 and 2004 imported with every surface automatic, housings exactly at
# the traced heights were passed by at most 0.26% (0004's sensor side; 0007 0.05%, the
# others none: tests/fit/interchange/test_housings.py checks 0.5%). 5% is twenty times
# that: room for a fit asked a little beyond the default (a wider field or image circle;
# IMAGE_MARGIN is itself 5%), while the housing stays near the beam (0.1 mm at a 2 mm
# beam: the outline `lensfit draw` shows stays the design's).
AUTOMATIC_MARGIN = 0.05
STOP_RIM_POINTS = 48
FIELD_STEPS = 8
STOP_RINGS = (0.5, 0.7, 0.85, 0.95)
# A ray at the stop's rim meets it at the radius to the aiming's tolerance (1e-9 mm); a
# height within this relative slack of an aperture is on it, not past it
ON_THE_EDGE = 1e-9
SIGNIFICANT_DIGITS = 6  # as the paraxial estimates are written


@dataclass(frozen=True)
class FileAperture:
    """What an imported file says of one surface's semi-diameter.

    ``kind``: "stop" (the aperture stop: its value is the aperture), "fixed" (an
    aperture), "automatic" (a value the design program computed from its beam) or
    "estimated" (no value in the file: the importer's paraxial estimate). ``what``: how
    the file says it, for the report ("DIAM solve 1: fixed", "CLAP", "RadialAperture",
    "no DIAM")."""

    kind: str
    what: str

    @property
    def widened(self) -> bool:
        return self.kind in ("automatic", "estimated")


@dataclass
class Beam:
    """The design beam's real rays: the largest radial height (mm) at each surface of
    the loaded lens (``Lens.surfaces``; NaN where no ray arrives), and what was traced."""

    heights_mm: np.ndarray
    rays: int
    description: str


def _round(x: float, up: bool) -> float:
    """``x`` rounded up (or down) to SIGNIFICANT_DIGITS significant digits; to the nearest
    where that is within 1e-12 of ``x`` (4 * 1.05 is 4.2 plus an ulp, and is written 4.2)."""
    near = float(f"{x:.{SIGNIFICANT_DIGITS}g}")
    if abs(near - x) <= 1e-12 * abs(x):
        return near
    d = Decimal(x)
    q = Decimal(1).scaleb(d.adjusted() - SIGNIFICANT_DIGITS + 1)
    return float(d.quantize(q, rounding=ROUND_CEILING if up else ROUND_FLOOR))


def _stop_points(r: float) -> np.ndarray:
    """Points on a stop of radius ``r``: its centre, STOP_RIM_POINTS on its rim and 12 on
    each of STOP_RINGS. The height at a surface is largest for rim points wherever the
    map from the stop is near linear; where the rays from the rim miss a surface (their
    path leaves a sphere's cap: lens 0004's rear group, a sensor point at the edge of the
    image circle), it is largest at the edge of the part that passes, which the rings
    find to within a twentieth of the radius."""
    a = np.linspace(0.0, 2.0 * math.pi, STOP_RIM_POINTS, endpoint=False)
    b = np.linspace(0.0, 2.0 * math.pi, 12, endpoint=False)
    return np.concatenate([[[0.0, 0.0]], r * np.stack([np.cos(a), np.sin(a)], 1),
                           *(f * r * np.stack([np.cos(b), np.sin(b)], 1) for f in STOP_RINGS)])


def _directions(lens: Any, half_x_deg: float, half_y_deg: float) -> list[tuple[float, float]]:
    """Direction cosines (x_O, y_O) of scene points on the field: FIELD_STEPS + 1 angles
    from the axis to the edge, along y for a rotationally symmetric lens (the stop's rim
    covers every azimuth) or along x, y and the diagonal of the field's ellipse for one
    with cylinders."""
    azimuths = (0.0, 45.0, 90.0) if lens.anamorphic else (90.0,)
    tx, ty = (math.tan(math.radians(f)) for f in (half_x_deg, half_y_deg))
    out = set()
    for p in azimuths:
        c, s = math.cos(math.radians(p)), math.sin(math.radians(p))
        # the edge of the field's ellipse (in tangents) along this azimuth
        edge = 1.0 / math.hypot(c / tx, s / ty) if tx > 0 and ty > 0 else 0.0
        for j in range(FIELD_STEPS + 1):
            t = math.atan(edge * j / FIELD_STEPS)
            out.add((math.sin(t) * c, math.sin(t) * s))
    return sorted(out)


def _heights(rho: np.ndarray, valid: np.ndarray, lens: Any, surfaces: list[int],
             apertures: set[int]) -> np.ndarray:
    """The largest radial height (mm) at each surface of ``lens`` over the rays (rows of
    ``rho``, the heights at ``surfaces``, in order along the path), counting a ray at a
    surface only where ``valid`` and not behind an aperture it passes by more than
    ON_THE_EDGE."""
    n = len(lens.surfaces)
    col = np.arange(len(surfaces))
    blocked_at = np.full(len(rho), len(surfaces))
    for c in reversed(col):
        j = surfaces[c]
        if j in apertures:
            past = valid[:, c] & (rho[:, c] > lens.surfaces[j].semi_diameter_mm
                                  * (1.0 + ON_THE_EDGE))
            blocked_at[past] = c
    valid = valid & (col[None, :] <= blocked_at[:, None])
    out = np.full(n, np.nan)
    if len(rho):
        top = np.where(valid, rho, -np.inf).max(axis=0)
        out[np.asarray(surfaces, dtype=int)] = np.where(np.isfinite(top), top, np.nan)
    return out


def _object_side(lens: Any, field_xy_deg: tuple[float, float], us: list[float],
                 stop_r: float, lams: np.ndarray, apertures: set[int]) -> tuple[np.ndarray, int]:
    """Heights (:func:`_heights`) of the rays from scene points on the field (inverse
    distances ``us``) through the stop's points (radius ``stop_r``) at ``lams``, aimed at
    the stop (:func:`lensfit.sample.aim.aim_object_side`) and traced on to the last
    surface without clipping; a ray that misses a surface or reflects totally behind
    the stop counts at the surfaces before. And the number of rays aimed."""
    from lensfit.sample.aim import aim_object_side
    from lensfit.trace.tracer import Rays, Status, Step, trace

    dirs = np.array(_directions(lens, *field_xy_deg))
    stop_pts = _stop_points(stop_r)
    d, u, w, p = (v.reshape(-1) for v in np.meshgrid(
        np.arange(len(dirs)), np.asarray(us, dtype=np.float64), lams,
        np.arange(len(stop_pts)), indexing="ij"))
    aimed = aim_object_side(lens, dirs[d, 0], dirs[d, 1], u, stop_pts[p, 0], stop_pts[p, 1],
                            w, fd_scale_mm=max(stop_r, 1.0), history=True)
    ok = aimed.ok
    n, s = len(lens.surfaces), lens.stop_index
    hist: list[np.ndarray] = []
    out = trace(lens, Rays(aimed.pos[ok], aimed.dir[ok], w[ok]),
                [Step(k) for k in range(s + 1, n)], clip=False, history=hist)
    pos = np.concatenate([aimed.history[ok], *([np.stack(hist, axis=1)] if hist else [])],
                         axis=1)
    # A ray that failed behind the stop stays where it failed from there on
    fail_at = np.where(out.status == Status.OK, n, out.surface.astype(np.int64))
    valid = np.arange(n)[None, :] < fail_at[:, None]
    rho = np.hypot(pos[..., 0], pos[..., 1])
    return _heights(rho, valid, lens, list(range(n)), apertures), int(ok.sum())


def _sensor_side(lens: Any, domain: Any, lams: np.ndarray, apertures: set[int]
                 ) -> tuple[np.ndarray, int]:
    """Heights (:func:`_heights`) behind the stop of the rays lensfit fits P_s with by
    default: from the stop's points (the domain's stop radius) to sensor points out to
    the domain's image circle (FIELD_STEPS + 1 radii, along the azimuths of
    :func:`_directions`) at the ends and the middle of its sensor travel, aimed by
    :func:`lensfit.sample.aim.aim_sensor_side`. And the number of rays aimed."""
    from lensfit.sample.aim import aim_sensor_side

    n, s = len(lens.surfaces), lens.stop_index
    if s == n - 1:
        return np.full(n, np.nan), 0
    azimuths = (0.0, 45.0, 90.0) if lens.anamorphic else (90.0,)
    r = domain.sensor_radius_mm * np.arange(FIELD_STEPS + 1) / FIELD_STEPS
    pts = np.array(sorted({(float(v * math.cos(math.radians(a))),
                            float(v * math.sin(math.radians(a)))) for v in r
                           for a in azimuths}))
    lo, hi = domain.focus_min_mm, domain.focus_max_mm
    zs = np.array(sorted({lo, 0.5 * (lo + hi), hi}))
    stop_pts = _stop_points(domain.stop_radius_mm)
    q, z, w, p = (v.reshape(-1) for v in np.meshgrid(
        np.arange(len(pts)), zs, lams, np.arange(len(stop_pts)), indexing="ij"))
    aimed = aim_sensor_side(lens, pts[q, 0], pts[q, 1], z, stop_pts[p, 0], stop_pts[p, 1],
                            w, history=True)
    ok = aimed.ok
    pos = aimed.history[ok]  # after each surface behind the stop
    rho = np.hypot(pos[..., 0], pos[..., 1])
    return (_heights(rho, np.ones(rho.shape, dtype=bool), lens, list(range(s + 1, n)),
                     apertures), int(ok.sum()))


def _widened(lens: Any, automatic: set[int], heights: np.ndarray) -> Any:
    """``lens`` with each surface in ``automatic`` at least as wide as its height times
    (1 + AUTOMATIC_MARGIN) (within a sphere's or a cylinder's radius): not validated, for
    the chief rays that find the default fit domain."""
    out = list(lens.surfaces)
    for j in automatic:
        h = heights[j]
        if math.isfinite(h):
            sd = max(out[j].semi_diameter_mm, h * (1.0 + AUTOMATIC_MARGIN))
            if out[j].shape in ("sphere", "cylinder-x", "cylinder-y"):
                sd = min(sd, abs(out[j].radius_mm))
            out[j] = dataclasses.replace(out[j], semi_diameter_mm=sd)
    return dataclasses.replace(lens, surfaces=tuple(out))


def trace_design_beam(lens: Any, half_field_deg: float, apertures: set[int],
                      automatic: set[int]) -> Beam:
    """The largest height of real rays at each surface of ``lens`` (the module
    docstring): the design beam and the default fit domain's sensor side, where the
    surfaces in ``apertures`` clip and no other. ``automatic``: the surfaces whose
    housings are to be widened (the default fit domain is found with them widened for
    the design beam, as its chief rays must pass the housings). Raises ValueError,
    InputError or LensError when the design beam cannot be traced."""
    from lensfit.paraxial.paraxial import paraxial
    from lensfit.prescription.ranges import default_wavelengths
    from lensfit.sample.aim import SamplingError
    from lensfit.sample.domain import CLOSE_FOCUS_EFL, default_domain

    lo, hi = default_wavelengths(lens).range_nm
    lams = np.array([lo, 0.5 * (lo + hi), hi])
    f = max(0.0, float(half_field_deg))
    r = lens.stop_radius_max_mm
    efl = min(abs(float(paraxial(lens, meridian=m).efl_mm)) for m in ("x", "y"))
    close = CLOSE_FOCUS_EFL * efl if math.isfinite(efl) and efl > 0 else math.inf

    def distances(close: float) -> list[float]:
        return [0.0] if math.isinf(close) else [0.0, 0.5 / close, 1.0 / close]

    with np.errstate(all="ignore"):
        try:
            heights, rays = _object_side(lens, (f, f), distances(close), r, lams, apertures)
        except SamplingError:  # the close-focus scene point is not in front of the lens
            close = math.inf
            heights, rays = _object_side(lens, (f, f), [0.0], r, lams, apertures)
        if not rays:
            raise ValueError("no ray of the design beam reaches the stop")
        fields = (f"half fields 0 to {f:.4g} deg" if f else
                  "on the axis (the file gives no angle field)")
        scene = "at infinity" + (f" and to {close:.4g} mm in front" if math.isfinite(close)
                                 else "")
        text = (f"the design beam (the stop filled, {r:.6g} mm; {fields}; {lo:g}-{hi:g} nm; "
                f"the scene {scene}: {rays} real rays)")
        try:
            domain = default_domain(_widened(lens, automatic, heights))
        except (InputError, LensError, ValueError) as e:
            return Beam(heights, rays, f"{text}; no default fit domain ({e})")
        more, n_s = _sensor_side(lens, domain, lams, apertures)
        heights, rays = np.fmax(heights, more), rays + n_s
        text += (f" and the default fit domain's sensor side (image circle "
                 f"{domain.sensor_radius_mm:.4g} mm, sensor travel {domain.focus_min_mm:.4g} "
                 f"to {domain.focus_max_mm:.4g} mm: {n_s} real rays)")
        fx, fy = domain.field_xy_deg
        if max(fx, fy) > f * (1.0 + 1e-9):  # a wider field than the design's
            more, n_o = _object_side(lens, (fx, fy), distances(domain.close_focus_mm),
                                     domain.stop_radius_mm, lams, apertures)
            heights, rays = np.fmax(heights, more), rays + n_o
            text += f" and scene side (half field {max(fx, fy):.4g} deg: {n_o} real rays)"
    return Beam(heights, rays, text)


def _fits(surfaces: list[Any], k: int, sd_mm: float, names: list[str]) -> str:
    """'' when surface ``k`` may have the semi-diameter ``sd_mm`` (the loader's rules:
    within the shape, not crossing a neighbour), else what stops it (``names``: how the
    file names each surface)."""
    from lensfit.prescription.load import CROSSING_TOLERANCE_MM, _is_stop_plane, first_crossing

    s = dataclasses.replace(surfaces[k], semi_diameter_mm=sd_mm)
    # Strictly inside a sphere's (a cylinder's) radius: at the radius itself the surface
    # is vertical and its slope infinite
    if s.shape in ("sphere", "cylinder-x", "cylinder-y") and \
            sd_mm >= abs(s.radius_mm) * (1.0 - 1e-9):
        return "the surface's radius allows"
    with np.errstate(all="ignore"):
        edge = s.sag(0.0, sd_mm) if s.shape == "cylinder-x" else s.sag(sd_mm, 0.0)
    if not np.isfinite(edge):
        return "the edge of the conic allows"
    trial = [*surfaces[:k], s, *surfaces[k + 1:]]
    for i in (k - 1, k):
        if i < 0 or i + 1 >= len(trial):
            continue
        if trial[i].thickness_mm == 0.0 and (_is_stop_plane(trial, i)
                                            or _is_stop_plane(trial, i + 1)):
            continue
        with np.errstate(all="ignore"):
            gap, _ = first_crossing(trial[i], trial[i + 1])
        if not gap >= -CROSSING_TOLERANCE_MM:
            return f"{names[i if i != k else i + 1]} allows (wider, the two would cross)"
    return ""


def size_housings(data: dict[str, Any], apertures: list[FileAperture], where: list[str],
                  places: list[str], *, label: str, half_field_deg: float, unit: str,
                  lens: Any = None) -> tuple[Any, list[str]]:
    """Widen the automatic semi-diameters of ``data`` (the converted lens, in the TOML
    layout; ``apertures`` says what each surface's is) by the module's rule, in place,
    and return the validated lens and one line per surface saying what was done
    (``places``: where each surface is in the file, "lens.zmx:41: SURF 5"), after a line
    on the design beam when one was traced. ``where`` names the surfaces for a loader
    refusal (lensfit.interchange.common.validate); ``unit`` is the file's length unit;
    ``lens``: ``data`` validated, when the caller has it."""
    from lensfit.interchange.common import file_surfaces, validate

    if lens is None:
        lens = validate(data, label, where)
    rows = data["surface"]
    scale = float(data["lens"].get("scale", 1.0))
    folded = file_surfaces(lens)
    surfaces = [dataclasses.replace(s, thickness_mm=t) for _, s, _, t in folded]
    index = [k for k, _, _, _ in folded]
    lines: list[str] = []
    beam = None
    if any(a.widened for a in apertures):
        fixed = {index[k] for k, a in enumerate(apertures) if a.kind == "fixed"}
        auto = {index[k] for k, a in enumerate(apertures) if a.widened}
        try:
            beam = trace_design_beam(lens, half_field_deg, fixed, auto)
        except (ValueError, InputError, LensError, ArithmeticError) as e:
            lines.append(f"{label}: the design beam could not be traced ({e}): automatic "
                         "semi-diameters kept as the file gives them")
        else:
            lines.append(f"{label}: automatic semi-diameters pass, with a "
                         f"{AUTOMATIC_MARGIN:.0%} margin, the real rays of {beam.description}")

    def show(mm: float) -> str:
        return f"{mm / scale:.6g} {unit}"

    names = [w.split(": ", 1)[-1] for w in where]  # "SURF 5", "surface_group.surfaces[3]"
    changed = False
    for k, (a, row) in enumerate(zip(apertures, rows, strict=True)):
        value = float(row["semi_diameter"])
        h = float(beam.heights_mm[index[k]]) if beam is not None else math.nan
        reach = f"real rays reach {show(h)}" if math.isfinite(h) else ""
        head = f"{places[k]}: "
        if a.kind == "stop":
            lines.append(f"{head}the stop ({a.what}): aperture {value:.6g} {unit} kept")
            continue
        if a.kind == "fixed":
            clips = (f"; it clips the design beam ({reach})"
                     if math.isfinite(h) and h > surfaces[k].semi_diameter_mm
                     * (1.0 + ON_THE_EDGE) else "")
            lines.append(f"{head}fixed aperture ({a.what}): {value:.6g} {unit} kept{clips}")
            continue
        said = (f"automatic semi-diameter ({a.what}) {value:.6g} {unit}"
                if a.kind == "automatic" else
                f"no semi-diameter in the file ({a.what}): paraxial estimate {value:.6g} "
                f"{unit}")
        new = value
        if beam is None:
            what = "kept (not traced)"
        elif not math.isfinite(h):
            what = "kept (no real ray of the design beam reaches it)"
        else:
            target = h * (1.0 + AUTOMATIC_MARGIN)
            # Kept when it reaches the target to rounding (1e-12 relative: a value the
            # export wrote in mm, imported back from a lens in inches, is the same housing)
            if surfaces[k].semi_diameter_mm >= target * (1.0 - 1e-12):
                what = f"kept ({reach})"
            else:
                new = max(value, _round(target / scale, up=True))
                limit = _fits(surfaces, k, new * scale, names)
                if not limit:
                    what = (f"widened to {new:.6g} {unit} ({reach}, plus "
                            f"{AUTOMATIC_MARGIN:.0%})")
                else:  # the widest the shape and the neighbours allow
                    lo, hi = surfaces[k].semi_diameter_mm, new * scale
                    for _ in range(60):
                        mid = 0.5 * (lo + hi)
                        lo, hi = (mid, hi) if not _fits(surfaces, k, mid, names) else (lo, mid)
                    new = max(value, _round(lo / scale, up=False))
                    short = "; the beam is clipped here" if new * scale < h else ""
                    what = f"widened to {new:.6g} {unit}, as far as {limit} ({reach}{short})"
                surfaces[k] = dataclasses.replace(surfaces[k], semi_diameter_mm=new * scale)
        lines.append(f"{head}{said}: {what}")
        # The keys in the layout's order: aperture and the file's value after the value
        out = {}
        for key, v in row.items():
            out[key] = new if key == "semi_diameter" else v
            if key == "semi_diameter":
                out["aperture"] = "automatic"
                if a.kind == "automatic":
                    out["design_semi_diameter"] = value
        row.clear()
        row.update(out)
        changed = True
    if changed:
        lens = validate(data, label, where)
    return lens, lines
