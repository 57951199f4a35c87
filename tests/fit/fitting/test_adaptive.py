"""Adaptive fits (issue 24): the degrees grow until the held-out error leaves room, the
terms the target does not need are cut, and the grid grows where the samples, not the
degree, limit a fit. Each judged against what a user trusts: the PSF against exactly
traced rays (lensfit.trust), and the terms and bytes of the table.

* A lens whose target is met at low degree stops there: the stopping rule.
* A synthetic system whose stop degree needs more stop points than the grid starts with:
  the grid grows in that dimension alone and the output then meets its target.
* A cemented achromat imported from a .zmx (the published prescription of Thorlabs'
  AC254-100-A, its stop on the first, curved surface): a fast default fit meets the
  PSF target.
* The Cooke triplet whose glass range is narrower than 380-780 nm (N-F2 from 404.66 nm,
  tests/fit/fixtures/lens/cooke_triplet_n_f2.toml): its default-domain fit on a grid
  half the default's meets the PSF target, the grid growing where the field runs short.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest

import lensfit.fitting.tensor as tensor_fit
from lensfit.cli import main
from lensfit.fitting import FitOptions
from lensfit.fitting.options import GROW_SHARE
from lensfit.pipeline import stage
from lensfit.poly.polynomial import System
from lensfit.poly.tensor import symmetric_disc_points
from lensfit.prescription import load_lens
from lensfit.sample import OUTPUTS_O, Domain, Samples, default_domain
from lensfit.sample.rays import TRAIN_VIGNETTING, GridSamples

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "zmx"


def _import(zmx: Path, tmp: Path) -> Path:
    """`lensfit import` of a .zmx into a TOML (the user's first step)."""
    toml = tmp / f"{zmx.stem}.toml"
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["import", str(zmx), "-o", str(toml)]) == 0
    return toml


def test_a_lens_met_at_low_degree_stops_there(tmp_path):
    """The stopping rule. The hand-written achromat fixture (stop plane in front, 100 mm)
    at f/8 over 2 degrees and 500-600 nm needs little: every output reaches GROW_SHARE of
    its target at the first field degree, so the ladder stops there, and the cut keeps
    what the target needs. Measured: 162 terms (the first rung had 5548), a 7.7 KB
    table, worst PSF cell 0.17%; bounds: 400 terms, 20 KB, the 1% target."""
    lens = load_lens(_import(FIXTURES / "achromat.zmx", tmp_path))
    domain = default_domain(lens, f_number=8.0, field_deg=2.0, wavelengths_nm=(500.0, 600.0))
    fits, fig = stage.run(lens, domain=domain, generated_dir=tmp_path / "gen", timing=False)
    first = 0
    for f in fits:
        for o in f.outputs:
            # Two rungs: the first field degree, then the cut
            assert len(o.path_terms) == len(o.path_rms) == 2, (o.name, o.path_terms)
            assert o.path_rms[0] <= GROW_SHARE * o.target and o.rms <= o.target
            assert o.terms == o.path_terms[1] <= o.path_terms[0] and o.limit is None
            first += o.path_terms[0]
    terms = sum(o.terms for f in fits for o in f.outputs)
    assert terms < 400 < first
    table = next((tmp_path / "gen").glob("*/*.table"))
    assert table.stat().st_size < 20_000
    assert fig["psf_vs_exact"]["worst"]["relative_l2"] <= 0.01


# --- growth of the grid where the stop points run short (synthetic, exact) -----------------

DOMAIN = Domain(field_deg=10.0, close_focus_mm=1000.0, stop_radius_mm=5.0,
                sensor_radius_mm=10.0, focus_min_mm=-0.1, focus_max_mm=0.1)
INPUTS = DOMAIN.inputs_o()
SCAFFOLD = System("P_o", INPUTS, ())


