"""The importer of lentil-format JSON lens tables (lensfit.prescription.lentil)."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from typing import Any

import pytest

from lensfit.cli import main
from lensfit.common.errors import LensError
from lensfit.glass import catalog_glass
from lensfit.prescription import lens_from_dict, load_lens
from lensfit.prescription.lentil import (
    GLASS_ND_MATCH,
    convert_entry,
    load_lentil_json,
    to_toml,
)

LENTIL_JSON = Path(__file__).parents[3].parent / "shared/lensdata/lentil-lenses.json"

needs_lentil = pytest.mark.skipif(
    not LENTIL_JSON.exists(),
    reason=f"lentil lens table not found at {LENTIL_JSON} (shared/lensdata is outside the repo)",
)


def element(
    radius: float,
    thickness: float,
    material: str,
    housing: float,
    *,
    ior: float | None = None,
    abbe: float | None = None,
    geometry: str = "spherical",
) -> dict[str, Any]:
    """One element in the lentil layout."""
    return {
        "radius": radius,
        "thickness": thickness,
        "material": material,
        "ior": ior,
        "abbe": abbe,
        "housing-radius": housing,
        "lens-geometry": geometry,
        "aspherical-equation": None,
    }


def entry(elements: list[dict[str, Any]], year: int = 1960) -> dict[str, Any]:
    return {
        "company": "test",
        "product-name": "synthetic",
        "year": year,
        "focal-length-mm-patent": 50.0,
        "optical-elements-patent": elements,
    }


def singlet(
    material: str = "BK7", ior: float | None = 1.5168, abbe: float | None = 64.2
) -> list[dict[str, Any]]:
    """Iris, then a biconvex singlet (lentil layout)."""
    return [
        element(0.0, 2.0, "iris", 8.0),
        element(50.0, 5.0, material, 10.0, ior=ior, abbe=abbe),
        element(-50.0, 47.0, "air", 10.0),
    ]


def convert(elements: list[dict[str, Any]], year: int = 1960) -> dict[str, Any]:
    return convert_entry("9000", entry(elements, year), source="test.json")


# ------------------------------------------------------------- entry 0001


@pytest.fixture(scope="module")
def lentil_data() -> dict[str, Any]:
    if not LENTIL_JSON.exists():
        pytest.skip(f"lentil lens table not found at {LENTIL_JSON}")
    return load_lentil_json(LENTIL_JSON)


@needs_lentil
def test_entry_0001_matches_committed_lensdb_file(lentil_data: dict[str, Any]) -> None:
    converted = lens_from_dict(convert_entry("0001", lentil_data["0001"], source="lentil"))
    committed = load_lens("0001")
    assert len(converted.surfaces) == len(committed.surfaces) == 15
    for i, (a, b) in enumerate(zip(converted.surfaces, committed.surfaces, strict=True)):
        assert a.shape == b.shape, i
        assert a.radius_mm == b.radius_mm, i
        assert a.thickness_mm == b.thickness_mm, i
        assert a.material_spec == b.material_spec, i
        assert a.semi_diameter_mm == b.semi_diameter_mm, i
        assert a.stop == b.stop, i
        assert a == b, i  # media and coatings too
    # and the numbers are lentil's, surface by surface (0001 has no flats but the iris)
    elements = lentil_data["0001"]["optical-elements-patent"]
    for s, e in zip(converted.surfaces, elements, strict=True):
        assert s.thickness_mm == e["thickness"]
        assert s.semi_diameter_mm == e["housing-radius"]
        assert s.stop == (e["material"] == "iris")
        if s.shape != "plane":
            assert s.radius_mm == e["radius"]


@needs_lentil
def test_to_toml_round_trips_and_is_deterministic(lentil_data: dict[str, Any]) -> None:
    for lens_id in ("0001", "0014", "2002"):  # spherical, aspheric, cylinders without iris
        data = convert_entry(lens_id, lentil_data[lens_id], source="lentil")
        text = to_toml(data)
        assert tomllib.loads(text) == data
        again = to_toml(convert_entry(lens_id, lentil_data[lens_id], source="lentil"))
        assert again.encode() == text.encode()


@needs_lentil
def test_cli_import_writes_a_loadable_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(["import", str(LENTIL_JSON), "--id", "0001", "-o", str(tmp_path)])
    assert rc == 0
    (written,) = sorted(tmp_path.iterdir())
    assert written.suffix == ".toml" and written.name.startswith("0001-")
    assert str(written) in capsys.readouterr().out
    assert load_lens(written).surfaces == load_lens("0001").surfaces


@needs_lentil
def test_cli_import_unknown_id(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["import", str(LENTIL_JSON), "--id", "0404", "-o", str(tmp_path)])
    assert rc == 2
    err = capsys.readouterr().err
    assert "0404" in err and str(LENTIL_JSON) in err
    assert not list(tmp_path.iterdir())


@needs_lentil
def test_glass_matching_in_0001(lentil_data: dict[str, Any]) -> None:
    data = convert_entry("0001", lentil_data["0001"], source="lentil")
    elements = lentil_data["0001"]["optical-elements-patent"]
    # LAK9 (table nd 1.6913) is within 1e-3 of catalog N-LAK9 (nd 1.6910)
    assert elements[4]["material"] == "LAK9"
    assert data["surface"][4]["material"] == "N-LAK9"
    # SF5 (table nd 1.6751) is 2.4e-3 from catalog SF5 (1.6727): the table's nd/vd stay
    assert elements[0]["material"] == "SF5"
    assert abs(catalog_glass("SF5").nd - elements[0]["ior"]) > GLASS_ND_MATCH
    assert data["surface"][0]["nd"] == 1.6751 and data["surface"][0]["vd"] == 32.3
    assert data["surface"][0]["glass_label"] == "SF5"
    assert "material" not in data["surface"][0]


# ------------------------------------------------------------- synthetic entries


def test_named_glass_uses_the_catalog_within_tolerance() -> None:
    bk7 = catalog_glass("N-BK7")
    # 0.9e-3 away: still the catalog glass (found with the N- prefix)
    near = convert(singlet("BK7", ior=bk7.nd + 0.9e-3))["surface"][1]
    assert near["material"] == "N-BK7" and "nd" not in near
    # 1.5e-3 away: a different glass; the table's nd/vd are kept under a label
    far_data = convert(singlet("BK7", ior=bk7.nd + 1.5e-3, abbe=60.0))
    far = far_data["surface"][1]
    assert far["nd"] == bk7.nd + 1.5e-3 and far["vd"] == 60.0 and far["glass_label"] == "BK7"
    assert "material" not in far
    assert "BK7" in far_data["lens"]["notes"]  # the choice is written down
    lens = lens_from_dict(far_data)
    assert float(lens.surfaces[1].medium.n(587.5618)) == pytest.approx(bk7.nd + 1.5e-3, abs=1e-6)


def test_abbe_material_keeps_nd_vd() -> None:
    s = convert(singlet("abbe", ior=1.6, abbe=40.0))["surface"][1]
    assert (s["nd"], s["vd"]) == (1.6, 40.0) and "material" not in s


def test_cylinders_map_to_cylinder_shapes() -> None:
    elements = [
        element(0.0, 2.0, "iris", 8.0),
        element(80.0, 4.0, "BK7", 10.0, ior=1.5168, abbe=64.2, geometry="cyl-x"),
        element(0.0, 3.0, "air", 10.0),
        element(-80.0, 4.0, "BK7", 10.0, ior=1.5168, abbe=64.2, geometry="cyl-y"),
        element(0.0, 40.0, "air", 10.0),
    ]
    data = convert(elements)
    assert [s["shape"] for s in data["surface"]] == [
        "plane",
        "cylinder-x",
        "plane",
        "cylinder-y",
        "plane",
    ]
    lens = lens_from_dict(data)
    assert lens.surfaces[1].curvature_xy == (0.0, 1 / 80.0)  # cylinder axis x: power in y
    assert lens.surfaces[3].curvature_xy == (-1 / 80.0, 0.0)


def test_entry_without_iris_gets_a_stop_plane() -> None:
    # A meniscus concave to the scene: its edge bulges 0.51 mm towards the scene
    # (sag of R = -40 mm at 6.4 mm), so the added stop must sit at least that far in front.
    elements = [
        element(-40.0, 4.0, "BK7", 6.4, ior=1.5168, abbe=64.2),
        element(-20.0, 30.0, "air", 6.4),
    ]
    data = convert(elements)
    stop = data["surface"][0]
    assert stop["shape"] == "plane" and stop.get("stop") is True and stop["material"] == "air"
    assert stop["semi_diameter"] == 6.4
    edge_sag = 40.0 - math.sqrt(40.0**2 - 6.4**2)
    assert stop["thickness"] >= edge_sag
    assert stop["thickness"] < edge_sag + 0.01  # just in front, not far away
    assert data["surface"][1]["radius"] == -40.0
    assert "no iris" in data["lens"]["notes"]
    lens = lens_from_dict(data)
    assert lens.stop_index == 0 and len(lens.surfaces) == 3


def test_crossing_housings_are_shrunk() -> None:
    # R = +-20 mm with 1 mm centre thickness: the two sags add up to 1 mm at
    # h = sqrt(20² - 19.5²) = 4.44 mm, well inside the 15 mm housing.
    elements = [
        element(0.0, 2.0, "iris", 4.0),
        element(20.0, 1.0, "BK7", 15.0, ior=1.5168, abbe=64.2),
        element(-20.0, 20.0, "air", 15.0),
    ]
    raw = convert(elements)
    lens = lens_from_dict(raw)  # loads: the importer shrank the housings
    h_meet = math.sqrt(20.0**2 - 19.5**2)
    for s in lens.surfaces[1:]:
        # shrunk to just inside the meeting height (the importer keeps a 2% margin)
        assert 0.95 * h_meet <= s.semi_diameter_mm < h_meet
    assert "do not cross" in raw["lens"]["notes"]
    # without the shrinking the same table is refused as crossing
    for s in raw["surface"][1:]:
        s["semi_diameter"] = 15.0
    with pytest.raises(LensError, match="cross"):
        lens_from_dict(raw)


def test_coating_default_follows_the_year() -> None:
    assert convert(singlet(), year=1935)["coating"]["default"] == "none"
    assert convert(singlet(), year=1960)["coating"]["default"] == "mgf2"


# ------------------------------------------------------------- bad input


def test_bad_json_names_the_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "broken.json"
    path.write_text('{"0001": {"year": 1953,,}}', encoding="utf-8")
    with pytest.raises(LensError) as info:
        load_lentil_json(path)
    assert info.value.file == str(path)
    assert str(info.value).startswith(f"{path}: ")
    assert "line 1" in str(info.value)  # the parser's position is passed on
    assert main(["import", str(path), "-o", str(tmp_path / "out")]) == 2
    assert str(path) in capsys.readouterr().err


def test_json_that_is_not_an_object(tmp_path: Path) -> None:
    path = tmp_path / "list.json"
    path.write_text(json.dumps([1, 2]), encoding="utf-8")
    with pytest.raises(LensError) as info:
        load_lentil_json(path)
    assert info.value.file == str(path)


def test_unknown_glass_without_index_names_the_element() -> None:
    with pytest.raises(LensError) as info:
        convert(singlet("UNOBTAINIUM", ior=None, abbe=None))
    e = info.value
    assert (e.file, e.surface, e.key) == ("test.json", 1, "material")
    assert "UNOBTAINIUM" in str(e)


@pytest.mark.parametrize("key", ["thickness", "housing-radius"])
def test_missing_number_names_the_element(key: str) -> None:
    elements = singlet()
    elements[2][key] = None
    with pytest.raises(LensError) as info:
        convert(elements)
    e = info.value
    assert (e.file, e.surface, e.key) == ("test.json", 2, key)
    assert str(e).startswith(f"test.json: surface 2: key '{key}': ")
