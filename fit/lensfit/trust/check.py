"""How far a fit can be trusted, in the user's terms: its PSF against exactly traced rays.

For each cell of a small table (the widest fitted stop, f/8 and f/32; a light on the axis
and one at 80% of the frame's corner; 450, 550 and 650 nm; the light at infinity and the
sensor at the best focus of the axis at 550 nm for that stop, as a camera is focused),
and for the edges of the fitted field itself (the field's corner on the frame's
diagonal, its x edge, and for an anamorphic lens its y edge; at the widest stop, where
the polynomials' field error shows most: smaller stops hide it), two PSFs are
summed over the same stop points (a sunflower set, so Monte Carlo noise cancels and only
the transport differs):

* the exact one, :func:`lensfit.psf.psf.exact_psf_nodes` (every ray traced in float64; the
  sensor-side rays of each stop point aimed at a Chebyshev grid over the window and
  interpolated through where they land, which agrees with tracing every pair to ~1e-8
  (3.5e-7 at a 2.7 mm window, the every-pair trace's own Newton noise));
* the polynomial one, :func:`lensfit.psf.psf.poly_psf` (the fitted P_o and P_s),

and the cell's figure is the relative L2 distance of the intensities,
||I_poly - I_exact|| / ||I_exact||, over a window that holds the geometric spot and at
least four Airy radii around the chief ray's image. A light whose window would leave the
fitted sensor disc (an aberrated spot at the field's edge) is moved towards the axis, 3%
of its angle at a time, until every window of its cells lies inside (the cell records
``field_share``, its angle over the one asked for). The worst cell is the fit's
statement of trust: `lensfit fit` prints it, the table carries it and lensrt logs it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from lensfit.common.errors import InputError
from lensfit.paraxial.facts import lens_facts
from lensfit.paraxial.paraxial import paraxial, stop_radius_for_f_number
from lensfit.poly import System
from lensfit.prescription.model import Lens
from lensfit.psf import psf
from lensfit.psf.psf import light_direction
from lensfit.sample.aim import Aimed
from lensfit.sample.domain import FULL_FRAME_HALF_DIAGONAL_MM, Domain
from lensfit.trace.tracer import Status

WAVELENGTHS_NM = (450.0, 550.0, 650.0)
F_NUMBERS = (8.0, 32.0)  # besides the widest fitted stop
# The field's edges are checked at the widest fitted stop only: at f/8 their cells
# measured at most half the widest stop's (0001: 0.32% against 0.77%; a Cooke triplet:
# 0.25% against 0.79%), and six more cells cost a fifth of the PSF check's time
CORNER_SHARE = 0.8  # of the frame's corner
PULL = 0.97  # a light whose window leaves the sensor disc moves by this towards the axis
LABELS = {"axis": "axis", "corner80": "80% corner", "corner": "field corner",
          "edge_x": "field x edge", "edge_y": "field y edge"}
# Chebyshev nodes per axis of the window for the exact sensor-side rays. Against 9 nodes,
# the PSF intensity moved by at most 4e-8 relative L2 with 5 nodes (3e-7 with 4) over
# the axis and the field's corner of a triplet, 0001 and 0004 wide open at 450 and 650
# nm, windows of 22-588 um (tests/fit/test_trust.py checks them against every pair
# traced): five decades below the 1% target, in 0.6 times the time of 7 nodes
NODES = 5
MIN_PIXELS, MAX_PIXELS = 24, 48
MIN_POINTS, MAX_POINTS = 512, 2048


def corner_field(lens: Lens, domain: Domain, share: float = CORNER_SHARE
                 ) -> tuple[float, float]:
    """(θx, θy) in degrees of a light imaged at ``share`` of the 36 x 24 mm frame's
    (-x, -y) corner (paraxially, per meridian), pulled inside the fitted field if it lies
    beyond it. Both angles are negative (docs/conventions.md): the light is up and to
    the right of the axis, the light of every committed fit's corner cell."""
    corner = np.array([18.0, 12.0]) * share * min(1.0, domain.sensor_radius_mm
                                                  / FULL_FRAME_HALF_DIAGONAL_MM)
    efl = [abs(paraxial(lens, meridian=m).efl_mm) for m in ("x", "y")]
    theta = np.degrees(np.arctan(corner / efl))
    sx, sy = (math.sin(math.radians(f)) for f in domain.field_xy_deg)
    for _ in range(60):
        x_O, y_O = light_direction(*theta)
        if (x_O / sx) ** 2 + (y_O / sy) ** 2 <= share**2:
            break
        theta *= 0.97
    return -float(theta[0]), -float(theta[1])


