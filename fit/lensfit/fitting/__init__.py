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

from lensfit.fitting.lens import fit_lens
from lensfit.fitting.options import (
    APERTURE,
    FIELD,
    METHODS,
    WAVE_MM,
    X_LIKE,
    Y_LIKE,
    FitOptions,
)
from lensfit.fitting.pursuit import fit_system
from lensfit.fitting.results import OutputFit, SystemFit, error_metric
from lensfit.fitting.tensor import fit_system_tensor
from lensfit.sample.rays import TRAIN_VIGNETTING

__all__ = ["APERTURE", "FIELD", "METHODS", "TRAIN_VIGNETTING", "WAVE_MM", "X_LIKE", "Y_LIKE",
           "FitOptions", "OutputFit", "SystemFit", "error_metric", "fit_lens", "fit_system",
           "fit_system_tensor"]
