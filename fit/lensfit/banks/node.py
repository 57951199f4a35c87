"""One node of a bank: the task a Dask worker (or the driver itself) runs.

A node is one light (field point and distance), one f-number and one focus offset, every
wavelength of the bank, rendered by lensrt through its Python binding into a window
centred on the chief ray's image point. What it leaves, in this order:

1. ``nodes/<stem>.exr``: the spectral EXR (lensrt writes it atomically, without timings,
   so the same node gives the same bytes on any worker);
2. ``nodes/<stem>.json``: its record (checked JSON, written atomically): the lens and its
   table's CRC-32, the spec's digest, the lensrt version that rendered it, the node's
   coordinates, how it was integrated, the error estimate, seconds (wall) and
   cpu_seconds (the render's CPU time), and the EXR's CRC-32.

The record comes last: a node is finished when its record exists, matches the spec, the
table and the loaded lensrt's version, and its EXR has the CRC-32 the record gives. A
Monte Carlo node also saves its phasor sums (``nodes/<stem>.phasors``, lensrt's own
atomic save) at each checkpoint, and a rerun resumes from them (the sums add, so the
finished node is the same bytes).
"""

from __future__ import annotations

import math
import os
import re
import threading
import time
import zlib
from pathlib import Path
from typing import Any

from lensfit.codegen.checked_json import checked_json_text, load_checked_json
from lensfit.common.atomic import write_atomic
from lensfit.common.errors import InputError

RECORD_VERSION = 2  # 2: each channel on its own chief point (lensrt 0.9.0)

# A fixed window (window.center_mm) that holds essentially none of a node's PSF is
# refused (issue 39): lensrt-psf exits 4 for an image that is zero everywhere, but the
# cells integrator resolves a PSF's far tail, so a window millimetres from the light's
# image renders values ten orders below the peak and nothing says so. Measured on lens
# 0001 (a 0.06 mm window of 24 x 24 pixels, 500 and 600 nm): the window centred on the
# image point holds 222 (f/8) and 2493 (f/2) in lensrt's power unit; moved 0.2 mm away, 7e-5
# and 2.4e-5 of that (the Airy halo: kept); 1 mm away, 1.6e-7 and 1.4e-8; 5 mm away,
# 2.4e-10 (8 rings; 4e-9 at 128). A window 0.5 mm from the centre of a blur of radius
# 0.25 mm (f/2, the sensor 1 mm behind focus) holds 4.5e-5 of the centred one's. Below
# MISS_FRACTION of the centred window's power a node is refused: a thousand times below
# the faintest window kept above and 2.5 orders above the far tails.
MISS_FRACTION = 1e-6
# A flare bank's window is meant for the ghosts (0001's visible ghosts hold 1e-6 to 1e-3
# of the direct image's power; 0-2 at f/8 1.1e-4): its node is refused when the direct
# image holds below MISS_FRACTION and the ghosts together below this share of the direct
# image's centred power (a thousandth of the faintest ghost worth fitting)
MISS_FRACTION_GHOSTS = 1e-9
# The centred window (and the run's up-front pilot) by the cells integrator at this many
# rings, no refinement: 0.3% on the centred window at f/8 (its estimate), and what
# decides is a ratio of six orders
PILOT_RINGS = 8

# Each worker thread keeps one lensrt context per (library, threads) and the tables it
# loaded into that context per (table, CRC-32): a task reuses what the previous task of
# the same bank loaded in its thread. Per thread, not per process: a Dask worker runs
# tasks in several threads of one process, and a context serves one thread at a time
# (lensrt.h). Dicts shared by the threads and filled check-then-set gave two threads one
# context, and a context that lost the race freed lenses the cache still held (issue 37:
# 28 of 30 nodes failed, a lens named "(null)")
_THREAD = threading.local()


def _cache(name: str) -> dict[Any, Any]:
    """This thread's cache ``name`` (made empty on the thread's first use)."""
    cache = getattr(_THREAD, name, None)
    if cache is None:
        cache = {}
        setattr(_THREAD, name, cache)
    return cache


def file_crc32(path: str | os.PathLike[str]) -> int:
    crc = 0
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            crc = zlib.crc32(chunk, crc)
    return crc & 0xFFFFFFFF


def stem(indices: tuple[int, ...]) -> str:
    f, z, d, y, x = indices
    return f"nodes/f{f}-z{z}-d{d}-y{y}-x{x}"