def edge_fields(lens: Lens, domain: Domain) -> list[tuple[str, tuple[float, float]]]:
    """The edges of the fitted field, (name, (θx, θy) degrees): its corner on the frame's
    diagonal (:func:`corner_field` at 100%), its x edge, and for an anamorphic lens its y
    edge (a rotationally symmetric lens's y edge mirrors its x edge)."""
    fx, fy = domain.field_xy_deg
    # The frame's corner direction, scaled onto the field's ellipse in direction cosines
    x_O, y_O = light_direction(*corner_field(lens, domain, 1.0))
    sx, sy = (math.sin(math.radians(f)) for f in domain.field_xy_deg)
    rho = math.hypot(x_O / sx, y_O / sy)
    x_O, y_O = x_O / rho, y_O / rho
    z_O = math.sqrt(max(1.0 - x_O * x_O - y_O * y_O, 0.0))
    corner = (-math.degrees(math.atan2(x_O, z_O)), -math.degrees(math.atan2(y_O, z_O)))
    out = [("corner", corner), ("edge_x", (-fx, 0.0))]
    if lens.anamorphic:
        out.append(("edge_y", (0.0, -fy)))
    return out


def _f_number(lens: Lens, radius: float) -> float:
    """The f-number of a stop radius (the radius scales as 1/N, paraxially)."""
    return lens_facts(lens).stop_radius_f1_mm / radius


def _window(lens: Lens, radius: float, field: tuple[float, float], distance: float,
            lam: float, focus: float, f_number: float, *, chief: Aimed | None = None
            ) -> tuple[float, tuple[float, float]]:
    """Window width (mm) and centre: the geometric spot (exact rays through 400 stop
    points) with margin, at least four Airy radii each side of the chief ray's image.
    ``chief``: the light's ray through the stop centre (psf._chief_ray), when the
    caller has it (it does not depend on the stop or the focus)."""
    return _windows(lens, radius, field, distance, [lam], focus, f_number,
                    chiefs=chief)[0]


def _chief_rays(lens: Lens, field: tuple[float, float], distance: float,
                lams: Sequence[float]) -> Aimed:
    """psf._chief_ray at each of ``lams``, one row each, aimed together (Newton treats
    each ray alone, so each row is the ray psf._chief_ray aims)."""
    x_O, y_O = light_direction(*field)
    u_O = 0.0 if math.isinf(distance) else 1.0 / distance
    chief = psf.aim_object_side(lens, x_O, y_O, u_O, 0.0, 0.0, np.asarray(lams, float))
    if not np.all(chief.ok):
        raise ValueError(f"field_deg = {tuple(field)!r}: the chief ray of {lens.name} "
                         "misses or does not converge")
    return chief


def _windows(lens: Lens, radius: float, field: tuple[float, float], distance: float,
             lams: Sequence[float], focus: float, f_number: float, *,
             chiefs: Aimed | None = None) -> list[tuple[float, tuple[float, float]]]:
    """:func:`_window` at each of ``lams``, their rays aimed and traced together (one
    call each for all the wavelengths: the calls' own cost was most of a window's).
    ``chiefs``: :func:`_chief_rays` of ``lams``, when the caller has them."""
    lam = np.asarray(lams, dtype=np.float64)
    if chiefs is None:
        chiefs = _chief_rays(lens, field, distance, lam)
    # The chief rays' images: the centres
    end_z = lens.sensor_z + psf._check_focus(focus)
    chief = psf._rear_trace(lens, chiefs, lam, end_z)
    if np.any(chief.status != Status.OK):
        bad = Status(chief.status[np.argmax(chief.status != Status.OK)]).name
        raise ValueError(f"field_deg = {tuple(field)!r}: the chief ray of {lens.name} "
                         f"fails behind the stop (status {bad})")
    # 400 stop points at every wavelength, the spot's radius around each centre
    pts = psf.sunflower_points(400, radius)
    x_O, y_O = light_direction(*field)
    u_O = 0.0 if math.isinf(distance) else 1.0 / distance
    lam_rays = np.repeat(lam, len(pts))
    obj = psf.aim_object_side(lens, x_O, y_O, u_O, np.tile(pts[:, 0], len(lam)),
                              np.tile(pts[:, 1], len(lam)), lam_rays, outputs=False)
    rays = psf._rear_trace(lens, obj, lam_rays, end_z)
    ok = (obj.ok & (rays.status == Status.OK)).reshape(len(lam), -1)
    out = []
    for k, wavelength in enumerate(lam):
        centre = (float(chief.pos[k, 0]), float(chief.pos[k, 1]))
        pos = rays.pos.reshape(len(lam), -1, 3)[k, ok[k]]
        spot = 0.0
        if len(pos):
            spot = float(np.max(np.hypot(pos[:, 0] - centre[0], pos[:, 1] - centre[1])))
        airy = 1.22 * float(wavelength) * 1e-6 * f_number
        out.append((2.0 * max(1.3 * spot, 4.0 * airy), centre))
    return out


