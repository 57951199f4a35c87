"""A sheet of HDR images side by side, tone-mapped for a person: issue 38's pinhole
render, the same image through the lens, and the lens's flare layer.

    python runtime/tools/image_sheet.py -o sheet.png --title "night street, lens 0001 f/8" \\
        --panel street.exr "pinhole" \\
        --panel street_lens.exr "through the lens" \\
        --panel street_lens.exr:flare "flare layer"

Each --panel is an EXR, optionally with a layer after a colon, and a label. A layer is a
channel prefix of a layered file (``direct.R``, ``flare.R``, ...); without one the
unprefixed R, G, B are read (the total in lensrt's layered files). Each panel is shown at
its own pixel size, side by side, top-aligned, with its label under it.

The tone map is lensrt's (``lensrt_exr.tone_map``): log luminance over --decades (default
3) below a white level, the hue kept, gamma 2.2. The panels share one white level, so
they compare: --white, or by default the --percentile (99.5) of the luminance of all the
shared panels' pixels together (the lamps of a night scene clip above it). A panel of a
layer named ``flare`` gets its own white level (its own percentile) unless
--shared-flare, and its label says how much brighter it is shown.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import OpenEXR  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
from lensrt_exr import tone_map  # noqa: E402

GAP = 8  # pixels between panels and around them
LABEL_HEIGHT = 28  # pixels of the band under the panels for the labels
TITLE_HEIGHT = 34  # pixels of the band above the panels for --title
DPI = 100  # the figure's dots per inch: sizes are in pixels either way
BACKGROUND = "#202020"
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])  # linear sRGB (Rec. 709)


@dataclass
class Panel:
    """One panel: an image's linear RGB and how to show it."""

    path: Path
    layer: str
    label: str
    rgb: np.ndarray  # (height, width, 3) float32, linear
    own_exposure: bool = False


def parse_source(text: str) -> tuple[Path, str]:
    """'PATH' or 'PATH:LAYER' -> (path, layer); a colon followed by a path (a '/') is part
    of the path."""
    path, colon, layer = text.rpartition(":")
    if colon and path and layer and "/" not in layer:
        return Path(path), layer
    return Path(text), ""


def read_rgb(path: Path, layer: str = "") -> np.ndarray:
    """The R, G, B channels of one layer ('' unprefixed) as (height, width, 3) float32."""
    if not path.is_file():
        raise SystemExit(f"image_sheet: {path}: not found or not a regular file")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            planes = {name: np.asarray(c.pixels) for name, c in f.channels().items()}
    except Exception as exc:  # the bindings raise RuntimeError and others
        raise SystemExit(f"image_sheet: {path}: OpenEXR cannot read it ({exc})") from None
    names = [f"{layer}.{c}" if layer else c for c in "RGB"]
    missing = [n for n in names if n not in planes]
    if missing:
        # Name the layers that do have R, G, B
        layers = sorted({n.rpartition(".")[0] for n in planes if n.rpartition(".")[2] == "R"})
        shown = ", ".join(f"'{x}'" for x in layers) or "none"
        raise SystemExit(f"image_sheet: {path}: no channels {', '.join(missing)} "
                         f"(layers with R, G, B: {shown}; '' is unprefixed)")
    rgb = np.stack([planes[n] for n in names], axis=-1).astype(np.float32)
    return np.where(np.isfinite(rgb), np.maximum(rgb, 0.0), 0.0)


def white_level(images: list[np.ndarray], percentile: float) -> float:
    """The luminance percentile of all the images' pixels together (at least a tiny
    positive number, for an all-black image)."""
    lum = np.concatenate([(img @ LUMINANCE).ravel() for img in images])
    return max(float(np.percentile(lum, percentile)), 1e-30)


def sheet_size(panels: list[tuple[int, int]], title: bool) -> tuple[int, int]:
    """The sheet's (width, height) in pixels for panels of these (width, height)."""
    width = sum(w for w, _ in panels) + GAP * (len(panels) + 1)
    height = max(h for _, h in panels) + GAP + LABEL_HEIGHT + (TITLE_HEIGHT if title else GAP)
    return width, height


def make_sheet(panels: list[Panel], out: Path, title: str | None = None,
               decades: float = 3.0, white: float | None = None,
               percentile: float = 99.5) -> None:
    """Tone-map the panels (a shared white level, own ones where asked) and write the
    sheet as a PNG."""
    shared = [p.rgb for p in panels if not p.own_exposure]
    common = white if white is not None else (
        white_level(shared, percentile) if shared else 1.0)
    width, height = sheet_size([(p.rgb.shape[1], p.rgb.shape[0]) for p in panels],
                               title is not None)
    fig = plt.figure(figsize=(width / DPI, height / DPI), dpi=DPI, facecolor=BACKGROUND)
    top = TITLE_HEIGHT if title is not None else GAP
    x = GAP
    for p in panels:
        h, w = p.rgb.shape[:2]
        # Each panel's white level, and the label saying so where it is its own
        level = white_level([p.rgb], percentile) if p.own_exposure else common
        label = p.label
        if p.own_exposure:
            label += (f" (own exposure, x{common / level:.3g})" if level > 1e-30
                      else " (own exposure: black)")
        # figimage places pixels from the bottom left, unscaled
        fig.figimage(tone_map(p.rgb, level, decades), xo=x, yo=height - top - h,
                     origin="upper")
        fig.text((x + 0.5 * w) / width, (height - top - h - GAP) / height, label,
                 ha="center", va="top", color="white", fontsize=11)
        x += w + GAP
    if title is not None:
        fig.text(0.5, 1.0 - 0.5 * TITLE_HEIGHT / height, title, ha="center", va="center",
                 color="white", fontsize=13)
    # Not bbox_inches="tight": the PNG is exactly width x height pixels
    fig.savefig(out, dpi=DPI, facecolor=BACKGROUND)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--panel", nargs=2, action="append", required=True,
                    metavar=("PATH[:LAYER]", "LABEL"), help="an EXR (and layer) and its label")
    ap.add_argument("-o", "--output", type=Path, required=True, help="the PNG to write")
    ap.add_argument("--title")
    ap.add_argument("--decades", type=float, default=3.0,
                    help="decades of luminance below white shown (default 3)")
    ap.add_argument("--white", type=float, help="the shared white level (linear luminance)")
    ap.add_argument("--percentile", type=float, default=99.5,
                    help="the luminance percentile taken as white (default 99.5)")
    ap.add_argument("--shared-flare", action="store_true",
                    help="show a 'flare' layer at the shared exposure too")
    a = ap.parse_args(argv)
    if not a.decades > 0 or not 0 < a.percentile <= 100 or (a.white is not None
                                                            and not a.white > 0):
        ap.error("--decades and --white must be positive, --percentile in (0, 100]")
    panels = []
    for source, label in a.panel:
        path, layer = parse_source(source)
        panels.append(Panel(path, layer, label, read_rgb(path, layer),
                            own_exposure=layer == "flare" and not a.shared_flare))
    make_sheet(panels, a.output, a.title, a.decades, a.white, a.percentile)
    return 0


if __name__ == "__main__":
    sys.exit(main())
