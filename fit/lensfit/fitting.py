"""Fit P_o and P_s of a lens: sample rays, pursue sparse polynomials, measure held-out error.

How each output is fitted:

* **Symmetry.** Lenses here are centred and their cylinders aligned with x or y, so every
  system is mirror-symmetric in x and in y. Candidate monomials must have the output's
  parity in the x-like inputs (x_O or x_S, and x_a) and in the y-like ones: even for
  tau and phi, odd in x for x_o and x_i, odd in y for y_o and y_i. That removes three
  quarters of the dictionary and makes the fitted systems exactly symmetric.
* **Phase without piston.** A part of the OPL that does not depend on the stop point is a
  constant phase per pixel (per light and wavelength), which does not change intensity.
  phi is therefore fitted in two parts: the stop-dependent part by OMP on data and
  columns centred within each group of samples sharing their non-stop inputs (all the
  term budget goes where it matters), then the piston (the group means left over) by a
  small OMP over monomials of the non-stop inputs only. The report gives the error
  after piston removal (what intensity sees) and the absolute OPL error apart.
* **Held-out error** decides the term count: the fewest terms that reach the target,
  else the count with the smallest held-out error within the budget.

Two methods (``FitOptions.method``):

* ``"tensor"`` (default): rays on a grid of field points (scene or sensor point, focus,
  wavelength) times one mirror-symmetric set of stop points, fitted by the tensor least
  squares of :mod:`lensfit.poly.tensor`: every aperture monomial up to
  ``aperture_degree`` times every field monomial up to a field degree, the smallest
  degree of ``field_degrees`` whose held-out error reaches the target. The field
  inputs are fixed per pixel and wavelength by a renderer, which folds them away before
  it sums phasors, so field terms cost set-up, not splats. Measured on lens 0001 over
  its whole declared domain: phi held-out RMS 0.089 waves (pursuit, 240 terms) against
  2e-4 waves (tensor, degree 10 x 10).
* ``"pursuit"``: sparse polynomials in all six inputs by orthogonal least squares
  (below), the method of the first fits.

**Targets from the PSF.** The relative L2 change of a PSF is about 2 x 2 pi x the RMS
phase error in waves (measured on aberrated lenses and 0001, shared/DESIGN.md); P_o and
P_s errors add in quadrature, so each system's phase target is
``psf_target / (4 pi sqrt 2)`` waves unless ``target_waves`` is given.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from lensfit.errors import InputError
from lensfit.poly.omp import OmpPath, omp
from lensfit.poly.polynomial import Input, Polynomial, System, design_matrix, monomials
from lensfit.poly.tensor import aperture_exponents, field_exponents, fit_tensor, single_blas
from lensfit.prescription.model import Lens
from lensfit.sample.domain import Domain, default_domain
from lensfit.sample.rays import (
    OUTPUTS_O,
    OUTPUTS_S,
    GridSamples,
    Samples,
    sample_grid,
    sample_object_side,
    sample_sensor_side,
)

WAVE_MM = 550e-6  # OPL errors are quoted in waves at 550 nm
TRAIN_VIGNETTING = 1.1  # train on rays up to 10% beyond a housing, so the clip edge fits
APERTURE = (3, 4)  # columns of x_a, y_a in both systems
X_LIKE, Y_LIKE = (0, 3), (1, 4)  # mirror pairs: (x_O|x_S, x_a) and (y_O|y_S, y_a)
FIELD = (0, 1, 2, 5)  # the inputs a renderer fixes per pixel (or light) and wavelength
METHODS = ("tensor", "pursuit")
STAGNATION = 0.7  # a field degree that leaves more than this share of the error stalls


@dataclass(frozen=True)
class FitOptions:
    """Budgets and targets. Zero-valued fields are never meaningful: all have defaults."""

    method: str = "tensor"  # or "pursuit"
    psf_target: float = 0.01  # relative L2 of a PSF against exactly traced rays
    target_waves: float | None = None  # phi RMS after piston removal (waves at 550 nm);
    #                                    None: derived from psf_target
    target_position_um: float = 0.5  # x_o, y_o, x_i, y_i RMS
    target_tau: float = 1e-4  # relative RMS of tau
    test_groups: int = 400
    test_per_group: int = 16
    seed: int = 1
    # tensor method
    groups: int = 4000  # field points of the grid
    aperture_points: int = 128  # stop points per field point (a multiple of 4)
    aperture_degree: int = 10  # phi; positions and transmittance use 4 less
    max_aperture_degree: int = 14  # raised to (by 2, once) when the field degree stalls
    field_degrees: tuple[int, ...] = (4, 6, 8, 10, 12)  # tried in turn against the target
    # pursuit method
    max_degree: int = 9  # positions and transmittance
    phase_degree: int = 9  # phi: degree 11 measured no better at f/2 with 200 terms
    max_terms: int = 200  # per output (phi: the stop-dependent part)
    piston_terms: int = 40  # phi's stop-independent part
    train_groups: int = 2500
    train_per_group: int = 8

    def __post_init__(self) -> None:
        object.__setattr__(self, "field_degrees", tuple(int(d) for d in self.field_degrees))
        if self.method not in METHODS:
            raise ValueError(f"fit options: method = {self.method!r}: expected one of "
                             f"{', '.join(METHODS)}")
        if not (math.isfinite(self.psf_target) and 0.0 < self.psf_target < 1.0):
            raise ValueError(f"fit options: psf_target = {self.psf_target!r}: expected a "
                             "relative error in (0, 1), e.g. 0.01 for 1%")
        if self.target_waves is not None and not (self.target_waves > 0):
            raise ValueError(f"fit options: target_waves = {self.target_waves!r}: expected a "
                             "positive RMS in waves")
        if self.aperture_points <= 0 or self.aperture_points % 4:
            raise ValueError(f"fit options: aperture_points = {self.aperture_points}: expected "
                             "a positive multiple of 4 (mirror-symmetric sets)")
        if not self.field_degrees or min(self.field_degrees) < 0 or self.aperture_degree < 2:
            raise ValueError("fit options: field_degrees must be non-empty and >= 0, "
                             "aperture_degree >= 2")
        if not self.aperture_degree <= self.max_aperture_degree <= 15:
            raise ValueError(f"fit options: max_aperture_degree = {self.max_aperture_degree}: "
                             "expected aperture_degree..15 (lensrt's limit)")

    @property
    def phase_target_waves(self) -> float:
        """Each system's phi target: given, or psf_target / (4 pi sqrt 2) (module doc)."""
        if self.target_waves is not None:
            return float(self.target_waves)
        return self.psf_target / (4.0 * math.pi * math.sqrt(2.0))

    def to_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["field_degrees"] = list(self.field_degrees)
        return d


