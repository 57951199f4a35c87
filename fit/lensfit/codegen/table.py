"""Coefficient tables: polynomial systems as plain text a small C evaluator can parse.

Format ``lensfit-poly-table``, version 5 (the reader also reads versions 1 and 2). UTF-8 text,
lines end with '\\n'; fields are separated by one or more spaces or tabs (only those:
other Unicode blanks belong to a field), and a '\r' before the '\n' is ignored. Lines that
are empty or start with '#' (after optional blanks) are comments and are skipped anywhere.
(lensfit writes, after the header, where the table comes from and, for a lens folder,
``# wavelengths LO-HI nm: <why>``, the fitted band and its reason: informative only, the
``input lambda`` lines hold the band the readers check.)
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
the polynomials (:class:`lensfit.paraxial.facts.LensFacts`), exactly these keys in this order,
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

Every value but the name is a finite real number written like the others (``%.17g``),
inside its range (below, "Ranges"). Version 1 has no lens lines; the writer emits version
1 when it is given no lens facts.

Version 3 adds the trust lines after the lens lines: how far the PSF of these polynomials
is from the exactly traced one (:mod:`lensfit.trust.check`), so that a runtime can say so when it
loads the table. Exactly these keys, in this order, one line each:

    trust psf_vs_exact       the worst relative L2 distance of the polynomial PSF from the
                             exactly traced PSF over the fit's trust table (0.01 is 1%)
    trust psf_vs_exact_cell  which cell was worst, e.g. f/2%20axis%20450%20nm (a text field)
    trust psf_target         the PSF error the fit was made for (relative L2)

The two numbers are finite and inside their ranges (below). The writer emits version 5
(below) when it is given trust figures, version 2 with lens facts only, version 1 with
neither.

A ghost table (issue 13: one two-reflection path of the lens, rendered as its own lens)
is a version-5 table with ghost lines after the trust lines, exactly these keys in this
order, and a third system ``P_clip``:

    ghost first <i>          model surface index of the first reflection (in path order,
                             the surface reflected at last; integer >= 0)
    ghost second <j>         the surface reflected at first (integer > i)
    ghost label <text>       the lens file's numbering, e.g. 4-8 (a text field): "a-b",
                             decimal without leading zeros, with a = first or first - 1,
                             b = second or second - 1, 0 <= first - a <= second - b <= 1
                             (the loader inserts at most one surface, the stop, which
                             shifts the model's indices behind it by one)
    ghost side <P_o|P_s>     which system is the ghost half (the other is the direct one)

``P_clip`` has exactly the inputs of the ghost side's system and outputs in pairs, each
one clip test (a path passes when every test passes): ``x_h<k> y_h<k>`` (unit ``1``), a
housing crossing over that housing's radius, passes when x^2 + y^2 <= 1; ``x_s<c>
y_s<c>`` (unit ``mm``), a further crossing of the stop plane, passes inside the render's
aperture. The ghost side's own x, y outputs keep their clip against the housing lens
line. :class:`GhostLines` holds the ghost lines (``Table.ghost``; None in a direct table).

Version 4 is version 3 with a last line that every version the writer emits now ends
with (issue 25: integrity):

    checksum crc32 <8 lowercase hex digits>

the CRC-32 (zlib's and PNG's polynomial) of every byte before that line, so that a
table changed after lensfit wrote it (a bit flip, an edit, a table cut short: the line
is then missing) is refused by both readers, naming the file. lensrt reads version 5
only; a version-3 table (no checksum) is refused by both with the command that rewrites
it, `lensfit regenerate <lens id>` (which alone reads version 3: ``legacy=True``; the
coefficients are carried over bit for bit, no refit). Comments are inside the checksum.

Version 5 (issue 39: semantic integrity) is version 4 with probe lines: each system
ends, after its outputs' terms and before its ``end``, with PROBES (6) lines

    probe <v_1> ... <v_n_inputs> <y_1> ... <y_n_outputs>

the system evaluated by the writer at fixed points (PROBE_XHAT: normalised coordinates
mapped back through each input's transform, inside the declared domain), inputs in their
units then outputs in theirs, each ``%.17g``. Both readers evaluate the polynomials as
read at each probe's inputs and refuse the table when an output differs from the line's
by more than PROBE_RTOL * sum |c_t| + PROBE_ATOL (1e-9 of the output's scale: evaluation
order rounding only, see PROBE_RTOL), naming the file, the probe line, the system, the
output and both values: a table whose coefficients were edited, or whose lines were
swapped, and whose checksum was then made again is refused. This is the last check.

Version 4 (no probe lines) is refused by both readers with the commands that upgrade it:
`lensfit regenerate <lens>` rewrites a generated folder's tables (the lens's, its
ghosts', its scenes') and ghosts.json's CRCs of them; `lensfit upgrade-table FILE ...`
one file. Both evaluate the table's own polynomials (:func:`upgrade_text`): every other
byte is kept, no refit. ``read_table(text, legacy=True)`` reads versions 3 and 4.

Ranges (both readers refuse a value outside, naming the key and the value; the writer
refuses to write one; the bounds are inclusive):

    focal_length_mm                        |f| in [1e-3, 1e6] mm (1 um to 1 km)
    stop_radius_max_mm, stop_radius_f1_mm,
    housing_first_mm, housing_last_mm      [1e-3, 1e6] mm
    sensor_defocus_mm,
    front_focal_distance_mm                [-1e6, 1e6] mm
    squeeze                                [0.1, 10] (cinema anamorphics: 1.3 to 2)
    trust psf_vs_exact                     [1e-12, 10]: a measured distance between two
                                           PSFs made by different means is never below
                                           rounding, and at 1000% the fit is another lens
    trust psf_target                       [1e-6, 1]: no fit is made for less than a
                                           millionth, and 100% asks for nothing
    input lo, hi                           finite, lo < hi (inverse_square: lo > 0)
    coefficients, probe values             finite

(:mod:`lensfit.paraxial.facts` holds the lens ranges, TRUST_RANGES the trust ones; lensrt's
runtime/src/lens/table.c the same numbers.) Numbers are the decimal syntax above only:
hex floats (0x1p3), inf, nan and infinity, which C's strtod would read, are refused by
both readers. A table is text: a control byte (below 0x20 but tab, or DEL; a CR only
right before a newline) anywhere, comments included, is refused naming the line.

A system's ``info`` (provenance) is not stored. ``read_table(write_table(s))`` gives back
the names, units, domains, transforms, exponents and coefficients bit for bit, terms in
their order, and the lens facts exactly (:class:`Table`). Malformed text raises ValueError
naming the line: ``table line 7: ...``.
"""

