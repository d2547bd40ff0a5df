"""The symbolic derivatives (gagen.symbolic.derivatives): derivation time and program size.

For each model: the time to derive the equations, then the time of `derive_derivatives`
(SymPy's cache cleared before each model), the definitions it adds, and the size of each
kernel as `sympy.count_ops` over the definitions it needs and its outputs (before any
CSE), next to the inverse dynamics' own program for scale. The inverse-dynamics
derivatives are sized by both methods (forward mode, and the analytical world-frame
algorithm where it applies): the table behind `derivatives.ANALYTIC_FROM_DOF`.

    python benchmarks/derivative_ops.py
    python benchmarks/derivative_ops.py --models rrr chain:6
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import sympy as sp

from gagen.model.resolve import resolve_model
from gagen.symbolic.derivation import derivation_for, derive_equations
from gagen.symbolic.derivatives import derivative_method, derive_derivatives
from gagen.symbolic.differentiate import needed_definitions
from gagen.symbolic.rnea_derivatives import applies

REPO = Path(__file__).resolve().parents[1]
URDF = REPO / "tests" / "data" / "urdf"
DEFAULT_MODELS = ["rrr", str(URDF / "ur5_robot.urdf"), str(URDF / "panda.urdf"), "chain:12",
                  "chain:3", "chain:4", "chain:5", "chain:6"]


def program_ops(definitions, outputs) -> int:
    """count_ops over the definitions the outputs need, each once, and the outputs."""
    needed = needed_definitions(definitions, outputs)
    return sum(sp.count_ops(e) for _, e in needed) + sum(sp.count_ops(e) for e in outputs)


def measure(name: str) -> dict:
    sp.core.cache.clear_cache()
    model = resolve_model(name)
    start = time.perf_counter()
    eqs = derive_equations(model)
    derive = time.perf_counter() - start
    start = time.perf_counter()
    d = derive_derivatives(eqs)
    derivatives = time.perf_counter() - start
    return {
        "model": Path(name).stem if name.endswith(".urdf") else name,
        "dof": eqs.n,
        "derivation": derivation_for(model),
        "derive_s": derive,
        "derivatives_s": derivatives,
        "new_definitions": len(d.intermediates) - len(eqs.intermediates),
        "id_ops": program_ops(eqs.intermediates, list(eqs.inverse_dynamics)),
        "method": derivative_method(model),
        "id_derivatives_ops": d.operation_count("inverse_dynamics_derivatives"),
        "forward_ops": _kernel_ops(eqs, "forward"),
        "analytic_ops": _kernel_ops(eqs, "analytic") if applies(model) else None,
        "coriolis_ops": d.operation_count("coriolis_matrix"),
    }


def _kernel_ops(eqs, method: str) -> int:
    return derive_derivatives(eqs, method).operation_count("inverse_dynamics_derivatives")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=DEFAULT_MODELS)
    args = parser.parse_args(argv)
    print("| model | dof | derivation | derive equations (s) | derive derivatives (s) "
          "| new definitions | ID ops | ID-derivatives kernel ops (method) "
          "| forward mode / analytical | Coriolis kernel ops |")
    print("|---|--:|---|--:|--:|--:|--:|--:|--:|--:|")
    for name in args.models:
        r = measure(name)
        print(f"| {r['model']} | {r['dof']} | {r['derivation']} | {r['derive_s']:.2f} "
              f"| {r['derivatives_s']:.2f} | {r['new_definitions']} | {r['id_ops']} "
              f"| {r['id_derivatives_ops']} ({r['method']}) "
              f"| {r['forward_ops']} / {r['analytic_ops'] or '-'} | {r['coriolis_ops']} |",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
