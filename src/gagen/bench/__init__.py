"""gagen's benchmark suite: `python -m gagen bench [--out DIR] [--full]`.

Modules: `timing` (the interleaved runner every section uses), `peers` (Pinocchio, PyDy
and plain SymPy versions of the same robot), `percall`, `batched`, `simulation`,
`scaling`, `coldbuild`, `pinocchio_cpp`, `floating`, `centroidal`, `taskspace`,
`constraints`, `derivatives`, `casadi`, `jaxbench`, `report` (report.md and PNG plots) and
`run` (the whole suite). Pinocchio and PyDy are optional (`pip install gagen[bench]`);
without them their rows are skipped.

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
  scaling           cold builds of chain:2, chain:4, chain:6 and the UR5 (each in a fresh
                    process): derive, generate, compile times, peak memory, operations
                    before/after CSE, forward dynamics per call
  derivatives       FD/ID derivatives and the Coriolis matrix on rrr, the Panda, and ANYmal C
                    and Talos reduced on a floating base against Pinocchio's
                    computeABADerivatives / computeRNEADerivatives / computeCoriolisMatrix
                    and central differences; the floating robots' FD Jacobian in C against
                    CasADi's generated C of adam's aba Jacobian (-O3, its object cached);
                    cold builds of the main and derivative modules
--full adds, in tens of minutes:
  scaling           chain:5 ... chain:50, UR5, Panda, ANYmal C, Talos reduced and full and
                    Tiago (fixed bases): build times and the curve; FD, ID and M per call
                    from Python against Pinocchio's aba / rnea / crba, and per state in
                    the batched C loop against Pinocchio's C++ (a harness compiled with
                    -O3 -march=native)
  panda             the Panda per call against Pinocchio
  floating          ANYmal C and Talos on a floating base: FD, ID, M and a foot Jacobian
                    against Pinocchio (and MuJoCo's mj_forward if installed)
  regressor         the Panda's regressor per call against Pinocchio's
                    computeJointTorqueRegressor; identification from 10,000 samples
                    (gagen.identify against Pinocchio's regressor in a loop + lstsq)
  centroidal        ANYmal C's centre of mass, A_g, its bias d/dt A_g qd and d/dt A_g
                    against Pinocchio's centerOfMass, computeCentroidalMap, ccrba, dccrba
                    and computeCentroidalMapTimeVariation
  taskspace         a frame's J̇ q̇, J̇ and operational-space inertia on the Panda's tool and
                    an ANYmal C foot against Pinocchio (forwardKinematics +
                    getFrameClassicalAcceleration, computeJointJacobiansTimeVariation +
                    getFrameJacobianTimeVariation, computeMinverse + Jacobian products)
  constraints       ANYmal C standing on four 3-D point contacts: the constrained forward
                    dynamics and impulse dynamics against Pinocchio's constraintDynamics
                    and impulseDynamics (exact KKT solution, mu = 0), their derivatives
                    against computeConstraintDynamicsDerivatives
  casadi            gagen.casadi against adam's CasADi dynamics (the Panda with fixed
                    fingers, ANYmal C): forward dynamics and its Jacobian per evaluation
                    inside CasADi (SX, and generated C at -O3; adam's compiles cached in
                    the cache folder), and the docs' IPOPT swing on each (needs casadi,
                    adam-robotics: pip install gagen[bench])
  jax               4,096 states in jax.jit(jax.vmap(...)): forward dynamics and its
                    jacfwd through gagen.jax's FFI and printed functions, against gagen's
                    stacked call, adam's JAX backend and MuJoCo MJX (Panda, Panda arm,
                    ANYmal C); the printed functions' JIT compile times
--only SECTION ... runs the named sections alone.
Candidates are timed interleaved (round-robin over the repeats); reported are medians,
interquartile ranges and ratios to a baseline."""
