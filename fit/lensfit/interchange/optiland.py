"""Optiland's JSON save format (``optiland.fileio.save_optiland_file``, which writes
``Optic.to_dict()``): import to lensfit's TOML.

The file is one JSON object: ``surface_group.surfaces`` (an ``ObjectSurface``, the
surfaces, and the image: an ``ImageSurface`` in older files, a plain ``Surface`` as
Optiland 0.6.3 saves it), each with a ``geometry`` (``type``; ``cs``, the
surface's coordinate system with its absolute ``z`` and tilts/decenters; ``radius``,
``conic``; ``coefficients`` of an ``EvenAsphere``; ``radius_x``, ``radius_y``,
``conic_yz``, ``coeffs_poly_y`` of a ``ToroidalGeometry``), ``material_post`` (the
medium behind it: ``IdealMaterial`` with ``index`` and ``absorp``, ``AbbeMaterial`` with
``index``, ``abbe`` and ``model``, ``Material`` with ``name``, the maker as
``reference`` and, in newer files, ``catalog``), ``is_stop``,
``aperture`` (a physical aperture such as ``RadialAperture`` with ``r_min``, ``r_max``,
or null), ``thickness`` (newer files), ``interaction_model`` (newer: ``is_reflective``,
``coating``) or ``is_reflective``/``coating`` (older); and the system ``aperture``
(``type``: EPD, imageFNO, objectNA, float_by_stop_size; ``value``), ``fields``
(``fields`` of ``x``, ``y``; the type in ``field_type`` or
``field_definition.field_type``), ``wavelengths``, ``pickups``, ``solves``.

Mapped: StandardGeometry (conic 0 -> sphere, else asphere; radius inf -> plane),
Plane, EvenAsphere (``coefficients[i]`` on r^(2i+2): the r^2 term must be 0; the rest
become ``aspheric`` A4..), ToroidalGeometry where it is an exact cylinder
(radius_x inf -> cylinder-x of radius_y; radius_y inf -> cylinder-y of radius_x;
equal radii -> sphere; no conic or polynomial terms); thickness from ``thickness`` or
from the ``cs.z`` of the next surface; media: IdealMaterial of index 1 -> air, of
another index n -> the constant index ``material = { n = n }`` (a medium without
dispersion, a note); AbbeMaterial -> nd/vd (lensfit's Abbe model, a note saying by how
much Optiland's model differs: ``OPTILAND_ABBE_DIFFERENCE``); Material -> the catalog
glass, qualified by a maker in parentheses after the name ("SK16 (HIKARI)", a note), by
``catalog`` and by ``reference`` or, where the reference is missing (null in Optiland's
published samples), by the folder of its data file's ``filename`` when that names a
maker (``.../glass/hikari/SK16.yml``: refractiveindex.info keeps each maker's glasses in
a folder of its name; a note); an older HIKARI name is its current one ('SK16' of
'hikari' is HIKARI:J-SK16, a note; ``common.resolve_glass``); ``is_stop``; a
RadialAperture's ``r_max`` -> semi_diameter; aperture imageFNO -> ``f_number``; angle
fields -> ``field_of_view_deg``.

Semi-diameters: Optiland computes clear apertures by tracing and saves them only as a
physical ``aperture``. A surface without one gets the paraxial estimate |y_marginal| +
|y_chief| (d line, marginal ray from the system aperture, chief ray at the largest
field angle) and a note saying so; without a usable system aperture that is an error.
Such a surface's semi-diameter is automatic, not an aperture (the estimate may even be
smaller than the real beam): it is widened to pass, with a margin, every real ray of
the design beam and of the default fit domain, and kept as ``aperture = "automatic"``
(``lensfit.interchange.housings``);
a RadialAperture, and the stop's semi-diameter, are apertures and kept as written.

Errors (one line each naming the JSON path, exit 2, nothing written): other geometry,
material (``AbbeMaterialE``: ne and Ve), aperture or surface types, a tilted or
decentered coordinate system, a reflecting surface, an absorbing IdealMaterial, an index
outside 1-3 (above 3: an infrared medium such as germanium, opaque to the visible light
lensfit traces; the line says so) or an Abbe number outside 5-150, the stop on the image,
an unknown glass, a malformed value, a lens lensfit's loader refuses (on the JSON path of
the surface it names, and any other surface its message names by its JSON path).
Notes: wavelengths, coatings, comments, pickups, solves, apodization, the EPD and
other aperture types, non-angle fields; per surface, what each IdealMaterial (other
than air) and AbbeMaterial became, a maker read from the name or the filename, an older
HIKARI name.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from lensfit.common import strict_json
from lensfit.glass import MODEL_VD_RANGE, UnknownGlassError, catalog_glass
from lensfit.interchange.common import (
    MANUFACTURERS,
    ImportProblems,
    ImportResult,
    Notes,
    glass_message,
    index_range_problem,
    lens_table,
    paraxial_semi_diameters,
    resolve_glass,
    split_maker_suffix,
    validate,
)
from lensfit.interchange.housings import FileAperture, size_housings

IGNORED = frozenset({"version", "ray_tracer", "polarization"})
IMAGE_SURFACE_TYPES = ("ImageSurface", "Surface")
NOTED = {
    "wavelengths": "wavelengths not mapped (lensfit fits a wavelength range)",
    "pickups": "pickups not mapped (the values they resolved to are in the file)",
    "solves": "solves not mapped (the values they resolved to are in the file)",
    "apodization": "apodization not mapped",
}


def looks_like_optiland(data: Any) -> bool:
    return isinstance(data, dict) and isinstance(data.get("surface_group"), dict)


def read_optiland(path: str | Path, *, lens_id: str | None = None) -> ImportResult:
    p = Path(path)
    label = str(path)
    try:  # encodings, huge numbers and deep nesting: lensfit.common.strict_json
        data = strict_json.read(p, label)
    except strict_json.JSONInputError as e:
        raise ImportProblems([str(e)]) from None
    return convert_optiland(data, label=label, lens_id=lens_id or p.stem)


def _show(v: Any) -> str:
    """A value as JSON, cut to 40 characters; an integer too long to print (Python stops
    at 4,300 digits) or nesting too deep to print is described instead."""
    if isinstance(v, int) and not isinstance(v, bool) and v.bit_length() > 128:
        return f"an integer of about {int(v.bit_length() * 0.30103) + 1} digits"
    try:
        return json.dumps(v)[:40]
    except (ValueError, TypeError, RecursionError):
        return f"a {type(v).__name__}"


def _finite_number(v: Any) -> bool:
    """A number (not a bool) that a float holds, finite."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        return False
    if isinstance(v, int):
        return v.bit_length() <= 1023
    return math.isfinite(v)


