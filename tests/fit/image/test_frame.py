"""The input frame of `lensfit image` (issue 38): read as authored, refused in one line
naming the file and the value otherwise, and its geometry and bank grid in closed form."""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from lensfit.banks.spec import load_spec
from lensfit.image.bank import frame_bank_spec, node_counts, spec_toml, tan_grid
from lensfit.image.frame import FrameError, Geometry, frame_geometry, read_frame
from lensfit.image.through import depth_weights, slice_distances

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "runtime" / "python"))


def write_exr(path: Path, channels: dict[str, np.ndarray], **attributes) -> Path:
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              **attributes}
    with OpenEXR.File(header, {k: np.ascontiguousarray(v) for k, v in channels.items()}) as f:
        f.write(str(path))
    return path


def rgb(h: int = 4, w: int = 6, value: float = 1.0) -> dict[str, np.ndarray]:
    return {c: np.full((h, w), value, np.float32) for c in "RGB"}


def test_rgb_spectral_and_depth_frames_are_read_as_written(tmp_path):
    planes = rgb()
    planes["G"][1, 2] = 7.0
    f = read_frame(write_exr(tmp_path / "a.exr", planes))
    assert f.kind == "rgb" and f.shape == (6, 4) and f.planes[1, 1, 2] == 7.0
    assert f.depth_mm is None
    spectral = {"S0.600,000000nm": np.full((3, 5), 2.0, np.float32),
                "S0.450,000000nm": np.full((3, 5), 1.0, np.float32),
                "Z": np.full((3, 5), 5000.0, np.float32)}
    g = read_frame(write_exr(tmp_path / "b.exr", spectral))
    assert g.kind == "spectral" and g.wavelengths_nm == (450.0, 600.0)
    assert g.planes[0, 0, 0] == 1.0 and g.planes[1, 0, 0] == 2.0  # in wavelength order
    assert g.depth_mm is not None and g.depth_mm[2, 4] == 5000.0


@pytest.mark.parametrize("channel,value,pixel", [("G", np.nan, (3, 1)), ("B", -1.0, (0, 2)),
                                                 ("R", np.inf, (5, 3))])
def test_a_bad_value_is_named_with_its_channel_and_pixel(tmp_path, channel, value, pixel):
    planes = rgb()
    planes[channel][pixel[1], pixel[0]] = value
    path = write_exr(tmp_path / "bad.exr", planes)
    with pytest.raises(FrameError) as e:
        read_frame(path)
    msg = str(e.value)
    assert str(path) in msg and f"'{channel}'" in msg
    assert f"(x {pixel[0]}, y {pixel[1]})" in msg and repr(float(value)) in msg


def test_depth_must_be_a_positive_distance(tmp_path):
    planes = rgb()
    planes["Z"] = np.full((4, 6), 1000.0, np.float32)
    planes["Z"][2, 3] = 0.0
    with pytest.raises(FrameError, match=r"'Z' pixel \(x 3, y 2\) = 0.0: expected a positive"):
        read_frame(write_exr(tmp_path / "z.exr", planes))


def test_unusable_files_are_refused_naming_them(tmp_path):
    no_light = write_exr(tmp_path / "n.exr", {"A": np.ones((2, 2), np.float32)})
    with pytest.raises(FrameError, match=r"n\.exr: no usable channels \(channels: A\)"):
        read_frame(no_light)
    text = tmp_path / "t.exr"
    text.write_text("not an EXR")
    with pytest.raises(FrameError, match=r"t\.exr: not an EXR"):
        read_frame(text)
    with pytest.raises(FrameError, match="no such file"):
        read_frame(tmp_path / "missing.exr")
    fifo = tmp_path / "fifo.exr"
    os.mkfifo(fifo)
    with pytest.raises(FrameError, match="not a regular file"):
        read_frame(fifo)  # never opened: a FIFO would block


@pytest.mark.parametrize("key,value", [("oiio:ColorSpace", "sRGB"), ("colorSpace", "Rec709 gamma"),
                                       ("interpretation", "Filmic Log")])
def test_a_display_encoded_frame_is_not_light(tmp_path, key, value):
    path = write_exr(tmp_path / "s.exr", rgb(), **{key: value})
    with pytest.raises(FrameError, match=f"attribute '{key}'.*not linear"):
        read_frame(path)
    # linear tags are light
    read_frame(write_exr(tmp_path / "l.exr", rgb(), **{key: "lin_rec709 scene-linear"}))


