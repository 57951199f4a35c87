"""Load and validate lens prescriptions (TOML, see lensdb/README.md).

Validation runs in three steps, each error naming file, surface index and key:

1. TOML syntax (line and column from the parser);
2. structure against ``lensdb/schema.json`` (types, required and unknown keys);
3. meaning: finite numbers, positive sizes, one stop, known glasses, surfaces that
   do not cross, a sensor behind the last surface.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import math
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np

from lensfit import data_folder, missing_data_folder
from lensfit.common.errors import (
    InputError,
    LensError,
    int_digits,
    parse_problem,
    regular_file_problem,
    toml_overflow,
)
from lensfit.glass import (
    AIR,
    MODEL_DPGF_MAX,
    MODEL_ND_RANGE,
    MODEL_VD_RANGE,
    InlineGlassError,
    Medium,
    UnknownGlassError,
    abbe_glass,
    inline_glass,
    resolve_glass,
)
from lensfit.prescription.model import BARE, Coating, Layer, Lens, Surface

# Surfaces may touch (cemented doublets) but not overlap: 1 nm of slack for rounding.
CROSSING_TOLERANCE_MM = 1e-6
# lens.id names files (lens<id>.table) and C symbols (lens<id>_P_o_d): short enough for both
MAX_ID_LENGTH = 64


def repo_root() -> Path:
    return Path(__file__).resolve().parents[3]


def lensdb_dir() -> Path:
    """The lens database folder: $LENSFIT_LENSDB, else the checkout's lensdb/, else the
    current directory's (lensfit.data_folder); LensError naming it when it is missing."""
    db = data_folder("lensdb")
    if not db.is_dir():
        raise LensError(missing_data_folder("lensdb"))
    return db


@functools.cache
def _schema() -> dict[str, Any]:
    with open(lensdb_dir() / "schema.json", encoding="utf-8") as f:
        return json.load(f)


def find_lens_file(name: str) -> Path:
    """Resolve a lens name: a path to a TOML file, an id ('0001') or a file stem."""
    p = Path(name)
    if p.suffix == ".toml" and p.exists():
        return p
    db = lensdb_dir()
    candidates = sorted(db.glob("*.toml"))
    for c in candidates:
        if c.stem == name or c.stem.split("-", 1)[0] == name:
            return c
    if p.suffix == ".toml":
        raise LensError("cannot read: no such file", file=name)
    known = ", ".join(c.stem for c in candidates)
    raise LensError(f"unknown lens '{name}' (not a .toml file and not in {db}; known: {known})")


def list_lenses() -> list[Path]:
    return sorted(lensdb_dir().glob("*.toml"))


def load_lens(name: str | os.PathLike[str]) -> Lens:
    """Load, validate and resolve a prescription from a file path or a lensdb name."""
    path = find_lens_file(os.fspath(name))
    label = os.path.relpath(path) if not os.path.isabs(os.fspath(name)) else os.fspath(path)
    # A regular file only: a FIFO would block the read, a folder is no prescription
    problem = regular_file_problem(path)
    if problem:
        raise LensError(f"cannot read: {problem}", file=label)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise LensError(f"cannot read: {e}", file=label) from None
    try:
        data = tomllib.loads(text)
    except ValueError as e:  # TOMLDecodeError, or an integer of over 4300 digits
        raise LensError(f"malformed TOML: {parse_problem(e)}", file=label) from None
    except RecursionError:
        raise LensError("malformed TOML: nested too deeply", file=label) from None
    return lens_from_dict(data, file=label)


def _toml_text(value: Any) -> str:
    """A value as the person wrote it in TOML (true, not Python's True)."""
    return str(value).lower() if isinstance(value, bool) else repr(value)


