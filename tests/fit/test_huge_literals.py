"""A 5000-digit integer in a file lensfit reads (issue 39, item 1): Python refuses to turn
an integer literal of over 4300 digits into an int and says so in a ValueError that no
reader caught (a traceback). Every reader of TOML and checked JSON now refuses it in one
line naming the file: a lens, a scene, a bank spec, the glass catalog, and checked JSON
(fit checkpoints, ghost records, bank.json and node records all read through
load_checked_json)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from lensfit.banks.spec import SpecError, load_spec
from lensfit.codegen.checked_json import load_checked_json
from lensfit.codegen.scene import SceneError, load_scene
from lensfit.common.errors import InputError, LensError
from lensfit.glass.catalog import _load_catalog
from lensfit.prescription import load_lens

BIG = "9" * 5000
SAID = "an integer literal of more than 4300 digits"


def test_lens_toml(tmp_path: Path) -> None:
    p = tmp_path / "big.toml"
    p.write_text(f"[lens]\nname = \"x\"\nfocal_length_mm = {BIG}\n")
    with pytest.raises(LensError, match=SAID) as e:
        load_lens(p)
    assert str(p) in str(e.value) or p.name in str(e.value)


@pytest.mark.parametrize("reader, error", [(load_scene, SceneError), (load_spec, SpecError)])
def test_scene_and_bank_spec(tmp_path: Path, reader, error) -> None:
    p = tmp_path / "big.toml"
    p.write_text(f"name = {BIG}\n")
    with pytest.raises(error, match=SAID) as e:
        reader(p)
    assert str(p) in str(e.value)


def test_glass_catalog(tmp_path: Path) -> None:
    p = tmp_path / "catalog.toml"
    p.write_text(f"[[glass]]\nnd = {BIG}\n")
    with pytest.raises(InputError, match=f"{p}: cannot read the glass catalog: {SAID}"):
        _load_catalog(p)


def test_checked_json(tmp_path: Path) -> None:
    p = tmp_path / "bank.json"
    p.write_text(f'{{"version": {BIG}, "checksum": "crc32:00000000"}}')
    with pytest.raises(InputError, match=f"{p}: cannot read: {SAID}"):
        load_checked_json(p, "run it again")


def test_cli_says_it_in_one_line(tmp_path: Path) -> None:
    p = tmp_path / "big.toml"
    p.write_text(f"[lens]\nname = \"x\"\nfocal_length_mm = {BIG}\n")
    r = subprocess.run([sys.executable, "-m", "lensfit.cli", "info", str(p)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert SAID in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
