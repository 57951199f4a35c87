"""Both systems of a lens: sample, then fit each by the chosen method."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol

from lensfit.fitting.options import FitOptions
from lensfit.fitting.pilot import PILOT_DEGREES, points_for_degree, stop_pilot
from lensfit.fitting.pursuit import fit_system
from lensfit.fitting.results import SystemFit
from lensfit.fitting.tensor import OutOfReach, fit_system_growing
from lensfit.poly.polynomial import Input
from lensfit.prescription.model import Lens
from lensfit.sample.domain import Domain, default_domain, describe_domain
from lensfit.sample.rays import (
    OUTPUTS_O,
    OUTPUTS_S,
    sample_grid,
    sample_object_side,
    sample_sensor_side,
)


class Checkpoints(Protocol):
    """Where finished systems are kept and found again (lensfit.pipeline.cache.FitCache)."""

    def load_system(self, name: str, inputs: tuple[Input, ...] | None = None
                    ) -> SystemFit | None: ...

    def save_system(self, fit: SystemFit) -> None: ...


SYSTEMS = (("P_o", OUTPUTS_O), ("P_s", OUTPUTS_S))  # in the order fit_lens fits them


def fit_lens(lens: Lens, domain: Domain | None = None,
             options: FitOptions | None = None,
             progress: Callable[[str], None] | None = None,
             checkpoints: Checkpoints | None = None) -> list[SystemFit]:
    """Sample and fit both systems of ``lens`` over ``domain`` (default: its default).
    ``progress`` is called with a label after each step: each system's sampling
    ("P_o sampled") and each output fitted ("P_o phi_o"); not for a system taken from
    ``checkpoints``, which also keeps each system fitted here. Each system's samples
    come from its own seed, so a system taken from a checkpoint leaves the other's fit
    unchanged, bit for bit."""
    domain = domain or default_domain(lens)
    options = options or FitOptions()
    results = []
    for name, sampler, inputs, outputs, salt in (
        ("P_o", sample_object_side, domain.inputs_o(), OUTPUTS_O, 0),
        ("P_s", sample_sensor_side, domain.inputs_s(), OUTPUTS_S, 1),
    ):
        done = checkpoints.load_system(name, inputs) if checkpoints is not None else None
        if done is not None:
            results.append(done)
            continue
        t0 = time.perf_counter()
        seed = 2 * (options.seed * 7919 + salt)
        stop_degree = options.aperture_degree
        if options.method == "tensor":
            points = options.aperture_points
            if options.stop_pilot:
                stop_degree, points = _piloted(lens, domain, name, options, seed)
            train = sample_grid(lens, domain, name, options.groups, points, seed=seed)
        else:
            train = sampler(lens, domain, options.train_groups, options.train_per_group,
                            seed=seed)
        test = sampler(lens, domain, options.test_groups, options.test_per_group,
                       seed=seed + 1)
        t1 = time.perf_counter()
        if progress is not None:
            progress(f"{name} sampled")
        if options.method == "tensor":
            try:
                system, fits, train = fit_system_growing(lens, domain, name, inputs, outputs,
                                                         train, test, options, seed=seed,
                                                         progress=progress,
                                                         aperture_degree=stop_degree)
            except OutOfReach as e:
                raise _refusal(lens, domain, str(e)) from None
        else:
            system, fits = fit_system(name, inputs, outputs, train, test, options, progress)
        t2 = time.perf_counter()
        system.info.update({"lens": lens.name, "domain": domain.to_dict()})
        results.append(SystemFit(system, fits, train, test, t1 - t0, t2 - t1))
        if checkpoints is not None:
            checkpoints.save_system(results[-1])
    return results


def _piloted(lens: Lens, domain: Domain, name: str, options: FitOptions, seed: int
             ) -> tuple[int, int]:
    """(stop degree, stop points) of system ``name``'s grid from its stop pilot
    (:mod:`lensfit.fitting.pilot`): the degree the phase needs at the field's edges (never
    below ``options.aperture_degree``, at most ``options.max_aperture_degree``) and the
    points that determine it (at most ``options.max_aperture_points``). Raises
    :class:`OutOfReach` when no stop degree comes within ten times the target."""
    pilot = stop_pilot(lens, domain, name, options.phase_target_waves, seed=seed + 7)
    if pilot.out_of_reach():
        raise _refusal(lens, domain, pilot.describe())
    if not pilot.floors:  # no pilot field point had rays enough to tell: the defaults
        return options.aperture_degree, options.aperture_points
    need = pilot.degree()
    need = max(PILOT_DEGREES) if need is None else need
    degree = min(max(options.aperture_degree, need), options.max_aperture_degree)
    points = options.aperture_points
    if degree > options.aperture_degree:
        points = min(max(points, points_for_degree(degree)), options.max_aperture_points)
    return degree, points


def _refusal(lens: Lens, domain: Domain, why: str) -> OutOfReach:
    """The one line `lensfit fit` exits 2 with for a lens out of reach: the lens file,
    its domain, ``why`` and what to change."""
    return OutOfReach(f"{lens.source_file or lens.name}: cannot be fitted over "
                      f"{describe_domain(lens, domain)}: {why}; a narrower field (--field) "
                      "or a smaller stop (--f-number) needs fewer terms")
