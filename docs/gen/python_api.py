"""The Python API reference (reference/python/*.md), generated from the code at build time.

Run by mkdocs-gen-files (mkdocs.yml). The modules are discovered, never listed: for each
top-level name in TOPS the package's folder is walked with pkgutil (iter_modules,
recursively: the same walk as pkgutil.walk_packages, without importing anything), so a
module that moves or a package that is added needs no edit here or in mkdocs.yml. One page
per package: the package itself and its direct modules as `::: module` blocks, which
mkdocstrings renders from the source (griffe, static analysis); a top-level module
(lensrt_ctypes, lensrt_exr) is a page of its own. reference/python/index.md lists them.
"""
from __future__ import annotations

import importlib.util
import pkgutil
from pathlib import Path

import mkdocs_gen_files

# The import names documented: lensfit (fit/), lensrt's binding modules (runtime/python/;
# the package `lensrt` only re-exports these two). mkdocs.yml's handler paths point there.
TOPS = ["lensfit", "lensrt_ctypes", "lensrt_exr"]
ROOT = Path(__file__).resolve().parents[2]
SEARCH = [ROOT / "fit", ROOT / "runtime" / "python"]


def locate(name: str) -> Path:
    for base in SEARCH:
        for cand in (base / name / "__init__.py", base / f"{name}.py"):
            if cand.is_file():
                return cand
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None:
        raise RuntimeError(f"docs/gen/python_api.py: cannot find {name}")
    return Path(spec.origin)


def walk(pkg: str, folder: Path, out: dict[str, list[str]]) -> None:
    """out[package] = its direct public modules; recurse into subpackages."""
    out[pkg] = []
    for info in sorted(pkgutil.iter_modules([str(folder)]), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        full = f"{pkg}.{info.name}"
        if info.ispkg:
            walk(full, folder / info.name, out)
        else:
            out[pkg].append(full)


def first_line(path: Path) -> str:
    import ast
    try:
        doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    except SyntaxError:
        return ""
    line = doc.strip().split("\n\n")[0].replace("\n", " ")
    return line.replace("``", "`")


packages: dict[str, list[str]] = {}
single: list[str] = []
for top in TOPS:
    origin = locate(top)
    if origin.name == "__init__.py":
        walk(top, origin.parent, packages)
    else:
        single.append(top)

index = ["# Python API reference", "",
         "Generated at build time from the code (`docs/gen/python_api.py`: the packages are "
         "walked with pkgutil, so renamed or new modules appear without an edit). One page "
         "per package with its modules. Docstrings are shown as written "
         "(reST-ish prose rendered as Markdown, no section parsing: "
         "[About these docs](../../about.md)).",
         "", "| page | modules | what it is |", "|---|---:|---|"]
for pkg, mods in sorted(packages.items()):
    page = f"reference/python/{pkg}.md"
    init = locate(pkg.split(".")[0]).parent.joinpath(*pkg.split(".")[1:], "__init__.py")
    with mkdocs_gen_files.open(page, "w") as f:
        f.write(f"# `{pkg}`\n\n")
        sub = sorted(p for p in packages if p.rsplit(".", 1)[0] == pkg and p != pkg)
        if sub:
            f.write("Subpackages: " + ", ".join(f"[`{p}`]({p}.md)" for p in sub) + "\n\n")
        f.write(f"::: {pkg}\n    options:\n      members: false\n      heading_level: 2\n\n")
        for mod in mods:
            f.write(f"::: {mod}\n\n")
    index.append(f"| [`{pkg}`]({pkg}.md) | {len(mods)} | {first_line(init)} |")
for mod in single:
    page = f"reference/python/{mod}.md"
    with mkdocs_gen_files.open(page, "w") as f:
        f.write(f"# `{mod}`\n\n::: {mod}\n\n")
    index.append(f"| [`{mod}`]({mod}.md) | 1 | {first_line(locate(mod))} |")
with mkdocs_gen_files.open("reference/python/index.md", "w") as f:
    f.write("\n".join(index) + "\n")
