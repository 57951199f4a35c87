"""What a bank is worth: its reader (lensrt_bank_psf) against direct renders.

At a node every channel is the node's own render (``registration channel``: no
resampling), so the reader's error there is the node's error estimate. Between nodes the
reader blends the nodes around the query and places the result on an interpolated chief
point; this module measures that against the lens itself. At the centre of each field cell
(the point farthest from the nodes, in the first f-number / focus / distance slice) and at
the bank's first, middle and last wavelength:

* ``bank``: the reader's PSF against a direct render of the same window (centred on the
  chief point the reader returned), relative L2: what a renderer gets, placement included;
* ``nearest``: the nearest node's channel against a direct render centred on the true
  chief point: the error of taking the nearest node even with its placement exact;
* ``chief_px``: the reader's chief point's distance from the true one, in pixels.

Each direct render is integrated to the spec's target (its own error is part of both
figures). The reader's cubic blend has an error of fourth order in the grid spacing once
the grid resolves the PSF's changes, of second order at worst: halving the spacing
divides the between-node error by 4 to 16, down to the nodes' own error; the check says
how many field points per axis would at most bring the blend (on the lens's chief point)
to the spec's target (second order), and when the interpolated chief point is off by more than a
tenth of a pixel (a cubic needs 4 points on an axis: with 3, 4 px at the cell centres of
banks/demo.toml's y axis).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from lensfit.banks.node import create_render, node_light
from lensfit.banks.spec import BankSpec

MAX_POINTS = 8  # cell centres checked (spread over the grid): 3 renders x 2 each


def _centres(values: tuple[float, ...]) -> list[tuple[float, int]]:
    """Each cell's centre on one axis and its first node (one value: the value itself)."""
    if len(values) == 1:
        return [(values[0], 0)]
    return [(0.5 * (values[i] + values[i + 1]), i) for i in range(len(values) - 1)]


def _pick(points: list[Any], n: int) -> list[Any]:
    """n of the points spread evenly from the first to the last (all when there are fewer)."""
    if len(points) <= n:
        return points
    return [points[round(k * (len(points) - 1) / (n - 1))] for k in range(n)]


def _rel_l2(a: np.ndarray, ref: np.ndarray) -> float:
    norm = float(np.linalg.norm(ref))
    return float(np.linalg.norm(a - ref)) / norm if norm > 0 else math.inf


