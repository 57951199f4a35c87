"""What the bank reader gives back (issue 37, item 2): at a node, at every wavelength of
the bank, the node's own render bit for bit (each channel is rendered in a window on its
own chief point, so nothing is resampled); between nodes, measured against direct renders
(check.json); an EXR that is another node's is refused even with its CRC-32 in the index.

Lens 0001's committed table at f/8, 24 x 24 pixel windows of 2.5 um, the cells integrator
to 2%: a node takes a fraction of a second.
"""

from __future__ import annotations

import math
import re
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from bank_specs import bank_spec

from lensfit.banks.check import check_bank
from lensfit.banks.node import create_render, node_coordinates
from lensfit.banks.run import run_bank
from lensfit.banks.spec import load_spec

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "runtime" / "python"))
from lensrt_ctypes import LIBRARY, Bank, Lensrt, LensrtError  # noqa: E402

pytestmark = pytest.mark.skipif(not LIBRARY.exists(),
                                reason=f"needs {LIBRARY}: build it with `make runtime`")

SPEC = bank_spec("acc", fields_x="{fields}", wavelengths=(450, 550, 650), pixels=24,
                 render='integrator = "cells"\ntarget_error = 0.02')


def make_bank(tmp_path: Path, fields: str) -> tuple[Path, Path]:
    spec = tmp_path / "acc.toml"
    spec.write_text(SPEC.format(fields=fields))
    out = tmp_path / "bank"
    run_bank(spec, out, workers=0, progress=False, sheet=False, check=False)
    return spec, out


@pytest.fixture(scope="module")
def bank(tmp_path_factory) -> tuple[Path, Path]:
    return make_bank(tmp_path_factory.mktemp("acc"), "[0, 6, 12]")


def test_reader_at_a_node_is_the_direct_render_at_every_wavelength(bank) -> None:
    """At each node and each of the bank's wavelengths (lateral colour moves the chief
    point by pixels between 450 and 650 nm at 12 deg), the reader's PSF is a direct render
    of that wavelength centred on its chief point, bit for bit, and its centre that chief
    point: the reader loses nothing of the node's accuracy."""
    spec_path, out = bank
    spec = load_spec(spec_path).to_dict()
    rt = Lensrt(LIBRARY, threads=1)
    lens = rt.load(next((ROOT / "generated").glob("0001*/lens*.table")))
    shifts = []
    with Bank(rt, out / "bank.index") as b:
        for x, fx in enumerate(spec["grid"]["field_x_deg"]):
            c = node_coordinates(spec, (0, 0, 0, 0, x))
            for lam in spec["grid"]["wavelengths_nm"]:
                got, chief = b.psf(fx, 0.0, lam, 8.0)
                light = (fx, 0.0, 0.0, 1.0)
                assert chief == rt.image_point(lens, light, lam, 0.0)
                r = create_render(rt, lens, spec, c, [lam], chief)
                r.integrate_to(spec["render"]["target_error"],
                               max_rings=spec["render"]["max_rings"])
                np.testing.assert_array_equal(got, r.image()[0])
                shifts.append(chief[0])
    # The test means something: the chief points of one node differ by pixels
    pitch = 0.06 / 24
    assert (max(shifts[-3:]) - min(shifts[-3:])) / pitch > 1.0


def test_given_chief_point_places_the_psf(bank) -> None:
    """A query with the lens's own chief point (chief_mm) is centred there; the image is
    the same blend."""
    _, out = bank
    rt = Lensrt(LIBRARY, threads=1)
    with Bank(rt, out / "bank.index") as b:
        a, chief = b.psf(3.0, 0.0, 550.0, 8.0)
        given = (chief[0] + 0.001, chief[1] - 0.002)
        c, centre = b.psf(3.0, 0.0, 550.0, 8.0, chief_mm=given)
        assert centre == given
        np.testing.assert_array_equal(a, c)
        with pytest.raises(LensrtError, match="not finite"):
            b.psf(3.0, 0.0, 550.0, 8.0, chief_mm=(math.nan, 0.0))


def test_exr_of_another_node_is_refused(bank, tmp_path: Path) -> None:
    """Node 1's EXR replaced by node 0's, with the index's CRC-32 and checksum updated to
    match: the reader refuses it by the node's identity in the EXR (lensrt/bankNode)."""
    _, out = bank
    copy = tmp_path / "bank"
    (copy / "nodes").mkdir(parents=True)
    for p in (out / "nodes").glob("*.exr"):
        (copy / "nodes" / p.name).write_bytes(p.read_bytes())
    data = (out / "nodes" / "f0-z0-d0-y0-x0.exr").read_bytes()
    (copy / "nodes" / "f0-z0-d0-y0-x1.exr").write_bytes(data)
    text = (out / "bank.index").read_text()
    body = text[:text.rindex("checksum")]
    lines = body.splitlines()
    for i, line in enumerate(lines):
        if line.startswith("node 1 "):
            parts = line.split(" ")
            parts[-2] = f"{zlib.crc32(data):08x}"
            lines[i] = " ".join(parts)
    body = "\n".join(lines) + "\n"
    (copy / "bank.index").write_text(body + f"checksum crc32 {zlib.crc32(body.encode()):08x}\n")
    rt = Lensrt(LIBRARY, threads=1)
    with Bank(rt, copy / "bank.index") as b:
        b.psf(0.0, 0.0, 550.0, 8.0)  # node 0 itself serves
        with pytest.raises(LensrtError, match=re.escape("x1.exr: node 1")
                           + r".*says it is node '0 0 0 0 0 .*not this one"):
            b.psf(6.0, 0.0, 550.0, 8.0)


def test_blending_beats_the_nearest_node_once_the_grid_resolves_the_field(tmp_path) -> None:
    """Between nodes 1.25 deg apart (lens 0001 at f/8 changes its PSF by 12% over 2.5 deg
    on the axis) the reader's blend, placed on the lens's chief point, is closer to the
    direct render than the nearest node at every cell centre and wavelength checked, and
    the check's figures are what it says: relative L2 errors, finite, the interpolated
    chief point (cubic in tan(field) over 4 nodes) within a tenth of a pixel."""
    spec_path, out = make_bank(tmp_path, "[0, 1.25, 2.5, 3.75]")
    spec = load_spec(spec_path)
    table = next((ROOT / "generated").glob("0001*/lens*.table"))
    result = check_bank(spec, out / "bank.index", str(LIBRARY), table)
    assert len(result["points"]) == 3 * 3  # 3 cells x 3 wavelengths
    for p in result["points"]:
        assert p["bank_lens_chief"] < p["nearest"], p
        assert 0 <= p["bank"] < 1 and p["chief_px"] < 0.1, p
    assert result["worse_than_nearest"] == 0
