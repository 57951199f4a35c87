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

A whole folder is replaced at once by :func:`replace_folder` (or the context manager
:func:`replacing_folder`): the new folder is written as a sibling
``<folder>.tmp-<pid>-<clock>-<attempt>``, entries of the old folder that the new one
does not replace are carried over as hard links, and the two are exchanged in one
``renameat2(RENAME_EXCHANGE)`` (Linux; elsewhere two renames with SIGINT/SIGTERM held
back between them); the old tree is then removed. A reader, and a write killed at any
point, sees the old folder or the whole new one. A failure or an interrupt removes the
temporary; one left by a killed process (SIGKILL) is removed when the same folder is
written next.

Every failure is an :class:`OutputError` (an InputError: one line, exit 2) naming the
path. ``lensfit.codegen.generate.write_folder`` should call :func:`write_files`."""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import re
import shutil
import signal
import stat
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

from lensfit.common.errors import InputError


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


def _of_dead_processes(path: Path, pattern: re.Pattern[str], pid: int
                       ) -> list[tuple[str, re.Match[str]]]:
    """Names beside ``path`` that ``pattern`` matches whole and whose process id (its
    group ``pid``) is neither ours nor running: temporaries left by a killed writer."""
    try:
        names = sorted(os.listdir(path.parent))
    except OSError:
        return []
    found = []
    for name in names:
        m = pattern.fullmatch(name)
        if m and int(m.group(pid)) not in (0, os.getpid()) and not _pid_alive(int(m.group(pid))):
            found.append((name, m))
    return found


def remove_stale(path: Path) -> list[Path]:
    """Remove ``<path>.tmp-<pid>-<digits>-<digits>`` of processes that no longer run;
    the files removed."""
    pattern = re.compile(re.escape(path.name) + r"\.tmp-(\d+)-(\d+)-(\d+)")
    removed = []
    for name, _ in _of_dead_processes(path, pattern, 1):
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


def _fsync(path: Path) -> None:
    """fsync a file or a folder, ignoring what cannot be synced."""
    try:
        fd = os.open(path, os.O_RDONLY)
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
    _fsync(p.absolute().parent)
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


def plain_name(name: str) -> bool:
    """``name`` names a file inside its folder: not empty, '.' or '..', and without a
    path separator, a NUL or another control character (names read from records are
    checked with this before anything is written)."""
    return (isinstance(name, str) and name not in ("", ".", "..") and "/" not in name
            and "\\" not in name and all(ord(ch) >= 32 and ch != "\x7f" for ch in name))


def write_files(folder: str | os.PathLike[str], files: Mapping[str, str | bytes], *,
                option: str = "", mode: int | None = None) -> list[Path]:
    """Write each of ``files`` (name -> text) into ``folder`` with :func:`write_atomic`,
    creating the folder; every target is checked before the first write, and when the
    first write fails the folders created are removed again."""
    out = Path(folder)
    what = f"{option} {out}" if option else str(out)
    for name in files:
        if not plain_name(name):
            raise OutputError(f"{out}: {str(name)[:80]!r} is not a plain file name (no "
                              "'/', no '..', no control character): nothing written")
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


# ---- whole folders -------------------------------------------------------------------

_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap the paths ``a`` and ``b`` atomically (renameat2 RENAME_EXCHANGE); False where
    the system or the file system cannot."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                   ctypes.c_uint]
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    e = ctypes.get_errno()
    if e in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(e, os.strerror(e), str(b))


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP held back (delivered at the end) in the main thread."""
    held = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _folder_temp(folder: Path, kind: str, what: str) -> Path:
    clock = time.time_ns() % 1_000_000_000
    for attempt in range(100):
        tmp = folder.with_name(f"{folder.name}.{kind}-{os.getpid()}-{clock}-{attempt}")
        if kind == "old":
            if not os.path.lexists(tmp):
                return tmp
            continue
        try:
            tmp.mkdir()
        except FileExistsError:
            continue
        except OSError as e:
            raise OutputError(f"{what}: cannot write: {_why(e)}") from None
        return tmp
    raise OutputError(f"{what}: cannot write: {os.strerror(errno.EEXIST)}")


def remove_stale_folders(folder: Path) -> list[Path]:
    """Temporaries of :func:`replace_folder` of processes that no longer run: a new
    folder not yet in place (``.tmp-``) is removed; an old one moved aside (``.old-``,
    the two-rename path) is put back where the folder is missing, else removed."""
    folder = Path(folder)
    pattern = re.compile(re.escape(folder.name) + r"\.(tmp|old)-(\d+)-(\d+)-(\d+)")
    removed: list[Path] = []
    for name, m in _of_dead_processes(folder, pattern, 2):
        p = folder.parent / name
        if not p.is_dir() or p.is_symlink():
            continue
        if m.group(1) == "old" and not os.path.lexists(folder):
            with contextlib.suppress(OSError):
                os.rename(p, folder)
                continue
        shutil.rmtree(p, ignore_errors=True)
        removed.append(p)
    return removed


