"""`lensfit ghosts --fit` on Dask: one ghost per task, over one lens or many.

The driver (``cmd_ghosts``) enumerates and ranks each lens's ghosts in its own process,
then hands every kept ghost of every lens to :func:`lensfit.banks.engine.run_tasks` as
one task (a LocalCluster by default, ``--scheduler`` for a cluster, ``--workers 0`` in
this process). A task fits its ghost (``fit_with_trust``) and writes what it made (the
table's text, C and GLSL when asked, the ghosts.json entry and the line to print) to a
checked JSON record ``<lens folder>/.ghost-tasks/<stem>-<digest>.json``, atomically.

The digest covers everything the fit depends on (the lens file's bytes and coating
variant, the light, the f-number, the ghost, the enumeration's rays, the direct fit's
record), so nothing is mixed:

* a rerun after a crash or a SIGKILL (of a worker: the scheduler retries the task; of the
  driver: the same command again) fits only the ghosts without a record;
* a ghost whose entry in the folder's ghosts.json carries the same digest, with its table
  unchanged (and its C or GLSL there when asked for), is not fitted again either;
* when every kept ghost of a lens is done, its folder is written (write_folder) and its
  records removed; a lens with a failed ghost keeps its records for the next run.
"""

from __future__ import annotations

import hashlib
import json
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lensfit.codegen.checked_json import REGENERATE_FOLDER, checked_json_text, load_checked_json
from lensfit.codegen.table import read_table
from lensfit.common.atomic import make_folder, plain_name, write_atomic
from lensfit.common.errors import InputError

TASKS_FOLDER = ".ghost-tasks"


@dataclass
class LensPlan:
    """One lens's kept ghosts and what their fits need, made by the driver."""

    lens: Any
    ghosts: list  # GhostEstimate, kept ones
    info: dict[str, Any]
    light: tuple[float, float]
    folder: Path  # <generated>/<lens folder>
    direct: Any  # the direct fit's table
    domain: Any
    lens_bytes: bytes  # the lens file, for the digest
    fit_json_crc: int
    distance_mm: float
    rays: int
    jobs: list[dict[str, Any]] = field(default_factory=list)


def _digest(plan: LensPlan, g) -> str:
    key = {"lens": hashlib.sha256(plan.lens_bytes).hexdigest(), "variant": plan.lens.variant,
           "light": list(plan.light), "f_number": plan.info["f_number"],
           "distance_mm": repr(plan.distance_mm), "rays": plan.rays,
           "ghost": [g.first, g.second], "fit_json_crc32": plan.fit_json_crc}
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def stem_of(g) -> str:
    return f"ghost_{g.first}_{g.second}"


def fit_ghost_task(job: dict[str, Any]) -> dict[str, Any]:
    """Fit one ghost and write its record (the worker's side)."""
    from lensfit.codegen import emit_c, emit_glsl
    from lensfit.codegen.table import write_table
    from lensfit.ghosts.tables import fit_with_trust, ghost_report

    lens, g, light, f_number = job["lens"], job["ghost"], job["light"], job["f_number"]
    fit, table, cells = fit_with_trust(lens, g, job["direct"], job["domain"], light, f_number)
    stem, comment, prefix = stem_of(g), job["comment"], job["prefix"]
    files = {f"{stem}.table": write_table(table, comment=comment)}
    if job["c"]:  # megabytes a ghost; lensrt loads the table
        files.update(emit_c(list(table), f"{prefix}{stem}", header_comment=comment,
                            which="horner"))
    if job["glsl"]:  # P_o, P_s and P_clip for a renderer's own shaders
        files.update(emit_glsl(list(table), f"{prefix}{stem}", header_comment=comment))
    entry = ghost_report(fit, g.name, cells, g.to_dict())
    entry.update(light_deg=list(light), f_number=f_number, task_digest=job["digest"],
                 table_crc32=f"{zlib.crc32(files[f'{stem}.table'].encode()) & 0xFFFFFFFF:08x}")
    worst = max(cells, key=lambda c: c.rel_l2)
    # A ghost fitted over a narrowed stop (fit_with_trust) serves its f-number and slower
    narrowed = (f", stop narrowed to f/{f_number:g}"
                if fit.stop_radius_mm < job["domain"].stop_radius_mm * (1 - 1e-9) else "")
    line = (f"ghost {g.name} ({g.case}, side {fit.half.system}{narrowed}): {fit.seconds:.1f} s, "
            f"converged {fit.converged_test:.1%}, clip agreement "
            f"{fit.agreement_housings:.2%} ({len(fit.clip_housings.outputs) // 2} pairs), "
            f"PSF vs exact {worst.rel_l2:.2%} (f/{worst.f_number:g} "
            f"{worst.wavelength_nm:g} nm), energy {worst.energy_ratio:.4f}, without "
            f"P_clip {worst.energy_ratio_no_clip:.4f}")
    if entry["miss_reason"]:  # named, written and kept: the report says why
        line += f"\n  MISSES the target: {entry['miss_reason']}"
    write_atomic(job["record"], checked_json_text({"digest": job["digest"], "files": files,
                                                   "entry": entry, "line": line}))
    return {"record": job["record"], "line": line}


