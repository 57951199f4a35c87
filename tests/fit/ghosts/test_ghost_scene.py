"""A scene's flares (issue 13, part 3): which fitted ghosts a scene keeps, their
specialised systems against the general ones, their C, GLSL and tables, and bad choices
refused naming the file, key and value. (`lensfit ghosts --fit --glsl` writes a general
ghost's GLSL with the same emitter: test_ghosts_cli; a whole general ghost, ~2 MB of
GLSL, takes over 10 minutes to compile as C, so the specialised one is checked here.)"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from lensfit.cli import main
from lensfit.codegen import call_c, glsl_as_c, glsl_check_shader, load_c
from lensfit.codegen.scene import Scene, SceneError, max_abs_difference, specialise
from lensfit.codegen.table import read_table
from lensfit.common.errors import InputError
from lensfit.ghosts.scene import choose_ghosts, fitted_ghosts
from lensfit.poly import design_matrix
from lensfit.prescription import load_lens

ROOT = Path(__file__).resolve().parents[3]
FOLDER = ROOT / "generated" / "0001-angenieux-double-gauss"


def _scene(**changes) -> Scene:
    d = {"name": "flare", "wavelengths_nm": [450.0, 550.0, 650.0], "focus_offset_mm": 0.0,
         "f_number": 8.0, "flares": True,
         "light": [{"field_x_deg": 0.0, "field_y_deg": 0.0, "distance_mm": "inf"}]}
    return Scene.from_dict({**d, **changes}, "flare.toml")


@pytest.fixture(scope="module")
def fitted():
    return fitted_ghosts(FOLDER, "0001")


@pytest.fixture(scope="module")
def lens():
    return load_lens("0001")


def test_specialised_ghost_systems_equal_the_general_ones(fitted):
    """Folding the scene's light, wavelength and focus into a ghost table changes no
    value beyond rounding (the stop-independent phase is dropped from both): 1e-9 of the
    outputs' scale (positions ~20 mm, stop crossings ~14 mm, phases ~1e2 mm)."""
    scene = _scene(wavelengths_nm=[550.0])
    light = scene.lights[0].inputs()
    for label, side in (("4-8", "P_s"), ("0-2", "P_o")):
        table = fitted[label]
        special = {s.name: s for s in specialise(table, scene)}
        general = {s.name: s for s in table}
        fixed_s = {"z_S": 0.0, "lambda": 550.0}
        assert max_abs_difference(general["P_s"], special["P_s"], fixed_s) < 1e-9
        assert max_abs_difference(general["P_o"], special["P_o_light0"],
                                  {**light, "lambda": 550.0}) < 1e-9
        if "P_clip" in general:
            assert side == "P_s"
            assert max_abs_difference(general["P_clip"], special["P_clip"], fixed_s) < 1e-9
        else:
            assert not any(n.startswith("P_clip") for n in special)


def test_choice_by_name_count_and_threshold(lens, fitted):
    assert list(fitted) == ["0-2", "0-4", "2-4", "2-6", "4-8"]
    assert choose_ghosts(lens, _scene(ghosts=["4-8"]), fitted) == ["4-8"]
    # At f/8 on axis 0-2 peaks at 3.0e-5 of the PSF peak and 4-8 at 2.1e-5
    # (`lensfit ghosts 0001 --f-number 8`): the brightest first, both above 1e-5
    assert choose_ghosts(lens, _scene(ghost_count=1), fitted) == ["0-2"]
    assert choose_ghosts(lens, _scene(ghost_threshold=1e-5), fitted) == ["0-2", "4-8"]
    # By default the visible ones: the peak pixel at least 2^-24 of the light's. 0-2 and
    # 4-8 are 8.8 and 8.4 stops above that black level, 0-4 0.4 stops; 2-4 is 0.3 and 2-6
    # 1.0 stops below it (the same command's 'stops' column)
    assert choose_ghosts(lens, _scene(), fitted) == ["0-2", "4-8", "0-4"]
    with pytest.raises(SceneError, match=r"flare.toml: key 'ghost_threshold': no fitted "
                                         r"ghost .* above 0.001 .*the brightest, 0-2"):
        choose_ghosts(lens, _scene(ghost_threshold=1e-3), fitted)


@pytest.mark.parametrize("name, what", [
    ("3-13", "ghost '3-13' is not fitted for Angenieux"),
    ("7-8", "surface 7 is the stop"),
    ("4-99", "surface 99 is out of range"),
    ("8-4", "expected i < j"),
])
def test_unfitted_or_impossible_ghosts_are_refused(lens, fitted, name, what):
    with pytest.raises((SceneError, InputError), match=rf"flare.toml: key 'ghosts': .*{what}"):
        choose_ghosts(lens, _scene(ghosts=[name]), fitted)


