"""C code generation: the CSE'd equations printed into C99 through templates.

Each C function gets the assignments its outputs depend on (cse.py), printed once and
shared by every function that needs them. The robot's simulation (simulation.c) evaluates
forward dynamics in a position and a velocity stage (stage_split.py) inside integrators
specialised for the model (templates/gagen_second_order.h).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import jinja2
import numpy as np
import sympy as sp
from sympy.core.function import Function
from sympy.printing.c import C99CodePrinter
from sympy.printing.precedence import PRECEDENCE, precedence

from .. import __version__
from ..manifest import (
    FRICTION_WIDTH,
    JOINT_KINDS,
    QUATERNION_RESTORING,
    ModelInfo,
    constraint_derivative_layout,
    dof_parents,
)
from ..symbolic.centroidal import centroidal_program
from ..symbolic.differentiate import needed_definitions
from ..symbolic.frames import (
    OFFSET_SIZE,
    TRANSFORM_SIZE,
    add_frame_kinematics,
    constrained_frames,
)
from ..symbolic.gibbs_appell import Equations
from ..symbolic.regressor import (
    KINEMATICS_PER_BODY,
    RegressorKinematics,
    regressor_kinematics,
    regressor_parameters,
)
from .config import INLINE_STAGE_OPS, CodegenConfig  # noqa: F401 (re-exported)
from .cse import CSEResult, operation_count
from .ldlt import factor_pattern, ldlt_plan  # noqa: F401 (factor_pattern re-exported)
from .segments import FILE_CHARS, Segment, Statement, schedule_late, split
from .stages import StageSplit, split_stages

# copied verbatim next to the generated sources (templates/c/)
COPIED_FILES = ("integrator.c", "integrator.h", "gagen_ode.h", "gagen_second_order.h",
                "gagen_generic.h", "gagen_math.h", "gagen_api.h")
# the C files of a model, all compiled into its module (plain C, usable without Python)
MODEL_C_FILES = ("mass_matrix.c", "rhs.c", "simulation.c", "inverse_dynamics.c", "frames.c",
                 "regressor.c", "centroidal.c", "integrator.c")
# the module's one file that speaks to Python: the kernels' table for gagen's runtime
MODULE_FILE = "module.c"
# a model with constraints: the derivatives of its constrained dynamics, which call the
# derivative module's kernels too, so its module leaves the file out (builder._c_files);
# the header it includes is copied next to it
CONSTRAINED_DERIVATIVES_FILE = "constrained_derivatives.c"
CONSTRAINED_DERIVATIVES_HEADER = "gagen_constraint_derivatives.h"
_C_KEYWORDS = frozenset({
    "auto", "break", "case", "char", "const", "continue", "default", "do", "double", "else",
    "enum", "extern", "float", "for", "goto", "if", "inline", "int", "long", "register",
    "restrict", "return", "short", "signed", "sizeof", "static", "struct", "switch", "typedef",
    "union", "unsigned", "void", "volatile", "while", "_Bool", "_Complex", "_Imaginary",
})


# A model's identifier names its header (<ident>.h, next to gagen's own files) and prefixes
# its C functions and macros, so it must not be one of gagen's file names, start like
# gagen's own symbols (gagen_so_*, GAGEN_*), or be a C keyword. (System headers cannot be
# shadowed: the build folder is never on the include path, every local include is quoted.)
_GAGEN_FILE_STEMS = frozenset(Path(f).stem.lower()
                              for f in (*COPIED_FILES, *MODEL_C_FILES, MODULE_FILE,
                                        CONSTRAINED_DERIVATIVES_FILE))
RESERVED_PREFIX = "model_"


def c_identifier(name: str) -> str:
    """The one way a model's name becomes a C identifier: [A-Za-z0-9_] only, never reserved.

    Runs of other characters become `_` (`my robot-1` -> `my_robot_1`); a name that is
    empty, starts with a digit, is a C keyword, one of gagen's file names or starts with
    `gagen` gets the prefix `model_` (`int` -> `model_int`, `integrator` -> `model_integrator`).
    """
    ident = re.sub(r"[^A-Za-z0-9_]+", "_", str(name)).strip("_")
    lowered = ident.lower()
    if (not ident or ident[0].isdigit() or ident in _C_KEYWORDS or lowered in _GAGEN_FILE_STEMS
            or lowered.startswith("gagen")):
        ident = RESERVED_PREFIX + ident
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


class _Unusual(Exception):
    """An expression the fast printer leaves to SymPy's printer as a whole."""


# The node types gagen's expressions are made of, printed by GagenCPrinter's fast path;
# any other node is printed by SymPy's printer (`GagenCPrinter._print`).
_FAST_TYPES = ("Symbol", "Integer", "Rational", "Float", "Add", "Mul", "Pow", "sin", "cos",
               "sign")
_ADD, _MUL, _POW, _FUNC, _ATOM = (PRECEDENCE[k] for k in ("Add", "Mul", "Pow", "Func", "Atom"))
# SymPy's level for the one factor of a negated product (codeprinter.CodePrinter._print_Mul)
_NEGATED = 0.5 * (_POW + _MUL)
_KIND_PRECEDENCE = {"Symbol": _ATOM, "Add": _ADD, "Mul": _MUL, "Pow": _POW, "sin": _FUNC,
                    "cos": _FUNC, "sign": _FUNC}


