"""Shared helpers for the lensfit tests: synthetic lenses built from surface lists."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from lensfit.prescription import Lens, make_lens


@pytest.fixture
def build_lens() -> Callable[..., Lens]:
    """``build_lens(surfaces, coating=None, **lens_info)`` -> validated Lens."""

    def build(surfaces, coating=None, **info) -> Lens:
        return make_lens(surfaces, coating=coating, file="<test>", **info)

    return build