def _asked(files: dict[str, str], stem: str, c: bool, glsl: bool) -> dict[str, str] | None:
    """The files of a fitted ghost this run asks for (its table, its C with ``c``, its
    GLSL with ``glsl``), or None when one of them is missing (it is fitted again)."""
    kinds = {".table": True, ".c": c, ".h": c, ".glsl": glsl}
    out = {n: t for n, t in files.items() for ext, want in kinds.items()
           if want and n.endswith(f"{stem}{ext}")}
    have = {ext for n in out for ext in kinds if n.endswith(f"{stem}{ext}")}
    return out if have == {ext for ext, want in kinds.items() if want} else None


def _names(g, prefix: str) -> set[str]:
    """Every file name a task may write for ghost ``g`` (its table, C and GLSL)."""
    stem = stem_of(g)
    return {f"{stem}.table", *(f"{prefix}{stem}{ext}" for ext in (".c", ".h", ".glsl"))}


def _check_entry(entry: Any, g, where: str, *, complete: bool = True) -> None:
    """ValueError unless ``entry`` is a ghosts.json entry (of ghost ``g`` when given: its
    label and surfaces), with the keys readers use of their types (all of them when
    ``complete``, as a task's record has them; else those present)."""
    if not isinstance(entry, dict):
        raise ValueError(f"{where}: expected an object")
    first, second, label = entry.get("first"), entry.get("second"), entry.get("label")
    if not (type(first) is int and type(second) is int and 0 <= first < second
            and isinstance(label, str) and plain_name(label)):
        raise ValueError(f"{where}: label {str(label)[:20]!r}, first {str(first)[:20]}, "
                         f"second {str(second)[:20]}: expected a label and surfaces 0 <= "
                         "first < second")
    if g is not None and (label, first, second) != (g.name, g.first, g.second):
        raise ValueError(f"{where}: ghost {label} ({first}, {second}): expected ghost "
                         f"{g.name} ({g.first}, {g.second})")
    kinds = {"within_target": (bool,), "miss_reason": (str, type(None)),
             "table_crc32": (str,), "task_digest": (str,)}
    for k, types in kinds.items():
        if (complete or k in entry) and not isinstance(entry.get(k), types):
            raise ValueError(f"{where}: {k} {str(entry.get(k))[:20]!r} of the wrong type")
    v = entry.get("psf_vs_exact")
    if (complete or "psf_vs_exact" in entry) and (
            isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < 1e3):
        raise ValueError(f"{where}: psf_vs_exact {str(v)[:20]!r}: expected a relative "
                         "error in [0, 1000)")