class GagenCPrinter(C99CodePrinter):
    """C99 printer that names symbols by array slot and avoids pow() for small powers.

    sin and cos of a coordinate q[k] print as the locals sn<k> and cs<k>, which each
    function computes first (`trig_prelude`), two coordinates at a time. sign(x) prints as
    gagen_sign(x) (0 at 0), or, while `smooth_sign_width` holds the C text of a width w,
    as gagen_smooth_sign(x, w) = tanh(x / w) (the simulation's velocity stage), and
    f*sign(x) then as gagen_coulomb(f, x, w).

    `doprint` takes a fast path for the nodes gagen's expressions are made of (symbols,
    numbers, sums, products, small integer powers, sin, cos and sign): it walks `expr.args`
    in SymPy's canonical order, which is deterministic, where SymPy's printer sorts every
    sum's terms and asks each node for its precedence and sign through the assumptions
    (about ten times slower). The C it writes is SymPy's printer's (`sympy_doprint`) up to
    the order of terms and factors: the same numbers (`(1.0/4.0)`, Floats to 17 digits),
    parentheses, `x*x` for small powers, `1.0/x`, negative terms as subtractions, the
    balanced sums. Other nodes go to SymPy's printer, and an expression it cannot print
    plainly (an unsupported function, a number constant, UnevaluatedExpr) goes to it whole.
    """

    smooth_sign_width: str | None = None

    def __init__(self, names: dict[sp.Symbol, str], coordinates: list[sp.Symbol],
                 fast_trig: bool = True):
        # gagen_math.h's sin and cos: about twice as fast as libm's, within 1 ulp
        trig = {"sin": "gagen_sin", "cos": "gagen_cos"} if fast_trig else {}
        super().__init__({"strict": False, "user_functions": trig})
        self._fast_trig = fast_trig
        self._names = names
        self._angles = {q: k for k, q in enumerate(coordinates)}
        self._dispatch: dict[type, object] = {}  # node type -> its fast method ...
        self._kinds: dict[type, str | None] = {}  # ... and its kind (_resolve)
        self._floats: dict[tuple, str] = {}  # a Float's C text, by value and precision
        self._leaf_cache: dict[sp.Expr, tuple[frozenset, frozenset]] = {}
        self._reads: dict[sp.Expr, frozenset[str]] = {}

    def name_of(self, symbol: sp.Symbol) -> str:
        """The C name a symbol prints as."""
        return self._names[symbol]

    def names(self, symbol: sp.Symbol) -> bool:
        """Whether the symbol has a C name yet."""
        return symbol in self._names

    def bind_names(self, names: dict[sp.Symbol, str]) -> None:
        """Give more symbols their C names (the locals hoisted into a stage)."""
        self._names.update(names)

    # -- what an expression reads ------------------------------------------------------

    def _leaves(self, expr: sp.Expr) -> tuple[frozenset, frozenset]:
        """The symbols an expression reads and the sin/cos locals of coordinates it uses
        (("sn" or "cs", k) pairs), found in one walk and kept: every assignment is asked
        for by several kernels (sympy's atoms() and free_symbols walk it each time)."""
        found = self._leaf_cache.get(expr)
        if found is None:
            symbols, trig = set(), set()
            angles, trig_types = self._angles, (sp.sin, sp.cos)
            stack = [expr]
            while stack:
                e = stack.pop()
                if e.is_Symbol:
                    symbols.add(e)
                    continue
                args = e.args
                if args:
                    if e.is_Function and isinstance(e, trig_types) and args[0] in angles:
                        trig.add(("sn" if isinstance(e, sp.sin) else "cs", angles[args[0]]))
                    stack.extend(args)
            found = (frozenset(symbols), frozenset(trig))
            self._leaf_cache[expr] = found
        return found

    def trig_used(self, exprs) -> list[int]:
        """The coordinates whose sin or cos `exprs` use, in order."""
        return sorted({k for e in exprs for _, k in self._leaves(e)[1]})

    def reads(self, expr: sp.Expr) -> frozenset[str]:
        """The C names an expression reads: its symbols' and its sin/cos locals."""
        names = self._reads.get(expr)
        if names is None:
            symbols, trig = self._leaves(expr)
            named = [self._names[s] for s in symbols if s in self._names]
            names = frozenset(named).union(f"{kind}{k}" for kind, k in trig)
            if len(named) == len(symbols):  # kept once final: names are never unbound
                self._reads[expr] = names
        return names

    def trig_prelude(self, exprs) -> list[str]:
        """C statements that set sn<k>, cs<k> for the coordinates whose sin or cos `exprs` use."""
        used = self.trig_used(exprs)
        if not used:
            return []
        lines = ["double " + ", ".join(f"sn{k}, cs{k}" for k in used) + ";"]
        if not self._fast_trig:
            return lines + [f"sn{k} = sin(q[{k}]); cs{k} = cos(q[{k}]);" for k in used]
        for a, b in zip(used[::2], used[1::2]):
            lines.append(f"gagen_sincos2(q[{a}], q[{b}], &sn{a}, &cs{a}, &sn{b}, &cs{b});")
        if len(used) % 2:
            k = used[-1]
            lines.append(f"gagen_sincos(q[{k}], &sn{k}, &cs{k});")
        return lines

    # -- the fast path -------------------------------------------------------------------

    def doprint(self, expr, assign_to=None):
        """The C text of an expression (the fast path; `sympy_doprint` is SymPy's own)."""
        if assign_to is not None or not isinstance(expr, sp.Basic):
            return super().doprint(expr, assign_to)
        self._not_supported, self._number_symbols = set(), set()
        try:
            text = self._fast(expr)
        except _Unusual:
            text = None
        if text is None or self._not_supported or self._number_symbols or "\n" in text:
            return super().doprint(expr)
        return text

    def sympy_doprint(self, expr) -> str:
        """The C text of an expression as SymPy's printer writes it, its terms sorted."""
        return super().doprint(expr)

    def _fast(self, expr) -> str:
        method = self._dispatch.get(type(expr))
        if method is None:
            method = self._resolve(type(expr))[0]
        return method(expr)

    def _resolve(self, cls: type) -> tuple:
        """The fast method of a node type and its kind (a name of _FAST_TYPES, or None for
        SymPy's printer): the method SymPy's dispatch would reach through the same class
        (Coordinate and Internal are Symbols)."""
        kind = None
        if not (hasattr(cls, self.printmethod) or issubclass(cls, sp.UnevaluatedExpr)):
            if issubclass(cls, Function):  # SymPy's dispatch treats subclasses apart
                if cls in (sp.sin, sp.cos, sp.sign):
                    kind = cls.__name__
            else:
                for base in cls.__mro__:
                    if base.__name__ in _FAST_TYPES and base.__module__.startswith("sympy."):
                        kind = base.__name__
                        break
                    if hasattr(self, "_print_" + base.__name__):
                        break  # SymPy's printer has a method of its own first (Zero, Dummy)
        method = self._sympy_node if kind is None else getattr(self, "_fast_" + kind)
        self._dispatch[cls], self._kinds[cls] = method, kind
        return method, kind

    def _kind(self, expr) -> str | None:
        cls = type(expr)
        return self._kinds[cls] if cls in self._kinds else self._resolve(cls)[1]

    def _sympy_node(self, expr) -> str:
        """An unusual node, printed by SymPy's printer."""
        if expr.has(sp.UnevaluatedExpr):
            raise _Unusual  # doprint rewrites these first
        return self._print(expr)

    def _prec(self, expr) -> float:
        """SymPy's precedence of a node, where it matters to the fast path. A product's is
        that of a Mul whatever its sign: its parents parenthesise it either way."""
        kind = self._kind(expr)
        if kind is None:
            return precedence(expr)
        if kind == "Integer":
            return _ADD if expr.p < 0 else _ATOM
        if kind == "Rational":
            return _ADD if expr.p < 0 else _MUL
        if kind == "Float":
            return _ADD if self._fast_Float(expr).startswith("-") else _ATOM
        return _KIND_PRECEDENCE[kind]

    def _paren(self, expr, level: float) -> str:
        """A node's text, in parentheses if its precedence is at most `level` (SymPy's
        parenthesize, not strict)."""
        text = self._fast(expr)
        return f"({text})" if self._prec(expr) <= level else text

    def _fast_Symbol(self, expr) -> str:
        return self._names[expr]

    def _fast_Integer(self, expr) -> str:
        return str(expr.p)

    def _fast_Rational(self, expr) -> str:
        return f"{expr.p}.0/{expr.q}.0"  # C89CodePrinter._print_Rational

    def _fast_Float(self, expr) -> str:
        key = (expr._mpf_, expr._prec)
        text = self._floats.get(key)
        if text is None:
            text = self._floats[key] = self._print_Float(expr)  # 17 digits: round trip
        return text

    def _fast_sin(self, expr) -> str:
        k = self._angles.get(expr.args[0])
        return f"sn{k}" if k is not None else self._fast_function(expr)

    def _fast_cos(self, expr) -> str:
        k = self._angles.get(expr.args[0])
        return f"cs{k}" if k is not None else self._fast_function(expr)

    def _fast_function(self, expr) -> str:
        name = self.known_functions.get(type(expr).__name__)
        if not isinstance(name, str):
            return self._sympy_node(expr)
        return f"{name}({self._fast(expr.args[0])})"

    def _fast_sign(self, expr) -> str:
        arg = self._fast(expr.args[0])
        if self.smooth_sign_width is None:
            return f"gagen_sign({arg})"
        return f"gagen_smooth_sign({arg}, {self.smooth_sign_width})"

    def _fast_Add(self, expr) -> str:
        terms = []
        for term in expr.args:
            text = self._fast(term)
            if term.is_Add:
                terms.append((False, f"({text})"))
                continue
            negative = text.startswith("-")
            if negative:
                text = text[1:]
            if self._prec(term) < _ADD:
                text = f"({text})"
            terms.append((negative, text))
        return _balanced_sum(terms)

    def _fast_Pow(self, expr) -> str:
        base, exp = expr.args
        if exp.is_Integer:
            k = exp.p
            if 2 <= k <= 4:
                return "*".join([self._paren(base, _MUL)] * k)
            if k == -1:
                return "1.0/" + self._paren(base, _MUL)
            if -4 <= k <= -2:
                return "1.0/(" + "*".join([self._paren(base, _MUL)] * -k) + ")"
        return self._sympy_node(expr)

    def _fast_Mul(self, expr) -> str:
        """SymPy's CodePrinter._print_Mul, on the factors in their canonical order: the
        coefficient's sign in front, the factors with negative powers as the divisor."""
        args = expr.args
        if self.smooth_sign_width is not None:
            signs = [a for a in args if isinstance(a, sp.sign)]
            if len(signs) == 1:
                coefficient = sp.Mul(*[a for a in args if a is not signs[0]])
                return (f"gagen_coulomb({self._fast(coefficient)}, "
                        f"{self._fast(signs[0].args[0])}, {self.smooth_sign_width})")
        sign = ""
        numerator: list = []
        first = args[0]
        if first.is_Number:
            kind = self._kind(first)
            if kind not in ("Integer", "Rational", "Float"):
                return self._sympy_node(expr)
            if (first._mpf_[0] == 1) if kind == "Float" else first.p < 0:
                sign, first = "-", -first
            if kind == "Float" or first.p != 1 or first.q != 1:
                numerator.append(first)  # 1.0 stays, as SymPy's _keep_coeff leaves it
            args = args[1:]
        divisor: list[tuple[sp.Expr, int]] = []
        for factor in args:
            kind = self._kind(factor)
            if kind == "Pow":
                exp = factor.exp
                if not (exp.is_Integer and -4 <= exp.p <= 4):
                    return self._sympy_node(expr)  # sqrt, pow(): SymPy's printer's choice
                if exp.p < 0:
                    divisor.append((factor.base, -exp.p))
                    continue
            elif kind is None or kind in ("Integer", "Rational", "Float"):
                # M_PI_2 and the like, or a number out of place: SymPy's printer, whole
                return self._sympy_node(expr)
            numerator.append(factor)
        level = _ADD if sign else _MUL
        if not numerator:
            text = "1"
        elif len(numerator) == 1 and sign:
            text = self._paren(numerator[0], _NEGATED)
        else:
            text = "*".join([self._paren(f, level) for f in numerator])
        if not divisor:
            return sign + text
        # a divisor is parenthesised as a Mul's whatever the sign: a/(x*y), never a/x*y
        parts = ["*".join([self._paren(base, _MUL)] * k) for base, k in divisor]
        if len(divisor) == 1 and divisor[0][1] == 1:
            return f"{sign}{text}/{parts[0]}"
        return f"{sign}{text}/({'*'.join(parts)})"

    # -- SymPy's printer (fallbacks and `sympy_doprint`) ---------------------------------

    def parenthesize(self, item, level, strict=False):
        # x**2 prints as the product x*x: under a product's operators it needs parentheses
        # as a product does (SymPy's rank for a power left a/x**2 as a/x*x)
        if (isinstance(item, sp.Pow) and item.exp.is_Integer and 2 <= abs(item.exp.p) <= 4
                and level >= _ADD):
            return f"({self._print(item)})"
        return super().parenthesize(item, level, strict)

    def _print_Symbol(self, expr):
        return self._names[expr]

    def _print_sin(self, expr):
        k = self._angles.get(expr.args[0])
        return f"sn{k}" if k is not None else self._print_Function(expr)

    def _print_cos(self, expr):
        k = self._angles.get(expr.args[0])
        return f"cs{k}" if k is not None else self._print_Function(expr)

    def _print_sign(self, expr):
        arg = self._print(expr.args[0])
        if self.smooth_sign_width is None:
            return f"gagen_sign({arg})"
        return f"gagen_smooth_sign({arg}, {self.smooth_sign_width})"

    def _print_Mul(self, expr, **kwargs):
        # friction * sign(qd) in the simulation's stage: gagen_coulomb skips the smooth sign
        # (a tanh near rest) when the friction is 0, as it is for most joints of a URDF
        signs = [a for a in expr.args if isinstance(a, sp.sign)]
        if self.smooth_sign_width is None or len(signs) != 1:
            return super()._print_Mul(expr, **kwargs)
        coefficient = sp.Mul(*[a for a in expr.args if a is not signs[0]])
        return (f"gagen_coulomb({self._print(coefficient)}, {self._print(signs[0].args[0])}, "
                f"{self.smooth_sign_width})")

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
class CodeBlock:
    """The straight-line code of one C function: sin and cos, local assignments, outputs.

    A large block is split (codegen/segments.py): then `segments` are its functions, each
    called with `args` and the workspace, and defined with `params` in kernels_<k>.c."""

    prelude: list[str]
    locals: list[tuple[str, str]]
    outputs: list[tuple[str, str]]
    segments: list[Segment] = field(default_factory=list)
    workspace: int = 0
    params: str = ""
    args: str = ""


