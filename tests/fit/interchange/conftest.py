"""Shared by the importer tests."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from lensfit.interchange import ImportProblems, convert_optiland


@pytest.fixture
def optiland_problems() -> Callable[[dict[str, Any], str], list[str]]:
    """The problem lines with which convert_optiland refuses ``data`` read as ``label``
    (it must refuse)."""

    def problems(data: dict[str, Any], label: str) -> list[str]:
        with pytest.raises(ImportProblems) as e:
            convert_optiland(data, label=label)
        return e.value.problems

    return problems
