"""The GL compute path against the CPU path, closed forms and its own contract.

Every test here needs an OpenGL 4.3 core context (Mesa's llvmpipe is enough: CI
installs it). Without one the tests skip with the library's reason, except where
LENSRT_REQUIRE_GL is set (`.ci/run` sets it): there a missing device is a failure, so
CI can never pass by skipping them.

Both devices draw the same samples (the host draws them for either), so for the same
seed and sample count the images differ only by how each evaluates the transport: the
CPU splats in float with per-pixel pruned terms, the GL path in float with the window's
basis truncated by a bound at least as strict. The tolerances below say how far apart
that may put them.
"""

from __future__ import annotations

import ctypes.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from lensrt_ctypes import LIBRARY, NO_DEVICE, Lensrt, LensrtError, Result
from test_validation import (
    AIRY_ZERO,
    INVALID_ARGUMENT,
    LAM,
    LENS0001,
    WL_NM,
    centres,
    disc_amplitude_integral,
    parabola_vertex,
    rel_l2,
)

ROOT = Path(__file__).resolve().parents[2]
PSF = ROOT / "build" / "runtime" / "runtime" / "lensrt-psf"
UNSUPPORTED = Result.UNSUPPORTED
REQUIRE = bool(os.environ.get("LENSRT_REQUIRE_GL"))

# Float rounding floor of the GL path relative to a double reference: each splat's phase
# is a float sum of terms totalling up to a few hundred waves at f/2 (eps 6e-8 -> ~2e-5
# waves, 1e-4 rad), and a coherent worst case turns a phase error e into 2e of intensity:
# 2e-4.
FLOAT_FLOOR = 2e-4


def no_device(reason: str) -> None:
    if REQUIRE:
        pytest.fail(f"LENSRT_REQUIRE_GL is set but there is no GL device: {reason}")
    pytest.skip(f"no OpenGL 4.3 device on this machine: {reason}")


@pytest.fixture(scope="session")
def gl() -> Lensrt:
    """A context whose GL device exists (made once; the shaders' JIT is per render)."""
    if not LIBRARY.exists():
        pytest.skip("lensrt is not built")
    rt = Lensrt(LIBRARY)
    try:
        info = rt.gl_info()
    except LensrtError as e:
        if e.code in (NO_DEVICE, UNSUPPORTED):
            no_device(str(e))
        raise
    print(f"GL device: {info['platform']}, GL_RENDERER {info['renderer']}, "
          f"GL_VERSION {info['version']}")
    return rt


@pytest.fixture(scope="session")
def lens0001(gl):
    if not LENS0001.exists():
        pytest.skip(f"{LENS0001} is missing")
    return gl.load(LENS0001)


def test_device_reports_renderer_and_version(gl):
    info = gl.gl_info()
    assert info["platform"] in ("egl-device", "egl-surfaceless", "glfw")
    assert info["renderer"] and info["renderer"] != "unknown"
    major, minor = (int(x) for x in info["version"].split()[0].split(".")[:2])
    assert (major, minor) >= (4, 3), info["version"]


# ------------------------------------------------------- agreement with the CPU -----

SCENES = {
    # f/2, 7 curved blades, light -6,-4 deg, defocused: transmittance varies over the stop
    "f2-blades-off-axis": dict(f_number=2.0, width_mm=0.2, light=(-6.0, -4.0), focus=0.2,
                               shape="blades", blades=7, blade_curvature=0.3, rotation_deg=10.0),
    # f/8 circle on the axis, in focus
    "f8-axis": dict(f_number=8.0, width_mm=0.03, light=(0.0, 0.0), focus=0.0, shape="circle"),
}


@pytest.mark.parametrize("name", list(SCENES))
def test_gl_matches_cpu_on_a_fitted_lens(gl, lens0001, name):
    # Same seed and samples on both devices; the CPU in double is the reference. The
    # CPU's default mode drops per-pixel phase terms whose bounds sum to 3e-3 waves; the
    # GL path drops basis vectors whose bound |u_j| |V_j|_1 sums to the same tolerance, a
    # bound at least as strict. So the GL image may be no further from the double one
    # than the CPU's default image is (3x for the different truncations, which are not
    # the same terms), plus the float floor of its own sums.
    s = SCENES[name]
    center = gl.image_point(lens0001, s["light"], 580.0, s["focus"])
    shape = {k: s[k] for k in ("shape", "blades", "blade_curvature", "rotation_deg") if k in s}

    def render(device, precision="default"):
        return gl.render(lens0001, width=24, height=24, width_mm=s["width_mm"], center=center,
                         focus_offset_mm=s["focus"], f_number=s["f_number"], lights=[s["light"]],
                         wavelengths=[450.0, 650.0], samples=1 << 14, seed=3, device=device,
                         precision=precision, pixel_filter="point", **shape)
    # (pixel centres: the box filter's grid is the same kernel on more points, and its
    # GL path is tests/runtime/test_pixel_area.py's)

    ref = render("cpu", "double")
    cpu = rel_l2(render("cpu"), ref)
    img = render("gl")
    err = rel_l2(img, ref)
    print(f"{name}: CPU default vs double {cpu:.2e}, GL vs double {err:.2e}")
    assert np.all(np.isfinite(img)) and img.max() > 0
    assert err <= 3 * cpu + FLOAT_FLOOR


