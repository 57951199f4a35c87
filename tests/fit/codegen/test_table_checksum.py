"""Integrity of what lensfit writes and lensrt and lensfit load (issue 25): coefficient
tables end with a CRC-32 of their content (version 4 on), fit.json and ghosts.json carry one.

* 1,000 seeded single-bit flips of a table: every one refused by lensfit's reader and by
  lensrt's loader (a CRC-32 detects every single-bit error, so this is a test of both
  readers checking it, and of the checksum line's own strict form).
* A ghost table cut after its P_s system (its P_clip is optional, so the cut text is a
  well-formed table) is refused by both.
* A version-3 table is refused by both naming `lensfit regenerate`, which rewrites it as
  version 4 with its coefficients bit for bit.
* A changed fit.json or ghosts.json is refused naming the file and the key.
"""

from __future__ import annotations

import ctypes as C
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from lensfit.codegen.checked_json import load_checked_json
from lensfit.codegen.generate import read_fit_json, upgrade_json, upgrade_table
from lensfit.codegen.table import read_table, split_checksum, write_table
from lensfit.common.errors import InputError

ROOT = Path(__file__).resolve().parents[3]
TINY = ROOT / "tests" / "fuzz" / "seeds" / "table" / "ghost_tiny.table"  # a whole ghost table
LENS = ROOT / "generated" / "0001-angenieux-double-gauss"
FLIPS = 1000


def _lensrt():
    """lensrt through its Python binding, or None where the library is not built (the
    lensfit side of each test still runs)."""
    import sys

    sys.path.insert(0, str(ROOT / "runtime" / "python"))
    try:
        from lensrt_ctypes import LIBRARY, Lensrt
    except ImportError:
        return None
    if not LIBRARY.exists():
        return None
    rt = Lensrt(LIBRARY)
    rt.lib.lensrt_lens_load_text.argtypes = [C.c_void_p, C.c_char_p, C.c_size_t, C.c_char_p,
                                             C.POINTER(C.c_void_p)]
    return rt


@pytest.fixture(scope="module")
def rt():
    return _lensrt()


def lensrt_refuses(rt, data: bytes, name: str = "x.table") -> str | None:
    """lensrt_lens_load_text's message for `data`, or None when it loads."""
    lens = C.c_void_p()
    code = rt.lib.lensrt_lens_load_text(rt.ctx, data, C.c_size_t(len(data)), name.encode(),
                                        C.byref(lens))
    if code == 0:
        rt.lib.lensrt_lens_destroy(rt.ctx, lens)
        return None
    return rt.lib.lensrt_context_last_error(rt.ctx).decode("utf-8", "replace")


