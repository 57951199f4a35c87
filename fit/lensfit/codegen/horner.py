"""Multivariate Horner form of a sparse polynomial, shared by the C and GLSL emitters.

A sparse polynomial in normalised inputs x_0 .. x_{n-1} is factored recursively by the
powers of one variable at a time:

    P = sum_k x^k P_k(other variables),   k in {k_0 < k_1 < ... < k_m}
      = x^k_0 (P_k0 + x^(k_1-k_0) (P_k1 + ... + x^(k_m-k_(m-1)) P_km))

which is Horner's rule in x with the gaps between used powers bridged by x^gap; each P_k
is factored the same way by another variable until only a constant is left. The powers
x^gap (and x^k_0) are computed once per system, before the outputs.

Multiplications: a node with m + 1 distinct powers costs m products (one per gap) plus
one when k_0 > 0; leaves are constants and cost nothing; a power x^p costs one product
once (x^p = x^a x^b with both already known, by halving). The count is reported in the
generated comments.

Variable order (a greedy choice at every node, not one global order): split by the
variable with the fewest distinct powers per term that uses it, i.e. the smallest ratio
(number of distinct powers, 0 included) / (number of terms with a non-zero power); ties go
to the lower input index. Splitting costs about one product per distinct power, and that
product is shared by every term that uses the variable, so a low ratio means cheap,
widely shared products. Measured once on six random 150-term, degree-9 polynomials in
six variables (multiplications, powers included): this rule 1451; one-step exhaustive
look-ahead 1439; "most terms first" 1536; the best of all 720 fixed global orders 1546,
the worst 1676; the expanded sum with shared powers 2675 (powers not counted).
``tests/fit/codegen/test_codegen_horner.py`` checks the rule against every fixed order on
smaller cases.

Before factoring, terms are canonicalised: equal exponent rows are merged (their
coefficients summed exactly with ``math.fsum``), zero coefficients dropped and rows
sorted, so the result does not depend on the order of the terms.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lensfit.poly import Polynomial


@dataclass(frozen=True)
class Node:
    """``x_var^powers[0] (children[0] + x_var^gap_1 (children[1] + ...))``."""

    var: int
    powers: tuple[int, ...]  # increasing, distinct
    children: tuple[Node | float, ...]  # one per power; a float is a constant


Tree = Node | float


def canonical_terms(p: Polynomial) -> tuple[np.ndarray, np.ndarray]:
    """Merge equal exponent rows (exact sum), drop zero coefficients, sort rows."""
    merged: dict[tuple[int, ...], list[float]] = {}
    for e, c in zip(map(tuple, p.exponents.tolist()), p.coefficients.tolist(), strict=True):
        merged.setdefault(e, []).append(c)
    rows = sorted((e, math.fsum(cs)) for e, cs in merged.items())
    rows = [(e, c) for e, c in rows if c != 0.0]
    n = p.exponents.shape[1]
    exps = np.array([e for e, _ in rows], dtype=np.int64).reshape(-1, n)
    return exps, np.array([c for _, c in rows], dtype=np.float64)


def choose_variable(exps: np.ndarray, active: list[int]) -> int:
    """Fewest distinct powers per term using the variable; ties to the lowest index."""

    def key(j: int) -> tuple[float, int]:
        col = exps[:, j]
        return len(np.unique(col)) / np.count_nonzero(col), j

    return min(active, key=key)


def build(exps: np.ndarray, coefs: np.ndarray,
          choose: Callable[[np.ndarray, list[int]], int] = choose_variable) -> Tree:
    """Horner tree of canonical terms (see :func:`canonical_terms`)."""
    if len(coefs) == 0:
        return 0.0
    active = [j for j in range(exps.shape[1]) if exps[:, j].any()]
    if not active:
        # Canonical terms have distinct rows, so this is the single constant term
        return float(coefs.sum())
    j = choose(exps, active)
    powers = sorted({int(k) for k in exps[:, j]})
    children = []
    for k in powers:
        rows = exps[:, j] == k
        sub = exps[rows].copy()
        sub[:, j] = 0
        children.append(build(sub, coefs[rows], choose))
    return Node(j, tuple(powers), tuple(children))


def polynomial_tree(p: Polynomial) -> Tree:
    return build(*canonical_terms(p))


def multipliers(tree: Tree, into: dict[int, set[int]] | None = None) -> dict[int, set[int]]:
    """For each variable, the powers the tree multiplies by (gaps and leading powers)."""
    into = {} if into is None else into
    if isinstance(tree, Node):
        used = into.setdefault(tree.var, set())
        if tree.powers[0] > 0:
            used.add(tree.powers[0])
        used.update(b - a for a, b in zip(tree.powers, tree.powers[1:], strict=False))
        for child in tree.children:
            multipliers(child, into)
    return into


def power_plan(needed: set[int]) -> list[tuple[int, int, int]]:
    """Products (p, a, b), x^p = x^a * x^b in order, that make every power in ``needed``.

    Reuse a known pair when there is one; otherwise halve an even power, or step an odd
    one down by one, and recurse."""
    known = {1}
    plan: list[tuple[int, int, int]] = []

    def make(p: int) -> None:
        if p in known:
            return
        for a in sorted(known, reverse=True):
            if p - a in known:
                plan.append((p, a, p - a))
                known.add(p)
                return
        parts = (p // 2, p - p // 2) if p % 2 == 0 else (p - 1, 1)
        for q in parts:
            make(q)
        plan.append((p, parts[0], parts[1]))
        known.add(p)

    for p in sorted(needed):
        make(p)
    return plan


def node_multiplications(tree: Tree) -> int:
    """Products inside the tree, not counting the powers of the variables."""
    if not isinstance(tree, Node):
        return 0
    own = len(tree.powers) - 1 + (tree.powers[0] > 0)
    return own + sum(node_multiplications(c) for c in tree.children)


def naive_multiplications(p: Polynomial) -> int:
    """Products of the expanded sum with shared powers: one per variable factor per term."""
    exps, _ = canonical_terms(p)
    return int(np.count_nonzero(exps))


_ATOM = re.compile(r"[A-Za-z0-9_.]+(e[-+][0-9]+)?f?")


def _operand(text: str) -> str:
    return text if _ATOM.fullmatch(text) else f"({text})"


def render(tree: Tree, literal: Callable[[float], str], power: Callable[[int, int], str]) -> str:
    """The tree as one C/GLSL expression; spaces only between tokens (see wrap_expression).

    ``literal(c)`` writes a coefficient, ``power(j, p)`` names x_j^p."""
    if not isinstance(tree, Node):
        return literal(tree)
    text = render(tree.children[-1], literal, power)
    for i in range(len(tree.powers) - 2, -1, -1):
        gap = tree.powers[i + 1] - tree.powers[i]
        head = render(tree.children[i], literal, power)
        text = f"{head} + {power(tree.var, gap)}*{_operand(text)}"
    if tree.powers[0] > 0:
        text = f"{power(tree.var, tree.powers[0])}*{_operand(text)}"
    return text


@dataclass(frozen=True)
class SystemPlan:
    """What an emitter needs for one system: trees, the powers to precompute, counts."""

    trees: tuple[Tree, ...]
    powers: tuple[tuple[int, tuple[tuple[int, int, int], ...]], ...]  # (var, plan), by var
    used_inputs: tuple[int, ...]  # inputs any output depends on, increasing
    output_multiplications: tuple[int, ...]
    power_multiplications: int

    @property
    def multiplications(self) -> int:
        return sum(self.output_multiplications) + self.power_multiplications


def plan_system(outputs: tuple[Polynomial, ...]) -> SystemPlan:
    trees = tuple(polynomial_tree(p) for p in outputs)
    needed: dict[int, set[int]] = {}
    for t in trees:
        multipliers(t, needed)
    powers = tuple((j, tuple(power_plan(needed[j]))) for j in sorted(needed))
    used = set(needed)
    return SystemPlan(
        trees=trees,
        powers=powers,
        used_inputs=tuple(sorted(used)),
        output_multiplications=tuple(node_multiplications(t) for t in trees),
        power_multiplications=sum(len(plan) for _, plan in powers),
    )


def power_name(j: int, p: int) -> str:
    """Local name of xhat_j^p in generated code: x3, x3_2, ..."""
    return f"x{j}" if p == 1 else f"x{j}_{p}"
