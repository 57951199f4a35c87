"""runtime/python/lensrt_exr.py (lensrt's spectral EXR files through the OpenEXR bindings,
grouped by layer and wavelength) against the library's own images: a plain file
(lensrt_render_write_exr) and a layered one (lensrt_layers_write_exr through the ctypes
binding) read back bit for bit, layer by layer;
unknown layers, other files and damaged ones refused with a ValueError naming the file.
Needs the library built with EXR (skipped otherwise, as the writer then refuses)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "runtime" / "python"))

from lensrt_ctypes import LensrtError  # noqa: E402
from lensrt_exr import exr_layers, read_spectral_exr  # noqa: E402

WAVELENGTHS = [610.0, 450.5, 530.25]  # out of order: the reader sorts them


def scene(rt, lens, light, seed, width=9):
    r = rt.create(lens, width=width, height=37, width_mm=0.03, height_mm=0.1, f_number=8.0,
                  wavelengths=WAVELENGTHS, lights=[light], seed=seed)
    r.run(1024)
    return r


@pytest.fixture(scope="module")
def renders(rt):
    lens = rt.analytic(sensor_distance_mm=50.0, focal_length_mm=50.0)
    return [scene(rt, lens, (0.0, 0.0), 1), scene(rt, lens, (0.005, 0.0, 0.0, 0.5), 2),
            scene(rt, lens, (0.0, -0.01, 0.0, 2.0), 3), scene(rt, lens, (0.0, 0.0), 4, width=10)]


def write_or_skip(write) -> None:
    try:
        write()
    except LensrtError as exc:
        if "without OpenEXR" in str(exc):
            pytest.skip("lensrt built without OpenEXR")
        raise


def in_file_order(image: np.ndarray) -> np.ndarray:
    """A render's image (wavelengths in the render's order) in ascending wavelength."""
    return image[np.argsort(WAVELENGTHS)]


def test_plain_file_bit_for_bit(tmp_path, renders):
    path = tmp_path / "psf.exr"
    write_or_skip(lambda: renders[0].write_exr(path))
    img = read_spectral_exr(path)
    assert exr_layers(path) == [""]
    assert img.wavelengths_nm.tolist() == sorted(WAVELENGTHS)
    assert list(img.channels.values()) == ["S0.450,500000nm", "S0.530,250000nm", "S0.610,000000nm"]
    # 37 rows: three ZIP chunks of 16 scanlines, the last one partial
    assert np.array_equal(img.spectral, in_file_order(renders[0].image()))
    assert np.array_equal(img.rgb, renders[0].rgb())
    assert img.attributes["spectralLayoutVersion"] == "1.0"
    assert img.attributes["lensrt/fNumber"] == 8.0


def test_layered_file_bit_for_bit(tmp_path, renders, rt):
    path = tmp_path / "flare.exr"
    direct, g1, g2 = renders[:3]
    write_or_skip(lambda: rt.write_exr_layers(path, {"direct": [direct], "flare": [g1, g2]}))
    assert exr_layers(path) == ["", "direct", "flare"]
    total, d, f = (read_spectral_exr(path, layer) for layer in ("", "direct", "flare"))
    assert list(d.channels.values())[0] == "direct.S0.450,500000nm"
    assert np.array_equal(d.spectral, in_file_order(direct.image()))
    assert np.array_equal(d.rgb, direct.rgb())
    # the flare and the total: the renders' images added in double, rounded once to float
    flare = (g1.image().astype(np.float64) + g2.image()).astype(np.float32)
    everything = (direct.image().astype(np.float64) + g1.image() + g2.image()
                  ).astype(np.float32)
    assert np.array_equal(f.spectral, in_file_order(flare))
    assert np.array_equal(total.spectral, in_file_order(everything))
    # the default layer is the unprefixed one
    assert np.array_equal(read_spectral_exr(path).spectral, total.spectral)
    assert "direct: " in total.attributes["lensrt/layers"]


def test_refusals_name_the_file(tmp_path, renders, rt):
    path = tmp_path / "flare.exr"
    layers = {"direct": [renders[0]], "flare": [renders[1]]}
    write_or_skip(lambda: rt.write_exr_layers(path, layers))
    with pytest.raises(ValueError, match=r"flare\.exr.*layer 'glare'.*'direct', 'flare'"):
        read_spectral_exr(path, "glare")
    other = tmp_path / "other.exr"
    other.write_bytes(b"not an EXR file at all")
    with pytest.raises(ValueError, match=r"other\.exr.*OpenEXR cannot read it"):
        read_spectral_exr(other)
    cut = tmp_path / "cut.exr"
    cut.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(ValueError, match=r"cut\.exr"):
        read_spectral_exr(cut)
    # the writer's refusals reach Python with the library's message
    with pytest.raises(LensrtError, match=r"'fl\.are'"):
        rt.write_exr_layers(tmp_path / "x.exr", {"direct": [renders[0]], "fl.are": [renders[1]]})
    with pytest.raises(LensrtError, match="10 x 37"):
        rt.write_exr_layers(tmp_path / "x.exr", {"direct": [renders[0]], "flare": [renders[3]]})
    assert not (tmp_path / "x.exr").exists()


def test_damaged_files_give_value_errors(tmp_path, renders, rt):
    """The reader's contract on untrusted bytes: every damaged copy of a layered file (bytes
    changed in the header, the offset table and the chunks; cut short) is read or refused
    with a ValueError naming the file, never another exception. 400 mutants from a fixed
    seed (a few seconds)."""
    path = tmp_path / "flare.exr"
    layers = {"direct": [renders[0]], "flare": [renders[1], renders[2]]}
    write_or_skip(lambda: rt.write_exr_layers(path, layers))
    data = path.read_bytes()
    rng = np.random.default_rng(13)
    bad = tmp_path / "bad.exr"
    refused = 0
    for k in range(400):
        b = bytearray(data)
        if k % 4 == 0:  # cut short
            b = b[:int(rng.integers(0, len(b)))]
        else:  # 1-3 bytes changed, half of the time within the header and offset table
            span = len(b) if k % 2 else min(len(b), 1500)
            for at in rng.integers(0, span, int(rng.integers(1, 4))):
                b[at] = int(rng.integers(0, 256))
        bad.write_bytes(bytes(b))
        for layer in ("", "flare"):
            try:
                read_spectral_exr(bad, layer)
            except ValueError as exc:
                assert "bad.exr" in str(exc), exc
                refused += 1
    assert refused > 200  # most damage is seen (cuts always are)
