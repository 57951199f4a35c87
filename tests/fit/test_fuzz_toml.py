"""Property-based fuzzing of the TOML loaders (issue 14): the lens prescription loader
(``lensfit.prescription.load.load_lens``, what ``lensfit info`` uses), the scene loader
(``lensfit.scene.load_scene``) and the bank spec loader (``lensfit.banks.spec.load_spec``).

Property: loading any file either succeeds or raises one of the errors the command line
reports as one line (``lensfit.cli.main`` catches exactly these); any other exception
(RecursionError, OverflowError, TypeError, KeyError, a bare ValueError) would reach the user
as a traceback, which the CLI treats as a bug.

Inputs: (a) mutations of the committed files (lensdb/*.toml, scenes/*.toml), both on the
text (delete, duplicate, replace characters) and on the parsed tables (replace a value with
a huge/negative/NaN/inf number, a string, a nested table or array; drop a key; add an
unknown key), written back with a small TOML writer; (b) random TOML documents from a
strategy of nested tables.

Budget: a short deterministic run by default (``derandomize=True``, no example database, so
CI sees the same examples every time); set LENSFIT_FUZZ_EXAMPLES (e.g. 20000, as
``make fuzz`` does) for a long run.
"""

from __future__ import annotations

import json
import math
import os
import re
import tomllib
from pathlib import Path
from typing import Any

import pytest
from bank_specs import bank_spec
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

from lensfit.banks.spec import load_spec
from lensfit.codegen.scene import SceneError, load_scene
from lensfit.common.errors import InputError, LensError
from lensfit.glass import UnknownGlassError
from lensfit.prescription.load import load_lens
from lensfit.sample.aim import SamplingError

ROOT = Path(__file__).resolve().parents[2]
LENS_FILES = sorted((ROOT / "lensdb").glob("*.toml"))
SCENE_FILES = sorted((ROOT / "scenes").glob("*.toml"))
LENS_TEXTS = [p.read_text(encoding="utf-8") for p in LENS_FILES]
SCENE_TEXTS = [p.read_text(encoding="utf-8") for p in SCENE_FILES]
BANK_FILES = sorted((ROOT / "banks").glob("*.toml"))
BANK_TEXTS = [p.read_text(encoding="utf-8") for p in BANK_FILES]

# The errors lensfit.cli.main turns into one line and exit status 2.
PROJECT_ERRORS = (InputError, LensError, SceneError, SamplingError, UnknownGlassError)

EXAMPLES = int(os.environ.get("LENSFIT_FUZZ_EXAMPLES", "0")) or None
FUZZ = settings(
    # Short by default: each test runs in a few seconds on the 2-core CI machine.
    max_examples=EXAMPLES or 300,
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                           HealthCheck.filter_too_much, HealthCheck.data_too_large],
)


# --- a small TOML writer (no tomli_w in the venv) -------------------------------------

def _string(s: str) -> str:
    # JSON string escapes are valid TOML basic-string escapes; TOML also forbids a raw DEL.
    return json.dumps(s, ensure_ascii=False).replace("\x7f", "\\u007f")


def _key(k: str) -> str:
    return _string(k)  # a quoted key always parses


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return _string(v)
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__}")  # only reached by a test bug


def dumps(doc: dict[str, Any]) -> str:
    """A TOML document with every top-level key on one line (tables inline)."""
    return "".join(f"{_key(k)} = {_value(v)}\n" for k, v in doc.items())


def test_writer_round_trips_the_committed_files() -> None:
    # The writer must reproduce what tomllib read, or the structural mutations below
    # would test the writer instead of the loaders.
    for text in LENS_TEXTS + SCENE_TEXTS + BANK_TEXTS:
        doc = tomllib.loads(text)
        assert tomllib.loads(dumps(doc)) == doc


# --- strategies -------------------------------------------------------------------------

text_no_surrogates = st.text(st.characters(blacklist_categories=("Cs",)), max_size=12)


def _all_keys(obj: Any) -> set[str]:
    if isinstance(obj, dict):
        return set(obj).union(*(_all_keys(v) for v in obj.values()))
    if isinstance(obj, list):
        return set().union(*(_all_keys(v) for v in obj))
    return set()


