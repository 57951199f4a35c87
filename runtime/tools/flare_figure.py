"""Flares of fitted lenses: the paper's Figure 10 (coated against uncoated) for any lens
folders that hold fitted ghosts, as close-ups of chosen ghosts and as full frames.

`make demo` (issue 26)::

    python runtime/tools/flare_figure.py -o figure10.png --light=-6,-4 --wavelengths 8 \\
        --blades 7 --curvature 0.3 --rotation 10 --direct-half 1.5 --pixel-samples 2 \\
        --closeup generated/2004-schneider-anamorphic "2004 coated" \\
        --closeup generated/2004-schneider-anamorphic-uncoated "2004 uncoated" \\
        --panel generated/0001-angenieux-double-gauss 16 "0001 coated" --note "..."

Each --closeup is a lens folder and a label: its --closeup-ghosts (default 0-2) on one
window (--closeup-size, default 2.0 x 0.8 mm around their footprints, --closeup-pitch
10 um pixels) at --closeup-f-number (default 16), each ghost by lensrt with the box
filter's automatic sub-pixel counts (a thin anamorphic streak aliases with one point per
pixel). All close-ups share one exposure: white is their brightest pixel, over
--closeup-decades (default 3.5) of a log tone map, so the uncoated ghost is as much
brighter as it is. The full-frame panels below are as before, with the stop's --blades
(the direct image's diffraction star) in a window of --direct-half mm around its image
point (cut to that circle when wider than the default), the direct image at the box
filter's automatic counts and the ghosts at --pixel-samples: by default lensrt's
automatic counts too (lensrt's pixel rule, lensrt.h: points h = pitch / n apart with
1 / h above the intensity's bandwidth D / lambda, so that a feature's power does not
depend on where it falls against the pixels: a thin streak's power moved 0.88-1.18 with
its sub-pixel position at the 2 x 2 points that were the default here (2004's ghost 0-2
at f/16), within 1.4e-4 at the rule's: tests/runtime/test_flare_figure.py). A defocused
ghost's rays spread over about 1 / N, so at f/8 on 25 um pixels the rule takes 8-9
points per axis, tens of times the point filter's splats (`make bench` times the default
frame against the point-filter row: runtime/bench/cells_bench.py); --pixel-samples 2 is
the cheaper choice for footprints that span many pixels and vary slowly over one (`make
demo` takes it), and --pixel-filter point renders every image at the pixel centres (as
before lensrt 0.8). The JSON records each image's filter, the counts asked and taken,
and seconds.

The full-frame mode alone (no --closeup) lays the panels out two by two:

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
    p.add_argument("--panel", nargs=3, action="append", default=[],
                   metavar=("FOLDER", "F_NUMBER", "LABEL"),
                   help="a full-frame panel: the direct image and every fitted ghost")
    p.add_argument("--closeup", nargs=2, action="append", default=[],
                   metavar=("FOLDER", "LABEL"),
                   help="a close-up panel of --closeup-ghosts of a lens folder on a window of "
                        "fine pixels (module doc); all close-ups share one exposure")
    p.add_argument("--closeup-ghosts", default="0-2",
                   help="labels of the ghosts the close-ups show, comma-separated (default 0-2)")
    p.add_argument("--closeup-f-number", type=float, default=16.0, help="default 16")
    p.add_argument("--closeup-center", default=None, metavar="X,Y",
                   help="mm (default: the centre of the ghosts' footprints)")
    p.add_argument("--closeup-size", default="2.0x0.8", metavar="WxH",
                   help="mm (default 2.0x0.8)")
    p.add_argument("--closeup-pitch", type=float, default=10.0,
                   help="the close-ups' pixel pitch in um (default 10)")
    p.add_argument("--closeup-decades", type=float, default=3.5,
                   help="decades of the close-ups' log tone map below white (default 3.5)")
    p.add_argument("--note", default="",
                   help="a line for the figure's caption and its JSON (say why a lens is used)")
    p.add_argument("--blades", type=int, default=0,
                   help="aperture blades (0: a round stop, the default)")
    p.add_argument("--curvature", type=float, default=0.0, help="blade curvature (default 0)")
    p.add_argument("--rotation", type=float, default=0.0, help="blade rotation in degrees")
    p.add_argument("--direct-half", type=float, default=DIRECT_HALF_MM,
                   help="half width in mm of the full frame's direct-image window (default "
                        f"{DIRECT_HALF_MM}; a bladed stop's star needs a few mm)")
    p.add_argument("--pixel-filter", choices=("box", "point"), default="box",
                   help="box (default): each pixel the mean over its area (lensrt 0.8); "
                        "point: the pixel centre's value")
    p.add_argument("--pixel-samples", default="auto", metavar="N|NxM|auto",
                   help="box filter: sub-pixel points per axis of the full frame's ghost "
                        "images (default auto: lensrt's rule, exact for any feature's power; "
                        "2 is cheaper for footprints that span many pixels); the direct "
                        "image and the close-ups always take lensrt's automatic counts")
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
    args = p.parse_args(argv)
    if not args.panel and not args.closeup:
        p.error("give at least one --panel or --closeup")
    args.ghost_samples = pixel_samples(args.pixel_samples)
    return args


def pixel_samples(text: str) -> int | tuple[int, int]:
    """--pixel-samples: 'auto' (0: lensrt chooses), N or NxM."""
    if text.strip().lower() in ("auto", "0"):
        return 0
    try:
        nums = [int(v) for v in text.lower().split("x")]
    except ValueError:
        nums = []
    if len(nums) not in (1, 2) or min(nums) < 1 or max(nums) > 16:
        raise SystemExit(f"flare_figure: --pixel-samples {text!r}: expected auto, N or NxM "
                         "with 1 <= N, M <= 16")
    return nums[0] if len(nums) == 1 else (nums[0], nums[1])


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
    from lensfit.codegen.generate import read_fit_json
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


def aperture(args) -> dict:
    """The render's stop shape: round, or --blades blades."""
    if not getattr(args, "blades", 0):
        return {}
    return {"shape": "blades", "blades": args.blades, "blade_curvature": args.curvature,
            "rotation_deg": args.rotation}


