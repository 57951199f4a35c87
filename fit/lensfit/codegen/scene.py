"""Scene specialisation: emit only what one scene needs from a lens's general systems.

A scene fixes some inputs and does without some outputs:

* each point light fixes (x_O, y_O, u_O) of P_o: one bivariate-in-the-stop system per
  light (``P_o_light<i>``), with the wavelength folded too when the scene has only one;
* a fixed focus offset folds z_S into P_s (and a single wavelength folds lambda);
* terms of phi that do not depend on the stop point are a constant phase per pixel and
  are dropped (they cannot change an intensity);
* ``clip = false`` drops the pupil positions, ``transmittance = false`` drops tau.

A specialised system equals the general one at the fixed inputs (up to the dropped
constant phase). Scene file (TOML)::

    name = "demo"
    wavelengths_nm = [450.0, 550.0, 650.0]
    focus_offset_mm = 0.0            # omit to keep z_S free
    f_number = 8.0                   # the stop a scene fit covers (lensfit fit --scene)
    clip = true
    transmittance = true
    flares = false                   # true: the lens's fitted ghosts too (below)
    ghosts = ["0-2", "4-8"]          # with flares: these ghosts (the lens file's numbers),
    # or ghost_count = 2             #   the K brightest for the scene's lights,
    # or ghost_threshold = 1e-5      #   or those peaking above this share of the PSF
    #                                #   peak (none of the three: the visible ones,
    #                                #   lensfit.ghosts.enumerate "Visibility")
    [[light]]
    field_x_deg = 0.0                # field angles, the designers' convention (README,
    field_y_deg = 5.0                # "Conventions"): this light is imaged at +y
    distance_mm = "inf"              # or a number: distance from the first vertex
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from lensfit.common.errors import int_shown, read_toml, toml_overflow
from lensfit.poly import Polynomial, System
from lensfit.psf.psf import light_direction  # the one definition (lensfit.psf.psf)

APERTURE_INPUTS = ("x_a", "y_a")


# A scene's name names its folder and is part of C symbols: ASCII only, short enough
# for file names (lens<id>_<name>.table) and C identifiers
SCENE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_-]{0,63}")
SCENE_NAME_RULE = ("expected a name of 1 to 64 ASCII letters, digits, '_' or '-', starting "
                   "with a letter (it names a folder and C symbols)")


class SceneError(ValueError):
    """A scene that cannot be served, naming the file, key and value."""


@dataclass(frozen=True)
class Light:
    field_x_deg: float
    field_y_deg: float
    distance_mm: float = math.inf  # from the first vertex (the centre of the outer pupil)

    def inputs_xy(self) -> tuple[float, float]:
        return light_direction(self.field_x_deg, self.field_y_deg)

    def inputs(self) -> dict[str, float]:
        """P_o's scene inputs: direction cosines of the light and its inverse distance."""
        x_o, y_o = light_direction(self.field_x_deg, self.field_y_deg)
        u = 0.0 if math.isinf(self.distance_mm) else 1.0 / self.distance_mm
        return {"x_O": x_o, "y_O": y_o, "u_O": u}


