"""Compile generated C: a shared library for agreement tests, a driver for ns/evaluation.

The compiler is ``$CC`` or ``cc`` (CompilerNotFound otherwise). ``load_c`` builds
``-shared -fPIC`` and returns a ``ctypes`` library; ``call_c`` evaluates one generated
function row by row; ``check_compiles`` compiles with strict flags and fails on any
diagnostic. ``time_c`` links the sources with a small C driver (below) and returns the
best-of-repeats time of one call in nanoseconds; ``timer`` compiles once and runs the
driver as often as asked (see :mod:`lensfit.codegen.bench`).

The driver fills ``points`` raw inputs uniformly inside the system's domain (xorshift64*,
fixed seed), then times ``iters`` sweeps over them; every output of every call is added
to an accumulator written to a volatile at the end, and the generated function lives in
another translation unit (no LTO), so the calls cannot be optimised away. ``iters`` is
doubled until one repeat takes at least ``min_seconds``; the best of ``repeats`` repeats
is reported, which filters out interruptions by other processes.

Default flags: ``-O2 -std=c99``, no ``-march=native``: the numbers then describe code
that runs on any x86-64, and without FMA the double results stay bit-reproducible across
machines. Pass ``flags=(..., "-march=native")`` to measure the host's best.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from lensfit.codegen.common import REALS
from lensfit.poly import System

DEFAULT_FLAGS = ("-O2", "-std=c99")
_CTYPES = {"d": (ctypes.c_double, np.float64), "f": (ctypes.c_float, np.float32)}


class CompilerNotFound(RuntimeError):
    """No C compiler: set CC or install one (Debian: build-essential)."""


def find_cc() -> str:
    """Path of ``$CC`` (default ``cc``), or CompilerNotFound."""
    name = os.environ.get("CC", "cc")
    path = shutil.which(name)
    if path is None:
        raise CompilerNotFound(f"no C compiler {name!r} on PATH: set CC or install one "
                               "(Debian: apt-get install build-essential)")
    return path


def write_sources(sources: dict[str, str], folder: Path) -> list[Path]:
    """Write every file; return the .c files, sorted."""
    for name, text in sorted(sources.items()):
        if Path(name).name != name:
            raise ValueError(f"source name {name!r} must be a plain file name")
        (folder / name).write_text(text)
    return sorted(folder / n for n in sources if n.endswith(".c"))


def compile_c(sources: dict[str, str], output: Path, flags: Sequence[str],
              extra: Sequence[str] = ()) -> None:
    """Compile ``sources`` (written next to ``output``) into ``output``; CalledProcessError
    carries the compiler's message."""
    c_files = write_sources(sources, output.parent)
    cmd = [find_cc(), *flags, *extra, "-o", str(output), *map(str, c_files), "-lm"]
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=output.parent)
    if done.returncode != 0:
        raise subprocess.CalledProcessError(done.returncode, cmd, done.stdout, done.stderr)


def check_compiles(sources: dict[str, str],
                   flags: Sequence[str] = ("-std=c99", "-Wall", "-Wextra", "-pedantic",
                                           "-Werror")) -> None:
    """Compile every .c file with ``flags -c``; raise CalledProcessError on any diagnostic."""
    with tempfile.TemporaryDirectory(prefix="lensfit-cc-") as tmp:
        for c in write_sources(sources, Path(tmp)):
            cmd = [find_cc(), *flags, "-c", c.name, "-o", c.with_suffix(".o").name]
            done = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp)
            if done.returncode != 0 or done.stderr.strip():
                raise subprocess.CalledProcessError(done.returncode or 1, cmd, done.stdout,
                                                    done.stderr)


def load_c(sources: dict[str, str], flags: Sequence[str] = ("-O1", "-std=c99")) -> ctypes.CDLL:
    """Build the sources into a shared library and load it (the file is removed after
    loading; the mapping stays valid)."""
    with tempfile.TemporaryDirectory(prefix="lensfit-so-") as tmp:
        lib = Path(tmp) / "libgenerated.so"
        compile_c(sources, lib, flags, ("-shared", "-fPIC"))
        return ctypes.CDLL(str(lib))


def call_c(lib: ctypes.CDLL, function: str, x: np.ndarray, n_out: int,
           variant: str = "d") -> np.ndarray:
    """Call ``void function(const real in[], real out[])`` on each row of ``x`` (N, n_in);
    real is double ('d') or float ('f'); returns (N, n_out) float64."""
    ctype, dtype = _CTYPES[variant]
    fn = getattr(lib, function)
    fn.restype = None
    fn.argtypes = [ctypes.POINTER(ctype), ctypes.POINTER(ctype)]
    x = np.ascontiguousarray(np.atleast_2d(x), dtype=dtype)
    out = np.zeros((len(x), n_out), dtype=dtype)
    for row, res in zip(x, out, strict=True):
        fn(row.ctypes.data_as(ctypes.POINTER(ctype)), res.ctypes.data_as(ctypes.POINTER(ctype)))
    return out.astype(np.float64)


