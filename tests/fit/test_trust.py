"""How far a fit can be trusted (lensfit.trust): the exact PSF it measures against, its
table on a quick fit, and the committed fits' figures checked from fresh points.

* psf.exact_psf_nodes (each stop point's sensor-side rays traced to a Chebyshev grid and
  interpolated) against psf.exact_psf with every pair traced;
* psf_vs_exact on the quick fit of conftest.py: the documented cells and keys, the worst
  cell, what fit.json and the table record;
* the committed fits of generated/: cells of fit.json's table recomputed with other
  sunflower counts and another node count, and the committed tables of 0001 and 2004
  against exactly traced rays at points of their domains the table did not measure.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from lensfit.codegen.generate import GENERATED_DIR, lens_folder_name, read_fit_json
from lensfit.codegen.scene import light_direction
from lensfit.codegen.table import TRUST_KEYS, read_table
from lensfit.paraxial import stop_radius_for_f_number
from lensfit.paraxial.facts import lens_facts
from lensfit.prescription import load_lens
from lensfit.psf import psf
from lensfit.sample.aim import aim_sensor_side
from lensfit.trust import check as trust

LAMBDA_NM = 550.0
CELL_KEYS = {"stop", "f_number", "stop_radius_mm", "field", "field_deg", "distance_mm",
             "wavelength_nm", "focus_offset_mm", "window_um", "pixels", "points",
             "relative_l2"}


@pytest.fixture(scope="module")
def lens():
    return load_lens("0001")


def airy_radius_mm(wavelength_nm: float, f_number: float) -> float:
    return 1.22 * wavelength_nm * 1e-6 * f_number


def relative_l2(poly: np.ndarray, exact: np.ndarray) -> float:
    """The figure of lensfit.trust: ||I_poly - I_exact|| / ||I_exact|| of the intensities."""
    ie, ip = np.abs(exact) ** 2, np.abs(poly) ** 2
    return float(np.linalg.norm(ip - ie) / np.linalg.norm(ie))


# --- the exact reference --------------------------------------------------------------------


@pytest.mark.parametrize("field", [(0.0, 0.0), (3.0, 2.0), (7.0, -4.0)])
def test_exact_psf_nodes_agrees_with_every_pair_traced(lens, field):
    """f/8, 550 nm, 300 sunflower stop points, 16 x 16 pixels over eight Airy radii around
    the chief ray's image. Across such a window the sensor-side outputs of one stop point
    are polynomials of low degree in the pixel position, so the trust table's 7 x 7
    Chebyshev nodes interpolate them to the exact rays' own Newton noise: measured a
    relative L2 of the complex field of 1e-8 on axis and 5e-10 off axis. Bound 1e-6."""
    r = stop_radius_for_f_number(lens, 8.0)
    z_s = psf.best_focus_offset(lens, r, LAMBDA_NM)
    x_c, y_c = psf.geometric_image_point(lens, field, math.inf, LAMBDA_NM, z_s)
    pts = psf.sunflower_points(300, r)
    kw = dict(stop_radius_mm=r, aperture_xy_mm=pts, field_deg=field, wavelength_nm=LAMBDA_NM,
              focus_offset_mm=z_s, width=16, height=16,
              width_mm=8 * airy_radius_mm(LAMBDA_NM, 8.0), center_x_mm=x_c, center_y_mm=y_c)
    every_pair = psf.exact_psf(lens, **kw)
    nodes, used = psf.exact_psf_nodes(lens, nodes=trust.NODES, **kw)
    assert used.all()  # at f/8 every stop point's rays exist and pass
    # A focused spot, not noise: near the centre the 300 phasors of amplitude sqrt(tau)
    # ~ 0.9 add nearly in phase
    assert np.abs(every_pair).max() > 0.25 * len(pts)
    err = np.linalg.norm(nodes - every_pair) / np.linalg.norm(every_pair)
    assert err < 1e-6, err
    # exact_psf(nodes=N) is the same computation
    assert np.array_equal(psf.exact_psf(lens, nodes=trust.NODES, **kw), nodes)


def test_exact_psf_nodes_clips_at_the_last_housing_as_every_pair(lens):
    """The last surface's housing cut through the beam (its radius the median of the
    rays' |x_i, y_i|, so about half the pairs are clipped): exact_psf_nodes, which tests
    x_i, y_i only for the stop points whose polynomials' bound reaches the housing,
    against every pair traced and tested (exact_psf), as in the test above. Bound 1e-6
    as there: the clip's edge moves by the interpolation's ~1e-10 mm, a pixel's share
    of a pair crossing it"""
    r = stop_radius_for_f_number(lens, 8.0)
    field = (7.0, -4.0)
    z_s = psf.best_focus_offset(lens, r, LAMBDA_NM)
    x_c, y_c = psf.geometric_image_point(lens, field, math.inf, LAMBDA_NM, z_s)
    pts = psf.sunflower_points(300, r)
    sen = aim_sensor_side(lens, x_c, y_c, z_s, pts[:, 0], pts[:, 1], LAMBDA_NM)
    radius = float(np.median(np.hypot(sen.outputs[:, 0], sen.outputs[:, 1])))
    last = dataclasses.replace(lens.surfaces[-1], semi_diameter_mm=radius)
    cut = dataclasses.replace(lens, surfaces=(*lens.surfaces[:-1], last))
    assert lens_facts(cut).housing_last_mm == radius
    kw = dict(stop_radius_mm=r, aperture_xy_mm=pts, field_deg=field, wavelength_nm=LAMBDA_NM,
              focus_offset_mm=z_s, width=16, height=16,
              width_mm=8 * airy_radius_mm(LAMBDA_NM, 8.0), center_x_mm=x_c, center_y_mm=y_c)
    every_pair = psf.exact_psf(cut, **kw)
    nodes, used = psf.exact_psf_nodes(cut, nodes=trust.NODES, **kw)
    whole, _ = psf.exact_psf_nodes(lens, nodes=trust.NODES, **kw)
    # The housing takes a large share of the light, and the nodes' PSF follows it
    assert np.linalg.norm(whole - every_pair) > 0.2 * np.linalg.norm(every_pair)
    err = np.linalg.norm(nodes - every_pair) / np.linalg.norm(every_pair)
    assert err < 1e-6, err


def test_exact_psf_nodes_refuses_a_bad_node_count(lens):
    with pytest.raises(ValueError, match="nodes = 1: expected at least 2"):
        psf.exact_psf_nodes(lens, stop_radius_mm=3.0, aperture_xy_mm=np.zeros((1, 2)),
                            wavelength_nm=LAMBDA_NM, width=2, height=2, width_mm=0.01, nodes=1)


# --- the table of a quick fit --------------------------------------------------------------


def test_psf_vs_exact_of_a_quick_fit(quick_run):
    """The documented table over the quick fit's domain (f/8 wide open): the widest stop
    and f/32 (f/8 is the widest itself), on axis and at 80% of the corner, 450, 550 and
    650 nm, light at infinity, the best focus of the axis at 550 nm for each stop; worst
    is the largest figure. fit.json records it (without the time) and the table carries
    its worst figure, the cell's label and the target."""
    lens, domain = quick_run.lens, quick_run.domain
    table = quick_run.figures["psf_vs_exact"]
    assert set(table) == {"cells", "worst", "seconds"} and table["seconds"] > 0
    cells = table["cells"]
    # The field's own edges (corner, x edge) at the widest stop only: f/8 is the widest
    # here, and f/32 hides the field error
    assert [(c["stop"], c["field"], c["wavelength_nm"]) for c in cells] == [
        *itertools.product(["widest"], ["axis", "corner80", "corner", "edge_x"],
                           trust.WAVELENGTHS_NM),
        *itertools.product(["f/32"], ["axis", "corner80"], trust.WAVELENGTHS_NM)]
    assert table["worst"] == max(cells, key=lambda c: c["relative_l2"])
    facts = lens_facts(lens)
    radius = {"widest": domain.stop_radius_mm, "f/32": stop_radius_for_f_number(lens, 32.0)}
    corner = trust.corner_field(lens, domain)
    edge = dict(trust.edge_fields(lens, domain))
    focus = {}
    for c in cells:
        assert set(c) == CELL_KEYS  # no field_share: no light had to move inwards
        r = radius[c["stop"]]
        assert c["stop_radius_mm"] == pytest.approx(r, rel=1e-12)
        assert c["f_number"] == pytest.approx(facts.stop_radius_f1_mm / r, abs=1e-4)
        assert c["f_number"] == pytest.approx(8.0 if c["stop"] == "widest" else 32.0,
                                              rel=1e-3)
        want = {"axis": (0.0, 0.0), "corner80": corner, "corner": edge["corner"],
                "edge_x": edge["edge_x"]}[c["field"]]
        # The edge lights lie on the fitted field's boundary (direction cosines over the
        # domain's semi-axes: 1, to 1e-9 for the trigonometry)
        if c["field"] in ("corner", "edge_x"):
            x_O, y_O = light_direction(*c["field_deg"])
            sx, sy = (math.sin(math.radians(f)) for f in domain.field_xy_deg)
            assert math.hypot(x_O / sx, y_O / sy) == pytest.approx(1.0, abs=1e-9)
        assert tuple(c["field_deg"]) == pytest.approx(want, abs=1e-12)
        assert c["distance_mm"] == "inf"
        # One focus per stop, inside the fitted range
        focus.setdefault(c["stop"], c["focus_offset_mm"])
        assert c["focus_offset_mm"] == focus[c["stop"]]
        assert domain.focus_min_mm <= c["focus_offset_mm"] <= domain.focus_max_mm
        # The window: at least four Airy radii either side; pixels and stop points within
        # the module's limits
        airy_um = airy_radius_mm(c["wavelength_nm"], c["f_number"]) * 1e3
        assert c["window_um"] >= 8 * airy_um * (1 - 1e-9)
        assert trust.MIN_PIXELS <= c["pixels"] <= trust.MAX_PIXELS
        assert 0.9 * trust.MIN_POINTS <= c["points"] <= trust.MAX_POINTS
        assert math.isfinite(c["relative_l2"]) and c["relative_l2"] > 0
    for stop, z in focus.items():
        best = psf.best_focus_offset(lens, radius[stop], 550.0)
        assert z == pytest.approx(best, abs=1e-12)
    # Recorded: fit.json without the time, the table's trust lines, the figures
    systems, meta = read_fit_json(quick_run.folder / "fit.json")
    assert meta["psf_vs_exact"] == {k: v for k, v in table.items() if k != "seconds"}
    assert systems.trust == trust.trust_figures(table, quick_run.options.psf_target)
    assert systems.trust == {"psf_vs_exact": table["worst"]["relative_l2"],
                             "psf_vs_exact_cell": trust.cell_label(table["worst"]),
                             "psf_target": quick_run.options.psf_target}
    assert quick_run.figures["psf_target"] == quick_run.options.psf_target