def test_gl_statistics_and_resume(gl, lens0001):
    # run(N) then run(M) adds the same passes as run(N + M): bit-identical sums when N is
    # a multiple of the pass (16384), as on the CPU. Sums saved from the GL device load
    # into a CPU render of the same scene (they do not depend on the device).
    kw = dict(width=16, height=16, width_mm=0.03, f_number=8.0, wavelengths=[550.0], seed=5)
    one = gl.create(lens0001, device="gl", **kw)
    one.run(1 << 15)
    two = gl.create(lens0001, device="gl", **kw)
    two.run(1 << 14)
    two.run(1 << 14)
    np.testing.assert_array_equal(one.image(), two.image())
    st = one.stats()
    assert st.samples_per_wavelength == 1 << 15
    assert st.splats == (1 << 15) * 16 * 16
    assert 0 < st.phase_terms < 55 and st.dark_fraction == 0.0
    cpu = gl.create(lens0001, device="cpu", **kw)
    path = Path(os.environ.get("TMPDIR", "/tmp")) / f"lensrt-gl-{os.getpid()}.phasors"
    try:
        one.save(path)
        cpu.load(path)
    finally:
        path.unlink(missing_ok=True)
    np.testing.assert_array_equal(cpu.image(), one.image())


@pytest.mark.parametrize("parts", [(1, 2047), (100, 100, 57), (300, 16500)])
def test_gl_split_runs_equal_one_run_bit_for_bit(gl, lens0001, tmp_path, parts):
    # Any split (issue 39, item 4): a run that ends inside a block of 256 samples keeps the
    # sums before that block, and the next run draws the block again whole, on the GL
    # device as on the CPU; the image read between runs changes nothing. The raw sums
    # (the phasor file's last bytes) compared
    kw = dict(width=16, height=16, width_mm=0.03, f_number=8.0, wavelengths=[550.0], seed=5)
    one = gl.create(lens0001, device="gl", **kw)
    one.run(sum(parts))
    split = gl.create(lens0001, device="gl", **kw)
    for n in parts:
        split.run(n)
        split.image()
    one.save(tmp_path / "one.phasors")
    split.save(tmp_path / "split.phasors")
    payload = 16 * 16 * 16  # re and im in double per pixel
    a = (tmp_path / "one.phasors").read_bytes()[-payload:]
    b = (tmp_path / "split.phasors").read_bytes()[-payload:]
    differ = sum(a[i:i + 8] != b[i:i + 8] for i in range(0, payload, 8))
    assert differ == 0, f"{differ} of {payload // 8} sums differ"
    assert split.stats().samples_per_wavelength == one.stats().samples_per_wavelength


def test_gl_unbiased_estimator_matches_cpu(gl, lens0001):
    # The unbiased estimator needs the sums of |X|^2 as well; with random samples the
    # two devices hold the same samples, so the images agree as in the fitted-lens test
    # (the CPU default vs double term is ~1e-5 here; FLOAT_FLOOR dominates).
    kw = dict(width=16, height=16, width_mm=0.03, f_number=8.0, wavelengths=[550.0], seed=9,
              sampler="random", estimator="unbiased", samples=1 << 14)
    ref = gl.render(lens0001, device="cpu", precision="double", **kw)
    cpu = rel_l2(gl.render(lens0001, device="cpu", **kw), ref)
    err = rel_l2(gl.render(lens0001, device="gl", **kw), ref)
    print(f"unbiased: CPU default vs double {cpu:.2e}, GL vs double {err:.2e}")
    assert err <= 3 * cpu + FLOAT_FLOOR


# ------------------------------------------------------------------ precision -----


