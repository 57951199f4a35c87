"""A small reader for lensrt's spectral EXR files, numpy only (no OpenEXR bindings).

lensrt writes single-part scanline EXR files (ZIP compression, FLOAT channels) in the
spectral layout of Fichet et al. 2021: one channel per wavelength named
``S0.<lambda with a decimal comma>nm`` plus an R, G, B preview. A layered file
(``lensrt_layers_write_exr``, ``lensrt-psf --flares``) keeps those unprefixed channels for
the total and repeats the same set behind OpenEXR layer prefixes: ``direct.S0.550,000000nm``,
``direct.R``, ``flare.S0.550,000000nm``, ...

    from lensrt_exr import exr_layers, read_spectral_exr
    exr_layers("flare.exr")                     # ['', 'direct', 'flare']  ('' = unprefixed)
    img = read_spectral_exr("flare.exr")        # the unprefixed channels: the total
    flare = read_spectral_exr("flare.exr", layer="flare")
    flare.spectral[k]                           # (height, width) float32 at flare.wavelengths_nm[k]

What it reads: the header (channel list, the attributes of the types lensrt writes:
string, int, float, double, v2d, box2i, compression, lineOrder, chromaticities), and
scanline chunks compressed with NONE, ZIPS or ZIP of FLOAT, HALF or UINT channels. Tiled,
deep and multi-part files and the other compressions are refused with a ValueError
naming the file, as is anything malformed: this is for lensrt's own files and tests, not a
general EXR library. Decoding follows the OpenEXR file layout document (magic, version
flags, attribute list, offset table, chunks) and its ZIP scheme (zlib, then a byte
predictor and the split of even and odd bytes undone).
"""

from __future__ import annotations

import re
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

MAGIC = 20000630
# Version-field flags (OpenEXR file layout): tiled, long names, deep, multi-part
_TILED, _LONG_NAMES, _DEEP, _MULTIPART = 0x200, 0x400, 0x800, 0x1000
_COMPRESSIONS = {0: ("NONE", 1), 2: ("ZIPS", 1), 3: ("ZIP", 16)}  # name, scanlines per chunk
# UINT, HALF, FLOAT: numpy type and bytes
_PIXEL = {0: (np.dtype("<u4"), 4), 1: (np.dtype("<f2"), 2), 2: (np.dtype("<f4"), 4)}
# The spectral layout's emissive channel, Stokes component 0; the unit prefixes for metres
_SPECTRAL = re.compile(r"^S0\.(\d*,?\d*(?:[Ee][+-]?\d+)?)(p|n|u|m|c|d)?m$")
_TO_NM = {"p": 1e-3, "n": 1.0, "u": 1e3, "m": 1e6, "c": 1e7, "d": 1e8, None: 1e9}
_RGB = ("R", "G", "B")
# What a damaged header may ask for: lensrt's largest window side (LENSRT_MAX_RESOLUTION),
# and 2^30 values (4 GiB of float32) in all
_MAX_SIDE, _MAX_VALUES = 65536, 1 << 30


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


class _Reader:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def take(self, n: int) -> bytes:
        if self.pos + n > len(self.data):
            raise _fail(self.path, f"ends at byte {len(self.data)}, "
                                   f"{n} more expected at {self.pos}")
        out = self.data[self.pos:self.pos + n]
        self.pos += n
        return out

    def cstring(self, limit: int) -> str:
        end = self.data.find(b"\0", self.pos, self.pos + limit + 1)
        if end < 0:
            raise _fail(self.path, f"a name at byte {self.pos} is not ended within {limit} bytes")
        out = self.data[self.pos:end].decode("latin-1")
        self.pos = end + 1
        return out


