"""The PSF bank reader (lensrt_bank_open, lensrt_bank_psf; issue 23) through the ctypes
binding, against the closed form of a perfect lens.

The bank: the analytic thin lens (focal length 50 mm, sensor at 50 mm: every point light at
infinity is imaged as an Airy pattern), f/8, 3 x 3 field points (-2, 0, 2 deg in x and y),
3 wavelengths (450, 550, 650 nm), 48 x 48 pixels of pitch 450 nm x 8 / 6 = 0.6 um (6 pixels
per lambda N at the shortest wavelength). Each node is rendered by the cells integrator and
written reproducible; its window is centred a fraction of a pixel off its chief point (a
different fraction for each node, as on a renderer's sensor grid), so that the reader must
register every node by a sub-pixel shift. The index is written by this test's own minimal
writer (below).

I(r) = I0 (2 J1(x) / x)^2, x = pi r / (lambda N), is the paraxial PSF of a perfect lens.
"""

from __future__ import annotations

import math
import zlib
from pathlib import Path

import numpy as np
import pytest
from lensrt_ctypes import Bank, LensrtError, Result, write_exr_reproducible
from scipy.special import j1

FOCAL_MM = 50.0
F_NUMBER = 8.0
FIELDS_DEG = [-2.0, 0.0, 2.0]
WAVELENGTHS_NM = [450.0, 550.0, 650.0]
PIXELS = 48
PITCH_MM = WAVELENGTHS_NM[0] * 1e-6 * F_NUMBER / 6
# The cells integrator's target: 16 rings (0.4 s a node on 2 cores). Its estimate (about
# 1e-3) is far below the analytic lens's own distance from the paraxial Airy pattern
# (0.3% on the axis, 0.7% at the 2.8 deg corners: the O(NA^2) terms of the exact path
# lengths and the obliquity at f/8), which the tolerances below measure and include
CELLS_TARGET = 2e-3


# ------------------------------------------------------------------------------------
# A minimal bank index writer, for this test only (lensrt.h, "PSF banks", version 1);
# lensfit's own writer is lensfit.banks.index.
# ------------------------------------------------------------------------------------

def write_index(path: Path, nodes: list[dict], lens_name: str = "analytic-f50") -> None:
    def num(v: float) -> str:
        return repr(float(v))

    def grid(key: str, values: list[float]) -> str:
        return " ".join([key, str(len(values)), *(num(v) for v in values)])

    lines = ["lensrt-bank 1", f"lens {lens_name}", "table_crc32 00000000",
             f"width {PIXELS}", f"height {PIXELS}", f"pixel_mm {num(PITCH_MM)} {num(PITCH_MM)}",
             grid("wavelengths_nm", WAVELENGTHS_NM), grid("f_numbers", [F_NUMBER]),
             grid("focus_offsets_mm", [0.0]), grid("distances_mm", [0.0]),
             grid("field_x_deg", FIELDS_DEG), grid("field_y_deg", FIELDS_DEG),
             f"nodes {len(nodes)}"]
    for k, n in enumerate(nodes):
        lines.append(" ".join(["node", str(k), "0", "0", "0", str(n["iy"]), str(n["ix"]),
                               num(n["centre"][0]), num(n["centre"][1]), num(n["error"]),
                               f"{n['crc']:08x}", n["path"]]))
        lines.append(" ".join(["chief", str(k), *(num(v) for xy in n["chief"] for v in xy)]))
    body = "\n".join(lines) + "\n"
    path.write_text(body + f"checksum crc32 {zlib.crc32(body.encode()):08x}\n")


# ------------------------------------------------------------------------------------


def airy(r_mm: np.ndarray, wavelength_nm: float) -> np.ndarray:
    """(2 J1(x) / x)^2 at x = pi r / (lambda N) (1 at r = 0)."""
    x = np.pi * np.asarray(r_mm) / (wavelength_nm * 1e-6 * F_NUMBER)
    safe = np.where(x == 0.0, 1.0, x)
    return np.where(x == 0.0, 1.0, (2.0 * j1(safe) / safe) ** 2)


