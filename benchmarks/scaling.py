"""How build time, memory and call time grow with the robot: chain:5 ... chain:50 and the
shared robots (UR5, Panda, ANYmal C, Talos reduced and full, Tiago; fixed bases).

For each model: a cold build in a fresh process (gagen.bench.coldbuild: stage times, wall
time, peak memory of the process tree), then forward dynamics, inverse dynamics and the
mass matrix per call from Python against Pinocchio's aba, rnea and crba, and per state in
the batched loop (against Pinocchio in C++ with --cpp). See gagen.bench.scaling.

    python benchmarks/scaling.py                         # all default models, fresh cache
    python benchmarks/scaling.py --models chain:2 chain:6 --out bench-out

The measurement is `gagen.bench.scaling.scaling_rows(models, cache_dir)`; each model is
built in its own sub-folder of `cache_dir`, so a fresh `cache_dir` means cold builds.
`python -m gagen bench` runs a short version, `--full` this one.
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
from pathlib import Path

import gagen
from gagen.bench.scaling import COLUMNS, REPEATS, markdown_table, scaling_models, scaling_rows

__all__ = ["markdown_table", "scaling_rows", "write_outputs"]

DEFAULT_MODELS, _MISSING = scaling_models(full=True)


def write_outputs(rows: list[dict], out: Path, header: str = "") -> None:
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "scaling.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
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
                        help=f"interleaved repeats of the forward-dynamics timing "
                        f"(default {REPEATS})")
    parser.add_argument("--out", metavar="DIR", help="write scaling.md and scaling.csv here")
    parser.add_argument("--cpp", action="store_true",
                        help="also time Pinocchio in C++ over stacked states (compiles a "
                        "harness against the pin wheel's headers: a minute or two)")
    args = parser.parse_args(argv)
    if args.models is DEFAULT_MODELS:
        for note in _MISSING:
            print(note, file=sys.stderr)
    cache = Path(args.cache_dir) if args.cache_dir else Path(
        tempfile.mkdtemp(prefix="gagen-scaling-"))
    print(f"building into {cache}", file=sys.stderr)

    def progress(text):
        print(f"  {text}", file=sys.stderr, flush=True)

    rows = scaling_rows(args.models, cache, args.repeats, progress=progress, cpp=args.cpp)
    header = (f"Cold builds with gagen {gagen.__version__}, each in a fresh process; per "
              f"call: medians of {args.repeats} interleaved timeit repeats against "
              "Pinocchio; batched: per state over 1000 stacked states.\n\n")
    print(markdown_table(rows))
    if args.out:
        write_outputs(rows, Path(args.out), header)
        print(f"wrote {Path(args.out) / 'scaling.md'} and scaling.csv", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
