"""Forward-mode differentiation of a straight-line program of named intermediates.

The derivations write every quantity as a short definition `t_k = e_k(earlier symbols)`.
The derivative of an output with respect to a set of variables x (coordinates, rates,
parameters) follows by the chain rule over those definitions, in their order:

    dt_k/dx_j = sum over the symbols s of e_k:  (de_k/ds) * (ds/dx_j)

Each partial de_k/ds is the derivative of one small expression, and each sum is named as
a new intermediate, so the derivative program stays a straight-line program of short
definitions, about as many per variable as the program it differentiates; nothing is
expanded, and derivatives that are structurally zero are never written (a chain's body k
depends on q_1..q_k only).
"""

from __future__ import annotations

from collections.abc import Iterable

import sympy as sp

from .kinematics import Recorder

Derivatives = dict[int, sp.Expr]  # variable index -> non-zero derivative


def needed_definitions(definitions: list[tuple[sp.Symbol, sp.Expr]], outputs: Iterable,
                       first: int = 0) -> list[tuple[sp.Symbol, sp.Expr]]:
    """The definitions from index `first` on that the outputs depend on, in order."""
    position = {s: k for k, (s, _) in enumerate(definitions) if k >= first}
    keep: set[int] = set()
    stack = [s for e in outputs for s in sp.sympify(e).free_symbols if s in position]
    while stack:
        k = position[stack.pop()]
        if k not in keep:
            keep.add(k)
            stack.extend(s for s in definitions[k][1].free_symbols if s in position)
    return [definitions[k] for k in sorted(keep)]


def differentiate(definitions: list[tuple[sp.Symbol, sp.Expr]], outputs: list[sp.Expr],
                  variables: list[sp.Symbol], rec: Recorder) -> list[list[sp.Expr]]:
    """The Jacobian d outputs[i] / d variables[j], as expressions in named intermediates.

    `definitions` is the program the outputs are written in (each symbol defined from
    earlier ones); `rec` names the derivative's definitions and should continue that
    program (`recorder_after`), so that the names it reuses (sin q, cos q, ...) are the
    program's own. Returns a len(outputs) x len(variables) list of lists.
    """
    index = {v: j for j, v in enumerate(variables)}
    seeds: dict[sp.Symbol, Derivatives] = {v: {j: sp.Integer(1)} for v, j in index.items()}
    tangent: dict[sp.Symbol, Derivatives] = {}
    for symbol, expr in needed_definitions(definitions, outputs):
        tangent[symbol] = _tangent(expr, tangent, seeds, rec)
    jacobian = []
    for expr in outputs:
        row = _tangent(sp.sympify(expr), tangent, seeds, rec)
        jacobian.append([row.get(j, sp.Integer(0)) for j in range(len(variables))])
    return jacobian


def recorder_after(definitions: list[tuple[sp.Symbol, sp.Expr]], prefix: str = "_g"
                   ) -> Recorder:
    """A Recorder continuing `definitions`: new names are numbered after them, and an
    expression they already name is reused, never defined twice."""
    rec = Recorder(prefix)
    rec.definitions = list(definitions)
    rec._by_expr = {expr: symbol for symbol, expr in definitions}
    # numbered after every name of the program, also when some definitions were dropped
    numbers = [int(s.name[len(prefix):]) for s, _ in definitions
               if s.name.startswith(prefix) and s.name[len(prefix):].isdigit()]
    rec.next_index = max(numbers, default=-1) + 1
    return rec


def _tangent(expr: sp.Expr, tangent: dict[sp.Symbol, Derivatives],
             seeds: dict[sp.Symbol, Derivatives], rec: Recorder) -> Derivatives:
    """The non-zero derivatives of one expression, from those of its symbols."""
    terms: dict[int, list[sp.Expr]] = {}
    active = [s for s in expr.free_symbols if tangent.get(s) or seeds.get(s)]
    partials = _partials(expr, set(active))
    for s in sorted(active, key=_symbol_order):
        inner = tangent.get(s) or seeds[s]
        partial = rec.name(partials[s])
        if partial == 0:
            continue
        for j, d in inner.items():
            terms.setdefault(j, []).append(partial * d)
    out: Derivatives = {}
    for j, parts in terms.items():
        value = rec.name(sp.Add(*parts))
        if value != 0:
            out[j] = value
    return out


def _partials(expr: sp.Expr, symbols: set[sp.Symbol]) -> dict[sp.Symbol, sp.Expr]:
    """d expr / d s for each s of `symbols`. A sum is differentiated term by term, each
    term only by the symbols it holds: an output of a few hundred operations in a hundred
    symbols (a Gibbs-Appell torque) costs the sum of its terms' sizes, not a hundred times
    its size."""
    if not expr.is_Add:
        return {s: _derivative(expr, s) for s in symbols}
    parts: dict[sp.Symbol, list[sp.Expr]] = {s: [] for s in symbols}
    for term in expr.args:
        held = symbols & term.free_symbols
        if held:
            for s, d in _partials(term, held).items():
                parts[s].append(d)
    return {s: sp.Add(*ds) for s, ds in parts.items()}


def _derivative(expr: sp.Expr, s: sp.Symbol) -> sp.Expr:
    """d expr / d s, with d sign(x)/dx = 0: Coulomb friction's sign(qd) (symbolic.joints) is
    constant wherever it has a derivative, and its jump at 0 has none (SymPy would leave an
    unevaluated Derivative or write 2 DiracDelta(x), which no backend can evaluate)."""
    signs = {f: sp.Dummy() for f in expr.atoms(sp.sign)}
    if not signs:
        return sp.diff(expr, s)
    held = sp.diff(expr.xreplace(signs), s)  # each sign(...) held constant
    return held.xreplace({dummy: f for f, dummy in signs.items()})


def _symbol_order(symbol: sp.Symbol) -> tuple[str, str]:
    # a set's order depends on the process's string hashing; names must not
    return type(symbol).__name__, symbol.name
