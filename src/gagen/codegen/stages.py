"""Forward dynamics in two stages: what depends on the positions q alone, and the rest.

An integrator stage of a robot's [q, qd] state knows the positions of the next stage before
it knows this stage's accelerations (dq/dt = qd), so the compiled integrators evaluate
qdd(q, qd, u) in two halves and overlap them (gagen_second_order.h):

- the position stage: every assignment that depends on q and the parameters only (sin and
  cos of the joint angles, the mass matrix, the gravity torques, and the position-only
  factors of the velocity terms), plus the LDL^T factorisation of M;
- the velocity stage: the assignments that involve qd, reading the position stage's
  results that they need (the interface), then the forcing and the triangular solves.

Position-only subexpressions inside velocity assignments (e.g. `p2*s1` in `p2*s1*qd1`) are
hoisted into position assignments of their own, so that the velocity stage does as little
as possible: it is the part that lies on the integrator's critical path.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from ..symbolic.symbols import internal_symbols
from .cse import Assignment


@dataclass
class StageSplit:
    """The assignments of each stage, in dependency order, and what passes between them."""

    position: list[Assignment]
    velocity: list[Assignment]
    velocity_outputs: list[sp.Expr]
    interface: list[sp.Symbol]  # position symbols read by the velocity stage


def _trivial(expr: sp.Expr) -> bool:
    """An atom or a negated atom: nothing worth a slot of its own (`-x` costs nothing)."""
    return expr.is_Atom or (expr.is_Mul and len(expr.args) == 2 and expr.args[0] == -1
                            and expr.args[1].is_Atom)


class _Hoister:
    """Rewrites velocity expressions so that their position-only parts are position symbols.

    A position-only subexpression becomes a new assignment, or the existing one with the
    same expression (`known`); the position-only arguments of a sum or product are grouped
    into one.
    """

    def __init__(self, is_position, known: dict[sp.Expr, sp.Symbol], prefix: str = "_h"):
        self.is_position = is_position
        self.assignments: list[Assignment] = []
        self._symbols = dict(known)
        self._names = internal_symbols(prefix)

    def symbol_for(self, expr: sp.Expr) -> sp.Expr:
        if _trivial(expr):
            return expr
        if expr not in self._symbols:
            symbol = next(self._names)
            self._symbols[expr] = symbol
            self.assignments.append(Assignment(symbol, expr))
        return self._symbols[expr]

    def __call__(self, expr: sp.Expr) -> sp.Expr:
        if expr.is_Atom:
            return expr
        if self.is_position(expr):
            return self.symbol_for(expr)
        args = expr.args
        if expr.is_Add or expr.is_Mul:
            fixed = [a for a in args if self.is_position(a)]
            others = [a for a in args if not self.is_position(a)]
            before = fixed + others  # the arguments, reordered
            moving = [self(a) for a in others]
            if len(fixed) > 1:
                group = expr.func(*fixed)
                if not _trivial(group):
                    fixed = [self.symbol_for(group)]
            elif len(fixed) == 1:
                fixed = [self.symbol_for(fixed[0])]
            after = fixed + moving
        else:
            before, after = args, [self(a) for a in args]
        # the same arguments make the same (canonical) expression: SymPy's construction is
        # the costly part, and most nodes on the way down to a hoisted part keep theirs
        if len(after) == len(before) and all(a is b for a, b in zip(after, before)):
            return expr
        return expr.func(*after)


def split_stages(assignments: list[Assignment], position_outputs: list[sp.Expr],
                 velocity_outputs: list[sp.Expr], velocity_inputs: set[sp.Symbol]
                 ) -> StageSplit:
    """Split `assignments` (all those the outputs need, in dependency order).

    `position_outputs` must depend on positions only (M, g); `velocity_outputs` may depend
    on anything (the forcing). `velocity_inputs` are the symbols known in the velocity stage
    only (qd, tau).
    """
    moving: set[sp.Symbol] = set()
    depends = set(velocity_inputs)
    for a in assignments:
        if not depends.isdisjoint(a.expr.free_symbols):
            moving.add(a.symbol)
            depends.add(a.symbol)
    for e in position_outputs:
        if not depends.isdisjoint(e.free_symbols):
            raise ValueError(f"a position output depends on the velocities: {e}")
    known_position: dict[sp.Expr, bool] = {}

    def is_position(e: sp.Expr) -> bool:
        """Whether `e` reads none of `depends`, from its arguments' answers (kept): the
        hoister asks of every node at every level, and free_symbols walks the subtree."""
        answer = known_position.get(e)
        if answer is None:
            if e.is_Symbol:
                answer = e not in depends
            elif e.is_Add or e.is_Mul or e.is_Pow or e.is_Function:
                answer = all(is_position(a) for a in e.args)
            else:
                answer = depends.isdisjoint(e.free_symbols)
            known_position[e] = answer
        return answer

    known = {a.expr: a.symbol for a in assignments if a.symbol not in moving}
    hoist = _Hoister(is_position, known)
    velocity = [Assignment(a.symbol, hoist(a.expr)) for a in assignments if a.symbol in moving]
    outputs = [hoist(e) for e in velocity_outputs]
    position = [a for a in assignments if a.symbol not in moving] + hoist.assignments
    defined = {a.symbol for a in position}
    read = set().union(*(a.expr.free_symbols for a in velocity), *(e.free_symbols
                                                                  for e in outputs))
    interface = [a.symbol for a in position if a.symbol in read and a.symbol in defined]
    return StageSplit(position, velocity, outputs, interface)
