"""Hand-emitted C99: every system of a lens as multivariate Horner code, double and float.

One file pair per lens, ``<stem>.h`` and ``<stem>.c`` (stem = prefix without trailing
'_'). For each system S the header declares

    void <prefix>S_d(const double in[<prefix>S_N_IN], double out[<prefix>S_N_OUT]);
    void <prefix>S_f(const float in[<prefix>S_N_IN], float out[<prefix>S_N_OUT]);

``in`` holds RAW inputs in their units; the function normalises them (xhat = (w - c)/s,
w = v or 1/v^2, computed as (w - c) * (1/s)), evaluates each output in the Horner form of
:mod:`lensfit.codegen.horner` and writes ``out`` in the outputs' units. The double variant
prints coefficients with 17 significant digits (round-trip exact), the float variant
with 9 and an ``f`` suffix, so it computes in float throughout. The header also carries
``#define``s for the counts, input/output indices and domain bounds, each with its unit.

The files compile cleanly with ``cc -std=c99 -Wall -Wextra -pedantic -Werror`` (tested).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from lensfit.codegen.common import (
    REALS,
    ascii_text,
    check_systems,
    comment_block,
    count,
    fmt_double,
    fmt_float,
    output_comment,
    system_defines,
    unit_text,
    wrap_expression,
)
from lensfit.codegen.horner import SystemPlan, plan_system, power_name, render
from lensfit.poly import Input, System


def file_stem(prefix: str) -> str:
    """File name stem of a prefix: 'lens0001_' -> 'lens0001'."""
    return prefix.rstrip("_") or prefix


def literal_for(variant: str, where: str) -> Callable[[float], str]:
    """Coefficient formatter of a variant; float overflow names ``where`` in the error."""
    if variant == "d":
        return fmt_double
    return lambda c: fmt_float(c, f"{where}: coefficient")


def normalise_expr(inp: Input, arg: str, variant: str,
                   literal: Callable[[float], str] | None = None) -> str:
    """C/GLSL expression for xhat of one input from the raw value ``arg``.

    Same operations as Input.normalise except (w - c) * (1/s) for (w - c) / s: a multiply
    is cheaper than a divide and differs by at most one rounding."""
    lit = literal or (fmt_double if variant == "d" else fmt_float)
    one = "1.0" if variant == "d" else "1.0f"
    c, s = inp.offset_scale
    w = arg if inp.transform == "affine" else f"{one} / ({arg} * {arg})"
    if c > 0:
        w = f"({w} - {lit(c)})"
    elif c < 0:
        w = f"({w} + {lit(-c)})"
    elif inp.transform != "affine":
        w = f"({w})"
    return w if s == 1.0 else f"{w} * {lit(1.0 / s)}"


def scale_unit(inp: Input) -> str:
    """Unit of 1/s: 1/unit for affine inputs, unit^2 for inverse_square ones."""
    u = unit_text(inp.unit)
    if inp.transform != "affine":
        return f"{u}^2"
    return "1" if u == "1" else f"1/({u})" if "/" in u else f"1/{u}"


def normalise_comment(inp: Input) -> str:
    """`x_O [mm], affine: (v - c) * (1/s), c in mm, 1/s in 1/mm`."""
    u = unit_text(inp.unit)
    if inp.transform == "affine":
        how, cu = "(v - c)", u
    else:
        how, cu = "(1/v^2 - c)", f"1/{u}^2"
    return (f"{ascii_text(inp.name)} [{u}], {inp.transform}: {how} * (1/s), c in {cu}, "
            f"1/s in {scale_unit(inp)}")


def function_body(system: System, plan: SystemPlan, variant: str, arg: str, res: str,
                  literal: Callable[[float], str] | None = None,
                  glsl: bool = False) -> list[str]:
    """Statements of one variant: normalisation, powers, one assignment per output.

    Shared with the GLSL emitter (``glsl``: no ``const`` locals, no ``(void)`` casts; and
    its own ``literal``)."""
    declare = "" if glsl else "const "
    real = REALS[variant]
    lines = ["    /* Normalised inputs xhat in [-1, 1] (see the header for c and s) */"]
    for j, inp in enumerate(system.inputs):
        if j not in plan.used_inputs:
            lines.append(f"    /* {arg}[{j}], {ascii_text(inp.name)} [{unit_text(inp.unit)}]: "
                         "no output depends on it */")
            continue
        lines.append(f"    /* {normalise_comment(inp)} */")
        lines.append(f"    {declare}{real} {power_name(j, 1)} = "
                     f"{normalise_expr(inp, f'{arg}[{j}]', variant, literal)};")
    if not plan.used_inputs and not glsl:
        lines.append(f"    (void){arg};")
    if plan.power_multiplications:
        lines.append(f"    /* Powers of xhat ({plan.power_multiplications} multiplications) */")
    for j, steps in plan.powers:
        for p, a, b in steps:
            lines.append(f"    {declare}{real} {power_name(j, p)} = "
                         f"{power_name(j, a)} * {power_name(j, b)};")
    for i, (p, tree) in enumerate(zip(system.outputs, plan.trees, strict=True)):
        lit = literal or literal_for(variant, f"{system.name} output {p.output}")
        lines.append(f"    /* {output_comment(p)}; "
                     f"{count(plan.output_multiplications[i], 'multiplication')} */")
        lines.extend(wrap_expression(render(tree, lit, power_name) + ";",
                                     f"    {res}[{i}] =", " " * 8))
    return lines


def system_summary(system: System, plan: SystemPlan) -> str:
    return (f"{system.name}: {count(len(system.inputs), 'input')} -> "
            f"{count(len(system.outputs), 'output')}, "
            f"{count(sum(p.terms for p in system.outputs), 'term')}, Horner form with "
            f"{count(plan.multiplications, 'multiplication')} per evaluation "
            f"({plan.power_multiplications} for powers)")


def prototype(sym: str, variant: str) -> str:
    real = REALS[variant]
    return f"void {sym}_{variant}(const {real} in[{sym}_N_IN], {real} out[{sym}_N_OUT])"


def header_intro(header_comment: str, what: str) -> list[str]:
    text = (f"{header_comment}\n\n" if header_comment else "") + what
    return comment_block(text.rstrip())


def emit_horner_c(systems: Sequence[System], prefix: str, *,
                  header_comment: str = "") -> dict[str, str]:
    """``{"<stem>.h": ..., "<stem>.c": ...}`` for all ``systems`` under ``prefix``."""
    systems = check_systems(systems, prefix)
    stem = file_stem(prefix)
    guard = f"{stem.upper()}_H"
    plans = [plan_system(s.outputs) for s in systems]
    about = ("Generated by lensfit.codegen.c_horner; do not edit, regenerate.\n\n"
             "For each system S, S_d (double) and S_f (float) take RAW inputs in the units\n"
             "below, normalise them over the declared domain (xhat = (w - c)/s, w = v or\n"
             "1/v^2) and write the outputs in their units. Outside the domain the\n"
             "polynomials extrapolate.")
    h = header_intro(header_comment, about)
    h += ["", f"#ifndef {guard}", f"#define {guard}", "",
          "#ifdef __cplusplus", 'extern "C" {', "#endif"]
    for s, plan in zip(systems, plans, strict=True):
        sym = prefix + s.name
        h += [""] + comment_block(system_summary(s, plan)) + system_defines(s, prefix)
        h += [f"{prototype(sym, 'd')};", f"{prototype(sym, 'f')};"]
    h += ["", "#ifdef __cplusplus", "}", "#endif", "", f"#endif /* {guard} */", ""]

    c = header_intro(header_comment, "Generated by lensfit.codegen.c_horner; do not edit, "
                     "regenerate.\nDeclarations, units and domains: " + stem + ".h")
    c += ["", f'#include "{stem}.h"']
    for s, plan in zip(systems, plans, strict=True):
        sym = prefix + s.name
        for variant in ("d", "f"):
            c += ["", f"/* {system_summary(s, plan)}; {REALS[variant]} */",
                  prototype(sym, variant), "{"]
            c += function_body(s, plan, variant, "in", "out")
            c += ["}"]
    c.append("")
    return {f"{stem}.h": "\n".join(h), f"{stem}.c": "\n".join(c)}
