"""What the importers share: the result and error types, glass look-up, the lens table
they fill in, and the atomic write of an output file."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lensfit.common.errors import InputError, LensError
from lensfit.glass import (
    AIR,
    MODEL_ND_RANGE,
    UnknownGlassError,
    abbe_glass,
    catalog_glass,
    inline_glass,
)

# The manufacturer qualifiers lensfit.glass knows (see /lensdb/glass/README.md); before
# the manufacturer catalogs land only the project catalog exists and this stays empty.
try:  # pragma: no cover - depends on which glass API is installed
    from lensfit.glass import MANUFACTURERS as _MAKERS
    from lensfit.glass import resolve_glass as _resolve_glass
except ImportError:  # pragma: no cover
    _MAKERS = ()
    _resolve_glass = None

MANUFACTURERS: tuple[str, ...] = tuple(m.upper() for m in _MAKERS)


class ImportProblems(InputError):
    """An input that cannot be imported: one line per problem (each naming the file and
    the line number or JSON path). The command line prints every line, exits with 2 and
    writes nothing."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


@dataclass
class ImportResult:
    """A lens in the TOML layout (``data``, validated), what was not mapped (``notes``:
    one line each, printed on stderr while the lens is written) and what was done with
    each surface's semi-diameter (``semi_diameters``: one line per surface, after a line
    on the design beam when one was traced; lensfit.interchange.housings)."""

    data: dict[str, Any]
    notes: list[str] = field(default_factory=list)
    semi_diameters: list[str] = field(default_factory=list)


class Notes:
    """Informational "not mapped" items, grouped by keyword and reason so that 24
    wavelength lines make one line naming the first of them and the count."""

    def __init__(self, label: str, sep: str = ":") -> None:
        self.label = label
        self.sep = sep  # ":" before a line number, ": " before a JSON path
        self._items: dict[tuple[str, str], list[str]] = {}

    def add(self, where: str, what: str, reason: str) -> None:
        self._items.setdefault((what, reason), []).append(where)

    def lines(self) -> list[str]:
        out = []
        for (what, reason), wheres in self._items.items():
            more = f" (and {len(wheres) - 1} more)" if len(wheres) > 1 else ""
            head = f"{self.label}{self.sep}{wheres[0]}"
            out.append(f"{head}{more}: {reason}" if what == wheres[0]
                       else f"{head}: {what}{more}: {reason}")
        return out


def finite(value: float) -> bool:
    return isinstance(value, float) and math.isfinite(value)


# HIKARI names its current glasses J-... (Q-... for precision moulding). Older HIKARI and
# Nikon catalogs name many of the same glasses without a prefix (SK16) or with E-
# (E-SK16): so do refractiveindex.info's hikari folder and Optiland, which reads it
# (Optiland 0.6.3's Cooke triplet uses 'SK16' of 'hikari'). Measured with Optiland 0.6.3's
# data (tests/fit/interchange/test_optiland_cross.py): the 169 such names that have a J-
# glass in lensfit's HIKARI catalog differ from it by at most 9.6e-4 in n over 400-700 nm
# (median 6e-5; SK16 3.0e-5), within the 1e-3 by which melts of one glass differ
# (lensfit.prescription.lentil.GLASS_ND_MATCH): the J- glass is taken, with a note.
_PREFIXED_MAKERS = {"HIKARI": ("J-", ("J-", "Q-"), ("E-",))}
OLD_NAME_DIFFERENCE = 1e-3


def _current_name(name: str, maker: str) -> str | None:
    """The maker's current name of an older glass name ("SK16", "E-SK16" -> "J-SK16" for
    HIKARI), or None when the maker has no such convention or the name is current."""
    if maker not in _PREFIXED_MAKERS:
        return None
    prefix, current, old = _PREFIXED_MAKERS[maker]
    upper = name.upper()
    if upper.startswith(current):
        return None
    for p in old:
        if upper.startswith(p):
            name = name[len(p):]
            break
    return prefix + name


def split_maker_suffix(name: str) -> tuple[str, str | None]:
    """("SK16", "HIKARI") from a name that carries its maker in parentheses, as
    lensfit's messages and some files print it: "SK16 (HIKARI)", "'SK16' (hikari)"; the
    name unchanged and None when the parentheses name no known manufacturer."""
    m = re.fullmatch(r"\s*(['\"]?)(.+?)\1\s*\(\s*([^()]+?)\s*\)\s*", name)
    if m is None or m.group(3).upper() not in MANUFACTURERS:
        return name, None
    return m.group(2).strip(), m.group(3).upper()


