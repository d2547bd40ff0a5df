"""Common-subexpression elimination over every output at once, in one dependency order.

The derivation's intermediates and all outputs (mass matrix, forcing, inverse dynamics,
gravity, energy) go through `sympy.cse` together, so a subexpression shared anywhere is
computed once. Each C function then takes the assignments its outputs depend on, in the
one order shared by all functions.
"""

from __future__ import annotations

import heapq
import time
from dataclasses import dataclass, field

import sympy as sp

from ..symbolic.gibbs_appell import Equations
from ..symbolic.symbols import internal_symbols


@dataclass
class Assignment:
    symbol: sp.Symbol
    expr: sp.Expr
    deps: frozenset = field(default_factory=frozenset)


class CSEResult:
    """All assignments in one dependency order, and the reduced output expressions."""

    def __init__(self, eqs: Equations, eliminate: bool = True, definitions=None,
                 outputs=None):
        """CSE of `eqs`'s outputs in its intermediates, or of other `outputs` (name -> list)
        written in `definitions` (the regressor's program)."""
        outputs = eqs.outputs() if outputs is None else outputs
        defs = eqs.intermediates if definitions is None else definitions
        self.eliminated = eliminate
        flat = [e for v in outputs.values() for e in v]
        self.ops_before = _ops(e for _, e in defs) + _ops(flat)
        start = time.perf_counter()
        if eliminate:
            temps, reduced = sp.cse([e for _, e in defs] + flat,
                                    symbols=internal_symbols("_x"), order="canonical")
        else:
            temps, reduced = [], [e for _, e in defs] + flat
        self.seconds = time.perf_counter() - start
        reduced_defs, reduced_out = reduced[: len(defs)], reduced[len(defs):]
        assignments = [Assignment(s, e) for s, e in temps]
        assignments += [Assignment(s, e) for (s, _), e in zip(defs, reduced_defs)]
        self.assignments = _dependency_order(assignments)
        self.outputs: dict[str, list[sp.Expr]] = {}
        k = 0
        for key, values in outputs.items():
            self.outputs[key] = reduced_out[k: k + len(values)]
            k += len(values)
        # without elimination the program is the one counted before (in another order)
        self.ops_after = (_ops(a.expr for a in self.assignments) + _ops(reduced_out)
                          if eliminate else self.ops_before)

    def needed(self, exprs) -> list[Assignment]:
        """The assignments these expressions depend on, in the shared order."""
        defined = self._defined()
        need: set[sp.Symbol] = set()
        stack = [s for e in exprs for s in e.free_symbols if s in defined]
        while stack:
            s = stack.pop()
            if s not in need:
                need.add(s)
                stack.extend(d for d in defined[s].deps if d not in need)
        return [a for a in self.assignments if a.symbol in need]

    def _defined(self) -> dict[sp.Symbol, Assignment]:
        """The assignments by symbol (kept: every kernel asks)."""
        cached = getattr(self, "_by_symbol", None)
        if cached is None or cached[0] != len(self.assignments):
            cached = self._by_symbol = (len(self.assignments),
                                        {a.symbol: a for a in self.assignments})
        return cached[1]


def _ops(exprs) -> int:
    return operation_count(exprs)


def operation_count(exprs) -> int:
    """The arithmetic operations of expressions, counted as `sympy.count_ops` counts them
    (a - b one subtraction, x / y one division, -x one negation) to within a few per cent,
    but a hundred times faster: count_ops took a third of a big model's generation."""
    total = 0
    stack = [(sp.sympify(e), False) for e in exprs]
    while stack:
        e, in_sum = stack.pop()
        if e.is_Atom:
            continue
        if e.is_Add:
            total += len(e.args) - 1
            stack.extend((a, True) for a in e.args)
        elif e.is_Mul:
            coefficient, factors = e.as_coeff_mul()
            # 1 or -1 for those Integers, else 0 (a Float never equals an Integer in SymPy);
            # comparing SymPy numbers with == sympifies, a third of this function's time
            unit = coefficient.p if (coefficient.is_Integer and coefficient.p in (1, -1)) else 0
            total += len(factors) - 1 + (unit == 0) + (unit == -1 and not in_sum)
            for f in factors:
                if f.is_Pow and f.exp is sp.S.NegativeOne:  # a division, not a product
                    total += len(factors) == 1
                    stack.append((f.base, False))
                else:
                    stack.append((f, False))
        else:
            total += 1
            stack.extend((a, False) for a in e.args if not a.is_Number)
    return total


def _dependency_order(assignments: list[Assignment]) -> list[Assignment]:
    """Topological order; among ready assignments the earliest given comes first."""
    by_symbol = {a.symbol: k for k, a in enumerate(assignments)}
    for a in assignments:
        a.deps = frozenset(s for s in a.expr.free_symbols if s in by_symbol)
    waiting = {k: len(a.deps) for k, a in enumerate(assignments)}
    users: dict[int, list[int]] = {k: [] for k in range(len(assignments))}
    for k, a in enumerate(assignments):
        for d in a.deps:
            users[by_symbol[d]].append(k)
    ready = [k for k, count in waiting.items() if count == 0]
    heapq.heapify(ready)
    order = []
    while ready:
        k = heapq.heappop(ready)
        order.append(assignments[k])
        for u in users[k]:
            waiting[u] -= 1
            if waiting[u] == 0:
                heapq.heappush(ready, u)
    if len(order) != len(assignments):
        raise RuntimeError("cyclic intermediate definitions")
    return order