class _Ctx:
    def __init__(self, label: str) -> None:
        self.label = label
        self.problems: list[str] = []
        self.notes = Notes(label, sep=": ")

    def bad(self, path: str, msg: str) -> None:
        self.problems.append(f"{self.label}: {path}: {msg}")

    def get(self, obj: Any, key: str, path: str, kinds: tuple[type, ...], *,
            required: bool = True, default: Any = None) -> Any:
        """obj[key] of one of ``kinds`` (a float: finite; inf allowed where asked by
        ``math.inf`` in kinds is not possible, see ``number``)."""
        if not isinstance(obj, dict) or key not in obj:
            if required:
                self.bad(f"{path}.{key}", "missing")
            return default
        v = obj[key]
        if not isinstance(v, kinds) or isinstance(v, bool) and bool not in kinds:
            names = " or ".join(k.__name__ for k in kinds)
            self.bad(f"{path}.{key}", f"expected {names}, found {_show(v)[:40]}")
            return default
        return v

    def number(self, obj: Any, key: str, path: str, *, required: bool = True,
               default: float | None = None, allow_inf: bool = False) -> float | None:
        v = self.get(obj, key, path, (int, float), required=required, default=None)
        if v is None:
            return default
        if isinstance(v, int) and v.bit_length() > 1023:  # float() would overflow
            self.bad(f"{path}.{key}", f"expected a number within a float's range, found "
                     f"{_show(v)}")
            return default
        v = float(v)
        if math.isnan(v) or (math.isinf(v) and not allow_inf) or abs(v) > 1e300 and \
                math.isfinite(v):
            self.bad(f"{path}.{key}", f"expected a finite number, found {v}")
            return default
        return v


