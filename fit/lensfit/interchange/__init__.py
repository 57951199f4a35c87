"""Lens files of other programs: ``lensfit import`` (Zemax .zmx, Optiland JSON) and
``lensfit export`` (.zmx). Each importer maps what lensfit's TOML holds exactly, stops
with one line per problem for what would change the optics, and lists the rest as
notes (see ``zemax`` and ``optiland``)."""

from __future__ import annotations

import json
from pathlib import Path

from lensfit.errors import regular_file_problem
from lensfit.interchange.common import ImportProblems, ImportResult, write_atomic
from lensfit.interchange.optiland import convert_optiland, looks_like_optiland, read_optiland
from lensfit.interchange.zemax import parse_zmx, read_zmx, write_zmx

__all__ = [
    "ImportProblems",
    "ImportResult",
    "convert_optiland",
    "file_kind",
    "looks_like_optiland",
    "parse_zmx",
    "read_optiland",
    "read_zmx",
    "write_atomic",
    "write_zmx",
]


def file_kind(path: str | Path) -> str:
    """'zmx', 'optiland' or 'lentil' (the lentil lens-table JSON) from the name and, for
    JSON, the top-level keys."""
    p = Path(path)
    if p.suffix.lower() == ".zmx":
        return "zmx"
    if p.suffix.lower() == ".json":
        if regular_file_problem(p):
            return "optiland"  # its reader says why the file cannot be read
        try:
            data = json.loads(p.read_bytes().decode("utf-8"))
        except (OSError, ValueError, RecursionError):
            return "lentil"  # its reader reports the problem
        return "optiland" if looks_like_optiland(data) else "lentil"
    return "unknown"
