"""The derivative module's C: the derivatives of the dynamics (symbolic/derivatives.py)
printed as four C functions, in a module of their own.

The derivative program is large (the Panda's inverse-dynamics derivatives are ten times
its inverse dynamics), so it is not part of a model's main module: a model's default build
stays as fast as it was, and `gagen.load` builds this module on first use of a derivative
(gagen.building.builder). Its files do not clash with the main module's: the header is
`<ident>_derivatives.h`, the C files `derivatives.c` and `derivative_<stage>.c`, the
segment functions of split kernels `derivative_kernels_<k>.c`, and every function is
`<ident>_...`, so a C program can compile both modules' sources together.

One CSE pass runs over every output (M, the forcing F, dtau/dq, dtau/dqd and C; for the
Gibbs-Appell form only, as in the main module). The inverse-dynamics derivatives are
then split like the simulation's forward dynamics (codegen/stages.py), at qdd:

- `fixed` (q, qd, p) -> S: dtau/dqd (free of qdd) and every value free of qdd that the two
  other stages read (the kinematics, velocities and their derivatives, and the parts of
  dtau/dq free of qdd, hoisted);
- `acceleration` (S, q, qd, qdd, p) -> dtau/dq: the rest;
- `mass_forcing` (S, q, qd, tau, p) -> M and F: what M and F need that `fixed` did not
  compute.

So the forward-dynamics derivatives cost one pass over the derivative program plus M and F,
not two passes: fixed, mass_forcing, the LDL^T factors of M and qdd = M^-1 F (the main
module's unrolled plan, codegen/ldlt.py), then acceleration at that qdd, and the triangular
solves with the same factors for -M^-1 dtau/dq, -M^-1 dtau/dqd and M^-1.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from importlib import resources

import sympy as sp

from .. import __version__
from ..symbolic.derivatives import DerivativeEquations
from ..symbolic.differentiate import needed_definitions
from .config import CodegenConfig
from .cse import CSEResult
from .ldlt import least_fill_plan
from .render import (
    CodeBlock,
    GagenCPrinter,
    GeneratedCode,
    _Kernels,
    _symbol_names,
    c_identifier,
    kernel_files,
    model_context,
    template_environment,
)
from .stages import split_stages

# The derivative module's kernels and their C arrays, in the order their segment functions
# take them (then `w`); the last one is the kernel's output (render.KERNEL_ARRAYS).
DERIVATIVE_KERNEL_ARRAYS = {
    "derivatives_fixed": ("q", "qd", "p", "S"),
    "derivatives_acceleration": ("S", "q", "qd", "qdd", "p", "J"),
    "derivatives_mass_forcing": ("S", "q", "qd", "tau", "p", "MF"),
    "coriolis_matrix": ("q", "qd", "p", "C"),
    "derivatives_geometry": ("q", "p", "G"),
    "derivatives_joints": ("qd", "p", "T"),
}
# Every one of them runs in loops (stacked inputs, MPC): built with the FMA clone too.
DERIVATIVE_LOOPED_KERNELS = tuple(DERIVATIVE_KERNEL_ARRAYS)
# gagen's files that the derivative module's C needs next to it
DERIVATIVE_COPIED_FILES = ("gagen_math.h", "gagen_api.h", "integrator.h")
# The derivative module's C files and the part of derivatives.c.j2 each holds: the API
# functions, and the three stages and the Coriolis matrix in files of their own, which the
# build compiles in parallel (the Panda's one file took 12.6 s to compile on 2 cores)
DERIVATIVE_C_FILES = (("derivatives.c", "api"), ("derivative_fixed.c", "fixed"),
                      ("derivative_acceleration.c", "acceleration"),
                      ("derivative_coriolis.c", "coriolis"))
# The loop form solves with M for the forward-dynamics derivatives' 3n right-hand sides at
# most this many columns at a time, kept in registers (12 AVX registers, of 16), in as few
# chunks as that allows, each a multiple of 8 columns
SOLVE_CHUNK = 48
# ... in loop form: the API functions and the loops, and the generated geometry
DERIVATIVE_LOOP_FILES = (("derivatives.c", "api"), ("derivative_geometry.c", "geometry"))
# the derivative module's one file that speaks to Python: its kernels' table
DERIVATIVE_MODULE_FILE = "derivatives_module.c"


@dataclass
class DerivativeBlocks:
    """The code of the derivative module's kernels and the layout of S, the values the
    `fixed` stage passes on: dtau/dqd at S[0 .. n^2), then the interface of the others."""

    fixed: CodeBlock
    acceleration: CodeBlock
    mass_forcing: CodeBlock
    coriolis: CodeBlock
    size: int  # doubles of S


def derivative_program(deq: DerivativeEquations
                       ) -> tuple[list[tuple[sp.Symbol, sp.Expr]], dict[str, list[sp.Expr]]]:
    """The outputs of the derivative module (name -> list) and the definitions they need."""
    eqs, n = deq.equations, deq.n
    M = eqs.mass_matrix if deq.mass_matrix is None else deq.mass_matrix
    outputs = {
        "mass_matrix": [M[r, s] for r in range(n) for s in range(r + 1)],
        "forcing": list(eqs.forcing if deq.forcing is None else deq.forcing),
        "dtau_dq": list(deq.dtau_dq),
        "dtau_dqd": list(deq.dtau_dqd),
        "coriolis": list(deq.coriolis),
    }
    flat = [e for values in outputs.values() for e in values]
    return needed_definitions(deq.intermediates, flat), outputs


def loop_program(deq: DerivativeEquations
                 ) -> tuple[list[tuple[sp.Symbol, sp.Expr]], dict[str, list[sp.Expr]]]:
    """The loop form's outputs (the geometry G and the joint terms T, module docstring of
    model/derivatives_loop.c.j2) and the definitions they need."""
    tree = deq.geometry
    outputs = {
        "geometry": [e for row in tree.inertia + tree.motion + tree.base for e in row],
        "joints": [*tree.armature, *tree.damping, *tree.dissipative],
    }
    flat = [e for values in outputs.values() for e in values]
    return needed_definitions(deq.intermediates, flat), outputs


@dataclass
class LoopBlocks:
    """The code of the loop form's two generated kernels."""

    geometry: CodeBlock
    joints: CodeBlock


