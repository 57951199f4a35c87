"""scenes/night_street.py, issue 38's demo scene, and runtime/tools/image_sheet.py.

The scene is rendered small; the lamps must be its HDR peaks and land where the pinhole
formula puts them (a closed form from the focal length and the sensor width, not
Mitsuba's own projection), so the EXR's attributes describe the camera that made it."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")
OpenEXR = pytest.importorskip("OpenEXR")

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scenes"))
sys.path.insert(0, str(ROOT / "runtime" / "tools"))
import image_sheet  # noqa: E402  (needs the path above)
import night_street  # noqa: E402  (needs the path above)

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
# The lamps without a shade: the whole bulb shows, so its image is centred on its centre
UNSHADED = ("lantern_left", "lantern_right", "bollard", "centre")


def read_exr(path: Path) -> tuple[dict[str, object], dict[str, np.ndarray]]:
    with OpenEXR.File(str(path), separate_channels=True) as f:
        return dict(f.header()), {n: np.asarray(c.pixels) for n, c in f.channels().items()}


def pinhole_pixel(point: tuple[float, float, float], width: int, height: int,
                  focal_mm: float, sensor_mm: float) -> tuple[float, float]:
    """(column, row), pixel edges at integers, row 0 at the top: the camera at
    night_street.CAMERA looks along -z, +x right, +y up; a point at depth d in front of it
    lands f x / d mm right of the centre and f y / d mm above it, on pixels sensor_mm /
    width wide."""
    x, y, z = (p - c for p, c in zip(point, night_street.CAMERA, strict=True))
    pitch = sensor_mm / width
    return width / 2 + focal_mm * x / -z / pitch, height / 2 - focal_mm * y / -z / pitch


def blob_centre(lum: np.ndarray, col: float, row: float, half: int = 3) -> tuple[float, float]:
    """The centroid (pixel centres at +0.5) of the pixels above a tenth of the brightest in
    a window around (col, row), weighted by luminance."""
    c0, r0 = max(int(col) - half, 0), max(int(row) - half, 0)
    win = lum[r0: int(row) + half + 1, c0: int(col) + half + 1]
    w = np.where(win > 0.1 * win.max(), win, 0.0)
    rows, cols = np.indices(win.shape)
    return (c0 + 0.5 + float((w * cols).sum() / w.sum()),
            r0 + 0.5 + float((w * rows).sum() / w.sum()))


def check_lamps(rgb: np.ndarray, focal_mm: float, sensor_mm: float) -> None:
    """Every unshaded lamp in the frame, half a pixel wide or more, is a peak where the
    pinhole formula puts it."""
    height, width = rgb.shape[:2]
    pitch = sensor_mm / width
    lum = rgb @ LUMINANCE
    lit = np.median(lum[lum > 0])
    seen = 0
    for lamp in night_street.lamps():
        col, row = pinhole_pixel(lamp.center, width, height, focal_mm, sensor_mm)
        depth = night_street.CAMERA[2] - lamp.center[2]
        wide = 2 * lamp.radius * focal_mm / depth / pitch >= 0.5
        if not (lamp.name in UNSHADED and wide and 3 <= col < width - 3
                and 3 <= row < height - 3):
            continue
        seen += 1
        # A lamp pixel, 10^3 or more above the lit surfaces
        assert lum[int(row), int(col)] > 1e3 * lit, lamp.name
        c, r = blob_centre(lum, col, row)
        assert abs(c - col) < 1.0 and abs(r - row) < 1.0, (lamp.name, (c, r), (col, row))
    assert seen >= 3  # lamps near two corners and the centre at least


@pytest.fixture(scope="module")
def cli_render(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The script run as a user runs it: 35 mm on a 36 mm sensor, 192 x 108, 16 spp (a
    distant lamp is under a pixel wide: enough samples to find it)."""
    out = tmp_path_factory.mktemp("street") / "street.exr"
    run = subprocess.run([sys.executable, str(ROOT / "scenes" / "night_street.py"), "-o",
                          str(out), "--width", "192", "--height", "108", "--spp", "16",
                          "--focal-mm", "35"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return out


def test_exr_is_linear_rgb_with_the_camera(cli_render: Path) -> None:
    header, planes = read_exr(cli_render)
    assert sorted(planes) == ["B", "G", "R"]
    assert header["lensfit/pinholeFocalMm"] == pytest.approx(35.0)
    assert header["lensfit/sensorWidthMm"] == pytest.approx(36.0)
    rgb = np.stack([planes[c] for c in "RGB"], axis=-1)
    assert rgb.shape == (108, 192, 3) and rgb.dtype == np.float32
    assert np.all(np.isfinite(rgb)) and rgb.min() >= 0.0
    # HDR: the lamps are the peaks, far above the median pixel
    lum = rgb @ LUMINANCE
    assert lum.max() / np.median(lum) > 1e3
    assert lum.max() / np.median(lum[lum > 0]) > 1e3


def test_lamps_land_where_the_pinhole_puts_them(cli_render: Path) -> None:
    _, planes = read_exr(cli_render)
    check_lamps(np.stack([planes[c] for c in "RGB"], axis=-1), 35.0, 36.0)


def test_lamps_at_another_focal_length_and_sensor() -> None:
    # 40 mm on a 45 mm wide sensor (the field of a 32 mm lens on full frame), in-process
    rgb = night_street.render(160, 90, 40.0, 16, sensor_width_mm=45.0, progress=False)
    check_lamps(rgb, 40.0, 45.0)
    # Not mirrored: the left lantern is in the left half, the bollard in the right
    width, height = 160, 90
    lamps = {lamp.name: lamp for lamp in night_street.lamps()}
    assert pinhole_pixel(lamps["lantern_left"].center, width, height, 40.0, 45.0)[0] < width / 3
    assert pinhole_pixel(lamps["bollard"].center, width, height, 40.0, 45.0)[0] > 2 * width / 3
    fov = night_street.horizontal_fov_deg(40.0, 45.0)
    assert fov == pytest.approx(2 * math.degrees(math.atan(22.5 / 40.0)))


def test_render_is_deterministic() -> None:
    a = night_street.render(48, 27, 50.0, 2, progress=False)
    b = night_street.render(48, 27, 50.0, 2, progress=False)
    assert np.array_equal(a, b)


def write_rgb_exr(path: Path, planes: dict[str, np.ndarray]) -> None:
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {k: v.astype(np.float32) for k, v in planes.items()}) as f:
        f.write(str(path))


def test_image_sheet_writes_three_panels(tmp_path: Path) -> None:
    from PIL import Image

    rng = np.random.default_rng(1)
    h, w = 36, 64
    plain = rng.uniform(0.0, 1.0, (h, w, 3))
    plain[10, 20] = 1e4  # a lamp
    write_rgb_exr(tmp_path / "pinhole.exr", {c: plain[..., k] for k, c in enumerate("RGB")})
    # A layered file: the total unprefixed, the direct and flare layers prefixed
    flare = 1e-3 * rng.uniform(0.0, 1.0, (h, w, 3))
    layered = {}
    for k, c in enumerate("RGB"):
        layered[c] = plain[..., k] + flare[..., k]
        layered[f"direct.{c}"] = plain[..., k]
        layered[f"flare.{c}"] = flare[..., k]
    write_rgb_exr(tmp_path / "lens.exr", layered)
    out = tmp_path / "sheet.png"
    run = subprocess.run([sys.executable, str(ROOT / "runtime" / "tools" / "image_sheet.py"),
                          "-o", str(out), "--title", "test",
                          "--panel", str(tmp_path / "pinhole.exr"), "pinhole",
                          "--panel", str(tmp_path / "lens.exr"), "through the lens",
                          "--panel", f"{tmp_path / 'lens.exr'}:flare", "flare"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    with Image.open(out) as img:
        assert img.size == (3 * w + 4 * image_sheet.GAP, h + image_sheet.GAP
                            + image_sheet.LABEL_HEIGHT + image_sheet.TITLE_HEIGHT)
        pixels = np.asarray(img.convert("RGB"))
    # The lamp is white in the first panel, at its pixel
    y0, x0 = image_sheet.TITLE_HEIGHT, image_sheet.GAP
    assert pixels[y0 + 10, x0 + 20].min() == 255
    # The flare panel has its own exposure: not black although 10^-3 of the others
    x2 = x0 + 2 * (w + image_sheet.GAP)
    assert pixels[y0: y0 + h, x2: x2 + w].mean() > 40
    # A layer the file lacks is an error naming the layers it has
    run = subprocess.run([sys.executable, str(ROOT / "runtime" / "tools" / "image_sheet.py"),
                          "-o", str(out), "--panel", f"{tmp_path / 'pinhole.exr'}:flare", "x"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode != 0 and "layers with R, G, B: ''" in run.stderr
