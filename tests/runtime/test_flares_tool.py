"""lensrt-psf --ghost / --flares (issue 13, deliverable 4): the direct image and each ghost
rendered as its own render (own phasor sums) with the same scene, the output one EXR,
OUT.exr, whose unprefixed spectral channels hold the total and whose layers `direct.` and
`flare.` (the ghosts' sum) the parts (read with runtime/python/lensrt_exr.py), and a PNG
of the total.

Ghost tables are made from lens0001.table's text (its P_o and P_s unchanged) with a
hand-made P_clip, so the answers have closed forms:
  * a P_clip that never blocks: the ghost's image is the direct image (same samples with
    --no-estimate), so the total is twice the direct image and its PNG, tone-mapped
    relative to its peak, is the direct PNG;
  * a P_clip that is a stop of radius r0 inside the render's stop R: the ghost's power is
    the power through r0, which lensrt-psf reports relative to the direct image's.
The layered file against separate runs (same seed and samples): its direct layer is the
direct-only run's image bit for bit, its flare layer's power the sum of the one-ghost
runs' flare powers, its total the sum of its layers to float rounding.
Bad input (a ghost of another lens, a direct table given as a ghost, an empty --flares
folder, --save-phasors with ghosts, the same ghost named twice) exits 2 before rendering
with one line naming the files. Set LENSRT_PSF to test another build of the tool.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "runtime" / "python"))

from lensrt_exr import exr_layers, read_spectral_exr  # noqa: E402

from lensfit.codegen.table import restamp_probes  # noqa: E402

PSF = Path(os.environ.get("LENSRT_PSF", ROOT / "build" / "runtime" / "runtime" / "lensrt-psf"))
LENS0001 = ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table"
# f/4: the stop radius is stop_radius_f1_mm / 4; the window holds the whole defocused PSF
BASE = ["--f-number", "4", "--resolution", "32x32", "--size", "0.12", "--focus", "0.2",
        "--wavelengths", "3", "--light", "-6,-4", "--samples", "4096", "--no-estimate"]


@pytest.fixture(autouse=True)
def _needs_tool() -> None:
    if not PSF.exists():
        pytest.skip(f"{PSF} is not built")


def lens_value(text: str, key: str) -> float:
    return float(re.search(rf"^lens {key} (\S+)$", text, re.M).group(1))


def ghost_table(text: str, side: str, clip: list[tuple[str, str, list[str]]],
                first: int = 4, second: int = 8) -> str:
    """lens0001's table with ghost lines and a P_clip taking `side`'s inputs, with the
    probe lines and checksum line lensfit writes (the source's own are dropped first)."""
    text = "".join(t for t in text.splitlines(keepends=True) if not t.startswith("checksum crc32 "))
    head, rest = text.split("\nsystem P_o ", 1)
    ghost = (f"ghost first {first}\nghost second {second}\nghost label {first}-{second}\n"
             f"ghost side {side}\n")
    out = head + "\n" + ghost + "system P_o " + rest
    if not out.endswith("\n"):
        out += "\n"
    lines = out.split("\n")
    at = lines.index(next(ln for ln in lines if ln.startswith(f"system {side} ")))
    inputs = lines[at + 1:at + 7]
    out += f"system P_clip 6 {len(clip)}\n" + "\n".join(inputs) + "\n"
    for name, unit, terms in clip:
        out += f"output {name} {unit} {len(terms)}\n" + "".join(t + "\n" for t in terms)
    return restamp_probes(out + "end\n")


@pytest.fixture(scope="module")
def tables(tmp_path_factory) -> dict[str, Path]:
    text = LENS0001.read_text()
    s = float(re.search(r"^input x_a \S+ \S+ (\S+) affine", text, re.M).group(1))
    r0 = 4.5
    folder = tmp_path_factory.mktemp("ghosts")
    never = [("x_h0", "1", ["0 0 0 1 0 0 1e-6"]), ("y_h0", "1", ["0 0 0 0 1 0 1e-6"])]
    stop = [("x_h0", "1", [f"0 0 0 1 0 0 {s / r0!r}"]), ("y_h0", "1", [f"0 0 0 0 1 0 {s / r0!r}"])]
    paths = {"never": folder / "never" / "ghost_4_8.table",
             "stop": folder / "stop" / "ghost_0_2.table",
             "other": folder / "other" / "ghost_4_8.table",
             "crossing": folder / "crossing" / "ghost_4_8.table"}
    for p in paths.values():
        p.parent.mkdir()
    paths["never"].write_text(ghost_table(text, "P_s", never))
    paths["stop"].write_text(ghost_table(text, "P_o", stop, 0, 2))
    # a stop crossing (mm) at the aperture point itself
    paths["crossing"].write_text(ghost_table(text, "P_s", [
        ("x_s1", "mm", [f"0 0 0 1 0 0 {s!r}"]), ("y_s1", "mm", [f"0 0 0 0 1 0 {s!r}"])]))
    # the same ghost of another lens (its name changed)
    paths["other"].write_text(ghost_table(text.replace("lens name Angenieux", "lens name Other", 1),
                                          "P_s", never))
    # both in one folder, for --flares
    both = folder / "both"
    both.mkdir()
    (both / "ghost_4_8.table").write_text(paths["never"].read_text())
    (both / "ghost_0_2.table").write_text(paths["stop"].read_text())
    (both / "notes.txt").write_text("not a table")
    paths["both"] = both
    paths["r0"] = Path(str(r0))
    paths["R"] = Path(repr(lens_value(text, "stop_radius_f1_mm") / 4))
    return paths


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(PSF), "--lens", str(LENS0001), *BASE, *args],
                          capture_output=True, text=True, timeout=300)


