"""The paper's direct dynamics, timed four ways: how much faster is the compiled integrator?

The 5-s simulation of `rrr` (from rest at q = 0 under `paper_controller()`, rtol = 1e-6,
atol = 1e-8, 501 output samples, i.e. `python -m gagen simulate`) run as

    (a) scipy RK45, lambdify backend   (SymPy's lambdify, Python in every step)
    (b) scipy RK45, compiled backend   (compiled model and gravity torque, Python per step)
    (c) compiled dopri5                (the whole simulation in C; same steps as RK45)
    (d) compiled rk4, h = 1e-3         (5000 fixed steps in C)

Each time is one complete `gagen.simulate(...)` call; the cases are interleaved
round-robin (gagen.bench.timing). Reported: median, spread (quartiles) and the ratio of
(a)'s median to each case's median. The goal: (c) at least 1000x faster than (a).

    python benchmarks/simulation.py [--repeats 7] [--runs 1] [--cache-dir DIR]

The shared machine's speed drifts in phases, and Python-heavy case (a) slows down more
than (c) in busy phases; `--runs K` repeats the whole measurement K times (minutes apart
if the phases are long) and reports every run's speed-up, their median and the lowest.

The measurement is `gagen.bench.simulation.simulation_rows`; `python -m gagen bench`
runs it too.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys

import gagen
from gagen.bench import simulation as core
from gagen.bench.simulation import ATOL, GOAL, REPEATS, RTOL, markdown_table

__all__ = ["markdown_table", "simulation_rows"]


def simulation_rows(cache_dir=None, repeats: int = REPEATS, progress=None) -> list[dict]:
    """The four cases on rrr loaded through `gagen.load` (compiled from `cache_dir`)."""
    dyns = {"compiled": gagen.load("rrr", cache_dir=cache_dir),
            "lambdify": gagen.load("rrr", backend="lambdify")}
    return core.simulation_rows(dyns, repeats, progress=progress)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=REPEATS,
                        help=f"rounds of the round-robin (default {REPEATS})")
    parser.add_argument("--runs", type=int, default=1,
                        help="measure this many times and summarise the speed-ups (default 1)")
    parser.add_argument("--cache-dir", metavar="DIR",
                        help="cache of compiled models (default: gagen's cache)")
    args = parser.parse_args(argv)
    print("loading rrr (compiled and lambdify) and warming up...", file=sys.stderr, flush=True)

    def progress(text):
        print(f"  {text}", file=sys.stderr, flush=True)

    speedups = []
    for run in range(max(1, args.runs)):
        rows = simulation_rows(args.cache_dir, args.repeats, progress)
        c = next(r for r in rows if r["case"] == "c")
        speedups.append(c["speedup"])
        if run == 0:
            print(f"The paper's 5-s direct dynamics of rrr (paper_controller(), rtol={RTOL:g}, "
                  f"atol={ATOL:g}, 501 samples); one `gagen.simulate` call each, median of "
                  f"{args.repeats} interleaved rounds. gagen {gagen.__version__}, Python "
                  f"{platform.python_version()}, {platform.machine()}.\n")
        else:
            print(f"\nRun {run + 1}:\n")
        print(markdown_table(rows))
        verdict = "met" if c["speedup"] >= GOAL else "NOT met"
        print(f"\nGoal (c) >= {GOAL:,.0f}x faster than (a): {verdict} ({c['speedup']:,.0f}x).",
              flush=True)
    if len(speedups) > 1:
        print(f"\nSpeed-up of (c) over (a) in {len(speedups)} runs: "
              + ", ".join(f"{v:,.0f}x" for v in speedups)
              + f"; median {statistics.median(speedups):,.0f}x, lowest {min(speedups):,.0f}x.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
