"""Coefficient tables: polynomial systems as plain text a small C evaluator can parse.

Format ``lensfit-poly-table``, version 2 (the reader also reads version 1). UTF-8 text,
lines end with '\\n'; fields are separated by one or more spaces or tabs (only those:
other Unicode blanks belong to a field), and a '\r' before the '\n' is ignored. Lines that
are empty or start with '#' (after optional blanks) are comments and are skipped anywhere.
The first other line is the header; then, in version 2, the lens lines; then one block
per system:

    lensfit-poly-table 2
    lens <key> <value>                                           (9 lines, version 2 only)
    system <name> <n_inputs> <n_outputs>
    input <name> <unit> <lo> <hi> <transform> <c> <s>          (n_inputs lines)
    output <name> <unit> <n_terms>                               (then, per output:)
    <e_1> ... <e_n_inputs> <coefficient>                         (n_terms lines)
    end

* Names and units are text fields: written as they are, except that an empty field is
  written ``-``, and a field that is exactly ``-``, or any byte of it that is ``%``, a
  space, a control character (below 0x21) or DEL (0x7F), is written ``%XX`` (two upper
  case hex digits of the UTF-8 byte). Decoding: ``-`` is empty, ``%XX`` is that byte.
* ``lo``, ``hi``: the input's domain in its unit; ``transform``: ``affine`` (w = v) or
  ``inverse_square`` (w = 1/v^2); ``c``, ``s``: the normalisation xhat = (w - c) / s,
  redundant with lo/hi (``c = (a + b)/2``, ``s = (b - a)/2`` with [a, b] the range of w)
  but written so an evaluator need not recompute them. The reader checks them.
* Real numbers are C ``%.17g`` (Python ``format(x, ".17g")``): 17 significant digits, so
  ``strtod`` gives back the same double. Exponents are non-negative decimal integers.
* A term line holds the exponent of each input (in input order) then the coefficient,
  in the output's unit: the term is ``coefficient * prod_j xhat_j ** e_j``.

Version 2 adds the lens lines: first-order facts of the lens a runtime needs besides
the polynomials (:class:`lensfit.facts.LensFacts`), exactly these keys in this order,
one line each, between the header (and the comments the writer puts after it) and the
first ``system`` line:

    name                     the lens's name (a text field, encoded as above)
    focal_length_mm          paraxial effective focal length, y-z meridian, d line (signed)
    stop_radius_max_mm       the widest the physical stop opens
    stop_radius_f1_mm        the stop radius that would give f/1 for an object at infinity
                             (paraxial): f/N needs a stop radius of stop_radius_f1_mm / N
    housing_first_mm         clip radius at the first surface: a path passes when
                             x_o^2 + y_o^2 <= housing_first_mm^2
    housing_last_mm          clip radius at the last surface: x_i^2 + y_i^2 <= housing_last_mm^2
    sensor_defocus_mm        the z_S = 0 sensor minus the paraxial focus for infinity (y, d
                             line): z_S = -sensor_defocus_mm puts the sensor at that focus
    front_focal_distance_mm  front focal point to the first vertex (positive in front)
    squeeze                  anamorphic squeeze EFL_y / EFL_x (1 for a rotationally
                             symmetric lens)

Every value but the name is a finite real number written like the others (``%.17g``);
radii and squeeze are positive, the focal length is not zero. Version 1 has no lens
lines; the writer emits version 1 when it is given no lens facts.

A system's ``info`` (provenance) is not stored. ``read_table(write_table(s))`` gives back
the names, units, domains, transforms, exponents and coefficients bit for bit, terms in
their order, and the lens facts exactly (:class:`Table`). Malformed text raises ValueError
naming the line: ``table line 7: ...``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

import numpy as np

from lensfit.facts import LensFacts, fact_problem
from lensfit.poly import Input, Polynomial, System
from lensfit.poly.polynomial import TRANSFORMS

FORMAT = "lensfit-poly-table"
VERSION = 2  # what the writer emits when given lens facts (else 1)
READS = (1, 2)  # versions the reader accepts
_INT = re.compile(r"[0-9]+")
_REAL = re.compile(r"[-+]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?")
_BLANKS = re.compile(r"[ \t]+")


def encode_field(text: str) -> str:
    """A name or unit as one whitespace-free field (see the module doc)."""
    if text == "":
        return "-"
    if text == "-":
        return "%2D"
    return "".join(f"%{ord(ch):02X}" if ord(ch) <= 0x20 or ch in "%\x7f" else ch
                   for ch in text)


def decode_field(token: str, where: str) -> str:
    """Inverse of encode_field; ``where`` starts the error message."""
    if token == "-":
        return ""
    raw = token.encode("utf-8")
    out = bytearray()
    i = 0
    while i < len(raw):
        if raw[i] == ord("%"):
            pair = raw[i + 1:i + 3].decode("ascii", "replace")
            if not re.fullmatch(r"[0-9A-Fa-f]{2}", pair):
                raise ValueError(f"{where}: bad escape {token[i:i + 3]!r} in {token!r} "
                                 "(expected %XX with two hex digits)")
            out.append(int(pair, 16))
            i += 3
        else:
            out.append(raw[i])
            i += 1
    try:
        return out.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"{where}: {token!r} does not decode to UTF-8 text") from e


def fmt_real(x: float) -> str:
    return format(float(x), ".17g")


class Table(list[System]):
    """What :func:`read_table` returns: the systems (it is a list of them), plus the
    table's format ``version`` and its ``lens`` facts (None in a version-1 table)."""

    def __init__(self, systems: Sequence[System], lens: LensFacts | None = None,
                 version: int = VERSION) -> None:
        super().__init__(systems)
        self.lens = lens
        self.version = version


