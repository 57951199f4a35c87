"""make bench: banks on Dask (issue 23).

1. The scheduler's overhead per task: a LocalCluster of 2 workers (1 thread each) runs
   empty tasks; tasks per second, and the seconds a worker spends per task.
2. Scaling: the same bank (banks/demo.toml) on 1 worker and on 2 workers, each on a
   cluster started beforehand (its start-up is not counted), interleaved, medians; the
   ratio is the claim.
3. The reader against direct renders at the cell centres of the bank (check.py): a table.
4. The node's seconds (rendering alone, and the whole task: lens, render, EXR, record)
   and the overhead's share of a node.
5. On paper, from these figures: nodes per hour of a 1,000-node bank on 10 and 100
   workers, and what would limit them (the scheduler's task rate, the writes).

Writes build/bench/banks.md and banks.json.

    python -m lensfit.banks.bench --out build/bench [--repeats 2]
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import time
from pathlib import Path
from typing import Any

from lensfit.banks.engine import empty_task, local_cluster, run_tasks
from lensfit.banks.run import run_bank

ROOT = Path(__file__).resolve().parents[3]
SPEC = ROOT / "banks" / "demo.toml"


def overhead(n_tasks: int, repeats: int) -> dict[str, Any]:
    """Empty tasks on 2 workers: tasks per second (median of ``repeats``)."""
    with local_cluster(2) as cluster:
        rates = []
        for r in range(repeats + 1):  # the first warms the workers up
            jobs = [{"i": i} for i in range(n_tasks)]
            keys = [f"empty-{r}-{i}" for i in range(n_tasks)]
            t0 = time.perf_counter()
            run_tasks(empty_task, jobs, keys, scheduler=cluster.scheduler_address,
                      progress=False)
            if r:
                rates.append(n_tasks / (time.perf_counter() - t0))
    rate = statistics.median(rates)
    return {"tasks": n_tasks, "tasks_per_second": rate, "rates": rates,
            "worker_seconds_per_task": 2 / rate}


def scaling(out: Path, repeats: int) -> dict[str, Any]:
    """The demo bank from scratch on 1 and on 2 workers, interleaved."""
    times: dict[int, list[float]] = {1: [], 2: []}
    clusters = {w: local_cluster(w) for w in (1, 2)}
    summary = None
    try:
        for _ in range(repeats):
            for w in (1, 2):
                folder = out / f"bank-{w}"
                shutil.rmtree(folder, ignore_errors=True)
                t0 = time.perf_counter()
                summary = run_bank(SPEC, folder, scheduler=clusters[w].scheduler_address,
                                   progress=False, sheet=False)
                times[w].append(time.perf_counter() - t0)
    finally:
        for c in clusters.values():
            c.close()
    assert summary is not None
    records = [json.loads(p.read_text()) for p in sorted((out / "bank-2" / "nodes").glob("*.json"))]
    return {"nodes": summary.nodes, "seconds_1": times[1], "seconds_2": times[2],
            "median_1": statistics.median(times[1]), "median_2": statistics.median(times[2]),
            "speedup": statistics.median(times[1]) / statistics.median(times[2]),
            "node_render_seconds": statistics.median(r["seconds"] for r in records),
            "node_exr_bytes": statistics.median(
                (out / "bank-2" / r["exr"]).stat().st_size for r in records)}


def accuracy(folder: Path) -> dict[str, Any]:
    """The demo bank's reader against direct renders at its cell centres (check.py)."""
    import os

    from lensrt_ctypes import LIBRARY

    from lensfit.banks.check import check_bank
    from lensfit.banks.run import resolve_table
    from lensfit.banks.spec import load_spec

    spec = load_spec(SPEC)
    library = os.environ.get("LENSRT_LIBRARY") or str(LIBRARY)
    return check_bank(spec, folder / "bank.index", library, resolve_table(spec.lens, SPEC.parent))


def node_task_seconds(out: Path) -> float:
    """The whole task of a node in this process (lens loaded once, as a worker does)."""
    folder = out / "bank-0"
    shutil.rmtree(folder, ignore_errors=True)
    s = run_bank(SPEC, folder, workers=0, progress=False, sheet=False)
    return s.wall_seconds / s.nodes


