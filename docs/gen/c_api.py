"""The C API reference page (reference/c-api.md), generated from runtime/include/lensrt.h.

Run by mkdocs-gen-files at build time (mkdocs.yml). mkdocstrings-c 0.1.1 cannot read
lensrt.h (its comment scanner stops at the header's first block comment, and it takes a
declaration's comment only from the line right above it), so this script reads the header
itself: the header's own section rules (`/* ---- name ----- */`) become the page's
sections, and every declaration (function, struct, enum, typedef, macro) becomes an entry
with its code as written (field comments included) and the comment block right above it
as its text. Consecutive declarations with no comment or blank line between them share
one entry (e.g. lensrt_render_save, _load, _merge).

The build fails (an exception, which aborts `mkdocs build`) when a function declared with
LENSRT_API in lensrt.h has no entry: the check reads the header with a second, independent
pattern, so a declaration the parser missed cannot pass unnoticed.

Also runnable alone: `python docs/gen/c_api.py [lensrt.h]` prints the page.
"""
from __future__ import annotations

import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
HEADER = ROOT / "runtime" / "include" / "lensrt.h"
PAGE = "reference/c-api.md"

SECTION = re.compile(r"^/\*\s*-{3,}\s*(.*?)\s*-{3,}\s*\*/\s*$")
SKIP_DIRECTIVES = re.compile(
    r"^#\s*(ifndef LENSRT_H|define LENSRT_H|include\b|endif\s*/\*\s*LENSRT_H)")


@dataclass
class Entry:
    names: list[str]
    kind: str
    code: list[str]
    doc: str = ""
    anchor: str = ""


@dataclass
class Section:
    title: str
    intro: list[str] = field(default_factory=list)
    entries: list[Entry] = field(default_factory=list)


def comment_text(lines: list[str]) -> str:
    """A block comment's text: delimiters and the leading ` * ` of each line removed."""
    text = "\n".join(lines).strip()
    text = re.sub(r"^/\*+", "", text)
    text = re.sub(r"\*+/$", "", text)
    out = []
    for ln in text.split("\n"):
        ln = re.sub(r"^\s*\* ?", "", ln) if re.match(r"^\s*\*(\s|$)", ln) else ln
        out.append(ln.rstrip())
    while out and not out[0].strip():
        out.pop(0)
    while out and not out[-1].strip():
        out.pop()
    # dedent by the common indentation of the non-empty lines (first line excepted:
    # it follows the "/*" directly)
    rest = [ln for ln in out[1:] if ln.strip()]
    pad = min((len(ln) - len(ln.lstrip()) for ln in rest), default=0)
    return "\n".join([out[0].strip()] + [ln[pad:] for ln in out[1:]]) if out else ""


def strip_comments(code: str) -> str:
    return re.sub(r"/\*.*?\*/", " ", code, flags=re.S)


def names_of(code: str) -> tuple[list[str], str]:
    """The names a declaration introduces and its kind."""
    bare = strip_comments(code)
    m = re.match(r"\s*#\s*define\s+(\w+)", bare)
    if m:
        return [m.group(1)], "macro"
    if re.search(r"\bLENSRT_API\b", bare):
        m = re.search(r"\b(lensrt_\w+)\s*\(", bare)
        if not m:
            raise RuntimeError(f"lensrt.h: a LENSRT_API declaration without a name: {code!r}")
        return [m.group(1)], "function"
    flat = " ".join(bare.split())
    m = re.match(r"typedef\s+[^{]*?\(\s*\*\s*(\w+)\s*\)\s*\(", flat)
    if m:
        return [m.group(1)], "function pointer type"
    m = re.match(r"typedef\s+(struct|enum|union)\s+(\w+)?\s*\{.*\}\s*(\w+)\s*;$", flat)
    if m:
        return [m.group(3)], m.group(1)
    m = re.match(r"(struct|enum|union)\s+(\w+)\s*\{.*\}\s*;$", flat)
    if m:
        return [m.group(2)], m.group(1)
    m = re.match(r"typedef\s+.*?(\w+)\s*;$", flat)
    if m:
        return [m.group(1)], "type"
    m = re.match(r"(struct|enum)\s+(\w+)\s*;$", flat)
    if m:
        return [m.group(2)], "declaration"
    raise RuntimeError(f"lensrt.h: a declaration this script cannot name: {code!r}")


