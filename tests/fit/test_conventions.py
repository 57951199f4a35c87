"""Issue 15, items 4 and 6: `lensfit info --wavelength` and the stated conventions.

The field-sign tests check the designers' convention (Zemax, Code V, Optiland): a light
at field +θ sends its chief ray in with a positive slope (dy/dz > 0), so an ordinary lens
images it at +y, about f tan θ from the axis.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from lensfit.cli import CONVENTION_NOTE, main
from lensfit.prescription import load_lens
from lensfit.trace.tracer import Rays, forward_path, trace

# ------------------------------------------------------------ info --wavelength


def _info(capsys, *args: str):
    assert main(["info", "0001", "--json", *args]) == 0
    return json.loads(capsys.readouterr().out)


def _real_ray_efl(lens, wavelength_nm: float) -> float:
    """EFL from a real ray 1e-3 mm off the axis at this wavelength (independent of the
    paraxial matrices): h / tan(u') behind the lens."""
    h = 1e-3
    out = trace(lens, Rays(np.array([[0.0, h, -1.0]]), [[0.0, 0.0, 1.0]], wavelength_nm),
                forward_path(lens), clip=False)
    assert out.ok[0]
    return float(-h * out.dir[0, 2] / out.dir[0, 1])


def test_info_wavelength_gives_first_order_facts_at_that_wavelength(capsys):
    lens = load_lens("0001")
    d_line = _info(capsys)
    both = _info(capsys, "--wavelength", "450,650")
    assert isinstance(both, list) and [t["wavelength_nm"] for t in both] == [450.0, 650.0]
    for t in both:
        # Third-order terms at h = 1e-3 mm are ~1e-10 relative: 1e-6 is ample
        assert t["efl_mm"] == pytest.approx(_real_ray_efl(lens, t["wavelength_nm"]), rel=1e-6)
    # The lens's chromatic change of focus (BFD 55.90 and 56.12 mm) is far above 1e-6
    assert abs(both[1]["bfd_mm"] - both[0]["bfd_mm"]) > 0.1
    # Repeating the option is the same as a list; the d line by number is the default
    again = _info(capsys, "--wavelength", "450", "--wavelength", "650")
    assert again == both
    d_by_number = _info(capsys, "--wavelength", "587.5618")
    assert d_by_number == d_line


def test_info_wavelength_keeps_the_stop_of_the_f_number(capsys):
    """--f-number sets the stop at the d line; at another wavelength the stop is the same
    physical disc and only the first-order facts change."""
    at_d = _info(capsys, "--f-number", "8")
    at_450 = _info(capsys, "--f-number", "8", "--wavelength", "450")
    assert at_450["stop_radius_mm"] == at_d["stop_radius_mm"]
    assert at_d["f_number"] == pytest.approx(8.0, rel=1e-12)
    assert at_450["f_number"] != pytest.approx(8.0, rel=1e-6)


@pytest.mark.parametrize("value,words", [
    ("nan", ("--wavelength 'nan'", "positive finite")),
    ("inf", ("--wavelength 'inf'", "positive finite")),
    ("0", ("--wavelength '0'", "positive finite")),
    ("-450", ("--wavelength '-450'", "positive finite")),
    ("550,green", ("--wavelength '550,green'", "'green'")),
    ("250", ("--wavelength 250", "range of glass")),
    ("550,3000", ("--wavelength 3000", "range of glass")),
])
def test_info_bad_wavelength_is_one_line_and_exit_2(capsys, value, words):
    assert main(["info", "0001", "--wavelength", value]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and not captured.out, (err, captured.out)
    for w in words:
        assert w in err[0], (w, err[0])


def test_info_prints_the_convention_note(capsys):
    assert main(["info", "0001"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1].strip() == CONVENTION_NOTE
