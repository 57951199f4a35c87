"""Banks on Dask (issue 23): a LocalCluster bank equals the one-process bank byte for byte;
a worker killed while it holds a task and a run killed mid-node both end in the same
bank; a rerun renders nothing; bad specs, foreign folders and grids outside the lens are
refused before any task starts.

Lens 0001's committed table, tiny windows (24 x 24 pixels, 2 wavelengths) so that a node
takes about a second of Monte Carlo (262144 samples per wavelength in 4 checkpoints, long
enough to be killed mid-task) or a fraction of one by the cells integrator.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
import zlib
from pathlib import Path

import pytest
from bank_specs import bank_spec

from lensfit.banks.run import run_bank
from lensfit.banks.spec import SpecError, load_spec
from lensfit.common.errors import InputError

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "runtime" / "python"))
from lensrt_ctypes import LIBRARY  # noqa: E402

pytestmark = pytest.mark.skipif(not LIBRARY.exists(),
                                reason=f"needs {LIBRARY}: build it with `make runtime`")

SPEC = bank_spec("{name}", fields_x=(0, 5, 10), pixels=24, render="{render}")
MONTE_CARLO = 'integrator = "monte-carlo"\nsamples = 262144\ncheckpoints = 4'
CELLS = 'integrator = "cells"\ntarget_error = 0.02'


def spec_file(tmp_path: Path, render: str = CELLS, name: str = "t", **replace: str) -> Path:
    text = SPEC.format(name=name, render=render)
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    p = tmp_path / f"{name}.toml"
    p.write_text(text)
    return p


def bank_bytes(folder: Path) -> dict[str, int]:
    """CRC-32 of every file a renderer reads (the index and the node EXRs)."""
    files = [folder / "bank.index", *sorted((folder / "nodes").glob("*.exr"))]
    return {p.name: zlib.crc32(p.read_bytes()) for p in files}


def leftovers(folder: Path) -> list[str]:
    """Anything in nodes/ but the finished nodes' EXRs and records."""
    return sorted(p.name for p in (folder / "nodes").iterdir()
                  if p.suffix not in (".exr", ".json") or ".tmp" in p.name
                  or ".stage" in p.name)


@pytest.fixture(scope="module")
def reference_mc(tmp_path_factory) -> Path:
    """The Monte Carlo bank rendered in one process, no Dask."""
    tmp = tmp_path_factory.mktemp("ref")
    out = tmp / "bank"
    s = run_bank(spec_file(tmp, MONTE_CARLO, "mc"), out, workers=0, progress=False,
                 sheet=False)
    assert (s.nodes, s.rendered, s.skipped) == (3, 3, 0)
    return out


