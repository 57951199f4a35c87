"""Fit a ghost's half-system and its clip outputs; measure them on held-out exact rays.

The half's four outputs (x, y, tau, phi) are fitted as the direct halves are
(:func:`lensfit.fitting.fit_system_tensor` on a grid of field points times one set of
stop points, held-out errors on random rays that pass). Whether a ray gets through is
fitted two ways, both measured as the share of held-out rays whose pass/block verdict
agrees with the exact trace:

* ``max``: the paper's single P_clip, (x_k, y_k) / R_k at the housing step where the
  ratio is largest; pass when its norm is <= 1. Its value jumps where the binding
  housing changes, which a polynomial smooths over.
* ``housings``: (x_k / R_k, y_k / R_k) of the few housing steps that decide the
  verdict, chosen greedily on the training rays (add the step whose test removes most
  disagreements until the exact verdict is reproduced on >= 99.9% of them); pass when
  every one has norm <= 1.

In case C both also test the two extra stop crossings, fitted in mm (x, y on the stop
plane), against a round stop of the domain's radius (a renderer tests the blade shape).
Clip outputs are trained on rays up to CLIP_TRAIN times a housing radius, so that the
polynomials know the outside of the edge too.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from lensfit.fitting import APERTURE, FIELD, FitOptions, OutputFit, fit_system_tensor
from lensfit.poly.polynomial import Polynomial, System
from lensfit.poly.tensor import TensorFit
from lensfit.prescription.model import Lens
from lensfit.sample.domain import Domain, default_domain
from lensfit.sample.ghost import (
    GhostHalf,
    GhostSamples,
    ghost_half,
    sample_ghost,
    sample_ghost_grid,
)
from lensfit.sample.rays import OUTPUTS_O, OUTPUTS_S, GridSamples, Samples

CLIP_TRAIN = 2.0  # clip outputs: train on rays up to twice a housing's radius out
SELECT_SHARE = 0.999  # greedy housing selection: stop when this share of training agrees
# Small budgets (a ghost is dimmer than the direct image, and many are fitted per lens).
# Every term of the degree that reaches the target, as before the direct fits became
# adaptive (prune=False): growing to room for the cut costs a ghost another rung of its
# 30-second budget, and its 3% trust check was measured on uncut tables
GHOST_OPTIONS = FitOptions(groups=500, aperture_points=128, field_degrees=(4, 6, 8),
                           test_groups=200, test_per_group=16, prune=False)


@dataclass
class GhostFit:
    """A fitted ghost half, its clip outputs, and held-out figures."""

    half: GhostHalf
    system: System  # the half's four outputs
    outputs: list[OutputFit]
    clip_max: System  # x_clip, y_clip (+ the stop crossings in case C)
    clip_housings: System  # x_h<k>, y_h<k> per selected housing step (+ stop crossings)
    selected: list[int]  # the housing steps (indices into half.steps) chosen greedily
    agreement_max: float  # held-out share of rays whose verdict agrees with the exact one
    agreement_housings: float
    converged_train: float  # share of requested rays that converged
    converged_test: float
    held_out_rays: int  # converged held-out rays the agreements are measured on
    blocked_share: float  # of those, the share the exact trace blocks
    seconds: float
    options: FitOptions | None = None  # the budgets it was fitted with

    @property
    def stop_radius_mm(self) -> float:
        """The stop radius it was fitted over (its x_a range)."""
        return next(i.hi for i in self.system.inputs if i.name == "x_a")


def select_housings(ratio: np.ndarray, exact: np.ndarray, base: np.ndarray,
                    share: float = SELECT_SHARE) -> list[int]:
    """Greedy choice of housing steps (columns of ``ratio`` (N, H)) whose tests, with the
    ``base`` verdict (N,) (True: passes what is always tested), reproduce ``exact`` (N,)
    on at least ``share`` of the rays."""
    chosen: list[int] = []
    verdict = base.copy()
    while np.mean(verdict == exact) < share:
        agree = [np.sum((verdict & (ratio[:, k] <= 1.0)) == exact) if k not in chosen else -1
                 for k in range(ratio.shape[1])]
        best = int(np.argmax(agree))
        if agree[best] <= np.sum(verdict == exact):
            break  # no housing helps further
        chosen.append(best)
        verdict &= ratio[:, best] <= 1.0
    return chosen


def _clip_grid(grid: GridSamples, values: np.ndarray, vig: np.ndarray) -> GridSamples:
    """Grid samples of clip outputs ``values`` (N, m): every ray that exists and is
    within CLIP_TRAIN of the housings counts as fitted (vignetting 0), the rest not."""
    g, k = grid.ok.shape
    with np.errstate(invalid="ignore"):
        inside = grid.ok.reshape(-1) & (vig <= CLIP_TRAIN)
    return GridSamples(grid.system, grid.field, grid.aperture, values.reshape(g, k, -1),
                       grid.ok, np.where(inside, 0.0, np.inf).reshape(g, k))


def _clip_test(test: GhostSamples, values: np.ndarray) -> Samples:
    ok = test.rays.ok
    return Samples(test.half.system, test.inputs[ok], values[ok], test.group[ok],
                   np.zeros(int(ok.sum())), len(ok), {})


def _stop_values(s: GhostSamples) -> tuple[np.ndarray, list[tuple[str, str]]]:
    """The extra stop crossings (case C) as columns x_s1, y_s1, x_s2, y_s2 (mm)."""
    st = s.rays.stop
    cols = [st[:, c, a] for c in range(st.shape[1]) for a in (0, 1)]
    names = [(f"{xy}_s{c + 1}", "mm") for c in range(st.shape[1]) for xy in ("x", "y")]
    return (np.column_stack(cols) if cols else np.zeros((len(st), 0))), names


def _evaluate_factored(p: Polynomial, xhat: np.ndarray) -> np.ndarray:
    """``p.evaluate_normalised(xhat)`` as a tensor fit's terms factor: the stop monomials
    times a coefficient matrix times the field monomials (one matrix product instead of
    the terms one by one; the same sum in another order)."""
    ap, fd = list(APERTURE), list(FIELD)
    a_exps, a_idx = np.unique(p.exponents[:, ap], axis=0, return_inverse=True)
    f_exps, f_idx = np.unique(p.exponents[:, fd], axis=0, return_inverse=True)
    w = np.zeros((len(a_exps), len(f_exps)))
    np.add.at(w, (a_idx.reshape(-1), f_idx.reshape(-1)), p.coefficients)
    return TensorFit(a_exps, f_exps, w, 0, 0).evaluate(xhat[:, ap], xhat[:, fd])


def _predicted_pass(system: System, inputs: np.ndarray, n_clip: int, stop_r: float
                    ) -> np.ndarray:
    """Verdict of fitted clip outputs: the first 2 n_clip outputs are (x, y) / R pairs,
    the rest (x, y) pairs on the stop in mm."""
    ok = np.ones(len(inputs), dtype=bool)
    if not system.outputs:
        return ok
    xhat = system.normalise(inputs)
    v = np.column_stack([_evaluate_factored(p, xhat) for p in system.outputs])
    for c in range(0, v.shape[1], 2):
        limit = 1.0 if c < 2 * n_clip else stop_r
        ok &= np.hypot(v[:, c], v[:, c + 1]) <= limit
    return ok


def fit_ghost(lens: Lens, i: int, j: int, domain: Domain | None = None,
              options: FitOptions = GHOST_OPTIONS) -> GhostFit:
    """Sample and fit the ghost half of (i, j) over ``domain`` (default: the lens's)."""
    t0 = time.perf_counter()
    domain = domain or default_domain(lens)
    half = ghost_half(lens, i, j)
    o = half.system == "P_o"
    inputs = domain.inputs_o() if o else domain.inputs_s()
    seed = 2 * (options.seed * 7919 + (0 if o else 1)) + 1000 * (i * 64 + j)
    # Training grid and held-out rays are independent: on two threads (the tracer's numpy
    # releases the GIL), each the same rays as one after the other
    with ThreadPoolExecutor(max_workers=2) as pool:
        test_job = pool.submit(sample_ghost, lens, domain, half, options.test_groups,
                               options.test_per_group, seed + 1)
        train = sample_ghost_grid(lens, domain, half, options.groups,
                                  options.aperture_points, seed)
        test = test_job.result()
    name = f"{half.system}_ghost_{i}_{j}"
    system, outs = fit_system_tensor(name, inputs, OUTPUTS_O if o else OUTPUTS_S,
                                     train.grid, test.samples(), options)
    stop_r = domain.stop_radius_mm
    tr, te = train.rays, test.rays
    vig_tr = tr.vignetting
    stop_tr, stop_names = _stop_values(train)
    stop_te, _ = _stop_values(test)
    clip_options = replace(options, field_degrees=options.field_degrees[:2])

    def fit_clip(label, values_tr, values_te, names):
        sysname = f"{name}_{label}"
        clip, _ = fit_system_tensor(sysname, inputs, names,
                                    _clip_grid(train.grid, values_tr, vig_tr),
                                    _clip_test(test, values_te), clip_options)
        return clip

    # (a) the paper's single max-ratio output
    clip_max = fit_clip("clip_max", np.column_stack([tr.max_clip(), stop_tr]),
                        np.column_stack([te.max_clip(), stop_te]),
                        [("x_clip", "1"), ("y_clip", "1")] + stop_names)
    # (b) the housings that decide, chosen on the training rays
    okt = tr.ok
    base = np.ones(int(okt.sum()), dtype=bool)
    if half.stop_crossings:
        base &= np.all(np.hypot(tr.stop[okt, :, 0], tr.stop[okt, :, 1]) <= stop_r, 1)
    selected = select_housings(tr.ratio[okt], tr.passes(stop_r)[okt], base)
    names = [n for k in selected for n in ((f"x_h{k}", "1"), (f"y_h{k}", "1"))]
    pick = lambda r: np.column_stack(  # noqa: E731
        [r.clip[:, k, a] for k in selected for a in (0, 1)] or [np.zeros(len(r.clip))[:, None]])
    if selected or stop_names:
        clip_h = fit_clip("clip_housings",
                          np.column_stack(([pick(tr)] if selected else []) + [stop_tr]),
                          np.column_stack(([pick(te)] if selected else []) + [stop_te]),
                          names + stop_names)
    else:
        clip_h = System(f"{name}_clip_housings", inputs, ())
    # Held-out agreement on every converged ray
    ok = te.ok
    exact = te.passes(stop_r)[ok]
    x = test.inputs[ok]
    agree_max = float(np.mean(_predicted_pass(clip_max, x, 1, stop_r) == exact))
    agree_h = float(np.mean(_predicted_pass(clip_h, x, len(selected), stop_r) == exact))
    return GhostFit(half, system, outs, clip_max, clip_h, selected, agree_max, agree_h,
                    float(np.mean(tr.ok)), float(np.mean(te.ok)), int(ok.sum()),
                    float(np.mean(~exact)) if exact.size else 0.0, time.perf_counter() - t0,
                    options)
