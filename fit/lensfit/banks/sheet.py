"""The contact sheet of a bank: every node's PSF where its field point lies in the frame.

One panel per (f-number, focus offset, distance) slice, the nodes laid out as the frame
shows them (+field y up, +field x right), each tile the node's sRGB preview tone-mapped
against its own peak (a log scale over 3 decades, so the wings show), labelled with its
field angles and error estimate. A bank of PSFs renders each wavelength of a node on its
own chief point (node.py), so the tiles show no lateral colour: the index holds it, as
each wavelength's chief point. Returned as PNG bytes (the caller writes them atomically).
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from lensfit.banks.spec import BankSpec


def contact_sheet(spec: BankSpec, out: Path, records: list[dict[str, Any]]) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from lensrt_exr import read_spectral_exr, tone_map

    g = spec.grid
    nf, nz, nd, ny, nx = g.shape
    slices = nf * nz * nd
    per_slice = ny * nx
    fig, axes = plt.subplots(slices * ny, nx, squeeze=False,
                             figsize=(1.6 * nx + 0.4, 1.6 * ny * slices + 0.6 * slices))
    for rec in records:
        f, z, d, y, x = rec["indices"]
        s = (f * nz + z) * nd + d
        ax = axes[s * ny + (ny - 1 - y), x]  # +field y at the top
        rgb = read_spectral_exr(out / rec["exr"]).rgb
        lum = rgb @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
        peak = float(lum.max())
        ax.imshow(tone_map(rgb, peak, 3.0) if peak > 0 else np.zeros_like(rgb),
                  origin="upper", interpolation="nearest")
        err = rec["error_estimate"]
        label = f"({rec['field_x_deg']:g}, {rec['field_y_deg']:g})°"
        if err >= 0:
            label += f" {err:.1%}"
        ax.set_title(label, fontsize=6, pad=2)
        ax.set_xticks([])
        ax.set_yticks([])
    for s in range(slices):
        f, rest = divmod(s, nz * nd)
        z, d = divmod(rest, nd)
        dist = g.distances_mm[d]
        axes[s * ny, 0].set_ylabel(
            f"f/{g.f_numbers[f]:g}, z_S {g.focus_offsets_mm[z]:g} mm, "
            f"{'inf' if math.isinf(dist) else f'{dist:g} mm'}", fontsize=6)
    w = spec.window
    fig.suptitle(f"bank {spec.name}: {records[0]['lens'] if records else ''}, "
                 f"{per_slice} field points x {slices} slices, {w.size_mm[0]:g} x "
                 f"{w.size_mm[1]:g} mm windows on the chief ray, "
                 f"{len(g.wavelengths_nm)} wavelengths"
                 + (" (each on its own chief point: no lateral colour)" if w.center_mm is None
                    else ""), fontsize=7)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()
