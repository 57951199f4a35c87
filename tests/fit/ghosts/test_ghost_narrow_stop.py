"""A ghost whose fit over the direct fit's stop misses the trust target is fitted over
the stop of the f-number it is checked at (lensfit.ghosts.tables.fit_with_trust): 0009's
ghost 0-2 at f/8 (98% over the f/2 stop, its rays near the stop's rim not converging).
The table's other half is the direct one re-expressed over that stop, the same function,
so that both halves share their stop inputs as lensrt requires."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lensfit.codegen.generate import read_fit_json
from lensfit.codegen.table import read_table, write_table
from lensfit.ghosts.enumerate import enumerate_ghosts, parse_ghost
from lensfit.ghosts.tables import TRUST_TARGET, fit_with_trust, on_inputs
from lensfit.poly import Input
from lensfit.prescription import load_lens
from lensfit.sample.domain import Domain

ROOT = Path(__file__).resolve().parents[3]
LENS = ROOT / "lensdb" / "0009-zeiss-biotar.toml"
FOLDER = ROOT / "generated" / "0009-zeiss-biotar"


@pytest.fixture(scope="module")
def biotar():
    direct, meta = read_fit_json(FOLDER / "fit.json")
    return load_lens(LENS), direct, Domain.from_dict(meta["domain"])


def test_on_inputs_is_the_same_function_over_the_narrowed_stop(biotar):
    _, direct, _ = biotar
    r = direct.lens.stop_radius_f1_mm / 8.0
    rng = np.random.default_rng(3)
    for s in direct:
        narrow = tuple(Input(i.name, i.unit, -r, r, i.transform)
                       if i.name in ("x_a", "y_a") else i for i in s.inputs)
        t = on_inputs(s, narrow)
        x = np.column_stack([rng.uniform(i.lo, i.hi, 500) for i in narrow])
        a, b = s.evaluate(x), t.evaluate(x)
        assert np.all(np.abs(a - b) <= 1e-12 * (1 + np.abs(a).max(axis=0))), s.name


def test_0009_ghost_0_2_fits_over_the_f8_stop(biotar):
    lens, direct, domain = biotar
    pair = parse_ghost(lens, "0-2", "ghost")
    est = enumerate_ghosts(lens, f_number=8.0, light=(-6.0, -4.0), pairs=[pair])[0]
    fit, table, cells = fit_with_trust(lens, est, direct, domain, (-6.0, -4.0), 8.0)
    assert max(c.rel_l2 for c in cells) <= TRUST_TARGET
    assert all(abs(c.energy_ratio - 1.0) < 0.01 for c in cells)
    r = direct.lens.stop_radius_f1_mm / 8.0
    assert fit.stop_radius_mm == pytest.approx(r, rel=1e-12)
    # Both halves over the same stop, to the bit, through the table's text
    back = read_table(write_table(table))
    p_o, p_s = (next(s for s in back if s.name == n) for n in ("P_o", "P_s"))
    assert p_o.inputs[3:] == p_s.inputs[3:]
    assert p_s.inputs[3].hi == pytest.approx(r, rel=1e-12)
