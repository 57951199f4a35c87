"""The parser of ``lensfit`` and its subcommands (:func:`build_parser`); what ``--help``
prints is plain text.
"""

from __future__ import annotations

import argparse
import math

from lensfit.cli import fit as fit_cmds
from lensfit.cli import ghosts as ghosts_cmds
from lensfit.cli import lens as lens_cmds
from lensfit.cli import render as render_cmds
from lensfit.cli.common import EXIT_MISS, _center_arg, _coating_arg, _generated_arg
from lensfit.ghosts.enumerate import (
    DEFAULT_OVEREXPOSURE_STOPS,
    DEFAULT_PIXEL_MM,
    DISPLAY_STOPS,
)
from lensfit.image.through import DEFAULT_NODES, DEFAULT_OVERSAMPLE


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """A parser's subcommands by name (aliases once): what the docs' CLI page and the
    --help test walk."""
    out: dict[str, argparse.ArgumentParser] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                if all(sub is not s for s in out.values()):
                    out[name] = sub
    return out


def build_parser() -> argparse.ArgumentParser:
    # What argparse prints is plain text: no reST (the module docstrings are for the API
    # docs; tests/fit/test_cli_help.py checks every subcommand's --help)
    ap = argparse.ArgumentParser(prog="lensfit", description="The lensfit command line.")
    sub = ap.add_subparsers(dest="cmd", required=True)

    p = sub.add_parser("info", help="paraxial table of a lens")
    p.add_argument("lens")
    p.add_argument("--json", action="store_true", help="print a JSON object")
    p.add_argument("--f-number", type=float, help="stop the lens down to this f-number")
    p.add_argument("--allow-glass-extrapolation", action="store_true",
                   help="use glasses outside their published range (as the lens file's "
                        "glass_extrapolation = \"allow\"); each is listed")
    p.add_argument("--wavelength", action="append", metavar="NM",
                   help="first-order facts at this wavelength in nm instead of the d line "
                        "(repeatable or a comma list; the stop of --f-number stays that of "
                        "the d line)")
    p.set_defaults(func=lens_cmds.cmd_info)

    p = sub.add_parser("ghosts", help="ghosts of a lens ranked by their peak pixel relative "
                       "to the light's; the visible ones kept (issues 13, 26)")
    p.add_argument("lens", nargs="*", help="lens ids or files (one or more)")
    p.add_argument("--f-number", type=float, default=None,
                   help="stop the lens down to this f-number (default: wide open)")
    p.add_argument("--light", default="0,0", metavar="X,Y",
                   help="field angles of a light at infinity in degrees, designers' sign "
                        "(README Conventions; default 0,0)")
    p.add_argument("--distance", type=float, default=math.inf, metavar="MM",
                   help="the light's distance from the first vertex in mm (default inf)")
    p.add_argument("--json", action="store_true", help="print the estimates as JSON")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--threshold", type=float, default=None,
                       help="keep ghosts whose peak is above this share of the PSF peak "
                            "(default: keep the visible ones, --overexposure)")
    group.add_argument("--count", type=int, default=None, help="keep the K brightest ghosts")
    p.add_argument("--overexposure", type=float, default=DEFAULT_OVEREXPOSURE_STOPS,
                   metavar="STOPS",
                   help="a ghost is visible (and kept by default) when its peak pixel "
                        "shows in a photograph whose exposure puts the light's peak pixel "
                        f"this many stops over white (default {DEFAULT_OVEREXPOSURE_STOPS:g}: "
                        f"the sun over a sunlit white; {DISPLAY_STOPS:g} stops shown below "
                        "white)")
    p.add_argument("--pixel-um", type=float, default=DEFAULT_PIXEL_MM * 1e3, metavar="UM",
                   help="the pixel pitch both peaks are averaged over for visibility "
                        f"(default {DEFAULT_PIXEL_MM * 1e3:g} um)")
    p.add_argument("--rays", type=int, default=20000,
                   help="rays per wavelength over the front (default 20000; a fifth of "
                        "that per ghost in the second pass)")
    p.add_argument("--ghost", action="append", default=[], metavar="I-J",
                   help="only these ghosts, in the lens file's numbering (repeatable or a "
                        "comma list)")
    _coating_arg(p)
    p.add_argument("--fit", action="store_true",
                   help="fit the kept ghosts over the direct fit's domain and write their "
                        "tables to <generated>/<lens folder>/ghosts/")
    p.add_argument("--c", action="store_true",
                   help="with --fit: also write each ghost's Horner C (2-3 MB a ghost; lensrt "
                        "loads the tables, lensfit scene writes a scene's ghosts as C)")
    p.add_argument("--glsl", action="store_true",
                   help="with --fit: also write each ghost's GLSL (P_o, P_s and P_clip, "
                        "float and double)")
    p.add_argument("--add", action="store_true",
                   help="with --fit: keep the ghosts fitted before (replacing those fitted "
                        "again) instead of writing exactly the kept ones")
    _generated_arg(p, "of the lens folders (with --fit)")
    p.add_argument("--all", action="store_true",
                   help="with --fit: also every lens of lensdb with a direct fit in "
                        "--generated")
    p.add_argument("--scheduler", default=None,
                   help="with --fit: a running Dask scheduler's address (default: a "
                        "LocalCluster here), one ghost per task")
    p.add_argument("--workers", type=int, default=None,
                   help="with --fit: LocalCluster worker processes (default: one per core; "
                        "0: fit in this process without Dask)")
    p.set_defaults(func=ghosts_cmds.cmd_ghosts)

    p = sub.add_parser("draw", help="draw the cross-section with ray fans")
    p.add_argument("lens")
    p.add_argument("-o", "--output", required=True, help="PNG file to write")
    p.add_argument("--field", type=float, default=None, help="off-axis field angle in degrees")
    p.add_argument("--rays", type=int, default=11, help="rays per fan")
    p.add_argument("--f-number", type=float, default=None, help="stop down to this f-number")
    p.set_defaults(func=lens_cmds.cmd_draw)

    p = sub.add_parser("import", help="convert a Zemax .zmx, Optiland JSON or lentil JSON "
                       "lens to lensfit TOML")
    p.add_argument("json_file", metavar="FILE")
    p.add_argument("--id", action="append", help="lentil: entry id to convert (repeatable; "
                   "default all); .zmx/Optiland: the lens id (default: the file stem)")
    p.add_argument("-o", "--output", default=None, help="lentil: output folder (default "
                   "lensdb); .zmx/Optiland: the .toml file or a folder (default "
                   "./FILE-stem.toml)")
    p.set_defaults(func=lens_cmds.cmd_import)

    p = sub.add_parser("export", help="write a lens as a Zemax .zmx file")
    p.add_argument("lens")
    p.add_argument("-o", "--output", required=True, help=".zmx file to write")
    p.set_defaults(func=lens_cmds.cmd_export)

    p = sub.add_parser("list", help="list the lenses in lensdb")
    p.set_defaults(func=lens_cmds.cmd_list)

    p = sub.add_parser("check", help="validate lenses and check EFL against the patent")
    p.add_argument("lens", nargs="*")
    p.set_defaults(func=lens_cmds.cmd_check)

    for name, func, help_ in (
        ("fit", fit_cmds.cmd_fit, "fit P_o and P_s, write generated/<lens>/ and the report"),
        ("report", fit_cmds.cmd_report, "fit and write the fit-error report (Markdown, PNG, JSON)"),
    ):
        p = sub.add_parser(name, help=help_)
        p.add_argument("lens")
        p.add_argument("--f-number", type=float, default=None,
                       help="widest aperture fitted (default: the lens file's [fit] or "
                            "[lens] f_number, else f/2, or wide open if slower)")
        p.add_argument("--field", type=float, default=None, metavar="DEG",
                       help="half field angle in x (default: the lens file's [fit] "
                            "field_deg or half its [lens] field_of_view_deg, else the field "
                            "of a 36 x 24 mm frame; at most 60 and as far as the chief ray "
                            "passes); the image circle follows")
        p.add_argument("--image-circle", type=float, default=None, metavar="MM",
                       help="radius of the sensor disc fitted (default: follows --field)")
        p.add_argument("--wavelengths", default=None, metavar="LO,HI",
                       help="wavelength range in nm (default: 380,780 narrowed to the "
                            "range every glass of the lens supports)")
        p.add_argument("--close-focus", type=float, default=None, metavar="MM",
                       help="closest scene point from the first vertex in mm, or inf "
                            "(default: ten focal lengths); the sensor travel follows")
        p.add_argument("--focus", default=None, metavar="LO,HI",
                       help="sensor shift range z_S in mm (default: what focuses from "
                            "infinity to the close focus)")
        p.add_argument("--psf-target", type=float, default=0.01, metavar="REL",
                       help="PSF error the fit aims at, relative L2 against exactly "
                            "traced rays (default 0.01); the phase target follows")
        p.add_argument("--method", choices=("tensor", "pursuit"), default="tensor",
                       help="tensor least squares on a ray grid (default) or the sparse "
                            "pursuit of the first fits")
        p.add_argument("--quick", action="store_true",
                       help="small budgets and samples (for tests and trials)")
        timing = p.add_mutually_exclusive_group()
        timing.add_argument("--timing", action="store_true",
                            help="compile and time the generated C and casadi's C (the "
                                 "report's Speed table; minutes for a large table)")
        timing.add_argument("--no-timing", action="store_true",
                            help="no compiling and timing (the default; kept for scripts)")
        p.add_argument("--allow-miss", action="store_true",
                       help=f"exit 0 even when the PSF check misses the target (the "
                            f"table is written and flagged either way; without this the "
                            f"exit status is {EXIT_MISS})")
        p.add_argument("--allow-glass-extrapolation", action="store_true",
                       help="use glasses outside their published range (as the lens "
                            "file's glass_extrapolation = \"allow\"); the report lists each")
        _coating_arg(p)
        if name == "fit":
            _generated_arg(p, "to write the lens folder to")
            p.add_argument("--report", default=None, help="folder for the report")
            p.add_argument("--glsl", action="store_true",
                           help="also write the GLSL source (megabytes for a full fit; "
                                "lensrt's GL path loads the table)")
            p.add_argument("--no-progress", action="store_true",
                           help="no progress bar (there is none when stderr is not a "
                                "terminal)")
            p.add_argument("--scene", default=None, metavar="SCENE.toml",
                           help="fit only what this scene needs (its lights, wavelengths, "
                                "stop and focus): generated/<lens>/scene-fits/<name>/")
        else:
            p.add_argument("--json", action="store_true", help="print the figures as JSON")
            p.add_argument("-o", "--out", default=None, help="folder for the report")
        p.set_defaults(func=func)

    p = sub.add_parser("regenerate",
                       help="rewrite generated/<lens>/ from its fit.json, without fitting")
    p.add_argument("lens", help="lens id or file, or a generated folder's name "
                   "(e.g. 0001-angenieux-double-gauss-uncoated)")
    _generated_arg(p, "of the lens folder")
    p.set_defaults(func=fit_cmds.cmd_regenerate)

    p = sub.add_parser("upgrade-table",
                       help="rewrite version-3 or -4 lensfit-poly-table files as version 5 "
                            "in place: probe lines from their own polynomials, no fit (a "
                            "ghost table's ghosts.json keeps its old CRC: use regenerate "
                            "for a generated folder)")
    p.add_argument("files", nargs="+", help="table files")
    p.set_defaults(func=fit_cmds.cmd_upgrade_table)

    p = sub.add_parser("bank", help="render a bank of PSFs (field points x focus x stops x "
                       "wavelengths) on Dask; a rerun resumes")
    p.add_argument("spec", help="bank spec TOML (see lensfit.banks.spec; banks/demo.toml)")
    p.add_argument("-o", "--out", default=None,
                   help="bank folder (default: build/banks/<spec file's stem>)")
    p.add_argument("--scheduler", default=None,
                   help="address of a running Dask scheduler (default: a LocalCluster here)")
    p.add_argument("--workers", type=int, default=None,
                   help="LocalCluster worker processes (default: one per core, at most two "
                        "per core; 0: render in this process without Dask)")
    p.add_argument("--restart", action="store_true",
                   help="discard the nodes of a bank of another spec or table, or of a "
                        "damaged bank.json, in the folder (the same bank resumes either way)")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="show the Dask cluster's logs (INFO; default: errors only)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-sheet", action="store_true", help="no contact-sheet PNG")
    p.add_argument("--no-check", action="store_true",
                   help="do not measure the reader between nodes against direct renders "
                        "(check.json; a few seconds)")
    _generated_arg(p, "where the spec's lens id is looked up")
    p.set_defaults(func=render_cmds.cmd_bank)

    p = sub.add_parser("image", help="put a linear HDR frame (EXR) through a lens: direct, "
                       "flare and ghost layers")
    p.add_argument("lens", help="lens id, generated folder or .table")
    p.add_argument("input", help="linear EXR: R, G, B or spectral S0.<lambda>nm channels, "
                   "optional Z (depth, mm from the first vertex)")
    p.add_argument("-o", "--out", required=True, help="output EXR (layers direct, flare, "
                   "ghost_<i>_<j>; unprefixed channels: their total)")
    p.add_argument("--png", default=None, help="also a tone-mapped preview PNG of the total")
    p.add_argument("--f-number", type=float, default=8.0, help="the stop (default 8)")
    p.add_argument("--focus-offset", type=float, default=0.0,
                   help="sensor shift z_S in mm, + away from the lens (default 0)")
    p.add_argument("--pixel-um", type=float, default=None,
                   help="pixel pitch in um (default: sensor width / frame width)")
    p.add_argument("--sensor-width", type=float, default=None,
                   help="sensor width in mm (default: the EXR's lensfit/sensorWidthMm, "
                        "else 36)")
    p.add_argument("--focal", type=float, default=None,
                   help="the input's pinhole focal length in mm (default: the EXR's "
                        "lensfit/pinholeFocalMm, else the lens's)")
    p.add_argument("--center", type=_center_arg, default=(0.0, 0.0), metavar="X,Y",
                   help="the frame's centre on the sensor in mm (a window of the sensor; "
                        "write --center=X,Y when X is negative)")
    p.add_argument("--blades", type=int, default=0, help="aperture blades (0: a circle)")
    p.add_argument("--blade-curvature", type=float, default=0.0)
    p.add_argument("--rotation", type=float, default=0.0, help="blade rotation, degrees")
    p.add_argument("--nodes", type=int, default=DEFAULT_NODES,
                   help="bank field points across the frame (y's from its aspect; default "
                        f"{DEFAULT_NODES})")
    p.add_argument("--oversample", type=int, default=DEFAULT_OVERSAMPLE,
                   help="the direct layer on a grid this many times finer per axis (1-16; "
                        f"default {DEFAULT_OVERSAMPLE}: 1.5%% from every pixel's own PSF "
                        "on lens 0001 at f/8, 3: 2.4%%, 2: 5%%)")
    p.add_argument("--target-error", type=float, default=0.01,
                   help="each bank node's relative L2 error estimate (default 0.01)")
    p.add_argument("--ghosts", default="none",
                   help="flares: ghost tables 'kept' (the lens folder's ghosts/) or a folder "
                        "of them; default 'none' (each ghost of each source is a Huygens "
                        "render of 1-7 minutes of CPU: docs/image.md)")
    p.add_argument("--threshold", type=float, default=0.0,
                   help="a pixel whose channels sum above this is a light source (default: "
                        "the frame's brightest / 16)")
    p.add_argument("--max-sources", type=int, default=4,
                   help="the brightest sources given flares (default 4)")
    p.add_argument("--flare-target-error", type=float, default=0.0,
                   help="each ghost render's error estimate (default 0.02)")
    p.add_argument("--flare-downsample", type=int, default=0,
                   help="frame pixels per ghost-render pixel per axis (default 4)")
    p.add_argument("--depth-slices", type=int, default=4,
                   help="distances the depth channel is split over (default 4)")
    p.add_argument("--cache", default=None,
                   help="bank cache folder (default: $LENSFIT_IMAGE_CACHE, else "
                        "build/image-cache)")
    p.add_argument("--scheduler", default=None,
                   help="address of a running Dask scheduler for the bank")
    p.add_argument("--workers", type=int, default=None,
                   help="LocalCluster workers for the bank (0: in this process)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _generated_arg(p, "where the lens id is looked up")
    p.set_defaults(func=render_cmds.cmd_image)

    p = sub.add_parser("scene", help="specialise a fitted lens for one scene")
    p.add_argument("lens")
    p.add_argument("scene", help="scene TOML file (see lensfit.codegen.scene)")
    _generated_arg(p, "of the fitted lens (to read)")
    p.add_argument("-o", "--out", default=None,
                   help="folder to write (default: generated/<lens>/scenes/<name>)")
    p.add_argument("--json", action="store_true", help="print the comparison as JSON")
    p.add_argument("--no-timing", action="store_true", help="skip timing the C")
    p.add_argument("--glsl", action="store_true",
                   help="also write the specialised systems' GLSL (and each kept ghost's)")
    p.set_defaults(func=fit_cmds.cmd_scene)
    return ap
