"""lensrt-psf refuses bad input at once: exit status 2, one line naming the problem, no
output written (issue 14, defects 3, 6 and 7).

Each case is a command that today's tool must refuse before rendering; the renders are
tiny (16 x 16, 2 wavelengths, 64 samples) so that a case which wrongly renders is quick
and is caught by its exit status and by the output file it leaves. Set LENSRT_PSF to test
another build of the tool (default build/runtime/runtime/lensrt-psf, as `make` builds it).
"""

from __future__ import annotations

import os
import re
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
PSF = Path(os.environ.get("LENSRT_PSF", ROOT / "build" / "runtime" / "runtime" / "lensrt-psf"))
LENS0001 = ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table"
BASE = ["--f-number", "8", "--resolution", "16x16", "--samples", "64", "--wavelengths", "2",
        "--quiet"]


@pytest.fixture(autouse=True)
def _needs_tool() -> None:
    if not PSF.exists():
        pytest.skip(f"{PSF} is not built")


def run(*args: str, lens: str = str(LENS0001)) -> subprocess.CompletedProcess:
    return subprocess.run([str(PSF), "--lens", lens, *BASE, *args], capture_output=True,
                          text=True, timeout=120)


def refused(r: subprocess.CompletedProcess, *words: str) -> None:
    """Exit 2, exactly one line on stderr containing every word."""
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert len(lines) == 1, r.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.mark.parametrize("option,value", [
    ("--light", "inf,5"), ("--light", "5,inf"), ("--light", "0,0,100,inf"),
    ("--light", "nan,0"), ("--center", "inf,inf"), ("--center", "0,inf"),
    ("--size", "inf"), ("--size", "0.1xinf"), ("--wavelengths", "500,inf"),
    ("--wavelengths", "inf,600"), ("--focus", "inf"), ("--wavelength", "inf"),
])
def test_non_finite_values_are_refused(tmp_path: Path, option: str, value: str) -> None:
    out = tmp_path / "out.exr"
    refused(run(option, value, "-o", str(out)), option, value)
    assert not out.exists()


def test_light_at_infinity_still_means_infinity(tmp_path: Path) -> None:
    # The distance alone may be inf: the same light as distance 0 (the documented meaning),
    # hence the same phasor sums bit for bit (same seed, same scene). The sums are the
    # file's last 16 x 16 pixels x 2 wavelengths x 2 doubles; the header before them
    # holds the render time.
    a, b = tmp_path / "a.phasors", tmp_path / "b.phasors"
    ra = run("--light", "-1,-2,inf", "--save-phasors", str(a), "--no-estimate")
    rb = run("--light", "-1,-2,0", "--save-phasors", str(b), "--no-estimate")
    assert ra.returncode == 0 and rb.returncode == 0, ra.stderr + rb.stderr
    n = 16 * 16 * 2 * 2 * 8
    assert a.read_bytes()[-n:] == b.read_bytes()[-n:]


def test_one_wavelength(tmp_path: Path) -> None:
    # --wavelength 550 renders one wavelength; --wavelengths 550 stays a count (the EXR
    # of the single wavelength is far smaller than one of 550 channels)
    out = tmp_path / "one.exr"
    r = run("--wavelength", "550", "-o", str(out), "--no-estimate")
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size < 16 * 16 * 4 * 20
    refused(run("--wavelength", "550nm", "-o", str(tmp_path / "x.exr")), "--wavelength", "550nm")
    assert "--wavelength NM" in subprocess.run([str(PSF), "--help"], capture_output=True,
                                               text=True).stdout


@pytest.mark.parametrize("option", ["-o", "--png", "--save-phasors"])
def test_folder_as_output_is_refused_before_rendering(tmp_path: Path, option: str) -> None:
    other = tmp_path / "other.phasors"
    extra = [] if option == "--save-phasors" else ["--save-phasors", str(other)]
    refused(run(option, str(tmp_path), *extra), str(tmp_path))
    assert not other.exists()


def test_empty_output_is_refused_before_rendering(tmp_path: Path) -> None:
    other = tmp_path / "other.phasors"
    refused(run("-o", "", "--save-phasors", str(other)), "cannot write")
    assert not other.exists()


