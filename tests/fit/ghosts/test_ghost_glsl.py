"""Ghost GLSL (issue 13, deliverable 3): `lensfit scene --glsl` writes each kept ghost's
specialised systems (P_o, P_s and P_clip) as GLSL beside its C and table, and
`lensfit ghosts --fit --glsl` the general ones through the same emitter
(test_ghosts_cli). Checked numerically through the GLSL's C route against the table's
polynomials, and with glslangValidator where it is installed (`make setup` installs
glslang-tools). A whole general ghost (~2 MB of GLSL) takes over 10 minutes to compile
as C, so the scene's specialised 0001 ghost 4-8 (case C: P_clip with housing and
stop-crossing pairs) is the one checked."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from lensfit.cli import main
from lensfit.codegen import call_c, glsl_as_c, load_c
from lensfit.codegen.table import read_table
from lensfit.poly import System, design_matrix

needs_cc = pytest.mark.skipif(shutil.which(os.environ.get("CC", "cc")) is None,
                              reason="no C compiler (set CC or install build-essential)")


def _inputs(system: System, n: int = 400) -> np.ndarray:
    """Raw inputs uniform over the system's domain, plus its two extreme corners."""
    rng = np.random.default_rng(13)
    lo = np.array([i.lo for i in system.inputs])
    hi = np.array([i.hi for i in system.inputs])
    return np.vstack([lo + (hi - lo) * rng.random((n, len(lo))), lo, hi])


def _agrees(lib, prefix: str, system: System) -> None:
    """Double: within 1e-12 of sum |c_k xhat^e| (the rounding scale of any evaluation
    order of a few thousand terms is ~n eps of it); float at float32 inputs: within 1e-5
    of sum |c_k| (float32 Horner over degree <= 12: ~degree x 6e-8, with margin)."""
    x = _inputs(system)
    xhat = system.normalise(x)
    scale = np.stack([np.abs(design_matrix(xhat, p.exponents) * p.coefficients).sum(axis=1)
                      for p in system.outputs], axis=1) + 1e-300
    got = call_c(lib, f"{prefix}{system.name}_d", x, len(system.outputs), "d")
    assert (np.abs(got - system.evaluate(x)) / scale).max() < 1e-12, system.name
    xf = x.astype(np.float32).astype(np.float64)
    got = call_c(lib, f"{prefix}{system.name}_f", xf, len(system.outputs), "f")
    coef = np.array([np.abs(p.coefficients).sum() for p in system.outputs]) + 1e-300
    assert (np.abs(got - system.evaluate(xf)) / coef).max() < 1e-5, system.name


@needs_cc
def test_scene_glsl_of_a_kept_ghost_agrees_with_its_table(tmp_path, capsys):
    scene = tmp_path / "flare.toml"
    scene.write_text('name = "flare"\nwavelengths_nm = [550.0]\nfocus_offset_mm = 0.0\n'
                     'flares = true\nghosts = ["4-8"]\n[[light]]\nfield_x_deg = 0.0\n'
                     'field_y_deg = 1.0\n', encoding="utf-8")
    out = tmp_path / "out"
    assert main(["scene", "0001", str(scene), "-o", str(out), "--no-timing", "--glsl"]) == 0
    capsys.readouterr()
    assert (out / "lens0001_flare.glsl").is_file()  # the direct systems' too
    folder = out / "ghosts"
    assert sorted(p.suffix for p in folder.iterdir()) == [".c", ".glsl", ".h", ".table"]
    table = read_table((folder / "lens0001_flare_ghost_4_8.table").read_text())
    assert [s.name for s in table] == ["P_o_light0", "P_s", "P_clip"]
    assert any(p.output.startswith("x_s") for p in table[2].outputs)  # a stop crossing
    glsl = (folder / "lens0001_flare_ghost_4_8.glsl").read_text()
    lib = load_c({"ghost.c": glsl_as_c(glsl)})
    for system in table:
        _agrees(lib, "lens0001_flare_ghost_4_8_", system)
    _validates(glsl, list(table), "lens0001_flare_ghost_4_8_", tmp_path)


def _validates(glsl: str, systems: list[System], prefix: str, tmp_path: Path) -> None:
    """glslangValidator accepts a compute shader calling every function (both precisions)."""
    tool = shutil.which("glslangValidator")
    if tool is None:
        return  # the numerical check above stands; README's set-up installs the tool
    calls = []
    for k, s in enumerate(systems):
        n_in, n_out = len(s.inputs), len(s.outputs)
        mid = ", ".join(repr(0.5 * (i.lo + i.hi)) for i in s.inputs)
        calls += [f"    float rf{k}[{n_out}]; double rd{k}[{n_out}];",
                  f"    {prefix}{s.name}_f(float[{n_in}]({mid}), rf{k});",
                  f"    {prefix}{s.name}_d(double[{n_in}]({mid}), rd{k});",
                  f"    ff[{k}] = rf{k}[0]; dd[{k}] = rd{k}[0];"]
    path = tmp_path / "check.comp"
    path.write_text("\n".join([
        "#version 430", "layout(local_size_x = 1) in;", glsl,
        "layout(std430, binding = 0) buffer Results { double dd[8]; float ff[8]; };",
        "void main()", "{", *calls, "}", ""]))
    done = subprocess.run([tool, str(path)], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
