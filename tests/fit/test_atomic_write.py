"""lensfit's one checked atomic write (lensfit.atomic, issue 25): the rules of lensrt's
(runtime/src/io/atomic_file.c), and the commands that write files through it."""

from __future__ import annotations

import os
import socket
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from lensfit.cli import main
from lensfit.common import atomic
from lensfit.common.atomic import OutputError, check_target, write_atomic, write_files


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_replaces_a_regular_file_and_keeps_its_mode(tmp_path):
    target = tmp_path / "a.txt"
    target.write_text("old\n")
    target.chmod(0o640)
    write_atomic(target, "new\n")
    assert target.read_text() == "new\n"
    assert stat.S_IMODE(target.stat().st_mode) == 0o640
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_a_new_file_gets_the_umask_mode(tmp_path):
    old = os.umask(0o022)
    try:
        write_atomic(tmp_path / "b.bin", b"\x00\x01")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "b.bin").stat().st_mode) == 0o644
    assert (tmp_path / "b.bin").read_bytes() == b"\x00\x01"


def _special(tmp_path: Path, kind: str) -> Path:
    p = tmp_path / f"target-{kind}"
    if kind == "fifo":
        os.mkfifo(p)
    elif kind == "symlink":
        (tmp_path / "real").write_text("keep\n")
        p.symlink_to(tmp_path / "real")
    elif kind == "dangling":
        p.symlink_to(tmp_path / "nowhere")
    elif kind == "socket":
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(p))
        s.close()
    elif kind == "folder":
        p.mkdir()
    return p


@pytest.mark.parametrize("kind,words", [
    ("fifo", "is a FIFO; lensfit writes regular files only"),
    ("symlink", "is a symbolic link; lensfit replaces files by renaming and does not "
                "follow links: give the link's target path"),
    ("dangling", "is a symbolic link"),
    ("socket", "is not a regular file; lensfit writes regular files only"),
    ("folder", "is a directory, not a file"),
])
def test_special_targets_are_refused_and_kept(tmp_path, kind, words):
    p = _special(tmp_path, kind)
    before = os.lstat(p)
    with pytest.raises(OutputError) as e:
        write_atomic(p, "x")
    assert str(e.value) == f"{p}: {words}" or words in str(e.value)
    after = os.lstat(p)
    assert (after.st_mode, after.st_ino) == (before.st_mode, before.st_ino)
    assert not [q for q in tmp_path.iterdir() if ".tmp-" in q.name]


def test_a_device_node_is_refused():
    with pytest.raises(OutputError, match="^/dev/null: is a device node; lensfit writes "
                                          "regular files only$"):
        write_atomic("/dev/null", "x")
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


def test_stale_temporaries_of_dead_processes_go(tmp_path):
    target = tmp_path / "c.txt"
    dead = tmp_path / f"c.txt.tmp-{_dead_pid()}-123-0"
    live = tmp_path / f"c.txt.tmp-{os.getppid()}-123-0"
    other = tmp_path / "c.txt.tmp-notours"
    for p in (dead, live, other):
        p.write_text("partial")
    write_atomic(target, "done\n")
    assert not dead.exists() and live.exists() and other.exists()
    assert target.read_text() == "done\n"


def test_a_failed_write_leaves_nothing(tmp_path, monkeypatch):
    def fail(*_a):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(atomic.os, "replace", fail)
    out = tmp_path / "new" / "deeper"
    with pytest.raises(OutputError, match="cannot write: No space left on device"):
        write_files(out, {"a.toml": "x"})
    assert list(tmp_path.iterdir()) == []


def test_check_target_tries_the_folder():
    with pytest.raises(OutputError, match=r"^-o /proc/x\.png: cannot write: "):
        check_target("/proc/x.png", "-o")


# The commands (refused before any work, the target untouched, exit 2, one line)

def _one_line(capsys, argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("cmd,suffix", [("draw", ".png"), ("export", ".zmx")])
@pytest.mark.parametrize("kind,words", [
    ("fifo", "is a FIFO; lensfit writes regular files only"),
    ("symlink", "is a symbolic link; lensfit replaces files by renaming and does not "
                "follow links: give the link's target path"),
    ("socket", "is not a regular file; lensfit writes regular files only"),
])
def test_draw_and_export_keep_special_files(capsys, tmp_path, cmd, suffix, kind, words):
    p = _special(tmp_path, kind)
    target = p.with_name(p.name + suffix)
    p.rename(target)
    before = os.lstat(target)
    assert _one_line(capsys, [cmd, "0001", "-o", str(target)]) == \
        f"lensfit: error: -o {target}: {words}"
    after = os.lstat(target)
    assert (after.st_mode, after.st_ino) == (before.st_mode, before.st_ino)


def test_draw_and_export_refuse_a_device(capsys):
    for cmd in ("draw", "export"):
        # /dev/null has no .png suffix: the device is refused before the suffix check
        line = _one_line(capsys, [cmd, "0001", "-o", "/dev/null"])
        assert line == "lensfit: error: -o /dev/null: is a device node; lensfit writes " \
                       "regular files only"


def test_import_keeps_a_fifo(capsys, tmp_path):
    src = Path(__file__).resolve().parent / "fixtures" / "optiland" / "cooke_triplet.json"
    fifo = tmp_path / "x.toml"
    os.mkfifo(fifo)
    assert _one_line(capsys, ["import", str(src), "-o", str(fifo)]) == \
        f"lensfit: error: -o {fifo}: is a FIFO; lensfit writes regular files only"
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_export_keeps_the_mode_of_the_file_it_replaces(capsys, tmp_path):
    out = tmp_path / "l.zmx"
    out.write_text("old\n")
    out.chmod(0o600)
    assert main(["export", "0001", "-o", str(out)]) == 0
    assert stat.S_IMODE(out.stat().st_mode) == 0o600
    assert out.read_text().startswith(("VERS", "MODE", "\ufeff", "NAME")) or "SURF" in \
        out.read_text()


@pytest.mark.parametrize("cmd", [["draw", "0001", "-o", "/proc/x.png"],
                                 ["export", "0001", "-o", "/proc/x.zmx"],
                                 ["import", "FIXTURE", "-o", "/proc/x.toml"],
                                 ["scene", "0001", "SCENE", "-o", "/proc/x"]])
def test_unwritable_outputs(capsys, tmp_path, cmd):
    fixtures = Path(__file__).resolve().parent / "fixtures"
    scene = tmp_path / "s.toml"
    scene.write_text('name = "t"\nwavelengths_nm = [550.0]\n[[light]]\nfield_x_deg = 0.0\n'
                     'field_y_deg = 2.0\n')
    argv = [str(fixtures / "optiland" / "cooke_triplet.json") if a == "FIXTURE"
            else str(scene) if a == "SCENE" else a for a in cmd]
    line = _one_line(capsys, argv)
    want = ("lensfit: error: -o /proc/x: cannot write in /proc: No such file or directory"
            if cmd[0] == "scene" else
            f"lensfit: error: -o {cmd[-1]}: cannot write: No such file or directory")
    assert line == want


@pytest.mark.parametrize("name", ["../evil", "a/b", "..", ".", "", "a\\b", "a\x00b",
                                  "line\nbreak"])
def test_write_files_takes_plain_names_only(tmp_path, name):
    """Names come from records too (ghost tasks): one that is not a plain name inside
    the folder is refused before anything is written (issue 39)."""
    with pytest.raises(OutputError, match="not a plain file name"):
        write_files(tmp_path / "out", {"fine.txt": "a", name: "b"})
    assert list(tmp_path.iterdir()) == []
