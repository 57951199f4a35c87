"""A griffe extension for the Python API pages: square brackets in docstrings are text.

The docstrings are reST-ish prose rendered as Markdown (docs/about.md). In Markdown,
`w[c][l]` (an index, lensfit.image.reference) is a reference link `[c][l]`, which
mkdocs-autorefs cannot resolve, and strict mode fails. This extension escapes `[` and `]`
in every docstring outside code spans and indented (code) blocks, so indices and
intervals print as written. Named in mkdocs.yml (mkdocstrings python handler, extensions).
"""
from __future__ import annotations

import re
from typing import Any

import griffe

_CODE = re.compile(r"(``.*?``|`[^`\n]*`)", re.S)


def escape(text: str) -> str:
    out = []
    for line in text.split("\n"):
        if line.startswith("    "):             # an indented block: code in Markdown
            out.append(line)
            continue
        parts = _CODE.split(line)
        for k in range(0, len(parts), 2):
            parts[k] = parts[k].replace("[", "\\[").replace("]", "\\]")
        out.append("".join(parts))
    return "\n".join(out)


class PlainBrackets(griffe.Extension):
    def on_object(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = escape(obj.docstring.value)
