"""An image through the lens (lensrt_image_*, 0.11.0) through the ctypes binding's Image:
a shift-invariant synthetic bank (every node the same Gaussian PSF, chief points at
f tan(field): no distortion) whose direct layer must be scipy's (pocketfft's) FFT
convolution of the input with PSF / axis power, plus the layers, stats, sources and a
refusal through the binding. The deeper checks (energy, seams, distortion, every refusal)
are tests/runtime/test_image.c's; this one measures the library against numpy's FFT.

The bank is written here: uncompressed scanline EXRs (packed by hand, as
tests/runtime/bank_files.h does in C) with the lensrt/bankNode attribute of a
`registration channel` bank, and its stamped index.
"""

from __future__ import annotations

import math
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from lensrt_ctypes import IMAGE_DIRECT, IMAGE_FLARE, Bank, Image, LensrtError, Result
from scipy.signal import fftconvolve

FOCAL_MM = 10.0
PITCH_MM = 0.005
SIZE = 9                       # PSF pixels per side (odd: centred on a pixel)
SIGMA = 1.3                    # pixels
FIELDS_X = [-1.2, -0.6, 0.0, 0.6, 1.2]
FIELDS_Y = [-1.0, 0.0, 1.0]
WAVELENGTH_NM = 550.0


def spectral_name(nm: float) -> str:
    micro = int(math.floor(nm * 1e6 + 0.5))
    return f"S0.{micro // 1000000},{micro % 1000000:06d}nm"


def attr(name: str, kind: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value


def write_exr(path: Path, plane: np.ndarray, identity: str) -> None:
    """One FLOAT channel, no compression, one scanline a chunk."""
    h, w = plane.shape
    box = struct.pack("<4i", 0, 0, w - 1, h - 1)
    chlist = (spectral_name(WAVELENGTH_NM).encode() + b"\0"
              + struct.pack("<iB3xii", 2, 0, 1, 1) + b"\0")
    header = (b"\x76\x2f\x31\x01\x02\x00\x00\x00" + attr("channels", "chlist", chlist)
              + attr("compression", "compression", b"\0") + attr("dataWindow", "box2i", box)
              + attr("displayWindow", "box2i", box) + attr("lineOrder", "lineOrder", b"\0")
              + attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
              + attr("screenWindowCenter", "v2f", struct.pack("<2f", 0.0, 0.0))
              + attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
              + attr("lensrt/bankNode", "string", identity.encode()) + b"\0")
    start = len(header) + 8 * h
    chunks = [struct.pack("<ii", y, 4 * w) + plane[y].astype("<f4").tobytes() for y in range(h)]
    offsets, at = [], start
    for c in chunks:
        offsets.append(at)
        at += len(c)
    path.write_bytes(header + struct.pack(f"<{h}Q", *offsets) + b"".join(chunks))


def gaussian() -> np.ndarray:
    x = np.arange(SIZE) + 0.5 - SIZE / 2
    g = np.exp(-(x[None, :] ** 2 + x[:, None] ** 2) / (2 * SIGMA ** 2))
    return (g / g.sum()).astype(np.float32)


def write_bank(folder: Path) -> Path:
    (folder / "nodes").mkdir(parents=True)
    psf = gaussian()
    r = repr
    lines = ["lensrt-bank 1", "lens synthetic", "table_crc32 00000000", f"width {SIZE}",
             f"height {SIZE}", f"pixel_mm {r(PITCH_MM)} {r(PITCH_MM)}", "registration channel",
             f"wavelengths_nm 1 {r(WAVELENGTH_NM)}", "f_numbers 1 8.0", "focus_offsets_mm 1 0.0",
             "distances_mm 1 0.0",
             " ".join(["field_x_deg", str(len(FIELDS_X)), *map(r, FIELDS_X)]),
             " ".join(["field_y_deg", str(len(FIELDS_Y)), *map(r, FIELDS_Y)]),
             f"nodes {len(FIELDS_X) * len(FIELDS_Y)}"]
    k = 0
    for iy, fy in enumerate(FIELDS_Y):
        for ix, fx in enumerate(FIELDS_X):
            chief = (FOCAL_MM * math.tan(math.radians(fx)), FOCAL_MM * math.tan(math.radians(fy)))
            rel = f"nodes/y{iy}-x{ix}.exr"
            write_exr(folder / rel, psf, f"0 0 0 {iy} {ix} 8.0 0.0 0.0 {r(fx)} {r(fy)}")
            crc = zlib.crc32((folder / rel).read_bytes())
            lines.append(f"node {k} 0 0 0 {iy} {ix} {r(chief[0])} {r(chief[1])} 0.001 "
                         f"{crc:08x} {rel}")
            lines.append(f"chief {k} {r(chief[0])} {r(chief[1])}")
            k += 1
    body = "\n".join(lines) + "\n"
    index = folder / "bank.index"
    index.write_text(body + f"checksum crc32 {zlib.crc32(body.encode()):08x}\n")
    return index


@pytest.fixture(scope="module")
def bank(rt, tmp_path_factory):
    if not hasattr(rt.lib, "lensrt_image_create"):
        pytest.skip("this lensrt library predates lensrt_image_* (0.11.0): rebuild it")
    b = Bank(rt, write_bank(tmp_path_factory.mktemp("image-bank")))
    try:
        b.load_nodes()
    except LensrtError as e:
        if e.code == Result.UNSUPPORTED:
            pytest.skip(f"a build without OpenEXR: {e}")
        raise
    yield b
    b.close()


def test_direct_layer_is_the_fft_convolution(bank) -> None:
    """The direct layer of a shift-invariant bank is the input convolved with the PSF
    divided by the axis PSF's power (1 here: the Gaussian is normalised), as
    scipy.signal.fftconvolve (pocketfft) computes it, to float rounding."""
    h, w = 40, 48
    rng = np.random.default_rng(7)
    frame = rng.random((2, h, w), dtype=np.float32)
    weights = np.array([[1.0], [0.5]])
    with Image(bank, width=w, height=h, focal_x_mm=FOCAL_MM, channel_weights=weights) as im:
        im.run(frame)
        direct = im.layer(IMAGE_DIRECT)
        flare = im.layer(IMAGE_FLARE)
        stats = im.stats()
        sources = im.sources()
    psf = gaussian().astype(np.float64)
    kernel = psf / psf.astype(np.float64).sum()
    for c in range(2):
        ref = fftconvolve(frame[c].astype(np.float64), kernel, mode="same")
        err = np.max(np.abs(direct[c] - ref))
        assert err <= 2e-6 * ref.max(), f"channel {c}: {err} from pocketfft's of {ref.max()}"
    assert direct.shape == (2, h, w) and direct.dtype == np.float32
    assert not flare.any() and sources == []
    assert stats["n_nodes"] == 15 and stats["fft_width"] > 0 and stats["n_sources"] == 0
    assert stats["worst_flare_error"] == -1.0


def test_refusals_through_the_binding(bank) -> None:
    """A frame outside the field grid and a NaN pixel raise LensrtError with the value."""
    with pytest.raises(LensrtError, match=r"field_x spans"):
        Image(bank, width=200, height=40, focal_x_mm=FOCAL_MM)
    with Image(bank, width=16, height=16, focal_x_mm=FOCAL_MM) as im:
        frame = np.zeros((1, 16, 16), dtype=np.float32)
        frame[0, 3, 5] = np.nan
        with pytest.raises(LensrtError, match=r"input channel 0 pixel \(5, 3\) is nan"):
            im.run(frame)
        with pytest.raises(ValueError):
            im.run(np.zeros((2, 16, 16), dtype=np.float32))
