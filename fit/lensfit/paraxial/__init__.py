"""First-order optics: focal lengths, pupils, f-number and focusing."""

from lensfit.paraxial.paraxial import (
    D_LINE_NM,
    Paraxial,
    Pupil,
    f_number_for_stop_radius,
    image_distance,
    paraxial,
    stop_radius_f1_mm,
    stop_radius_for_f_number,
    system_matrix,
    table,
)

__all__ = [
    "D_LINE_NM",
    "Paraxial",
    "Pupil",
    "f_number_for_stop_radius",
    "image_distance",
    "paraxial",
    "stop_radius_f1_mm",
    "stop_radius_for_f_number",
    "system_matrix",
    "table",
]
