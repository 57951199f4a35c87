"""lensfit refuses bad input with one line and exit status 2, before any work, never with a
traceback (issue 14, defects 3, 5 and 6).

Each case runs the command line in process (a traceback would be an exception out of
``main`` and fail the test) or, where the old code blocked (a FIFO), in a child with a
timeout. Commands whose work is long (a fit) run with ``stage.run`` replaced by a stub
that fails the test: the error must come before the work.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lensfit.cli import lens as cli
from lensfit.cli import main
from lensfit.pipeline import stage

ROOT = Path(__file__).resolve().parents[2]
LENS = (ROOT / "lensdb" / "0001-angenieux-double-gauss.toml").read_text(encoding="utf-8")
HUGE = "1" + "0" * 400  # an integer TOML accepts and no float holds
SCENE = """name = "t"
wavelengths_nm = [550.0]
[[light]]
field_x_deg = 0.0
field_y_deg = 2.0
distance_mm = 5000.0
"""


def refused(capsys, argv: list[str], *words: str) -> str:
    """Exit 2 and exactly one line on stderr containing every word."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for w in words:
        assert w in err[0], (w, err[0])
    return err[0]


@pytest.fixture
def no_work(monkeypatch):
    def fail(*_a, **_k):
        raise AssertionError("the fit started before the bad input was found")
    monkeypatch.setattr(stage, "run", fail)


# Lens prescriptions

@pytest.mark.parametrize("old,new,words", [
    ("thickness = 10.99", f"thickness = {HUGE}", ("surface 0", "thickness", "float")),
    ("year = 1953", "year = inf", ("year", "finite")),
    ("year = 1953", f"year = {HUGE}", ("year", "float")),
    ("schema_version = 1", "schema_version = 1\nx = " + "[" * 3000 + "]" * 3000, ("nested",)),
    ("[coating]", "[fit]\nf_numbr = 2.0\n\n[coating]", ("f_numbr", "unknown key")),
    ("semi_diameter = 54.0", "semi_diameter = 54.0\nsemi_diamter = 1.0", ("semi_diamter",)),
])
def test_bad_lens_toml(capsys, tmp_path, old, new, words):
    path = tmp_path / "lens.toml"
    path.write_text(LENS.replace(old, new, 1), encoding="utf-8")
    refused(capsys, ["info", str(path)], str(path), *words)


