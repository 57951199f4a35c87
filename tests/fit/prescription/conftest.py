"""Shared fixtures for the prescription tests: a small valid lens written to tmp_path."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

# A thick biconvex N-BK7 singlet behind a plane stop. Every edited line is unique so
# that a test can change exactly one key of exactly one surface. Geometry: the front
# sag at the 10 mm semi-diameter is 50 - sqrt(50² - 10²) = 1.01 mm and the back sag
# at 9.5 mm is -0.91 mm, so the 5 mm centre thickness leaves a 3 mm edge; the sensor
# sits near the paraxial focus (BFD about 47.5 mm).
SINGLET_TOML = """\
schema_version = 1

[lens]
id = "9000"
name = "test singlet"
maker = "test"
year = 2024
source = "unit test"

[[surface]]  # 0: the stop
shape = "plane"
thickness = 2.0
material = "air"
semi_diameter = 8.0
stop = true

[[surface]]  # 1: front of the singlet
shape = "sphere"
radius = 50.0
thickness = 5.0
material = "N-BK7"
semi_diameter = 10.0

[[surface]]  # 2: back of the singlet
shape = "sphere"
radius = -50.0
thickness = 47.0
material = "air"
semi_diameter = 9.5
"""

LensWriter = Callable[..., Path]


@pytest.fixture
def singlet_toml() -> str:
    return SINGLET_TOML


@pytest.fixture
def write_lens(tmp_path: Path) -> LensWriter:
    """write_lens(text, name="lens") writes a TOML file into tmp_path and returns it."""

    def write(text: str, name: str = "lens") -> Path:
        path = tmp_path / f"{name}.toml"
        path.write_text(text, encoding="utf-8")
        return path

    return write


@pytest.fixture
def singlet_variant(write_lens: LensWriter) -> LensWriter:
    """singlet_variant(old, new) writes the singlet with the one occurrence of ``old``
    replaced by ``new`` (failing if ``old`` is not there exactly once)."""

    def variant(old: str, new: str, name: str = "variant") -> Path:
        assert SINGLET_TOML.count(old) == 1, f"{old!r} must occur once in the base lens"
        return write_lens(SINGLET_TOML.replace(old, new), name)

    return variant
