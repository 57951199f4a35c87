"""Write a lens's fitted systems as code: the folder ``generated/<lens>/``.

Everything written here depends only on the fitted systems and the prescription (no
timings, no dates), so fitting the same lens again rewrites the same bytes. `lensfit
fit` replaces the folder as a whole (:func:`lensfit.common.atomic.replace_folder` with
:func:`fit_folder_keep`): an interrupted fit leaves the previous folder as it was.

    <stem>.h, <stem>.c            hand-emitted Horner C99, double and float (the fast form)
    <stem>.glsl                   GLSL 4.30 functions (float and double), with --glsl only
    <stem>.table                  coefficient table for generic evaluators, with the lens's
                                  first-order facts and the PSF trust figures
                                  (lensfit-poly-table 5)
    fit.json                      domain, options, held-out errors and the PSF table
                                  against exactly traced rays; the systems are the table's

casadi's C (``lensfit.codegen.emit_c(which="casadi")``) is no longer written to lens
folders: for tensor fits it is ~30 MB a file and measured ~3x slower than Horner.

A scene specialisation (``lensfit scene``) writes the Horner C and the table of its
folded systems to ``scenes/<name>/``; its table carries the same lens lines.
:func:`regenerate` rewrites a folder from its ``fit.json`` without fitting again.
"""

from __future__ import annotations

import os
import re
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from lensfit import data_folder
from lensfit.codegen import emit_c, emit_glsl, write_table
from lensfit.codegen.c_horner import file_stem
from lensfit.codegen.checked_json import REGENERATE_FOLDER, checked_json_text, load_checked_json
from lensfit.codegen.table import (
    LEGACY,
    GhostLines,
    Table,
    read_table,
    upgrade_text,
)
from lensfit.codegen.table import VERSION as TABLE_VERSION
from lensfit.common.atomic import write_files
from lensfit.common.errors import InputError
from lensfit.paraxial.facts import LensFacts, lens_facts
from lensfit.poly import System
from lensfit.prescription.model import Lens


def generated_dir(given: str | os.PathLike[str] | None = None) -> Path:
    """The generated folder: ``given`` (a command's --generated), else $LENSFIT_GENERATED,
    else the checkout's generated/, else the current directory's (lensfit.data_folder)."""
    return data_folder("generated", given)


def __getattr__(name: str) -> Path:
    # GENERATED_DIR, the generated folder by lensfit.data_folder's rule, looked up at each
    # use (it follows $LENSFIT_GENERATED and, outside a checkout, the current directory)
    if name == "GENERATED_DIR":
        return generated_dir()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def lens_id(lens: Lens) -> str:
    """The lens's id from its file ('0001'), else a slug of its name."""
    ident = str(lens.raw.get("lens", {}).get("id", "")) if lens.raw else ""
    if not ident:
        # C-identifier safe: ASCII letters and digits, single '_' between, none at the end
        slug = re.sub(r"_+", "_", re.sub(r"[^a-z0-9]", "_", lens.name.lower()))
        ident = slug[:24].rstrip("_")
    return ident


def lens_prefix(lens: Lens) -> str:
    return f"lens{lens_id(lens)}_"


def lens_folder_name(lens: Lens) -> str:
    """The lens file's stem (else its id), with "-<variant>" for a variant such as the
    uncoated lens (:func:`lensfit.prescription.with_coating`)."""
    stem = Path(lens.source_file).stem
    name = stem if stem and stem != "<memory>" else lens_id(lens)
    return f"{name}-{lens.variant}" if lens.variant else name


def sources_for(systems: Sequence[System], prefix: str, comment: str, *,
                facts: LensFacts | None = None, trust: dict[str, Any] | None = None,
                casadi: bool = False, glsl: bool = False, c: bool = True,
                table_note: str = "") -> dict[str, str]:
    """Every generated file's text, by file name (the table carries ``facts`` and
    ``trust``: give them for a lens folder). The Horner C unless ``c`` is false; casadi's
    C only with ``casadi`` (for a tensor fit ~30 MB a file and ~3x slower than the Horner
    C); GLSL only with ``glsl`` (~6 MB for a tensor fit; lensrt's GL path uploads the
    table instead). ``table_note``: more comment lines for the table only."""
    files: dict[str, str] = {}
    if c:
        files.update(emit_c(systems, prefix, header_comment=comment, which="horner"))
    if casadi:
        files.update(emit_c(systems, prefix, header_comment=comment, which="casadi"))
    if glsl:
        files.update(emit_glsl(systems, prefix, header_comment=comment))
    files.update(table_file(systems, prefix, "\n".join(filter(None, (comment, table_note))),
                            facts, trust))
    return files


def table_file(systems: Sequence[System], prefix: str, comment: str,
               facts: LensFacts | None, trust: dict[str, Any] | None = None,
               ghost: GhostLines | None = None) -> dict[str, str]:
    """The coefficient table the runtime loads, ``{"<stem>.table": text}`` (a ghost
    table with ``ghost``)."""
    return {f"{file_stem(prefix)}.table": write_table(systems, comment=comment, lens=facts,
                                                      trust=trust, ghost=ghost)}


