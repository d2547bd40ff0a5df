"""The paper's reproduction (`python -m gagen paper`): its robot, its settings, its figures.

Runs direct dynamics (Fig. 2 and 3) and inverse dynamics along eq. 11 (Fig. 4) on `rrr`
with the paper's defaults, through the same functions as `simulate` and `inverse`, then
compares the results, in memory, with the paper's figures.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

from .runs import (
    InverseRun,
    SimulateRun,
    print_inverse_report,
    print_simulate_report,
    run_inverse,
    run_simulate,
)

log = logging.getLogger(__name__)

PAPER_MODEL = "rrr"
PAPER_DURATION = 5.0  # s: the simulated time of Fig. 2 and the motion time Tp of Fig. 4
DEFAULT_OUT = "out/rrr"


@dataclass
class PaperRuns:
    """The paper's two computations."""

    direct: SimulateRun
    inverse: InverseRun


def reproduce_paper(out: str | Path = DEFAULT_OUT, gif: bool = False,
                    cache_dir: str | Path | None = None) -> PaperRuns:
    """Both of the paper's computations on rrr, their files written into `out`; prints
    each one's report and then how they compare with the paper's figures."""
    out = Path(out)
    log.info(f"== direct dynamics (as `python -m gagen simulate {PAPER_MODEL} --out {out}`)")
    direct = run_simulate(PAPER_MODEL, duration=PAPER_DURATION, out=out, cache_dir=cache_dir,
                          gif=gif)
    print_simulate_report(direct)
    log.info(f"== inverse dynamics (as `python -m gagen inverse {PAPER_MODEL} --out {out}`)")
    inverse = run_inverse(PAPER_MODEL, duration=PAPER_DURATION, out=out, cache_dir=cache_dir)
    print_inverse_report(inverse)
    runs = PaperRuns(direct, inverse)
    print_comparison(runs, out)
    return runs


def print_comparison(runs: PaperRuns, out: Path) -> None:
    """The final position (Fig. 2) and the torques' ranges (Fig. 4) next to the paper's."""
    final = [math.degrees(v) for v in runs.direct.result.q[-1]]
    tau = runs.inverse.tau
    ranges = [(tau[:, k].min(), tau[:, k].max()) for k in range(3)]
    print("\nThe paper's results, reproduced (files in " + str(out) + "):")
    print("  Fig. 2  final q1, q2, q3: {:.1f}, {:.1f}, {:.1f} deg   (paper: about -60, -60, -30)"
          .format(*final))
    print("  Fig. 3  the arm's successive positions: fig3_arm.png")
    print("  Fig. 4  T01z {:+.1f} .. {:+.1f} N m  (paper: within about +-15)".format(*ranges[0]))
    print("          T12x {:+.1f} .. {:+.1f} N m  (paper: peaks at roughly 300-400)".format(
        *ranges[1]))
    print("          T23x {:+.1f} .. {:+.1f} N m  (paper: within 200)".format(*ranges[2]))