def convert_optiland(data: Any, *, label: str = "<optiland>", lens_id: str = "import"
                     ) -> ImportResult:
    """Convert parsed Optiland JSON to lensfit's TOML layout (validated by the loader)."""
    ctx = _Ctx(label)
    if not looks_like_optiland(data):
        found = (f"found {type(data.get('surface_group')).__name__}"
                 if isinstance(data, dict) and "surface_group" in data else "found none")
        raise ImportProblems([f"{label}: surface_group: expected an object (Optiland's "
                              f"surface group), {found}"])
    for key in data:
        if key in IGNORED or key in ("surface_group", "aperture", "fields", "name"):
            continue
        if key in NOTED:
            if data[key] not in (None, [], {}, {"solves": []}):
                ctx.notes.add(key, key, NOTED[key])
            continue
        ctx.notes.add(key, key, "unknown key not mapped")
    surfaces_raw = ctx.get(data["surface_group"], "surfaces", "surface_group", (list,))
    if surfaces_raw is None:
        raise ImportProblems(ctx.problems)
    if len(surfaces_raw) < 3:
        ctx.bad("surface_group.surfaces", f"{len(surfaces_raw)} surfaces: a lens needs an "
                "object surface, at least one surface and an image surface")
        raise ImportProblems(ctx.problems)

    zs: list[float | None] = []
    for i, s in enumerate(surfaces_raw):
        path = f"surface_group.surfaces[{i}]"
        geom = ctx.get(s, "geometry", path, (dict,))
        cs = ctx.get(geom, "cs", path + ".geometry", (dict,)) if geom is not None else None
        z = None
        if cs is not None:
            z = ctx.number(cs, "z", f"{path}.geometry.cs", allow_inf=(i == 0))
            for k in ("x", "y", "rx", "ry", "rz"):
                v = ctx.number(cs, k, f"{path}.geometry.cs", required=False, default=0.0)
                if v:
                    how = "tilted" if k[0] == "r" else "decentered"
                    ctx.bad(f"{path}.geometry.cs.{k}", f"a {how} surface: unsupported "
                            "(lensfit's surfaces are centred)")
            if cs.get("reference_cs") is not None:
                ctx.bad(f"{path}.geometry.cs.reference_cs", "a relative coordinate system: "
                        "unsupported")
        zs.append(z)

    first = surfaces_raw[0]
    if isinstance(first, dict):
        if first.get("type") != "ObjectSurface":
            ctx.bad("surface_group.surfaces[0].type", f"expected ObjectSurface, found "
                    f"{_show(first.get('type'))[:40]}")
        mat = first.get("material_post")
        if isinstance(mat, dict) and not _is_air(mat):
            ctx.bad("surface_group.surfaces[0].material_post", "object space in glass: "
                    "unsupported (lensfit's object space is air)")
        if zs[0] is not None and math.isfinite(zs[0]):
            ctx.notes.add("surface_group.surfaces[0].geometry.cs.z", "object distance",
                          "not mapped (lensfit's scene and focus are set at fit time)")
    last = surfaces_raw[-1]
    n_last = len(surfaces_raw) - 1
    if isinstance(last, dict):
        # Optiland 0.6.3 saves its image surface as a plain "Surface" (older versions as an
        # "ImageSurface"): the last surface of a surface group is the image either way
        if last.get("type") not in IMAGE_SURFACE_TYPES:
            ctx.bad(f"surface_group.surfaces[{n_last}].type", "expected ImageSurface or "
                    f"Surface (the image), found {_show(last.get('type'))[:40]}")
        if last.get("is_stop") is True:
            ctx.bad(f"surface_group.surfaces[{n_last}].is_stop", "the stop on the image "
                    "surface: unsupported")
        g = last.get("geometry")
        if isinstance(g, dict) and g.get("type") not in ("Plane", None):
            r = g.get("radius")
            if not (isinstance(r, float) and math.isinf(r)):
                ctx.bad(f"surface_group.surfaces[{n_last}].geometry", "a curved image "
                        "surface: unsupported (lensfit's sensor is a plane)")

    out: list[dict[str, Any]] = []
    where: list[str] = []
    missing_sd: list[int] = []
    for i in range(1, n_last):
        s = surfaces_raw[i]
        path = f"surface_group.surfaces[{i}]"
        d = _surface(ctx, s, path, zs, i)
        if d is None:
            continue
        if "semi_diameter" not in d:
            missing_sd.append(len(out))
        out.append(d)
        where.append(path)
    if ctx.problems:
        raise ImportProblems(ctx.problems)
    if not any(d.get("stop") for d in out):
        ctx.bad("surface_group.surfaces", "no surface has is_stop = true")
        raise ImportProblems(ctx.problems)

    info_extra: dict[str, Any] = {}
    ap = data.get("aperture")
    ap_type, ap_value = None, None
    if ap is not None:
        ap_type = ctx.get(ap, "type", "aperture", (str,))
        ap_value = ctx.number(ap, "value", "aperture")
        if ap_type == "imageFNO" and ap_value and ap_value > 0:
            info_extra["f_number"] = ap_value
    half_field, field_kind = _fields(ctx, data.get("fields"))
    if field_kind == "angle" and half_field:
        info_extra["field_of_view_deg"] = 2.0 * half_field
    if ctx.problems:
        raise ImportProblems(ctx.problems)
    if ap_type is not None and ap_type not in ("imageFNO",):
        ctx.notes.add("aperture", f"aperture {ap_type} {ap_value:g}" if ap_value is not None
                      else "aperture", "not mapped (lensfit's aperture is the stop "
                      "surface's semi-diameter)")
    if missing_sd:
        paraxial_semi_diameters(
            out, missing_sd, where, ap_type, ap_value,
            object_distance=math.inf if zs[0] is None else -float(zs[0]),
            half_field_deg=half_field if field_kind == "angle" else 0.0,
            bad=lambda w, m: ctx.bad(w or "aperture", m),
            note=lambda w, sd: ctx.notes.add(f"{w}.aperture", "no aperture",
                                             f"semi-diameter {sd:g} from the paraxial "
                                             "marginal and chief rays"))
    if ctx.problems:
        raise ImportProblems(ctx.problems)

    name = data.get("name") if isinstance(data.get("name"), str) else ""
    info = lens_table(lens_id=lens_id, name=name or "", source=f"Optiland file "
                      f"{Path(label).name}", notes=[f"Imported by lensfit import from "
                                                     f"{Path(label).name}"])
    info.update(info_extra)
    table = {"schema_version": 1, "lens": info,
             "coating": {"default": "none", "design_wavelength_nm": 550.0}, "surface": out}
    # A RadialAperture is an aperture; a surface without one had its clear aperture
    # computed by Optiland from the beam: automatic (lensfit.interchange.housings)
    apertures = [FileAperture("stop", "no aperture: paraxial estimate" if k in missing_sd
                              else "RadialAperture") if d.get("stop") else
                 FileAperture("estimated", "no aperture") if k in missing_sd else
                 FileAperture("fixed", "RadialAperture") for k, d in enumerate(out)]
    lens = validate(table, label, where, sep=": ")
    _, sd_lines = size_housings(table, apertures, where, [f"{label}: {w}" for w in where],
                                label=label, unit="mm", lens=lens,
                                half_field_deg=half_field if field_kind == "angle" else 0.0)
    return ImportResult(table, ctx.notes.lines(), sd_lines)