def parse(text: str) -> list[Section]:
    lines = text.split("\n")
    sections = [Section("Overview")]
    pending: list[str] = []        # comment blocks waiting for their declaration
    last: Entry | None = None      # the previous entry, while nothing separates them
    i, n = 0, len(lines)
    while i < n:
        line = lines[i]
        s = line.strip()
        m = SECTION.match(s)
        if m:
            sections[-1].intro.extend(pending)
            pending, last = [], None
            sections.append(Section(m.group(1)))
            i += 1
            continue
        if not s:
            if pending:
                # a comment followed by a blank line speaks for the section, not for
                # one declaration
                sections[-1].intro.extend(pending)
                pending = []
            last = None
            i += 1
            continue
        if s.startswith("/*"):
            block = [line]
            while "*/" not in lines[i] and i + 1 < n:
                i += 1
                block.append(lines[i])
            pending.append(comment_text(block))
            last = None
            i += 1
            continue
        if s.startswith("#"):
            block = [line]
            while block[-1].rstrip().endswith("\\") and i + 1 < n:
                i += 1
                block.append(lines[i])
            i += 1
            if SKIP_DIRECTIVES.match(s):
                continue
            if re.match(r"#\s*ifdef\s+__cplusplus", s):       # extern "C" guards
                while i < n and not lines[i].strip().startswith("#endif"):
                    i += 1
                i += 1
                continue
            if re.match(r"#\s*if", s):                       # a conditional block: one entry
                depth = 1
                while i < n and depth:
                    t = lines[i].strip()
                    if re.match(r"#\s*if", t):
                        depth += 1
                    elif re.match(r"#\s*endif", t):
                        depth -= 1
                    block.append(lines[i])
                    i += 1
                m = re.search(r"#\s*define\s+(\w+)", "\n".join(block))
                entry = Entry([m.group(1)] if m else ["(conditional)"], "macro", block)
            elif re.match(r"#\s*define", s):
                # a comment continued on the next lines belongs to this define
                while "/*" in block[-1] and "*/" not in block[-1] and i < n:
                    block.append(lines[i])
                    i += 1
                names, kind = names_of("\n".join(block))
                entry = Entry(names, kind, block)
            else:
                raise RuntimeError(f"lensrt.h line {i}: an unexpected directive {s!r}")
        else:
            block = []
            depth, in_comment, done = 0, False, False
            while i < n and not done:
                ln = lines[i]
                block.append(ln)
                j = 0
                while j < len(ln):
                    two = ln[j:j + 2]
                    if in_comment:
                        if two == "*/":
                            in_comment, j = False, j + 2
                            continue
                    elif two == "/*":
                        in_comment, j = True, j + 2
                        continue
                    elif ln[j] in "{(":
                        depth += 1
                    elif ln[j] in "})":
                        depth -= 1
                    elif ln[j] == ";" and depth == 0:
                        done = True
                    j += 1
                i += 1
            # a trailing comment opened on the last line and continued below
            while in_comment and i < n:
                block.append(lines[i])
                in_comment = "*/" not in lines[i]
                i += 1
            names, kind = names_of("\n".join(block))
            entry = Entry(names, kind, block)
        if last is not None and not pending and (
                entry.kind == last.kind or entry.names[0].endswith("_INIT")):
            # no comment and no blank line between: the same entry (its INIT macro, or
            # sibling declarations under one comment)
            last.names += entry.names
            last.code += entry.code
            continue
        entry.doc = "\n\n".join(pending)
        pending = []
        sections[-1].entries.append(entry)
        last = entry
    sections[-1].intro.extend(pending)
    return sections


def md_escape(text: str) -> str:
    """Prose from a C comment as Markdown: HTML and emphasis characters escaped outside
    `code spans`."""
    parts = re.split(r"(`[^`\n]*`)", text)
    for k in range(0, len(parts), 2):
        p = parts[k]
        p = p.replace("\\", "\\\\").replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
        p = re.sub(r"([*_\[\]])", r"\\\1", p)
        parts[k] = p
    return "".join(parts)