@dataclass
class GeneratedCode:
    files: dict[str, str]
    ops_before: int
    ops_after: int
    cse_seconds: float
    module_name: str
    ident: str


def template_environment() -> jinja2.Environment:
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("gagen.codegen", "templates"),
        keep_trailing_newline=True,
        trim_blocks=True,
        lstrip_blocks=True,
        undefined=jinja2.StrictUndefined,
    )
    return env




def _symbol_names(eqs: Equations, cse: CSEResult) -> dict[sp.Symbol, str]:
    c = eqs.coords
    names: dict[sp.Symbol, str] = {}
    for array, symbols in (("q", c.q), ("qd", c.qd), ("qdd", c.qdd), ("tau", c.tau),
                           ("p", eqs.parameters)):
        names.update({s: f"{array}[{k}]" for k, s in enumerate(symbols)})
    for k, a in enumerate(cse.assignments):
        names[a.symbol] = f"t{k}"
    return names


# Each kernel's C arrays, in the order its segment functions take them (then `w`); the last
# one is the kernel's output.
KERNEL_ARRAYS = {
    "mass_matrix": ("q", "p", "M"),
    "forcing": ("q", "qd", "tau", "p", "F"),
    "mass_forcing": ("q", "qd", "tau", "p", "MF"),
    "inverse_dynamics": ("q", "qd", "qdd", "p", "tau"),
    "energy": ("q", "qd", "p", "TV"),
    "gravity": ("q", "p", "G"),
    "position": ("q", "p", "S"),
    "velocity": ("S", "q", "qd", "tau", "p", "F"),
    "velocity_aba": ("S", "q", "qd", "tau", "p", "qdd"),
    "placements": ("q", "p", "X"),
    "frame_offsets": ("p", "F"),
    "regressor_kinematics": ("q", "qd", "qdd", "p", "K"),
    "regressor_parameters": ("p", "pi"),
}


