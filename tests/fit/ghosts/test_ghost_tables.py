"""Ghost tables (issue 13, parts 3 and 5): the table format's ghost lines and P_clip,
and the committed ghost tables of 0001 against exactly traced ghost rays: the Huygens
image (relative L2), its energy and footprint, and the paper's Figure 6 failure (the
same ghost without P_clip) shown to be caught."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lensfit.codegen.table import (
    CLIP_SYSTEM,
    GhostLines,
    Table,
    read_table,
    with_checksum,
    write_table,
)
from lensfit.poly import Input, Polynomial, System
from lensfit.prescription import load_lens
from lensfit.psf.psf import exact_psf, poly_psf, sunflower_points
from lensfit.sample.ghost import ghost_half

ROOT = Path(__file__).resolve().parents[3]
FOLDER = ROOT / "generated" / "0001-angenieux-double-gauss"
GHOSTS = FOLDER / "ghosts"


def _system(name: str, outputs: list[tuple[str, str]], inputs=("x_a", "y_a")) -> System:
    ins = tuple(Input(n, "mm", -2.0, 2.0) for n in inputs)
    outs = tuple(Polynomial(o, unit, np.array([[1, 0], [0, 1]], dtype=np.int32),
                            np.array([0.5, -0.25])) for o, unit in outputs)
    return System(name, ins, outs)


@pytest.fixture(scope="module")
def direct() -> Table:
    return read_table((FOLDER / "lens0001.table").read_text())


GHOST_4_8 = GhostLines(4, 8, "4-8", "P_s")


def _ghost_text(direct: Table, clip: System | None, ghost: GhostLines = GHOST_4_8) -> str:
    systems = [*direct] + ([clip] if clip else [])
    return write_table(Table(systems, direct.lens, 3, direct.trust, ghost))


def test_ghost_lines_and_p_clip_round_trip(direct):
    p_s = next(s for s in direct if s.name == "P_s")
    pairs = [("x_h3", "1"), ("y_h3", "1"), ("x_s1", "mm"), ("y_s1", "mm")]
    clip = System(CLIP_SYSTEM, p_s.inputs, _system("c", pairs).outputs[:0] + tuple(
        Polynomial(n, u, np.zeros((1, 6), dtype=np.int32), np.array([0.1]))
        for n, u in pairs))
    back = read_table(_ghost_text(direct, clip))
    assert back.ghost == GhostLines(4, 8, "4-8", "P_s")
    assert [s.name for s in back] == ["P_o", "P_s", CLIP_SYSTEM]
    assert back[2].inputs == p_s.inputs
    assert [p.output for p in back[2].outputs] == [n for n, _ in pairs]
    # A direct table has no ghost lines
    assert read_table((FOLDER / "lens0001.table").read_text()).ghost is None


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("ghost second 8", "ghost second 3"), "more than ghost first"),
    (lambda t: t.replace("ghost side P_s", "ghost side P_x"), "expected P_o or P_s"),
    (lambda t: t.replace("ghost label 4-8\n", ""), "ghost line 3 of 4"),
    (lambda t: t.replace("ghost first 4\nghost second 8", "ghost second 8\nghost first 4"),
     "keys come in the order"),
    (lambda t: t.replace("output x_s1 mm", "output x_s1 1"), "expected a pair"),
    (lambda t: t.replace("output y_s1 mm", "output y_q1 mm"), "expected a pair"),
    (lambda t: t.replace("ghost first 4\nghost second 8\nghost label 4-8\nghost side P_s\n",
                         ""), "without ghost lines"),
])
def test_malformed_ghost_tables_name_the_line(direct, edit, message):
    p_s = next(s for s in direct if s.name == "P_s")
    clip = System(CLIP_SYSTEM, p_s.inputs, tuple(
        Polynomial(n, u, np.zeros((1, 6), dtype=np.int32), np.array([0.1]))
        for n, u in [("x_s1", "mm"), ("y_s1", "mm")]))
    text = _ghost_text(direct, clip)
    assert read_table(text).ghost is not None  # the unedited text is valid
    edited = "".join(t for t in edit(text).splitlines(keepends=True)
                     if not t.startswith("checksum crc32 "))
    with pytest.raises(ValueError, match=message):
        read_table(with_checksum(edited))  # stamped: the parser's check, not the checksum


def test_p_clip_inputs_must_be_the_ghost_sides(direct):
    p_o = next(s for s in direct if s.name == "P_o")
    clip = System(CLIP_SYSTEM, p_o.inputs, tuple(
        Polynomial(n, "1", np.zeros((1, 6), dtype=np.int32), np.array([0.1]))
        for n in ("x_h2", "y_h2")))
    with pytest.raises(ValueError, match="inputs differ"):
        _ghost_text(direct, clip)  # the ghost side is P_s
    text = _ghost_text(direct, clip, GhostLines(0, 2, "0-2", "P_o"))
    assert read_table(text).ghost.side == "P_o"


# --- the committed ghost tables of 0001 against exact ghost rays --------------------------

@pytest.fixture(scope="module")
def report() -> dict:
    return json.loads((GHOSTS / "ghosts.json").read_text())


def test_committed_ghost_tables_share_the_direct_fit(direct, report):
    """Each ghost table's other half is the committed direct system, bit for bit (a refit
    of the lens without `lensfit ghosts --fit` would break this), and its lens lines are
    the direct table's."""
    assert {g["label"] for g in report["ghosts"]} == {"0-2", "0-4", "2-4", "2-6", "4-8"}
    for g in report["ghosts"]:
        t = read_table((GHOSTS / f"ghost_{g['first']}_{g['second']}.table").read_text())
        assert t.ghost == GhostLines(g["first"], g["second"], g["label"], g["side"])
        assert t.lens == direct.lens
        other = "P_s" if g["side"] == "P_o" else "P_o"
        mine, theirs = (next(s for s in x if s.name == other) for x in (t, direct))
        assert write_table([mine]) == write_table([theirs])  # every coefficient's 17 digits
        # The report's figures meet the targets
        assert g["clip_agreement"] >= 0.995
        assert g["psf_vs_exact"] <= 0.03
        assert t.trust["psf_vs_exact"] == pytest.approx(g["psf_vs_exact"], rel=1e-15)


