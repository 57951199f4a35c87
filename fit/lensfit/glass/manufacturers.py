"""The manufacturers' glass catalogs: SCHOTT, OHARA, HOYA, CDGM, HIKARI and SUMITA.

The catalogs are the manufacturers' own spreadsheets, as shipped in the data folder of
the ``opticalglass`` package (BSD-3-Clause; installed without its GUI dependencies by
``make setup``). Only its data files are used: this module reads them with ``xlrd``
(.xls) and ``openpyxl`` (.xlsx). Each catalog is parsed once, on first use, and kept
(``functools.cache``), so lenses that name only project-catalog glasses never open a
spreadsheet.

Where each spreadsheet keeps what (columns as Excel letters, rows from 1) is in
``CATALOGS``; ``lensdb/glass/README.md`` describes the formulas and the ranges. The
published range of a glass is the span of wavelengths at which its row prints an
index (the catalogs print no other range); outside it the formula is extrapolated.
"""

from __future__ import annotations

import functools
import importlib.util
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lensfit.glass.formulas import FormulaGlass

#: Wavelengths (nm) of the spectral lines that the catalogs name in index headers.
_LINES_NM = {
    "t": 1013.98, "s": 852.11, "A'": 768.19, "r": 706.52, "C": 656.27, "C'": 643.85,
    "He-Ne": 632.8, "D": 589.29, "d": 587.56, "e": 546.07, "F": 486.13, "F'": 479.99,
    "He-Cd": 441.57, "g": 435.83, "h": 404.66, "i": 365.01,
}


@dataclass(frozen=True)
class CatalogLayout:
    """Where one spreadsheet keeps its data (Excel column letters, rows from 1)."""

    maker: str
    file: str
    sheets: tuple[int, ...]  # sheet indices read (same layout each)
    header_row: int  # the row whose cells name the index columns' wavelengths
    first_row: int  # first row of glass data
    name: str
    nd: str
    ne: str
    vd: str
    ve: str
    formula: str
    coefficients: tuple[str, ...]  # first and last column of the coefficients
    indices: tuple[str, str]  # first and last column of the printed indices
    mantissa_exponent: bool = False  # HOYA prints each coefficient as (mantissa, power of 10)


CATALOGS: dict[str, CatalogLayout] = {
    c.maker: c
    for c in (
        CatalogLayout("SCHOTT", "SCHOTT.xls", (0,), 4, 5, name="A", nd="B", ne="C", vd="D",
                      ve="E", formula="sellmeier3", coefficients=("G", "L"),
                      indices=("DM", "EI")),
        CatalogLayout("OHARA", "OHARA.xlsx", (0, 1), 2, 3, name="B", nd="Q", ne="R", vd="AA",
                      ve="AB", formula="sellmeier3", coefficients=("BI", "BN"),
                      indices=("E", "X")),
        CatalogLayout("HOYA", "HOYA.xlsx", (0,), 4, 5, name="C", nd="E", ne="H", vd="F",
                      ve="I", formula="schott", coefficients=("AC", "AN"),
                      indices=("K", "AA"), mantissa_exponent=True),
        CatalogLayout("CDGM", "CDGM.xls", (0,), 2, 3, name="A", nd="J", ne="K", vd="R", ve="S",
                      formula="schott", coefficients=("V", "AA"), indices=("C", "P")),
        CatalogLayout("HIKARI", "HIKARI.xlsx", (0,), 3, 4, name="A", nd="Q", ne="R", vd="Y",
                      ve="Z", formula="hikari", coefficients=("BD", "BL"),
                      indices=("D", "X")),
        CatalogLayout("SUMITA", "SUMITA.xlsx", (0,), 2, 3, name="C", nd="P", ne="Q", vd="D",
                      ve="E", formula="schott", coefficients=("AV", "BA"),
                      indices=("H", "V")),
    )
}

#: The manufacturers, in the order an ambiguity error lists them.
MANUFACTURERS: tuple[str, ...] = tuple(CATALOGS)


class CatalogDataError(RuntimeError):
    """The catalog data (the ``opticalglass`` package) is missing or not as expected."""


def column(letters: str) -> int:
    """Excel column letters -> 0-based index ("A" -> 0, "AA" -> 26)."""
    n = 0
    for ch in letters:
        n = n * 26 + ord(ch) - ord("A") + 1
    return n - 1