def _carry(src: Path, dst: Path) -> None:
    """``src`` (an entry of the old folder) into the new folder at ``dst``: files as hard
    links (a copy where links are refused), folders recreated, links as links."""
    if src.is_symlink():
        os.symlink(os.readlink(src), dst)
    elif src.is_dir():
        dst.mkdir()
        shutil.copymode(src, dst)
        for entry in sorted(os.listdir(src)):
            _carry(src / entry, dst / entry)
    elif src.is_file():
        try:
            os.link(src, dst, follow_symlinks=False)
        except OSError:
            shutil.copy2(src, dst, follow_symlinks=False)
    # sockets, FIFOs and devices are not carried over


def _in_place_only(folder: Path) -> bool:
    """Folders that cannot be swapped: the current directory or one above it (the
    process would be left in the old one), or a mount point."""
    here = Path.cwd().resolve()
    target = folder.resolve()
    return target == here or target in here.parents or os.path.ismount(target)


@contextlib.contextmanager
def replacing_folder(folder: str | os.PathLike[str], *,
                     keep: Callable[[str], bool] | None = None,
                     option: str = "") -> Iterator[Path]:
    """Yield an empty temporary folder beside ``folder``; when the block ends without an
    exception, put it in place of ``folder`` as a whole (module doc). The entries of
    the old folder that the block did not write and ``keep(name)`` accepts (default:
    all) are carried over. On any exception (KeyboardInterrupt included) the temporary
    is removed and ``folder`` is left as it was.

    Where a folder cannot be swapped (the current directory or above, a mount point),
    the files are moved in one by one, each atomically."""
    out = Path(folder)
    what = f"{option} {out}" if option else str(out)
    if out.is_symlink() or (os.path.lexists(out) and not out.is_dir()):
        raise OutputError(f"{what}: is a symbolic link or a file; expected a folder")
    created = make_folder(out.absolute().parent, what)
    remove_stale_folders(out.absolute())
    tmp = _folder_temp(out.absolute(), "tmp", what)
    try:
        yield tmp
        if out.is_dir():
            shutil.copymode(out, tmp)
            for name in sorted(os.listdir(out)):
                if not os.path.lexists(tmp / name) and (keep is None or keep(name)):
                    _carry(out / name, tmp / name)
        for p in sorted(tmp.rglob("*")):
            if p.is_file() and not p.is_symlink():
                _fsync(p)
        _fsync(tmp)
        if out.is_dir() and _in_place_only(out):
            _move_in(tmp, out)
        else:
            _swap(tmp, out.absolute(), what)
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        remove_folders(created)
        raise OutputError(f"{what}: cannot write: {_why(e)}") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        remove_folders(created)
        raise


def _swap(tmp: Path, out: Path, what: str) -> None:
    """Put the folder ``tmp`` in place of ``out``; the old tree is removed."""
    with _signals_held():
        if not os.path.lexists(out):
            os.rename(tmp, out)
        elif _exchange(tmp, out):
            shutil.rmtree(tmp, ignore_errors=True)  # the old folder, now at tmp's name
        else:
            old = _folder_temp(out, "old", what)
            os.rename(out, old)
            try:
                os.rename(tmp, out)
            except BaseException:
                os.rename(old, out)
                raise
            shutil.rmtree(old, ignore_errors=True)
    _fsync(out.parent)


def _move_in(tmp: Path, out: Path) -> None:
    """The fallback of :func:`replacing_folder`: every top-level entry of ``tmp`` moved
    into ``out`` by rename, each atomically; then ``tmp`` removed."""
    for name in sorted(os.listdir(tmp)):
        dst = out / name
        if (tmp / name).is_dir() and dst.is_dir() and not dst.is_symlink():
            old = _folder_temp(dst, "old", str(dst))
            with _signals_held():
                os.rename(dst, old)
                os.rename(tmp / name, dst)
            shutil.rmtree(old, ignore_errors=True)
        elif target_refusal(dst) is None:
            os.replace(tmp / name, dst)
    shutil.rmtree(tmp, ignore_errors=True)


def replace_folder(folder: str | os.PathLike[str], files: Mapping[str, str | bytes], *,
                   keep: Callable[[str], bool] | None = None, option: str = "",
                   mode: int | None = None) -> Path:
    """Replace ``folder`` as a whole by one that holds ``files`` (name -> text or bytes,
    each with ``mode``) and the old folder's other entries that ``keep(name)`` accepts
    (:func:`replacing_folder`)."""
    out = Path(folder)
    for name in files:
        if not name or "/" in name or name in (".", ".."):
            raise OutputError(f"{out}: {name!r} is not a file name")
    with replacing_folder(out, keep=keep, option=option) as tmp:
        write_files(tmp, files, option=option, mode=mode)
    return out