# The kernels that run in loops (integrators, stacked inputs): their segment functions are
# GAGEN_KERNEL, built for CPUs with and without FMA like the unsplit kernels (gagen_math.h).
# Measured on a 50-link chain: inverse dynamics 2.04 -> 1.54 us and forward dynamics
# 4.84 -> 3.79 us per call, for 1.8 times their compile time.
LOOPED_KERNELS = ("inverse_dynamics", "gravity", "position", "velocity", "velocity_aba",
                  "mass_matrix", "mass_forcing")


class _Kernels:
    """Prints the blocks of one model's kernels, each assignment's text once for all of
    them, and splits the large ones into segment functions (codegen/segments.py)."""

    def __init__(self, ident: str, cse: CSEResult, printer: GagenCPrinter,
                 config: CodegenConfig, arrays: dict[str, tuple[str, ...]] = KERNEL_ARRAYS,
                 looped: tuple[str, ...] = LOOPED_KERNELS):
        self.ident, self.cse, self.printer = ident, cse, printer
        self.arrays, self.looped = arrays, looped  # another module's kernels: its own
        self.split_chars, self.segment_chars = config.split_chars, config.segment_chars
        self.printed: dict[sp.Symbol, str] = {}
        self.segments: list[Segment] = []  # of every split kernel, in order

    def block(self, kernel: str, exprs: list[sp.Expr], targets: list[str],
              assignments=None, externals: dict[sp.Symbol, str] | None = None,
              cache: bool = True, split: bool = True) -> CodeBlock:
        """The code of one kernel: the assignments its outputs need (or those given), then
        the outputs. `externals` are symbols read from an array (`S[3]`), not computed;
        `cache` shares each assignment's text with the other kernels (names must agree);
        `split=False` keeps a big block whole (a case of a switch, not a kernel)."""
        if assignments is None:
            assignments = self.cse.needed(exprs)
        printer = self.printer
        texts = self.printed if cache else {}
        for a in assignments:
            if a.symbol not in texts:
                texts[a.symbol] = printer.doprint(a.expr)
        reads = [(printer.name_of(s), source) for s, source in (externals or {}).items()]
        local = [(printer.name_of(a.symbol), texts[a.symbol]) for a in assignments]
        outputs = [(t, printer.doprint(e)) for t, e in zip(targets, exprs)]
        all_exprs = [a.expr for a in assignments] + list(exprs)
        block = CodeBlock(prelude=printer.trig_prelude(all_exprs), locals=reads + local,
                          outputs=outputs)
        size = sum(len(text) for _, text in local + outputs)
        if split and size > self.split_chars:
            self._split(block, kernel, assignments, exprs, reads, all_exprs)
        return block

    def _split(self, block: CodeBlock, kernel: str, assignments, exprs, reads,
               all_exprs) -> None:
        printer = self.printer
        statements = [Statement(name, text, printer.reads(a.expr))
                      for a, (name, text) in zip(assignments, block.locals[len(reads):])]
        outputs = [(t, text, printer.reads(e)) for (t, text), e in zip(block.outputs, exprs)]
        statements = schedule_late(statements, [names for _, _, names in outputs])
        segments, workspace = split(f"{self.ident}_{kernel}", _trig(printer, all_exprs),
                                    statements, outputs, externals=dict(reads),
                                    segment_chars=self.segment_chars)
        arrays = self.arrays[kernel]
        params = ", ".join([f"const double *restrict {a}" for a in arrays[:-1]]
                           + [f"double *restrict {arrays[-1]}"])
        for segment in segments:
            segment.params = params
            segment.looped = kernel in self.looped
        block.segments, block.workspace = segments, workspace
        block.params, block.args = params, ", ".join(arrays)
        self.segments.extend(segments)


def _trig(printer: GagenCPrinter, exprs) -> tuple[list[str], list[str]]:
    """The trig prelude of some expressions: its lines and the locals they define."""
    used = printer.trig_used(exprs)
    return printer.trig_prelude(exprs), [f"{kind}{k}" for k in used for kind in ("sn", "cs")]


def kernel_files(segments: list[Segment], file_chars: int = FILE_CHARS) -> list[list[Segment]]:
    """The segment functions gathered into files of about `file_chars` characters, so the
    build can compile them in parallel."""
    files: list[list[Segment]] = []
    size = file_chars
    for segment in segments:
        if size >= file_chars:
            files.append([])
            size = 0
        files[-1].append(segment)
        size += segment.chars
    return files