def _schema_error(err: jsonschema.ValidationError, file: str) -> LensError:
    """Turn a JSON-schema error into a message with surface index and key."""
    path = list(err.absolute_path)
    surface = None
    key = None
    if len(path) >= 2 and path[0] == "surface" and isinstance(path[1], int):
        surface = path[1]
        rest = path[2:]
    else:
        rest = path
    if rest:
        key = ".".join(str(p) for p in rest)
    where = key + "." if key else ""
    if err.validator == "required":
        missing = [r for r in err.validator_value if r not in err.instance]
        return LensError("missing required key", file=file, surface=surface, key=where + missing[0])
    if err.validator == "additionalProperties":
        allowed = set(err.schema.get("properties", {}))
        extra = sorted(k for k in err.instance if k not in allowed)
        return LensError(
            f"unknown key (allowed: {', '.join(sorted(allowed))})",
            file=file,
            surface=surface,
            key=where + extra[0],
        )
    if err.validator in ("oneOf", "anyOf") and err.context:
        # A value that fits none of the alternatives: report the error inside the
        # alternative it got furthest into, or else list what the alternatives accept.
        depth = len(err.absolute_path)
        deeper = [e for e in err.context if len(e.absolute_path) > depth]
        if deeper:
            return _schema_error(max(deeper, key=lambda e: len(e.absolute_path)), file)
        inner = [e for e in err.context if e.validator not in ("enum", "type")]
        if inner:
            return _schema_error(inner[0], file)
        values: list[str] = []
        kinds: list[str] = []
        for e in err.context:
            if e.validator == "enum":
                values += [repr(v) for v in e.validator_value]
            elif e.validator == "type":
                kinds.append("a table" if e.validator_value == "object" else str(e.validator_value))
        accepted = " or ".join([", ".join(values), *kinds] if values else kinds)
        return LensError(
            f"expected {accepted}; found {_toml_text(err.instance)}",
            file=file,
            surface=surface,
            key=key,
        )
    if err.validator == "type":
        return LensError(
            f"expected {err.validator_value}, found {_toml_text(err.instance)}",
            file=file,
            surface=surface,
            key=key,
        )
    if err.validator in ("enum", "const"):
        allowed = err.validator_value
        return LensError(
            f"expected one of {allowed!r}, found {_toml_text(err.instance)}",
            file=file,
            surface=surface,
            key=key,
        )
    return LensError(err.message, file=file, surface=surface, key=key)


def _walk_numbers(obj: Any, path: list[Any]):
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _walk_numbers(v, [*path, k])
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _walk_numbers(v, [*path, i])
    elif isinstance(obj, float):
        yield path, obj


def lens_from_dict(data: dict[str, Any], *, file: str = "<memory>") -> Lens:
    """Validate plain data in the TOML layout and build a ``Lens`` (the inverse of
    ``Lens.to_dict``)."""
    # Step 1: every number finite (TOML allows nan and inf)
    for path, value in _walk_numbers(data, []):
        if not math.isfinite(value):
            surface = path[1] if len(path) > 1 and path[0] == "surface" else None
            rest = path[2:] if surface is not None else path
            raise LensError(
                f"expected a finite number, found {value}",
                file=file,
                surface=surface,
                key=".".join(str(p) for p in rest),
            )

    # Step 1b: every integer within a float's range (a 400-digit thickness)
    big = toml_overflow(data)
    if big:
        path, _ = big
        surface = path[1] if len(path) > 1 and path[0] == "surface" else None
        rest = path[2:] if surface is not None else path
        raise LensError("expected a number within a float's range, found an integer of "
                        f"{int_digits(big[1])} digits", file=file, surface=surface,
                        key=".".join(str(p) for p in rest))

    # Step 2: structure against the schema; report the error deepest in the tree first
    validator = jsonschema.Draft202012Validator(_schema())
    errors = sorted(validator.iter_errors(data), key=lambda e: (-len(e.absolute_path), str(e.path)))
    if errors:
        raise _schema_error(errors[0], file)

    info = data["lens"]
    if len(info["id"]) > MAX_ID_LENGTH:  # the schema's pattern holds the characters
        raise LensError(f"expected 1 to {MAX_ID_LENGTH} ASCII letters, digits or '_' (the id "
                        f"names generated files and C symbols), found {len(info['id'])} "
                        "characters", file=file, key="lens.id")
    scale = float(info.get("scale", 1.0))
    if scale <= 0:
        raise LensError(f"expected a positive number, found {scale}", file=file, key="lens.scale")
    coat = data.get("coating", {})
    design_nm = float(coat.get("design_wavelength_nm", 550.0))
    if not 200.0 <= design_nm <= 2000.0:
        raise LensError(
            f"expected a wavelength in nm between 200 and 2000, found {design_nm}",
            file=file,
            key="coating.design_wavelength_nm",
        )
    default_coating = coat.get("default", "mgf2")

    # Step 3: each surface, in order
    raw_surfaces = data["surface"]
    surfaces: list[Surface] = []
    for i, s in enumerate(raw_surfaces):
        surfaces.append(_surface(s, i, file, scale))

    # The medium in front of each surface is what decides which get the default coating
    coated: list[Surface] = []
    for i, s in enumerate(surfaces):
        before = AIR if i == 0 else surfaces[i - 1].medium
        spec = raw_surfaces[i].get("coating", "default")
        coating = _coating(spec, before, s.medium, default_coating, design_nm, file, i)
        coated.append(dataclasses.replace(s, coating=coating))
    surfaces = coated

    stops = [i for i, s in enumerate(surfaces) if s.stop]
    if not stops:
        raise LensError(
            "no aperture stop: mark exactly one surface with 'stop = true'", file=file, key="stop"
        )
    if len(stops) > 1:
        raise LensError(
            f"more than one aperture stop (surfaces {stops}); mark exactly one",
            file=file,
            surface=stops[1],
            key="stop",
        )
    s_i = stops[0]
    if surfaces[-1].medium is not AIR and surfaces[-1].medium.name != "air":
        raise LensError(
            "the last surface must be followed by air (the sensor is in air)",
            file=file,
            surface=len(surfaces) - 1,
            key="material",
        )
    if surfaces[-1].thickness_mm <= 0:
        raise LensError(
            f"expected a positive distance to the sensor, found {surfaces[-1].thickness_mm}",
            file=file,
            surface=len(surfaces) - 1,
            key="thickness",
        )
    _check_crossing(surfaces, file)
    # The inserted stop surface coincides with the file's surface: the crossing check
    # above covers it
    surfaces = _stop_plane(surfaces, s_i)

    name = info["name"]
    provenance = dict(info)
    return Lens(
        name=name,
        surfaces=tuple(surfaces),
        provenance=provenance,
        design_wavelength_nm=design_nm,
        source_file=file,
        raw=copy.deepcopy(data),
    )


