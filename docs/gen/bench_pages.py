"""Benchmark pages from the committed snapshots of `make bench`'s summaries.

Run by mkdocs-gen-files (mkdocs.yml). Each file of docs/benchmarks/snapshots/ (copied there
by docs/gen/collect_bench.py, the last step of `make bench`) becomes a page
benchmarks/<name>.md: its header (measured, collected, commit, machine) as a table, then
the summary itself: a Markdown summary as written (headings moved one level down; links
to its figures and JSON, which are not copied, shown as plain text), a text summary as a
preformatted block. benchmarks/snapshots.md lists them. The narrative page
(docs/benchmarks/index.md) links to these pages instead of repeating their tables.
"""
from __future__ import annotations

import re
from pathlib import Path

import mkdocs_gen_files

ROOT = Path(__file__).resolve().parents[2]
SNAPSHOTS = ROOT / "docs" / "benchmarks" / "snapshots"
SEPARATOR = "----- end of snapshot header -----"


def split(text: str) -> tuple[dict[str, str], str]:
    if SEPARATOR not in text:
        return {}, text
    head, body = text.split(SEPARATOR + "\n", 1)
    fields = {}
    for line in head.strip().splitlines():
        key, _, value = line.partition(":")
        fields[key.strip()] = value.strip()
    return fields, body


def neutralise_links(md: str) -> str:
    """Relative links and images of a bench summary point at build/bench/ files that are
    not in the docs: keep their text and name the file."""
    md = re.sub(r"!\[([^\]]*)\]\(([^)\s]+)\)",
                lambda m: m.group(0) if "://" in m.group(2)
                else "*(figure `build/bench/" + m.group(2) + "`"
                + (": " + m.group(1) if m.group(1) else "") + ")*",
                md)
    md = re.sub(r"(?<!!)\[([^\]]+)\]\(([^)\s]+)\)",
                lambda m: m.group(0) if "://" in m.group(2) or m.group(2).startswith("#")
                else f"{m.group(1)} (`build/bench/{m.group(2)}`)", md)
    return md


def demote(md: str) -> str:
    out, fenced = [], False
    for line in md.splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
        if not fenced and re.match(r"#{1,5} ", line):
            line = "#" + line
        out.append(line)
    return "\n".join(out)


rows = []
for path in sorted(SNAPSHOTS.glob("*")) if SNAPSHOTS.is_dir() else []:
    if path.suffix not in (".md", ".txt"):
        continue
    fields, body = split(path.read_text(encoding="utf-8"))
    stem = path.name.replace(".", "-")
    page = f"benchmarks/{stem}.md"
    lines = [f"# `{path.name}` (from `make bench`)", "",
             "A snapshot of `make bench`'s output, copied by `docs/gen/collect_bench.py`; "
             "regenerate with `make bench` and commit `docs/benchmarks/snapshots/`. "
             "Narrative and context: [Benchmarks](index.md).", "",
             "| | |", "|---|---|"]
    lines += [f"| {k} | {v.replace('|', '/')} |" for k, v in fields.items()]
    lines.append("")
    if path.suffix == ".md":
        lines.append(demote(neutralise_links(body)))
    else:
        lines += ["```text", body.rstrip(), "```"]
    with mkdocs_gen_files.open(page, "w") as f:
        f.write("\n".join(lines) + "\n")
    mkdocs_gen_files.set_edit_path(page, f"benchmarks/snapshots/{path.name}")
    rows.append(f"| [`{path.name}`]({stem}.md) | {fields.get('measured', '?')} | "
                f"{fields.get('commit', '?')} |")

with mkdocs_gen_files.open("benchmarks/snapshots.md", "w") as f:
    f.write("# Benchmark snapshots\n\nThe summaries `make bench` wrote, as last collected "
            "into `docs/benchmarks/snapshots/` (`docs/gen/collect_bench.py`, the last step "
            "of `make bench`). The narrative: [Benchmarks](index.md).\n\n"
            "| snapshot | measured | commit |\n|---|---|---|\n" + "\n".join(rows) + "\n")