# Keys the loaders know (taken from the committed files), so random documents get past the
# unknown-key checks, mixed with arbitrary ones.
KNOWN_KEYS = sorted(set().union(*(_all_keys(tomllib.loads(t))
                                  for t in LENS_TEXTS + SCENE_TEXTS + BANK_TEXTS)))
keys = st.one_of(st.sampled_from(KNOWN_KEYS), text_no_surrogates)
scalars = st.one_of(
    st.booleans(),
    st.integers(),
    st.sampled_from([0, -1, 10**400, -(10**400), 2**63 - 1, -(2**63)]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, -1.0, 1e-320, 1e308, -1e308]),
    text_no_surrogates,
    st.sampled_from(["inf", "nan", "-inf", "", "air", "sphere", "mgf2", "1e999"]),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4),
        st.dictionaries(keys, inner, max_size=4),
    ),
    max_leaves=12,
)
documents = st.dictionaries(keys, values, max_size=6)


def _paths(obj: Any, path: tuple = ()) -> list[tuple]:
    """Every key path into a parsed document (the root is the empty path)."""
    out = [path]
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, (*path, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, (*path, i))
    return out


def _mutate_tree(draw: st.DrawFn, doc: dict[str, Any]) -> dict[str, Any]:
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(_paths(doc)))
        op = draw(st.sampled_from(["replace", "drop", "add"]))
        if not path:
            op = "add"
        parent: Any = doc
        for p in path[:-1]:
            parent = parent[p]
        target = parent[path[-1]] if path else doc
        if op == "replace":
            parent[path[-1]] = draw(values)
        elif op == "drop":
            del parent[path[-1]]
        elif isinstance(target, dict):
            target[draw(keys)] = draw(values)
        elif isinstance(target, list):
            target.append(draw(values))
        else:
            parent[path[-1]] = draw(values)
    return doc


def _mutate_text(draw: st.DrawFn, text: str) -> str:
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, max(len(text) - 1, 0)))
        n = draw(st.integers(1, 8))
        op = draw(st.sampled_from(["delete", "duplicate", "replace"]))
        if op == "delete":
            text = text[:i] + text[i + n:]
        elif op == "duplicate":
            text = text[:i] + text[i:i + n] + text[i:]
        else:
            text = text[:i] + draw(st.sampled_from(
                ["9" * 400, "-", "nan", "inf", "[", "]", "{", "\"", "=", "\n", "[[surface]]\n",
                 "\x00", "é", "1e999", "0", "{a = {b = 1}}"])) + text[i + n:]
    return text


@st.composite
def mutated(draw: st.DrawFn, texts: list[str]) -> str:
    text = draw(st.sampled_from(texts))
    if draw(st.booleans()):
        return _mutate_text(draw, text)
    return dumps(_mutate_tree(draw, tomllib.loads(text)))


# --- the property ---------------------------------------------------------------------

def _check(loader: Any, path: Path, text: str) -> None:
    path.write_text(text, encoding="utf-8")
    try:
        loader(path)
    except PROJECT_ERRORS as e:
        # The CLI reports these as one line naming the file and key; the event shows
        # (with --hypothesis-show-statistics) how far into the loaders the inputs reach.
        event(type(e).__name__ + ": " + str(e).split(": ", 2)[-1][:40])
    else:
        event("loaded")


DEEP = "x = " + "[" * 5000 + "]" * 5000 + "\n"


@FUZZ
@given(text=mutated(LENS_TEXTS))
@example(text=DEEP)
@example(text="[lens]\nfocal_length_mm = " + "9" * 400 + "\n")
def test_lens_loader_mutations(tmp_path: Path, text: str) -> None:
    _check(load_lens, tmp_path / "fuzz.toml", text)


@FUZZ
@given(doc=documents)
def test_lens_loader_random_documents(tmp_path: Path, doc: dict[str, Any]) -> None:
    _check(load_lens, tmp_path / "fuzz.toml", dumps(doc))


