"""lensrt_image_run on a 1920 x 1080 x 3 frame (issue 38): seconds per stage, against a
baseline measured in the same run.

The bank is synthetic (the binding's write_bank): 9 x 5 nodes over +-26 x +-16 deg, 32 x 32
PSFs of 5 um (Gaussians whose width grows with field), 3 wavelengths with lateral colour
(sub-pixel shifts between them: the kernels' phase ramps), chief points with 0.6% of
barrel distortion at the corners; the frame is a 10 mm pinhole's, 3 channels mixing the 3
wavelengths, its pixels random. The baseline is the cheapest thing a shift-invariant lens
would need: the whole frame's 3 channels convolved with one 32 x 32 PSF by
scipy.signal.fftconvolve (pocketfft, float64, one thread). The ratio says what the
field-varying PSF, the warp and the node split cost on top of that. A second figure
times pocketfft doing lensrt's own per-node work (each node's 2 x 2 cells convolved with
a kernel, 3 channels, times the nodes): what lensrt's FFT costs against pocketfft.

usage: python runtime/bench/image_bench.py [--library PATH] [--out DIR] [--threads N]
                                           [--repeat N] [--width W --height H]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
from lensrt_ctypes import IMAGE_DIRECT, Bank, Image, Lensrt, write_bank
from scipy.signal import fftconvolve

FOCAL_MM = 10.0
PITCH_MM = 0.005
PSF = 32
FIELDS_X = np.linspace(-26.0, 26.0, 9)
FIELDS_Y = np.linspace(-16.0, 16.0, 5)
WAVELENGTHS = [450.0, 550.0, 650.0]
WEIGHTS = np.array([[0.1, 0.3, 1.0], [0.2, 1.0, 0.2], [1.0, 0.3, 0.05]])
DISTORTION = -0.02      # chief = f t (1 + k |t|^2)
LATERAL_PX = 0.35       # pixels of x shift per wavelength step, times the field in x


def gaussian(sigma: float) -> np.ndarray:
    x = np.arange(PSF) + 0.5 - PSF / 2
    g = np.exp(-(x[None, :] ** 2 + x[:, None] ** 2) / (2 * sigma ** 2))
    return g / g.sum()


def make_bank(folder: Path) -> Path:
    ny, nx, nl = len(FIELDS_Y), len(FIELDS_X), len(WAVELENGTHS)
    psfs = np.zeros((ny, nx, nl, PSF, PSF), dtype=np.float32)
    chiefs = np.zeros((ny, nx, nl, 2))
    for iy, fy in enumerate(FIELDS_Y):
        for ix, fx in enumerate(FIELDS_X):
            tx, ty = np.tan(np.radians(fx)), np.tan(np.radians(fy))
            d = 1.0 + DISTORTION * (tx * tx + ty * ty)
            for il in range(nl):
                psfs[iy, ix, il] = gaussian(1.5 + 0.04 * abs(fx) + 0.05 * abs(fy) + 0.3 * il)
                lateral = LATERAL_PX * (il - 1) * tx / 0.48 * PITCH_MM
                chiefs[iy, ix, il] = (FOCAL_MM * tx * d + lateral, FOCAL_MM * ty * d)
    return write_bank(folder, psfs, chiefs, field_x_deg=list(FIELDS_X), field_y_deg=list(FIELDS_Y),
                      wavelengths_nm=WAVELENGTHS, pixel_mm=PITCH_MM)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--library", default=None, help="liblensrt.so (default: the checkout's)")
    ap.add_argument("--out", default=None, help="write image.json here")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    frame = rng.random((3, args.height, args.width), dtype=np.float32)
    rt = Lensrt(args.library, threads=args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        bank = Bank(rt, make_bank(Path(tmp)))
        bank.load_nodes()
        t0 = time.perf_counter()
        im = Image(bank, width=args.width, height=args.height, focal_x_mm=FOCAL_MM,
                   channel_weights=WEIGHTS)
        t_create = time.perf_counter() - t0
        best, stats = float("inf"), {}
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            im.run(frame)
            t = time.perf_counter() - t0
            if t < best:
                best, stats = t, im.stats()
        direct = im.layer(IMAGE_DIRECT)
        im.close()
        bank.close()
    # The baseline: one PSF over the whole frame, each channel, pocketfft
    psf = gaussian(2.0)
    base = float("inf")
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        for c in range(3):
            fftconvolve(frame[c].astype(np.float64), psf, mode="same")
        base = min(base, time.perf_counter() - t0)
    # The second: the same per-node work done by pocketfft, one node's region (its 2 x 2
    # cells) convolved in full with a kernel of the bank's grid, 3 channels, times the nodes
    # (a cell's mean pixels: the frame's pixels over the grid steps its field spans)
    def cells(pixels: int, step_deg: float) -> float:
        return 2 * np.degrees(np.arctan(0.5 * pixels * PITCH_MM / FOCAL_MM)) / step_deg

    # (approximate: a node's 2 x 2 cells, or the frame when it is smaller)
    cell_w = min(args.width, int(2 * args.width / cells(args.width, FIELDS_X[1] - FIELDS_X[0])))
    cell_h = min(args.height, int(2 * args.height / cells(args.height, FIELDS_Y[1] - FIELDS_Y[0])))
    region = rng.random((cell_h, cell_w))
    kernel = np.pad(psf, 4)
    per_node = float("inf")
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        for _c in range(3):
            fftconvolve(region, kernel, mode="full")
        per_node = min(per_node, time.perf_counter() - t0)
    nodes_pocketfft = per_node * stats["n_nodes"]
    assert np.isfinite(direct).all() and direct.min() >= 0.0
    print(f"image_bench: {args.width} x {args.height} x 3, bank {len(FIELDS_X)} x {len(FIELDS_Y)} "
          f"nodes of {PSF} x {PSF} px, {len(WAVELENGTHS)} wavelengths, {args.threads} thread(s)")
    print(f"  create {t_create:.3f} s (chief points, landing points, kernels)")
    print(f"  run    {best:.3f} s: warp {stats['seconds_warp']:.3f}, kernels "
          f"{stats['seconds_kernels']:.3f}, convolve {stats['seconds_convolve']:.3f}, flares "
          f"{stats['seconds_flares']:.3f}; {stats['n_nodes']} nodes, largest FFT "
          f"{stats['fft_width']} x {stats['fft_height']}")
    print(f"  baseline (scipy fftconvolve, one PSF, 3 channels) {base:.3f} s; "
          f"ratio {best / base:.1f}")
    print(f"  the nodes' convolutions by pocketfft ({stats['n_nodes']} x 3 of {cell_w} x "
          f"{cell_h} px) {nodes_pocketfft:.3f} s; lensrt's kernels + convolve "
          f"{stats['seconds_kernels'] + stats['seconds_convolve']:.3f} s, ratio "
          f"{(stats['seconds_kernels'] + stats['seconds_convolve']) / nodes_pocketfft:.1f}")

    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        record = {"width": args.width, "height": args.height, "channels": 3,
                  "nodes": [len(FIELDS_X), len(FIELDS_Y)], "psf_pixels": PSF,
                  "threads": args.threads, "seconds_create": t_create, "seconds_run": best,
                  "stats": stats, "seconds_baseline_one_psf": base,
                  "seconds_pocketfft_nodes": nodes_pocketfft,
                  "ratio_to_one_psf": best / base}
        (Path(args.out) / "image.json").write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
