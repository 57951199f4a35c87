"""Helpers shared by the emitters: names, literals, comments and the per-system summary.

Everything here is deterministic text: no dict or set is iterated without sorting, so
emitting the same systems twice gives the same bytes whatever the hash seed.
"""

from __future__ import annotations

import math
import re
import unicodedata
from collections.abc import Sequence

import numpy as np

from lensfit.poly import Input, Polynomial, System

_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_NAME_PART = re.compile(r"[A-Za-z0-9_]+")
FLT_MAX = float(np.finfo(np.float32).max)

# C / GLSL type of each variant: "d" double, "f" float
REALS = {"d": "double", "f": "float"}


def check_prefix(prefix: str) -> str:
    """The symbol prefix must be a C identifier that C and GLSL do not reserve."""
    if not isinstance(prefix, str) or not _IDENT.fullmatch(prefix):
        raise ValueError(f"symbol prefix {prefix!r} is not a C identifier "
                         "(letters, digits and '_', not starting with a digit)")
    if prefix.startswith("_"):
        raise ValueError(f"symbol prefix {prefix!r}: external identifiers starting with "
                         "'_' are reserved in C")
    if prefix.startswith("gl_") or "__" in prefix:
        raise ValueError(f"symbol prefix {prefix!r}: 'gl_' prefixes and '__' are reserved "
                         "in GLSL")
    return prefix


def check_systems(systems: Sequence[System], prefix: str) -> list[System]:
    """Validate what every emitter needs: names usable in symbols, non-empty systems."""
    check_prefix(prefix)
    systems = list(systems)
    if not systems:
        raise ValueError("no systems to emit")
    seen: set[str] = set()
    for s in systems:
        if not _NAME_PART.fullmatch(s.name):
            raise ValueError(f"system name {s.name!r} cannot be part of a C symbol "
                             "(use letters, digits and '_')")
        symbol = prefix + s.name
        if "__" in symbol + "_":
            raise ValueError(f"symbol {symbol!r} contains '__', reserved in GLSL; "
                             "change the prefix or the system name")
        if s.name in seen:
            raise ValueError(f"system name {s.name!r} appears twice")
        seen.add(s.name)
        if not s.inputs or not s.outputs:
            raise ValueError(f"system {s.name}: code generation needs at least one input "
                             f"and one output, found {len(s.inputs)} and {len(s.outputs)}")
    return systems


def ascii_text(text: str) -> str:
    """Comment-safe ASCII: Greek letters by name (tau, Phi), other non-ASCII as U+XXXX."""
    out = []
    for ch in text:
        if 32 <= ord(ch) < 127:
            out.append(ch)
            continue
        uname = unicodedata.name(ch, "")
        greek = uname.removeprefix("GREEK SMALL LETTER ").removeprefix("GREEK CAPITAL LETTER ")
        greek = "LAMBDA" if greek == "LAMDA" else greek  # Unicode spells it without the b
        if uname.startswith("GREEK SMALL LETTER "):
            out.append(greek.lower())
        elif uname.startswith("GREEK CAPITAL LETTER "):
            out.append(greek.capitalize())
        elif uname == "MICRO SIGN":
            out.append("u")
        elif uname == "DEGREE SIGN":
            out.append("deg")
        else:
            out.append(f"U+{ord(ch):04X}")
    # Never close a comment early
    return "".join(out).replace("*/", "* /")


def ident_part(text: str) -> str:
    """A name made usable inside a C identifier: ASCII, other characters as '_'."""
    return re.sub(r"[^A-Za-z0-9_]", "_", ascii_text(text)).strip("_") or "x"


def unique_parts(names: Sequence[str]) -> list[str]:
    """ident_part of each name; a clash (or '__', reserved in GLSL) falls back to index."""
    parts = [re.sub(r"_+", "_", ident_part(n)) for n in names]
    return [p if parts.count(p) == 1 else f"{p}_{i}" for i, p in enumerate(parts)]


def unit_text(unit: str) -> str:
    return ascii_text(unit) if unit else "1"


