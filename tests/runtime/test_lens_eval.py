"""Per-ray evaluation (lensrt_lens_eval, lensrt_lens_system_info) against independent references.

* The polynomials themselves: lensfit's own evaluation of the same table
  (``lensfit.codegen.table.read_table`` -> ``System.evaluate``, numpy float64 with a
  different summation order), for lenses 0001 and 2004 (anamorphic), both systems.
* The Jacobians: central finite differences of lensrt_lens_eval itself.
* The physics: rays traced exactly through the prescription of 0001 with the fit's own
  aiming (``lensfit.sample.rays.aim_sensor_side`` / ``aim_object_side``, what the fit was
  made from): pupil positions within the fit's held-out error, and ray directions from the
  gradients of the optical path length (Hamilton's point characteristic), within a bound
  derived from the held-out phase error.
* Argument errors, empty batches, both number types, and threads.
"""

from __future__ import annotations

import ctypes as C
import json
import threading
from pathlib import Path

import numpy as np
import pytest

from lensfit.codegen.table import read_table
from lensfit.paraxial.paraxial import stop_radius_for_f_number
from lensfit.prescription import load_lens
from lensfit.sample.aim import aim_object_side, aim_sensor_side

ROOT = Path(__file__).resolve().parents[2]
LENSES = {"0001": ROOT / "generated" / "0001-angenieux-double-gauss",
          "2004": ROOT / "generated" / "2004-schneider-anamorphic"}
SYSTEMS = ("P_o", "P_s")


def table_path(lens_id: str) -> Path:
    return LENSES[lens_id] / f"lens{lens_id}.table"


@pytest.fixture(scope="module")
def lenses(rt):
    return {k: rt.load(table_path(k)) for k in LENSES}


@pytest.fixture(scope="module")
def tables():
    return {k: {s.name: s for s in read_table(table_path(k).read_text())} for k in LENSES}


def box_inputs(rt, lens, system: str, n: int, seed: int) -> np.ndarray:
    """Uniform raw inputs over the fitted box of every input."""
    info = rt.system_info(lens, system)
    lo, hi = np.array(info["min"]), np.array(info["max"])
    return lo + (hi - lo) * np.random.default_rng(seed).random((n, len(lo)))


# ------------------------------------------------------------ against lensfit -----

@pytest.mark.parametrize("lens_id", sorted(LENSES))
@pytest.mark.parametrize("system", SYSTEMS)
def test_system_info_matches_table(rt, lenses, tables, lens_id, system):
    info = rt.system_info(lenses[lens_id], system)
    ref = tables[lens_id][system]
    assert info["inputs"] == ref.input_names
    assert info["outputs"] == ref.output_names
    assert info["min"] == [i.lo for i in ref.inputs]
    assert info["max"] == [i.hi for i in ref.inputs]
    assert info["terms"] == [p.terms for p in ref.outputs]


@pytest.mark.parametrize("lens_id", sorted(LENSES))
@pytest.mark.parametrize("system", SYSTEMS)
def test_values_match_lensfit(rt, lenses, tables, lens_id, system):
    # 1003 rays: 31 full blocks of 32 and a tail of 11 (summed 4 rays at a time)
    x = box_inputs(rt, lenses[lens_id], system, 1003, seed=11)
    ref = tables[lens_id][system].evaluate(x)
    scale = np.abs(ref).max(axis=0)

    # Double: both sides sum up to 17031 double terms, in different orders; rounding
    # gives ~sqrt(terms) eps times the terms' magnitude (up to 34x the output, measured),
    # about 1e-14 of the output scale (measured <= 8e-15). 1e-12 leaves room for
    # unlucky cancellation and catches any wrong term (the smallest kept coefficients are
    # far above 1e-12 of the scale).
    out = rt.eval(lenses[lens_id], system, x)
    assert np.all(np.abs(out - ref) <= 1e-12 * scale)

    # Float: inputs are rounded to float by the caller, the sums are done in double, and the
    # outputs rounded once. So against lensfit at the float inputs, each output is within
    # half an ulp of float (correct rounding) plus the double sums' error above.
    xf = x.astype(np.float32)
    ref_f = tables[lens_id][system].evaluate(xf.astype(np.float64))
    out_f = rt.eval(lenses[lens_id], system, xf, dtype=np.float32)
    assert out_f.dtype == np.float32
    half_ulp = 0.5 * np.spacing(np.abs(ref_f).astype(np.float32)).astype(np.float64)
    assert np.all(np.abs(out_f - ref_f) <= half_ulp + 1e-12 * scale)


