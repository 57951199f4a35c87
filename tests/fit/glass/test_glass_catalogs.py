"""The manufacturers' glass catalogs, name resolution, inline glasses and extrapolation.

Each catalog's every glass: its formula, at the spectral lines, against the same row's
printed nd, ne, vd and ve (lensfit.glass.manufacturers, lensfit.glass.formulas).
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lensfit.cli import main
from lensfit.common.errors import LensError
from lensfit.glass import (
    FORMULAS,
    MANUFACTURERS,
    AmbiguousGlassError,
    FormulaGlass,
    SellmeierGlass,
    TableGlass,
    UnknownGlassError,
    catalog_glass,
    resolve_glass,
)
from lensfit.glass.formulas import LINE_NM, formula_n_squared
from lensfit.glass.manufacturers import load_catalog
from lensfit.prescription import list_lenses, load_lens
from lensfit.prescription.load import lens_from_dict
from lensfit.prescription.ranges import allow_extrapolation, out_of_range
from lensfit.trace.tracer import _check_wavelengths
from lensfit.trust.report import _glass_range_markdown

# Glasses per catalog in opticalglass 1.1.1's data (rows with a name and a complete set of
# coefficients): a parser that drops or misreads rows changes these.
COUNTS = {"SCHOTT": 123, "OHARA": 153, "HOYA": 194, "CDGM": 240, "HIKARI": 158,
          "SUMITA": 134}

# Index tolerance per catalog, |n_formula - n_printed| at d and e. The catalogs print n
# to 5 decimals (rounding <= 5e-6) and their formulas are least-squares fits to measured
# indices. Worst seen: SCHOTT 4.9e-6, OHARA 5.3e-6, HOYA 5.6e-6 (so 1e-5: rounding plus
# a fit residual as large again); CDGM 2.7e-5 (H-ZF88, ne) and SUMITA 2.3e-5 (K-PSFn1,
# nd), whose formulas fit their own tables less closely (3e-5). HIKARI prints 6
# decimals computed from its formula: worst 4.9e-7 (1e-6). A wrong formula, coefficient
# order or unit misses by 1e-3 or more (test_a_wrong_formula_misses).
TOL_N = {"SCHOTT": 1e-5, "OHARA": 1e-5, "HOYA": 1e-5, "CDGM": 3e-5, "HIKARI": 1e-6,
         "SUMITA": 3e-5}
# Half the last printed digit of vd and ve: 2 decimals, but SUMITA prints one (17.8) or
# none (K-CaFK95: 95).
VD_HALF_DIGIT = {"SUMITA": 0.5}

# Printing errors in the spreadsheets, with the value the same sheet prints elsewhere.
# SCHOTT P-SF69: the ne column says 1.72883; the sheet's own index table (column DY, ne)
# says 1.72833, which the formula gives (to 3e-6) and ve = 29.00 agrees with.
ERRATA = {("SCHOTT", "P-SF69", "ne"): 1.72833}


def _lines(g: FormulaGlass) -> dict[str, float]:
    return {k: float(g.n(v)) for k, v in LINE_NM.items()}


@pytest.mark.parametrize("maker", MANUFACTURERS)
def test_every_glass_reproduces_its_catalog_values(maker: str) -> None:
    cat = load_catalog(maker)
    assert len(cat) == COUNTS[maker]
    tol = TOL_N[maker]
    half = VD_HALF_DIGIT.get(maker, 0.005)
    bad = []
    checked = 0
    for g in cat.values():
        n = _lines(g)
        printed = {k: ERRATA.get((maker, g.name, k), getattr(g, k))
                   for k in ("nd", "ne", "vd", "ve")}
        for key, line in (("nd", "d"), ("ne", "e")):
            if not math.isnan(printed[key]):
                checked += 1
                if abs(n[line] - printed[key]) > tol:
                    bad.append(f"{g.name} {key}: {n[line]:.6f} vs {printed[key]}")
        # The Abbe numbers as principal dispersions: nF - nC = (nd - 1)/vd. The printed
        # vd's rounding moves that by (nd - 1) half / vd^2, and nF, nC carry the index
        # tolerance each (2 tol).
        for v, (lo, hi), nkey in (("vd", ("F", "C"), "nd"), ("ve", ("F'", "C'"), "ne")):
            if math.isnan(printed[v]) or math.isnan(printed[nkey]):
                continue
            checked += 1
            want = (printed[nkey] - 1.0) / printed[v]
            allowed = 2 * tol + (printed[nkey] - 1.0) * half / printed[v] ** 2
            if abs((n[lo] - n[hi]) - want) > allowed:
                bad.append(f"{g.name} {v}: n{lo}-n{hi} = {n[lo] - n[hi]:.6f}, catalog "
                           f"(n-1)/{v} = {want:.6f}")
    assert not bad, f"{maker}: {len(bad)} mismatches: {bad[:10]}"
    # nd and vd printed for every glass; ne and ve for nearly every one
    assert checked >= 3 * len(cat)


@pytest.mark.parametrize("maker", MANUFACTURERS)
def test_a_wrong_formula_misses(maker: str) -> None:
    """The tolerances above can fail: the coefficients read as another formula, in
    reverse order, or with λ in nm instead of µm miss nd by far more than any of them."""
    for g in list(load_catalog(maker).values())[:20]:
        c = g.coefficients
        wrong = [(g.formula, tuple(reversed(c)), 1e-3)]
        wrong += [(f, c, 1e-3) for f, names in FORMULAS.items()
                  if f != g.formula and len(names) == len(c)]
        wrong += [(g.formula, c, 1.0)]  # λ in nm
        for formula, coef, scale in wrong:
            with np.errstate(all="ignore"):
                n2 = formula_n_squared(formula, coef, np.array([LINE_NM["d"] * scale]))
                n = float(np.sqrt(n2[0]))
            assert not abs(n - g.nd) < 1e-3, (g.name, formula, scale)


@pytest.mark.parametrize("maker", MANUFACTURERS)
def test_published_ranges(maker: str) -> None:
    for g in load_catalog(maker).values():
        lo, hi = g.range_nm
        # Every row prints indices from g (or i) to C at least
        assert lo <= 435.84 and hi >= 656.27, g.name
        assert g.reference == f"{maker}:{g.name}"


def test_formulas_by_hand() -> None:
    """Each formula at λ = 0.5 µm written out term by term."""
    w = 0.5
    sell = FormulaGlass("x", "t", "sellmeier3", (1.0, 0.2, 0.5, 0.01, 0.05, 100.0), (400, 700))
    n2 = 1 + 1.0 * w**2 / (w**2 - 0.01) + 0.2 * w**2 / (w**2 - 0.05) + 0.5 * w**2 / (w**2 - 100)
    assert float(sell.n(500.0)) == pytest.approx(math.sqrt(n2), rel=1e-15)
    a = (2.2, -0.01, 0.01, 1e-4, 2e-5, 3e-6)
    sch = FormulaGlass("x", "t", "schott", a, (400, 700))
    n2 = a[0] + a[1] * w**2 + a[2] * w**-2 + a[3] * w**-4 + a[4] * w**-6 + a[5] * w**-8
    assert float(sch.n(500.0)) == pytest.approx(math.sqrt(n2), rel=1e-15)
    h = (2.2, -0.01, -1e-4, 0.01, 1e-4, 2e-5, 3e-6, 4e-7, 5e-8)
    hik = FormulaGlass("x", "t", "hikari", h, (400, 700))
    n2 = (h[0] + h[1] * w**2 + h[2] * w**4 + h[3] * w**-2 + h[4] * w**-4 + h[5] * w**-6
          + h[6] * w**-8 + h[7] * w**-10 + h[8] * w**-12)
    assert float(hik.n(500.0)) == pytest.approx(math.sqrt(n2), rel=1e-15)
    with pytest.raises(ValueError, match="takes 6 coefficients"):
        FormulaGlass("x", "t", "schott", (1.0,), (400, 700))


def test_formula_glass_identity_ignores_catalog_values() -> None:
    """Equal formula, coefficients and range are the same medium, whatever the printed
    values (a NaN nd made twice is not equal to itself: the lens loader compares media)."""
    a = FormulaGlass("x", "t", "schott", (2.2, 0, 0, 0, 0, 0), (400, 700), nd=float("nan"))
    b = FormulaGlass("x", "t", "schott", (2.2, 0, 0, 0, 0, 0), (400, 700), nd=float("nan"))
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1
    assert a != FormulaGlass("x", "t", "schott", (2.3, 0, 0, 0, 0, 0), (400, 700))


# --- names -----------------------------------------------------------------------------


def test_project_catalog_keeps_priority() -> None:
    # N-BK7 is in both the project catalog and SCHOTT's: unqualified means the project's
    for name in ("N-BK7", "n-bk7", "NBK7", "F2", "s-lah59"):
        g = resolve_glass(name)
        assert isinstance(g, SellmeierGlass) and g == catalog_glass(name)
    schott = resolve_glass("schott:N-BK7")
    assert isinstance(schott, FormulaGlass) and schott.maker == "SCHOTT"
    lam = np.linspace(400.0, 700.0, 31)
    # Both are SCHOTT's N-BK7 data (2017 Zemax catalog vs the current sheet)
    assert np.max(np.abs(schott.n(lam) - catalog_glass("N-BK7").n(lam))) < 1e-5


@pytest.mark.parametrize(("query", "maker", "name"), [
    ("N-BAK1", "SCHOTT", "N-BAK1"), ("sf2", "SCHOTT", "SF2"), ("N-SSK2", "SCHOTT", "N-SSK2"),
    ("n-sk2", "SCHOTT", "N-SK2"), ("schott:F5", "SCHOTT", "F5"), ("CDGM:f5", "CDGM", "F5"),
    ("Hikari:J-SK16", "HIKARI", "J-SK16"), ("hikari: j-sk16", "HIKARI", "J-SK16"),
    ("s-lal8", "OHARA", "S-LAL 8"), ("ohara:S-LAL 8", "OHARA", "S-LAL 8"),
])  # fmt: skip
def test_issue_glasses_resolve(query: str, maker: str, name: str) -> None:
    g = resolve_glass(query)
    assert (g.maker, g.name) == (maker, name)
    assert resolve_glass(g.reference) == g  # the reference a file writes comes back


def test_manufacturer_argument() -> None:
    assert resolve_glass("F5", "Schott") == resolve_glass("SCHOTT:F5")
    assert resolve_glass("schott:F5", "SCHOTT") == resolve_glass("SCHOTT:F5")
    with pytest.raises(UnknownGlassError, match="the name says manufacturer"):
        resolve_glass("schott:F5", "cdgm")


def test_ambiguous_name_lists_candidates() -> None:
    with pytest.raises(AmbiguousGlassError) as info:
        resolve_glass("F5")
    assert info.value.candidates == ["SCHOTT:F5", "CDGM:F5"]
    assert "SCHOTT:F5, CDGM:F5" in str(info.value)
    assert isinstance(info.value, UnknownGlassError)  # callers catching that catch this


def test_unknown_names_list_close_matches() -> None:
    with pytest.raises(UnknownGlassError) as info:
        resolve_glass("hikari:SK16")  # HIKARI calls it J-SK16: no silent substitute
    assert "HIKARI:J-SK16" in str(info.value)
    with pytest.raises(UnknownGlassError) as info:
        resolve_glass("N-BAK11")
    assert "SCHOTT:N-BAK1" in str(info.value)
    with pytest.raises(UnknownGlassError, match="unknown glass manufacturer 'acme'"):
        resolve_glass("acme:N-BK7")
    with pytest.raises(UnknownGlassError, match="use lensfit.glass.AIR"):
        resolve_glass("air")


def test_project_lookups_open_no_spreadsheet() -> None:
    """Loading every lensdb lens touches no manufacturer catalog (start-up stays fast)."""
    code = ("import sys; from lensfit.prescription import list_lenses, load_lens\n"
            "from lensfit.glass.manufacturers import load_catalog\n"
            "[load_lens(p) for p in list_lenses()]\n"
            "assert load_catalog.cache_info().currsize == 0\n"
            "assert 'xlrd' not in sys.modules and 'openpyxl' not in sys.modules\n")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_lensdb_glasses_unchanged() -> None:
    """Every named glass of lensdb resolves to the project catalog's entry, as before."""
    for p in list_lenses():
        for s in load_lens(p).surfaces:
            if "material" in s.material_spec and s.material_spec["material"] != "air":
                assert s.medium == catalog_glass(s.material_spec["material"])


