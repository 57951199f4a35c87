"""Errors a person can act on: every message names the file, the place and the key."""

from __future__ import annotations

import os
from collections.abc import Iterable


class InputError(ValueError):
    """Bad input other than a lens file (an option, an output path, a fit file), as one
    line naming the option or file and the value. The command line reports it with exit
    status 2; other exceptions are bugs and keep their traceback."""


def parse_problem(e: ValueError) -> str:
    """What a TOML or JSON parser's ValueError says, for a person. Python refuses to turn
    an integer literal of more than 4300 digits into an int (sys.get_int_max_str_digits:
    a guard against quadratic-time conversion), and its message advises raising that
    limit; no value lensfit reads has such a literal, so it is named as what it is."""
    text = str(e)
    if "integer string conversion" in text:
        return ("an integer literal of more than 4300 digits (no value lensfit reads has "
                "one)")
    return text


def regular_file_problem(path: str | object) -> str | None:
    """Why ``path`` cannot be read as an input file (a folder, a FIFO, a device: a FIFO
    would block the read), or None for a regular file or a missing one (whose read
    reports it)."""
    import os
    import stat

    try:
        mode = os.stat(path).st_mode  # type: ignore[arg-type]
    except OSError:
        return None
    return None if stat.S_ISREG(mode) else "not a regular file"


def refuse_repeated_tables(paths: Iterable[str | os.PathLike[str]],
                           what: str = "ghost table") -> None:
    """InputError when two of ``paths`` are the same file (the same device and inode, as
    ``os.stat`` follows links: the same path twice, a symbolic link, another relative
    path, a folder's table also named alone), which would render that ghost twice and add
    its flare twice. The message names the file and both spellings. A path ``os.stat``
    cannot read is left to its reader's own message."""
    seen: dict[tuple[int, int], str] = {}
    for path in paths:
        try:
            st = os.stat(path)
        except OSError:
            continue
        key, name = (st.st_dev, st.st_ino), os.fspath(path)
        if key in seen:
            raise InputError(f"{what} {seen[key]} is given twice (as {seen[key]} and {name}, "
                             "the same file): its flare would be added twice; give it once")
        seen[key] = name


def read_toml(path: str | object, what: str, error: type[Exception]) -> dict:
    """The parsed TOML file ``path`` (a scene, a bank spec), or ``error`` with one line
    "<path>: cannot read <what>: <why>" (a folder, a FIFO, bad UTF-8 or TOML, nesting
    too deep for the parser)."""
    import tomllib
    from pathlib import Path

    p = Path(path)  # type: ignore[arg-type]
    problem = regular_file_problem(p)  # a FIFO would block the read
    if problem:
        raise error(f"{p}: cannot read {what}: {problem}")
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as e:
        raise error(f"{p}: cannot read {what}: {e}") from None
    except ValueError as e:  # TOMLDecodeError, or an integer of over 4300 digits
        raise error(f"{p}: cannot read {what}: {parse_problem(e)}") from None
    except RecursionError:
        raise error(f"{p}: cannot read {what}: nested too deeply") from None


def int_digits(n: int) -> int:
    """The decimal digits of an integer, counted without converting it to a string
    (str() of an int of more than 4300 digits raises ValueError; a TOML hexadecimal,
    octal or binary literal of any length parses, since those bases are not limited)."""
    n = abs(n)
    d = max(1, int((n.bit_length() - 1) * 0.30102999566398120))
    while 10**d <= n:
        d += 1
    while d > 1 and 10 ** (d - 1) > n:
        d -= 1
    return d


def int_shown(n: int) -> str:
    """An integer as a message shows it: itself, or beyond a float's range its sign and
    digit count (safe for any length: :func:`int_digits`)."""
    import sys

    if abs(n) <= sys.float_info.max:
        return repr(n)
    return f"{'-' if n < 0 else ''}an integer of {int_digits(n)} digits"


def toml_overflow(obj: object, path: tuple = ()) -> tuple[tuple, int] | None:
    """The first integer in parsed TOML too large for a float (TOML integers are
    unbounded in Python; float() of one raises OverflowError), with its key path."""
    import sys

    if isinstance(obj, dict):
        items = obj.items()
    elif isinstance(obj, list):
        items = enumerate(obj)
    elif isinstance(obj, int) and not isinstance(obj, bool) and abs(obj) > sys.float_info.max:
        return path, obj
    else:
        return None
    for k, v in items:
        found = toml_overflow(v, (*path, k))
        if found:
            return found
    return None


class LensError(ValueError):
    """A prescription (or other lens input) that cannot be used.

    The message always starts with the file, then the surface index (when the
    problem is in a surface) and the key, then what was expected and what was found:

        lensdb/0001.toml: surface 3: key 'radius': expected a finite number, found nan
    """

    def __init__(
        self,
        message: str,
        *,
        file: str | None = None,
        surface: int | None = None,
        key: str | None = None,
    ) -> None:
        self.file = file
        self.surface = surface
        self.key = key
        self.detail = message
        where = []
        if file is not None:
            where.append(str(file))
        if surface is not None:
            where.append(f"surface {surface}")
        if key is not None:
            where.append(f"key '{key}'")
        super().__init__(": ".join([*where, message]))
