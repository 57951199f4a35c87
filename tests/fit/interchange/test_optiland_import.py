"""lensfit import of Optiland's JSON save format (lensfit.interchange.optiland), on a
hand-made fixture in the layout ``Optic.to_dict`` writes (tests/fit/fixtures/optiland/):
a Cooke triplet with a separate stop plane, catalog glasses qualified by maker, an
AbbeMaterial, RadialApertures, a coating and a comment.

The older layout (no ``thickness``, ``is_reflective``/``coating`` on the surface, no
apertures) is derived from it here: thicknesses then come from the ``cs.z`` differences
and semi-diameters from a paraxial trace, which is checked against lensfit's own paraxial
module (a different code path: 2x2 matrices): the stop so found must give an entrance
pupil of the file's EPD.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from lensfit.cli import main
from lensfit.interchange import ImportProblems, convert_optiland
from lensfit.paraxial import paraxial
from lensfit.prescription import lens_from_dict, load_lens, make_lens

FIX = Path(__file__).resolve().parents[1] / "fixtures" / "optiland" / "cooke_triplet.json"
DATA = json.loads(FIX.read_text(encoding="utf-8"))

EXPECTED = [
    {"shape": "sphere", "radius": 22.01359, "thickness": 3.25896, "material": "N-SK16",
     "semi_diameter": 6.0},
    {"shape": "sphere", "radius": -435.76044, "thickness": 6.00755, "material": "air",
     "semi_diameter": 6.0},
    {"shape": "sphere", "radius": -22.21328, "thickness": 0.99997, "material": "F2",
     "semi_diameter": 5.0},
    {"shape": "sphere", "radius": 20.29192, "thickness": 2.0, "material": "air",
     "semi_diameter": 5.0},
    {"shape": "plane", "thickness": 2.75041, "material": "air", "semi_diameter": 4.5,
     "stop": True},
    {"shape": "sphere", "radius": 79.6836, "thickness": 2.95208, "nd": 1.6204, "vd": 60.3,
     "semi_diameter": 5.5},
    {"shape": "sphere", "radius": -18.3783, "thickness": 42.20778, "material": "air",
     "semi_diameter": 5.5},
]


def test_cooke_triplet_fixture():
    result = convert_optiland(copy.deepcopy(DATA), label="cooke.json")
    assert result.data["surface"] == EXPECTED
    info = result.data["lens"]
    assert info["field_of_view_deg"] == 40.0  # angle fields up to y = 20 degrees
    assert info["name"].startswith("Cooke triplet")
    lens = lens_from_dict(result.data)
    # Independent: the same table typed as a lensfit lens has the same first order
    assert paraxial(lens).efl_mm == paraxial(make_lens(EXPECTED)).efl_mm
    notes = "\n".join(result.notes)
    for words in ("cooke.json: wavelengths: wavelengths not mapped",
                  "cooke.json: surface_group.surfaces[1].interaction_model.coating: coating",
                  "cooke.json: surface_group.surfaces[5].comment: comment",
                  "cooke.json: surface_group.surfaces[6].material_post: AbbeMaterial",
                  "cooke.json: aperture: aperture EPD 10: not mapped"):
        assert words in notes, notes


def older_layout(data: dict) -> dict:
    d = copy.deepcopy(data)
    for s in d["surface_group"]["surfaces"]:
        s.pop("thickness", None)
        s.pop("interaction_model", None)
        s["aperture"] = None
        s.update(is_reflective=False, coating=None, bsdf=None)
    return d


def test_older_layout_thickness_from_z_and_paraxial_semi_diameters():
    result = convert_optiland(older_layout(DATA), label="old.json")
    surf = result.data["surface"]
    # z differences of the running sums, at 15 digits: the typed thicknesses
    assert [s["thickness"] for s in surf] == [e["thickness"] for e in EXPECTED]
    lens = lens_from_dict(result.data)
    # The stop from the EPD 10 marginal ray: lensfit's paraxial entrance pupil for that
    # stop is 5 mm (the semi-diameters are written to 6 significant digits: 1e-5)
    assert paraxial(lens).entrance_pupil.radius_mm == pytest.approx(5.0, rel=1e-5)
    # every surface passes the marginal ray (5 mm at the first surface, parallel light)
    assert surf[0]["semi_diameter"] > 5.0
    assert sum("paraxial marginal and chief rays" in n for n in result.notes) == 7


@pytest.mark.parametrize(("edit", "path", "words"), [
    (lambda d: d["surface_group"]["surfaces"][3]["geometry"]["cs"].update(rx=0.1),
     "surface_group.surfaces[3].geometry.cs.rx", "a tilted surface: unsupported"),
    (lambda d: d["surface_group"]["surfaces"][2]["interaction_model"].update(
        is_reflective=True),
     "surface_group.surfaces[2].interaction_model.is_reflective", "a mirror"),
    (lambda d: d["surface_group"]["surfaces"][1]["material_post"].update(name="NOPE-7"),
     "surface_group.surfaces[1].material_post.name", "glass 'NOPE-7' (schott): unknown"),
    (lambda d: d["surface_group"]["surfaces"][1]["geometry"].update(type="ZernikeGeometry"),
     "surface_group.surfaces[1].geometry.type", "unsupported surface type"),
    (lambda d: d["surface_group"]["surfaces"][1]["geometry"].update(radius="big"),
     "surface_group.surfaces[1].geometry.radius", "expected int or float"),
    (lambda d: d["surface_group"]["surfaces"][4].update(
        aperture={"type": "RectangularAperture", "x_max": 1.0}),
     "surface_group.surfaces[4].aperture", "unsupported"),
])
def test_each_problem_names_its_json_path(edit, path, words, optiland_problems):
    d = copy.deepcopy(DATA)
    edit(d)
    problems = optiland_problems(d, "t.json")
    assert len(problems) == 1, problems
    assert problems[0].startswith(f"t.json: {path}: "), problems[0]
    assert words in problems[0]


def test_cli_import_optiland(tmp_path, capsys):
    out = tmp_path / "cooke.toml"
    assert main(["import", str(FIX), "-o", str(out)]) == 0
    assert load_lens(out).surfaces[4].stop
    bad = tmp_path / "bad.json"
    d = copy.deepcopy(DATA)
    d["surface_group"]["surfaces"][2]["interaction_model"]["is_reflective"] = True
    d["surface_group"]["surfaces"][3]["geometry"]["cs"]["x"] = 1.0
    bad.write_text(json.dumps(d), encoding="utf-8")
    capsys.readouterr()
    assert main(["import", str(bad), "-o", str(tmp_path / "bad.toml")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 3 and "nothing written" in err[-1]  # two problems, one line each
    assert not (tmp_path / "bad.toml").exists()


def test_loader_refusal_names_the_files_surfaces():
    # surfaces[1] 0.5 mm thick: the biconvex element's faces (radii 22 and -436, clear
    # radius 6) cross. The loader counts lensfit's surfaces from 0 ("surfaces 0 and 1");
    # the line names them as the file does
    d = copy.deepcopy(DATA)
    d["surface_group"]["surfaces"][1]["thickness"] = 0.5
    with pytest.raises(ImportProblems) as e:
        convert_optiland(d, label="t.json")
    assert len(e.value.problems) == 1, e.value.problems
    line = e.value.problems[0]
    assert line.startswith("t.json: surface_group.surfaces[1]: key 'thickness': "
                           "surface_group.surfaces[1] and surface_group.surfaces[2] cross "
                           "inside their clear aperture (gap "), line
    assert "surfaces 0 and 1" not in line