def _check_record(doc: dict[str, Any], digest: str, g, prefix: str) -> None:
    """ValueError unless a record (its checksum already verified) is what a task writes
    for ghost ``g``: files of the ghost's own plain names, a table that reads back as
    this ghost's, its entry and its printed line (issue 39: a record is read for its
    names before anything is written)."""
    files, line = doc.get("files"), doc.get("line")
    if doc.get("digest") != digest:
        raise ValueError("another digest")
    if not isinstance(files, dict) or not all(isinstance(t, str) for t in files.values()):
        raise ValueError("files: expected an object of texts")
    names = _names(g, prefix)
    for name in files:
        if not plain_name(name) or name not in names:
            raise ValueError(f"files: {str(name)[:80]!r} is not a file of ghost {g.name} "
                             f"(one of {', '.join(sorted(names))})")
    text = files.get(f"{stem_of(g)}.table")
    if text is None:
        raise ValueError(f"files: no {stem_of(g)}.table")
    try:
        table = read_table(text)
    except ValueError as e:
        raise ValueError(f"{stem_of(g)}.table: {e}") from None
    if table.ghost is None or (table.ghost.first, table.ghost.second) != (g.first, g.second):
        raise ValueError(f"{stem_of(g)}.table: not the table of ghost {g.name}")
    entry = doc.get("entry")
    _check_entry(entry, g, "entry")
    if entry["table_crc32"] != f"{zlib.crc32(text.encode()) & 0xFFFFFFFF:08x}" \
            or entry["task_digest"] != digest:
        raise ValueError("entry: table_crc32 or task_digest is not the record's")
    if not isinstance(line, str) or any(ord(ch) < 32 and ch != "\n" for ch in line):
        raise ValueError("line: expected text without control characters")


def _record(path: Path, digest: str, g, c: bool, glsl: bool,
            prefix: str) -> dict[str, Any] | None:
    """A task's record of the ghost for the same inputs, with the files this run asks
    for; None when there is none (or it is damaged, not what a task writes for this
    ghost, or lacks a file asked for: the ghost is then fitted again)."""
    if not path.is_file():
        return None
    try:
        doc = load_checked_json(path, "it is fitted again")
    except InputError:
        return None  # damaged: fitted again, then replaced
    if doc.get("digest") != digest:
        return None
    try:
        _check_record(doc, digest, g, prefix)
    except ValueError as e:
        print(f"lensfit: note: {path}: record refused ({e}); ghost {g.name} is fitted "
              "again", file=sys.stderr)
        return None
    files = _asked(doc["files"], stem_of(g), c, glsl)
    return None if files is None else {**doc, "files": files}


def _from_folder(out: Path, before: list[dict[str, Any]], g, digest: str, c: bool,
                 glsl: bool) -> dict[str, Any] | None:
    """The ghost as the folder already holds it, when fitted for the same inputs and
    holding the files this run asks for."""
    for e in before:
        if e.get("task_digest") == digest and e.get("label") == g.name:
            table = out / f"{stem_of(g)}.table"
            try:
                text = table.read_text(encoding="utf-8")
            except OSError:
                return None
            if f"{zlib.crc32(text.encode()) & 0xFFFFFFFF:08x}" != e.get("table_crc32"):
                return None
            files = _asked({p.name: p.read_text(encoding="utf-8")
                            for p in out.glob(f"*{stem_of(g)}.*")}, stem_of(g), c, glsl)
            if files is None:
                return None
            return {"files": files, "entry": e, "line": f"ghost {g.name}: as fitted before "
                                                        f"({table})"}
    return None


def _before(out: Path) -> list[dict[str, Any]]:
    index = out / "ghosts.json"
    return read_ghost_index(index) if index.is_file() else []


def read_ghost_index(index: Path) -> list[dict[str, Any]]:
    """The entries of a ghosts.json, its checksum verified and each entry's label and
    surfaces (and the other keys readers use, where present) of their types: the one
    reader of ghosts.json (ghost fits, scenes, banks)."""
    try:
        entries = load_checked_json(index, REGENERATE_FOLDER)["ghosts"]
        if not isinstance(entries, list):
            raise TypeError("key 'ghosts' is not a list")
    except (KeyError, TypeError) as e:
        raise InputError(f"{index}: cannot read the ghosts fitted before: {e}") from None
    for i, e in enumerate(entries):  # the keys used here, of their types
        try:
            _check_entry(e, None, f"ghosts[{i}]", complete=False)
        except ValueError as err:
            raise InputError(f"{index}: key {err}; {REGENERATE_FOLDER}") from None
    return entries