def test_cell_labels_and_markdown():
    cell = {"stop": "widest", "f_number": 2.0, "field": "corner80", "wavelength_nm": 450.0,
            "window_um": 193.3, "relative_l2": 0.0017753}
    assert trust.cell_label(cell) == "f/2 80% corner 450 nm"
    assert trust.cell_label({**cell, "field": "axis", "f_number": 8.0,
                             "wavelength_nm": 550.0}) == "f/8 axis 550 nm"
    assert trust.cell_label({**cell, "field": "light0"}) == "f/2 light0 450 nm"
    figures = trust.trust_figures({"cells": [cell], "worst": cell}, 0.01)
    assert tuple(figures) == TRUST_KEYS
    lines = trust.markdown_table({"cells": [cell, {**cell, "wavelength_nm": 550.0,
                                                   "relative_l2": 0.0012}]})
    assert lines[0] == "| stop | light | 450 nm | 550 nm | window |"
    assert lines[2] == "| f/2 | 80% of the corner | 0.18% | 0.12% | 193 µm |"


# --- the committed fits ---------------------------------------------------------------------


def committed(lens_id: str):
    """(lens, table, fit.json) of generated/<lens>/ (lensfit-fit 2, table version 5)."""
    lens = load_lens(lens_id)
    systems, meta = read_fit_json(GENERATED_DIR / lens_folder_name(lens) / "fit.json")
    assert systems.version == 5 and systems.trust is not None
    return lens, systems, meta


