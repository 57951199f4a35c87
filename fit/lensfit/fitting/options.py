"""Budgets, targets and the column layout shared by both fitting methods."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

WAVE_MM = 550e-6  # OPL errors are quoted in waves at 550 nm
APERTURE = (3, 4)  # columns of x_a, y_a in both systems
X_LIKE, Y_LIKE = (0, 3), (1, 4)  # mirror pairs: (x_O|x_S, x_a) and (y_O|y_S, y_a)
FIELD = (0, 1, 2, 5)  # the inputs a renderer fixes per pixel (or light) and wavelength
METHODS = ("tensor", "pursuit")
STAGNATION = 0.7  # a field degree that leaves more than this share of the error stalls
# Adaptive fits (FitOptions.prune): the degrees grow until the held-out error is this share
# of the target, then the terms it does not need are cut until the error is PRUNE_SHARE of
# it, the rest of the target left as margin for the PSF (module doc of lensfit.fitting)
GROW_SHARE = 0.6
PRUNE_SHARE = 0.8


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
    groups: int = 2000  # field points of the grid, to begin with
    aperture_points: int = 128  # stop points per field point (a multiple of 4), to begin with
    # The grid doubles in a dimension (to these at most) while an output misses its target
    # for want of samples there (lensfit.fitting.tensor.fit_system_growing)
    max_groups: int = 8000
    max_aperture_points: int = 512
    aperture_degree: int = 10  # phi; positions and transmittance use 4 less
    max_aperture_degree: int = 14  # raised to (by 2, once) when the field degree stalls
    field_degrees: tuple[int, ...] = (4, 6, 8, 10, 12, 14)  # tried in turn against the target
    prune: bool = True  # cut the terms the target does not need (GROW_SHARE, PRUNE_SHARE)
    # Fit once more with a tighter phase target when the PSF check misses the target by
    # a little (lensfit.pipeline.stage._tighter)
    retry: bool = True
    # Measure the stop degree each system's phase needs before drawing its grid, start
    # there (with the stop points it needs), and refuse at once a system no stop degree
    # lensrt evaluates can bring near its target (lensfit.fitting.pilot); off for small
    # budgets (--quick, tests), which keep the degrees they ask for
    stop_pilot: bool = True
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
        # From 1e-6: a table refuses a trust psf_target below (lensfit.codegen.table,
        # TRUST_RANGES), and a fit should not run for hours to write one it cannot
        if not (math.isfinite(self.psf_target) and 1e-6 <= self.psf_target < 1.0):
            raise ValueError(f"fit options: psf_target = {self.psf_target!r}: expected a "
                             "relative error in [1e-6, 1), e.g. 0.01 for 1%")
        if self.target_waves is not None and not (self.target_waves > 0):
            raise ValueError(f"fit options: target_waves = {self.target_waves!r}: expected a "
                             "positive RMS in waves")
        if self.aperture_points <= 0 or self.aperture_points % 4:
            raise ValueError(f"fit options: aperture_points = {self.aperture_points}: expected "
                             "a positive multiple of 4 (mirror-symmetric sets)")
        if not self.field_degrees or min(self.field_degrees) < 0 or self.aperture_degree < 2:
            raise ValueError("fit options: field_degrees must be non-empty and >= 0, "
                             "aperture_degree >= 2")
        if self.max_groups < self.groups or (self.max_aperture_points < self.aperture_points
                                             or self.max_aperture_points % 4):
            raise ValueError(f"fit options: max_groups = {self.max_groups}, "
                             f"max_aperture_points = {self.max_aperture_points}: expected at "
                             "least groups and aperture_points, the latter a multiple of 4")
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

