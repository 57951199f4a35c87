"""The uncoated variant of a lens (`--coating none`, issue 13: coated against uncoated
flares): the same geometry and glasses with every surface bare, its own name and folder.
(Bare against coated reflectances: tests/fit/ghosts/test_enumerate.py.)"""

from __future__ import annotations

import dataclasses

import pytest

from lensfit.cli import main
from lensfit.errors import InputError
from lensfit.generate import lens_folder_name
from lensfit.prescription import BARE, load_lens, with_coating


@pytest.fixture(scope="module")
def lens():
    return load_lens("0001")


def test_uncoated_is_the_same_lens_with_bare_surfaces(lens):
    bare = with_coating(lens, "none")
    assert with_coating(lens, "file") is lens
    assert any(s.coating != BARE for s in lens.surfaces)  # 0001 is coated (MgF2)
    assert all(s.coating == BARE for s in bare.surfaces)
    assert [dataclasses.replace(s, coating=BARE) for s in lens.surfaces] == list(bare.surfaces)
    assert bare.name == f"{lens.name} (uncoated)" and bare.variant == "uncoated"
    assert lens_folder_name(bare) == lens_folder_name(lens) + "-uncoated"
    assert bare.stop_index == lens.stop_index and bare.source_file == lens.source_file
    with pytest.raises(InputError, match="coating 'mgf3': expected one of file, none"):
        with_coating(lens, "mgf3")


def test_cli_refuses_an_unknown_coating(capsys):
    with pytest.raises(SystemExit) as e:
        main(["fit", "0001", "--coating", "mgf3"])
    assert e.value.code == 2
    assert "--coating" in capsys.readouterr().err
