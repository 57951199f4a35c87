"""Tests for lensfit.glass: catalog Sellmeier data, the nd/vd model and air."""

from __future__ import annotations

import math
import pathlib

import numpy as np
import pytest

from lensfit.glass import (
    AIR,
    LAMBDA_C_NM,
    LAMBDA_D_NM,
    LAMBDA_F_NM,
    AbbeGlass,
    Medium,
    SellmeierGlass,
    UnknownGlassError,
    abbe_glass,
    abbe_number,
    catalog_glass,
    catalog_path,
    known_glass_names,
)

VISIBLE_NM = np.linspace(380.0, 780.0, 2001)

REQUIRED = [
    "N-SF5", "SF5", "N-BAF10", "N-LAK9", "N-SF15", "SF15", "N-SK16", "N-BK7", "F2",
    "N-SF6", "N-LASF9", "SF6",
    "S-BAH10", "S-LAH59", "S-LAH64", "S-TIH53", "S-TIH6", "S-TIM1",
    "MgF2", "SiO2",
]  # fmt: skip

ALL_NAMES = known_glass_names()


def test_catalog_path_points_at_repo_file() -> None:
    path = catalog_path()
    assert path.name == "catalog.toml"
    assert path.parent == pathlib.Path(__file__).resolve().parents[3] / "lensdb" / "glass"
    assert path.is_file()


def test_required_glasses_present() -> None:
    assert set(REQUIRED) <= set(ALL_NAMES)


@pytest.mark.parametrize("name", ALL_NAMES)
def test_catalog_nd_vd_consistent(name: str) -> None:
    g = catalog_glass(name)
    # Catalogs print nd to 5 (Schott) or 6 (Ohara) decimals, i.e. rounding <= 5e-6; the
    # Sellmeier fits reproduce their own nd to ~3e-6 (worst: N-SF5, -2.8e-6). 2e-5 leaves
    # margin yet catches any transcription error in a coefficient's leading digits.
    assert abs(float(g.n(LAMBDA_D_NM)) - g.nd) < 2e-5
    # vd is printed to 0.01; fits reproduce it to <= 0.005 (N-BK7: 64.166 vs 64.17).
    assert abs(abbe_number(g) - g.vd) < 0.1


@pytest.mark.parametrize("name", ALL_NAMES)
def test_catalog_entry_well_formed(name: str) -> None:
    g = catalog_glass(name)
    assert isinstance(g, SellmeierGlass)
    assert len(g.B) == 3 and len(g.C) == 3
    assert all(c > 0 for c in g.C)
    lo, hi = g.range_nm
    assert lo < hi
    assert g.source.startswith("refractiveindex.info")
    assert g.maker in {"Schott", "Ohara", "crystal", "film"}


@pytest.mark.parametrize("name", ALL_NAMES)
def test_catalog_glass_physical_over_visible(name: str) -> None:
    n = catalog_glass(name).n(VISIBLE_NM)
    assert n.dtype == np.float64
    assert np.all(np.isfinite(n))
    assert np.all(n > 1.0)
    # normal dispersion: strictly decreasing with wavelength across the visible band
    assert np.all(np.diff(n) < 0.0)


@pytest.mark.parametrize(
    ("wavelength_nm", "published"),
    [(587.56, 1.51680), (486.13, 1.52238), (656.27, 1.51432)],
)
def test_n_bk7_datasheet_values(wavelength_nm: float, published: float) -> None:
    # SCHOTT N-BK7 data sheet nd, nF, nC (printed to 5 decimals => +-5e-6 rounding);
    # 1e-5 allows rounding plus the Sellmeier fit residual (~1e-6).
    assert abs(float(catalog_glass("N-BK7").n(wavelength_nm)) - published) < 1e-5


def test_fused_silica_malitson_nd() -> None:
    # Malitson (1965) fused silica: nd = 1.4585, vd = 67.8 (classic published values).
    g = catalog_glass("SiO2")
    assert abs(float(g.n(LAMBDA_D_NM)) - 1.4585) < 1e-4
    assert abs(abbe_number(g) - 67.8) < 0.1


