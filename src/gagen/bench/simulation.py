"""The paper's direct dynamics, timed four ways: how much faster is the compiled integrator?

The 5-s simulation of `rrr` (from rest at q = 0 under `paper_controller()`, rtol = 1e-6,
atol = 1e-8, 501 output samples, i.e. `python -m gagen simulate`) run as

    (a) scipy RK45, lambdify backend   (SymPy's lambdify, Python in every step)
    (b) scipy RK45, compiled backend   (compiled model and gravity torque, Python per step)
    (c) compiled dopri5                (the whole simulation in C; same steps as RK45)
    (d) compiled rk4, h = 1e-3         (5000 fixed steps in C)

Each time is one complete `gagen.simulate(...)` call (validation, integration, torques
at the output samples, result), timed by the interleaved runner (fast cases as a loop of
calls of about `target` seconds, divided). Reported: median, quartiles, and the speed-up
of each case over (a) (the median of (a) over the case's median).
"""

from __future__ import annotations

import numpy as np

from ..sim.controllers import paper_controller
from ..sim.simulate import simulate
from .timing import Candidate, interleaved

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


def simulation_rows(dyns: dict, repeats: int = REPEATS, target: float = ROUND_SECONDS,
                    progress=None, duration: float = DURATION) -> list[dict]:
    """Time the four cases; one dict per case, (a) first.

    `dyns` maps "compiled" and "lambdify" to rrr's dynamics objects. Keys: case, label,
    backend, method, median_s, q1_s, q3_s, min_s, repeats, calls (per sample), steps,
    nfev, final_q_deg, max_dev_rad (largest |q - q of case (a)|), speedup (median of (a)
    over this case's median).
    """
    controller = paper_controller()
    q0 = np.zeros(3)

    def run(case):
        _, _, backend, method, options = case
        return simulate(dyns[backend], (0.0, duration), q0, q0, controller, method=method,
                        rtol=RTOL, atol=ATOL, **options)

    first = {case[0]: run(case) for case in CASES}  # also checks that every case works
    cands = [Candidate(case[0], run, (case,), info={"label": case[1]}) for case in CASES]

    def rounds(done, total):
        if progress and (done == total or done % max(1, total // 3) == 0):
            progress(f"round {done}/{total}")

    timings = interleaved(cands, repeats, target, baseline="a", progress=rounds)
    ref = first["a"]
    rows = []
    for (key, label, backend, method, _), t in zip(CASES, timings):
        res = first[key]
        rows.append({
            "case": key, "label": label, "backend": backend, "method": method,
            "median_s": t.median, "q1_s": t.q1, "q3_s": t.q3, "min_s": t.min,
            "repeats": len(t.samples), "calls": t.number, "steps": res.stats["steps"],
            "nfev": res.stats["nfev"], "final_q_deg": np.degrees(res.q[-1]).round(4).tolist(),
            "max_dev_rad": float(np.abs(res.q - ref.q).max()), "speedup": 1.0 / t.ratio,
            "samples_s": list(t.samples),
        })
    return rows


def format_time(seconds: float) -> str:
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
            f"| ({r['case']}) {r['label']} | {r['method']} | {format_time(r['median_s'])} "
            f"| {format_time(r['q1_s'])} .. {format_time(r['q3_s'])} | {r['steps']} "
            f"| {r['nfev']} | {format_time(r['median_s'] / r['nfev'])} "
            f"| {r['max_dev_rad']:.1e} | {r['speedup']:,.0f}x |")
    return "\n".join(lines)