@dataclass(frozen=True)
class Scene:
    name: str
    wavelengths_nm: tuple[float, ...]
    lights: tuple[Light, ...]
    focus_offset_mm: float | None = None
    clip: bool = True
    transmittance: bool = True
    flares: bool = False
    source_file: str = field(default="<memory>", compare=False)
    f_number: float | None = None  # the stop a scene fit covers (default: the lens's)
    ghosts: tuple[str, ...] | None = None  # flares: these ghosts ("i-j", file numbering)
    ghost_count: int | None = None  # flares: the K brightest for the scene's lights
    ghost_threshold: float | None = None  # flares: relative PSF peak (default: visible)

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "<memory>") -> Scene:
        def fail(key: str, value: Any, want: str) -> SceneError:
            shown = (str(value).lower() if isinstance(value, bool)  # TOML's spelling
                     else int_shown(value) if isinstance(value, int) else repr(value))
            return SceneError(f"{source}: key '{key}': {want}, found {shown}")

        known = {"name", "wavelengths_nm", "light", "focus_offset_mm", "clip",
                 "transmittance", "flares", "f_number", "ghosts", "ghost_count",
                 "ghost_threshold"}
        for k in d:
            if k not in known:
                raise fail(k, d[k], f"unknown key (known: {', '.join(sorted(known))})")
        # Integers beyond a float's range (float() would raise OverflowError)
        big = toml_overflow(d)
        if big:
            raise fail(".".join(str(p) for p in big[0]), big[1],
                       "expected a number within a float's range")
        name = d.get("name")
        if not isinstance(name, str) or not SCENE_NAME.fullmatch(name):
            # The name becomes a folder name and part of C symbols (lens0001_<name>_P_s)
            raise fail("name", name if not isinstance(name, str) or len(name) <= 80
                       else f"{name[:40]}... ({len(name)} characters)", SCENE_NAME_RULE)
        lam = d.get("wavelengths_nm")
        if (not isinstance(lam, list) or not lam
                or not all(isinstance(v, int | float) and not isinstance(v, bool)
                           and math.isfinite(v) and v > 0 for v in lam)):
            raise fail("wavelengths_nm", lam,
                       "expected a non-empty list of positive finite numbers")
        lights = []
        raw_lights = d.get("light")
        if not isinstance(raw_lights, list) or not raw_lights:
            raise fail("light", raw_lights, "expected at least one [[light]] table")
        light_keys = {"field_x_deg", "field_y_deg", "distance_mm"}
        for i, lt in enumerate(raw_lights):
            # An unknown key (a misspelt distance_mm) would leave the light at infinity
            for k in lt if isinstance(lt, dict) else ():
                if k not in light_keys:
                    raise fail(f"light[{i}].{k}", lt[k], "unknown key in [[light]] (known: "
                               f"{', '.join(sorted(light_keys))})")
            # Booleans are not numbers (float(true) would be 1 mm or 1 degree)
            for k in light_keys:
                v = lt.get(k) if isinstance(lt, dict) else None
                if isinstance(v, bool):
                    raise fail(f"light[{i}].{k}", v, "expected a number"
                               + (' or "inf"' if k == "distance_mm" else ""))
            try:
                dist = lt.get("distance_mm", "inf")
                dist = math.inf if dist == "inf" else float(dist)
                light = Light(float(lt["field_x_deg"]), float(lt["field_y_deg"]), dist)
            except (KeyError, TypeError, ValueError, AttributeError) as e:
                raise fail(f"light[{i}]", lt, f"expected field_x_deg, field_y_deg and "
                           f"distance_mm (number or \"inf\") ({e})") from None
            if not light.distance_mm > 0:
                raise fail(f"light[{i}].distance_mm", dist,
                           "expected a positive distance in front of the lens")
            for k in ("field_x_deg", "field_y_deg"):  # tan() would wrap 180 to 0
                if not abs(getattr(light, k)) < 90.0:
                    raise fail(f"light[{i}].{k}", getattr(light, k),
                               "expected an angle in (-90, 90) degrees, in front of the lens")
            lights.append(light)
        focus = d.get("focus_offset_mm")
        if focus is not None and (isinstance(focus, bool) or not (
                isinstance(focus, int | float) and math.isfinite(focus))):
            raise fail("focus_offset_mm", focus, "expected a finite number (mm)")
        f_number = d.get("f_number")
        if f_number is not None and (isinstance(f_number, bool)
                                     or not (isinstance(f_number, int | float)
                                             and math.isfinite(f_number) and f_number > 0)):
            raise fail("f_number", f_number, "expected a positive f-number")
        flags = {}
        for k in ("clip", "transmittance", "flares"):
            v = d.get(k, k != "flares")
            if not isinstance(v, bool):
                raise fail(k, v, "expected true or false")
            flags[k] = v
        choice = _ghost_choice(d, flags["flares"], fail)
        return cls(name, tuple(float(v) for v in lam), tuple(lights),
                   None if focus is None else float(focus), source_file=source,
                   f_number=None if f_number is None else float(f_number), **flags,
                   **choice)


def _ghost_choice(d: dict[str, Any], flares: bool, fail) -> dict[str, Any]:
    """The scene's ghost choice: at most one of ghosts, ghost_count and ghost_threshold,
    and only with flares = true."""
    keys = [k for k in ("ghosts", "ghost_count", "ghost_threshold") if k in d]
    if keys and not flares:
        raise fail(keys[0], d[keys[0]], "chooses ghosts, which needs flares = true")
    if len(keys) > 1:
        raise fail(keys[1], d[keys[1]], f"expected one of ghosts, ghost_count and "
                                        f"ghost_threshold, found {' and '.join(keys)}")
    out: dict[str, Any] = {}
    if "ghosts" in d:
        v = d["ghosts"]
        if not (isinstance(v, list) and v and all(isinstance(g, str) for g in v)):
            raise fail("ghosts", v, 'expected a non-empty list of ghosts like ["4-8"]')
        out["ghosts"] = tuple(v)
    if "ghost_count" in d:
        v = d["ghost_count"]
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise fail("ghost_count", v, "expected a positive number of ghosts")
        out["ghost_count"] = v
    if "ghost_threshold" in d:
        v = d["ghost_threshold"]
        if (isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v)
                or not 0 < v < 1):
            raise fail("ghost_threshold", v, "expected a share of the PSF peak in (0, 1)")
        out["ghost_threshold"] = float(v)
    return out


