"""Shared helpers for the lensfit tests: synthetic lenses built from surface lists."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from lensfit.prescription import Lens, lens_from_dict


def lens_data(surfaces: list[dict[str, Any]], **info: Any) -> dict[str, Any]:
    """Plain data of a synthetic lens in the lensdb layout (bare surfaces by default)."""
    lens = {
        "id": "test",
        "name": "synthetic test lens",
        "maker": "tests",
        "year": 2026,
        "source": "tests",
    }
    lens.update(info)
    return {
        "schema_version": 1,
        "lens": lens,
        "coating": {"default": "none"},
        "surface": surfaces,
    }


@pytest.fixture
def build_lens() -> Callable[..., Lens]:
    """``build_lens(surfaces, coating=None, **lens_info)`` -> validated Lens."""

    def build(
        surfaces: list[dict[str, Any]], coating: dict[str, Any] | None = None, **info: Any
    ) -> Lens:
        data = lens_data(surfaces, **info)
        if coating is not None:
            data["coating"] = coating
        return lens_from_dict(data, file="<test>")

    return build