def test_values_do_not_depend_on_batching_or_jacobians(rt, lenses):
    # A ray's arithmetic is the same in a full block, in a short tail, alone, and with
    # Jacobians: the same bits (no tolerance).
    lens = lenses["0001"]
    x = box_inputs(rt, lens, "P_s", 70, seed=12)
    whole = rt.eval(lens, "P_s", x)
    with_jac, _ = rt.eval(lens, "P_s", x, jacobians=True)
    one_by_one = np.concatenate([rt.eval(lens, "P_s", x[k:k + 1]) for k in range(0, 70, 9)])
    assert np.array_equal(whole, with_jac)
    assert np.array_equal(whole[::9], one_by_one)
    assert np.array_equal(rt.eval(lens, "P_s", x[5:41]), whole[5:41])


# ------------------------------------------------------------ Jacobians -----

@pytest.mark.parametrize("lens_id", sorted(LENSES))
@pytest.mark.parametrize("system", SYSTEMS)
def test_jacobians_match_finite_differences(rt, lenses, lens_id, system):
    lens = lenses[lens_id]
    info = rt.system_info(lens, system)
    half = (np.array(info["max"]) - np.array(info["min"])) / 2
    x = box_inputs(rt, lens, system, 101, seed=13)
    out, jac = rt.eval(lens, system, x, jacobians=True)
    assert jac.shape == (101, 4, 6)
    # Central differences of lensrt_lens_eval with step h = 1e-3 of each input's half-width
    # (raw units, so lambda's inverse-square normalisation is inside the difference), with
    # Richardson's extrapolation from h and h/2: truncation O(h^4) and rounding
    # ~eps * (terms' magnitude) / h ~ 3e-12 of output scale / half-width. Measured
    # <= 1e-11 of that unit; 1e-9 is 100x above it, while a wrong chain-rule factor or a
    # dropped term would be off by 1e-6 or more.
    for i in range(6):
        h = 1e-3 * half[i]

        def central(step, i=i):
            xp, xm = x.copy(), x.copy()
            xp[:, i] += step
            xm[:, i] -= step
            return (rt.eval(lens, system, xp) - rt.eval(lens, system, xm)) / (2 * step)

        fd = (4 * central(h / 2) - central(h)) / 3
        unit = np.abs(out).max(axis=0) / half[i]
        err = np.abs(jac[:, :, i] - fd) / unit
        assert err.max() <= 1e-9, (info["inputs"][i], err.max(axis=0))

    # Float Jacobians: the double ones rounded (inputs rounded first)
    xf = x.astype(np.float32)
    _, jac_d = rt.eval(lens, system, xf.astype(np.float64), jacobians=True)
    _, jac_f = rt.eval(lens, system, xf, jacobians=True, dtype=np.float32)
    assert jac_f.dtype == np.float32
    assert np.array_equal(jac_f, jac_d.astype(np.float32))


# ------------------------------------------------------ against exact rays -----

def _disc(rng: np.random.Generator, n: int, radius: float) -> np.ndarray:
    angle = rng.uniform(0.0, 2 * np.pi, n)
    r = radius * np.sqrt(rng.random(n))
    return np.stack([r * np.cos(angle), r * np.sin(angle)], axis=1)


@pytest.fixture(scope="module")
def exact_0001():
    fit = json.loads((LENSES["0001"] / "fit.json").read_text())
    held = {(h["system"], h["name"]): h for h in fit["held_out"]}
    return load_lens("0001-angenieux-double-gauss"), fit["domain"], held


def _direction_tolerance(held_phase: dict, half_width: float) -> float:
    """Bound on the error of a gradient of phi over an input of half-width s (mm).

    The fit's phase error e is a smooth function bounded by eps over the domain; for a
    polynomial of degree n bounded by eps on [-s, s], Bernstein's inequality bounds its
    derivative by n eps / s away from the ends. n = 10 is the highest exponent of one input
    in the phase polynomials; eps is 8x the held-out absolute phase rms (the held-out
    positions' max/rms ratio is 6-12)."""
    eps_mm = 8 * held_phase["absolute_rms_um"] * 1e-3
    return 10 * eps_mm / half_width


