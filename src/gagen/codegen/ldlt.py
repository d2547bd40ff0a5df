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
