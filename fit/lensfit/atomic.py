"""The one checked atomic write of lensfit, following lensrt's rules
(runtime/src/io/atomic_file.c) so that both tools treat a target path alike:

* the target must be a regular file or absent: a symbolic link, a folder, a device node,
  a FIFO or a socket is refused (a rename would replace it with a regular file);
* the bytes go to a unique temporary ``<target>.tmp-<pid>-<clock>-<attempt>`` in the
  target's folder (created with O_EXCL), are flushed and fsynced, and the temporary is
  renamed over the target: a reader sees the old file or the whole new one;
* the replacement keeps the permission bits of the file it replaces (a new file gets
  0666 less the umask, as lensrt's);
* temporaries of that naming whose process no longer runs (killed during a write) are
  removed when the same target is written next;
* a failed write leaves nothing: no temporary, no folder it created.

Every failure is an :class:`OutputError` (an InputError: one line, exit 2) naming the
path. ``lensfit.generate.write_folder`` should call :func:`write_files`."""

from __future__ import annotations

import errno
import os
import re
import stat
import time
from collections.abc import Mapping
from pathlib import Path

from lensfit.errors import InputError


class OutputError(InputError):
    """An output that cannot be written, naming the path and why."""


def target_refusal(path: str | os.PathLike[str]) -> str | None:
    """Why ``path`` cannot be replaced by a write (lensrt_target_refusal's reasons), or
    None when it is absent or a regular file."""
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return None  # absent, or not inspectable: the open says why
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISLNK(mode):
        return ("is a symbolic link; lensfit replaces files by renaming and does not "
                "follow links: give the link's target path")
    if stat.S_ISDIR(mode):
        return "is a directory, not a file"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "is a device node; lensfit writes regular files only"
    if stat.S_ISFIFO(mode):
        return "is a FIFO; lensfit writes regular files only"
    return "is not a regular file; lensfit writes regular files only"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # exists, owned by someone else
    return True


def remove_stale(path: Path) -> list[Path]:
    """Remove ``<path>.tmp-<pid>-<digits>-<digits>`` of processes that no longer run;
    the files removed."""
    pattern = re.compile(re.escape(path.name) + r"\.tmp-(\d+)-(\d+)-(\d+)")
    removed = []
    try:
        names = os.listdir(path.parent)
    except OSError:
        return removed
    for name in names:
        m = pattern.fullmatch(name)
        if not m or int(m.group(1)) in (0, os.getpid()) or _pid_alive(int(m.group(1))):
            continue
        try:
            os.unlink(path.parent / name)
            removed.append(path.parent / name)
        except OSError:
            pass
    return removed


def _why(e: OSError) -> str:
    return e.strerror or str(e)


def check_target(path: str | os.PathLike[str], option: str = "") -> Path:
    """Refuse, before any work, an output file lensfit could not write: a special file or
    link (see :func:`target_refusal`), or a folder where no file can be created (tried
    with a temporary of our naming, removed at once). Raises OutputError."""
    p = Path(path)
    what = f"{option} {p}" if option else str(p)
    refusal = target_refusal(p)
    if refusal:
        raise OutputError(f"{what}: {refusal}")
    parent = p.absolute().parent
    if parent.is_dir():
        fd, tmp = _open_temporary(p, what, keep_mode=False)
        os.close(fd)
        os.unlink(tmp)
    return p


def _open_temporary(path: Path, what: str, *, keep_mode: bool = True,
                    mode: int | None = None) -> tuple[int, Path]:
    if mode is None and keep_mode:
        try:
            st = os.stat(path)
            if stat.S_ISREG(st.st_mode):
                mode = st.st_mode & 0o7777
        except OSError:
            pass
    remove_stale(path)
    clock = time.time_ns() % 1_000_000_000
    for attempt in range(100):
        tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}-{clock}-{attempt}")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        except OSError as e:
            raise OutputError(f"{what}: cannot write: {_why(e)}") from None
        if mode is not None:
            try:
                os.fchmod(fd, mode)
            except OSError as e:
                os.close(fd)
                os.unlink(tmp)
                raise OutputError(f"{what}: cannot keep the file's mode: {_why(e)}") from None
        return fd, tmp
    raise OutputError(f"{what}: cannot write: {os.strerror(errno.EEXIST)}")


def _fsync_folder(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_atomic(path: str | os.PathLike[str], data: str | bytes, *, option: str = "",
                 mode: int | None = None) -> Path:
    """Write ``data`` (text as UTF-8 with '\\n' line ends, or bytes) to ``path`` by the
    rules of the module doc. The folder must exist (see :func:`write_files`). ``mode``:
    the file's permission bits whatever the umask and a replaced file's (generated code
    is for everyone: 0o644); None keeps a replaced file's, else 0o666 less the umask."""
    p = Path(path)
    what = f"{option} {p}" if option else str(p)
    refusal = target_refusal(p)
    if refusal:
        raise OutputError(f"{what}: {refusal}")
    raw = data.encode("utf-8") if isinstance(data, str) else data
    fd, tmp = _open_temporary(p, what, mode=mode)
    try:
        try:
            view = memoryview(raw)
            while view:
                n = os.write(fd, view)
                view = view[n:]
            os.fsync(fd)
        finally:
            os.close(fd)
        # Checked again just before the rename: a link made meanwhile is not replaced
        refusal = target_refusal(p)
        if refusal:
            raise OutputError(f"{what}: {refusal}")
        os.replace(tmp, p)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"{what}: cannot write: {_why(e)}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_folder(p.absolute().parent)
    return p


def make_folder(folder: Path, what: str) -> list[Path]:
    """Create ``folder`` and its missing parents; the folders created, outermost first
    (for :func:`remove_folders` when the write fails)."""
    missing = []
    p = folder.absolute()
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    if not p.is_dir():
        raise OutputError(f"{what}: {p} is not a folder")
    created = []
    for q in reversed(missing):
        try:
            q.mkdir()
        except FileExistsError:
            continue
        except OSError as e:
            remove_folders(created)
            raise OutputError(f"{what}: cannot create the folder {q}: {_why(e)}") from None
        created.append(q)
    return created


def remove_folders(created: list[Path]) -> None:
    """Remove the folders :func:`make_folder` created (innermost first) where empty."""
    for q in reversed(created):
        try:
            q.rmdir()
        except OSError:
            break


def write_files(folder: str | os.PathLike[str], files: Mapping[str, str | bytes], *,
                option: str = "", mode: int | None = None) -> list[Path]:
    """Write each of ``files`` (name -> text) into ``folder`` with :func:`write_atomic`,
    creating the folder; every target is checked before the first write, and when the
    first write fails the folders created are removed again."""
    out = Path(folder)
    what = f"{option} {out}" if option else str(out)
    for name in files:
        refusal = target_refusal(out / name)
        if refusal:
            raise OutputError(f"{out / name}: {refusal}")
    created = make_folder(out, what)
    written = []
    try:
        for name, data in sorted(files.items()):
            written.append(write_atomic(out / name, data, mode=mode))
    except BaseException:
        if not written:
            remove_folders(created)
        raise
    return written