def test_local_cluster_equals_one_process(tmp_path: Path) -> None:
    spec = spec_file(tmp_path)
    one = run_bank(spec, tmp_path / "one", workers=0, progress=False)
    two = run_bank(spec, tmp_path / "two", workers=2, progress=False)
    assert (one.nodes, two.nodes, two.rendered) == (3, 3, 3)
    assert bank_bytes(tmp_path / "one") == bank_bytes(tmp_path / "two")
    assert (tmp_path / "two" / "contact-sheet.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # Every node refined to the target (the cells estimate within 2%)
    assert 0 <= two.worst_error <= 0.02
    # A rerun of the same spec finds every node finished and renders nothing
    again = run_bank(spec, tmp_path / "two", workers=0, progress=False)
    assert (again.rendered, again.skipped) == (0, 3)
    assert bank_bytes(tmp_path / "two") == bank_bytes(tmp_path / "one")
    assert leftovers(tmp_path / "two") == []


def test_threads_of_one_worker_render_the_same_bank(tmp_path: Path) -> None:
    """A worker running tasks in several threads of one process (`dask worker`'s default
    on a 2-core machine; here a LocalCluster without processes): every node renders, byte
    for byte as in one process (issue 37: caches shared by the threads corrupted nodes)."""
    from distributed import LocalCluster

    spec = spec_file(tmp_path, **{"field_x_deg = [0, 5, 10]": "field_x_deg = [0, 2, 4, 6, 8, 10]"})
    one = run_bank(spec, tmp_path / "one", workers=0, progress=False, sheet=False)
    with LocalCluster(n_workers=1, threads_per_worker=3, processes=False,
                      dashboard_address=None) as cluster:
        many = run_bank(spec, tmp_path / "many", scheduler=cluster.scheduler_address,
                        progress=False, sheet=False)
    assert (one.nodes, many.nodes, many.rendered) == (6, 6, 6)
    assert bank_bytes(tmp_path / "many") == bank_bytes(tmp_path / "one")


def test_each_thread_has_its_own_context_and_lenses() -> None:
    """The invariant behind the test above, checked directly: two threads asking at once
    get two contexts and two loaded tables, and a thread asking again gets its own back."""
    from lensfit.banks import node

    table = str(ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table")
    job = {"library": str(LIBRARY), "spec": {"render": {"threads": 1}}}
    start, got = threading.Barrier(2), {}

    def work(i: int) -> None:
        start.wait()
        rt, threads = node._context(job)
        lens = node._load(rt, threads, job["library"], table, node.file_crc32(table))
        got[i] = (rt, node._context(job)[0], lens,
                  node._load(rt, threads, job["library"], table, node.file_crc32(table)))

    workers = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for t in workers:
        t.start()
    for t in workers:
        t.join()
    (rt0, again0, lens0, lens0b), (rt1, _, lens1, _) = got[0], got[1]
    assert rt0 is again0 and lens0.value == lens0b.value  # a thread reuses its own
    assert rt0 is not rt1 and lens0.value != lens1.value  # never another thread's


def test_node_of_another_lensrt_version_is_rendered_again(tmp_path: Path) -> None:
    """A node rendered by another lensrt (0.8.0 changed the image's unit and the pixel's
    filter) is not finished: its record names the version, and a rerun renders it again
    to the same bytes as a fresh bank."""
    import json

    from lensfit.codegen.checked_json import checked_json_text, load_checked_json

    spec = spec_file(tmp_path)
    first = run_bank(spec, tmp_path / "b", workers=0, progress=False, sheet=False)
    assert first.rendered == 3
    record = sorted((tmp_path / "b" / "nodes").glob("*.json"))[0]
    doc = load_checked_json(record, "render the node again")
    assert doc["lensrt_version"].count(".") == 2
    doc = json.loads(json.dumps(doc))
    doc.pop("checksum", None)
    doc["lensrt_version"] = "0.7.0"
    record.write_text(checked_json_text(doc))
    again = run_bank(spec, tmp_path / "b", workers=0, progress=False, sheet=False)
    assert (again.rendered, again.skipped) == (1, 2)
    fresh = run_bank(spec, tmp_path / "c", workers=0, progress=False, sheet=False)
    assert fresh.rendered == 3
    assert bank_bytes(tmp_path / "b") == bank_bytes(tmp_path / "c")


def test_worker_killed_while_it_holds_a_task(tmp_path: Path, reference_mc: Path) -> None:
    from distributed import Client

    from lensfit.banks.engine import local_cluster

    spec = spec_file(tmp_path, MONTE_CARLO, "mc")
    out = tmp_path / "bank"
    result: dict = {}
    with local_cluster(2) as cluster, Client(cluster) as client:
        pids = client.run(os.getpid)
        run = threading.Thread(target=lambda: result.update(summary=run_bank(
            spec, out, scheduler=cluster.scheduler_address, progress=False, sheet=False)))
        run.start()
        # SIGKILL the worker process holding a node once its render is under way
        killed = None
        deadline = time.monotonic() + 120
        while killed is None and time.monotonic() < deadline and run.is_alive():
            busy = [w for w, keys in client.processing().items() if keys]
            if busy:
                time.sleep(0.3)  # into the render (a node is about a second)
                if client.processing().get(busy[0]):  # still holding a task: kill it now
                    os.kill(pids[busy[0]], signal.SIGKILL)
                    killed = busy[0]
            time.sleep(0.01)
        run.join(240)
    assert killed is not None, "no worker was seen holding a task"
    assert "summary" in result, "the bank did not finish after a worker was killed"
    assert result["summary"].nodes == 3
    assert bank_bytes(out) == bank_bytes(reference_mc)
    assert leftovers(out) == []


def test_killed_run_resumes_to_the_same_bank(tmp_path: Path, reference_mc: Path) -> None:
    spec = spec_file(tmp_path, MONTE_CARLO, "mc")
    out = tmp_path / "bank"
    cmd = [sys.executable, "-m", "lensfit.cli", "bank", str(spec), "-o", str(out),
           "--workers", "0", "--no-progress", "--no-sheet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    # Kill the run once the second node has saved a checkpoint (the first is finished)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if list((out / "nodes").glob("*-x1.*phasors")):
            break
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.wait(30)
    assert list((out / "nodes").glob("*-x1.*phasors")), "the run was not killed mid-node"
    assert not (out / "bank.index").exists()
    s = run_bank(spec, out, workers=0, progress=False, sheet=False)
    assert s.skipped >= 1 and s.rendered >= 1
    assert bank_bytes(out) == bank_bytes(reference_mc)
    assert leftovers(out) == []


def test_changed_spec_or_table_is_never_mixed(tmp_path: Path) -> None:
    spec = spec_file(tmp_path)
    out = tmp_path / "bank"
    run_bank(spec, out, workers=0, progress=False, sheet=False)
    before = bank_bytes(out)
    # Another spec in the same folder: refused, naming the folder's record; nothing touched
    other = spec_file(tmp_path, CELLS.replace("0.02", "0.03"), "t")
    with pytest.raises(InputError, match=r"bank\.json: this folder holds a bank of another "
                                         r"spec .*--restart"):
        run_bank(other, out, workers=0, progress=False, sheet=False)
    assert bank_bytes(out) == before
    # Another lens's table: refused the same way
    lens9 = spec_file(tmp_path, CELLS, "t", **{'lens = "0001"': 'lens = "0009"'})
    with pytest.raises(InputError, match=r"another (table|lens)"):
        run_bank(lens9, out, workers=0, progress=False, sheet=False)
    # --restart discards the old nodes and renders the new spec's
    s = run_bank(other, out, workers=0, progress=False, sheet=False, restart=True)
    assert (s.rendered, s.skipped) == (3, 0)


def test_damaged_node_is_rendered_again(tmp_path: Path) -> None:
    spec = spec_file(tmp_path)
    out = tmp_path / "bank"
    run_bank(spec, out, workers=0, progress=False, sheet=False)
    before = bank_bytes(out)
    exr = sorted((out / "nodes").glob("*.exr"))[1]
    raw = bytearray(exr.read_bytes())
    raw[len(raw) // 2] ^= 0x10
    exr.write_bytes(bytes(raw))
    s = run_bank(spec, out, workers=0, progress=False, sheet=False)
    assert (s.rendered, s.skipped) == (1, 2)
    assert bank_bytes(out) == before


@pytest.mark.parametrize("change, message", [
    ({"[render]": "[render]\nsampels = 3"}, r"key 'render.sampels': unknown key"),
    ({"field_x_deg = [0, 5, 10]": "field_x_deg = []"}, r"key 'grid.field_x_deg': expected a "
                                                       r"non-empty list"),
    ({"field_x_deg = [0, 5, 10]": "field_x_deg = [0, nan]"}, r"key 'grid.field_x_deg\[1\]': "
                                                             r"expected angles"),
    ({"field_x_deg = [0, 5, 10]": "field_x_deg = [5, 0]"},
     r"key 'grid.field_x_deg': expected increasing"),
    ({"f_numbers = [8]": "f_numbers = [true]"}, r"key 'grid.f_numbers\[0\]': expected "
                                               r"f-numbers in \(0, 1000\], found true"),
    # Absurd values that rendered non-finite fields in every node, blaming the table
    ({"f_numbers = [8]": "f_numbers = [1e308]"}, r"key 'grid.f_numbers\[0\]': expected "
                                                r"f-numbers in \(0, 1000\], found 1e\+308"),
    ({"size_mm = [0.06, 0.06]": "size_mm = [1e-300, 0.06]"},
     r"key 'window.size_mm': expected pixels of at least 1e-05 mm .* 1e-300 mm over 24 "
     r"pixels in x"),
    ({"pixels = [24, 24]": "pixels = [24]"}, r"key 'window.pixels': expected \[width, height\]"),
    ({"[grid]": "[grid]\nfocus_offsets_mm = [0, 0]"},
     r"key 'grid.focus_offsets_mm': expected distinct"),
])
def test_bad_specs_are_refused(tmp_path: Path, change: dict, message: str) -> None:
    spec = spec_file(tmp_path, CELLS, "t", **change)
    with pytest.raises(SpecError, match=rf"t\.toml: {message}"):
        load_spec(spec)
    with pytest.raises(SpecError):
        run_bank(spec, tmp_path / "bank", workers=0, progress=False)
    assert not (tmp_path / "bank").exists()  # refused before any task (or folder)


@pytest.mark.parametrize("change, message", [
    ({"wavelengths_nm = [500, 600]": "wavelengths_nm = [300, 600]"},
     r"grid.wavelengths_nm\[0\]': 300.0 nm is outside the lens's 380-780 nm"),
    ({"f_numbers = [8]": "f_numbers = [1.5]"}, r"f/1.5 is wider than the lens's f/2"),
    ({"field_x_deg = [0, 5, 10]": "field_x_deg = [0, 5, 40]"},
     r"grid.field_x_deg\[2\]' = 40.0 and 'grid.field_y_deg\[0\]' = 0.0: the node at "
     r"\(40, 0\) deg is outside the lens's fitted field"),
    # Each axis inside the lens's 12.2 deg field, the corner (10, 10) deg outside its circle
    ({"field_y_deg = [0]": "field_y_deg = [0, 10]"},
     r"the node at \(10, 10\) deg is outside the lens's fitted field, an ellipse of "
     r"12.21 x 12.21 deg"),
    ({'lens = "0001"': 'lens = "99"'}, r"key 'lens': '99': no such lens"),
])
def test_grid_outside_the_lens_is_refused_before_any_task(tmp_path: Path, change: dict,
                                                          message: str) -> None:
    spec = spec_file(tmp_path, CELLS, "t", **change)
    with pytest.raises(SpecError, match=message):
        run_bank(spec, tmp_path / "bank", workers=0, progress=False)
    assert not (tmp_path / "bank").exists()


def test_cli_reports_a_bad_spec_in_one_line(tmp_path: Path) -> None:
    spec = spec_file(tmp_path, CELLS, "t", **{"[render]": "[render]\nthreads = -1"})
    r = subprocess.run([sys.executable, "-m", "lensfit.cli", "bank", str(spec), "-o",
                        str(tmp_path / "b")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "key 'render.threads'" in r.stderr, r.stderr


def test_flare_bank_refuses_one_table_under_two_labels(tmp_path: Path) -> None:
    """A ghosts.json whose two labels name one table would add its flare twice in every
    node: refused naming the spec's key, the index and the table."""
    from lensfit.banks.run import ghost_tables
    from lensfit.codegen.checked_json import checked_json_text

    spec = load_spec(spec_file(tmp_path, CELLS, "flare", **{
        "[render]": '[flare]\nghosts = ["0-2", "2-4"]\n[render]'}))
    folder = tmp_path / "lens"
    (folder / "ghosts").mkdir(parents=True)
    (folder / "ghosts" / "ghost_1_3.table").write_text("table")
    entries = [{"label": label, "first": 1, "second": 3} for label in ("0-2", "2-4")]
    (folder / "ghosts" / "ghosts.json").write_text(checked_json_text(
        {"format": "lensfit-ghosts 1", "ghosts": entries}))
    with pytest.raises(SpecError, match=r"flare.toml: key 'flare.ghosts': .*ghosts.json: "
                                        r"ghost table .*ghost_1_3.table is given twice"):
        ghost_tables(spec, folder / "lens0001.table", "flare.toml")


def test_flare_bank_holds_direct_and_ghost_layers(tmp_path: Path) -> None:
    """A flare bank: ghost 0-2 of 0001 with the direct image in one fixed window (its
    footprint at f/16 for a light near (-6, -4) deg); the node EXR's unprefixed channels
    are the sum of its direct. and flare. layers, and the C reader (registration window:
    no shift) gives a node's own image at that node's field point."""
    import numpy as np
    from lensrt_ctypes import Bank, Lensrt
    from lensrt_exr import exr_layers, read_spectral_exr

    spec = spec_file(tmp_path, 'integrator = "cells"\ntarget_error = 0.05', "flare", **{
        "field_x_deg = [0, 5, 10]": "field_x_deg = [-6, -5]",
        "field_y_deg = [0]": "field_y_deg = [-4]", "f_numbers = [8]": "f_numbers = [16]",
        "wavelengths_nm = [500, 600]": "wavelengths_nm = [550]",
        "pixels = [24, 24]": "pixels = [24, 16]",
        "size_mm = [0.06, 0.06]": "size_mm = [1.2, 0.8]\ncenter_mm = [-10.1, -6.7]",
        "[render]": '[flare]\nghosts = ["0-2"]\n[render]'})
    out = tmp_path / "bank"
    s = run_bank(spec, out, workers=0, progress=False, sheet=False)
    assert s.nodes == 2 and 0 <= s.worst_error <= 0.05
    exr = out / "nodes" / "f0-z0-d0-y0-x0.exr"
    assert exr_layers(exr) == ["", "direct", "flare"]
    total, direct, flare = (read_spectral_exr(exr, layer=x).spectral
                            for x in ("", "direct", "flare"))
    assert flare.sum() > 0
    # The sum in float: within a float's rounding of each pixel's two terms
    np.testing.assert_allclose(total, direct + flare, rtol=2.0**-22, atol=0)
    assert "registration window" in (out / "bank.index").read_text()
    rt = Lensrt(threads=1)
    with Bank(rt, out / "bank.index") as bank:
        img, _ = bank.psf(-6.0, -4.0, 550.0, f_number=16)
    np.testing.assert_array_equal(img, total[0])


def test_unreachable_scheduler_is_one_line(tmp_path: Path) -> None:
    spec = spec_file(tmp_path)
    r = subprocess.run([sys.executable, "-m", "lensfit.cli", "bank", str(spec), "-o",
                        str(tmp_path / "b"), "--scheduler", "tcp://127.0.0.1:9",
                        "--no-progress"], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "2s"})
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "--scheduler tcp://127.0.0.1:9: cannot reach" in \
        r.stderr, r.stderr


def test_window_off_every_image_is_refused_before_anything_is_written(tmp_path: Path) -> None:
    """A fixed window 5 mm from the light's image at every node (fields 0 and 5 deg: image
    points at 0 and 8.7 mm) held 4e-9 of the PSF's power and was written as a bank, pixels
    ten orders below the peak, exit 0 (issue 39). Refused from the spec and the lens: one
    line naming the key, the node, the window and what to change; no folder."""
    spec = spec_file(tmp_path, CELLS, "t", **{
        "size_mm = [0.06, 0.06]": "size_mm = [0.06, 0.06]\ncenter_mm = [4.0, 4.0]"})
    with pytest.raises(SpecError) as e:
        run_bank(spec, tmp_path / "bank", workers=0, progress=False)
    msg = str(e.value)
    assert "\n" not in msg
    assert msg.startswith(f"{spec}: key 'window.center_mm': the window misses the light's "
                          "image at every node"), msg
    assert "node f0-z0-d0-y0-x0 (field (0, 0) deg, f/8" in msg, msg
    assert "window of 0.06 x 0.06 mm centred on (4, 4) mm" in msg, msg
    assert "move window.center_mm onto the image" in msg, msg
    assert not (tmp_path / "bank").exists()
    r = subprocess.run([sys.executable, "-m", "lensfit.cli", "bank", str(spec), "-o",
                        str(tmp_path / "b"), "--no-progress"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert not (tmp_path / "b").exists()


def test_node_whose_window_misses_its_image_fails_alone(tmp_path: Path) -> None:
    """A fixed window on the axis's image point: the node at 0 deg holds its PSF, the one
    at 12 deg (image at 21.1 mm: 5.8e-11 of its PSF in the window) essentially none of
    it. That node fails in one line naming it, the window and what to change, nothing of
    it written; the other is finished."""
    from lensfit.banks.engine import TaskError

    spec = spec_file(tmp_path, CELLS, "t", **{
        "field_x_deg = [0, 5, 10]": "field_x_deg = [0, 12]",
        "size_mm = [0.06, 0.06]": "size_mm = [0.06, 0.06]\ncenter_mm = [0, 0]"})
    out = tmp_path / "bank"
    with pytest.raises(TaskError) as e:
        run_bank(spec, out, workers=0, progress=False, sheet=False)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("1 of 2 bank t failed: "), msg
    assert ("-f0-z0-d0-y0-x1: node f0-z0-d0-y0-x1 (field (12, 0) deg, f/8, focus offset 0 "
            "mm): the window of 0.06 x 0.06 mm centred on (0, 0) mm holds ") in msg, msg
    assert ("of the PSF's power (the light's image is at (21.1, 0) mm, 21.1 mm from the "
            "window)") in msg, msg
    assert "nothing written: move window.center_mm onto the image" in msg, msg
    names = sorted(p.name for p in (out / "nodes").iterdir())
    assert names == ["f0-z0-d0-y0-x0.exr", "f0-z0-d0-y0-x0.json"], names
    assert not (out / "bank.index").exists()


def test_window_miss_thresholds() -> None:
    """node.window_miss: below MISS_FRACTION of the centred window's power the direct
    image misses; a flare bank's window is kept while its ghosts hold
    MISS_FRACTION_GHOSTS of it, whatever the direct image's share."""
    import math

    from lensfit.banks.node import MISS_FRACTION, MISS_FRACTION_GHOSTS, window_miss

    spec = {"window": {"center_mm": [4.0, 0.0], "size_mm": [0.06, 0.06]}}
    c = {"field_x_deg": 0.0, "field_y_deg": 0.0, "f_number": 8.0, "focus_offset_mm": 0.0,
         "distance_mm": math.inf}
    chief = [(0.0, 0.0)]
    ref = 222.0
    assert window_miss(spec, c, chief, 2 * MISS_FRACTION * ref, None, ref, "n") is None
    why = window_miss(spec, c, chief, 0.5 * MISS_FRACTION * ref, None, ref, "n")
    assert why is not None and "holds 5.0e-07 of the PSF's power" in why
    assert "3.97 mm from the window" in why
    assert window_miss(spec, c, chief, 0.0, 2 * MISS_FRACTION_GHOSTS * ref, ref, "n") is None
    why = window_miss(spec, c, chief, 0.0, 0.5 * MISS_FRACTION_GHOSTS * ref, ref, "n")
    assert why is not None and "the ghosts 5.0e-10 of it" in why