@pytest.mark.parametrize("f_number", [8.0, 2.0])
def test_sensor_side_against_exact_rays(rt, lenses, exact_0001, f_number):
    lens, domain, held = exact_0001
    rng = np.random.default_rng(int(f_number))
    n = 300
    radius = stop_radius_for_f_number(lens, f_number)
    assert radius <= domain["stop_radius_mm"] + 1e-9
    sensor = _disc(rng, n, domain["sensor_radius_mm"])
    stop = _disc(rng, n, radius)
    z = rng.uniform(domain["focus_min_mm"], domain["focus_max_mm"], n)
    lam = np.full(n, 550.0)
    exact = aim_sensor_side(lens, sensor[:, 0], sensor[:, 1], z, stop[:, 0], stop[:, 1], lam,
                            vignetting=False)
    assert exact.ok.all()
    x = np.stack([sensor[:, 0], sensor[:, 1], z, stop[:, 0], stop[:, 1], lam], axis=1)
    out, jac = rt.eval(lenses["0001"], "P_s", x, jacobians=True)

    # Inner pupil position: within the held-out max of each coordinate, and the rms within
    # twice the held-out rms (300 rays against the fit's 6400 held-out samples)
    for j, name in enumerate(("x_i", "y_i")):
        err_um = np.abs(out[:, j] - exact.outputs[:, j]) * 1e3
        assert err_um.max() <= held[("P_s", name)]["max"], name
        assert np.sqrt(np.mean(err_um**2)) <= 2 * held[("P_s", name)]["rms"], name

    # phi_i is the optical path length from the stop point to the sensor point (in air,
    # n = 1): its gradient over the end point is the unit direction of the ray arriving
    # there, (d/dx_S, d/dy_S, d/dz_S) = (l, m, n) of the traced ray, pointing away from the
    # lens. Over the start point it is minus the direction leaving the stop.
    phase = held[("P_s", "phi_i")]
    half = dict(zip(("x_S", "y_S", "z_S", "x_a"),
                    (domain["sensor_radius_mm"], domain["sensor_radius_mm"],
                     (domain["focus_max_mm"] - domain["focus_min_mm"]) / 2,
                     domain["stop_radius_mm"]), strict=True))
    for i, name in enumerate(("x_S", "y_S", "z_S")):
        err = np.abs(jac[:, 3, i] - exact.dir[:, i])
        assert err.max() <= _direction_tolerance(phase, half[name]), (name, err.max())
    slopes = np.concatenate([exact.unknowns, np.ones((n, 1))], axis=1)
    leaving = slopes / np.linalg.norm(slopes, axis=1, keepdims=True)
    err = np.abs(jac[:, 3, 3:5] + leaving[:, :2])
    assert err.max() <= _direction_tolerance(phase, half["x_a"]), err.max()


@pytest.mark.parametrize("f_number", [8.0, 2.0])
def test_object_side_against_exact_rays(rt, lenses, exact_0001, f_number):
    lens, domain, held = exact_0001
    rng = np.random.default_rng(10 + int(f_number))
    n = 300
    radius = stop_radius_for_f_number(lens, f_number)
    sin_field = np.sin(np.radians(domain["field_deg"]))
    light = _disc(rng, n, sin_field)
    # Half the lights at infinity, the others between infinity and the close focus
    u = np.where(np.arange(n) % 2 == 0, 0.0, rng.uniform(0.0, 1.0 / domain["close_focus_mm"], n))
    stop = _disc(rng, n, radius)
    lam = np.full(n, 550.0)
    exact = aim_object_side(lens, light[:, 0], light[:, 1], u, stop[:, 0], stop[:, 1], lam)
    assert exact.ok.all()
    x = np.stack([light[:, 0], light[:, 1], u, stop[:, 0], stop[:, 1], lam], axis=1)
    out, jac = rt.eval(lenses["0001"], "P_o", x, jacobians=True)

    for j, name in enumerate(("x_o", "y_o")):
        err_um = np.abs(out[:, j] - exact.outputs[:, j]) * 1e3
        assert err_um.max() <= held[("P_o", name)]["max"], name
        assert np.sqrt(np.mean(err_um**2)) <= 2 * held[("P_o", name)]["rms"], name

    phase = held[("P_o", "phi_o")]
    # phi_o ends on the stop (in air): its gradient over the stop point is the direction of
    # the ray arriving there
    err = np.abs(jac[:, 3, 3:5] - exact.dir[:, :2])
    assert err.max() <= _direction_tolerance(phase, domain["stop_radius_mm"]), err.max()
    # At infinity phi_o = OPL(S -> stop) - S.w for any start S on the ray, w = (x_O, y_O,
    # -sqrt(1 - x_O^2 - y_O^2)) towards the light: its derivative over x_O (y_O fixed) is
    # -S_x - S_z x_O / |w_z|, i.e. minus where the incoming ray crosses the plane z = 0
    # (the aiming's unknowns). The direction cosines' half-width is sin(field).
    inf = u == 0
    err = np.abs(jac[inf, 3, 0:2] + exact.unknowns[inf])
    assert err.max() <= _direction_tolerance(phase, sin_field), err.max()


