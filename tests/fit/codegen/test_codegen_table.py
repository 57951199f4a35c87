"""Coefficient tables: exact round trip, the documented layout, errors with line numbers,
the lens lines of version 2, the trust lines of version 3 (now 4, with its checksum),
and versions 1 and 2 still read."""

from __future__ import annotations

import numpy as np
import pytest

from lensfit.codegen import write_table
from lensfit.codegen.table import (
    decode_field,
    encode_field,
    split_checksum,
    upgrade_text,
    with_checksum,
)
from lensfit.codegen.table import read_table as read_checked
from lensfit.paraxial.facts import LensFacts
from lensfit.poly import Input, Polynomial, System

FACTS = LensFacts(name="Test lens, 50 mm f/2 (100%)", focal_length_mm=49.999999999999993,
                  stop_radius_max_mm=9.5, stop_radius_f1_mm=18.75, housing_first_mm=14.0,
                  housing_last_mm=1.0 / 3.0, sensor_defocus_mm=-0.0125,
                  front_focal_distance_mm=-1e-300, squeeze=1.0)


def stamp(text: str) -> str:
    """The text with the checksum line the writer ends every table with (an old one
    dropped): these tests write and edit tables by hand to check the layout and the
    parser, not the checksum (test_table_checksum.py checks that)."""
    lines = [t for t in text.splitlines(keepends=True) if not t.startswith("checksum crc32 ")]
    body = "".join(lines)
    return with_checksum(body if body.endswith("\n") or not body else body + "\n")


def read_table(text: str):
    return read_checked(stamp(text))


def assert_same(a: list[System], b: list[System]) -> None:
    """Equal names, units, domains, transforms; exponents and coefficients bit for bit."""
    assert len(a) == len(b)
    for s, t in zip(a, b, strict=True):
        assert (s.name, s.inputs) == (t.name, t.inputs)
        assert len(s.outputs) == len(t.outputs)
        for p, q in zip(s.outputs, t.outputs, strict=True):
            assert (p.output, p.unit) == (q.output, q.unit)
            assert np.array_equal(p.exponents, q.exponents)
            assert p.coefficients.tobytes() == q.coefficients.tobytes()


def test_round_trip_is_exact(systems):
    text = write_table(systems, comment="lens 0001\nfitted 2024")
    assert_same(read_table(text), systems)
    assert write_table(read_table(text)) == write_table(systems)


def test_round_trip_of_awkward_values():
    odd = System("odd name", (
        Input("", "", -1e-300, 5e-324),
        Input("-", "%", 0.1, 0.30000000000000004, "inverse_square"),
        Input("λ mid", "µm", 0.38, 0.78, "inverse_square"),
    ), (
        Polynomial("a\tb", "-", [[0, 0, 0], [1, 2, 3], [0, 0, 40]],
                   [-0.0, 5e-324, 1.7976931348623157e308]),
        Polynomial("none", "1", np.zeros((0, 3), np.int32), []),
    ))
    assert_same(read_table(write_table([odd])), [odd])
    for text in ["", "-", "--", "a b", "50%", "µm", "x\ty", "λ\u00a0x", "%41"]:
        assert decode_field(encode_field(text), "here") == text
        assert " " not in encode_field(text) and encode_field(text)


def test_documented_layout():
    s = System("P_o", (Input("x", "mm", -2.0, 2.0), Input("λ", "nm", 400.0, 800.0,
                                                          "inverse_square")),
               (Polynomial("y", "mm", [[0, 0], [1, 2]], [0.5, -1.0 / 3.0]),))
    assert write_table([s]) == stamp(
        "lensfit-poly-table 1\n"
        "system P_o 2 1\n"
        "input x mm -2 2 affine 0 2\n"
        "input λ nm 400 800 inverse_square 3.9062500000000001e-06 2.3437500000000002e-06\n"
        "output y mm 2\n"
        "0 0 0.5\n"
        "1 2 -0.33333333333333331\n"
        "end\n")


def test_comments_blank_lines_tabs_and_crlf_are_accepted(systems):
    text = split_checksum(write_table(systems[2:]).encode())[0].decode()  # stamped again
    messy = "# leading comment\n\n" + text.replace(" ", " \t ").replace("\n", "\r\n  # c\r\n")
    assert_same(read_table(messy), systems[2:])