def write_table(systems: Sequence[System], comment: str = "",
                lens: LensFacts | None = None) -> str:
    """The systems as one ``lensfit-poly-table`` text (``comment`` lines become '# ...').

    With ``lens`` (default: ``systems.lens`` when ``systems`` is a :class:`Table`) the
    text is version 2 with the lens lines; without, version 1."""
    if lens is None:
        lens = getattr(systems, "lens", None)
    lines = [f"{FORMAT} {VERSION if lens is not None else 1}"]
    lines += [f"# {line}".rstrip() for line in comment.splitlines()]
    if lens is not None:
        lens.check()
        lines.append(f"lens name {encode_field(lens.name)}")
        for key, value in zip(LensFacts.keys()[1:], lens.values()[1:], strict=True):
            lines.append(f"lens {key} {fmt_real(value)}")
    for s in systems:
        n = len(s.inputs)
        lines.append(f"system {encode_field(s.name)} {n} {len(s.outputs)}")
        for inp in s.inputs:
            c, sc = inp.offset_scale
            lines.append(" ".join(["input", encode_field(inp.name), encode_field(inp.unit),
                                   fmt_real(inp.lo), fmt_real(inp.hi), inp.transform,
                                   fmt_real(c), fmt_real(sc)]))
        for p in s.outputs:
            lines.append(f"output {encode_field(p.output)} {encode_field(p.unit)} {p.terms}")
            for e, coef in zip(p.exponents.tolist(), p.coefficients.tolist(), strict=True):
                lines.append(" ".join([*map(str, e), fmt_real(coef)]))
        lines.append("end")
    return "\n".join(lines) + "\n"


class _Lines:
    """Significant lines with their 1-based numbers; errors name the line."""

    def __init__(self, text: str) -> None:
        self.rows = []
        for i, line in enumerate(text.split("\n"), start=1):
            line = line.removesuffix("\r").strip(" \t")
            if line and not line.startswith("#"):
                self.rows.append((i, _BLANKS.split(line)))
        self.pos = 0
        self.last = text.count("\n") + 1

    def done(self) -> bool:
        return self.pos >= len(self.rows)

    def next(self, expected: str) -> tuple[int, list[str]]:
        if self.done():
            raise ValueError(f"table line {self.last}: unexpected end of text, expected "
                             f"{expected}")
        row = self.rows[self.pos]
        self.pos += 1
        return row


def _fail(n: int, message: str) -> ValueError:
    return ValueError(f"table line {n}: {message}")


def _count(token: str, n: int, what: str) -> int:
    if not _INT.fullmatch(token):
        raise _fail(n, f"{what}: expected a non-negative integer, found {token!r}")
    if int(token) >= 2**31:
        raise _fail(n, f"{what}: {token} is too large")
    return int(token)


def _real(token: str, n: int, what: str) -> float:
    if not _REAL.fullmatch(token):
        raise _fail(n, f"{what}: expected a real number like -1.25e-05, found {token!r}")
    x = float(token)
    if not math.isfinite(x):
        raise _fail(n, f"{what}: expected a finite number, found {token!r}")
    return x


def _fields(n: int, fields: list[str], keyword: str, count: int, form: str) -> None:
    if not fields or fields[0] != keyword:
        raise _fail(n, f"expected '{form}', found {' '.join(fields)!r}")
    if len(fields) != count:
        raise _fail(n, f"expected {count} fields '{form}', found {len(fields)}")


