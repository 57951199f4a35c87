"""Bank specs for the tests (lensfit.banks.spec): small grids of lens 0001 at f/8 on the
axis row that render in a second or so. pytest puts tests/fit on the path (its
conftest.py), so the bank tests import this as ``bank_specs``."""

from __future__ import annotations

from collections.abc import Sequence

CELLS = 'integrator = "cells"\ntarget_error = 0.05'


def bank_spec(name: str = "t", *, fields_x: Sequence[float] | str = (0, 5),
              wavelengths: Sequence[float] = (500, 600), pixels: int = 16,
              size_mm: float = 0.06, render: str = CELLS) -> str:
    """The spec's TOML text (name and render may be "{name}" and "{render}" templates)."""
    fields = fields_x if isinstance(fields_x, str) else str(list(fields_x))
    return f"""name = "{name}"
lens = "0001"
[grid]
field_x_deg = {fields}
field_y_deg = [0]
f_numbers = [8]
wavelengths_nm = {list(wavelengths)}
[window]
pixels = [{pixels}, {pixels}]
size_mm = [{size_mm:g}, {size_mm:g}]
[render]
{render}
"""