def _attribute(path: Path, name: str, kind: str, value: bytes) -> object:
    """An attribute's value for the types lensrt writes; other types as raw bytes."""
    try:
        if kind == "string":
            return value.decode("utf-8", "replace")
        if kind == "int":
            return struct.unpack("<i", value)[0]
        if kind == "float":
            return struct.unpack("<f", value)[0]
        if kind == "double":
            return struct.unpack("<d", value)[0]
        if kind == "v2d":
            return struct.unpack("<2d", value)
        if kind == "box2i":
            return struct.unpack("<4i", value)
        if kind in ("compression", "lineOrder"):
            return value[0]
        if kind == "chromaticities":
            return struct.unpack("<8f", value)
    except (struct.error, IndexError) as exc:
        raise _fail(path, f"attribute '{name}' of type {kind} has {len(value)} bytes"
                    ) from exc
    return value


def _read_header(r: _Reader) -> tuple[dict[str, object], list[tuple[str, int]]]:
    magic, version = struct.unpack("<ii", r.take(8))
    if magic != MAGIC:
        raise _fail(r.path, f"not an OpenEXR file (magic number {magic})")
    if version & 0xFF != 2 or version & (_TILED | _DEEP | _MULTIPART):
        raise _fail(r.path, f"version field {version:#x}: only single-part scanline images "
                            "are read")
    limit = 255 if version & _LONG_NAMES else 31
    attributes: dict[str, object] = {}
    channels: list[tuple[str, int]] = []
    while True:
        name = r.cstring(limit)
        if not name:
            break
        kind = r.cstring(limit)
        (size,) = struct.unpack("<i", r.take(4))
        if size < 0:
            raise _fail(r.path, f"attribute '{name}' has size {size}")
        value = r.take(size)
        if kind == "chlist":
            c = _Reader.__new__(_Reader)
            c.path, c.data, c.pos = r.path, value, 0
            while True:
                cname = c.cstring(limit)
                if not cname:
                    break
                ptype, _linear, xs, ys = struct.unpack("<iB3xii", c.take(16))
                if ptype not in _PIXEL or xs != 1 or ys != 1:
                    raise _fail(r.path, f"channel '{cname}': pixel type {ptype}, sampling "
                                        f"{xs} x {ys} (read: UINT, HALF, FLOAT at 1 x 1)")
                channels.append((cname, ptype))
        attributes[name] = _attribute(r.path, name, kind, value)
    for required in ("channels", "compression", "dataWindow"):
        if required not in attributes:
            raise _fail(r.path, f"no '{required}' attribute")
    window = attributes["dataWindow"]
    if not (isinstance(window, tuple) and len(window) == 4):
        raise _fail(r.path, f"dataWindow is not a box2i: {window!r}")
    if attributes["compression"] not in _COMPRESSIONS:
        raise _fail(r.path, f"compression {attributes['compression']} (read: NONE, ZIPS, ZIP)")
    return attributes, channels


def _unzip(raw: bytes, size: int, path: Path) -> bytes:
    """OpenEXR's ZIP: zlib, then the predictor (each byte is a difference to the one
    before, offset by 128) and the reordering (first half the even bytes, second half
    the odd ones) undone."""
    try:  # at most one byte more than expected: a damaged stream cannot inflate without end
        t = np.frombuffer(zlib.decompressobj().decompress(raw, size + 1), np.uint8).astype(np.int64)
    except zlib.error as exc:
        raise _fail(path, f"a ZIP chunk does not inflate: {exc}") from exc
    if t.size != size:
        raise _fail(path, f"a ZIP chunk inflates to {t.size} bytes, expected {size}")
    t[1:] -= 128
    t = np.cumsum(t) & 0xFF
    out = np.empty(size, np.uint8)
    half = (size + 1) // 2
    out[0::2] = t[:half]
    out[1::2] = t[half:]
    return out.tobytes()


