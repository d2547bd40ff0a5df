"""C code generation: one CSE pass over every output, printed into C99 through templates.

The derivation's intermediates and all outputs (mass matrix, forcing, inverse dynamics,
energy) go through `sympy.cse` together, so a subexpression shared anywhere is
computed once. Each C function then gets the assignments its outputs depend on, in one
dependency order shared by all functions.
"""

from __future__ import annotations

import hashlib
import heapq
import re
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import jinja2
import sympy as sp
from sympy.printing.c import C99CodePrinter
from sympy.printing.precedence import PRECEDENCE, precedence

from . import __version__
from .gibbs_appell import Equations

TEMPLATE_FILES = ("macros.j2", "header.h.j2", "mass_matrix.c.j2", "rhs.c.j2", "rhs_gc.c.j2",
                  "inverse_dynamics.c.j2", "wrapper.pyx.j2", "integrator.c", "integrator.h",
                  "gagen_math.h")
# copied verbatim next to the generated sources
COPIED_FILES = ("integrator.c", "integrator.h", "gagen_math.h")
# the C files of a model, all compiled into its module
MODEL_C_FILES = ("mass_matrix.c", "rhs.c", "rhs_gc.c", "inverse_dynamics.c", "integrator.c")
_C_KEYWORDS = frozenset({
    "auto", "break", "case", "char", "const", "continue", "default", "do", "double", "else",
    "enum", "extern", "float", "for", "goto", "if", "inline", "int", "long", "register",
    "restrict", "return", "short", "signed", "sizeof", "static", "struct", "switch", "typedef",
    "union", "unsigned", "void", "volatile", "while", "_Bool", "_Complex", "_Imaginary",
})


def c_identifier(name: str, fallback: str = "model") -> str:
    """A valid C identifier made from any name (`I_{xx}` -> `I_xx`, `m.1` -> `m_1`)."""
    ident = re.sub(r"[^A-Za-z0-9_]+", "_", name).strip("_") or fallback
    if ident[0].isdigit():
        ident = f"_{ident}"
    if ident in _C_KEYWORDS:
        ident += "_"
    return ident


def _balanced_sum(terms: list[tuple[bool, str]]) -> str:
    """C text of a sum of (negated?, text) terms, grouped as a balanced tree.

    Without -ffast-math the compiler keeps C's left-to-right order, so a k-term sum
    written flat is a chain of k - 1 dependent additions; grouped, its depth is log2(k).
    The kernels are latency-bound (each integrator stage waits on the previous one), so
    the shorter chains make them faster. `a - b + (c - d)` evaluates as (a - b) + (c - d).
    """
    if len(terms) == 1:
        negative, text = terms[0]
        return f"-{text}" if negative else text
    half = (len(terms) + 1) // 2
    left, right = _balanced_sum(terms[:half]), terms[half:]
    if len(right) == 1:
        negative, text = right[0]
        return f"{left} {'-' if negative else '+'} {text}"
    return f"{left} + ({_balanced_sum(right)})"


class GagenCPrinter(C99CodePrinter):
    """C99 printer that names symbols by array slot and avoids pow() for small powers."""

    def __init__(self, names: dict[sp.Symbol, str]):
        # gagen_math.h's sin and cos: about twice as fast as libm's, within 1 ulp
        super().__init__({"strict": False,
                          "user_functions": {"sin": "gagen_sin", "cos": "gagen_cos"}})
        self._names = names

    def _print_Symbol(self, expr):
        return self._names[expr]

    def _print_Add(self, expr, order=None):
        terms = []
        for term in self._as_ordered_terms(expr, order=order):
            text = self._print(term)
            negative = text.startswith("-") and not term.is_Add
            if negative:
                text = text[1:]
            if precedence(term) < PRECEDENCE["Add"] or term.is_Add:
                text = f"({text})"
            terms.append((negative, text))
        return _balanced_sum(terms)

    def _print_Pow(self, expr):
        base, exp = expr.args
        if exp.is_Integer and 2 <= int(exp) <= 4:
            b = self.parenthesize(base, PRECEDENCE["Mul"])  # atoms and calls stay bare
            return "*".join([b] * int(exp))
        if exp == -1:
            return f"1.0/{self.parenthesize(base, PRECEDENCE['Mul'])}"
        if exp.is_Integer and -4 <= int(exp) <= -2:
            b = self.parenthesize(base, PRECEDENCE["Mul"])
            return "1.0/(" + "*".join([b] * -int(exp)) + ")"
        return super()._print_Pow(expr)