def _input(n: int, f: list[str]) -> Input:
    _fields(n, f, "input", 8, "input <name> <unit> <lo> <hi> <transform> <c> <s>")
    where = f"table line {n}"
    name, unit = decode_field(f[1], where), decode_field(f[2], where)
    lo, hi = _real(f[3], n, "lo"), _real(f[4], n, "hi")
    if f[5] not in TRANSFORMS:
        raise _fail(n, f"transform: expected one of {', '.join(TRANSFORMS)}, found {f[5]!r}")
    try:
        inp = Input(name, unit, lo, hi, f[5])
    except ValueError as e:
        raise _fail(n, str(e)) from None
    # c and s are redundant: they must be what lo and hi give (to rounding)
    for what, token, want in zip(("c", "s"), f[6:8], inp.offset_scale, strict=True):
        got = _real(token, n, what)
        if not math.isclose(got, want, rel_tol=1e-14, abs_tol=1e-300):
            raise _fail(n, f"{what} = {token} does not match lo/hi and {f[5]}, which give "
                           f"{fmt_real(want)}")
    return inp


def _output(lines: _Lines, n_inputs: int) -> Polynomial:
    n, f = lines.next("'output <name> <unit> <n_terms>'")
    _fields(n, f, "output", 4, "output <name> <unit> <n_terms>")
    where = f"table line {n}"
    name, unit = decode_field(f[1], where), decode_field(f[2], where)
    k = _count(f[3], n, "n_terms")
    exps = np.zeros((k, n_inputs), dtype=np.int32)
    coefs = np.zeros(k)
    for t in range(k):
        m, row = lines.next(f"term {t + 1} of {k} of output {name!r}")
        if len(row) != n_inputs + 1:
            raise _fail(m, f"term of output {name!r}: expected {n_inputs} exponents and a "
                           f"coefficient, found {len(row)} fields")
        exps[t] = [_count(tok, m, f"exponent {j + 1}") for j, tok in enumerate(row[:-1])]
        coefs[t] = _real(row[-1], m, "coefficient")
    return Polynomial(name, unit, exps, coefs)


def _lens(lines: _Lines) -> LensFacts:
    """The lens lines of a version-2 table: every key once, in the documented order."""
    keys = LensFacts.keys()
    values: list[str | float] = []
    for i, key in enumerate(keys):
        form = f"lens {key} <value>"
        n, f = lines.next(f"'{form}' (lens line {i + 1} of {len(keys)})")
        if not f or f[0] != "lens":
            raise _fail(n, f"expected '{form}' (lens line {i + 1} of {len(keys)}), found "
                           f"{' '.join(f)!r}")
        if len(f) != 3:
            raise _fail(n, f"expected 3 fields '{form}', found {len(f)}")
        if f[1] != key:
            raise _fail(n, f"expected lens key {key!r} (lens line {i + 1} of {len(keys)}: "
                           f"keys come in the order {', '.join(keys)}), found {f[1]!r}")
        if key == "name":
            values.append(decode_field(f[2], f"table line {n}"))
            continue
        value = _real(f[2], n, f"lens {key}")
        problem = fact_problem(key, value)
        if problem:
            raise _fail(n, f"lens {key} = {f[2]}: {problem}")
        values.append(value)
    return LensFacts(*values)


def read_table(text: str) -> Table:
    """Parse a ``lensfit-poly-table`` text (see the module doc) into systems (a
    :class:`Table`: a list of the systems, with the lens facts as ``.lens``)."""
    lines = _Lines(text)
    n, f = lines.next(f"the header '{FORMAT} {VERSION}'")
    if len(f) != 2 or f[0] != FORMAT:
        raise _fail(n, f"expected the header '{FORMAT} {VERSION}', found {' '.join(f)!r}")
    if f[1] not in map(str, READS):
        raise _fail(n, f"format version {f[1]!r} is not supported (this reader: "
                       f"{', '.join(map(str, READS))})")
    version = int(f[1])
    lens = _lens(lines) if version >= 2 else None
    systems = []
    while not lines.done():
        n, f = lines.next("'system'")
        _fields(n, f, "system", 4, "system <name> <n_inputs> <n_outputs>")
        name = decode_field(f[1], f"table line {n}")
        n_in, n_out = _count(f[2], n, "n_inputs"), _count(f[3], n, "n_outputs")
        inputs = tuple(_input(*lines.next(f"input {j + 1} of {n_in} of system {name!r}"))
                       for j in range(n_in))
        outputs = tuple(_output(lines, n_in) for _ in range(n_out))
        m, end = lines.next(f"'end' of system {name!r}")
        if end != ["end"]:
            raise _fail(m, f"expected 'end' after the {n_out} outputs of system {name!r}, "
                           f"found {' '.join(end)!r}")
        systems.append(System(name, inputs, outputs))
    if not systems:
        raise _fail(lines.last, "no system in the table")
    return Table(systems, lens, version)
