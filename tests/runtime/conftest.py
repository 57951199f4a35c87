"""Fixtures for the lensrt runtime tests: the ctypes binding and one context per session.

The tests need the shared library that `make runtime` builds (`make test` builds it
first). Without it every test here is skipped with a message that says so. Set
LENSRT_LIBRARY to test another build of the library.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "runtime" / "python"))

from lensrt_ctypes import LIBRARY  # noqa: E402  (needs the path above)

SKIP_MESSAGE = (f"lensrt runtime tests need {LIBRARY}: build it with `make runtime` "
                "(`make test` builds it first)")


@pytest.fixture(autouse=True)
def _needs_lensrt() -> None:
    if not LIBRARY.exists():
        pytest.skip(SKIP_MESSAGE)


@pytest.fixture(scope="session")
def rt():
    """A lensrt context with the OpenMP default number of threads."""
    if not LIBRARY.exists():
        pytest.skip(SKIP_MESSAGE)
    from lensrt_ctypes import Lensrt

    return Lensrt(LIBRARY)


@pytest.fixture(scope="session")
def rt1():
    """A single-threaded context: cheaper for many tiny renders (no OpenMP barriers)."""
    if not LIBRARY.exists():
        pytest.skip(SKIP_MESSAGE)
    from lensrt_ctypes import Lensrt

    return Lensrt(LIBRARY, threads=1)
