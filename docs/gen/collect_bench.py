"""Copy `make bench`'s summaries into the docs as committed snapshots.

`make bench` runs this last: every *.md and *.txt at the top of build/bench/ (each step's
summary: fourier.md, cells.md, fits.md, sweep.md, lensrt-tables.txt, slow-tests.txt, ...)
is copied to docs/benchmarks/snapshots/ with a header saying when it was measured (the
file's modification time), when it was collected, the commit and the machine. The
documentation's benchmark pages are generated from these files (docs/gen/bench_pages.py),
so a figure in the docs is the one `make bench` wrote. Commit the snapshots that changed.

    python docs/gen/collect_bench.py [--from build/bench] [--to docs/benchmarks/snapshots]
"""
from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SEPARATOR = "----- end of snapshot header -----"


def git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ""


def machine() -> str:
    model = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        kb = int(Path("/proc/meminfo").read_text().split()[1])
        mem = f", {kb / 2**20:.0f} GiB memory"
    except (OSError, ValueError, IndexError):
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return (f"{platform.machine()}, {model or 'unknown CPU'}, {cores} cores available{mem}, "
            f"{platform.system()} {platform.release()}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--from", dest="src", default=str(ROOT / "build" / "bench"))
    ap.add_argument("--to", dest="dst", default=str(ROOT / "docs" / "benchmarks" / "snapshots"))
    ap.add_argument("--note", default="", help="a line added to each header")
    args = ap.parse_args(argv)
    src, dst = Path(args.src), Path(args.dst)
    files = sorted(p for p in src.glob("*") if p.suffix in (".md", ".txt") and p.is_file())
    if not files:
        print(f"collect_bench: no *.md or *.txt in {src}", file=sys.stderr)
        return 1
    dst.mkdir(parents=True, exist_ok=True)
    head = git("rev-parse", "--short=12", "HEAD") or "unknown"
    changed = git("status", "--porcelain", "--untracked-files=no")
    dirty = " with uncommitted changes" if changed else ""
    now = dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    where = machine()
    for p in files:
        measured = dt.datetime.fromtimestamp(p.stat().st_mtime).astimezone()
        header = [f"source: build/bench/{p.name}",
                  f"measured: {measured.strftime('%Y-%m-%d %H:%M %Z')} "
                  "(the file's modification time)",
                  f"collected: {now} by docs/gen/collect_bench.py",
                  f"commit: {head}{dirty} (the checkout's HEAD when collected)",
                  f"machine: {where}"]
        if args.note:
            header.append(f"note: {args.note}")
        body = p.read_text(encoding="utf-8", errors="replace")
        out = dst / p.name
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text("\n".join(header) + "\n" + SEPARATOR + "\n" + body, encoding="utf-8")
        tmp.replace(out)
        print(f"collect_bench: {p} -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
