"""Per-ray evaluation throughput: lensrt_lens_eval against the exact tracer, in one run.

    python runtime/bench/eval_bench.py --out build/bench [--library PATH/liblensrt.so]

P_s of the default lens (0001) on rays drawn over its fitted domain (sensor points on the
sensor disc, stop points on the widest stop, sensor shifts over the fitted range,
wavelengths over 380-780 nm). lensrt_lens_eval runs on this thread (it never uses other
threads) in double and float, with and without Jacobians, in batches of 32768 rays so that
the ctypes call costs nothing; each figure is the best of --repeats timings. The exact
reference is lensfit's own aiming of the same rays through the prescription
(``aim_sensor_side``: Newton's method on the ray leaving the stop, the traced ray's
position, transmittance and optical path at the sensor), on a subset of the rays, also on
one thread (vectorised numpy). Prints a table and writes --out/eval.json under the key
"eval": rays per second and the ratio to the exact tracer measured in the same run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "runtime" / "python"))

from lensrt_ctypes import LIBRARY, Lensrt  # noqa: E402  (needs the path above)

LENS = "0001-angenieux-double-gauss"
TABLE = ROOT / "generated" / LENS / "lens0001.table"


def draw_rays(domain: dict, n: int, seed: int) -> np.ndarray:
    """Raw P_s inputs (n, 6) over the fitted domain."""
    rng = np.random.default_rng(seed)

    def disc(radius: float) -> np.ndarray:
        angle = rng.uniform(0.0, 2 * np.pi, n)
        r = radius * np.sqrt(rng.random(n))
        return np.stack([r * np.cos(angle), r * np.sin(angle)], axis=1)

    sensor, stop = disc(domain["sensor_radius_mm"]), disc(domain["stop_radius_mm"])
    z = rng.uniform(domain["focus_min_mm"], domain["focus_max_mm"], n)
    lam = rng.uniform(domain["wavelength_min_nm"], domain["wavelength_max_nm"], n)
    return np.stack([sensor[:, 0], sensor[:, 1], z, stop[:, 0], stop[:, 1], lam], axis=1)


def best_rate(fn, n: int, repeats: int) -> float:
    """Rays per second of the fastest of `repeats` calls of fn (which does n rays)."""
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return n / best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "build" / "bench")
    ap.add_argument("--library", type=Path, default=LIBRARY)
    ap.add_argument("--rays", type=int, default=32768, help="rays per lensrt batch")
    ap.add_argument("--exact-rays", type=int, default=4096, help="rays traced exactly")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)

    # Imported here: lensfit and its dependencies are only needed for the reference
    from lensfit.prescription import load_lens
    from lensfit.sample.aim import aim_sensor_side

    domain = json.loads((ROOT / "generated" / LENS / "fit.json").read_text())["domain"]
    rt = Lensrt(args.library, threads=1)
    lens = rt.load(TABLE)
    rays = draw_rays(domain, args.rays, seed=1)
    rays_f = rays.astype(np.float32)
    rt.eval(lens, "P_s", rays[:64], jacobians=True)  # warm up (page in the table)

    cases = {
        "double": lambda: rt.eval(lens, "P_s", rays),
        "float": lambda: rt.eval(lens, "P_s", rays_f, dtype=np.float32),
        "double_jacobians": lambda: rt.eval(lens, "P_s", rays, jacobians=True),
        "float_jacobians": lambda: rt.eval(lens, "P_s", rays_f, jacobians=True, dtype=np.float32),
    }
    rates = {name: best_rate(fn, len(rays), args.repeats) for name, fn in cases.items()}

    # The exact reference on a subset of the same rays, one thread
    lensfit_lens = load_lens(LENS)
    sub = rays[: args.exact_rays]
    ok = [0]

    def exact() -> None:
        aimed = aim_sensor_side(lensfit_lens, *sub.T, vignetting=False)
        ok[0] = int(np.sum(aimed.ok))

    exact_rate = best_rate(exact, len(sub), max(1, args.repeats - 1))

    result = {
        "lens": LENS,
        "system": "P_s",
        "library": str(args.library),
        "machine": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "threads": 1,
        "rays": len(rays),
        "terms": rt.system_info(lens, "P_s")["terms"],
        "rays_per_second": rates,
        "exact_rays": len(sub),
        "exact_converged": ok[0],
        "exact_rays_per_second": exact_rate,
        "speedup_vs_exact": {k: v / exact_rate for k, v in rates.items()},
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "eval.json").write_text(json.dumps({"eval": result}, indent=2) + "\n")

    print(f"Per-ray evaluation of P_s, {LENS} ({sum(result['terms'])} terms), one thread:")
    print(f"  {'':24s} {'rays/s':>12s} {'x exact':>9s}")
    for name, rate in rates.items():
        print(f"  lensrt_lens_eval {name:17s} {rate:12.4g} {rate / exact_rate:9.1f}")
    print(f"  exact tracer (lensfit)   {exact_rate:12.4g} {1.0:9.1f}   "
          f"({ok[0]}/{len(sub)} rays converged)")
    print(f"  -> {args.out / 'eval.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