@pytest.fixture(scope="module")
def committed_fits():
    cache = {}

    def get(lens_id: str):
        if lens_id not in cache:
            cache[lens_id] = committed(lens_id)
        return cache[lens_id]

    return get


def recompute(lens, systems, cell: dict, points: int, nodes: int) -> float:
    """The cell's figure from scratch: its stop, light, focus, wavelength and window
    (centred on the chief ray's image, as lensfit.trust centres it), but ``points``
    sunflower stop points and ``nodes`` Chebyshev nodes."""
    lam, field = cell["wavelength_nm"], tuple(cell["field_deg"])
    distance = math.inf if cell["distance_mm"] == "inf" else cell["distance_mm"]
    x_c, y_c = psf.geometric_image_point(lens, field, distance, lam, cell["focus_offset_mm"])
    pts = psf.sunflower_points(points, cell["stop_radius_mm"])
    kw = dict(stop_radius_mm=cell["stop_radius_mm"], field_deg=field, distance_mm=distance,
              wavelength_nm=lam, focus_offset_mm=cell["focus_offset_mm"],
              width=cell["pixels"], height=cell["pixels"], width_mm=cell["window_um"] * 1e-3,
              center_x_mm=x_c, center_y_mm=y_c)
    exact, used = psf.exact_psf_nodes(lens, aperture_xy_mm=pts, nodes=nodes, **kw)
    assert used.sum() > 0.9 * points
    poly = psf.poly_psf(systems, facts=lens_facts(lens), aperture_xy_mm=pts[used], **kw)
    return relative_l2(poly, exact)


