"""Import lens tables in the JSON layout of the lentil lens database.

That layout (see ``../shared/lensdata/README.md``) lists elements from scene to sensor
with ``radius`` (0 or a huge value for a flat), ``thickness`` (a list for zoom
positions: the first is taken), ``material`` (a glass name, ``abbe`` for nd/vd only,
``air``, ``iris`` for the stop), ``ior`` and ``abbe`` (nd, vd), ``housing-radius``
(a radius) and ``lens-geometry`` (``spherical``, ``aspherical``, ``cyl-x``, ``cyl-y``).

Choices made by the importer, each written into the lens's notes:

* A named glass uses its catalog Sellmeier data when the catalog (also tried with the
  Schott ``N-`` prefix) has it with nd within ``GLASS_ND_MATCH`` of the table's value;
  otherwise the table's nd/vd are kept and the name becomes a ``glass_label``. Patents
  give nd and vd, so that is the number to stay faithful to.
* ``cyl-x`` becomes ``cylinder-x`` (cylinder axis along x, power in y) and ``cyl-y``
  becomes ``cylinder-y``, following the axis naming of lentil's cylinder intersection.
* Aspheres get conic 0 (the layout has no conic) and A4..A10 from
  ``aspherical-equation``.
* A housing radius larger than |radius| is reduced to 99.9% of |radius| (a
  hemisphere is the most a spherical surface can be).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path
from typing import Any

from lensfit.common.errors import LensError
from lensfit.glass import UnknownGlassError, catalog_glass

# Catalog melts vary by about 1e-3 in nd; a larger gap means a different glass.
GLASS_ND_MATCH = 1e-3
FLAT_RADIUS = 1e4  # |radius| at or above this (lentil writes 99999) is a flat
COATED_FROM_YEAR = 1940  # single-layer MgF2 became common in the 1940s


def load_lentil_json(path: str | Path) -> dict[str, Any]:
    from lensfit.common import strict_json

    p = Path(path)
    # Encodings, huge numbers and deep nesting are one line naming the file (strict_json)
    try:
        data = strict_json.read(p, str(p))
    except strict_json.JSONInputError as e:
        raise LensError(e.place, file=str(p)) from None
    if not isinstance(data, dict):
        raise LensError("expected an object of lens entries keyed by id", file=str(p))
    return data


def _glass(name: str, nd: float | None, vd: float | None) -> tuple[dict[str, Any], str | None]:
    """Material keys for a named glass, and a note when the name was not used."""
    candidates = [name, "N-" + name]
    for cand in candidates:
        try:
            g = catalog_glass(cand)
        except UnknownGlassError:
            continue
        if nd is None or abs(g.nd - nd) <= GLASS_ND_MATCH:
            return {"material": g.name}, None
    if nd is None or vd is None:
        raise ValueError(f"glass {name!r} is not in the catalog and has no nd/vd")
    note = f"{name}: table nd {nd} vd {vd} kept (no catalog glass within {GLASS_ND_MATCH} in nd)"
    return {"nd": nd, "vd": vd, "glass_label": name}, note


def _number(value: Any, source: str, i: int | None, key: str, lens_id: str) -> float:
    """A finite number from an element field, or a LensError naming file, element and key."""
    if isinstance(value, bool) or not isinstance(value, int | float) or (
            isinstance(value, int) and value.bit_length() > 1023) or not math.isfinite(value):
        shown = (f"an integer of about {int(value.bit_length() * 0.30103) + 1} digits"
                 if isinstance(value, int) and value.bit_length() > 128 else f"{value!r:.60}")
        raise LensError(
            f"entry {lens_id}: expected a finite number, found {shown}",
            file=source,
            surface=i,
            key=key,
        )
    return float(value)


def convert_entry(
    lens_id: str, entry: dict[str, Any], *, source: str, scale: float = 1.0
) -> dict[str, Any]:
    """One lentil entry as plain data in the lensdb TOML layout."""
    # Types first: a JSON entry of the wrong shape is bad input, not a crash
    if not isinstance(entry, dict):
        raise LensError(f"entry {lens_id}: expected an object, found {type(entry).__name__}",
                        file=source, key=f"{lens_id}")
    elements = entry.get("optical-elements-patent") or entry.get("optical-elements-adjusted")
    if not elements:
        raise LensError("entry has no optical elements", file=source, key=f"{lens_id}")
    if not isinstance(elements, list) or not all(isinstance(e, dict) for e in elements):
        raise LensError(f"entry {lens_id}: expected a list of element objects, found "
                        f"{elements!r:.60}", file=source, key="optical-elements")
    notes: list[str] = []
    surfaces: list[dict[str, Any]] = []
    for i, e in enumerate(elements):
        s: dict[str, Any] = {}
        mat = str(e.get("material", "")).strip()
        radius = _number(e.get("radius") or 0.0, source, i, "radius", lens_id)
        geometry = e.get("lens-geometry", "spherical")
        flat = radius == 0.0 or abs(radius) >= FLAT_RADIUS or mat.lower() == "iris"
        if flat:
            s["shape"] = "plane"
        elif geometry == "aspherical":
            s["shape"] = "asphere"
        elif geometry in ("cyl-x", "cyl-y"):
            s["shape"] = "cylinder-" + geometry[-1]
        elif geometry == "spherical":
            s["shape"] = "sphere"
        else:
            raise LensError(
                f"unknown lens-geometry {geometry!r}", file=source, surface=i, key="lens-geometry"
            )
        if not flat:
            s["radius"] = radius
        thickness = e.get("thickness")
        if isinstance(thickness, list) and thickness:
            notes.append(f"surface {i}: zoom thicknesses {thickness}, first one used")
            thickness = thickness[0]
        s["thickness"] = _number(thickness, source, i, "thickness", lens_id)
        if mat.lower() in ("air", "iris"):
            s["material"] = "air"
        elif mat.lower() == "abbe":
            s["nd"] = _number(e.get("ior"), source, i, "ior", lens_id)
            s["vd"] = _number(e.get("abbe"), source, i, "abbe", lens_id)
        else:
            nd_vd = [None if e.get(k) is None else _number(e[k], source, i, k, lens_id)
                     for k in ("ior", "abbe")]
            try:
                keys, note = _glass(mat, *nd_vd)
            except ValueError as exc:
                raise LensError(
                    f"entry {lens_id}: {exc}", file=source, surface=i, key="material"
                ) from None
            s.update(keys)
            if note:
                notes.append(f"surface {i}: {note}")
        sd = _number(e.get("housing-radius"), source, i, "housing-radius", lens_id)
        if not flat and sd >= abs(radius):
            notes.append(f"surface {i}: housing radius {sd} reduced to 0.999*|radius|")
            sd = 0.999 * abs(radius)
        s["semi_diameter"] = sd
        if s["shape"] == "asphere":
            s["conic"] = 0.0
            coeffs = e.get("aspherical-equation") or []
            if not isinstance(coeffs, list):
                raise LensError(f"entry {lens_id}: expected a list of numbers, found {coeffs!r}",
                                file=source, surface=i, key="aspherical-equation")
            s["aspheric"] = [_number(a, source, i, "aspherical-equation", lens_id)
                             for a in coeffs]
        if mat.lower() == "iris":
            s["stop"] = True
        surfaces.append(s)

    import numpy as np

    # Sizes near the float limit (1e308) overflow in the sag checks; the overflow is an
    # inf there, which the loader refuses, not a warning
    with np.errstate(over="ignore", invalid="ignore"):
        if not any(s.get("stop") for s in surfaces):
            _add_front_stop(surfaces, notes, source)
        _separate_crossing(surfaces, notes, source)

    year = entry.get("year") or 0
    if isinstance(year, bool) or not isinstance(year, int) or not 0 <= year <= 9999:
        raise LensError(f"entry {lens_id}: expected a year, found {year!r}", file=source,
                        key="year")
    company = str(entry.get("company") or "unknown")
    product = str(entry.get("product-name") or "lens")
    info: dict[str, Any] = {
        "id": lens_id,
        "name": f"{company.title()} {product.replace('-', ' ')} ({year})",
        "maker": company,
        "year": year,
        "source": f"lentil lens database entry {lens_id} (zpelgrims/lentil, MIT)",
    }
    if entry.get("patent-number"):
        info["patent"] = str(entry["patent-number"])
    if entry.get("focal-length-mm-patent"):
        info["focal_length_mm"] = _number(entry["focal-length-mm-patent"], source, None,
                                          "focal-length-mm-patent", lens_id)
    if scale != 1.0:
        info["scale"] = scale
    text = " ".join(str(entry.get(k) or "") for k in ("notes",)).strip()
    info["notes"] = " ".join([text, *[n + "." for n in notes]]).strip()
    coated = year >= COATED_FROM_YEAR
    return {
        "schema_version": 1,
        "lens": info,
        "coating": {"default": "mgf2" if coated else "none", "design_wavelength_nm": 550.0},
        "surface": surfaces,
    }


def _add_front_stop(surfaces: list[dict[str, Any]], notes: list[str], source: str) -> None:
    """A table without an iris (an attachment) gets a stop plane just in front of its
    first surface, as wide as that surface, so that it can be traced on its own."""
    from lensfit.prescription.load import _surface

    first = _surface(surfaces[0], 0, source, 1.0)
    sd = first.semi_diameter_mm
    h = [sd * j / 64 for j in range(65)]
    lowest = min(min(float(first.sag(x, 0.0)), float(first.sag(0.0, x))) for x in h)
    gap = round(max(0.0, -lowest) + 0.001, 3)
    surfaces.insert(
        0,
        {"shape": "plane", "thickness": gap, "material": "air", "semi_diameter": sd, "stop": True},
    )
    notes.append(
        f"the table has no iris: a stop plane of radius {sd} was added {gap} mm in front of "
        "the first surface (later surface numbers in these notes count it)"
    )


def _separate_crossing(surfaces: list[dict[str, Any]], notes: list[str], source: str) -> None:
    """Housing radii in the source are estimates; where two neighbouring surfaces
    would cross inside them, shrink both to 98% of the height where they first meet."""
    from lensfit.prescription.load import CROSSING_TOLERANCE_MM, _surface, first_crossing

    for _ in range(4 * len(surfaces)):
        built = [_surface(s, i, source, 1.0) for i, s in enumerate(surfaces)]
        changed = False
        for i in range(len(built) - 1):
            gap, _h = first_crossing(built[i], built[i + 1])
            if gap >= -CROSSING_TOLERANCE_MM:
                continue
            # Find the height where the gap first closes, by bisection on [0, h_common]
            lo, hi = 0.0, min(built[i].semi_diameter_mm, built[i + 1].semi_diameter_mm)
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                trial = [dataclasses.replace(b, semi_diameter_mm=mid) for b in built[i : i + 2]]
                if first_crossing(*trial)[0] < -CROSSING_TOLERANCE_MM:
                    hi = mid
                else:
                    lo = mid
            new_sd = round(0.98 * lo, 3)
            for j in (i, i + 1):
                if surfaces[j]["semi_diameter"] > new_sd:
                    notes.append(
                        f"surface {j}: housing radius {surfaces[j]['semi_diameter']} reduced to "
                        f"{new_sd} so that surfaces {i} and {i + 1} do not cross"
                    )
                    surfaces[j]["semi_diameter"] = new_sd
            changed = True
            break
        if not changed:
            return


def slug(data: dict[str, Any]) -> str:
    info = data["lens"]
    words = f"{info['id']} {info['name'].split('(')[0]}"
    s = re.sub(r"[^a-z0-9]+", "-", words.lower()).strip("-")
    return re.sub(r"-+", "-", s)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"cannot write {v} to TOML")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def to_toml(data: dict[str, Any]) -> str:
    """Write lensdb data as TOML (deterministic: same data, same bytes)."""
    tables = ("lens", "fit", "coating")
    # Scalars go before the first table; a table or list must be one of those written
    unknown = [k for k, v in data.items() if isinstance(v, (dict, list))
               and k not in ("surface", *tables)]
    if unknown:
        raise ValueError(f"to_toml: cannot place the tables {sorted(unknown)}")
    lines = [
        "# Lens prescription for lensfit; format: lensdb/README.md.",
        "# Lengths in mm, wavelengths in nm; surfaces from the scene to the sensor.",
        f"schema_version = {data['schema_version']}",
    ]
    # Top-level keys (glass_extrapolation) before the first table
    lines += [f"{k} = {_toml_value(v)}" for k, v in data.items()
              if k != "schema_version" and not isinstance(v, (dict, list))]
    lines.append("")
    for table in tables:
        if table in data:
            lines.append(f"[{table}]")
            lines += [f"{k} = {_toml_value(v)}" for k, v in data[table].items()]
            lines.append("")
    for i, s in enumerate(data["surface"]):
        lines.append(f"[[surface]]  # {i}")
        lines += [f"{k} = {_toml_value(v)}" for k, v in s.items()]
        lines.append("")
    return "\n".join(lines)
