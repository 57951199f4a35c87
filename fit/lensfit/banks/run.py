"""Run a bank: plan its nodes, skip the finished ones, render the rest on Dask, index it.

The bank folder holds ``bank.json`` (the spec, the lens, its table's CRC-32: checked
JSON), ``nodes/`` (per node an EXR and its record, node.py), ``bank.index`` (index.py,
written when every node is finished) and ``contact-sheet.png``. A rerun of the same spec
renders only what is not finished (and resumes a Monte Carlo node's saved sums); a
folder holding a bank of another spec or table is refused (``restart`` empties it), so
two banks are never mixed.
"""

from __future__ import annotations

import math
import os
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lensfit.banks.engine import check_scheduler, check_workers, run_tasks
from lensfit.banks.index import INDEX_NAME, index_text
from lensfit.banks.node import (
    file_crc32,
    finished_record,
    refuse_special,
    render_node,
    stem,
    task_key,
)
from lensfit.banks.spec import BankSpec, SpecError, load_spec
from lensfit.codegen.checked_json import checked_json_text, load_checked_json
from lensfit.common.atomic import OutputError, make_folder, write_atomic
from lensfit.common.errors import InputError, refuse_repeated_tables

BANK_RECORD = "bank.json"
SHEET_NAME = "contact-sheet.png"
CHECK_NAME = "check.json"


@dataclass
class Summary:
    nodes: int
    rendered: int
    skipped: int
    worst_error: float
    cpu_seconds: float
    wall_seconds: float
    index: Path
    check: dict[str, Any] | None = None  # check.py's measure between the nodes

    def line(self) -> str:
        worst = f"{self.worst_error:.2%}" if self.worst_error >= 0 else "none (Monte Carlo)"
        text = (f"bank {self.index.parent}: {self.nodes} nodes ({self.rendered} rendered, "
                f"{self.skipped} already finished), worst error estimate {worst} (at a node "
                f"the reader gives the node's own render), {self.cpu_seconds:.1f} "
                f"CPU-seconds of rendering, {self.wall_seconds:.1f} s in all")
        if self.check is not None:
            from lensfit.banks.check import check_line

            text += "\n" + check_line(self.check)
        return text


def resolve_table(lens: str, base: Path, generated: Path | None = None) -> Path:
    """The coefficient table a spec's ``lens`` names: a ``.table`` file or a folder
    (relative to the spec's folder), else a lens id or folder name of generated/ (an id
    shared by a lens and its variants, ``<folder>-uncoated``, names the lens)."""
    from lensfit.codegen.generate import GENERATED_DIR

    gen = generated or GENERATED_DIR
    as_path = (base / lens) if not Path(lens).is_absolute() else Path(lens)
    if lens.endswith(".table") or "/" in lens:
        folder_or_table = as_path
    else:
        names = sorted(p.name for p in gen.iterdir() if p.is_dir()) if gen.is_dir() else []
        hits = [n for n in names if n == lens] or [n for n in names if n.startswith(lens + "-")]
        lenses = [n for n in hits if not any(n.startswith(h + "-") for h in hits if h != n)]
        if len(lenses) != 1:
            why = ("no such lens" if not lenses
                   else f"names {len(lenses)} lenses ({', '.join(lenses)})")
            raise SpecError(f"key 'lens': {lens!r}: {why} in {gen}")
        folder_or_table = gen / lenses[0]
    if folder_or_table.is_dir():
        tables = sorted(folder_or_table.glob("lens*.table"))
        if len(tables) != 1:
            raise SpecError(f"key 'lens': {folder_or_table}: expected one lens*.table, found "
                            f"{len(tables)}")
        return tables[0].resolve()
    if not folder_or_table.is_file():
        raise SpecError(f"key 'lens': {lens!r}: {folder_or_table} is not a table file")
    return folder_or_table.resolve()