def render_window(rt, table: Path, frame: Frame, win, f_number: float,
                  light: tuple[float, float], args, samples: int,
                  pixel_samples: int | tuple[int, int] = 0) -> tuple[np.ndarray, float, dict]:
    """Linear sRGB of one image over the pixel rectangle ``win``, and its power (the
    spectral image's sum times the pixel area, averaged over wavelengths; a PSF smaller
    than a pixel is under-sampled by pixel centres, so the direct power is measured in a
    window of its own, :func:`direct_power`)."""
    i0, i1, j0, j1 = win
    cx, cy = frame.centre(win)
    lens = rt.load(table)
    r = rt.create(lens, width=i1 - i0, height=j1 - j0, width_mm=(i1 - i0) * frame.pitch,
                  height_mm=(j1 - j0) * frame.pitch, center=(cx, cy), f_number=f_number,
                  lights=[light], wavelengths=args.wavelengths,
                  pixel_filter=getattr(args, "pixel_filter", "box"),
                  pixel_samples=pixel_samples, **aperture(args))
    st = r.stats()
    how: dict = {"pixel_filter": getattr(args, "pixel_filter", "box"),
                 "pixel_samples": [int(st.pixel_samples_x), int(st.pixel_samples_y)],
                 "pixel_samples_asked": ("auto" if pixel_samples == 0 else pixel_samples)}
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
                  f_number=f_number, lights=[light], wavelengths=args.wavelengths,
                  **aperture(args))
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
    from lensfit.common.errors import InputError, refuse_repeated_tables

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
    h = getattr(args, "direct_half", DIRECT_HALF_MM)
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
        # The direct image (a few pixels' core) takes lensrt's automatic counts; the
        # ghosts --pixel-samples (default the same rule; module doc)
        ps = 0 if name == "direct" else getattr(args, "ghost_samples", 0)
        rgb, power, how = render_window(rt, path, frame, w, f_number, light, args, n, ps)
        if name == "direct":
            power = direct_power(rt, path, frame.centre(w), f_number, light, args)
        if name == "direct" and h > DIRECT_HALF_MM:
            # A star's window is cut to the circle of radius --direct-half around the image
            # point (its spikes and halo go on beyond, above the tone map's white: not
            # rendered), so that the cut reads as a disc and not as the window's square
            ix = -frame.w_mm / 2 + (np.arange(i0, i1) + 0.5) * frame.pitch
            jy = frame.h_mm / 2 - (np.arange(j0, j1) + 0.5) * frame.pitch
            cxy = (0.5 * (min(xs) + max(xs)), 0.5 * (min(ys) + max(ys)))
            inside = (ix[None, :] - cxy[0]) ** 2 + (jy[:, None] - cxy[1]) ** 2 <= h * h
            rgb = rgb * inside[..., None]
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
        said += f", {how['pixel_filter']} {how['pixel_samples'][0]}x{how['pixel_samples'][1]}"
        print(f"  {folder.name} {name}: {i1 - i0} x {j1 - j0} pixels, {said}, power {power:.4g}, "
              f"{record[-1]['seconds']:.1f} s", flush=True)
    return direct, flare, record