# --- inline glasses in a lens file -----------------------------------------------------


def _lens(material: object, *, extrapolation: str | None = None) -> dict:
    data = {
        "schema_version": 1,
        "lens": {"id": "t", "name": "test singlet", "maker": "t", "year": 2026,
                 "source": "test"},
        "coating": {"default": "none"},
        "surface": [
            {"shape": "sphere", "radius": 50.0, "thickness": 5.0, "semi_diameter": 10.0,
             "material": material},
            {"shape": "sphere", "radius": -50.0, "thickness": 10.0, "semi_diameter": 10.0,
             "material": "air"},
            {"shape": "plane", "thickness": 40.0, "semi_diameter": 8.0, "material": "air",
             "stop": True},
        ],
    }
    if extrapolation is not None:
        data["glass_extrapolation"] = extrapolation
    return data


SK16 = resolve_glass("hikari:J-SK16")
SK16_INLINE = {"name": "SK16", "formula": "hikari", "coefficients": list(SK16.coefficients),
               "range_nm": [400.0, 700.0]}


def test_inline_formula_is_the_catalog_glass() -> None:
    lens = lens_from_dict(_lens(SK16_INLINE), file="t.toml")
    g = lens.surfaces[0].medium
    lam = np.linspace(400.0, 700.0, 31)
    assert np.array_equal(g.n(lam), SK16.n(lam))
    assert g.range_nm == (400.0, 700.0) and g.name == "SK16"
    assert lens.to_dict()["surface"][0]["material"] == SK16_INLINE  # round trip


