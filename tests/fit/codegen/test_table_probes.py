"""Semantic corruption behind a valid checksum (issue 39, item 3): version 5's probe lines
and the ranges of the physical keys, in lensfit's reader and in lensrt's (through its
Python binding, where the library is built).

* Coefficient lines swapped (between outputs, or two coefficients of one output
  exchanged), a coefficient or a probe value edited, the checksum made again: refused by
  both, naming the system, the output and both values; with the probes made again too
  the same text loads (so the probes are what refuse it).
* A sample of coefficient swaps in a committed table: each swap that moves the output by
  more than the tolerance at some probe point is refused (the probe points' choice).
* Each lens and trust key out of its range, hex floats, inf and nan, a line of NUL
  bytes, a ghost label that does not number ghost first and second: refused by both,
  naming key and value.
* A version-4 table: refused by both naming `lensfit regenerate` and `lensfit
  upgrade-table`, which rewrite it as version 5, byte for byte what lensfit writes now.
* Hypothesis: crafted tables (a valid table's body mutated, the CRC made again): both
  readers refuse or load without crashing, and they agree on coefficient edits and
  line swaps.
"""

from __future__ import annotations

import re
import shutil
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_table_checksum import _lensrt  # tests/fit/codegen is on sys.path (rootdir)
from test_table_checksum import lensrt_refuses as lensrt_message

from lensfit.cli import main
from lensfit.codegen.generate import upgrade_ghosts_json, upgrade_table
from lensfit.codegen.table import (
    PROBE_RTOL,
    PROBES,
    VERSION,
    probe_inputs,
    probe_problem,
    read_table,
    restamp_probes,
    split_checksum,
    upgrade_text,
    with_checksum,
)
from lensfit.poly.polynomial import design_matrix

ROOT = Path(__file__).resolve().parents[3]
TINY = ROOT / "tests" / "fuzz" / "seeds" / "table" / "ghost_tiny.table"
LENS = ROOT / "generated" / "0001-angenieux-double-gauss"
LENS0001 = LENS / "lens0001.table"




@pytest.fixture(scope="module")
def rt():
    """lensrt through its binding, or None where it is not built (test_table_checksum)."""
    return _lensrt()


def lensfit_message(text: str) -> str | None:
    try:
        read_table(text)
    except ValueError as e:
        return str(e)
    return None


def crc_only(text: str) -> str:
    """``text`` with its checksum line made again, nothing else: a hand edit behind a
    valid checksum."""
    body = split_checksum(text.encode())[0].decode()
    return with_checksum(body if body.endswith("\n") else body + "\n")


def both_refuse(rt, text: str, *needles: str) -> None:
    got = lensfit_message(text)
    assert got is not None, "lensfit loaded it"
    for needle in needles:
        assert needle in got, got
    if rt is not None:
        got = lensrt_message(rt, text.encode(), "x.table")
        assert got is not None, "lensrt loaded it"
        for needle in needles:
            assert needle in got, got


def both_load(rt, text: str) -> None:
    assert lensfit_message(text) is None, lensfit_message(text)
    if rt is not None:
        assert lensrt_message(rt, text.encode()) is None, lensrt_message(rt, text.encode())


@pytest.fixture(scope="module")
def lens_text() -> str:
    return LENS0001.read_text(encoding="utf-8")


def term_line(lines: list[str], output: str, k: int = 0, nth: int = 1) -> int:
    """The index of term k of the nth output named ``output``."""
    at = [i for i, line in enumerate(lines) if line.startswith(f"output {output} ")][nth - 1]
    return at + 1 + k


# --- probes -------------------------------------------------------------------------------


def test_committed_tables_are_version_5_with_probes():
    for path in sorted((ROOT / "generated").rglob("*.table")) + [TINY]:
        text = path.read_text(encoding="utf-8")
        table = read_table(text)
        assert table.version == VERSION == 5
        assert text.count("\nprobe ") == PROBES * len(table), path


def test_swapped_lines_between_outputs_are_refused(rt, lens_text):
    lines = lens_text.splitlines(keepends=True)
    a, b = term_line(lines, "x_o"), term_line(lines, "y_o")
    lines[a], lines[b] = lines[b], lines[a]
    swapped = "".join(lines)
    both_refuse(rt, crc_only(swapped), "system P_o: output x_o: probe 1 of 6",
                "the polynomials give", "behind a valid checksum")
    both_load(rt, restamp_probes(swapped))  # the same text with its probes made again