def test_integer_channels_are_not_light(tmp_path):
    planes = {c: np.ones((2, 2), np.uint32) for c in "RGB"}
    with pytest.raises(FrameError, match="holds integers"):
        read_frame(write_exr(tmp_path / "u.exr", planes))


def test_geometry_is_the_pinhole_in_closed_form(tmp_path):
    f = read_frame(write_exr(tmp_path / "g.exr", rgb(4, 8), **{
        "lensfit/pinholeFocalMm": np.array([50.0]), "lensfit/sensorWidthMm": np.array([16.0])}))
    g = frame_geometry(f, 100.0)
    assert g.pitch_mm == 2.0 and g.focal_x_mm == 50.0  # the file's, not the lens's
    x, y = g.pixel_xy_mm()
    assert x[0] == -7.0 and x[-1] == 7.0 and y[0] == 3.0 and y[-1] == -3.0  # row 0 at +y
    (x0, x1), (y0, y1) = g.edge_fields_deg()
    assert math.isclose(x1, math.degrees(math.atan(8 / 50)), rel_tol=1e-14)
    assert math.isclose(y0, -math.degrees(math.atan(4 / 50)), rel_tol=1e-14)
    assert frame_geometry(f, 100.0, pixel_mm=0.01, focal_mm=80).focal_x_mm == 80
    with pytest.raises(FrameError, match="sensor width = -1"):
        frame_geometry(f, 100.0, sensor_width_mm=-1.0)


def test_depth_shares_are_a_partition_of_unity_linear_in_inverse_distance():
    d = (8000.0, 4000.0, 2000.0)  # farthest first: 1/d ascending
    depth = np.array([[8000.0, 6000.0, 4000.0, 3000.0, 2000.0, 1e9, 500.0]])
    w = depth_weights(depth, d)
    assert np.allclose(w.sum(axis=0), 1.0)
    assert np.allclose(w[:, 0, 0], [1, 0, 0]) and np.allclose(w[:, 0, 2], [0, 1, 0])
    u = 1 / 6000.0  # between 1/8000 and 1/4000: linear in 1/d
    assert math.isclose(w[1, 0, 1], (u - 1 / 8000) / (1 / 4000 - 1 / 8000), rel_tol=1e-12)
    assert np.allclose(w[:, 0, 5], [1, 0, 0]) and np.allclose(w[:, 0, 6], [0, 0, 1])  # ends
    s = slice_distances(np.array([[2000.0, 8000.0]]), 3, 0.0)
    assert np.allclose(1 / np.array(s), np.linspace(1 / 8000, 1 / 2000, 3))
    with pytest.raises(Exception, match="nearer than the lens was fitted"):
        slice_distances(np.array([[200.0, 8000.0]]), 3, 1000.0)


def test_the_frames_bank_spec_is_a_valid_spec_on_a_tangent_grid(tmp_path):
    g = Geometry(width=1920, height=1080, pitch_mm=0.01875, focal_x_mm=100, focal_y_mm=100)
    assert node_counts(g, 9) == (9, 5)
    t = np.tan(np.radians(tan_grid(-10.0, 10.0, 5)))
    assert np.allclose(np.diff(t), np.diff(t)[0], rtol=1e-8)
    spec = frame_bank_spec("img", ROOT / "generated" / "0001-angenieux-double-gauss" /
                           "lens0001.table", g, f_number=8, focus_offset_mm=0.0,
                           distances_mm=(math.inf,), wavelengths_nm=(450.0, 550.0),
                           half_px=8, nodes_x=9, aperture={"shape": "blades", "blades": 7},
                           target_error=0.02)
    p = tmp_path / "s.toml"
    p.write_text(spec_toml(spec))
    s = load_spec(p)  # the bank module's own parser accepts it
    assert s.window.pixels == (17, 17) and math.isclose(s.window.size_mm[0], 17 * 0.01875)
    assert s.grid.field_x_deg[0] == -s.grid.field_x_deg[-1]
    assert math.isclose(s.grid.field_x_deg[-1], math.degrees(math.atan(18 / 100)), rel_tol=1e-8)
    assert s.aperture.blades == 7 and s.grid.distances_mm == (math.inf,)
