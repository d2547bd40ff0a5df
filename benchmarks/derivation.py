"""Derivation cost per model: time, intermediates, and operation counts before and after CSE.

    python benchmarks/derivation.py [--models rrr chain:3 ...] [--repeats 3]

Prints a markdown table; times are of cold derivations (SymPy's cache cleared). `derivation_rows` gives the same numbers as dicts, for reuse by
other benchmark scripts.
"""

from __future__ import annotations

import argparse
import statistics
import time

import sympy as sp
from sympy.core.cache import clear_cache

import gagen
from gagen.codegen import CSEResult

DEFAULT_MODELS = ["rrr"] + [f"chain:{n}" for n in range(3, 11)]
COLUMNS = [
    ("model", "model", "{}"),
    ("dof", "dof", "{}"),
    ("derive_seconds", "derive (s, median)", "{:.3f}"),
    ("intermediates", "intermediates", "{}"),
    ("ops_structured", "ops (structured)", "{}"),
    ("ops_after_cse", "ops after CSE", "{}"),
    ("cse_seconds", "CSE (s)", "{:.2f}"),
]


def structured_ops(eqs: gagen.Equations) -> int:
    """count_ops over every intermediate definition and every output, intermediates kept."""
    exprs = [e for _, e in eqs.intermediates]
    exprs += [e for values in eqs.outputs().values() for e in values]
    return sum(sp.count_ops(e) for e in exprs)


def derivation_rows(names, repeats: int = 3) -> list[dict]:
    """One dict per model: derivation time (median of `repeats`), sizes and op counts.

    SymPy's cache is cleared before each timed derivation: a repeat would otherwise reuse
    the previous run's results and take a fraction of the time of a first derivation.
    """
    rows = []
    for name in names:
        model = gagen.resolve_model(name)
        times = []
        eqs = None
        for _ in range(max(1, repeats)):
            clear_cache()
            start = time.perf_counter()
            eqs = gagen.derive(model)
            times.append(time.perf_counter() - start)
        cse = CSEResult(eqs)
        rows.append({
            "model": name,
            "dof": model.dof,
            "derive_seconds": statistics.median(times),
            "intermediates": len(eqs.intermediates),
            "ops_structured": structured_ops(eqs),
            "ops_after_cse": cse.ops_after,
            "cse_seconds": cse.seconds,
        })
    return rows


def markdown_table(rows: list[dict]) -> str:
    lines = ["| " + " | ".join(title for _, title, _ in COLUMNS) + " |",
             "|" + "|".join("---" if key == "model" else "---:" for key, _, _ in COLUMNS) + "|"]
    for row in rows:
        lines.append("| " + " | ".join(fmt.format(row[key]) for key, _, fmt in COLUMNS) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=DEFAULT_MODELS, metavar="MODEL",
                        help="built-in names or model files (default: rrr chain:3 ... chain:10)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="derivations per model; the median time is shown (default: 3)")
    args = parser.parse_args(argv)
    print(markdown_table(derivation_rows(args.models, args.repeats)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
