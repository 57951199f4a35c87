"""The default fit band follows the glasses (lensfit.glass.ranges.default_wavelengths).

A lens fits 380-780 nm narrowed to the range every glass supports; ``--wavelengths`` (or
a scene) outside a glass's range is still refused; extrapolation stays opt-in and keeps
380-780 nm. The band and why are printed in one line, recorded in fit.json, the table's
comment and the report, and lensrt refuses wavelengths outside the table's band.

The fixture tests/fit/fixtures/lens/cooke_triplet_n_f2.toml is the Cooke triplet of
the Zemax sample "Cooke 40 degree field" (50 mm, f/5, 20 degrees) in N-SK16 and SCHOTT
N-F2; N-F2 is published over 404.66-2325.4 nm only. Every CLI case here but the one
real fit (``--quick``, about 20 s) is refused, or stopped, before any sampling.
"""

from __future__ import annotations

import json
import os
import re
import tomllib
from pathlib import Path

import pytest

from lensfit.cli import main
from lensfit.cli.fit import _print_extrapolated
from lensfit.codegen import read_table
from lensfit.codegen.scene import SCENE_WAVELENGTH_MARGIN_NM, Scene, scene_domain
from lensfit.common.errors import LensError
from lensfit.glass.manufacturers import load_catalog
from lensfit.paraxial import paraxial, stop_radius_for_f_number
from lensfit.pipeline import stage
from lensfit.prescription import load_lens
from lensfit.prescription.ranges import DEFAULT_BAND_NM, MIN_BAND_NM, default_wavelengths
from lensfit.sample.domain import default_domain, fit_wavelengths

REPO = Path(__file__).resolve().parents[3]
TRIPLET = REPO / "tests" / "fit" / "fixtures" / "lens" / "cooke_triplet_n_f2.toml"
LINE = ("wavelengths 404.66-780 nm: the range every glass supports (SCHOTT:N-F2: "
        "404.66-2325.4 nm) within 380-780 nm")


@pytest.fixture(scope="module")
def triplet():
    return load_lens(str(TRIPLET))


def _variant(tmp_path: Path, *edits: tuple[str, str], name: str = "t.toml") -> Path:
    """The fixture with text replaced (each ``old`` must be there)."""
    text = TRIPLET.read_text(encoding="utf-8")
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new, 1)
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture
def stub(monkeypatch):
    """stage.run replaced: records what the CLI asked for, fits nothing."""
    calls: list[dict] = []

    def run(lens, **kw):
        calls.append({"lens": lens, **kw})
        raise SystemExit(0)  # stop the command here: nothing after the fit matters

    monkeypatch.setattr(stage, "run", run)
    return calls


def _cli(argv: list[str], capsys) -> tuple[int, str, str]:
    try:
        rc = main(argv)
    except SystemExit as e:
        rc = e.code
    out = capsys.readouterr()
    return rc, out.out, out.err


# --- the fixture -------------------------------------------------------------------------


def test_fixture_is_a_sane_cooke_triplet(triplet):
    """EFL 50 mm (the design's), f/4.5 wide open (f/5 as designed), a plane stop in air
    between the flint and the rear crown; the default domain is the design's own: its
    stated f/5 and 40 degree field of view (the 36 x 24 mm frame would be 23.4)."""
    p = paraxial(triplet)
    assert p.efl_mm == pytest.approx(50.0, rel=2e-3)
    assert 4.0 <= p.f_number <= 5.0
    stop = triplet.surfaces[triplet.stop_index]
    assert stop.stop and not getattr(stop, "inserted", False)
    assert triplet.medium_before(triplet.stop_index).name == "air"
    assert triplet.medium_after(triplet.stop_index).name == "air"
    d = default_domain(triplet)
    assert d.field_deg == 20.0
    assert d.stop_radius_mm == pytest.approx(stop_radius_for_f_number(triplet, 5.0), rel=1e-12)


# --- the default band ----------------------------------------------------------------------


def _published_ranges() -> dict[str, tuple[float, float]]:
    """Every glass of the fixture with its range, read without lensfit's lens loader: the
    lens file (tomllib), the project catalog's TOML and SCHOTT's spreadsheet."""
    lens = tomllib.loads(TRIPLET.read_text(encoding="utf-8"))
    project = tomllib.loads((REPO / "lensdb" / "glass" / "catalog.toml")
                            .read_text(encoding="utf-8"))
    project = {g["name"]: tuple(g["range_nm"]) for g in project["glass"]}
    out = {}
    for s in lens["surface"]:
        m = s["material"]
        if m == "air":
            continue
        maker, _, name = m.rpartition(":")
        out[m] = (tuple(load_catalog(maker.upper())[name].range_nm) if maker
                  else project[name])
    out["MgF2"] = project["MgF2"]  # the default coating of every glass-air surface
    return out


