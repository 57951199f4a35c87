"""lensfit.errors.refuse_repeated_tables: the same ghost table named twice (the same
path, a symbolic link, another relative path; the same device and inode) is refused
naming both spellings, since its flare would be added twice; distinct files (even equal
copies, which the callers tell apart by their ghost) and missing ones pass."""

from __future__ import annotations

import os

import pytest

from lensfit.common.errors import InputError, refuse_repeated_tables


def test_same_file_under_any_spelling_refused(tmp_path, monkeypatch):
    a = tmp_path / "ghosts" / "ghost_1_2.table"
    a.parent.mkdir()
    a.write_text("table")
    link = tmp_path / "link.table"
    link.symlink_to(a)
    monkeypatch.chdir(tmp_path)
    relative = os.path.join("ghosts", "..", "ghosts", "ghost_1_2.table")
    for second in (a, link, relative):
        with pytest.raises(InputError) as e:
            refuse_repeated_tables([a, tmp_path / "other.table", second])
        assert str(e.value).startswith(f"ghost table {a} is given twice (as {a} and {second}, "
                                       "the same file)")


def test_distinct_or_missing_files_pass(tmp_path):
    a, b = tmp_path / "a.table", tmp_path / "b.table"
    a.write_text("table")
    b.write_text("table")  # an equal copy is another file
    refuse_repeated_tables([a, b, tmp_path / "missing.table", tmp_path / "missing.table"])