GOOD = ("lensfit-poly-table 1\n"          # 1
        "system S 2 1\n"                   # 2
        "input u mm -1 1 affine 0 1\n"     # 3
        "input v 1 0 4 affine 2 2\n"       # 4
        "output y mm 2\n"                  # 5
        "0 0 1.5\n"                        # 6
        "1 3 -2.5e-3\n"                    # 7
        "end\n")                           # 8


@pytest.mark.parametrize(("old", "new", "line", "message"), [
    ("lensfit-poly-table 1", "lensfit-poly-table 6", 1, "version '6' is not supported"),
    ("lensfit-poly-table 1", "poly 1", 1, "expected the header"),
    ("system S 2 1", "system S two 1", 2, "n_inputs: expected a non-negative integer"),
    ("system S 2 1", "sys S 2 1", 2, "expected 'system"),
    ("input v 1 0 4 affine 2 2", "input v 1 0 4 affine 2", 4, "expected 8 fields"),
    ("input v 1 0 4 affine 2 2", "input v 1 0 4 cubic 2 2", 4, "transform"),
    ("input v 1 0 4 affine 2 2", "input v 1 4 0 affine 2 2", 4, "empty or non-finite domain"),
    ("input v 1 0 4 affine 2 2", "input v 1 0 4 affine 2.5 2", 4, "c = 2.5 does not match"),
    ("input v 1 0 4 affine 2 2", "input v 1 0 inf affine 2 2", 4, "hi: expected a real"),
    ("input u mm -1 1", "input u%4 mm -1 1", 3, "bad escape"),
    ("1 3 -2.5e-3", "1 3 -2.5e-3x", 7, "coefficient: expected a real number"),
    ("1 3 -2.5e-3", "1 3 1_0", 7, "coefficient: expected a real number"),
    ("1 3 -2.5e-3", "1 -3 -2.5e-3", 7, "exponent 2: expected a non-negative integer"),
    ("1 3 -2.5e-3", "1 3 4 -2.5e-3", 7, "expected 2 exponents and a coefficient"),
    ("output y mm 2", "output y mm 3", 8, "expected 2 exponents and a coefficient"),
    ("end\n", "", 8, "unexpected end of text, expected 'end'"),
    ("end\n", "fin\n", 8, "expected 'end'"),
    ("output y mm 2", "outputs y mm 2", 5, "expected 'output"),
])
def test_malformed_tables_name_the_line(old, new, line, message):
    assert read_table(GOOD)  # the unmodified text is fine
    bad = GOOD.replace(old, new)
    assert bad != GOOD
    with pytest.raises(ValueError, match=f"^table line {line}: .*{message}"):
        read_table(bad)


def test_empty_table_is_an_error():
    with pytest.raises(ValueError, match="table line 1: unexpected end of text"):
        read_checked("")
    with pytest.raises(ValueError, match="table line 2: no system"):
        read_table("lensfit-poly-table 1\n")


# --- version 2: the lens lines ------------------------------------------------------------


def test_lens_lines_round_trip(systems):
    text = write_table(systems, comment="lens 0001", lens=FACTS)
    table = read_table(text)
    assert (table.version, table.lens) == (2, FACTS)  # every value exactly
    assert_same(table, systems)
    assert write_table(table, comment="lens 0001") == text  # a Table keeps its facts
    assert write_table(table, comment="lens 0001", lens=FACTS) == text


def test_lens_lines_layout():
    s = System("S", (Input("x", "mm", -2.0, 2.0),), (Polynomial("y", "mm", [[1]], [0.5]),))
    assert write_table([s], comment="c", lens=FACTS) == stamp(
        "lensfit-poly-table 2\n"
        "# c\n"
        "lens name Test%20lens,%2050%20mm%20f/2%20(100%25)\n"
        "lens focal_length_mm 49.999999999999993\n"
        "lens stop_radius_max_mm 9.5\n"
        "lens stop_radius_f1_mm 18.75\n"
        "lens housing_first_mm 14\n"
        "lens housing_last_mm 0.33333333333333331\n"
        "lens sensor_defocus_mm -0.012500000000000001\n"
        "lens front_focal_distance_mm -1e-300\n"
        "lens squeeze 1\n"
        "system S 1 1\n"
        "input x mm -2 2 affine 0 2\n"
        "output y mm 1\n"
        "1 0.5\n"
        "end\n")


def test_version_1_tables_still_read():
    table = read_table(GOOD)
    assert (table.version, table.lens) == (1, None)
    assert [s.name for s in table] == ["S"]
    assert write_table(table) == stamp(GOOD.replace("-2.5e-3", "-0.0025000000000000001"))