def _is_air(mat: dict[str, Any]) -> bool:
    return mat.get("type") == "IdealMaterial" and mat.get("index") == 1.0 and \
        not mat.get("absorp")


def _surface(ctx: _Ctx, s: Any, path: str, zs: list[float | None], i: int
             ) -> dict[str, Any] | None:
    before = len(ctx.problems)
    if not isinstance(s, dict):
        ctx.bad(path, "expected an object")
        return None
    typ = s.get("type")
    if typ != "Surface":
        ctx.bad(f"{path}.type", f"surface type {_show(typ)[:40]}: unsupported "
                "(not imported)")
        return None
    d: dict[str, Any] = {}
    geom = s.get("geometry")
    if isinstance(geom, dict):
        shape = _geometry(ctx, geom, f"{path}.geometry")
        if shape:
            d.update(shape)
    # Thickness: the saved one (newer files) or the next vertex's z
    t = ctx.number(s, "thickness", path, required=False)
    if t is None and zs[i] is not None and zs[i + 1] is not None:
        # The saved z are running sums of the thicknesses: their difference carries the
        # sums' rounding, up to an ulp of each z (0.99997 comes back as
        # 0.9999699999999994). Rounded to the decimal place 8 ulp above that, a typed
        # thickness comes back; the change is below 1e-13 mm for z below 100 mm.
        a, b = float(zs[i]), float(zs[i + 1])  # type: ignore[arg-type]
        err = 8.0 * math.ulp(max(abs(a), abs(b), 1e-300))
        t = round(b - a, max(0, math.floor(-math.log10(err))))
    if t is None:
        ctx.bad(f"{path}.thickness", "missing (neither a thickness nor the next surface's z)")
    else:
        d["thickness"] = t
    mat = s.get("material_post")
    if isinstance(mat, dict):
        d.update(_material(ctx, mat, f"{path}.material_post"))
    else:
        ctx.bad(f"{path}.material_post", "missing")
    # Reflection and coatings: newer files in interaction_model, older on the surface
    im = s.get("interaction_model")
    holder, hpath = (im, f"{path}.interaction_model") if isinstance(im, dict) else (s, path)
    if holder.get("is_reflective"):
        ctx.bad(f"{hpath}.is_reflective", "a mirror: unsupported (lensfit traces refracting "
                "lenses)")
    if isinstance(im, dict) and im.get("type") not in (None, "RefractiveReflectiveModel"):
        ctx.bad(f"{hpath}.type", f"interaction {_show(im.get('type'))[:40]}: "
                "unsupported")
    if holder.get("coating") is not None:
        ctx.notes.add(f"{hpath}.coating", "coating", "not mapped (the lens is written "
                      "uncoated)")
    if holder.get("bsdf") is not None:
        ctx.notes.add(f"{hpath}.bsdf", "scattering (bsdf)", "not mapped")
    if isinstance(s.get("comment"), str) and s["comment"]:
        ctx.notes.add(f"{path}.comment", "comment", "not mapped")
    ap = s.get("aperture")
    if ap is not None:
        if not isinstance(ap, dict) or ap.get("type") != "RadialAperture":
            kind = ap.get("type") if isinstance(ap, dict) else ap
            ctx.bad(f"{path}.aperture", f"aperture {_show(kind)[:40]}: unsupported "
                    "(lensfit's apertures are centred circles)")
        else:
            rmin = ctx.number(ap, "r_min", f"{path}.aperture", required=False, default=0.0)
            rmax = ctx.number(ap, "r_max", f"{path}.aperture")
            if rmin:
                ctx.bad(f"{path}.aperture.r_min", f"an annular aperture (inner radius "
                        f"{rmin:g}): unsupported")
            elif rmax is not None:
                d["semi_diameter"] = rmax
    stop = s.get("is_stop", False)
    if not isinstance(stop, bool):
        ctx.bad(f"{path}.is_stop", f"expected true or false, found {_show(stop)[:40]}")
    elif stop:
        d["stop"] = True
    if len(ctx.problems) > before:
        return None
    order = ["shape", "radius", "thickness", "material", "nd", "vd", "semi_diameter", "conic",
             "aspheric", "stop"]
    return {k: d[k] for k in order if k in d}


