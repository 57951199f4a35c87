"""Generated C (Horner and casadi) against System.evaluate, strict compilation, determinism."""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from codegen_systems import coefficient_scale, make_systems, sample_inputs, term_scale

from lensfit.codegen import (
    CompilerNotFound,
    call_c,
    casadi_system,
    check_compiles,
    emit_c,
    emit_glsl,
    load_c,
    time_c,
    write_table,
)
from lensfit.poly import Polynomial, System, design_matrix

PREFIX = "lens0001_"
STRICT = ("-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror")

pytestmark = pytest.mark.skipif(shutil.which(os.environ.get("CC", "cc")) is None,
                                reason="no C compiler (set CC or install build-essential)")

# Double: the generated code evaluates the same terms in another order (Horner, and the
# normalisation as (w - c) * (1/s) instead of (w - c) / s); each term goes through at most
# ~30 roundings (degree <= 10 plus Horner levels), so both results are within about
# 30 * 2^-53 * sum|terms| = 3e-15 of the exact value. 1e-12 leaves a factor ~300 of
# margin; a wrong digit anywhere is caught by test_double_literals_round_trip.
TOL_DOUBLE = 1e-12
# Float: inputs are compared at their float32 values, so what remains is float
# arithmetic (2^-24 = 6e-8 per rounding). The normalisation loses absolute accuracy in
# xhat (w - c cancels: up to ~3 roundings of |w|/s <= 2.6 for the wavelength), and a term
# changes by at most e_j |c_k| <= 10 |c_k| per unit of xhat_j, so the error is bounded by
# about (10 * 3 * 2.6 + 30) * 6e-8 * sum|c_k| = 7e-6 sum|c_k|, and sum|c_k| bounds |P| on
# the domain. Typical errors are ~100 times smaller; sum|terms| is not a usable scale
# here, since a term that is small only because xhat_j ~ 0 still feels the error of xhat_j.
TOL_FLOAT = 1e-5


@pytest.fixture(scope="module")
def horner(systems: list[System]) -> dict[str, str]:
    return emit_c(systems, PREFIX, header_comment="Test lens\nrandom systems")


@pytest.fixture(scope="module")
def casadi_c(systems: list[System]) -> dict[str, str]:
    return emit_c(systems, PREFIX, header_comment="Test lens", which="casadi")


@pytest.fixture(scope="module")
def horner_lib(horner):
    return load_c(horner)


@pytest.fixture(scope="module")
def casadi_lib(casadi_c):
    return load_c(casadi_c)


def _check(system: System, lib, function: str, variant: str) -> None:
    x = sample_inputs(system, 600)
    if variant == "f":
        x = x.astype(np.float32).astype(np.float64)
    got = call_c(lib, function, x, len(system.outputs), variant)
    want = system.evaluate(x)
    if variant == "d":
        err = np.abs(got - want) / term_scale(system, x)
        assert err.max() < TOL_DOUBLE, (function, err.max(axis=0))
    else:
        err = np.abs(got - want) / coefficient_scale(system)
        assert err.max() < TOL_FLOAT, (function, err.max(axis=0))


@pytest.mark.parametrize("variant", ["d", "f"])
@pytest.mark.parametrize("index", [0, 1, 2])
def test_horner_agrees_with_python(systems, horner_lib, index, variant):
    s = systems[index]
    _check(s, horner_lib, f"{PREFIX}{s.name}_{variant}", variant)


@pytest.mark.parametrize("variant", ["d", "f"])
@pytest.mark.parametrize("index", [0, 1, 2])
def test_casadi_agrees_with_python(systems, casadi_lib, index, variant):
    s = systems[index]
    _check(s, casadi_lib, f"{PREFIX}{s.name}_casadi_{variant}", variant)


