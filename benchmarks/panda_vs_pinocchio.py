"""Per-call time of the Panda's dynamics from Python: gagen's compiled module vs pinocchio.

Three quantities, each with both implementations called from Python at the same fixed state:
forward dynamics (`dyn.forward_dynamics` vs `pinocchio.aba`), the mass matrix
(`dyn.mass_matrix` vs `pinocchio.crba`; crba fills only the upper triangle, gagen returns
the full matrix) and inverse dynamics (`dyn.inverse_dynamics` vs `pinocchio.rnea`).

All candidates are timed in ONE process and interleaved (gagen.bench.timing): every
repeat runs each candidate once, the starting candidate rotating. Reported: the median
per call, the quartiles and IQR, and the ratio of each median to pinocchio's. Results are
checked to agree before anything is timed.

    python benchmarks/panda_vs_pinocchio.py [--cache-dir DIR] [--repeats 21] [--out DIR]

The measurement is `gagen.bench.percall.panda_rows`; `python -m gagen bench --full` runs
it too. Without pinocchio only gagen is timed.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import gagen
from gagen.bench import percall
from gagen.bench.common import PANDA as PANDA_FILE
from gagen.bench.common import find_urdf_dir, optional

_FOUND = find_urdf_dir(needed=PANDA_FILE)
PANDA = (_FOUND or Path(__file__).resolve().parents[2] / "shared" / "urdf") / PANDA_FILE
REPEATS = 21
COLUMNS = ("quantity", "implementation", "call", "median_us", "q1_us", "q3_us", "iqr_us",
           "ratio_to_pinocchio", "number", "repeats")


def panda_rows(cache_dir=None, repeats: int = REPEATS, urdf: Path = PANDA) -> list[dict]:
    """One row per (quantity, implementation): median, quartiles, IQR (µs) and ratio."""
    dyn = gagen.load(urdf, backend="compiled", cache_dir=cache_dir, verbose=False)
    rows = percall.panda_rows(dyn, Path(urdf), repeats, target=0.05, baseline="pinocchio")
    names = {"gagen compiled": "gagen", "Pinocchio": "pinocchio"}
    out = [{key: row["ratio"] if key == "ratio_to_pinocchio" else row[key] for key in COLUMNS}
           for row in rows]
    for row in out:
        row["implementation"] = names[row["implementation"]]
    return out


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
    if optional("pinocchio") is None:
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