def test_exchanged_coefficients_of_one_output_are_refused(rt, lens_text):
    lines = lens_text.splitlines(keepends=True)
    for system, output in ((1, "x_o"), (1, "phi_o"), (2, "tau_i"), (2, "phi_i")):
        edited = list(lines)
        a, b = term_line(lines, output, 0), term_line(lines, output, 3)
        ca, cb = lines[a].split()[-1], lines[b].split()[-1]
        edited[a] = lines[a].replace(ca, cb)
        edited[b] = lines[b].replace(cb, ca)
        name = "P_o" if system == 1 else "P_s"
        both_refuse(rt, crc_only("".join(edited)), f"system {name}: output {output}: probe")


def test_an_edited_coefficient_or_probe_is_refused_naming_both_values(rt, lens_text):
    lines = lens_text.splitlines(keepends=True)
    at = term_line(lines, "tau_i", 2, nth=1)
    coef = lines[at].split()[-1]
    edited = list(lines)
    edited[at] = lines[at].replace(coef, repr(float(coef) * (1 + 1e-6)))
    both_refuse(rt, crc_only("".join(edited)), "system P_s: output tau_i", "the probe line says")
    # A probe's output value changed (phi_o, the last of P_o's first probe line)
    at = next(i for i, line in enumerate(lines) if line.startswith("probe "))
    edited = list(lines)
    fields = lines[at].split()
    edited[at] = " ".join([*fields[:-1], "1.5"]) + "\n"
    both_refuse(rt, crc_only("".join(edited)), "system P_o: output phi_o: probe 1 of 6",
                "the probe line says 1.5")
    # A probe input outside its domain, a probe line missing
    edited[at] = " ".join(["probe", "5", *fields[2:]]) + "\n"
    both_refuse(rt, crc_only("".join(edited)), "probe", "x_O", "outside its domain")
    edited[at] = ""
    both_refuse(rt, crc_only("".join(edited)), "probe line 6 of 6 of system")


def test_a_sample_of_coefficient_swaps_moves_a_probe(lens_text):
    """The probe points see every swap that matters: 2,000 random pairs of terms per
    output of lens0001 whose exchange moves the output at some point of a fine grid of
    the domain by more than 1e-6 of its scale are refused by the probes."""
    table = read_table(lens_text)
    rng = np.random.default_rng(39)
    for s in table:
        xhat = s.normalise(probe_inputs(s))
        grid = rng.uniform(-1, 1, (4000, len(s.inputs)))
        for p in s.outputs:
            c = p.coefficients
            scale = np.abs(c).sum()
            m_probe = design_matrix(xhat, p.exponents)
            m_grid = design_matrix(grid, p.exponents)
            i, j = rng.integers(0, len(c), (2, 2000))
            keep = i != j
            i, j = i[keep], j[keep]
            effect = np.abs((c[i] - c[j]) * (m_grid[:, i] - m_grid[:, j])).max(axis=0)
            seen = np.abs((c[i] - c[j]) * (m_probe[:, i] - m_probe[:, j])).max(axis=0)
            matters = effect > 1e-6 * scale
            assert np.all(seen[matters] > PROBE_RTOL * scale), (s.name, p.output)


def test_probe_problem_is_none_for_the_written_values(lens_text):
    table = read_table(lens_text)
    for s in table:
        x = probe_inputs(s)
        assert probe_problem(s, x, s.evaluate(x)) is None
        y = s.evaluate(x)
        y[3, 0] += 1e-3
        assert "probe 4 of 6" in probe_problem(s, x, y)


# --- ranges, numbers, bytes, labels -------------------------------------------------------

RANGES = [
    ("lens focal_length_mm", "1e308"), ("lens focal_length_mm", "0"),
    ("lens focal_length_mm", "-2e6"), ("lens stop_radius_max_mm", "1e-300"),
    ("lens stop_radius_f1_mm", "2e6"), ("lens housing_first_mm", "-54"),
    ("lens housing_last_mm", "0"), ("lens sensor_defocus_mm", "1e30"),
    ("lens front_focal_distance_mm", "-2e6"), ("lens squeeze", "1e6"),
    ("lens squeeze", "0.01"), ("trust psf_vs_exact", "1e308"),
    ("trust psf_vs_exact", "1e-300"), ("trust psf_vs_exact", "0"),
    ("trust psf_target", "0"), ("trust psf_target", "2"), ("trust psf_target", "1e-7"),
]


@pytest.mark.parametrize(("key", "value"), RANGES)
def test_each_key_out_of_range_is_refused_naming_key_and_value(rt, lens_text, key, value):
    text = re.sub(rf"^{key} \S+$", f"{key} {value}", lens_text, count=1, flags=re.M)
    assert text != lens_text
    got = lensfit_message(crc_only(text))
    assert got is not None and f"{key} = {value}" in got and "expected" in got, got
    if rt is not None:
        got = lensrt_message(rt, crc_only(text).encode())
        assert got is not None and f"{key} {value} is out of range" in got, got