def lensfit_refuses(data: bytes) -> bool:
    try:
        read_table(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        return True
    return False


def test_every_single_bit_flip_is_refused(rt):
    data = TINY.read_bytes()
    assert not lensfit_refuses(data)  # the unflipped table is fine: the refusals are real
    if rt is not None:
        rt.lib.lensrt_lens_load_text.argtypes = [C.c_void_p, C.c_char_p, C.c_size_t,
                                                 C.c_char_p, C.POINTER(C.c_void_p)]
        assert lensrt_refuses(rt, data) is None
    rng = np.random.default_rng(25)
    bits = rng.integers(0, 8 * len(data), FLIPS)
    for bit in bits:
        bad = bytearray(data)
        bad[bit // 8] ^= 1 << (bit % 8)
        assert lensfit_refuses(bytes(bad)), f"lensfit accepted a flip of bit {bit}"
        if rt is not None:
            assert lensrt_refuses(rt, bytes(bad)) is not None, f"lensrt accepted bit {bit}"


def test_a_ghost_table_cut_after_p_s_is_refused(rt, tmp_path):
    text = (LENS / "ghosts" / "ghost_4_8.table").read_text(encoding="utf-8")
    lines = text.splitlines(keepends=True)
    ends = [i for i, line in enumerate(lines) if line == "end\n"]
    assert len(ends) == 3  # P_o, P_s, P_clip
    cut = "".join(lines[:ends[1] + 1])  # what `head -n` left: well formed without P_clip
    with pytest.raises(ValueError, match="expected the last line 'checksum crc32"):
        read_table(cut)
    if rt is not None:
        path = tmp_path / "ghost_4_8.table"
        path.write_text(cut, encoding="utf-8")
        with pytest.raises(Exception, match="expected the last line 'checksum crc32"):
            rt.load(path)


def test_version_3_is_refused_and_regenerate_upgrades_it_bit_for_bit(rt, tmp_path):
    v5 = TINY.read_text(encoding="utf-8")
    body = split_checksum(v5.encode())[0].decode()
    v3 = "".join(line for line in body.splitlines(keepends=True)
                 if not line.startswith("probe ")).replace("lensfit-poly-table 5\n",
                                                           "lensfit-poly-table 3\n", 1)
    folder = tmp_path / "0042-tiny" / "ghosts"
    folder.mkdir(parents=True)
    path = folder / "ghost_1_3.table"
    path.write_text(v3, encoding="utf-8")
    with pytest.raises(ValueError, match="version 3 carries no checksum.*lensfit regenerate"):
        read_table(v3)
    if rt is not None:
        # The message names the generated folder (the one above ghosts/)
        with pytest.raises(Exception, match="lensfit regenerate 0042-tiny`"):
            rt.load(path)
    assert upgrade_table(path)
    assert path.read_text(encoding="utf-8") == v5  # the same bytes as lensfit writes now
    assert not upgrade_table(path)  # idempotent
    if rt is not None:
        rt.load(path)


def test_fit_json_changes_are_refused(tmp_path):
    folder = tmp_path / "fit"
    folder.mkdir()
    shutil.copy(LENS / "scene-fits" / "demo" / "fit.json", folder / "fit.json")
    table = json.loads((folder / "fit.json").read_text())["table"]
    shutil.copy(LENS / "scene-fits" / "demo" / table, folder / table)
    good = (folder / "fit.json").read_bytes()
    read_fit_json(folder / "fit.json")  # as committed: fine
    rng = np.random.default_rng(26)
    for bit in rng.integers(0, 8 * len(good), 200):
        bad = bytearray(good)
        bad[bit // 8] ^= 1 << (bit % 8)
        (folder / "fit.json").write_bytes(bytes(bad))
        with pytest.raises(InputError, match="fit.json"):
            read_fit_json(folder / "fit.json")
    # A change a JSON parser forgives (an exponent's case) is refused all the same
    doc = good.decode()
    assert "e-" in doc
    (folder / "fit.json").write_text(doc.replace("e-", "E-", 1))
    with pytest.raises(InputError, match="key 'checksum'.*does not match"):
        read_fit_json(folder / "fit.json")
    # Written before checksums: refused with the command, read by regenerate (legacy),
    # and upgraded to exactly what lensfit writes
    old = {k: v for k, v in json.loads(doc).items() if k != "checksum"}
    (folder / "fit.json").write_text(json.dumps(old, indent=1, sort_keys=True) + "\n")
    with pytest.raises(InputError, match="key 'checksum': missing.*lensfit regenerate"):
        read_fit_json(folder / "fit.json")
    read_fit_json(folder / "fit.json", legacy=True)
    assert upgrade_json(folder / "fit.json")
    assert (folder / "fit.json").read_bytes() == good


def test_ghosts_json_changes_are_refused(tmp_path):
    from lensfit.ghosts.scene import fitted_ghosts

    shutil.copytree(LENS / "ghosts", tmp_path / "ghosts")
    index = tmp_path / "ghosts" / "ghosts.json"
    assert set(fitted_ghosts(tmp_path, "0001")) >= {"0-2", "4-8"}
    doc = load_checked_json(index, "")
    kept = json.loads(index.read_text())["checksum"]
    doc["ghosts"] = doc["ghosts"][:1]  # a ghost dropped by hand, the old checksum kept
    index.write_text(json.dumps({**doc, "checksum": kept}, indent=1, sort_keys=True) + "\n")
    with pytest.raises(InputError, match="ghosts.json: key 'checksum'"):
        fitted_ghosts(tmp_path, "0001")


def test_written_tables_round_trip_with_their_checksum():
    # What the reader accepts of lensfit's own, the writer writes again byte for byte
    # (checksum included; the comment lines are the reader's to skip, given back here)
    text = (LENS / "scenes" / "demo" / "lens0001_demo.table").read_text(encoding="utf-8")
    table = read_table(text)
    assert table.version == 5
    comment = "\n".join(line[2:] for line in text.splitlines() if line.startswith("# "))
    assert write_table(table, comment=comment) == text