def load_scene(path: str | Path) -> Scene:
    return Scene.from_dict(read_toml(path, "scene", SceneError), str(path))


def _check_domain(scene: Scene, system: System, fixed: dict[str, float], what: str) -> None:
    """Every fixed value must lie in the fitted domain: no silent extrapolation."""
    for inp in system.inputs:
        if inp.name in fixed:
            v = fixed[inp.name]
            if not (inp.lo - 1e-12 * abs(inp.lo) - 1e-15 <= v
                    <= inp.hi + 1e-12 * abs(inp.hi) + 1e-15):
                raise SceneError(f"{scene.source_file}: {what}: {inp.name} = {v:.6g} "
                                 f"{inp.unit} is outside the fitted domain "
                                 f"[{inp.lo:.6g}, {inp.hi:.6g}]")
    # Directions were sampled on the disc (ellipse) of the field, not on its box's corners
    if "x_O" in fixed and "y_O" in fixed and "x_O" in system.input_names:
        names = system.input_names
        sx, sy = (system.inputs[names.index(k)].hi for k in ("x_O", "y_O"))
        r = math.hypot(fixed["x_O"] / sx, fixed["y_O"] / sy)
        if r > 1.0 + 1e-12:
            raise SceneError(f"{scene.source_file}: {what}: the direction (x_O, y_O) = "
                             f"({fixed['x_O']:.6g}, {fixed['y_O']:.6g}) is outside the "
                             f"fitted field (the ellipse of half axes {sx:.6g}, {sy:.6g})")


def _drop_constant_phase(p: Polynomial, names: list[str]) -> Polynomial:
    if not p.output.startswith("phi"):
        return p
    cols = [names.index(a) for a in APERTURE_INPUTS]
    keep = p.exponents[:, cols].sum(axis=1) > 0
    return Polynomial(p.output, p.unit, p.exponents[keep], p.coefficients[keep])


def _outputs_wanted(scene: Scene, system: System) -> list[str]:
    names = []
    for n in system.output_names:
        if n.startswith(("x_", "y_")) and not scene.clip:
            continue
        if n.startswith("tau") and not scene.transmittance:
            continue
        names.append(n)
    return names


def _finish(scene: Scene, system: System, fixed: dict[str, float], name: str,
            what: str) -> System:
    _check_domain(scene, system, fixed, what)
    s = system.select(_outputs_wanted(scene, system)).specialise(fixed, name=name)
    outs = tuple(_drop_constant_phase(p, s.input_names) for p in s.outputs)
    info = {**s.info, "scene": scene.name}
    return replace(s, outputs=outs, info=info)


def specialise(systems: list[System], scene: Scene) -> list[System]:
    """The systems ``scene`` needs, folded and trimmed (see the module doc): for a
    direct table P_o per light and P_s; for a ghost table (``systems.ghost``) also
    P_clip, folded as its ghost side is. The ghosts of a scene with flares are chosen
    and specialised by :mod:`lensfit.ghosts.scene`."""
    by_name = {s.name: s for s in systems}
    if "P_o" not in by_name or "P_s" not in by_name:
        raise SceneError(f"{scene.source_file}: the lens has no fitted P_o and P_s")
    lam = {"lambda": scene.wavelengths_nm[0]} if len(scene.wavelengths_nm) == 1 else {}
    for v in scene.wavelengths_nm:
        _check_domain(scene, by_name["P_s"], {"lambda": v}, "wavelengths_nm")
    out = []
    for i, light in enumerate(scene.lights):
        fixed = {**light.inputs(), **lam}
        out.append(_finish(scene, by_name["P_o"], fixed, f"P_o_light{i}", f"light[{i}]"))
    fixed_s = dict(lam)
    if scene.focus_offset_mm is not None:
        fixed_s["z_S"] = scene.focus_offset_mm
    out.append(_finish(scene, by_name["P_s"], fixed_s, "P_s", "focus_offset_mm"))
    ghost = getattr(systems, "ghost", None)
    if ghost is not None and "P_clip" in by_name and scene.clip:
        clip = by_name["P_clip"]
        if ghost.side == "P_s":
            out.append(_finish(scene, clip, fixed_s, "P_clip", "focus_offset_mm"))
        else:
            for i, light in enumerate(scene.lights):
                out.append(_finish(scene, clip, {**light.inputs(), **lam},
                                   f"P_clip_light{i}", f"light[{i}]"))
    return out