def test_default_band_is_the_intersection_of_the_glass_ranges(triplet):
    ranges = _published_ranges()
    assert ranges["schott:N-F2"] == (404.66, 2325.4)  # SCHOTT prints N-F2 from the h line
    lo = max(DEFAULT_BAND_NM[0], *(r[0] for r in ranges.values()))
    hi = min(DEFAULT_BAND_NM[1], *(r[1] for r in ranges.values()))
    assert (lo, hi) == (404.66, 780.0)
    d = default_domain(triplet)
    assert (d.wavelength_min_nm, d.wavelength_max_nm) == (lo, hi)
    w = default_wavelengths(triplet)
    assert (w.lo_nm, w.hi_nm, w.asked_by) == (lo, hi, None)
    assert w.line() == LINE
    assert fit_wavelengths(triplet) == w
    # Explicit wavelengths are taken as asked (checked when the fit starts)
    assert default_domain(triplet, wavelengths_nm=(450.0, 650.0)).wavelength_min_nm == 450.0


def test_a_lens_whose_glasses_cover_the_band_keeps_380_780():
    d = default_domain(load_lens("0001"))
    assert (d.wavelength_min_nm, d.wavelength_max_nm) == DEFAULT_BAND_NM
    assert default_wavelengths(load_lens("0001")).line() == (
        "wavelengths 380-780 nm: the default range, which every glass supports")


def test_both_ends_narrowed_names_every_narrowing_glass(tmp_path):
    """An inline glass published over 400-700 nm (lensdb/README.md's example) for the
    front crown: 404.66 from N-F2, 700 from it."""
    sk16 = ('{ name = "SK16", formula = "sellmeier3", coefficients = [1.34317774, '
            '0.241144399, 0.994317969, 0.00704687339, 0.0229005004, 92.7508526], '
            'range_nm = [400, 700] }')
    lens = load_lens(str(_variant(tmp_path, ('material = "N-SK16"', f"material = {sk16}"))))
    assert default_wavelengths(lens).line() == (
        "wavelengths 404.66-700 nm: the range every glass supports (SK16: 400-700 nm, "
        "SCHOTT:N-F2: 404.66-2325.4 nm) within 380-780 nm")


@pytest.mark.parametrize(("range_nm", "says"), [
    ("[300, 420]", "leave only 404.66-420 nm within 380-780 nm, less than the 50 nm a "
                   "default fit covers; ask for it with --wavelengths 404.66,420 or allow "
                   "extrapolation"),
    ("[300, 400]", "have no wavelength in common within 380-780 nm; allow extrapolation"),
])
def test_too_narrow_or_empty_is_an_error_naming_the_glasses(tmp_path, capsys, range_nm,
                                                             says):
    glass = ('{ name = "UV", formula = "sellmeier3", coefficients = [1.03961212, '
             '0.231792344, 1.01046945, 0.00600069867, 0.0200179144, 103.560653], '
             f'range_nm = {range_nm} }}')
    path = _variant(tmp_path, ('material = "N-SK16"', f"material = {glass}"))
    lo, hi = json.loads(range_nm)
    with pytest.raises(LensError) as info:
        default_wavelengths(load_lens(str(path)))
    e = info.value
    assert (e.file, e.surface, e.key) == (str(path), 0, "material")
    assert str(e).startswith(f"{path}: surface 0: key 'material': no default wavelength "
                             f"range: the published ranges of the glasses (UV: {lo}-{hi} "
                             "nm, SCHOTT:N-F2: 404.66-2325.4 nm) ")
    assert says in str(e)
    assert MIN_BAND_NM == 50.0
    # The CLI says so in one line, before any work; lensfit info too, and goes on
    rc, out, err = _cli(["fit", str(path), "--quick", "--generated", str(tmp_path / "g"),
                         "--report", str(tmp_path / "r")], capsys)
    assert (rc, out) == (2, "") and err.count("\n") == 1 and says in err
    assert not (tmp_path / "g").exists()
    rc, out, _ = _cli(["info", str(path)], capsys)
    assert rc == 0 and "  default fit         none: no default wavelength range" in out
    # Extrapolation allowed: the default band again
    rc, out, _ = _cli(["info", str(path), "--allow-glass-extrapolation"], capsys)
    assert rc == 0 and "default fit         wavelengths 380-780 nm: the default" in out