def _check_domain(spec: BankSpec, rt, lens, src: str) -> None:
    """Every node inside the lens's fitted domain, checked before any task starts."""
    info = rt.info(lens)
    g = spec.grid
    for i, lam in enumerate(g.wavelengths_nm):
        if not info["wavelength_min_nm"] - 1e-9 <= lam <= info["wavelength_max_nm"] + 1e-9:
            raise SpecError(f"{src}: key 'grid.wavelengths_nm[{i}]': {lam!r} nm is outside the "
                            f"lens's {info['wavelength_min_nm']:g}-{info['wavelength_max_nm']:g}"
                            " nm")
    for i, n in enumerate(g.f_numbers):
        if n < info["f_number_min"] * (1 - 1e-9):
            raise SpecError(f"{src}: key 'grid.f_numbers[{i}]': f/{n:g} is wider than the "
                            f"lens's f/{info['f_number_min']:.3g}")
    for i, z in enumerate(g.focus_offsets_mm):
        if not info["focus_offset_min_mm"] - 1e-9 <= z <= info["focus_offset_max_mm"] + 1e-9:
            raise SpecError(f"{src}: key 'grid.focus_offsets_mm[{i}]': {z!r} mm is outside the "
                            f"lens's {info['focus_offset_min_mm']:g} to "
                            f"{info['focus_offset_max_mm']:g} mm")
    for i, d in enumerate(g.distances_mm):
        if math.isfinite(d) and info["distance_min_mm"] > 0 and d < info["distance_min_mm"]:
            raise SpecError(f"{src}: key 'grid.distances_mm[{i}]': {d!r} mm is closer than the "
                            f"lens's {info['distance_min_mm']:g} mm")
    # The fitted field is an ellipse in direction cosines (lensrt_lens_info field_x,
    # field_y): every node (x, y), corners included, inside it, as lensrt checks a light
    fx, fy = info["field_x"], info["field_y"]
    for j, y in enumerate(g.field_y_deg):
        for i, x in enumerate(g.field_x_deg):
            cx, cy = rt.light_direction_cosines((x, y))
            if (cx / fx) ** 2 + (cy / fy) ** 2 > 1 + 1e-9:
                raise SpecError(
                    f"{src}: keys 'grid.field_x_deg[{i}]' = {x!r} and 'grid.field_y_deg[{j}]' "
                    f"= {y!r}: the node at ({x:g}, {y:g}) deg is outside the lens's fitted "
                    f"field, an ellipse of {math.degrees(math.asin(fx)):.4g} x "
                    f"{math.degrees(math.asin(fy)):.4g} deg (direction cosines {abs(cx):.4g}, "
                    f"{abs(cy):.4g}); every node of the grid must lie inside it")


MAX_PILOT_SLICES = 16  # (f-number, focus, distance) slices the up-front window check tries