def test_writer_refuses_facts_it_cannot_write(systems):
    from dataclasses import replace
    with pytest.raises(ValueError, match=r"lens focal_length_mm = inf: expected a finite"):
        write_table(systems, lens=replace(FACTS, focal_length_mm=float("inf")))
    with pytest.raises(ValueError, match=r"lens housing_last_mm = 0.0: expected a length in "
                                         r"\[0.001, 1e\+06\] mm"):
        write_table(systems, lens=replace(FACTS, housing_last_mm=0.0))


GOOD2 = ("lensfit-poly-table 2\n"               # 1
         "# comment\n"                          # 2
         "lens name My%20lens\n"                # 3
         "lens focal_length_mm 50\n"            # 4
         "lens stop_radius_max_mm 10\n"         # 5
         "lens stop_radius_f1_mm 20\n"          # 6
         "lens housing_first_mm 15\n"           # 7
         "lens housing_last_mm 12\n"            # 8
         "lens sensor_defocus_mm 0\n"           # 9
         "lens front_focal_distance_mm 30\n"    # 10
         "lens squeeze 1\n"                     # 11
         + GOOD.split("\n", 1)[1])              # 12: system S 2 1 ...


@pytest.mark.parametrize(("old", "new", "line", "message"), [
    ("lens stop_radius_f1_mm 20", "lens stop_radius_f1_mm twenty", 6,
     "lens stop_radius_f1_mm: expected a real number"),
    ("lens stop_radius_f1_mm 20", "lens stop_radius_f1_mm 20 mm", 6, "expected 3 fields"),
    ("lens stop_radius_f1_mm 20", "lens f1 20", 6,
     "expected lens key 'stop_radius_f1_mm' .*found 'f1'"),
    ("lens housing_first_mm 15\nlens housing_last_mm 12",
     "lens housing_last_mm 12\nlens housing_first_mm 15", 7,
     "expected lens key 'housing_first_mm'"),
    ("lens housing_last_mm 12", "lens housing_last_mm -12", 8,
     r"lens housing_last_mm = -12: expected a length in \[0.001, 1e\+06\] mm"),
    ("lens squeeze 1", "lens squeeze 0", 11,
     r"lens squeeze = 0: expected a squeeze in \[0.1, 10\]"),
    ("lens focal_length_mm 50", "lens focal_length_mm 0", 4,
     "lens focal_length_mm = 0: expected a focal length of 0.001 to 1e\\+06 mm either sign"),
    ("lens focal_length_mm 50", "lens focal_length_mm nan", 4, "expected a real number"),
    ("lens name My%20lens", "lens name My%2lens", 3, "bad escape"),
    ("lens name My%20lens\n", "", 3, "expected lens key 'name' .*found 'focal_length_mm'"),
    ("lens squeeze 1\n", "", 11, "expected 'lens squeeze <value>' .*found 'system S 2 1'"),
    ("lens squeeze 1\n", "lens squeeze 1\nlens squeeze 1\n", 12, "expected 'system"),
])
def test_malformed_lens_lines_name_the_line(old, new, line, message):
    assert read_table(GOOD2).lens.name == "My lens"  # the unmodified text is fine
    bad = GOOD2.replace(old, new)
    assert bad != GOOD2
    with pytest.raises(ValueError, match=f"^table line {line}: .*{message}"):
        read_table(bad)


def test_version_2_tables_still_read():
    table = read_table(GOOD2)
    assert (table.version, table.lens.name, table.trust) == (2, "My lens", None)
    assert write_table(table).startswith("lensfit-poly-table 2\n")  # no trust: version 2


def test_version_2_without_lens_lines_is_an_error():
    with pytest.raises(ValueError, match="^table line 2: expected 'lens name <value>'"):
        read_table(GOOD.replace("lensfit-poly-table 1", "lensfit-poly-table 2"))


# --- version 3: the trust lines -----------------------------------------------------------

TRUST = {"psf_vs_exact": 0.0017753640198416778, "psf_vs_exact_cell": "f/2 80% corner 450 nm",
         "psf_target": 0.01}


def test_trust_lines_round_trip(systems):
    text = write_table(systems, comment="lens 0001", lens=FACTS, trust=TRUST)
    table = read_table(text)
    assert (table.version, table.lens, table.trust) == (5, FACTS, TRUST)  # exactly
    assert_same(table, systems)
    assert write_table(table, comment="lens 0001") == text  # a Table keeps its trust
    # Without trust figures the same systems and facts are version 2, without both 1
    assert read_table(write_table(systems, lens=FACTS)).version == 2
    assert read_table(write_table(systems)).version == 1


