"""Gibbs-Appell (`derive`) against the recursive derivation (`derive_recursive`) as robots grow.

For each model: the derivation time of each (the old one in a subprocess, given up after
`--old-timeout` seconds), and its size as `sympy.count_ops` summed over the intermediates
and the outputs. For the models in `--build`, a cold build of the recursive equations
through `gagen.building.builder.build` (its `derive` swapped for `derive_recursive`, into a
fresh cache folder): generate (which includes CSE) and compile seconds, operations before
and after CSE.

    python benchmarks/recursive_scaling.py
    python benchmarks/recursive_scaling.py --models chain:6 chain:12 --build chain:12
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import tempfile
import time
from pathlib import Path

import sympy as sp

from gagen.building import builder
from gagen.errors import ModelError
from gagen.model.resolve import resolve_model
from gagen.symbolic.gibbs_appell import derive
from gagen.symbolic.recursive import derive_recursive

REPO = Path(__file__).resolve().parents[1]
DEFAULT_MODELS = ["chain:6", "chain:12", "chain:24", "chain:50",
                  str(REPO / "tests" / "data" / "urdf" / "talos_full_v2.urdf")]
DEFAULT_BUILDS = ["chain:12", "chain:24"]


def operation_count(eqs) -> int:
    """Operations of the intermediates and every output, each counted once."""
    outputs = [e for exprs in eqs.outputs().values() for e in exprs]
    return (sum(sp.count_ops(e) for _, e in eqs.intermediates)
            + sum(sp.count_ops(e) for e in outputs))


def timed_derivation(derivation, model) -> tuple[float, int, int]:
    """Seconds (cold SymPy cache), operations and intermediates of one derivation."""
    sp.core.cache.clear_cache()
    start = time.perf_counter()
    eqs = derivation(model)
    seconds = time.perf_counter() - start
    return seconds, operation_count(eqs), len(eqs.intermediates)


def _old_in_child(name: str, queue) -> None:
    queue.put(timed_derivation(derive, resolve_model(name)))


def old_derivation(name: str, timeout: float) -> tuple[float, int, int] | None:
    """The Gibbs-Appell derivation in a subprocess; None if it takes over `timeout` s."""
    queue = mp.get_context("fork").Queue()
    child = mp.get_context("fork").Process(target=_old_in_child, args=(name, queue))
    child.start()
    child.join(timeout)
    if child.is_alive():
        child.kill()
        child.join()
        return None
    return queue.get()


def recursive_build(model, cache_dir: Path) -> builder.BuildReport:
    """A cold build of the recursive equations."""
    sp.core.cache.clear_cache()
    _, report = builder.build(model, cache_dir=cache_dir, derivation="recursive")
    return report


def label(name: str) -> str:
    return Path(name).name if name.endswith(".urdf") else name


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=DEFAULT_MODELS)
    parser.add_argument("--build", nargs="*", default=DEFAULT_BUILDS)
    parser.add_argument("--old-timeout", type=float, default=60.0)
    args = parser.parse_args(argv)
    print("| model | dof | derive old (s) | derive new (s) | ops old | ops new "
          "| intermediates new | generate new (s) | compile new (s) | ops after CSE |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in args.models:
        try:
            model = resolve_model(name)
        except (ModelError, OSError) as exc:  # a URDF that does not load is reported
            print(f"| {label(name)} | does not load: {exc} |")
            continue
        old = old_derivation(name, args.old_timeout)
        new_s, new_ops, new_count = timed_derivation(derive_recursive, model)
        old_s = f"{old[0]:.1f}" if old else f"> {args.old_timeout:.0f}"
        old_ops = str(old[1]) if old else "-"
        gen = comp = after = "-"
        if name in args.build:
            with tempfile.TemporaryDirectory(prefix="gagen-recursive-") as folder:
                report = recursive_build(model, Path(folder))
            gen = f"{report.stages['generate']:.1f}"
            comp = f"{report.stages['compile']:.1f}"
            after = str(report.ops_after_cse)
        print(f"| {label(name)} | {model.dof} | {old_s} | {new_s:.1f} | {old_ops} | {new_ops} "
              f"| {new_count} | {gen} | {comp} | {after} |", flush=True)


if __name__ == "__main__":
    main()