@pytest.mark.parametrize(("glass", "tol"), [("N-BK7", 5e-6), ("N-SF6", 3e-5)])
def test_inline_table_spline(glass: str, tol: float) -> None:
    real = catalog_glass(glass)
    table_nm = np.linspace(400.0, 700.0, 7)  # every 50 nm
    spec = {"name": f"{glass} table", "table_nm": list(table_nm),
            "table_n": [float(v) for v in real.n(table_nm)]}
    g = lens_from_dict(_lens(spec), file="t.toml").surfaces[0].medium
    assert isinstance(g, TableGlass) and g.range_nm == (400.0, 700.0)
    # Through the points exactly (to rounding)
    assert np.max(np.abs(g.n(table_nm) - real.n(table_nm))) < 1e-14
    # Between them the spline in 1/λ² follows the Sellmeier curve: measured 1.5e-6
    # (N-BK7) and 8.6e-6 (N-SF6). A natural spline misses N-SF6 by 2.3e-4, a spline in λ
    # by 9e-4, linear interpolation by 1.7e-3: the tolerances tell them apart.
    fine = np.linspace(400.0, 700.0, 3001)
    n = g.n(fine)
    assert np.max(np.abs(n - real.n(fine))) < tol
    # Normal dispersion stays normal: strictly decreasing, no wiggle between points
    assert np.all(np.diff(n) < 0)
    # Outside: the tangent line in 1/λ² at the end point; value and slope continuous
    for edge, out in ((400.0, 350.0), (700.0, 800.0)):
        u_edge, u_out = (edge * 1e-3) ** -2, (out * 1e-3) ** -2
        h = 1e-4  # a small step inside, in nm
        inner = edge + (h if edge < 600 else -h)
        slope_in = (float(g.n(inner)) - float(g.n(edge))) / ((inner * 1e-3) ** -2 - u_edge)
        slope_out = (float(g.n(out)) - float(g.n(edge))) / (u_out - u_edge)
        assert slope_out == pytest.approx(slope_in, rel=1e-4)
        # 2e-9 nm apart: |dn/dλ| < 1e-3 per nm here (N-SF6 at 400 nm: 7e-4), so < 4e-12
        assert abs(float(g.n(edge - 1e-9)) - float(g.n(edge + 1e-9))) < 4e-12


