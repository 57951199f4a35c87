"""`lensfit ghosts LENS... --fit` on Dask (issue 23, deliverable 5): a kept ghost fitted as
a task on a LocalCluster of 2 workers; a rerun fits nothing (the folder holds the ghost
for the same digest); with two lenses, a failed ghost leaves its lens unwritten and the
other lens written, and a record of a finished ghost (as a task writes it) is used by the
next run instead of fitting again.

Two copies of an uncoated N-BK7 singlet (one ghost each) sharing one quick direct fit; one
ghost fit (~35 s on an idle core): the second lens's ghost comes from a record made of the
first's, so the test fits once.
"""

from __future__ import annotations

import json
import re
import shutil
import zlib

import pytest
from test_ghosts_cli import SINGLET  # tests/fit/ghosts is on sys.path (rootdir)

from lensfit.cli import main
from lensfit.codegen.checked_json import checked_json_text
from lensfit.ghosts import tables as ghost_tables
from lensfit.ghosts.tasks import TASKS_FOLDER

# The singlet of test_ghosts_cli under two ids (its folder's name is the id)
SINGLETS = {name: SINGLET.replace('id = "singlet"', f'id = "{name}"')
            for name in ("singleta", "singletb")}


def folder_bytes(folder):
    return {p.name: zlib.crc32(p.read_bytes()) for p in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """The singlets' direct fit, then lens a's ghost fitted on a LocalCluster."""
    tmp = tmp_path_factory.mktemp("tasks")
    gen = tmp / "gen"
    lenses = []
    for name, text in SINGLETS.items():
        path = tmp / f"{name}.toml"
        path.write_text(text, encoding="utf-8")
        lenses.append(str(path))
    # One quick direct fit serves both: the two lenses are the same glass and surfaces
    assert main(["fit", lenses[0], "--quick", "--f-number", "8", "--field", "5",
                 "--generated", str(gen), "--report", str(tmp / "r"), "--no-timing"]) == 0
    shutil.copytree(gen / "singleta", gen / "singletb")
    args = ["ghosts", "--f-number", "8", "--rays", "2000", "--count", "1", "--fit",
            "--generated", str(gen)]
    assert main([*args, lenses[0], "--workers", "2"]) == 0
    return gen, args, lenses


def test_ghost_fitted_on_a_local_cluster(fitted) -> None:
    gen, _, _ = fitted
    out = gen / "singleta" / "ghosts"
    assert sorted(p.name for p in out.iterdir()) == ["ghost_1_2.table", "ghosts.json"]
    (entry,) = json.loads((out / "ghosts.json").read_text())["ghosts"]
    # The fit met its target against exactly traced ghost rays (as the one-process fit
    # does: test_ghosts_cli), and records what it was fitted for
    assert entry["label"] == "0-1" and entry["psf_vs_exact"] <= 0.03
    assert len(entry["task_digest"]) == 16
    # The lens file by its name, not by the (absolute) path it was given as
    assert entry["estimate"]["file"] == "singleta.toml"
    assert not (gen / "singleta" / TASKS_FOLDER).exists()  # records removed once written


def test_rerun_fits_nothing(fitted, monkeypatch, capsys) -> None:
    gen, args, lenses = fitted
    before = folder_bytes(gen / "singleta" / "ghosts")

    def refuse(*a, **k):
        raise AssertionError("a ghost was fitted again")

    monkeypatch.setattr(ghost_tables, "fit_with_trust", refuse)
    assert main([*args, lenses[0], "--workers", "0"]) == 0
    assert "as fitted before" in capsys.readouterr().out
    assert folder_bytes(gen / "singleta" / "ghosts") == before


def test_failed_ghost_keeps_its_lens_for_the_next_run(fitted, monkeypatch, capsys) -> None:
    gen, args, lenses = fitted
    out_a, out_b = gen / "singleta" / "ghosts", gen / "singletb" / "ghosts"
    before_a = folder_bytes(out_a)

    def fail(*a, **k):
        raise RuntimeError("fit failed on purpose")

    # Both lenses: a's ghost is in its folder already, b's fit fails
    monkeypatch.setattr(ghost_tables, "fit_with_trust", fail)
    assert main([*args, *lenses, "--workers", "0"]) == 1
    err = capsys.readouterr().err
    assert "1 of 1 ghost fits failed" in err and "fit failed on purpose" in err
    assert "run the same command again" in err
    assert folder_bytes(out_a) == before_a  # the other lens: written as it was
    assert not (out_b / "ghosts.json").exists()

    # A finished ghost's record (as a task writes it: here a's results under b's digest,
    # the lenses being optically the same) is used instead of a fit
    digest = re.search(r"ghost-singletb-ghost_1_2-([0-9a-f]{16})", err).group(1)
    (entry,) = json.loads((out_a / "ghosts.json").read_text())["ghosts"]
    entry["task_digest"] = digest
    table = (out_a / "ghost_1_2.table").read_text()
    record = gen / "singletb" / TASKS_FOLDER / f"ghost_1_2-{digest}.json"
    record.parent.mkdir(exist_ok=True)
    record.write_text(checked_json_text({
        "digest": digest, "entry": entry, "line": "ghost 0-1: from its record",
        "files": {"ghost_1_2.table": table}}))
    assert main([*args, *lenses, "--workers", "0"]) == 0
    assert "ghost 0-1: from its record" in capsys.readouterr().out
    assert (out_b / "ghost_1_2.table").read_text() == table
    (written,) = json.loads((out_b / "ghosts.json").read_text())["ghosts"]
    assert written["task_digest"] == digest
    assert not record.parent.exists()
    assert folder_bytes(out_a) == before_a


def _craft(entry, table):
    """What a task writes, then one part changed by ``change`` (each keeps a valid
    checksum: the record is rewritten by checked_json_text)."""
    return {"entry": entry, "line": "ghost 0-1: from its record",
            "files": {"ghost_1_2.table": table}}


CRAFTED = {
    # a table named to be written outside the ghosts folder
    "path": lambda r: r.update(files={"../../evil_ghost_1_2.table":
                                      r["files"]["ghost_1_2.table"]}),
    "other name": lambda r: r["files"].update({"evil.sh": "echo"}),
    "entry text": lambda r: r.update(entry="x"),
    "line number": lambda r: r.update(line=5),
    "junk table": lambda r: r["files"].update({"ghost_1_2.table": "junk"}),
    "other ghost's label": lambda r: r["entry"].update(label="4-8-9"),
    "entry crc": lambda r: r["entry"].update(table_crc32="00000000"),
}


@pytest.mark.parametrize("kind", sorted(CRAFTED))
def test_a_crafted_record_is_refused_before_anything_is_written(fitted, tmp_path,
                                                                monkeypatch, capsys, kind):
    """A record with a valid checksum but not what a task writes for its ghost is
    refused with a note and the ghost fitted again (here the fit fails on purpose, so
    nothing is written); no file lands outside the lens's ghosts folder (issue 39)."""
    gen0, args, lenses = fitted
    gen = tmp_path / "gen"
    shutil.copytree(gen0, gen)
    shutil.rmtree(gen / "singletb" / "ghosts", ignore_errors=True)
    args = [a if a != str(gen0) else str(gen) for a in args]

    def fail(*a, **k):
        raise RuntimeError("fit failed on purpose")

    monkeypatch.setattr(ghost_tables, "fit_with_trust", fail)
    assert main([*args, lenses[1], "--workers", "0"]) == 1
    digest = re.search(r"ghost-singletb-ghost_1_2-([0-9a-f]{16})",
                       capsys.readouterr().err).group(1)
    out_a = gen / "singleta" / "ghosts"
    (entry,) = json.loads((out_a / "ghosts.json").read_text())["ghosts"]
    entry = {k: v for k, v in entry.items() if k != "checksum"}
    entry["task_digest"] = digest
    record = _craft(entry, (out_a / "ghost_1_2.table").read_text())
    CRAFTED[kind](record)
    path = gen / "singletb" / TASKS_FOLDER / f"ghost_1_2-{digest}.json"
    path.parent.mkdir(exist_ok=True)
    path.write_text(checked_json_text({"digest": digest, **record}))
    before = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")
                    if p != path)
    assert main([*args, lenses[1], "--workers", "0"]) == 1
    err = capsys.readouterr().err
    assert f"{path}: record refused (" in err and "fit failed on purpose" in err, err
    assert not (gen / "singletb" / "ghosts").exists()
    after = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*") if p != path)
    assert after == before


@pytest.mark.parametrize("entry", [{"label": "0-2", "first": "../../x", "second": 2},
                                   {"label": "0-2", "first": 2, "second": 0},
                                   {"label": "../0-2", "first": 0, "second": 2},
                                   {"label": "0-2", "first": 0, "second": 2,
                                    "table_crc32": 5},
                                   "x"])
def test_ghosts_json_entries_are_typed_for_every_reader(tmp_path, entry):
    """ghosts.json behind a valid checksum: an entry whose surfaces are not integers
    (they name the table file: ghost_<first>_<second>.table) or whose keys are of the
    wrong type is refused by its one reader, for the scenes and banks that read it too,
    naming the file and the key (issue 39)."""
    from lensfit.common.errors import InputError
    from lensfit.ghosts.scene import fitted_ghosts
    from lensfit.ghosts.tasks import read_ghost_index

    index = tmp_path / "ghosts" / "ghosts.json"
    index.parent.mkdir()
    index.write_text(checked_json_text({"format": "lensfit-ghosts 1", "ghosts": [entry]}))
    for read in (lambda: read_ghost_index(index), lambda: fitted_ghosts(tmp_path, "x")):
        with pytest.raises(InputError, match=r"ghosts\.json: key ghosts\[0\]"):
            read()
