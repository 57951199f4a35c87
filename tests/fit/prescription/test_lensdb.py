"""The lens database: every lens loads, matches its patent and uses real glasses;
and the ``lensfit info`` command on it."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from lensfit.cli import main
from lensfit.glass import AIR, catalog_glass
from lensfit.paraxial import paraxial
from lensfit.paraxial.validate import efl_check
from lensfit.prescription import lens_from_dict, list_lenses, load_lens

LENSES = list_lenses()
IDS = [p.stem for p in LENSES]
VISIBLE_NM = np.linspace(380.0, 780.0, 401)

# lentil traced f/1.1078 for 0001 at its widest stop (field "fstop"/"unscaled" of
# ../shared/lensdata/lentil-lenses.json), with real rays and its own stop search.
LENTIL_F_NUMBER_0001 = 1.108


def lens_id(path: Path) -> str:
    return path.stem.split("-", 1)[0]


def test_lensdb_is_complete() -> None:
    ids = {lens_id(p) for p in LENSES}
    assert len(LENSES) >= 16
    assert len(ids) == len(LENSES)  # ids are unique
    assert {"2001", "2002", "2003", "2004"} <= ids  # the anamorphics
    assert {"0014"} <= ids  # the aspheric fisheye
    assert {"0004", "0005", "0013"} <= ids  # the wide-angles


@pytest.mark.parametrize("path", LENSES, ids=IDS)
def test_lens_loads_and_round_trips(path: Path) -> None:
    lens = load_lens(path)
    assert lens.provenance["id"] == lens_id(path)  # file name and [lens] id agree
    assert lens_from_dict(lens.to_dict()).surfaces == lens.surfaces
    assert lens.sensor_z > 0


def test_special_lenses_have_their_special_surfaces() -> None:
    for i in ("2001", "2002", "2003", "2004"):
        assert load_lens(i).anamorphic, i
    assert any(s.shape == "asphere" for s in load_lens("0014").surfaces)


@pytest.mark.parametrize("path", LENSES, ids=IDS)
def test_efl_matches_the_patent_or_says_why_not(path: Path) -> None:
    ok, message = efl_check(str(path))
    assert ok, message
    reason = load_lens(path).provenance.get("efl_check")
    if reason is not None:
        # a reason is a sentence a reader can act on, not a placeholder
        assert isinstance(reason, str)
        assert len(reason.strip()) >= 40, reason
        assert reason.rstrip().endswith("."), reason
        assert len(reason.split()) >= 6, reason


def test_efl_check_fails_on_a_wrong_focal_length(tmp_path: Path) -> None:
    # The check must be able to fail: 0001 claiming 102 mm (2% off) is refused.
    src = Path(load_lens("0001").source_file).read_text(encoding="utf-8")
    assert src.count("focal_length_mm = 100.0") == 1
    bad = tmp_path / "0001-wrong.toml"
    bad.write_text(src.replace("focal_length_mm = 100.0", "focal_length_mm = 102.0"), "utf-8")
    ok, message = efl_check(str(bad))
    assert not ok, message


def test_default_lens_0001_first_order() -> None:
    lens = load_lens("0001")
    p = paraxial(lens)
    # patent: 100 mm; 1% is the rounding of a patent table (see lensfit.validate)
    assert p.efl_mm == pytest.approx(100.0, rel=0.01)
    # lentil's f-number is a real-ray trace, ours paraxial (EFL / entrance pupil): the
    # two differ by the aperture's spherical aberration and pupil aberration, a few
    # percent at f/1.1, hence 5%.
    assert p.f_number == pytest.approx(LENTIL_F_NUMBER_0001, rel=0.05)


def _glass_names() -> list[str]:
    names = set()
    for path in LENSES:
        for s in load_lens(path).to_dict()["surface"]:
            if s.get("material", "air").lower() != "air":
                names.add(s["material"])
    return sorted(names)


@pytest.mark.parametrize("name", _glass_names())
def test_named_glasses_resolve(name: str) -> None:
    g = catalog_glass(name)
    # a catalog glass's nd is consistent with its own Sellmeier formula (catalogs
    # print nd to 5 decimals, so 1e-4 is loose enough for rounding, tight for a typo)
    assert float(g.n(587.56)) == pytest.approx(g.nd, abs=1e-4)


@pytest.mark.parametrize("path", LENSES, ids=IDS)
def test_every_medium_is_physical_over_the_visible(path: Path) -> None:
    lens = load_lens(path)
    for i, s in enumerate(lens.surfaces):
        if s.medium is AIR:
            continue
        n = np.asarray(s.medium.n(VISIBLE_NM))
        assert np.all(np.isfinite(n)), (i, s.medium.name)
        assert np.all(n > 1.0), (i, s.medium.name)
        # normal dispersion: the index falls with wavelength across the visible
        assert np.all(np.diff(n) < 0), (i, s.medium.name)


# ------------------------------------------------------------- lensfit info


def _info_json(capsys: pytest.CaptureFixture[str], *args: str) -> dict[str, Any]:
    assert main(["info", "0001", "--json", *args]) == 0
    return json.loads(capsys.readouterr().out)


def test_cli_info_json(capsys: pytest.CaptureFixture[str]) -> None:
    t = _info_json(capsys)
    for key in ("efl_mm", "bfd_mm", "stop_radius_mm", "f_number"):
        assert isinstance(t[key], float) and math.isfinite(t[key]), key
    for pupil in ("entrance_pupil", "exit_pupil"):
        assert set(t[pupil]) == {"position_mm", "radius_mm"}
        assert all(math.isfinite(v) for v in t[pupil].values())
    lens = load_lens("0001")
    assert t["stop_radius_mm"] == lens.stop_radius_max_mm  # wide open by default
    # self-consistent: f-number is EFL over the entrance pupil diameter (1e-12: rounding)
    assert t["f_number"] == pytest.approx(
        t["efl_mm"] / (2 * t["entrance_pupil"]["radius_mm"]), rel=1e-12
    )
    # the double Gauss's entrance pupil is larger than its stop (front group magnifies)
    assert t["entrance_pupil"]["radius_mm"] > t["stop_radius_mm"]


def test_cli_info_f_number(capsys: pytest.CaptureFixture[str]) -> None:
    wide = _info_json(capsys)
    t = _info_json(capsys, "--f-number", "8")
    # the stop radius is solved from a linear relation: 1e-9 is generous rounding
    assert t["f_number"] == pytest.approx(8.0, abs=1e-9)
    assert t["stop_radius_mm"] < wide["stop_radius_mm"]
    assert t["efl_mm"] == wide["efl_mm"]  # stopping down does not move the focus


def test_cli_info_f_number_too_wide(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", "0001", "--f-number", "0.5"]) == 2
    err = capsys.readouterr().err
    assert "f/0.5" in err and "wider than" in err
    fastest = paraxial(load_lens("0001")).f_number
    assert f"f/{fastest:.9g}" in err  # and says how far it does open


def test_cli_info_unknown_lens(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", "nope"]) == 2
    captured = capsys.readouterr()
    assert "'nope'" in captured.err
    assert captured.out == ""
