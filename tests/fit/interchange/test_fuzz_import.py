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

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from lensfit.common.errors import InputError, LensError
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
# No glass anywhere: no power, no finite focal length for FNUM to map (found by make fuzz)
@example(text="MODE SEQ\nUNIT MM\nFNUM 4 0\nSURF 0\n  DISZ INFINITY\nSURF 1\n  STOP\n  DISZ 1.5\n"
              "  DIAM 6 1 0 0 1 \"\"\nSURF 2\n  CURV 0.05\n  DISZ 5\n  DIAM 8 1 0 0 1 \"\"\n"
              "SURF 3\n  CURV -0.0125\n  DISZ 28\n  DIAM 8 1 0 0 1 \"\"\nSURF 4\n  DISZ 0\n")
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


# Issue 25: the shapes the first fuzzer never produced (7 Optiland tracebacks, 3 lentil):
# huge integers, numbers beyond a float's range, deep nesting, containers of the wrong
# type (a list where an object is expected), other encodings. The whole path from the
# file's bytes is fuzzed (lensfit.strict_json, then the converter).

from lensfit.common import strict_json  # noqa: E402
from lensfit.prescription.lentil import convert_entry  # noqa: E402

LENTIL = [{"optical-elements-patent": [
    {"radius": 50.0, "thickness": 5.0, "material": "BK7", "ior": 1.5168, "abbe": 64.17,
     "housing-radius": 10.0},
    {"radius": -50.0, "thickness": 5.0, "material": "air", "housing-radius": 10.0},
    {"radius": 0, "thickness": 5.0, "material": "iris", "housing-radius": 8.0},
    {"radius": 1e5, "thickness": [40.0, 41.0], "material": "abbe", "ior": 1.6, "abbe": 40.0,
     "housing-radius": 10.0, "lens-geometry": "aspherical",
     "aspherical-equation": [0.0, 1e-6]}], "year": 1950, "company": "x"}]

HOSTILE = st.one_of(
    # Huge integers (as objects, below Python's 4,300-digit printing limit, which
    # hypothesis needs to report them; 5,001 digits are fuzzed as text below)
    st.integers(min_value=-10**4000, max_value=10**4000),
    st.sampled_from([10**400, -10**400, 10**309, 2**1024, 10**4000]),
    st.sampled_from([1e308, -1e308, 5e-324, 0.0, -0.0]),
    st.recursive(st.integers(0, 3), lambda inner: st.lists(inner, min_size=1, max_size=1),
                 max_leaves=200),                              # deep (up to 200 levels)
    st.builds(lambda n: _wrap([], n), st.integers(50, 400)),     # deeper than the limit
    st.builds(list, st.lists(VALUES, max_size=2)),              # a list where an object is
    st.dictionaries(st.text(max_size=4), VALUES, max_size=2),  # an object where a list is
    st.text(max_size=4),
)


def _wrap(value: Any, depth: int) -> Any:
    for _ in range(depth):
        value = [value]
    return value


@st.composite
def hostile_tree(draw: st.DrawFn, docs: list[Any]) -> Any:
    """A fixture with 1-3 values (or whole containers) replaced by hostile shapes, or
    wrapped in a list (a list where an object is expected)."""
    doc = copy.deepcopy(draw(st.sampled_from(docs)))
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(_paths(doc)))
        if not path:
            if draw(st.booleans()):
                doc = [doc]
            continue
        parent: Any = doc
        for p in path[:-1]:
            parent = parent[p]
        old = parent[path[-1]]
        parent[path[-1]] = draw(st.one_of(HOSTILE, st.just([old]),
                                          st.builds(_wrap, st.just(old), st.integers(1, 80))))
    return doc


ENCODINGS = ["utf-8", "utf-8-sig", "utf-16", "utf-16-le", "utf-16-be", "utf-32",
             "latin-1", "cp1252"]


def _encode(doc: Any, encoding: str, raw_numbers: bool) -> bytes:
    """The document as a file's bytes; Python's json writes integers of any size (with
    the digit limit lifted) and inf as Infinity, as a hostile file would hold them."""
    import sys

    old = sys.get_int_max_str_digits()
    sys.set_int_max_str_digits(0)
    try:
        text = json.dumps(doc, ensure_ascii=not raw_numbers)
    finally:
        sys.set_int_max_str_digits(old)
    return text.encode(encoding, errors="replace")