@pytest.mark.parametrize(
    ("query", "expected"),
    [
        ("N-SF5", "N-SF5"),
        ("n-sf5", "N-SF5"),
        ("NSF5", "N-SF5"),
        ("nsf5", "N-SF5"),
        ("SF5", "SF5"),  # the lead glass is a different entry from N-SF5
        ("SLAH59", "S-LAH59"),
        ("s-lah59", "S-LAH59"),
        ("S_TIH6", "S-TIH6"),
        (" mgf2 ", "MgF2"),
        ("sio2", "SiO2"),
    ],
)
def test_name_normalisation(query: str, expected: str) -> None:
    assert catalog_glass(query).name == expected


@pytest.mark.parametrize("bad", ["N-FOO", "", "BK8", "air", "AIR"])
def test_unknown_glass_raises(bad: str) -> None:
    with pytest.raises(UnknownGlassError) as info:
        catalog_glass(bad)
    err = info.value
    assert isinstance(err, KeyError)
    assert err.name == bad
    msg = str(err)
    assert msg.startswith(f"unknown glass {bad!r}")
    assert "known glasses:" in msg and "N-BK7" in msg and "S-LAH59" in msg


def test_air_is_exactly_one() -> None:
    assert isinstance(AIR, Medium)
    assert AIR.name == "air"
    n = AIR.n(VISIBLE_NM)
    assert n.dtype == np.float64 and n.shape == VISIBLE_NM.shape
    assert np.all(n == 1.0)  # exact: indices are relative to air
    assert AIR.n(550.0) == 1.0 and np.shape(AIR.n(550.0)) == ()


def test_media_satisfy_protocol() -> None:
    assert isinstance(catalog_glass("N-BK7"), Medium)
    assert isinstance(abbe_glass(1.6, 40.0), Medium)


@pytest.mark.parametrize("medium", [catalog_glass("N-SF6"), abbe_glass(1.7, 30.0), AIR])
def test_vectorised_over_arrays_and_scalars(medium: Medium) -> None:
    grid = np.array([[400.0, 500.0, 600.0], [450.0, 550.0, 700.0]])
    n = medium.n(grid)
    assert n.shape == grid.shape and n.dtype == np.float64
    scalar = medium.n(550.0)
    assert np.shape(scalar) == () and np.asarray(scalar).dtype == np.float64
    assert float(scalar) == n[1, 1]
    assert np.array_equal(medium.n([400.0, 500.0]), n[0, :2])
    assert np.array_equal(medium.n(np.float32(550.0)), scalar)
    assert medium.n(np.array([], dtype=np.float64)).shape == (0,)


@pytest.mark.parametrize("bad", [0.0, -500.0, math.nan, math.inf])
def test_bad_wavelength_rejected(bad: float) -> None:
    for medium in (catalog_glass("N-BK7"), abbe_glass(1.5, 60.0)):
        with pytest.raises(ValueError, match="wavelength"):
            medium.n(np.array([500.0, bad]))


# --------------------------------------------------------------------------- nd/vd model


VD_VALUES = (15.0, 25.0, 40.0, 64.17, 95.0, 150.0)
ND_VD_GRID = [(nd, vd) for nd in (1.35, 1.5168, 1.7, 1.85, 2.1) for vd in VD_VALUES]


@pytest.mark.parametrize(("nd", "vd"), ND_VD_GRID)
def test_abbe_glass_reproduces_nd_vd(nd: float, vd: float) -> None:
    g = abbe_glass(nd, vd)
    # Exact by construction; 1e-12 only absorbs float64 rounding (observed <= 2e-16 on nd).
    assert abs(float(g.n(LAMBDA_D_NM)) - nd) < 1e-12
    # vd = (nd-1)/(nF-nC) divides by nF-nC ~ 1e-2, amplifying rounding to ~1e-12 absolute
    # (observed <= 1.1e-12 at vd 68), hence a *relative* 1e-12 bound.
    nf, nc = g.n(np.array([LAMBDA_F_NM, LAMBDA_C_NM]))
    assert (nd - 1.0) / (nf - nc) == pytest.approx(vd, rel=1e-12, abs=0.0)
    assert abbe_number(g) == pytest.approx(vd, rel=1e-12, abs=0.0)


