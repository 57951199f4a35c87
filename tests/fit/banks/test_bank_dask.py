"""Banks on Dask as its users expect (issue 37): the dashboard's line, -v for the
cluster's logs, no retries of deterministic errors, --scheduler at a service that is not
Dask or at an invalid port, the --workers cap, a driver killed with SIGTERM, special files
in a bank folder, a damaged bank.json with --restart, two banks of one spec on one
scheduler, the workers' own LENSRT_LIBRARY, and CPU-seconds measured.

Tiny banks of lens 0001 (2 x 1 fields, 2 wavelengths, 16 x 16 pixels): a node takes a
fraction of a second by the cells integrator.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from bank_specs import bank_spec

from lensfit.banks import engine, node
from lensfit.banks.engine import TaskError, run_tasks
from lensfit.banks.run import run_bank
from lensfit.common.errors import InputError

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "runtime" / "python"))
from lensrt_ctypes import LIBRARY  # noqa: E402

pytestmark = pytest.mark.skipif(not LIBRARY.exists(),
                                reason=f"needs {LIBRARY}: build it with `make runtime`")

SPEC = bank_spec("{name}", render="{render}")
CELLS = 'integrator = "cells"\ntarget_error = 0.05'
MONTE_CARLO = 'integrator = "monte-carlo"\nsamples = {samples}\ncheckpoints = 2'
NODE = "nodes/f0-z0-d0-y0-x0"


def spec_file(tmp_path: Path, render: str = CELLS, name: str = "t") -> Path:
    p = tmp_path / f"{name}.toml"
    p.write_text(SPEC.format(name=name, render=render))
    return p


def cli(*args: str, env: dict[str, str] | None = None, timeout: float = 120
        ) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lensfit.cli", "bank", *args],
                          capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


def within(seconds: float, fn, *args, **kwargs):
    """fn(...) in a thread: its result or its exception, failing the test (not hanging
    it) when it takes longer than ``seconds`` (a FIFO opened for reading blocks)."""
    box: dict = {}

    def run() -> None:
        try:
            box["result"] = fn(*args, **kwargs)
        except BaseException as e:  # noqa: BLE001  (raised below, in the test)
            box["error"] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"{fn.__name__} still running after {seconds} s"
    if "error" in box:
        raise box["error"]
    return box["result"]


# --- the dashboard and -v ----------------------------------------------------------------

def test_cli_prints_the_dashboard_line_and_v_shows_the_cluster_logs(tmp_path: Path) -> None:
    spec = spec_file(tmp_path)
    quiet = cli(str(spec), "-o", str(tmp_path / "a"), "--workers", "1", "--no-progress",
                "--no-sheet")
    assert quiet.returncode == 0, quiet.stderr
    assert "Dask dashboard: " in quiet.stderr
    if engine.dashboard_available():
        assert "Dask dashboard: http://" in quiet.stderr, quiet.stderr
    else:
        assert "pip install 'lensfit[dashboard]'" in quiet.stderr, quiet.stderr
    assert " - INFO - " not in quiet.stderr, quiet.stderr
    loud = cli(str(spec), "-o", str(tmp_path / "b"), "--workers", "1", "--no-progress",
               "--no-sheet", "-v")
    assert loud.returncode == 0, loud.stderr
    assert "distributed.scheduler - INFO - " in loud.stderr, loud.stderr
    assert "distributed.worker - INFO - " in loud.stderr, loud.stderr


def test_dashboard_line_gives_the_link_where_the_scheduler_serves_one(monkeypatch) -> None:
    class FakeClient:
        dashboard_link = "http://10.0.0.5:8787/status"

        def __init__(self, services: dict) -> None:
            self.services = services

        def scheduler_info(self) -> dict:
            return {"services": self.services}

    monkeypatch.setattr(engine, "dashboard_available", lambda: True)
    assert engine._dashboard_line(FakeClient({"dashboard": 8787}), local=True) == \
        "Dask dashboard: http://10.0.0.5:8787/status"
    assert "serves none" in engine._dashboard_line(FakeClient({}), local=False)
    monkeypatch.setattr(engine, "dashboard_available", lambda: False)
    assert "pip install 'lensfit[dashboard]'" in engine._dashboard_line(
        FakeClient({"dashboard": 8787}), local=True)


# --- retries: a deterministic error fails once -------------------------------------------

def _failing_task(job: dict) -> dict:
    with open(job["log"], "a") as f:
        f.write("called\n")
    raise InputError(f"{job['log']}: a deterministic error")


def test_a_task_that_raises_runs_once(tmp_path: Path) -> None:
    from distributed import LocalCluster

    log = tmp_path / "calls.txt"
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster:
        with pytest.raises(TaskError, match=r"1 of 1 t failed: k0: .*a deterministic error"):
            run_tasks(_failing_task, [{"log": str(log)}], ["k0"],
                      scheduler=cluster.scheduler_address, progress=False, label="t")
    assert log.read_text() == "called\n"  # not 3 times (retries=2 reran it)


# --- --scheduler at something that is not a Dask scheduler ------------------------------

class _Server:
    """A TCP service on localhost: ``banner`` sent on connect (an HTTP error reply, which
    Dask read as a 3 EiB frame), or silence (a server waiting for a request line)."""

    def __init__(self, banner: bytes | None) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen()
        self.port = self.sock.getsockname()[1]
        self.banner, self.conns = banner, []
        threading.Thread(target=self.serve, daemon=True).start()

    def serve(self) -> None:
        while True:
            try:
                c, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(c)
            if self.banner is not None:
                c.sendall(self.banner)

    def close(self) -> None:
        self.sock.close()
        for c in self.conns:
            c.close()


def test_a_service_that_is_not_dask_is_refused_in_one_line(tmp_path: Path) -> None:
    server = _Server(b"HTTP/1.0 400 Bad Request\r\nServer: test\r\n\r\n")
    try:
        address = f"tcp://127.0.0.1:{server.port}"
        r = cli(str(spec_file(tmp_path)), "-o", str(tmp_path / "b"), "--scheduler", address,
                "--no-progress", timeout=60)
    finally:
        server.close()
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1, r.stderr
    assert f"--scheduler {address}: not a Dask scheduler" in r.stderr, r.stderr
    assert "MemoryError" not in r.stderr and "Traceback" not in r.stderr


def test_a_silent_service_is_refused_after_the_probe(monkeypatch) -> None:
    monkeypatch.setattr(engine, "PROBE_SECONDS", 1.0)
    server = _Server(None)
    try:
        address = f"tcp://127.0.0.1:{server.port}"
        t0 = time.monotonic()
        with pytest.raises(InputError, match=rf"--scheduler {address}: no Dask scheduler "
                                             r"answered there within 1 s"):
            within(30, engine.connect_client, address)
        assert time.monotonic() - t0 < 10
    finally:
        server.close()


@pytest.mark.parametrize("address, why", [
    ("tcp://127.0.0.1:99999", "port 99999 is not 1-65535"),
    ("tcp://127.0.0.1:0", "port 0 is not 1-65535"),
    ("tcp://:8786", "no host"),
])
def test_an_invalid_scheduler_address_is_refused_before_anything(tmp_path: Path, address: str,
                                                                 why: str) -> None:
    t0 = time.monotonic()
    with pytest.raises(InputError, match=rf"--scheduler {address}: not a scheduler address "
                                         rf".*{why}"):
        run_bank(spec_file(tmp_path), tmp_path / "b", scheduler=address, progress=False)
    assert time.monotonic() - t0 < 5
    assert not (tmp_path / "b").exists()


# --- --workers: capped; a driver killed takes its workers with it ------------------------

def test_workers_above_the_cap_are_refused(tmp_path: Path) -> None:
    cap = engine.WORKERS_PER_CORE * engine.default_workers()
    with pytest.raises(InputError, match=rf"--workers 1000: .* at most {cap} worker "
                                         r"processes"):
        run_bank(spec_file(tmp_path), tmp_path / "b", workers=1000, progress=False)
    assert not (tmp_path / "b").exists()
    r = cli(str(spec_file(tmp_path)), "-o", str(tmp_path / "b"), "--workers", "1000")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    engine.check_workers(cap)  # the cap itself is allowed


def _descendants(pid: int) -> list[int]:
    import psutil

    try:
        return [p.pid for p in psutil.Process(pid).children(recursive=True)]
    except psutil.NoSuchProcess:
        return []


def _alive(pids: list[int]) -> list[int]:
    import psutil

    out = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                out.append(pid)
        except psutil.NoSuchProcess:
            pass
    return out


def _workers(pids: list[int]) -> list[int]:
    import psutil

    out = []
    for pid in _alive(pids):
        try:
            if "spawn_main" in " ".join(psutil.Process(pid).cmdline()):
                out.append(pid)
        except psutil.NoSuchProcess:
            pass
    return out


def test_sigterm_to_the_driver_ends_its_workers(tmp_path: Path) -> None:
    """`lensfit bank --workers 2` killed with SIGTERM once its workers run: the cluster is
    closed, the exit status is 143, and no process it started is left a few seconds on."""
    spec = spec_file(tmp_path, MONTE_CARLO.format(samples=2_000_000), "mc")
    proc = subprocess.Popen([sys.executable, "-m", "lensfit.cli", "bank", str(spec), "-o",
                             str(tmp_path / "b"), "--workers", "2", "--no-progress"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        seen: list[int] = []
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and proc.poll() is None:
            seen = sorted(set(seen) | set(_descendants(proc.pid)))
            if len(_workers(seen)) >= 2:  # both worker processes spawned
                time.sleep(1.0)  # and running tasks
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the bank finished before it was killed"
        proc.send_signal(signal.SIGTERM)
        proc.wait(60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, proc.stderr.read()
    assert "terminated" in proc.stderr.read()
    deadline = time.monotonic() + 10
    while _alive(seen) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert _alive(seen) == [], "processes left behind by the killed driver"


# --- special files in the bank folder ----------------------------------------------------

@pytest.mark.parametrize("restart", [False, True])
@pytest.mark.parametrize("suffix", [".exr", ".json", ".phasors"])
def test_a_fifo_in_place_of_a_node_file_is_refused_never_opened(tmp_path: Path, suffix: str,
                                                                restart: bool) -> None:
    spec, out = spec_file(tmp_path), tmp_path / "b"
    (out / "nodes").mkdir(parents=True)
    fifo = out / f"{NODE}{suffix}"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match=rf"{fifo} is a FIFO; .*remove it"):
        within(30, run_bank, spec, out, workers=0, progress=False, sheet=False,
               restart=restart)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)  # never replaced


def test_a_fifo_in_a_finished_bank_is_refused_also_with_restart(tmp_path: Path) -> None:
    spec, out = spec_file(tmp_path), tmp_path / "b"
    run_bank(spec, out, workers=0, progress=False, sheet=False)
    exr = out / f"{NODE}.exr"
    exr.unlink()
    os.mkfifo(exr)
    other = spec_file(tmp_path, CELLS.replace("0.05", "0.04"), "t")  # --restart's cleanup
    for s, restart in ((spec, False), (other, True)):
        with pytest.raises(InputError, match=rf"{exr} is a FIFO"):
            within(30, run_bank, s, out, workers=0, progress=False, sheet=False,
                   restart=restart)
        assert stat.S_ISFIFO(os.lstat(exr).st_mode)
    # nothing was discarded by the refused --restart
    assert (out / f"{NODE}.json").is_file() and (out / "bank.index").is_file()
    r = cli(str(spec), "-o", str(out), "--workers", "0", timeout=60)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "is a FIFO" in r.stderr


@pytest.mark.parametrize("name", ["bank.json", "bank.index", "contact-sheet.png"])
def test_a_fifo_in_place_of_a_bank_file_is_refused(tmp_path: Path, name: str) -> None:
    spec, out = spec_file(tmp_path), tmp_path / "b"
    out.mkdir()
    os.mkfifo(out / name)
    with pytest.raises(InputError, match=rf"{out / name} is a FIFO"):
        within(30, run_bank, spec, out, workers=0, progress=False, restart=True)
    assert stat.S_ISFIFO(os.lstat(out / name).st_mode)


# --- a damaged bank.json -----------------------------------------------------------------

@pytest.mark.parametrize("damage", ["not json", "checksum"])
def test_a_damaged_bank_record_is_discarded_by_restart(tmp_path: Path, damage: str) -> None:
    spec, out = spec_file(tmp_path), tmp_path / "b"
    run_bank(spec, out, workers=0, progress=False, sheet=False)
    record = out / "bank.json"
    if damage == "not json":
        record.write_text("{ truncated")
    else:
        record.write_text(record.read_text().replace('"t"', '"u"', 1))
    with pytest.raises(InputError, match=r"bank\.json.*run with --restart"):
        run_bank(spec, out, workers=0, progress=False, sheet=False)
    s = run_bank(spec, out, workers=0, progress=False, sheet=False, restart=True)
    assert (s.rendered, s.skipped) == (2, 0)  # its nodes discarded with it
    again = run_bank(spec, out, workers=0, progress=False, sheet=False)
    assert (again.rendered, again.skipped) == (0, 2)


# --- node identity: two banks of one spec on one scheduler -------------------------------

def test_two_banks_of_one_spec_on_one_scheduler_are_two_banks(tmp_path: Path) -> None:
    """Keys of the spec's digest alone made the second bank's tasks the first's: its folder
    got no nodes. Both run at once on one single-threaded worker."""
    from distributed import LocalCluster

    spec = spec_file(tmp_path, MONTE_CARLO.format(samples=65536), "mc")
    jobs = [{"digest": "d" * 64, "out": str(tmp_path / x), "stem": NODE} for x in "ab"]
    assert node.task_key(jobs[0]) != node.task_key(jobs[1])
    results: dict = {}
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster:
        def bank(name: str) -> None:
            results[name] = run_bank(spec, tmp_path / name, scheduler=cluster.scheduler_address,
                                     progress=False, sheet=False)

        runs = [threading.Thread(target=bank, args=(x,)) for x in "ab"]
        for t in runs:
            t.start()
        for t in runs:
            t.join(120)
    assert sorted(results) == ["a", "b"]
    for x in "ab":
        assert results[x].rendered == 2
        assert len(list((tmp_path / x / "nodes").glob("*.exr"))) == 2


# --- the workers' own lensrt -------------------------------------------------------------

def test_a_worker_uses_its_own_lensrt_library(tmp_path: Path, monkeypatch) -> None:
    own = tmp_path / "own" / "liblensrt.so"
    own.parent.mkdir()
    shutil.copy(LIBRARY, own)
    job = {"library": "/driver/only/liblensrt.so", "spec": {"render": {"threads": 1}}}
    monkeypatch.setenv("LENSRT_LIBRARY", str(own))
    assert node.worker_library(job) == str(own)
    rt, _ = within(30, node._context, job)  # a new thread: a context of its own
    assert rt.lib._name == str(own)
    monkeypatch.delenv("LENSRT_LIBRARY")
    assert node.worker_library({"library": str(own)}) == str(own)  # the driver's, here
    assert node.worker_library(job) == str(LIBRARY)  # neither: the binding's default


# --- CPU-seconds -------------------------------------------------------------------------

def test_cpu_seconds_are_measured_per_task(tmp_path: Path) -> None:
    import json

    s = run_bank(spec_file(tmp_path), tmp_path / "b", workers=0, progress=False, sheet=False)
    records = [json.loads(p.read_text()) for p in sorted((tmp_path / "b" / "nodes").glob(
        "*.json"))]
    assert len(records) == 2
    for r in records:  # one lensrt thread: the task's thread's CPU time, at most its wall
        assert 0 < r["cpu_seconds"] <= r["seconds"] * 1.05 + 0.01, r
    assert s.cpu_seconds == pytest.approx(sum(r["cpu_seconds"] for r in records))
