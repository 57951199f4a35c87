"""Glass dispersion: the project catalog, the manufacturers' catalogs, inline glasses
(formulas, tables, constant indices), the nd/vd(/dPgF) model and air. ``resolve_glass``
turns a lens file's glass name into a medium."""

from lensfit.glass.catalog import (
    AIR,
    LAMBDA_C_NM,
    LAMBDA_D_NM,
    LAMBDA_F_NM,
    LAMBDA_G_NM,
    MODEL_DPGF_MAX,
    MODEL_ND_RANGE,
    MODEL_VD_RANGE,
    AbbeGlass,
    Air,
    Medium,
    SellmeierGlass,
    UnknownGlassError,
    abbe_glass,
    abbe_number,
    catalog_glass,
    catalog_path,
    known_glass_names,
    normal_line_pgf,
    partial_dispersion,
)
from lensfit.glass.formulas import FORMULAS, FormulaGlass
from lensfit.glass.inline import ConstantGlass, InlineGlassError, TableGlass, inline_glass
from lensfit.glass.manufacturers import MANUFACTURERS
from lensfit.glass.resolve import AmbiguousGlassError, resolve_glass

__all__ = [
    "AIR",
    "AbbeGlass",
    "Air",
    "AmbiguousGlassError",
    "ConstantGlass",
    "FORMULAS",
    "FormulaGlass",
    "InlineGlassError",
    "LAMBDA_C_NM",
    "LAMBDA_D_NM",
    "LAMBDA_F_NM",
    "LAMBDA_G_NM",
    "MANUFACTURERS",
    "MODEL_DPGF_MAX",
    "MODEL_ND_RANGE",
    "MODEL_VD_RANGE",
    "Medium",
    "SellmeierGlass",
    "TableGlass",
    "UnknownGlassError",
    "abbe_glass",
    "abbe_number",
    "catalog_glass",
    "catalog_path",
    "inline_glass",
    "known_glass_names",
    "normal_line_pgf",
    "partial_dispersion",
    "resolve_glass",
]