COATING_CHOICES = ("file", "none")


def with_coating(lens: Lens, coating: str) -> Lens:
    """The lens with its coatings as the file gives them (``"file"``) or with every
    surface bare (``"none"``: the uncoated variant, named "<name> (uncoated)", whose
    fits go to ``generated/<lens folder>-uncoated/``), for coated-against-uncoated
    comparisons (issue 13: the paper's Figure 10)."""
    if coating not in COATING_CHOICES:
        raise InputError(f"coating {coating!r}: expected one of {', '.join(COATING_CHOICES)}")
    if coating == "file":
        return lens
    data = copy.deepcopy(lens.raw)
    data.setdefault("coating", {})["default"] = "none"
    for s in data["surface"]:
        s.pop("coating", None)
    bare = lens_from_dict(data, file=lens.source_file)
    return dataclasses.replace(bare, name=f"{lens.name} (uncoated)", variant="uncoated")


def make_lens(
    surfaces: list[dict[str, Any]],
    *,
    coating: dict[str, Any] | None = None,
    file: str = "<memory>",
    **info: Any,
) -> Lens:
    """A lens from a list of surface tables (the TOML layout), for tests, benchmarks and
    scripts. Provenance defaults to a synthetic lens; coatings default to bare."""
    lens = {"id": "synthetic", "name": "synthetic lens", "maker": "lensfit", "year": 2026}
    lens["source"] = "built in code"
    lens.update(info)
    data = {
        "schema_version": 1,
        "lens": lens,
        "coating": {"default": "none"} if coating is None else coating,
        "surface": surfaces,
    }
    return lens_from_dict(data, file=file)


def _scaled_aspheric(a: float, j: int, scale: float, err: Any) -> float:
    """Aspheric coefficient A(2j+4) of a lens scaled by ``scale``: a * scale^-(2j+3).
    A large power of a small scale overflows a float (scale 0.01, 200 terms: 1e802):
    a zero stays zero, and a result beyond a float's range is refused."""
    try:
        v = a * scale ** (-(2 * j + 3))
    except OverflowError:
        v = math.inf
    if math.isfinite(v):
        return v
    if a == 0.0:
        return 0.0
    from fractions import Fraction

    try:  # exact, for a tiny coefficient times a huge power
        return float(Fraction(a) * Fraction(scale) ** (-(2 * j + 3)))
    except OverflowError:
        raise err(f"aspheric[{j}] (A{2 * j + 4}) = {a:g} scaled by lens.scale = {scale:g} "
                  f"(times scale^-{2 * j + 3}) is beyond a float's range", "aspheric") from None


