"""lensrt's spectral EXR files in Python, read with the OpenEXR bindings (PyPI `openexr`,
pinned in fit/requirements.lock).

lensrt writes single-part scanline EXR files in the spectral layout of Fichet et al.
2021: one FLOAT channel per wavelength named ``S0.<lambda with a decimal comma>nm`` plus
an R, G, B preview. A layered file (``lensrt_layers_write_exr``, ``lensrt-psf --flares``)
keeps those unprefixed channels for the total and repeats the same set behind OpenEXR
layer prefixes: ``direct.S0.550,000000nm``, ``direct.R``, ``flare.S0.550,000000nm``, ...
This module groups the channels by layer and orders them by wavelength:

    from lensrt_exr import exr_layers, read_spectral_exr
    exr_layers("flare.exr")                     # ['', 'direct', 'flare']  ('' = unprefixed)
    img = read_spectral_exr("flare.exr")        # the unprefixed channels: the total
    flare = read_spectral_exr("flare.exr", layer="flare")
    flare.spectral[k]                           # (height, width) float32 at flare.wavelengths_nm[k]

A file OpenEXR cannot read, or a layer without spectral channels, is a ValueError
naming the file.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenEXR

# The spectral layout's emissive channel, Stokes component 0; the unit prefixes for metres
_SPECTRAL = re.compile(r"^S0\.(\d*,?\d*(?:[Ee][+-]?\d+)?)(p|n|u|m|c|d)?m$")
_TO_NM = {"p": 1e-3, "n": 1.0, "u": 1e3, "m": 1e6, "c": 1e7, "d": 1e8, None: 1e9}
_RGB = ("R", "G", "B")


@dataclass
class SpectralExr:
    """One layer of a spectral EXR ('' is the unprefixed image)."""

    path: Path
    layer: str
    wavelengths_nm: np.ndarray  # ascending
    spectral: np.ndarray  # (n_wavelengths, height, width) float32, in wavelength order
    rgb: np.ndarray | None  # (height, width, 3) float32, or None without an R, G, B preview
    channels: dict[float, str]  # wavelength (nm) -> channel name
    attributes: dict[str, object] = field(default_factory=dict)
    layers: list[str] = field(default_factory=list)  # every layer of the file


def _fail(path: Path, what: str) -> ValueError:
    return ValueError(f"EXR '{path}': {what}")


def _wavelength_nm(name: str) -> float | None:
    m = _SPECTRAL.match(name)
    if not m or not m.group(1).replace(",", ""):
        return None
    return float(m.group(1).replace(",", ".")) * _TO_NM[m.group(2)]


def spectral_channel_name(wavelength_nm: float) -> str:
    """lensrt's channel name of a wavelength, "S0.<nm>,<6 decimals>nm" (the inverse of
    the reading above)."""
    micro = math.floor(wavelength_nm * 1e6 + 0.5)
    return f"S0.{micro // 1000000},{micro % 1000000:06d}nm"


def write_node_exr(path: str | Path, planes: np.ndarray, wavelengths_nm, identity: str
                   ) -> None:
    """A bank node's EXR (lensrt.h, "PSF banks", registration channel): planes
    (n_wavelengths, height, width) as FLOAT channels named after the wavelengths, no
    compression, with the string attribute lensrt/bankNode ``identity``."""
    header = {"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage,
              "lensrt/bankNode": identity}
    channels = {spectral_channel_name(lam): np.ascontiguousarray(p, dtype=np.float32)
                for lam, p in zip(wavelengths_nm, planes, strict=True)}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


def _split_layer(name: str) -> tuple[str, str] | None:
    """(layer, channel) of a spectral or R, G, B channel of the unprefixed image ('')
    or of a one-level layer ("direct.S0.550,000000nm" -> ("direct", "S0.550,000000nm"));
    None for any other channel."""
    if _wavelength_nm(name) is not None or name in _RGB:
        return "", name
    layer, dot, rest = name.partition(".")
    if dot and layer and (_wavelength_nm(rest) is not None or rest in _RGB):
        return layer, rest
    return None


def _read(path: Path) -> tuple[dict[str, object], dict[str, np.ndarray]]:
    """The header and every channel's pixels; whatever OpenEXR raises for a file it cannot
    read becomes the ValueError naming the file."""
    if not path.is_file():
        raise _fail(path, "not found or not a regular file")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            header = dict(f.header())
            planes = {name: np.asarray(c.pixels) for name, c in f.channels().items()}
    except Exception as exc:  # the bindings raise RuntimeError and others
        raise _fail(path, f"OpenEXR cannot read it ({type(exc).__name__}: {exc})") from exc
    return header, planes


def _layers(names) -> list[str]:
    return sorted({s[0] for s in (_split_layer(n) for n in names) if s})


def exr_layers(path: str | Path) -> list[str]:
    """The layers of a spectral EXR: '' for the unprefixed channels, then the named ones."""
    return _layers(_read(Path(path))[1])


def read_spectral_exr(path: str | Path, layer: str = "") -> SpectralExr:
    """One layer of a spectral EXR (default '': the unprefixed channels, which lensrt's
    layered files use for the total). A layer without spectral channels is a ValueError
    naming the file, the layer and the layers there are."""
    path = Path(path)
    attributes, planes = _read(path)
    layers = _layers(planes)
    mine = {s[1]: n for n, s in ((n, _split_layer(n)) for n in planes) if s and s[0] == layer}
    spectral = {_wavelength_nm(c): full for c, full in mine.items() if c not in _RGB}
    if not spectral:
        shown = ", ".join(f"'{x}'" for x in layers) or "none"
        raise _fail(path, f"no spectral channels in layer '{layer}' "
                          f"(layers: {shown}; '' is unprefixed)")
    wavelengths = sorted(spectral)
    rgb = None
    if all(c in mine for c in _RGB):
        rgb = np.stack([planes[mine[c]] for c in _RGB], axis=-1).astype(np.float32)
    return SpectralExr(path=path, layer=layer, wavelengths_nm=np.array(wavelengths),
                       spectral=np.stack([planes[spectral[w]] for w in wavelengths]
                                         ).astype(np.float32),
                       rgb=rgb, channels={w: spectral[w] for w in wavelengths},
                       attributes=attributes, layers=layers)


def tone_map(rgb: np.ndarray, white: float, decades: float = 2.5) -> np.ndarray:
    """Linear sRGB (..., 3) to display values in [0, 1] (gamma 2.2): a log tone map of the
    luminance over ``decades`` below ``white``, the hue kept."""
    lum = 0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        level = np.clip(1.0 + np.log10(np.maximum(lum, 1e-300) / white) / decades, 0.0, 1.0)
        scale = np.where(lum > 0, level / np.maximum(lum / white, 1e-300), 0.0)
    out = np.clip(rgb / white * scale[..., None], 0.0, 1.0)
    return out ** (1 / 2.2)
