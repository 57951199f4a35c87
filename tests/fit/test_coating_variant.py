"""The uncoated variant of a lens (`--coating none`, issue 13: coated against uncoated
flares): the same geometry and glasses with every surface bare, its own name and folder.
(Bare against coated reflectances: tests/fit/ghosts/test_enumerate.py.)"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lensfit.cli import main
from lensfit.codegen.generate import GENERATED_DIR, lens_folder_name
from lensfit.codegen.table import read_table
from lensfit.common.errors import InputError
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


def test_uncoated_folder_shares_positions_and_phase_and_carries_no_c():
    """The committed uncoated fits have the coated ones' positions and phase bit for bit
    (the same rays; the coating changes tau only), which is why a variant's folder keeps
    its table and fit.json but no C (generate.lens_files)."""
    root = GENERATED_DIR
    for coated in ("0001-angenieux-double-gauss", "2004-schneider-anamorphic"):
        a = read_table(next((root / coated).glob("lens*.table")).read_text())
        bare = root / f"{coated}-uncoated"
        b = read_table(next(bare.glob("lens*.table")).read_text())
        for sa, sb in zip(a, b, strict=True):
            for pa, pb in zip(sa.outputs, sb.outputs, strict=True):
                same = (np.array_equal(pa.exponents, pb.exponents)
                        and np.array_equal(pa.coefficients, pb.coefficients))
                assert same == (not pa.output.startswith("tau")), (coated, pa.output)
        assert not list(bare.glob("*.c")) and not list(bare.glob("*.h"))
        assert list((root / coated).glob("lens*.c"))
