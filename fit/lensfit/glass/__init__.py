"""Glass dispersion: catalog Sellmeier glasses, the nd/vd model and air."""

from lensfit.glass.catalog import (
    AIR,
    LAMBDA_C_NM,
    LAMBDA_D_NM,
    LAMBDA_F_NM,
    LAMBDA_G_NM,
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
)

__all__ = [
    "AIR",
    "AbbeGlass",
    "Air",
    "LAMBDA_C_NM",
    "LAMBDA_D_NM",
    "LAMBDA_F_NM",
    "LAMBDA_G_NM",
    "Medium",
    "SellmeierGlass",
    "UnknownGlassError",
    "abbe_glass",
    "abbe_number",
    "catalog_glass",
    "catalog_path",
    "known_glass_names",
]
