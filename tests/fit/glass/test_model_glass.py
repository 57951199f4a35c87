"""The nd/vd model glass with a partial-dispersion deviation (dPgF) and the medium without
dispersion (an inline constant index), checked against their definitions:

* vd = (nd - 1)/(nF - nC) and P_g,F = (ng - nF)/(nF - nC), with the Fraunhofer lines
  written out here (d 587.56, F 486.13, C 656.27, g 435.83 nm), and the normal line
  P_g,F = 0.6438 - 0.001682 min(vd, 100) written out here as well: dPgF is the deviation
  from it, P_g,F = normal line + dPgF;
* a constant index n is n at every wavelength, and no check of a later stage (glass
  ranges, the default fit band, coatings, ghosts, the tracer) refuses it.

Tolerances: the model's coefficients come from a closed form in float64. n at d is nd to
a few ulps (1e-15). vd and P_g,F divide by nF - nC (about 0.008 for vd 64), which turns
the ulps of n (2.2e-16 at n = 1.5) into a relative error near 1.5 x 2.2e-16 / 0.008 =
4e-14 on vd, P_g,F likewise: 1e-12 leaves a margin of 25 and still fails for any change
of the model (a wrong line constant changes P_g,F by 1e-4 or more).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lensfit.common.errors import LensError
from lensfit.glass import (
    ConstantGlass,
    abbe_glass,
    abbe_number,
    inline_glass,
    partial_dispersion,
)
from lensfit.prescription import lens_from_dict, make_lens
from lensfit.prescription.ranges import check_glass_ranges, default_wavelengths

D, F, C, G = 587.56, 486.13, 656.27, 435.83


def normal_line(vd: float) -> float:
    return 0.6438 - 0.001682 * min(vd, 100.0)


# Real glasses' nd, vd and dPgF (data sheets), the model's extremes, and no dPgF
CASES = [
    (1.5168, 64.17, 0.0),       # N-BK7
    (1.43875, 94.66, 0.0457),   # S-FPL55 (OHARA data sheet dPgF)
    (1.80518, 25.43, 0.0),      # SF6
    (1.6727, 32.21, -0.0119),   # a KZFS-like negative deviation
    (1.5, 5.0, 0.1),            # the model's limits
    (2.0, 150.0, -0.1),
]


@pytest.mark.parametrize(("nd", "vd", "dpgf"), CASES)
def test_model_glass_reproduces_nd_vd_and_pgf_by_definition(nd, vd, dpgf):
    g = abbe_glass(nd, vd, dpgf)
    n_d, n_f, n_c, n_g = (float(v) for v in g.n(np.array([D, F, C, G])))
    assert n_d == pytest.approx(nd, abs=1e-15)
    assert (nd - 1.0) / (n_f - n_c) == pytest.approx(vd, rel=1e-12)
    assert abbe_number(g) == pytest.approx(vd, rel=1e-12)
    p_gf = (n_g - n_f) / (n_f - n_c)
    assert p_gf == pytest.approx(normal_line(vd) + dpgf, abs=1e-12)
    assert partial_dispersion(g) == pytest.approx(p_gf, abs=1e-15)


def test_dpgf_zero_is_the_model_as_before():
    # Lenses written before dPgF existed keep their glasses bit for bit
    lam = np.linspace(380.0, 780.0, 41)
    for nd, vd, _ in CASES:
        assert np.array_equal(abbe_glass(nd, vd).n(lam), abbe_glass(nd, vd, 0.0).n(lam))
    assert abbe_glass(1.5168, 64.17) == abbe_glass(1.5168, 64.17, 0.0)
    assert abbe_glass(1.5168, 64.17) != abbe_glass(1.5168, 64.17, 0.01)


def test_dpgf_limits_keep_n_decreasing():
    # |dPgF| <= 0.1 keeps P_g,F within 0.376-0.736, inside 0.323-1.028 where the model
    # decreases strictly over 380-780 nm, for every vd the loader accepts
    lam = np.linspace(380.0, 780.0, 401)
    for vd in (5.0, 20.0, 60.0, 100.0, 150.0):
        for dpgf in (-0.1, 0.1):
            assert np.all(np.diff(abbe_glass(1.7, vd, dpgf).n(lam)) < 0), (vd, dpgf)
    for bad in (0.1000001, -0.2, math.nan, math.inf):
        with pytest.raises(ValueError):
            abbe_glass(1.6, 40.0, bad)


def test_constant_index_is_constant_everywhere():
    g = inline_glass({"n": 1.5})
    assert isinstance(g, ConstantGlass) and g.name == "n=1.5"
    lam = np.linspace(380.0, 780.0, 401)
    assert np.all(g.n(lam) == 1.5)  # exactly: no formula in between
    assert g.n(D) == 1.5 and np.shape(g.n(D)) == ()
    assert not hasattr(g, "range_nm")  # no published range: no wavelength is outside it
    assert inline_glass({"name": "immersion oil", "n": 1.515}).name == "immersion oil"


def _singlet(material: dict) -> dict:
    return {"schema_version": 1,
            "lens": {"id": "t", "name": "t", "maker": "unknown", "year": 0, "source": "test"},
            "surface": [
                {"shape": "sphere", "radius": 50.0, "thickness": 5.0, "semi_diameter": 8.0,
                 "stop": True, **material},
                {"shape": "sphere", "radius": -50.0, "thickness": 47.0, "material": "air",
                 "semi_diameter": 8.0},
            ]}


def test_constant_index_passes_every_later_check():
    from lensfit.ghosts.enumerate import enumerate_ghosts
    from lensfit.trace.tracer import Rays, trace

    lens = lens_from_dict(_singlet({"material": {"n": 1.5}}))  # default coating: MgF2
    # Coatings: the glass-air interfaces get the default layer, as with any glass
    assert all(not s.coating.bare for s in lens.surfaces if not s.inserted)
    # Glass ranges: none, so the default band is the full 380-780 nm and any band passes
    assert (default_wavelengths(lens).lo_nm, default_wavelengths(lens).hi_nm) == (380.0, 780.0)
    assert check_glass_ranges(lens, 200.0, 2000.0) == []
    # The tracer: no dispersion, so rays of 380 and 780 nm land at the same points
    pos = np.array([[0.0, y, -10.0] for y in (-6.0, -3.0, 0.0, 3.0, 6.0)])
    d = np.tile([0.0, math.sin(0.05), math.cos(0.05)], (5, 1))
    blue = trace(lens, Rays(pos, d, np.full(5, 380.0)))
    red = trace(lens, Rays(pos, d, np.full(5, 780.0)))
    assert np.array_equal(blue.pos, red.pos)
    # Ghosts: the two-surface ghost of the singlet is enumerated like any other
    (ghost,) = enumerate_ghosts(lens, wavelengths_nm=(450.0, 650.0), rays=400, fine_rays=400)
    assert math.isfinite(ghost.exposure_peak)


@pytest.mark.parametrize(("material", "key", "says"), [
    ({"nd": 1.6, "vd": 40.0, "dpgf": 0.2}, "dpgf", "-0.1 <= dpgf <= 0.1"),
    ({"material": "N-BK7", "dpgf": 0.01}, "dpgf", "not both"),
    ({"dpgf": 0.01}, "dpgf", "'dpgf' goes with 'nd' and 'vd'"),
    ({"nd": 1.5, "vd": 0.0}, "vd", "material = { n = 1.5 }"),
    ({"material": {"n": 0.9}}, "material.n", "1 <= n <= 3"),
    ({"material": {"n": math.nan}}, "material.n", "expected a finite number"),
    ({"material": {"n": 1.5, "table_nm": [400, 700], "table_n": [1.5, 1.4]}},
     "material.n", "not both"),
])  # fmt: skip
def test_bad_model_glasses_name_the_key(material, key, says):
    with pytest.raises(LensError) as e:
        lens_from_dict(_singlet(material), file="t.toml")
    assert (e.value.surface, e.value.key) == (0, key), str(e.value)
    assert says in str(e.value)


def test_model_glass_keys_in_the_lens_file():
    lens = make_lens([{"shape": "sphere", "radius": 50.0, "thickness": 5.0, "nd": 1.6,
                       "vd": 40.0, "dpgf": 0.01, "semi_diameter": 8.0, "stop": True},
                      {"shape": "plane", "thickness": 40.0, "material": "air",
                       "semi_diameter": 8.0}])
    s = next(s for s in lens.surfaces if not s.inserted)  # not the stop's copy in front
    assert s.material_spec == {"nd": 1.6, "vd": 40.0, "dpgf": 0.01}
    assert s.to_dict()["dpgf"] == 0.01
    assert partial_dispersion(s.medium) == pytest.approx(normal_line(40.0) + 0.01, abs=1e-12)
