"""A bank spec: which lens, which grid of nodes, which window and how each is rendered.

A bank spec is a TOML file (``banks/demo.toml`` is the one ``make demo`` runs)::

    name = "demo"                      # 1-64 of [A-Za-z0-9_-]
    lens = "0001"                      # a lens id or folder of generated/, or a .table path
    [grid]
    field_x_deg = [-12, -6, 0, 6, 12]  # the chief ray's field angles (designers' signs)
    field_y_deg = [-8, 0, 8]
    f_numbers = [8]
    focus_offsets_mm = [0.0]           # sensor shift z_S (default [0])
    distances_mm = ["inf"]             # light distance from the first vertex (default inf)
    wavelengths_nm = [450, 500, 550, 600, 650]
    [window]                           # every node: a window centred on its chief ray
    pixels = [64, 64]
    size_mm = [0.1, 0.1]
    # center_mm = [0, 0]               # or one fixed window for every node (flare banks)
    [aperture]                         # optional: circle (default) or blades
    shape = "blades"
    blades = 7
    blade_curvature = 0.5
    rotation_deg = 0
    [render]                           # optional
    integrator = "cells"               # or "monte-carlo"
    target_error = 0.01                # cells: refine each node to this estimate
    max_rings = 256
    samples = 65536                    # monte-carlo: samples per wavelength
    checkpoints = 4                    # monte-carlo: sums saved this many times per node
    seed = 0
    threads = 1                        # lensrt threads per task
    [flare]                            # optional: a flare bank
    ghosts = "kept"                    # the lens folder's fitted ghosts (ghosts/ghosts.json),
                                       # or some of them: ["0-2", "2-4"]

Every key is checked: an unknown key, a value of the wrong type, an empty or unsorted grid,
NaN or infinity where a number is meant, are refused naming the file, the key and the
value (:class:`SpecError`, exit status 2).
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from lensfit.common.errors import InputError, int_shown, read_toml, toml_overflow

NAME = re.compile(r"[A-Za-z0-9_-]{1,64}")
GHOST = re.compile(r"[0-9]{1,3}-[0-9]{1,3}")  # a ghost's label: the file's surfaces i-j
MAX_NODES = 65_536  # what lensrt_bank_open reads (LENSRT_MAX_BANK_NODES)
MAX_PIXELS = 4096
# The f-numbers and pixels a bank may ask for. f/1000 is a 0.05 mm stop on a 100 mm lens
# (a PSF of 1000 lambda N, half a metre, past any window); beyond it, and with pixels far
# below a wavelength, renders ran into non-finite fields and every node failed blaming the
# table (f/1e308, a 1e-300 mm window: issue 39)
MAX_F_NUMBER = 1000.0
MIN_PITCH_MM = 1e-5


class SpecError(InputError):
    """A bank spec that cannot be used, naming the file, the key and the value."""


@dataclass(frozen=True)
class Grid:
    field_x_deg: tuple[float, ...]
    field_y_deg: tuple[float, ...]
    f_numbers: tuple[float, ...]
    wavelengths_nm: tuple[float, ...]
    focus_offsets_mm: tuple[float, ...] = (0.0,)
    distances_mm: tuple[float, ...] = (math.inf,)

    @property
    def shape(self) -> tuple[int, int, int, int, int]:
        """Nodes along (f-number, focus offset, distance, field y, field x)."""
        return (len(self.f_numbers), len(self.focus_offsets_mm), len(self.distances_mm),
                len(self.field_y_deg), len(self.field_x_deg))


@dataclass(frozen=True)
class Window:
    pixels: tuple[int, int]
    size_mm: tuple[float, float]
    center_mm: tuple[float, float] | None = None  # None: each node's chief ray

    @property
    def pitch_mm(self) -> tuple[float, float]:
        return (self.size_mm[0] / self.pixels[0], self.size_mm[1] / self.pixels[1])


@dataclass(frozen=True)
class Aperture:
    shape: str = "circle"
    blades: int = 0
    blade_curvature: float = 0.0
    rotation_deg: float = 0.0


@dataclass(frozen=True)
class Render:
    integrator: str = "cells"
    target_error: float = 0.01
    max_rings: int = 256
    samples: int = 65536
    checkpoints: int = 4
    seed: int = 0
    threads: int = 1


@dataclass(frozen=True)
class Flare:
    ghosts: str | tuple[str, ...] = ()  # "kept", or ghost labels "i-j"; () no flare


@dataclass(frozen=True)
class BankSpec:
    name: str
    lens: str
    grid: Grid
    window: Window
    aperture: Aperture = field(default_factory=Aperture)
    render: Render = field(default_factory=Render)
    flare: Flare = field(default_factory=Flare)
    source_file: str = field(default="<memory>", compare=False)

    def to_dict(self) -> dict[str, Any]:
        """The spec as plain data (infinite distances as "inf", as in the TOML)."""
        d = asdict(self)
        d.pop("source_file")
        d["grid"]["distances_mm"] = ["inf" if math.isinf(v) else v
                                     for v in self.grid.distances_mm]
        for part in ("grid", "window"):
            d[part] = {k: list(v) for k, v in d[part].items() if v is not None}
        if isinstance(self.flare.ghosts, tuple):
            d["flare"]["ghosts"] = list(self.flare.ghosts)
        return d

    @classmethod
    def from_dict(cls, d: Any, source: str = "<memory>") -> BankSpec:
        return _parse(d, source)

    def digest(self) -> str:
        """SHA-256 of the canonical spec: what a finished node was rendered for."""
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()

    @property
    def n_nodes(self) -> int:
        return math.prod(self.grid.shape)


def load_spec(path: str | Path) -> BankSpec:
    """Read and check a bank spec file."""
    return _parse(read_toml(path, "bank spec", SpecError), str(path))


# ------------------------------------------------------------------ checks -----

def _fail(source: str, key: str, value: Any, want: str) -> SpecError:
    shown = (str(value).lower() if isinstance(value, bool)  # TOML's spelling
             else int_shown(value) if isinstance(value, int) else repr(value))
    if len(shown) > 120:
        shown = shown[:100] + f"... ({len(shown)} characters)"
    return SpecError(f"{source}: key '{key}': {want}, found {shown}")


def _table(d: Any, key: str, known: set[str], required: set[str], source: str
           ) -> dict[str, Any]:
    if not isinstance(d, dict):
        raise _fail(source, key, d, "expected a table")
    for k in d:
        if k not in known:
            raise _fail(source, f"{key}.{k}" if key else k, d[k],
                        f"unknown key (known: {', '.join(sorted(known))})")
    for k in sorted(required - set(d)):
        raise _fail(source, f"{key}.{k}" if key else k, None, "missing")
    return d


def _number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _numbers(d: dict[str, Any], key: str, source: str, *, check=lambda v: True,
             want: str = "", increasing: bool = False, allow_inf: bool = False
             ) -> tuple[float, ...]:
    raw = d[key.split(".")[-1]]
    values = []
    if not isinstance(raw, list) or not raw:
        raise _fail(source, key, raw, f"expected a non-empty list of {want}")
    for i, v in enumerate(raw):
        if allow_inf and v == "inf":
            values.append(math.inf)
            continue
        if not _number(v) or not check(v):
            raise _fail(source, f"{key}[{i}]", v, f"expected {want}")
        values.append(float(v))
    if len(set(values)) != len(values):
        raise _fail(source, key, raw, "expected distinct values")
    if increasing and values != sorted(values):
        raise _fail(source, key, raw, "expected increasing values")
    return tuple(values)


def _scalar(d: dict[str, Any], key: str, default: Any, source: str, kind: type,
            check, want: str) -> Any:
    v = d.get(key.split(".")[-1], default)
    ok = (isinstance(v, int) and not isinstance(v, bool)) if kind is int else (
        _number(v) if kind is float else isinstance(v, kind))
    if not ok or not check(v):
        raise _fail(source, key, v, f"expected {want}")
    return kind(v)


def _parse(d: Any, source: str) -> BankSpec:
    big = toml_overflow(d)
    if big:
        raise _fail(source, ".".join(str(p) for p in big[0]), big[1],
                    "expected a number within a float's range")
    top = _table(d, "", {"name", "lens", "grid", "window", "aperture", "render", "flare"},
                 {"name", "lens", "grid", "window"}, source)
    name = top["name"]
    if not isinstance(name, str) or not NAME.fullmatch(name):
        raise _fail(source, "name", name, "expected 1-64 of A-Z a-z 0-9 _ -")
    lens = top["lens"]
    if not isinstance(lens, str) or not lens or "\0" in lens or len(lens) > 4096:
        raise _fail(source, "lens", lens, "expected a lens id, a folder of generated/ or a "
                                          "table path")

    # The grid of nodes
    g = _table(top["grid"], "grid", {"field_x_deg", "field_y_deg", "f_numbers",
                                     "focus_offsets_mm", "distances_mm", "wavelengths_nm"},
               {"field_x_deg", "field_y_deg", "f_numbers", "wavelengths_nm"}, source)
    angle = "angles in (-90, 90) degrees"
    grid = Grid(
        field_x_deg=_numbers(g, "grid.field_x_deg", source, check=lambda v: abs(v) < 90,
                             want=angle, increasing=True),
        field_y_deg=_numbers(g, "grid.field_y_deg", source, check=lambda v: abs(v) < 90,
                             want=angle, increasing=True),
        f_numbers=_numbers(g, "grid.f_numbers", source,
                           check=lambda v: 0 < v <= MAX_F_NUMBER,
                           want=f"f-numbers in (0, {MAX_F_NUMBER:g}]"),
        wavelengths_nm=_numbers(g, "grid.wavelengths_nm", source,
                                check=lambda v: 100 < v < 10000,
                                want="wavelengths in nm (100 to 10000)", increasing=True),
        focus_offsets_mm=(_numbers(g, "grid.focus_offsets_mm", source,
                                   want="sensor shifts in mm") if "focus_offsets_mm" in g
                          else (0.0,)),
        distances_mm=(_numbers(g, "grid.distances_mm", source, check=lambda v: v > 0,
                               want='positive distances in mm or "inf"', allow_inf=True)
                      if "distances_mm" in g else (math.inf,)))
    n_nodes = math.prod(grid.shape)
    if n_nodes > MAX_NODES:
        raise _fail(source, "grid", f"{n_nodes} nodes", f"expected at most {MAX_NODES} nodes")

    # The window every node renders, centred on its chief ray
    w = _table(top["window"], "window", {"pixels", "size_mm", "center_mm"},
               {"pixels", "size_mm"}, source)
    px, size = w["pixels"], w["size_mm"]
    if (not isinstance(px, list) or len(px) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_PIXELS
                       for v in px)):
        raise _fail(source, "window.pixels", px,
                    f"expected [width, height] in pixels, 1 to {MAX_PIXELS}")
    if not isinstance(size, list) or len(size) != 2 or not all(
            _number(v) and 0 < v <= 100 for v in size):
        raise _fail(source, "window.size_mm", size, "expected [width, height] in mm, in (0, 100]")
    for axis, (n, mm) in enumerate(zip(px, size, strict=True)):
        if mm / n < MIN_PITCH_MM:
            raise _fail(source, "window.size_mm", size,
                        f"expected pixels of at least {MIN_PITCH_MM:g} mm (a hundredth of the "
                        f"shortest wavelength); {mm!r} mm over {n} pixels in "
                        f"{'xy'[axis]} is {mm / n:.3g} mm")
    centre = w.get("center_mm")
    if centre is not None and (not isinstance(centre, list) or len(centre) != 2 or not all(
            _number(v) and abs(v) <= 1000 for v in centre)):
        raise _fail(source, "window.center_mm", centre,
                    "expected [x, y] on the sensor in mm (one window for every node)")
    window = Window((int(px[0]), int(px[1])), (float(size[0]), float(size[1])),
                    None if centre is None else (float(centre[0]), float(centre[1])))

    # The aperture (a circle unless blades are given)
    a = _table(top.get("aperture", {}), "aperture",
               {"shape", "blades", "blade_curvature", "rotation_deg"}, set(), source)
    shape = _scalar(a, "aperture.shape", "circle", source, str,
                    lambda v: v in ("circle", "blades"), '"circle" or "blades"')
    aperture = Aperture(
        shape=shape,
        blades=_scalar(a, "aperture.blades", 0 if shape == "circle" else 6, source, int,
                       lambda v: (v == 0) if shape == "circle" else 3 <= v <= 32,
                       "3 to 32 blades with shape = \"blades\" (none for a circle)"),
        blade_curvature=_scalar(a, "aperture.blade_curvature", 0.0, source, float,
                                lambda v: 0 <= v <= 1, "a curvature in [0, 1]"),
        rotation_deg=_scalar(a, "aperture.rotation_deg", 0.0, source, float,
                             lambda v: abs(v) <= 360, "an angle in [-360, 360] degrees"))

    # How each node is integrated
    r = _table(top.get("render", {}), "render",
               {"integrator", "target_error", "max_rings", "samples", "checkpoints", "seed",
                "threads"}, set(), source)
    render = Render(
        integrator=_scalar(r, "render.integrator", "cells", source, str,
                           lambda v: v in ("cells", "monte-carlo"),
                           '"cells" or "monte-carlo"'),
        target_error=_scalar(r, "render.target_error", 0.01, source, float,
                             lambda v: 1e-6 <= v < 1, "a relative error in [1e-6, 1)"),
        max_rings=_scalar(r, "render.max_rings", 256, source, int, lambda v: 8 <= v <= 4096,
                          "8 to 4096 rings"),
        samples=_scalar(r, "render.samples", 65536, source, int, lambda v: 1 <= v <= 2**40,
                        "1 to 2^40 samples per wavelength"),
        checkpoints=_scalar(r, "render.checkpoints", 4, source, int, lambda v: 1 <= v <= 1024,
                            "1 to 1024 checkpoints"),
        seed=_scalar(r, "render.seed", 0, source, int, lambda v: 0 <= v < 2**63,
                     "a seed in [0, 2^63)"),
        threads=_scalar(r, "render.threads", 1, source, int, lambda v: 0 <= v <= 256,
                        "0 (all cores) to 256 lensrt threads per task"))
    if render.integrator == "monte-carlo" and render.samples < render.checkpoints:
        raise _fail(source, "render.checkpoints", render.checkpoints,
                    f"expected at most render.samples = {render.samples} checkpoints")

    # A flare bank: ghosts rendered into every node with the direct image
    fl = _table(top.get("flare", {}), "flare", {"ghosts"}, set(), source)
    ghosts = fl.get("ghosts", ())
    if ghosts != "kept" and not (isinstance(ghosts, list) and ghosts and all(
            isinstance(g, str) and GHOST.fullmatch(g) for g in ghosts)
            and len(set(ghosts)) == len(ghosts)) and ghosts != ():
        raise _fail(source, "flare.ghosts", ghosts,
                    'expected "kept" or a list of distinct ghost labels like ["0-2", "2-4"]')
    flare = Flare(ghosts if isinstance(ghosts, str) else tuple(ghosts))
    return BankSpec(name, lens, grid, window, aperture, render, flare, source)
