"""The progress bar of `lensfit fit` (stderr, tqdm): one step per system's sampling,
per output fitted, the PSF check, and writing the code and the report, each weighted by
its typical share of the wall time so that the ETA is honest.

Shares measured on lens 0001 with the default options and domain (f/2, 380-780 nm) as
lensfit.pipeline.stage runs them (single-threaded BLAS), on a shared 2-core machine, 57.5 s in
all: P_o sampled 6.3 s, x_o/y_o/tau_o 0.08 s each, phi_o 0.85 s; P_s sampled 6.7 s,
x_i/y_i/tau_i 0.07 s each, phi_i 0.7 s; the PSF check 22.9 s (40%); the generated
code, the held-out figures and the report's plots 19.5 s (34%; timing the C, without
--no-timing, adds to this last step).
"""

from __future__ import annotations

from collections.abc import Iterable

SAMPLING = 6.5  # seconds of the measurement above, per system
OUTPUT = {"phi": 0.8}  # the phase fits take longest
OTHER_OUTPUT = 0.08
PSF_CHECK = 23.0
WRITE = 19.5
RESOLUTION = 1000  # the bar counts thousandths of the whole fit


def step_weights(systems: Iterable[tuple[str, Iterable[str]]]) -> dict[str, float]:
    """{progress label: weight}: "<system> sampled", "<system> <output>" (the labels of
    lensfit.fitting.fit_lens's callback), "psf" and "write"."""
    w: dict[str, float] = {}
    for name, outputs in systems:
        w[f"{name} sampled"] = SAMPLING
        for out in outputs:
            w[f"{name} {out}"] = OUTPUT.get(out.split("_")[0], OTHER_OUTPUT)
    w["psf"] = PSF_CHECK
    w["write"] = WRITE
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
