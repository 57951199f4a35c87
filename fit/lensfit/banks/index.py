"""The bank index that renderers read (``bank.index``; lensrt_bank_open in C).

A text file in the style of the coefficient tables: one key per line, numbers in C-locale
decimal (Python's ``repr`` of a float, which strtod reads back exactly), LF line ends and
a last line ``checksum crc32 <8 lowercase hex>`` over every byte before it::

    lensrt-bank 1
    lens <name>
    table_crc32 <hex>                  the coefficient table the nodes were rendered from
    width <pixels>
    height <pixels>
    pixel_mm <px> <py>
    registration channel|window        channel: each wavelength of a node in a window of its
                                       own, centred on its chief point; window: one window
    wavelengths_nm <n> <l_1> ... <l_n>
    f_numbers <n> ...
    focus_offsets_mm <n> ...
    distances_mm <n> ...               0 stands for infinity
    field_x_deg <n> ...
    field_y_deg <n> ...
    nodes <N>
    node <k> <i_f> <i_z> <i_d> <i_y> <i_x> <centre x mm> <centre y mm> <error> <crc32> <path>
    chief <k> <x_1> <y_1> ... <x_n> <y_n>     the chief ray's image point per wavelength (mm)
    ...
    checksum crc32 <hex>

Node k's window (``width`` x ``height`` pixels of ``pixel_mm``) is centred on the centre
given (with ``registration channel``, each channel's on its own chief point, the centre
being the middle wavelength's); its EXR is ``path`` (relative to the index) with the
CRC-32 of its bytes; ``error`` is the node's error estimate (relative L2; -1 when the
integrator gives none). The nodes come in the order of their indices (f-number slowest,
field x fastest).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Sequence
from typing import Any

from lensfit.banks.spec import BankSpec

FORMAT = "lensrt-bank 1"
INDEX_NAME = "bank.index"


def _num(v: float) -> str:
    if not math.isfinite(v):
        raise ValueError(f"bank index: {v!r} is not a finite number")
    return repr(float(v))


def _list(key: str, values: Sequence[float]) -> str:
    return " ".join([key, str(len(values)), *(_num(v) for v in values)])


def index_text(spec: BankSpec, lens_name: str, table_crc32: int,
               nodes: Sequence[dict[str, Any]]) -> str:
    """The index of a finished bank: ``nodes`` are the node records (node.py) in index
    order."""
    g, w = spec.grid, spec.window
    if len(nodes) != spec.n_nodes:
        raise ValueError(f"bank index: {len(nodes)} nodes for a grid of {spec.n_nodes}")
    lines = [FORMAT, f"lens {lens_name}", f"table_crc32 {table_crc32:08x}",
             f"width {w.pixels[0]}", f"height {w.pixels[1]}",
             f"pixel_mm {_num(w.pitch_mm[0])} {_num(w.pitch_mm[1])}",
             f"registration {'channel' if w.center_mm is None else 'window'}",
             _list("wavelengths_nm", g.wavelengths_nm), _list("f_numbers", g.f_numbers),
             _list("focus_offsets_mm", g.focus_offsets_mm),
             _list("distances_mm", [0.0 if math.isinf(v) else v for v in g.distances_mm]),
             _list("field_x_deg", g.field_x_deg), _list("field_y_deg", g.field_y_deg),
             f"nodes {len(nodes)}"]
    for k, n in enumerate(nodes):
        if n["k"] != k:
            raise ValueError(f"bank index: node {n['k']} where node {k} belongs")
        cx, cy = n["centre_mm"]
        lines.append(" ".join(["node", str(k), *(str(i) for i in n["indices"]), _num(cx),
                               _num(cy), _num(n["error_estimate"]), n["exr_crc32"],
                               n["exr"]]))
        lines.append(" ".join(["chief", str(k), *(_num(v) for xy in n["chief_mm"]
                                                   for v in xy)]))
    body = "\n".join(lines) + "\n"
    crc = zlib.crc32(body.encode("ascii")) & 0xFFFFFFFF
    return body + f"checksum crc32 {crc:08x}\n"
