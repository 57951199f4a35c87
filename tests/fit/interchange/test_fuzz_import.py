"""Property-based fuzzing of the importers (issue 15, with the loaders' fuzzing of
tests/fit/test_fuzz_toml.py): random and mutated .zmx text and Optiland JSON never crash.

Property: ``parse_zmx`` / ``decode`` and ``convert_optiland`` either return a lens or
raise one of the errors the command line reports as lines and exit 2 (ImportProblems is
an InputError); any other exception would reach the user as a traceback.

Inputs: the committed fixtures (tests/fit/fixtures/zmx, .../optiland) mutated on the text
(lines deleted, duplicated, swapped; tokens replaced by numbers, words and keywords) and
on the JSON tree (values replaced, keys dropped or added), random keyword lines, and
random bytes through the decoder. Budget as in test_fuzz_toml.py: short and deterministic
by default, LENSFIT_FUZZ_EXAMPLES for a long run.
"""

from __future__ import annotations

import copy
import json
import os
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from lensfit.errors import InputError, LensError
from lensfit.glass import UnknownGlassError
from lensfit.interchange import ImportProblems, convert_optiland, parse_zmx
from lensfit.interchange.zemax import SURFACE_KEYWORDS, decode

FIX = Path(__file__).resolve().parents[1] / "fixtures"
ZMX = [decode(p.read_bytes()) for p in sorted((FIX / "zmx").glob("*.zmx"))]
OPTILAND = [json.loads(p.read_text(encoding="utf-8"))
            for p in sorted((FIX / "optiland").glob("*.json"))]
PROJECT_ERRORS = (InputError, LensError, UnknownGlassError)

EXAMPLES = int(os.environ.get("LENSFIT_FUZZ_EXAMPLES", "0")) or None
FUZZ = settings(max_examples=EXAMPLES or 300, derandomize=True, database=None, deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

KEYWORDS = sorted(SURFACE_KEYWORDS | {"SURF", "MODE", "UNIT", "GCAT", "FTYP", "XFLN", "YFLN",
                                      "FNUM", "NAME", "NOTE", "NSOB", "WAVM", "FLOA", "SQAP"})
TOKENS = st.one_of(
    st.sampled_from(["0", "-0", "1", "-1", "1e308", "-1e308", "1e-320", "nan", "inf",
                     "INFINITY", "9" * 400, "0x10", "1,5", "", "\"\"", "___BLANK", "MIRROR",
                     "N-BK7", "TOROIDAL", "EVENASPH", "COORDBRK", "IN", "MM", "SEQ", "2",
                     "3", "8", "13"]),
    st.sampled_from(KEYWORDS),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**6, 10**6).map(str),
    st.text(st.characters(blacklist_categories=("Cs",)), max_size=6),
)
LINES = st.builds(lambda kw, toks, indent: ("  " if indent else "") + " ".join([kw, *toks]),
                  st.sampled_from(KEYWORDS), st.lists(TOKENS, max_size=5), st.booleans())


@st.composite
def mutated_zmx(draw: st.DrawFn) -> str:
    lines = draw(st.sampled_from(ZMX)).splitlines()
    for _ in range(draw(st.integers(1, 5))):
        if not lines:
            break
        i = draw(st.integers(0, len(lines) - 1))
        op = draw(st.sampled_from(["delete", "duplicate", "swap", "token", "insert",
                                   "truncate"]))
        if op == "delete":
            del lines[i]
        elif op == "duplicate":
            lines.insert(i, lines[i])
        elif op == "swap":
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
        elif op == "token":
            toks = lines[i].split()
            if toks:
                k = draw(st.integers(0, len(toks) - 1))
                toks[k] = draw(TOKENS)
                lines[i] = ("  " if lines[i][:1] == " " else "") + " ".join(toks)
        elif op == "insert":
            lines.insert(i, draw(LINES))
        else:
            lines = lines[:i]
    return "\n".join(lines) + "\n"


def _check_zmx(text: str) -> None:
    try:
        parse_zmx(text, label="fuzz.zmx")
    except PROJECT_ERRORS:
        pass


@FUZZ
@given(text=mutated_zmx())
@example(text="SURF 0\nSURF 1\nSURF 2\n")
@example(text="MODE SEQ\nSURF 0\n  DISZ INFINITY\nSURF 1\n  STOP\n  DISZ 1e308\n  DIAM 1e308\n"
              "SURF 2\n  DISZ 0\n")
def test_zmx_mutations(text: str) -> None:
    _check_zmx(text)


@FUZZ
@given(lines=st.lists(LINES, max_size=30))
def test_zmx_random_lines(lines: list[str]) -> None:
    _check_zmx("\n".join(lines))


@FUZZ
@given(raw=st.binary(max_size=200))
def test_decode_any_bytes(raw: bytes) -> None:
    _check_zmx(decode(raw))  # decode never fails; the text is then just bad input


VALUES = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=6),
              st.sampled_from(["Plane", "StandardGeometry", "EvenAsphere",
                               "ToroidalGeometry", "IdealMaterial", "AbbeMaterial",
                               "Material", "RadialAperture", "Surface", "ImageSurface",
                               "EPD", "imageFNO", "float_by_stop_size"])),
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=8,
)


def _paths(obj: Any, path: tuple = ()) -> list[tuple]:
    out = [path]
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, (*path, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, (*path, i))
    return out


@st.composite
def mutated_optiland(draw: st.DrawFn) -> Any:
    doc = copy.deepcopy(draw(st.sampled_from(OPTILAND)))
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(_paths(doc)))
        if not path:
            continue
        parent: Any = doc
        for p in path[:-1]:
            parent = parent[p]
        if draw(st.booleans()):
            parent[path[-1]] = draw(VALUES)
        elif isinstance(parent, dict):
            del parent[path[-1]]
        else:
            parent.pop(path[-1])
    return doc


@FUZZ
@given(doc=mutated_optiland())
def test_optiland_mutations(doc: Any) -> None:
    try:
        convert_optiland(doc, label="fuzz.json")
    except PROJECT_ERRORS:
        pass


def test_import_problems_is_a_cli_error() -> None:
    # lensfit.cli.main reports InputError subclasses as lines with exit 2
    assert issubclass(ImportProblems, InputError)
