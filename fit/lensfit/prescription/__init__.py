"""Prescriptions: the TOML lens format, its validation and the resolved ``Lens``."""

from lensfit.prescription.load import (
    find_lens_file,
    lens_from_dict,
    lensdb_dir,
    list_lenses,
    load_lens,
    make_lens,
    with_coating,
)
from lensfit.prescription.model import BARE, SHAPES, Coating, Layer, Lens, Surface

__all__ = [
    "BARE",
    "SHAPES",
    "Coating",
    "Layer",
    "Lens",
    "Surface",
    "find_lens_file",
    "lens_from_dict",
    "lensdb_dir",
    "list_lenses",
    "load_lens",
    "make_lens",
    "with_coating",
]