def test_committed_figures_recomputed_from_fresh_points(committed_fits):
    """Lens 0001: the report's worst cell and the f/8 corner cell at 550 nm, recomputed
    with other stop points (sunflower sets of 1100 and 700 points instead of the cell's)
    and 9 Chebyshev nodes instead of 7. Same points would agree to ~1e-6 (the exact
    rays' Newton noise); other points sample the pupil differently. Measured on the
    committed fit: 2-5% for the f/2 corner cell (700-1500 points against 2048), 0.2-0.4%
    for the f/8 cells, up to 25% for the f/2 axis cells (whose spacing rule gives ~600
    points, and whose figure is ten times below the worst). Tolerances: 30% for the
    worst cell (whichever it is after a refit), 5% for the f/8 cell. Both stay within
    the fit's PSF target when the report says so."""
    lens, systems, meta = committed_fits("0001")
    table = meta["psf_vs_exact"]
    worst = table["worst"]
    assert worst == max(table["cells"], key=lambda c: c["relative_l2"])
    f8 = next(c for c in table["cells"] if c["stop"] == "f/8" and c["field"] == "corner80"
              and c["wavelength_nm"] == LAMBDA_NM)
    target = meta["options"]["psf_target"]
    for cell, points, rtol in ((worst, 1100, 0.30), (f8, 700, 0.05)):
        assert cell["points"] != points
        got = recompute(lens, systems, cell, points, nodes=9)
        print(f"{trust.cell_label(cell)}: fit.json {cell['relative_l2']:.4g}, "
              f"recomputed {got:.4g} ({points} points)")
        assert got == pytest.approx(cell["relative_l2"], rel=rtol), trust.cell_label(cell)
        if worst["relative_l2"] <= target:
            assert got <= target


# Light off axis at half the fitted field in x and in y (ellipse radius 0.71)
FIELD_SHARE = 0.5
# The committed figure is the worst over the trust table's cells; these points lie between
# cells (other fields, windows, points), where the error varies smoothly: a factor 2 on the
# worst cell. The floor (0.05%) covers a fit whose table is far below anything a PSF
# shows (the report prints two decimals of a percent). Measured: 0001 1.4e-5 - 1.3e-3
# against a bound 3.6e-3; 2004 1.1e-4 - 9.6e-4 against 1.3e-2.
TRUST_MARGIN, TRUST_FLOOR = 2.0, 5e-4


