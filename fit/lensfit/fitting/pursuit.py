"""The first fits' method: sparse polynomials in all six inputs by orthogonal least
squares (``FitOptions.method = "pursuit"``)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lensfit.common.errors import InputError
from lensfit.fitting.options import APERTURE, FitOptions
from lensfit.fitting.results import (
    OutputFit,
    _group_centre,
    _group_means,
    _output_fit,
    _parity_mask,
    _pick,
    error_metric,
)
from lensfit.poly.omp import OmpPath, omp
from lensfit.poly.polynomial import Input, Polynomial, System, design_matrix, monomials
from lensfit.sample.rays import TRAIN_VIGNETTING, Samples


def _pursue(A_train, y_train, A_test, name, test_group, y_test, max_terms, target):
    """OMP with the held-out error of every prefix of the path; stops once the target is
    reached on held-out rays."""
    history: list[float] = []

    def stop(k: int, support: np.ndarray, coef: np.ndarray) -> bool:
        pred = A_test[:, support] @ coef
        err = error_metric(name, pred, y_test, test_group)
        history.append(float(np.sqrt(np.mean(err * err))))
        return history[-1] <= target

    path = omp(A_train, y_train, max_terms=max_terms, stop=stop, criterion="ols")
    return path, np.array(history)


def fit_system(name: str, inputs: tuple[Input, ...], outputs, train: Samples, test: Samples,
               options: FitOptions, progress: Callable[[str], None] | None = None
               ) -> tuple[System, list[OutputFit]]:
    """Fit every output of one system to its samples."""
    fit_rows = train.vignetting <= TRAIN_VIGNETTING
    if not np.any(fit_rows):
        raise InputError(f"{name}: no training ray within {TRAIN_VIGNETTING} of the housings")
    tr, te = train.subset(fit_rows), test.subset(test.passes)
    if len(te) == 0:
        raise InputError(f"{name}: no held-out ray passes the lens")
    scaffold = System(name, inputs, ())
    xt, xe = scaffold.normalise(tr.inputs), scaffold.normalise(te.inputs)
    exps = monomials(len(inputs), options.max_degree)
    phase_exps = monomials(len(inputs), options.phase_degree)

    polys: list[Polynomial] = []
    fits: list[OutputFit] = []
    for j, (out, unit) in enumerate(outputs):
        odd_x, odd_y = out.startswith("x_"), out.startswith("y_")
        pool = phase_exps if out.startswith("phi") else exps
        cand = pool[_parity_mask(pool, odd_x, odd_y)]
        y_tr, y_te = tr.outputs[:, j], te.outputs[:, j]
        if out.startswith("phi"):
            poly, of = _fit_phase(out, unit, cand, xt, xe, tr, te, y_tr, y_te, options)
        else:
            target = options.target_tau if out.startswith("tau") else options.target_position_um
            A_tr, A_te = design_matrix(xt, cand), design_matrix(xe, cand)
            path, hist = _pursue(A_tr, y_tr, A_te, out, te.group, y_te, options.max_terms,
                                 target)
            k = _pick(hist, target)
            poly = Polynomial(out, unit, cand[path.support[:k]], path.coefficients(k))
            err = error_metric(out, poly.evaluate_normalised(xe), y_te, te.group)
            of = _output_fit(name, out, poly, err, hist, target,
                             "1" if out.startswith("tau") else "um")
        polys.append(poly)
        fits.append(of)
        if progress is not None:
            progress(f"{name} {out}")
    return System(name, inputs, tuple(polys)), fits



def _fit_phase(out, unit, cand, xt, xe, tr, te, y_tr, y_te, options):
    """The stop-dependent part on group-centred data, then the piston."""
    has_ap = cand[:, APERTURE[0]] + cand[:, APERTURE[1]] > 0
    ap_cand, pist_cand = cand[has_ap], cand[~has_ap]
    A_tr = _group_centre(design_matrix(xt, ap_cand), tr.group)
    A_te = design_matrix(xe, ap_cand)
    yc = _group_centre(y_tr, tr.group)
    path, hist = _pursue(A_tr, yc, A_te, out, te.group, y_te, options.max_terms,
                         options.phase_target_waves)
    del A_tr
    k = _pick(hist, options.phase_target_waves)
    ap_exps, ap_coef = ap_cand[path.support[:k]], path.coefficients(k)
    # The piston: group means of what is left, against the non-stop monomials
    left = y_tr - design_matrix(xt, ap_exps) @ ap_coef
    inv, means = _group_means(left, tr.group)
    first = np.unique(inv, return_index=True)[1]  # one row per group, in the means' order
    P = design_matrix(xt[first], pist_cand)
    pist_path: OmpPath = omp(P, means, max_terms=min(options.piston_terms, len(pist_cand)),
                             tol=1e-7, criterion="ols")  # 0.1 nm: the piston needs no more
    kp = pist_path.terms
    exps = np.concatenate([ap_exps, pist_cand[pist_path.support[:kp]]])
    coef = np.concatenate([ap_coef, pist_path.coefficients(kp)])
    poly = Polynomial(out, unit, exps, coef)
    pred = poly.evaluate_normalised(xe)
    err = error_metric(out, pred, y_te, te.group)
    absolute = float(np.sqrt(np.mean((pred - y_te) ** 2)) * 1e3)
    return poly, _output_fit(tr.system, out, poly, err, hist, options.phase_target_waves, "waves",
                             piston_terms=kp, absolute_rms_um=absolute)

