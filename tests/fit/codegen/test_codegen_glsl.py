"""Generated GLSL: numerically through its C route, and with glslangValidator if present."""

from __future__ import annotations

import os
import re
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
from codegen_systems import coefficient_scale, sample_inputs, term_scale

from lensfit.codegen import (
    call_c,
    check_compiles,
    emit_glsl,
    glsl_as_c,
    glsl_check_shader,
    load_c,
)
from lensfit.poly import System

PREFIX = "lens0001_"

needs_cc = pytest.mark.skipif(shutil.which(os.environ.get("CC", "cc")) is None,
                              reason="no C compiler (set CC or install build-essential)")


@pytest.fixture(scope="module")
def glsl(systems: list[System]) -> str:
    return emit_glsl(systems, PREFIX, header_comment="Test lens")["lens0001.glsl"]


@pytest.fixture(scope="module")
def glsl_lib(glsl: str):
    return load_c({"glsl.c": glsl_as_c(glsl)})


@needs_cc
def test_glsl_compiles_as_strict_c(glsl):
    # The clip system uses no input; GLSL has no (void) cast to mark the parameter used
    check_compiles({"glsl.c": glsl_as_c(glsl)},
                   ("-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror",
                    "-Wno-unused-parameter"))


@needs_cc
@pytest.mark.parametrize("variant", ["d", "f"])
@pytest.mark.parametrize("index", [0, 1, 2])
def test_glsl_agrees_with_python(systems, glsl_lib, index, variant):
    """Same tolerances and reasoning as the C tests (test_codegen_c): 1e-12 of the sum of
    |terms| in double, 1e-5 of sum|c_k| in float at float32 inputs."""
    s = systems[index]
    x = sample_inputs(s, 600)
    if variant == "f":
        x = x.astype(np.float32).astype(np.float64)
    got = call_c(glsl_lib, f"{PREFIX}{s.name}_{variant}", x, len(s.outputs), variant)
    want = s.evaluate(x)
    if variant == "d":
        assert (np.abs(got - want) / term_scale(s, x)).max() < 1e-12
    else:
        assert (np.abs(got - want) / coefficient_scale(s)).max() < 1e-5


def test_glsl_double_constants_are_bit_exact(glsl):
    """Every packDouble2x32 pattern decodes to the decimal value in its comment."""
    pattern = re.compile(r"packDouble2x32\(uvec2\(0x([0-9A-F]{8})u, 0x([0-9A-F]{8})u\)\); "
                         r"/\* (\S+) \*/")
    found = pattern.findall(glsl)
    assert len(found) > 100
    for lo, hi, decimal in found:
        bits = (int(hi, 16) << 32) | int(lo, 16)
        assert struct.unpack("<d", struct.pack("<Q", bits))[0] == float(decimal)


def test_glsl_is_plain_glsl(glsl):
    assert glsl.isascii()
    assert re.search(r"\d(lf|LF)\b", glsl) is None  # no double-literal suffixes
    assert "(void)" not in glsl and "static" not in glsl
    assert "#error lens0001.glsl needs GLSL 4.00" in glsl


def test_glslang_validates(glsl, systems, tmp_path: Path):
    tool = shutil.which("glslangValidator")
    if tool is None:
        pytest.skip("glslangValidator is not on PATH (Debian: apt-get install glslang-tools)")
    shader = glsl_check_shader(glsl, systems, PREFIX)
    path = tmp_path / "check.comp"
    path.write_text(shader)
    done = subprocess.run([tool, str(path)], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    # And the check can fail: GLSL 3.30 has no double
    path.write_text(shader.replace("#version 430", "#version 330"))
    done = subprocess.run([tool, str(path)], capture_output=True, text=True)
    assert done.returncode != 0