def test_gl_precision_needed_and_sufficient(gl, lens0001):
    # Needed: a light 2 m in front of a perfect lens f = 50 mm at f/8 has a total path of
    # ~2051 mm = 3.7e6 waves. Kept in float (precision naive_float: the OPL not reduced
    # in double before the float splat) the phases scramble by up to +-1/8 wave and the
    # Strehl falls to ~0.82 (uniform +-pi/4 errors: sinc^2(pi/4) = 0.81).
    # Sufficient: reduced in double, then float trigonometry, the Strehl stays 1 and the
    # image matches the CPU's all-double analytic kernel to the float floor.
    f, f_number, dist, n = 50.0, 8.0, 2000.0, 1 << 14
    v = 1.0 / (1.0 / f - 1.0 / dist)
    lens = gl.analytic(sensor_distance_mm=f, focal_length_mm=f)
    cx, cy = gl.image_point(lens, (0.0, 0.0, dist), WL_NM, v - f)
    n_px, pitch = 9, LAM * f_number / 8
    peak = disc_amplitude_integral(f / (2 * f_number), v, 0.0) ** 2
    kw = dict(width=n_px, height=n_px, width_mm=n_px * pitch, center=(cx, cy),
              focus_offset_mm=v - f, f_number=f_number, lights=[(0.0, 0.0, dist)],
              wavelengths=[WL_NM], samples=n)
    cpu = gl.render(lens, device="cpu", precision="double", **kw)[0]
    default = gl.render(lens, device="gl", **kw)[0]
    naive = gl.render(lens, device="gl", precision="naive_float", **kw)[0]
    strehl = {"default": default.max() / peak, "naive_float": naive.max() / peak}
    print(f"GL Strehl at 2 m: {strehl}, GL default vs CPU double {rel_l2(default, cpu):.1e}")
    assert strehl["default"] >= 0.99
    assert strehl["naive_float"] < 0.9
    assert rel_l2(default, cpu) < FLOAT_FLOOR

    # The same on the fitted lens (light at 2 m, near its best focus): the default GL
    # path within the pruning bound 2 * 2 pi tol at the default tol, 3e-3 (0.038), of the
    # CPU's double render; naive far off (28% on the CPU).
    focus, n_px, pitch = 5.0, 15, 0.0015
    cx, cy = gl.image_point(lens0001, (0.0, 0.0, dist), WL_NM, focus)
    kw = dict(width=n_px, height=n_px, width_mm=n_px * pitch, center=(cx, cy),
              focus_offset_mm=focus, f_number=8.0, lights=[(0.0, 0.0, dist)],
              wavelengths=[WL_NM], samples=1 << 13)
    ref = gl.render(lens0001, device="cpu", precision="double", **kw)[0]
    default = rel_l2(gl.render(lens0001, device="gl", **kw)[0], ref)
    naive = rel_l2(gl.render(lens0001, device="gl", precision="naive_float", **kw)[0], ref)
    print(f"fitted lens at 2 m, GL vs CPU double: default {default:.1e}, naive {naive:.2f}")
    assert default < 4 * np.pi * 3e-3
    assert naive > 0.1


def test_gl_refuses_double_precision(gl, lens0001):
    with pytest.raises(LensrtError) as e:
        gl.create(lens0001, width=4, height=4, width_mm=0.01, precision="double", device="gl")
    assert e.value.code == INVALID_ARGUMENT and "CPU-only" in str(e.value)


# ---------------------------------------------------------------- closed forms -----


def test_gl_airy_first_dark_ring(gl):
    # Free space behind a disc of radius 0.1 mm, sensor at 5 m (far field): the first
    # dark ring at 1.21967 lambda z / D within 0.3%, as the CPU test checks (the
    # tolerance's reasoning is there: Sobol error ~1e-5, Fresnel residue ~5e-5).
    z, radius, n = 5000.0, 0.1, 1 << 14
    lens = gl.analytic(sensor_distance_mm=z)
    x0 = z * np.tan(np.arcsin(AIRY_ZERO * LAM / (2 * radius)))
    n_px, width = 41, 0.01 * x0
    row = gl.render(lens, width=n_px, height=1, width_mm=width, center=(x0, 0.0), radius_mm=radius,
                    wavelengths=[WL_NM], samples=n, device="gl")[0, 0]
    zero = parabola_vertex(centres(n_px, width, x0), row)
    print(f"GL Airy: first dark ring at {zero / x0 - 1:+.2e} relative")
    assert abs(zero / x0 - 1.0) < 3e-3


def test_gl_one_dimensional_slit_matches_cpu(gl):
    # The paper's 1D setting (cylindrical waves, one row): the same samples on both
    # devices, the CPU kernel in double. Only float trigonometry and float block sums
    # differ: FLOAT_FLOOR.
    lens = gl.analytic(sensor_distance_mm=100.0, one_dimensional=True)
    kw = dict(width=64, height=1, width_mm=0.4, shape="slit", slit_width_mm=0.2,
              wavelengths=[WL_NM], samples=1 << 14)
    cpu = gl.render(lens, device="cpu", **kw)
    img = gl.render(lens, device="gl", **kw)
    print(f"1D slit: GL vs CPU {rel_l2(img, cpu):.1e}")
    assert rel_l2(img, cpu) < FLOAT_FLOOR


# ---------------------------------------------------------------- no device -----