def _surface(s: dict[str, Any], i: int, file: str, scale: float) -> Surface:
    shape = s["shape"]

    def err(msg: str, key: str) -> LensError:
        return LensError(msg, file=file, surface=i, key=key)

    # Geometry
    if shape == "plane":
        if "radius" in s and s["radius"] != 0:
            raise err(f"a plane has no radius; found {s['radius']}", "radius")
        radius = math.inf
    else:
        if "radius" not in s:
            raise err(f"missing key (a {shape} needs a radius)", "radius")
        radius = float(s["radius"])
        if radius == 0:
            raise err("expected a non-zero radius (use shape = 'plane' for a flat)", "radius")
        radius *= scale
    thickness = float(s["thickness"]) * scale
    if thickness < 0:
        raise err(
            f"negative gap {thickness} mm: surfaces must follow each other along +z",
            "thickness",
        )
    sd = float(s["semi_diameter"]) * scale
    if sd <= 0:
        raise err(f"expected a positive semi-diameter, found {sd}", "semi_diameter")
    if shape in ("sphere", "cylinder-x", "cylinder-y") and sd > abs(radius):
        raise err(
            f"semi-diameter {sd} mm is larger than |radius| {abs(radius)} mm",
            "semi_diameter",
        )
    conic = float(s.get("conic", 0.0))
    aspheric = tuple(
        _scaled_aspheric(float(a), j, scale, err) for j, a in enumerate(s.get("aspheric", []))
    )
    if shape != "asphere" and ("conic" in s or "aspheric" in s):
        key = "conic" if "conic" in s else "aspheric"
        raise err(f"only an asphere has '{key}' (shape is {shape!r})", key)

    # Medium behind the surface
    medium, spec = _medium(s, i, file)
    stop = bool(s.get("stop", False))
    # What the semi-diameter is: an aperture ("fixed") or a housing sized to the beam
    aperture = s.get("aperture", "fixed")
    if aperture == "automatic" and stop:
        raise err("the stop's semi-diameter is its aperture: aperture = 'automatic' is not "
                  "allowed on the stop", "aperture")
    design_sd = None
    if "design_semi_diameter" in s:
        if aperture != "automatic":
            raise err("only an automatic semi-diameter (aperture = 'automatic') has a "
                      "design_semi_diameter", "design_semi_diameter")
        design_sd = float(s["design_semi_diameter"]) * scale
        if design_sd <= 0:
            raise err(f"expected a positive semi-diameter, found {design_sd}",
                      "design_semi_diameter")
    surf = Surface(
        shape=shape,
        radius_mm=radius,
        thickness_mm=thickness,
        medium=medium,
        semi_diameter_mm=sd,
        conic=conic,
        aspheric=aspheric,
        stop=stop,
        material_spec=spec,
        aperture=aperture,
        design_semi_diameter_mm=design_sd,
    )
    edge = surf.sag(sd, 0.0) if shape != "cylinder-x" else surf.sag(0.0, sd)
    if not np.isfinite(edge):
        raise err(
            f"semi-diameter {sd} mm is beyond the edge of this conic/asphere", "semi_diameter"
        )
    return surf