def solve_chunk(n: int) -> int:
    """The columns the loop form's solve takes at a time for 3n right-hand sides."""
    chunks = -(-3 * n // SOLVE_CHUNK)
    return -(-3 * n // (8 * chunks)) * 8


def _loop_context(tree, cse: CSEResult, kernels: _Kernels) -> dict:
    """The loop form's blocks and tree tables for model/derivatives_loop.c.j2."""
    out = cse.outputs
    geometry = kernels.block("derivatives_geometry", out["geometry"],
                             [f"G[{k}]" for k in range(len(out["geometry"]))])
    kept = [(k, e) for k, e in enumerate(out["joints"]) if e != 0]
    joints = kernels.block("derivatives_joints", [e for _, e in kept],
                           [f"T[{k}]" for k, _ in kept])
    for cols in tree.columns:  # the C reads a link's coordinates as a range
        if cols != list(range(cols[0], cols[0] + len(cols))):
            raise AssertionError("a joint's velocity coordinates are not contiguous")
    slot = {b: r for r, b in enumerate(tree.roots)}
    up = tree.column_parent
    runs = []
    for c in range(len(up)):
        lo = c
        while lo > 0 and up[lo] == lo - 1:
            lo -= 1
        runs.append(lo)
    return {"tree": tree, "blocks": LoopBlocks(geometry, joints),
            "first": [cols[0] for cols in tree.columns],
            "count": [len(cols) for cols in tree.columns],
            "root_slot": [slot.get(b, -1) for b in range(len(tree.parents))],
            "free": [int(f) for f in tree.free_roots], "chunk": solve_chunk(len(up)),
            "runs": runs,
            "depth_first": tree.column_order == list(range(len(up)))}


def _blocks(deq: DerivativeEquations, kernels: _Kernels) -> DerivativeBlocks:
    cse, printer, coords = kernels.cse, kernels.printer, deq.equations.coords
    n = deq.n
    out = cse.outputs
    split = split_stages(cse.needed(out["dtau_dq"] + out["dtau_dqd"]), out["dtau_dqd"],
                         out["dtau_dq"], set(coords.qdd))
    hoisted = [a for a in split.position if not printer.names(a.symbol)]
    printer.bind_names({a.symbol: f"h{k}" for k, a in enumerate(hoisted)})
    fixed_symbols = {a.symbol for a in split.position}
    mass_forcing_outputs = out["mass_matrix"] + out["forcing"]
    mass_forcing = [a for a in cse.needed(mass_forcing_outputs) if a.symbol not in fixed_symbols]
    read = set().union(*(a.expr.free_symbols for a in mass_forcing),
                       *(e.free_symbols for e in mass_forcing_outputs))
    # S: dtau/dqd, then what the acceleration stage reads, then what M and F read besides
    interface = list(split.interface)
    interface += [a.symbol for a in split.position if a.symbol in read
                  and a.symbol not in set(split.interface)]
    at = {symbol: f"S[{n * n + k}]" for k, symbol in enumerate(interface)}
    fixed = kernels.block("derivatives_fixed", out["dtau_dqd"] + interface,
                          [f"S[{k}]" for k in range(n * n)] + list(at.values()),
                          assignments=split.position)
    acceleration = kernels.block("derivatives_acceleration", split.velocity_outputs,
                                 [f"J[{k}]" for k in range(n * n)],
                                 assignments=split.velocity,
                                 externals={s: at[s] for s in split.interface}, cache=False)
    lower = [(r, s) for r in range(n) for s in range(r + 1)]
    targets = [f"MF[{r * n + s}]" for r, s in lower] + [f"MF[{n * n + r}]" for r in range(n)]
    mass_forcing_block = kernels.block(
        "derivatives_mass_forcing", mass_forcing_outputs, targets, assignments=mass_forcing,
        externals={s: at[s] for s in interface if s in read})
    coriolis = kernels.block("coriolis_matrix", out["coriolis"],
                             [f"C[{k}]" for k in range(n * n)])
    return DerivativeBlocks(fixed, acceleration, mass_forcing_block, coriolis,
                            size=n * n + len(interface))


def generate_derivatives(deq: DerivativeEquations, module_name: str, key: str,
                         equations_key: str, config: CodegenConfig | None = None
                         ) -> GeneratedCode:
    """The C sources and header of a model's derivative module and the module's table of
    them (file name -> text). `equations_key` is the source key of the model's main module:
    the module carries it, so the runtime pairs the two modules of the same equations only.
    The module is in the form `deq` was derived in: unrolled (the derivative program
    printed whole) or loop (`deq.geometry`: the tree's geometry, and loops over the tree)."""
    config = config or CodegenConfig()
    eqs = deq.equations
    ident = c_identifier(eqs.model.name)
    if deq.geometry is not None:
        definitions, outputs = loop_program(deq)
    else:
        definitions, outputs = derivative_program(deq)
    cse = CSEResult(eqs, eqs.derivation == "gibbs-appell" if config.cse is None
                    else config.cse, definitions, outputs)
    printer = GagenCPrinter(_symbol_names(eqs, cse), list(eqs.coords.q), config.fast_trig)
    kernels = _Kernels(ident, cse, printer,
                       dataclasses.replace(config, split_chars=config.derivative_split_chars),
                       arrays=DERIVATIVE_KERNEL_ARRAYS,
                       looped=DERIVATIVE_LOOPED_KERNELS)
    n = eqs.n
    header = f"generated by gagen {__version__} for model '{ident}'; do not edit"
    context = {
        **model_context(eqs),
        "module_name": module_name,
        "key": key,
        "equations_key": equations_key,
        "header": header,
    }
    env = template_environment()
    if deq.geometry is not None:
        context.update(_loop_context(deq.geometry, cse, kernels))
        parts, source = DERIVATIVE_LOOP_FILES, env.get_template("model/derivatives_loop.c.j2")
    else:
        lower = [(r, s) for r in range(n) for s in range(r + 1)]
        zero = {(r, s) for (r, s), e in zip(lower, cse.outputs["mass_matrix"]) if e == 0}
        context.update(blocks=_blocks(deq, kernels), solve=least_fill_plan(n, zero))
        parts, source = DERIVATIVE_C_FILES, env.get_template("model/derivatives.c.j2")
    files = {
        f"{ident}_derivatives.h": env.get_template("model/derivatives.h.j2").render(context),
        DERIVATIVE_MODULE_FILE: env.get_template("model/derivatives_module.c.j2").render(context),
    }
    for name, part in parts:
        files[name] = source.render(context, part=part)
    # kernels.c.j2 includes "<ident>.h": here the segment files include this module's header
    segment_context = {"header": header, "ident": f"{ident}_derivatives"}
    kernels_template = env.get_template("model/kernels.c.j2")
    for k, segments in enumerate(kernel_files(kernels.segments, config.file_chars)):
        files[f"derivative_kernels_{k}.c"] = kernels_template.render(segment_context,
                                                                     segments=segments)
    for name in DERIVATIVE_COPIED_FILES:
        text = resources.files("gagen.codegen").joinpath("templates", "c", name).read_text()
        files[name] = f"/* {header} (copied from gagen's templates) */\n" + text
    return GeneratedCode(files=files, ops_before=cse.ops_before, ops_after=cse.ops_after,
                         cse_seconds=cse.seconds, module_name=module_name, ident=ident)