def test_missing_platform_is_a_clear_error_and_cpu_still_works(gl, lens0001, monkeypatch):
    # GLFW without an X server cannot make a context: the render names every platform
    # tried and why, and the same context still renders on the CPU.
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    rt = Lensrt(LIBRARY, gl_platform="glfw")
    lens = rt.load(LENS0001)
    with pytest.raises(LensrtError) as e:
        rt.create(lens, width=4, height=4, width_mm=0.01, device="gl")
    assert e.value.code == NO_DEVICE
    assert "glfw" in str(e.value) and "CPU device still works" in str(e.value)
    img = rt.render(lens, width=4, height=4, width_mm=0.01, wavelengths=[550.0], samples=256)
    assert np.all(np.isfinite(img)) and img.max() > 0


def test_cli_device_gl(gl, tmp_path):
    if not PSF.exists():
        pytest.skip(f"{PSF} is not built")
    out = tmp_path / "psf.exr"
    args = [str(PSF), "--lens", str(LENS0001), "-o", str(out), "--resolution", "16x16",
            "--size", "0.03", "--f-number", "8", "--wavelengths", "2", "--samples", "4096",
            "--device", "gl"]
    run = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "GL_RENDERER" in run.stderr and out.stat().st_size > 0
    # No device (GLFW without an X server): exit status 3 and nothing written
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    out.unlink()
    run = subprocess.run(args + ["--gl-platform", "glfw"], capture_output=True, text=True,
                         env=env, timeout=300)
    assert run.returncode == 3, run.stderr
    assert "no OpenGL 4.3 core context" in run.stderr and not out.exists()


GLFW_SCRIPT = """
import sys, numpy as np
sys.path.insert(0, sys.argv[1])
from lensrt_ctypes import Lensrt
rt = Lensrt(sys.argv[2], gl_platform=sys.argv[3])
info = rt.gl_info()
print(info["platform"], "|", info["renderer"], file=sys.stderr)
lens = rt.load(sys.argv[4])
img = rt.render(lens, width=12, height=12, width_mm=0.03, f_number=8.0, wavelengths=[550.0],
                samples=1 << 13, device="gl")
np.save(sys.argv[5], img)
"""


@pytest.mark.parametrize("platform", ["egl-surfaceless", "glfw"])
def test_fallback_platforms_render_the_same(gl, lens0001, tmp_path, platform):
    # Each platform of the fallback chain, forced, renders what the first one found
    # renders (the same driver here: identical up to float rounding). GLFW needs an X
    # server: xvfb-run provides one (CI installs xvfb and libglfw3).
    cmd = [sys.executable, "-c", GLFW_SCRIPT, str(ROOT / "runtime" / "python"), str(LIBRARY),
           platform, str(LENS0001), str(tmp_path / "img.npy")]
    if platform == "glfw":
        if not shutil.which("xvfb-run") or not ctypes.util.find_library("glfw"):
            no_device("the GLFW fallback needs xvfb-run and libglfw.so.3 (Debian: xvfb, libglfw3)")
        cmd = ["xvfb-run", "-a"] + cmd
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if run.returncode != 0 and "no OpenGL 4.3" in run.stderr:
        no_device(run.stderr.strip().splitlines()[-1])
    assert run.returncode == 0, run.stderr
    print(run.stderr.strip())
    ref = gl.render(lens0001, width=12, height=12, width_mm=0.03, f_number=8.0, wavelengths=[550.0],
                    samples=1 << 13, device="gl")
    assert rel_l2(np.load(tmp_path / "img.npy"), ref) < 1e-6


FINALISE_SCRIPT = """
import gc, sys
sys.path.insert(0, sys.argv[1])
from lensrt_ctypes import Lensrt
rt = Lensrt(sys.argv[2])
lens = rt.analytic(sensor_distance_mm=50.0, focal_length_mm=50.0)
for device in ("cpu", "gl"):
    r = rt.create(lens, width=8, height=8, width_mm=0.02, f_number=8.0, wavelengths=[550.0],
                  device=device)
    r.run(1 << 10)
    # A reference cycle holding the render and its context: the collector finalises them
    # in whatever order; here the context's finaliser is made to run first
    r.cycle = r
    rt.__del__()
    del r
    gc.collect()
    rt = Lensrt(sys.argv[2])
    lens = rt.analytic(sensor_distance_mm=50.0, focal_length_mm=50.0)
print("ok")
"""


def test_context_finalised_before_its_render(gl):
    # pytest's final garbage collection once finalised a Lensrt before a Render of it, and
    # the render's destruction then used the freed context (and its GL device): a crash at
    # exit. The binding must destroy renders with their context, and a render finalised
    # afterwards must do nothing. Run in a child so a crash fails this test, not the run.
    run = subprocess.run([sys.executable, "-c", FINALISE_SCRIPT, str(ROOT / "runtime" / "python"),
                          str(LIBRARY)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and run.stdout.strip() == "ok", (run.returncode, run.stderr)
