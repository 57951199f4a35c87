"""The lens facts of a coefficient table: what they are for real lenses."""

from __future__ import annotations

import math

import pytest

from lensfit.paraxial import paraxial, stop_radius_f1_mm, stop_radius_for_f_number, table
from lensfit.paraxial.facts import LensFacts, lens_facts
from lensfit.prescription import load_lens


@pytest.mark.parametrize("name", ["0001", "0004", "2004"])
def test_facts_are_the_paraxial_table_and_the_housings(name):
    lens = load_lens(name)
    facts = lens_facts(lens)
    t = table(lens)
    assert facts.name == lens.name
    assert facts.focal_length_mm == t["efl_mm"] == paraxial(lens).efl_mm
    assert facts.sensor_defocus_mm == t["sensor_defocus_mm"]
    assert facts.front_focal_distance_mm == t["ffd_mm"]
    assert facts.stop_radius_max_mm == lens.stop_radius_max_mm
    # The clip radii of x_o, y_o and x_i, y_i: the housings of the first and last surface
    assert facts.housing_first_mm == lens.surfaces[0].semi_diameter_mm
    assert facts.housing_last_mm == lens.surfaces[-1].semi_diameter_mm
    if lens.anamorphic:
        assert facts.squeeze == t["anamorphic_squeeze"] and facts.squeeze > 1.5
    else:
        assert facts.squeeze == 1.0
    assert LensFacts.keys()[0] == "name" and len(facts.values()) == 9


@pytest.mark.parametrize("name", ["0001", "0009", "2004"])
@pytest.mark.parametrize("f_number", [2.0, 2.8, 8.0, 16.0])
def test_stop_radius_f1_over_n_is_the_stop_for_f_number(name, f_number):
    lens = load_lens(name)
    r1 = lens_facts(lens).stop_radius_f1_mm
    assert r1 == stop_radius_f1_mm(lens)
    try:
        want = stop_radius_for_f_number(lens, f_number)
    except ValueError:  # slower lens: f/2 is wider than it opens (r1/N is still defined)
        assert r1 / f_number > lens.stop_radius_max_mm
        return
    # The same expression: exact for powers of two, else within one rounding
    if math.log2(f_number).is_integer():
        assert r1 / f_number == want
    else:
        assert math.isclose(r1 / f_number, want, rel_tol=4e-16)
    # ... and that stop gives the f-number (entrance pupil at infinity)
    assert math.isclose(paraxial(lens, stop_radius_mm=want).f_number, f_number, rel_tol=1e-12)