def resolve_glass(name: str, makers: list[str]) -> tuple[dict[str, Any], str | None]:
    """The ``material`` keys of a glass named in an imported file, qualified by the
    file's catalogs ``makers`` (Zemax GCAT, Optiland's reference), in order, and a note
    when the glass was found outside them or under another name (None otherwise).

    The project catalog (lensdb/glass/catalog.toml) comes first when it has the name
    from one of ``makers`` (or when the file names no maker), so that a lens exported
    from lensdb comes back with the same glass; then each maker's catalog in the file's
    order (as OpticStudio searches GCAT); then each maker's current name of an older
    name (HIKARI's "SK16" is "J-SK16", with the note); then the name unqualified, with
    the note. Raises UnknownGlassError (AmbiguousGlassError is a subclass) when none
    resolves."""
    # OpticStudio names some catalog files with a date (SUMITA_AUG2011): the maker
    wanted = [m.upper().split("_")[0] for m in makers]
    try:
        g = catalog_glass(name)
    except UnknownGlassError:
        g = None
    if g is not None and (not wanted or str(getattr(g, "maker", "")).upper() in wanted):
        return {"material": g.name}, None
    outside = (f"glass {name} is not in the file's catalogs ({' '.join(makers)}): "
               "found as {ref}")
    if _resolve_glass is not None:
        known = [m for m in wanted if m in MANUFACTURERS]
        for m in known:
            try:
                medium = _resolve_glass(name, m)
            except UnknownGlassError:
                continue
            return {"material": str(getattr(medium, "reference", f"{m}:{name}"))}, None
        for m in known:
            current = _current_name(name, m)
            if current is None:
                continue
            try:
                medium = _resolve_glass(current, m)
            except UnknownGlassError:
                continue
            ref = str(getattr(medium, "reference", f"{m}:{current}"))
            return {"material": ref}, (
                f"glass {name} ({m}) taken as {ref}, {m}'s current name for it (older "
                f"names of its glasses differ from the current ones by up to "
                f"{OLD_NAME_DIFFERENCE:g} in n over 400-700 nm)")
        medium = _resolve_glass(name)
        ref = str(getattr(medium, "reference", medium.name))
        return {"material": ref}, (outside.format(ref=ref) if wanted else None)
    if g is not None:
        return {"material": g.name}, outside.format(ref=g.name)
    raise UnknownGlassError(name, [])


def glass_message(e: UnknownGlassError) -> str:
    """An UnknownGlassError as a short phrase (its list of known glasses left out)."""
    text = str(e)
    if "; known glasses:" in text:
        text = text.split("; known glasses:")[0]
    return text.strip('"')


# Why an index above the loader's range (MODEL_ND_RANGE, 1-3) is refused rather than
# clipped or kept: the media with such indices are infrared ones (germanium about 4.0,
# silicon about 3.4, in Optiland's InfraredTriplet and IR designs), opaque over the
# visible range lensfit traces; an index below 1 is no medium at all.
VISIBLE_NM = (380.0, 780.0)


def index_range_problem(n: float, what: str = "nd") -> str | None:
    """None when the index ``n`` is within lensfit's range for an index (an nd/vd model
    glass's nd or a constant index: ``MODEL_ND_RANGE``, 1-3), else the phrase that says
    so and why: "expected 1 <= nd <= 3" and, above 3, that such a medium is an infrared
    one (germanium, silicon) and lensfit traces visible light, where it is opaque."""
    lo, hi = MODEL_ND_RANGE
    if lo <= n <= hi:
        return None
    text = f"expected {lo:g} <= {what} <= {hi:g}"
    if n > hi and math.isfinite(n):
        a, b = VISIBLE_NM
        text += (f"; an index above {hi:g} belongs to an infrared medium (germanium about "
                 f"4.0, silicon about 3.4), opaque to the visible light ({a:g}-{b:g} nm) "
                 "lensfit traces")
    return text


def lens_table(*, lens_id: str, name: str, source: str, notes: list[str]) -> dict[str, Any]:
    """The ``[lens]`` table of an imported file (maker and year are not in the formats:
    "unknown" and 0)."""
    info: dict[str, Any] = {"id": lens_id, "name": name or lens_id, "maker": "unknown",
                            "year": 0, "source": source}
    if notes:
        info["notes"] = " ".join(n if n.endswith(".") else n + "." for n in notes)
    return info


