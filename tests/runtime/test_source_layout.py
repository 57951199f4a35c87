"""The layout of the runtime's sources (runtime/src): no file over 800 lines, and no cycle
among its translation units.

A translation unit A depends on B when A uses a function or object that B defines: an
undefined symbol of A's object file that B's object file defines (nm). The object files
are made here, each .c compiled alone with `cc -c -O0` into a temporary folder (the
include paths and defines of runtime/CMakeLists.txt), in two configurations: every
optional part this machine has headers for (OpenEXR, GL, OpenMP), and none of them (the
minimal build: only the units with a conditional on those parts, whose symbols may
differ); the graph is the union of both. The graph must be a DAG; a cycle is
printed edge by edge with the symbols that make each edge. Skipped (with the reason)
only when there is no C compiler or no nm.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "runtime" / "src"
INCLUDE = ROOT / "runtime" / "include"
MAX_LINES = 800


@pytest.fixture(autouse=True)
def _needs_lensrt() -> None:
    """These checks read the sources only: not skipped without a built library (this
    overrides conftest.py's fixture of the same name)."""


def _sources(suffixes: tuple[str, ...]) -> list[Path]:
    return sorted(p for p in SRC.rglob("*") if p.suffix in suffixes and p.is_file())


def test_no_source_over_800_lines() -> None:
    long = []
    for path in _sources((".c", ".h")):
        with open(path, "rb") as f:
            n = sum(1 for _ in f)
        if n > MAX_LINES:
            long.append(f"{path.relative_to(ROOT)}: {n} lines")
    assert not long, (f"runtime sources over {MAX_LINES} lines (split them by concern):\n"
                      + "\n".join(long))


def _tool(name: str) -> str | None:
    return shutil.which(os.environ.get(name.upper(), name))


def _configurations(cc: str) -> dict[str, list[str]]:
    """The defines and flags of the two configurations compiled here."""
    base = ["-std=c99", "-O0", "-w", "-DLENSRT_BUILDING", "-D_POSIX_C_SOURCE=200809L",
            f"-I{INCLUDE}", f"-I{SRC}"]
    full = list(base)
    for d in ("/usr/include/OpenEXR", "/usr/local/include/OpenEXR"):
        if Path(d, "openexr.h").exists():
            full += ["-DLENSRT_EXR=1", f"-isystem{d}"]
            break
    if any(Path(d, "EGL/egl.h").exists() and Path(d, "GL/glcorearb.h").exists()
           for d in ("/usr/include", "/usr/local/include")):
        full.append("-DLENSRT_GL=1")
    probe = subprocess.run([cc, "-fopenmp", "-x", "c", "-fsyntax-only", "-"], input="int x;\n",
                           capture_output=True, text=True)
    if probe.returncode == 0:
        full += ["-fopenmp", "-DLENSRT_OPENMP=1"]
    return {"full": full, "minimal": base}


OPTIONAL = re.compile(r"^\s*#\s*(if|ifdef|ifndef|elif)\b.*\b(LENSRT_EXR|LENSRT_GL|LENSRT_OPENMP)\b",
                      re.M)


def _optional(unit: Path) -> bool:
    """Whether a unit's symbols may differ without the optional parts: it, or any header
    of runtime/src (then every unit), has a conditional on them. The others are compiled
    once (the full configuration)."""
    if any(OPTIONAL.search(h.read_text(errors="replace")) for h in _sources((".h",))):
        return True
    return bool(OPTIONAL.search(unit.read_text(errors="replace")))


def _symbols(nm: str, obj: Path) -> tuple[set[str], set[str]]:
    """(defined, undefined) external symbols of an object file."""
    out = subprocess.run([nm, "-P", "-g", str(obj)], capture_output=True, text=True,
                         check=True).stdout
    defined, undefined = set(), set()
    for line in out.splitlines():
        parts = line.split()
        if len(parts) < 2:
            continue
        (undefined if parts[1] in ("U", "w", "v") else defined).add(parts[0])
    return defined, undefined


def dependency_graph() -> dict[str, dict[str, set[str]]]:
    """{A: {B: symbols of B that A uses}} over runtime/src's .c files (paths relative to
    runtime/src), the union over the configurations."""
    cc, nm = _tool("cc"), _tool("nm")
    if not cc or not nm:
        pytest.skip(f"the translation-unit graph needs a C compiler and nm (cc: {cc}, nm: {nm})")
    units = _sources((".c",))
    graph: dict[str, dict[str, set[str]]] = {u.relative_to(SRC).as_posix(): {} for u in units}
    full_table: dict[str, tuple[set[str], set[str]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for config, flags in _configurations(cc).items():
            def compile_one(unit: Path, config: str = config,
                            flags: list[str] = flags) -> tuple[str, Path]:
                name = unit.relative_to(SRC).as_posix()
                obj = Path(tmp, config, name + ".o")
                obj.parent.mkdir(parents=True, exist_ok=True)
                res = subprocess.run([cc, *flags, "-c", str(unit), "-o", str(obj)],
                                     capture_output=True, text=True)
                assert res.returncode == 0, f"{name} ({config}) does not compile:\n{res.stderr}"
                return name, obj

            todo = units if config == "full" else [u for u in units if _optional(u)]
            with ThreadPoolExecutor(max_workers=os.cpu_count() or 2) as pool:
                objects = list(pool.map(compile_one, todo))
            # The units not compiled again have the full configuration's symbols
            table = {**full_table, **{name: _symbols(nm, obj) for name, obj in objects}}
            if config == "full":
                full_table = dict(table)
            owner: dict[str, str] = {}
            for name, (defined, _) in table.items():
                for sym in defined:
                    owner.setdefault(sym, name)
            for name, (_, undefined) in table.items():
                for sym in undefined:
                    dep = owner.get(sym)
                    if dep and dep != name:
                        graph[name].setdefault(dep, set()).add(sym)
    return graph


def strongly_connected(graph: dict[str, dict[str, set[str]]]) -> list[list[str]]:
    """The strongly connected components of more than one unit (Tarjan): the units that
    depend on each other, directly or through others."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []
    counter = [0]

    def strongconnect(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                strongconnect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                components.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strongconnect(v)
    return components


def find_cycles(graph: dict[str, dict[str, set[str]]]) -> list[list[str]]:
    """Cycles (lists of units, the first repeated at the end) of each strongly connected
    component: every two-unit cycle in it, then the same for what stays strongly connected
    without those pairs' edges; a component without such pairs gives a shortest cycle
    through its first unit."""
    cycles = []
    for comp in strongly_connected(graph):
        members = set(comp)
        pairs = [[a, b, a] for a in comp for b in comp if a < b and b in graph[a] and a in graph[b]]
        cycles.extend(pairs)
        if pairs:
            cut = {(a, b) for a, b, _ in pairs} | {(b, a) for a, b, _ in pairs}
            rest = {a: {b: graph[a][b] for b in graph[a] if b in members and (a, b) not in cut}
                    for a in comp}
            cycles.extend(find_cycles(rest))
            continue
        # A shortest cycle through the component's first unit (breadth first)
        start = comp[0]
        prev: dict[str, str] = {}
        frontier, seen, found = [start], {start}, None
        while frontier and not found:
            nxt = []
            for v in frontier:
                for w in sorted(graph[v]):
                    if w not in members:
                        continue
                    if w == start:
                        found = v
                        break
                    if w not in seen:
                        seen.add(w)
                        prev[w] = v
                        nxt.append(w)
                if found:
                    break
            frontier = nxt
        path = [found]
        while path[-1] != start:
            path.append(prev[path[-1]])
        cycles.append([*reversed(path), start])
    return cycles


def describe(graph: dict[str, dict[str, set[str]]], cycle: list[str]) -> str:
    lines = [" -> ".join(cycle)]
    for a, b in zip(cycle, cycle[1:], strict=False):
        lines.append(f"    {a} uses {b}: {', '.join(sorted(graph[a][b]))}")
    return "\n".join(lines)


def test_translation_units_form_a_dag() -> None:
    graph = dependency_graph()
    edges = sum(len(v) for v in graph.values())
    print(f"{len(graph)} translation units, {edges} dependencies")
    cycles = find_cycles(graph)
    report = "\n".join([*(f"units in one cycle: {', '.join(c)}" for c in strongly_connected(graph)),
                        *(describe(graph, c) for c in cycles)])
    if report:
        print(report)
    assert not cycles, f"dependency cycles among runtime/src's translation units:\n{report}"