def terms(systems: list[System]) -> int:
    return int(sum(p.terms for s in systems for p in s.outputs))


def max_abs_difference(general: System, special: System, fixed: dict[str, float],
                       n: int = 2000, seed: int = 0) -> float:
    """Largest |general - special| over random free inputs, with the stop-independent
    terms of phi dropped from the general system too (as the specialisation does)."""
    rng = np.random.default_rng(seed)
    free = [i for i in general.inputs if i.name not in fixed]
    x_free = np.column_stack([rng.uniform(i.lo, i.hi, n) for i in free])
    x_full = np.column_stack([
        np.full(n, fixed[i.name]) if i.name in fixed else x_free[:, [f.name for f in free]
                                                                 .index(i.name)]
        for i in general.inputs])
    names = special.output_names
    sel = general.select(names)
    sel = replace(sel, outputs=tuple(_drop_constant_phase(p, sel.input_names)
                                     for p in sel.outputs))
    return float(np.max(np.abs(sel.evaluate(x_full) - special.evaluate(x_free))))


# A scene fit's domain: margins around what the scene uses
SCENE_FIELD_MARGIN = 1.05  # on the largest direction cosine of a light
SCENE_IMAGE_MARGIN_MM = 0.3  # around the lights' images: room for their PSF windows
SCENE_FOCUS_MARGIN_MM = 0.02  # either side of a fixed sensor shift
SCENE_WAVELENGTH_MARGIN_NM = 1.0  # either side of the scene's wavelengths


def scene_wavelengths(lens, scene: Scene):
    """The band a scene fit covers and why (:class:`lensfit.prescription.ranges.Wavelengths`):
    the scene's wavelengths with ``SCENE_WAVELENGTH_MARGIN_NM`` either side, the margin
    kept inside the range every glass supports (a scene at 400-700 nm fits a lens whose
    glass is published over 400-700 nm) unless the lens allows extrapolation. A scene
    wavelength itself outside a glass's range is refused when the fit starts, naming
    the scene's file and key."""
    from lensfit.prescription.ranges import Wavelengths, allows_extrapolation, common_range

    lam = scene.wavelengths_nm
    lo, hi = min(lam) - SCENE_WAVELENGTH_MARGIN_NM, max(lam) + SCENE_WAVELENGTH_MARGIN_NM
    if not allows_extrapolation(lens):
        g_lo, g_hi = common_range(lens)
        lo, hi = max(lo, min(min(lam), g_lo)), min(hi, max(max(lam), g_hi))
    name = Path(scene.source_file).name
    listed = ", ".join(f"{w:g}" for w in lam)
    return Wavelengths(lo, hi, f"the wavelengths of scene {name} ({listed} nm) with a "
                               f"margin of up to {SCENE_WAVELENGTH_MARGIN_NM:g} nm",
                       f"scene {name}, key 'wavelengths_nm' = [{listed}]")


def scene_domain(lens, scene: Scene):
    """The domain a scene fit covers (``lensfit fit --scene``): the disc of directions
    that holds its lights, the image circle of their images plus room for a PSF window,
    their nearest distance, its wavelengths (:func:`scene_wavelengths`), its stop
    (``f_number``, default the lens's default) and its focus (with small margins, named
    above)."""
    from lensfit.psf.psf import geometric_image_point
    from lensfit.sample.domain import default_domain

    r = max(math.hypot(*lt.inputs_xy()) for lt in scene.lights)
    field = max(math.degrees(math.asin(min(SCENE_FIELD_MARGIN * r, 0.99))), 0.5)
    focus = scene.focus_offset_mm
    image = max(math.hypot(*geometric_image_point(lens, (lt.field_x_deg, lt.field_y_deg),
                                                  lt.distance_mm, 550.0, focus or 0.0))
                for lt in scene.lights)
    close = min(lt.distance_mm for lt in scene.lights)
    base = default_domain(lens, scene.f_number, close_focus_mm=0.98 * close,
                          focus_mm=None if focus is None else
                          (focus - SCENE_FOCUS_MARGIN_MM, focus + SCENE_FOCUS_MARGIN_MM),
                          wavelengths_nm=scene_wavelengths(lens, scene).range_nm)
    return base.with_(field_deg=field, field_y_deg=None,
                      sensor_radius_mm=image + SCENE_IMAGE_MARGIN_MM)