@FUZZ
@given(text=mutated(SCENE_TEXTS))
@example(text=DEEP)
def test_scene_loader_mutations(tmp_path: Path, text: str) -> None:
    _check(load_scene, tmp_path / "fuzz.toml", text)


@FUZZ
@given(doc=documents)
def test_scene_loader_random_documents(tmp_path: Path, doc: dict[str, Any]) -> None:
    _check(load_scene, tmp_path / "fuzz.toml", dumps(doc))


@FUZZ
@given(text=mutated(BANK_TEXTS))
@example(text=DEEP)
@example(text=BANK_TEXTS[0].replace("f_numbers = [8]", "f_numbers = [" + "9" * 400 + "]"))
def test_bank_spec_loader_mutations(tmp_path: Path, text: str) -> None:
    _check(load_spec, tmp_path / "fuzz.toml", text)


# Bank specs with huge integer literals and absurd values (issue 39): a literal of more
# than 4300 digits in any base (Python's int() refuses a decimal one, but a hexadecimal,
# octal or binary one parses to an int that str() and repr() then refuse: the refusal's
# own message raised ValueError, a traceback), a float at or past its range, a value of
# another type, put where the committed and the tests' specs have a number
HUGE_LITERALS = ["9" * 4301, "-" + "9" * 5000, "+" + "1" * 4400, "1" + "_0" * 4400,
                 "0x" + "f" * 4000, "0xF" + "0" * 5000, "0o" + "7" * 5000,
                 "0b1" + "0" * 15000]
ABSURD_LITERALS = ["1e308", "-1e308", "1.7976931348623157e308", "5e-324", "-0.0", "0",
                   "-1", "inf", "-inf", "nan", "2147483648", "-9223372036854775809",
                   "18446744073709551616", "1e-300", "[]", "[[]]", '"8"', "{}", "true",
                   "[1e308, -1e308]", "[" + ", ".join(["1"] * 5000) + "]"]
NUMBER = re.compile(r"(?<![\w.\"])[-+]?[0-9][0-9_.eE+-]*")


def _bank_texts() -> list[str]:
    """The committed specs, the tests' spec (lens 0001) and its variants with a fixed
    window, a flare and blades, so that every key of a spec holds a number somewhere."""
    base = bank_spec("fuzz")
    return [*BANK_TEXTS, base,
            base.replace("size_mm = [0.06, 0.06]",
                         "size_mm = [0.06, 0.06]\ncenter_mm = [-10.1, -6.7]")
            + '[flare]\nghosts = ["0-2"]\n[aperture]\nshape = "blades"\nblades = 7\n'
              "blade_curvature = 0.5\nrotation_deg = 10\n",
            base.replace("[grid]", "[grid]\nfocus_offsets_mm = [0, 0.1]\n"
                                   "distances_mm = [1000, 5000]")
            + "max_rings = 64\nsamples = 4096\ncheckpoints = 2\nseed = 3\nthreads = 1\n"]


BANK_LITERAL_TEXTS = _bank_texts()


@st.composite
def bank_literals(draw: st.DrawFn) -> str:
    """A spec with one to three of its numbers replaced by a huge or absurd literal."""
    text = draw(st.sampled_from(BANK_LITERAL_TEXTS))
    for _ in range(draw(st.integers(1, 3))):
        spots = list(NUMBER.finditer(text))
        m = spots[draw(st.integers(0, len(spots) - 1))]
        new = draw(st.sampled_from(HUGE_LITERALS) if draw(st.booleans())
                   else st.sampled_from(ABSURD_LITERALS))
        text = text[:m.start()] + new + text[m.end():]
    return text


def _one_line_refusal(loader: Any, path: Path, text: str) -> None:
    """Loads, or is refused as the CLI reports it: one line naming the file (no
    traceback, whatever the literal's size)."""
    path.write_text(text, encoding="utf-8")
    try:
        loader(path)
    except PROJECT_ERRORS as e:
        message = str(e)
        assert "\n" not in message and message.startswith(str(path)), message[:300]
        assert len(message) < 1000, message[:300]
        event(type(e).__name__ + ": " + message.split(": ", 2)[-1][:40])
    else:
        event("loaded")