def test_trust_lines_layout():
    """After the lens lines, in the documented order; the cell is an escaped text field."""
    s = System("S", (Input("x", "mm", -2.0, 2.0),), (Polynomial("y", "mm", [[1]], [0.5]),))
    text = write_table([s], comment="c", lens=FACTS, trust=TRUST)
    lines = text.split("\n")
    assert lines[0] == "lensfit-poly-table 5"
    assert lines[2].startswith("lens name ") and lines[10].startswith("lens squeeze ")
    assert lines[11:15] == ["trust psf_vs_exact 0.0017753640198416778",
                            "trust psf_vs_exact_cell f/2%2080%25%20corner%20450%20nm",
                            "trust psf_target 0.01",
                            "system S 1 1"]


@pytest.mark.parametrize(("change", "message"), [
    ({"psf_vs_exact": float("nan")}, "trust: psf_vs_exact = nan: expected a finite number"),
    ({"psf_vs_exact": -1e-3}, "trust: psf_vs_exact = -0.001"),
    ({"psf_target": float("inf")}, "trust: psf_target = inf"),
    ({"psf_target": "1%"}, "trust: psf_target = '1%'"),
    ({"psf_vs_exact_cell": 3}, "trust: psf_vs_exact_cell: expected text"),
    ({"seconds": 20.0}, "trust: expected the keys psf_vs_exact, psf_vs_exact_cell, "
                        "psf_target, found"),
])
def test_writer_refuses_trust_it_cannot_write(systems, change, message):
    with pytest.raises(ValueError, match=message):
        write_table(systems, lens=FACTS, trust={**TRUST, **change})


def test_writer_refuses_trust_without_lens_facts(systems):
    with pytest.raises(ValueError, match="trust figures need the lens facts"):
        write_table(systems, trust=TRUST)


GOOD3 = split_checksum(upgrade_text(stamp(  # version 5: the probe lines added
    GOOD2.replace("lensfit-poly-table 2", "lensfit-poly-table 4")
    .replace("lens squeeze 1\n",
             "lens squeeze 1\n"                              # 11
             "trust psf_vs_exact 0.002\n"                    # 12
             "trust psf_vs_exact_cell f/8%20axis%20550%20nm\n"  # 13
             "trust psf_target 0.01\n"))).encode())[0].decode()  # 14, then system S 2 1


@pytest.mark.parametrize(("old", "new", "line", "message"), [
    ("trust psf_vs_exact 0.002", "trust psf_vs_exact -0.002", 12,
     r"trust psf_vs_exact = -0.002: expected a number in \[1e-12, 10\]"),
    ("trust psf_vs_exact 0.002", "trust psf_vs_exact 0,2%", 12,
     "trust psf_vs_exact: expected a real number"),
    ("trust psf_target 0.01", "trust psf_target inf", 14, "expected a real number"),
    ("trust psf_vs_exact 0.002", "trust psf_vs_exact 0.002 waves", 12,
     "expected 'trust psf_vs_exact <value>'"),
    ("trust psf_vs_exact_cell f/8%20axis", "trust psf_vs_exact_cell f/8%zzaxis", 13,
     "bad escape"),
    ("trust psf_vs_exact 0.002\ntrust psf_vs_exact_cell f/8%20axis%20550%20nm",
     "trust psf_vs_exact_cell f/8%20axis%20550%20nm\ntrust psf_vs_exact 0.002", 12,
     "keys come in the order psf_vs_exact, psf_vs_exact_cell, psf_target"),
    ("trust psf_target 0.01\n", "", 14,
     "expected 'trust psf_target <value>' .*found 'system S 2 1'"),
    ("trust psf_vs_exact 0.002\ntrust psf_vs_exact_cell f/8%20axis%20550%20nm\n"
     "trust psf_target 0.01\n", "", 12, "expected 'trust psf_vs_exact <value>'"),
])
def test_malformed_trust_lines_name_the_line(old, new, line, message):
    table = read_table(GOOD3)  # the unmodified text is fine
    assert table.trust == {"psf_vs_exact": 0.002, "psf_vs_exact_cell": "f/8 axis 550 nm",
                           "psf_target": 0.01}
    bad = GOOD3.replace(old, new)
    assert bad != GOOD3
    with pytest.raises(ValueError, match=f"^table line {line}: .*{message}"):
        read_table(bad)
