"""The output EXR: the total (unprefixed channels) and one layer per part.

Layers (OpenEXR channel prefixes): ``direct``, ``flare`` (the sum of the ghosts) and
``ghost_<i>_<j>`` per ghost table, each with the input's channels (R, G, B, or the
spectral S0.<lambda>nm, which also get an R, G, B preview); the unprefixed channels are
direct + flare. Written to a temporary file beside the output and renamed over it
(lensfit.common.atomic): never half-written, never over a special file.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from lensfit.image.frame import RGB, Frame, Geometry


def layer_channels(name: str, planes: np.ndarray, frame: Frame,
                   wavelengths: tuple[float, ...], rt: Any) -> dict[str, np.ndarray]:
    prefix = f"{name}." if name else ""
    out: dict[str, np.ndarray] = {}
    if frame.kind == "rgb":
        for c, plane in zip(RGB, planes, strict=True):
            out[prefix + c] = np.ascontiguousarray(plane, dtype=np.float32)
        return out
    from lensrt_exr import spectral_channel_name

    for lam, plane in zip(wavelengths, planes, strict=True):
        out[prefix + spectral_channel_name(lam)] = np.ascontiguousarray(plane, dtype=np.float32)
    rgb = rt.spectrum_rgb(list(wavelengths), planes)
    for k, c in enumerate(RGB):
        out[prefix + c] = np.ascontiguousarray(rgb[..., k])
    return out


def write_layers(path: Path, layers: dict[str, np.ndarray], frame: Frame, geometry: Geometry,
                 wavelengths: tuple[float, ...], attributes: dict[str, Any], rt: Any) -> None:
    """Write the layers and their total (module doc)."""
    import OpenEXR

    from lensfit.common.atomic import write_atomic

    for name, planes in layers.items():
        if not np.isfinite(planes).all():  # what lensrt_image hands back is checked
            raise RuntimeError(f"layer {name}: a value that is not finite")
    channels: dict[str, np.ndarray] = {}
    total = layers["direct"] + layers["flare"]
    channels.update(layer_channels("", total, frame, wavelengths, rt))
    for name, planes in layers.items():
        channels.update(layer_channels(name, planes, frame, wavelengths, rt))
    header: dict[str, Any] = {"compression": OpenEXR.ZIP_COMPRESSION,
                              "type": OpenEXR.scanlineimage}
    for k, v in attributes.items():
        header[k] = np.array([float(v)]) if isinstance(v, float) else str(v)
    with tempfile.TemporaryDirectory(dir=path.parent, prefix=".image-") as tmp:
        part = Path(tmp) / "out.exr"
        with OpenEXR.File(header, channels) as f:
            f.write(str(part))
        write_atomic(path, part.read_bytes())