@dataclass
class Stages:
    """Forward dynamics under u + g(q) as a position and a velocity stage (simulation.c).

    With the articulated-body algorithm (`aba`), S holds the interface, g(q) and the pivots
    D_k; otherwise the interface, g(q), M(q)'s factors 1/D and M (holding U = L D)."""

    position: CodeBlock
    velocity: CodeBlock
    size: int  # doubles of S
    interface: int  # values the position stage passes to the velocity stage
    gravity_at: int
    dinv_at: int
    mass_at: int
    pivots_at: int
    ops: int  # operations of both stages
    inline: bool  # small enough to go inline into every integrator stage
    aba: bool


def friction_width_index(eqs: Equations) -> int | None:
    """The slot in p of the smooth sign's width, for a model with Coulomb friction."""
    if not eqs.model.has_friction:
        return None
    return list(eqs.model.parameters).index(FRICTION_WIDTH)


def _stages(eqs: Equations, kernels: _Kernels, inline_stage_ops: int) -> Stages:
    out, coords, printer = kernels.cse.outputs, eqs.coords, kernels.printer
    n = eqs.n
    aba = "forward_dynamics" in out
    if aba:
        # the articulated-body pass: tau enters in the velocity stage, the pivots are
        # position-only and checked by the position stage
        fixed_outputs = out["gravity"] + out["pivots"]
        moving_outputs = out["forward_dynamics"]
    else:
        no_torque = {tau: sp.Integer(0) for tau in coords.tau}
        fixed_outputs = out["mass_matrix"] + out["gravity"]
        moving_outputs = [e.xreplace(no_torque) for e in out["forcing"]]
    split: StageSplit = split_stages(kernels.cse.needed(fixed_outputs + moving_outputs),
                                     fixed_outputs, moving_outputs,
                                     set(coords.qd) | set(coords.tau))
    hoisted = [a for a in split.position if not printer.names(a.symbol)]
    printer.bind_names({a.symbol: f"h{k}" for k, a in enumerate(hoisted)})
    used = set().union(*(a.expr.free_symbols for a in split.velocity),
                       *(e.free_symbols for e in split.velocity_outputs))
    if not aba and used & set(coords.tau):
        raise RuntimeError("internal error: the velocity stage refers to the joint torques")
    ni = len(split.interface)
    gravity_at = ni
    if aba:
        pivots_at, dinv_at, mass_at, size = ni + n, 0, 0, ni + 2 * n
        targets = [f"S[{gravity_at + r}]" for r in range(n)] \
            + [f"S[{pivots_at + r}]" for r in range(n)]
        moving_targets = [f"qdd[{r}]" for r in range(n)]
    else:
        dinv_at, mass_at, pivots_at = ni + n, ni + 2 * n, 0
        size = ni + 2 * n + n * n
        lower = [(r, s) for r in range(n) for s in range(r + 1)]
        targets = [f"S[{mass_at + r * n + s}]" for r, s in lower] \
            + [f"S[{gravity_at + r}]" for r in range(n)]
        moving_targets = [f"F[{r}]" for r in range(n)]
    interface = {symbol: f"S[{k}]" for k, symbol in enumerate(split.interface)}
    position = kernels.block("position", fixed_outputs + list(interface), targets
                             + list(interface.values()), assignments=split.position)
    width = friction_width_index(eqs)
    # the integrators see Coulomb friction through a smooth sign (model.FRICTION_WIDTH);
    # forward_dynamics calls the same stage with the width set to 0, the exact sign
    printer.smooth_sign_width = None if width is None else f"p[{width}]"
    try:
        velocity = kernels.block("velocity_aba" if aba else "velocity",
                                 split.velocity_outputs, moving_targets,
                                 assignments=split.velocity, externals=interface, cache=False)
    finally:
        printer.smooth_sign_width = None
    ops = operation_count([a.expr for a in split.position + split.velocity]
                          + fixed_outputs + split.velocity_outputs)
    return Stages(position, velocity, size=size, interface=ni, gravity_at=gravity_at,
                  dinv_at=dinv_at, mass_at=mass_at, pivots_at=pivots_at, ops=ops,
                  inline=ops <= inline_stage_ops and not (position.segments
                                                          or velocity.segments),
                  aba=aba)


def _case_blocks(kernels: _Kernels, exprs: list[sp.Expr], size: int, array: str
                 ) -> list[CodeBlock]:
    """One whole block per `size` consecutive outputs, writing `array[0 .. size - 1]`."""
    return [kernels.block("case", exprs[k: k + size], [f"{array}[{i}]" for i in range(size)],
                          split=False)
            for k in range(0, len(exprs), size)]


def _regressor_blocks(eqs: Equations, kernels: _Kernels, config: CodegenConfig,
                      reg: RegressorKinematics, parameters: list[sp.Expr]
                      ) -> dict[str, CodeBlock]:
    """The regressor's functions: the per-body kinematics its C loop reads and pi
    (`parameters`; model/regressor.c.j2), from a CSE of their own (eliminating as the dynamics' does):
    what they share with the dynamics is in different C functions anyway, and the
    dynamics' kernels stay as they are without it. Their segment functions, if any, join
    `kernels`'."""
    outputs = {"regressor_kinematics": reg.values, "regressor_parameters": parameters}
    program = needed_definitions(reg.intermediates,
                                 [e for values in outputs.values() for e in values])
    cse = CSEResult(eqs, kernels.cse.eliminated, program, outputs)
    printer = GagenCPrinter(_symbol_names(eqs, cse), list(eqs.coords.q), config.fast_trig)
    own = _Kernels(kernels.ident, cse, printer, config)
    blocks = {name: own.block(name, cse.outputs[name],
                              [f"{target}[{k}]" for k in range(len(cse.outputs[name]))])
              for name, target in (("regressor_kinematics", "K"),
                                   ("regressor_parameters", "pi"))}
    kernels.segments.extend(own.segments)
    return blocks


# the arrays of the centroidal kernels (their own CSE and printer, as the regressor's): X is
# the placements, which they read instead of placing the bodies again
CENTROIDAL_ARRAYS = {"center_of_mass": ("X", "q", "p", "com"),
                     "centroidal_map": ("X", "q", "p", "Ag"), "robot_mass": ("p", "m")}