def radii(centre: tuple[float, float], chief: tuple[float, float]) -> np.ndarray:
    """Distances (mm) from each pixel centre of a window centred on `centre` (row 0 at +y)
    to `chief`."""
    offsets = (np.arange(PIXELS) + 0.5 - PIXELS / 2) * PITCH_MM
    x, y = np.meshgrid(centre[0] + offsets, centre[1] - offsets)
    return np.hypot(x - chief[0], y - chief[1])


def distance_to_airy(image: np.ndarray, shape: np.ndarray) -> tuple[float, float]:
    """The least-squares scale s of `shape` to `image` and the relative L2 distance of
    `image` from s * shape."""
    s = float(np.sum(image * shape) / np.sum(shape * shape))
    return s, float(np.linalg.norm(image - s * shape) / np.linalg.norm(s * shape))


def bilinear_shift(image: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """`image` read at (i + sx, j + sy) (|sx|, |sy| < 2 pixels) by bilinear interpolation
    between pixel centres, zero outside: what lensrt_bank_psf does to a node's channel
    whose chief point lies (sx, -sy) pixels from the node's centre (row 0 at +y)."""
    x0, y0 = math.floor(sx), math.floor(sy)
    fx, fy = sx - x0, sy - y0
    p = np.pad(image, 3)
    h, w = image.shape

    def tap(dx: int, dy: int) -> np.ndarray:
        return p[3 + y0 + dy:3 + y0 + dy + h, 3 + x0 + dx:3 + x0 + dx + w]

    return ((1 - fx) * (1 - fy) * tap(0, 0) + fx * (1 - fy) * tap(1, 0)
            + (1 - fx) * fy * tap(0, 1) + fx * fy * tap(1, 1))


@pytest.fixture(scope="module")
def bank(rt, tmp_path_factory) -> dict:
    if not hasattr(rt.lib, "lensrt_bank_open"):
        pytest.skip("this lensrt library predates PSF banks (0.5.0): rebuild it (`make runtime`)")
    folder = tmp_path_factory.mktemp("bank")
    (folder / "nodes").mkdir()
    lens = rt.analytic(focal_length_mm=FOCAL_MM, sensor_distance_mm=FOCAL_MM)
    nodes = []
    for iy, fy in enumerate(FIELDS_DEG):
        for ix, fx in enumerate(FIELDS_DEG):
            chief = [rt.image_point(lens, (fx, fy), wl) for wl in WAVELENGTHS_NM]
            # The window off the chief point at 550 nm by a fraction of a pixel, a
            # different one for each node (-0.44 .. 0.44 pixels in x and y)
            k = len(nodes)
            off = (((3 * k) % 8 + 0.5) / 8 - 0.5, ((5 * k + 2) % 8 + 0.5) / 8 - 0.5)
            centre = (chief[1][0] + off[0] * PITCH_MM, chief[1][1] + off[1] * PITCH_MM)
            r = rt.create(lens, width=PIXELS, height=PIXELS, width_mm=PIXELS * PITCH_MM,
                          center=centre, f_number=F_NUMBER, lights=[(fx, fy)],
                          wavelengths=WAVELENGTHS_NM)
            _, error = r.integrate_to(CELLS_TARGET)
            name = f"nodes/f8-z0-d0-y{iy}-x{ix}.exr"
            write_exr_reproducible(r, folder / name)
            nodes.append({"ix": ix, "iy": iy, "fx": fx, "fy": fy, "chief": chief,
                          "centre": centre, "error": error, "path": name, "image": r.image(),
                          "crc": zlib.crc32((folder / name).read_bytes())})
    write_index(folder / "bank.index", nodes)
    b = Bank(rt, folder / "bank.index")
    yield {"bank": b, "nodes": nodes, "folder": folder, "lens": lens,
           "model_error": node_model_error(nodes)}
    b.close()


def node_model_error(nodes: list[dict]) -> float:
    """The worst relative L2 distance of a node's channel from the Airy pattern on its
    chief point (the analytic lens against the paraxial closed form, plus the cells
    error), over every node and wavelength."""
    worst = 0.0
    for n in nodes:
        for w, wl in enumerate(WAVELENGTHS_NM):
            shape = airy(radii(n["centre"], n["chief"][w]), wl)
            worst = max(worst, distance_to_airy(n["image"][w], shape)[1])
    return worst


def terms(nodes: list[dict], field: tuple[float, float], wavelength_nm: float
          ) -> list[tuple[float, dict, int]]:
    """The (weight, node, channel) terms lensrt_bank_psf blends: the Lagrange polynomial in
    tan(field) through the 3 nodes of each axis (lensrt.h: up to 4 per axis), linear between
    the two channels around the wavelength (zero weights left out)."""
    def lagrange(values: list[float], q: float) -> list[float]:
        t = [math.tan(math.radians(v)) for v in values]
        tq = math.tan(math.radians(q))
        return [math.prod((tq - t[c]) / (t[a] - t[c]) for c in range(len(t)) if c != a)
                for a in range(len(t))]

    iw = min(int(np.searchsorted(WAVELENGTHS_NM, wavelength_nm, side="right")) - 1,
             len(WAVELENGTHS_NM) - 2)
    tw = (wavelength_nm - WAVELENGTHS_NM[iw]) / (WAVELENGTHS_NM[iw + 1] - WAVELENGTHS_NM[iw])
    wx, wy = lagrange(FIELDS_DEG, field[0]), lagrange(FIELDS_DEG, field[1])
    out = []
    for y, x, dw in np.ndindex(3, 3, 2):
        w = wy[y] * wx[x] * (tw if dw else 1 - tw)
        if w:
            out.append((w, nodes[y * 3 + x], iw + dw))
    return out


def registration_error(node: dict, channel: int) -> float:
    """The relative L2 error of bilinear registration at this pitch for one node channel:
    the Airy pattern sampled on the node's grid, shifted by the taps onto its chief point,
    against the pattern sampled on its chief point. About h^2 / 8 |I''| at the peak for a
    half-pixel shift, |I''(0)| = I0 (pi / (lambda N))^2 / 2: 1.7% of the peak at 450 nm
    and a pitch of lambda N / 6, less for smaller shifts and in L2."""
    wl, chief = WAVELENGTHS_NM[channel], node["chief"][channel]
    sampled = airy(radii(node["centre"], chief), wl)
    sx = (chief[0] - node["centre"][0]) / PITCH_MM
    sy = -(chief[1] - node["centre"][1]) / PITCH_MM
    exact = airy(radii(chief, chief), wl)
    return float(np.linalg.norm(bilinear_shift(sampled, sx, sy) - exact) / np.linalg.norm(exact))


def test_info(bank) -> None:
    info = bank["bank"].info()
    assert info["lens_name"] == "analytic-f50"
    assert (info["width"], info["height"]) == (PIXELS, PIXELS)
    assert info["pixel_x_mm"] == PITCH_MM and info["pixel_y_mm"] == PITCH_MM
    assert info["wavelengths_nm"] == WAVELENGTHS_NM
    assert info["field_x_deg"] == FIELDS_DEG and info["field_y_deg"] == FIELDS_DEG
    assert info["f_numbers"] == [F_NUMBER]
    assert info["n_nodes"] == 9
    assert info["worst_error_estimate"] == max(n["error"] for n in bank["nodes"])


def test_psf_at_a_node_is_the_node_registered(bank) -> None:
    """At a node and one of its wavelengths the PSF is the node's channel read at its
    chief point (the corner node: its window is off its chief point by a fraction of a
    pixel), to float rounding."""
    n = bank["nodes"][8]
    for w, wl in enumerate(WAVELENGTHS_NM):
        psf, chief = bank["bank"].psf(n["fx"], n["fy"], wl, f_number=F_NUMBER)
        assert chief == pytest.approx(n["chief"][w], abs=1e-15)
        sx = (n["chief"][w][0] - n["centre"][0]) / PITCH_MM
        sy = -(n["chief"][w][1] - n["centre"][1]) / PITCH_MM
        assert 0.01 < max(abs(sx), abs(sy)) <= 0.5
        want = bilinear_shift(n["image"][w], sx, sy)
        np.testing.assert_allclose(psf, want, rtol=1e-5, atol=1e-6 * float(want.max()))


@pytest.mark.parametrize("field", [(1.0, -1.0), (-0.5, 1.5), (1.7, 0.3)])
def test_psf_between_nodes_is_airy(bank, field) -> None:
    """Between field nodes, at 550 nm, the PSF is the Airy pattern on the returned centre.

    The PSF is sum_n w_n R_n(node_n), R_n the bilinear registration of node n (a convex
    combination of 4 pixels per output pixel, so ||R_n(x)|| <= ||x||). With A the Airy
    pattern on the centre and A_n on node n's chief point, ||R_n(node_n) - A|| <=
    ||node_n - A_n|| + ||R_n(A_n) - A||: the node's distance from the closed form
    (node_model_error, measured on every node: the analytic lens's O(NA^2) terms and the
    cells estimate) plus the resampling error at this pitch (registration_error, computed on
    the closed form, for each node's own shift), each times |w_n| (the weights sum to 1; the
    polynomial's are partly negative). 20% more covers the
    fitted scales."""
    fx, fy = field
    psf, chief = bank["bank"].psf(fx, fy, 550.0)
    blend = terms(bank["nodes"], field, 550.0)
    # The centre: the nodes' chief points interpolated in tan(field), which for this lens
    # without distortion (its image point is f tan(field)) is the lens's own image point,
    # to the rounding of the polynomial's weights (1e-12 mm is 1e-9 of a pixel)
    true = bank["bank"].rt.image_point(bank["lens"], field, 550.0)
    assert chief == pytest.approx(true, abs=1e-12)
    # The shape: the Airy pattern on the returned centre
    scale, err = distance_to_airy(psf, airy(radii(chief, chief), 550.0))
    tol = 1.2 * sum(abs(w) * (bank["model_error"] + registration_error(n, c))
                    for w, n, c in blend)
    assert err <= tol, f"PSF at {field} deg: {err:.4f} from the Airy pattern (tolerance {tol:.4f})"
    # The scale: the closed form's peak (stop area / (lambda z))^2 within the obliquity and
    # NA^2 terms of the exact lens (1% at 2.8 deg), less the resampling's smoothing
    peak = (math.pi * (FOCAL_MM / (2 * F_NUMBER)) ** 2 / (550e-6 * FOCAL_MM)) ** 2
    assert scale == pytest.approx(peak, rel=0.01 + tol)


def test_psf_between_wavelengths(bank) -> None:
    """At 500 nm, between the 450 and 550 nm channels, the PSF is their linear blend,
    each registered on its chief point. The Airy pattern's scale grows with lambda, so the
    blend differs from Airy(500 nm) by about (d lambda)^2 / 8 |d^2 I / d lambda^2|, i.e.
    O((d lambda / lambda)^2) = 4% x a constant below 1 with d lambda = 100 nm (the exact
    figure, blend_error, 2.8%, is measured on the closed form itself); the node and
    registration errors add as in test_psf_between_nodes_is_airy."""
    nodes = bank["nodes"]
    n = nodes[4]
    psf, chief = bank["bank"].psf(n["fx"], n["fy"], 500.0)
    assert chief == pytest.approx(tuple(0.5 * (np.array(n["chief"][0]) + np.array(n["chief"][1]))),
                                  abs=1e-12)
    r = radii(chief, chief)
    blend = terms(nodes, (n["fx"], n["fy"]), 500.0)
    registration = sum(w * registration_error(m, c) for w, m, c in blend)
    # The closed form's blend: Airy at 450 and 550 nm with their absolute peaks (1 / lambda^2)
    closed = sum(w * airy(r, WAVELENGTHS_NM[c]) / WAVELENGTHS_NM[c] ** 2 for w, _, c in blend)
    _, blend_error = distance_to_airy(closed, airy(r, 500.0))
    assert 1e-3 < blend_error < 0.05  # second order in 100 / 500: present, and small
    # The PSF is that blend (node and registration errors) ...
    _, err = distance_to_airy(psf, closed)
    tol = 1.2 * (bank["model_error"] + registration)
    assert err <= tol, f"PSF at 500 nm: {err:.4f} from the Airy blend (tolerance {tol:.4f})"
    # ... and so within the blend's error of the Airy pattern at 500 nm
    _, err = distance_to_airy(psf, airy(r, 500.0))
    tol = 1.2 * (blend_error + bank["model_error"] + registration)
    assert err <= tol, f"PSF at 500 nm: {err:.4f} from Airy (tolerance {tol:.4f})"


def test_queries_outside_the_bank(bank) -> None:
    b = bank["bank"]
    with pytest.raises(LensrtError, match=r"field_x_deg 2\.5 is outside the bank's range \[-2, 2\]"
                       ) as e:
        b.psf(2.5, 0.0, 550.0)
    assert e.value.code == Result.OUT_OF_DOMAIN
    with pytest.raises(LensrtError, match=r"wavelength_nm 700 is outside") as e:
        b.psf(0.0, 0.0, 700.0)
    assert e.value.code == Result.OUT_OF_DOMAIN
    with pytest.raises(LensrtError, match=r"f_number 2 is not one of the bank's: 8") as e:
        b.psf(0.0, 0.0, 550.0, f_number=2.0)
    assert e.value.code == Result.OUT_OF_DOMAIN
    with pytest.raises(LensrtError, match=r"distance_mm 1000 is not one of the bank's: 0"):
        b.psf(0.0, 0.0, 550.0, distance_mm=1000.0)


def test_reproducible_exr_and_damaged_bank(rt, bank, tmp_path) -> None:
    """The same render written reproducible twice gives the same bytes; an index naming a
    node EXR with a flipped byte is refused with a message naming that EXR."""
    lens = bank["lens"]
    paths = []
    for k in range(2):
        r = rt.create(lens, width=8, height=8, width_mm=8 * PITCH_MM, f_number=F_NUMBER,
                      wavelengths=[550.0])
        r.integrate(4)
        paths.append(tmp_path / f"r{k}.exr")
        write_exr_reproducible(r, paths[-1])
    assert paths[0].read_bytes() == paths[1].read_bytes()
    assert b"lensrt/seconds" not in paths[0].read_bytes()
    # A copy of the bank whose node 0 has a flipped byte
    src = bank["folder"]
    (tmp_path / "nodes").mkdir()
    for n in bank["nodes"]:
        (tmp_path / n["path"]).write_bytes((src / n["path"]).read_bytes())
    first = tmp_path / bank["nodes"][0]["path"]
    data = bytearray(first.read_bytes())
    data[len(data) // 2] ^= 0x04
    first.write_bytes(bytes(data))
    write_index(tmp_path / "bank.index", bank["nodes"])
    # Opened (a node is read when first needed), refused when loaded or first queried
    damaged = Bank(rt, tmp_path / "bank.index")
    with pytest.raises(LensrtError, match=r"f8-z0-d0-y0-x0\.exr: node 0 .*changed or damaged") as e:
        damaged.load_nodes()
    assert e.value.code == Result.PARSE
    with pytest.raises(LensrtError, match=r"node 0 .*changed or damaged"):
        damaged.psf(FIELDS_DEG[0], FIELDS_DEG[0], 550.0)
    # ... every time: a node that failed is not kept
    with pytest.raises(LensrtError, match=r"node 0 .*changed or damaged"):
        damaged.psf(FIELDS_DEG[0], FIELDS_DEG[0], 550.0)
    damaged.psf(FIELDS_DEG[2], FIELDS_DEG[2], 550.0)  # the other nodes serve
    damaged.close()