@pytest.mark.parametrize("extra", [["--samples", "1"], ["--samples", "3"],
                                   ["--samples", "1", "--no-estimate"]])
def test_unbiased_with_too_few_samples_is_refused_before_rendering(tmp_path: Path, extra) -> None:
    out = tmp_path / "out.phasors"
    refused(run("--estimator", "unbiased", *extra, "--save-phasors", str(out)), "unbiased")
    assert not out.exists()


def test_library_error_printed_once(tmp_path: Path) -> None:
    # A lens table that does not parse: the loader's message, once (it used to come
    # through the log hook and again from the tool)
    bad = tmp_path / "bad.table"
    bad.write_text("not a lens table\n")
    refused(run("-o", str(tmp_path / "out.exr"), lens=str(bad)), str(bad))


def test_folder_as_lens_is_refused(tmp_path: Path) -> None:
    folder = tmp_path / "x.table"
    folder.mkdir()
    refused(run("-o", str(tmp_path / "out.exr"), lens=str(folder)), str(folder), "regular file")


def test_fifo_as_lens_is_refused(tmp_path: Path) -> None:
    # Without the check the open blocks forever: the timeout fails the test
    fifo = tmp_path / "f.table"
    os.mkfifo(fifo)
    r = subprocess.run([str(PSF), "--lens", str(fifo), *BASE, "-o", str(tmp_path / "o.exr")],
                       capture_output=True, text=True, timeout=20)
    refused(r, str(fifo), "regular file")


@pytest.mark.parametrize("kind", ["folder", "fifo"])
def test_loader_refuses_non_regular_files(tmp_path: Path, kind: str) -> None:
    # lensrt_lens_load itself (not only the tool): a folder used to make it ask for 2^63
    # bytes, a FIFO to block in the open; run in a child so that a blocking open fails
    # the test by its timeout instead of hanging the run
    path = tmp_path / "x.table"
    path.mkdir() if kind == "folder" else os.mkfifo(path)
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import lensrt_ctypes as L\n"
            "try:\n    L.Lensrt().load(sys.argv[2])\nexcept L.LensrtError as e:\n"
            "    print(e); sys.exit(7)\n")
    r = subprocess.run([sys.executable, "-c", code, str(ROOT / "runtime" / "python"), str(path)],
                       capture_output=True, text=True, timeout=20)
    assert r.returncode == 7, r.stdout + r.stderr
    assert "not a regular file" in r.stdout and str(path) in r.stdout


@pytest.mark.parametrize("kind", ["symlink", "fifo"])
def test_output_that_is_no_regular_file_refused_before_rendering(tmp_path, kind):
    # The library refuses to replace a link or a FIFO (io/atomic_file.c); the tool says so
    # before it renders, not after
    target = tmp_path / "real.exr"
    out = tmp_path / "o.exr"
    if kind == "symlink":
        out.symlink_to(target)
    else:
        os.mkfifo(out)
    r = run("-o", str(out))
    refused(r, str(out), "symbolic link" if kind == "symlink" else "not a regular file")
    assert not target.exists()
    assert out.is_symlink() if kind == "symlink" else stat.S_ISFIFO(os.lstat(out).st_mode)


def test_error_estimate_temporaries_of_killed_runs_removed(tmp_path):
    # A run killed during its error estimate leaves <out>.mc-<pid>-a/b.phasors; the next
    # estimate for the same output removes those of processes that no longer exist
    dead = _dead_pid()
    out = tmp_path / "o.exr"
    stale = [tmp_path / f"o.exr.mc-{dead}-a.phasors", tmp_path / f"o.exr.mc-{dead}-b.phasors"]
    live = tmp_path / f"o.exr.mc-{os.getpid()}-a.phasors"
    for p in [*stale, live]:
        p.write_bytes(b"left by a killed run")
    r = run("-o", str(out))
    assert r.returncode == 0, r.stderr
    assert "error estimate" in r.stdout  # the estimate ran
    assert not any(p.exists() for p in stale)
    assert live.exists()


def _dead_pid() -> int:
    """The pid of a child that has exited and been reaped (no process has it now)."""
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


# ------------------------------------------------- the cells integrator's options -----