def _centroidal_blocks(eqs: Equations, kernels: _Kernels, config: CodegenConfig
                       ) -> dict[str, CodeBlock]:
    """The centre of mass, A_g and the robot's mass as straight-line code
    (symbolic/centroidal.py) reading the bodies' placements from X, from a CSE of their own
    as the regressor's: the dynamics' kernels stay as they are. Their segment functions, if
    any, join `kernels`'."""
    program = centroidal_program(eqs)
    outputs = {"center_of_mass": program.center_of_mass,
               "centroidal_map": program.centroidal_map,
               "robot_mass": [program.mass]}
    cse = CSEResult(eqs, kernels.cse.eliminated, program.intermediates, outputs)
    names = _symbol_names(eqs, cse)
    names.update({symbol: f"x{k}" for symbol, k in program.placements.items()})
    printer = GagenCPrinter(names, list(eqs.coords.q), config.fast_trig)
    own = _Kernels(kernels.ident, cse, printer, config, arrays=CENTROIDAL_ARRAYS, looped=())
    targets = {"center_of_mass": [f"com[{k}]" for k in range(3)],
               "centroidal_map": [f"Ag[{k}]" for k in range(6 * eqs.n)],
               "robot_mass": ["m[0]"]}
    blocks = {}
    for name, exprs in cse.outputs.items():
        needed = cse.needed(exprs)
        used = set().union(*(a.expr.free_symbols for a in needed),
                           *(e.free_symbols for e in exprs))
        reads = {s: f"X[{k}]" for s, k in program.placements.items() if s in used}
        blocks[name] = own.block(name, exprs, targets[name], externals=reads)
    kernels.segments.extend(own.segments)
    return blocks


def model_context(eqs: Equations) -> dict:
    """What every template says about the model: its identifier, sizes, and the names of
    its coordinates and parameters with the defaults."""
    ident = c_identifier(eqs.model.name)
    return {
        "ident": ident,
        "IDENT": ident.upper(),
        "n": eqs.n,
        "np": len(eqs.parameters),
        "nq": eqs.nq,
        # user names reach the sources only as identifiers (comments of the header)
        "coordinates": [c_identifier(c) for c in eqs.model.coordinates],
        "parameters": [(c_identifier(k), repr(float(v)))
                       for k, v in eqs.model.parameters.items()],
    }


def generate(eqs: Equations, module_name: str, key: str,
             config: CodegenConfig | None = None) -> GeneratedCode:
    """Generate the C sources and header of a model and its module's table of them
    (module.c, for gagen's runtime), as file name -> text.

    The regressor's kinematics (symbolic.regressor.regressor_kinematics) continue the
    program after the frames' kinematics."""
    config = config or CodegenConfig()
    if eqs.placements is None:  # equations written without the frames' kinematics
        eqs = add_frame_kinematics(eqs)
    reg = regressor_kinematics(eqs)
    model = eqs.model
    reg_parameters = regressor_parameters(model)  # pi (symbolic: computed once)
    ident = c_identifier(model.name)
    cse = CSEResult(eqs, eqs.derivation == "gibbs-appell" if config.cse is None else config.cse)
    printer = GagenCPrinter(_symbol_names(eqs, cse), list(eqs.coords.q), config.fast_trig)
    kernels = _Kernels(ident, cse, printer, config)
    n = eqs.n
    lower = [(r, s) for r in range(n) for s in range(r + 1)]
    out = cse.outputs
    info = ModelInfo.from_model(model)
    zero = {(r, s) for (r, s), e in zip(lower, out["mass_matrix"]) if e == 0}
    zero_fill = zero_fills_mass_matrix(n, len(zero))
    mass_entries = [(r, s, e) for (r, s), e in zip(lower, out["mass_matrix"])
                    if not (zero_fill and (r, s) in zero)]
    blocks = {
        "mass_matrix": kernels.block("mass_matrix", [e for _, _, e in mass_entries],
                                     [_symmetric_target("M", n, r, s)
                                      for r, s, _ in mass_entries]),
        "forcing": kernels.block("forcing", out["forcing"], [f"F[{r}]" for r in range(n)]),
        "inverse_dynamics": kernels.block("inverse_dynamics", out["inverse_dynamics"],
                                          [f"tau[{r}]" for r in range(n)]),
        "energy": kernels.block("energy", out["energy"], ["TV[0]", "TV[1]"]),
        "gravity": kernels.block("gravity", out["gravity"], [f"G[{r}]" for r in range(n)]),
        "placements": kernels.block("placements", out["placements"],
                                    [f"X[{k}]" for k in range(len(out["placements"]))]),
        "frame_offsets": kernels.block("frame_offsets", out["frame_offsets"],
                                       [f"F[{k}]" for k in range(len(out["frame_offsets"]))]),
        **_regressor_blocks(eqs, kernels, config, reg, reg_parameters),
        **_centroidal_blocks(eqs, kernels, config),
    }
    parents = dof_parents(info.bodies, n)
    lower_entries = mass_entries_on_paths(out["mass_matrix"], parents)
    by_factors = forward_dynamics_by_factors(kernels.cse, [e for _, _, e in lower_entries],
                                             parents)
    if model.constraints or by_factors:
        # the constrained dynamics need M, F and the constrained frames' poses, motions and
        # Jacobian columns (symbolic.frames.constraint_frame_terms) at each call: one
        # program for them shares their kinematics (ANYmal C: 4495 operations instead of
        # 2278 + 2667 for M and F) and fetches less code per call than kernels one after the
        # other. The frames' terms from it, instead of frames.c's loops over the bodies'
        # tables, took ANYmal C's four feet 3.53 -> 3.44 us per call from Python (40.1k ->
        # 34.2k instructions in C, with the placements' step before). Of M, the lower
        # triangle only, where the factorisation reads it: each entry on a coordinate's
        # path to the world (the others are zero and never read), a zero one written as
        # such, no clearing of all n^2 first (2.79 -> 2.71 us in C, medians of 9 runs).
        # The forward dynamics of a model without constraints take the same program where
        # it is cheaper than the articulated-body one (forward_dynamics_by_factors)
        terms = out.get("constraint_frames", [])
        blocks["mass_forcing"] = kernels.block(
            "mass_forcing",
            [e for _, _, e in lower_entries] + list(out["forcing"]) + list(terms),
            [f"MF[{r * n + s}]" for r, s, _ in lower_entries]
            + [f"MF[{n * n + r}]" for r in range(n)]
            + [f"MF[{n * n + n + k}]" for k in range(len(terms))])
    # per body and per frame, the code of one alone: a frame's kinematics then places its
    # path to the world, not every body and every frame
    cases = {
        "joint_transforms": _case_blocks(kernels, out["joint_transforms"], TRANSFORM_SIZE, "T"),
        "frame_offsets": _case_blocks(kernels, out["frame_offsets"], OFFSET_SIZE, "F"),
    }
    stages = _stages(eqs, kernels, config.inline_stage_ops)
    context = {
        **model_context(eqs),
        "nreg": len(reg_parameters),
        "reg": reg,
        "per_body": KINEMATICS_PER_BODY,
        "width_index": friction_width_index(eqs),
        "configuration": [c_identifier(c) for c in model.configuration],
        # where each floating joint starts in q and qd, and the entry of q of each
        # velocity coordinate that is a plain number (-1: a floating joint's)
        "floating": [start for body, start in model.indices().items()
                     if model.body(body).joint.floating],
        "q_of_v": _configuration_entries(model),
        "quaternion_restoring": repr(float(QUATERNION_RESTORING)),
        # the tree for frame kinematics: numbers only (the names stay in the manifest)
        "tree": info.bodies,
        "frame_bodies": [body for _, body, _ in info.frames],
        "frame_names": [c_identifier(name) for name, _, _ in info.frames],
        # the moving bodies for centroidal.c: (body, moving parent, kind, first coordinate)
        "centroidal": info.moving_tree,
        "dof_parents": dof_parents(info.bodies, n),
        "ltdl_plan": ltdl_plan(dof_parents(info.bodies, n)),
        # forward_dynamics() by M = L^T D L (constraints.c) instead of the stages
        "fd_by_factors": by_factors,
        # the constraints: numbers only (their names stay in the manifest)
        **constraint_context(info, list(model.parameters)),
        "jointed": info.jointed_coordinates(),
        "ldlt": ldlt_plan(n, zero),
        "zero_fill": zero_fill,
        "blocks": blocks,
        "cases": cases,
        "stages": stages,
        "module_name": module_name,
        "key": key,
        # names, joints and defaults for the runtime, as hex digits: no text of the model
        "manifest_hex": info.to_hex(),
        "version": __version__,
        "header": f"generated by gagen {__version__} for model '{ident}'; do not edit",
    }
    env = template_environment()
    files = {
        f"{ident}.h": env.get_template("model/header.h.j2").render(context),
        "mass_matrix.c": env.get_template("model/mass_matrix.c.j2").render(context),
        "rhs.c": env.get_template("model/rhs.c.j2").render(context),
        "simulation.c": env.get_template("model/simulation.c.j2").render(context),
        "inverse_dynamics.c": env.get_template("model/inverse_dynamics.c.j2").render(context),
        "frames.c": env.get_template("model/frames.c.j2").render(context),
        "regressor.c": env.get_template("model/regressor.c.j2").render(context),
        "centroidal.c": env.get_template("model/centroidal.c.j2").render(context),
        MODULE_FILE: env.get_template("model/module.c.j2").render(context),
    }
    kernels_template = env.get_template("model/kernels.c.j2")
    for k, segments in enumerate(kernel_files(kernels.segments, config.file_chars)):
        files[f"kernels_{k}.c"] = kernels_template.render(context, segments=segments)
    copied = list(COPIED_FILES)
    if info.constraints:
        context["cd"] = {key: np.ravel(value).tolist()
                         for key, value in constraint_derivative_layout(info).items()}
        files[CONSTRAINED_DERIVATIVES_FILE] = env.get_template(
            "model/constrained_derivatives.c.j2").render(context)
        copied.append(CONSTRAINED_DERIVATIVES_HEADER)
    for name in copied:
        text = resources.files("gagen.codegen").joinpath("templates", "c", name).read_text()
        files[name] = f"/* {context['header']} (copied from gagen's templates) */\n" + text
    return GeneratedCode(files=files, ops_before=cse.ops_before, ops_after=cse.ops_after,
                         cse_seconds=cse.seconds, module_name=module_name, ident=ident)