def file_surface_names(detail: str, names: list[str]) -> str:
    """A loader message with the surface indices it names (lensfit's, 0 for the first
    surface of the converted table: "surfaces 6 and 7 cross ...", "surfaces [2, 5]",
    "surface 3") replaced by the file's own names of those surfaces (``names[i]``: "SURF
    7" of a .zmx, "surface_group.surfaces[7]" of an Optiland file); an index without a
    name is left as it is."""
    def name(i: str) -> str | None:
        k = int(i)
        return names[k] if 0 <= k < len(names) else None

    def pair(m: re.Match[str]) -> str:
        a, b = name(m.group(1)), name(m.group(2))
        return f"{a} and {b}" if a and b else m.group(0)

    def listed(m: re.Match[str]) -> str:
        got = [name(i) for i in re.findall(r"\d+", m.group(1))]
        return ", ".join(g for g in got if g) if all(got) else m.group(0)

    def one(m: re.Match[str]) -> str:
        return name(m.group(1)) or m.group(0)

    detail = re.sub(r"\bsurfaces (\d+) and (\d+)\b", pair, detail)
    detail = re.sub(r"\bsurfaces \[(\d+(?:, \d+)*)\]", listed, detail)
    return re.sub(r"\bsurface (\d+)\b", one, detail)


def file_surfaces(lens: Any) -> list[tuple[int, Any, bool, float]]:
    """The surfaces as the lens file has them: (index in ``lens.surfaces``, surface, stop
    flag, thickness). The stop surface the loader inserted on a refracting surface marked
    as the stop (``inserted`` "front" or "back": a zero-thickness copy of it) is folded
    back into that surface, as a .zmx writes it (STOP on the surface, which OpticStudio
    clips on the surface, as lensfit does); a copy behind its surface held the gap that
    follows."""
    ss = lens.surfaces
    out = []
    for k, s in enumerate(ss):
        if getattr(s, "inserted", ""):
            continue
        stop, thickness = s.stop, s.thickness_mm
        if k + 1 < len(ss) and getattr(ss[k + 1], "inserted", "") == "back":
            stop, thickness = True, ss[k + 1].thickness_mm  # the plane kept the gap
        if k > 0 and getattr(ss[k - 1], "inserted", "") == "front":
            stop = True
        out.append((k, s, stop, thickness))
    return out


def validate(data: dict[str, Any], label: str, where_surface: list[str], *,
             sep: str = ":") -> Any:
    """Load the converted table as lensfit would (lens_from_dict) and return the Lens;
    turn a refusal into an ImportProblems line that names the source line (or JSON path)
    of the surface, after ``label`` and ``sep`` (":" before a .zmx line number, ": "
    before an Optiland JSON path), and any surface the loader's message names by its index
    (lensfit's 0-based index in the converted table) by the file's own name for it
    (``SURF n`` of a .zmx, ``surface_group.surfaces[i]`` of an Optiland file:
    ``where_surface[i]`` without its line number)."""
    import numpy as np

    from lensfit.prescription import lens_from_dict

    try:
        # Lengths near the float limit (1e308) overflow in the loader's sag checks; the
        # overflow is an inf there, which the loader refuses, not a warning
        with np.errstate(over="ignore", invalid="ignore"):
            return lens_from_dict(data, file=label)
    except LensError as e:
        head = f"{label}: "
        if e.surface is not None and 0 <= e.surface < len(where_surface):
            head = f"{label}{sep}{where_surface[e.surface]}: "
        key = f"key '{e.key}': " if e.key else ""
        names = [w.split(": ", 1)[-1] for w in where_surface]
        detail = file_surface_names(e.detail, names)
        raise ImportProblems([f"{head}{key}{detail} (lensfit's loader refuses the "
                              "converted lens; nothing written)"]) from None


def write_atomic(path: Path, text: str, *, option: str = "") -> None:
    """Write ``text`` to ``path`` with lensfit's one checked atomic write
    (:func:`lensfit.common.atomic.write_atomic`: special files and links refused, a temporary
    in the same folder, fsync, rename; the file's mode kept; OutputError on failure)."""
    from lensfit.common.atomic import write_atomic as _write

    _write(path, text, option=option)


D_LINE_NM = 587.5618


def _medium(d: dict[str, Any]):
    if "nd" in d:
        return abbe_glass(float(d["nd"]), float(d["vd"]), float(d.get("dpgf", 0.0)))
    name = d.get("material", "air")
    if isinstance(name, dict):  # an inline glass (a constant index from the importers)
        return inline_glass(name)
    if name == "air":
        return AIR
    try:
        return catalog_glass(name)
    except UnknownGlassError:
        if _resolve_glass is None:
            raise
        return _resolve_glass(name)


