"""Property-based fuzzing of the checksummed records lensfit reads back (issue 39): fit
checkpoints (``lensfit.fit_cache``: a system's fit, the PSF check) and ghost-task records
(``lensfit.ghosts.tasks``).

A checksum only says a record is as some writer left it, so the strategies here craft
records with a *valid* checksum: a valid record's JSON tree with one node replaced (a huge
integer literal of over 4300 digits, a negative, a string, null, a bool, a nested list or
object, a key dropped or added), written back by ``checked_json_text``.

Properties: reading never raises (a refused record is a one-line note and the step is
done again); a record that is accepted gives back exactly what was saved wherever the
results depend on it (the polynomials, the PSF check's cells, the files to write and
their names); nothing is written outside the ghosts folder.

Budget as test_fuzz_toml: short and deterministic by default, LENSFIT_FUZZ_EXAMPLES for
``make fuzz``.
"""

from __future__ import annotations

import contextlib
import copy
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from lensfit.codegen import write_table
from lensfit.codegen.checked_json import checked_json_text
from lensfit.codegen.table import read_table
from lensfit.fitting import FitOptions, error_metric, fit_lens
from lensfit.ghosts import tasks
from lensfit.pipeline.cache import FitCache, fit_key
from lensfit.poly.polynomial import Polynomial, System
from lensfit.prescription import load_lens
from lensfit.sample import default_domain

EXAMPLES = int(os.environ.get("LENSFIT_FUZZ_EXAMPLES", "0")) or None
# No shrinking: a record is large, and the failing path is printed in full anyway
FUZZ = settings(max_examples=EXAMPLES or 100, derandomize=True, database=None,
                deadline=None, phases=[Phase.explicit, Phase.generate],
                suppress_health_check=[HealthCheck.too_slow,
                                       HealthCheck.function_scoped_fixture,
                                       HealthCheck.data_too_large])
# test_fit_resume's small budgets: a fit of both systems in about a second
TINY = FitOptions(stop_pilot=False,
                  groups=150, aperture_points=64, aperture_degree=6, field_degrees=(2, 4),
                  test_groups=40, test_per_group=8)

# Values put in place of a node: each a kind a reader must refuse or take unharmed
REPLACEMENTS = st.one_of(
    st.just(10**4400), st.just(-(10**4400)),  # over Python's int-to-text limit of 4300
    st.integers(-2**70, 2**70), st.floats(allow_nan=False, allow_infinity=False),
    st.text(max_size=20), st.none(), st.booleans(),
    st.lists(st.integers(-3, 3), max_size=3),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=2),
    st.sampled_from(["../../evil", "inf", "nan", "0x1p3", "\x00", "4-8-9"]),
)