# M = L^T D L is written out (taskspace.c) up to this many eliminations; past it, a loop
# over the tree's parents. The written form's code grows with them (ANYmal C's 237: 20 kB,
# more than half the CPU's instruction cache), and where it runs (the constrained dynamics,
# the task-space calls) with other large kernels its instructions come from L2 on every
# call: the loop is no slower there (ANYmal C's constrained forward dynamics 2.81 us in C
# against 2.85 us written out, CPU time of a loop of single calls, -mfma), in a twentieth
# of the code
LTDL_UNROLLED = 100


def ltdl_plan(parents: list[int]) -> list[tuple[int, list[tuple[int, list[int]]]]] | None:
    """The steps of Featherstone's factorisation M = L^T D L on this tree (taskspace.c's
    gagen_ltdl): per coordinate k from the last, each ancestor i with the coordinates j it
    updates (i and its ancestors); None when they number more than LTDL_UNROLLED."""
    plan, count = [], 0
    for k in reversed(range(len(parents))):
        steps = []
        i = parents[k]
        while i >= 0:
            js, j = [], i
            while j >= 0:
                js.append(j)
                j = parents[j]
            steps.append((i, js))
            count += len(js)
            i = parents[i]
        plan.append((k, steps))
        if count > LTDL_UNROLLED:
            return None
    return plan


def mass_entries_on_paths(lower: list[sp.Expr], parents: list[int]
                          ) -> list[tuple[int, int, sp.Expr]]:
    """(r, s, entry) of M's lower triangle (row by row) where M = L^T D L reads it: each
    entry on a coordinate's path to the world, and the other non-zero ones."""
    n = len(parents)
    chains = [{r, *_ancestors(parents, r)} for r in range(n)]
    pairs = [(r, s) for r in range(n) for s in range(r + 1)]
    return [(r, s, e) for (r, s), e in zip(pairs, lower) if e != 0 or s in chains[r]]


def tree_factored(cse: CSEResult, model) -> list[int] | None:
    """The tree's parents (per velocity coordinate) where forward dynamics go by M's
    factors along the tree (forward_dynamics_by_factors), else None: what the C and the
    printed JAX of the model both follow."""
    parents = dof_parents(ModelInfo.from_model(model).bodies, len(cse.outputs["forcing"]))
    entries = mass_entries_on_paths(cse.outputs["mass_matrix"], parents)
    if forward_dynamics_by_factors(cse, [e for _, _, e in entries], parents):
        return parents
    return None


def forward_dynamics_by_factors(cse: CSEResult, mass_entries: list[sp.Expr],
                                parents: list[int]) -> bool:
    """Whether forward_dynamics() is cheaper as M and F from one program, M = L^T D L along
    the tree (no fill-in) and two solves, than by the articulated-body program of the
    recursive derivation: by their operation counts (a derivation without that program
    keeps its stages). The factorisation costs, per coordinate k and ancestor i, the
    entries of i's path; the solves one multiply-add per entry of L.

    ANYmal C: 4665 + 690 operations against 7138, and 0.96 against 1.67 us per state
    (stacked calls of 1000 states, alternating the two builds); the Panda (a chain of 9)
    2415 + 237 against 3147, 0.36 against 0.43 us; UR5 0.17 against 0.28 us; Talos reduced
    (38) 10171 + the tree's against 14260, 4.04 against 3.92 us (its programs are many
    times the instruction cache: as fast either way)."""
    out = cse.outputs
    if "forward_dynamics" not in out:
        return False
    aba = out["forward_dynamics"] + out["pivots"]
    mass_forcing = list(mass_entries) + list(out["forcing"])
    factor = sum(len(_ancestors(parents, i)) + 2 for k in range(len(parents))
                 for i in _ancestors(parents, k))
    solves = 2 * sum(len(_ancestors(parents, k)) for k in range(len(parents))) + len(parents)
    return (_program_operations(cse, mass_forcing) + factor + solves
            < _program_operations(cse, aba))


