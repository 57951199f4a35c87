"""lensfit: lens prescriptions, spectral ray tracing, polynomial fits and generated code.

Where lensfit finds its data: one rule, ``data_folder()``, for the two folders it reads.

* ``lensdb``: the lens TOML files, ``schema.json`` and ``glass/catalog.toml``;
* ``generated``: the fitted lenses, one folder each (``lens<id>.table``, ``fit.json``).

For each, the first of:

1. the command's option: ``--generated DIR`` (every ``lensfit`` command that reads or
   writes generated folders: fit, regenerate, scene, ghosts, bank);
2. the environment: ``LENSFIT_GENERATED``, ``LENSFIT_LENSDB``;
3. the source checkout's ``generated/`` and ``lensdb/``, when lensfit runs from a checkout
   (this package at ``fit/lensfit/``: ``make setup``'s editable install, or
   ``PYTHONPATH=fit``);
4. ``generated/`` and ``lensdb/`` in the current directory (an installed lensfit run
   outside a checkout).

A folder that is needed and missing is an error naming the folder, which rule gave it
and the setting that would change it (``missing_data_folder``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

DataKind = Literal["lensdb", "generated"]

# The environment variable and the option of each folder (the option: None for lensdb,
# which is set by the environment only)
DATA_ENV: dict[str, str] = {"lensdb": "LENSFIT_LENSDB", "generated": "LENSFIT_GENERATED"}
DATA_OPTION: dict[str, str | None] = {"lensdb": None, "generated": "--generated"}


def checkout_root() -> Path | None:
    """The repository root when this package runs from a source checkout
    (``<root>/fit/lensfit/``), else None (an installed package)."""
    root = Path(__file__).resolve().parents[2]
    if (root / "fit" / "pyproject.toml").is_file() and (root / "fit" / "lensfit").is_dir():
        return root
    return None


def data_folder_source(kind: DataKind, given: str | os.PathLike[str] | None = None
                       ) -> tuple[Path, str]:
    """The folder of ``kind`` by the rule above, and which rule gave it (for messages):
    ``given`` is the command's option when it has one."""
    if kind not in DATA_ENV:
        raise ValueError(f"data_folder: {kind!r}: expected one of {', '.join(DATA_ENV)}")
    option = DATA_OPTION[kind]
    if given is not None and os.fspath(given) != "":
        return Path(given), f"from {option or 'the caller'}"
    env = os.environ.get(DATA_ENV[kind])
    if env:
        return Path(env), f"from ${DATA_ENV[kind]}"
    root = checkout_root()
    if root is not None:
        return root / kind, f"the checkout's, {root}"
    return Path.cwd() / kind, "the current directory's"


def data_folder(kind: DataKind, given: str | os.PathLike[str] | None = None) -> Path:
    """The folder of ``kind`` (``"lensdb"`` or ``"generated"``) by the rule above; it may
    not exist (``lensfit fit`` makes the generated folder)."""
    return data_folder_source(kind, given)[0]


def missing_data_folder(kind: DataKind, given: str | os.PathLike[str] | None = None) -> str:
    """The message for a missing folder of ``kind``: the folder, where it came from and the
    settings that choose another."""
    path, source = data_folder_source(kind, given)
    option = DATA_OPTION[kind]
    how = f"give {option} DIR or set {DATA_ENV[kind]}" if option else f"set {DATA_ENV[kind]}"
    what = ("the lens database: lens TOML files, schema.json, glass/catalog.toml"
            if kind == "lensdb" else "the fitted lenses' folders")
    return f"{path}: no {kind} folder ({source}; {what}); {how} to the folder that holds it"


def require_data_folder(kind: DataKind, given: str | os.PathLike[str] | None = None) -> Path:
    """data_folder(), or InputError (missing_data_folder) when it is not a folder."""
    path = data_folder(kind, given)
    if not path.is_dir():
        from lensfit.common.errors import InputError

        raise InputError(missing_data_folder(kind, given))
    return path