def render_closeup(rt, folder: Path, label: str, light, args) -> dict:
    """A close-up: the --closeup-ghosts of a lens folder on one window of fine pixels
    (--closeup-size at --closeup-pitch), each by lensrt with the box filter's automatic
    counts, summed; the direct image is not rendered here (a window beside it)."""
    index = folder / "ghosts" / "ghosts.json"
    from lensfit.codegen.checked_json import REGENERATE_FOLDER, load_checked_json

    ghosts = load_checked_json(index, REGENERATE_FOLDER)["ghosts"]
    want = [w.strip() for w in args.closeup_ghosts.split(",") if w.strip()]
    chosen = [g for g in ghosts if g["label"] in want]
    if len(chosen) != len(want):
        raise SystemExit(f"flare_figure: {index}: ghosts {want} asked, "
                         f"{[g['label'] for g in ghosts]} fitted")
    f_number = args.closeup_f_number
    w_mm, h_mm = pair(args.closeup_size, "--closeup-size")
    pitch = args.closeup_pitch * 1e-3
    nx, ny = max(1, round(w_mm / pitch)), max(1, round(h_mm / pitch))
    if args.closeup_center is not None:
        centre = pair(args.closeup_center, "--closeup-center")
    else:
        boxes = footprints(folder, chosen, f_number, light)
        if not boxes:
            raise SystemExit(f"flare_figure: {folder}: no ray of ghosts {want} reaches the "
                             f"sensor from light {light} at f/{f_number:g}")
        centre = (0.5 * (min(b[0] for b in boxes.values()) + max(b[1] for b in boxes.values())),
                  0.5 * (min(b[2] for b in boxes.values()) + max(b[3] for b in boxes.values())))
    rgb = np.zeros((ny, nx, 3))
    record = []
    for g in chosen:
        t0 = time.perf_counter()
        lens = rt.load(ghost_path(folder, g))
        r = rt.create(lens, width=nx, height=ny, width_mm=nx * pitch, height_mm=ny * pitch,
                      center=centre, f_number=f_number, lights=[light],
                      wavelengths=args.wavelengths, pixel_filter=args.pixel_filter,
                      pixel_samples=0, **aperture(args))
        st = r.stats()
        how: dict = {"pixel_filter": args.pixel_filter, "pixel_samples_asked": "auto",
                     "pixel_samples": [int(st.pixel_samples_x), int(st.pixel_samples_y)]}
        if args.integrator == "montecarlo":
            r.run(MIN_SAMPLES * 16)
            how["samples"] = MIN_SAMPLES * 16
        else:
            kind, count, how["error_estimate"] = r.integrate_auto_to(args.target_error)
            how["integrator"] = kind
            how["nodes" if kind == "fourier" else "rings"] = count
        rgb += r.rgb()
        power = float(r.image().sum(axis=(1, 2)).mean()) * pitch**2
        record.append({"image": g["label"], "power": power, **how,
                       "seconds": time.perf_counter() - t0})
        print(f"  close-up {folder.name} {g['label']}: {nx} x {ny} pixels of {pitch * 1e3:g} um, "
              f"{how['pixel_filter']} {how['pixel_samples'][0]}x{how['pixel_samples'][1]}, "
              f"{how.get('integrator', 'montecarlo')} (estimate "
              f"{how.get('error_estimate', float('nan')):.2%}), power {power:.4g}, "
              f"{record[-1]['seconds']:.1f} s", flush=True)
    return {"folder": folder, "label": label, "f_number": f_number, "centre": centre,
            "size_mm": (nx * pitch, ny * pitch), "pitch_mm": pitch, "rgb": rgb,
            "record": record}


def scale_bar(ax, x0: float, y0: float, length: float, text: str, fontsize: float = 7) -> None:
    """A white bar of ``length`` (axes data units, mm) from (x0, y0), labelled above."""
    ax.plot([x0, x0 + length], [y0, y0], color="white", linewidth=2, solid_capstyle="butt")
    ax.text(x0 + length / 2, y0, text, color="white", fontsize=fontsize, ha="center",
            va="bottom")


def nice_length(span: float) -> float:
    """A round length near a fifth of ``span``."""
    target = span / 5
    base = 10 ** math.floor(math.log10(target))
    return max(m * base for m in (1, 2, 5) if m * base <= target)