def _geometry(ctx: _Ctx, g: dict[str, Any], path: str) -> dict[str, Any] | None:
    typ = g.get("type")
    if typ == "Plane":
        return {"shape": "plane"}
    if typ in ("StandardGeometry", "EvenAsphere"):
        r = ctx.number(g, "radius", path, allow_inf=True)
        k = ctx.number(g, "conic", path, required=False, default=0.0)
        coeffs: list[float] = []
        if typ == "EvenAsphere":
            raw = ctx.get(g, "coefficients", path, (list,), required=False, default=[])
            for j, c in enumerate(raw or []):
                if not _finite_number(c):
                    ctx.bad(f"{path}.coefficients[{j}]", f"expected a finite number, found "
                            f"{_show(c)[:40]}")
                    return None
                coeffs.append(float(c))
            if coeffs and coeffs[0]:
                ctx.bad(f"{path}.coefficients[0]", f"an r^2 coefficient {coeffs[0]:g}: "
                        "lensfit's asphere has none (its terms start at r^4); not "
                        "representable")
                return None
            coeffs = coeffs[1:]
            while coeffs and coeffs[-1] == 0.0:
                coeffs.pop()
        if r is None or k is None:
            return None
        if math.isinf(r) or r == 0.0:
            if coeffs:
                ctx.bad(path, "a flat asphere: lensfit's asphere needs a radius; not "
                        "representable")
                return None
            return {"shape": "plane"}
        if typ == "EvenAsphere" or k:
            return {"shape": "asphere", "radius": r, "conic": k, "aspheric": coeffs}
        return {"shape": "sphere", "radius": r}
    if typ == "ToroidalGeometry":
        rx = ctx.number(g, "radius_x", path, allow_inf=True)
        ry = ctx.number(g, "radius_y", path, allow_inf=True)
        k = ctx.number(g, "conic_yz", path, required=False, default=0.0)
        poly = ctx.get(g, "coeffs_poly_y", path, (list,), required=False, default=[])
        if rx is None or ry is None or k is None:
            return None
        if any(c for c in poly or []):
            ctx.bad(f"{path}.coeffs_poly_y", "polynomial terms on the y curve: not "
                    "representable (lensfit's cylinders are circular)")
            return None
        flat_x = math.isinf(rx) or rx == 0.0
        flat_y = math.isinf(ry) or ry == 0.0
        if k and not flat_y:
            ctx.bad(f"{path}.conic_yz", "a conic y curve: not representable")
            return None
        if flat_x and flat_y:
            return {"shape": "plane"}
        if flat_x:
            return {"shape": "cylinder-x", "radius": ry}
        if flat_y:
            return {"shape": "cylinder-y", "radius": rx}
        if rx == ry:
            return {"shape": "sphere", "radius": ry}
        ctx.bad(path, f"a toroid with radius {ry:g} in y and {rx:g} in x: not representable "
                "(lensfit has spheres and cylinders)")
        return None
    ctx.bad(f"{path}.type", f"geometry {_show(typ)[:40]}: unsupported surface type "
            "(not imported)")
    return None