from __future__ import annotations

import math
import re
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lensfit.paraxial.facts import LensFacts, fact_problem
from lensfit.poly import Input, Polynomial, System
from lensfit.poly.polynomial import TRANSFORMS

FORMAT = "lensfit-poly-table"
VERSION = 5  # what the writer emits when given lens facts and trust figures
READS = (1, 2, 5)  # versions the reader accepts (3, 4: only to upgrade, ``legacy=True``)
LEGACY = (3, 4)  # no checksum (3) or no probe lines (4): `lensfit regenerate` rewrites them
CHECKSUM = "checksum crc32"  # the last line: ``checksum crc32 <8 lowercase hex digits>``
_CHECKSUM_LINE = re.compile(rb"checksum crc32 ([0-9a-f]{8})\n\Z")
REGENERATE = ("`lensfit regenerate <lens id or generated folder name>` (rewrites "
              "generated/<lens>/ with checksums and probe lines, no refit), or `lensfit "
              "upgrade-table FILE` for a table file of its own")


def table_checksum(body: bytes) -> str:
    """The checksum line's value for the bytes before it: CRC-32 (the polynomial of zlib
    and PNG) as 8 lowercase hex digits. A CRC detects every error burst of up to 32 bits,
    so every single-bit flip of a table."""
    return f"{zlib.crc32(body) & 0xFFFFFFFF:08x}"