def data_dir() -> Path:
    """The folder of the catalog spreadsheets (``opticalglass/data``), found without
    importing the package (its ``__init__`` wants pandas)."""
    spec = importlib.util.find_spec("opticalglass")
    if spec is None or not spec.submodule_search_locations:
        raise CatalogDataError(
            "the manufacturers' glass catalogs need the 'opticalglass' package "
            "(run `make setup`; it installs opticalglass==1.1.1 without its GUI)")
    return Path(next(iter(spec.submodule_search_locations))) / "data"


def _read_rows(path: Path, sheet: int, last_col: int) -> list[list[Any]]:
    """Cell values of one sheet, row by row (empty cells as None or '')."""
    if path.suffix == ".xls":
        import xlrd

        sh = xlrd.open_workbook(str(path)).sheet_by_index(sheet)
        return [sh.row_values(r, 0, min(last_col + 1, sh.ncols)) for r in range(sh.nrows)]
    import warnings

    import openpyxl

    # OHARA's print areas and SUMITA's page headers give harmless warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        wb = openpyxl.load_workbook(str(path), read_only=True, data_only=True)
        try:
            ws = wb.worksheets[sheet]
            return [list(r) for r in ws.iter_rows(max_col=last_col + 1, values_only=True)]
        finally:
            wb.close()


def _number(v: Any) -> float | None:
    """A finite float from a cell, or None (empty, text, '-')."""
    if isinstance(v, bool) or v is None:
        return None
    if isinstance(v, (int, float)):
        return float(v) if math.isfinite(v) else None
    try:
        f = float(str(v).strip())
    except ValueError:
        return None
    return f if math.isfinite(f) else None


def header_wavelength_nm(label: Any) -> float:
    """Wavelength (nm) of an index column from its header: a number in nm (HOYA, CDGM)
    or µm (HIKARI), 'n2325.4', or a spectral line ('nC'', 'ｔ\\n1.01398')."""
    if isinstance(label, (int, float)):
        return float(label) * (1000.0 if label < 10 else 1.0)
    text = str(label).strip()
    last = text.split()[-1] if text.split() else text
    num = _number(last)
    if num is not None:
        return num * (1000.0 if num < 10 else 1.0)
    key = text[1:] if text.startswith("n") else text
    if key in _LINES_NM:
        return _LINES_NM[key]
    m = re.fullmatch(r"n?(\d+(?:\.\d+)?)", text)
    if m:
        return float(m.group(1))
    raise CatalogDataError(f"index column header {label!r}: no wavelength")


@functools.cache
def load_catalog(maker: str) -> dict[str, FormulaGlass]:
    """All glasses of one manufacturer (``MANUFACTURERS``), keyed by upper-case name.
    Parsed once per process. Rows without a name or a complete set of coefficients
    (headings, notes) are skipped."""
    layout = CATALOGS[maker]
    path = data_dir() / layout.file
    c0, c1 = (column(c) for c in layout.coefficients)
    i0, i1 = (column(c) for c in layout.indices)
    cols = {k: column(getattr(layout, k)) for k in ("name", "nd", "ne", "vd", "ve")}
    last = max(c1, i1, *cols.values())
    glasses: dict[str, FormulaGlass] = {}
    for sheet in layout.sheets:
        rows = _read_rows(path, sheet, last)
        header = rows[layout.header_row - 1]
        header += [None] * (last + 1 - len(header))
        waves = [header_wavelength_nm(header[j]) for j in range(i0, i1 + 1)]
        for row in rows[layout.first_row - 1:]:
            row = list(row) + [None] * (last + 1 - len(row))
            name = row[cols["name"]]
            if not isinstance(name, str) or not name.strip():
                continue
            coef = [_number(v) for v in row[c0:c1 + 1]]
            if any(v is None for v in coef):
                continue
            if layout.mantissa_exponent:
                coef = [m * 10.0 ** e for m, e in zip(coef[::2], coef[1::2], strict=True)]
            printed = [w for w, v in zip(waves, row[i0:i1 + 1], strict=True)
                       if _number(v) is not None]
            if not printed:
                continue
            name = " ".join(name.split())
            values = {k: _number(row[cols[k]]) for k in ("nd", "ne", "vd", "ve")}
            glass = FormulaGlass(
                name=name, maker=maker, formula=layout.formula,
                coefficients=tuple(coef), range_nm=(min(printed), max(printed)),
                **{k: math.nan if v is None else v for k, v in values.items()},
                source=f"{layout.file} (opticalglass 1.1.1 data)")
            glasses.setdefault(name.upper(), glass)  # OHARA's second sheet repeats none
    if not glasses:
        raise CatalogDataError(f"{path}: no glass read; not the expected layout")
    return glasses