def truth(x: np.ndarray) -> np.ndarray:
    """Outputs (N, 4) of a made-up P_o at raw inputs (N, 6): positions and tau of low
    degree, a phase whose stop part needs stop degree 6 (the x_a^6 and x_a^2 y_a^4
    terms) times a field factor of degree 2, in mm."""
    h = SCAFFOLD.normalise(x)
    xo, yo, xa, ya = h[:, 0], h[:, 1], h[:, 3], h[:, 4]
    field = 1.0 + 0.3 * xo**2 + 0.2 * yo**2
    phi = 1e-3 * field * (xa**2 + ya**2 + 0.5 * xa**6 + 0.4 * xa**2 * ya**4 - 0.3 * ya**4)
    return np.column_stack([5.0 * xa * (1 + 0.1 * xo**2), 5.0 * ya, np.full(len(x), 0.9),
                            phi])


def field_points(rng: np.random.Generator, n: int) -> np.ndarray:
    """n field points (x_O, y_O, u_O, lambda) of DOMAIN: uniform on its field disc,
    inverse distances and wavelengths uniform."""
    s = math.sin(math.radians(DOMAIN.field_deg))
    r, a = np.sqrt(rng.random(n)) * s, rng.uniform(0, 2 * math.pi, n)
    return np.column_stack([r * np.cos(a), r * np.sin(a),
                            rng.uniform(0, DOMAIN.inverse_distance_max, n),
                            rng.uniform(400.0, 700.0, n)])


def grid(field: np.ndarray, ap: np.ndarray) -> GridSamples:
    g, k = np.repeat(np.arange(len(field)), len(ap)), np.tile(np.arange(len(ap)), len(field))
    x = np.column_stack([field[g, :3], ap[k], field[g, 3]])
    shape = (len(field), len(ap))
    return GridSamples("P_o", field, ap, truth(x).reshape(*shape, 4), np.ones(shape, bool),
                       np.zeros(shape))


def test_the_grid_grows_where_the_stop_points_run_short(monkeypatch):
    """32 stop points (8 per parity class) cannot carry stop degree 6 (10 monomials in
    the even class): the phase stalls at stop degree 4, raising it to 6 is refused for
    want of stop points, so the phase names "stop points" as its limit; the grid doubles its stop
    points (only new rays are traced: extend_grid, stood in for by the exact synthetic
    truth), the phase alone is fitted again and meets its target. The other outputs,
    met at first, are not refitted."""
    rng = np.random.default_rng(1)
    field = field_points(rng, 60)
    train = grid(field, symmetric_disc_points(rng, 32) * DOMAIN.stop_radius_mm)
    n = 400
    rt = np.sqrt(rng.random(n)) * DOMAIN.stop_radius_mm
    at = rng.uniform(0, 2 * math.pi, n)
    g = rng.integers(0, 60, n)
    x = np.column_stack([field[g, :3], rt * np.cos(at), rt * np.sin(at), field[g, 3]])
    test = Samples("P_o", x, truth(x), g, np.zeros(n), n)

    calls = []

    def extend(lens, domain, grid_, *, points=0, groups=0, seed):
        calls.append((points, groups))
        more = symmetric_disc_points(np.random.default_rng(seed), points)
        return grid(grid_.field, np.concatenate([grid_.aperture,
                                                 more * DOMAIN.stop_radius_mm]))

    monkeypatch.setattr(tensor_fit, "extend_grid", extend)
    options = FitOptions(stop_pilot=False,
                         aperture_degree=4, max_aperture_degree=6, field_degrees=(2, 4),
                         target_waves=1e-6, target_position_um=1e-6, target_tau=1e-9,
                         groups=60, aperture_points=32, prune=False)
    labels: list[str] = []
    system, fits, grown = tensor_fit.fit_system_growing(
        None, DOMAIN, "P_o", INPUTS, OUTPUTS_O, train, test, options, seed=7,
        progress=labels.append)
    by = {o.name: o for o in fits}
    assert calls == [(32, 0)] and grown.aperture.shape == (64, 2)
    assert "P_o sampled again (60 field points x 64 stop points)" in labels
    assert labels.count("P_o phi_o") == 2 and labels.count("P_o x_o") == 1  # phase alone
    assert by["phi_o"].reached and by["phi_o"].limit is None
    assert all(by[k].reached for k in ("x_o", "y_o", "tau_o"))
    assert system.output_names == ["x_o", "y_o", "tau_o", "phi_o"]