def _program_operations(cse: CSEResult, outputs: list[sp.Expr]) -> int:
    """The operations of the outputs and of the assignments they need."""
    return operation_count([a.expr for a in cse.needed(outputs)] + list(outputs))


def constraint_context(info: ModelInfo, parameters: list[str]) -> dict:
    """The tables of constraints.c: per constraint its frames (-1: the world), reference
    (Pinocchio's number), 6-D or 3-D convention, rows, first row and where a contact's
    anchor parameters are in p (-1: none); per row its axis; the header's list of them."""
    table, axes, row = [], [], 0
    for c in info.constraints:
        anchors = c.anchor_names()
        table.append({"a": info.frame_indices[c.frames[0]],
                      "b": info.frame_indices[c.frames[1]] if c.type == "loop" else -1,
                      "reference": 1 if c.reference == "local" else 2,
                      "six": int(c.holds_frame), "dim": c.dimension, "first": row,
                      "anchor": [parameters.index(a) for a in anchors] + [-1] * (6 - len(anchors))})
        axes += list(c.axes)
        row += c.dimension
    names = [f"{c.type} {c_identifier(c.name)}: {' '.join(c.axis_names)}, {c.reference}"
             for c in info.constraints]
    paths = [set().union(*(_path_coordinates(info, f) for f in c.frames))
             for c in info.constraints]
    ranges = [_runs(path) for path in paths]
    common = [_runs(paths[k] & paths[j]) for k in range(len(paths)) for j in range(k + 1)]
    parents = dof_parents(info.bodies, info.dof)
    eliminations = [[(c, i) for c in sorted(path, reverse=True) for i in _ancestors(parents, c)]
                    for path in paths]
    size = sum(len(e) * c.dimension for e, c in zip(eliminations, info.constraints))
    slots = constrained_frames(info)
    return {"constraint_table": table, "constraint_axes": axes, "constraint_rows": row,
            # per constraint the slots of its frames among the constrained frames (B: -1 for
            # a contact), and per slot where its terms start after M and F and its columns'
            # coordinates (symbolic.frames.constraint_frame_terms)
            "constraint_slots": [[slots.index(f) for f in c.frames] + [-1] * (2 - len(c.frames))
                                 for c in info.constraints],
            "constraint_frame_columns": [_frame_column_coordinates(info, f) for f in slots],
            "constraint_names": names, "constraint_ranges": ranges,
            "constraint_common": common,
            "constraint_range_size": max([len(r) for r in ranges + common] + [1]),
            # each constraint's rows of J L^-1, written out up to a size
            "constraint_eliminations": eliminations if size <= CONSTRAINT_UNROLLED else None,
            # and the Delassus matrix's blocks, pair by pair of constraints, up to a count
            "constraint_blocks_written": (size <= CONSTRAINT_BLOCKS_UNROLLED
                                          and len(table) <= CONSTRAINT_BLOCKS_WRITTEN)}


# the rows of J L^-1 are written out per constraint (constraints.c) up to this many
# multiply-adds over all constraints; past it, a loop over each path's runs. ANYmal C's four
# feet have 432: written out, 9 kB of instructions, which with M's, the forcing's and the
# rows' do not stay in the CPU's instruction cache from one call to the next; the loop
# took its constrained forward dynamics 2.81 -> 2.68 us in C (CPU time, a loop of single
# calls, the LTDL factorisation a loop in both)
CONSTRAINT_UNROLLED = 200
# the Delassus matrix's blocks are written out up to this size of the rows' eliminations
CONSTRAINT_BLOCKS_UNROLLED = 6000
# the blocks of G = Z Y^T are written out per pair of constraints (their common runs as
# constants: the loops unroll and vectorise) up to this many constraints (136 pairs); the
# runs read from tables cost ANYmal C's four feet a fifth of the constrained dynamics
CONSTRAINT_BLOCKS_WRITTEN = 16


def _ancestors(parents: list[int], c: int) -> list[int]:
    out, i = [], parents[c]
    while i >= 0:
        out.append(i)
        i = parents[i]
    return out


def _frame_column_coordinates(info: ModelInfo, frame: str) -> list[int]:
    """The coordinates of a frame's Jacobian columns in frames.c's gagen_frame_columns
    order: from its body up, a floating joint's linear three then its angular three."""
    sizes = {JOINT_KINDS["fixed"]: 0, JOINT_KINDS["floating"]: 6}
    out: list[int] = []
    body = info.frames[info.frame_indices[frame]][1]
    while body >= 0:
        parent, kind, column = info.bodies[body]
        out += list(range(column, column + sizes.get(kind, 1)))
        body = parent
    return out


def _runs(coordinates: set[int]) -> list[tuple[int, int]]:
    """Sorted coordinates as runs [start, stop) of consecutive ones."""
    runs: list[tuple[int, int]] = []
    for c in sorted(coordinates):
        if runs and runs[-1][1] == c:
            runs[-1] = (runs[-1][0], c + 1)
        else:
            runs.append((c, c + 1))
    return runs


def _path_coordinates(info: ModelInfo, frame: str) -> set[int]:
    """The velocity coordinates of the joints between a frame and the world: the columns
    where its Jacobian, and its rows of J L^-1, can be non-zero."""
    return set(_frame_column_coordinates(info, frame))


def zero_fills_mass_matrix(n: int, zeros: int) -> bool:
    """Whether mass_matrix() clears M with memset and then writes its non-zero entries only:
    when more than a quarter of the lower triangle's entries are structural zeros (a
    branching tree's), one vectorised fill of n*n doubles costs less than two scalar stores
    per zero (Tiago: 48 coordinates, most of M zero)."""
    return 4 * zeros > n * (n + 1) // 2


def _symmetric_target(array: str, n: int, r: int, s: int) -> str:
    """The C target of entry (r, s) of a symmetric n x n array: both triangles at once
    (copying the upper from the lower afterwards reads every entry back, and the
    compiler's alias analysis of those copies grows with their square)."""
    if r == s:
        return f"{array}[{r * n + s}]"
    return f"{array}[{s * n + r}] = {array}[{r * n + s}]"


def _configuration_entries(model) -> list[int]:
    """For each velocity coordinate, its entry in q, or -1 for a floating joint's."""
    out = []
    for body, (iq, iv) in model.indices().items():
        joint = model.body(body).joint
        out += [-1] * 6 if joint.floating else [iq]
    return out


def write_sources(code: GeneratedCode, folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in sorted(code.files.items()):
        (folder / name).write_text(text)
