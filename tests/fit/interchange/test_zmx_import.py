"""lensfit import of Zemax .zmx files (lensfit.interchange.zemax), on hand-written fixtures
in tests/fit/fixtures/zmx/: one per supported surface type and glass form, a UTF-16 file
in inches, and bad input (each problem one line naming its line number, exit 2, nothing
written).

The expected lenses are written out independently here as TOML tables (radius = 1/CURV,
the medium of a surface behind it, DIAM the semi-diameter) and compared field by field
with what the importer produced; first-order checks use closed forms (the thick-lens
equation) rather than the importer's own numbers.
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import pytest

from lensfit.cli import main
from lensfit.interchange import ImportProblems, parse_zmx, read_zmx
from lensfit.interchange.zemax import decode
from lensfit.paraxial import paraxial, stop_radius_for_f_number
from lensfit.paraxial import table as paraxial_table
from lensfit.paraxial.paraxial import D_LINE_NM
from lensfit.prescription import lens_from_dict, load_lens, make_lens
from lensfit.prescription.lentil import to_toml
from lensfit.sample import default_domain

FIX = Path(__file__).resolve().parents[1] / "fixtures" / "zmx"
ACHROMAT = (FIX / "achromat.zmx").read_text(encoding="utf-8")


def surfaces_equal(a, b) -> None:
    """Two loaded lenses have the same surfaces: shape, geometry, medium, stop."""
    assert len(a.surfaces) == len(b.surfaces)
    for i, (s, t) in enumerate(zip(a.surfaces, b.surfaces, strict=True)):
        assert (s.shape, s.stop) == (t.shape, t.stop), i
        # CURV is printed to 17 significant digits, so 1/CURV gives the radius back to
        # within an ulp or two: 1e-14 relative
        assert s.radius_mm == pytest.approx(t.radius_mm, rel=1e-14), i
        for k in ("thickness_mm", "semi_diameter_mm", "conic"):
            assert getattr(s, k) == getattr(t, k), (i, k)
        assert s.aspheric == pytest.approx(t.aspheric, rel=1e-15), i
        assert s.medium.name == t.medium.name, i
        assert float(s.medium.n(D_LINE_NM)) == float(t.medium.n(D_LINE_NM)), i


def test_achromat_standard_surfaces_catalog_glasses(tmp_path):
    result = read_zmx(FIX / "achromat.zmx")
    lens = lens_from_dict(result.data)
    expected = make_lens([
        {"shape": "plane", "thickness": 2.0, "material": "air", "semi_diameter": 10.0,
         "stop": True},
        {"shape": "sphere", "radius": 62.0, "thickness": 6.0, "material": "N-BK7",
         "semi_diameter": 12.7},
        {"shape": "sphere", "radius": -44.0, "thickness": 2.5, "material": "N-SF5",
         "semi_diameter": 12.7},
        {"shape": "sphere", "radius": -131.0, "thickness": 95.5, "material": "air",
         "semi_diameter": 12.7},
    ])
    surfaces_equal(lens, expected)
    info = result.data["lens"]
    assert info["name"] == "Achromat 100 mm f/5 (lensfit test fixture)"
    assert info["f_number"] == 5.0
    assert info["field_of_view_deg"] == 10.0  # YFLN 0 3 5 on the axis of y: 2 x 5 degrees
    assert "Hand-written for the lensfit import tests" in info["notes"]
    assert "scale" not in info  # UNIT MM
    assert result.data["coating"]["default"] == "none"  # OpticStudio traces uncoated
    # The notes name what was not mapped, with line numbers; pure UI keywords are silent
    notes = "\n".join(result.notes)
    for line, kw in ((18, "WAVM (and 2 more)"), (41, "COMM"), (49, "COAT")):
        assert f"achromat.zmx:{line}: {kw}" in notes
    for kw in ("HIDE", "MIRR", "SLAB", "POPS", "MEMA", "NSCD", "VERS", "PFIL", "RAIM"):
        assert kw not in notes
    # ENPD 20 (before FNUM) is the design's aperture: f/N = EFL / 20 mm at the d line, the
    # aperture `lensfit fit` fits by default; mapped, so not a note
    assert "ENPD" not in notes
    efl = paraxial_table(lens)["efl_mm"]
    assert result.data["fit"]["f_number"] == pytest.approx(efl / 20.0, rel=1e-15)
    assert "achromat.zmx line 7 (ENPD 20 mm" in result.data["fit"]["reason"]
    # ... and written to the TOML (to_toml places the [fit] table), read back the same
    written = tomllib.loads(to_toml(result.data))
    assert written["fit"] == result.data["fit"]
    domain = default_domain(lens_from_dict(written))
    assert domain.stop_radius_mm == pytest.approx(stop_radius_for_f_number(lens, efl / 20.0))


def test_design_aperture_wider_than_the_stop_is_a_note(tmp_path):
    """An ENPD the stop cannot open to is not fitted by default: a note says so."""
    text = (FIX / "achromat.zmx").read_text().replace("ENPD 20", "ENPD 40")
    src = tmp_path / "wide.zmx"
    src.write_text(text)
    result = read_zmx(src)
    assert "fit" not in result.data
    assert any("wide.zmx:7: ENPD: aperture f/" in n and "not mapped" in n
               for n in result.notes), result.notes


def test_even_asphere_conic_and_model_glass():
    lens = lens_from_dict(read_zmx(FIX / "asphere_model.zmx").data)
    front, back = lens.surfaces[1], lens.surfaces[2]
    assert (front.shape, front.radius_mm, front.conic) == ("asphere", 20.0, -0.5)
    assert front.aspheric == (1e-5, -2e-8)  # PARM 2, 3 -> A4, A6; trailing zeros dropped
    # a STANDARD surface with a conic is an asphere without polynomial terms
    assert (back.shape, back.radius_mm, back.conic, back.aspheric) == ("asphere", -80.0,
                                                                        -1.2, ())
    assert front.material_spec == {"nd": 1.58913, "vd": 61.27}
    # First order: the thick-lens equation (the conic and A4.. have no paraxial effect)
    # with the model glass's index at the paraxial wavelength, which is nd to 1e-6 (the
    # model passes through nd at 587.56 nm; paraxial uses 587.5618 nm); rounding only,
    # so 1e-12 relative
    n = float(front.medium.n(D_LINE_NM))
    assert n == pytest.approx(1.58913, abs=1e-6)
    r1, r2, d = 20.0, -80.0, 5.0
    power = (n - 1) * (1 / r1 - 1 / r2 + (n - 1) * d / (n * r1 * r2))
    assert paraxial(lens).efl_mm == pytest.approx(1 / power, rel=1e-12)


def test_toroidal_cylinders_and_sphere():
    result = read_zmx(FIX / "cylinders.zmx")
    lens = lens_from_dict(result.data)
    shapes = [(s.shape, s.radius_mm) for s in lens.surfaces]
    assert shapes == [("plane", math.inf), ("cylinder-x", 50.0), ("plane", math.inf),
                      ("cylinder-y", 60.0), ("sphere", -40.0)]
    # cylinder-x has power in y only: the y-z meridian of this lens is the same as a
    # lens with that cylinder made a sphere and the cylinder-y a plane (and vice versa)
    def variant(keep: str) -> list[dict]:
        rows = []
        for row in result.data["surface"]:
            r = dict(row)
            if r["shape"] == keep:
                r["shape"] = "sphere"
            elif r["shape"].startswith("cylinder"):
                r["shape"] = "plane"
                r.pop("radius")
            rows.append(r)
        return rows
    px = paraxial(lens, meridian="x").efl_mm
    py = paraxial(lens, meridian="y").efl_mm
    assert py == pytest.approx(paraxial(make_lens(variant("cylinder-x"))).efl_mm, rel=1e-12)
    assert px == pytest.approx(paraxial(make_lens(variant("cylinder-y"))).efl_mm, rel=1e-12)
    assert px != pytest.approx(py, rel=1e-3)


def test_utf16_file_in_inches_is_scaled_exactly():
    raw = (FIX / "singlet_inch_utf16.zmx").read_bytes()
    assert raw[:2] == b"\xff\xfe"  # the fixture really is UTF-16 LE with a BOM
    result = read_zmx(FIX / "singlet_inch_utf16.zmx")
    info = result.data["lens"]
    assert info["scale"] == 25.4  # written as in the file, converted by the loader
    lens = lens_from_dict(result.data)
    # radii 2 in and -2 in, 0.2 in thick, 1.9 in to the image, in mm
    assert [s.radius_mm for s in lens.surfaces[1:]] == [2.0 * 25.4, -2.0 * 25.4]
    assert lens.surfaces[2].thickness_mm == 1.9 * 25.4
    # A6 in 1/in^3 -> 1/mm^3: divided by 25.4^3 (the loader's scale rule)
    assert lens.surfaces[2].aspheric == pytest.approx((0.01 / 25.4**3,), rel=1e-15)
    # XFLN/YFLN (10, 10) degrees: the chief ray's angle from the axis is
    # atan(sqrt(tan^2 10 + tan^2 10)) = 14.0019 degrees, the full field twice that
    t = math.tan(math.radians(10.0))
    assert info["field_of_view_deg"] == pytest.approx(
        2 * math.degrees(math.atan(math.sqrt(2) * t)), rel=1e-14)
    # The same bytes decoded as UTF-8 text give the same lens
    text = raw[2:].decode("utf-16-le")
    assert parse_zmx(text, label="x.zmx", lens_id="singlet_inch_utf16").data["surface"] == \
        result.data["surface"]


def test_decode_forms():
    text = "MODE SEQ\nUNIT MM\n"
    for raw in (text.encode("utf-16"), b"\xef\xbb\xbf" + text.encode(), text.encode(),
                text.encode("utf-16-le")):
        assert decode(raw) == text
    assert decode(b"NAME Objektiv \xe9\n") == "NAME Objektiv \xe9\n"  # Latin-1 fallback


def test_stop_on_a_refracting_surface(tmp_path):
    # The stop is written where the .zmx puts it: on the singlet's front surface (which
    # lensfit's loader takes since 2444334, and clips on that surface as OpticStudio does)
    result = read_zmx(FIX / "stop_on_lens.zmx")
    surf = result.data["surface"]
    assert surf[0]["stop"] is True and surf[0]["material"] == "N-BK7"
    lens = load_lens(_write(tmp_path, result))
    assert lens.stop_file_index == 0
    # Exported, the stop is again on that surface (not the loader's stop copy), and
    # importing the export gives the same lens, inserted stop surface included
    from lensfit.interchange import write_zmx

    text, _ = write_zmx(lens)
    assert text.count("SURF ") == 4 and "SURF 1\n  STOP\n  TYPE STANDARD\n  CURV 0.02" in text
    back = lens_from_dict(parse_zmx(text, label="b.zmx").data)
    assert [(s.shape, s.radius_mm, s.thickness_mm, s.stop, s.inserted)
            for s in back.surfaces] == [(s.shape, s.radius_mm, s.thickness_mm, s.stop,
                                         s.inserted) for s in lens.surfaces]


def test_export_of_a_stop_on_the_last_surface():
    # A stop on the back of the last lens: the loader inserts the plane behind it, with
    # the gap to the sensor; the export folds it back (STOP and DISZ on that surface)
    from lensfit.interchange import write_zmx

    lens = make_lens([
        {"shape": "sphere", "radius": 50.0, "thickness": 5.0, "material": "N-BK7",
         "semi_diameter": 10.0},
        {"shape": "sphere", "radius": -50.0, "thickness": 47.5, "material": "air",
         "semi_diameter": 10.0, "stop": True},
    ])
    assert [s.inserted for s in lens.surfaces] == ["", "", "back"]
    text, _ = write_zmx(lens)
    assert "SURF 2\n  STOP\n" in text and "  DISZ 47.5\n" in text and "SURF 4" not in text
    back = lens_from_dict(parse_zmx(text, label="b.zmx").data)
    assert [(s.radius_mm, s.thickness_mm, s.stop, s.inserted) for s in back.surfaces] == \
        [(s.radius_mm, s.thickness_mm, s.stop, s.inserted) for s in lens.surfaces]


def _write(tmp_path: Path, result) -> Path:
    from lensfit.prescription.lentil import to_toml

    p = tmp_path / "lens.toml"
    p.write_text(to_toml(result.data), encoding="utf-8")
    return p


# --- the command line ---------------------------------------------------------------------

def test_cli_import_writes_toml_and_notes(tmp_path, capsys):
    out = tmp_path / "achromat.toml"
    assert main(["import", str(FIX / "achromat.zmx"), "-o", str(out)]) == 0
    cap = capsys.readouterr()
    # One line per surface on what its semi-diameter is (every one an aperture here: a
    # fixed DIAM, or FLAP; no design beam to trace), then the file written
    src = FIX / "achromat.zmx"
    assert cap.out.strip().splitlines() == [
        f"{src}:33: SURF 1: the stop (DIAM solve 1: fixed): aperture 10 mm kept",
        f"{src}:40: SURF 2: fixed aperture (DIAM solve 1: fixed): 12.7 mm kept",
        f"{src}:53: SURF 3: fixed aperture (DIAM solve 1: fixed): 12.7 mm kept",
        f"{src}:59: SURF 4: fixed aperture (FLAP: a circular aperture): 12.7 mm kept",
        f"wrote {out}"]
    assert all(line.startswith("lensfit: note: ") for line in cap.err.splitlines())
    lens = load_lens(out)
    assert lens.provenance["id"] == "achromat"
    assert [p.name for p in tmp_path.iterdir()] == ["achromat.toml"]  # no temporary left


def test_cli_import_into_a_folder_with_an_id(tmp_path, capsys):
    assert main(["import", str(FIX / "cylinders.zmx"), "-o", str(tmp_path), "--id",
                 "9100"]) == 0
    assert load_lens(tmp_path / "cylinders.toml").provenance["id"] == "9100"


def problems_of(capsys, argv: list[str], out: Path) -> list[str]:
    """Exit 2, nothing written, and the problem lines (the summary line dropped)."""
    assert main(argv) == 2
    assert not out.exists()
    assert not list(out.parent.iterdir())
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith("nothing written")
    return err[:-1]


def test_every_problem_listed_with_its_line(tmp_path, capsys):
    out = tmp_path / "bad.toml"
    lines = problems_of(capsys, ["import", str(FIX / "bad_many.zmx"), "-o", str(out)], out)
    expected = [
        (5, "NSOB: non-sequential object"),
        (17, "SURF 2 TYPE COORDBRK: unsupported surface type"),
        (24, "SURF 3 GLAS NOSUCHGLASS (GCAT SCHOTT): unknown glass"),
        (28, "SURF 4 CURV: expected a number, found '0.0x1'"),
        (30, "SURF 4 GLAS MIRROR: a mirror: unsupported"),
        (35, "SURF 5 EVENASPH PARM 1: an r^2 coefficient"),
        (38, "SURF 5 SQAP: rectangular aperture: unsupported"),
    ]
    assert len(lines) == len(expected), lines
    for line, (n, words) in zip(lines, expected, strict=True):
        assert line.startswith(f"lensfit: error: {FIX / 'bad_many.zmx'}:{n}: {words}"), line


def _line_of(text: str, pattern: str) -> int:
    for i, line in enumerate(text.splitlines(), start=1):
        if re.search(pattern, line):
            return i
    raise AssertionError(pattern)


@pytest.mark.parametrize(("old", "new", "words"), [
    ("  TYPE STANDARD\n  CURV 1.6129", "  TYPE COORDBRK\n  CURV 1.6129",
     "SURF 2 TYPE COORDBRK: unsupported surface type"),
    ("GLAS N-BK7 1 0", "GLAS N-BK77 1 0",
     "SURF 2 GLAS N-BK77 (GCAT SCHOTT): unknown glass 'N-BK77'"),
    ("GLAS N-SF5 0 0", "GLAS MIRROR 0 0", "SURF 3 GLAS MIRROR: a mirror"),
    ("MODE SEQ", "MODE NSC", "MODE NSC: non-sequential data"),
    ("DISZ 95.5", "DISZ 95.5.1", "SURF 4 DISZ: expected a number, found '95.5.1'"),
    ("DISZ 95.5", "DISZ nan", "SURF 4 DISZ: expected a finite number"),
    ("DISZ 6\n", "DISZ\n", "SURF 2 DISZ: missing value 1"),
    ("SURF 3\n", "SURF 7\n", "SURF 7: expected SURF 3"),
    ("SURF 3\n", "SURF three\n", "SURF: expected a number, found 'three'"),
    ("UNIT MM", "UNIT FURLONG", "UNIT FURLONG: unsupported lens unit"),
    ("  COAT THORC\n", "  COAT THORC\n  SCBD 1 0 0 0 0 90 0 0\n",
     "SURF 2 SCBD: surface tilt or decenter"),
    ("  MEMA 12.7 0 0 0 1 \"\"", "  ZZZZ 1",
     "SURF 2 ZZZZ: unknown surface keyword: it may change the optics"),
    ("  FLAP 0 12.7 0", "  CLAP 2 12.7 0", "SURF 4 CLAP: an annular aperture"),
    ("  COAT THORC\n", "  COAT THORC\n  XDAT 1 5 0 0\n",
     "SURF 2 STANDARD XDAT 1: extra data on a STANDARD surface"),
    ("  COAT THORC\n", "  COAT THORC\n  PARM 3 0.5\n",
     "SURF 2 STANDARD PARM 3: a parameter on a STANDARD surface"),
    ("  CURV -7.6335877862595417E-3 0 0 0 0 \"\"\n",
     "  CURV -7.6335877862595417E-3 0 0 0 0 \"\"\n  CURV 0\n", "SURF 4 CURV: given twice"),
])
def test_one_problem_one_line(tmp_path, capsys, old, new, words):
    assert ACHROMAT.count(old) == 1, old
    text = ACHROMAT.replace(old, new)
    src = tmp_path / "in" / "lens.zmx"
    src.parent.mkdir()
    src.write_text(text, encoding="utf-8")
    # the line named is the first one that differs from the fixture
    n = next(i for i, (a, b) in enumerate(zip(ACHROMAT.splitlines(), text.splitlines(),
                                              strict=False), start=1) if a != b)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    lines = problems_of(capsys, ["import", str(src), "-o", str(out_dir / "lens.toml")],
                        out_dir / "lens.toml")
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"lensfit: error: {src}:{n}: {words}"), lines[0]


def test_truncated_file(tmp_path, capsys):
    text = ACHROMAT.split("SURF 4\n")[0] + "SURF 4\n"  # ends at the SURF line
    src = tmp_path / "in.zmx"
    src.write_text(text, encoding="utf-8")
    with pytest.raises(ImportProblems) as e:
        read_zmx(src)
    n = text.count("\n")
    assert any(p.startswith(f"{src}:{n}: SURF 4: no DISZ line (a truncated file?)")
               for p in e.value.problems), e.value.problems


def test_loader_refusal_names_the_surface_line(tmp_path):
    # DIAM larger than |radius|: the loader refuses it; the importer names the SURF line
    text = ACHROMAT.replace("  DIAM 12.7 1 0 0 1 \"\"\n  MEMA", "  DIAM 70 1 0 0 1 \"\"\n  MEMA")
    with pytest.raises(ImportProblems) as e:
        parse_zmx(text, label="a.zmx")
    n = _line_of(ACHROMAT, r"^SURF 2$")
    assert e.value.problems == [e.value.problems[0]]
    assert e.value.problems[0].startswith(f"a.zmx:{n}: SURF 2: key 'semi_diameter': ")


def test_loader_refusal_names_the_files_surfaces():
    # SURF 2 only 0.5 mm thick: its face (radius 62) and SURF 3's (radius -44) cross
    # within their 12.7 mm clear radius. The loader counts lensfit's surfaces from 0
    # ("surfaces 1 and 2"); the line names them by the file's SURF numbers
    text = ACHROMAT.replace("  DISZ 6\n", "  DISZ 0.5\n")
    assert text != ACHROMAT
    with pytest.raises(ImportProblems) as e:
        parse_zmx(text, label="a.zmx")
    n = _line_of(ACHROMAT, r"^SURF 2$")
    assert len(e.value.problems) == 1, e.value.problems
    line = e.value.problems[0]
    assert line.startswith(f"a.zmx:{n}: SURF 2: key 'thickness': SURF 2 and SURF 3 cross "
                           "inside their clear aperture (gap "), line
    assert "surfaces 1 and 2" not in line


def test_file_surface_names_in_loader_messages():
    from lensfit.interchange.common import file_surface_names

    names = ["SURF 1", "SURF 2", "SURF 3"]
    assert file_surface_names("surfaces 1 and 2 cross", names) == "SURF 2 and SURF 3 cross"
    assert file_surface_names("more than one aperture stop (surfaces [0, 2]); mark one",
                              names) == "more than one aperture stop (SURF 1, SURF 3); mark one"
    assert file_surface_names("the glass of surface 0", names) == "the glass of SURF 1"
    # an index the file has no name for is left as it is
    assert file_surface_names("surfaces 2 and 3 cross", names) == "surfaces 2 and 3 cross"


def test_marginal_ray_height_solve_is_a_note_and_vcon_is_ignored():
    # MAZH h z: OpticStudio's "Marginal Ray Height" thickness solve (height h at pupil
    # zone z); DISZ holds the thickness it solved to, which is used. VCON (no values):
    # the optimiser's variable flag on the conic, ignored as VDSZ is
    text = ACHROMAT.replace("  DISZ 95.5\n", "  DISZ 95.5\n  MAZH 0 7.0E-1\n").replace(
        "  MEMA 12.7 0 0 0 1 \"\"\n", "  MEMA 12.7 0 0 0 1 \"\"\n  VCON\n")
    assert text.count("MAZH") == 1 and text.count("VCON") == 1
    result = parse_zmx(text, label="a.zmx")
    plain = parse_zmx(ACHROMAT, label="a.zmx")
    assert result.data["surface"] == plain.data["surface"]
    assert result.data["surface"][3]["thickness"] == 95.5
    n = _line_of(text, r"^  MAZH ")
    notes = "\n".join(result.notes)
    assert (f"a.zmx:{n}: MAZH: thickness solve on the marginal ray height not mapped (the "
            "thickness it solved to, DISZ, is used)") in notes
    assert "VCON" not in notes


def test_docstring_lists_the_ignored_keywords():
    # The ignore-list is documented in the module docstring, word for word
    from lensfit.interchange import zemax

    doc = set(zemax.__doc__.replace("(", " ").replace(")", " ").split())
    assert zemax.IGNORED_TOP <= doc and zemax.IGNORED_SURFACE <= doc
    assert "NSOB" not in zemax.IGNORED_TOP


def test_missing_semi_diameter_estimated_from_the_aperture():
    # No DIAM on SURF 3: the paraxial estimate from the aperture (ENPD 20 mm, which is
    # used before FNUM) and the 5 degree field, with a note naming the SURF line
    glas = "  GLAS N-SF5 0 0 1.50E+00 4.00E+01 0 0 0 0 0 0"
    text = ACHROMAT.replace(glas + '\n  DIAM 12.7 1 0 0 1 ""', glas)
    assert text != ACHROMAT
    result = parse_zmx(text, label="a.zmx")
    n = _line_of(text, r"^SURF 3$")
    note = next(note for note in result.notes
                if note.startswith(f"a.zmx:{n}: SURF 3 DIAM: no semi-diameter in the file: "))
    estimate = float(note.split("file: ")[1].split()[0])
    assert "from the paraxial marginal and chief rays" in note
    # the marginal ray of a 20 mm pupil is at about 10 mm there, the 5 degree chief ray
    # adds about 0.5 mm (the stop is 8.5 mm in front): between 10 and 11.5 mm
    assert 10.0 < estimate < 11.5
    # The estimate is automatic, not an aperture: widened where real rays pass it (issue
    # 36; tests/fit/interchange/test_housings.py checks the rule)
    row = result.data["surface"][2]
    assert row["aperture"] == "automatic" and "design_semi_diameter" not in row
    assert row["semi_diameter"] >= estimate
    # Without any aperture setting there is nothing to estimate from: an error
    bare = "\n".join(line for line in text.splitlines()
                     if not line.startswith(("ENPD", "FNUM")))
    with pytest.raises(ImportProblems) as e:
        parse_zmx(bare, label="a.zmx")
    n = _line_of(bare, r"^SURF 3$")
    assert e.value.problems == [f"a.zmx: no semi-diameter on {n}: SURF 3, and the system "
                                "aperture (none) does not give the paraxial marginal ray to "
                                "estimate them"]


CYL = (FIX / "cylinders.zmx").read_text(encoding="utf-8")


@pytest.mark.parametrize(("old", "new", "words"), [
    ("  PARM 2 0\n", "  PARM 2 1e-4\n", "SURF 2 TOROIDAL PARM 2: a polynomial term"),
    ("  XDAT 1 0.000000000000E+000", "  XDAT 1 3.000000000000E+000",
     "SURF 2 TOROIDAL XDAT 1: 3 Zernike terms: not representable"),
    ("  PARM 1 -40\n", "  PARM 1 -45\n",
     "SURF 5 TOROIDAL: a toroid with radius -40 in y and -45 in x: not representable"),
    ("  CURV 0.02\n", "  CURV 0.02\n  CONI -1\n", "SURF 2 TOROIDAL CONI: a conic y curve"),
])
def test_toroids_that_are_not_cylinders(old, new, words):
    assert CYL.count(old) == 1, old
    text = CYL.replace(old, new)
    n = next(i for i, (a, b) in enumerate(zip(CYL.splitlines(), text.splitlines(),
                                              strict=False), start=1) if a != b)
    with pytest.raises(ImportProblems) as e:
        parse_zmx(text, label="c.zmx")
    assert len(e.value.problems) == 1, e.value.problems
    where = n if "toroid with" not in words else _line_of(text, r"CURV -0.025")
    assert e.value.problems[0].startswith(f"c.zmx:{where}: {words}"), e.value.problems[0]


def test_older_field_keywords_and_unknown_file_kind(tmp_path, capsys):
    # XFLD/YFLD (older files) hold the same fields as XFLN/YFLN
    text = ACHROMAT.replace("XFLN 0 0 0 0 0 0 0 0 0 0 0 0", "XFLD 0 0 0").replace(
        "YFLN 0 3 5 0 0 0 0 0 0 0 0 0", "YFLD 0 3 5")
    assert parse_zmx(text, label="a.zmx").data["lens"]["field_of_view_deg"] == 10.0
    # A file of another program: one line, exit 2, nothing written
    src = tmp_path / "lens.seq"
    src.write_text("RDM\n", encoding="utf-8")
    assert main(["import", str(src), "-o", str(tmp_path / "x.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"lensfit: error: {src}: expected a Zemax .zmx file or a .json file "
                   "(Optiland or lentil)"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lens.seq"]


def test_glass_outside_the_gcat_catalogs_is_a_note():
    # OpticStudio looks a name up in the GCAT catalogs only; lensfit also finds N-BK7
    # when GCAT names OHARA alone, and says so
    text = ACHROMAT.replace("GCAT SCHOTT", "GCAT OHARA")
    result = parse_zmx(text, label="a.zmx")
    assert result.data["surface"][1]["material"] == "N-BK7"
    n = _line_of(text, r"GLAS N-BK7")
    assert f"a.zmx:{n}: SURF 2 GLAS: glass N-BK7 is not in the file's catalogs (OHARA): " \
           "found as N-BK7" in result.notes
    # A dated catalog name qualifies by its maker (SUMITA_AUG2011 is SUMITA)
    from lensfit.interchange.common import MANUFACTURERS, resolve_glass

    if "SUMITA" not in MANUFACTURERS:
        pytest.skip("no manufacturer catalogs in this lensfit.glass")
    assert resolve_glass("K-LaF3", ["SCHOTT", "SUMITA_AUG2011"]) == \
        ({"material": "SUMITA:K-LaF3"}, None)
