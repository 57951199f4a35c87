"""A sheet of PSF previews side by side, each with its label and a scale bar in um.

    python runtime/tools/psf_sheet.py -o sheet.png \\
        --panel f2.png 0.2 f/2 --panel f8.png 0.1 f/8 --panel f32.png 0.16 f/32

Each --panel is a PNG written by `lensrt-psf --png`, the width of its window on the sensor
in mm (lensrt-psf --size; pixels are square) and a label. The bar is a round length
(1, 2 or 5 x 10^k um) nearest to a quarter of the panel's width, as in the paper's
Figure 7. The pixels are shown as they are (the tone map is lensrt's).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import patheffects  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402
from PIL import Image  # noqa: E402

PANEL_INCHES = 3.2  # each panel's width on the sheet
DPI = 160           # 512 pixels per panel: 2 sheet pixels per pixel of a 256-pixel PSF
# A dark outline keeps the white label and bar readable on a bright part of a PSF
OUTLINE = [patheffects.withStroke(linewidth=3, foreground="black")]


def scale_bar_um(width_um: float) -> float:
    """The 1, 2 or 5 x 10^k um length nearest (in ratio) to a quarter of `width_um`."""
    if not (width_um > 0 and math.isfinite(width_um)):
        raise ValueError(f"panel width must be positive, got {width_um}")
    quarter = width_um / 4.0
    decade = 10.0 ** math.floor(math.log10(quarter))
    candidates = [m * decade for m in (1.0, 2.0, 5.0, 10.0)]
    return min(candidates, key=lambda c: abs(math.log(c / quarter)))


def format_um(length_um: float) -> str:
    return f"{length_um:g} \u00b5m"


def make_sheet(panels: list[tuple[Path, float, str]], out: Path, title: str | None = None) -> None:
    """Write the sheet: panels is [(png, window width in mm, label)]."""
    images = []
    for path, width_mm, label in panels:
        try:
            img = np.asarray(Image.open(path).convert("RGB"))
        except (OSError, ValueError) as e:
            raise SystemExit(f"psf_sheet: {path}: cannot read the PNG: {e}") from None
        if not (width_mm > 0 and math.isfinite(width_mm)):
            raise SystemExit(f"psf_sheet: {path}: window width must be a positive number of mm, "
                             f"got {width_mm}")
        images.append((img, width_mm * 1000.0, label))
    top = 0.35 if title else 0.0  # inches for the title line
    fig_h = PANEL_INCHES * max(img.shape[0] / img.shape[1] for img, _, _ in images) + top
    fig = plt.figure(figsize=(PANEL_INCHES * len(images), fig_h), facecolor="black")
    if title:
        fig.text(0.5, 1.0 - 0.5 * top / fig_h, title, color="white", fontsize=10, ha="center",
                 va="center")
    for k, (img, width_um, label) in enumerate(images):
        height_um = width_um * img.shape[0] / img.shape[1]
        # one panel per column, bottom-aligned, with the image's aspect
        ax = fig.add_axes((k / len(images), 0.0, 1.0 / len(images),
                           PANEL_INCHES * img.shape[0] / img.shape[1] / fig_h))
        # extent in um: x from the left edge, y from the bottom, square pixels
        ax.imshow(img, extent=(0.0, width_um, 0.0, height_um), interpolation="nearest")
        ax.set_axis_off()
        ax.text(0.05 * width_um, 0.95 * height_um, label, color="white", fontsize=14,
                fontweight="bold", va="top", ha="left", path_effects=OUTLINE)
        bar = scale_bar_um(width_um)
        x0, y0 = 0.06 * width_um, 0.06 * height_um
        ax.add_patch(Rectangle((x0, y0), bar, 0.012 * width_um, facecolor="white",
                               edgecolor="black", linewidth=1.0))
        ax.text(x0 + bar / 2, y0 + 0.03 * width_um, format_um(bar), color="white", fontsize=10,
                ha="center", va="bottom", path_effects=OUTLINE)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp.png")
    fig.savefig(tmp, dpi=DPI, facecolor="black")
    plt.close(fig)
    tmp.replace(out)  # atomic: a reader never sees half a sheet


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--output", type=Path, required=True, help="sheet PNG to write")
    ap.add_argument("--panel", nargs=3, action="append", required=True,
                    metavar=("PNG", "WIDTH_MM", "LABEL"),
                    help="a PSF preview, its window width in mm and its label; repeat")
    ap.add_argument("--title", help="a line above the panels")
    args = ap.parse_args(argv)
    panels = []
    for png, width, label in args.panel:
        try:
            width_mm = float(width)
        except ValueError:
            ap.error(f"--panel {png}: window width must be a number of mm, got {width!r}")
        panels.append((Path(png), width_mm, label))
    make_sheet(panels, args.output, args.title)
    print(f"psf_sheet: wrote {args.output} ("
          + ", ".join(f"{label}: {format_um(scale_bar_um(w * 1000))} bar"
                      for _, w, label in panels) + ")")
    return 0


if __name__ == "__main__":
    sys.exit(main())
