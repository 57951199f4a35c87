"""Tasks on Dask: a LocalCluster on this machine by default, an existing cluster by address.

This is the one place lensfit starts distributed work (banks of PSFs, ghost fits over many
lenses). A task is a plain function of one picklable job that writes its own result
atomically and returns a small record; the caller decides what is already done (resume)
before it submits. A task that raises fails once: its errors are deterministic (the same
job raises again), so it is named in the :class:`TaskError` and the others go on. A task
whose worker died (SIGKILL, out of memory) is rerun by Dask's scheduler
(``distributed.scheduler.allowed-failures``, 3 by default). ``workers=0`` runs the tasks
one after another in this process, with no Dask at all: the reference a distributed run
must equal. The LocalCluster has at most :data:`WORKERS_PER_CORE` workers per core, is
closed on SIGTERM as on Ctrl-C (its workers end with the driver), logs at ERROR (INFO with
``verbose``, the CLI's ``-v``) and serves Dask's dashboard where bokeh is installed
(``pip install 'lensfit[dashboard]'``); ``say`` gets its link. A ``--scheduler`` address is
checked (a port of 1-65535) and probed under one deadline before a Client connects:
Dask's Client waits forever on a service that does not answer, and reads an HTTP reply
as a 3 EiB frame (MemoryError).

Farms. Start a cluster with Dask's own deployers and pass its scheduler's address:

* Slurm, dask-jobqueue: ``SLURMCluster(cores=1, processes=1, memory="1GB",
  walltime="02:00:00")``, ``.scale(jobs=100)``, then ``--scheduler`` its
  ``scheduler_address``;
* Kubernetes: dask-kubernetes' operator (``KubeCluster``) or the ``dask/dask`` Helm chart,
  then the scheduler service's address;
* by hand: ``dask scheduler``, and on each machine ``dask worker tcp://HEAD:8786
  --nthreads 1 --nworkers N --memory-limit 1GB`` (one thread per worker process: a node's
  lensrt threads are the spec's ``render.threads``; threads of one worker each keep their
  own lensrt context, node.py).

Memory per task: a worker process peaked at 85 MiB over the demo bank (79 MiB of it
Python, Dask and lensrt loaded) and at 127 MiB over 512 x 512-pixel nodes of 8
wavelengths, so about 25 bytes per pixel and wavelength, again per ghost of a flare bank
(measured 2026-11-28 with ``resource.getrusage`` in a LocalCluster worker).

Each worker must import lensfit and the lensrt binding (``pip install ./fit
./runtime/python`` in the workers' environment), load a lensrt library (its own
LENSRT_LIBRARY where set, else the driver's path, node.worker_library) and see the lens
tables and the bank folder at the same paths as the driver (a shared file system mounted
alike: jobs carry absolute paths). Start those workers without Dask's
MALLOC_TRIM_THRESHOLD_ (``distributed.nanny.pre-spawn-environ``; see local_cluster): with
it a ghost fit is three times slower.
"""

from __future__ import annotations

import asyncio
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from lensfit.common.errors import InputError


class TaskError(RuntimeError):
    """Tasks that failed, each named with its error."""


# How many LocalCluster worker processes per core at most: more only share the same cores
# and multiply the memory (each worker is a Python process with its own lensrt contexts)
WORKERS_PER_CORE = 2
PROBE_SECONDS = 10.0  # a scheduler that does not answer lensfit's probe by then is refused


