"""Per-call time of the Panda's dynamics from Python: gagen's compiled module vs pinocchio.

Three quantities, each with both implementations called from Python at the same fixed state:
forward dynamics (`dyn.forward_dynamics` vs `pinocchio.aba`), the mass matrix
(`dyn.mass_matrix` vs `pinocchio.crba`; crba fills only the upper triangle, gagen returns
the full matrix) and inverse dynamics (`dyn.inverse_dynamics` vs `pinocchio.rnea`).

All candidates are timed in ONE process and interleaved: every repeat runs each candidate
once (round-robin, the starting candidate rotating), so a slow phase of a busy machine
hits them all alike. Reported: the median per call, the quartiles and IQR, and the ratio
of gagen's median to pinocchio's. Results are checked to agree before anything is timed.

    python benchmarks/panda_vs_pinocchio.py [--cache-dir DIR] [--repeats 21] [--out DIR]

`panda_rows(cache_dir)` is the reusable core. Without pinocchio only gagen is timed.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import timeit
from pathlib import Path

import numpy as np

import gagen

PANDA = Path(__file__).resolve().parents[2] / "shared" / "urdf" / "panda.urdf"
REPEATS = 21
QUANTITIES = ("forward dynamics", "mass matrix", "inverse dynamics")
COLUMNS = ("quantity", "implementation", "call", "median_us", "q1_us", "q3_us", "iqr_us",
           "ratio_to_pinocchio", "number", "repeats")


def _pinocchio():
    try:
        import pinocchio
    except ImportError:
        return None
    return pinocchio


def panda_state(dyn, seed: int = 0):
    """A fixed state within the joint limits: q, qd, qdd and the torques tau = ID(q, qd, qdd)."""
    rng = np.random.default_rng(seed)
    lo, hi = [], []
    limits = {b.joint.name: b.joint.limits for b in dyn.model.bodies}
    for name in dyn.coordinates:
        lim = limits[name]
        ok = lim is not None and lim.lower is not None and lim.upper is not None
        lo.append(lim.lower if ok else -np.pi)
        hi.append(lim.upper if ok else np.pi)
    q = rng.uniform(lo, hi)
    qd, qdd = rng.normal(size=dyn.n), rng.normal(size=dyn.n)
    return q, qd, qdd, dyn.inverse_dynamics(q, qd, qdd)


def candidates(dyn, urdf: Path = PANDA):
    """(quantity, implementation, call text, function, args); checks that the two agree."""
    q, qd, qdd, tau = panda_state(dyn)
    out = [
        ("forward dynamics", "gagen", "dyn.forward_dynamics(q, qd, tau)",
         dyn.forward_dynamics, (q, qd, tau)),
        ("mass matrix", "gagen", "dyn.mass_matrix(q)", dyn.mass_matrix, (q,)),
        ("inverse dynamics", "gagen", "dyn.inverse_dynamics(q, qd, qdd)",
         dyn.inverse_dynamics, (q, qd, qdd)),
    ]
    pin = _pinocchio()
    if pin is None:
        return out
    model = pin.buildModelFromUrdf(str(urdf))  # mimic joints independent, as in gagen
    data = model.createData()
    ids = [model.getJointId(name) for name in dyn.coordinates]
    if model.nq != model.nv or model.nv != dyn.n:
        raise RuntimeError("this benchmark expects one q entry per coordinate (no continuous "
                           "joints)")
    perm = np.array([model.idx_vs[j] for j in ids])

    def to_pin(v):
        out = np.empty(model.nv)
        out[perm] = v
        return out

    pq, pqd, pqdd, ptau = (to_pin(v) for v in (q, qd, qdd, tau))
    # the same numbers before timing anything
    M = np.array(pin.crba(model, data, pq))
    M = np.triu(M) + np.triu(M, 1).T
    checks = (
        (pin.aba(model, data, pq, pqd, ptau)[perm], dyn.forward_dynamics(q, qd, tau)),
        (M[np.ix_(perm, perm)], dyn.mass_matrix(q)),
        (pin.rnea(model, data, pq, pqd, pqdd)[perm], dyn.inverse_dynamics(q, qd, qdd)),
    )
    for (theirs, ours), quantity in zip(checks, QUANTITIES):
        scale = np.abs(theirs).max()
        if not np.allclose(ours, theirs, rtol=1e-9, atol=1e-9 * scale):
            raise RuntimeError(f"gagen and pinocchio disagree on the {quantity}")
    out += [
        ("forward dynamics", "pinocchio", "pinocchio.aba(model, data, q, qd, tau)",
         pin.aba, (model, data, pq, pqd, ptau)),
        ("mass matrix", "pinocchio", "pinocchio.crba(model, data, q)",
         pin.crba, (model, data, pq)),
        ("inverse dynamics", "pinocchio", "pinocchio.rnea(model, data, q, qd, qdd)",
         pin.rnea, (model, data, pq, pqd, pqdd)),
    ]
    return out


def interleaved_times(cands, repeats: int = REPEATS,
                      target: float = 0.05) -> tuple[list[list[float]], list[int]]:
    """Seconds per call, per candidate and repeat, timed round-robin over the repeats."""
    timers = [timeit.Timer("fn(*args)", globals={"fn": fn, "args": args})
              for *_, fn, args in cands]
    numbers = []
    for timer in timers:  # loop sizes: each loop takes about `target` seconds
        timer.timeit(100)  # warm up
        once = timer.timeit(1000) / 1000
        numbers.append(max(1000, int(target / max(once, 1e-9))))
    times: list[list[float]] = [[] for _ in cands]
    for r in range(repeats):
        for k in range(len(cands)):
            i = (k + r) % len(cands)
            times[i].append(timers[i].timeit(numbers[i]) / numbers[i])
    return times, numbers


def panda_rows(cache_dir=None, repeats: int = REPEATS, urdf: Path = PANDA) -> list[dict]:
    """One row per (quantity, implementation): median, quartiles, IQR (µs) and ratio."""
    dyn = gagen.load(urdf, backend="compiled", cache_dir=cache_dir, verbose=False)
    cands = candidates(dyn, urdf)
    times, numbers = interleaved_times(cands, repeats)
    rows = []
    for (quantity, impl, call, _, _), ts, number in zip(cands, times, numbers):
        q1, median, q3 = statistics.quantiles(ts, n=4, method="inclusive")
        rows.append({"quantity": quantity, "implementation": impl, "call": call,
                     "median_us": median * 1e6, "q1_us": q1 * 1e6, "q3_us": q3 * 1e6,
                     "iqr_us": (q3 - q1) * 1e6, "ratio_to_pinocchio": None,
                     "number": number, "repeats": repeats})
    pin_median = {r["quantity"]: r["median_us"] for r in rows if r["implementation"] == "pinocchio"}
    for r in rows:
        if r["quantity"] in pin_median:
            r["ratio_to_pinocchio"] = r["median_us"] / pin_median[r["quantity"]]
    return rows


def markdown_table(rows: list[dict]) -> str:
    lines = ["| quantity | implementation | call | median µs | IQR µs (q1–q3) | ratio to pinocchio |",
             "|---|---|---|--:|--:|--:|"]
    for r in rows:
        ratio = "—" if r["ratio_to_pinocchio"] is None else f"{r['ratio_to_pinocchio']:.2f}"
        lines.append(f"| {r['quantity']} | {r['implementation']} | `{r['call']}` "
                     f"| {r['median_us']:.3f} | {r['iqr_us']:.3f} ({r['q1_us']:.3f}–"
                     f"{r['q3_us']:.3f}) | {ratio} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cache-dir", metavar="DIR",
                        help="gagen's cache (default: $GAGEN_CACHE_DIR or ~/.cache/gagen); "
                        "the Panda is built there on first use")
    parser.add_argument("--repeats", type=int, default=REPEATS,
                        help=f"interleaved repeats per candidate (default {REPEATS})")
    parser.add_argument("--urdf", default=str(PANDA), help="the Panda's URDF")
    parser.add_argument("--out", metavar="DIR",
                        help="write panda_vs_pinocchio.md and panda_vs_pinocchio.csv here")
    args = parser.parse_args(argv)
    if _pinocchio() is None:
        print("pinocchio is not installed: timing gagen only (pip install pin)",
              file=sys.stderr)
    rows = panda_rows(args.cache_dir, args.repeats, Path(args.urdf))
    table = markdown_table(rows)
    print(table)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        with open(out / "panda_vs_pinocchio.csv", "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=COLUMNS)
            writer.writeheader()
            writer.writerows(rows)
        note = (f"Panda, gagen {gagen.__version__}, one process, {args.repeats} interleaved "
                "repeats per candidate; per-call times from Python.\n\n")
        (out / "panda_vs_pinocchio.md").write_text(note + table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
