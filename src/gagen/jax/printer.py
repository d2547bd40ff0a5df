"""gagen's optimised programs printed as JAX: the build-time half of target="jax".

The same CSE'd assignments the C printer prints (codegen/render.py's `generate` and
codegen/derivatives.py's `generate_derivatives`: the same equations, the same
`CSEResult`s, each assignment printed by the same `GagenCPrinter` fast path), written as
Python functions over `jax.numpy`. Every function works elementwise over the inputs'
leading dimensions, so one call takes one state or a batch, and `jax.jit` compiles it for
whatever backend JAX has.

What is printed is checked before it is written: every expression is parsed as Python
and may contain only numbers, the names this printer gave (inputs `q3`, parameters `p7`,
assignments `t12`, the sines and cosines `sn0`, `cs0`) and the functions of `FUNCTIONS`,
joined by arithmetic. Nothing of the description reaches the module as text: the model's
names stay in the manifest, and the module's own names are built here from numbers.

Imports SymPy (through the equations): only a build does. gagen.jax.printed keeps the
modules in the cache and loads them without SymPy.
"""

from __future__ import annotations

import ast

import sympy as sp

from gagen import __version__
from gagen.codegen.cse import CSEResult
from gagen.codegen.derivatives import derivative_program
from gagen.codegen.ldlt import ldlt_plan
from gagen.codegen.render import GagenCPrinter, c_identifier, tree_factored
from gagen.errors import BuildError
from gagen.symbolic.differentiate import needed_definitions
from gagen.symbolic.frames import add_frame_kinematics
from gagen.symbolic.regressor import KINEMATICS_PER_BODY, regressor_kinematics
from gagen.symbolic.regressor import regressor_parameters as regressor_parameter_exprs

# The functions a printed expression may call, as the C printer names them, and what they
# are in JAX (the module's prelude binds them).
FUNCTIONS = {"sin": "jnp.sin", "cos": "jnp.cos", "tan": "jnp.tan", "sqrt": "jnp.sqrt",
             "pow": "jnp.power", "exp": "jnp.exp", "log": "jnp.log", "fabs": "jnp.abs",
             "tanh": "jnp.tanh", "atan2": "jnp.arctan2", "asin": "jnp.arcsin",
             "acos": "jnp.arccos", "atan": "jnp.arctan", "gagen_sign": "jnp.sign"}
CONSTANTS = {"M_PI": "math.pi", "M_PI_2": "(math.pi / 2)", "M_PI_4": "(math.pi / 4)",
             "M_E": "math.e", "M_SQRT2": "math.sqrt(2.0)"}
_ARITHMETIC = (ast.Expression, ast.BinOp, ast.UnaryOp, ast.Add, ast.Sub, ast.Mult, ast.Div,
               ast.USub, ast.UAdd, ast.Constant, ast.Name, ast.Load, ast.Call)
_INPUTS = ("q", "qd", "qdd", "tau", "p")
# the most operations a printed value may add to the program by being duplicated into its
# readers (XLA's fusion inlines cheap values into every reader); a costlier one is kept in
# an array of its own (_Writer.body). Measured on the Panda arm's forward dynamics (4,096
# states): 8 keeps 257 of the 457 values read twice or more, which ran 1.4x faster than keeping
# all (fastest of 80 interleaved runs: 1.83 ms against 2.56 ms; 3, 16 and 32 were no faster).
# On ANYmal C's forward dynamics 16 is faster than 8 (701 of XLA's loops instead of 758;
# medians of interleaved runs, load 2-4 on 2 cores: 8.98 against 10.69 ms, and 9.83 against
# 11.02 ms; 24 and 32 in between, 64 twice as slow), the Panda arm's the same (2.61 ms
# both), the Panda's derivatives compile as fast (26-27 s CPU against 25-26 s).
DUPLICATED = 16


def _symbol_names(eqs, cse: CSEResult) -> dict[sp.Symbol, str]:
    """Python names of the program's symbols: q3, qd3, qdd3, tau3, p7, t12."""
    c = eqs.coords
    names: dict[sp.Symbol, str] = {}
    for prefix, symbols in (("q", c.q), ("qd", c.qd), ("qdd", c.qdd), ("tau", c.tau),
                            ("p", eqs.parameters)):
        names.update({s: f"{prefix}{k}" for k, s in enumerate(symbols)})
    for k, a in enumerate(cse.assignments):
        names[a.symbol] = f"t{k}"
    return names