@pytest.mark.parametrize("vd", VD_VALUES)
def test_abbe_glass_nearly_air(vd: float) -> None:
    # nd - 1 = 1e-4: nF - nC is ~1e-6, so float64 rounding of n (~1e-16) limits the
    # recomputed vd to a relative ~ eps * vd / (nd - 1) (~3e-10 at vd 150); nd stays exact.
    nd = 1.0001
    g = abbe_glass(nd, vd)
    assert abs(float(g.n(LAMBDA_D_NM)) - nd) < 1e-12
    bound = 8.0 * np.finfo(np.float64).eps * vd / (nd - 1.0)
    assert abbe_number(g) == pytest.approx(vd, rel=bound, abs=0.0)
    assert np.all(np.diff(g.n(VISIBLE_NM)) < 0.0)


@pytest.mark.parametrize(("nd", "vd"), ND_VD_GRID)
def test_abbe_glass_monotonic(nd: float, vd: float) -> None:
    n = abbe_glass(nd, vd).n(VISIBLE_NM)
    assert np.all(np.isfinite(n))
    assert np.all(np.diff(n) < 0.0)


def test_abbe_glass_nd_one_is_dispersionless() -> None:
    assert np.allclose(abbe_glass(1.0, 50.0).n(VISIBLE_NM), 1.0, rtol=0.0, atol=1e-15)


def test_abbe_glass_default_name_and_fields() -> None:
    g = AbbeGlass(1.5168, 64.17)
    assert g.name == "nd=1.51680 vd=64.17"
    assert (g.nd, g.vd) == (1.5168, 64.17)
    assert AbbeGlass(1.5168, 64.17, name="BK7-ish").name == "BK7-ish"
    assert g == abbe_glass(1.5168, 64.17)


@pytest.mark.parametrize(
    ("nd", "vd", "match"),
    [
        (0.9, 50.0, "nd must be >= 1"),
        (1.5, 0.0, "vd"),
        (1.5, -3.0, "vd"),
        (math.nan, 50.0, "finite"),
        (1.5, math.inf, "finite"),
    ],
)
def test_abbe_glass_rejects_bad_input(nd: float, vd: float, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        abbe_glass(nd, vd)
    with pytest.raises(ValueError, match=match):
        AbbeGlass(nd, vd)


# Worst |n_model - n_sellmeier| over 380-780 nm, measured with this catalog (README table):
#   all entries: 4.66e-3 (S-TIH53 at 380 nm; dense flints have more blue curvature than
#                the normal-line model), bound 5e-3;
#   Schott/Ohara glasses with vd >= 40: 5.1e-4 (S-LAH64 at 780 nm), bound 6e-4.
@pytest.mark.parametrize("name", ALL_NAMES)
def test_abbe_glass_close_to_catalog_sellmeier(name: str) -> None:
    real = catalog_glass(name)
    model = abbe_glass(real.nd, real.vd)
    err = np.max(np.abs(model.n(VISIBLE_NM) - real.n(VISIBLE_NM)))
    assert err < 5e-3
    if real.maker in {"Schott", "Ohara"} and real.vd >= 40.0:
        assert err < 6e-4


# --------------------------------------------------------------------------- catalog file


def _write_catalog(path: pathlib.Path, names: list[str]) -> None:
    entry = (
        '[[glass]]\nname = "{name}"\nmaker = "test"\nB = [1.03961212, 0.231792344, 1.01046945]\n'
        "C = [0.00600069867, 0.0200179144, 103.560653]\nnd = 1.5168\nvd = 64.17\n"
        'range_nm = [300.0, 2500.0]\nsource = "test"\n'
    )
    path.write_text("".join(entry.format(name=n) for n in names), encoding="utf-8")


def test_catalog_override_env(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "mini.toml"
    _write_catalog(path, ["X-TEST1"])
    monkeypatch.setenv("LENSFIT_GLASS_CATALOG", str(path))
    assert catalog_path() == path
    assert known_glass_names() == ["X-TEST1"]
    assert catalog_glass("xtest1").name == "X-TEST1"
    with pytest.raises(UnknownGlassError):
        catalog_glass("N-BK7")
    monkeypatch.delenv("LENSFIT_GLASS_CATALOG")
    assert "N-BK7" in known_glass_names()


def test_catalog_name_collision_rejected(
    tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "dup.toml"
    _write_catalog(path, ["N-FOO", "NFOO"])
    monkeypatch.setenv("LENSFIT_GLASS_CATALOG", str(path))
    with pytest.raises(ValueError, match="collide"):
        known_glass_names()
