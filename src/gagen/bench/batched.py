"""Batched forward dynamics: one call on N stacked states, time per state.

`dyn.forward_dynamics(q, qd, tau)` with q, qd, tau of shape (N, n), for the compiled
backend (one C loop over the rows) and the lambdify backend (NumPy arrays through the
lambdified expressions, then a stacked Cholesky solve), all sizes interleaved in one run.
"""

from __future__ import annotations

import numpy as np

from .timing import DEFAULT_REPEATS, DEFAULT_TARGET, Candidate, interleaved

SIZES = (1, 10, 100, 1000, 10000)
BACKENDS = ("compiled", "lambdify")


def stacked_states(n: int, count: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    return (rng.uniform(-1.0, 1.0, (count, n)) * 0.8, rng.normal(size=(count, n)),
            rng.normal(scale=2.0, size=(count, n)))


def batched_rows(dyns: dict, sizes=SIZES, repeats: int = DEFAULT_REPEATS,
                 target: float = DEFAULT_TARGET, progress=None) -> list[dict]:
    """One row per (backend, N): median seconds per call and nanoseconds per state.

    `dyns` maps a backend name to its dynamics object; the first is every ratio's
    baseline (for the same N).
    """
    names = list(dyns)
    cands = []
    for count in sizes:
        q, qd, tau = stacked_states(next(iter(dyns.values())).n, count)
        reference = None
        for backend in names:
            dyn = dyns[backend]
            out = dyn.forward_dynamics(q, qd, tau)
            if reference is None:
                reference = out
            elif not np.allclose(out, reference, rtol=1e-9, atol=1e-9 * np.abs(reference).max()):
                raise RuntimeError(f"stacked forward dynamics of {backend} and {names[0]} "
                                   f"disagree at N = {count}")
            cands.append(Candidate(f"{backend} N={count}", dyn.forward_dynamics, (q, qd, tau),
                                   group=str(count), info={"backend": backend, "N": count}))
    if progress:
        progress(f"{len(cands)} candidates (N = {', '.join(map(str, sizes))}); timing "
                 f"{repeats} interleaved repeats")
    timings = interleaved(cands, repeats, target,
                          baseline={str(c): f"{names[0]} N={c}" for c in sizes})
    rows = []
    for t in timings:
        count = t.info["N"]
        rows.append({"backend": t.info["backend"], "N": count,
                     "call": "dyn.forward_dynamics(q, qd, tau)  # (N, n) arrays",
                     "median_s": t.median, "q1_s": t.q1, "q3_s": t.q3,
                     "ns_per_state": t.median / count * 1e9,
                     "iqr_ns_per_state": t.iqr / count * 1e9,
                     "ratio": t.ratio, "baseline": names[0], "number": t.number,
                     "repeats": len(t.samples), "samples_s": list(t.samples)})
    return rows