# --- an imported achromat ------------------------------------------------------------------

def test_an_achromat_imported_from_zmx_meets_the_target(tmp_path):
    """Thorlabs AC254-100-A from its published prescription, written as a .zmx with the
    stop on the first (curved) surface and f/6 by its entrance pupil; imported, then
    `lensfit fit --quick` (the small grid and field degrees 4 and 6, the adaptive path
    whole: growth, the cut, the grid's growth where it is short). Its front half is a
    straight line to the stop, which the cut takes to single terms. Measured: worst PSF
    cell 0.73% (f/6 axis 450 nm) against exactly traced rays; the phase of the sensor side
    misses its held-out target at field degree 6 and says why. Bound: the 1% target."""
    toml = _import(FIXTURES / "ac254_100_a.zmx", tmp_path)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(["fit", str(toml), "--quick", "--no-timing", "--generated",
                   str(tmp_path / "gen"), "--report", str(tmp_path / "rep")])
    assert rc == 0
    meta = json.loads(next((tmp_path / "gen").glob("*/fit.json")).read_text())
    assert meta["psf_vs_exact"]["worst"]["relative_l2"] <= 0.01
    assert "within the target" in out.getvalue()
    by = {o["name"]: o for o in meta["held_out"]}
    assert by["x_o"]["terms"] == by["y_o"]["terms"] == by["tau_o"]["terms"] == 1
    for o in meta["held_out"]:
        if not o["reached"]:  # named with its reason, on the line of its output
            assert o["limit"] in ("stop points", "field points", "degree")
            line = next(ln for ln in out.getvalue().splitlines() if f" {o['name']} " in ln)
            assert "not reached: " in line




@pytest.mark.slow  # 26 s; test_glass_range_default.py fits this triplet in make test
def test_a_triplet_with_a_narrow_glass_range_meets_the_target(tmp_path):
    """The Cooke triplet with N-F2 (published from 404.66 nm): the default domain, which
    is the design's own (the file states f/5 and a 40 degree field of view: 20 degrees
    half field, 404.66-780 nm), on half the default grid (1000 field points, 150
    held-out groups), the rest default: the adaptive path grows and cuts. Measured:
    worst PSF cell 0.49% (f/5 field corner 450 nm) against exactly traced rays, the
    field's own corner and x edge included (before the field points were drawn denser
    towards the field's edges: 2.6% there, 0.44% at 80% of the corner); bound: the 1%
    target."""
    lens = load_lens(Path(__file__).resolve().parents[1] / "fixtures" / "lens"
                     / "cooke_triplet_n_f2.toml")
    options = FitOptions(groups=1000, test_groups=150)
    fits, fig = stage.run(lens, options=options, generated_dir=tmp_path, timing=False)
    assert fig["domain"]["wavelength_min_nm"] == 404.66
    assert fig["domain"]["field_deg"] == 20.0
    assert fig["psf_vs_exact"]["worst"]["relative_l2"] <= 0.01
    assert {c["field"] for c in fig["psf_vs_exact"]["cells"]} >= {"corner", "edge_x"}
    assert any(o.path_terms[-1] < max(o.path_terms) for f in fits for o in f.outputs)


# --- an output out of reach is refused early (issue 41) -------------------------------------


def test_out_of_reach_rule_on_measured_ladders():
    """The rule against the ladders measured on real lenses (held-out phase RMS in waves
    after each field degree, target 5.63e-4): 0008's P_o improves 4-6x per degree and is
    never out of reach; 0007's P_o at f/2 over 35 degrees stalls at 0.24, 0.227 and is,
    once its stop degree was raised (never before: the raise gained 10x on 0009)."""
    target = 5.63e-4
    ladder_0008 = [1.36, 0.156, 2.32e-2, 3.77e-3, 6.94e-4]
    for k in range(2, len(ladder_0008) + 1):
        assert not tensor_fit._out_of_reach(ladder_0008[:k], 6 - k, target, True)
    ladder_0007 = [2.42, 0.676, 0.368, 0.239, 0.227]
    assert tensor_fit._out_of_reach(ladder_0007, 1, target, True)
    assert not tensor_fit._out_of_reach(ladder_0007, 1, target, False)
    # Still 0.227 x 0.95^1 / 10 = 0.0216 waves at best: 38 times the target; at 0.05
    # waves and the same rate, 4.7e-3 at best, within 10 times: fitted on
    assert not tensor_fit._out_of_reach([0.0526, 0.05], 1, target, True)


