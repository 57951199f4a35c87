"""Fixtures of the code generation tests."""

from __future__ import annotations

import pytest
from codegen_systems import make_systems

from lensfit.poly import System


@pytest.fixture(scope="session")
def systems() -> list[System]:
    return make_systems()