_DRIVER = r"""/* Timing driver written by lensfit.codegen.timing */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <time.h>

#define N_IN {n_in}
#define N_OUT {n_out}
#define POINTS {points}
#define REPEATS {repeats}
#define MIN_SECONDS {min_seconds}

typedef {real} real;
void {function}(const real in[N_IN], real out[N_OUT]);

static const double lo[N_IN] = {{{lo}}};
static const double hi[N_IN] = {{{hi}}};
static real xs[POINTS][N_IN];

static double now(void)
{{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}}

/* Seconds for iters sweeps over all points; every output feeds *acc */
static double sweep(long iters, real *acc)
{{
    real out[N_OUT];
    double t0 = now();
    long it;
    int i, k;
    for (it = 0; it < iters; ++it) {{
        for (i = 0; i < POINTS; ++i) {{
            {function}(xs[i], out);
            for (k = 0; k < N_OUT; ++k) *acc += out[k];
        }}
    }}
    return now() - t0;
}}

int main(void)
{{
    unsigned long long s = 0x9E3779B97F4A7C15ULL;
    volatile real sink;
    real acc = 0;
    double best = 1e300, t;
    long iters = 1;
    int i, j, r;
    for (i = 0; i < POINTS; ++i) {{
        for (j = 0; j < N_IN; ++j) {{
            double u;
            s ^= s >> 12; s ^= s << 25; s ^= s >> 27;
            u = (double)((s * 0x2545F4914F6CDD1DULL) >> 11) * (1.0 / 9007199254740992.0);
            xs[i][j] = (real)(lo[j] + (hi[j] - lo[j]) * u);
        }}
    }}
    while (sweep(iters, &acc) < MIN_SECONDS) iters *= 2;
    for (r = 0; r < REPEATS; ++r) {{
        t = sweep(iters, &acc) / ((double)iters * POINTS);
        if (t < best) best = t;
    }}
    sink = acc;
    (void)sink;
    printf("%.4f\n", best * 1e9);
    return 0;
}}
"""


@contextmanager
def timer(sources: dict[str, str], function: str, system: System, *, variant: str = "d",
          n_outputs: int | None = None, points: int = 4096, repeats: int = 7,
          min_seconds: float = 0.05,
          flags: Sequence[str] = DEFAULT_FLAGS) -> Iterator[Callable[[], float]]:
    """Compile once; yield a function that runs the driver and returns ns per call.

    ``n_outputs`` defaults to the system's (give N_OUT * N_IN for a Jacobian)."""
    if variant not in _CTYPES:
        raise ValueError(f"variant must be 'd' or 'f', got {variant!r}")
    if "lensfit_timing_driver.c" in sources:
        raise ValueError("a source is named like the driver: lensfit_timing_driver.c")
    driver = _DRIVER.format(
        n_in=len(system.inputs), n_out=n_outputs or len(system.outputs), points=points,
        repeats=repeats, min_seconds=repr(float(min_seconds)),
        real=REALS[variant], function=function,
        lo=", ".join(repr(float(i.lo)) for i in system.inputs),
        hi=", ".join(repr(float(i.hi)) for i in system.inputs))
    with tempfile.TemporaryDirectory(prefix="lensfit-time-") as tmp:
        exe = Path(tmp) / "bench"
        compile_c({**sources, "lensfit_timing_driver.c": driver}, exe, flags)

        def run() -> float:
            done = subprocess.run([str(exe)], capture_output=True, text=True, check=True)
            return float(done.stdout.strip())

        yield run


def time_c(sources: dict[str, str], function: str, system: System, *, variant: str = "d",
           n_outputs: int | None = None, points: int = 4096, repeats: int = 7,
           min_seconds: float = 0.05, flags: Sequence[str] = DEFAULT_FLAGS) -> float:
    """Nanoseconds per call of ``function(in, out)`` (best of ``repeats``), compiled from
    ``sources`` and the driver with ``flags``; inputs uniform in ``system``'s domain."""
    with timer(sources, function, system, variant=variant, n_outputs=n_outputs,
               points=points, repeats=repeats, min_seconds=min_seconds, flags=flags) as run:
        return run()
