"""Coefficient tables: exact round trip, the documented layout, errors with line numbers."""

from __future__ import annotations

import numpy as np
import pytest

from lensfit.codegen import read_table, write_table
from lensfit.codegen.table import decode_field, encode_field
from lensfit.poly import Input, Polynomial, System


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
    assert write_table([s]) == (
        "lensfit-poly-table 1\n"
        "system P_o 2 1\n"
        "input x mm -2 2 affine 0 2\n"
        "input λ nm 400 800 inverse_square 3.9062500000000001e-06 2.3437500000000002e-06\n"
        "output y mm 2\n"
        "0 0 0.5\n"
        "1 2 -0.33333333333333331\n"
        "end\n")


def test_comments_blank_lines_tabs_and_crlf_are_accepted(systems):
    text = write_table(systems[2:])
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
    ("lensfit-poly-table 1", "lensfit-poly-table 2", 1, "version '2' is not supported"),
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
        read_table("")
    with pytest.raises(ValueError, match="table line 2: no system"):
        read_table("lensfit-poly-table 1\n")