def test_a_phase_no_degree_can_follow_is_refused_with_its_figures():
    """A phase with a kink-like stop dependence (|x_a|^1.5: polynomials converge at an
    algebraic rate) against a target of 1e-6 waves: the ladder stalls, the stop degree
    is raised once, and the output is refused as out of reach, naming the output, its
    error, degrees and target, before the highest field degree is tried."""
    rng = np.random.default_rng(3)
    G = 120
    field = field_points(rng, G)

    def kinked(x: np.ndarray) -> np.ndarray:
        out = truth(x)
        h = SCAFFOLD.normalise(x)
        out[:, 3] = 1e-3 * (1.0 + 0.3 * h[:, 0] ** 2) * np.abs(h[:, 3]) ** 1.5
        return out

    ap = symmetric_disc_points(rng, 128) * DOMAIN.stop_radius_mm
    g, k = np.repeat(np.arange(G), len(ap)), np.tile(np.arange(len(ap)), G)
    x = np.column_stack([field[g, :3], ap[k], field[g, 3]])
    train = GridSamples("P_o", field, ap, kinked(x).reshape(G, len(ap), 4),
                        np.ones((G, len(ap)), bool), np.zeros((G, len(ap))))
    n = 600
    rt = np.sqrt(rng.random(n)) * DOMAIN.stop_radius_mm
    at = rng.uniform(0, 2 * math.pi, n)
    gt = rng.integers(0, G, n)
    xt = np.column_stack([field[gt, :3], rt * np.cos(at), rt * np.sin(at), field[gt, 3]])
    test = Samples("P_o", xt, kinked(xt), gt, np.zeros(n), n)
    options = FitOptions(stop_pilot=False,
                         aperture_degree=6, max_aperture_degree=8, field_degrees=(2, 4, 6, 8),
                         target_waves=1e-6, groups=G, aperture_points=128, prune=False)
    with pytest.raises(tensor_fit.OutOfReach, match=r"P_o phi_o reaches \S+ waves RMS on "
                       r"held-out rays at field degree [246] \(stop degree \d+\), against "
                       r"its target 1e-06 waves"):
        tensor_fit.fit_system_tensor("P_o", INPUTS, OUTPUTS_O, train, test, options,
                                     only={"phi_o"}, refuse_out_of_reach=True)
    # Ghost fits (their own fallbacks) do not ask for it: the output is kept, limited
    _, fits = tensor_fit.fit_system_tensor("P_o", INPUTS, OUTPUTS_O, train, test, options,
                                           only={"phi_o"})
    assert not fits[0].reached and fits[0].limit is not None