# How far Optiland's AbbeMaterial models are from lensfit's Abbe model (the same nd and
# vd), the largest |n_Optiland - n_lensfit| over 400-700 nm, measured with Optiland 0.6.3
# (tests/fit/interchange/test_optiland_cross.py): for a crown (N-BK7's 1.5168/64.17) and
# a dense flint (SF6's 1.80518/25.43). The polynomial model (Optiland 0.6's default) also
# misses nd itself (by 7e-5 for the crown, 4.8e-4 for the flint); lensfit's model passes
# through nd and vd exactly and is 1.1e-4 (crown) and 1.2e-3 (flint) from the catalog
# glasses (lensdb/glass/README.md).
OPTILAND_ABBE_DIFFERENCE = {"polynomial": (4.9e-4, 1.5e-3), "buchdahl": (2.4e-4, 2.1e-3)}


def _model_glass(ctx: _Ctx, m: dict[str, Any], path: str) -> dict[str, Any]:
    """An AbbeMaterial: nd (``index``) and vd (``abbe``) with lensfit's Abbe model."""
    nd = ctx.number(m, "index", path)
    vd = ctx.number(m, "abbe", path)
    if nd is None or vd is None:
        return {}
    vd_lo, vd_hi = MODEL_VD_RANGE
    nd_problem = index_range_problem(nd)
    if nd_problem:
        ctx.bad(f"{path}.index", f"nd {nd:g}: {nd_problem}")
        return {}
    if not vd_lo <= vd <= vd_hi:
        ctx.bad(f"{path}.abbe", f"vd {vd:g}: expected {vd_lo:g} <= vd <= {vd_hi:g} (a medium "
                "without dispersion is an IdealMaterial)")
        return {}
    model = m.get("model")
    model = model if isinstance(model, str) else "polynomial"  # 0.6's default
    if model in OPTILAND_ABBE_DIFFERENCE:
        crown, flint = OPTILAND_ABBE_DIFFERENCE[model]
        differs = (f"Optiland's {model} model differs from it by about {crown:g} in n over "
                   f"400-700 nm for a crown, {flint:g} for a dense flint")
    else:
        differs = f"Optiland's {model!r} model is not lensfit's"
    ctx.notes.add(path, path, f"AbbeMaterial nd {nd:g} vd {vd:g}: kept, with lensfit's "
                  f"Abbe model (lensdb/glass/README.md); {differs}")
    return {"nd": nd, "vd": vd}


