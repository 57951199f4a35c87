"""Lens files of other programs: ``lensfit import`` (Zemax .zmx, Optiland JSON) and
``lensfit export`` (.zmx). Each importer maps what lensfit's TOML holds exactly, stops
with one line per problem for what would change the optics, and lists the rest as
notes (see ``zemax`` and ``optiland``)."""

from __future__ import annotations

from pathlib import Path

from lensfit.common import strict_json
from lensfit.common.errors import regular_file_problem
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
            data = strict_json.read(p, str(p))
        except strict_json.JSONInputError:
            # Its reader reports the problem: Optiland's when the text names a surface group
            try:
                return "optiland" if b"surface_group" in p.read_bytes().replace(b"\x00", b"") \
                    else "lentil"
            except OSError:
                return "lentil"
        # An object with a surface group of any type: Optiland's reader says what is wrong
        return "optiland" if isinstance(data, dict) and "surface_group" in data else "lentil"
    return "unknown"
