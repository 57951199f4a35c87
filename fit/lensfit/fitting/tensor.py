"""The default method: tensor least squares on a grid of field points times stop points
(:mod:`lensfit.poly.tensor`), per output."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from lensfit.common.errors import InputError
from lensfit.fitting.options import (
    APERTURE,
    FIELD,
    GROW_SHARE,
    PRUNE_SHARE,
    STAGNATION,
    WAVE_MM,
    FitOptions,
)
from lensfit.fitting.results import OutputFit, _output_fit, error_metric
from lensfit.poly.polynomial import Input, Polynomial, System
from lensfit.poly.tensor import (
    aperture_exponents,
    field_exponents,
    fit_tensor,
    prune_support,
    single_blas,
)
from lensfit.prescription.model import Lens
from lensfit.sample.domain import Domain
from lensfit.sample.rays import TRAIN_VIGNETTING, GridSamples, Samples, extend_grid


def fit_system_tensor(name: str, inputs: tuple[Input, ...], outputs, train: GridSamples,
                      test: Samples, options: FitOptions,
                      progress: Callable[[str], None] | None = None,
                      only: set[str] | None = None, refuse_out_of_reach: bool = False,
                      far_weight: float | None = None, aperture_degree: int | None = None
                      ) -> tuple[System, list[OutputFit]]:
    """Fit every output of one system on grid samples by tensor least squares (module
    doc): per output, the field degrees of ``options.field_degrees`` in turn until the
    held-out error reaches the target (GROW_SHARE of it with ``options.prune``), then,
    with ``options.prune``, the cut to the terms the target needs. ``only``: fit these
    outputs alone (the System then has only their polynomials).

    An output whose degrees stop short of their goal (the target, or GROW_SHARE of it
    with ``options.prune``: room to cut) says why in ``OutputFit.limit``: "stop points"
    or "field points" when the held-out error is far above the error on the grid (the
    polynomial is right where it was fitted and wrong between: too few samples for its
    degree in that dimension, the one with fewer samples per monomial), else "degree".
    ``refuse_out_of_reach`` (a lens fit, :func:`fit_system_growing`; ghost fits have
    fallbacks of their own): raise :class:`OutOfReach` for an output no degree brings
    near its target (:func:`_out_of_reach`). ``far_weight`` (a lens fit: FAR_WEIGHT):
    rays that exist and pass a housing by more than TRAIN_VIGNETTING (up to
    FAR_VIGNETTING, where they are at least FAR_MIN_SHARE of the grid) are fitted too, at
    this weight, rather than left as holes. ``aperture_degree``: the phase's stop degree
    to start at (default ``options.aperture_degree``; the other outputs 4 less)."""
    te = test.subset(test.passes)
    if len(te) == 0:
        raise InputError(f"{name}: no held-out ray passes the lens")
    scaffold = System(name, inputs, ())
    # Normalised grid coordinates: the stop points, and the field points
    # (the columns not wanted are filled with each input's lower bound, a valid value)
    lo = np.array([i.lo for i in inputs])
    full = np.tile(lo, (len(train.field), 1))
    full[:, list(FIELD)] = train.field
    v_hat = scaffold.normalise(full)[:, list(FIELD)]
    ap_full = np.tile(lo, (len(train.aperture), 1))
    ap_full[:, list(APERTURE)] = train.aperture
    a_hat = scaffold.normalise(ap_full)[:, list(APERTURE)]
    xe = scaffold.normalise(te.inputs)
    # A field input the domain holds fixed (a scene fit at infinity: u_O = 0 throughout)
    # gets no powers: its columns would all be equal
    caps = tuple(0 if np.ptp(v_hat[:, i]) < 1e-9 else max(options.field_degrees)
                 for i in range(len(FIELD)))
    # Cells fitted: rays that exist and pass within 10% of every housing ("near"); with
    # ``far_weight``, every ray that exists, those beyond at that weight
    with np.errstate(invalid="ignore"):
        near = train.ok & (train.vignetting <= TRAIN_VIGNETTING)
    if not np.any(near):
        raise InputError(f"{name}: no training ray within {TRAIN_VIGNETTING} of the housings")
    mask, weights = near, None
    with np.errstate(invalid="ignore"):
        far = train.ok & ~near & (train.vignetting <= FAR_VIGNETTING)
    if far_weight is not None and np.count_nonzero(far) >= FAR_MIN_SHARE * far.size:
        mask = near | far
        weights = np.where(near, 1.0, far_weight)
    polys: list[Polynomial] = []
    fits: list[OutputFit] = []
    for j, (out, unit) in enumerate(outputs):
        if only is not None and out not in only:
            continue
        parity = (int(out.startswith("x_")), int(out.startswith("y_")))
        phase = out.startswith("phi")
        if phase:
            target, unit_err = options.phase_target_waves, "waves"
        elif out.startswith("tau"):
            target, unit_err = options.target_tau, "1"
        else:
            target, unit_err = options.target_position_um, "um"
        da = (aperture_degree or options.aperture_degree) - (0 if phase else 4)
        values = np.where(mask, train.outputs[:, :, j], 0.0)
        scale = _metric_scale(out, values, near)
        # Grow until the error leaves room to cut (GROW_SHARE of the target), or reaches
        # the target when cutting is off
        goal = target * (GROW_SHARE if options.prune else 1.0)
        hist: list[float] = []
        terms: list[int] = []
        best = None
        fill = None
        degrees = list(options.field_degrees)
        raised = just_raised = False  # the stop degree was raised (once at most)
        limit = None
        out_caps = caps  # each field variable's highest power, set per rung (below)
        field_worse = False  # a higher field degree made the held-out error worse
        rung_best: list[float] = []  # the best held-out error after each field degree
        while degrees:
            degree = degrees[0]
            v_exps = field_exponents(len(FIELD), degree, out_caps)
            try:
                tf = fit_tensor(a_hat, v_hat, values, mask, aperture_exponents(da), v_exps,
                                parity=parity, fill=fill, weights=weights)
            except ValueError as e:  # more terms than the grid can determine
                limit = "stop points" if "aperture" in str(e) else "field points"
                break
            if tf.holes:  # the next rung starts from this one's values in the holes
                fill = tf.grid(a_hat, v_hat)
            # The held-out rays through W's factors (stop monomials times W times field
            # monomials: one matrix product) rather than the polynomial's tens of thousands
            # of terms one by one: the same sum in another order, ~20x faster
            pred = _evaluate_tensor(tf, xe)
            err = error_metric(out, pred, te.outputs[:, j], te.group)
            rms = float(np.sqrt(np.mean(err * err)))
            hist.append(rms)
            terms.append(int(np.count_nonzero(tf.W)))  # the polynomial's terms
            previous = best[0] if best is not None else math.inf
            if best is None or rms < best[0]:
                best = (rms, err, pred, tf)
            if rms <= goal:
                break
            # A higher field degree that makes the held-out error worse (and the fit of
            # the grid better, by construction) is fitting between too few field points
            # (a 23-degree triplet's P_o phase on 1000 field points: 4.83e-3 waves at
            # field degree 12, worse at 14 at either stop degree; 9.8e-4 at 14 on 2000)
            if not just_raised and rms > previous:
                field_worse = True
            # A higher field degree that barely helps means the stop degree is the limit
            # (lens 0009's P_o at f/2: 2.4e-3, 2.3e-3, 2.2e-3 waves for field degrees 6,
            # 8, 10 at stop degree 10; 2.5e-4 at stop degree 12, field degree 8): raise
            # the stop degree once and try this field degree again
            if (not raised and rms > STAGNATION * previous
                    and da + 2 <= options.max_aperture_degree):
                da, raised, just_raised = da + 2, True, True
                continue
            if just_raised and rms > previous:
                # Raising made it worse (holes in the grid that higher stop degrees
                # extrapolate into: lens 0004's P_s): back to the lower stop degree
                da -= 2
            just_raised = False
            degrees.pop(0)
            rung_best.append(best[0])
            # Out of reach only where the degree is the limit: the best fit's error on the
            # grid's own rays is as large as held out (else more samples may help: lens
            # 0004's P_s stalled at 2.8e-3 waves on 128 stop points, 7.4e-5 on 256)
            if (refuse_out_of_reach
                    and _out_of_reach(rung_best, len(degrees), target,
                              raised or da + 2 > options.max_aperture_degree)
                    and _sampling_limit(best[3], best[0], a_hat, v_hat, values, near,
                                        scale) is None):
                raise OutOfReach(
                    f"{name} {out} reaches {best[0]:.3g} {unit_err} RMS on held-out rays at "
                    f"field degree {degree} (stop degree {da}), against its target "
                    f"{target:.3g} {unit_err}; at the rate of its last field degree "
                    f"({rung_best[-1] / rung_best[-2]:.2f}x) the highest "
                    f"({options.field_degrees[-1]}) and a larger grid would not come within "
                    f"{OUT_OF_REACH:g} times the target")
            if options.prune and tf.energy is not None and degrees and degrees[0] >= CAP_FROM:
                out_caps = _next_caps(tf, caps, target / scale, values.size)
        if best is None:
            raise ValueError(f"{name}: {out}: the grid of {len(train.field)} field points "
                             "cannot determine even the lowest field degree")
        _, err, pred, tf = best
        poly = _tensor_polynomial(out, unit, tf, len(inputs))
        hist_terms = list(terms)
        if best[0] > goal:
            limit = (_sampling_limit(tf, best[0], a_hat, v_hat, values, near, scale) or limit
                     or ("field points" if field_worse else None))
        if options.prune and tf.energy is not None:
            pruned = _prune(out, unit, tf, best[0], pred, target, scale, parity, a_hat, v_hat,
                            values, mask, weights, xe, te.outputs[:, j], te.group,
                            len(inputs), phase)
            if pruned is not None:
                poly, err, pred, rms = pruned
                hist.append(rms)
                hist_terms.append(poly.terms)
        extra = {}
        if phase:  # terms without the stop point: the piston; and the error with it
            extra = {"piston_terms": int(np.sum(poly.exponents[:, list(APERTURE)].sum(1) == 0)),
                     "absolute_rms_um": float(np.sqrt(np.mean((pred - te.outputs[:, j]) ** 2))
                                              * 1e3)}
        of = _output_fit(name, out, poly, err, hist, target, unit_err, **extra)
        of.path_terms = hist_terms
        if best[0] > goal:
            of.limit = limit or "degree"
        polys.append(poly)
        fits.append(of)
        if progress is not None:
            progress(f"{name} {out}")
    return System(name, inputs, tuple(polys)), fits


# The weight of a lens fit's rays that exist but pass a housing by more than
# TRAIN_VIGNETTING (fit_system_tensor's far_weight). Left out, they leave holes where the
# lens vignettes, and conjugate gradients do not converge on a grid with a third of its
# cells missing: the Petzvals' sensor-side phase (0003, 0006; 21-33% holes) stayed at
# 0.04-0.12 waves held out at field and stop degree 10 after 300 iterations. Fitted at
# weight 1 (the maps are smooth through a housing, which only clips) it drops to
# 4e-5-1.1e-4 in 33-45 iterations; at 0.3 to 2.3e-5-6.3e-5 in 86-110, while a lens that
# barely vignettes (0008: P_o 3.77e-3, P_s 4.57e-4 waves masked) stays within 4% of the
# masked figure (3.91e-3, 4.62e-4; at weight 1: 4.3e-3, 4.75e-4)
FAR_WEIGHT = 0.3
# Only rays within this of every housing are fitted so (0003's and 0006's grids hold 97%
# and 99.5% of their rays there), and only where they fill at least FAR_MIN_SHARE of the
# grid: a few far rays are no holes worth filling, and may follow another branch of the
# trace (lens 0002 at f/1.9: 7 of 256,000 sensor-side rays, at the stop's rim and 380 nm,
# 1.21 times a housing's radius out, 700 waves off their field point's trend; fitted at
# weight 0.3 they took its phi_i from 7.2e-4 to 0.44 waves held out)
FAR_VIGNETTING = 1.6
FAR_MIN_SHARE = 0.01


class OutOfReach(InputError):
    """An output whose degrees cannot bring it near its target (:func:`_out_of_reach`):
    the fit stops there instead of climbing the rest of the ladder for minutes."""


# An output is out of reach when, improving at the rate of its last field degree at each
# degree still to go and then GROWTH_GAIN by a larger grid (a margin: the grid grows only
# where held-out errors exceed the grid's own, and the rule is not applied there), it
# would still miss its target OUT_OF_REACH times (a PSF error ten times the target).
# Judged only after the stop degree was raised or cannot be (that raise gained 10x on
# 0009's P_o). Measured:
# lens 0007 at f/2 over 35 degrees, P_o phase 0.24, 0.227 waves at field degrees 10, 12
# (target 5.6e-4): out of reach at 12, after 132 CPU-s, where the whole ladder with the
# grid's growth ran past 300 CPU-s; the lenses that fit improve 4-10x per field degree
# (0008's P_o 2.3e-2, 3.8e-3, 6.9e-4 waves at 8, 10, 12) and stay far from the rule
OUT_OF_REACH = 10.0
GROWTH_GAIN = 10.0


def _out_of_reach(rung_best: list[float], left: int, target: float, raised: bool) -> bool:
    """True when the errors ``rung_best`` (best after each field degree so far), improved
    at their last rate at each of the ``left`` degrees to go and by GROWTH_GAIN, stay
    above OUT_OF_REACH ``target``; never before the stop degree was ``raised``."""
    if not raised or len(rung_best) < 2 or rung_best[-2] <= 0.0:
        return False
    rate = min(rung_best[-1] / rung_best[-2], 1.0)
    return rung_best[-1] * rate**left / GROWTH_GAIN > OUT_OF_REACH * target


def fit_system_growing(lens: Lens, domain: Domain, name: str, inputs: tuple[Input, ...],
                       outputs, train: GridSamples, test: Samples, options: FitOptions, *,
                       seed: int, progress: Callable[[str], None] | None = None,
                       aperture_degree: int | None = None
                       ) -> tuple[System, list[OutputFit], GridSamples]:
    """:func:`fit_system_tensor`, then, while an output stops short of its goal for want
    of samples (``OutputFit.limit``), the grid doubled in that dimension (stop points up to
    ``options.max_aperture_points``, field points up to ``options.max_groups``; only the
    new rays are traced) and those outputs fitted again, kept where they improve.
    Returns the system, its fits and the grid it ended with."""
    system, fits = fit_system_tensor(name, inputs, outputs, train, test, options, progress,
                                     refuse_out_of_reach=True, far_weight=FAR_WEIGHT,
                                     aperture_degree=aperture_degree)
    polys = {p.output: p for p in system.outputs}
    by_name = {f.name: f for f in fits}
    for step in range(1, 3):
        short = [f for f in by_name.values() if f.limit in ("stop points", "field points")]
        if not short:
            break
        stop = sum(f.limit == "stop points" for f in short) >= len(short) / 2
        if stop and 2 * len(train.aperture) <= options.max_aperture_points:
            train = extend_grid(lens, domain, train, points=len(train.aperture),
                                seed=seed + 1000 * step)
        elif 2 * len(train.field) <= options.max_groups:
            train = extend_grid(lens, domain, train, groups=len(train.field),
                                seed=seed + 1000 * step + 1)
        else:
            break
        if progress is not None:
            progress(f"{name} sampled again ({len(train.field)} field points x "
                     f"{len(train.aperture)} stop points)")
        again, refits = fit_system_tensor(name, inputs, outputs, train, test, options,
                                          progress, only={f.name for f in short},
                                          refuse_out_of_reach=True, far_weight=FAR_WEIGHT,
                                          aperture_degree=aperture_degree)
        for p, f in zip(again.outputs, refits, strict=True):
            old = by_name[f.name]
            if ((f.reached and (not old.reached or f.terms < old.terms))
                    or (not old.reached and f.rms < old.rms)):
                polys[f.name], by_name[f.name] = p, f
    order = [out for out, _ in outputs]
    return (System(name, inputs, tuple(polys[o] for o in order)), [by_name[o] for o in order],
            train)


# A field variable whose highest powers hold less than this share of the target's energy
# (per grid cell, squared) keeps its degree while the others grow, from field degree
# CAP_FROM on: below it a fit far from its target tells too little (lens 0009's P_s phase,
# capped from degree 8 on by the energies of its degree-6 fit: 2.0e-3 waves at degree 8
# against 4.5e-4 uncapped)
CAP_SHARE = 0.3
CAP_FROM = 14


def _next_caps(tf, caps, target, cells) -> tuple[int, ...]:
    """Each field variable's highest power for the next rung: the variable grows with
    the field degree while its highest powers matter, and stays where the energy above a
    power (:attr:`TensorFit.energy`) is below (CAP_SHARE target)^2 per cell. A triplet's
    P_o over 23 degrees needs field degree 14 in the scene direction but 4 in the inverse
    distance and 6 in the wavelength (1.35e-3 waves held out at 34068 terms, against
    2.4e-3 at 30828 for degree 12 in all four). ``target`` in the output's units, over
    ``cells`` grid cells."""
    threshold = (CAP_SHARE * target) ** 2 * cells
    per_field = tf.energy.sum(axis=0)  # (n_v,)
    new = []
    for v, cap in enumerate(caps):
        e = tf.field_exps[:, v]
        top = int(e.max())
        # the smallest power k with the energy of all powers above k below the threshold
        tail = np.array([per_field[e > k].sum() for k in range(top + 1)])
        need = int(np.argmax(tail <= threshold)) if np.any(tail <= threshold) else top
        new.append(cap if need >= top else min(cap, max(need, 1)))
    return tuple(new)


# The held-out error this many times the error on the grid's own rays: the samples, not
# the degree, limit the fit (0009's P_o phi at f/2, stop degree 12 on 128 stop points:
# 5.6e-4 waves held out against 6.7e-6 on the grid; 5.5e-5 held out on 256 points)
OVERFIT = 3.0


def _sampling_limit(tf, rms, a_hat, v_hat, values, mask, scale) -> str | None:
    """"stop points" or "field points" when the held-out ``rms`` of the fit ``tf`` is
    OVERFIT times its error on the grid (``scale``: to the error measure's units), in
    the dimension with fewer samples per monomial of one parity class; None when the
    grid's own error is as large."""
    res = (tf.grid(a_hat, v_hat) - values)[mask] * scale
    on_grid = float(np.sqrt(np.mean(res * res)))
    if rms < OVERFIT * on_grid:
        return None
    per_stop = len(a_hat) / max(len(tf.aperture_exps), 1)
    per_field = len(v_hat) / max(len(tf.field_exps), 1)
    return "stop points" if per_stop <= per_field else "field points"


def _metric_scale(out: str, values: np.ndarray, mask: np.ndarray) -> float:
    """Factor from the output's units to its error measure's (error_metric): waves for
    phi, micrometres for positions, relative for tau (by its mean magnitude)."""
    if out.startswith("phi"):
        return 1.0 / WAVE_MM
    if out.startswith("tau"):
        return 1.0 / max(float(np.mean(np.abs(values[mask]))), 1e-12)
    return 1e3


def _prune(out, unit, tf, rms_full, pred_full, target, scale, parity, a_hat, v_hat, values,
           mask, weights, xe, y_te, group_te, n_inputs, phase):
    """The full fit ``tf`` cut down to the pairs of monomials the target needs
    (:func:`lensfit.poly.tensor.prune_support`) and refitted on them; None when nothing
    can go or the cut fit misses the target on held-out rays.

    The budget is the energy the held-out error has room for, (PRUNE_SHARE target)^2 less
    the full fit's error^2, per grid cell: on a complete grid the refitted error^2 is
    the full fit's plus the energy left out (exactly for total-degree cuts, nearly for
    the cuts made). A phase's piston (the blocks without the stop point) gets the same
    room against its absolute error (``pred_full``: the full fit on the held-out rays).
    Should the held-out error still miss (holes, or rays between the grid's points), the
    budget is quartered and the cut tried again, twice at most."""
    cells = values.size
    room = (PRUNE_SHARE * target) ** 2 - rms_full**2
    if room <= 0.0:
        return None
    budget = room * cells / scale**2
    piston = None  # shares the budget
    if phase:
        absolute = float(np.sqrt(np.mean((pred_full - y_te) ** 2)) * scale)
        piston = max((PRUNE_SHARE * target) ** 2 - absolute**2, 0.0) * cells / scale**2
    fill = tf.grid(a_hat, v_hat) if tf.holes else None
    n_full = int(np.count_nonzero(tf.W))
    for _ in range(3):
        support = prune_support(tf.aperture_exps, tf.field_exps, tf.energy, budget, piston)
        cut = fit_tensor(a_hat, v_hat, values, mask, tf.aperture_exps, tf.field_exps,
                         parity=parity, fill=fill, support=support, weights=weights)
        if np.count_nonzero(cut.W) >= n_full:
            return None
        pred = _evaluate_tensor(cut, xe)
        err = error_metric(out, pred, y_te, group_te)
        rms = float(np.sqrt(np.mean(err * err)))
        if rms <= target:
            return _tensor_polynomial(out, unit, cut, n_inputs), err, pred, rms
        budget, piston = budget / 4.0, None if piston is None else piston / 4.0
    return None


def _evaluate_tensor(tf, xe: np.ndarray) -> np.ndarray:
    """The tensor fit ``tf`` at normalised inputs ``xe`` (N, 6), single-threaded BLAS."""
    with single_blas():
        return tf.evaluate(xe[:, list(APERTURE)], xe[:, list(FIELD)])


def _tensor_polynomial(out: str, unit: str, tf, n_inputs: int) -> Polynomial:
    """The tensor fit as a Polynomial over the system's six inputs."""
    a_e, f_e, coef = tf.terms()
    exps = np.zeros((len(coef), n_inputs), dtype=np.int32)
    exps[:, list(APERTURE)] = a_e
    exps[:, list(FIELD)] = f_e
    return Polynomial(out, unit, exps, coef)