def _footprint(image: np.ndarray) -> int:
    """Pixels whose irradiance is above 1% of the window's mean (the issue's footprint)."""
    return int(np.sum(image > 0.01 * image.mean()))


@pytest.mark.parametrize("first, second, clip_matters", [(0, 2, False), (4, 8, True)])
def test_fitted_ghost_against_exact_ghost_rays(direct, report, first, second, clip_matters):
    """At f/8, 550 nm, the light of its trust cell, on a 32 x 32 window around the ghost,
    with the same 1000 sunflower stop points: the Huygens image of the fitted ghost table
    against that of exactly traced ghost rays. Bounds (issue 13): relative L2 <= 3%, energy and
    footprint within 2%. Measured: 0-2 0.15% (light at (-6, -4) deg), 4-8 0.91% (on the
    axis: from (-6, -4) it never reaches the sensor) L2, energies within 0.3%.
    Without P_clip, 4-8 (its stop crossings clip 9% of its rays over the domain) comes
    out 15% too bright; the test asks for more than 5%."""
    lens = load_lens("0001")
    g = next(x for x in report["ghosts"] if (x["first"], x["second"]) == (first, second))
    cell = next(c for c in g["trust"] if c["wavelength_nm"] == 550.0)
    cx, cy, width = cell["window"]
    table = read_table((GHOSTS / f"ghost_{first}_{second}.table").read_text())
    r = table.lens.stop_radius_f1_mm / 8.0
    kw = dict(stop_radius_mm=r, aperture_xy_mm=sunflower_points(1000, r),
              wavelength_nm=550.0, width=32, height=32, width_mm=width, center_x_mm=cx,
              center_y_mm=cy, field_deg=tuple(cell["field_deg"]))
    exact = np.abs(exact_psf(lens, ghost=ghost_half(lens, first, second), **kw)) ** 2
    fitted = np.abs(poly_psf(table, **kw)) ** 2
    assert np.linalg.norm(fitted - exact) / np.linalg.norm(exact) <= 0.03
    assert fitted.sum() / exact.sum() == pytest.approx(1.0, abs=0.02)
    assert _footprint(fitted) == pytest.approx(_footprint(exact), rel=0.02)
    # The ghost is that dim next to the direct image (the enumeration's estimate, 1.1e-5
    # of the direct power at 550 nm, counts the whole ghost; the window holds most of it)
    direct_power = np.abs(poly_psf(direct, **kw)) ** 2
    assert 1e-6 < fitted.sum() / direct_power.sum() < 1e-4
    # Figure 6: the same ghost without P_clip
    no_clip = Table([s for s in table if s.name != CLIP_SYSTEM], table.lens, 3, table.trust,
                    table.ghost)
    loose = np.abs(poly_psf(no_clip, **kw)) ** 2
    if clip_matters:
        assert loose.sum() / exact.sum() > 1.05
    else:
        assert CLIP_SYSTEM not in [s.name for s in table]