@dataclass
class OutputFit:
    """How one output was fitted and how good it is on held-out rays."""

    system: str
    name: str
    unit: str  # unit of rms/max below
    terms: int
    max_degree: int
    rms: float
    max: float
    path_terms: list[int]  # Pareto data: terms ...
    path_rms: list[float]  # ... and held-out RMS after that many terms
    target: float
    reached: bool
    piston_terms: int = 0
    absolute_rms_um: float | None = None  # phi only: error including piston, micrometres
    ns_per_eval_double: float | None = None  # filled in by code generation
    ns_per_eval_float: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class SystemFit:
    system: System
    outputs: list[OutputFit]
    train: Samples | GridSamples
    test: Samples
    seconds_sampling: float
    seconds_fitting: float


def _parity_mask(exps: np.ndarray, odd_x: bool, odd_y: bool) -> np.ndarray:
    px = (exps[:, X_LIKE[0]] + exps[:, X_LIKE[1]]) % 2 == int(odd_x)
    py = (exps[:, Y_LIKE[0]] + exps[:, Y_LIKE[1]]) % 2 == int(odd_y)
    return px & py


def _group_means(a: np.ndarray, group: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(per-row group index into the means, mean of each group's rows of a (1-D or 2-D)),
    groups in ascending id order."""
    _, inv, counts = np.unique(group, return_inverse=True, return_counts=True)
    sums = np.zeros((len(counts),) + a.shape[1:])
    np.add.at(sums, inv, a)
    return inv, sums / counts.reshape((-1,) + (1,) * (a.ndim - 1))


def _group_centre(a: np.ndarray, group: np.ndarray) -> np.ndarray:
    """Subtract from each row the mean of its group (rows of a 1-D or 2-D array)."""
    inv, means = _group_means(a, group)
    return a - means[inv]


def error_metric(name: str, pred: np.ndarray, true: np.ndarray, group: np.ndarray):
    """Error in report units: um for positions, relative for tau, waves (piston removed)."""
    if name.startswith("phi"):
        return _group_centre(pred - true, group) / WAVE_MM
    if name.startswith("tau"):
        return (pred - true) / true
    return (pred - true) * 1e3


def _pick(path_rms: np.ndarray, target: float) -> int:
    """Fewest terms reaching the target, else the best held-out count (1-based)."""
    hit = np.nonzero(path_rms <= target)[0]
    return int(hit[0] + 1) if hit.size else int(np.argmin(path_rms) + 1)


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
               options: FitOptions) -> tuple[System, list[OutputFit]]:
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
    return System(name, inputs, tuple(polys)), fits


def _output_fit(system, out, poly, err, hist, target, unit, **extra) -> OutputFit:
    rms = float(np.sqrt(np.mean(err * err)))
    return OutputFit(
        system=system, name=out, unit=unit, terms=poly.terms, max_degree=poly.max_degree,
        rms=rms, max=float(np.max(np.abs(err))), path_terms=list(range(1, len(hist) + 1)),
        path_rms=[float(h) for h in hist], target=target, reached=rms <= target, **extra,
    )


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


def fit_system_tensor(name: str, inputs: tuple[Input, ...], outputs, train: GridSamples,
                      test: Samples, options: FitOptions) -> tuple[System, list[OutputFit]]:
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


def fit_lens(lens: Lens, domain: Domain | None = None,
             options: FitOptions | None = None) -> list[SystemFit]:
    """Sample and fit both systems of ``lens`` over ``domain`` (default: its default)."""
    domain = domain or default_domain(lens)
    options = options or FitOptions()
    results = []
    for name, sampler, inputs, outputs, salt in (
        ("P_o", sample_object_side, domain.inputs_o(), OUTPUTS_O, 0),
        ("P_s", sample_sensor_side, domain.inputs_s(), OUTPUTS_S, 1),
    ):
        t0 = time.perf_counter()
        seed = 2 * (options.seed * 7919 + salt)
        if options.method == "tensor":
            train = sample_grid(lens, domain, name, options.groups, options.aperture_points,
                                seed=seed)
        else:
            train = sampler(lens, domain, options.train_groups, options.train_per_group,
                            seed=seed)
        test = sampler(lens, domain, options.test_groups, options.test_per_group,
                       seed=seed + 1)
        t1 = time.perf_counter()
        if options.method == "tensor":
            system, fits = fit_system_tensor(name, inputs, outputs, train, test, options)
        else:
            system, fits = fit_system(name, inputs, outputs, train, test, options)
        t2 = time.perf_counter()
        system.info.update({"lens": lens.name, "domain": domain.to_dict()})
        results.append(SystemFit(system, fits, train, test, t1 - t0, t2 - t1))
    return results
