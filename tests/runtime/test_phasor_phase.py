"""The phase reference of saved phasor sums, as lensrt.h documents it above
lensrt_render_save (issue 40): for a fitted lens, each grid point's sum carries
exp(+i 2 pi (phi_o(a) + phi_i(a, s) - phi_i(0, s)) / lambda), the rear group's
stop-centre path to that point subtracted; for an analytic lens, the whole free-space
path. Checked by reading a saved file's sums and comparing their phases with quadratures
of the integrand from lensrt_lens_eval. A few seconds.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
LENS0001 = ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table"
HEADER = 96  # io/phasor_file.c's file_header


def read_sums(path: Path) -> np.ndarray:
    """The sums of a phasor file as complex (lights, wavelengths, height, width)."""
    b = path.read_bytes()
    w, h, n_wl, n_l, has_sq, n_runs = struct.unpack_from("<6i", b, 64)
    n = w * h * n_wl * n_l
    off = HEADER + 24 * n_runs
    assert len(b) == off + 16 * n + (8 * n if has_sq else 0)
    s = np.frombuffer(b, dtype="<f8", count=2 * n, offset=off)
    return (s[0::2] + 1j * s[1::2]).reshape(n_l, n_wl, h, w)


def wrap(x: np.ndarray) -> np.ndarray:
    return (x + np.pi) % (2 * np.pi) - np.pi


def disc(radius: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    g = ((np.arange(n) + 0.5) / n * 2 - 1) * radius
    x, y = np.meshgrid(g, g)
    k = x * x + y * y <= radius * radius
    return x[k], y[k]


def test_fitted_sums_are_referenced_to_the_stop_centre_path(rt1, tmp_path: Path) -> None:
    lens = rt1.load(LENS0001)
    lam, n_px, pitch = 550.0, 5, 0.003
    r = rt1.create(lens, width=n_px, height=n_px, width_mm=n_px * pitch, f_number=8.0,
                   wavelengths=[lam], pixel_filter="point", precision="double", seed=1)
    r.run(1 << 14)
    r.save(tmp_path / "s.phasors")
    sums = read_sums(tmp_path / "s.phasors")[0, 0]
    ax, ay = disc(r.stats().stop_radius_mm, 101)
    ones = np.ones_like(ax)
    po = rt1.eval(lens, "P_o", np.column_stack([0 * ax, 0 * ax, 0 * ax, ax, ay, lam * ones]))
    lam_mm = lam * 1e-6
    xs = (np.arange(n_px) + 0.5 - n_px / 2) * pitch
    ys = (n_px / 2 - np.arange(n_px) - 0.5) * pitch  # row 0 at the top
    ref, absolute = [], []
    for j in range(n_px):
        for i in range(n_px):
            ps = rt1.eval(lens, "P_s", np.column_stack([xs[i] * ones, ys[j] * ones, 0 * ax, ax,
                                                        ay, lam * ones]))
            ps0 = rt1.eval(lens, "P_s", np.array([[xs[i], ys[j], 0.0, 0.0, 0.0, lam]]))[0]
            amp = np.sqrt(np.clip(po[:, 2], 0, None) * np.clip(ps[:, 2], 0, None))
            path = po[:, 3] + ps[:, 3]
            u_ref = np.sum(amp * np.exp(2j * np.pi * (path - ps0[3]) / lam_mm))
            u_abs = np.sum(amp * np.exp(2j * np.pi * path / lam_mm))
            ref.append(wrap(np.angle(sums[j, i]) - np.angle(u_ref)))
            absolute.append(wrap(np.angle(sums[j, i]) - np.angle(u_abs)))
    # Measured 1.2 mrad at 2^15 samples on 9 x 9 pixels; without the reference, radians
    assert np.max(np.abs(ref)) < 0.02, ref
    assert np.max(np.abs(absolute)) > 0.3, absolute


def test_analytic_sums_carry_the_whole_path(rt1, tmp_path: Path) -> None:
    # A perfect lens (f = 50 mm, f/8), light on the axis at infinity, sensor 2 um behind
    # focus: the sum at the image point has the phase of k (|s - a| - |I - a|)
    lam, f, dz = 550.0, 50.0, 0.002
    lens = rt1.analytic(sensor_distance_mm=f, focal_length_mm=f)
    r = rt1.create(lens, width=3, height=3, width_mm=0.003, f_number=8.0, wavelengths=[lam],
                   pixel_filter="point", focus_offset_mm=dz, seed=1)
    r.run(1 << 14)
    r.save(tmp_path / "a.phasors")
    got = np.angle(read_sums(tmp_path / "a.phasors")[0, 0, 1, 1])
    ax, ay = disc(f / 16, 301)
    z = f + dz
    path = np.sqrt(ax**2 + ay**2 + z * z) - np.sqrt(ax**2 + ay**2 + f * f)
    want = np.angle(np.sum(np.exp(2j * np.pi * path / (lam * 1e-6)) * z / (ax**2 + ay**2 + z * z)))
    assert abs(wrap(got - want)) < 0.01, (got, want)
    assert abs(want) > 1.0  # 2 um of defocus: far from zero, so the test can tell