@pytest.mark.parametrize(("material", "key", "says"), [
    ({"formula": "schott", "coefficients": [1.0], "range_nm": [400, 700]},
     "material.coefficients", "takes 6 coefficients"),
    ({"formula": "sellmeier3", "coefficients": [1, 0, 0, 0.3, 0, 0], "range_nm": [400, 700]},
     "material.coefficients", "no index >= 1"),
    ({"formula": "schott", "coefficients": [2.2, 0, 0, 0, 0, 0]},
     "material.range_nm", "missing key"),
    ({"formula": "schott", "coefficients": [2.2, 0, 0, 0, 0, 0], "range_nm": [700, 400]},
     "material.range_nm", "0 < lo < hi"),
    ({"formula": "cauchy", "coefficients": [1.5], "range_nm": [400, 700]},
     "material.formula", "expected one of"),
    ({"table_nm": [500.0, 400.0], "table_n": [1.5, 1.6]}, "material.table_nm", "increasing"),
    ({"table_nm": [400.0, 500.0], "table_n": [1.5]}, "material.table_n", "expected 2"),
    ({"table_nm": [400.0, 500.0], "table_n": [1.5, 0.9]}, "material.table_n", ">= 1"),
    ({"table_nm": [400.0]}, "material.table_n", "missing key"),
    ({"name": "Air", "table_nm": [400.0, 500.0], "table_n": [1.5, 1.4]}, "material.name",
     "not a glass"),
    ({"table_nm": [400, 500], "table_n": [1.5, 1.4], "formula": "schott"}, "material.table_n",
     "not both"),
    ({"colour": "blue"}, "material.colour", "unknown key"),
    ("F5", "material", "SCHOTT:F5, CDGM:F5"),
    ("schott:N-BK8", "material", "close matches: SCHOTT:N-BK7"),
])  # fmt: skip
def test_inline_and_name_errors_name_file_surface_key(material, key, says) -> None:
    with pytest.raises(LensError) as info:
        lens_from_dict(_lens(material), file="lenses/t.toml")
    e = info.value
    assert (e.file, e.surface, e.key) == ("lenses/t.toml", 0, key), str(e)
    assert says in str(e)
    assert str(e).startswith("lenses/t.toml: surface 0: key ")