# --------------------------------------------------------- argument errors -----

def _raw(rt):
    from lensrt_ctypes import EvalDesc, SystemInfo

    rt._eval_functions()
    return rt.lib, EvalDesc, SystemInfo


def _call(rt, lens, desc, ctx=True):
    ref = C.byref(desc) if desc is not None else None
    code = rt.lib.lensrt_lens_eval(rt.ctx if ctx else None, lens, ref)
    return code, rt.lib.lensrt_context_last_error(rt.ctx).decode()


def test_argument_errors_are_refused_with_a_message(rt, lenses):
    from lensrt_ctypes import LensrtError, Result

    lib, EvalDesc, _ = _raw(rt)
    lens = lenses["0001"]
    x = np.array([[1.0, 2.0, 0.5, 1.0, -1.0, 550.0]] * 5)
    out = np.full((5, 4), -7.0)

    def desc(**kw):
        d = EvalDesc(1, 0, 5, x.ctypes.data, out.ctypes.data, None)
        for k, v in kw.items():
            setattr(d, k, v)
        return d

    cases = [
        (None, "desc is NULL"),
        (desc(struct_size=0), "struct_size is 0"),
        (desc(struct_size=16), "struct_size is 16"),
        (desc(system=3), "system is 3"),  # 2 is a ghost table's P_clip (test_ghost.c)
        (desc(type=3), "type is 3"),
        (desc(inputs=None), "inputs is NULL with n_rays 5"),
        (desc(outputs=None), "outputs is NULL with n_rays 5"),
    ]
    for d, message in cases:
        code, text = _call(rt, lens, d)
        assert code == Result.INVALID_ARGUMENT, message
        assert message in text, (message, text)
    assert np.all(out == -7.0)

    # Non-finite inputs and a wavelength <= 0: the ray and the input named, nothing written
    bad_inputs = [(np.nan, 3, 5, "lambda"), (np.inf, 4, 0, "x_S"), (0.0, 2, 5, "lambda")]
    for value, ray, col, name in bad_inputs:
        bad = x.copy()
        bad[ray, col] = value
        code, text = _call(rt, lens, desc(inputs=bad.ctypes.data))
        assert code == Result.INVALID_ARGUMENT
        assert f"ray {ray}: input {name}" in text and "nothing was written" in text, text
        assert np.all(out == -7.0)
    # Float inputs are checked the same way
    bad = x.astype(np.float32)
    bad[1, 2] = np.nan
    code, text = _call(rt, lens, desc(type=1, inputs=bad.ctypes.data))
    assert code == Result.INVALID_ARGUMENT and "ray 1: input z_S" in text

    # An analytic lens has no fitted systems
    analytic = rt.analytic(focal_length_mm=50.0, sensor_distance_mm=50.0)
    code, text = _call(rt, analytic, desc())
    assert code == Result.UNSUPPORTED and "analytic" in text
    with pytest.raises(LensrtError) as err:
        rt.system_info(analytic, "P_s")
    assert err.value.code == Result.UNSUPPORTED

    # Without a context: the same codes, no message anywhere
    assert _call(rt, lens, desc(system=3), ctx=False)[0] == Result.INVALID_ARGUMENT
    assert _call(rt, lens, desc(), ctx=False)[0] == Result.SUCCESS
    assert np.array_equal(out, rt.eval(lens, "P_s", x, context=False))


def test_empty_batch_succeeds(rt, lenses):
    lib, EvalDesc, _ = _raw(rt)
    # n_rays 0: nothing to read or write, NULL pointers allowed
    assert _call(rt, lenses["0001"], EvalDesc(0, 1, 0, None, None, None))[0] == 0
    out, jac = rt.eval(lenses["0001"], "P_o", np.empty((0, 6)), jacobians=True)
    assert out.shape == (0, 4) and jac.shape == (0, 4, 6)


