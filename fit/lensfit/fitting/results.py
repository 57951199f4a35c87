"""What a fit reports per output, and the error metric it is judged by."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from lensfit.fitting.options import WAVE_MM, X_LIKE, Y_LIKE
from lensfit.poly.polynomial import System
from lensfit.sample.rays import GridSamples, Samples


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
    limit: str | None = None  # what stopped its degrees short of their goal (the target,
    #   or room to cut): "stop points", "field points" (too few samples) or "degree"
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



def _output_fit(system, out, poly, err, hist, target, unit, **extra) -> OutputFit:
    rms = float(np.sqrt(np.mean(err * err)))
    return OutputFit(
        system=system, name=out, unit=unit, terms=poly.terms, max_degree=poly.max_degree,
        rms=rms, max=float(np.max(np.abs(err))), path_terms=list(range(1, len(hist) + 1)),
        path_rms=[float(h) for h in hist], target=target, reached=rms <= target, **extra,
    )