def plan_jobs(plan: LensPlan, *, c: bool, glsl: bool) -> list[dict[str, Any]]:
    """The tasks of a lens's kept ghosts that are not done (no record, not in the folder
    as fitted for the same digest)."""
    from lensfit.codegen.generate import header_comment, lens_prefix

    out, work = plan.folder / "ghosts", plan.folder / TASKS_FOLDER
    before = _before(out)
    jobs = []
    for g in plan.ghosts:
        digest = _digest(plan, g)
        record = work / f"{stem_of(g)}-{digest}.json"
        if (_record(record, digest, g, c, glsl, lens_prefix(plan.lens))
                or _from_folder(out, before, g, digest, c, glsl)):
            continue
        comment = header_comment(plan.lens, f"Ghost {g.name} (reflect at surface "
                                            f"{g.second_file}, then {g.first_file}): "
                                            "`lensfit ghosts --fit`.")
        jobs.append({"lens": plan.lens, "ghost": g, "direct": plan.direct,
                     "domain": plan.domain, "light": plan.light,
                     "f_number": plan.info["f_number"], "c": c, "glsl": glsl,
                     "comment": comment, "prefix": lens_prefix(plan.lens),
                     "digest": digest, "record": str(record),
                     "key": f"ghost-{plan.folder.name}-{stem_of(g)}-{digest}"})
    if jobs:
        make_folder(work, "ghost task records")
    return jobs


def write_lens(plan: LensPlan, *, c: bool, glsl: bool, add: bool) -> list[str]:
    """Write a lens's ghosts folder from its records (and what the folder held for the
    same digests), then remove the records; the lines to print."""
    from lensfit.codegen.generate import lens_prefix, write_folder

    out, work = plan.folder / "ghosts", plan.folder / TASKS_FOLDER
    before = _before(out)
    files: dict[str, str] = {}
    report, lines, used = [], [], []
    for g in plan.ghosts:
        digest = _digest(plan, g)
        record_path = work / f"{stem_of(g)}-{digest}.json"
        done = (_record(record_path, digest, g, c, glsl, lens_prefix(plan.lens))
                or _from_folder(out, before, g, digest, c, glsl))
        if done is None:
            raise InputError(f"{record_path}: ghost {g.name} of {plan.folder.name} has no "
                             "record: run the command again")
        files.update(done["files"])
        report.append(done["entry"])
        lines.append(done["line"])
        used.append(record_path)
    if add and before:
        # Keep the ghosts fitted before that were not named this time
        names = {e["label"] for e in report}
        report = [e for e in before if e.get("label") not in names] + report
        files.update({p.name: p.read_text(encoding="utf-8") for e in before
                      if e.get("label") not in names
                      for p in out.glob(f"*ghost_{e['first']}_{e['second']}.*")})
    files["ghosts.json"] = checked_json_text({"format": "lensfit-ghosts 1", "ghosts": report})
    write_folder(out, files)
    for old in out.glob("*ghost_*"):  # ghosts no longer kept
        if old.name not in files:
            old.unlink()
    for p in used:
        p.unlink(missing_ok=True)
    if work.is_dir() and not any(work.iterdir()):
        work.rmdir()
    lines.append(f"wrote {len(plan.ghosts)} ghost table(s) and ghosts.json ({len(report)} "
                 f"ghosts) to {out}")
    missed = [e["label"] for e in report if e.get("within_target") is False]
    lines.append(f"{len(report) - len(missed)} of {len(report)} ghosts within the PSF target"
                 + (f"; missing it (their reasons above and in ghosts.json, key "
                    f"'miss_reason'): {', '.join(missed)}" if missed else ""))
    return lines
