"""Code generation for polynomial systems: C99, casadi's C, GLSL and coefficient tables.

* :func:`emit_c` (``which="horner"``, :mod:`~lensfit.codegen.c_horner`): hand-emitted
  multivariate Horner C99, double and float, one file pair per lens.
* ``which="casadi"`` (:mod:`~lensfit.codegen.c_casadi`): the symbolic layer; casadi's
  generated C for the values and the Jacobians with respect to the raw inputs.
* :func:`emit_glsl` (:mod:`~lensfit.codegen.glsl`): GLSL 4.30 functions of the same form.
* :func:`write_table` / :func:`read_table` (:mod:`~lensfit.codegen.table`): a plain-text
  coefficient table for generic evaluators, with the lens's first-order facts.
* :mod:`~lensfit.codegen.timing`: compile, load (ctypes) and time the generated C;
  ``python -m lensfit.codegen.bench`` compares Horner and casadi in ns/evaluation.

Every emitter returns ``{file name: text}``; the text depends only on the systems, the
prefix and the comment (byte for byte, whatever the hash seed or the order of terms).
"""

from __future__ import annotations

from collections.abc import Sequence

from lensfit.codegen.c_casadi import casadi_system, emit_casadi_c
from lensfit.codegen.c_horner import emit_horner_c
from lensfit.codegen.common import check_prefix
from lensfit.codegen.glsl import GLSL_AS_C_PRELUDE, emit_glsl, glsl_as_c, glsl_check_shader
from lensfit.codegen.table import Table, read_table, write_table
from lensfit.codegen.timing import CompilerNotFound, call_c, check_compiles, load_c, time_c
from lensfit.poly import System

__all__ = [
    "GLSL_AS_C_PRELUDE",
    "CompilerNotFound",
    "Table",
    "call_c",
    "casadi_system",
    "check_compiles",
    "check_prefix",
    "emit_c",
    "emit_casadi_c",
    "emit_glsl",
    "emit_horner_c",
    "glsl_as_c",
    "glsl_check_shader",
    "load_c",
    "read_table",
    "time_c",
    "write_table",
]


def emit_c(systems: Sequence[System], prefix: str, *, header_comment: str = "",
           which: str = "horner") -> dict[str, str]:
    """C99 sources for all ``systems`` of a lens under the symbol ``prefix``.

    ``which="horner"``: ``<stem>.h``, ``<stem>.c`` with ``<prefix>S_d`` / ``_f``;
    ``which="casadi"``: ``<stem>_casadi.h``, ``_casadi_d.c``, ``_casadi_f.c`` with
    ``<prefix>S_casadi_d`` / ``_f`` and ``<prefix>S_casadi_jac_d`` / ``_f``.
    ``stem`` is the prefix without trailing '_'. ValueError for a prefix that is not a
    C identifier."""
    if which == "horner":
        return emit_horner_c(systems, prefix, header_comment=header_comment)
    if which == "casadi":
        return emit_casadi_c(systems, prefix, header_comment=header_comment)
    raise ValueError(f"which must be 'horner' or 'casadi', got {which!r}")