def main_with_closeups(args, light, frame: Frame, rt, panels: list[dict]) -> int:
    """The figure with a row of close-ups (one exposure for all of them: white is the
    brightest pixel over the close-ups) over the full-frame panels, each a row."""
    closeups = [render_closeup(rt, Path(folder), label, light, args)
                for folder, label in args.closeup]
    lum_w = np.array([0.2126, 0.7152, 0.0722])
    white_c = max(float((c["rgb"] @ lum_w).max()) for c in closeups) or 1.0
    ncols = max(1, len(closeups))
    cw, ch = closeups[0]["size_mm"]
    row_h = [PANEL_INCHES * ch / cw + 0.5]
    full_w = PANEL_INCHES * ncols
    row_h += [full_w * frame.ny / frame.nx + 0.5 for _ in panels]
    fig = plt.figure(figsize=(full_w, sum(row_h) + 0.5), facecolor="black")
    gs = fig.add_gridspec(len(row_h), ncols, height_ratios=row_h)
    for k, c in enumerate(closeups):
        ax = fig.add_subplot(gs[0, k])
        (w, h), (cx, cy) = c["size_mm"], c["centre"]
        ax.imshow(tone_map(c["rgb"], white_c, args.closeup_decades), interpolation="nearest",
                  extent=(cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2))
        bar = nice_length(w)
        scale_bar(ax, cx - w / 2 + 0.05 * w, cy - h / 2 + 0.1 * h, bar, f"{bar * 1e3:g} µm")
        px = c["record"][0]["pixel_samples"] if c["record"] else [1, 1]
        ax.set_title(f"{c['label']}: ghost {args.closeup_ghosts} at f/{c['f_number']:g}, "
                     f"{c['pitch_mm'] * 1e3:g} µm pixels (box, {px[0]}x{px[1]} points)",
                     color="white", fontsize=7)
        ax.set_xticks([])
        ax.set_yticks([])
    for k, p in enumerate(panels):
        ax = fig.add_subplot(gs[1 + k, :])
        white = p["white"]
        ax.imshow(tone_map(p["direct"] + p["flare"], white, DECADES),
                  extent=(-frame.w_mm / 2, frame.w_mm / 2, -frame.h_mm / 2, frame.h_mm / 2))
        scale_bar(ax, -frame.w_mm / 2 + 1.0, -frame.h_mm / 2 + 1.0, 5.0, "5 mm")
        shown = [r for r in p["record"] if r["image"] != "direct" and r["window"]]
        blades = f", {args.blades} blades" if args.blades else ""
        ax.set_title(f"{p['label']}: full {frame.w_mm:g} x {frame.h_mm:g} mm frame at "
                     f"{frame.nx} x {frame.ny}, f/{p['f_number']:g}{blades}, the light "
                     f"saturated with its star and {len(shown)} ghosts; white = the "
                     f"brightest ghost, {DECADES:g} decades", color="white", fontsize=7)
        ax.set_xticks([])
        ax.set_yticks([])
    cap = (f"Light at ({light[0]:g}, {light[1]:g}) deg, {args.wavelengths} wavelengths. "
           f"Close-ups: one exposure for all (white = their brightest pixel), "
           f"{args.closeup_decades:g} decades (log)")
    if args.note:
        cap += f". {args.note}"
    fig.suptitle(cap, color="white", fontsize=7, wrap=True)
    fig.tight_layout()
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=frame.nx / full_w, facecolor="black")
    summary = {
        "light_deg": list(light), "wavelengths": args.wavelengths, "note": args.note,
        "closeups": [{"folder": str(c["folder"]), "label": c["label"],
                      "f_number": c["f_number"], "ghosts": args.closeup_ghosts,
                      "centre_mm": list(c["centre"]), "size_mm": list(c["size_mm"]),
                      "pitch_mm": c["pitch_mm"], "white": white_c,
                      "decades": args.closeup_decades, "images": c["record"]}
                     for c in closeups],
        "panels": [{"folder": str(p["folder"]), "label": p["label"], "f_number": p["f_number"],
                    "blades": args.blades, "direct_half_mm": args.direct_half,
                    "white": p["white"], "decades": DECADES, "images": p["record"]}
                   for p in panels],
        "seconds": time.perf_counter() - args.t_start}
    out.with_suffix(".json").write_text(json.dumps(summary, indent=1) + "\n")
    print(f"wrote {out} and {out.with_suffix('.json')} ({summary['seconds']:.1f} s)")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    args.t_start = time.perf_counter()
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
    for p in panels:
        p["white"] = groups[p["folder"].name.removesuffix("-uncoated")] or 1.0
    if args.closeup:
        return main_with_closeups(args, light, frame, rt, panels)
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