# --- extrapolation -----------------------------------------------------------------------


def test_extrapolation_refused_by_default() -> None:
    lens = lens_from_dict(_lens(SK16_INLINE), file="t.toml")
    _check_wavelengths(lens, np.array([400.0, 700.0]))  # inside: fine
    with pytest.raises(LensError) as info:
        _check_wavelengths(lens, np.array([380.0, 780.0]))
    assert (info.value.file, info.value.surface, info.value.key) == ("t.toml", 0, "material")
    assert "380-780 nm are outside the 400-700 nm range of glass SK16" in str(info.value)


def test_extrapolation_allowed_and_listed() -> None:
    lens = lens_from_dict(_lens(SK16_INLINE, extrapolation="allow"), file="t.toml")
    _check_wavelengths(lens, np.array([380.0, 780.0]))
    bad = out_of_range(lens, 380.0, 780.0)
    assert [(o.glass, o.range_nm, o.surfaces) for o in bad] == [("SK16", (400.0, 700.0), (0,))]
    assert "extrapolated at 380-400 nm and 700-780 nm" in bad[0].describe()
    md = "\n".join(_glass_range_markdown(lens, {"wavelength_min_nm": 380.0,
                                                "wavelength_max_nm": 780.0}))
    assert "Glass extrapolated" in md and "SK16 (surface 0): published 400-700 nm" in md
    assert _glass_range_markdown(lens, {"wavelength_min_nm": 450.0,
                                        "wavelength_max_nm": 650.0}) == []
    # The command line's switch is the same policy
    refused = lens_from_dict(_lens(SK16_INLINE), file="t.toml")
    _check_wavelengths(allow_extrapolation(refused), np.array([380.0, 780.0]))
    with pytest.raises(LensError):
        lens_from_dict(_lens(SK16_INLINE, extrapolation="yes"), file="t.toml")