def test_float_variant_computes_in_float(systems, horner):
    """Every literal in a float function has the f suffix, none in a double one."""
    text = horner["lens0001.c"]
    for s in systems:
        for variant in ("f", "d"):
            body = text.split(f"void {PREFIX}{s.name}_{variant}(")[1].split("\n}\n")[0]
            literals = re.findall(r"(?<![\w.])\d+\.\d*(?:e[-+]?\d+)?f?", body)
            assert literals
            assert all(lit.endswith("f") == (variant == "f") for lit in literals), variant
            assert ("double" in body) == (variant == "d")


def test_double_literals_round_trip(systems, horner):
    """Each merged coefficient is in the double code as a literal that parses back to
    exactly the same double (17 significant digits)."""
    from lensfit.codegen.horner import canonical_terms

    text = horner["lens0001.c"]
    for s in systems:
        body = text.split(f"void {PREFIX}{s.name}_d(")[1].split("\n}\n")[0]
        found = {float(t) for t in re.findall(r"-?\d+\.\d*(?:e[-+]?\d+)?", body)}
        for p in s.outputs:
            for c in canonical_terms(p)[1]:
                assert float(c) in found, (s.name, p.output, c)


def test_strict_compile(horner, casadi_c):
    check_compiles(horner, STRICT)
    # casadi's C compiles strictly thanks to one pragma (see lensfit.codegen.c_casadi)
    check_compiles(casadi_c, STRICT)


def test_strict_compile_catches_warnings():
    """The strict check itself fails on a warning (an unused variable)."""
    with pytest.raises(subprocess.CalledProcessError):
        check_compiles({"w.c": "void f(void);\nvoid f(void) { int unused; }\n"}, STRICT)


def test_header_is_cpp_compatible(horner, casadi_c, tmp_path: Path):
    cxx = shutil.which("c++")
    if cxx is None:
        pytest.skip("no C++ compiler")
    for name in ("lens0001.h", "lens0001_casadi.h"):
        (tmp_path / name).write_text({**horner, **casadi_c}[name])
        src = tmp_path / "use.cpp"
        src.write_text(f'#include "{name}"\nint main() {{ return 0; }}\n')
        subprocess.run([cxx, "-Wall", "-Wextra", "-pedantic", "-Werror", "-fsyntax-only",
                        str(src)], check=True, cwd=tmp_path)
    assert 'extern "C"' in horner["lens0001.h"]
    assert "#ifndef LENS0001_H" in horner["lens0001.h"]


def test_header_constants_carry_units(systems, horner):
    header = horner["lens0001.h"]
    assert "#define lens0001_P_o_N_IN 6" in header
    assert "#define lens0001_P_o_LO_lambda (380.0) /* [nm] lower bound */" in header
    assert "inverse_square" in header
    for line in header.splitlines():
        if line.startswith("#define lens0001_"):
            assert "/*" in line, line  # every constant is commented (with its unit)
    assert header.isascii() and horner["lens0001.c"].isascii()