def test_system_info_struct_size(rt, lenses):
    from lensrt_ctypes import Result

    lib, _, SystemInfo = _raw(rt)
    lens = lenses["2004"]
    info = SystemInfo()
    info.struct_size = 0
    assert lib.lensrt_lens_system_info(lens, 1, C.byref(info)) == Result.INVALID_ARGUMENT
    info = SystemInfo()
    assert lib.lensrt_lens_system_info(lens, 7, C.byref(info)) == Result.INVALID_ARGUMENT
    assert lib.lensrt_lens_system_info(lens, 1, None) == Result.INVALID_ARGUMENT

    # A caller's struct from a newer header (larger, zero tail): our fields are filled, the
    # tail is left zero, and the caller's struct_size is kept
    class Bigger(C.Structure):
        _fields_ = [("info", SystemInfo), ("future", C.c_uint64 * 4)]

    big = Bigger()
    big.info.struct_size = C.sizeof(Bigger)
    big.future[:] = [0, 0, 0, 0]
    assert lib.lensrt_lens_system_info(lens, 1, C.byref(big.info)) == Result.SUCCESS
    assert big.info.struct_size == C.sizeof(Bigger)
    assert big.info.n_inputs == 6 and big.info.input_names[5] == b"lambda"
    assert list(big.future) == [0, 0, 0, 0]


def test_concurrent_threads_give_identical_results(rt, lenses):
    # ctypes releases the GIL during the call: four threads evaluate the same lens at
    # once, each its own batch and each in both types; every result must equal the
    # single-threaded one bit for bit (no shared state is written).
    lens = lenses["0001"]
    batches = [box_inputs(rt, lens, "P_s", 500, seed=20 + k) for k in range(4)]
    expected = [rt.eval(lens, "P_s", b, jacobians=True) for b in batches]
    results: list = [None] * 4
    errors: list = []

    def work(k: int) -> None:
        try:
            for _ in range(3):
                got = rt.eval(lens, "P_s", batches[k], jacobians=True, context=False)
                if not all(np.array_equal(a, b) for a, b in zip(got, expected[k], strict=True)):
                    raise AssertionError(f"thread {k}: results differ")
            results[k] = rt.eval(lens, "P_s", batches[k], dtype=np.float32, context=False)
        except Exception as e:  # noqa: BLE001  (reported below)
            errors.append(e)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for k in range(4):
        assert np.array_equal(results[k], rt.eval(lens, "P_s", batches[k], dtype=np.float32))


GHOST_0001 = LENSES["0001"] / "ghosts" / "ghost_4_8.table"  # P_clip on side P_s


@pytest.mark.parametrize("system", ["P_o", "P_s", "P_clip"])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("jacobians", [False, True])
def test_far_outside_the_domain_no_nan_or_inf_leaves(rt, lenses, system, dtype, jacobians):
    """Finite inputs far outside the fitted box (1e100 .. 1e300, a wavelength of 1e-300,
    beyond float's range): every batch either gives finite values or fails as a whole
    with OUT_OF_DOMAIN, its outputs zeroed, naming the ray and an input outside its range.
    Never a NaN or an inf with success (the header's promise)."""
    from lensrt_ctypes import Result

    lib, EvalDesc, _ = _raw(rt)
    lens = rt.load(GHOST_0001) if system == "P_clip" else lenses["0001"]
    sid = {"P_o": 0, "P_s": 1, "P_clip": 2}[system]
    info = rt.system_info(lens, system)
    mid = (np.array(info["min"]) + np.array(info["max"])) / 2
    n_in, n_out = len(mid), len(info["outputs"])
    huge = ([1e30, 1e100, -1e100, 1e200, 1e300, -1e300] if dtype == np.float64
            else [1e20, -3e38, 3e38])
    lam = [1e-300, 1e300] if dtype == np.float64 else [1e-30, 3e38]  # 1 / lambda^2 overflows
    cases = [(col, v) for col in range(n_in - 1) for v in huge] + [(n_in - 1, v) for v in lam]
    failed = 0
    for col, value in cases:
        x = np.tile(mid, (3, 1)).astype(dtype)
        x[1, col] = value
        out = np.full((3, n_out), -7.0, dtype=dtype)
        jac = np.full((3, n_out, n_in), -7.0, dtype=dtype) if jacobians else None
        d = EvalDesc(sid, 1 if dtype == np.float32 else 0, 3, x.ctypes.data,
                     out.ctypes.data, jac.ctypes.data if jacobians else None)
        code, text = _call(rt, lens, d)
        if code == Result.SUCCESS:
            assert np.all(np.isfinite(out)), (col, value, out)
            assert not jacobians or np.all(np.isfinite(jac)), (col, value)
        else:
            failed += 1
            assert code == Result.OUT_OF_DOMAIN, (col, value, code, text)
            assert "ray 1: output" in text and "outside its fitted range" in text, text
            assert np.all(out == 0) and (not jacobians or np.all(jac == 0)), (col, value)
    # Polynomials of degree > 2 overflow double at 1e300 (and float at 1e20): the refusal
    # path is exercised in every parametrisation, not only the success path
    assert failed > 0
