"""Model glasses and media without dispersion from .zmx and Optiland files, and the
Optiland files that Optiland 0.6.3 itself saves (tests/fit/fixtures/optiland/, see its
README): imported without hand edits, with a note per surface saying what was done.

* Zemax ``GLAS ___BLANK 1 0 nd vd dPgF``: nd/vd/dpgf with lensfit's Abbe model, whose
  indices at F, d, C and g are checked here against the definitions vd = (nd - 1)/(nF -
  nC) and P_g,F = (ng - nF)/(nF - nC) = normal line + dPgF (lines and normal line written
  out below; tolerances as in tests/fit/glass/test_model_glass.py: 1e-15 on n at d, 1e-12
  on vd and P_g,F, the ulps of n divided by nF - nC); ``vd 0`` a constant index, n = nd at
  every wavelength from 380 to 780 nm, exactly. ``write_zmx`` writes both back.
* Optiland ``IdealMaterial`` (a constant index), ``AbbeMaterial`` (nd/vd), the image
  surface saved as a plain "Surface", and HIKARI's older glass names ('SK16' of
  'hikari', as Optiland's own Cooke triplet has it) and makers written in parentheses.
* Bad values: one line each with the file and line number (JSON path), exit 2, nothing
  written.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest

from lensfit.cli import main
from lensfit.glass import ConstantGlass
from lensfit.interchange import ImportProblems, convert_optiland, parse_zmx, write_zmx
from lensfit.prescription import lens_from_dict, make_lens

OPT = Path(__file__).resolve().parents[1] / "fixtures" / "optiland"
D, F, C, G = 587.56, 486.13, 656.27, 435.83
LAM = np.linspace(380.0, 780.0, 401)


def normal_line(vd: float) -> float:
    return 0.6438 - 0.001682 * min(vd, 100.0)


def zmx(glass1: str, glass2: str, gcat: str = "SCHOTT") -> str:
    """A cemented doublet, the stop on its front, with the two GLAS lines given."""
    return "\n".join([
        "MODE SEQ", "NAME doublet", "UNIT MM", f"GCAT {gcat}",
        "SURF 0", "  TYPE STANDARD", "  CURV 0", "  DISZ INFINITY",
        "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.02", "  DISZ 5", f"  {glass1}",
        "  DIAM 10 1 0 0 1 \"\"",
        "SURF 2", "  TYPE STANDARD", "  CURV -0.03", "  DISZ 2", f"  {glass2}",
        "  DIAM 10 1 0 0 1 \"\"",
        "SURF 3", "  TYPE STANDARD", "  CURV -0.005", "  DISZ 45", "  DIAM 10 1 0 0 1 \"\"",
        "SURF 4", "  TYPE STANDARD", "  CURV 0", "  DISZ 0", ""])


MODEL = "GLAS ___BLANK 1 0 1.6 40 0.012 0 0 0 0 0"
CONSTANT = "GLAS ___BLANK 1 0 1.5 0 0 0 0 0 0 0"
GLAS1, GLAS2 = 14, 20  # the line numbers of the two GLAS lines in zmx()


def media(lens) -> list:
    return [s.medium for s in lens.surfaces if not s.inserted]


def test_zmx_model_glass_with_dpgf_and_a_medium_without_dispersion():
    result = parse_zmx(zmx(MODEL, CONSTANT), label="d.zmx")
    surf = result.data["surface"]
    assert {k: surf[0][k] for k in ("nd", "vd", "dpgf")} == {"nd": 1.6, "vd": 40.0,
                                                              "dpgf": 0.012}
    assert "material" not in surf[0]
    assert surf[1]["material"] == {"n": 1.5}
    model, constant, air = media(lens_from_dict(result.data))
    # The model glass, by the definitions of vd and P_g,F
    n_d, n_f, n_c, n_g = (float(v) for v in model.n(np.array([D, F, C, G])))
    assert n_d == pytest.approx(1.6, abs=1e-15)
    assert (n_d - 1) / (n_f - n_c) == pytest.approx(40.0, rel=1e-12)
    assert (n_g - n_f) / (n_f - n_c) == pytest.approx(normal_line(40.0) + 0.012, abs=1e-12)
    # The medium without dispersion: nd at every wavelength, exactly
    assert isinstance(constant, ConstantGlass) and np.all(constant.n(LAM) == 1.5)
    # One note per surface, naming its GLAS line
    notes = "\n".join(result.notes)
    assert (f"d.zmx:{GLAS1}: SURF 1 GLAS MODEL: nd 1.6 vd 40: lensfit's Abbe model "
            "(lensdb/glass/README.md), P_g,F on the normal line + dPgF 0.012") in notes
    assert (f"d.zmx:{GLAS2}: SURF 2 GLAS MODEL: nd 1.5 vd 0: a medium without dispersion, "
            "n = 1.5 at every wavelength (material = { n = 1.5 })") in notes


def test_zmx_model_glass_without_dpgf_and_air():
    # Older files end the GLAS line at vd; nd 1 vd 0 is air
    result = parse_zmx(zmx("GLAS ___BLANK 1 0 1.6 40", "GLAS ___BLANK 1 0 1 0 0 0 0"),
                       label="d.zmx")
    surf = result.data["surface"]
    assert (surf[0]["nd"], surf[0]["vd"], "dpgf" in surf[0]) == (1.6, 40.0, False)
    # Surface 2 is followed by air; its medium is the one between surfaces 2 and 3
    assert surf[1]["material"] == "air"
    assert any(f"d.zmx:{GLAS2}: SURF 2 GLAS MODEL: nd 1 vd 0: air" in n for n in result.notes)


def test_zmx_model_glass_as_optilands_writer_writes_it():
    # Optiland 0.6.3's .zmx writer (optiland.fileio.zemax.writer.encoder, _encode_glas)
    # writes a model glass "GLAS MODEL 1 0 nd V 0 0 0 0 0 0", in the columns of
    # OpticStudio's ___BLANK: the same model glass, dPgF included where given
    for dpgf in ("0", "0.012"):
        blank = parse_zmx(zmx(f"GLAS ___BLANK 1 0 1.6 40 {dpgf} 0 0 0 0 0", CONSTANT),
                          label="d.zmx")
        model = parse_zmx(zmx(f"GLAS MODEL 1 0 1.6 40 {dpgf} 0 0 0 0 0", CONSTANT),
                          label="d.zmx")
        assert model.data["surface"] == blank.data["surface"]
    assert model.data["surface"][0]["dpgf"] == 0.012
    assert any(n.startswith(f"d.zmx:{GLAS1}: SURF 1 GLAS MODEL: nd 1.6 vd 40: lensfit's "
                            "Abbe model") and "Optiland's .zmx writer's name" in n
               for n in model.notes), model.notes
    # Optiland writes vd 99.99 for a medium without dispersion (nF = nC): kept as written,
    # as Optiland's own reader takes it back, with a note saying so
    znse = "GLAS MODEL 1 0 2.4028000000000000E+00 9.9989999999999995E+01 0 0 0 0 0 0"
    result = parse_zmx(zmx(znse, "GLAS N-SF5 0 0"), label="d.zmx")
    assert {k: result.data["surface"][0][k] for k in ("nd", "vd")} == {"nd": 2.4028,
                                                                        "vd": 99.99}
    assert any("vd 99.99 is what Optiland writes for a medium without dispersion" in n
               for n in result.notes), result.notes


INFRARED = ("an index above 3 belongs to an infrared medium (germanium about 4.0, silicon "
            "about 3.4), opaque to the visible light (380-780 nm) lensfit traces")


def test_germanium_is_refused_with_the_reason(tmp_path, capsys):
    # Germanium (n 4.002, Optiland's InfraredTriplet) through Optiland's .zmx writer: one
    # line naming the file, the GLAS line, the surface and the index, and why
    src, out = tmp_path / "ge.zmx", tmp_path / "out" / "ge.toml"
    out.parent.mkdir()
    ge = "GLAS MODEL 1 0 4.0019999999999998E+00 9.9989999999999995E+01 0 0 0 0 0 0"
    src.write_text(zmx(ge, "GLAS N-SF5 0 0"), encoding="utf-8")
    assert main(["import", str(src), "-o", str(out)]) == 2
    assert not list(out.parent.iterdir())
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and err[-1].endswith("nothing written"), err
    assert err[0] == (f"lensfit: error: {src}:{GLAS1}: SURF 1 GLAS MODEL nd 4.002 vd 99.99: "
                      f"expected 1 <= nd <= 3; {INFRARED} (not imported)")


def test_zmx_export_writes_model_glasses_back():
    lens = lens_from_dict(parse_zmx(zmx(MODEL, CONSTANT), label="d.zmx").data)
    text, notes = write_zmx(lens)
    assert "  GLAS ___BLANK 1 0 1.6 40.0 0.012 0 0 0 0 0\n" in text
    assert "  GLAS ___BLANK 1 0 1.5 0 0 0 0 0 0 0\n" in text  # vd 0: no dispersion
    back = lens_from_dict(parse_zmx(text, label="rt.zmx").data)
    assert [s.material_spec for s in back.surfaces] == [s.material_spec for s in lens.surfaces]
    for a, b in zip(media(lens), media(back), strict=True):
        assert np.array_equal(a.n(LAM), b.n(LAM))
    # A named constant index goes out nameless, and says so
    named = make_lens([{"shape": "sphere", "radius": 50.0, "thickness": 5.0, "material":
                        {"name": "oil", "n": 1.515}, "semi_diameter": 8.0, "stop": True},
                       {"shape": "plane", "thickness": 40.0, "material": "air",
                        "semi_diameter": 8.0}])
    text, notes = write_zmx(named)
    assert "GLAS ___BLANK 1 0 1.515 0 " in text
    assert any("glass name 'oil' not exported" in n for n in notes)


@pytest.mark.parametrize(("glas", "says"), [
    ("GLAS ___BLANK 1 0 0.9 40 0", "SURF 1 GLAS MODEL nd 0.9 vd 40: expected 1 <= nd <= 3"),
    ("GLAS ___BLANK 1 0 1e300 40 0", "SURF 1 GLAS MODEL nd 1e+300 vd 40: expected 1 <= nd"),
    ("GLAS ___BLANK 1 0 1.6 -40 0", "SURF 1 GLAS MODEL nd 1.6 vd -40: expected 5 <= vd <= "
                                    "150, or vd 0"),
    ("GLAS ___BLANK 1 0 1.6 2 0", "SURF 1 GLAS MODEL nd 1.6 vd 2: expected 5 <= vd"),
    ("GLAS ___BLANK 1 0 1.6 1e6 0", "SURF 1 GLAS MODEL nd 1.6 vd 1e+06: expected 5 <= vd"),
    ("GLAS ___BLANK 1 0 nan 40 0", "SURF 1 GLAS MODEL nd: expected a finite number, "
                                   "found 'nan'"),
    ("GLAS ___BLANK 1 0 1.6 inf 0", "SURF 1 GLAS MODEL vd: expected a finite number"),
    ("GLAS ___BLANK 1 0 1.6 40 0.75", "SURF 1 GLAS MODEL nd 1.6 vd 40 dPgF 0.75: expected "
                                      "|dPgF| <= 0.1"),
    ("GLAS ___BLANK 1 0 1.6", "SURF 1 GLAS MODEL vd: missing value 5"),
])  # fmt: skip
def test_zmx_bad_model_glass_one_line_exit_2_nothing_written(tmp_path, capsys, glas, says):
    src, out = tmp_path / "bad.zmx", tmp_path / "out" / "bad.toml"
    out.parent.mkdir()
    src.write_text(zmx(glas, "GLAS N-SF5 0 0"), encoding="utf-8")
    assert main(["import", str(src), "-o", str(out)]) == 2
    assert not list(out.parent.iterdir())
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and err[-1].endswith("nothing written"), err
    assert err[0].startswith(f"lensfit: error: {src}:{GLAS1}: {says}"), err[0]


def test_zmx_older_hikari_name_is_its_current_one():
    result = parse_zmx(zmx("GLAS SK16 0 0 1.62 60", "GLAS N-SF5 0 0", gcat="HIKARI SCHOTT"),
                       label="h.zmx")
    assert result.data["surface"][0]["material"] == "HIKARI:J-SK16"
    assert any(n.startswith(f"h.zmx:{GLAS1}: SURF 1 GLAS: glass SK16 (HIKARI) taken as "
                            "HIKARI:J-SK16, HIKARI's current name") for n in result.notes)
    # A name HIKARI never used is still unknown, with the close matches
    with pytest.raises(ImportProblems) as e:
        parse_zmx(zmx("GLAS SK99 0 0", "GLAS N-SF5 0 0", gcat="HIKARI"), label="h.zmx")
    assert e.value.problems[0].startswith(f"h.zmx:{GLAS1}: SURF 1 GLAS SK99 (GCAT HIKARI): "
                                          "unknown glass")


# --- Optiland ------------------------------------------------------------------------------

COOKE = json.loads((OPT / "cooke_triplet_optiland063.json").read_text(encoding="utf-8"))
MEDIA = json.loads((OPT / "media_optiland063.json").read_text(encoding="utf-8"))


def test_optiland_063_cooke_triplet_imports_without_edits(tmp_path, capsys):
    # As Optiland 0.6.3 saves its own sample: the image is a plain "Surface", the crowns
    # 'SK16' of 'hikari' (HIKARI's J-SK16), the flint 'F2' of 'schott'
    assert COOKE["surface_group"]["surfaces"][-1]["type"] == "Surface"
    result = convert_optiland(copy.deepcopy(COOKE), label="cooke.json")
    assert [s["material"] for s in result.data["surface"]] == \
        ["HIKARI:J-SK16", "air", "F2", "air", "HIKARI:J-SK16", "air"]
    assert [s["radius"] for s in result.data["surface"]] == \
        [22.01359, -435.76044, -22.21328, 20.29192, 79.6836, -18.39533]
    notes = "\n".join(result.notes)
    for i in (1, 5):  # one note per surface
        assert (f"cooke.json: surface_group.surfaces[{i}].material_post.name: glass SK16 "
                "(HIKARI) taken as HIKARI:J-SK16") in notes
    # The whole way through the command line
    out = tmp_path / "cooke.toml"
    assert main(["import", str(OPT / "cooke_triplet_optiland063.json"), "-o", str(out)]) == 0
    assert [s["thickness"] for s in result.data["surface"]] == \
        [3.25896, 6.00755, 0.99997, 4.75041, 2.95208, 42.20778]
    assert [bool(s.get("stop")) for s in result.data["surface"]].index(True) == 3


def test_optiland_063_media():
    result = convert_optiland(copy.deepcopy(MEDIA), label="m.json")
    surf = result.data["surface"]
    assert surf[0]["material"] == {"n": 1.5}
    assert (surf[2]["nd"], surf[2]["vd"]) == (1.5168, 64.17)
    assert (surf[3]["nd"], surf[3]["vd"]) == (1.62004, 36.37)
    const, _, crown, flint, _ = media(lens_from_dict(result.data))
    assert np.all(const.n(LAM) == 1.5)
    for glass, nd, vd in ((crown, 1.5168, 64.17), (flint, 1.62004, 36.37)):
        n_d, n_f, n_c = (float(v) for v in glass.n(np.array([D, F, C])))
        assert n_d == pytest.approx(nd, abs=1e-15)
        assert (n_d - 1) / (n_f - n_c) == pytest.approx(vd, rel=1e-12)
    notes = "\n".join(result.notes)
    assert ("m.json: surface_group.surfaces[1].material_post: IdealMaterial of index 1.5: a "
            "medium without dispersion") in notes
    assert ("m.json: surface_group.surfaces[3].material_post: AbbeMaterial nd 1.5168 vd "
            "64.17: kept, with lensfit's Abbe model (lensdb/glass/README.md); Optiland's "
            "buchdahl model differs from it by about 0.00024") in notes
    assert "surface_group.surfaces[4].material_post: AbbeMaterial nd 1.62004 vd 36.37: " \
        "kept, with lensfit's Abbe model (lensdb/glass/README.md); Optiland's polynomial " \
        "model differs from it by about 0.00049" in notes


def material(doc: dict, i: int) -> dict:
    return doc["surface_group"]["surfaces"][i]["material_post"]


@pytest.mark.parametrize(("name", "ref"), [
    ("SK16 (HIKARI)", None), ("'SK16' (hikari)", None), ("J-SK16 (Hikari)", ""),
    ("SK16 (HIKARI)", "hikari"),
])  # fmt: skip
def test_optiland_maker_in_parentheses(name, ref):
    d = copy.deepcopy(COOKE)
    material(d, 1).update(name=name, reference=ref)
    result = convert_optiland(d, label="c.json")
    assert result.data["surface"][0]["material"] == "HIKARI:J-SK16"
    assert any(n.startswith("c.json: surface_group.surfaces[1].material_post.name: glass "
                            f"{name!r}: ") and "of HIKARI's catalog" in n
               for n in result.notes), result.notes


M1 = "surface_group.surfaces[1].material_post"
M3 = "surface_group.surfaces[3].material_post"


@pytest.mark.parametrize("filename", [
    "C:\\Users\\someone\\optiland\\database\\data-nk\\glass\\hikari\\SK16.yml",
    "/usr/lib/python3/site-packages/optiland/database/data-nk/glass/hikari/SK16.yml",
])  # fmt: skip
def test_optiland_maker_from_the_filename_when_no_reference(filename):
    # Optiland's published samples (docs/samples/Cooke_triplet.json) give the glass
    # 'SK16' with reference null: the maker is only the folder of its data file
    d = copy.deepcopy(COOKE)
    material(d, 1).update(reference=None, filename=filename)
    result = convert_optiland(d, label="c.json")
    assert result.data["surface"][0]["material"] == "HIKARI:J-SK16"
    notes = "\n".join(result.notes)
    assert ("c.json: surface_group.surfaces[1].material_post.filename: glass 'SK16' has no "
            "reference: the maker 'hikari' is taken from the folder of its data file "
            "(.../hikari/SK16.yml)") in notes
    assert ("c.json: surface_group.surfaces[1].material_post.name: glass SK16 (HIKARI) "
            "taken as HIKARI:J-SK16") in notes


def test_optiland_filename_folder_that_is_no_maker_or_a_reference_given():
    # A folder that names no maker qualifies nothing: SK16 alone is no glass lensfit has
    d = copy.deepcopy(COOKE)
    material(d, 1).update(reference=None, filename="/data/glass/specs/SK16.yml")
    with pytest.raises(ImportProblems) as e:
        convert_optiland(d, label="c.json")
    assert e.value.problems[0].startswith("c.json: surface_group.surfaces[1].material_post."
                                          "name: glass 'SK16': unknown glass 'SK16'")
    # The reference, where given, is the maker; the filename is not read
    d = copy.deepcopy(COOKE)
    material(d, 1).update(reference="hikari", filename="/glass/schott/SK16.yml")
    result = convert_optiland(d, label="c.json")
    assert result.data["surface"][0]["material"] == "HIKARI:J-SK16"
    assert not any(".filename" in n for n in result.notes)
    # A glass unknown in the filename's maker's catalog says which maker was tried
    d = copy.deepcopy(COOKE)
    material(d, 1).update(name="N-SK10", reference=None,
                          filename="C:\\optiland\\glass\\schott\\N-SK10.yml")
    with pytest.raises(ImportProblems) as e:
        convert_optiland(d, label="c.json")
    assert e.value.problems[0].startswith("c.json: surface_group.surfaces[1].material_post."
                                          "name: glass 'N-SK10' (schott): unknown glass")


def test_optiland_germanium_is_refused_with_the_reason(optiland_problems):
    for k, what, limit, where in ((1, "a constant index", "n", M1), (3, "nd", "nd", M3)):
        d = copy.deepcopy(MEDIA)
        material(d, k).update(index=4.002)
        assert optiland_problems(d, "m.json") == [
            f"m.json: {where}.index: {what} 4.002: expected 1 <= {limit} <= 3; {INFRARED}"]


@pytest.mark.parametrize(("edit", "path", "words"), [
    (lambda d: material(d, 1).update(index=0.9), f"{M1}.index", "a constant index 0.9: "
     "expected 1 <= n <= 3"),
    (lambda d: material(d, 1).update(index=1e300), f"{M1}.index", "expected 1 <= n <= 3"),
    (lambda d: material(d, 1).update(index=math.nan), f"{M1}.index",
     "expected a finite number, found nan"),
    (lambda d: material(d, 1).update(absorp=0.01), f"{M1}.absorp", "an absorbing medium"),
    (lambda d: material(d, 3).update(abbe=-30.0), f"{M3}.abbe", "vd -30: expected 5 <= vd "
     "<= 150"),
    (lambda d: material(d, 3).update(abbe=math.inf), f"{M3}.abbe",
     "expected a finite number, found inf"),
    (lambda d: material(d, 3).update(index=0.5), f"{M3}.index", "nd 0.5: expected 1 <= nd"),
    (lambda d: material(d, 3).update(type="AbbeMaterialE"), f"{M3}.type",
     "an e-line Abbe material (ne, Ve): not representable"),
    (lambda d: material(d, 3).update(type="Material", name="SK16 (ACME)"), f"{M3}.name",
     "glass 'SK16 (ACME)': unknown glass"),
    (lambda d: d["surface_group"]["surfaces"][-1].update(is_stop=True),
     "surface_group.surfaces[6].is_stop", "the stop on the image surface: unsupported"),
    (lambda d: d["surface_group"]["surfaces"][-1].update(type="ThinLens"),
     "surface_group.surfaces[6].type", "expected ImageSurface or Surface (the image), "
     "found \"ThinLens\""),
])  # fmt: skip
def test_optiland_bad_media_one_line_with_the_json_path(edit, path, words, optiland_problems):
    d = copy.deepcopy(MEDIA)
    edit(d)
    problems = optiland_problems(d, "m.json")
    assert len(problems) == 1, problems
    assert problems[0].startswith(f"m.json: {path}: "), problems[0]
    assert words in problems[0], problems[0]


def test_optiland_bad_media_through_the_command_line(tmp_path, capsys):
    d = copy.deepcopy(MEDIA)
    material(d, 1).update(index=0.9)
    material(d, 3).update(abbe=-30.0)
    src, out = tmp_path / "bad.json", tmp_path / "out" / "bad.toml"
    out.parent.mkdir()
    src.write_text(json.dumps(d), encoding="utf-8")
    assert main(["import", str(src), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and err[-1].endswith("nothing written"), err
    assert err[0].startswith(f"lensfit: error: {src}: {M1}.index: ")
    assert err[1].startswith(f"lensfit: error: {src}: {M3}.abbe: ")
    assert not list(out.parent.iterdir())
