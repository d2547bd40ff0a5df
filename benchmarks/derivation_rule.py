"""Which derivation to compile, by measurement: the paper's Gibbs-Appell closed form (one
CSE over M and the forcing; forward dynamics by an unrolled LDL^T) against the recursive
form (RNEA, CRBA, and the articulated-body algorithm for forward dynamics).

For each model both are built (cold, in a scratch cache) and timed per call from Python and
per state in the batched C loop (N = 1000 stacked states), interleaved in one run; the
table gives the build times and the ratio Gibbs-Appell / recursive (above 1: the recursive
form is faster). `symbolic/derivation.py::RECURSIVE_FROM_DOF` is set from this table.

    python benchmarks/derivation_rule.py [--models chain:4 chain:6 ...] [--repeats 11]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

import gagen
from gagen.bench.timing import Candidate, interleaved

REPO = Path(__file__).resolve().parents[1]
URDF = REPO / "tests" / "data" / "urdf"
DEFAULT_MODELS = ["chain:4", "chain:6", "chain:7", "chain:8", "chain:9", "chain:10",
                  str(URDF / "ur5_robot.urdf"), str(URDF / "panda.urdf")]
FORMS = ("gibbs-appell", "recursive")
BATCH = 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=DEFAULT_MODELS)
    parser.add_argument("--repeats", type=int, default=11)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as cache:
        for name in args.models:
            built = {}
            for form in FORMS:
                start = time.perf_counter()
                built[form] = gagen.load(name, cache_dir=Path(cache) / form, derivation=form)
                built[form + "_s"] = time.perf_counter() - start
            rows.append((name, built))
            print(f"built {name}: " + ", ".join(f"{f} {built[f + '_s']:.1f} s" for f in FORMS),
                  flush=True)
        print("| model | n | build GA s | build rec s | FD | ID | M | FD batched | ID batched |")
        print("|---|--:|--:|--:|--:|--:|--:|--:|--:|")
        for name, built in rows:
            n = built[FORMS[0]].n
            rng = np.random.default_rng(0)
            q, qd, tau = rng.normal(size=(3, n))
            Q, QD, TAU = rng.normal(size=(3, BATCH, n))
            cands = []
            for form in FORMS:
                d = built[form]
                cands += [Candidate(f"{form} fd", d.forward_dynamics, (q, qd, tau)),
                          Candidate(f"{form} id", d.inverse_dynamics, (q, qd, tau)),
                          Candidate(f"{form} M", d.mass_matrix, (q,)),
                          Candidate(f"{form} FD", d.forward_dynamics, (Q, QD, TAU)),
                          Candidate(f"{form} ID", d.inverse_dynamics, (Q, QD, TAU))]
            times = {c.name: t.median for c, t in zip(cands, interleaved(cands, args.repeats))}
            ratios = [times[f"gibbs-appell {k}"] / times[f"recursive {k}"]
                      for k in ("fd", "id", "M", "FD", "ID")]
            label = Path(name).stem if name.endswith(".urdf") else name
            print(f"| {label} | {n} | {built['gibbs-appell_s']:.1f} | {built['recursive_s']:.1f} | "
                  + " | ".join(f"{r:.2f}" for r in ratios) + " |", flush=True)


if __name__ == "__main__":
    main()