def prose(text: str) -> str:
    """Paragraphs of a comment: indented or tabular lines kept as preformatted text."""
    out = []
    for para in re.split(r"\n\s*\n", text.strip()):
        lines = para.split("\n")
        tabular = any(re.match(r"^\s{2,}\S", ln) or re.search(r"\S\s{3,}\S", ln) for ln in lines)
        if tabular:
            out.append("```text\n" + para + "\n```")
        else:
            out.append(md_escape(" ".join(ln.strip() for ln in lines)))
    return "\n\n".join(out)


def render(sections: list[Section], header_rel: str) -> str:
    out = [
        "# C API reference (`lensrt.h`)",
        "",
        f"Generated at build time from `{header_rel}` by `docs/gen/c_api.py`: every "
        "declaration of the header with the comment above it, in the header's own "
        "sections and order. The header is the contract; this page is a view of it. "
        "How to use the API: [Embedding in C](../embedding.md).",
        "",
    ]
    used: set[str] = set()
    for sec in sections:
        for e in sec.entries:
            e.anchor, k = e.names[0], 2
            while e.anchor in used:          # a forward typedef and its struct
                e.anchor, k = f"{e.names[0]}-{k}", k + 1
            used.add(e.anchor)
    toc = []
    for sec in sections[1:]:
        funcs = [(nm, e.anchor) for e in sec.entries for nm in e.names if e.kind == "function"]
        toc.append(f"* [{sec.title}](#{slug(sec.title)}): " + ", ".join(
            f"[`{nm}`](#{anchor})" for nm, anchor in funcs))
    out += ["Sections and their functions:", ""] + toc + [""]
    for k, sec in enumerate(sections):
        if k == 0:
            out += ["## Overview {#overview}", ""]
        else:
            out += [f"## {sec.title} {{#{slug(sec.title)}}}", ""]
        for block in sec.intro:
            out += [prose(block), ""]
        for e in sec.entries:
            title = ", ".join(f"`{nm}`" for nm in e.names)
            out += [f"### {title} {{#{e.anchor}}}", "", f"*{e.kind}*", "",
                    "```c", "\n".join(e.code).rstrip(), "```", ""]
            if e.doc:
                out += [prose(e.doc), ""]
    return "\n".join(out)


def slug(title: str) -> str:
    return "sec-" + re.sub(r"[^a-z0-9]+", "-", title.lower()).strip("-")


def declared_functions(text: str) -> set[str]:
    """Every function declared with LENSRT_API, by a pattern independent of parse()."""
    bare = strip_comments(text)
    return set(re.findall(r"\bLENSRT_API\s+[^;{}()]*?\b(lensrt_\w+)\s*\(", bare))


def check(sections: list[Section], text: str, page: str) -> None:
    documented = {nm for s in sections for e in s.entries for nm in e.names}
    missing = sorted(nm for nm in declared_functions(text)
                     if nm not in documented or f"`{nm}`" not in page)
    if missing:
        raise RuntimeError("docs/gen/c_api.py: functions of lensrt.h missing from "
                           f"{PAGE}: {', '.join(missing)}")
    if not declared_functions(text):
        raise RuntimeError("docs/gen/c_api.py: no LENSRT_API function found in lensrt.h")


def build(header: Path = HEADER) -> str:
    text = header.read_text(encoding="utf-8")
    sections = parse(text)
    try:
        rel = header.relative_to(ROOT).as_posix()
    except ValueError:
        rel = header.name
    page = render(sections, rel)
    check(sections, text, page)
    return page


if __name__ == "__main__":          # run alone; mkdocs-gen-files runs it as "<run_path>"
    sys.stdout.write(build(Path(sys.argv[1]) if len(sys.argv) > 1 else HEADER))
else:
    import mkdocs_gen_files

    page = build()
    with mkdocs_gen_files.open(PAGE, "w") as f:
        f.write(page)
    mkdocs_gen_files.set_edit_path(PAGE, "../runtime/include/lensrt.h")