def _jacobian(system: System, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Analytic d out_i / d in_j of the Python polynomials (N, n_out, n_in), and the scale
    sum_k |term derivative| of the same shape."""
    xhat = system.normalise(x)
    jac = np.zeros((len(x), len(system.outputs), len(system.inputs)))
    scale = np.zeros_like(jac)
    for j, inp in enumerate(system.inputs):
        c, s = inp.offset_scale
        v = x[:, j]
        dxhat = np.full_like(v, 1.0 / s) if inp.transform == "affine" else -2.0 / (v**3 * s)
        for i, p in enumerate(system.outputs):
            e = p.exponents.copy()
            factor = e[:, j].astype(np.float64)
            e[:, j] = np.maximum(e[:, j] - 1, 0)
            terms = design_matrix(xhat, e) * (p.coefficients * factor)
            jac[:, i, j] = terms.sum(axis=1) * dxhat
            scale[:, i, j] = np.abs(terms).sum(axis=1) * np.abs(dxhat) + 1e-300
    return jac, scale


def test_analytic_jacobian_matches_finite_differences(systems):
    """The reference derivative itself, against central differences (step 1e-6 of the
    domain: truncation ~1e-12 relative, cancellation ~1e-10 relative to the values)."""
    s = systems[0]
    x = sample_inputs(s, 20)[:20]
    jac, _ = _jacobian(s, x)
    width = np.array([i.hi - i.lo for i in s.inputs])
    for j in range(len(s.inputs)):
        h = 1e-6 * width[j]
        step = np.zeros(len(s.inputs))
        step[j] = h
        fd = (s.evaluate(x + step) - s.evaluate(x - step)) / (2 * h)
        scale = np.abs(s.evaluate(x)).max() / width[j] + np.abs(fd).max()
        assert np.abs(fd - jac[:, :, j]).max() < 1e-6 * scale


@pytest.mark.parametrize("index", [0, 1, 2])
def test_casadi_jacobian_matches_analytic(systems, casadi_lib, index):
    """Same error model as the values (the derivative is again a sum of terms), so the
    same 1e-12 relative to the sum of |derivative terms|."""
    s = systems[index]
    x = sample_inputs(s, 200)
    n_in, n_out = len(s.inputs), len(s.outputs)
    got = call_c(casadi_lib, f"{PREFIX}{s.name}_casadi_jac_d", x, n_out * n_in)
    want, scale = _jacobian(s, x)
    err = np.abs(got.reshape(-1, n_out, n_in) - want) / scale
    assert err.max() < TOL_DOUBLE, err.max(axis=0)


def test_casadi_functions_in_python(systems):
    """casadi_system evaluated by casadi itself (no C), values and Jacobian layout."""
    s = systems[0]
    f, jac = casadi_system(s, "p_o", form="horner")
    x = sample_inputs(s, 5)
    got = np.array([np.asarray(f(row)).ravel() for row in x])
    assert np.all(np.abs(got - s.evaluate(x)) < TOL_DOUBLE * term_scale(s, x))
    j = np.asarray(jac(x[0])).reshape(len(s.outputs), len(s.inputs))
    want, scale = _jacobian(s, x[:1])
    assert np.all(np.abs(j - want[0]) < TOL_DOUBLE * scale[0])


@pytest.mark.parametrize("bad", ["1abc", "a-b", "", "a b", "_x", "_Lens", "gl_lens", "a__b"])
def test_bad_prefix_is_refused(systems, bad):
    for emit in (lambda: emit_c(systems, bad), lambda: emit_c(systems, bad, which="casadi"),
                 lambda: emit_glsl(systems, bad)):
        with pytest.raises(ValueError, match="prefix"):
            emit()


def test_bad_system_names_are_refused(systems):
    s = systems[2]
    with pytest.raises(ValueError, match="cannot be part of a C symbol"):
        emit_c([System("P-o", s.inputs, s.outputs)], PREFIX)
    with pytest.raises(ValueError, match="appears twice"):
        emit_c([s, s], PREFIX)
    with pytest.raises(ValueError, match="'__'"):
        emit_c([System("clip_", s.inputs, s.outputs)], PREFIX)
    with pytest.raises(ValueError, match="which"):
        emit_c([s], PREFIX, which="fortran")


def test_float_overflow_is_refused(systems):
    s = systems[2]
    big = System("big", s.inputs, (Polynomial("y", "1", np.zeros((1, 2), np.int32), [1e39]),))
    with pytest.raises(ValueError, match="does not fit a float"):
        emit_c([big], PREFIX)


def test_regeneration_is_byte_identical(systems, horner, casadi_c):
    assert emit_c(systems, PREFIX, header_comment="Test lens\nrandom systems") == horner
    assert emit_c(systems, PREFIX, header_comment="Test lens", which="casadi") == casadi_c


def test_horner_code_ignores_term_order(systems, horner):
    """Permuting the terms of every output changes neither the C nor the GLSL text."""
    rng = np.random.default_rng(3)
    shuffled = []
    for s in systems:
        outs = []
        for p in s.outputs:
            order = rng.permutation(p.terms)
            outs.append(Polynomial(p.output, p.unit, p.exponents[order], p.coefficients[order]))
        shuffled.append(System(s.name, s.inputs, tuple(outs)))
    assert emit_c(shuffled, PREFIX, header_comment="Test lens\nrandom systems") == horner
    assert emit_glsl(shuffled, PREFIX) == emit_glsl(systems, PREFIX)


_DIGEST = textwrap.dedent("""
    import hashlib, sys
    sys.path.insert(0, sys.argv[1])
    from codegen_systems import make_systems
    from lensfit.codegen import emit_c, emit_glsl, write_table
    s = make_systems()
    files = {**emit_c(s, "lens0001_"), **emit_c(s, "lens0001_", which="casadi"),
             **emit_glsl(s, "lens0001_"), "table": write_table(s)}
    print(hashlib.sha256(repr(sorted(files.items())).encode()).hexdigest())
""")


def test_output_does_not_depend_on_hash_seed():
    here = str(Path(__file__).parent)
    digests = []
    for seed in ("0", "12345"):
        env = {**os.environ, "PYTHONHASHSEED": seed}
        done = subprocess.run([sys.executable, "-c", _DIGEST, here], env=env, check=True,
                              capture_output=True, text=True)
        digests.append(done.stdout.strip())
    s = make_systems()
    files = {**emit_c(s, PREFIX), **emit_c(s, PREFIX, which="casadi"),
             **emit_glsl(s, PREFIX), "table": write_table(s)}
    here_digest = hashlib.sha256(repr(sorted(files.items())).encode()).hexdigest()
    assert digests == [here_digest, here_digest]


def test_time_c_reports_nanoseconds(systems, horner):
    ns = time_c(horner, f"{PREFIX}clip_d", systems[2], points=64, repeats=1,
                min_seconds=0.001)
    assert 0.0 < ns < 1e6


def test_missing_compiler_is_reported(monkeypatch, horner):
    monkeypatch.setenv("CC", "no-such-compiler-lensfit")
    with pytest.raises(CompilerNotFound, match="no C compiler"):
        load_c(horner)


def test_benchmark_system_is_the_documented_shape():
    from lensfit.codegen.bench import benchmark_system

    s = benchmark_system(terms=20)
    assert len(s.inputs) == 6 and s.inputs[5].transform == "inverse_square"
    assert [p.terms for p in s.outputs] == [20, 20, 20, 20]
    assert max(p.max_degree for p in s.outputs) <= 9
    assert all(len({tuple(e) for e in p.exponents.tolist()}) == 20 for p in s.outputs)


SANITIZE = ("-O1", "-std=c99", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
            "-fno-omit-frame-pointer")


def test_generated_code_is_clean_under_asan_and_ubsan(systems, horner, casadi_c, tmp_path):
    """Out-of-bounds reads of in[] or writes of out[] (or undefined behaviour) abort the
    timing driver when built with the sanitizers."""
    probe = tmp_path / "probe.c"
    probe.write_text("int main(void) { return 0; }\n")
    cc = shutil.which(os.environ.get("CC", "cc"))
    if subprocess.run([cc, *SANITIZE, str(probe), "-o", str(tmp_path / "probe")],
                      capture_output=True).returncode != 0:
        pytest.skip("the C compiler cannot build with -fsanitize=address,undefined")
    quick = {"points": 16, "repeats": 1, "min_seconds": 0.0, "flags": SANITIZE}
    for s in systems:
        for v in ("d", "f"):
            assert time_c(horner, f"{PREFIX}{s.name}_{v}", s, variant=v, **quick) > 0
    # casadi: only the double file (the float one is the same code with another type)
    only_d = {k: v for k, v in casadi_c.items() if not k.endswith("_f.c")}
    for fn, n_out in (("P_o_casadi_d", None), ("P_o_casadi_jac_d", 24)):
        assert time_c(only_d, PREFIX + fn, systems[0], n_outputs=n_out, **quick) > 0
