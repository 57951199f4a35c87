"""The demo scene of issue 38: a street at night, as a pinhole camera sees it, for a whole
HDR image through the lens.

    python scenes/night_street.py -o street.exr --width 960 --height 540 --spp 8 \\
        --focal-mm 50

Everything is procedural and built with Mitsuba 3's Python dict API (``mi.load_dict``),
rendered in the ``scalar_rgb`` variant (CPU only, no LLVM or GPU needed): a street of
buildings whose facades hold a grid of lit and dark windows, a road with a zebra crossing
and lane marks, paved sidewalks, street lamps on poles, lamps hung on wires across the
street, telephone lines, wall lanterns near the top corners of the frame, a lit bollard
near the bottom right, a lantern on the far building near the centre of the frame, and a
dark sky.

The lamps are small emissive spheres and light the street (direct light, the street
lamps and hung lamps under shades that keep their light below the horizon, so the
camera sees their lower half): their pixels are 10^3-10^5 times the pavement and walls
they light (at 960 x 540: lamps 3.7e3-1.1e4, the lit pavement 0.4-1.5, the median pixel
0.4). The lit windows and the sky glow but light nothing.

The camera is a pinhole at ``CAMERA`` looking along -z, level, +y up and +x right (the
project's convention, docs/conventions.md), with the horizontal field of view of a
``--sensor-width-mm`` (default 36, full frame) wide sensor behind a lens of focal length
``--focal-mm``: a point (x, y, z) in the camera's frame lands at column
W / 2 + f x / (-z) / p and row H / 2 - f y / (-z) / p (p = sensor width / W, pixel
edges at integers, row 0 at the top): ``project`` below.

The output is a linear RGB float32 EXR (channels R, G, B) with the float attributes
``lensfit/pinholeFocalMm`` and ``lensfit/sensorWidthMm``. The render is deterministic:
fixed seeds, fixed scene. At 960 x 540 and the default 8 samples per pixel (16 lamp
samples each) it takes 27 s on 2 cores (40 CPU-s; 2026-11-29, Mitsuba 3.9.1).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

SENSOR_WIDTH_MM = 36.0  # a full-frame sensor's width
CAMERA = (-1.6, 1.6, 0.0)  # the pinhole: in the left lane, at eye height (m)
SEED = 38  # the render's seed (issue 38); the procedural textures use it too
DEFAULT_SPP = 8  # camera samples per pixel
EMITTER_SAMPLES = 16  # lamp samples per camera sample

# The street's layout (m): the road spans |x| < ROAD_HALF, the sidewalks reach the
# facades at |x| = FACADE_X, and the street ends at a building across it at z = END_Z
ROAD_HALF = 5.0
FACADE_X = 8.0
CURB = 0.15
END_Z = -140.0

# Radiance (linear RGB, W sr^-1 m^-2 up to a common scale) of the lamps and their colours
LAMP_RADIANCE = 1.2e4
SODIUM = (1.0, 0.55, 0.18)
LED = (1.0, 0.93, 0.82)
COOL = (0.80, 0.90, 1.0)
SKY = (0.004, 0.007, 0.016)


@dataclass(frozen=True)
class Lamp:
    """A lamp: an emissive sphere."""

    name: str
    center: tuple[float, float, float]
    radius: float
    color: tuple[float, float, float]
    radiance: float = LAMP_RADIANCE


def horizontal_fov_deg(focal_mm: float, sensor_width_mm: float = SENSOR_WIDTH_MM) -> float:
    """The horizontal field of view of a sensor this wide behind a lens of this focal
    length, in degrees."""
    return math.degrees(2.0 * math.atan(0.5 * sensor_width_mm / focal_mm))


def project(point: tuple[float, float, float], width: int, height: int, focal_mm: float,
            sensor_width_mm: float = SENSOR_WIDTH_MM) -> tuple[float, float]:
    """(column, row) where the pinhole images a world point, in pixels with the edges at
    integers (pixel (i, j) spans [i, i + 1] x [j, j + 1]), row 0 at the top."""
    # The point in the camera's frame: +x right, +y up, looking along -z
    x, y, z = (p - c for p, c in zip(point, CAMERA, strict=True))
    if z >= 0:
        raise ValueError(f"point {point} is not in front of the camera")
    pitch_mm = sensor_width_mm / width
    return (0.5 * width + focal_mm * x / -z / pitch_mm,
            0.5 * height - focal_mm * y / -z / pitch_mm)


def lamps() -> list[Lamp]:
    """Every lamp of the scene."""
    out: list[Lamp] = []
    # Street lamps: poles on both curbs, staggered, each with an arm over the road
    for k in range(6):
        for side in (-1.0, 1.0):
            z = -14.0 - 20.0 * k - (10.0 if side > 0 else 0.0)
            color = SODIUM if (k + (side > 0)) % 3 else LED
            out.append(Lamp(f"street_{'lr'[side > 0]}{k}",
                            (side * (ROAD_HALF - 0.9), 5.85, z), 0.12, color))
    # Lamps hung on wires across the street
    for k, z in enumerate((-36.0, -66.0, -96.0)):
        out.append(Lamp(f"hung_{k}", (0.0, 6.55, z), 0.16, LED))
    # Wall lanterns, placed to image near the top corners at 50 mm on full frame
    out.append(Lamp("lantern_left", (-FACADE_X + 0.35, 4.9, -19.2), 0.11, SODIUM))
    out.append(Lamp("lantern_right", (FACADE_X - 0.35, 6.67, -29.4), 0.11, SODIUM))
    # A lit traffic bollard in the middle of the road, near the bottom right
    out.append(Lamp("bollard", (-0.47, 0.95, -3.8), 0.045, COOL, 0.6 * LAMP_RADIANCE))
    # A lantern over the door of the building at the end of the street, near the centre
    out.append(Lamp("centre", (-1.0, 3.4, END_Z + 0.5), 0.35, LED))
    return out


def _facade_textures(rng: np.random.Generator, length: float, height: float,
                     wall: tuple[float, float, float], px_per_m: int = 8
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The reflectance and emission textures (rows from the top, (h, w, 3) float32) of a
    building's facade: a wall with a grid of windows, some lit, and shop windows below."""
    w, h = max(8, round(length * px_per_m)), max(8, round(height * px_per_m))
    albedo = np.empty((h, w, 3), np.float32)
    albedo[:] = wall
    emit = np.zeros((h, w, 3), np.float32)
    # A darker cornice band at the top and a plinth at the bottom
    albedo[: max(1, px_per_m // 3)] *= 0.55
    albedo[-max(1, px_per_m // 4):] *= 0.6
    # Upper floors: 3 m storeys, 2.5 m window bays, windows 1.2 x 1.6 m
    floor_px, bay_px = 3 * px_per_m, round(2.5 * px_per_m)
    win_w, win_h = round(1.2 * px_per_m), round(1.6 * px_per_m)
    n_floors = int(height // 3)
    n_bays = max(1, int(length // 2.5))
    x0 = (w - n_bays * bay_px) // 2 + (bay_px - win_w) // 2
    for f in range(1, n_floors):
        top = h - (f + 1) * floor_px + (floor_px - win_h) // 2
        for b in range(n_bays):
            left = x0 + b * bay_px
            window = (slice(top, top + win_h), slice(left, left + win_w))
            # A dark glass pane with a thin light frame around it
            albedo[top - 1: top + win_h + 1, left - 1: left + win_w + 1] = 0.45
            albedo[window] = 0.04
            if rng.random() < 0.42:
                # A lit room: warm or cool, with a mullion across the pane
                tint = np.array(SODIUM if rng.random() < 0.25 else
                                (1.0, 0.78, 0.5) if rng.random() < 0.7 else COOL, np.float32)
                emit[window] = tint * rng.uniform(3.0, 12.0)
                emit[top + win_h // 2 - 1: top + win_h // 2, left: left + win_w] *= 0.15
                # A drawn blind on some: the top part dimmer
                if rng.random() < 0.3:
                    emit[top: top + win_h // 3, left: left + win_w] *= 0.25
    # The ground floor: shop windows, lit in some buildings, with a door
    shop_h = round(2.4 * px_per_m)
    top = h - round(0.4 * px_per_m) - shop_h
    lit = rng.random() < 0.6
    for b in range(n_bays):
        left = x0 + b * bay_px - px_per_m // 4
        window = (slice(top, top + shop_h), slice(left, left + win_w + px_per_m // 2))
        albedo[window] = 0.05
        if lit and b % 3 != 1:
            emit[window] = np.array((1.0, 0.9, 0.75), np.float32) * rng.uniform(4.0, 10.0)
    return albedo, emit


def _bitmap(array: np.ndarray) -> dict[str, Any]:
    """A nearest-neighbour bitmap texture of linear values from an image whose rows run
    from the top."""
    import mitsuba as mi

    # Flipped: the rectangle's v = 0 edge (its bottom) takes the bitmap's first row
    return {"type": "bitmap", "bitmap": mi.Bitmap(np.ascontiguousarray(array[::-1])),
            "raw": True, "filter_type": "nearest"}


def _rect(center: tuple[float, float, float], size: tuple[float, float], facing: str,
          bsdf: dict[str, Any], emitter: dict[str, Any] | None = None) -> dict[str, Any]:
    """A rectangle of size (u, v) metres centred at `center`, its normal along `facing`
    ('+x', '-x', '+y', '+z'), its texture's u along the street (-z) or along x, v up
    (on the ground, along -z)."""
    import mitsuba as mi

    t = mi.ScalarTransform4f().translate(list(center))
    # Turn the rectangle's own frame (u = x, v = y, normal +z) to face the street
    if facing == "+x":
        t = t.rotate([0, 1, 0], 90.0)  # normal +x, u along -z
    elif facing == "-x":
        t = t.rotate([0, 1, 0], -90.0).scale([-1, 1, 1])  # normal -x, u along -z
    elif facing == "+y":
        t = t.rotate([1, 0, 0], -90.0)  # normal +y, u along x, v along -z
    elif facing != "+z":
        raise ValueError(facing)
    shape: dict[str, Any] = {"type": "rectangle",
                             "to_world": t.scale([0.5 * size[0], 0.5 * size[1], 1.0]),
                             "bsdf": bsdf}
    if emitter is not None:
        shape["emitter"] = emitter
    return shape


def _hood(lamp: Lamp, radius: float) -> dict[str, dict[str, Any]]:
    """A lamp's shade: a flat dark disc just above the bulb and a skirt down to its
    middle, which keeps most of its light below the horizon (a cut-off street light)."""
    import mitsuba as mi

    cx, cy, cz = lamp.center
    top = cy + lamp.radius + 0.01
    metal = _diffuse((0.05, 0.055, 0.06))
    # Mitsuba's disc is the unit disc in z = 0: lay it flat, facing down
    disc = mi.ScalarTransform4f().translate([cx, top, cz]).rotate([1, 0, 0], 90.0)
    return {f"{lamp.name}_shade": {"type": "disk", "to_world": disc.scale(radius),
                                   "bsdf": metal},
            f"{lamp.name}_skirt": {"type": "cylinder", "p0": [cx, cy, cz],
                                   "p1": [cx, top, cz], "radius": radius, "bsdf": metal}}


def _diffuse(value: Any) -> dict[str, Any]:
    if isinstance(value, dict):
        return {"type": "diffuse", "reflectance": value}
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(value)}}


def scene_dict(width: int, height: int, focal_mm: float, spp: int,
               sensor_width_mm: float = SENSOR_WIDTH_MM,
               weights: dict[str, float] | None = None,
               crop: tuple[int, int, int, int] | None = None) -> dict[str, Any]:
    """The whole scene as a Mitsuba dict. `weights` are how often each lamp (by name) is
    picked to light a point, against the others (default all 1), and `crop` the film's
    window (x, y, width, height) to render."""
    import mitsuba as mi

    rng = np.random.default_rng(SEED)
    T = mi.ScalarTransform4f

    def weight(name: str) -> float:
        return 1.0 if weights is None else float(weights[name])
    scene: dict[str, Any] = {"type": "scene"}
    # Direct light only, sampled from the lamps: the street is lit by many small lamps,
    # each picked in proportion to its weight; the lit windows and the sky light nothing
    scene["integrator"] = {"type": "direct", "emitter_samples": EMITTER_SAMPLES,
                           "bsdf_samples": 0}
    # The pinhole: level, looking along -z, its horizontal field that of the sensor
    scene["sensor"] = {
        "type": "perspective", "fov_axis": "x",
        "fov": horizontal_fov_deg(focal_mm, sensor_width_mm),
        "near_clip": 0.05, "far_clip": 1000.0,
        "to_world": T().look_at(origin=list(CAMERA),
                                target=[CAMERA[0], CAMERA[1], CAMERA[2] - 1.0],
                                up=[0, 1, 0]),
        "film": {"type": "hdrfilm", "width": width, "height": height,
                 "pixel_format": "rgb", "component_format": "float32",
                 "rfilter": {"type": "box"}},  # each pixel its own samples
        "sampler": {"type": "multijitter", "sample_count": spp, "seed": SEED},
    }
    if crop is not None:
        film = scene["sensor"]["film"]
        film["crop_offset_x"], film["crop_offset_y"], film["crop_width"], film["crop_height"] = crop
    # A dim night sky, never sampled as a light: it only fills the shadows a little
    scene["sky"] = {"type": "constant", "radiance": {"type": "rgb", "value": list(SKY)},
                    "sampling_weight": 0.0}

    # The road: dark asphalt, a dashed centre line, edge lines and a zebra crossing
    length = -END_Z + 10.0
    z_mid = 5.0 - 0.5 * length
    scene["road"] = _rect((0.0, 0.0, z_mid), (2 * ROAD_HALF, length), "+y",
                          _diffuse((0.07, 0.07, 0.075)))
    paint = _diffuse((0.62, 0.62, 0.6))
    for k, z in enumerate(np.arange(-16.0, END_Z + 8.0, -6.0)):
        scene[f"dash_{k}"] = _rect((0.0, 0.003, float(z)), (0.12, 3.0), "+y", paint)
    for side in (-1.0, 1.0):
        scene[f"edge_{side:+.0f}"] = _rect((side * (ROAD_HALF - 0.25), 0.003, z_mid),
                                           (0.1, length), "+y", paint)
    for k, x in enumerate(np.arange(-ROAD_HALF + 0.5, ROAD_HALF - 0.4, 1.0)):
        scene[f"zebra_{k}"] = _rect((float(x), 0.003, -10.5), (0.5, 3.5), "+y", paint)

    # Sidewalks: square paving stones in two greys, their curbs, on both sides
    walk = FACADE_X - ROAD_HALF
    tiles = {"type": "checkerboard",
             "color0": {"type": "rgb", "value": [0.30, 0.29, 0.27]},
             "color1": {"type": "rgb", "value": [0.22, 0.215, 0.21]},
             "to_uv": T().scale([walk / 0.6, length / 0.6, 1.0])}
    for side in (-1.0, 1.0):
        x = side * (ROAD_HALF + 0.5 * walk)
        scene[f"walk_{side:+.0f}"] = _rect((x, CURB, z_mid), (walk, length), "+y",
                                           _diffuse(tiles))
        scene[f"curb_{side:+.0f}"] = _rect((side * ROAD_HALF, 0.5 * CURB, z_mid),
                                           (length, CURB), "+x" if side < 0 else "-x",
                                           _diffuse((0.4, 0.39, 0.37)))

    # Buildings: a facade per building on each side, of random length and height
    walls = [(0.36, 0.29, 0.23), (0.29, 0.27, 0.26), (0.40, 0.36, 0.29), (0.26, 0.21, 0.19),
             (0.32, 0.32, 0.34)]
    for side in (-1.0, 1.0):
        z = 6.0
        k = 0
        while z > END_Z:
            span = float(min(rng.uniform(12.0, 22.0), z - END_Z))
            storeys = int(rng.integers(3, 7))
            tall = 3.0 * storeys + 1.0
            wall = walls[int(rng.integers(len(walls)))]
            albedo, emit = _facade_textures(rng, span, tall, wall)
            scene[f"facade_{side:+.0f}_{k}"] = _rect(
                (side * FACADE_X, 0.5 * tall, z - 0.5 * span), (span, tall),
                "+x" if side < 0 else "-x", _diffuse(_bitmap(albedo)),
                {"type": "area", "radiance": _bitmap(emit), "sampling_weight": 0.0})
            z -= span
            k += 1
    # The building across the end of the street
    albedo, emit = _facade_textures(rng, 2 * FACADE_X + 4.0, 19.0, walls[2])
    scene["facade_end"] = _rect((0.0, 9.5, END_Z), (2 * FACADE_X + 4.0, 19.0), "+z",
                                _diffuse(_bitmap(albedo)),
                                {"type": "area", "radiance": _bitmap(emit),
                                 "sampling_weight": 0.0})

    # Lamps: emissive spheres
    metal = _diffuse((0.05, 0.055, 0.06))
    for lamp in lamps():
        scene[lamp.name] = {
            "type": "sphere", "center": list(lamp.center), "radius": lamp.radius,
            "emitter": {"type": "area", "sampling_weight": weight(lamp.name), "radiance": {
                "type": "rgb", "value": [lamp.radiance * c for c in lamp.color]}}}
        cx, cy, cz = lamp.center
        if lamp.name.startswith("street_"):
            # A pole on the curb and an arm out to the lamp, with a hood above it
            side = math.copysign(1.0, cx)
            foot = side * (ROAD_HALF + 0.35)
            scene[f"{lamp.name}_pole"] = {"type": "cylinder", "p0": [foot, 0.0, cz],
                                          "p1": [foot, cy + 0.35, cz], "radius": 0.07,
                                          "bsdf": metal}
            scene[f"{lamp.name}_arm"] = {"type": "cylinder", "p0": [foot, cy + 0.3, cz],
                                         "p1": [cx, cy + 0.3, cz], "radius": 0.035,
                                         "bsdf": metal}
            scene.update(_hood(lamp, 0.42))
        elif lamp.name.startswith("hung_"):
            # The wire from facade to facade, sagging to the lamp, in straight pieces
            pts = [(x, cy + 0.35 + 0.9 * (x / FACADE_X) ** 2, cz)
                   for x in np.linspace(-FACADE_X, FACADE_X, 13)]
            for i, (p, q) in enumerate(zip(pts[:-1], pts[1:], strict=True)):
                scene[f"{lamp.name}_wire{i}"] = {"type": "cylinder", "p0": list(p),
                                                 "p1": list(q), "radius": 0.012,
                                                 "bsdf": metal}
            scene.update(_hood(lamp, 0.4))
        elif lamp.name.startswith("lantern_"):
            # A bracket from the wall
            wall_x = math.copysign(FACADE_X, cx)
            scene[f"{lamp.name}_bracket"] = {"type": "cylinder", "p0": [wall_x, cy + 0.2, cz],
                                             "p1": [cx, cy + 0.2, cz], "radius": 0.025,
                                             "bsdf": metal}
        elif lamp.name == "bollard":
            # The bollard's post
            scene["bollard_post"] = {"type": "cylinder", "p0": [cx, 0.0, cz],
                                     "p1": [cx, cy - 0.05, cz], "radius": 0.09,
                                     "bsdf": _diffuse((0.5, 0.5, 0.5))}
    # Overhead wires: telephone lines along the street, from pole top to pole top
    for side in (-1.0, 1.0):
        x = side * (ROAD_HALF + 0.35)
        scene[f"line_{side:+.0f}"] = {"type": "cylinder", "p0": [x, 6.2, 4.0],
                                      "p1": [x, 6.2, END_Z], "radius": 0.008, "bsdf": metal}
    return scene


def lamp_weights(scene: Any, lamp_list: list[Lamp], width: int, height: int,
                 window: tuple[int, int, int, int], grid: int = 8,
                 floor: float = 0.05) -> dict[str, float]:
    """How much each lamp lights what a window of the image sees, as weights for picking
    lamps there: the mean over a grid of the window's pixels of the lamp's share of the
    irradiance at the point the pixel sees (from the lamps' centres: shades and walls in
    the way count), at least `floor` times the largest so that every lamp keeps a chance
    (unbiased whatever the weights)."""
    import mitsuba as mi

    x0, y0, w, h = window
    sensor = scene.sensors()[0]
    total = np.zeros(len(lamp_list))
    for gy in range(grid):
        for gx in range(grid):
            # The point the pixel's centre sees and its normal
            px = (x0 + (gx + 0.5) * w / grid) / width
            py = (y0 + (gy + 0.5) * h / grid) / height
            ray, _ = sensor.sample_ray(0.0, 0.5, [px, py], [0.5, 0.5])
            si = scene.ray_intersect(ray)
            # Nothing to light on the sky or a lamp's bulb (the only spheres)
            if not si.is_valid() or si.shape.shape_type() == int(mi.ShapeType.Sphere):
                continue
            p = np.array(si.p, dtype=float)
            n = np.array(si.n, dtype=float)
            if np.dot(n, np.array(ray.d, dtype=float)) > 0:
                n = -n
            here = np.zeros(len(lamp_list))
            for k, lamp in enumerate(lamp_list):
                # The lamp's solid angle times the cosine, if nothing is in the way
                v = np.array(lamp.center) - p
                d = float(np.linalg.norm(v))
                cos = float(np.dot(n, v)) / d
                if cos <= 0.0:
                    continue
                shadow = mi.Ray3f(mi.ScalarPoint3f(p + 1e-3 * n), mi.ScalarVector3f(v / d))
                shadow.maxt = d - 1.05 * lamp.radius
                if not scene.ray_test(shadow):
                    here[k] = lamp.radiance * cos * (lamp.radius / d) ** 2
            # Each point's shares: a dim point's lamps count as much as a bright one's
            if here.sum() > 0.0:
                total += here / here.sum()
    if total.max() <= 0.0:
        total[:] = 1.0  # sky only: any lamp will do
    total = np.maximum(total, floor * total.max())
    return {lamp.name: float(t / total.max()) for lamp, t in zip(lamp_list, total, strict=True)}


def render(width: int, height: int, focal_mm: float, spp: int,
           sensor_width_mm: float = SENSOR_WIDTH_MM, progress: bool = True,
           tile: int = 96) -> np.ndarray:
    """The scene's linear RGB image, (height, width, 3) float32, row 0 at the top.

    The image is rendered in tiles of `tile` pixels, each with its own lamp weights
    (`lamp_weights`): a lamp that lights little of what a tile sees is picked less there,
    so the few lamps that light a patch of street get most of its samples."""
    import mitsuba as mi

    # CPU only: the scalar RGB variant needs neither LLVM nor a GPU
    mi.set_variant("scalar_rgb")
    mi.set_log_level(mi.LogLevel.Warn)
    lamp_list = lamps()
    probe = mi.load_dict(scene_dict(width, height, focal_mm, 1, sensor_width_mm))
    tiles = [(x, y, min(tile, width - x), min(tile, height - y))
             for y in range(0, height, tile) for x in range(0, width, tile)]
    image = np.zeros((height, width, 3), np.float32)
    start = time.perf_counter()
    for i, (x, y, w, h) in enumerate(tiles):
        # The tile's lamp weights, then the tile alone with them, its own fixed seed
        weights = lamp_weights(probe, lamp_list, width, height, (x, y, w, h))
        scene = mi.load_dict(scene_dict(width, height, focal_mm, spp, sensor_width_mm,
                                        weights, (x, y, w, h)))
        part = mi.render(scene, spp=spp, seed=SEED + i)
        image[y: y + h, x: x + w] = np.array(part, dtype=np.float32).reshape(h, w, 3)
        if progress:
            print(f"\rnight_street: rendering, tile {i + 1} of {len(tiles)} "
                  f"({time.perf_counter() - start:.1f} s)", end="", file=sys.stderr, flush=True)
    if progress:
        print(file=sys.stderr)
    return image


def write_exr(path: Path, rgb: np.ndarray, focal_mm: float,
              sensor_width_mm: float = SENSOR_WIDTH_MM) -> None:
    """A float32 R, G, B EXR with the pinhole's focal length and sensor width."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "lensfit/pinholeFocalMm": float(focal_mm),
              "lensfit/sensorWidthMm": float(sensor_width_mm),
              "comments": "scenes/night_street.py (issue 38): a pinhole render, linear RGB"}
    channels = {name: np.ascontiguousarray(rgb[..., k], dtype=np.float32)
                for k, name in enumerate("RGB")}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--output", type=Path, required=True, help="the EXR to write")
    ap.add_argument("--width", type=int, default=960)
    ap.add_argument("--height", type=int, default=540)
    ap.add_argument("--spp", type=int, default=DEFAULT_SPP, help="samples per pixel")
    ap.add_argument("--focal-mm", type=float, default=50.0,
                    help="the lens's focal length (its EFL), mm")
    ap.add_argument("--sensor-width-mm", type=float, default=SENSOR_WIDTH_MM)
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    a = ap.parse_args(argv)
    if a.width < 1 or a.height < 1 or a.spp < 1:
        ap.error("--width, --height and --spp must be positive")
    if not (a.focal_mm > 0 and a.sensor_width_mm > 0):
        ap.error("--focal-mm and --sensor-width-mm must be positive")
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        sys.exit("night_street: needs Mitsuba 3 (pip install -r fit/requirements.lock)")
    start = time.perf_counter()
    rgb = render(a.width, a.height, a.focal_mm, a.spp, a.sensor_width_mm, not a.quiet)
    write_exr(a.output, rgb, a.focal_mm, a.sensor_width_mm)
    if not a.quiet:
        fov = horizontal_fov_deg(a.focal_mm, a.sensor_width_mm)
        print(f"night_street: {a.width} x {a.height}, {a.spp} spp, f = {a.focal_mm:g} mm on "
              f"{a.sensor_width_mm:g} mm ({fov:.2f} deg across): {a.output} in "
              f"{time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