def node_coordinates(spec: dict[str, Any], indices: tuple[int, ...]) -> dict[str, float]:
    g = spec["grid"]
    f, z, d, y, x = indices
    dist = g["distances_mm"][d]
    return {"f_number": g["f_numbers"][f], "focus_offset_mm": g["focus_offsets_mm"][z],
            "distance_mm": math.inf if dist == "inf" else dist,
            "field_y_deg": g["field_y_deg"][y], "field_x_deg": g["field_x_deg"][x]}


def refuse_special(path: Path) -> None:
    """A node's file that is there but not a regular file (a FIFO, a device, a socket, a
    folder, a link) is refused naming it: lensfit never opens one for reading (a FIFO
    would block the run) and never replaces one."""
    from lensfit.common.atomic import target_refusal

    why = target_refusal(path)
    if why is not None:
        raise InputError(f"{path} {why}; a bank's nodes/ holds only its own files: remove "
                         "it or give another folder")


def finished_record(job: dict[str, Any]) -> dict[str, Any] | None:
    """The node's record when the node is finished for this job (spec, table, EXR bytes);
    None when it must be rendered. A node path that is not a regular file is refused
    (:func:`refuse_special`)."""
    out = Path(job["out"])
    record, exr = out / f"{job['stem']}.json", out / f"{job['stem']}.exr"
    for p in (record, exr, out / f"{job['stem']}.phasors",
              *(out / f"{job['stem']}.ghost-{g['label']}.phasors"
                for g in job.get("ghosts", []))):
        refuse_special(p)
    if not record.exists():
        return None
    try:
        doc = load_checked_json(record, "render the node again")
    except InputError:
        return None  # damaged or foreign: rendered again, then replaced
    if (doc.get("version") != RECORD_VERSION or doc.get("spec_digest") != job["digest"]
            or doc.get("lensrt_version") != job.get("lensrt_version", "")
            or doc.get("table_crc32") != f"{job['table_crc32']:08x}"
            or doc.get("k") != job["k"]
            or [g["table_crc32"] for g in doc.get("ghosts", [])]
            != [f"{g['table_crc32']:08x}" for g in job.get("ghosts", [])]):
        return None
    try:
        if f"{file_crc32(exr):08x}" != doc.get("exr_crc32"):
            return None
    except OSError:
        return None
    return doc


def task_key(job: dict[str, Any]) -> str:
    """The node's Dask key: its bank's spec digest and folder, and its stem. Two banks of
    one spec in two folders on one scheduler are two tasks (a key of the digest alone
    gave the second bank the first's results, and its folder no nodes)."""
    import hashlib

    where = hashlib.sha256(f"{job['digest']}\0{job['out']}".encode()).hexdigest()[:16]
    return f"bank-{where}-{job['stem'].split('/')[-1]}"


def _load(rt, threads: int, library: str, table: str, crc: int):
    """A lens table loaded once per worker process, refused when it is not the table the
    bank was planned with (never mix two tables)."""
    key = (library, threads, table, crc)
    lenses = _cache("lenses")
    if key not in lenses:
        now = file_crc32(table)
        if now != crc:
            raise InputError(f"{table}: the table changed since the bank was planned "
                             f"(CRC-32 {now:08x}, planned {crc:08x}); run the bank again")
        lenses[key] = rt.load(table)
    return lenses[key]


def worker_library(job: dict[str, Any]) -> str:
    """The lensrt library this worker loads: its own $LENSRT_LIBRARY where it sets one
    (a worker on another machine, another build), else the driver's (the job's) where
    that path exists here, else the binding's default. A node rendered by another lensrt
    version records it, and is rendered again by a run of the driver's version."""
    own = os.environ.get("LENSRT_LIBRARY")
    if own:
        return own
    if os.path.exists(job["library"]):
        return job["library"]
    from lensrt_ctypes import LIBRARY

    return str(LIBRARY)


def _context(job: dict[str, Any]):
    from lensrt_ctypes import Lensrt

    key = (worker_library(job), int(job["spec"]["render"]["threads"]))
    contexts = _cache("contexts")
    if key not in contexts:
        contexts[key] = Lensrt(key[0], threads=key[1])
    return contexts[key], key[1]


def node_light(c: dict[str, float]) -> tuple[float, float, float, float]:
    """The unit light of a node's (or any field point's) coordinates (0: infinity)."""
    dist = 0.0 if math.isinf(c["distance_mm"]) else c["distance_mm"]
    return (c["field_x_deg"], c["field_y_deg"], dist, 1.0)