def psf_vs_exact(lens: Lens, systems: Sequence[System], domain: Domain, *,
                 wavelengths: Sequence[float] = WAVELENGTHS_NM,
                 f_numbers: Sequence[float] = F_NUMBERS,
                 fields: Sequence[tuple[str, tuple[float, float], float]] | None = None,
                 focus_mm: float | None = None) -> dict[str, Any]:
    """The table of the module doc: {"cells": [...], "worst": cell, "seconds": s}.

    ``fields`` (name, (θx, θy) degrees, distance mm) replace the axis and the corner
    (a scene's lights); ``focus_mm`` replaces each stop's best focus."""
    t0 = time.perf_counter()
    facts = lens_facts(lens)
    stops: list[tuple[str, float]] = [("widest", domain.stop_radius_mm)]
    for n in f_numbers:
        try:
            r = stop_radius_for_f_number(lens, n)
        except ValueError:
            continue
        if r < domain.stop_radius_mm:
            stops.append((f"f/{n:g}", r))
    # One focus per stop: its own best focus at 550 nm (or the one given), in the range;
    # the stops' searches side by side (psf.best_focus_offsets)
    focus = (psf.best_focus_offsets(lens, [r for _, r in stops], 550.0) if focus_mm is None
             else [focus_mm] * len(stops))
    focus_of = {label: min(max(z, domain.focus_min_mm), domain.focus_max_mm)
                for (label, _), z in zip(stops, focus, strict=True)}
    # Wavelengths outside a narrow fitted band are replaced by its nearest edge
    lams = sorted({min(max(float(lam), domain.wavelength_min_nm),
                       domain.wavelength_max_nm) for lam in wavelengths})
    radius_of = dict(stops)
    windows: dict[tuple[str, tuple[float, float], float, float], tuple[float, Any]] = {}
    chiefs: dict[tuple[tuple[float, float], float], Aimed] = {}

    def window(label: str, field: tuple[float, float], distance: float, lam: float
               ) -> tuple[float, tuple[float, float]]:
        """_window of a cell, computed once (_inside and the cell itself both ask), for
        every wavelength of its stop and light at once; the chief rays once per light
        (every stop shares them)."""
        key = (label, field, distance, lam)
        if key not in windows:
            r = radius_of[label]
            if (field, distance) not in chiefs:
                chiefs[field, distance] = _chief_rays(lens, field, distance, lams)
            found = _windows(lens, r, field, distance, lams, focus_of[label],
                             facts.stop_radius_f1_mm / r, chiefs=chiefs[field, distance])
            windows.update(((label, field, distance, w), f) for w, f in zip(lams, found,
                                                                           strict=True))
        return windows[key]

    # (name, field, distance, stops checked, share of the angle asked for)
    plan: list[tuple[str, tuple[float, float], float, list[str], float]] = []
    if fields is None:
        every = [label for label, _ in stops]
        edge_stops = ["widest"]
        asked = [("axis", (0.0, 0.0), every), ("corner80", corner_field(lens, domain), every),
                 *((name, f, edge_stops) for name, f in edge_fields(lens, domain))]
        for name, field, where in asked:
            inside, share = _inside(lens, domain, field, where, lams, window)
            plan.append((name, inside, math.inf, where, share))
    else:
        plan = [(name, tuple(field), distance, [label for label, _ in stops], 1.0)
                for name, field, distance in fields]
    cells = []
    for label, radius in stops:
        n_f = facts.stop_radius_f1_mm / radius  # _f_number
        focus = focus_of[label]
        for fname, field, distance, where, share in plan:
            if label not in where:
                continue
            for lam in lams:
                width, centre = window(label, field, distance, lam)
                airy = 1.22 * lam * 1e-6 * n_f
                pixels = int(min(MAX_PIXELS, max(MIN_PIXELS, math.ceil(width / (0.5 * airy)))))
                # Stop points close enough that the sum does not alias across the window
                spacing = lam * 1e-6 * facts.focal_length_mm / width
                n_pts = int(min(MAX_POINTS, max(MIN_POINTS,
                                                math.ceil(math.pi * radius**2 / spacing**2))))
                pts = psf.sunflower_points(n_pts, radius)
                common = dict(stop_radius_mm=radius, field_deg=field, distance_mm=distance,
                              wavelength_nm=lam,
                              focus_offset_mm=focus, width=pixels, height=pixels,
                              width_mm=width, center_x_mm=centre[0], center_y_mm=centre[1])
                exact, used = psf.exact_psf_nodes(lens, aperture_xy_mm=pts, nodes=NODES,
                                                  facts=facts, **common)
                poly = psf.poly_psf(systems, facts=facts, aperture_xy_mm=pts[used], **common)
                ie, ip = np.abs(exact) ** 2, np.abs(poly) ** 2
                norm = float(np.linalg.norm(ie))
                rel = float(np.linalg.norm(ip - ie) / norm) if norm > 0 else math.inf
                cells.append({
                    "stop": label, "f_number": round(n_f, 4), "stop_radius_mm": radius,
                    "field": fname, "field_deg": list(field),
                    "distance_mm": "inf" if math.isinf(distance) else distance,
                    "wavelength_nm": lam,
                    "focus_offset_mm": focus, "window_um": width * 1e3, "pixels": pixels,
                    "points": int(np.count_nonzero(used)), "relative_l2": rel,
                })
                if share != 1.0:
                    cells[-1]["field_share"] = share
    worst = max(cells, key=lambda c: c["relative_l2"])
    return {"cells": cells, "worst": worst, "seconds": time.perf_counter() - t0}