def lens_files(lens: Lens, systems: Sequence[System], meta: dict[str, Any],
               trust: dict[str, Any]) -> dict[str, str]:
    """Every file of the folder ``generated/<lens>/``, by name (``meta``: fit.json's keys;
    ``trust``: the table's trust figures, :func:`lensfit.trust.check.trust_figures`; GLSL
    when ``meta["glsl"]`` is true, as `lensfit fit --glsl` records it). The table gets a
    comment line with the fitted wavelengths and why when ``meta["wavelengths"]`` has
    them (:func:`wavelengths_note`).

    A coating variant (`--coating none`) gets no C: its positions and phase are the
    lens's own, bit for bit (the same rays; only tau differs), so its 2.5 MB of Horner C
    would repeat the lens's. lensrt loads its table."""
    prefix = lens_prefix(lens)
    files = sources_for(systems, prefix, header_comment(lens), facts=lens_facts(lens),
                        trust=trust, glsl=bool(meta.get("glsl", False)), c=not lens.variant,
                        table_note=wavelengths_note(meta))
    files["fit.json"] = fit_json({**meta, "table": f"{file_stem(prefix)}.table"})
    return files


def wavelengths_note(meta: dict[str, Any]) -> str:
    """The table's comment line on its wavelengths, from fit.json's ``wavelengths``
    (:meth:`lensfit.prescription.ranges.Wavelengths.to_dict`): e.g. ``wavelengths 404.66-780 nm:
    the range every glass supports (N-F2: 404.66-2325.4 nm) within 380-780 nm``. Empty
    for a fit.json written before the key. A comment: lensrt and lensfit skip it; the
    table's own lambda input line holds the range they check."""
    w = meta.get("wavelengths")
    if not isinstance(w, dict):
        return ""
    try:
        from lensfit.prescription.ranges import Wavelengths

        line = Wavelengths(float(w["min_nm"]), float(w["max_nm"]), str(w["reason"])).line()
    except (KeyError, TypeError, ValueError):
        return ""
    return " ".join(line.split())  # one line whatever the reason holds


def regenerate(folder: Path) -> tuple[Lens, list[str]]:
    """Rewrite ``folder`` (a ``generated/<lens>/``) from its fit.json without fitting: the
    code of the recorded systems and the lens facts of the lens file it names. Returns
    the lens and the names of the files written."""
    from lensfit.prescription import load_lens, with_coating  # pulls in the glass catalog

    folder = Path(folder)
    fit_file = folder / "fit.json"
    if not fit_file.is_file():
        raise InputError(f"{fit_file}: no fit.json to regenerate from; run `lensfit fit`")
    # Tables of an earlier version (no checksum, or no probe lines) first: the lens's, its
    # ghosts' and its scenes' (their coefficients carried over bit for bit), then the
    # records of them
    upgraded = [str(p.relative_to(folder)) for p in sorted(folder.rglob("*.table"))
                if upgrade_table(p)]
    upgraded += [str(p.relative_to(folder)) for p in sorted(folder.rglob("*.json"))
                 if p.name in ("fit.json", "ghosts.json") and upgrade_json(p)]
    upgraded += [str(p.relative_to(folder)) for p in sorted(folder.rglob("ghosts.json"))
                 if upgrade_ghosts_json(p)]
    systems, meta = read_fit_json(fit_file, legacy=True)
    trust = getattr(systems, "trust", None)
    if trust is None:
        raise InputError(f"{fit_file}: its table predates the trust figures (version 3); "
                         "run `lensfit fit` to refit and measure them")
    lens_file = meta.get("lens_file")
    if not isinstance(lens_file, str) or not lens_file:
        raise InputError(f"{fit_file}: key 'lens_file': expected the lens's file name, "
                         f"found {lens_file!r}")
    lens = with_coating(load_lens(Path(lens_file).stem), meta.get("coating", "file"))
    if folder.name != lens_folder_name(lens):
        raise InputError(f"{folder}: the folder of {lens_file} is named "
                         f"{lens_folder_name(lens)!r}, not {folder.name!r}")
    meta = {k: v for k, v in meta.items() if k not in ("format", "table")}
    files = lens_files(lens, list(systems), meta, trust)
    write_folder(folder, files)
    return lens, sorted(set(files) | set(upgraded))


def scene_files(lens: Lens, special: Sequence[System], scene_name: str,
                scene_file: str, trust: dict[str, Any],
                ghost: GhostLines | None = None, glsl: bool = False) -> dict[str, str]:
    """The files of ``scenes/<name>/`` for the specialised systems ``special``: Horner C
    (and with ``glsl`` GLSL) and the table, which carries the lens's facts and ``trust``
    like the lens folder's (a specialisation is the same polynomials with inputs folded
    in). With ``ghost``, the files of that ghost (for ``scenes/<name>/ghosts/``)."""
    prefix = f"{lens_prefix(lens)}{scene_name.replace('-', '_')}_"
    extra = f"Specialised for scene {Path(scene_file).name}."
    if ghost is not None:
        prefix += f"ghost_{ghost.first}_{ghost.second}_"
        extra = f"Ghost {ghost.label}, specialised for scene {Path(scene_file).name}."
    comment = header_comment(lens, extra)
    files = emit_c(special, prefix, header_comment=comment) | table_file(
        special, prefix, comment, lens_facts(lens), trust, ghost)
    if glsl:
        files |= emit_glsl(special, prefix, header_comment=comment)
    return files