def test_lensfit_fit_refuses_an_out_of_reach_lens_in_one_line(tmp_path, monkeypatch, capsys):
    """The command line: exit 2, one line naming the lens file, its domain and what to
    change, no generated folder and no checkpoint left (a rerun would be refused
    again). The fit itself stands in (the refusal of a real lens takes minutes: 0007 at
    its default domain, 132 CPU-s)."""
    from lensfit.fitting import lens as fitting_lens

    lens_file = _import(FIXTURES / "achromat.zmx", tmp_path)

    def refuse(*args, **kwargs):
        raise tensor_fit.OutOfReach("P_o phi_o reaches 0.227 waves RMS on held-out rays")

    monkeypatch.setattr(fitting_lens, "fit_system_growing", refuse)
    monkeypatch.chdir(tmp_path)
    code = main(["fit", str(lens_file), "--no-progress", "--generated", str(tmp_path / "gen"),
                 "--report", str(tmp_path / "rep")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err[-1].startswith(f"lensfit: error: {lens_file}: cannot be fitted over a ")
    assert "P_o phi_o reaches 0.227 waves" in err[-1] and "--field" in err[-1]
    assert not (tmp_path / "gen").exists() and not (tmp_path / "rep").exists()
    assert not (tmp_path / "build" / "fit-cache").exists()


# --- rays beyond the housings (FAR_WEIGHT) ---------------------------------------------------

def _far_case(share: float, seed: int = 5):
    """The made-up P_o on 120 field points x 128 stop points, ``share`` of its cells
    marked 1.3 times a housing's radius out (far, within FAR_VIGNETTING) and 5% beyond
    FAR_VIGNETTING; held-out rays from the truth."""
    rng = np.random.default_rng(seed)
    G = 120
    field = field_points(rng, G)
    train = grid(field, symmetric_disc_points(rng, 128) * DOMAIN.stop_radius_mm)
    u = rng.random(train.ok.shape)
    train.vignetting[u < share] = 1.3
    train.vignetting[u > 0.95] = 2.0
    n = 400
    rt = np.sqrt(rng.random(n)) * DOMAIN.stop_radius_mm
    at = rng.uniform(0, 2 * math.pi, n)
    g = rng.integers(0, G, n)
    x = np.column_stack([field[g, :3], rt * np.cos(at), rt * np.sin(at), field[g, 3]])
    return train, Samples("P_o", x, truth(x), g, np.zeros(n), n)


def _phase(train, test, far_weight):
    options = FitOptions(stop_pilot=False, aperture_degree=6, field_degrees=(2,),
                         target_waves=1e-9, groups=120, aperture_points=128, prune=False)
    system, _ = tensor_fit.fit_system_tensor("P_o", INPUTS, OUTPUTS_O, train, test, options,
                                             only={"phi_o"}, far_weight=far_weight)
    return system.outputs[0].coefficients


def test_far_rays_are_fitted_where_they_fill_the_grid_and_only_there():
    """Rays that exist beyond a housing are fitted at FAR_WEIGHT where they are at least
    FAR_MIN_SHARE of the grid, and never beyond FAR_VIGNETTING: wild values (1 mm of
    phase) in the cells a rule leaves out change nothing, bit for bit, while the same
    wild values in cells the rule fits move the coefficients. The made-up phase is in
    the fit's span, so wherever the cells hold the truth the fit recovers it (CG: 1e-9
    relative, as for holes in tests/fit/poly/test_tensor.py)."""
    assert 0 < tensor_fit.FAR_WEIGHT < 1 and tensor_fit.FAR_VIGNETTING > TRAIN_VIGNETTING
    # 0.5% far cells: below FAR_MIN_SHARE, they stay holes
    train, test = _far_case(0.005)
    few = train.vignetting == 1.3
    assert 0 < np.count_nonzero(few) < tensor_fit.FAR_MIN_SHARE * few.size
    clean = _phase(train, test, tensor_fit.FAR_WEIGHT)
    beyond = train.vignetting > tensor_fit.FAR_VIGNETTING
    train.outputs[few | beyond, 3] += 1.0
    assert np.array_equal(_phase(train, test, tensor_fit.FAR_WEIGHT), clean)
    # 20% far cells: fitted; the truth there gives the truth back, wild values do not
    train, test = _far_case(0.2)
    many = train.vignetting == 1.3
    beyond = train.vignetting > tensor_fit.FAR_VIGNETTING
    fitted = _phase(train, test, tensor_fit.FAR_WEIGHT)
    plain = _phase(train, test, None)
    np.testing.assert_allclose(fitted, plain, rtol=0, atol=1e-9 * np.max(np.abs(plain)))
    train.outputs[beyond, 3] += 1.0  # beyond FAR_VIGNETTING: never fitted
    assert np.array_equal(_phase(train, test, tensor_fit.FAR_WEIGHT), fitted)
    train.outputs[many, 3] += 1.0
    assert np.max(np.abs(_phase(train, test, tensor_fit.FAR_WEIGHT) - fitted)) > 1e-3