def _read_planes(path: Path) -> tuple[dict[str, object], dict[str, np.ndarray]]:
    """Every channel as a (height, width) array (float32 for FLOAT and HALF)."""
    r = _Reader(path)
    attributes, channels = _read_header(r)
    x0, y0, x1, y1 = attributes["dataWindow"]
    width, height = x1 - x0 + 1, y1 - y0 + 1
    if not (0 < width <= _MAX_SIDE and 0 < height <= _MAX_SIDE):
        raise _fail(path, f"data window {attributes['dataWindow']} is empty or beyond "
                          f"{_MAX_SIDE} pixels a side")
    if width * height * len(channels) > _MAX_VALUES:
        raise _fail(path, f"{width} x {height} pixels of {len(channels)} channels is more than "
                          f"this reader holds ({_MAX_VALUES} values)")
    _, lines = _COMPRESSIONS[attributes["compression"]]
    n_chunks = -(-height // lines)
    offsets = struct.unpack(f"<{n_chunks}Q", r.take(8 * n_chunks))
    names = sorted(name for name, _ in channels)  # chunks hold channels in name order
    types = dict(channels)
    planes = {n: np.empty((height, width), _PIXEL[types[n]][0]) for n in names}
    line_bytes = width * sum(_PIXEL[types[n]][1] for n in names)
    for offset in offsets:
        r.pos = offset
        y, size = struct.unpack("<ii", r.take(8))
        if not y0 <= y <= y1 or (y - y0) % lines:
            raise _fail(path, f"chunk at byte {offset} starts at line {y}")
        rows = min(lines, y1 + 1 - y)
        raw = r.take(size)
        expected = rows * line_bytes
        # OpenEXR stores a chunk uncompressed when compression would not make it smaller
        data = raw if size == expected else _unzip(raw, expected, path)
        at = 0
        for row in range(y - y0, y - y0 + rows):
            for n in names:
                dtype, nbytes = _PIXEL[types[n]]
                planes[n][row] = np.frombuffer(data, dtype, width, at)
                at += nbytes * width
    out = {n: (p.astype(np.float32) if p.dtype.kind == "f" else p) for n, p in planes.items()}
    return attributes, out


def _guarded(path: Path, read):
    """read(), with whatever a damaged file makes numpy or struct raise turned into the
    ValueError naming the file that every refusal here is."""
    try:
        return read()
    except ValueError as exc:
        if str(path) in str(exc):
            raise
        raise _fail(path, f"malformed ({exc})") from exc
    except (struct.error, IndexError, KeyError, OverflowError, TypeError) as exc:
        raise _fail(path, f"malformed ({type(exc).__name__}: {exc})") from exc


def exr_layers(path: str | Path) -> list[str]:
    """The layers of a spectral EXR: '' for the unprefixed channels, then the named ones."""
    r = _Reader(Path(path))
    _, channels = _guarded(r.path, lambda: _read_header(r))
    found = {s[0] for s in (_split_layer(n) for n, _ in channels) if s}
    return sorted(found)


def read_spectral_exr(path: str | Path, layer: str = "") -> SpectralExr:
    """One layer of a spectral EXR (default '': the unprefixed channels, which lensrt's
    layered files use for the total). A layer without spectral channels is a ValueError
    naming the file, the layer and the layers there are."""
    path = Path(path)
    attributes, planes = _guarded(path, lambda: _read_planes(path))
    layers = sorted({s[0] for s in (_split_layer(n) for n in planes) if s})
    mine = {s[1]: n for n, s in ((n, _split_layer(n)) for n in planes) if s and s[0] == layer}
    spectral = {_wavelength_nm(c): full for c, full in mine.items() if c not in _RGB}
    if not spectral:
        shown = ", ".join(f"'{x}'" for x in layers) or "none"
        raise _fail(path, f"no spectral channels in layer '{layer}' "
                          f"(layers: {shown}; '' is unprefixed)")
    wavelengths = sorted(spectral)
    rgb = None
    if all(c in mine for c in _RGB):
        rgb = np.stack([planes[mine[c]] for c in _RGB], axis=-1)
    return SpectralExr(path=path, layer=layer, wavelengths_nm=np.array(wavelengths),
                       spectral=np.stack([planes[spectral[w]] for w in wavelengths]), rgb=rgb,
                       channels={w: spectral[w] for w in wavelengths}, attributes=attributes,
                       layers=layers)