def header_comment(lens: Lens, extra: str = "") -> str:
    text = (f"Generated by lensfit from {Path(lens.source_file).name}: {lens.name}. "
            "Do not edit: run `lensfit fit` to regenerate.")
    return text + (" " + extra if extra else "")


def write_folder(folder: Path, files: dict[str, str]) -> None:
    """Write all files atomically, each through lensfit's one checked atomic write
    (:func:`lensfit.common.atomic.write_files`: a temporary then a rename, a link or a special
    file refused; every target checked before the first write)."""
    write_files(folder, files, mode=0o644)  # for everyone, whatever the umask


def fit_folder_keep(files: dict[str, str]) -> Callable[[str], bool]:
    """Which entries of a lens folder a new fit writing ``files`` keeps
    (:func:`lensfit.common.atomic.replace_folder`): not fit.json nor an earlier fit's code of
    the same stem (``lens0001.glsl`` of a fit with --glsl), the rest (ghosts/,
    scenes/, scene-fits/ of other commands) yes."""
    stems = {name.partition(".")[0] for name in files if "." in name}

    def keep(name: str) -> bool:
        return name != "fit.json" and not ("." in name and name.partition(".")[0] in stems)

    return keep


def fit_json(meta: dict[str, Any]) -> str:
    """The machine-readable record of a fit (deterministic: sorted keys, fixed format,
    its own checksum: :mod:`lensfit.codegen.checked_json`). The systems themselves are
    in the table it names (key ``table``), bit for bit."""
    return checked_json_text({"format": "lensfit-fit 2", **meta})


def read_fit_json(path: Path, *, legacy: bool = False) -> tuple[Table, dict[str, Any]]:
    """(the systems, from the table fit.json names, with its lens facts and trust; the
    rest of fit.json). Its checksum is verified; ``legacy`` reads one without a checksum
    and a version-3 table, as :func:`regenerate` does."""
    path = Path(path)
    doc = load_checked_json(path, REGENERATE_FOLDER, legacy=legacy)
    if doc.get("format") != "lensfit-fit 2":
        raise InputError(f"{path}: key 'format': expected 'lensfit-fit 2', "
                         f"found {doc.get('format')!r}; run `lensfit fit` to refit")
    name = doc.get("table")
    if not isinstance(name, str) or "/" in name or not name.endswith(".table"):
        raise InputError(f"{path}: key 'table': expected the table's file name, found "
                         f"{name!r}")
    table = path.parent / name
    try:
        systems = read_table(table.read_text(encoding="utf-8"), legacy=legacy)
    except (OSError, ValueError, UnicodeDecodeError) as e:
        raise InputError(f"{table}: {e}") from None
    return systems, doc


def upgrade_json(path: Path) -> bool:
    """Give a JSON record written before checksums (fit.json, ghosts.json) its checksum,
    the content unchanged. Returns whether it changed."""
    doc = load_checked_json(path, "", legacy=True)
    text = checked_json_text(doc)
    if path.read_text(encoding="utf-8") == text:
        return False
    write_folder(path.parent, {path.name: text})
    return True


def upgrade_table(path: Path) -> bool:
    """Rewrite a version-3 (no checksum) or version-4 (no probe lines) table as version 5
    in place (:func:`lensfit.codegen.table.upgrade_text`): the same bytes but for the
    header, the probe lines (the table's own polynomials evaluated) and the checksum
    line; the coefficients are proven unchanged. Returns whether it changed."""
    text = path.read_text(encoding="utf-8")
    head = text.partition("\n")[0]
    if head.split() not in (["lensfit-poly-table", str(v)] for v in LEGACY):
        return False
    try:
        new = upgrade_text(text)
    except ValueError as e:
        raise InputError(f"{path}: cannot upgrade to version {TABLE_VERSION}: {e}") from None
    write_folder(path.parent, {path.name: new})
    return True


def upgrade_ghosts_json(path: Path) -> bool:
    """Record the CRC-32 of each ghost table as it is now in ghosts.json (``table_crc32``,
    which `lensfit ghosts` compares to reuse a fit: lensfit.ghosts.tasks), after
    :func:`upgrade_table` rewrote the tables. Returns whether it changed."""
    doc = load_checked_json(path, "", legacy=True)
    for e in doc.get("ghosts", []):
        if not isinstance(e, dict) or "table_crc32" not in e:
            continue
        table = path.parent / f"ghost_{e.get('first')}_{e.get('second')}.table"
        if table.is_file():
            e["table_crc32"] = f"{zlib.crc32(table.read_bytes()) & 0xFFFFFFFF:08x}"
    text = checked_json_text(doc)
    if path.read_text(encoding="utf-8") == text:
        return False
    write_folder(path.parent, {path.name: text})
    return True