def check_bank(spec: BankSpec, index: Path, library: str, table: Path,
               max_points: int = MAX_POINTS) -> dict[str, Any]:
    """The reader against direct renders at cell centres (module doc): per point and
    wavelength the three figures, and the worst of each."""
    from lensrt_ctypes import Bank, Lensrt

    rt = Lensrt(library, threads=spec.render.threads)
    lens = rt.load(table)
    d = spec.to_dict()
    g = spec.grid
    lams = sorted({g.wavelengths_nm[0], g.wavelengths_nm[len(g.wavelengths_nm) // 2],
                   g.wavelengths_nm[-1]})
    slice_ = {"f_number": g.f_numbers[0], "focus_offset_mm": g.focus_offsets_mm[0],
              "distance_mm": g.distances_mm[0]}
    dist_q = 0.0 if math.isinf(g.distances_mm[0]) else g.distances_mm[0]
    pitch = spec.window.pitch_mm
    cells = [(x, y, ix, iy) for y, iy in _centres(g.field_y_deg)
             for x, ix in _centres(g.field_x_deg)]
    rows = []
    with Bank(rt, index) as bank:
        for fx, fy, ix, iy in _pick(cells, max_points):
            c = {**slice_, "field_x_deg": fx, "field_y_deg": fy}
            # The nearest node (ties: the first), in tan(field) as the reader interpolates
            nx = min((ix, ix + 1) if len(g.field_x_deg) > 1 else (0,),
                     key=lambda i: abs(math.tan(math.radians(g.field_x_deg[i]))
                                       - math.tan(math.radians(fx))))
            ny = min((iy, iy + 1) if len(g.field_y_deg) > 1 else (0,),
                     key=lambda i: abs(math.tan(math.radians(g.field_y_deg[i]))
                                       - math.tan(math.radians(fy))))
            for lam in lams:
                got, chief_b = bank.psf(fx, fy, lam, g.f_numbers[0], g.focus_offsets_mm[0],
                                        dist_q)
                true = rt.image_point(lens, node_light(c), lam, c["focus_offset_mm"])
                direct_b = _direct(rt, lens, d, c, lam, chief_b)
                direct_t = (direct_b if chief_b == true
                            else _direct(rt, lens, d, c, lam, true))
                near, _ = bank.psf(g.field_x_deg[nx], g.field_y_deg[ny], lam, g.f_numbers[0],
                                   g.focus_offsets_mm[0], dist_q)
                placed, _ = bank.psf(fx, fy, lam, g.f_numbers[0], g.focus_offsets_mm[0],
                                     dist_q, chief_mm=true)
                rows.append({"field_x_deg": fx, "field_y_deg": fy, "wavelength_nm": lam,
                             "bank": _rel_l2(got, direct_b),
                             "bank_lens_chief": _rel_l2(placed, direct_t),
                             "nearest": _rel_l2(near, direct_t),
                             "chief_px": math.hypot((chief_b[0] - true[0]) / pitch[0],
                                                    (chief_b[1] - true[1]) / pitch[1])})
    worst = {k: max((r[k] for r in rows), default=0.0)
             for k in ("bank", "bank_lens_chief", "nearest", "chief_px")}
    n_axis = max(len(g.field_x_deg), len(g.field_y_deg))
    # Second order in the spacing: the blend's own error (on the lens's chief point) with
    # n points per axis -> about n sqrt(worst / target) points for the target
    target = spec.render.target_error
    shape = worst["bank_lens_chief"]
    advice = (math.ceil((n_axis - 1) * math.sqrt(shape / target)) + 1
              if shape > target and n_axis > 1 else n_axis)
    return {"points": rows, "worst_bank": worst["bank"],
            "worst_bank_lens_chief": worst["bank_lens_chief"], "worst_nearest": worst["nearest"],
            "worst_chief_px": worst["chief_px"],
            "worse_than_nearest": sum(r["bank"] > r["nearest"] for r in rows),
            "wavelengths_nm": lams, "target": target,
            "field_points_for_target": advice}


def _direct(rt, lens, spec: dict[str, Any], c: dict[str, float], lam: float,
            centre: tuple[float, float]) -> np.ndarray:
    """A direct render of one wavelength, centred on ``centre``, to the spec's target."""
    r = create_render(rt, lens, spec, c, [lam], centre)
    r.integrate_to(spec["render"]["target_error"], max_rings=spec["render"]["max_rings"])
    return r.image()[0]


def check_line(result: dict[str, Any]) -> str:
    """One line for the bank's summary."""
    n = len(result["points"])
    cells = len({(p["field_x_deg"], p["field_y_deg"]) for p in result["points"]})
    line = (f"between nodes (the reader against direct renders at {cells} cell centres x "
            f"{len(result['wavelengths_nm'])} wavelengths): worst {result['worst_bank']:.2%} "
            f"relative L2 with the bank's interpolated chief point (within "
            f"{result['worst_chief_px']:.2f} px), {result['worst_bank_lens_chief']:.2%} with "
            f"the lens's own (query chief_mm); the nearest node: {result['worst_nearest']:.2%}")
    if result["worse_than_nearest"]:
        line += (f"; worse than the nearest node at {result['worse_than_nearest']} of {n} "
                 "points")
    if result["worst_bank_lens_chief"] > result["target"]:
        line += (f"; at most about {result['field_points_for_target']} field points per axis "
                 f"would reach the target {result['target']:.2%}")
    if result["worst_chief_px"] > 0.1:
        line += ("; the interpolated chief point is more than 0.1 px off: pass the lens's "
                 "(chief_mm) or give the field axes 4 points or more")
    return line
