"""What the subcommands of ``lensfit`` share: checks of the files and folders named on
the command line, option parsers and the exit status of a missed fit.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from lensfit.common.atomic import check_target
from lensfit.common.errors import InputError

# `lensfit fit` / `lensfit report`: the fit missed its PSF target (written and flagged)
EXIT_MISS = 3

# lensfit draw --rays: rays per fan (a fan of 10^8 rays grew to 19 GB; 1000 rays are
# already finer than the 130 dpi drawing can show)
MAX_RAYS = 1000


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _check_folder(path: str | Path, option: str) -> Path:
    """An output folder that can be created or written, checked before any work."""
    p = Path(path)
    if str(path) == "":
        raise InputError(f"{option}: expected a folder, found an empty name")
    if p.exists() and not p.is_dir():
        raise InputError(f"{option} {p}: is a file, expected a folder")
    base = _nearest_existing(p)
    if not base.is_dir():
        raise InputError(f"{option} {p}: {base} is a file, not a folder")
    if not os.access(base, os.W_OK | os.X_OK):
        raise InputError(f"{option} {p}: {base} is not writable")
    _probe_folder(base, f"{option} {p}")
    return p


def _probe_folder(base: Path, what: str) -> None:
    """Create and remove a folder in ``base``: access() says yes to root anywhere, and
    /proc or a read-only mount refuse only when tried."""
    import tempfile

    try:
        os.rmdir(tempfile.mkdtemp(prefix=".lensfit-probe-", dir=base))
    except OSError as e:
        raise InputError(f"{what}: cannot write in {base}: {e.strerror or e}") from None


def _check_file(path: str | Path, option: str) -> Path:
    """An output file whose folder exists and is writable, checked before any work."""
    p = Path(path)
    if str(path) == "" or p.is_dir():
        raise InputError(f"{option} {str(path)!r}: expected a file name, found "
                         f"{'a folder' if str(path) else 'an empty name'}")
    parent = p.absolute().parent
    if not parent.is_dir():
        raise InputError(f"{option} {p}: the folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{option} {p}: the folder {parent} is not writable")
    # A link or special file is refused, and a temporary must be creatable (lensfit.common.atomic)
    return check_target(p, option)


def _fmt(v: float | None, unit: str = "", digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "inf"
    return f"{v:.{digits}f}{(' ' + unit) if unit else ''}"


def _light_arg(text: str) -> tuple[float, float]:
    """``--light X,Y``: field angles in degrees (designers' sign, README Conventions)."""
    parts = text.split(",")
    try:
        x, y = (float(v) for v in parts)
    except ValueError:
        raise InputError(f"--light {text!r}: expected two field angles X,Y in degrees") from None
    return x, y


def _center_arg(text: str) -> tuple[float, float]:
    """``--center X,Y``: a point on the sensor in mm."""
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--center {text!r}: expected two sensor coordinates X,Y in mm"
                         ) from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise InputError(f"--center {text!r}: expected finite coordinates in mm")
    return x, y


def _generated(args: argparse.Namespace, must_exist: bool = False) -> Path:
    """The generated folder of a command: --generated, else $LENSFIT_GENERATED, else the
    checkout's, else the current directory's (lensfit.data_folder); with ``must_exist``
    an InputError naming the folder and the settings when it is missing."""
    from lensfit import data_folder, require_data_folder

    if must_exist:
        return require_data_folder("generated", args.generated)
    return data_folder("generated", args.generated)


def _generated_arg(p: argparse.ArgumentParser, what: str) -> None:
    """--generated DIR: the generated folder the command reads (or writes)."""
    p.add_argument("--generated", default=None, metavar="DIR",
                   help=f"the generated folder {what} (default: $LENSFIT_GENERATED, else "
                        "the checkout's generated/ when lensfit runs from one, else "
                        "./generated)")


def _check_dask_args(args: argparse.Namespace) -> None:
    """--workers and --scheduler (lensfit.banks.engine) of bank and ghosts --fit."""
    if args.workers is not None and args.workers < 0:
        raise InputError(f"--workers {args.workers}: expected 0 (this process) or more")
    if args.scheduler is not None and args.workers is not None:
        raise InputError("--workers and --scheduler: the cluster at the address has its own "
                         "workers; give one of them")


def _finite(v: float) -> float | None:
    """A number for JSON: None where it is not finite (a ghost no ray of which reaches
    the sensor is -inf stops from black; JSON has no infinity)."""
    return v if math.isfinite(v) else None


def _coated(lens, args: argparse.Namespace):
    """The lens, or its uncoated variant with --coating none."""
    from lensfit.prescription import with_coating

    return with_coating(lens, getattr(args, "coating", "file"))


def _coating_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--coating", choices=("file", "none"), default="file",
                   help="the coatings of the lens file (default), or none: the uncoated "
                        "variant, written to <lens folder>-uncoated")


def _glass_policy(lens, args: argparse.Namespace):
    """The lens with glass extrapolation allowed when --allow-glass-extrapolation."""
    from lensfit.prescription.ranges import allow_extrapolation

    return allow_extrapolation(lens) if args.allow_glass_extrapolation else lens


def _print_glass_ranges(lens, wavelengths: list[str] | None) -> None:
    """The band `lensfit fit` covers by default (380-780 nm narrowed to the range every
    glass supports, or why there is none), then, when extrapolation is allowed, the
    glasses extrapolated over it and any --wavelength."""
    from lensfit.common.errors import LensError
    from lensfit.prescription.ranges import allows_extrapolation, out_of_range
    from lensfit.sample.domain import fit_wavelengths

    try:
        band = fit_wavelengths(lens)
        print(f"  {'default fit':20s}{band.line()}")
        lams = list(band.range_nm)
    except LensError as e:  # no band every glass supports: say why, as `lensfit fit` will
        print(f"  {'default fit':20s}none: {e.detail}")
        lams = []
    for text in wavelengths or []:
        lams += [float(v) for v in text.split(",")]
    if not lams or not allows_extrapolation(lens):
        return  # the --wavelength values were checked against every glass already
    for o in out_of_range(lens, min(lams), max(lams)):
        print(f"  {'glass range':20s}{o.describe()}: allowed (glass_extrapolation)")


def _pair(text: str | None, what: str) -> tuple[float, float] | None:
    """'LO,HI' -> (lo, hi) with lo < hi, both finite."""
    if text is None:
        return None
    parts = text.split(",")
    try:
        lo, hi = (float(v) for v in parts)
    except ValueError:
        raise InputError(f"{what} = {text!r}: expected two numbers LO,HI") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise InputError(f"{what} = {text!r}: expected finite numbers with LO < HI")
    return lo, hi
