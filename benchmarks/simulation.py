"""The paper's direct dynamics, timed four ways: how much faster is the compiled integrator?

The 5-s simulation of `rrr` (from rest at q = 0 under `paper_controller()`, rtol = 1e-6,
atol = 1e-8, 501 output samples, i.e. `python -m gagen simulate`) run as

    (a) scipy RK45, lambdify backend   (SymPy's lambdify, Python in every step)
    (b) scipy RK45, compiled backend   (compiled model and gravity torque, Python per step)
    (c) compiled dopri5                (the whole simulation in C; same steps as RK45)
    (d) compiled rk4, h = 1e-3         (5000 fixed steps in C)

Each time is one complete `gagen.simulate(...)` call (validation, integration, torques
at the output samples, result). The cases are interleaved round-robin: every round times
each case once (fast cases as a loop of calls, about 20 ms per round, divided), so slow
drifts of the machine hit all cases alike. Reported: median, spread (quartiles) and the
ratio of (a)'s median to each case's median. The goal: (c) at least 1000x faster than (a).

    python benchmarks/simulation.py [--repeats 7] [--cache-dir DIR]

`simulation_rows(cache_dir=None, repeats=...)` is the reusable core.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time

import numpy as np

import gagen
from gagen.controllers import paper_controller
from gagen.simulate import simulate

REPEATS = 7
DURATION = 5.0
RTOL, ATOL = 1e-6, 1e-8
ROUND_SECONDS = 0.02
GOAL = 1000.0
CASES = (
    # key, label, backend, method, options
    ("a", "scipy RK45, lambdify backend", "lambdify", "RK45", {}),
    ("b", "scipy RK45, compiled backend", "compiled", "RK45", {}),
    ("c", "compiled dopri5", "compiled", "dopri5", {}),
    ("d", "compiled rk4, h = 1e-3", "compiled", "rk4", {"h": 1e-3}),
)


def _quartiles(values: list[float]) -> tuple[float, float, float]:
    if len(values) < 2:
        return values[0], values[0], values[0]
    q1, median, q3 = statistics.quantiles(values, n=4, method="inclusive")
    return q1, median, q3


def simulation_rows(cache_dir=None, repeats: int = REPEATS, progress=None) -> list[dict]:
    """Time the four cases (see the module docstring); one dict per case, (a) first.

    Keys: case, label, backend, method, median_s, q1_s, q3_s, min_s, repeats, calls (per
    round),
    steps, nfev, final_q_deg, max_dev_rad (largest |q - q of case (a)|), speedup (median of
    (a) / median of this case).
    """
    dyns = {"compiled": gagen.load("rrr", cache_dir=cache_dir),
            "lambdify": gagen.load("rrr", backend="lambdify")}
    controller = paper_controller()
    q0 = np.zeros(3)

    def run(case):
        _, _, backend, method, options = case
        return simulate(dyns[backend], (0.0, DURATION), q0, q0, controller, method=method,
                        rtol=RTOL, atol=ATOL, **options)

    # warm up and size each case's loop so that one round takes about ROUND_SECONDS
    first, numbers = {}, {}
    for case in CASES:
        start = time.perf_counter()
        first[case[0]] = run(case)
        once = time.perf_counter() - start
        numbers[case[0]] = max(1, int(ROUND_SECONDS / max(once, 1e-9)))
    times: dict[str, list[float]] = {case[0]: [] for case in CASES}
    for r in range(repeats):
        for case in CASES:
            n = numbers[case[0]]
            start = time.perf_counter()
            for _ in range(n):
                run(case)
            times[case[0]].append((time.perf_counter() - start) / n)
        if progress:
            progress(r + 1, repeats)
    ref = first["a"]
    base = statistics.median(times["a"])
    rows = []
    for key, label, backend, method, _ in CASES:
        res = first[key]
        q1, median, q3 = _quartiles(times[key])
        rows.append({
            "case": key, "label": label, "backend": backend, "method": method,
            "median_s": median, "q1_s": q1, "q3_s": q3, "min_s": min(times[key]),
            "repeats": repeats, "calls": numbers[key], "steps": res.stats["steps"],
            "nfev": res.stats["nfev"], "final_q_deg": np.degrees(res.q[-1]).round(4).tolist(),
            "max_dev_rad": float(np.abs(res.q - ref.q).max()), "speedup": base / median,
        })
    return rows


def _time(seconds: float) -> str:
    if seconds < 1e-6:
        return f"{seconds * 1e9:.0f} ns"
    if seconds < 1e-3:
        return f"{seconds * 1e6:.0f} µs"
    if seconds < 1.0:
        return f"{seconds * 1e3:.2f} ms"
    return f"{seconds:.3f} s"


def markdown_table(rows: list[dict]) -> str:
    lines = [("| case | method | median | spread (quartiles) | steps | RHS evals "
              "| per RHS eval | max abs(q - q_a) (rad) | speed-up vs (a) |"),
             "|---|---|--:|--:|--:|--:|--:|--:|--:|"]
    for r in rows:
        lines.append(
            f"| ({r['case']}) {r['label']} | {r['method']} | {_time(r['median_s'])} "
            f"| {_time(r['q1_s'])} .. {_time(r['q3_s'])} | {r['steps']} | {r['nfev']} "
            f"| {_time(r['median_s'] / r['nfev'])} | {r['max_dev_rad']:.1e} | {r['speedup']:,.0f}x |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=REPEATS,
                        help=f"rounds of the round-robin (default {REPEATS})")
    parser.add_argument("--cache-dir", metavar="DIR",
                        help="cache of compiled models (default: gagen's cache)")
    args = parser.parse_args(argv)
    print("loading rrr (compiled and lambdify) and warming up...", file=sys.stderr, flush=True)

    def progress(done, total):
        print(f"  round {done}/{total}", file=sys.stderr, flush=True)

    rows = simulation_rows(args.cache_dir, args.repeats, progress)
    c = next(r for r in rows if r["case"] == "c")
    print(f"The paper's 5-s direct dynamics of rrr (paper_controller(), rtol={RTOL:g}, "
          f"atol={ATOL:g}, 501 samples); one `gagen.simulate` call each, median of "
          f"{args.repeats} interleaved rounds. gagen {gagen.__version__}, Python "
          f"{platform.python_version()}, {platform.machine()}.\n")
    print(markdown_table(rows))
    verdict = "met" if c["speedup"] >= GOAL else "NOT met"
    print(f"\nGoal (c) >= {GOAL:,.0f}x faster than (a): {verdict} ({c['speedup']:,.0f}x).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