def test_lens_fifo_and_folder_are_refused(tmp_path):
    # The old code blocked forever reading a FIFO: a child with a timeout
    fifo, folder = tmp_path / "fifo.toml", tmp_path / "folder.toml"
    os.mkfifo(fifo)
    folder.mkdir()
    for path in (fifo, folder):
        r = subprocess.run([sys.executable, "-m", "lensfit.cli", "info", str(path)],
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 2, r.stderr
        assert r.stderr.strip().count("\n") == 0 and "not a regular file" in r.stderr


# Scenes (lensfit scene reads generated/0001's fit.json first)

@pytest.mark.parametrize("old,new,words", [
    ("distance_mm", "distanc_mm", ("light[0].distanc_mm", "unknown key")),
    ("field_x_deg = 0.0", f"field_x_deg = {HUGE}", ("light.0.field_x_deg", "float")),
    ("distance_mm = 5000.0", f"distance_mm = {HUGE}", ("distance_mm", "float")),
    ("[550.0]", f"[{HUGE}]", ("wavelengths_nm", "float")),
    ("[550.0]", "[inf]", ("wavelengths_nm", "finite")),
    ('name = "t"', f'name = "t"\nfocus_offset_mm = {HUGE}', ("focus_offset_mm",)),
    ('name = "t"', 'name = "t"\nx = ' + "[" * 3000 + "]" * 3000, ("nested",)),
])
def test_bad_scene_toml(capsys, tmp_path, old, new, words):
    path = tmp_path / "scene.toml"
    path.write_text(SCENE.replace(old, new, 1), encoding="utf-8")
    out = tmp_path / "out"
    refused(capsys, ["scene", "0001", str(path), "-o", str(out), "--no-timing"], str(path),
            *words)
    assert not out.exists()


def test_scene_fifo_is_refused(tmp_path):
    fifo = tmp_path / "scene.toml"
    os.mkfifo(fifo)
    r = subprocess.run([sys.executable, "-m", "lensfit.cli", "scene", "0001", str(fifo), "-o",
                        str(tmp_path / "out")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "not a regular file" in r.stderr, r.stderr


# Outputs, checked before the work

def test_scene_output_that_is_a_file(capsys, tmp_path):
    scene, out = tmp_path / "scene.toml", tmp_path / "out"
    scene.write_text(SCENE, encoding="utf-8")
    out.write_text("keep\n")
    refused(capsys, ["scene", "0001", str(scene), "-o", str(out)], "-o", str(out))
    refused(capsys, ["scene", "0001", str(scene), "-o", str(out / "sub")], "-o", "is a file")
    assert out.read_text() == "keep\n"


def test_draw_outputs(capsys, tmp_path):
    folder = tmp_path / "d.png"
    folder.mkdir()
    refused(capsys, ["draw", "0001", "-o", str(folder)], "-o", "folder")
    refused(capsys, ["draw", "0001", "-o", str(tmp_path / "missing" / "x.png")], "-o",
            "does not exist")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.png"]


@pytest.mark.parametrize("rays", ["100000000", "1001", "1"])
def test_draw_rays_are_limited(capsys, tmp_path, rays):
    out = tmp_path / "x.png"
    refused(capsys, ["draw", "0001", "-o", str(out), "--rays", rays], "--rays", rays)
    assert not out.exists()


def test_import_output_that_is_a_file(capsys, tmp_path):
    src, out = tmp_path / "l.json", tmp_path / "out"
    src.write_text("{}")
    out.write_text("keep\n")
    refused(capsys, ["import", str(src), "-o", str(out)], "-o", str(out))
    assert out.read_text() == "keep\n"


def test_report_output_that_is_a_file(capsys, tmp_path, no_work):
    out = tmp_path / "out"
    out.write_text("keep\n")
    refused(capsys, ["report", "0001", "--quick", "-o", str(out)], "-o", str(out))


@pytest.mark.parametrize("option", ["--generated", "--report"])
def test_fit_folders_checked_before_the_fit(capsys, tmp_path, no_work, option):
    out = tmp_path / "file"
    out.write_text("keep\n")
    refused(capsys, ["fit", "0001", "--quick", option, str(out)], option, str(out))
    assert out.read_text() == "keep\n"


# lentil JSON entries of the wrong type

ELEMENT = {"radius": 50.0, "thickness": 5.0, "material": "air", "housing-radius": 10.0}


@pytest.mark.parametrize("entry,words", [
    ([], ("entry 0001", "object")),
    ({"optical-elements-patent": [1, 2]}, ("element objects",)),
    ({"optical-elements-patent": "abc"}, ("element objects",)),
    ({"optical-elements-patent": [dict(ELEMENT, radius="abc")]}, ("radius", "'abc'")),
    ({"optical-elements-patent": [dict(ELEMENT, thickness=[[1]])]}, ("thickness",)),
    ({"optical-elements-patent": [ELEMENT], "year": "abc"}, ("year", "'abc'")),
])
def test_lentil_entries_of_the_wrong_type(capsys, tmp_path, entry, words):
    src, out = tmp_path / "l.json", tmp_path / "out"
    src.write_text(json.dumps({"0001": entry}))
    refused(capsys, ["import", str(src), "-o", str(out)], str(src), *words)
    assert not out.exists() or not any(out.iterdir())


# Only the project's own errors are bad input

def test_a_bug_is_not_reported_as_bad_input(monkeypatch):
    def buggy(_args):
        raise ValueError("operands could not be broadcast together")
    monkeypatch.setattr(cli, "cmd_info", buggy)
    with pytest.raises(ValueError, match="broadcast"):
        main(["info", "0001"])


@pytest.mark.parametrize("argv,words", [
    (["report", "0001", "--psf-target", "-1"], ("psf_target",)),
    (["report", "0001", "--wavelengths", "700,400"], ("--wavelengths",)),
    (["report", "0001", "--field", "95"], ("field",)),
    (["report", "0001", "--f-number", "0.1"], ("f/0.1",)),
])
def test_bad_options_are_still_bad_input(capsys, no_work, argv, words):
    refused(capsys, argv, *words)


def test_a_closed_pipe_ends_quietly():
    """`lensfit info 0001 | head -1`: the reader goes away before lensfit writes; lensfit
    stops with 141 (128 + SIGPIPE) and no traceback on stderr."""
    import subprocess
    import sys as _sys

    p = subprocess.Popen([_sys.executable, "-m", "lensfit.cli", "info", "0001"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()  # long before the interpreter has imported lensfit
    _, err = p.communicate(timeout=120)
    assert (p.returncode, err.decode()) == (141, "")


# Issue 25: the last tracebacks, each one line with exit 2 naming the key or path

OPTILAND = (ROOT / "tests" / "fit" / "fixtures" / "optiland" / "cooke_triplet.json"
            ).read_text(encoding="utf-8")
LENTIL = json.dumps({"0001": {"optical-elements-patent": [
    {"radius": 50.0, "thickness": 5.0, "material": "BK7", "ior": 1.5168, "abbe": 64.17,
     "housing-radius": 10.0},
    {"radius": -50.0, "thickness": 5.0, "material": "air", "housing-radius": 10.0},
    {"radius": 0, "thickness": 5.0, "material": "iris", "housing-radius": 8.0},
    {"radius": 1e5, "thickness": 40.0, "material": "air", "housing-radius": 10.0}]}})
BIG = "1" + "0" * 400


def _import_refused(capsys, tmp_path: Path, name: str, raw: bytes) -> list[str]:
    """lensfit import exits 2, the output (a .toml or a folder) is not created."""
    src, out = tmp_path / name, tmp_path / "x.toml"
    src.write_bytes(raw)
    assert main(["import", str(src), "-o", str(out)]) == 2
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == [name]
    return capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize("old,new,line", [
    ('"radius": 22.01359', f'"radius": {BIG}',
     "o.json:103: key 'radius': number 100000000000...000000: an integer of 401 digits, "
     "beyond a float's range"),
    ('"radius": 22.01359', '"radius": ' + "1" * 5001,
     "o.json:103: key 'radius': number 111111111111...111111: an integer of 5001 digits, "
     "beyond a float's range"),
    ('"radius": 22.01359', '"radius": 1e400',
     "o.json:103: key 'radius': number 1e400: beyond a float's range"),
    ('"value": 10.0', f'"value": {BIG}',
     "o.json:6: key 'value': number 100000000000...000000: an integer of 401 digits, "
     "beyond a float's range"),
    ('"pickups": []', '"pickups": ' + "[" * 5000 + "]" * 5000,
     "o.json:58: malformed JSON: nested deeper than 64 arrays and objects"),
])
def test_optiland_bad_json(capsys, tmp_path, old, new, line):
    err = _import_refused(capsys, tmp_path, "o.json", OPTILAND.replace(old, new, 1).encode())
    assert err == [f"lensfit: error: {tmp_path}/{line}",
                   "lensfit: error: 1 problem(s); nothing written"]


def test_optiland_encodings(capsys, tmp_path):
    # UTF-16 with its byte-order mark is read (as the .zmx importer reads OpticStudio's)
    ok = tmp_path / "ok"
    ok.mkdir()
    src, out = ok / "u.json", ok / "u.toml"
    src.write_bytes(OPTILAND.encode("utf-16"))
    assert main(["import", str(src), "-o", str(out)]) == 0
    assert out.read_text(encoding="utf-8").startswith("# Lens prescription")
    capsys.readouterr()
    bad = tmp_path / "bad"
    bad.mkdir()
    err = _import_refused(capsys, bad, "l.json",
                          OPTILAND.replace("Cooke", "Cook\u00e9").encode("latin-1"))
    assert err[0] == (f"lensfit: error: {bad}/l.json: cannot read: not UTF-8 text (byte "
                      "0xe9 at offset 39); save it as UTF-8")


def test_optiland_surface_group_list_writes_nothing(capsys, tmp_path):
    doc = json.loads(OPTILAND)
    doc["surface_group"] = [doc["surface_group"]]
    err = _import_refused(capsys, tmp_path, "g.json", json.dumps(doc).encode())
    assert err == [f"lensfit: error: {tmp_path}/g.json: surface_group: expected an object "
                   "(Optiland's surface group), found list",
                   "lensfit: error: 1 problem(s); nothing written"]


@pytest.mark.parametrize("old,new,line", [
    ('"radius": 50.0', f'"radius": {BIG}',
     "l.json: line 1: key 'radius': number 100000000000...000000: an integer of 401 digits, "
     "beyond a float's range"),
    ('"ior": 1.5168', '"ior": "1.5"',
     "l.json: surface 0: key 'ior': entry 0001: expected a finite number, found '1.5'"),
    ('"thickness": 5.0', '"thickness": ' + "[" * 5000 + "]" * 5000,
     "l.json: line 1: malformed JSON: nested deeper than 64 arrays and objects"),
])
def test_lentil_bad_json(capsys, tmp_path, old, new, line):
    err = _import_refused(capsys, tmp_path, "l.json", LENTIL.replace(old, new, 1).encode())
    assert err == [f"lensfit: error: {tmp_path}/{line}"]


@pytest.mark.parametrize("name,shown", [
    ("sc\u00e9ne", "'sc\u00e9ne'"),
    ("a" * 300, "'" + "a" * 40 + "... (300 characters)'"),
    ("9lives", "'9lives'"),
])
def test_scene_names_become_symbols(capsys, tmp_path, name, shown):
    path, out = tmp_path / "scene.toml", tmp_path / "out"
    path.write_text(SCENE.replace('"t"', json.dumps(name, ensure_ascii=False)),
                    encoding="utf-8")
    line = refused(capsys, ["scene", "0001", str(path), "-o", str(out), "--no-timing"])
    assert line == (f"lensfit: error: {path}: key 'name': expected a name of 1 to 64 ASCII "
                    "letters, digits, '_' or '-', starting with a letter (it names a folder "
                    f"and C symbols), found {shown}")
    assert not out.exists()


@pytest.mark.parametrize("old,new,key", [
    ("distance_mm = 5000.0", "distance_mm = true", "light[0].distance_mm"),
    ("field_y_deg = 2.0", "field_y_deg = true", "light[0].field_y_deg"),
])
def test_scene_booleans_are_not_numbers(capsys, tmp_path, old, new, key):
    path, out = tmp_path / "scene.toml", tmp_path / "out"
    path.write_text(SCENE.replace(old, new), encoding="utf-8")
    line = refused(capsys, ["scene", "0001", str(path), "-o", str(out), "--no-timing"])
    what = 'a number or "inf"' if key.endswith("distance_mm") else "a number"
    assert line == f"lensfit: error: {path}: key '{key}': expected {what}, found true"


@pytest.mark.parametrize("old,new,line", [
    ("thickness = 10.99", "thickness = true",
     "surface 0: key 'thickness': expected number, found true"),
    ("focal_length_mm = 100.0", "focal_length_mm = false",
     "key 'lens.focal_length_mm': expected number, found false"),
    ('id = "0001"', 'id = "' + "a" * 300 + '"',
     "key 'lens.id': expected 1 to 64 ASCII letters, digits or '_' (the id names generated "
     "files and C symbols), found 300 characters"),
    ('shape = "sphere"\nradius = 164.13', 'shape = "asphere"\nradius = 164.13\nconic = 0.0\n'
     "aspheric = [" + ", ".join(["1e-12"] * 200) + "]",
     "surface 0: key 'aspheric': aspheric[79] (A162) = 1e-12 scaled by lens.scale = 0.01 "
     "(times scale^-161) is beyond a float's range"),
])
def test_lens_booleans_ids_and_scaled_aspheres(capsys, tmp_path, old, new, line):
    path = tmp_path / "lens.toml"
    text = LENS.replace(old, new, 1)
    if "aspheric" in new:
        text = text.replace("focal_length_mm = 100.0", "focal_length_mm = 100.0\nscale = 0.01")
    path.write_text(text, encoding="utf-8")
    assert refused(capsys, ["info", str(path)]) == f"lensfit: error: {path}: {line}"