def _medium(s: dict[str, Any], i: int, file: str) -> tuple[Medium, dict[str, Any]]:
    has_nd = "nd" in s or "vd" in s
    if "material" in s and (has_nd or "dpgf" in s):
        raise LensError(
            "give either 'material' or 'nd' and 'vd', not both", file=file, surface=i,
            key="nd" if has_nd else "dpgf"
        )
    if "dpgf" in s and not has_nd:
        raise LensError("'dpgf' goes with 'nd' and 'vd' (the model glass's deviation of "
                        "P_g,F from the normal line)", file=file, surface=i, key="dpgf")
    if has_nd:
        for k in ("nd", "vd"):
            if k not in s:
                raise LensError(
                    "missing key ('nd' and 'vd' go together)", file=file, surface=i, key=k
                )
        nd, vd = float(s["nd"]), float(s["vd"])
        dpgf = float(s.get("dpgf", 0.0))
        (nd_lo, nd_hi), (vd_lo, vd_hi) = MODEL_ND_RANGE, MODEL_VD_RANGE
        if not nd_lo <= nd <= nd_hi:
            raise LensError(f"expected {nd_lo:g} <= nd <= {nd_hi:g}, found {nd}", file=file,
                            surface=i, key="nd")
        if not vd_lo <= vd <= vd_hi:
            hint = f" (a medium without dispersion: material = {{ n = {nd:g} }})" \
                if vd == 0 else ""
            raise LensError(f"expected {vd_lo:g} <= vd <= {vd_hi:g}, found {vd}{hint}",
                            file=file, surface=i, key="vd")
        if not abs(dpgf) <= MODEL_DPGF_MAX:
            raise LensError(f"expected -{MODEL_DPGF_MAX:g} <= dpgf <= {MODEL_DPGF_MAX:g} (the "
                            f"deviation of P_g,F from the normal line), found {dpgf}",
                            file=file, surface=i, key="dpgf")
        spec: dict[str, Any] = {"nd": nd, "vd": vd}
        if "dpgf" in s:
            spec["dpgf"] = dpgf
        if "glass_label" in s:
            spec["glass_label"] = s["glass_label"]
        return abbe_glass(nd, vd, dpgf), spec
    name = s.get("material")
    if name is None:
        raise LensError(
            "missing key (give 'material' or 'nd' and 'vd')", file=file, surface=i, key="material"
        )
    if isinstance(name, dict):  # inline dispersion (lensfit.glass.inline)
        try:
            return inline_glass(name), {"material": copy.deepcopy(name)}
        except InlineGlassError as e:
            raise LensError(str(e), file=file, surface=i, key=f"material.{e.key}") from None
    if name.lower() == "air":
        return AIR, {"material": "air"}
    try:  # the project catalog first, then the manufacturers' (lensfit.glass.resolve)
        return resolve_glass(name), {"material": name}
    except UnknownGlassError as e:
        raise LensError(str(e).strip('"'), file=file, surface=i, key="material") from None


def _coating(
    spec: Any,
    before: Medium,
    after: Medium,
    default: str,
    design_nm: float,
    file: str,
    i: int,
) -> Coating:
    glass_air = (before.name == "air") != (after.name == "air")
    if spec == "default":
        spec = default if glass_air else "none"
    if spec == "none":
        return BARE
    if spec == "mgf2":
        spec = {"layers": [{"material": "MgF2", "quarter_wave_nm": design_nm}]}
        label = f"MgF2 quarter wave at {design_nm:g} nm"
    else:
        label = "custom stack"
    layers = []
    for j, layer in enumerate(spec["layers"]):
        key = f"coating.layers.{j}"
        if ("material" in layer) == ("n" in layer):
            raise LensError("give exactly one of 'material' or 'n'", file=file, surface=i, key=key)
        if "material" in layer:
            try:
                medium: Medium = resolve_glass(layer["material"])
            except UnknownGlassError as e:
                raise LensError(
                    str(e).strip('"'), file=file, surface=i, key=key + ".material"
                ) from None
        else:
            n = float(layer["n"])
            if n < 1.0:
                raise LensError(f"expected n >= 1, found {n}", file=file, surface=i, key=key + ".n")
            medium = ConstantMedium(n)
        if ("thickness_nm" in layer) == ("quarter_wave_nm" in layer):
            raise LensError(
                "give exactly one of 'thickness_nm' or 'quarter_wave_nm'",
                file=file,
                surface=i,
                key=key,
            )
        if "thickness_nm" in layer:
            t = float(layer["thickness_nm"])
        else:
            lam = float(layer["quarter_wave_nm"])
            t = lam / (4.0 * float(medium.n(lam)))
        if not 0 < t < 1e5:
            raise LensError(
                f"expected a thickness in (0, 1e5) nm, found {t}", file=file, surface=i, key=key
            )
        layers.append(Layer(medium, t))
    return Coating(tuple(layers), label)


@dataclass(frozen=True)
class ConstantMedium:
    """A non-dispersive medium (thin-film layers given by a single index).

    A frozen dataclass so that two loads of the same prescription compare equal."""

    index: float
    name: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "index", float(self.index))
        if not self.name:
            object.__setattr__(self, "name", f"n={self.index:g}")

    def n(self, wavelength_nm: np.ndarray | float) -> np.ndarray:
        return np.full(np.shape(wavelength_nm), self.index, dtype=np.float64)