def fmt_double(x: float) -> str:
    """C double literal, 17 significant digits (round-trip exact), always with '.' or 'e'."""
    s = format(float(x), ".17g")
    if not any(ch in s for ch in ".en"):
        s += ".0"
    return s


def fmt_float(x: float, what: str = "constant") -> str:
    """C/GLSL float literal of x rounded to float32, 9 significant digits (round-trip)."""
    f = float(np.float32(x)) if abs(x) <= FLT_MAX else math.inf
    if not math.isfinite(f):
        raise ValueError(f"{what} {x!r} does not fit a float; emit the double variant only")
    s = format(f, ".9g")
    if not any(ch in s for ch in ".e"):
        s += ".0"
    return s + "f"


def fmt_plain(x: float) -> str:
    """Shortest round-trip decimal for comments (12.5, not 12.500000000000000)."""
    return repr(float(x))


def comment_block(text: str, indent: str = "") -> list[str]:
    """A C/GLSL block comment; each line of text becomes ' * line' (ASCII only)."""
    lines = [f"{indent}/*"]
    for line in text.splitlines() or [""]:
        line = ascii_text(line).rstrip()
        lines.append(f"{indent} * {line}".rstrip())
    lines.append(f"{indent} */")
    return lines


def input_comment(inp: Input) -> str:
    """`x_O [mm], domain [-12.0, 12.0] mm, affine: xhat = (v - c)/s, c = 0 mm, s = 12 mm`."""
    u = unit_text(inp.unit)
    c, s = inp.offset_scale
    if inp.transform == "affine":
        how, wu = "affine: xhat = (v - c)/s", u
    else:
        how, wu = "inverse_square: xhat = (1/v^2 - c)/s", f"1/{u}^2"
    return (f"{ascii_text(inp.name)} [{u}], domain [{fmt_plain(inp.lo)}, {fmt_plain(inp.hi)}]"
            f" {u}, {how}, c = {fmt_plain(c)} {wu}, s = {fmt_plain(s)} {wu}")


def count(n: int, word: str) -> str:
    """'1 term', '150 terms'."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def output_comment(p: Polynomial) -> str:
    return (f"{ascii_text(p.output)} [{unit_text(p.unit)}]: {count(p.terms, 'term')}, "
            f"max degree {p.max_degree}")


def system_defines(system: System, prefix: str) -> list[str]:
    """`#define`s shared by the C headers and the GLSL: counts, indices and domains.

    Every line carries its unit; identical text in every file, so including several of
    them in one translation unit is a legal identical redefinition."""
    sym = prefix + system.name
    n_in, n_out = len(system.inputs), len(system.outputs)
    lines = [f"#define {sym}_N_IN {n_in} /* number of inputs of {sym}_* */",
             f"#define {sym}_N_OUT {n_out} /* number of outputs of {sym}_* */"]
    for j, (inp, part) in enumerate(zip(system.inputs, unique_parts(system.input_names),
                                        strict=True)):
        u = unit_text(inp.unit)
        lines.append(f"#define {sym}_IN_{part} {j} /* {input_comment(inp)} */")
        lines.append(f"#define {sym}_LO_{part} ({fmt_double(inp.lo)}) /* [{u}] lower bound */")
        lines.append(f"#define {sym}_HI_{part} ({fmt_double(inp.hi)}) /* [{u}] upper bound */")
    for i, (p, part) in enumerate(zip(system.outputs, unique_parts(system.output_names),
                                      strict=True)):
        lines.append(f"#define {sym}_OUT_{part} {i} /* {output_comment(p)} */")
    return lines


def wrap_expression(expr: str, first: str, indent: str, width: int = 96) -> list[str]:
    """``first`` then the tokens of ``expr``, broken at spaces into lines of <= ``width``.

    The emitters put spaces only between tokens, so a break never splits a token; every
    line holds at least one token."""
    lines, line, bare = [], first, True
    for token in expr.split(" "):
        if not bare and len(line) + 1 + len(token) > width:
            lines.append(line)
            line = indent + token
        else:
            line = f"{line} {token}"
        bare = False
    lines.append(line)
    return lines