def _check_window(spec: BankSpec, rt, lens, ghost_lenses: list[Any], src: str) -> None:
    """A fixed window (window.center_mm) that misses the light's image at every node is
    refused before anything is written. Per (f-number, focus offset, distance) slice, the
    node whose chief point (middle wavelength) is nearest to the window is rendered there
    at PILOT_RINGS (its ghosts too) and measured as a node is (node.window_miss); when
    every slice's nearest node misses, so does the bank. More slices than
    MAX_PILOT_SLICES, or a node whose image point lensrt cannot find, leave it to the
    nodes (each refused on its own)."""
    from lensrt_ctypes import LensrtError

    from lensfit.banks.node import (
        PILOT_RINGS,
        centred_power,
        create_render,
        node_coordinates,
        node_light,
        stem,
        window_holds,
        window_miss,
    )

    if spec.window.center_mm is None:
        return
    shape = spec.grid.shape
    if math.prod(shape[:3]) > MAX_PILOT_SLICES:
        return
    d = spec.to_dict()
    lams = list(spec.grid.wavelengths_nm)
    cx, cy = spec.window.center_mm
    misses = []
    for head in _indices(shape[:3]):
        best = None
        for tail in _indices(shape[3:]):
            c = node_coordinates(d, head + tail)
            try:
                x, y = rt.image_point(lens, node_light(c), lams[len(lams) // 2],
                                      c["focus_offset_mm"])
            except LensrtError:
                return
            if best is None or math.hypot(x - cx, y - cy) < best[0]:
                best = (math.hypot(x - cx, y - cy), head + tail, c)
        assert best is not None
        _, idx, c = best
        try:
            chief = [rt.image_point(lens, node_light(c), lam, c["focus_offset_mm"])
                     for lam in lams]
        except LensrtError:
            return
        if window_holds(d["window"], chief):
            return

        def power(table_lens, c: dict[str, float] = c) -> float:
            r = create_render(rt, table_lens, d, c, lams, (cx, cy))
            r.integrate(PILOT_RINGS, estimate=False)
            return float(r.image().astype("float64").sum())

        why = window_miss(d, c, chief, power(lens),
                          sum(power(g) for g in ghost_lenses) if ghost_lenses else None,
                          centred_power(rt, lens, d, c, lams, chief), stem(idx).split("/")[-1])
        if why is None:
            return
        misses.append(why)
    raise SpecError(f"{src}: key 'window.center_mm': the window misses the light's image at "
                    f"every node (at {PILOT_RINGS} rings, the node nearest to it of each "
                    f"f-number, focus offset and distance: {len(misses)} checked); first, "
                    + misses[0])


def ghost_tables(spec: BankSpec, table: Path, src: str) -> list[dict[str, Any]]:
    """A flare bank's ghosts: label, table and CRC-32 of each, from the lens folder's
    ghosts/ghosts.json (what `lensfit ghosts --fit` wrote)."""
    if not spec.flare.ghosts:
        return []
    index = table.parent / "ghosts" / "ghosts.json"
    if not index.is_file():
        raise SpecError(f"{src}: key 'flare.ghosts': the lens has no fitted ghosts ({index} "
                        "not found: `lensfit ghosts LENS --fit` writes them)")
    from lensfit.ghosts.tasks import read_ghost_index

    entries = {e["label"]: e for e in read_ghost_index(index)}
    wanted = sorted(entries) if spec.flare.ghosts == "kept" else list(spec.flare.ghosts)
    out = []
    for i, label in enumerate(wanted):
        if label not in entries:
            raise SpecError(f"{src}: key 'flare.ghosts[{i}]': {label!r} is not a fitted ghost "
                            f"of the lens (fitted: {', '.join(sorted(entries)) or 'none'})")
        e = entries[label]
        path = index.parent / f"ghost_{e['first']}_{e['second']}.table"
        out.append({"label": label, "table": str(path.resolve()),
                    "table_crc32": file_crc32(path)})
    try:  # one table under two labels would add its flare twice
        refuse_repeated_tables(g["table"] for g in out)
    except InputError as e:
        raise SpecError(f"{src}: key 'flare.ghosts': {index}: {e}") from None
    return out


def plan(spec: BankSpec, out: Path, table: Path, crc: int, lens_name: str, library: str,
         ghosts: list[dict[str, Any]], lensrt_version: str = "") -> list[dict[str, Any]]:
    """One job per node, in index order (f-number slowest, field x fastest). A node
    rendered by another lensrt version is not finished (the image's physics or unit may
    differ: 0.8.0 changed both)."""
    digest, spec_dict = spec.digest(), spec.to_dict()
    jobs = []
    for k, idx in enumerate(_indices(spec.grid.shape)):
        jobs.append({"k": k, "indices": idx, "stem": stem(idx), "out": str(out),
                     "table": str(table), "table_crc32": crc, "lens_name": lens_name,
                     "library": library, "spec": spec_dict, "digest": digest,
                     "ghosts": ghosts, "lensrt_version": lensrt_version})
    return jobs


def _indices(shape: tuple[int, ...]) -> list[tuple[int, ...]]:
    out: list[tuple[int, ...]] = [()]
    for n in shape:
        out = [i + (j,) for i in out for j in range(n)]
    return out


def _bank_record(out: Path, doc: dict[str, Any], restart: bool) -> None:
    """Record this bank in its folder. A folder that holds another bank (another lens,
    table or spec), or a damaged record, is refused, or with ``restart`` emptied of its
    nodes; the same bank resumes. Anything in nodes/ that is not a regular file or a
    folder (a FIFO where a node's EXR goes) is refused first, restart or not: lensfit
    never opens one nor replaces one."""
    path = out / BANK_RECORD
    nodes = out / "nodes"
    refuse_special(path)
    for name in (INDEX_NAME, SHEET_NAME):
        refuse_special(out / name)
    for p in sorted(nodes.iterdir()) if nodes.is_dir() else []:
        if not p.is_dir() or p.is_symlink():
            refuse_special(p)
    if path.exists():
        hint = "run with --restart to discard it and the bank's nodes, or remove the folder"
        try:
            old = load_checked_json(path, hint)
        except InputError as e:
            if not restart:
                raise InputError(str(e) if hint in str(e) else f"{e}; {hint}") from None
            old = {}  # damaged: discarded with the nodes
        changed = [k for k in ("lens", "table_crc32", "ghost_tables", "spec_digest")
                   if old.get(k) != doc[k]]
        if not changed:
            return
        if not restart:
            key = changed[0]
            raise InputError(
                f"{path}: this folder holds a bank of another {key.split('_')[0]} "
                f"({key} {old.get(key)!r}, now {doc[key]!r}); run with --restart to "
                "discard its nodes, or give another folder")
        for p in sorted(nodes.glob("*")) if nodes.is_dir() else []:
            if p.is_file() and p.suffix in (".exr", ".json", ".phasors"):
                p.unlink()
        for name in (INDEX_NAME, SHEET_NAME, CHECK_NAME):
            (out / name).unlink(missing_ok=True)
    write_atomic(path, checked_json_text(doc))


def run_bank(spec_path: str | Path, out: str | Path, *, scheduler: str | None = None,
             workers: int | None = None, restart: bool = False, progress: bool = True,
             sheet: bool = True, generated: Path | None = None, verbose: bool = False,
             say: Callable[[str], None] | None = None, check: bool = True) -> Summary:
    """Render every unfinished node of a bank and write its index (and contact sheet).
    ``verbose``: the Dask cluster's logs at INFO; ``say``: lines for the user (the
    dashboard's address); ``check``: measure the reader between nodes (check.py)."""
    from lensrt_ctypes import LIBRARY, Lensrt, LensrtError

    check_workers(workers)  # before anything is loaded or written
    check_scheduler(scheduler)
    t0 = time.perf_counter()
    spec = load_spec(spec_path)
    src = spec.source_file
    try:
        table = resolve_table(spec.lens, Path(spec_path).resolve().parent, generated)
    except SpecError as e:
        raise SpecError(f"{src}: {e}") from None
    crc = file_crc32(table)

    # Load the lens once here: a damaged table or a grid outside its domain is refused
    # before any task starts
    library = str(Path(os.environ.get("LENSRT_LIBRARY") or LIBRARY).resolve())
    try:
        rt = Lensrt(library, threads=1)
        lens = rt.load(table)
    except (FileNotFoundError, LensrtError) as e:
        raise InputError(f"{src}: lens {spec.lens!r}: {e}") from None
    _check_domain(spec, rt, lens, src)
    ghosts = ghost_tables(spec, table, src)
    ghost_lenses = []
    for g in ghosts:  # every ghost table loads (its checksum, its format) before any task
        try:
            ghost_lenses.append(rt.load(g["table"]))
        except LensrtError as e:
            raise InputError(f"{src}: key 'flare.ghosts': ghost {g['label']}: {e}") from None
    _check_window(spec, rt, lens, ghost_lenses, src)
    # The lens's name in the index: its generated folder's (a symbol: no spaces)
    lens_name = table.parent.name if table.stem.startswith("lens") else table.stem
    if not re.fullmatch(r"[A-Za-z0-9._+-]{1,128}", lens_name):
        raise InputError(f"{table}: the lens name {lens_name!r} (its folder's) cannot be "
                         "written in a bank index: rename the folder to [A-Za-z0-9._+-]")

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: not a folder")
    make_folder(out / "nodes", "bank folder")
    _bank_record(out, {"version": 1, "name": spec.name, "lens": lens_name,
                       "table": str(table), "table_crc32": f"{crc:08x}",
                       "ghost_tables": {g["label"]: f"{g['table_crc32']:08x}" for g in ghosts},
                       "spec_digest": spec.digest(), "spec": spec.to_dict()}, restart)

    jobs = plan(spec, out.resolve(), table, crc, lens_name, library, ghosts, rt.version())
    finished = {j["k"]: finished_record(j) for j in jobs}
    pending = [j for j in jobs if finished[j["k"]] is None]
    keys = [task_key(j) for j in pending]
    done = run_tasks(render_node, pending, keys, scheduler=scheduler, workers=workers,
                     progress=progress, label=f"bank {spec.name}", verbose=verbose, say=say)

    # Every node finished: the index, from the records as written (checked above, or
    # returned by the task that wrote them)
    finished.update({r["k"]: r for r in done})
    records = []
    for j in jobs:
        rec = finished[j["k"]]
        if rec is None:
            raise OutputError(f"{out / j['stem']}.json: node {j['k']} did not finish")
        records.append(rec)
    index = write_atomic(out / INDEX_NAME, index_text(spec, lens_name, crc, records))
    if sheet:
        from lensfit.banks.sheet import contact_sheet

        write_atomic(out / SHEET_NAME, contact_sheet(spec, out, records))
    # What the bank is worth between its nodes: the reader against direct renders
    checked = None
    if check and spec.window.center_mm is None:
        from lensfit.banks.check import check_bank

        checked = check_bank(spec, index, library, table)
        write_atomic(out / CHECK_NAME, checked_json_text(checked))
    rendered = [r for r in done if not r.get("skipped")]
    errors = [r["error_estimate"] for r in records]
    return Summary(nodes=len(records), rendered=len(rendered),
                   skipped=len(records) - len(rendered),
                   worst_error=max(errors) if min(errors) >= 0 else -1.0,
                   # each task's CPU time (its thread's, or its process's with lensrt
                   # threads: node.py)
                   cpu_seconds=sum(r.get("cpu_seconds", 0.0) for r in rendered),
                   wall_seconds=time.perf_counter() - t0, index=index, check=checked)