def _paths(node: Any, at: tuple = ()) -> list[tuple]:
    """Every path into a JSON tree (the root excluded), lists sampled down to a few
    entries so long coefficient arrays do not drown the rest."""
    out = [at] if at else []
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, at + (k,))
    elif isinstance(node, list):
        picks = range(len(node)) if len(node) <= 4 else (0, 1, len(node) // 2, len(node) - 1)
        for i in picks:
            out += _paths(node[i], at + (i,))
    return out


@st.composite
def mutations(draw, doc: dict[str, Any]) -> tuple[dict[str, Any], tuple]:
    """``doc`` with one node replaced, dropped, or given an extra key; (doc, path)."""
    doc = copy.deepcopy(doc)
    path = draw(st.sampled_from(_paths(doc)))
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    how = draw(st.sampled_from(["replace", "replace", "drop", "add"]))
    if how == "drop" and isinstance(parent, dict):
        del parent[path[-1]]
    elif how == "add" and isinstance(parent, dict):
        parent[draw(st.text(max_size=8))] = draw(REPLACEMENTS)
    else:
        parent[path[-1]] = draw(REPLACEMENTS)
    return doc, path


def _write(path: Path, doc: dict[str, Any]) -> bool:
    """Write ``doc`` with a valid checksum; False where JSON cannot hold it."""
    try:
        path.write_text(checked_json_text(doc))
    except ValueError:
        return False
    return True


def _doc(path: Path) -> dict[str, Any]:
    return {k: v for k, v in json.loads(path.read_text()).items() if k != "checksum"}


@contextlib.contextmanager
def crafted(path: Path, data):
    """The record at ``path`` mutated (:func:`mutations`) and written with a valid
    checksum for the body of the ``with``, which gets the path into the tree that was
    changed (None where JSON cannot hold the change: nothing to test); the record is
    put back afterwards."""
    original = _doc(path)
    doc, where = data.draw(mutations(original))
    try:
        yield where if _write(path, doc) else None
    finally:
        path.write_text(checked_json_text(original))


# ---- fit checkpoints -------------------------------------------------------------------


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A small fit of lens 0001 at f/8 and its checkpoints (P_o, and a PSF check)."""
    lens = load_lens("0001")
    domain = default_domain(lens, 8.0)
    fits = fit_lens(lens, domain, TINY)
    root = tmp_path_factory.mktemp("cache")
    cache = FitCache(fit_key(lens, domain, TINY), "t", root)
    cache.save_system(fits[0])
    cell = {"stop": "widest", "f_number": 8.0, "stop_radius_mm": 6.0, "field": "axis",
            "field_deg": [0.0, 0.0], "distance_mm": "inf", "wavelength_nm": 550.0,
            "focus_offset_mm": 0.0, "window_um": 40.0, "pixels": 64, "points": 512,
            "relative_l2": 0.004}
    table = {"cells": [cell], "worst": cell, "seconds": 1.0}
    cache.save_psf(table, [f.system for f in fits])
    return cache, fits, table


@FUZZ
@given(data=st.data())
def test_a_crafted_system_checkpoint_is_refused_or_gives_the_same_polynomials(saved, data):
    cache, fits, _ = saved
    with crafted(cache.folder / "P_o.json", data) as where:
        if where is None:
            return
        notes: list[str] = []
        fit = FitCache(cache.key, "t", cache.folder.parent, note=notes.append
                       ).load_system("P_o", fits[0].system.inputs)
        if fit is None:
            assert len(notes) == 1, notes
        elif where[0] == "system":  # taken: then its polynomials are the ones saved ...
            if write_table([fit.system]) != write_table([fits[0].system]):
                _indistinguishable(fit.system, fits[0], where)


def _indistinguishable(system, saved, where) -> None:
    """... or differ from them on the held-out rays by far less than the fit's error
    (a change to a term of coefficient 1e-12, say): the held-out check allows 1e-6 of
    the error's square (fit_cache._RECHECK_RELATIVE), so a change orthogonal to the
    error may be up to ~1.4e-3 of it; 2e-3 of error + target bounds that."""
    te = saved.test.subset(saved.test.passes)
    new, old = system.evaluate(te.inputs), saved.system.evaluate(te.inputs)
    for j, o in enumerate(saved.outputs):
        d = error_metric(o.name, new[:, j], old[:, j], te.group)
        assert float(np.sqrt(np.mean(d * d))) <= 2e-3 * (o.rms + o.target), where


@FUZZ
@given(data=st.data())
def test_a_crafted_psf_checkpoint_is_refused_or_gives_the_same_cells(saved, data):
    cache, fits, table = saved
    with crafted(cache.folder / "psf.json", data) as where:
        if where is None:
            return
        got = FitCache(cache.key, "t", cache.folder.parent, note=lambda m: None
                       ).load_psf([f.system for f in fits])
        if got is not None and where[0] == "table" and where[-1] != "seconds":
            assert got["worst"] == table["worst"], where


# ---- ghost-task records ----------------------------------------------------------------


class _Ghost:
    first, second, name = 1, 2, "0-1"


GHOST_TABLE = Path(__file__).resolve().parents[2] / (
    "generated/0001-angenieux-double-gauss/ghosts/ghost_0_2.table")


def _small_ghost_table() -> str:
    """Lens 0001's committed table of ghost 0-2 cut to 3 terms per output (a table
    lensrt reads, 200 times smaller: the record is parsed once per example)."""
    t = read_table(GHOST_TABLE.read_text())
    small = [System(s.name, s.inputs, [Polynomial(p.output, p.unit, p.exponents[:3],
                                                  p.coefficients[:3]) for p in s.outputs],
                    s.info) for s in t]
    return write_table(small, lens=t.lens, trust=t.trust, ghost=t.ghost)


@pytest.fixture(scope="module")
def record_doc():
    """A ghost-task record as fit_ghost_task writes it, for lens 0001's ghost 0-2."""
    text = _small_ghost_table()
    g = _Ghost()
    g.first, g.second, g.name = 0, 2, "0-2"
    entry = {"label": "0-2", "first": 0, "second": 2, "within_target": True,
             "miss_reason": None, "psf_vs_exact": 0.004, "task_digest": "0123456789abcdef",
             "table_crc32": f"{__import__('zlib').crc32(text.encode()) & 0xFFFFFFFF:08x}"}
    return g, {"digest": "0123456789abcdef", "line": "ghost 0-2: fitted",
               "entry": entry, "files": {"ghost_0_2.table": text}}


def test_the_uncrafted_record_is_taken(tmp_path, record_doc):
    g, doc = record_doc
    path = tmp_path / "r.json"
    path.write_text(checked_json_text(doc))
    got = tasks._record(path, doc["digest"], g, False, False, "lens0001_")
    assert got is not None and got["files"] == doc["files"]


@FUZZ
@given(data=st.data())
def test_a_crafted_ghost_record_is_refused_or_names_only_the_ghosts_files(tmp_path,
                                                                         record_doc, data):
    g, original = record_doc
    doc, _ = data.draw(mutations(original))
    path = tmp_path / "r.json"
    if not _write(path, doc):
        return
    got = tasks._record(path, original["digest"], g, False, False, "lens0001_")
    if got is not None:  # taken: only this ghost's table, as written, under its name
        assert got["files"] == original["files"]
        assert got["entry"]["label"] == "0-2"