def _checked(text: str, defined: set[str]) -> str:
    """`text` if it is an arithmetic expression in defined names, numbers and FUNCTIONS."""
    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError as exc:
        raise BuildError(f"gagen.jax: an expression did not print as Python: {exc}") from None
    for node in ast.walk(tree):
        if not isinstance(node, _ARITHMETIC):
            raise BuildError(f"gagen.jax: the printed expression holds {type(node).__name__}")
        if isinstance(node, ast.Constant) and type(node.value) not in (int, float):
            raise BuildError("gagen.jax: the printed expression holds a non-numeric constant")
        if isinstance(node, ast.Call):
            if not (isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS
                    and not node.keywords):
                raise BuildError("gagen.jax: the printed expression calls an unknown function")
        elif isinstance(node, ast.Name) and node.id not in defined and node.id not in FUNCTIONS \
                and node.id not in CONSTANTS:
            raise BuildError(f"gagen.jax: the printed expression reads an undefined name "
                             f"{node.id!r}")
    return text


class _Writer:
    """Prints functions of one CSE'd program, each assignment's text once."""

    def __init__(self, eqs, cse: CSEResult):
        self.eqs, self.cse = eqs, cse
        self.names = _symbol_names(eqs, cse)
        self.printer = GagenCPrinter(dict(self.names), list(eqs.coords.q), fast_trig=False)
        self.texts: dict[sp.Symbol, str] = {}
        self.lines: list[str] = []
        # each printed name's cost where XLA inlines it: its operations and those of the
        # names it reads that are inlined too (0 for a value kept in an array of its own)
        self.inlined: dict[str, int] = {}
        # the names that are functions of the parameters alone
        self.fixed: set[str] = {f"p{k}" for k in range(len(eqs.parameters))}
        self.angles = set(eqs.coords.q)

    def trig_count(self, expr: sp.Expr) -> int:
        """How many sines and cosines of coordinates `expr` holds (count_ops counts each)."""
        angles = self.angles
        return sum(1 for node in sp.preorder_traversal(expr)
                   if isinstance(node, (sp.sin, sp.cos)) and node.args[0] in angles)

    def text(self, expr: sp.Expr) -> str:
        return self.printer.doprint(expr)

    def function(self, name: str, arguments: tuple[str, ...], outputs: dict[str, list],
                 shapes: dict[str, tuple[int, ...]], before_return: list[str] | None = None,
                 assignments=None, result: str | None = None) -> None:
        """def name(arguments): unpack the inputs read, the needed assignments, then each
        output's entries stacked to its shape; returns them (one, or a tuple)."""
        exprs = [e for values in outputs.values() for e in values]
        if assignments is None:
            assignments = self.cse.needed(exprs)
        self.lines.append(f"def {name}({', '.join(arguments)}):")
        body = self.body(assignments, outputs, arguments)
        self.lines += ["    " + line for line in body]
        for line in before_return or []:
            self.lines.append("    " + line)
        returned = result or ", ".join(
            f"_stack(({', '.join(v)}{',' if len(v) == 1 else ''}), {shapes[k]})"
            for k, v in self.output_texts.items())
        self.lines.append(f"    return {returned}")
        self.lines.append("")

    def body(self, assignments, outputs: dict[str, list], arguments, defined=None,
             later=()) -> list[str]:
        """The lines computing `outputs` (their texts in self.output_texts): the inputs'
        entries that are read, the sines and cosines, the assignments. `later`: the
        expressions the rest of the function computes from them."""
        exprs = [a.expr for a in assignments] + [e for v in outputs.values() for e in v]
        defined = set(defined or ())
        reads: set[str] = set()
        for e in exprs:
            reads |= self.printer.reads(e)
        lines = []
        for array in _INPUTS:
            if array not in arguments:
                continue
            used = sorted((int(r[len(array):]) for r in reads
                           if r.startswith(array) and r[len(array):].isdigit()
                           and r not in defined), key=int)
            for k in used:
                lines.append(f"{array}{k} = {array}[..., {k}]")
                defined.add(f"{array}{k}")
        # the sines and cosines of all the angles together, in one loop and one array each
        # (gagen.jax.trig: XLA's own are calls per element, copied into every reader)
        angles = [k for k in self.printer.trig_used(exprs) if f"sn{k}" not in defined]
        if angles:
            lines.append(f"{', '.join(f'sn{k}, cs{k}' for k in angles)}, = "
                         f"_sincos(({', '.join(f'q{k}' for k in angles)},))")
            defined |= {f"{kind}{k}" for k in angles for kind in ("sn", "cs")}
        # how many expressions of this body read each name: a value whose duplication into
        # its readers would cost more than DUPLICATED operations is divided by `unit` (1.0,
        # a value XLA cannot fold), which makes it a producer XLA's CPU fusion does not
        # duplicate into each consumer (it duplicates cheap elementwise producers: with no
        # such value, the Panda's inverse-dynamics derivatives became twenty times their
        # operations, 58 s to compile). Each kept value costs a divide and an array of its
        # own over the batch, written and read back (one loop of XLA's each): a value
        # cheaper than that is left to be duplicated. x / 1.0 is x exactly. `unit` is one
        # number behind an optimization barrier, not 1 + 0 q0 per state: each loop that
        # divided by it read q0, a strided column of the batch's q (every cache line of
        # q): printed forward dynamics 7% faster on the Panda arm and ANYmal C.
        readers: dict[str, int] = {}
        for e in exprs + list(later):
            for r in self.printer.reads(e):
                readers[r] = readers.get(r, 0) + 1
        if "unit" not in defined:
            first = next(a for a in _INPUTS if a in arguments)
            lines.append(f"unit = _linalg.kept({first}.dtype)")
            defined.add("unit")
        for a in assignments:
            name = self.names[a.symbol]
            if a.symbol not in self.texts:
                self.texts[a.symbol] = self.text(a.expr)
            text = _checked(self.texts[a.symbol], defined)
            reads = self.printer.reads(a.expr)
            if all(r in self.fixed for r in reads):
                # a function of the parameters alone: a number where p is (the defaults), a
                # value per batch where p is not batched; never an array of its own
                self.fixed.add(name)
                lines.append(f"{name} = {text}")
                defined.add(name)
                continue
            # the angles' sines and cosines are arrays already (one read, no operation)
            cost = int(sp.count_ops(a.expr)) - self.trig_count(a.expr) + sum(
                self.inlined.get(r, 0) for r in reads)
            if (readers.get(name, 0) - 1) * cost > DUPLICATED:
                text = f"({text}) / unit"
                cost = 0
            self.inlined[name] = cost
            lines.append(f"{name} = {text}")
            defined.add(name)
        self.output_texts = {k: [_checked(self.text(e), defined) for e in v]
                             for k, v in outputs.items()}
        self.defined = defined
        return lines


