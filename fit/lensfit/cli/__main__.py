"""``python -m lensfit.cli``: the ``lensfit`` command."""

import sys

from lensfit.cli import main

sys.exit(main())
