"""The unrolled LDLᵀ factorisation and solve of M q̈ = F, as Python data for the templates.

M's structural zeros (e.g. the coupling between a vertical base joint and a planar arm)
are known when the code is generated, so the factorisation only touches the entries of L
that can be non-zero, fill-in included. The templates print these index lists verbatim:
the sparsity logic lives here, once.
"""

from __future__ import annotations

from dataclasses import dataclass


def factor_pattern(n: int, zero: set[tuple[int, int]]) -> set[tuple[int, int]]:
    """Entries (i, j), i > j, of the LDLᵀ factor that can be non-zero, fill-in included."""
    nonzero: set[tuple[int, int]] = set()
    for j in range(n):
        for i in range(j + 1, n):
            if (i, j) not in zero or any((i, k) in nonzero and (j, k) in nonzero
                                         for k in range(j)):
                nonzero.add((i, j))
    return nonzero


@dataclass(frozen=True)
class Pivot:
    """Column j of the factorisation: D_j = M_jj - Σ_k U_jk² / D_k over `terms`, then
    U_ij -= Σ_k U_ik U_jk / D_k for each (i, ks) of `updates` (M holds U = L D)."""

    j: int
    terms: tuple[int, ...]
    updates: tuple[tuple[int, tuple[int, ...]], ...]


@dataclass(frozen=True)
class LDLTPlan:
    """Which entries each step of the unrolled factorisation and solve reads."""

    n: int
    pivots: tuple[Pivot, ...]
    forward: tuple[tuple[int, tuple[int, ...]], ...]  # y_i = F_i - Σ_k U_ik z_k
    backward: tuple[tuple[int, tuple[int, ...]], ...]  # q̈_i = (y_i - Σ_k U_ki q̈_k) / D_i


def ldlt_plan(n: int, zero: set[tuple[int, int]]) -> LDLTPlan:
    """The plan for an n×n M whose lower-triangle entries `zero` are structurally zero."""
    lnz = factor_pattern(n, zero)
    pivots = []
    for j in range(n):
        terms = tuple(k for k in range(j) if (j, k) in lnz)
        updates = []
        for i in range(j + 1, n):
            if (i, j) in lnz:
                ks = tuple(k for k in range(j) if (i, k) in lnz and (j, k) in lnz)
                if ks:
                    updates.append((i, ks))
        pivots.append(Pivot(j, terms, tuple(updates)))
    forward = tuple((i, tuple(k for k in range(i) if (i, k) in lnz)) for i in range(n))
    backward = tuple((i, tuple(k for k in range(i + 1, n) if (k, i) in lnz))
                     for i in range(n - 1, -1, -1))
    return LDLTPlan(n, tuple(pivots), forward, backward)


@dataclass(frozen=True)
class OrderedPlan:
    """An LDLᵀ plan (`ldlt_plan`) taken in an elimination order, its steps written with
    the original coordinates and the flat indices of M's stored lower triangle (entry
    (r, s), r >= s, at r*n + s), for templates that need no index arithmetic.

    `pivots`: (j, diagonal, terms, updates): D_j = M[diagonal] - Σ U[a]² Dinv_k over
    terms (a, k), then U[b] -= Σ U[c] U[d] Dinv_k over each update (b, ((c, d, k), ...)).
    `forward`: (i, ((a, k), ...)): z_i = (x_i - Σ U[a] z_k) Dinv_i. `backward`: (i, ((a, k),
    ...)): x_i -= Dinv_i Σ U[a] x_k. `order[t]` is the coordinate eliminated t-th."""

    n: int
    order: tuple[int, ...]
    pivots: tuple[tuple[int, int, tuple, tuple], ...]
    forward: tuple[tuple[int, tuple[tuple[int, int], ...]], ...]
    backward: tuple[tuple[int, tuple[tuple[int, int], ...]], ...]
    stored: int  # entries of the factor below the diagonal


def ordered_plan(n: int, zero: set[tuple[int, int]], order: list[int]) -> OrderedPlan:
    """The plan of P M Pᵀ = L D Lᵀ with P the permutation `order` (the t-th row of P M Pᵀ
    is coordinate order[t]); `zero` holds M's structurally zero entries (r, s), r > s."""
    def permuted_zero(a: int, b: int) -> bool:
        r, s = order[a], order[b]
        return (max(r, s), min(r, s)) in zero

    pz = {(a, b) for a in range(n) for b in range(a) if permuted_zero(a, b)}
    plan = ldlt_plan(n, pz)

    def flat(a: int, b: int) -> int:  # M's stored entry of permuted (a, b)
        r, s = order[a], order[b]
        return max(r, s) * n + min(r, s)

    pivots = tuple(
        (order[p.j], flat(p.j, p.j), tuple((flat(p.j, k), order[k]) for k in p.terms),
         tuple((flat(i, p.j), tuple((flat(i, k), flat(p.j, k), order[k]) for k in ks))
               for i, ks in p.updates))
        for p in plan.pivots)
    forward = tuple((order[i], tuple((flat(i, k), order[k]) for k in ks))
                    for i, ks in plan.forward)
    backward = tuple((order[i], tuple((flat(k, i), order[k]) for k in ks))
                     for i, ks in plan.backward)
    stored = len(factor_pattern(n, pz))
    return OrderedPlan(n, tuple(order), pivots, forward, backward, stored)


def least_fill_plan(n: int, zero: set[tuple[int, int]]) -> OrderedPlan:
    """The plan in whichever of the coordinates' order and its reverse keeps the factor
    smaller. For a tree whose coordinates come parents first (gagen's), the reverse
    eliminates the leaves first and L has no fill-in at all (Featherstone's LTDL): a
    floating base, which couples to every joint, is eliminated last instead of first
    (which would fill in every pair of joints, ANYmal's legs with each other)."""
    natural = ordered_plan(n, zero, list(range(n)))
    reverse = ordered_plan(n, zero, list(reversed(range(n))))
    return reverse if reverse.stored < natural.stored else natural