# --- the command line -------------------------------------------------------------------


def test_fit_prints_the_band_in_one_line(tmp_path, capsys, stub):
    rc, out, _ = _cli(["fit", str(TRIPLET), "--quick", "--generated", str(tmp_path)],
                      capsys)
    assert (rc, out) == (0, LINE + "\n")
    (call,) = stub
    d = call["domain"]
    assert (d.wavelength_min_nm, d.wavelength_max_nm) == (404.66, 780.0)
    assert call["wavelengths"].line() == LINE
    rc, out, _ = _cli(["report", str(TRIPLET), "--quick", "-o", str(tmp_path / "r")], capsys)
    assert (rc, out) == (0, LINE + "\n")
    rc, out, _ = _cli(["report", str(TRIPLET), "--quick", "--json"], capsys)
    assert (rc, out) == (0, "")  # --json: stdout is the JSON alone (key "wavelengths")


def test_wavelengths_override(tmp_path, capsys, stub):
    rc, out, _ = _cli(["fit", str(TRIPLET), "--quick", "--wavelengths", "450,650",
                       "--generated", str(tmp_path)], capsys)
    assert (rc, out) == (0, "wavelengths 450-650 nm: asked for (--wavelengths 450,650)\n")
    d = stub[0]["domain"]
    assert (d.wavelength_min_nm, d.wavelength_max_nm) == (450.0, 650.0)


@pytest.mark.parametrize("allow", ["switch", "file"])
def test_extrapolation_is_opt_in_and_keeps_380_780(tmp_path, capsys, stub, allow):
    path = (TRIPLET if allow == "switch" else
            _variant(tmp_path, ("schema_version = 1",
                                'schema_version = 1\nglass_extrapolation = "allow"')))
    argv = ["fit", str(path), "--quick", "--generated", str(tmp_path)]
    rc, out, _ = _cli(argv + (["--allow-glass-extrapolation"] if allow == "switch" else []),
                      capsys)
    assert (rc, out) == (0, "wavelengths 380-780 nm: the default 380-780 nm, glasses "
                            "extrapolated as the lens allows (SCHOTT:N-F2: 404.66-2325.4 "
                            "nm)\n")
    d = stub[0]["domain"]
    assert (d.wavelength_min_nm, d.wavelength_max_nm) == DEFAULT_BAND_NM
    # ... and the glass is listed after the fit, as before
    _print_extrapolated(stub[0]["lens"], d.to_dict())
    assert capsys.readouterr().out == (
        "  glass extrapolated: SCHOTT:N-F2 (surface 2): published 404.66-2325.4 nm, "
        "extrapolated at 380-404.66 nm\n")


def test_wavelengths_outside_a_glass_are_refused_before_any_work(tmp_path, capsys):
    gen, rep = tmp_path / "gen", tmp_path / "rep"
    rc, out, err = _cli(["fit", str(TRIPLET), "--quick", "--wavelengths", "380,780",
                         "--generated", str(gen), "--report", str(rep)], capsys)
    assert rc == 2 and err.count("\n") == 1
    assert out == "wavelengths 380-780 nm: asked for (--wavelengths 380,780)\n"
    assert err == (
        f"lensfit: error: {TRIPLET}: surface 2: key 'material': --wavelengths 380,780: "
        "wavelengths 380-780 nm are outside the 404.66-2325.4 nm range of glass "
        "SCHOTT:N-F2; use --wavelengths 404.66,780 or allow extrapolation (top-level "
        "glass_extrapolation = \"allow\" in the lens file, or --allow-glass-extrapolation)"
        "\n")
    assert not gen.exists() and not rep.exists()


def test_info_states_the_default_band(capsys):
    rc, out, _ = _cli(["info", str(TRIPLET)], capsys)
    assert rc == 0 and f"  default fit         {LINE}\n" in out
    assert "glass range" not in out  # nothing extrapolated, nothing refused


# --- scenes keep their own wavelengths -----------------------------------------------------


def _scene(wavelengths: list[float]) -> Scene:
    return Scene.from_dict({"name": "s", "wavelengths_nm": wavelengths,
                            "light": [{"field_x_deg": 0.0, "field_y_deg": 5.0}]},
                           "scenes/s.toml")