def with_checksum(body: str) -> str:
    """``body`` (a table's text up to its checksum line, ending with a newline) followed
    by that line, as the writer ends every table."""
    return body + f"{CHECKSUM} {table_checksum(body.encode('utf-8'))}\n"


def split_checksum(data: bytes) -> tuple[bytes, str | None]:
    """(the bytes before the checksum line, its value), or (data, None) without one."""
    at = data.rfind(b"\n", 0, len(data) - 1) + 1
    m = _CHECKSUM_LINE.fullmatch(data, at)
    return (data[:at], m.group(1).decode()) if m else (data, None)
TRUST_KEYS = ("psf_vs_exact", "psf_vs_exact_cell", "psf_target")
# The ranges of the trust figures (module doc, "Ranges"), inclusive; a value outside is
# refused by both readers and by the writer, naming the key and the value.
TRUST_RANGES = {"psf_vs_exact": (1e-12, 10.0), "psf_target": (1e-6, 1.0)}

# Probe lines (version 5, module doc): PROBES per system, at these normalised points
# (row p: probe p; column j: input j, for systems of up to 8 inputs). Irrational-looking
# fractions of the domain, every |xhat| distinct within a row and none 0 or +-1, so that
# distinct monomials take distinct values at each point (at a symmetric point, x_a = y_a,
# x_a^3 and x_a y_a^2 would be equal and a swap of their coefficients unseen). Four
# points spread over 0.28..0.96 weigh the low orders, two near opposite corners
# (0.90..0.99) the high ones, which are ~1e-6 in the middle. Measured on every table in
# generated/ (8.8e8 pairs of terms): swapping the coefficients of any two terms of an
# output that differ by more than 6.1e-7 of its scale (sum |c_t|) changes a probe
# beyond the tolerance below (tests/fit/codegen/test_table_probes.py checks a sample).
PROBES = 6
PROBE_XHAT = (
    (0.5692, -0.7758, 0.4534, -0.9197, 0.3358, -0.6936, 0.8800, -0.5333),
    (-0.8173, 0.5504, -0.6690, 0.3538, -0.9620, 0.4623, -0.7562, 0.2821),
    (0.9427, -0.3267, 0.7205, -0.5770, 0.6536, -0.8773, 0.3718, -0.4821),
    (-0.4518, 0.9324, -0.3968, 0.7237, -0.5862, 0.8096, -0.6751, 0.5896),
    (0.9912, -0.9637, 0.9345, -0.9786, 0.9123, -0.9478, 0.9871, -0.9254),
    (-0.9561, 0.9058, -0.9893, 0.9402, -0.9734, 0.9217, -0.9049, 0.9688),
)
# A probe output read back may differ from the polynomials evaluated again by
# PROBE_RTOL * sum |c_t| + PROBE_ATOL. Only rounding may separate them: the writer
# (numpy) and a reader (C, any summation order, FMA or not) each evaluate the same
# polynomial at the same doubles (the probe inputs round-trip through %.17g), so each
# errs by at most (n_terms + 15) * 2^-53 * sum |c_t m_t| <= 1.2e-10 * sum |c_t| for the
# largest table lensrt reads (LENSRT_MAX_TERMS = 1e6 terms; ~1e-13 for the 10^3 terms of
# a real table); 1e-9 is above both errors together. sum |c_t| is the output's scale
# (its bound over the whole domain: every monomial is at most 1 there), so a coefficient
# edited, or two swapped, by more than ~1e-9 of that scale changes a probe beyond the
# tolerance. PROBE_ATOL only keeps an all-zero output's tolerance from being 0.
PROBE_RTOL = 1e-9
PROBE_ATOL = 1e-300
GHOST_KEYS = ("first", "second", "label", "side")
CLIP_SYSTEM = "P_clip"
_INT = re.compile(r"[0-9]+")
_REAL = re.compile(r"[-+]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?")
_BLANKS = re.compile(r"[ \t]+")
_CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f]")


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


