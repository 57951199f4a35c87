"""Errors a person can act on: every message names the file, the place and the key."""

from __future__ import annotations


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