def _write(tmp_path: Path, data: dict) -> Path:
    import json

    # Minimal TOML writer for the test lens (tables of numbers, strings, lists)
    def val(v: object) -> str:
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {val(x)}" for k, x in v.items()) + " }"
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return json.dumps(v)

    lines = [f"{k} = {val(v)}" for k, v in data.items() if not isinstance(v, (dict, list))]
    for k in ("lens", "coating"):
        lines += [f"[{k}]", *(f"{a} = {val(b)}" for a, b in data[k].items())]
    for s in data["surface"]:
        lines += ["[[surface]]", *(f"{a} = {val(b)}" for a, b in s.items())]
    path = tmp_path / "sk16.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_cli_info_lists_glass_ranges(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path, _lens(SK16_INLINE))
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    # The default fit follows the glass: nothing is extrapolated, nothing refused
    assert ("  default fit         wavelengths 400-700 nm: the range every glass supports "
            "(SK16: 400-700 nm) within 380-780 nm\n") in out
    assert "glass range" not in out and "extrapolated" not in out
    assert main(["info", str(path), "--allow-glass-extrapolation"]) == 0
    out = capsys.readouterr().out
    assert "default fit         wavelengths 380-780 nm: the default 380-780 nm" in out
    assert "SK16 (surface 0): published 400-700 nm, extrapolated at 380-400 nm and 700-780" \
        in out and "allowed (glass_extrapolation)" in out
    inside = _write(tmp_path, _lens({**SK16_INLINE, "range_nm": [300.0, 900.0]}))
    assert main(["info", str(inside)]) == 0
    out = capsys.readouterr().out
    assert "glass range" not in out
    assert ("default fit         wavelengths 380-780 nm: the default range, which every "
            "glass supports") in out


def test_cli_fit_refuses_before_any_work(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """--wavelengths outside a glass's range (the default band follows the glasses:
    tests/fit/glass/test_glass_range_default.py)."""
    path = _write(tmp_path, _lens(SK16_INLINE))
    gen, rep = tmp_path / "gen", tmp_path / "rep"
    assert main(["fit", str(path), "--quick", "--no-timing", "--generated", str(gen),
                 "--report", str(rep), "--wavelengths", "380,780"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and ("surface 0: key 'material': --wavelengths 380,780: "
                                     "wavelengths 380-780 nm") in err
    assert "--wavelengths 400,700" in err
    assert not gen.exists() and not rep.exists()


def test_cli_fit_lists_extrapolated_glasses(capsys: pytest.CaptureFixture[str]) -> None:
    """What `lensfit fit` and `lensfit report` print after an allowed extrapolation."""
    from lensfit.cli.fit import _print_extrapolated

    lens = lens_from_dict(_lens(SK16_INLINE, extrapolation="allow"), file="t.toml")
    _print_extrapolated(lens, {"wavelength_min_nm": 380.0, "wavelength_max_nm": 700.0})
    assert capsys.readouterr().out == ("  glass extrapolated: SK16 (surface 0): published "
                                       "400-700 nm, extrapolated at 380-400 nm\n")
    _print_extrapolated(lens, {"wavelength_min_nm": 400.0, "wavelength_max_nm": 700.0})
    assert capsys.readouterr().out == ""
