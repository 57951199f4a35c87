"""JSON input files read strictly (the Optiland and lentil importers): every way a file
can fail is one line naming the file and the line (and the key where there is one),
never a traceback.

* Encoding: UTF-8 (a byte-order mark allowed); UTF-16 and UTF-32 with a byte-order mark
  or the zero bytes of RFC 4627's detection are decoded; other bytes are refused with
  their offset.
* Numbers: an integer of more than 308 digits, or a literal beyond a float's range
  (1e400), is refused (Python's int() stops at 4,300 digits, float() turns 1e400 into
  inf and a big integer into an OverflowError later); a non-zero literal that
  underflows to 0 (1e-400) is refused too. ``Infinity`` and ``NaN`` stay as the
  readers' own checks treat them.
* Nesting: at most ``MAX_DEPTH`` arrays and objects deep (lens files need under 10;
  the parser recurses and would fail near 1,000).
"""

from __future__ import annotations

import codecs
import json
import math
import re
from typing import Any

from lensfit.common.errors import InputError

MAX_DEPTH = 64
MAX_INT_DIGITS = 308  # 10**308 is the last power of ten a float holds


class JSONInputError(InputError):
    """One line naming the file, the line and key where known, and what is wrong:
    ``label:line: key 'k': detail``."""

    def __init__(self, label: str, detail: str, line: int | None = None,
                 key: str | None = None) -> None:
        self.label, self.detail, self.line, self.key = label, detail, line, key
        where = (f":{line}" if line else "") + (f": key '{key}'" if key else "")
        super().__init__(f"{label}{where}: {detail}")

    @property
    def place(self) -> str:
        """The message without the file: 'line 3: key 'k': detail'."""
        parts = ([f"line {self.line}"] if self.line else []) + (
            [f"key '{self.key}'"] if self.key else [])
        return ": ".join([*parts, self.detail])


class _BadNumber(ValueError):
    def __init__(self, text: str, why: str) -> None:
        super().__init__(text)
        self.text, self.why = text, why


def _parse_int(text: str) -> int:
    digits = text.lstrip("-")
    if len(digits) > MAX_INT_DIGITS:
        raise _BadNumber(text, f"an integer of {len(digits)} digits, beyond a float's range")
    return int(text)


def _parse_float(text: str) -> float:
    v = float(text)
    if math.isinf(v):
        raise _BadNumber(text, "beyond a float's range")
    if v == 0.0 and re.search(r"[1-9]", text.split("e")[0].split("E")[0]):
        raise _BadNumber(text, "underflows to 0")
    return v


def decode(raw: bytes, label: str) -> str:
    """The text of a JSON file (see the module doc for the encodings)."""
    if raw.startswith(codecs.BOM_UTF8):
        enc = "utf-8-sig"
    else:
        enc = json.detect_encoding(raw)
    try:
        return raw.decode(enc)
    except UnicodeDecodeError as e:
        name = "UTF-8" if enc.startswith("utf-8") else enc.upper()
        raise JSONInputError(label, f"cannot read: not {name} text (byte "
                             f"0x{raw[e.start]:02x} at offset {e.start}); save it as "
                             "UTF-8") from None


_STRINGS = re.compile(r'"(?:[^"\\]|\\.)*"', re.S)


def _depth_problem(text: str) -> tuple[int, int] | None:
    """(line, depth) where nesting first passes MAX_DEPTH, else None."""
    stripped = _STRINGS.sub(lambda m: '""' + "\n" * m.group(0).count("\n"), text)
    depth = 0
    for m in re.finditer(r"[\[\]{}]", stripped):
        depth += 1 if m.group(0) in "[{" else -1
        if depth > MAX_DEPTH:
            return stripped.count("\n", 0, m.start()) + 1, depth
    return None


def _locate(text: str, literal: str) -> tuple[int | None, str | None]:
    """(line, key) of the first occurrence of a number literal (the hooks of the parser
    do not know where they are)."""
    m = re.search(r"(?<![\w.+-])" + re.escape(literal) + r"(?![\w.])", text)
    if not m:
        return None, None
    line = text.count("\n", 0, m.start()) + 1
    key = re.search(r'"((?:[^"\\]|\\.)*)"\s*:\s*$', text[max(0, m.start() - 200):m.start()])
    return line, key.group(1) if key else None


def loads(raw: bytes | str, label: str) -> Any:
    """Parse a JSON document strictly (module doc); JSONInputError names the file."""
    text = decode(raw, label) if isinstance(raw, bytes) else raw
    deep = _depth_problem(text)
    if deep:
        raise JSONInputError(label, f"malformed JSON: nested deeper than {MAX_DEPTH} "
                             "arrays and objects", deep[0])
    try:
        return json.loads(text, parse_int=_parse_int, parse_float=_parse_float)
    except _BadNumber as e:
        shown = e.text if len(e.text) <= 24 else f"{e.text[:12]}...{e.text[-6:]}"
        raise JSONInputError(label, f"number {shown}: {e.why}", *_locate(text, e.text)
                             ) from None
    except json.JSONDecodeError as e:
        raise JSONInputError(label, f"malformed JSON: {e.msg}", e.lineno) from None
    except RecursionError:  # pragma: no cover - the depth check comes first
        raise JSONInputError(label, "malformed JSON: nested too deeply") from None


def read(path: Any, label: str) -> Any:
    """Read and parse a JSON file strictly; an unreadable file is a JSONInputError."""
    from pathlib import Path

    from lensfit.common.errors import regular_file_problem

    problem = regular_file_problem(path)
    if problem:
        raise JSONInputError(label, f"cannot read: {problem}")
    try:
        raw = Path(path).read_bytes()
    except OSError as e:
        raise JSONInputError(label, f"cannot read: {e.strerror or e}") from None
    return loads(raw, label)
