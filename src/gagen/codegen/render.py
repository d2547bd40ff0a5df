"""C code generation: the CSE'd equations printed into C99 through templates.

Each C function gets the assignments its outputs depend on (cse.py), printed once and
shared by every function that needs them. The robot's simulation (simulation.c) evaluates
forward dynamics in a position and a velocity stage (stage_split.py) inside integrators
specialised for the model (templates/gagen_second_order.h).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import jinja2
import sympy as sp
from sympy.printing.c import C99CodePrinter
from sympy.printing.precedence import PRECEDENCE, precedence

from .. import __version__
from ..manifest import ModelInfo
from ..symbolic.gibbs_appell import Equations
from .config import INLINE_STAGE_OPS, CodegenConfig  # noqa: F401 (re-exported)
from .cse import CSEResult
from .ldlt import factor_pattern, ldlt_plan  # noqa: F401 (factor_pattern re-exported)
from .stages import StageSplit, split_stages

# copied verbatim next to the generated sources (templates/c/)
COPIED_FILES = ("integrator.c", "integrator.h", "gagen_ode.h", "gagen_second_order.h",
                "gagen_math.h")
# the C files of a model, all compiled into its module
MODEL_C_FILES = ("mass_matrix.c", "rhs.c", "simulation.c", "inverse_dynamics.c",
                 "integrator.c")
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
_GAGEN_FILE_STEMS = frozenset(Path(f).stem.lower() for f in COPIED_FILES + MODEL_C_FILES)
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


class GagenCPrinter(C99CodePrinter):
    """C99 printer that names symbols by array slot and avoids pow() for small powers.

    sin and cos of a coordinate q[k] print as the locals sn<k> and cs<k>, which each
    function computes first (`trig_prelude`), two coordinates at a time.
    """

    def __init__(self, names: dict[sp.Symbol, str], coordinates: list[sp.Symbol],
                 fast_trig: bool = True):
        # gagen_math.h's sin and cos: about twice as fast as libm's, within 1 ulp
        trig = {"sin": "gagen_sin", "cos": "gagen_cos"} if fast_trig else {}
        super().__init__({"strict": False, "user_functions": trig})
        self._fast_trig = fast_trig
        self._names = names
        self._angles = {q: k for k, q in enumerate(coordinates)}

    def name_of(self, symbol: sp.Symbol) -> str:
        """The C name a symbol prints as."""
        return self._names[symbol]

    def names(self, symbol: sp.Symbol) -> bool:
        """Whether the symbol has a C name yet."""
        return symbol in self._names

    def bind_names(self, names: dict[sp.Symbol, str]) -> None:
        """Give more symbols their C names (the locals hoisted into a stage)."""
        self._names.update(names)

    def _print_Symbol(self, expr):
        return self._names[expr]

    def _print_sin(self, expr):
        k = self._angles.get(expr.args[0])
        return f"sn{k}" if k is not None else self._print_Function(expr)

    def _print_cos(self, expr):
        k = self._angles.get(expr.args[0])
        return f"cs{k}" if k is not None else self._print_Function(expr)

    def trig_prelude(self, exprs) -> list[str]:
        """C statements that set sn<k>, cs<k> for the coordinates whose sin or cos `exprs` use."""
        used = sorted({self._angles[f.args[0]] for e in exprs for f in e.atoms(sp.sin, sp.cos)
                       if f.args[0] in self._angles})
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
    """The straight-line code of one C function: sin and cos, local assignments, outputs."""

    prelude: list[str]
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


def _block(cse: CSEResult, printer: GagenCPrinter, exprs: list[sp.Expr],
           targets: list[str], printed: dict[sp.Symbol, str]) -> CodeBlock:
    """One function's code; `printed` keeps each assignment's C text for the other blocks."""
    return _assignments_block(printer, cse.needed(exprs), exprs, targets, printed)


def _assignments_block(printer: GagenCPrinter, assignments, exprs: list[sp.Expr],
                       targets: list[str], printed: dict[sp.Symbol, str] | None = None
                       ) -> CodeBlock:
    """The code of given assignments (their text cached in `printed` if given) and outputs."""
    cache = {} if printed is None else printed
    for a in assignments:
        if a.symbol not in cache:
            cache[a.symbol] = printer.doprint(a.expr)
    local = [(printer.name_of(a.symbol), cache[a.symbol]) for a in assignments]
    outputs = [(t, printer.doprint(e)) for t, e in zip(targets, exprs)]
    prelude = printer.trig_prelude([a.expr for a in assignments] + list(exprs))
    return CodeBlock(prelude=prelude, locals=local, outputs=outputs)


@dataclass
class Stages:
    """Forward dynamics under u + g(q) as a position and a velocity stage (simulation.c)."""

    position: CodeBlock
    velocity: CodeBlock
    interface: list[tuple[int, str]]  # (slot in S, local name)
    size: int  # doubles of S: interface, g(q), 1/D, M (holding U = L D)
    gravity_at: int
    dinv_at: int
    mass_at: int
    ops: int  # operations of both stages
    inline: bool  # small enough to go inline into every integrator stage


def _stages(eqs: Equations, cse: CSEResult, printer: GagenCPrinter,
            printed: dict[sp.Symbol, str], targets: dict[str, list[str]],
            inline_stage_ops: int) -> Stages:
    out = cse.outputs
    coords = eqs.coords
    no_torque = {tau: sp.Integer(0) for tau in coords.tau}
    free_forcing = [e.xreplace(no_torque) for e in out["forcing"]]
    fixed_outputs = out["mass_matrix"] + out["gravity"]
    split: StageSplit = split_stages(cse.needed(fixed_outputs + free_forcing), fixed_outputs,
                                     free_forcing, set(coords.qd) | set(coords.tau))
    hoisted = [a for a in split.position if not printer.names(a.symbol)]
    printer.bind_names({a.symbol: f"h{k}" for k, a in enumerate(hoisted)})
    used = set().union(*(a.expr.free_symbols for a in split.velocity),
                       *(e.free_symbols for e in split.velocity_outputs))
    if used & set(coords.tau):
        raise RuntimeError("internal error: the velocity stage refers to the joint torques")
    position = _assignments_block(printer, split.position, fixed_outputs,
                                  targets["mass_matrix"] + targets["gravity"], printed)
    velocity = _assignments_block(printer, split.velocity, split.velocity_outputs,
                                  targets["forcing"])
    n, ni = eqs.n, len(split.interface)
    interface = [(k, printer.name_of(s)) for k, s in enumerate(split.interface)]
    ops = sp.count_ops([a.expr for a in split.position + split.velocity]
                       + fixed_outputs + split.velocity_outputs)
    return Stages(position, velocity, interface, size=ni + 2 * n + n * n, gravity_at=ni,
                  dinv_at=ni + n, mass_at=ni + 2 * n, ops=ops,
                  inline=ops <= inline_stage_ops)


def generate(eqs: Equations, module_name: str, key: str,
             config: CodegenConfig | None = None) -> GeneratedCode:
    """Generate the C sources, header and Cython wrapper of a model (file name -> text)."""
    config = config or CodegenConfig()
    model = eqs.model
    ident = c_identifier(model.name)
    cse = CSEResult(eqs)
    printer = GagenCPrinter(_symbol_names(eqs, cse), list(eqs.coords.q), config.fast_trig)
    n = eqs.n
    lower = [(r, s) for r in range(n) for s in range(r + 1)]
    out = cse.outputs
    mass_targets = [f"M[{r * n + s}]" for r, s in lower]
    printed: dict[sp.Symbol, str] = {}
    forcing_targets = [f"F[{r}]" for r in range(n)]
    gravity_targets = [f"G[{r}]" for r in range(n)]
    blocks = {
        "mass_matrix": _block(cse, printer, out["mass_matrix"], mass_targets, printed),
        "forcing": _block(cse, printer, out["forcing"], forcing_targets, printed),
        "inverse_dynamics": _block(cse, printer, out["inverse_dynamics"],
                                   [f"tau[{r}]" for r in range(n)], printed),
        "energy": _block(cse, printer, out["energy"], ["TV[0]", "TV[1]"], printed),
        "gravity": _block(cse, printer, out["gravity"], gravity_targets, printed),
    }
    stages = _stages(eqs, cse, printer, printed, {"mass_matrix": mass_targets,
                                                  "gravity": gravity_targets,
                                                  "forcing": forcing_targets},
                     config.inline_stage_ops)
    zero = {(r, s) for (r, s), e in zip(lower, out["mass_matrix"]) if e == 0}
    context = {
        "ident": ident,
        "IDENT": ident.upper(),
        "n": n,
        "np": len(eqs.parameters),
        # user names reach the sources only as identifiers (comments of the header)
        "coordinates": [c_identifier(c) for c in model.coordinates],
        "parameters": [(c_identifier(k), repr(float(v))) for k, v in model.parameters.items()],
        "lower": lower,
        "ldlt": ldlt_plan(n, zero),
        "blocks": blocks,
        "stages": stages,
        "module_name": module_name,
        "key": key,
        # names, joints and defaults for the runtime, as hex digits: no text of the model
        "manifest_hex": ModelInfo.from_model(model).to_hex(),
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
        f"{module_name}.pyx": env.get_template("cython/wrapper.pyx.j2").render(context),
    }
    for name in COPIED_FILES:
        text = resources.files("gagen.codegen").joinpath("templates", "c", name).read_text()
        files[name] = f"/* {context['header']} (copied from gagen's templates) */\n" + text
    return GeneratedCode(files=files, ops_before=cse.ops_before, ops_after=cse.ops_after,
                         cse_seconds=cse.seconds, module_name=module_name, ident=ident)


def write_sources(code: GeneratedCode, folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in sorted(code.files.items()):
        (folder / name).write_text(text)
