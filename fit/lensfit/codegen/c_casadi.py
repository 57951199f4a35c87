"""casadi: the systems as symbolic SX expressions, their Jacobians, and casadi's C for both.

:func:`casadi_system` builds one system from RAW inputs (the normalisation is part of the
expression, so derivatives are with respect to the raw inputs in their units) and returns
two ``casadi.Function``s: the values, and the Jacobian d out_i / d in_j, dense and
row-major (entry i * N_IN + j), in [output unit / input unit].

:func:`emit_casadi_c` writes casadi's generated C, wrapped so that every symbol carries
the lens prefix and the calling convention matches the Horner file:

    <stem>_casadi.h     declarations and the same #defines as <stem>.h
    <stem>_casadi_d.c   casadi_real = double
    <stem>_casadi_f.c   casadi_real = float

    void <prefix>S_casadi_d(const double in[N_IN], double out[N_OUT]);
    void <prefix>S_casadi_jac_d(const double in[N_IN], double jac[N_OUT * N_IN]);
    (and _f twins with float)

Each .c file holds casadi's ``CodeGenerator.dump()`` with options ``casadi_real`` (double
or float), ``casadi_int = int``, ``prefix = <prefix>casadi_<d|f>`` (casadi's internal
helpers and constants), ``with_header``, ``with_mem``, ``main``, ``mex``, ``with_export``
and ``verbose`` all false; casadi's entry points are named ``<prefix>cs_<d|f>_S`` and
``..._jac`` and keep casadi's (arg, res, iw, w, mem) convention; the wrappers above call
them with stack work arrays of the sizes casadi reports.

Quirks found with casadi 3.8.2: the generated functions never use their ``iw``, ``w`` and
``mem`` arguments, which ``-Wextra`` reports as unused parameters, so each file starts with
``#pragma GCC diagnostic ignored "-Wunused-parameter"`` (GCC and clang); with it, the files
compile with ``-std=c99 -Wall -Wextra -pedantic -Werror``. casadi appends '_' to the
``prefix`` option (``CASADI_PREFIX(ID)`` is ``<prefix>_ ## ID``). In the float file casadi
still prints constants as 17-digit double literals assigned to float temporaries (so
they are rounded to float when compiled), and the Jacobian's ``(2.*a)`` doublings are
computed in double (exactly) before being stored as float.

``form`` picks the expression casadi receives: ``"monomial"`` (default), the plain sum of
``c_k prod xhat_j^e`` with each power x^p built once by repeated multiplication and
shared, an evaluation independent of the Horner tree (so the two C files check each
other); or ``"horner"``, the same tree as the hand-emitted code. ``python -m
lensfit.codegen.bench`` measured the monomial form about 2.2-2.4 times slower than the
hand-emitted Horner code, and the Horner form as fast as it, within noise.
"""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca

from lensfit.codegen.c_horner import file_stem, header_intro
from lensfit.codegen.common import REALS, check_systems, comment_block, count, system_defines
from lensfit.codegen.horner import Node, Tree, polynomial_tree
from lensfit.poly import Input, Polynomial, System

FORMS = ("monomial", "horner")


def _normalised(inp: Input, v: ca.SX) -> ca.SX:
    c, s = inp.offset_scale
    w = v if inp.transform == "affine" else 1.0 / (v * v)
    return (w - c) / s


def _monomial(p: Polynomial, powers: list[list[ca.SX]]) -> ca.SX:
    total = ca.SX(0.0)
    for e, coef in zip(p.exponents.tolist(), p.coefficients.tolist(), strict=True):
        term = ca.SX(coef)
        for j, k in enumerate(e):
            if k:
                term = term * powers[j][k]
        total = total + term
    return total


def _horner(tree: Tree, powers: list[list[ca.SX]]) -> ca.SX:
    if not isinstance(tree, Node):
        return ca.SX(tree)
    xp = powers[tree.var]
    value = _horner(tree.children[-1], powers)
    for i in range(len(tree.powers) - 2, -1, -1):
        gap = tree.powers[i + 1] - tree.powers[i]
        value = _horner(tree.children[i], powers) + xp[gap] * value
    if tree.powers[0]:
        value = xp[tree.powers[0]] * value
    return value


def casadi_expressions(system: System, form: str = "monomial") -> tuple[ca.SX, ca.SX, ca.SX]:
    """(in, out, jac): the raw input symbol (N_IN), the outputs (N_OUT) and the Jacobian
    flattened row-major (N_OUT * N_IN, d out_i / d in_j at i * N_IN + j)."""
    if form not in FORMS:
        raise ValueError(f"casadi form must be one of {FORMS}, got {form!r}")
    n_in = len(system.inputs)
    v = ca.SX.sym("in", n_in)
    xs = [_normalised(inp, v[j]) for j, inp in enumerate(system.inputs)]
    # x^p by repeated multiplication; casadi drops the ones no output uses
    top = max(int(p.exponents.max(initial=0)) for p in system.outputs)
    powers: list[list[ca.SX]] = []
    for x in xs:
        row = [ca.SX(1.0), x]
        for _ in range(2, top + 1):
            row.append(row[-1] * x)
        powers.append(row)
    if form == "monomial":
        outs = [_monomial(p, powers) for p in system.outputs]
    else:
        outs = [_horner(polynomial_tree(p), powers) for p in system.outputs]
    y = ca.vertcat(*outs)
    # casadi stores column-major: the columns of J^T are the rows of J
    jac = ca.reshape(ca.densify(ca.jacobian(y, v)).T, -1, 1)
    return v, y, jac