def create_render(rt, lens, spec: dict[str, Any], c: dict[str, float],
                  wavelengths: list[float], centre: tuple[float, float]):
    """A render of the spec's window, aperture and seed for the light at coordinates
    ``c`` at these wavelengths, its window centred on ``centre`` (mm)."""
    w, a = spec["window"], spec["aperture"]
    return rt.create(lens, width=w["pixels"][0], height=w["pixels"][1],
                     width_mm=w["size_mm"][0], height_mm=w["size_mm"][1], center=centre,
                     focus_offset_mm=c["focus_offset_mm"], f_number=c["f_number"],
                     shape=a["shape"], blades=a["blades"], blade_curvature=a["blade_curvature"],
                     rotation_deg=a["rotation_deg"], lights=[node_light(c)],
                     wavelengths=wavelengths, seed=spec["render"]["seed"])


def window_holds(window: dict[str, Any], chief: list[tuple[float, float]]) -> bool:
    """Whether the window (size_mm around center_mm) holds any of the chief points."""
    (cx, cy), (w, h) = window["center_mm"], window["size_mm"]
    return any(abs(x - cx) <= w / 2 and abs(y - cy) <= h / 2 for x, y in chief)


def centred_power(rt, lens, spec: dict[str, Any], c: dict[str, float],
                  wavelengths: list[float], chief: list[tuple[float, float]]) -> float:
    """The power (summed over wavelengths) of the node's direct image in a window of the
    spec's size centred on its middle chief point, at PILOT_RINGS: a lower bound on what
    a window on the PSF holds."""
    import numpy as np

    r = create_render(rt, lens, spec, c, wavelengths, tuple(chief[len(chief) // 2]))
    r.integrate(PILOT_RINGS, estimate=False)
    return float(r.image().astype(np.float64).sum())


def window_miss(spec: dict[str, Any], c: dict[str, float], chief: list[tuple[float, float]],
                direct: float, ghosts: float | None, centred: float, node: str) -> str | None:
    """Why a fixed window holds essentially none of a node's PSF (``direct`` and
    ``ghosts``, the summed images in the window; ghosts None: no flare), or None."""
    if centred <= 0 or direct >= MISS_FRACTION * centred or (
            ghosts is not None and ghosts >= MISS_FRACTION_GHOSTS * centred):
        return None
    w = spec["window"]
    (cx, cy), (ww, wh) = w["center_mm"], w["size_mm"]
    px, py = chief[len(chief) // 2]
    gap = math.hypot(max(0.0, abs(px - cx) - ww / 2), max(0.0, abs(py - cy) - wh / 2))
    dist = "" if math.isinf(c["distance_mm"]) else f", distance {c['distance_mm']:g} mm"
    what = (f"{direct / centred:.1e} of the direct image's power and the ghosts "
            f"{(ghosts or 0.0) / centred:.1e} of it" if ghosts is not None
            else f"{direct / centred:.1e} of the PSF's power")
    return (f"node {node} (field ({c['field_x_deg']:g}, {c['field_y_deg']:g}) deg, "
            f"f/{c['f_number']:g}, focus offset {c['focus_offset_mm']:g} mm{dist}): the "
            f"window of {ww:g} x {wh:g} mm centred on ({cx:g}, {cy:g}) mm holds {what} (the "
            f"light's image is at ({px:.4g}, {py:.4g}) mm, {gap:.3g} mm from the window); "
            "nothing written: move window.center_mm onto the image, widen window.size_mm, "
            "or drop center_mm so that each node's window is centred on its chief ray")


def _integrate(r, r_spec: dict[str, Any], phasors: Path) -> dict[str, Any]:
    """One render by the spec's integrator: how, and its error estimate (-1: none)."""
    if r_spec["integrator"] == "cells":
        rings, est = r.integrate_to(r_spec["target_error"], max_rings=r_spec["max_rings"])
        return {"rings": rings, "error_estimate": est}
    return {"samples": _monte_carlo(r, phasors, r_spec), "error_estimate": -1.0}


def _total_estimate(parts: list[tuple[float, float]], total_norm: float) -> float:
    """The relative L2 error of a sum of images from each image's (estimate, L2 norm):
    at most sum(e_i |I_i|) / |sum I_i| (triangle inequality); -1 when any is unknown."""
    if any(e < 0 for e, n in parts if n > 0):
        return -1.0
    if total_norm <= 0:
        return 0.0
    return sum(e * n for e, n in parts if n > 0) / total_norm


def render_node(job: dict[str, Any]) -> dict[str, Any]:
    """Render one node unless it is finished; its record."""
    done = finished_record(job)
    if done is not None:
        return {**done, "skipped": True}
    import numpy as np
    from lensrt_ctypes import write_exr_reproducible

    spec, out, stem_path = job["spec"], Path(job["out"]), Path(job["out"]) / job["stem"]
    rt, threads = _context(job)
    lens = _load(rt, threads, job["library"], job["table"], job["table_crc32"])
    c = node_coordinates(spec, job["indices"])
    light = node_light(c)
    wavelengths = spec["grid"]["wavelengths_nm"]

    # Register the node on the chief ray: its image point at every wavelength. Each
    # wavelength is rendered in a window of its own centred on its chief point, so that a
    # reader never resamples a channel (lensrt.h, `registration channel`); a spec with one
    # window for every node (a flare bank's) renders every wavelength in that window
    chief = [rt.image_point(lens, light, lam, c["focus_offset_mm"]) for lam in wavelengths]
    w, r_spec = spec["window"], spec["render"]
    per_channel = "center_mm" not in w
    groups = ([([lam], tuple(xy)) for lam, xy in zip(wavelengths, chief, strict=True)]
              if per_channel else [(wavelengths, tuple(w["center_mm"]))])

    def create(table_lens, lams, centre):
        return create_render(rt, table_lens, spec, c, lams, centre)

    ghost_lenses = [_load(rt, threads, job["library"], g["table"], g["table_crc32"])
                    for g in job.get("ghosts", [])]
    cpu_clock = _cpu_clock(threads)
    t0, cpu0 = time.perf_counter(), cpu_clock()
    # Per group (one wavelength, or all in the shared window): the direct render, then
    # each ghost in the same window, each integrated by the spec's integrator
    parts: list[list[Any]] = []  # per group: [direct, ghost...]
    direct_how: list[dict[str, Any]] = []
    ghost_how: list[list[dict[str, Any]]] = [[] for _ in ghost_lenses]
    for gi, (lams, centre) in enumerate(groups):
        suffix = f".{gi}" if per_channel else ""
        r = create(lens, lams, centre)
        direct_how.append(_integrate(r, r_spec, stem_path.with_suffix(f"{suffix}.phasors")))
        renders = [r]
        for k, (g, gl) in enumerate(zip(job.get("ghosts", []), ghost_lenses, strict=True)):
            rg = create(gl, lams, centre)
            ghost_how[k].append(_integrate(
                rg, r_spec, stem_path.with_suffix(f"{suffix}.ghost-{g['label']}.phasors")))
            renders.append(rg)
        parts.append(renders)
    if not per_channel and not window_holds(w, chief):
        # A fixed window off the light's image: refused when it holds essentially none
        # of the PSF (MISS_FRACTION), before anything of the node is written
        direct = float(parts[0][0].image().astype(np.float64).sum())
        flare = (float(sum(x.image().astype(np.float64).sum() for x in parts[0][1:]))
                 if ghost_lenses else None)
        why = window_miss(spec, c, chief, direct, flare,
                          centred_power(rt, lens, spec, c, wavelengths, chief),
                          job["stem"].split("/")[-1])
        if why is not None:
            for p in out.glob(f"{job['stem']}.*phasors"):
                p.unlink()
            raise InputError(why)
    seconds, cpu_seconds = time.perf_counter() - t0, cpu_clock() - cpu0

    # How each was integrated. Per channel, a channel's estimate is its own relative L2
    # error; the node's is the largest (what a query at any one wavelength may see, and a
    # bound on the whole spectral image's)
    how = {"integrator": r_spec["integrator"], **_merge_how(direct_how)}
    ghosts = [{"label": g["label"], "table_crc32": f"{g['table_crc32']:08x}",
               **_merge_how(hs)} for g, hs in zip(job.get("ghosts", []), ghost_how,
                                                  strict=True)]
    if ghosts:
        # A flare bank: the estimate of the sum from each image's (estimate, L2 norm)
        images = [np.concatenate([p[k].image() for p in parts]) for k in range(len(parts[0]))]
        how["direct_error_estimate"] = how["error_estimate"]
        how["error_estimate"] = _total_estimate(
            [(e, float(np.linalg.norm(im))) for e, im in
             zip([how["error_estimate"], *(g["error_estimate"] for g in ghosts)], images,
                 strict=True)], float(np.linalg.norm(np.sum(images, axis=0))))

    # The EXR first, then the record that declares the node finished
    exr = stem_path.with_suffix(".exr")
    identity = node_identity(job["indices"], c)
    if per_channel:
        write_channel_exr(rt, exr, parts, wavelengths, chief, identity,
                          layered=bool(ghosts))
    elif ghosts:
        rt.write_exr_layers(exr, {"direct": [parts[0][0]], "flare": parts[0][1:]},
                            reproducible=True)
    else:
        write_exr_reproducible(parts[0][0], exr)
    centre = tuple(chief[len(chief) // 2]) if per_channel else groups[0][1]
    record = {"version": RECORD_VERSION, "k": job["k"], "indices": list(job["indices"]),
              "lens": job["lens_name"], "table_crc32": f"{job['table_crc32']:08x}",
              "spec_digest": job["digest"], "lensrt_version": rt.version(),
              **{k: _json_number(v) for k, v in c.items()},
              "wavelengths_nm": wavelengths, "centre_mm": list(centre),
              "registration": "channel" if per_channel else "window",
              "chief_mm": [list(xy) for xy in chief], **how, "ghosts": ghosts,
              "seconds": seconds, "cpu_seconds": cpu_seconds, "exr": f"{job['stem']}.exr",
              "exr_crc32": f"{file_crc32(exr):08x}"}
    write_atomic(stem_path.with_suffix(".json"), checked_json_text(record))
    for p in out.glob(f"{job['stem']}.*phasors"):
        p.unlink()
    return {**record, "skipped": False}


def _cpu_clock(threads: int):
    """The CPU clock of a node's render: with one lensrt thread the render runs in the
    calling thread, so that thread's CPU time is the node's; with more (OpenMP threads) the
    process's, which on a worker running several tasks at once includes the others'."""
    return time.thread_time if threads == 1 else time.process_time


def _merge_how(hows: list[dict[str, Any]]) -> dict[str, Any]:
    """One record of how a node (or one ghost of it) was integrated from its groups'
    (one per wavelength, or one): the largest estimate (-1 when any has none), the most
    rings or samples, and each group's estimate when there are several."""
    est = [h["error_estimate"] for h in hows]
    out: dict[str, Any] = {"error_estimate": -1.0 if min(est) < 0 else max(est)}
    for key in ("rings", "samples"):
        if key in hows[0]:
            out[key] = max(h[key] for h in hows)
    if len(hows) > 1:
        out["channel_error_estimates"] = est
    return out


def node_identity(indices: tuple[int, ...], c: dict[str, float]) -> str:
    """The EXR attribute lensrt/bankNode: "<i_f> <i_z> <i_d> <i_y> <i_x> <f_number>
    <focus_offset_mm> <distance_mm (0: infinity)> <field_x_deg> <field_y_deg>", numbers
    as repr (which the reader's strtod reads back exactly; lensrt.h, PSF banks)."""
    dist = 0.0 if math.isinf(c["distance_mm"]) else c["distance_mm"]
    values = (c["f_number"], c["focus_offset_mm"], dist, c["field_x_deg"], c["field_y_deg"])
    return " ".join([*(str(i) for i in indices), *(repr(float(v)) for v in values)])


def write_channel_exr(rt, exr: Path, parts: list[list[Any]], wavelengths: list[float],
                      chief: list[tuple[float, float]], identity: str, layered: bool) -> None:
    """A node whose channels are renders of their own (one wavelength each, each window on
    its chief point) as one spectral EXR: each group's EXR as lensrt writes it
    (reproducible; with layers ``direct`` and ``flare`` for a flare bank), its spectral
    channels gathered, R, G, B of each layer converted from them (lensrt_spectrum_rgb),
    the header of the first with what differs per channel stated, written atomically."""
    import tempfile

    import numpy as np
    import OpenEXR
    from lensrt_ctypes import write_exr_reproducible
    from lensrt_exr import _split_layer, _wavelength_nm

    header: dict[str, Any] = {}
    spectral: dict[str, np.ndarray] = {}
    estimates: list[float] = []
    params: dict[str, list[int]] = {}  # each group's integrator parameter (ints), by name
    with tempfile.TemporaryDirectory(dir=exr.parent, prefix=".node-") as tmp:
        for gi, renders in enumerate(parts):
            path = Path(tmp) / f"{gi}.exr"
            if layered:
                rt.write_exr_layers(path, {"direct": renders[:1], "flare": renders[1:]},
                                    reproducible=True)
            else:
                write_exr_reproducible(renders[0], path)
            with OpenEXR.File(str(path), separate_channels=True) as f:
                h = dict(f.header())
                header = header or h
                estimates.append(float(np.max(h.get("lensrt/errorEstimate", -1.0))))
                for key in ("lensrt/cellsRings", "lensrt/fourierNodes"):
                    if key in h:
                        params.setdefault(key, []).append(int(h[key]))
                # The values straight from the renders (the EXR gives the names and the
                # header): nothing of a render is decoded back
                direct = renders[0].image()[0]
                flare = (np.sum([x.image()[0].astype(np.float64) for x in renders[1:]], axis=0)
                         if layered else None)
                for name in f.channels():
                    if name.rsplit(".", 1)[-1] in ("R", "G", "B"):
                        continue
                    layer = (_split_layer(name) or ("", name))[0]
                    plane = {"": direct if flare is None else direct + flare,  # in doubles
                             "direct": direct, "flare": flare}[layer]
                    spectral[name] = np.ascontiguousarray(plane, dtype=np.float32)
        # R, G, B of each layer ('' the unprefixed sum) from its spectral channels
        channels: dict[str, np.ndarray] = dict(spectral)
        by_layer: dict[str, list[tuple[float, np.ndarray]]] = {}
        for name, plane in spectral.items():
            layer, rest = _split_layer(name) or ("", name)
            by_layer.setdefault(layer, []).append((_wavelength_nm(rest), plane))
        for layer, planes in by_layer.items():
            planes.sort(key=lambda x: x[0])
            rgb = rt.spectrum_rgb([lam for lam, _ in planes], np.stack([p for _, p in planes]))
            for k, name in enumerate("RGB"):
                channels[f"{layer}.{name}" if layer else name] = np.ascontiguousarray(rgb[..., k])
        del header["channels"]
        mid = chief[len(chief) // 2]
        header.update({
            "lensrt/bankNode": identity,
            "lensrt/registration": "channel: each spectral channel is a window of its own, "
                                   "centred on its wavelength's chief point "
                                   "(lensrt/channelCentersMm, x y per wavelength)",
            "lensrt/channelCentersMm": " ".join(repr(float(v)) for xy in chief for v in xy),
            "lensrt/centerMm": np.array(mid, dtype=np.float64)})
        # The integrator's own parameters only (issue 40): the largest of the groups'
        # rings or nodes, and the largest estimate when every group has one
        for key, values in params.items():
            header[key] = max(values)
        header.pop("lensrt/errorEstimate", None)
        if estimates and min(estimates) >= 0:
            header["lensrt/errorEstimate"] = np.array([max(estimates)])
        if "comments" in header:
            header["comments"] = re.sub(
                r"1 wavelengths? [0-9.]+-[0-9.]+ nm",
                f"{len(wavelengths)} wavelengths {wavelengths[0]:g}-{wavelengths[-1]:g} nm, "
                "each in a window on its own chief point", str(header["comments"]))
        merged = Path(tmp) / "node.exr"
        with OpenEXR.File(header, channels) as f:
            f.write(str(merged))
        write_atomic(exr, merged.read_bytes())


def _json_number(v: float) -> float | str:
    return "inf" if math.isinf(v) else v


def _monte_carlo(r, phasors: Path, r_spec: dict[str, Any]) -> int:
    """Run Monte Carlo to the spec's samples in ``checkpoints`` steps, saving the sums
    after each and resuming from a saved sum of the same scene; the samples run."""
    from lensrt_ctypes import LensrtError

    total, steps = int(r_spec["samples"]), int(r_spec["checkpoints"])
    done = 0
    if phasors.exists():
        try:
            r.load(phasors)  # lensrt refuses the sums of another scene or seed
            done = int(r.stats().samples_per_wavelength)
        except LensrtError:
            phasors.unlink(missing_ok=True)
            done = 0
        if done > total:  # loaded sums cannot be taken back out of the render: refused
            raise InputError(f"{phasors}: holds {done} samples per wavelength, more than the "
                             f"spec's {total}; remove it")
    for step in range(1, steps + 1):
        goal = total * step // steps
        if goal > done:
            r.run(goal - done)
            done = goal
            if step < steps:
                r.save(phasors)
    return done