def paraxial_semi_diameters(out: list[dict[str, Any]], missing: list[int], where: list[str],
                            ap_type: str | None, ap_value: float | None, *,
                            object_distance: float, half_field_deg: float,
                            bad: Callable[[str, str], None],
                            note: Callable[[str, float], None]) -> None:
    """Fill in the semi-diameters a file does not give (``out[k]`` for k in ``missing``):
    |y_marginal| + |y_chief| of a paraxial y-nu trace at the d line, rounded to 6
    significant digits. The marginal ray comes from the system aperture ``ap_type``
    (EPD: its diameter; imageFNO: EFL/F; float_by_stop_size: the stop's diameter) and
    the axial object point (``object_distance`` in front of the first vertex, inf for
    parallel light); the chief ray from the largest field angle through the entrance
    pupil's centre. Both meridians are traced (a cylinder has power in one) and the
    larger height taken. ``bad(where, message)`` reports a problem, ``note(where,
    semi_diameter)`` each value filled in."""
    if ap_type not in ("EPD", "imageFNO", "float_by_stop_size") or not ap_value or \
            ap_value <= 0:
        bad("", f"no semi-diameter on {', '.join(where[i] for i in missing)}, and the "
            f"system aperture ({ap_type or 'none'}) does not give the paraxial marginal "
            "ray to estimate them")
        return
    try:
        media = [_medium(d) for d in out]
    except (UnknownGlassError, ValueError) as e:
        bad("", f"no semi-diameters, and no paraxial trace to estimate them: {e}")
        return
    n = [1.0] + [float(m.n(D_LINE_NM)) for m in media]
    stop = next(i for i, d in enumerate(out) if d.get("stop"))
    d_obj = object_distance
    heights = [0.0] * len(out)
    for meridian in ("y", "x"):
        curv = []
        for d in out:
            shape = d["shape"]
            power_here = (shape in ("sphere", "asphere")
                          or (shape == "cylinder-x" and meridian == "y")
                          or (shape == "cylinder-y" and meridian == "x"))
            curv.append(1.0 / d["radius"] if power_here else 0.0)

        def trace(y0: float, u0: float, curv=curv) -> list[float]:
            """Heights at each vertex of a ray with height y0 and slope u0 at vertex 0."""
            ys, y, nu = [], y0, u0
            for k, d in enumerate(out):
                ys.append(y)
                nu = nu - y * curv[k] * (n[k + 1] - n[k])
                y = y + d["thickness"] * nu / n[k + 1]
            return ys

        a = trace(1.0, 0.0)   # unit height, parallel
        b = trace(0.0, 1.0)   # through vertex 0, unit slope
        ha, hb = a[stop], b[stop]
        if ha == 0.0:
            bad("", "no semi-diameters, and the paraxial trace to estimate them failed "
                "(the stop is imaged to infinity)")
            return
        z_ep = hb / ha  # entrance pupil position (the chief ray crosses the axis there)
        # Marginal ray
        if ap_type == "float_by_stop_size":
            r_stop = ap_value / 2.0
            if math.isinf(d_obj):
                mr = [r_stop / ha * v for v in a]
            else:  # from the axial object point (height 0 at z = -d_obj)
                ray = [d_obj * u + w for u, w in zip(a, b, strict=True)]
                if ray[stop] == 0.0:
                    bad("", "no semi-diameters, and the object is imaged onto the stop")
                    return
                mr = [r_stop / ray[stop] * v for v in ray]
        else:
            epd = ap_value
            if ap_type == "imageFNO":
                # f-number = EFL / EPD with the EFL from the parallel ray's last slope
                y, nu = 1.0, 0.0
                for k, d in enumerate(out):
                    nu = nu - y * curv[k] * (n[k + 1] - n[k])
                    y = y + d["thickness"] * nu / n[k + 1]
                if nu == 0.0:
                    bad("", "no semi-diameters, and an image F/# on an afocal lens")
                    return
                epd = abs(-1.0 / nu) / ap_value
            if math.isinf(d_obj):
                mr = [epd / 2.0 * v for v in a]
            else:
                if z_ep + d_obj == 0.0:
                    bad("", "no semi-diameters, and the entrance pupil is on the object")
                    return
                u = epd / 2.0 / (z_ep + d_obj)
                mr = [u * (d_obj * av + bv) for av, bv in zip(a, b, strict=True)]
        # Chief ray at the largest field angle, through the entrance pupil's centre
        t = math.tan(math.radians(half_field_deg))
        cr = [t * (bv - z_ep * av) for av, bv in zip(a, b, strict=True)]
        for k in range(len(out)):
            heights[k] = max(heights[k], abs(mr[k]) + abs(cr[k]))
    for k in missing:
        h = heights[k]
        if not (math.isfinite(h) and h > 0):
            bad(where[k], f"no semi-diameter, and a paraxial estimate of {h:g}: give "
                "one")
            continue
        sd = float(f"{h:.6g}")
        keys = list(out[k])
        # keep the layout's key order: semi_diameter after the medium
        ordered = {kk: out[k][kk] for kk in keys if kk != "semi_diameter"}
        pos = [kk for kk in ("shape", "radius", "thickness", "material", "nd", "vd")
               if kk in ordered]
        res = {kk: ordered[kk] for kk in pos}
        res["semi_diameter"] = sd
        res.update({kk: v for kk, v in ordered.items() if kk not in res})
        out[k].clear()
        out[k].update(res)
        note(where[k], sd)