@pytest.mark.parametrize("extra", [
    ("--resume", "x.phasors"), ("--merge", "x.phasors"), ("--save-phasors", "x.phasors"),
    ("--no-estimate",), ("--estimator", "unbiased"), ("--max-samples", "1024"),
])
@pytest.mark.parametrize("integrator", ["cells", "fourier", "auto"])
def test_cells_refuses_monte_carlo_options(tmp_path: Path, extra, integrator) -> None:
    out = tmp_path / "out.exr"
    refused(run("--integrator", integrator, *extra, "-o", str(out)), f"--integrator {integrator}")
    assert not out.exists()


@pytest.mark.parametrize("args,word", [
    (("--integrator", "quadrature"), "montecarlo, cells, fourier or auto"),
    (("--rings", "1"), "2..4096"), (("--rings", "5000"), "2..4096"),
    (("--max-rings", "1"), "2..4096"),
    (("--integrator", "fourier", "--max-rings", "64"), "--max-rings goes with --integrator cells"),
    (("--samples", "1024", "--max-rings", "64"), "--max-rings goes with --integrator cells"),
    (("--integrator", "cells", "--rings", "64", "--max-rings", "32"), "below --rings"),
    (("--nodes", "-1"), "0 (chosen) or 1..4096"), (("--nodes", "5000"), "0 (chosen) or 1..4096"),
    (("--integrator", "cells", "--max-nodes", "64"), "--max-nodes goes with --integrator fourier"),
    (("--integrator", "fourier", "--nodes", "64", "--max-nodes", "32"), "below --nodes"),
])
def test_cells_option_values_are_refused(tmp_path: Path, args, word) -> None:
    out = tmp_path / "out.exr"
    refused(run(*args, "-o", str(out)), word)
    assert not out.exists()


