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

from lensfit import cli, stage
from lensfit.cli import main

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
