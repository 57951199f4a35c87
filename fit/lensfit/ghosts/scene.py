"""A scene's flares: which of the lens's fitted ghosts it keeps, and their systems.

``lensfit ghosts LENS --fit`` writes the fitted ghosts to ``generated/<lens>/ghosts/``
(ghosts.json and one table per ghost). A scene with ``flares = true`` keeps:

* ``ghosts = ["i-j", ...]``: exactly these (the lens file's numbering);
* ``ghost_count = K``: the K brightest for the scene's own lights and stop;
* ``ghost_threshold = T``: those whose peak is above T of the direct PSF's peak for at
  least one of the scene's lights;
* none of the three: the visible ones, those a photograph of at least one of the scene's
  lights shows (:mod:`lensfit.ghosts.enumerate`, "Visibility": the light's peak pixel
  DEFAULT_OVEREXPOSURE_STOPS over white, 8 stops shown below it).

Brightness is the enumeration's exact-ray estimate (:func:`lensfit.ghosts.enumerate.
enumerate_ghosts`) for each light at the scene's f-number (wide open without one),
restricted to the fitted ghosts. Each kept ghost is then specialised as the direct
systems are (:func:`lensfit.codegen.scene.specialise`, P_clip folded with its ghost side).
"""

from __future__ import annotations

from pathlib import Path

from lensfit.codegen.scene import Scene, SceneError
from lensfit.codegen.table import Table, read_table
from lensfit.common.errors import InputError
from lensfit.ghosts.enumerate import (
    DEFAULT_OVEREXPOSURE_STOPS,
    black_level,
    enumerate_ghosts,
    parse_ghost,
)
from lensfit.ghosts.tasks import read_ghost_index
from lensfit.prescription.model import Lens


def fitted_ghosts(folder: Path, lens_arg: str) -> dict[str, Table]:
    """The fitted ghost tables of a lens folder, by label ("4-8"), in ghosts.json's
    order; an error naming the file when there are none or one is unreadable."""
    index = folder / "ghosts" / "ghosts.json"
    if not index.is_file():
        raise InputError(f"{index}: not found: the lens has no fitted ghosts; run "
                         f"`lensfit ghosts {lens_arg} --fit` (with --count or --ghost)")
    entries = [(g["label"], g["first"], g["second"]) for g in read_ghost_index(index)]
    out = {}
    for label, i, j in entries:
        path = index.parent / f"ghost_{i}_{j}.table"
        try:
            table = read_table(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as e:
            raise InputError(f"{path}: {e}") from None
        if table.ghost is None or table.ghost.label != label:
            raise InputError(f"{path}: expected the ghost table of {label}")
        out[label] = table
    return out


def choose_ghosts(lens: Lens, scene: Scene, fitted: dict[str, Table]) -> list[str]:
    """The labels of the fitted ghosts ``scene`` keeps (module doc), brightest first for
    a count or threshold."""
    where = f"{scene.source_file}: key 'ghosts':"
    if scene.ghosts is not None:
        labels: list[str] = []
        names: dict[str, str] = {}
        for name in scene.ghosts:
            i, j = parse_ghost(lens, name, where)
            label = f"{lens.file_index(i)}-{lens.file_index(j)}"
            if label in names:  # its flare would be added twice
                raise SceneError(f"{where} ghost {label} is given twice (as "
                                 f"{names[label]!r} and {name!r}); give it once")
            names[label] = name
            if label not in fitted:
                raise SceneError(f"{where} ghost {name!r} is not fitted for {lens.name} "
                                 f"(fitted: {', '.join(fitted) or 'none'}); run `lensfit "
                                 f"ghosts LENS --fit --ghost {label}`")
            labels.append(label)
        return labels
    pairs = [(t.ghost.first, t.ghost.second) for t in fitted.values()]
    # Per ghost, the largest over the scene's lights of its relative peak (for a
    # threshold) and of its exposure peak (visibility, and the order)
    peak = dict.fromkeys(fitted, 0.0)
    exposure = dict.fromkeys(fitted, 0.0)
    for light in scene.lights:
        for g in enumerate_ghosts(lens, f_number=scene.f_number,
                                  light=(light.field_x_deg, light.field_y_deg),
                                  distance_mm=light.distance_mm, pairs=pairs):
            peak[g.name] = max(peak[g.name], g.relative_peak)
            exposure[g.name] = max(exposure[g.name], g.exposure_peak)
    if scene.ghost_count is not None:
        return sorted(exposure, key=lambda k: -exposure[k])[:scene.ghost_count]
    if scene.ghost_threshold is not None:
        threshold = scene.ghost_threshold
        ranked = sorted(peak, key=lambda k: -peak[k])
        keep = [k for k in ranked if peak[k] > threshold]
        if not keep:
            raise SceneError(f"{scene.source_file}: key 'ghost_threshold': no fitted ghost of "
                             f"{lens.name} peaks above {threshold:g} of the PSF peak for "
                             f"this scene's lights (the brightest, {ranked[0]}, peaks at "
                             f"{peak[ranked[0]]:.3g}); set ghost_count or ghosts instead")
        return keep
    black = black_level()
    ranked = sorted(exposure, key=lambda k: -exposure[k])
    keep = [k for k in ranked if exposure[k] >= black]
    if not keep:
        raise SceneError(f"{scene.source_file}: key 'flares': no fitted ghost of {lens.name} "
                         f"is visible for this scene's lights (its peak pixel at least "
                         f"{black:.3g} of the light's, the light "
                         f"{DEFAULT_OVEREXPOSURE_STOPS:g} stops over white; the brightest, "
                         f"{ranked[0]}, is at {exposure[ranked[0]]:.3g}); set ghost_count, "
                         "ghost_threshold or ghosts instead")
    return keep
