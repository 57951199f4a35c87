"""An image through the lens (lensrt_image_*, 0.11.0) through the ctypes binding's Image:
a shift-invariant synthetic bank (every node the same Gaussian PSF, chief points at
f tan(field): no distortion) whose direct layer must be scipy's (pocketfft's) FFT
convolution of the input with PSF / axis power through the layer's stencil, plus the
layers, stats, sources and a refusal through the binding; and the direct layer against
the closed form of box-filtered Gaussian PSFs seen by box pixels landing anywhere between
the bank's pixels. The deeper checks (energy, seams, distortion, every refusal) are
tests/runtime/test_image.c's.

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


def open_bank(rt, index: Path) -> Bank:
    """The bank at index, its nodes loaded; a skip where this library has no
    lensrt_image_* or no OpenEXR to read them."""
    if not hasattr(rt.lib, "lensrt_image_create"):
        pytest.skip("this lensrt library predates lensrt_image_* (0.11.0): rebuild it")
    b = Bank(rt, index)
    try:
        b.load_nodes()
    except LensrtError as e:
        if e.code == Result.UNSUPPORTED:
            pytest.skip(f"a build without OpenEXR: {e}")
        raise
    return b


@pytest.fixture(scope="module")
def bank(rt, tmp_path_factory):
    b = open_bank(rt, write_synthetic_bank(tmp_path_factory.mktemp("image-bank")))
    yield b
    b.close()


def stencil() -> np.ndarray:
    """The direct layer's operator per axis on a light landing on a pixel centre
    (src/image/direct.c): the splat's and the kernels' quadratic B-spline taps (1/8, 3/4,
    1/8) and the sharpening taps (-5/24, 1 + 5/12, -5/24)."""
    b2 = np.array([0.125, 0.75, 0.125])
    return np.convolve(np.convolve(b2, b2), [-5 / 24, 1 + 5 / 12, -5 / 24])


def test_direct_layer_is_the_fft_convolution(bank) -> None:
    """The direct layer of a shift-invariant bank is the input convolved with the PSF
    through the stencil, divided by the axis PSF's power (1 here: the Gaussian is
    normalised), as scipy.signal.fftconvolve (pocketfft) computes it, to float rounding."""
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
    kernel = fftconvolve(psf / psf.sum(), np.outer(stencil(), stencil()))
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


def box_gaussian(sigma: float, size: int) -> np.ndarray:
    """A Gaussian PSF of sigma pixels on an odd window centred on its chief point, each
    pixel its integral over the pixel (as lensrt's box filter renders PSFs)."""
    from scipy.special import ndtr

    edges = np.arange(size + 1) - size / 2
    g = np.diff(ndtr(edges / sigma))
    return np.outer(g, g)


def box_pair(d: np.ndarray, sigma: float, m: float) -> np.ndarray:
    """Per axis, a unit Gaussian of sigma pixels seen by a pixel (width 1) from a source
    box of width m whose centre is d pixels away, its light spread evenly over it: the
    double integral in closed form, sigma/m (F(a) - F(b) - F(c) + F(e)) at the box edges'
    distances over sigma, F(z) = z Phi(z) + phi(z) the normal density's second
    antiderivative."""
    from scipy.stats import norm

    def f(z: np.ndarray) -> np.ndarray:
        return z * norm.cdf(z) + norm.pdf(z)

    return (sigma / m) * (f((d + (1 + m) / 2) / sigma) - f((d + (m - 1) / 2) / sigma)
                          - f((d - (m - 1) / 2) / sigma) + f((d - (1 + m) / 2) / sigma))


@pytest.mark.parametrize("sigma_px, bound", [(0.6, 0.007), (1.2, 0.001)])
def test_direct_layer_against_the_closed_form(rt, tmp_path, sigma_px, bound) -> None:
    """Box pixels of a frame (oversample 3) through box-filtered Gaussian PSFs of sigma_px
    frame pixels, the bank's chief points 2% further out than the pinhole's (so the pixels
    land at every fraction between the bank's pixels): the direct layer against the
    closed form of each lit pixel's light (box_pair on each axis), relative L2.

    Bounds: the layer is right to second order in the bank's pitch (a third of a pixel
    here); measured 0.48% at 0.6 pixels and 0.052% at 1.2 (the residual falls about as
    sigma^-3); the bilinear taps before them gave 1.47% and 0.47%."""
    over, eps, w = 3, 0.02, 48
    fields_x, fields_y = [-1.2, -0.6, 0.0, 0.6, 1.2], [-1.0, -0.5, 0.0, 0.5, 1.0]
    sigma_bank = sigma_px * over
    size = 2 * int(np.ceil(4 * sigma_bank + 2)) + 1
    psf = box_gaussian(sigma_bank, size).astype(np.float32)
    chiefs = np.zeros((5, 5, 1, 2))
    chiefs[..., 0, 0] = (FOCAL_MM * (1 + eps) * np.tan(np.radians(fields_x)))[None, :]
    chiefs[..., 0, 1] = (FOCAL_MM * (1 + eps) * np.tan(np.radians(fields_y)))[:, None]
    index = write_bank(tmp_path, np.broadcast_to(psf, (5, 5, 1, size, size)), chiefs,
                       field_x_deg=fields_x, field_y_deg=fields_y,
                       wavelengths_nm=[WAVELENGTH_NM], pixel_mm=PITCH_MM / over)
    b = open_bank(rt, index)
    frame = np.zeros((1, w, w), np.float32)
    lit = [(i, j) for j in range(4, w - 4, 9) for i in range(4, w - 4, 9)]
    for i, j in lit:
        frame[0, j, i] = 1.0
    with Image(b, width=w, height=w, focal_x_mm=FOCAL_MM, oversample=over) as im:
        im.run(frame)
        out = im.layer(IMAGE_DIRECT)[0].astype(np.float64)
    b.close()
    # Each lit pixel lands (1 + eps) times as far from the axis, its box (1 + eps) wide
    centres = np.arange(w) + 0.5 - w / 2
    ref = np.zeros((w, w))
    for i, j in lit:
        ref += np.outer(box_pair(centres - centres[j] * (1 + eps), sigma_px, 1 + eps),
                        box_pair(centres - centres[i] * (1 + eps), sigma_px, 1 + eps))
    ref /= float(psf.astype(np.float64).sum())
    err = float(np.linalg.norm(out - ref) / np.linalg.norm(ref))
    assert err <= bound, f"sigma {sigma_px} px: {100 * err:.3f}% from the closed form"