def _constant_index(ctx: _Ctx, m: dict[str, Any], path: str) -> dict[str, Any]:
    """An IdealMaterial: air for n = 1, else a medium without dispersion."""
    n = ctx.number(m, "index", path)
    k = ctx.number(m, "absorp", path, required=False, default=0.0)
    if n is None or k is None:
        return {}
    if k:
        ctx.bad(f"{path}.absorp", f"an absorbing medium (k = {k:g}): not representable "
                "(lensfit's media do not absorb)")
        return {}
    if n == 1.0:
        return {"material": "air"}
    n_problem = index_range_problem(n, "n")
    if n_problem:
        ctx.bad(f"{path}.index", f"a constant index {n:g}: {n_problem}")
        return {}
    ctx.notes.add(path, path, f"IdealMaterial of index {n:g}: a medium without dispersion, "
                  f"n = {n:g} at every wavelength (material = {{ n = {n:g} }})")
    return {"material": {"n": n}}


def _is_maker(ref: str, bare: str) -> bool:
    """``ref`` names a glass maker lensfit has a catalog of, or the maker of the project
    catalog's glass ``bare`` (Schott, ...)."""
    if ref.upper() in MANUFACTURERS:
        return True
    try:
        return str(catalog_glass(bare).maker).upper() == ref.upper()
    except UnknownGlassError:
        return False


def filename_maker(filename: Any) -> str | None:
    """The folder above the data file of an Optiland ``Material`` (``.../glass/hikari/
    SK16.yml`` -> "hikari": refractiveindex.info's database, which Optiland reads, keeps
    each maker's glasses in a folder of the maker's name), with either path separator (the
    published files carry their authors' Windows paths); None when there is none."""
    if not isinstance(filename, str) or not filename:
        return None
    parts = [p for p in filename.replace("\\", "/").split("/") if p]
    return parts[-2] if len(parts) >= 2 else None