def test_scene_keeps_its_wavelengths_inside_the_glasses(triplet):
    d = scene_domain(triplet, _scene([450.0, 550.0, 650.0]))
    assert (d.wavelength_min_nm, d.wavelength_max_nm) == (
        450.0 - SCENE_WAVELENGTH_MARGIN_NM, 650.0 + SCENE_WAVELENGTH_MARGIN_NM)
    # At the glass's edge the margin stays inside the glass
    d = scene_domain(triplet, _scene([404.66, 550.0]))
    assert (d.wavelength_min_nm, d.wavelength_max_nm) == (404.66, 551.0)


def test_scene_outside_a_glass_is_refused(tmp_path, capsys):
    scene = tmp_path / "blue.toml"
    scene.write_text('name = "blue"\nwavelengths_nm = [400.0, 550.0]\n[[light]]\n'
                     'field_x_deg = 0.0\nfield_y_deg = 5.0\n', encoding="utf-8")
    rc, out, err = _cli(["fit", str(TRIPLET), "--quick", "--scene", str(scene),
                         "--generated", str(tmp_path / "g")], capsys)
    assert rc == 2 and err.count("\n") == 1
    # The margin stops at the glass's edge; the scene's 400 nm itself is outside it
    assert out.startswith("wavelengths 400-551 nm: the wavelengths of scene blue.toml")
    assert (f"{TRIPLET}: surface 2: key 'material': scene blue.toml, key 'wavelengths_nm' = "
            "[400, 550]: wavelengths 400-551 nm are outside the 404.66-2325.4 nm range of "
            "glass SCHOTT:N-F2") in err
    assert not (tmp_path / "g").exists()


# --- a real fit: the band recorded in fit.json, the table, the report; lensrt ------------


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """`lensfit fit` of the fixture with the default band (--quick, about 20 s)."""
    tmp = tmp_path_factory.mktemp("triplet")
    gen, rep = tmp / "gen", tmp / "rep"
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(["fit", str(TRIPLET), "--quick", "--no-timing", "--generated", str(gen),
                   "--report", str(rep), "--allow-miss"])  # the band is tested, not the PSF
    return rc, out.getvalue(), gen / "cooke_triplet_n_f2", rep


def test_default_fit_succeeds_and_records_its_band(fitted):
    rc, out, folder, rep = fitted
    assert rc == 0
    lines = out.splitlines()
    assert lines[0] == LINE and sum(ln.startswith("wavelengths ") for ln in lines) == 1
    assert "glass extrapolated" not in out
    meta = json.loads((folder / "fit.json").read_text(encoding="utf-8"))
    assert meta["wavelengths"] == {
        "min_nm": 404.66, "max_nm": 780.0,
        "reason": "the range every glass supports (SCHOTT:N-F2: 404.66-2325.4 nm) within "
                  "380-780 nm"}
    assert (meta["domain"]["wavelength_min_nm"], meta["domain"]["wavelength_max_nm"]) == (
        404.66, 780.0)
    text = (folder / meta["table"]).read_text(encoding="utf-8")
    assert f"\n# {LINE}\n" in text  # a comment: both readers skip it
    table = read_table(text)
    for system in table:
        (lam,) = [i for i in system.inputs if i.name == "lambda"]
        assert (lam.lo, lam.hi) == (404.66, 780.0)
    assert re.search(r"\ninput lambda nm 404\.66\d* 780 ", text)
    assert f"Wavelengths {LINE.removeprefix('wavelengths ')}." in (
        rep / "report.md").read_text(encoding="utf-8")


def test_lensrt_refuses_wavelengths_outside_the_fitted_band(fitted):
    """lensrt loads the table (its comment line skipped) and refuses a wavelength outside
    the table's lambda range, naming that range."""
    import sys

    sys.path.insert(0, str(REPO / "runtime" / "python"))
    from lensrt_ctypes import LIBRARY, Lensrt, LensrtError

    if not Path(os.environ.get("LENSRT_LIBRARY", LIBRARY)).exists():
        pytest.skip(f"needs {LIBRARY}: build it with `make runtime`")
    _, _, folder, _ = fitted
    rt = Lensrt()
    lens = rt.load(next(folder.glob("*.table")))
    info = rt.info(lens)
    assert (info["wavelength_min_nm"], info["wavelength_max_nm"]) == (404.66, 780.0)
    base = {"width": 8, "height": 8, "focus_offset_mm": 0.0, "width_mm": 0.05}
    for lam in (400.0, 781.0):
        with pytest.raises(LensrtError, match=re.escape(
                f"wavelength 0: {lam:g} nm is outside the fitted range [404.66, 780] nm")):
            rt.create(lens, wavelengths=[lam], **base)
    rt.create(lens, wavelengths=[404.66, 780.0], **base).run(64)  # the band's ends: fine
