"""The progress bar of `lensfit fit` (stderr, tqdm): one step per system's sampling,
per output fitted, and the PSF check, each weighted by its typical share of the wall
time so that the ETA is honest.

Shares measured on lens 0001 with the default options and domain (f/2, 380-780 nm),
lensfit.fitting.fit_lens with its progress callback and lensfit.trust.psf_vs_exact on a
shared 2-core machine (96.8 s in all): P_o sampled 11.5 s, P_o x_o/y_o/tau_o 0.1 s
each, phi_o 1.0 s, P_s sampled 12.8 s, x_i/y_i/tau_i 0.15 s each, phi_i 1.4 s, the PSF
check 69.3 s. A --quick fit has the same shape (sampling 3 s of 4 s fitting, PSF check
49 s), so one set of weights serves both.
"""

from __future__ import annotations

from collections.abc import Iterable

SAMPLING = 12.0  # seconds of the measurement above, per system
OUTPUT = {"phi": 1.2}  # the phase fits take longest
OTHER_OUTPUT = 0.13
PSF_CHECK = 69.0
RESOLUTION = 1000  # the bar counts thousandths of the whole fit


def step_weights(systems: Iterable[tuple[str, Iterable[str]]]) -> dict[str, float]:
    """{progress label: weight}: "<system> sampled", "<system> <output>" (the labels of
    lensfit.fitting.fit_lens's callback) and "psf"."""
    w: dict[str, float] = {}
    for name, outputs in systems:
        w[f"{name} sampled"] = SAMPLING
        for out in outputs:
            w[f"{name} {out}"] = OUTPUT.get(out.split("_")[0], OTHER_OUTPUT)
    w["psf"] = PSF_CHECK
    return w


class FitProgress:
    """A bar over the weighted steps; ``done`` steps (resumed from checkpoints) count
    as finished from the start, so the bar and its rate begin where they left off."""

    def __init__(self, weights: dict[str, float], done: Iterable[str] = (), *,
                 enabled: bool = True, desc: str = "fit") -> None:
        total = sum(weights.values())
        self._units = {k: v * RESOLUTION / total for k, v in weights.items()}
        self._order = list(weights)
        self._done = set()
        self._pos = 0.0
        self._bar = None
        for label in done:
            self._advance(label)
        if enabled:
            from tqdm import tqdm

            self._bar = tqdm(total=RESOLUTION, initial=round(self._pos), desc=desc,
                             unit="‰", dynamic_ncols=True, leave=False,
                             bar_format="{desc}: {percentage:3.0f}%|{bar}| "
                                        "[{elapsed}<{remaining}{postfix}]")
            self._bar.set_postfix_str(self._next(), refresh=True)

    def _next(self) -> str:
        """The step under way: the first not finished."""
        return next((k for k in self._order if k not in self._done), "")

    def _advance(self, label: str) -> int:
        if label in self._done or label not in self._units:
            return 0
        self._done.add(label)
        before = round(self._pos)
        self._pos += self._units[label]
        return round(self._pos) - before

    def __call__(self, label: str) -> None:
        """A step finished (fit_lens's callback)."""
        step = self._advance(label)
        if self._bar is not None:
            self._bar.set_postfix_str(self._next(), refresh=False)
            self._bar.update(step)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
