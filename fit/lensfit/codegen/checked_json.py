"""JSON records that carry their own checksum (fit.json, ghosts.json; issue 25).

The text is canonical (sorted keys, one-space indent, no NaN, a final newline) and holds
the key ``checksum``: ``crc32:<8 lowercase hex digits>``, the CRC-32 (zlib's) of the
canonical text of the same document without that key. A reader requires the file to be
byte for byte what :func:`checked_json_text` writes for the document it parses, so that
no byte can change unseen (also those a parser would forgive, such as ``1e5`` against
``1E5``): a changed record is refused naming the file and the key.
"""

from __future__ import annotations

import json
import zlib
from pathlib import Path
from typing import Any

from lensfit.codegen.table import REGENERATE
from lensfit.common.errors import InputError, parse_problem

KEY = "checksum"
REGENERATE_FOLDER = f"regenerate the folder with {REGENERATE}"  # for a record without a checksum


def _canonical(doc: dict[str, Any]) -> str:
    return json.dumps(doc, indent=1, sort_keys=True, allow_nan=False) + "\n"


def checked_json_text(doc: dict[str, Any]) -> str:
    """``doc`` (its own ``checksum`` key ignored) as canonical text with its checksum."""
    rest = {k: v for k, v in doc.items() if k != KEY}
    crc = zlib.crc32(_canonical(rest).encode("utf-8")) & 0xFFFFFFFF
    return _canonical({**rest, KEY: f"crc32:{crc:08x}"})


def load_checked_json(path: Path, regenerate: str, *, legacy: bool = False) -> dict[str, Any]:
    """The JSON object of ``path`` without its checksum key, verified. ``regenerate``
    says how to rewrite a record written before checksums (which ``legacy`` reads)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
        doc = json.loads(raw.decode("utf-8"))
    except (OSError, RecursionError) as e:
        raise InputError(f"{path}: cannot read: {e or 'nested too deeply'}") from None
    except ValueError as e:  # bad UTF-8 or JSON, or an integer of over 4300 digits
        raise InputError(f"{path}: cannot read: {parse_problem(e)}") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a JSON object, found {type(doc).__name__}")
    if KEY not in doc:
        if legacy:
            return doc
        raise InputError(f"{path}: key '{KEY}': missing (written before checksums); "
                         f"{regenerate}")
    try:
        same = raw.decode("utf-8") == checked_json_text(doc)
    except (TypeError, ValueError):  # keys that are not text, numbers json cannot write
        same = False
    if not same:
        raise InputError(f"{path}: key '{KEY}': {str(doc[KEY])[:40]!r} does not match the "
                         "content (the file was changed after lensfit wrote it); refused")
    return {k: v for k, v in doc.items() if k != KEY}