def _through_file(raw: bytes, convert) -> None:
    try:
        data = strict_json.loads(raw, "fuzz.json")
        convert(data)
    except PROJECT_ERRORS:
        pass


@FUZZ
@given(doc=hostile_tree(OPTILAND), encoding=st.sampled_from(ENCODINGS), raw=st.booleans())
@example(doc={"surface_group": [{"surfaces": []}]}, encoding="utf-8", raw=False)
@example(doc={"surface_group": {"surfaces": [10**400]}}, encoding="utf-8", raw=False)
def test_optiland_hostile_files(doc: Any, encoding: str, raw: bool) -> None:
    _through_file(_encode(doc, encoding, raw),
                  lambda d: convert_optiland(d, label="fuzz.json"))


@FUZZ
@given(doc=hostile_tree(OPTILAND))
def test_optiland_hostile_trees(doc: Any) -> None:
    """The converter on its own (an API caller's dict: no strict_json in front)."""
    try:
        convert_optiland(doc, label="fuzz.json")
    except PROJECT_ERRORS:
        pass


def _lentil(data: Any) -> None:
    if not isinstance(data, dict):
        return  # load_lentil_json refuses it (tested in test_cli_errors)
    for lens_id, entry in data.items():
        convert_entry(str(lens_id), entry, source="fuzz.json")


@FUZZ
@given(entry=hostile_tree(LENTIL), encoding=st.sampled_from(ENCODINGS), raw=st.booleans())
@example(entry={"optical-elements-patent": [{"radius": 10**400}]}, encoding="utf-8",
         raw=False)
def test_lentil_hostile_files(entry: Any, encoding: str, raw: bool) -> None:
    _through_file(_encode({"0001": entry}, encoding, raw), _lentil)


@FUZZ
@given(entry=hostile_tree(LENTIL))
def test_lentil_hostile_entries(entry: Any) -> None:
    try:
        _lentil({"0001": entry})
    except PROJECT_ERRORS:
        pass


@FUZZ
@given(text=mutated_zmx(), encoding=st.sampled_from(ENCODINGS),
       token=st.sampled_from(["9" * 5001, "1" + "0" * 400, "1e400", "-1e-400", "[[[[",
                              "{\"a\": 1}", "\x00", "\ufeff"]))
def test_zmx_hostile_encodings(text: str, encoding: str, token: str) -> None:
    lines = text.splitlines()
    if lines:
        lines[len(lines) // 2] += " " + token
    _check_zmx(decode("\n".join(lines).encode(encoding, errors="replace")))


@pytest.mark.parametrize("raw", [
    b"\xff\xfe" + "{}".encode("utf-16-le"), b"[" * 100000, b"1" * 5001, b"1e400",
    b'{"a": ' + b"1" * 400 + b"}", b"\xe9", b"-1e-400",
])
def test_strict_json_refuses_in_one_line(raw: bytes) -> None:
    try:
        strict_json.loads(raw, "x.json")
    except strict_json.JSONInputError as e:
        assert "\n" not in str(e) and str(e).startswith("x.json")


NUMBER = __import__("re").compile(r"(?<=: )-?\d[\d.eE+-]*")
TEXT_TOKENS = ["9" * 5001, "1" + "0" * 400, "-1e400", "1e-400", "[" * 5000 + "]" * 5000,
               "[" * 70 + "1" + "]" * 70, '"1.5"', "[]", "{}", "null", "true", "Infinity",
               "NaN"]


@FUZZ
@given(which=st.sampled_from(["optiland", "lentil"]), data=st.data(),
       encoding=st.sampled_from(ENCODINGS))
def test_hostile_number_text(which: str, data: st.DataObject, encoding: str) -> None:
    """A number literal of a fixture's text replaced by a hostile token (5,001 digits,
    1e400, thousands of brackets, a string or container where a number is)."""
    doc = OPTILAND[0] if which == "optiland" else {"0001": LENTIL[0]}
    text = json.dumps(doc, indent=1)
    spots = list(NUMBER.finditer(text))
    for _ in range(data.draw(st.integers(1, 3))):
        m = data.draw(st.sampled_from(spots))
        text = text[:m.start()] + data.draw(st.sampled_from(TEXT_TOKENS)) + text[m.end():]
        spots = list(NUMBER.finditer(text))
    convert = ((lambda d: convert_optiland(d, label="fuzz.json")) if which == "optiland"
               else _lentil)
    _through_file(text.encode(encoding, errors="replace"), convert)
