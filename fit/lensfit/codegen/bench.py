"""Benchmark of the generated C: ``python -m lensfit.codegen.bench [--native]``.

Times the hand-emitted Horner code against casadi's C (monomial and Horner forms, and
casadi's Jacobian) for a random stand-in of a fitted system, 6 inputs and 4 outputs of
150 terms of degree <= 9, with the driver of :mod:`lensfit.codegen.timing`.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from contextlib import ExitStack

import numpy as np

from lensfit.codegen.c_casadi import emit_casadi_c
from lensfit.codegen.c_horner import emit_horner_c
from lensfit.codegen.horner import naive_multiplications, plan_system
from lensfit.codegen.timing import DEFAULT_FLAGS, timer
from lensfit.poly import Input, Polynomial, System, monomials


def benchmark_system(seed: int = 0, terms: int = 150, max_degree: int = 9) -> System:
    """A stand-in for a fitted P_o: 6 inputs (wavelength as inverse_square, 380-780 nm),
    4 outputs of ``terms`` distinct random terms, degree drawn uniformly in
    0..max_degree, coefficients of mixed sign and magnitude (1e-6 .. 1e3)."""
    rng = np.random.default_rng(seed)
    inputs = (Input("x_O", "mm", -12.0, 12.0), Input("y_O", "mm", -12.0, 12.0),
              Input("1/d_O", "1/mm", 0.0, 0.01), Input("x_a", "mm", -20.0, 20.0),
              Input("y_a", "mm", -20.0, 20.0), Input("λ", "nm", 380.0, 780.0, "inverse_square"))
    table = monomials(len(inputs), max_degree)
    degree = table.sum(axis=1)
    outputs = []
    for name, unit in (("x_o", "mm"), ("y_o", "mm"), ("τ_o", "1"), ("φ_o", "mm")):
        chosen: set[int] = set()
        while len(chosen) < terms:
            d = int(rng.integers(0, max_degree + 1))
            chosen.add(int(rng.choice(np.flatnonzero(degree == d))))
        coefs = rng.choice([-1.0, 1.0], terms) * 10.0 ** rng.uniform(-6, 3, terms)
        outputs.append(Polynomial(name, unit, table[sorted(chosen)], coefs))
    return System("P_o", inputs, tuple(outputs))


def main(argv: Sequence[str] | None = None) -> None:
    """``python -m lensfit.codegen.bench``: ns/evaluation of the generated C variants for
    :func:`benchmark_system`; each figure is the median over ``--rounds`` interleaved
    rounds of a best-of-repeats measurement (robust on a shared machine)."""
    ap = argparse.ArgumentParser(prog="python -m lensfit.codegen.bench")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--terms", type=int, default=150)
    ap.add_argument("--degree", type=int, default=9)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--native", action="store_true", help="add -march=native")
    ap.add_argument("--cflag", action="append", default=[],
                    help="one more compiler flag (repeatable), e.g. --cflag=-ffp-contract=fast")
    args = ap.parse_args(argv)
    system = benchmark_system(args.seed, args.terms, args.degree)
    flags = (*DEFAULT_FLAGS, *(["-march=native"] if args.native else []), *args.cflag)
    plan = plan_system(system.outputs)
    print(f"system: 6 inputs, 4 outputs x {args.terms} terms, degree <= {args.degree}; "
          f"Horner {plan.multiplications} multiplications (powers included), expanded sum "
          f"{sum(naive_multiplications(p) for p in system.outputs)} plus powers; "
          f"flags {' '.join(flags)}")
    p = "bench_"
    horner = emit_horner_c([system], p)
    monomial = emit_casadi_c([system], p)
    casadi_horner = emit_casadi_c([system], p, form="horner")
    cases = []
    for v in ("d", "f"):
        cases += [("Horner (hand-emitted)", horner, f"{p}P_o_{v}", v, None),
                  ("casadi, monomial form", monomial, f"{p}P_o_casadi_{v}", v, None),
                  ("casadi, Horner form", casadi_horner, f"{p}P_o_casadi_{v}", v, None)]
    cases.append(("casadi Jacobian, monomial", monomial, f"{p}P_o_casadi_jac_d", "d", 24))
    with ExitStack() as stack:
        runs = [stack.enter_context(timer(src, fn, system, variant=v, n_outputs=n,
                                          repeats=5, min_seconds=0.02, flags=flags))
                for _, src, fn, v, n in cases]
        times: list[list[float]] = [[] for _ in cases]
        for _ in range(args.rounds):
            for t, run in zip(times, runs, strict=True):
                t.append(run())
    for (name, _, _, v, _), t in zip(cases, times, strict=True):
        print(f"{name:27s} {'double' if v == 'd' else 'float':6s} "
              f"{float(np.median(t)):7.1f} ns/eval   rounds: {' '.join(f'{x:.0f}' for x in t)}")


if __name__ == "__main__":
    main()
