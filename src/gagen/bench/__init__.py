"""gagen's benchmark suite: `python -m gagen bench [--out DIR] [--full]`.

Modules: `timing` (the interleaved runner every section uses), `peers` (Pinocchio, PyDy
and plain SymPy versions of the same robot), `percall`, `batched`, `simulation`,
`scaling`, `report` (report.md and PNG plots) and `run` (the whole suite). Pinocchio and
PyDy are optional (`pip install gagen[bench]`); without them their rows are skipped.

This module only registers the command: the measurement code is imported when it runs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

DESCRIPTION = """\
Reproducible benchmarks of gagen, written to --out as report.md (machine, method, tables),
results.json and PNG plots.

Default (a few minutes on 2 cores):
  per call on rrr   mass matrix, forward and inverse dynamics: gagen compiled and lambdify,
                    PyDy's Cython rhs, plain sympy.lambdify + numpy.linalg.solve, and
                    Pinocchio's crba / aba / rnea (peers skipped if not installed)
  batched           compiled and lambdify forward dynamics on N = 1 ... 10000 states
  simulation        the paper's 5-s simulation: scipy RK45 (lambdify, compiled), compiled
                    dopri5 and rk4
  scaling           cold builds of chain:2, chain:4, chain:6 and the UR5: derive, generate,
                    compile times, operations before/after CSE, forward dynamics per call
--full adds chain:3 ... chain:12 and the Panda to the scaling study, and the Panda
against Pinocchio per call (tens of minutes).

Candidates are timed interleaved (round-robin over the repeats); reported are medians,
interquartile ranges and ratios to a baseline."""


def _bench(args: argparse.Namespace) -> int:
    from .run import run

    mode = "smoke" if args.smoke else ("full" if args.full else "default")
    command = "python -m gagen bench --out " + str(args.out) + (
        " --full" if args.full else "") + (" --smoke" if args.smoke else "")
    return run(out=Path(args.out), mode=mode, urdf_dir=args.urdf_dir, cache_dir=args.cache_dir,
               sections=args.only, scaling_models=args.models, command=command)


def register(subparsers) -> None:
    """Add the `bench` command to gagen's command line."""
    from .run import SECTIONS

    p = subparsers.add_parser("bench", help="benchmarks: per call, batched, simulation, "
                              "scaling; writes report.md",
                              formatter_class=argparse.RawDescriptionHelpFormatter,
                              description=DESCRIPTION)
    p.add_argument("--out", default="bench-out", metavar="DIR",
                   help="output folder for report.md, results.json and the plots "
                   "(default: %(default)s)")
    p.add_argument("--full", action="store_true",
                   help="the complete study: chain:2 ... chain:12, UR5 and Panda")
    p.add_argument("--urdf-dir", metavar="DIR",
                   help="folder holding ur5_robot.urdf and panda.urdf (default: "
                   "$GAGEN_URDF_DIR, else ../shared/urdf next to the repository)")
    p.add_argument("--cache-dir", metavar="DIR",
                   help="where rrr is built for the per-call, batched and simulation "
                   "sections (default: a fresh temporary folder; the scaling study always "
                   "builds cold in one)")
    p.add_argument("--only", nargs="+", choices=SECTIONS, metavar="SECTION",
                   help=f"run only these sections ({', '.join(SECTIONS)})")
    p.add_argument("--models", nargs="+", metavar="MODEL",
                   help="models of the scaling study instead of the mode's list "
                   "(built-in names, model files, URDFs)")
    p.add_argument("--smoke", action="store_true", help=argparse.SUPPRESS)
    p.set_defaults(run=_bench)