def projection(node_s: float, rate: float, exr_bytes: float) -> list[dict[str, Any]]:
    """Nodes per hour of a 1,000-node bank on W workers: W / node_s, capped by the
    scheduler's task rate; the write bandwidth that needs."""
    rows = []
    for w in (10, 100):
        compute = w / node_s
        per_s = min(compute, rate)
        rows.append({"workers": w, "nodes_per_hour": 3600 * per_s,
                     "limit": "workers" if compute < rate else "scheduler",
                     "bank_minutes": 1000 / per_s / 60,
                     "write_mb_per_s": per_s * exr_bytes / 1e6})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="build/bench")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--empty-tasks", type=int, default=2000)
    args = ap.parse_args(argv)
    out = Path(args.out)
    work = out / "banks"
    work.mkdir(parents=True, exist_ok=True)

    ov = overhead(args.empty_tasks, args.repeats)
    sc = scaling(work, args.repeats)
    acc = accuracy(work / "bank-2")
    task_s = node_task_seconds(work)
    share = ov["worker_seconds_per_task"] / task_s
    rows = projection(task_s, ov["tasks_per_second"], sc["node_exr_bytes"])
    result = {"overhead": ov, "scaling": sc, "node_task_seconds": task_s,
              "overhead_share": share, "projection": rows, "accuracy": acc}
    (out / "banks.json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [
        "# Banks on Dask (lensfit.banks.bench)", "",
        f"Bank: {SPEC.relative_to(ROOT)} ({sc['nodes']} nodes), LocalCluster, 1 thread per "
        "worker, cluster start-up not counted; medians of "
        f"{args.repeats}, interleaved.", "",
        "| | 1 worker | 2 workers | speedup |", "|---|---:|---:|---:|",
        f"| bank seconds | {sc['median_1']:.2f} | {sc['median_2']:.2f} | "
        f"**{sc['speedup']:.2f}x** |", "",
        f"Scheduler: {ov['tasks_per_second']:.0f} empty tasks per second on 2 workers "
        f"({1e3 * ov['worker_seconds_per_task']:.2f} ms of a worker per task); a node takes "
        f"{task_s:.3f} s as a task ({sc['node_render_seconds']:.3f} s rendering), so the "
        f"overhead is **{share:.2%}** of a node (under 2% for nodes of "
        f"{ov['worker_seconds_per_task'] / 0.02:.2f} s or more: group smaller nodes into "
        "one task).", "",
        "On paper (a 1,000-node bank of these nodes; the scheduler's rate as measured "
        "here, EXR bytes per node "
        f"{sc['node_exr_bytes'] / 1e3:.0f} kB):", "",
        "| workers | nodes per hour | 1,000 nodes in | limited by | writes |",
        "|---:|---:|---:|---|---:|"]
    for r in rows:
        lines.append(f"| {r['workers']} | {r['nodes_per_hour']:.0f} | "
                     f"{r['bank_minutes']:.1f} min | {r['limit']} | "
                     f"{r['write_mb_per_s']:.1f} MB/s |")
    lines += ["", "Nodes per hour: workers / node seconds while that stays below the "
              "scheduler's task rate (measured here with the scheduler sharing 2 cores with "
              "its workers: a scheduler on a core of its own is faster), each node one EXR "
              "and one record written to a shared file system."]
    lines += ["", "## The reader against direct renders (lensfit.banks.check)", "",
              "At every node and bank wavelength the reader returns the node's own render "
              "bit for bit (registration channel; tests/fit/banks/test_bank_accuracy.py). "
              "Between nodes, at cell centres of the demo bank (relative L2 against a direct "
              "render to the same 1% target):", "",
              "| field (deg) | nm | bank, interpolated chief | bank, lens's chief | nearest "
              "node | chief error (px) |", "|---|---:|---:|---:|---:|---:|"]
    for p in acc["points"]:
        lines.append(f"| ({p['field_x_deg']:g}, {p['field_y_deg']:g}) | "
                     f"{p['wavelength_nm']:g} | {p['bank']:.2%} | {p['bank_lens_chief']:.2%} | "
                     f"{p['nearest']:.2%} | {p['chief_px']:.2f} |")
    lines += ["", f"Worst: {acc['worst_bank']:.2%} (lens's chief "
              f"{acc['worst_bank_lens_chief']:.2%}) against the nearest node's "
              f"{acc['worst_nearest']:.2%}; the check suggests "
              f"{acc['field_points_for_target']} field points per axis for "
              f"{acc['target']:.0%}."]
    text = "\n".join(lines) + "\n"
    (out / "banks.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
