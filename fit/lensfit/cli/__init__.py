"""The ``lensfit`` command line.

    lensfit list                         lenses in lensdb with their paraxial focal length
    lensfit info LENS [--json]           paraxial table (--wavelength NM: not the d line)
    lensfit ghosts LENS [--json]         ghosts ranked by peak pixel, the visible ones kept
                                         (--fit: fitted, with the reason where one misses)
    lensfit draw LENS -o FILE.png        cross-section with ray fans
    lensfit import FILE [-o OUT]         convert a Zemax .zmx, an Optiland JSON or a lentil
                                         JSON lens table to lensfit's TOML
    lensfit export LENS -o OUT.zmx       write a lens as a Zemax .zmx file
    lensfit check [LENS ...]             validate prescriptions and their EFL
    lensfit fit LENS                     fit P_o and P_s, write generated/<lens>/ and a report
    lensfit regenerate LENS              rewrite generated/<lens>/ from its fit.json (no fit)
    lensfit upgrade-table FILE ...       rewrite version-3/4 tables as version 5 (probe lines
                                         added from their own polynomials, no fit)
    lensfit report LENS [--json]         fit and write the fit-error report only
    lensfit scene LENS SCENE.toml        specialise generated/<lens>/ for one scene

LENS is a lensdb id (``0001``), a file stem in lensdb, or a path to a TOML file.
Where lensdb and generated/ are (lensfit.data_folder): ``--generated DIR`` on the commands
that read or write generated folders (fit, regenerate, scene, ghosts, bank), else
$LENSFIT_GENERATED / $LENSFIT_LENSDB, else the checkout's folders when lensfit runs from
one, else ``generated/`` and ``lensdb/`` in the current directory.
Errors go to stderr as one line naming file, surface and key; the exit code is 2.
``lensfit fit`` and ``lensfit report`` exit 3 (EXIT_MISS) when the fit's PSF against
exactly traced rays misses its target: the table and report are written and flagged all
the same; ``--allow-miss`` makes that exit 0. A fit whose output cannot come within ten
times its target at the highest degree (lensfit.fitting.tensor.OutOfReach) is refused
with exit 2 and writes nothing.
"""

from __future__ import annotations

import os
import sys

from lensfit.cli.common import EXIT_MISS
from lensfit.cli.parser import build_parser
from lensfit.common.errors import InputError, LensError
from lensfit.glass import UnknownGlassError

__all__ = ["EXIT_MISS", "build_parser", "main"]


def main(argv: list[str] | None = None) -> int:
    from lensfit.codegen.scene import SceneError
    from lensfit.sample.aim import SamplingError

    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (InputError, LensError, SceneError, SamplingError, UnknownGlassError) as e:
        # The project's own errors, about the input: one line and exit 2. Anything else
        # (a ValueError from numpy, say) is a bug and keeps its traceback.
        print(f"lensfit: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # Ctrl-C: what was written is whole (lensfit.common.atomic), and `lensfit fit` says
        # where its checkpoints are; no traceback
        print("lensfit: interrupted", file=sys.stderr)
        return 130  # 128 + SIGINT
    except BrokenPipeError:
        # The reader went away (`lensfit info 0001 | head -3`): stop quietly, as Unix tools
        # do; stdout goes to /dev/null so the flush at exit does not raise again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, what a shell reports for such a tool

