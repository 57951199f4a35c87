"""The default method: tensor least squares on a grid of field points times stop points
(:mod:`lensfit.poly.tensor`), per output."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from lensfit.errors import InputError
from lensfit.fitting.options import APERTURE, FIELD, STAGNATION, TRAIN_VIGNETTING, FitOptions
from lensfit.fitting.results import OutputFit, _output_fit, error_metric
from lensfit.poly.polynomial import Input, Polynomial, System
from lensfit.poly.tensor import aperture_exponents, field_exponents, fit_tensor, single_blas
from lensfit.sample.rays import GridSamples, Samples


def fit_system_tensor(name: str, inputs: tuple[Input, ...], outputs, train: GridSamples,
                      test: Samples, options: FitOptions,
                      progress: Callable[[str], None] | None = None
                      ) -> tuple[System, list[OutputFit]]:
    """Fit every output of one system on grid samples by tensor least squares (module
    doc): per output, the field degrees of ``options.field_degrees`` in turn until the
    held-out error reaches the target."""
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
    # Cells fitted: rays that exist and pass within 10% of every housing
    with np.errstate(invalid="ignore"):
        mask = train.ok & (train.vignetting <= TRAIN_VIGNETTING)
    if not np.any(mask):
        raise InputError(f"{name}: no training ray within {TRAIN_VIGNETTING} of the housings")
    polys: list[Polynomial] = []
    fits: list[OutputFit] = []
    for j, (out, unit) in enumerate(outputs):
        parity = (int(out.startswith("x_")), int(out.startswith("y_")))
        phase = out.startswith("phi")
        if phase:
            target, unit_err = options.phase_target_waves, "waves"
        elif out.startswith("tau"):
            target, unit_err = options.target_tau, "1"
        else:
            target, unit_err = options.target_position_um, "um"
        da = options.aperture_degree - (0 if phase else 4)
        values = np.where(mask, train.outputs[:, :, j], 0.0)
        hist: list[float] = []
        terms: list[int] = []
        best = None
        fill = None
        degrees = list(options.field_degrees)
        raised = just_raised = False  # the stop degree was raised (once at most)
        while degrees:
            degree = degrees[0]
            v_exps = field_exponents(len(FIELD), degree, caps)
            try:
                tf = fit_tensor(a_hat, v_hat, values, mask, aperture_exponents(da), v_exps,
                                parity=parity, fill=fill)
            except ValueError:  # more terms than the grid can determine
                break
            if tf.holes:  # the next rung starts from this one's values in the holes
                fill = tf.grid(a_hat, v_hat)
            poly = _tensor_polynomial(out, unit, tf, len(inputs))
            # The held-out rays through W's factors (stop monomials times W times field
            # monomials: one matrix product) rather than the polynomial's tens of thousands
            # of terms one by one: the same sum in another order, ~20x faster
            pred = _evaluate_tensor(tf, xe)
            err = error_metric(out, pred, te.outputs[:, j], te.group)
            rms = float(np.sqrt(np.mean(err * err)))
            hist.append(rms)
            terms.append(poly.terms)
            previous = best[0] if best is not None else math.inf
            if best is None or rms < best[0]:
                best = (rms, poly, err, pred)
            if rms <= target:
                break
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
        if best is None:
            raise ValueError(f"{name}: {out}: the grid of {len(train.field)} field points "
                             "cannot determine even the lowest field degree")
        _, poly, err, pred = best
        extra = {}
        if phase:  # terms without the stop point: the piston; and the error with it
            extra = {"piston_terms": int(np.sum(poly.exponents[:, list(APERTURE)].sum(1) == 0)),
                     "absolute_rms_um": float(np.sqrt(np.mean((pred - te.outputs[:, j]) ** 2))
                                              * 1e3)}
        of = _output_fit(name, out, poly, err, hist, target, unit_err, **extra)
        of.path_terms = terms
        polys.append(poly)
        fits.append(of)
        if progress is not None:
            progress(f"{name} {out}")
    return System(name, inputs, tuple(polys)), fits


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