def png_pixels(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"), dtype=np.int16)


def test_never_blocking_ghost_doubles_the_direct_image(tmp_path, tables):
    direct = run("--png", str(tmp_path / "direct.png"), "--quiet")
    assert direct.returncode == 0, direct.stderr
    out = tmp_path / "flare.exr"
    r = run("--ghost", str(tables["never"]), "-o", str(out), "--png", str(tmp_path / "total.png"))
    assert r.returncode == 0, r.stderr
    # one EXR (no sibling files) with the total unprefixed and the two layers
    assert sorted(p.name for p in tmp_path.iterdir()) == ["direct.png", "flare.exr", "total.png"]
    assert exr_layers(out) == ["", "direct", "flare"]
    direct_layer, flare_layer = read_spectral_exr(out, "direct"), read_spectral_exr(out, "flare")
    # the same samples through a P_clip that never blocks: the flare is the direct image
    assert np.array_equal(direct_layer.spectral, flare_layer.spectral)
    # progress and the ghost's power, the same as the direct image's (ratio 1)
    assert "ghost 4-8 (1 of 1)" in r.stderr
    power = float(re.search(r"ghost 4-8 \(surfaces 4, 8; .*\): .* power in the window (\S+) of",
                            r.stderr).group(1))
    assert power == pytest.approx(1.0, rel=1e-6)
    # total = 2 x direct: the same PNG up to the rounding of the log map (one level of 255)
    a, b = png_pixels(tmp_path / "direct.png"), png_pixels(tmp_path / "total.png")
    assert np.abs(a - b).max() <= 1
    assert a.max() > 200  # not a black image


def test_never_blocking_ghost_with_cells(tmp_path, tables):
    # The cells integrator on the same pair: a P_clip that never blocks gives the direct
    # field on the same meshes, so the flare layer is the direct layer bit for bit, and
    # each prints its estimate (the ghost's equal to the direct one's)
    out = tmp_path / "cells.exr"
    base = [a for a in BASE if a != "--no-estimate"]  # the cells integrator always estimates
    r = subprocess.run([str(PSF), "--lens", str(LENS0001), *base, "--ghost", str(tables["never"]),
                        "--integrator", "cells", "--rings", "8", "-o", str(out), "--quiet"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    direct_layer, flare_layer = read_spectral_exr(out, "direct"), read_spectral_exr(out, "flare")
    assert np.array_equal(direct_layer.spectral, flare_layer.spectral)
    assert direct_layer.spectral.max() > 0
    ghost = re.search(r"Cells error estimate, ghost 4-8: (\S+)% relative L2 \(8 rings\)", r.stdout)
    direct = re.search(r"Cells error estimate: (\S+)% relative L2 \(8 rings against 4\)", r.stdout)
    assert ghost and direct and ghost.group(1) == direct.group(1), r.stdout


def test_flares_folder_renders_every_ghost_sorted(tmp_path, tables):
    r = run("--flares", str(tables["both"]), "-o", str(tmp_path / "f.exr"))
    assert r.returncode == 0, r.stderr
    # sorted by name: ghost_0_2 before ghost_4_8; notes.txt left alone
    assert r.stderr.index("ghost 0-2 (1 of 2)") < r.stderr.index("ghost 4-8 (2 of 2)")
    # the smaller stop lets through the power of a stop of radius r0: (r0 / R)^2 of the
    # direct image's, up to the pupil's variation of transmittance and the Monte Carlo
    # error of the power (4096 samples): 3% (measured 0.388 against 0.384, 1.1%)
    power = float(re.search(r"ghost 0-2 \(surfaces 0, 2; .*\): .* power in the window (\S+) of",
                            r.stderr).group(1))
    r0, big = float(str(tables["r0"])), float(str(tables["R"]))
    assert power == pytest.approx((r0 / big) ** 2, rel=0.03)


def test_bad_ghosts_refused_before_rendering(tmp_path, tables):
    out = tmp_path / "x.exr"
    cases = [
        (["--ghost", str(tables["other"])], ["another lens", str(tables["other"]), "Other",
                                             str(LENS0001)]),
        (["--ghost", str(LENS0001)], ["not a ghost table", str(LENS0001)]),
        (["--flares", str(tmp_path)], ["no ghost_*.table", str(tmp_path)]),
        # a second folder would have replaced the first
        (["--flares", str(tables["both"]), "--flares", str(tmp_path)],
         ["--flares", "given twice", str(tmp_path)]),
        (["--ghost", str(tables["never"]), "--save-phasors", str(tmp_path / "s.phasors")],
         ["--save-phasors"]),
    ]
    for extra, words in cases:
        r = run(*extra, "-o", str(out), "--quiet")
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2, (extra, r.stderr)
        assert len(lines) == 1, r.stderr
        for w in words:
            assert w in lines[0], (w, lines[0])
        assert not out.exists()


def test_ghost_named_twice_refused(tmp_path, tables):
    """The same ghost named twice would be rendered twice and its flare added twice: the
    same path twice, a symbolic link to it, another relative spelling of it, a --flares
    folder's table also given as --ghost (the same device and inode), and a copy of it
    (another file of the same ghost of the lens) exit 2 before rendering, one line naming
    both spellings."""
    out = tmp_path / "x.exr"
    never = tables["never"]
    link = tmp_path / "link.table"
    link.symlink_to(never)
    other_spelling = never.parent / ".." / never.parent.name / never.name
    copy = tmp_path / "copy.table"
    copy.write_bytes(never.read_bytes())
    in_folder = tables["both"] / "ghost_4_8.table"
    same_file = "is given twice (as '{}' and '{}', the same file)"
    cases = [
        (["--ghost", str(never), "--ghost", str(never)], same_file.format(never, never)),
        (["--ghost", str(never), "--ghost", str(link)], same_file.format(never, link)),
        (["--ghost", str(never), "--ghost", str(other_spelling)],
         same_file.format(never, other_spelling)),
        # --ghost first, then the folder's tables sorted
        (["--flares", str(tables["both"]), "--ghost", str(in_folder)],
         same_file.format(in_folder, in_folder)),
        (["--ghost", str(never), "--ghost", str(copy)],
         f"ghost 4-8 of lens 'Angenieux double Gauss 100 mm f/1.1 (1953)' is given twice "
         f"(as '{never}' and '{copy}')"),
    ]
    for extra, words in cases:
        r = run(*extra, "-o", str(out), "--quiet")
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2, (extra, r.stderr)
        assert len(lines) == 1 and words in lines[0], (extra, r.stderr)
        assert "flare would be added twice" in lines[0]
        assert not out.exists()
    # distinct ghosts (the folder's two tables) still render together
    r = run("--ghost", str(tables["stop"]), "--ghost", str(never), "-o", str(out), "--quiet")
    assert r.returncode == 0, r.stderr


def test_stop_crossings_with_blades_render(tmp_path, tables):
    """A stop crossing at the aperture point itself (x_s1 = x_a) with a 7-blade stop: lensrt
    tests the crossing against the blades (it refused this before), the crossing lies in
    the blades wherever the sample does, so the ghost's power is the direct image's.
    Tolerance 1e-3: the crossing is evaluated in float, so a sample within rounding of a
    blade edge may go either way (1/4096 of the power each; none is expected)."""
    r = run("--ghost", str(tables["crossing"]), "--blades", "7", "-o", str(tmp_path / "x.exr"))
    assert r.returncode == 0, r.stderr
    power = float(re.search(r"ghost 4-8 \(surfaces 4, 8; .*\): .* power in the window (\S+) of",
                            r.stderr).group(1))
    assert power == pytest.approx(1.0, rel=1e-3)


def test_layers_against_separate_runs(tmp_path, tables):
    """--flares writes one file: direct layer = a direct-only run, flare layer's power = the
    sum of one-ghost runs' (same seed, same samples: --no-estimate renders each ghost with
    the direct render's seed and sample count)."""
    alone = tmp_path / "alone.exr"
    assert run("-o", str(alone), "--quiet").returncode == 0
    out = tmp_path / "flares.exr"
    r = run("--flares", str(tables["both"]), "-o", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["alone.exr", "flares.exr"]
    total, direct, flare = (read_spectral_exr(out, layer) for layer in ("", "direct", "flare"))
    # renders are deterministic functions of seed and samples: the same direct image bit for bit
    assert np.array_equal(direct.spectral, read_spectral_exr(alone).spectral)
    assert np.array_equal(direct.rgb, read_spectral_exr(alone).rgb)
    # each ghost alone (--ghost): its flare layer is that ghost's image
    powers = []
    for name in ("ghost_0_2.table", "ghost_4_8.table"):
        one = tmp_path / f"one_{name}.exr"
        assert run("--ghost", str(tables["both"] / name), "-o", str(one), "--quiet").returncode == 0
        powers.append(read_spectral_exr(one, "flare").spectral.astype(np.float64).sum())
    assert min(powers) > 0.01 * max(powers)  # both ghosts count
    # each pixel of the flare layer is the ghosts' sum rounded once to float (relative error
    # <= 2^-24 each, all values >= 0 with the paper's |sum|^2 estimator), so the powers agree
    # to 2^-24; 2^-22 leaves room for the double sums' own rounding
    power = flare.spectral.astype(np.float64).sum()
    assert power == pytest.approx(sum(powers), rel=2.0 ** -22)
    # the total is direct + flare to float rounding: three values each rounded once from
    # double sums, so |T - (D + F)| <= 2^-23 (D + F) (1 + 2^-23) for values >= 0
    d, f = direct.spectral.astype(np.float64), flare.spectral.astype(np.float64)
    assert np.all(np.abs(total.spectral - (d + f)) <= 2.0 ** -23 * (d + f) * (1 + 2.0 ** -23))
    assert "direct: " in total.attributes["lensrt/layers"]
    assert "ghost_0_2.table + " in total.attributes["lensrt/layers"]