def test_cells_render_and_gl_refusal(tmp_path: Path) -> None:
    # A small cells render prints its estimate on stdout and writes the EXR; the GL device
    # has no cells integrator: exit 3 with the library's message, nothing written
    out = tmp_path / "out.exr"
    r = run("--integrator", "cells", "--rings", "4", "--quiet", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert "Cells error estimate:" in r.stdout and out.is_file()
    gl = tmp_path / "gl.exr"
    r = run("--integrator", "cells", "--rings", "4", "--device", "gl", "--quiet", "-o", str(gl))
    assert r.returncode == 3, (r.returncode, r.stderr)
    assert "cells" in r.stderr or "GL" in r.stderr or "no GL" in r.stderr
    assert not gl.exists()


def test_default_is_fourier_then_monte_carlo_with_its_options(tmp_path: Path) -> None:
    # Without an integrator: auto (the Fourier integrator here: no clip cuts this PSF's
    # aperture), its estimate on stdout and "fourier" in the EXR; with a Monte Carlo
    # option (--samples), Monte Carlo as before; the GL device refuses Fourier: exit 3
    out = tmp_path / "out.exr"
    base = [a for a in BASE if a not in ("--samples", "64")]  # BASE's --samples picks Monte Carlo
    r = subprocess.run([str(PSF), "--lens", str(LENS0001), *base, "-o", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "Fourier error estimate:" in r.stdout and out.is_file()
    assert b"fourier" in out.read_bytes() and b"lensrt/fourierNodes" in out.read_bytes()
    # With a target the first rule is the library's choice for it (lensrt_render_fourier_
    # nodes): fewer nodes than the default rule at 1%, and the estimate within the target
    said = [a for a in base if a != "--quiet"]  # the rules and estimates on stderr
    d, t = (subprocess.run([str(PSF), "--lens", str(LENS0001), *said, *extra, "-o",
                            str(tmp_path / f"{k}.exr")], capture_output=True, text=True,
                           timeout=120) for k, extra in enumerate(([], ["--target-error", "0.01"])))
    assert d.returncode == 0 and t.returncode == 0, (d.stderr, t.stderr)
    nodes = [int(n) for n in re.findall(r"(\d+) nodes: Fourier error estimate", d.stderr)]
    chosen = re.findall(r"(\d+) nodes: Fourier error estimate ([0-9.e+-]+)%", t.stderr)
    assert len(nodes) == 1 and len(chosen) >= 1, (d.stderr, t.stderr)
    assert int(chosen[0][0]) < nodes[0] and float(chosen[-1][1]) <= 1.0, (nodes, chosen)
    mc = tmp_path / "mc.exr"
    r = run("--samples", "256", "--quiet", "-o", str(mc))
    assert r.returncode == 0, r.stderr
    assert "Monte Carlo error estimate:" in r.stdout and b"montecarlo" in mc.read_bytes()
    gl = tmp_path / "gl.exr"
    r = run("--integrator", "fourier", "--device", "gl", "--quiet", "-o", str(gl))
    assert r.returncode == 3, (r.returncode, r.stderr)
    assert not gl.exists()


def test_an_ambiguous_lens_id_is_refused_with_its_choices(tmp_path: Path) -> None:
    # Two lenses that share the id 2004 (and a variant of one, named after its folder):
    # the id alone is refused naming the lenses' folders, sorted; a whole folder name
    # picks exactly one. Of a lens and its variants only, the id names the lens (0001 in
    # generated/ has its uncoated variant beside it)
    gen = tmp_path / "gen"
    for name in ("2004-b", "2004-a-uncoated", "2004-a", "20040-other", "0001-x",
                 "0001-x-uncoated"):
        (gen / name).mkdir(parents=True)
        (gen / name / f"lens{name.split('-')[0]}.table").write_bytes(LENS0001.read_bytes())
    out = tmp_path / "out.exr"
    r = run("--generated", str(gen), "-o", str(out), lens="2004")
    refused(r, "--lens", "'2004' is ambiguous", "3 folders", "(2004-a, 2004-a-uncoated, 2004-b)")
    assert not out.exists()
    for name, table in (("2004-a", "2004-a"), ("2004-a-uncoated", "2004-a-uncoated"),
                        ("20040", "20040-other"), ("0001", "0001-x"),
                        ("0001-x-uncoated", "0001-x-uncoated")):
        r = subprocess.run([str(PSF), "--lens", name, "--generated", str(gen), *BASE[:-1],
                            "-o", str(out)], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, (name, r.stderr)
        assert f"/{table}/lens" in r.stderr, (name, r.stderr)  # the progress line names it
        out.unlink()
    refused(run("--generated", str(gen), "-o", str(out), lens="2004-a-unc"),
            "unknown lens '2004-a-unc'")


def test_an_image_zero_everywhere_is_refused_and_nothing_is_written(tmp_path: Path) -> None:
    # A stop of f/1e20 lets no light through in double: exit 4, one line, no EXR, no PNG,
    # no phasor file, and the outputs of an earlier run are left as they were
    out, png, sums = tmp_path / "a.exr", tmp_path / "a.png", tmp_path / "a.phasors"
    for f in (out, png, sums):
        f.write_bytes(b"earlier")
    outs = ("-o", str(out), "--png", str(png), "--save-phasors", str(sums))
    r = subprocess.run([str(PSF), "--lens", str(LENS0001), *BASE[2:], "--f-number", "1e20", *outs],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 4, r.stderr
    assert "zero everywhere" in r.stderr and "f/1e+20" in r.stderr and "--allow-empty" in r.stderr
    assert all(f.read_bytes() == b"earlier" for f in (out, png, sums))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr", "a.phasors", "a.png"]
    # Asked for, it is written
    r = subprocess.run([str(PSF), "--lens", str(LENS0001), *BASE[2:], "--f-number", "1e20", *outs,
                        "--allow-empty"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert all(f.read_bytes() != b"earlier" for f in (out, png, sums))


def test_stale_files_of_killed_runs_are_removed_and_live_ones_kept(tmp_path: Path) -> None:
    # What a run killed by kill -9 leaves next to its outputs: a staged output, an estimate
    # half and the library's temporary of one. A dead pid's are removed by the next run
    # that writes there; a live process's (this test's) and foreign names are kept
    out = tmp_path / "a.exr"
    dead, live = _dead_pid(), os.getpid()
    stale = [f"a.exr.stage-{dead}", f"a.exr.mc-{dead}-a.phasors",
             f"a.exr.mc-{dead}-b.phasors.tmp-{dead}-123-0"]
    kept = [f"a.exr.stage-{live}", f"a.exr.mc-{live}-a.phasors", f"a.exr.stage-{dead}x",
            "a.exr.stage-notes"]
    for name in stale + kept:
        (tmp_path / name).write_bytes(b"x" * 1000)
    r = run("-o", str(out))
    assert r.returncode == 0, r.stderr
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted(["a.exr", *kept]), left


@pytest.mark.parametrize("decades", ["nan", "inf", "-3", "0"])
def test_decades_must_be_finite_and_positive(tmp_path: Path, decades: str) -> None:
    # The PNG's log range: NaN, inf and non-positive values were turned into 5; now exit 2
    r = run("-o", str(tmp_path / "o.exr"), "--png", str(tmp_path / "o.png"), "--decades", decades)
    refused(r, "--decades", "expected a positive number", f"'{decades}'")
    assert not list(tmp_path.iterdir())


def test_a_failed_resume_or_merge_writes_nothing(tmp_path: Path) -> None:
    # A resume from a corrupted file, or a merge of sums the render already holds, fails
    # after the outputs were checked: nothing is written (no EXR, PNG or --save-phasors
    # file, no stage), and the outputs of an earlier run are left as they were
    sums = tmp_path / "s.phasors"
    r = run("--no-estimate", "-o", str(tmp_path / "s.exr"), "--save-phasors", str(sums))
    assert r.returncode == 0, r.stderr
    bad = tmp_path / "bad.phasors"
    data = bytearray(sums.read_bytes())
    data[len(data) // 2] ^= 1
    bad.write_bytes(bytes(data))
    out, png, save = tmp_path / "a.exr", tmp_path / "a.png", tmp_path / "a.phasors"
    for f in (out, png, save):
        f.write_bytes(b"earlier")
    outs = ("-o", str(out), "--png", str(png), "--save-phasors", str(save))
    before = sorted(p.name for p in tmp_path.iterdir())
    r = run(*outs, "--resume", str(bad))
    refused(r, "bad.phasors", "fails its checksum")
    r = run(*outs, "--resume", str(sums), "--merge", str(sums))
    refused(r, "s.phasors", "would be counted twice")
    assert all(f.read_bytes() == b"earlier" for f in (out, png, save))
    assert sorted(p.name for p in tmp_path.iterdir()) == before


# ------------------------------------- the auto integrator never keeps a missed target -----


def test_auto_refines_falls_back_or_fails_never_keeps(tmp_path: Path) -> None:
    # Issue 39, item 3: --integrator auto keeps no image whose own estimate misses the
    # target (here auto's default, 1%). A Fourier rule of 6 nodes that may not be refined
    # (--max-nodes 8) estimates 37%: auto goes to the cells integrator, which refines from
    # 4 rings to within 1% and is kept (the image of a plain cells render of that mesh, bit
    # for bit); limited to 4 rings (1.8%) it fails: exit 5, one line naming both
    # integrators' estimates, nothing written. Before, the 37% Fourier image was kept
    sys.path.insert(0, str(ROOT / "runtime" / "python"))
    from lensrt_exr import read_spectral_exr

    base = [str(PSF), "--lens", str(LENS0001), "--f-number", "8", "--resolution", "16x16",
            "--wavelengths", "2", "--light", "-6,-4", "--focus", "0.2", "--size", "0.1", "--quiet"]
    auto = [*base, "--integrator", "auto", "--nodes", "6", "--max-nodes", "8", "--rings", "4"]
    out = tmp_path / "fail.exr"
    r = subprocess.run([*auto, "--max-rings", "4", "-o", str(out)], capture_output=True, text=True,
                       timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 5, (r.returncode, r.stderr)
    assert len(lines) == 1 and "did not reach the target error 1%" in lines[0], r.stderr
    assert "Fourier" in lines[0] and "cells" in lines[0] and not out.exists()
    assert "error estimate" not in r.stdout
    kept = tmp_path / "kept.exr"
    r = subprocess.run([*auto, "-o", str(kept)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    m = re.search(r"^Cells error estimate: ([0-9.e+-]+)% relative L2 \((\d+) rings", r.stdout, re.M)
    assert m and float(m.group(1)) <= 1.0, r.stdout
    plain = tmp_path / "plain.exr"
    r = subprocess.run([*base, "--integrator", "cells", "--rings", m.group(2), "-o", str(plain)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert np.array_equal(read_spectral_exr(kept).spectral, read_spectral_exr(plain).spectral)
