"""An image through the lens (lensrt_image_*, 0.11.0) through the ctypes binding's Image:
a shift-invariant synthetic bank (every node the same Gaussian PSF, chief points at
f tan(field): no distortion) whose direct layer must be scipy's (pocketfft's) FFT
convolution of the input with PSF / axis power, plus the layers, stats, sources and a
refusal through the binding. The deeper checks (energy, seams, distortion, every refusal)
are tests/runtime/test_image.c's; this one measures the library against numpy's FFT.

The bank is written by the binding's write_bank (uncompressed scanline EXRs written by
lensrt_exr.write_node_exr with the lensrt/bankNode attribute of a `registration channel`
bank, and its stamped index).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from lensrt_ctypes import IMAGE_DIRECT, IMAGE_FLARE, Bank, Image, LensrtError, Result, write_bank
from scipy.signal import fftconvolve

FOCAL_MM = 10.0
PITCH_MM = 0.005
SIZE = 9                       # PSF pixels per side (odd: centred on a pixel)
SIGMA = 1.3                    # pixels
FIELDS_X = [-1.2, -0.6, 0.0, 0.6, 1.2]
FIELDS_Y = [-1.0, 0.0, 1.0]
WAVELENGTH_NM = 550.0


def gaussian() -> np.ndarray:
    x = np.arange(SIZE) + 0.5 - SIZE / 2
    g = np.exp(-(x[None, :] ** 2 + x[:, None] ** 2) / (2 * SIGMA ** 2))
    return (g / g.sum()).astype(np.float32)


def write_synthetic_bank(folder: Path) -> Path:
    """Every node the same PSF, its chief point at f tan(field)."""
    ny, nx = len(FIELDS_Y), len(FIELDS_X)
    psfs = np.broadcast_to(gaussian(), (ny, nx, 1, SIZE, SIZE))
    tx = FOCAL_MM * np.tan(np.radians(FIELDS_X))
    ty = FOCAL_MM * np.tan(np.radians(FIELDS_Y))
    chiefs = np.zeros((ny, nx, 1, 2))
    chiefs[..., 0, 0] = tx[None, :]
    chiefs[..., 0, 1] = ty[:, None]
    return write_bank(folder, psfs, chiefs, field_x_deg=FIELDS_X, field_y_deg=FIELDS_Y,
                      wavelengths_nm=[WAVELENGTH_NM], pixel_mm=PITCH_MM)


@pytest.fixture(scope="module")
def bank(rt, tmp_path_factory):
    if not hasattr(rt.lib, "lensrt_image_create"):
        pytest.skip("this lensrt library predates lensrt_image_* (0.11.0): rebuild it")
    b = Bank(rt, write_synthetic_bank(tmp_path_factory.mktemp("image-bank")))
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