def _makers(ctx: _Ctx, m: dict[str, Any], name: str, path: str) -> tuple[str, list[str]]:
    """The glass name and the makers that qualify it, in order: one in parentheses after
    the name ("SK16 (HIKARI)", with a note), Optiland's ``catalog`` (newer files) and its
    ``reference`` (the maker, or an author for data that is no catalog glass's); without a
    ``reference``, the maker folder of its data file's ``filename`` (``.../glass/hikari/
    SK16.yml``: Optiland found the glass there), with a note."""
    bare, in_name = split_maker_suffix(name)
    makers = [in_name] if in_name else []
    if in_name:
        ctx.notes.add(f"{path}.name", f"{path}.name", f"glass {name!r}: {bare!r} of "
                      f"{in_name}'s catalog")
    for key in ("catalog", "reference"):
        ref = m.get(key)
        if not isinstance(ref, str) or not ref or ref.upper() in (x.upper() for x in makers):
            continue
        if _is_maker(ref, bare):
            makers.append(ref)
    ref = m.get("reference")
    folder = filename_maker(m.get("filename"))
    if (not isinstance(ref, str) or not ref) and folder and \
            folder.upper() not in (x.upper() for x in makers) and _is_maker(folder, bare):
        makers.append(folder)
        leaf = m["filename"].replace("\\", "/").rsplit("/", 1)[-1]
        ctx.notes.add(f"{path}.filename", f"{path}.filename", f"glass {name!r} has no "
                      f"reference: the maker {folder!r} is taken from the folder of its "
                      f"data file (.../{folder}/{leaf[:40]})")
    return bare, makers


def _material(ctx: _Ctx, m: dict[str, Any], path: str) -> dict[str, Any]:
    typ = m.get("type")
    if typ == "IdealMaterial":
        return _constant_index(ctx, m, path)
    if typ == "AbbeMaterial":
        return _model_glass(ctx, m, path)
    if typ == "AbbeMaterialE":
        ctx.bad(f"{path}.type", "an e-line Abbe material (ne, Ve): not representable "
                "(lensfit's model glass is given by nd and vd)")
        return {}
    if typ == "Material":
        name = ctx.get(m, "name", path, (str,))
        ref = m.get("reference")
        if name is None:
            return {}
        bare, makers = _makers(ctx, m, name, path)
        try:
            spec, outside = resolve_glass(bare, makers)
        except UnknownGlassError as e:
            if isinstance(ref, str) and ref:
                maker = f" ({ref})"
            elif makers:  # from the name's parentheses, the catalog or the filename
                maker = f" ({', '.join(makers)})"
            else:
                maker = ""
            ctx.bad(f"{path}.name", f"glass {name!r}{maker}: {glass_message(e)} (not "
                    "imported)")
            return {}
        if outside:
            ctx.notes.add(f"{path}.name", f"{path}.name", outside)
        return spec
    ctx.bad(f"{path}.type", f"material {_show(typ)[:40]}: unsupported (not imported)")
    return {}


def _fields(ctx: _Ctx, f: Any) -> tuple[float, str]:
    """(largest radial field in the file's unit, field kind)."""
    if not isinstance(f, dict):
        return 0.0, ""
    kind = f.get("field_type")
    fd = f.get("field_definition")
    if isinstance(fd, dict) and isinstance(fd.get("field_type"), str):
        kind = {"AngleField": "angle", "ObjectHeightField": "object_height",
                "ParaxialImageHeightField": "paraxial_image_height",
                "RealImageHeightField": "real_image_height"}.get(fd["field_type"],
                                                                  fd["field_type"])
    fields = f.get("fields") or []
    if not isinstance(fields, list):
        ctx.bad("fields.fields", "expected a list")
        return 0.0, ""
    worst = 0.0
    for j, fl in enumerate(fields):
        x = ctx.number(fl, "x", f"fields.fields[{j}]", required=False, default=0.0)
        y = ctx.number(fl, "y", f"fields.fields[{j}]", required=False, default=0.0)
        if x is None or y is None:
            continue
        if kind == "angle":
            if abs(x) >= 90 or abs(y) >= 90:
                ctx.bad(f"fields.fields[{j}]", "an angle of 90 degrees or more")
                continue
            r = math.degrees(math.atan(math.hypot(math.tan(math.radians(x)),
                                                  math.tan(math.radians(y)))))
        else:
            r = math.hypot(x, y)
        worst = max(worst, r)
    if kind != "angle" and fields:
        ctx.notes.add("fields", f"fields ({kind})", "not mapped (lensfit's [lens] holds a "
                      "field of view in degrees)")
    return worst, str(kind)
