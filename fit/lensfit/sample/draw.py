"""Cross-section drawings of a lens with ray fans (matplotlib, PNG).

The y-z section is drawn; an anamorphic lens gets a second panel with the x-z
section. Each panel shows two fans from a point at infinity: on axis (blue) and at an
off-axis field angle (orange). Rays stopped by a housing or the stop are drawn in red
up to the point where they are stopped, marked with a cross.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from lensfit.common.atomic import write_atomic  # noqa: E402
from lensfit.common.errors import InputError  # noqa: E402
from lensfit.paraxial import D_LINE_NM, paraxial, stop_radius_for_f_number  # noqa: E402
from lensfit.prescription.model import Lens  # noqa: E402
from lensfit.sample.domain import FULL_FRAME_HALF_DIAGONAL_MM, MAX_DEFAULT_FIELD_DEG  # noqa: E402
from lensfit.trace.tracer import Rays, Status, forward_path, trace  # noqa: E402

FAN_OVERFILL = 1.25  # fans span 125% of the entrance pupil so that clipping shows


def default_field_deg(lens: Lens) -> float:
    """Half the field of a 36 x 24 mm frame's diagonal (21.6 mm), at most 60 degrees (the
    fit's default field, :func:`lensfit.sample.default_domain`, along one meridian)."""
    efl = abs(paraxial(lens).efl_mm)
    if not math.isfinite(efl):
        return 10.0
    return min(MAX_DEFAULT_FIELD_DEG, math.degrees(math.atan(FULL_FRAME_HALF_DIAGONAL_MM / efl)))


def fan(
    lens: Lens, field_deg: float, n_rays: int, axis: int, stop_radius_mm: float | None = None
) -> Rays:
    """A meridional fan of parallel rays at ``field_deg`` in the ``axis`` (0: x, 1: y)
    section, aimed by real rays so that it spans the stop (125% of its radius).

    Paraxial pupils are wrong at wide fields (pupil aberration), so the launch heights
    are found by tracing a dense fan to the stop plane and interpolating."""
    stop_r = lens.stop_radius_max_mm if stop_radius_mm is None else stop_radius_mm
    th = math.radians(field_deg)
    direction = np.zeros(3)
    direction[axis] = math.sin(th)
    direction[2] = math.cos(th)
    # Launch plane just in front of the front surface; wide enough to cover any field
    sd0 = lens.surfaces[0].semi_diameter_mm
    z0 = min(0.0, float(np.nanmin(lens.surfaces[0].sag(*_xy(axis, np.linspace(-sd0, sd0, 101))))))
    z0 -= 0.1 * lens.sensor_z
    reach = 3.0 * max(s.semi_diameter_mm for s in lens.surfaces) + abs(z0) * abs(math.tan(th))
    h = np.linspace(-reach, reach, 4001)
    start = np.zeros((len(h), 3))
    start[:, axis] = h + z0 * math.tan(th)  # crosses z = 0 at height h
    start[:, 2] = z0
    probe = Rays(start, np.tile(direction, (len(h), 1)), D_LINE_NM)
    path = forward_path(lens)[: lens.stop_index + 1]
    at_stop = trace(lens, probe, path, clip=False)
    ok = at_stop.ok
    target = np.linspace(-FAN_OVERFILL, FAN_OVERFILL, n_rays) * stop_r
    if ok.sum() < 2:
        heights = np.linspace(-1.0, 1.0, n_rays) * sd0
    else:
        ys, hs = at_stop.pos[ok, axis], h[ok]
        # The branch through the stop centre: the run of monotonic samples around y = 0
        j = int(np.argmin(np.abs(ys)))
        sign = np.sign(np.gradient(ys)[j]) or 1.0
        mono = np.sign(np.diff(ys)) == sign
        lo = j
        while lo > 0 and mono[lo - 1]:
            lo -= 1
        hi = j
        while hi < len(mono) and mono[hi]:
            hi += 1
        seg_y, seg_h = ys[lo : hi + 1], hs[lo : hi + 1]
        order = np.argsort(seg_y)
        seg_y, seg_h = seg_y[order], seg_h[order]
        heights = np.interp(target, seg_y, seg_h)
        if len(seg_y) >= 2:
            # Beyond the rays that reach the stop plane, extend linearly from the ends
            lo_slope = (seg_h[1] - seg_h[0]) / (seg_y[1] - seg_y[0])
            hi_slope = (seg_h[-1] - seg_h[-2]) / (seg_y[-1] - seg_y[-2])
            below, above = target < seg_y[0], target > seg_y[-1]
            heights[below] = seg_h[0] + (target[below] - seg_y[0]) * lo_slope
            heights[above] = seg_h[-1] + (target[above] - seg_y[-1]) * hi_slope
    pts = np.zeros((len(heights), 3))
    pts[:, axis] = heights + z0 * math.tan(th)
    pts[:, 2] = z0
    return Rays(pts, np.tile(direction, (len(heights), 1)), D_LINE_NM)