@dataclass
class Assignment:
    symbol: sp.Symbol
    expr: sp.Expr
    deps: frozenset = field(default_factory=frozenset)


@dataclass
class CodeBlock:
    """The straight-line code of one C function: local assignments, then outputs."""

    locals: list[tuple[str, str]]
    outputs: list[tuple[str, str]]


@dataclass
class GeneratedCode:
    files: dict[str, str]
    ops_before: int
    ops_after: int
    cse_seconds: float
    module_name: str
    ident: str


class CSEResult:
    """All assignments in one dependency order, and the reduced output expressions."""

    def __init__(self, eqs: Equations):
        outputs = eqs.outputs()
        defs = eqs.intermediates
        flat = [e for v in outputs.values() for e in v]
        self.ops_before = _ops(e for _, e in defs) + _ops(flat)
        start = time.perf_counter()
        temps, reduced = sp.cse([e for _, e in defs] + flat,
                                symbols=sp.numbered_symbols("_x"), order="canonical")
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
        self.ops_after = _ops(a.expr for a in self.assignments) + _ops(reduced_out)

    def needed(self, exprs) -> list[Assignment]:
        """The assignments these expressions depend on, in the shared order."""
        defined = {a.symbol: a for a in self.assignments}
        need: set[sp.Symbol] = set()
        stack = [s for e in exprs for s in e.free_symbols if s in defined]
        while stack:
            s = stack.pop()
            if s not in need:
                need.add(s)
                stack.extend(d for d in defined[s].deps if d not in need)
        return [a for a in self.assignments if a.symbol in need]


def _ops(exprs) -> int:
    return sum(sp.count_ops(e) for e in exprs)


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


def _comment_safe(text) -> str:
    """Text that cannot end a C comment early, whatever the user's names."""
    return str(text).replace("*/", "* /").replace("\n", " ")


def template_environment() -> jinja2.Environment:
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("gagen", "templates"),
        keep_trailing_newline=True,
        trim_blocks=True,
        lstrip_blocks=True,
        undefined=jinja2.StrictUndefined,
    )
    env.filters["comment"] = _comment_safe
    return env


def templates_digest() -> str:
    """A hash of every template, part of the build cache key."""
    h = hashlib.sha256()
    folder = resources.files("gagen").joinpath("templates")
    for name in TEMPLATE_FILES:
        h.update(name.encode())
        h.update(folder.joinpath(name).read_bytes())
    return h.hexdigest()


def _symbol_names(eqs: Equations, cse: CSEResult) -> dict[sp.Symbol, str]:
    c = eqs.coords
    names: dict[sp.Symbol, str] = {}
    for array, symbols in (("q", c.q), ("qd", c.qd), ("qdd", c.qdd), ("tau", c.tau),
                           ("p", eqs.parameters)):
        names.update({s: f"{array}[{k}]" for k, s in enumerate(symbols)})
    for k, a in enumerate(cse.assignments):
        names[a.symbol] = f"t{k}"
    return names


def _block(cse: CSEResult, printer: GagenCPrinter, exprs: list[sp.Expr],
           targets: list[str], printed: dict[sp.Symbol, str]) -> CodeBlock:
    """One function's code; `printed` keeps each assignment's C text for the other blocks."""
    local = []
    for a in cse.needed(exprs):
        if a.symbol not in printed:
            printed[a.symbol] = printer.doprint(a.expr)
        local.append((printer._names[a.symbol], printed[a.symbol]))
    outputs = [(t, printer.doprint(e)) for t, e in zip(targets, exprs)]
    return CodeBlock(locals=local, outputs=outputs)