def casadi_system(system: System, name: str,
                  form: str = "monomial") -> tuple[ca.Function, ca.Function]:
    """(values, Jacobian) of ``system`` as casadi Functions named ``name``, ``name_jac``.

    values: in[N_IN] (raw) -> out[N_OUT]; Jacobian: in[N_IN] -> jac[N_OUT * N_IN],
    row-major, d out_i / d in_j in [output unit / input unit]."""
    return _functions(name, *casadi_expressions(system, form))


def _functions(name: str, v: ca.SX, y: ca.SX, jac: ca.SX) -> tuple[ca.Function, ca.Function]:
    return (ca.Function(name, [v], [y], ["in"], ["out"]),
            ca.Function(name + "_jac", [v], [jac], ["in"], ["jac"]))


def _wrapper(f: ca.Function, public: str, real: str, n_in: int, n_res: int,
             result: str) -> list[str]:
    """``void public(const real in[n_in], real result[n_res])`` calling casadi's entry."""
    lines = [f"void {public}(const {real} in[{n_in}], {real} {result}[{n_res}])", "{",
             "    const casadi_real *arg[1];", "    casadi_real *res[1];"]
    call_iw, call_w = "0", "0"
    if f.sz_iw():
        lines.append(f"    casadi_int iw[{f.sz_iw()}];")
        call_iw = "iw"
    if f.sz_w():
        lines.append(f"    casadi_real w[{f.sz_w()}];")
        call_w = "w"
    lines += ["    arg[0] = in;", f"    res[0] = {result};",
              f"    {f.name()}(arg, res, {call_iw}, {call_w}, 0);", "}"]
    return lines


def emit_casadi_c(systems: Sequence[System], prefix: str, *, header_comment: str = "",
                  form: str = "monomial") -> dict[str, str]:
    """``{"<stem>_casadi.h", "<stem>_casadi_d.c", "<stem>_casadi_f.c"}`` (see module doc)."""
    systems = check_systems(systems, prefix)
    built = [casadi_expressions(s, form) for s in systems]  # checks form
    stem = file_stem(prefix) + "_casadi"
    guard = f"{stem.upper()}_H"
    about = (f"Generated by lensfit.codegen.c_casadi (casadi {ca.__version__}, form "
             f"'{form}'); do not edit, regenerate.\n\n"
             "S_casadi_d/_f: RAW inputs -> outputs, as S_d/_f of the Horner file.\n"
             "S_casadi_jac_d/_f: RAW inputs -> jac[i * N_IN + j] = d out_i / d in_j,\n"
             "in [output unit / input unit].")
    h = header_intro(header_comment, about)
    h += ["", f"#ifndef {guard}", f"#define {guard}", "",
          "#ifdef __cplusplus", 'extern "C" {', "#endif"]
    for s in systems:
        sym = prefix + s.name
        h += [""] + comment_block(
            f"{s.name}: {count(len(s.inputs), 'input')} -> {count(len(s.outputs), 'output')}, "
            f"{count(sum(p.terms for p in s.outputs), 'term')}; casadi, {form} form")
        h += system_defines(s, prefix)
        for v, real in REALS.items():
            h += [f"void {sym}_casadi_{v}(const {real} in[{sym}_N_IN], "
                  f"{real} out[{sym}_N_OUT]);",
                  f"void {sym}_casadi_jac_{v}(const {real} in[{sym}_N_IN], "
                  f"{real} jac[{sym}_N_OUT * {sym}_N_IN]);"]
    h += ["", "#ifdef __cplusplus", "}", "#endif", "", f"#endif /* {guard} */", ""]
    files = {f"{stem}.h": "\n".join(h)}

    for v, real in REALS.items():
        cg = ca.CodeGenerator(f"{stem}_{v}", {
            "casadi_real": real, "casadi_int": "int", "prefix": f"{prefix}casadi_{v}",
            "with_header": False, "with_mem": False, "main": False, "mex": False,
            "with_export": False, "verbose": False})
        renamed = []
        for s, expressions in zip(systems, built, strict=True):
            # casadi's entry points, named under the lens prefix
            fv, jv = _functions(f"{prefix}cs_{v}_{s.name}", *expressions)
            cg.add(fv)
            cg.add(jv)
            renamed.append((s, fv, jv))
        c = header_intro(header_comment, f"Generated by lensfit.codegen.c_casadi from casadi's "
                         f"CodeGenerator ({real}); do not edit, regenerate.")
        c += ["", "/* casadi leaves the iw, w and mem arguments of its functions unused */",
              "#if defined(__GNUC__)",
              '#pragma GCC diagnostic ignored "-Wunused-parameter"', "#endif", "",
              f'#include "{stem}.h"', "", "/* ---- casadi's code ---- */", cg.dump().rstrip(),
              "", "/* ---- Wrappers with the lens calling convention ---- */"]
        for s, fv, jv in renamed:
            sym = prefix + s.name
            n_in, n_out = len(s.inputs), len(s.outputs)
            c += [""] + _wrapper(fv, f"{sym}_casadi_{v}", real, n_in, n_out, "out")
            c += [""] + _wrapper(jv, f"{sym}_casadi_jac_{v}", real, n_in, n_in * n_out, "jac")
        c.append("")
        files[f"{stem}_{v}.c"] = "\n".join(c)
    return files