@pytest.mark.parametrize("field", ["axis", "off-axis"])
@pytest.mark.parametrize("stop", ["f/8", "widest"])
@pytest.mark.parametrize("lens_id", ["0001", "2004"])
def test_committed_table_against_exact_rays(committed_fits, lens_id, stop, field):
    """The committed table (lensrt's input) against exactly traced rays at 550 nm, a light
    at infinity, 16 x 16 pixels over eight Airy radii around the chief ray's image, the
    best axial focus for the stop, 400 sunflower stop points. The domain is the table's:
    the widest stop is x_a's range (2004 declares f/4 and a 24 x 13 degree field in its
    [fit] table), the light sits at half the fitted direction cosines. Asserts what the
    report claims: within its worst figure (with the margin above)."""
    lens, systems, _ = committed_fits(lens_id)
    p_o, p_s = systems
    ins_o = {i.name: i for i in p_o.inputs}
    ins_s = {i.name: i for i in p_s.inputs}
    widest = ins_o["x_a"].hi
    radius = widest if stop == "widest" else stop_radius_for_f_number(lens, 8.0)
    assert radius <= widest
    f_number = lens_facts(lens).stop_radius_f1_mm / radius
    if field == "axis":
        light = (0.0, 0.0)
    else:  # direction cosines (x, y, z) towards the light -> the chief ray's angles
        x, y = FIELD_SHARE * ins_o["x_O"].hi, -FIELD_SHARE * ins_o["y_O"].hi
        z = math.sqrt(1.0 - x * x - y * y)
        light = (math.degrees(math.atan(-x / z)), math.degrees(math.atan(-y / z)))
        assert psf.light_direction(*light) == pytest.approx((x, y), rel=1e-12)
    focus = min(max(psf.best_focus_offset(lens, radius, LAMBDA_NM), ins_s["z_S"].lo),
                ins_s["z_S"].hi)
    x_c, y_c = psf.geometric_image_point(lens, light, math.inf, LAMBDA_NM, focus)
    assert abs(x_c) < ins_s["x_S"].hi and abs(y_c) < ins_s["y_S"].hi
    pts = psf.sunflower_points(400, radius)
    kw = dict(stop_radius_mm=radius, field_deg=light, wavelength_nm=LAMBDA_NM,
              focus_offset_mm=focus, width=16, height=16,
              width_mm=8 * airy_radius_mm(LAMBDA_NM, f_number), center_x_mm=x_c,
              center_y_mm=y_c)
    exact, used = psf.exact_psf_nodes(lens, aperture_xy_mm=pts, nodes=trust.NODES, **kw)
    assert used.sum() > 0.9 * len(pts)
    poly = psf.poly_psf(systems, facts=systems.lens, aperture_xy_mm=pts[used], **kw)
    got = relative_l2(poly, exact)
    claimed = systems.trust["psf_vs_exact"]
    print(f"{lens_id} {stop} (f/{f_number:.3g}) {field}: {got:.3g}, table claims {claimed:.3g}")
    assert got <= TRUST_MARGIN * max(claimed, TRUST_FLOOR)


def test_committed_table_facts_are_the_lens_facts(committed_fits):
    """poly_psf above clips with the table's facts: they are the lens's."""
    for lens_id in ("0001", "2004"):
        lens, systems, _ = committed_fits(lens_id)
        assert systems.lens == lens_facts(lens)
        table = GENERATED_DIR / lens_folder_name(lens) / f"lens{lens_id}.table"
        assert read_table(table.read_text(encoding="utf-8")).trust == systems.trust


def test_a_cell_window_is_pulled_until_its_corners_lie_in_the_fitted_disc():
    """The PSF check evaluates P_s over its window's pixels, and P_s was fitted on the
    sensor disc only: a window on the diagonal whose larger coordinate plus half its
    width fits (a box test) can still reach outside the disc with its corner (lens
    0003's field-corner window: 22.3 mm on a 21.6 mm disc, where P_s extrapolated to
    2e-3 waves). A made-up window (centre proportional to the field angle, 1 mm wide)
    starts just inside by the box test and outside by its corner: _inside pulls the
    light (PULL at a time) until the corner is inside, and no further than one step."""
    from lensfit.sample.domain import Domain

    h, width = 21.6, 1.0
    domain = Domain(field_deg=20.0, close_focus_mm=math.inf, stop_radius_mm=5.0,
                    sensor_radius_mm=h, focus_min_mm=-0.1, focus_max_mm=0.1)
    scale = (h - 0.5 * width - 0.05) / math.sqrt(2) / 10.0  # mm per degree on the diagonal

    def window(label, field, distance, lam):
        return width, (scale * field[0], scale * field[1])

    field = (10.0, 10.0)
    cx, cy = window("widest", field, math.inf, 550.0)[1]
    assert max(abs(cx), abs(cy)) + 0.5 * width <= h  # the box test passed it
    assert math.hypot(abs(cx) + 0.5 * width, abs(cy) + 0.5 * width) > h
    inside, share = trust._inside(None, domain, field, ["widest"], [550.0], window)
    cx, cy = window("widest", inside, math.inf, 550.0)[1]
    assert math.hypot(abs(cx) + 0.5 * width, abs(cy) + 0.5 * width) <= h
    assert share < 1.0
    cx, cy = (c / trust.PULL for c in (cx, cy))  # one step less would not fit
    assert math.hypot(abs(cx) + 0.5 * width, abs(cy) + 0.5 * width) > h