def test_values_at_the_ends_of_the_ranges_load(rt, lens_text):
    for key, value in (("lens squeeze", "10"), ("lens squeeze", "0.1"),
                       ("lens sensor_defocus_mm", "-1e6"), ("trust psf_target", "1"),
                       ("trust psf_vs_exact", "10"), ("trust psf_vs_exact", "1e-12")):
        text = re.sub(rf"^{key} \S+$", f"{key} {value}", lens_text, count=1, flags=re.M)
        both_load(rt, crc_only(text))


@pytest.mark.parametrize("number", ["0x1p3", "0X1P3", "inf", "-inf", "nan", "infinity", "1e",
                                    "1.5f", "0x10"])
def test_hex_floats_inf_and_nan_are_refused(rt, lens_text, number):
    lines = lens_text.splitlines(keepends=True)
    at = term_line(lines, "x_o", 0)
    fields = lines[at].split()
    lines[at] = " ".join([*fields[:-1], number]) + "\n"
    text = crc_only("".join(lines))
    assert lensfit_message(text) is not None and "coefficient" in lensfit_message(text)
    if rt is not None:
        assert f"coefficient '{number}' is not a finite number" in lensrt_message(rt, text.encode())
    # ... and as a lens value
    text = crc_only(re.sub(r"^lens squeeze \S+$", f"lens squeeze {number}", lens_text,
                           count=1, flags=re.M))
    both_refuse(rt, text, "squeeze")


@pytest.mark.parametrize("line", ["\0\0\0\0\0\0\0\0\0\0\0\0\0", "0 0 0 1 0 0\0 1",
                                  "# a comment with a \x01 in it", "0 0 0 1 0 0 1\x7f",
                                  "0 0 0 1\r0 0 1"])
def test_control_bytes_are_refused(rt, lens_text, line):
    lines = lens_text.splitlines(keepends=True)
    at = term_line(lines, "x_o", 1)
    text = crc_only("".join([*lines[:at], line + "\n", *lines[at:]]))
    both_refuse(rt, text, "control byte 0x", "refused")
    got = lensfit_message(text)
    assert got.startswith(f"table line {at + 1}: control byte"), got


@pytest.mark.parametrize(("label", "ok"), [
    ("1-3", True), ("1-2", True), ("0-2", True),
    ("1-3-9", False), ("1-4", False), ("2-3", False), ("0-3", False), ("01-3", False),
    ("1-", False), ("x", False), ("-", False), ("1%2D3", True),
])
def test_ghost_label_numbers_first_and_second(rt, label, ok):
    text = TINY.read_text(encoding="utf-8").replace("ghost label 1-3\n", f"ghost label {label}\n")
    text = crc_only(text)
    if ok:
        both_load(rt, text)
    else:
        both_refuse(rt, text, "does not number ghost first 1 and ghost second 3")


# --- version 4 ----------------------------------------------------------------------------


def as_version_4(text: str) -> str:
    body = split_checksum(text.encode())[0].decode()
    body = "".join(line for line in body.splitlines(keepends=True)
                   if not line.startswith("probe "))
    return with_checksum(body.replace("lensfit-poly-table 5\n", "lensfit-poly-table 4\n", 1))


def test_version_4_is_refused_with_the_commands_that_upgrade_it(rt, lens_text, tmp_path):
    v4 = as_version_4(lens_text)
    with pytest.raises(ValueError, match=r"^table line 1: table version 4 carries no probe "
                                         r"lines .*`lensfit regenerate .*`lensfit upgrade-table"):
        read_table(v4)
    assert read_table(v4, legacy=True).version == 4
    if rt is not None:
        got = lensrt_message(rt, v4.encode(), "generated/0001-x/lens0001.table")
        assert "table version 4 carries no probe lines" in got
        assert "`lensfit regenerate 0001-x`" in got
        assert "`lensfit upgrade-table generated/0001-x/lens0001.table`" in got
    # Upgraded: byte for byte the committed version 5 (comments and all kept)
    assert upgrade_text(v4) == lens_text
    path = tmp_path / "lens0001.table"
    path.write_text(v4, encoding="utf-8")
    assert main(["upgrade-table", str(path)]) == 0
    assert path.read_text(encoding="utf-8") == lens_text
    assert main(["upgrade-table", str(path)]) == 0  # already 5: unchanged
    assert path.read_text(encoding="utf-8") == lens_text
    if rt is not None:
        rt.load(path)