HEX_F_NUMBER = BANK_LITERAL_TEXTS[-1].replace("f_numbers = [8]", "f_numbers = [0x" + "f" * 4000
                                               + "]")


@FUZZ
@given(text=bank_literals())
@example(text=HEX_F_NUMBER)
@example(text=BANK_LITERAL_TEXTS[-1].replace("pixels = [16, 16]", "pixels = [0o" + "7" * 5000
                                             + ", 16]"))
@example(text=BANK_LITERAL_TEXTS[-1].replace("seed = 3", "seed = 0b1" + "0" * 15000))
def test_bank_spec_huge_and_absurd_literals(tmp_path: Path, text: str) -> None:
    _one_line_refusal(load_spec, tmp_path / "fuzz.toml", text)


@pytest.mark.parametrize("kind", ["lens", "scene"])
@pytest.mark.parametrize("literal", ["0x" + "f" * 4000, "0o" + "7" * 5000,
                                     "0b1" + "0" * 15000, "-" + "9" * 4301])
def test_huge_literal_in_lens_and_scene_is_one_line(tmp_path: Path, kind: str,
                                                     literal: str) -> None:
    """The same literals in a lens and a scene: refused in one line naming the file (a
    hexadecimal or octal one raised ValueError from the refusal's own message)."""
    texts, loader = (LENS_TEXTS, load_lens) if kind == "lens" else (SCENE_TEXTS, load_scene)
    text = texts[0]
    m = NUMBER.search(text[text.index("="):])
    assert m is not None
    at = text.index("=") + m.start()
    path = tmp_path / "fuzz.toml"
    path.write_text(text[:at] + literal + text[at + len(m.group()):], encoding="utf-8")
    with pytest.raises(PROJECT_ERRORS) as e:
        loader(path)
    assert "\n" not in str(e.value) and str(e.value).startswith(str(path))
    assert "digits" in str(e.value)


@FUZZ
@given(doc=documents)
def test_bank_spec_loader_random_documents(tmp_path: Path, doc: dict[str, Any]) -> None:
    _check(load_spec, tmp_path / "fuzz.toml", dumps(doc))


@pytest.mark.parametrize("path", LENS_FILES + SCENE_FILES + BANK_FILES, ids=lambda p: p.name)
def test_committed_files_load(path: Path) -> None:
    # The unmutated seeds load: otherwise every mutation would fail for the same reason.
    {"scenes": load_scene, "banks": load_spec}.get(path.parent.name, load_lens)(path)


# Issue 25: booleans are not numbers in any TOML input (float(true) is 1.0: a scene's
# `distance_mm = true` was read as 1 mm). Every numeric value of a lens and of each
# scene, set to true or false, is refused with the file, the key and the value.

def _numeric_lines(text: str) -> list[int]:
    import re

    return [i for i, line in enumerate(text.splitlines())
            if re.fullmatch(r"\s*[A-Za-z_]+\s*=\s*-?[0-9][0-9.eE+-]*\s*(#.*)?", line)]


BOOL_CASES = [("lens", 0, i) for i in _numeric_lines(LENS_TEXTS[0])] + [
    ("scene", k, i) for k, text in enumerate(SCENE_TEXTS) for i in _numeric_lines(text)]


@pytest.mark.parametrize("kind,k,line", BOOL_CASES)
@pytest.mark.parametrize("word", ["true", "false"])
def test_booleans_are_not_numbers(tmp_path, kind, k, line, word):
    text = (LENS_TEXTS[0] if kind == "lens" else SCENE_TEXTS[k]).splitlines()
    key = text[line].split("=")[0].strip()
    text[line] = f"{key} = {word}"
    path = tmp_path / "x.toml"
    path.write_text("\n".join(text) + "\n", encoding="utf-8")
    with pytest.raises(PROJECT_ERRORS) as e:
        (load_lens if kind == "lens" else load_scene)(path)
    msg = str(e.value)
    assert msg.startswith(str(path)) and key in msg and f"found {word}" in msg, msg
