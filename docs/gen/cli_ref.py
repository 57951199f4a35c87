"""The command-line reference (reference/cli.md), generated at build time.

Run by mkdocs-gen-files (mkdocs.yml). `lensfit`: the parser from lensfit.cli.build_parser(),
its --help and every subcommand's (recursively), formatted at 100 columns. The C tools
(lensrt-psf, lensrt-bench): their --help when `make runtime` has built them
(build/runtime/runtime/), else one line saying so.
"""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import mkdocs_gen_files

os.environ["COLUMNS"] = "100"          # argparse's width, so the page does not depend on a terminal
ROOT = Path(__file__).resolve().parents[2]
TOOLS = ROOT / "build" / "runtime" / "runtime"

from lensfit.cli import build_parser  # noqa: E402  (after COLUMNS)
from lensfit.cli.parser import subcommands  # noqa: E402


def fence(text: str) -> str:
    return "```text\n" + text.rstrip() + "\n```\n"


parser = build_parser()
parser.prog = "lensfit"
subs = list(subcommands(parser))
out = ["# Command-line reference\n",
       "Generated at build time (`docs/gen/cli_ref.py`) from the code: `lensfit`'s argparse "
       "parser (`lensfit.cli.build_parser()`) and the C tools' own `--help`. What the "
       "commands are for: [lensfit commands](../cli.md), [Render a PSF](../psf.md).\n",
       "lensfit subcommands: " + ", ".join(f"[`{s}`](#lensfit-{s})" for s in subs) + "\n"]
out.append("## `lensfit` {#lensfit}\n\n" + fence(parser.format_help()))
for name, sub in subcommands(parser).items():
    sub.prog = f"lensfit {name}"
    out.append(f"### `lensfit {name}` {{#lensfit-{name}}}\n\n" + fence(sub.format_help()))
    for name2, sub2 in subcommands(sub).items():
        sub2.prog = f"lensfit {name} {name2}"
        out.append(f"#### `lensfit {name} {name2}`\n\n" + fence(sub2.format_help()))

out.append("## The C tools {#c-tools}\n")
for tool in ("lensrt-psf", "lensrt-bench"):
    exe = TOOLS / tool
    out.append(f"### `{tool}` {{#{tool}}}\n")
    if exe.is_file() and os.access(exe, os.X_OK):
        run = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=30)
        text = run.stdout or run.stderr
        out.append(fence(text))
    else:
        out.append(f"`{tool}` was not built when these pages were (`make runtime` builds it "
                   f"into `build/runtime/runtime/`); `{tool} --help` lists its options.\n")
with mkdocs_gen_files.open("reference/cli.md", "w") as f:
    f.write("\n".join(out))