@dataclass(frozen=True)
class GhostLines:
    """The ghost lines of a ghost table (module doc)."""

    first: int
    second: int
    label: str
    side: str  # "P_o" or "P_s"

    def check(self) -> None:
        if not 0 <= self.first < self.second:
            raise ValueError(f"ghost first {self.first}, second {self.second}: expected "
                             f"0 <= first < second")
        if self.side not in ("P_o", "P_s"):
            raise ValueError(f"ghost side {self.side!r}: expected P_o or P_s")
        problem = ghost_label_problem(self.first, self.second, self.label)
        if problem:
            raise ValueError(problem)


def ghost_label_problem(first: int, second: int, label: str) -> str | None:
    """What is wrong with a ghost label for model surfaces ``first`` < ``second`` (None
    when nothing is). The label is the lens file's numbering of the two surfaces, "a-b"
    (decimal, no leading zeros: lensfit.ghosts, GhostEstimate.name): the model's index
    less the surfaces the loader inserted before it, and it inserts at most one (the
    stop, lensfit.prescription.load._stop_plane), which reflects nothing. So a is first
    or first - 1, b is second or second - 1, and a surface behind the inserted one in
    the model is behind it in the file: 0 <= first - a <= second - b <= 1."""
    m = re.fullmatch(r"(0|[1-9][0-9]{0,8})-(0|[1-9][0-9]{0,8})", label)
    ok = m is not None and 0 <= first - int(m[1]) <= second - int(m[2]) <= 1
    if ok:
        return None
    return (f"ghost label {label!r} does not number ghost first {first} and ghost second "
            f"{second}: expected '{first}-{second}' (or one less for a surface behind the "
            f"stop surface the loader inserts: '{first}-{second - 1}', "
            f"'{max(first - 1, 0)}-{second - 1}')")


class Table(list[System]):
    """What :func:`read_table` returns: the systems (it is a list of them), plus the
    table's format ``version``, its ``lens`` facts (None in a version-1 table), its
    ``trust`` figures (a dict of TRUST_KEYS; None before version 3) and its ``ghost``
    lines (None in a direct table)."""

    def __init__(self, systems: Sequence[System], lens: LensFacts | None = None,
                 version: int = VERSION, trust: dict[str, Any] | None = None,
                 ghost: GhostLines | None = None) -> None:
        super().__init__(systems)
        self.lens = lens
        self.version = version
        self.trust = trust
        self.ghost = ghost


def trust_problem(key: str, value: float) -> str | None:
    """What is wrong with a (finite) trust figure: None when it is inside TRUST_RANGES."""
    lo, hi = TRUST_RANGES[key]
    if lo <= value <= hi:
        return None
    return f"expected a number in [{lo:g}, {hi:g}] (module doc, Ranges)"


def check_trust(trust: dict[str, Any]) -> dict[str, Any]:
    """The trust figures as the table stores them, or ValueError naming the key."""
    if set(trust) != set(TRUST_KEYS):
        raise ValueError(f"trust: expected the keys {', '.join(TRUST_KEYS)}, found "
                         f"{sorted(trust)}")
    for key in ("psf_vs_exact", "psf_target"):
        v = trust[key]
        if not (isinstance(v, int | float) and math.isfinite(v)):
            raise ValueError(f"trust: {key} = {v!r}: expected a finite number")
        problem = trust_problem(key, v)
        if problem:
            raise ValueError(f"trust: {key} = {v!r}: {problem}")
    if not isinstance(trust["psf_vs_exact_cell"], str):
        raise ValueError("trust: psf_vs_exact_cell: expected text")
    return {k: trust[k] for k in TRUST_KEYS}