def _inside(lens: Lens, domain: Domain, field: tuple[float, float], where: list[str],
            lams: list[float], window) -> tuple[tuple[float, float], float]:
    """``field`` moved towards the axis (PULL of its angle at a time) until the window of
    each of its cells (stops ``where``, wavelengths ``lams``; ``window(stop, field,
    distance, lam)`` gives (width, centre)) lies inside the fitted sensor disc, all four
    of its corners: (the
    field, its share of the angle asked for). InputError when even a light on the axis
    does not fit (a spot wider than the fitted image circle)."""
    h = domain.sensor_radius_mm
    theta = np.array(field, dtype=np.float64)
    for _ in range(200):
        fits = True
        for label in where:
            for lam in lams:
                width, (cx, cy) = window(label, (float(theta[0]), float(theta[1])),
                                         math.inf, lam)
                # The window is a square: its corner farthest from the axis must lie in
                # the fitted disc (P_s was never sampled beyond it). A test of the
                # larger coordinate alone let lens 0003's field-corner window reach
                # 22.3 mm on a 21.6 mm disc, where P_s extrapolated to 2e-3 waves and
                # 6 um; pulled to 94% of its angle, the cell went from 1.3-1.4% to 0.55-0.65%
                if math.hypot(abs(cx) + 0.5 * width, abs(cy) + 0.5 * width) > h:
                    fits = False
                    break
            if not fits:
                break
        if fits:
            share = 1.0 if not np.any(field) else float(
                np.hypot(*theta) / np.hypot(*field))
            return (float(theta[0]), float(theta[1])), share
        if not np.any(theta):
            break
        theta *= PULL
        if np.hypot(*theta) < 1e-3:
            theta[:] = 0.0
    raise InputError(
        f"{lens.source_file or lens.name}: the PSF check: the spot of a light on the axis "
        f"at {label} ({width * 1e3:.4g} um across) does not fit in the fitted image circle "
        f"(radius {h:g} mm); a wider image circle (--image-circle) or a narrower focus "
        "range (--focus) fits it")


def trust_figures(table: dict[str, Any], psf_target: float) -> dict[str, Any]:
    """What a coefficient table carries of ``table`` (lensfit.codegen.table, version 3)."""
    return {"psf_vs_exact": table["worst"]["relative_l2"],
            "psf_vs_exact_cell": cell_label(table["worst"]), "psf_target": psf_target}


def cell_label(cell: dict[str, Any]) -> str:
    """'f/2.0 corner80 450 nm' for messages and the table."""
    where = LABELS.get(cell["field"], cell["field"])
    share = cell.get("field_share")
    if share is not None:
        where += f" (at {share:.0%} of its angle)"
    return f"f/{cell['f_number']:.3g} {where} {cell['wavelength_nm']:g} nm"


def markdown_table(table: dict[str, Any]) -> list[str]:
    """The table as Markdown lines: stops and fields as rows, wavelengths as columns."""
    cells = table["cells"]
    lams = sorted({c["wavelength_nm"] for c in cells})
    rows: dict[tuple[str, str], dict[float, dict[str, Any]]] = {}
    for c in cells:
        rows.setdefault((f"f/{c['f_number']:.3g}", c["field"]), {})[c["wavelength_nm"]] = c
    lines = ["| stop | light | " + " | ".join(f"{lam:g} nm" for lam in lams) + " | window |",
             "|---|---|" + "---:|" * len(lams) + "---:|"]
    for (stop, field), by in rows.items():
        light = {"axis": "on axis", "corner80": "80% of the corner"}.get(
            field, LABELS.get(field, field))
        share = next(iter(by.values())).get("field_share")
        if share is not None:
            light += f" ({share:.0%})"
        vals = " | ".join(f"{by[lam]['relative_l2']:.2%}" if lam in by else "-" for lam in lams)
        win = max(c["window_um"] for c in by.values())
        lines.append(f"| {stop} | {light} | {vals} | {win:.0f} µm |")
    return lines