def factor_pattern(n: int, zero: set[tuple[int, int]]) -> set[tuple[int, int]]:
    """Entries (i, j), i > j, of the LDL^T factor that can be non-zero, fill-in included.

    The unrolled factorisation skips every product with a structural zero of M, e.g. the
    coupling between a vertical base joint and the joints of a planar arm."""
    nonzero: set[tuple[int, int]] = set()
    for j in range(n):
        for i in range(j + 1, n):
            if (i, j) not in zero or any((i, k) in nonzero and (j, k) in nonzero
                                         for k in range(j)):
                nonzero.add((i, j))
    return nonzero


def generate(eqs: Equations, module_name: str, key: str) -> GeneratedCode:
    """Generate the C sources, header and Cython wrapper of a model (file name -> text)."""
    model = eqs.model
    ident = c_identifier(model.name)
    cse = CSEResult(eqs)
    printer = GagenCPrinter(_symbol_names(eqs, cse))
    n = eqs.n
    lower = [(r, s) for r in range(n) for s in range(r + 1)]
    out = cse.outputs
    mass_targets = [f"M[{r * n + s}]" for r, s in lower]
    printed: dict[sp.Symbol, str] = {}
    forcing_targets = [f"F[{r}]" for r in range(n)]
    gravity_targets = [f"G[{r}]" for r in range(n)]
    no_torque = {tau: sp.Integer(0) for tau in eqs.coords.tau}
    free_forcing = [e.xreplace(no_torque) for e in out["forcing"]]
    blocks = {
        "mass_matrix": _block(cse, printer, out["mass_matrix"], mass_targets, printed),
        "rhs": _block(cse, printer, out["mass_matrix"] + out["forcing"],
                      mass_targets + forcing_targets, printed),
        "forcing": _block(cse, printer, out["forcing"], forcing_targets, printed),
        "inverse_dynamics": _block(cse, printer, out["inverse_dynamics"],
                                   [f"tau[{r}]" for r in range(n)], printed),
        "energy": _block(cse, printer, out["energy"], ["TV[0]", "TV[1]"], printed),
        "gravity": _block(cse, printer, out["gravity"], gravity_targets, printed),
        # M, F(q, qd, 0) and G(q) sharing one evaluation (forward_dynamics_gc): a feedback
        # law that compensates gravity then costs the integrator no second model pass.
        "terms": _block(cse, printer, out["mass_matrix"] + free_forcing + out["gravity"],
                        mass_targets + forcing_targets + gravity_targets, printed),
    }
    zero = {(r, s) for (r, s), e in zip(lower, out["mass_matrix"]) if e == 0}
    context = {
        "model": model,
        "name": model.name,
        "ident": ident,
        "IDENT": ident.upper(),
        "n": n,
        "np": len(eqs.parameters),
        "coordinates": model.coordinates,
        "parameters": [(k, repr(float(v))) for k, v in model.parameters.items()],
        "lower": lower,
        "lnz": factor_pattern(n, zero),
        "blocks": blocks,
        "module_name": module_name,
        "key": key,
        "version": __version__,
        "header": f"generated by gagen {__version__} for model '{model.name}'; do not edit",
    }
    env = template_environment()
    files = {
        f"{ident}.h": env.get_template("header.h.j2").render(context),
        "mass_matrix.c": env.get_template("mass_matrix.c.j2").render(context),
        "rhs.c": env.get_template("rhs.c.j2").render(context),
        "rhs_gc.c": env.get_template("rhs_gc.c.j2").render(context),
        "inverse_dynamics.c": env.get_template("inverse_dynamics.c.j2").render(context),
        f"{module_name}.pyx": env.get_template("wrapper.pyx.j2").render(context),
    }
    for name in COPIED_FILES:
        text = resources.files("gagen").joinpath("templates/" + name).read_text()
        files[name] = f"/* {_comment_safe(context['header'])} (copied from gagen's templates) */\n" + text
    return GeneratedCode(files=files, ops_before=cse.ops_before, ops_after=cse.ops_after,
                         cse_seconds=cse.seconds, module_name=module_name, ident=ident)


def write_sources(code: GeneratedCode, folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in sorted(code.files.items()):
        (folder / name).write_text(text)
