"""The reference a frame through the lens is measured against: every lit pixel's own PSF.

For each pixel with light, lensrt renders the PSF of a light at that pixel's own field
point (the pinhole's, :class:`lensfit.image.frame.Geometry`) directly from the lens table
(no bank, no interpolation): a window on the frame's own pixel grid, centred on the pixel
nearest the light's chief point, box-filtered pixels, the auto integrator to a target
error; its channels are projected as lensrt_image does (channel c: sum_l w[c][l] PSF_l,
divided by sum_l w[c][l] P_l with P_l the axis PSF's power, rendered the same way) and
added in. It costs one render per lit pixel and wavelength set: small frames only.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lensfit.image.frame import Geometry


def _psf(rt: Any, lens: Any, geometry: Geometry, fields: list[tuple[float, float]],
         centre_px: tuple[int, int], half: int, wavelengths: tuple[float, ...],
         f_number: float, focus_offset_mm: float, distance_mm: float,
         aperture: dict[str, Any], target: float) -> np.ndarray:
    """(n_wavelengths, 2 half + 1, 2 half + 1): the image of point lights at ``fields``
    (each of intensity 1 / their count) on the frame's grid around pixel centre_px
    (i, j)."""
    n = 2 * half + 1
    d = 0.0 if math.isinf(distance_mm) else distance_mm
    lights = [(fx, fy, d, 1.0 / len(fields)) for fx, fy in fields]
    # the centre of pixel (i, j) of the frame's grid (also beyond the frame's edge)
    cx = geometry.center_x_mm + (centre_px[0] + 0.5 - geometry.width / 2) * geometry.pitch_mm
    cy = geometry.center_y_mm + (geometry.height / 2 - centre_px[1] - 0.5) * geometry.pitch_mm
    r = rt.create(lens, width=n, height=n, width_mm=n * geometry.pitch_mm, center=(cx, cy),
                  focus_offset_mm=focus_offset_mm, f_number=f_number, lights=lights,
                  wavelengths=list(wavelengths), **aperture)
    r.integrate_auto_to(target)
    return r.image().astype(np.float64)


def per_pixel_reference(rt: Any, lens: Any, geometry: Geometry, planes: np.ndarray,
                        weights: np.ndarray, wavelengths: tuple[float, ...], *,
                        f_number: float, focus_offset_mm: float = 0.0,
                        distance_mm: float = math.inf, aperture: dict[str, Any] | None = None,
                        half: int = 8, target: float = 0.005, sub: int = 4) -> np.ndarray:
    """The direct layer by every lit pixel's own PSF (module doc): (channels, height,
    width) for planes (channels, height, width) with spectral weights (channels,
    n_wavelengths)."""
    ap = aperture or {}
    height, width = planes.shape[1:]
    xs, ys = geometry.pixel_xy_mm()
    # The axis PSF's power per wavelength: the normalisation lensrt_image uses
    ax, ay = rt.image_point(lens, (0.0, 0.0, 0.0 if math.isinf(distance_mm) else distance_mm,
                                   1.0), wavelengths[len(wavelengths) // 2], focus_offset_mm)
    axis_px = (int(math.floor((ax - geometry.center_x_mm) / geometry.pitch_mm
                              + geometry.width / 2)),
               int(math.floor(geometry.height / 2 - (ay - geometry.center_y_mm)
                              / geometry.pitch_mm)))
    axis = _psf(rt, lens, geometry, [(0.0, 0.0)], axis_px, half, wavelengths, f_number,
                focus_offset_mm, distance_mm, ap, target)
    power = axis.sum(axis=(1, 2))  # (n_wavelengths,)
    norm = weights @ power  # (channels,)
    out = np.zeros((planes.shape[0], height + 2 * half, width + 2 * half))  # padded
    lit = np.argwhere(planes.sum(axis=0) > 0)
    mid = wavelengths[len(wavelengths) // 2]
    for j, i in lit:
        fx, fy = geometry.field_deg(xs[i], ys[j])
        cx, cy = rt.image_point(lens, (float(fx), float(fy),
                                       0.0 if math.isinf(distance_mm) else distance_mm, 1.0),
                                mid, focus_offset_mm)
        ci = int(math.floor((cx - geometry.center_x_mm) / geometry.pitch_mm + width / 2))
        cj = int(math.floor(height / 2 - (cy - geometry.center_y_mm) / geometry.pitch_mm))
        # the pixel's footprint: sub x sub point lights at the midpoints of its parts
        offs = (np.arange(sub) + 0.5) / sub - 0.5
        fields = [tuple(float(v) for v in geometry.field_deg(xs[i] + a * geometry.pitch_mm,
                                                             ys[j] + b * geometry.pitch_mm))
                  for b in offs for a in offs]
        psf = _psf(rt, lens, geometry, fields, (ci, cj), half, wavelengths,
                   f_number, focus_offset_mm, distance_mm, ap, target)
        for c in range(planes.shape[0]):
            v = float(planes[c, j, i])
            if v:
                k = np.tensordot(weights[c], psf, axes=1) / norm[c]
                out[c, cj:cj + 2 * half + 1, ci:ci + 2 * half + 1] += v * k
    return out[:, half:half + height, half:half + width]


def window_error(layer: np.ndarray, ref: np.ndarray, i: int, j: int, radius: int = 6) -> float:
    """Relative L2 of ``layer`` against ``ref`` (channels, height, width) in the window of
    ``radius`` pixels around pixel (i, j): one lit pixel's own error."""
    sl = (slice(None), slice(max(j - radius, 0), j + radius + 1),
          slice(max(i - radius, 0), i + radius + 1))
    return float(np.linalg.norm(layer[sl] - ref[sl]) / np.linalg.norm(ref[sl]))