def write_table(systems: Sequence[System], comment: str = "",
                lens: LensFacts | None = None, trust: dict[str, Any] | None = None,
                ghost: GhostLines | None = None) -> str:
    """The systems as one ``lensfit-poly-table`` text (``comment`` lines become '# ...').

    With ``lens`` and ``trust`` (defaults: ``systems.lens`` and ``systems.trust`` when
    ``systems`` is a :class:`Table`) the text is version 3 with the lens and trust
    lines; with ``lens`` only, version 2; without, version 1. With ``ghost`` (default
    ``systems.ghost``) it is a ghost table (version 3, module doc)."""
    if lens is None:
        lens = getattr(systems, "lens", None)
    if trust is None:
        trust = getattr(systems, "trust", None)
    if ghost is None:
        ghost = getattr(systems, "ghost", None)
    if trust is not None and lens is None:
        raise ValueError("write_table: trust figures need the lens facts (version 3)")
    if ghost is not None:
        if trust is None:
            raise ValueError("write_table: a ghost table needs the lens facts and trust "
                             "figures (version 3)")
        _check_ghost_systems(ghost, list(systems))
    version = 1 if lens is None else 2 if trust is None else VERSION
    lines = [f"{FORMAT} {version}"]
    lines += [f"# {line}".rstrip() for line in comment.splitlines()]
    if lens is not None:
        lens.check()
        lines.append(f"lens name {encode_field(lens.name)}")
        for key, value in zip(LensFacts.keys()[1:], lens.values()[1:], strict=True):
            lines.append(f"lens {key} {fmt_real(value)}")
    if trust is not None:
        trust = check_trust(trust)
        lines.append(f"trust psf_vs_exact {fmt_real(trust['psf_vs_exact'])}")
        lines.append(f"trust psf_vs_exact_cell {encode_field(trust['psf_vs_exact_cell'])}")
        lines.append(f"trust psf_target {fmt_real(trust['psf_target'])}")
    if ghost is not None:
        lines += [f"ghost first {ghost.first}", f"ghost second {ghost.second}",
                  f"ghost label {encode_field(ghost.label)}", f"ghost side {ghost.side}"]
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
        if version == VERSION:
            lines += probe_lines(s)
        lines.append("end")
    return with_checksum("\n".join(lines) + "\n")


def probe_inputs(system: System) -> np.ndarray:
    """The PROBES points a table's probe lines evaluate ``system`` at, (PROBES, n_inputs)
    in the inputs' units: PROBE_XHAT mapped back through each input's transform, inside
    its domain."""
    n = len(system.inputs)
    if n > len(PROBE_XHAT[0]):
        raise ValueError(f"system {system.name}: {n} inputs; a table's probes cover at most "
                         f"{len(PROBE_XHAT[0])}")
    out = np.empty((PROBES, n))
    for j, inp in enumerate(system.inputs):
        c, sc = inp.offset_scale
        w = c + sc * np.array([row[j] for row in PROBE_XHAT])
        v = w if inp.transform == "affine" else 1.0 / np.sqrt(w)
        out[:, j] = np.clip(v, inp.lo, inp.hi)
    return out


def probe_lines(system: System) -> list[str]:
    """The probe lines of ``system`` (module doc): ``probe <inputs> <outputs>``, each
    value as fmt_real writes it (so that the inputs read back are the same doubles)."""
    x = probe_inputs(system)
    y = system.evaluate(x)
    return [" ".join(["probe", *map(fmt_real, xi), *map(fmt_real, yi)])
            for xi, yi in zip(x.tolist(), y.tolist(), strict=True)]


def upgrade_text(text: str) -> str:
    """A version-3 or version-4 table's text as version 5, the systems unchanged: the
    header says 5, each system gets its probe lines (its own polynomials evaluated, as
    the writer would), the checksum line is computed again; every other byte is kept,
    comments included. ValueError when the text is not a readable version 3 or 4."""
    table = read_table(text, legacy=True)
    if table.version not in LEGACY:
        raise ValueError(f"table version {table.version}: only versions "
                         f"{' and '.join(map(str, LEGACY))} are upgraded")
    body = split_checksum(text.encode("utf-8"))[0].decode("utf-8")
    if not body.endswith("\n"):
        body += "\n"
    out: list[str] = []
    header, k = False, 0
    for line in body.split("\n"):
        bare = line.removesuffix("\r").strip(" \t")
        if not header and bare and not bare.startswith("#"):
            out.append(f"{FORMAT} {VERSION}")
            header = True
            continue
        if bare == "end":
            out += probe_lines(table[k])
            k += 1
        out.append(line)
    new = with_checksum("\n".join(out))
    if write_table(read_table(new)) != write_table(table):
        raise ValueError("the systems differ after the upgrade")  # cannot happen
    return new