def default_workers() -> int:
    """The cores this process may run on (its affinity mask on Linux)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def check_workers(workers: int | None) -> None:
    """``--workers``: 0 (this process), or 1 to :data:`WORKERS_PER_CORE` per core."""
    if workers is None:
        return
    cap = WORKERS_PER_CORE * default_workers()
    if workers < 0:
        raise InputError(f"--workers {workers}: expected 0 (this process) or more")
    if workers > cap:
        raise InputError(f"--workers {workers}: this machine gives lensfit {default_workers()} "
                         f"cores, so at most {cap} worker processes; for more, start a Dask "
                         "cluster over several machines and give its --scheduler")


def check_scheduler(address: str | None) -> None:
    """``--scheduler``: an address Dask can parse, with a port of 1-65535 (port 99999 would
    wait the whole connect timeout)."""
    if address is None:
        return
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, loc = parse_address(address, strict=False)
        if scheme in ("tcp", "tls", "ws", "wss", "ucx"):
            host, port = parse_host_port(loc)
            if not host:
                raise ValueError("no host")
            if not 1 <= int(port) <= 65535:
                raise ValueError(f"port {port} is not 1-65535")
    except (ValueError, TypeError) as e:
        raise InputError(f"--scheduler {address}: not a scheduler address "
                         f"(tcp://HOST:PORT): {e}") from None


def run_tasks(fn: Callable[[dict[str, Any]], dict[str, Any]], jobs: Sequence[dict[str, Any]],
              keys: Sequence[str], *, scheduler: str | None = None, workers: int | None = None,
              retries: int = 0, progress: bool = True, label: str = "tasks",
              verbose: bool = False, say: Callable[[str], None] | None = None
              ) -> list[dict[str, Any]]:
    """``fn(job)`` for every job, on Dask (or in this process with ``workers=0``); the
    results in the jobs' order. Raises :class:`TaskError` naming every task that failed
    (after the others finished).

    A task that raises fails once (its error is deterministic: the same job raises again);
    ``retries`` reruns it anyway. A task whose worker died is rerun by the scheduler
    (``distributed.scheduler.allowed-failures``). ``verbose`` shows the cluster's logs at
    INFO; ``say`` gets the lines for the user (the dashboard's address)."""
    from tqdm import tqdm

    if len(keys) != len(jobs) or len(set(keys)) != len(keys):
        raise ValueError("run_tasks: one distinct key per job")
    check_workers(workers)
    check_scheduler(scheduler)
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
            with _terminate_as_exit():
                _run_dask(fn, jobs, keys, scheduler, workers, retries, bar, results,
                          failures, verbose, say)
    finally:
        bar.close()
    if failures:
        raise TaskError(f"{len(failures)} of {len(jobs)} {label} failed: "
                        + "; ".join(failures[:5]) + (" ..." if len(failures) > 5 else ""))
    return [r for r in results if r is not None]


def cluster_log_level(verbose: bool) -> int:
    return logging.INFO if verbose else logging.ERROR


def local_cluster(workers: int | None = None, verbose: bool = False):
    """The embedded default: worker processes on this machine, one thread each (lensrt
    has its own threads, set by the job), quiet unless something goes wrong (``verbose``:
    the scheduler's and workers' logs at INFO)."""
    import dask
    from distributed import LocalCluster

    check_workers(workers)
    level = cluster_log_level(verbose)
    logging.getLogger("distributed").setLevel(level)
    # Dask sets MALLOC_TRIM_THRESHOLD_ in its workers, which turns off glibc's adaptive
    # mmap threshold: every large numpy temporary is then mapped and unmapped anew. A ghost
    # fit took 91-101 s of which 97-105 s system time with it, 31-34 s without (singlet of
    # tests/fit/ghosts, one worker, 2026-11-27): the workers start without it
    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
        return LocalCluster(n_workers=workers or default_workers(), threads_per_worker=1,
                            processes=True,
                            dashboard_address=":0",  # a free port (its dashboard needs bokeh)
                            silence_logs=level)


def dashboard_available() -> bool:
    """Dask's dashboard needs bokeh (``pip install 'lensfit[dashboard]'``)."""
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None


def _dashboard_line(client, local: bool) -> str:
    if local and not dashboard_available():
        return ("Dask dashboard: off (it needs bokeh: pip install 'lensfit[dashboard]' or "
                "'bokeh>=3.1')")
    try:
        link = client.dashboard_link
    except Exception:  # noqa: BLE001  (a scheduler without a dashboard: said below)
        link = None
    if not link or "dashboard" not in client.scheduler_info().get("services", {}):
        return ("Dask dashboard: the scheduler serves none (it needs bokeh where the "
                "scheduler runs)")
    return f"Dask dashboard: {link}"


class _Terminated(SystemExit):
    """SIGTERM while tasks run: unwinds like an exit, so the LocalCluster is closed and its
    worker processes end with the driver (exit status 143, as for the signal)."""


class _terminate_as_exit:
    """SIGTERM raises :class:`_Terminated` in the main thread while the block runs (Python's
    default would end the process at once, leaving the cluster's teardown to its workers'
    watch on their parent). Elsewhere than the main thread: nothing changes."""

    def __enter__(self):
        self.old = None
        if threading.current_thread() is threading.main_thread():
            def handler(signum, frame):
                print("lensfit: terminated; closing the Dask cluster (rerun the same "
                      "command to resume)", file=sys.stderr, flush=True)
                raise _Terminated(128 + signum)
            self.old = signal.signal(signal.SIGTERM, handler)
        return self

    def __exit__(self, *exc):
        if self.old is not None:
            signal.signal(signal.SIGTERM, self.old)
        return False


async def _probe(address: str, timeout: float) -> dict[str, Any]:
    """The scheduler's identity, asked over a comm of our own under one deadline: an
    address where something else listens is refused in seconds (Dask's Client waits for a
    reply forever, or reads an HTTP reply as a frame length: MemoryError, 'Unable to
    allocate 3.07 EiB')."""
    from distributed.comm import connect
    from distributed.security import Security

    args = Security().get_connection_args("client")
    # connect's own timeout first (its error names the address), then ours
    comm = await asyncio.wait_for(connect(address, timeout=timeout, **args), timeout + 1)
    try:
        await asyncio.wait_for(comm.write({"op": "identity", "reply": True}), timeout)
        return await asyncio.wait_for(comm.read(), timeout)
    finally:
        comm.abort()


def connect_client(scheduler: str):
    """A Client of the scheduler at ``scheduler``, or an InputError naming the address."""
    import dask
    from dask.utils import parse_timedelta
    from distributed import Client

    check_scheduler(scheduler)
    timeout = min(PROBE_SECONDS, parse_timedelta(
        dask.config.get("distributed.comm.timeouts.connect"), default="seconds"))
    try:
        reply = asyncio.run(_probe(scheduler, timeout))
    except TimeoutError as e:
        if str(e):  # distributed's own: nothing accepted the connection
            raise InputError(f"--scheduler {scheduler}: cannot reach a Dask scheduler "
                             f"there: {e}") from None
        raise InputError(f"--scheduler {scheduler}: no Dask scheduler answered there within "
                         f"{timeout:g} s") from None
    except (OSError, ValueError) as e:
        raise InputError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there: "
                         f"{e}") from None
    except Exception as e:  # noqa: BLE001  (anything else speaks another protocol)
        why = ("a frame length Dask cannot allocate" if isinstance(e, MemoryError)
               else f"{type(e).__name__}: {str(e)[:80]}")
        raise InputError(f"--scheduler {scheduler}: not a Dask scheduler (its reply does "
                         f"not speak Dask's protocol: {why})") from None
    if not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        raise InputError(f"--scheduler {scheduler}: not a Dask scheduler (it answered "
                         f"{str(reply)[:80]!r})")
    try:
        return Client(scheduler)  # distributed.comm.timeouts.connect: 30 s
    except (OSError, TimeoutError, ValueError, MemoryError) as e:
        raise InputError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there: "
                         f"{type(e).__name__}: {e}") from None


def _run_dask(fn, jobs, keys, scheduler, workers, retries, bar, results, failures,
              verbose=False, say=None) -> None:
    from distributed import as_completed

    logging.getLogger("distributed").setLevel(cluster_log_level(verbose))
    cluster = None
    try:
        if scheduler is None:
            from distributed import Client

            cluster = local_cluster(workers, verbose)
            client = Client(cluster)
        else:
            client = connect_client(scheduler)
        with client:
            if say is not None:
                say(_dashboard_line(client, cluster is not None))
            # No retries: a task that raised raises again (a lost worker is the
            # scheduler's to rerun, allowed-failures)
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