@pytest.mark.parametrize("first, second, light", [(0, 2, (-6.0, -4.0)), (4, 8, (0.0, 0.0))])
def test_exact_ghost_psf_interpolated_sensor_side_agrees_with_every_pair(
        monkeypatch, direct, report, first, second, light):
    """The trust cells' exact PSF takes a ghost's sensor side (the direct half for 0-2,
    the ghost's own half with its housings and stop crossings for 4-8) from node rays
    interpolated to the pixels where checked rays agree (psf._interpolated_sensor); the
    image agrees with the one from a ray traced for every (stop point, pixel) pair
    (measured ~1e-9), and a stop point whose check fails is traced per pixel instead."""
    import lensfit.psf.psf as psf

    lens = load_lens("0001")
    half = ghost_half(lens, first, second)
    g = next(x for x in report["ghosts"] if (x["first"], x["second"]) == (first, second))
    cx, cy, width = next(c for c in g["trust"] if c["wavelength_nm"] == 550.0)["window"]
    r = direct.lens.stop_radius_f1_mm / 8.0
    kw = dict(stop_radius_mm=r, aperture_xy_mm=sunflower_points(60, r), wavelength_nm=550.0,
              width=16, height=16, width_mm=width, center_x_mm=cx, center_y_mm=cy,
              field_deg=light, ghost=half)
    interpolated = exact_psf(lens, **kw)
    checked = psf._interpolated_sensor
    with monkeypatch.context() as m:  # every point fails its check: all traced per pixel
        m.setattr(psf, "INTERP_TOL_WAVES", -1.0)
        fallback = exact_psf(lens, **kw)
    with monkeypatch.context() as m:  # no interpolation at all
        m.setattr(psf, "_interpolated_sensor",
                  lambda *a, **k: (np.zeros((16, 16), complex), np.ones(len(a[4]), bool)))
        every = exact_psf(lens, **kw)
    assert psf._interpolated_sensor is checked
    assert np.abs(every).max() > 0
    assert np.linalg.norm(interpolated - every) <= 1e-6 * np.linalg.norm(every)
    assert np.linalg.norm(fallback - every) <= 1e-12 * np.linalg.norm(every)


def test_a_ghost_that_misses_its_target_is_named_with_the_reason():
    """miss_reason (the report's and ghosts.json's 'miss_reason'): None within target;
    otherwise the worst cell and every cause the fit's own figures show, each output
    above its held-out target, P_clip's agreement, the aiming's reach, the power."""
    from types import SimpleNamespace

    from lensfit.fitting import OutputFit
    from lensfit.ghosts.tables import TRUST_TARGET, TrustCell, miss_reason

    def out(name, rms, target):
        return OutputFit("P_s", name, "waves" if name == "phi" else "mm", 100, 8, rms,
                         2 * rms, [], [], target, rms <= target)

    def cell(lam, err, energy=1.0):
        return TrustCell(8.0, lam, (-6.0, -4.0), (0.0, 0.0, 1.0), err, energy, energy, 1.0)

    good = SimpleNamespace(outputs=[out("x", 1e-4, 1e-3), out("phi", 1e-3, 1e-2)],
                           agreement_housings=1.0, converged_test=1.0)
    assert miss_reason(good, [cell(450.0, 0.01), cell(550.0, TRUST_TARGET)]) is None
    bad = SimpleNamespace(outputs=[out("x", 1e-2, 1e-3), out("phi", 0.75, 1e-2)],
                          agreement_housings=0.97, converged_test=0.93)
    why = miss_reason(bad, [cell(450.0, 0.1665, 1.08), cell(550.0, 0.05)])
    for part in ("PSF 16.65%", "f/8 450 nm", "P_s phi 0.75 waves RMS", "P_s x 0.01 mm",
                 "P_clip's verdict agrees on 97.00%", "exact aiming reached 93.0%",
                 "power 1.080"):
        assert part in why, why
    quiet = SimpleNamespace(outputs=[out("phi", 1e-3, 1e-2)], agreement_housings=1.0,
                            converged_test=1.0)
    assert "every output within its held-out target" in miss_reason(quiet,
                                                                     [cell(650.0, 0.04)])
