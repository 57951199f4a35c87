"""Glass names to media: the project catalog first, then the manufacturers' catalogs.

    resolve_glass("N-BK7")            project catalog (lensdb/glass/catalog.toml)
    resolve_glass("n-bak1")           case-insensitive; hyphens and blanks ignored
    resolve_glass("schott:N-BAK1")    a manufacturer's catalog only ("MAKER:NAME")
    resolve_glass("SK16", "hikari")   the same with the maker as an argument

An unqualified name is looked up in the project catalog first, so every lens that
resolved before resolves to the same glass; the spreadsheets are opened only when the
project catalog does not have the name. A name that several manufacturers use (and the
project catalog does not) is ambiguous: the error lists the qualified names to choose
from. No lookup ever falls back to another glass.
"""

from __future__ import annotations

import difflib
import functools

from lensfit.glass.catalog import (
    Medium,
    UnknownGlassError,
    _load_catalog,
    _normalise,
    catalog_glass,
    catalog_path,
)
from lensfit.glass.manufacturers import MANUFACTURERS, CatalogDataError, load_catalog

__all__ = ["AmbiguousGlassError", "resolve_glass", "split_qualifier"]

# How many close matches an unknown-glass error lists
_CLOSE_MATCHES = 5


class AmbiguousGlassError(UnknownGlassError):
    """An unqualified name found in several manufacturers' catalogs; ``.candidates``
    are the qualified names ("SCHOTT:F5", ...)."""

    def __init__(self, name: str, candidates: list[str]) -> None:
        self.candidates = list(candidates)
        super().__init__(name, candidates, (
            f"glass {name!r} is in several manufacturers' catalogs: "
            f"{', '.join(candidates)}; name one of them (MAKER:NAME)"))


def split_qualifier(name: str, manufacturer: str | None = None) -> tuple[str | None, str]:
    """("SCHOTT", "N-BAK1") from "schott:N-BAK1" (or from "N-BAK1", "Schott"); the maker
    is None when neither gives one. UnknownGlassError for an unknown maker or two
    different ones."""
    maker = None
    if ":" in name:
        maker, name = (part.strip() for part in name.split(":", 1))
    for given in (maker, manufacturer):
        if given is not None and given.upper() not in MANUFACTURERS:
            raise UnknownGlassError(name, [], (
                f"unknown glass manufacturer {given!r} (known: {', '.join(MANUFACTURERS)})"))
    if maker and manufacturer and maker.upper() != manufacturer.upper():
        raise UnknownGlassError(name, [], (
            f"glass {name!r}: the name says manufacturer {maker!r}, the caller "
            f"{manufacturer!r}"))
    maker = maker or manufacturer
    return (maker.upper() if maker else None), name


@functools.cache
def _maker_index(maker: str) -> dict[str, Medium]:
    """One manufacturer's glasses keyed by normalised name (see ``_normalise``); an
    UnknownGlassError saying what to install when the catalog data is missing."""
    try:
        return {_normalise(g.name): g for g in load_catalog(maker).values()}
    except CatalogDataError as e:
        raise UnknownGlassError(maker, [], f"{e}") from None


def _close(name: str, choices: list[tuple[str, str]]) -> list[str]:
    """Display names of the (normalised, display) pairs of ``choices`` whose normalised
    name is closest to ``name``'s, every display name of a matched key."""
    keys = difflib.get_close_matches(_normalise(name), sorted({k for k, _ in choices}),
                                     n=_CLOSE_MATCHES, cutoff=0.6)
    return [d for k in keys for kk, d in choices if kk == k]


def resolve_glass(name: str, manufacturer: str | None = None) -> Medium:
    """The glass ``name`` ("N-BK7", "schott:N-BAK1"), see the module docstring.

    Raises UnknownGlassError (a KeyError) naming close matches when there is no such
    glass, and AmbiguousGlassError (a subclass) when an unqualified name is in several
    manufacturers' catalogs. "air" is no glass: use ``lensfit.glass.AIR``."""
    if not isinstance(name, str) or not name.strip():
        raise UnknownGlassError(str(name), [], f"expected a glass name, found {name!r}")
    maker, bare = split_qualifier(name, manufacturer)
    key = _normalise(bare)
    if maker is not None:
        found = _maker_index(maker).get(key)
        if found is not None:
            return found
        near = _close(bare, [(k, g.reference) for k, g in _maker_index(maker).items()])
        hint = f"; close matches: {', '.join(near)}" if near else ""
        raise UnknownGlassError(name, near, f"unknown glass {bare!r} in the {maker} "
                                            f"catalog{hint}")
    if key == "AIR":
        return catalog_glass(bare)  # raises, with the hint to use AIR
    try:
        return catalog_glass(bare)
    except UnknownGlassError:
        pass
    hits = [g for m in MANUFACTURERS if (g := _maker_index(m).get(key)) is not None]
    if len(hits) == 1:
        return hits[0]
    if len(hits) > 1:
        raise AmbiguousGlassError(name, [g.reference for g in hits])
    choices = [(_normalise(g.name), g.name) for g in _load_catalog(catalog_path()).values()]
    choices += [(k, g.reference) for m in MANUFACTURERS for k, g in _maker_index(m).items()]
    near = _close(bare, choices)
    hint = f"; close matches: {', '.join(near)}" if near else ""
    raise UnknownGlassError(name, near, (
        f"unknown glass {bare!r} (not in {catalog_path().name} nor in the catalogs of "
        f"{', '.join(MANUFACTURERS)}){hint}"))