def restamp_probes(text: str) -> str:
    """A version-5 (or 4) table text edited by hand, given the probe lines and checksum
    lensfit would write for the systems it now holds (old probe and checksum lines
    dropped): for tests and tools that build tables from pieces, as :func:`with_checksum`
    is for the checksum alone. Every other byte is kept."""
    body = split_checksum(text.encode("utf-8"))[0].decode("utf-8")
    lines = [line for line in body.split("\n") if not line.lstrip(" \t").startswith("probe ")]
    for i, line in enumerate(lines):
        bare = line.strip(" \t\r")
        if bare and not bare.startswith("#"):
            if bare.split()[0] == FORMAT:
                lines[i] = f"{FORMAT} 4"
            break
    body = "\n".join(lines)
    return upgrade_text(with_checksum(body if body.endswith("\n") else body + "\n"))


def probe_problem(system: System, inputs: np.ndarray, outputs: np.ndarray) -> str | None:
    """None when ``system`` evaluated at each probe's ``inputs`` gives its ``outputs``
    within the tolerance (PROBE_RTOL); else what differs: the system, the output, the
    probe and both values."""
    got = system.evaluate(inputs)
    for k, p in enumerate(system.outputs):
        tol = PROBE_RTOL * float(np.abs(p.coefficients).sum()) + PROBE_ATOL
        diff = np.abs(got[:, k] - outputs[:, k])
        if np.all(diff <= tol):
            continue
        i = int(np.argmax(diff > tol))
        return (f"system {system.name}: output {p.output}: probe {i + 1} of {len(inputs)}: "
                f"the polynomials give {fmt_real(got[i, k])}, the probe line says "
                f"{fmt_real(outputs[i, k])} (difference {diff[i]:.3g}, tolerance {tol:.3g}): "
                "coefficients changed after lensfit wrote the table (edited, or lines "
                "swapped, behind a valid checksum); refused")
    return None


class _Lines:
    """Significant lines with their 1-based numbers; errors name the line."""

    def __init__(self, text: str) -> None:
        self.rows = []
        for i, line in enumerate(text.split("\n"), start=1):
            line = line.removesuffix("\r")
            bad = _CONTROL.search(line)
            if bad:
                raise _fail(i, f"control byte 0x{ord(bad[0]):02x} at column {bad.start() + 1}: "
                               "a table is text (a tab is the only control character it may "
                               "hold, a CR only before the newline); refused")
            line = line.strip(" \t")
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


def _keyed(lines: _Lines, keyword: str, keys: tuple[str, ...]):
    """The lines '<keyword> <key> <value>', every key once in the documented order: yields
    (line number, key, value token)."""
    for i, key in enumerate(keys):
        form = f"{keyword} {key} <value>"
        where = f"{keyword} line {i + 1} of {len(keys)}"
        n, f = lines.next(f"'{form}' ({where})")
        if len(f) != 3 or f[0] != keyword or f[1] != key:
            raise _fail(n, f"expected '{form}' ({where}: keys come in the order "
                           f"{', '.join(keys)}), found {' '.join(f)!r}")
        yield n, key, f[2]


def _trust(lines: _Lines) -> dict[str, Any]:
    """The trust lines of a version-3 table."""
    out: dict[str, Any] = {}
    for n, key, token in _keyed(lines, "trust", TRUST_KEYS):
        if key == "psf_vs_exact_cell":
            out[key] = decode_field(token, f"table line {n}")
            continue
        value = _real(token, n, f"trust {key}")
        problem = trust_problem(key, value)
        if problem:
            raise _fail(n, f"trust {key} = {token}: {problem}")
        out[key] = value
    return out