def test_a_ghost_named_twice_is_refused(lens, fitted):
    """Two spellings of one ghost would add its flare twice: refused naming both."""
    with pytest.raises(SceneError, match=r"flare.toml: key 'ghosts': ghost 4-8 is given twice "
                                         r"\(as '4-8' and ' 4 - 8'\)"):
        choose_ghosts(lens, _scene(ghosts=["4-8", "0-2", " 4 - 8"]), fitted)


def test_a_lens_without_fitted_ghosts(tmp_path):
    with pytest.raises(InputError, match=r"ghosts/ghosts.json: not found: .* `lensfit "
                                         r"ghosts 0009 --fit`"):
        fitted_ghosts(tmp_path, "0009")


def test_scene_command_writes_the_chosen_ghosts(tmp_path, capsys):
    scene = tmp_path / "flare.toml"
    scene.write_text('name = "flare"\nwavelengths_nm = [550.0]\nfocus_offset_mm = 0.0\n'
                     'flares = true\nghosts = ["4-8"]\n[[light]]\nfield_x_deg = 0.0\n'
                     'field_y_deg = 1.0\n', encoding="utf-8")
    out = tmp_path / "out"
    assert main(["scene", "0001", str(scene), "-o", str(out), "--no-timing"]) == 0
    assert "flares ghosts 4-8" in capsys.readouterr().out
    files = sorted(p.name for p in (out / "ghosts").iterdir())
    assert files == ["lens0001_flare_ghost_4_8.c", "lens0001_flare_ghost_4_8.h",
                     "lens0001_flare_ghost_4_8.table"]
    table = read_table((out / "ghosts" / files[2]).read_text())
    assert table.ghost.label == "4-8"
    assert [s.name for s in table] == ["P_o_light0", "P_s", "P_clip"]
    # With --glsl, GLSL beside the C: checked through its C route against the table
    assert main(["scene", "0001", str(scene), "-o", str(out), "--no-timing", "--glsl"]) == 0
    assert (out / "lens0001_flare.glsl").is_file()  # the direct systems' too
    glsl = (out / "ghosts" / "lens0001_flare_ghost_4_8.glsl").read_text()
    _glsl_agrees(glsl, table, "lens0001_flare_ghost_4_8_", tmp_path)
    # Without flares (and without --glsl) the ghosts folder goes
    scene.write_text(scene.read_text().replace("flares = true\nghosts = [\"4-8\"]\n", ""))
    assert main(["scene", "0001", str(scene), "-o", str(out), "--no-timing"]) == 0
    assert list((out / "ghosts").iterdir()) == []


def _glsl_agrees(glsl: str, table, prefix: str, tmp_path: Path) -> None:
    """A ghost's GLSL (P_o, P_s and P_clip with housing and stop-crossing pairs) through
    its C route against the table's polynomials at raw inputs over the domain: double
    within 1e-12 of sum |c_k xhat^e| (the rounding scale of any evaluation order of a few
    thousand terms is ~n eps of it), float at float32 inputs within 1e-5 of sum |c_k|
    (float32 Horner over degree <= 22: ~degree x 6e-8, with margin). glslangValidator
    (installed by `make setup`) must accept it as a compute shader."""
    if shutil.which(os.environ.get("CC", "cc")) is None:
        pytest.skip("no C compiler (set CC or install build-essential)")
    assert any(p.output.startswith("x_s") for p in table[2].outputs)  # a stop crossing
    lib = load_c({"ghost.c": glsl_as_c(glsl)})
    rng = np.random.default_rng(13)
    for system in table:
        lo = np.array([i.lo for i in system.inputs])
        hi = np.array([i.hi for i in system.inputs])
        x = np.vstack([lo + (hi - lo) * rng.random((400, len(lo))), lo, hi])
        xhat = system.normalise(x)
        scale = np.stack([np.abs(design_matrix(xhat, p.exponents) * p.coefficients).sum(1)
                          for p in system.outputs], axis=1) + 1e-300
        got = call_c(lib, f"{prefix}{system.name}_d", x, len(system.outputs), "d")
        assert (np.abs(got - system.evaluate(x)) / scale).max() < 1e-12, system.name
        xf = x.astype(np.float32).astype(np.float64)
        got = call_c(lib, f"{prefix}{system.name}_f", xf, len(system.outputs), "f")
        coef = np.array([np.abs(p.coefficients).sum() for p in system.outputs]) + 1e-300
        assert (np.abs(got - system.evaluate(xf)) / coef).max() < 1e-5, system.name
    tool = shutil.which("glslangValidator")
    if tool is not None:
        path = tmp_path / "check.comp"
        path.write_text(glsl_check_shader(glsl, list(table), prefix))
        done = subprocess.run([tool, str(path)], capture_output=True, text=True)
        assert done.returncode == 0, done.stdout + done.stderr
