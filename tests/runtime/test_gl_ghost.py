"""Ghost tables on the GL path (issue 13, deliverable 4): P_clip tested as on the CPU.

Side P_o: P_clip per sample in samples.comp (double, as the CPU host does); side P_s:
pairs decided per pixel from bounds in pixels.comp and tested per splat in splat.comp
(float, from the stop monomials). The ghosts are lens0001's P_o and P_s with hand-made
P_clip systems (test_flares_tool.ghost_table): a smaller stop of radius r0 inside the
render's stop R (a housing pair on side P_o; on side P_s a stop-crossing pair in mm plus a
housing pair that never blocks and one that blocks beyond r1 > r0). Same seed and
samples on both devices, the CPU in double the reference, and the tolerance of
test_gl.py's CPU agreement: the GL image no further from the double one than 3x the CPU
default's distance plus the float floor. Needs an OpenGL 4.3 device (LENSRT_REQUIRE_GL:
a missing one fails).

Stop crossings of a bladed or slit stop: a stop pair (x_s1, y_s1) = (2 x_a, 2 y_a) mm
passes where 2 a lies inside the render's aperture (7 straight blades rotated 10 deg;
64 blades of curvature 0.3, the most GLSL edge tests; two 3 mm slits 3.5 mm apart),
tested per sample in samples.comp (side P_o), decided per pixel from the box of possible
crossings in pixels.comp and tested per splat in splat.comp's straight-line code (side
P_s); against the CPU in double (whose tests are test_ghost.c's closed forms) at the same
tolerance.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from test_flares_tool import LENS0001, ghost_table
from test_gl import FLOAT_FLOOR, gl  # noqa: F401  (the session's GL context fixture)
from test_validation import rel_l2

R, R0, R1 = 7.0, 4.5, 5.5


def tables() -> dict[str, str]:
    text = LENS0001.read_text()
    s = float(re.search(r"^input x_a \S+ \S+ (\S+) affine", text, re.M).group(1))

    def pair(name: str, unit: str, c: float) -> list[tuple[str, str, list[str]]]:
        return [(f"x_{name}", unit, [f"0 0 0 1 0 0 {s * c!r}"]),
                (f"y_{name}", unit, [f"0 0 0 0 1 0 {s * c!r}"])]

    return {
        "P_o": ghost_table(text, "P_o", pair("h0", "1", 1 / R0), 0, 2),
        "P_s": ghost_table(text, "P_s", pair("h0", "1", 1e-6 / R0) + pair("s1", "mm", R / R0)
                           + pair("h2", "1", 1 / R1)),
    }


def _gl_against_cpu(gl, path, what: str, **aperture) -> None:  # noqa: F811
    """The ghost table at ``path`` rendered on GL and on the CPU (default and double
    precision), same seed and samples, around the direct image of a light at (-6, -4) deg:
    GL within 3x the CPU default's distance from the double image plus the float floor;
    and the ghost's clip matters (the direct table with the same stop gives another
    image)."""
    ghost = gl.load(path)
    direct = gl.load(LENS0001)
    center = gl.image_point(direct, (-6.0, -4.0), 580.0, 0.2)

    def render(lens, device, precision="default"):
        return gl.render(lens, width=24, height=24, width_mm=0.06, center=center,
                         focus_offset_mm=0.2, radius_mm=R, lights=[(-6.0, -4.0)],
                         wavelengths=[450.0, 650.0], samples=1 << 14, seed=3, device=device,
                         precision=precision, pixel_filter="point", **aperture)

    ref = render(ghost, "cpu", "double")
    cpu = rel_l2(render(ghost, "cpu"), ref)
    err = rel_l2(render(ghost, "gl"), ref)
    print(f"{what}: GL {err:.3g}, CPU default {cpu:.3g} relative L2 against CPU double")
    assert err <= 3 * cpu + FLOAT_FLOOR, (err, cpu)
    assert rel_l2(render(direct, "cpu", "double"), ref) > 0.1
    assert np.sum(ref) > 0


@pytest.mark.parametrize("side", ["P_o", "P_s"])
def test_gl_ghost_matches_cpu(gl, tmp_path, side):  # noqa: F811
    path = tmp_path / f"ghost_{side}.table"
    path.write_text(tables()[side])
    _gl_against_cpu(gl, path, side)


SHAPES = {
    "blades": dict(shape="blades", blades=7, rotation_deg=10.0),
    "curved": dict(shape="blades", blades=64, blade_curvature=0.3, rotation_deg=3.0),
    "slits": dict(shape="slit", slit_width_mm=3.0, slit_separation_mm=3.5),
}


@pytest.mark.parametrize(("side", "shape"),
                         [("P_o", "blades"), pytest.param("P_s", "blades", marks=pytest.mark.slow),
                          ("P_s", "curved"),
                          pytest.param("P_s", "slits", marks=pytest.mark.slow)])  # 17 s each
def test_gl_ghost_shaped_stop_matches_cpu(gl, tmp_path, side, shape):  # noqa: F811
    text = LENS0001.read_text()
    s = float(re.search(r"^input x_a \S+ \S+ (\S+) affine", text, re.M).group(1))
    crossing = [("x_s1", "mm", [f"0 0 0 1 0 0 {2 * s!r}"]),
                ("y_s1", "mm", [f"0 0 0 0 1 0 {2 * s!r}"])]
    housing = [("x_h0", "1", [f"0 0 0 1 0 0 {s / R1!r}"]),
               ("y_h0", "1", [f"0 0 0 0 1 0 {s / R1!r}"])]
    path = tmp_path / f"ghost_{side}.table"
    path.write_text(ghost_table(text, side, housing + crossing, *((0, 2) if side == "P_o" else ())))
    _gl_against_cpu(gl, path, f"{side}, {shape}", **SHAPES[shape])
