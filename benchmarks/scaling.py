"""How build time, code size and call time grow with the robot: chain:2 ... chain:12, UR5, Panda.

For each model: a cold build (nothing cached) timed stage by stage as `gagen.build.build`
reports it (derive; generate, which includes CSE; compile, which is Cython and the C
compiler in a subprocess), the operation counts before and after CSE, then the compiled
module is loaded and one call of `forward_dynamics` at a fixed state is timed (median of
7 repeats of a timeit loop).

    python benchmarks/scaling.py                         # all default models, fresh cache
    python benchmarks/scaling.py --models chain:2 chain:6 --out bench-out

`scaling_rows(models, cache_dir)` is the reusable core; each model is built in its own
sub-folder of `cache_dir`, so a fresh `cache_dir` means cold builds.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import tempfile
import time
import timeit
from pathlib import Path

import numpy as np

import gagen
from gagen.build import build
from gagen.loading import resolve_model

URDF_DIR = Path(__file__).resolve().parents[2] / "shared" / "urdf"
DEFAULT_MODELS = ([f"chain:{n}" for n in range(2, 13)]
                  + [str(URDF_DIR / "ur5_robot.urdf"), str(URDF_DIR / "panda.urdf")])
REPEATS = 7
COLUMNS = ("model", "dof", "derive_s", "generate_s", "compile_s", "build_s", "ops_before_cse",
           "ops_after_cse", "cse_ratio", "load_s", "fd_us", "fd_iqr_us", "cached")


def fixed_state(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A reproducible, generic state (no zeros that could take shortcuts)."""
    rng = np.random.default_rng(seed)
    return (rng.uniform(-1.0, 1.0, n) * 0.8, rng.normal(size=n), rng.normal(scale=2.0, size=n))


def time_per_call(fn, *args, repeats: int = REPEATS) -> list[float]:
    """Seconds per call, one value per repeat; loops sized so that one repeat takes ~0.2 s."""
    timer = timeit.Timer("fn(*args)", globals={"fn": fn, "args": args})
    number, _ = timer.autorange()
    return [t / number for t in timer.repeat(repeat=repeats, number=number)]


def quartiles(values: list[float]) -> tuple[float, float, float]:
    q1, median, q3 = statistics.quantiles(values, n=4, method="inclusive")
    return q1, median, q3


def scaling_row(model_name: str, cache_dir: Path, repeats: int = REPEATS) -> dict:
    """Build one model cold into `cache_dir`, load it, time forward dynamics."""
    model = resolve_model(model_name)
    start = time.perf_counter()
    _, report = build(model, cache_dir=cache_dir, verbose=False)
    build_s = time.perf_counter() - start
    start = time.perf_counter()
    dyn = gagen.load(model, backend="compiled", cache_dir=cache_dir, verbose=False)
    load_s = time.perf_counter() - start
    q, qd, tau = fixed_state(dyn.n)
    dyn.forward_dynamics(q, qd, tau)  # warm up, and fail here rather than in the timer
    q1, median, q3 = quartiles(time_per_call(dyn.forward_dynamics, q, qd, tau, repeats=repeats))
    stages = report.stages
    nan = float("nan")
    return {
        "model": model.name if not model_name.startswith("chain:") else model_name,
        "dof": model.dof,
        "derive_s": stages.get("derive", nan),
        "generate_s": stages.get("generate", nan),
        "compile_s": stages.get("compile", nan),
        "build_s": build_s,
        "ops_before_cse": report.ops_before_cse,
        "ops_after_cse": report.ops_after_cse,
        "cse_ratio": (report.ops_before_cse / report.ops_after_cse
                      if report.ops_after_cse else nan),
        "load_s": load_s,
        "fd_us": median * 1e6,
        "fd_iqr_us": (q3 - q1) * 1e6,
        "cached": report.cached,
    }


def scaling_rows(models, cache_dir, repeats: int = REPEATS, progress=None) -> list[dict]:
    """One row per model; each is built in its own sub-folder of `cache_dir`."""
    rows = []
    for k, name in enumerate(models):
        folder = Path(cache_dir) / f"{k:02d}-{_slug(name)}"
        row = scaling_row(name, folder, repeats)
        if progress:
            progress(row)
        rows.append(row)
    return rows


def _slug(name: str) -> str:
    stem = Path(name).stem if name.endswith(".urdf") or "/" in name else name
    return "".join(c if c.isalnum() else "_" for c in stem)


def markdown_table(rows: list[dict]) -> str:
    head = ("| model | dof | derive s | generate s (incl. CSE) | compile s | ops before CSE "
            "| ops after CSE | ratio | FD µs/call (IQR) |")
    lines = [head, "|---|--:|--:|--:|--:|--:|--:|--:|--:|"]
    for r in rows:
        cached = " (cached)" if r["cached"] else ""
        lines.append(
            f"| {r['model']}{cached} | {r['dof']} | {r['derive_s']:.2f} | {r['generate_s']:.2f} "
            f"| {r['compile_s']:.2f} | {r['ops_before_cse']} | {r['ops_after_cse']} "
            f"| {r['cse_ratio']:.2f} | {r['fd_us']:.2f} ({r['fd_iqr_us']:.2f}) |")
    return "\n".join(lines)


def write_outputs(rows: list[dict], out: Path, header: str = "") -> None:
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "scaling.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    (out / "scaling.md").write_text(header + markdown_table(rows) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=DEFAULT_MODELS, metavar="MODEL",
                        help="built-in names, model files or URDFs (default: chain:2 ... "
                        "chain:12, the UR5 and the Panda)")
    parser.add_argument("--cache-dir", metavar="DIR",
                        help="where to build (default: a fresh temporary folder, so builds "
                        "are cold; an existing cache entry is reused and marked 'cached')")
    parser.add_argument("--repeats", type=int, default=REPEATS,
                        help=f"timeit repeats per model (default {REPEATS})")
    parser.add_argument("--out", metavar="DIR", help="write scaling.md and scaling.csv here")
    args = parser.parse_args(argv)
    cache = Path(args.cache_dir) if args.cache_dir else Path(
        tempfile.mkdtemp(prefix="gagen-scaling-"))
    print(f"building into {cache}", file=sys.stderr)

    def progress(row):
        print(f"  {row['model']:<12} derive {row['derive_s']:6.2f} s  generate "
              f"{row['generate_s']:6.2f} s  compile {row['compile_s']:6.2f} s  "
              f"ops {row['ops_before_cse']} -> {row['ops_after_cse']}  "
              f"FD {row['fd_us']:.2f} µs", file=sys.stderr, flush=True)

    rows = scaling_rows(args.models, cache, args.repeats, progress)
    header = (f"Cold builds with gagen {gagen.__version__} (`build(model, cache_dir=fresh)`); "
              f"FD: median of {args.repeats} timeit repeats of "
              "`dyn.forward_dynamics(q, qd, tau)` at a fixed state.\n\n")
    print(markdown_table(rows))
    if args.out:
        write_outputs(rows, Path(args.out), header)
        print(f"wrote {Path(args.out) / 'scaling.md'} and scaling.csv", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