def _ghost(lines: _Lines) -> GhostLines | None:
    """The ghost lines, if the next line starts them."""
    if lines.done() or lines.rows[lines.pos][1][0] != "ghost":
        return None
    values: list[Any] = []
    for n, key, token in _keyed(lines, "ghost", GHOST_KEYS):
        values.append(_count(token, n, f"ghost {key}") if key in ("first", "second")
                      else decode_field(token, f"table line {n}"))
        if key == "side" and values[-1] not in ("P_o", "P_s"):
            raise _fail(n, f"ghost side {token!r}: expected P_o or P_s")
        if key == "second" and values[1] <= values[0]:
            raise _fail(n, f"ghost second {values[1]}: expected more than ghost first "
                           f"{values[0]}")
        if key == "label":
            problem = ghost_label_problem(values[0], values[1], values[2])
            if problem:
                raise _fail(n, problem)
    return GhostLines(*values)


def _check_ghost_systems(ghost: GhostLines, systems: list[System]) -> None:
    """A ghost table's systems: P_o, P_s and P_clip, P_clip with the ghost side's inputs
    and (x, y) pairs named and united as the module doc says. A scene's specialisation
    (``lensfit scene``) has P_o_light<i> (and P_clip_light<i> on side P_o) instead."""
    names = [s.name for s in systems]
    general = sorted(names) in (["P_clip", "P_o", "P_s"], ["P_o", "P_s"])
    if not general and not all(re.fullmatch(r"(P_o|P_s|P_clip)(_light[0-9]+)?", n)
                               for n in names):
        raise ValueError(f"ghost table: expected systems P_o, P_s and {CLIP_SYSTEM}, found "
                         f"{', '.join(names)}")
    by = {s.name: s for s in systems}
    clip = by.get(CLIP_SYSTEM)
    if general and clip is not None and clip.inputs != by[ghost.side].inputs:
        raise ValueError(f"ghost table: {CLIP_SYSTEM}'s inputs differ from those of "
                         f"{ghost.side}, the ghost side")
    for c in systems:
        if not c.name.startswith(CLIP_SYSTEM):
            continue
        outs = c.outputs
        if not outs or len(outs) % 2 or len(outs) > 8:
            raise ValueError(f"ghost table: {c.name} has {len(outs)} outputs; expected "
                             f"2 to 8 in (x, y) pairs")
        for px, py in zip(outs[::2], outs[1::2], strict=True):
            m = re.fullmatch(r"x_([hs])([0-9]+)", px.output)
            ok = (m is not None and py.output == f"y_{m[1]}{m[2]}" and px.unit == py.unit
                  == ("1" if m[1] == "h" else "mm"))
            if not ok:
                raise ValueError(f"ghost table: {c.name} outputs {px.output!r} "
                                 f"({px.unit}), {py.output!r} ({py.unit}): expected a pair "
                                 f"x_h<k>, y_h<k> (unit 1) or x_s<c>, y_s<c> (unit mm)")