def first_crossing(a: Surface, b: Surface) -> tuple[float, float]:
    """Smallest axial gap between surface ``a`` and the next surface ``b`` within their
    common clear aperture, and the height where it occurs (mm)."""
    h = np.linspace(0.0, min(a.semi_diameter_mm, b.semi_diameter_mm), 257)
    worst, where = np.inf, 0.0
    for x, y in ((h, 0 * h), (0 * h, h)):
        g = a.thickness_mm + b.sag(x, y) - a.sag(x, y)
        j = int(np.argmin(g))
        if g[j] < worst:
            worst, where = float(g[j]), float(h[j])
    return worst, where


def _same_medium(a: Medium, b: Medium) -> bool:
    return a == b or (a.name == "air" and b.name == "air")


def _is_stop_plane(surfaces: list[Surface], i: int) -> bool:
    """Surface i of the file is a stop that is only a stop: a plane with the same medium
    on both sides (air, or one glass: a stop inside glass)."""
    s = surfaces[i]
    before = AIR if i == 0 else surfaces[i - 1].medium
    return s.stop and s.shape == "plane" and _same_medium(before, s.medium)


def _stop_plane(surfaces: list[Surface], s_i: int) -> list[Surface]:
    """The model's surfaces with the stop as a surface of its own (lensdb/README.md, The
    aperture stop). A stop on a plane with the same medium on both sides is that plane.
    On any other surface (curved, or bounding two media) the stop is that surface itself,
    clipped where a ray meets it at its radial distance sqrt(x^2 + y^2), as design
    programs clip it: the loader inserts a zero-thickness copy of the surface's shape
    (sphere, conic, aspheric terms, cylinder) with the same medium on both sides (so it
    neither refracts nor reflects and has no coating), coincident with the surface. A
    ray's hit on the copy is its hit on the surface, so the stop point (x_a, y_a) is the
    x, y of the ray on the refracting surface and the stop disc is the clipped aperture.
    The copy goes on the surface's air side: behind it when only its back is air (a stop
    on the last surface leaves nothing but air to the sensor; the refraction then belongs
    to P_o), in front of it otherwise (a stop on the first surface leaves nothing but air
    to the scene; on a cemented surface it lies in the front glass; the refraction belongs
    to P_s). Its clear radius is the surface's semi_diameter. The tracer crosses the zero
    gap by the sequential convention (Lens.virtual_gap): t is rounding-small there."""
    s = surfaces[s_i]
    if _is_stop_plane(surfaces, s_i):
        return surfaces
    before = AIR if s_i == 0 else surfaces[s_i - 1].medium
    shape = {"shape": s.shape, "radius_mm": s.radius_mm, "conic": s.conic,
             "aspheric": s.aspheric, "semi_diameter_mm": s.semi_diameter_mm, "stop": True}
    if before.name != "air" and s.medium.name == "air":
        stop = Surface(**shape, thickness_mm=s.thickness_mm, medium=s.medium,
                       material_spec=dict(s.material_spec), inserted="back")
        return [*surfaces[:s_i], dataclasses.replace(s, stop=False, thickness_mm=0.0), stop,
                *surfaces[s_i + 1:]]
    spec = {"material": "air"} if s_i == 0 else dict(surfaces[s_i - 1].material_spec)
    stop = Surface(**shape, thickness_mm=0.0, medium=before, material_spec=spec,
                   inserted="front")
    return [*surfaces[:s_i], stop, dataclasses.replace(s, stop=False), *surfaces[s_i + 1:]]


def _check_crossing(surfaces: list[Surface], file: str) -> None:
    """Neighbouring surfaces must not cross inside their clear aperture; a stop plane at
    zero distance from a surface may (a plane written at a curved surface's vertex,
    traced by the sequential convention, Lens.virtual_gap)."""
    for i in range(len(surfaces) - 1):
        if surfaces[i].thickness_mm == 0.0 and (_is_stop_plane(surfaces, i)
                                               or _is_stop_plane(surfaces, i + 1)):
            continue
        gap, h = first_crossing(surfaces[i], surfaces[i + 1])
        if gap < -CROSSING_TOLERANCE_MM:
            raise LensError(
                f"surfaces {i} and {i + 1} cross inside their clear aperture "
                f"(gap {gap:.4g} mm at height {h:.4g} mm); check radius, thickness "
                "and semi_diameter",
                file=file,
                surface=i,
                key="thickness",
            )
