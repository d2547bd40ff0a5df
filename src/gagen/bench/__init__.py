"""gagen's benchmark suite: `python -m gagen bench [--out DIR] [--full]`.

Modules: `timing` (the interleaved runner every section uses), `peers` (Pinocchio, PyDy
and plain SymPy versions of the same robot), `percall`, `batched`, `simulation`,
`scaling`, `report` (report.md and PNG plots) and `run` (the whole suite). Pinocchio and
PyDy are optional (`pip install gagen[bench]`); without them their rows are skipped.

This module holds only the command's description (gagen.app.cli parses the command line);
the measurement code is imported when it runs.
"""

from __future__ import annotations

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
  throughput        many simulations: simulate_batch on 1 thread and every core, a Python
                    loop over simulate, MuJoCo's rollout on the Panda (same RK4, no
                    contacts), and Dask's overhead per chunk on a LocalCluster
  scaling           cold builds of chain:2, chain:4, chain:6 and the UR5: derive, generate,
                    compile times, operations before/after CSE, forward dynamics per call
--full adds chain:3 ... chain:12 and the Panda to the scaling study, the Panda against
Pinocchio per call, and the regressor section (tens of minutes):
  regressor         the Panda's regressor per call against Pinocchio's
                    computeJointTorqueRegressor; identification from 10,000 samples
                    (gagen.identify against Pinocchio's regressor in a loop + lstsq)

Candidates are timed interleaved (round-robin over the repeats); reported are medians,
interquartile ranges and ratios to a baseline."""
