"""The stop degree a system's phase needs, measured before its grid is drawn.

A tensor fit's polynomial, at any one field point, is a polynomial in the stop point of
the fit's stop degree: its error there is at least that of the best such polynomial
fitted to that field point's rays alone. The pilot measures that floor where it is
highest (the edges of the field or image circle, at both ends of the wavelength band and
of the focus or distance range): a few field points, each with many rays on the stop, one
small least squares per stop degree. It costs a second or two, and says

* the stop degree to start the ladder at (:func:`fit_system_tensor`, whose stagnation rule
  otherwise finds it one raise at a time, and only after the field degrees stalled), and
  so how many stop points the grid needs to determine it;
* that no stop degree the runtime can evaluate (lensrt's limit, 15 per input) reaches the
  target: the fit is then refused at once, where it used to climb its field degrees for
  minutes first.

Measured (worst over the pilot's field points, waves at 550 nm, stop degrees 8, 10, 12,
14; the target 5.6e-4): lens 0001's scene side 1.0e-3, 5.4e-5, 3.0e-6, 2.0e-7 (the
default degree 10 is enough); 0009's 1.0e-2, 1.0e-3, 1.2e-4, 1.5e-5 (12, with 256 stop
points, where the ladder used to find it by a raise and a regrown grid); 0007's (f/2
over 35 degrees) 0.45, 0.21, 0.14, 0.21: its pupil map has a singularity just outside
the stop at the field's edge, and no degree comes near.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lensfit.fitting.options import WAVE_MM
from lensfit.poly.polynomial import design_matrix
from lensfit.poly.tensor import aperture_exponents, single_blas, symmetric_disc_points
from lensfit.prescription.model import Lens
from lensfit.sample.aim import SamplingError, aim_object_side, aim_sensor_side
from lensfit.sample.domain import Domain

PILOT_POINTS = 1024  # stop points per pilot field point (a multiple of 4)
PILOT_DEGREES = (8, 10, 12, 14)  # stop degrees tried (14: the highest even one lensrt takes)
# A stop degree is enough when its floor is at most this share of the target: the field
# polynomial adds its own error on top (GROW_SHARE leaves 0.6 of the target in all)
PILOT_SHARE = 0.3
# Out of reach when even the highest degree's floor is this many times the target (the
# rule of lensfit.fitting.tensor.OUT_OF_REACH: a PSF error ten times the target)
PILOT_OUT_OF_REACH = 10.0
MIN_RAYS = 64  # a pilot field point with fewer passing rays is not judged


@dataclass
class StopPilot:
    """The floor of a system's phase error per stop degree, where it is highest."""

    system: str
    floors: dict[int, float] = field(default_factory=dict)  # stop degree -> waves RMS
    where: dict[int, str] = field(default_factory=dict)  # stop degree -> field point
    target: float = 0.0

    def degree(self) -> int | None:
        """The lowest stop degree whose floor is within PILOT_SHARE of the target; None
        when none is."""
        for d in sorted(self.floors):
            if self.floors[d] <= PILOT_SHARE * self.target:
                return d
        return None

    def out_of_reach(self) -> bool:
        """Even the highest degree tried stays PILOT_OUT_OF_REACH times the target."""
        return bool(self.floors) and min(self.floors.values()) > PILOT_OUT_OF_REACH * self.target

    def describe(self) -> str:
        d = max(self.floors)
        return (f"{self.system}'s phase, at one field point alone ({self.where[d]}), "
                f"reaches {self.floors[d]:.3g} waves RMS at stop degree {d}, the highest "
                f"lensrt evaluates, against the target {self.target:.3g}")


def _field_points(domain: Domain, system: str) -> list[tuple[str, tuple[float, ...]]]:
    """(label, raw field inputs) where the stop map is hardest: the edge of the field
    (x and the diagonal) and 70% of it, at both ends of the band and of the third input
    (inverse distance or sensor shift), as GridSamples.field rows."""
    lams = (domain.wavelength_min_nm, domain.wavelength_max_nm)
    if system == "P_o":
        sx, sy = (math.sin(math.radians(f)) for f in domain.field_xy_deg)
        thirds = (0.0, domain.inverse_distance_max)
        edge = [("x edge", (sx, 0.0)), ("corner", (sx / math.sqrt(2), sy / math.sqrt(2))),
                ("70% x", (0.7 * sx, 0.0))]
    else:
        h = domain.sensor_radius_mm
        thirds = (domain.focus_min_mm, domain.focus_max_mm)
        edge = [("x edge", (h, 0.0)), ("corner", (h / math.sqrt(2), h / math.sqrt(2))),
                ("70% x", (0.7 * h, 0.0))]
    return [(f"{name}, {lam:g} nm", (x, y, t, lam))
            for name, (x, y) in edge for lam in lams for t in thirds]


def stop_pilot(lens: Lens, domain: Domain, system: str, target_waves: float,
               seed: int) -> StopPilot:
    """The floor of ``system``'s phase error (waves RMS at 550 nm, piston removed, on a
    quarter of the rays held out, rays that pass every housing) per stop degree of
    PILOT_DEGREES: the worst over the pilot's field points (module doc)."""
    rng = np.random.default_rng(seed)
    r = domain.stop_radius_mm
    ap = symmetric_disc_points(rng, PILOT_POINTS, 0.5) * r
    held = np.arange(PILOT_POINTS) % 4 == 0
    pilot = StopPilot(system, target=target_waves)
    basis = {d: design_matrix(ap / r, aperture_exponents(d)) for d in PILOT_DEGREES}
    aim = aim_object_side if system == "P_o" else aim_sensor_side
    for label, (x, y, t, lam) in _field_points(domain, system):
        try:
            a = aim(lens, x, y, t, ap[:, 0], ap[:, 1], lam)
        except SamplingError:
            continue
        with np.errstate(invalid="ignore"):
            ok = a.ok & (a.vignetting <= 1.0)
        fit, test = ok & ~held, ok & held
        if np.count_nonzero(test) < MIN_RAYS // 4 or np.count_nonzero(fit) < MIN_RAYS:
            continue
        phi = a.outputs[:, 3]
        for d, B in basis.items():
            if np.count_nonzero(fit) < 2 * B.shape[1]:
                continue  # too few rays pass here to tell this degree's floor
            with single_blas():  # small solves: BLAS threads only wait on a busy machine
                coef, *_ = np.linalg.lstsq(B[fit], phi[fit], rcond=None)
            e = B[test] @ coef - phi[test]
            e = (e - e.mean()) / WAVE_MM
            rms = float(np.sqrt(np.mean(e * e)))
            if rms > pilot.floors.get(d, -1.0):
                pilot.floors[d], pilot.where[d] = rms, label
    return pilot


def points_for_degree(degree: int) -> int:
    """Stop points (a multiple of 128) that determine a stop polynomial of ``degree`` as
    lensfit's default grid determines degree 10: K mirror-symmetric points give each
    parity class K/4 distinct points, and the largest class may have at most 2/3 as many
    monomials (21 of 32 at the default's 128 points and degree 10; 256 points for 12
    and 14)."""
    e = aperture_exponents(degree)
    largest = max(int(np.sum((e[:, 0] % 2 == cx) & (e[:, 1] % 2 == cy)))
                  for cx in (0, 1) for cy in (0, 1))
    return 128 * max(1, math.ceil(4 * 1.5 * largest / 128))
