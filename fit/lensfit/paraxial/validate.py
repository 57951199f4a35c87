"""Checks that a prescription is what its patent says: paraxial EFL against the
patent focal length (after the lens's scale factor), to 1%."""

from __future__ import annotations

import math

from lensfit.paraxial import paraxial
from lensfit.prescription import load_lens

# Patent tables round radii and thicknesses to 0.01 mm and indices to 1e-4; on these
# lenses that moves the EFL by well under 0.5%, so a 1% gap means a transcription error.
EFL_TOLERANCE = 0.01


def efl_check(name: str) -> tuple[bool, str]:
    """(passed, one-line message). A lens with an ``efl_check`` note in its [lens]
    table is not compared; the note says why and the message repeats it."""
    lens = load_lens(name)
    info = lens.provenance
    efl = paraxial(lens, meridian="y").efl_mm
    label = f"{lens.source_file}: EFL {efl:.3f} mm"
    if lens.anamorphic:
        efl_x = paraxial(lens, meridian="x").efl_mm
        label = f"{lens.source_file}: EFL y {efl:.3f} mm, x {efl_x:.3f} mm"
    if "efl_check" in info:
        return True, f"{label}; not compared: {info['efl_check']}"
    f_patent = info.get("focal_length_mm")
    if f_patent is None:
        return False, f"{label}; no focal_length_mm and no efl_check note in [lens]"
    target = f_patent * info.get("scale", 1.0)
    err = (efl - target) / target if math.isfinite(efl) else math.inf
    ok = abs(err) <= EFL_TOLERANCE
    return ok, f"{label} vs patent {target:.3f} mm ({100 * err:+.2f}%)"