def test_regenerate_upgrades_ghost_tables_and_their_record(tmp_path):
    """A folder's version-4 ghost tables upgraded in place, ghosts.json's table_crc32
    following them (lensfit ghosts reuses a fit only when they match)."""
    folder = tmp_path / "ghosts"
    shutil.copytree(LENS / "ghosts", folder)
    committed = {p.name: p.read_bytes() for p in folder.iterdir()}
    for p in folder.glob("*.table"):
        p.write_text(as_version_4(p.read_text(encoding="utf-8")), encoding="utf-8")
    assert all(upgrade_table(p) for p in sorted(folder.glob("*.table")))
    assert not upgrade_ghosts_json(folder / "ghosts.json")  # the CRCs are the committed ones
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == committed


# --- crafted tables: a valid body mutated, the checksum made again ------------------------

TINY_TEXT = TINY.read_text(encoding="utf-8")
TINY_LINES = split_checksum(TINY_TEXT.encode())[0].decode().splitlines(keepends=True)
TERMS = [i for i, line in enumerate(TINY_LINES)
         if re.fullmatch(r"([0-9]+ ){6}\S+\n", line)]
SETTINGS = settings(max_examples=150, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])


@SETTINGS
@given(k=st.sampled_from(TERMS),
       value=st.floats(allow_nan=False, allow_infinity=False, min_value=-1e3, max_value=1e3))
def test_crafted_coefficient_edits(rt, k, value):
    lines = list(TINY_LINES)
    fields = lines[k].split()
    old = float(fields[-1])
    lines[k] = " ".join([*fields[:-1], repr(value)]) + "\n"
    text = with_checksum("".join(lines))
    ours = lensfit_message(text)
    if rt is not None:
        assert (ours is None) == (lensrt_message(rt, text.encode()) is None), ours
    # A change that moves a probe by over twice the tolerance is refused
    table = read_table(TINY_TEXT)
    where = max(i for i, line in enumerate(TINY_LINES[:k]) if line.startswith("system "))
    s = next(t for t in table if TINY_LINES[where].split()[1] == t.name)
    out = max(i for i, line in enumerate(TINY_LINES[:k]) if line.startswith("output "))
    p = s.output(TINY_LINES[out].split()[1])
    m = np.abs(design_matrix(s.normalise(probe_inputs(s)), p.exponents[k - out - 1:k - out]))
    scale = np.abs(p.coefficients).sum() - abs(old) + abs(value)
    if abs(value - old) * m.max() > 2 * PROBE_RTOL * scale:
        assert ours is not None and "probe" in ours, (k, value)


@SETTINGS
@given(a=st.sampled_from(TERMS), b=st.sampled_from(TERMS))
def test_crafted_line_swaps(rt, a, b):
    lines = list(TINY_LINES)
    lines[a], lines[b] = lines[b], lines[a]
    text = with_checksum("".join(lines))
    ours = lensfit_message(text)
    if rt is not None:
        assert (ours is None) == (lensrt_message(rt, text.encode()) is None), ours
    if ours is None:  # only a swap that changes nothing loads (lines of one output)
        grid = np.random.default_rng(a * 1000 + b).uniform(-1, 1, (200, 6))
        for s, t in zip(read_table(text), read_table(TINY_TEXT), strict=True):
            x = np.column_stack([inp.lo + (inp.hi - inp.lo) * (g + 1) / 2
                                 for inp, g in zip(s.inputs, grid.T, strict=False)])
            assert np.allclose(s.evaluate(x), t.evaluate(x), rtol=0, atol=1e-12), (a, b)


@SETTINGS
@given(data=st.data())
def test_crafted_byte_mutations_never_crash(rt, data):
    body = split_checksum(TINY_TEXT.encode())[0]
    at = data.draw(st.integers(0, len(body) - 2))
    how = data.draw(st.sampled_from(["replace", "insert", "delete", "token"]))
    if how == "token":
        token = data.draw(st.sampled_from([b"probe", b"0x1p3", b"inf", b"nan", b"1e308",
                                           b"-0", b"\0", b"\t", b"#", b"end\n", b"\n"]))
        body = body[:at] + token + body[at:]
    elif how == "insert":
        body = body[:at] + bytes([data.draw(st.integers(0, 255))]) + body[at:]
    elif how == "delete":
        body = body[:at] + body[at + 1:]
    else:
        body = body[:at] + bytes([data.draw(st.integers(0, 255))]) + body[at + 1:]
    if not body.endswith(b"\n"):
        body += b"\n"
    data_ = body + f"checksum crc32 {zlib.crc32(body) & 0xFFFFFFFF:08x}\n".encode()
    try:
        read_table(data_.decode("utf-8"))
    except (ValueError, UnicodeDecodeError):
        pass
    if rt is not None:
        lensrt_message(rt, data_)  # any answer but a crash
