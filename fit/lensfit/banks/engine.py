"""Tasks on Dask: a LocalCluster on this machine by default, an existing cluster by address.

This is the one place lensfit starts distributed work (banks of PSFs, ghost fits over many
lenses). A task is a plain function of one picklable job that writes its own result
atomically and returns a small record; the caller decides what is already done (resume)
before it submits. Dask's scheduler retries a task whose worker died (SIGKILL, out of
memory: its ``distributed.scheduler.allowed-failures``, 3 by default), and ``retries``
reruns a task that raised. ``workers=0`` runs the tasks one after another in this
process, with no Dask at all: the reference a distributed run must equal.

To use a farm, start a Dask cluster with Dask's own deployers and pass its scheduler's
address, e.g. on Slurm with dask-jobqueue::

    from dask_jobqueue import SLURMCluster
    cluster = SLURMCluster(cores=1, processes=1, memory="4GB", walltime="02:00:00")
    cluster.scale(jobs=100)
    print(cluster.scheduler_address)   # lensfit bank SPEC --scheduler tcp://...

Each worker must be able to import lensfit and the lensrt binding (``pip install fit/
runtime/python`` in the workers' environment) and to read the lens table and write the
bank folder (a shared file system), with LENSRT_LIBRARY naming lensrt's shared library
where it is not in the source tree's build folder. Start those workers without Dask's
MALLOC_TRIM_THRESHOLD_ (``distributed.nanny.pre-spawn-environ``; see local_cluster): with
it a ghost fit is three times slower.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Sequence
from typing import Any

from lensfit.errors import InputError


class TaskError(RuntimeError):
    """Tasks that failed after their retries, each named with its error."""


def default_workers() -> int:
    """The cores this process may run on (its affinity mask on Linux)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def run_tasks(fn: Callable[[dict[str, Any]], dict[str, Any]], jobs: Sequence[dict[str, Any]],
              keys: Sequence[str], *, scheduler: str | None = None, workers: int | None = None,
              retries: int = 2, progress: bool = True, label: str = "tasks"
              ) -> list[dict[str, Any]]:
    """``fn(job)`` for every job, on Dask (or in this process with ``workers=0``); the
    results in the jobs' order. Raises :class:`TaskError` naming every task that failed
    (after the others finished)."""
    from tqdm import tqdm

    if len(keys) != len(jobs) or len(set(keys)) != len(keys):
        raise ValueError("run_tasks: one distinct key per job")
    if not jobs:
        return []
    bar = tqdm(total=len(jobs), desc=label, unit="task", disable=not progress,
               dynamic_ncols=True)
    results: list[dict[str, Any] | None] = [None] * len(jobs)
    failures: list[str] = []
    try:
        if workers == 0 and scheduler is None:
            for i, job in enumerate(jobs):
                try:
                    results[i] = fn(job)
                except Exception as e:  # noqa: BLE001  (named in the TaskError)
                    failures.append(f"{keys[i]}: {e}")
                bar.update(1)
        else:
            _run_dask(fn, jobs, keys, scheduler, workers, retries, bar, results, failures)
    finally:
        bar.close()
    if failures:
        raise TaskError(f"{len(failures)} of {len(jobs)} {label} failed: "
                        + "; ".join(failures[:5]) + (" ..." if len(failures) > 5 else ""))
    return [r for r in results if r is not None]


def local_cluster(workers: int | None = None):
    """The embedded default: worker processes on this machine, one thread each (lensrt
    has its own threads, set by the job), quiet unless something goes wrong."""
    import dask
    from distributed import LocalCluster

    logging.getLogger("distributed").setLevel(logging.ERROR)
    # Dask sets MALLOC_TRIM_THRESHOLD_ in its workers, which turns off glibc's adaptive
    # mmap threshold: every large numpy temporary is then mapped and unmapped anew. A ghost
    # fit took 91-101 s of which 97-105 s system time with it, 31-34 s without (singlet of
    # tests/fit/ghosts, one worker, 2026-11-27): the workers start without it
    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
        return LocalCluster(n_workers=workers or default_workers(), threads_per_worker=1,
                            processes=True, dashboard_address=":0",
                            silence_logs=logging.ERROR)


def _run_dask(fn, jobs, keys, scheduler, workers, retries, bar, results, failures) -> None:
    from distributed import Client, as_completed

    cluster = local_cluster(workers) if scheduler is None else None
    try:
        if cluster is not None:
            client = Client(cluster)
        else:
            try:
                client = Client(scheduler)  # distributed.comm.timeouts.connect: 30 s
            except (OSError, TimeoutError, ValueError) as e:
                raise InputError(f"--scheduler {scheduler}: cannot reach a Dask scheduler "
                                 f"there: {e}") from None
        with client:
            futures = client.map(fn, jobs, key=list(keys), pure=False, retries=retries)
            where = {f.key: i for i, f in enumerate(futures)}
            for future in as_completed(futures):
                i = where[future.key]
                try:
                    results[i] = future.result()
                except Exception as e:  # noqa: BLE001  (named in the TaskError)
                    failures.append(f"{keys[i]}: {e}")
                bar.update(1)
    finally:
        if cluster is not None:
            cluster.close()


def empty_task(job: dict[str, Any]) -> dict[str, Any]:
    """A task that does nothing: the scheduler's overhead per task (make bench)."""
    return {"i": job["i"], "t": time.perf_counter()}