def read_table(text: str, *, legacy: bool = False) -> Table:
    """Parse a ``lensfit-poly-table`` text (see the module doc) into systems (a
    :class:`Table`: a list of the systems, with the lens facts as ``.lens``). The last
    line's checksum is verified first; ``legacy`` also reads version 3 (no checksum), as
    `lensfit regenerate` does to rewrite it."""
    data = text.encode("utf-8")
    body, checksum = split_checksum(data)
    lines = _Lines(body.decode("utf-8"))
    n, f = lines.next(f"the header '{FORMAT} {VERSION}'")
    if len(f) != 2 or f[0] != FORMAT:
        raise _fail(n, f"expected the header '{FORMAT} {VERSION}', found {' '.join(f)!r}")
    if f[1] == "3" and not legacy:
        raise _fail(n, f"table version 3 carries no checksum; regenerate it with "
                       f"{REGENERATE}")
    if f[1] == "4" and not legacy:
        raise _fail(n, "table version 4 carries no probe lines (so swapped or edited "
                       "coefficients behind a valid checksum could not be told); upgrade it "
                       f"with {REGENERATE}")
    if f[1] not in map(str, READS) and f[1] not in map(str, LEGACY):
        raise _fail(n, f"format version {f[1]!r} is not supported (this reader: "
                       f"{', '.join(map(str, READS))})")
    version = int(f[1])
    if version != 3:
        last = data.count(b"\n") + (not data.endswith(b"\n"))
        if checksum is None:
            raise _fail(last, f"expected the last line '{CHECKSUM} <8 hex digits>' (a table "
                              "cut short, or edited): refused")
        if checksum != table_checksum(body):
            raise _fail(last, f"checksum {checksum} does not match the content "
                              f"({table_checksum(body)}): the table was changed after lensfit "
                              "wrote it; refused")
    lens = _lens(lines) if version >= 2 else None
    trust = _trust(lines) if version >= 3 else None
    ghost = _ghost(lines) if version >= 3 else None
    systems = []
    probes: list[tuple[int, np.ndarray, np.ndarray]] = []
    while not lines.done():
        n, f = lines.next("'system'")
        _fields(n, f, "system", 4, "system <name> <n_inputs> <n_outputs>")
        name = decode_field(f[1], f"table line {n}")
        n_in, n_out = _count(f[2], n, "n_inputs"), _count(f[3], n, "n_outputs")
        inputs = tuple(_input(*lines.next(f"input {j + 1} of {n_in} of system {name!r}"))
                       for j in range(n_in))
        outputs = tuple(_output(lines, n_in) for _ in range(n_out))
        if version == VERSION:
            probes.append(_probes(lines, name, inputs, n_out))
        m, end = lines.next(f"'end' of system {name!r}")
        if end != ["end"]:
            raise _fail(m, f"expected 'end' after the {n_out} outputs of system {name!r}, "
                           f"found {' '.join(end)!r}")
        systems.append(System(name, inputs, outputs))
    if not systems:
        raise _fail(lines.last, "no system in the table")
    if ghost is not None:
        try:
            _check_ghost_systems(ghost, systems)
        except ValueError as e:
            raise _fail(lines.last, str(e)) from None
    elif CLIP_SYSTEM in (s.name for s in systems):
        raise _fail(lines.last, f"system {CLIP_SYSTEM} in a table without ghost lines")
    # Last, the probes: the polynomials as read must give what the writer computed
    for s, (n, x, y) in zip(systems, probes, strict=False):
        problem = probe_problem(s, x, y)
        if problem:
            raise _fail(n, problem)
    return Table(systems, lens, version, trust, ghost)


def _probes(lines: _Lines, name: str, inputs: tuple[Input, ...],
            n_out: int) -> tuple[int, np.ndarray, np.ndarray]:
    """A system's PROBES probe lines: (the first one's line number, inputs, outputs)."""
    n_in = len(inputs)
    x, y = np.empty((PROBES, n_in)), np.empty((PROBES, n_out))
    first = 0
    form = "probe <input values> <output values>"
    for i in range(PROBES):
        n, f = lines.next(f"probe line {i + 1} of {PROBES} of system {name!r}")
        first = first or n
        if not f or f[0] != "probe":
            raise _fail(n, f"expected '{form}' (probe line {i + 1} of {PROBES} of system "
                           f"{name!r}, after its outputs), found {' '.join(f)!r}")
        if len(f) != 1 + n_in + n_out:
            raise _fail(n, f"probe of system {name!r}: expected {n_in} input values and "
                           f"{n_out} output values, found {len(f) - 1} values")
        for j, inp in enumerate(inputs):
            v = _real(f[1 + j], n, f"probe input {inp.name}")
            if not inp.lo <= v <= inp.hi:
                raise _fail(n, f"probe input {inp.name} = {f[1 + j]} is outside its domain "
                               f"[{fmt_real(inp.lo)}, {fmt_real(inp.hi)}]")
            x[i, j] = v
        y[i] = [_real(tok, n, f"probe output {k + 1}") for k, tok in enumerate(f[1 + n_in:])]
    return first, x, y
