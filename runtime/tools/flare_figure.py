"""Full-frame flares of fitted lenses, side by side: the paper's Figure 10 (coated
against uncoated) for any lens folders that hold fitted ghosts.

    python runtime/tools/flare_figure.py -o flare.png --light=-6,-4 \\
        --panel generated/0001-angenieux-double-gauss 8 "coated" \\
        --panel generated/0001-angenieux-double-gauss-uncoated 8 "uncoated"

Each --panel is a lens folder (its direct table and ghosts/ from `lensfit ghosts --fit`),
the f-number and a label. For each panel the light's image is the direct PSF plus every
fitted ghost, each its own lensrt render (its own phasor sums; images add as
intensities), on the frame's pixel grid (36 x 24 mm at 1440 x 960 by default).

Only where an image can be is rendered: the direct PSF in a window around the light's
image point at the ends of the wavelength range, and each ghost in a window around its
footprint for this light and stop, from exactly traced ghost rays
(:func:`lensfit.ghosts.enumerate.enumerate_ghosts`), widened by a diffraction margin.
Outside its window an image is below what the frame's tone map shows: the window is
the geometric footprint plus WINDOW_MARGIN_LAMBDA_N wavelengths x f-number, where a
defocused edge's diffraction has fallen to ~1e-4 of the ghost's own level, and the
direct PSF's window holds its halo down to ~1e-6 of its peak. The rest of the frame is
black, which a brute-force full-frame render (`lensrt-psf --flares`) would have spent
nearly all its splats on.

Panels of the same lens folder stem (coated and -uncoated) share one exposure: white is
the brightest ghost pixel over them, so that the uncoated flare is as much brighter as
it is. The tone map is logarithmic over DECADES decades below white; the direct image
saturates, as in a photograph of a bright light. Colours are lensrt's linear sRGB (CIE
1931 2-degree observer, D65). Writes the PNG and, beside it, a JSON with each image's
window, power and seconds, and how it was integrated: with ``--integrator auto`` (the
default) the Fourier integrator's nodes, or where a clip cuts the aperture (most ghosts)
the cells integrator's rings, with ``cells`` the rings, and the error estimate (each
image refined until the estimate is within ``--target-error``, default 1%); with
``montecarlo`` its samples and
Monte Carlo floor (a power then includes the floor: the paper's estimator adds it to
every pixel, so it reads high by about that share).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "runtime" / "python"))

from lensrt_ctypes import Lensrt  # noqa: E402  (needs the path above)
from lensrt_exr import tone_map  # noqa: E402

DECADES = 2.5  # of the tone map below white
MIN_SAMPLES = 4096  # per wavelength and image
DIRECT_SAMPLES = 1 << 18  # the direct image's few pixels: its halo's floor to ~4e-6
WINDOW_MARGIN_LAMBDA_N = 30.0  # diffraction margin around a footprint: 30 lambda N
LAMBDA_MM = 550e-6
DIRECT_HALF_MM = 0.05  # the direct PSF's window: +-0.05 mm around its image points
PANEL_INCHES = 4.2


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("-o", "--output", required=True, help="PNG to write")
    p.add_argument("--panel", nargs=3, action="append", required=True,
                   metavar=("FOLDER", "F_NUMBER", "LABEL"))
    p.add_argument("--light", default="-6,-4", metavar="X,Y",
                   help="field angles in degrees, designers' sign (default -6,-4)")
    p.add_argument("--frame", default="36x24", help="sensor size in mm (default 36x24)")
    p.add_argument("--resolution", default="1440x960", help="pixels (default 1440x960)")
    p.add_argument("--wavelengths", type=int, default=16, help="default 16, 380-780 nm")
    p.add_argument("--floor", type=float, default=0.03,
                   help="Monte Carlo floor aimed at, relative to a ghost's own level "
                        "(default 0.03; module doc)")
    p.add_argument("--integrator", choices=("auto", "cells", "montecarlo"), default="auto",
                   help="auto (default): the Fourier integrator to --target-error, the cells "
                        "integrator where a clip cuts the aperture; cells: "
                        "lensrt_render_integrate to --target-error; montecarlo: samples within "
                        "--floor and --splats")
    p.add_argument("--target-error", type=float, default=0.01,
                   help="auto, cells: the relative L2 error each image is refined to "
                        "(default 0.01)")
    p.add_argument("--splats", type=float, default=1e10,
                   help="most splats per image (samples x pixels x wavelengths; default "
                        "1e10, ~10 s on 2 cores): larger ghosts get fewer samples and a "
                        "higher floor, which the JSON and the title report")
    return p.parse_args(argv)


def pair(text: str, what: str, kind=float) -> tuple:
    try:
        a, b = (kind(v) for v in text.lower().replace("x", ",").split(","))
    except ValueError:
        raise SystemExit(f"flare_figure: {what} {text!r}: expected two numbers") from None
    return a, b


class Frame:
    """The sensor's pixel grid: column i at x = -W/2 + (i + 0.5) p, row j at
    y = H/2 - (j + 0.5) p (row 0 at the top, as lensrt's images)."""

    def __init__(self, size_mm: tuple[float, float], pixels: tuple[int, int]) -> None:
        self.w_mm, self.h_mm = size_mm
        self.nx, self.ny = pixels
        self.pitch = self.w_mm / self.nx
        if abs(self.h_mm / self.ny - self.pitch) > 1e-9 * self.pitch:
            raise SystemExit(f"flare_figure: frame {size_mm} mm at {pixels} pixels: the "
                             "pixels must be square")

    def window(self, x0: float, x1: float, y0: float, y1: float):
        """Pixel rectangle (i0, i1, j0, j1) covering [x0, x1] x [y0, y1] mm, clipped to
        the frame; None when it misses the frame."""
        eps = 1e-9  # a box edge on a pixel edge (to rounding) does not take the next pixel
        i0 = max(0, math.floor((x0 + self.w_mm / 2) / self.pitch + eps))
        i1 = min(self.nx, math.ceil((x1 + self.w_mm / 2) / self.pitch - eps))
        j0 = max(0, math.floor((self.h_mm / 2 - y1) / self.pitch + eps))
        j1 = min(self.ny, math.ceil((self.h_mm / 2 - y0) / self.pitch - eps))
        return (i0, i1, j0, j1) if i0 < i1 and j0 < j1 else None

    def centre(self, win) -> tuple[float, float]:
        i0, i1, j0, j1 = win
        return (-self.w_mm / 2 + 0.5 * (i0 + i1) * self.pitch,
                self.h_mm / 2 - 0.5 * (j0 + j1) * self.pitch)


def footprints(folder: Path, ghosts: list[dict], f_number: float,
               light: tuple[float, float]) -> dict[str, tuple[float, float, float, float]]:
    """Each ghost's footprint box (x0, x1, y0, y1) in mm for this light and stop, from
    exactly traced rays, over every wavelength the enumeration traces."""
    from lensfit.generate import read_fit_json
    from lensfit.ghosts.enumerate import enumerate_ghosts
    from lensfit.prescription import load_lens, with_coating

    _, meta = read_fit_json(folder / "fit.json")
    lens = with_coating(load_lens(Path(meta["lens_file"]).stem), meta.get("coating", "file"))
    est = enumerate_ghosts(lens, f_number=f_number, light=light,
                           pairs=[(g["first"], g["second"]) for g in ghosts])
    boxes = {}
    for e in est:
        pts = [(c, r) for c, r in zip(e.centre_mm, e.extent_mm, strict=True) if c is not None]
        if not pts:
            continue  # no ray of this ghost reaches the sensor for this light
        boxes[e.name] = (min(c[0] - r for c, r in pts), max(c[0] + r for c, r in pts),
                         min(c[1] - r for c, r in pts), max(c[1] + r for c, r in pts))
    return boxes


def samples_for(radius_mm: float, f_number: float, pixels: int, args) -> tuple[int, float]:
    """Samples per wavelength for an image of blur radius ``radius_mm``, and the Monte
    Carlo floor they leave relative to its level.

    Inside a blur of radius r the phase is stationary over a share s ~ (lambda N / r)^2
    of the stop, so a pixel's phasor sum over N samples holds ~ s N coherent terms
    against a floor of the incoherent sum: floor / level ~ 1 / (s N). N aims at
    ``args.floor``, within MIN_SAMPLES and the splat budget ``args.splats``."""
    s = min(1.0, (LAMBDA_MM * f_number / max(radius_mm, 1e-9)) ** 2)
    want = 1.0 / (args.floor * s)
    cap = args.splats / (pixels * args.wavelengths)
    n = int(2 ** math.ceil(math.log2(max(MIN_SAMPLES, min(want, cap)))))
    return n, 1.0 / (s * n)


def render_window(rt, table: Path, frame: Frame, win, f_number: float,
                  light: tuple[float, float], args, samples: int) -> tuple[np.ndarray, float, dict]:
    """Linear sRGB of one image over the pixel rectangle ``win``, and its power (the
    spectral image's sum times the pixel area, averaged over wavelengths; a PSF smaller
    than a pixel is under-sampled by pixel centres, so the direct power is measured in a
    window of its own, :func:`direct_power`)."""
    i0, i1, j0, j1 = win
    cx, cy = frame.centre(win)
    lens = rt.load(table)
    r = rt.create(lens, width=i1 - i0, height=j1 - j0, width_mm=(i1 - i0) * frame.pitch,
                  height_mm=(j1 - j0) * frame.pitch, center=(cx, cy), f_number=f_number,
                  lights=[light], wavelengths=args.wavelengths)
    how: dict = {}
    if args.integrator == "cells":
        how["rings"], how["error_estimate"] = r.integrate_to(args.target_error)
        how["integrator"] = "cells"
    elif args.integrator == "auto":
        kind, count, how["error_estimate"] = r.integrate_auto_to(args.target_error)
        how["integrator"] = kind
        how["nodes" if kind == "fourier" else "rings"] = count
    else:
        r.run(samples)
        how["samples"] = samples
    power = float(r.image().sum(axis=(1, 2)).mean()) * frame.pitch**2
    return r.rgb(), power, how


def direct_power(rt, table: Path, centre: tuple[float, float], f_number: float,
                 light: tuple[float, float], args) -> float:
    """The direct image's power, from a 128 x 128 window of 1.6 um pixels (0.2 mm holds
    the PSF's power to ~0.5% at f/8; pixels of a third of the Airy radius resolve it)."""
    lens = rt.load(table)
    r = rt.create(lens, width=128, height=128, width_mm=0.2, center=centre,
                  f_number=f_number, lights=[light], wavelengths=args.wavelengths)
    if args.integrator == "cells":
        r.integrate_to(args.target_error)
    elif args.integrator == "auto":
        r.integrate_auto_to(args.target_error)
    else:
        r.run(MIN_SAMPLES)
    return float(r.image().sum(axis=(1, 2)).mean()) * (0.2 / 128) ** 2


def ghost_path(folder: Path, ghost: dict) -> Path:
    """A fitted ghost's table in a lens folder, from its ghosts.json entry."""
    return folder / "ghosts" / f"ghost_{ghost['first']}_{ghost['second']}.table"


def render_panel(rt, folder: Path, f_number: float, light, frame: Frame, args):
    """The frame's linear sRGB: the direct image and the ghosts, each in its window."""
    table = next(iter(sorted(folder.glob("lens*.table"))), None)
    if table is None:
        raise SystemExit(f"flare_figure: {folder}: no lens table (lens<ID>.table)")
    index = folder / "ghosts" / "ghosts.json"
    if not index.is_file():
        raise SystemExit(f"flare_figure: {index}: not found; run `lensfit ghosts LENS --fit`")
    from lensfit.codegen.checked_json import REGENERATE_FOLDER, load_checked_json
    from lensfit.errors import InputError, refuse_repeated_tables

    try:
        ghosts = load_checked_json(index, REGENERATE_FOLDER)["ghosts"]
        # a ghost listed twice in the index would add its flare twice
        refuse_repeated_tables(ghost_path(folder, g) for g in ghosts)
    except (InputError, KeyError, TypeError) as e:
        raise SystemExit(f"flare_figure: {index}: {e}") from None
    direct = np.zeros((frame.ny, frame.nx, 3), dtype=np.float64)
    flare = np.zeros_like(direct)
    record = []
    # The direct image around its image points at both ends of the spectrum
    lens = rt.load(table)
    pts = [rt.image_point(lens, light, lam) for lam in (380.0, 780.0)]
    xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    h = DIRECT_HALF_MM
    win = frame.window(min(xs) - h, max(xs) + h, min(ys) - h, max(ys) + h)
    images = [("direct", table, win, direct, 0.0)]
    boxes = footprints(folder, ghosts, f_number, light)
    margin = WINDOW_MARGIN_LAMBDA_N * 780e-6 * f_number
    for g in ghosts:
        box = boxes.get(g["label"])
        if box is None:
            record.append({"image": g["label"], "window": None, "power": 0.0})
            continue
        w = frame.window(box[0] - margin, box[1] + margin, box[2] - margin, box[3] + margin)
        path = ghost_path(folder, g)
        radius = 0.5 * max(box[1] - box[0], box[3] - box[2])
        images.append((g["label"], path, w, flare, radius))
    for name, path, w, canvas, radius in images:
        if w is None:
            record.append({"image": name, "window": None, "power": 0.0})
            continue
        t0 = time.perf_counter()
        i0, i1, j0, j1 = w
        n, floor = samples_for(radius, f_number, (i1 - i0) * (j1 - j0), args)
        if name == "direct":  # a few pixels: its halo's floor is what shows around it
            n = max(n, DIRECT_SAMPLES)
        rgb, power, how = render_window(rt, path, frame, w, f_number, light, args, n)
        if name == "direct":
            power = direct_power(rt, path, frame.centre(w), f_number, light, args)
        canvas[j0:j1, i0:i1] += rgb
        if args.integrator == "montecarlo":
            how["floor"] = floor
            said = f"{n} samples (floor {floor:.1%})"
        elif how["integrator"] == "fourier":
            said = f"Fourier, {how['nodes']} nodes (error estimate {how['error_estimate']:.2%})"
        else:
            said = f"cells, {how['rings']} rings (error estimate {how['error_estimate']:.2%})"
        record.append({"image": name, "window": list(w), "power": power, **how,
                       "seconds": time.perf_counter() - t0})
        print(f"  {folder.name} {name}: {i1 - i0} x {j1 - j0} pixels, {said}, power {power:.4g}, "
              f"{record[-1]['seconds']:.1f} s", flush=True)
    return direct, flare, record


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    light = pair(args.light, "--light")
    frame = Frame(pair(args.frame, "--frame"), pair(args.resolution, "--resolution", int))
    rt = Lensrt()
    panels = []
    for folder, f_number, label in args.panel:
        folder = Path(folder)
        direct, flare, record = render_panel(rt, folder, float(f_number), light, frame, args)
        panels.append({"folder": folder, "f_number": float(f_number), "label": label,
                       "direct": direct, "flare": flare, "record": record})
    # One exposure per lens: the folders' stem without the -uncoated suffix
    groups: dict[str, float] = {}
    for p in panels:
        key = p["folder"].name.removesuffix("-uncoated")
        lum = p["flare"] @ np.array([0.2126, 0.7152, 0.0722])
        groups[key] = max(groups.get(key, 0.0), float(lum.max()))
    cols = 2 if len(panels) > 1 else 1
    rows = math.ceil(len(panels) / cols)
    aspect = frame.ny / frame.nx
    fig, axes = plt.subplots(rows, cols, figsize=(cols * PANEL_INCHES,
                                                  rows * PANEL_INCHES * aspect + 0.6 * rows),
                             squeeze=False, facecolor="black")
    for ax, p in zip(axes.flat, panels, strict=False):
        white = groups[p["folder"].name.removesuffix("-uncoated")] or 1.0
        ax.imshow(tone_map(p["direct"] + p["flare"], white, DECADES),
                  extent=(-frame.w_mm / 2, frame.w_mm / 2, -frame.h_mm / 2, frame.h_mm / 2))
        shown = [r for r in p["record"] if r["image"] != "direct" and r["window"]]
        if args.integrator != "montecarlo":
            worst = max((r["error_estimate"] for r in shown), default=0.0)
            said = f"error estimate at most {worst:.1%} of a ghost's image"
        else:
            worst = max((r["floor"] for r in shown), default=0.0)
            said = f"Monte Carlo floor at most {worst:.0%} of a ghost's level"
        ax.set_title(f"{p['label']}: f/{p['f_number']:g}, {len(shown)} ghosts ({said})",
                     color="white", fontsize=7)
        ax.set_xticks([])
        ax.set_yticks([])
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    fig.suptitle(f"Light at ({light[0]:g}, {light[1]:g}) deg, {frame.w_mm:g} x "
                 f"{frame.h_mm:g} mm frame at {frame.nx} x {frame.ny}, {args.wavelengths} "
                 f"wavelengths; white = the brightest ghost of each lens, {DECADES:g} "
                 "decades (log); the direct image saturates", color="white", fontsize=7)
    fig.tight_layout()
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=frame.nx / PANEL_INCHES, facecolor="black")
    summary = [{"folder": str(p["folder"]), "label": p["label"], "f_number": p["f_number"],
                "images": p["record"]} for p in panels]
    out.with_suffix(".json").write_text(json.dumps({"light_deg": list(light),
                                                    "panels": summary}, indent=1) + "\n")
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