def _header(kind: str, ident: str) -> list[str]:
    return [f'"""{kind} of model {ident}, printed by gagen {__version__} from its optimised',
            'programs (gagen.jax.printer); do not edit."""',
            "",
            "import math",
            "",
            "import jax.numpy as jnp",
            "",
            "from gagen.jax.linalg import stack as _stack",
            "from gagen.jax.trig import sincos_stacked as _sincos",
            "from gagen.jax import linalg as _linalg",
            "",
            *(f"{name} = {value}" for name, value in FUNCTIONS.items()),
            *(f"{name} = {value}" for name, value in CONSTANTS.items()),
            ""]


def _lower_shape(n: int) -> tuple[int, ...]:
    return (n * (n + 1) // 2,)


def print_main(eqs) -> str:
    """The module of a model's dynamics: mass_matrix, forcing, inverse_dynamics, gravity,
    energy, forward_dynamics, placements, frame_offsets, regressor_kinematics,
    regressor_parameters (the programs of codegen.render.generate) and the numbers they
    need (the LDLᵀ plan, the regressor's tree, the kinematic parameters)."""
    if eqs.placements is None:
        eqs = add_frame_kinematics(eqs)
    n = eqs.n
    ident = c_identifier(eqs.model.name)
    cse = CSEResult(eqs, eqs.derivation == "gibbs-appell")
    out = cse.outputs
    w = _Writer(eqs, cse)
    lines = _header("The dynamics", ident)
    lower = [(r, s) for r in range(n) for s in range(r + 1)]
    zero = {(r, s) for (r, s), e in zip(lower, out["mass_matrix"]) if e == 0}
    plan = ldlt_plan(n, zero)
    lines += [f"NQ = {int(eqs.nq)}", f"NV = {int(n)}", f"NP = {len(eqs.parameters)}",
              f"LOWER = {tuple(lower)!r}",
              f"PLAN = {(plan.n, tuple((pv.j, pv.terms, pv.updates) for pv in plan.pivots), plan.forward, plan.backward)!r}",
              ""]
    w.lines = lines
    w.function("mass_matrix_lower", ("q", "p"), {"M": out["mass_matrix"]},
               {"M": _lower_shape(n)})
    w.function("forcing", ("q", "qd", "tau", "p"), {"F": out["forcing"]}, {"F": (n,)})
    w.function("inverse_dynamics", ("q", "qd", "qdd", "p"), {"tau": out["inverse_dynamics"]},
               {"tau": (n,)})
    w.function("gravity", ("q", "p"), {"G": out["gravity"]}, {"G": (n,)})
    w.function("energy", ("q", "qd", "p"), {"TV": out["energy"]}, {"TV": (2,)})
    tree = tree_factored(cse, eqs.model)
    if tree is None and "forward_dynamics" in out:
        # the articulated-body algorithm's program (recursive derivation)
        w.function("forward_dynamics", ("q", "qd", "tau", "p"),
                   {"qdd": out["forward_dynamics"]}, {"qdd": (n,)})
    else:
        # M and F, then the C's solve: M = Lᵀ D L along the tree where that costs fewer
        # operations than the articulated-body program, else the LDLᵀ plan of the C
        # (gagen.jax.linalg)
        if tree is not None:
            w.lines += [f"PARENTS = {tuple(tree)!r}", ""]
        solve = (f"_linalg.solve_tree(M, F, PARENTS, {_tree_unit(tree)})" if tree is not None
                 else "_linalg.solve_lower(M, F, PLAN)")
        w.function("_mass_forcing", ("q", "qd", "tau", "p"),
                   {"M": out["mass_matrix"], "F": out["forcing"]},
                   {"M": _lower_shape(n), "F": (n,)})
        w.lines += ["def forward_dynamics(q, qd, tau, p):",
                    "    M, F = _mass_forcing(q, qd, tau, p)",
                    f"    return {solve}", ""]
    w.function("placements", ("q", "p"), {"X": out["placements"]},
               {"X": (len(out["placements"]),)})
    w.function("frame_offsets", ("p",), {"F": out["frame_offsets"]},
               {"F": (len(out["frame_offsets"]),)})
    w.lines += _regressor(eqs, cse.eliminated)
    return "\n".join(w.lines) + "\n"


def _tree_unit(parents) -> str:
    """The text of the 1.0 the tree solve divides the values it keeps by (linalg.solve_tree):
    one number behind an optimization barrier where the tree branches, 1 + 0 q₀ per state
    along a chain. Measured, forward dynamics at 4,096 states, medians of 21 interleaved
    runs: the barrier took ANYmal C from 0.975 to 0.852 µs per state and the Panda (its
    fingers branch) from 0.340 to 0.314, but the Panda arm (a chain) from 0.315 to 0.398.
    Why, in a profile of the Panda arm's loops: with the barrier, XLA fused the whole back
    substitution into the loop that writes q̈ (the concatenation of its 7 entries, which
    evaluates each entry's chain apart, per element: 512 of the 1,858 µs of loops per
    call); with 1 + 0 q₀ that loop reads 14 arrays and does 16 operations."""
    chain = all(parent == k - 1 for k, parent in enumerate(parents))
    return "1.0 + 0.0 * q[..., 0]" if chain else "_linalg.kept(q.dtype)"


def _regressor(eqs, eliminate: bool) -> list[str]:
    """regressor_kinematics and regressor_parameters, from a CSE of their own as in
    codegen.render._regressor_blocks, the regressor's tree as numbers, and KINEMATIC: the
    parameters its kinematics read (lengths, gravity)."""
    reg = regressor_kinematics(eqs)
    parameters = regressor_parameter_exprs(eqs.model)
    outputs = {"regressor_kinematics": reg.values, "regressor_parameters": parameters}
    program = needed_definitions(reg.intermediates,
                                 [e for values in outputs.values() for e in values])
    cse = CSEResult(eqs, eliminate, program, outputs)
    w = _Writer(eqs, cse)
    kinematic_assignments = cse.needed(cse.outputs["regressor_kinematics"])
    read = set().union(*(a.expr.free_symbols for a in kinematic_assignments),
                       *(e.free_symbols for e in cse.outputs["regressor_kinematics"]))
    kinematic = tuple(k for k, s in enumerate(eqs.parameters) if s in read)
    w.lines = [f"KINEMATIC = {kinematic!r}",
               f"PER_BODY = {int(KINEMATICS_PER_BODY)}",
               f"REGRESSOR_TREE = {(tuple(reg.parents), tuple(reg.kinds), tuple(reg.rows), tuple(reg.joint_rows))!r}",
               f"NREG = {len(parameters)}", ""]
    w.function("regressor_kinematics", ("q", "qd", "qdd", "p"),
               {"K": cse.outputs["regressor_kinematics"]},
               {"K": (len(reg.values),)})
    w.function("regressor_parameters", ("p",), {"pi": cse.outputs["regressor_parameters"]},
               {"pi": (len(parameters),)})
    return w.lines


def print_derivatives(deq) -> str:
    """The module of a model's derivatives (codegen.derivatives.generate_derivatives's
    program): inverse_dynamics_derivatives, forward_dynamics_derivatives (M and F, the LDLᵀ
    factors, q̈, then ∂τ/∂q at q̈ and the solves, as the C does) and coriolis_matrix."""
    eqs = deq.equations
    n = deq.n
    ident = c_identifier(eqs.model.name)
    definitions, outputs = derivative_program(deq)
    cse = CSEResult(eqs, eqs.derivation == "gibbs-appell", definitions, outputs)
    out = cse.outputs
    w = _Writer(eqs, cse)
    lower = [(r, s) for r in range(n) for s in range(r + 1)]
    zero = {(r, s) for (r, s), e in zip(lower, out["mass_matrix"]) if e == 0}
    plan = ldlt_plan(n, zero)
    w.lines = _header("The derivatives", ident) + [
        f"NV = {int(n)}",
        f"PLAN = {(plan.n, tuple((pv.j, pv.terms, pv.updates) for pv in plan.pivots), plan.forward, plan.backward)!r}",
        ""]
    square = (n, n)
    w.function("inverse_dynamics_derivatives", ("q", "qd", "qdd", "p"),
               {"dq": out["dtau_dq"], "dqd": out["dtau_dqd"]}, {"dq": square, "dqd": square})
    w.function("coriolis_matrix", ("q", "qd", "p"), {"C": out["coriolis"]}, {"C": square})
    # forward dynamics derivatives: what is free of qdd first (M, F, dtau/dqd and the rest),
    # then qdd = M^-1 F, then dtau/dq at qdd
    needed = cse.needed(out["mass_matrix"] + out["forcing"] + out["dtau_dq"] + out["dtau_dqd"])
    qdd = set(eqs.coords.qdd)
    moving: set[sp.Symbol] = set()
    for a in needed:
        if a.expr.free_symbols & (qdd | moving):
            moving.add(a.symbol)
    fixed = [a for a in needed if a.symbol not in moving]
    later = [a for a in needed if a.symbol in moving]
    w.lines.append("def forward_dynamics_derivatives(q, qd, tau, p):")
    first = w.body(fixed, {"M": out["mass_matrix"], "F": out["forcing"],
                           "dqd": out["dtau_dqd"]}, ("q", "qd", "tau", "p"),
                   later=[a.expr for a in later] + list(out["dtau_dq"]))
    texts = w.output_texts
    w.lines += ["    " + line for line in first]
    w.lines += [f"    M = _stack(({', '.join(texts['M'])},), {_lower_shape(n)})",
                f"    F = _stack(({', '.join(texts['F'])},), {(n,)})",
                f"    dqd = _stack(({', '.join(texts['dqd'])},), {square})",
                "    factors = _linalg.factor(M, PLAN)",
                "    qdd = _linalg.solve_factored(factors, F, PLAN)"]
    w.lines += [f"    qdd{k} = qdd[..., {k}]" for k in range(n)]
    second = w.body(later, {"dq": out["dtau_dq"]}, ("q", "qd", "tau", "p"),
                    defined=w.defined | {f"qdd{k}" for k in range(n)})
    w.lines += ["    " + line for line in second]
    w.lines += [f"    dq = _stack(({', '.join(w.output_texts['dq'])},), {square})",
                "    return _linalg.forward_derivatives(factors, dq, dqd, PLAN)", ""]
    return "\n".join(w.lines) + "\n"
