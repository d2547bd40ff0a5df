"""Forward dynamics: the articulated-body program against M and forcing plus an LDL^T solve.

For each model: the derivation time and size (`sympy.count_ops` over the intermediates
and the outputs, each counted once) of `aba.forward_dynamics_aba`, next to those of what
forward dynamics uses today, `recursive.derive_recursive`'s mass matrix (lower triangle)
and forcing with only the intermediates they need, and the flops of solving M qdd = F:
by a dense LDL^T of size n (n^3/3 + 2 n^2, factorisation and the two triangular solves),
and by the generated code's unrolled plan (`gagen.codegen.ldlt`), which skips M's
structural zeros (a tree's branches), counted as its C template writes it.

    python benchmarks/aba_ops.py
    python benchmarks/aba_ops.py --models chain:6 tests/data/urdf/panda.urdf
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import sympy as sp

from gagen.codegen.ldlt import ldlt_plan
from gagen.errors import ModelError
from gagen.model.resolve import resolve_model
from gagen.symbolic.aba import _needed, forward_dynamics_aba
from gagen.symbolic.recursive import derive_recursive

REPO = Path(__file__).resolve().parents[1]
URDF = REPO / "tests" / "data" / "urdf"
DEFAULT_MODELS = ["chain:6", "chain:12", "chain:24", "chain:50", str(URDF / "panda.urdf"),
                  str(URDF / "talos_full_v2.urdf")]


def program_ops(definitions, outputs) -> tuple[int, int]:
    """Operations and number of the definitions the outputs need, plus the outputs'."""
    needed = _needed(definitions, outputs)
    ops = sum(sp.count_ops(e) for _, e in needed) + sum(sp.count_ops(e) for e in outputs)
    return ops, len(needed)


def ldlt_flops(n: int) -> int:
    return round(n ** 3 / 3 + 2 * n ** 2)


def plan_flops(M) -> int:
    """Flops of codegen's unrolled LDL^T factorisation and solve for this M's zeros:
    (a*b)*Dinv per term, one division per pivot, one multiply per solve step."""
    n = M.shape[0]
    plan = ldlt_plan(n, {(r, c) for r in range(n) for c in range(r) if M[r, c] == 0})
    flops = 0
    for pivot in plan.pivots:
        flops += 3 * len(pivot.terms) + 1 + sum(3 * len(ks) for _, ks in pivot.updates)
    flops += sum(2 * len(ks) + 1 for _, ks in plan.forward)
    flops += sum(2 * len(ks) + 1 for _, ks in plan.backward if ks)
    return flops


def measure(model) -> dict[str, float]:
    sp.core.cache.clear_cache()
    start = time.perf_counter()
    program = forward_dynamics_aba(model)
    aba_s = time.perf_counter() - start
    aba_ops, aba_count = program_ops(program.intermediates, program.qdd)
    sp.core.cache.clear_cache()
    start = time.perf_counter()
    eqs = derive_recursive(model)
    rec_s = time.perf_counter() - start
    outs = eqs.outputs()
    mf_ops, mf_count = program_ops(eqs.intermediates, outs["mass_matrix"] + outs["forcing"])
    n = model.dof
    return {"n": n, "aba_s": aba_s, "aba_ops": aba_ops, "aba_count": aba_count,
            "rec_s": rec_s, "mf_ops": mf_ops, "mf_count": mf_count, "ldlt": ldlt_flops(n), "plan": plan_flops(eqs.mass_matrix)}


def label(name: str) -> str:
    return Path(name).name if name.endswith(".urdf") else name


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=DEFAULT_MODELS)
    args = parser.parse_args(argv)
    print("| model | dof | ABA derive (s) | ABA ops | ABA intermediates | recursive derive (s) "
          "| M + forcing ops | dense LDL^T flops | codegen LDL^T flops | M + F + codegen LDL^T "
          "| ABA / (M + F + codegen LDL^T) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.models:
        try:
            model = resolve_model(name)
        except (ModelError, OSError) as exc:  # a URDF that does not load is reported
            print(f"| {label(name)} | does not load: {exc} |")
            continue
        r = measure(model)
        total = r["mf_ops"] + r["plan"]
        print(f"| {label(name)} | {r['n']} | {r['aba_s']:.1f} | {r['aba_ops']} | {r['aba_count']} "
              f"| {r['rec_s']:.1f} | {r['mf_ops']} | {r['ldlt']} | {r['plan']} | {total} "
              f"| {r['aba_ops'] / total:.2f} |", flush=True)


if __name__ == "__main__":
    main()