def _xy(axis: int, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return (h, 0 * h) if axis == 0 else (0 * h, h)


def _draw_section(ax, lens: Lens, axis: int, field_deg: float, n_rays: int, stop_r: float) -> None:
    zv = lens.vertex_z
    prof = []
    for k, s in enumerate(lens.surfaces):
        h = np.linspace(-s.semi_diameter_mm, s.semi_diameter_mm, 201)
        z = zv[k] + s.sag(*_xy(axis, h))
        prof.append((z, h))
        if s.stop:
            # The iris blades from the stop's edge outwards, at the edge's z on the stop
            # surface (the plane, or the refracting surface the stop lies on)
            top = s.semi_diameter_mm * 1.15
            for sign in (1, -1):
                z_edge = zv[k] + float(np.nan_to_num(s.sag(*_xy(axis, np.array(
                    [sign * stop_r])))[0]))
                ax.plot([z_edge, z_edge], [sign * stop_r, sign * top], color="k", lw=2.5)
        else:
            ax.plot(z, h, color="k", lw=1)
    # Edges of glass elements: join the rims of the two surfaces bounding the glass
    for k, s in enumerate(lens.surfaces[:-1]):
        if s.medium.name != "air":
            (za, ha), (zb, hb) = prof[k], prof[k + 1]
            for j in (0, -1):
                rim = max(abs(ha[j]), abs(hb[j])) * np.sign(ha[j])
                ax.plot([za[j], za[j], zb[j], zb[j]], [ha[j], rim, rim, hb[j]], color="k", lw=1)
            zz = np.concatenate([za, zb[::-1]])
            hh = np.concatenate([ha, hb[::-1]])
            ax.fill(zz, hh, color="#cfe2f3", alpha=0.6, lw=0)
    ax.axhline(0, color="0.6", lw=0.5, ls="-.")
    ax.axvline(lens.sensor_z, color="k", lw=2)

    for field, color in ((0.0, "tab:blue"), (field_deg, "tab:orange")):
        rays = fan(lens, field, n_rays, axis, stop_radius_mm=stop_r)
        hist: list[np.ndarray] = [rays.pos.copy()]
        out = trace(lens, rays, stop_radius_mm=stop_r, history=hist)
        path = np.stack(hist)  # (steps + 1, N, 3)
        for i in range(len(rays)):
            ok = out.status[i] == Status.OK
            if ok:
                pts = path[:, i]
            else:
                last = int(out.surface[i]) + 1 if out.surface[i] >= 0 else len(path) - 1
                pts = path[: last + 1, i]
            ax.plot(
                pts[:, 2],
                pts[:, axis],
                color=color if ok else "tab:red",
                lw=0.6 if ok else 0.5,
                alpha=0.9 if ok else 0.7,
            )
            if out.status[i] == Status.CLIPPED:
                ax.plot(pts[-1, 2], pts[-1, axis], "x", color="tab:red", ms=4)
    # Frame the lens, not the far ends of the incoming rays
    rim = max(s.semi_diameter_mm for s in lens.surfaces) * 1.3
    ax.set_ylim(-rim, rim)
    ax.set_xlim(-0.12 * lens.sensor_z, lens.sensor_z * 1.03)
    ax.set_aspect("equal")
    ax.set_xlabel("z (mm)")
    ax.set_ylabel(f"{'xy'[axis]} (mm)")


def draw_lens(
    lens: Lens,
    output: str | Path,
    *,
    field_deg: float | None = None,
    rays: int = 11,
    f_number: float | None = None,
) -> Path:
    """Write the cross-section of ``lens`` with ray fans to ``output`` (PNG, atomic)."""
    if rays < 2:
        raise InputError(f"need at least 2 rays per fan, got {rays}")
    field = default_field_deg(lens) if field_deg is None else float(field_deg)
    if not -89.0 <= field <= 89.0:
        raise InputError(f"field angle must be within +-89 degrees, got {field}")
    stop_r = lens.stop_radius_max_mm
    if f_number is not None:
        stop_r = stop_radius_for_f_number(lens, f_number)
    axes = (1, 0) if lens.anamorphic else (1,)
    fig, axs = plt.subplots(len(axes), 1, figsize=(11, 4.2 * len(axes)), squeeze=False)
    for ax, axis in zip(axs[:, 0], axes, strict=True):
        _draw_section(ax, lens, axis, field, rays, stop_r)
        ax.set_title(
            f"{lens.name}: {'xy'[axis]}-z section, fans at 0 and {field:.1f} deg, "
            f"f/{paraxial(lens, stop_radius_mm=stop_r).f_number:.2f}",
            fontsize=9,
        )
    fig.tight_layout()
    out = Path(output)
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=130)
    finally:
        plt.close(fig)
    return write_atomic(out, buf.getvalue(), option="-o")
