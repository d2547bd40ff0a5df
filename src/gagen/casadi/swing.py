"""A minimum-effort swing between two poses at rest, by direct multiple shooting in
`casadi.Opti` with IPOPT: the example of docs/casadi.md and the `casadi` benchmark.

The problem takes any forward dynamics as a `casadi.Function` (q, qd, tau) -> qdd, so the
same transcription runs on gagen's function (`gagen.casadi.functions(dyn)`) and on a peer's
(adam's, gagen.reference.adam):

    minimise    sum_k |tau_k|^2 h
    subject to  x_{k+1} = RK4(x_k, tau_k, h)    (x = (q, qd), k = 0 .. N-1, one RK4 step)
                x_0 = (q_start, 0),  x_N = (q_goal, 0)
                joint limits on q, effort limits on tau (where the model has them)
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

# The Panda's "ready" pose and a swing from it: the shoulder turns 1.2 rad, the elbow opens.
PANDA_START = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
PANDA_GOAL = np.array([1.2, -0.3, 0.3, -1.6, 0.4, 1.9, 0.0])


@dataclass
class SwingResult:
    """The optimum and IPOPT's account of the solve."""

    t: np.ndarray
    q: np.ndarray            # (N + 1, n)
    qd: np.ndarray           # (N + 1, n)
    tau: np.ndarray          # (N, n), piecewise constant
    effort: float            # the objective
    iterations: int
    seconds: float           # IPOPT's solve, wall clock (setup excluded)
    success: bool
    stats: dict = field(default_factory=dict)

    @property
    def seconds_per_iteration(self) -> float:
        return self.seconds / max(self.iterations, 1)


def swing(forward_dynamics, q_start, q_goal, duration: float = 1.0, intervals: int = 40,
          lower=None, upper=None, effort=None, tol: float = 1e-10,
          ipopt: dict | None = None) -> SwingResult:
    """Solve the swing (module docstring) with `forward_dynamics` (q, qd, tau) -> qdd, from
    rest at q_start to rest at q_goal in `duration` seconds over `intervals` intervals.
    `lower`, `upper`: joint limits; `effort`: |tau| limits (None: none). The initial guess
    is the straight line at rest and zero torques. IPOPT runs to `tol`."""
    import casadi as ca

    q_start, q_goal = np.asarray(q_start, float), np.asarray(q_goal, float)
    n = len(q_start)
    h = duration / intervals
    q, qd, tau = ca.MX.sym("q", n), ca.MX.sym("qd", n), ca.MX.sym("tau", n)
    x = ca.vertcat(q, qd)

    def rate(state, u):
        return ca.vertcat(state[n:], forward_dynamics(state[:n], state[n:], u))

    k1 = rate(x, tau)
    k2 = rate(x + h / 2 * k1, tau)
    k3 = rate(x + h / 2 * k2, tau)
    k4 = rate(x + h * k3, tau)
    step = ca.Function("rk4", [x, tau], [x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])

    opti = ca.Opti()
    X = opti.variable(2 * n, intervals + 1)
    U = opti.variable(n, intervals)
    opti.minimize(h * ca.sumsqr(U))
    opti.subject_to(step.map(intervals)(X[:, :-1], U) == X[:, 1:])
    opti.subject_to(X[:, 0] == np.concatenate([q_start, np.zeros(n)]))
    opti.subject_to(X[:, -1] == np.concatenate([q_goal, np.zeros(n)]))
    if lower is not None:
        opti.subject_to(opti.bounded(np.asarray(lower)[:, None], X[:n, :],
                                     np.asarray(upper)[:, None]))
    if effort is not None:
        limit = np.asarray(effort)[:, None]
        opti.subject_to(opti.bounded(-limit, U, limit))
    fractions = np.linspace(0.0, 1.0, intervals + 1)
    opti.set_initial(X[:n, :], q_start[:, None] + np.outer(q_goal - q_start, fractions))
    opti.set_initial(X[n:, :], 0.0)
    opti.set_initial(U, 0.0)
    opti.solver("ipopt", {"print_time": False},
                {"print_level": 0, "tol": tol, "sb": "yes", **(ipopt or {})})
    start = time.perf_counter()
    try:
        solution = opti.solve()
        success = True
    except RuntimeError:
        solution, success = opti.debug, False
    seconds = time.perf_counter() - start
    stats = opti.stats()
    Xv, Uv = np.array(solution.value(X)), np.array(solution.value(U)).reshape(n, intervals)
    return SwingResult(t=np.linspace(0.0, duration, intervals + 1), q=Xv[:n].T, qd=Xv[n:].T,
                       tau=Uv.T, effort=float(solution.value(opti.f)),
                       iterations=int(stats.get("iter_count", 0)), seconds=seconds,
                       success=success and bool(stats.get("success", False)),
                       stats={k: v for k, v in stats.items()
                              if isinstance(v, (int, float, str, bool))})


def joint_limits(dyn) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """(lower, upper, effort) of a model's joints from its description, or None where any
    joint lacks them."""
    joints = dyn.info.joints

    def values(key):
        out = [getattr(joint, key) for joint in joints]
        return None if any(v is None for v in out) else np.array(out, dtype=float)

    return values("lower"), values("upper"), values("effort")
