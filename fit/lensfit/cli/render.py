"""``lensfit bank`` and ``lensfit image``: PSF banks on Dask and frames through a lens.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lensfit.cli.common import _check_dask_args, _generated
from lensfit.common.errors import InputError


def cmd_bank(args: argparse.Namespace) -> int:
    from lensfit.banks.engine import TaskError
    from lensfit.banks.run import run_bank
    from lensfit.banks.spec import SpecError

    _check_dask_args(args)
    out = Path(args.out) if args.out else Path("build") / "banks" / Path(args.spec).stem
    gen = _generated(args)
    try:
        summary = run_bank(args.spec, out, scheduler=args.scheduler, workers=args.workers,
                           restart=args.restart, progress=not args.no_progress,
                           sheet=not args.no_sheet, generated=gen,
                           check=not args.no_check, verbose=args.verbose,
                           say=lambda line: print(line, file=sys.stderr, flush=True))
    except SpecError as e:
        # A lens id looked up in a generated folder that is not there: say which folder
        # the rule chose and how to choose another
        if "key 'lens'" not in str(e) or gen.is_dir():
            raise
        from lensfit import missing_data_folder

        raise InputError(f"{e}; {missing_data_folder('generated', args.generated)}") from None
    except TaskError as e:
        print(f"lensfit: error: {e}; rerun the same command to resume", file=sys.stderr)
        return 1
    print(summary.line())
    return 0


def cmd_image(args: argparse.Namespace) -> int:
    from lensfit.banks.engine import TaskError
    from lensfit.image.through import Options, summary_lines, through_lens, write_preview

    _check_dask_args(args)
    aperture: dict[str, object] = {}
    if args.blades:
        aperture = {"shape": "blades", "blades": args.blades,
                    "blade_curvature": args.blade_curvature, "rotation_deg": args.rotation}
    o = Options(f_number=args.f_number, focus_offset_mm=args.focus_offset,
                pixel_mm=None if args.pixel_um is None else args.pixel_um * 1e-3,
                center_mm=args.center,
                sensor_width_mm=args.sensor_width, focal_mm=args.focal, aperture=aperture,
                nodes_x=args.nodes, oversample=args.oversample, target_error=args.target_error,
                ghosts=None if args.ghosts == "none" else args.ghosts,
                flare_threshold=args.threshold, max_sources=args.max_sources,
                flare_target_error=args.flare_target_error,
                flare_downsample=args.flare_downsample, depth_slices=args.depth_slices,
                cache=args.cache, scheduler=args.scheduler, workers=args.workers,
                progress=not args.no_progress)
    try:
        result = through_lens(args.lens, args.input, args.out, o, generated=_generated(args),
                              say=lambda line: print(line, file=sys.stderr, flush=True))
    except TaskError as e:
        print(f"lensfit: error: {e}; rerun the same command to resume the bank",
              file=sys.stderr)
        return 1
    if args.png:
        write_preview(result, args.png)
    print("\n".join(summary_lines(result)))
    return 0
