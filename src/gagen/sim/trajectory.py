"""Reference trajectories; `Eq11Trajectory` is the paper's desired motion (DESIGN.md eq. 11)."""

from __future__ import annotations

import math

import numpy as np

# The paper's inverse-dynamics target (DESIGN.md section 1, Fig. 4): q1f, q2f, q3f in rad.
PAPER_QF = (-math.pi / 3, -math.pi / 3, -math.pi / 6)
PAPER_TP = 5.0


class Eq11Trajectory:
    """Rest-to-rest motion of the paper's eq. 11, for any number of coordinates.

        q(t) = q0 + (qf - q0) / Tp * (t - Tp / (2 pi) * sin(2 pi t / Tp)),   0 <= t <= Tp

    The velocity (qf - q0)/Tp * (1 - cos(2 pi t/Tp)) and the acceleration vanish at both
    ends. Before t = 0 the trajectory rests at q0, after Tp at qf (zero rates), exactly as
    the C integrator's computed-torque controller evaluates it (`gagen_eq11`).

    Calling it with a time gives `(q, qd, qdd)`, each of shape (n,); with an array of m
    times, each of shape (m, n). The object holds no state between calls, so one
    trajectory can serve any number of controllers and simulations.
    """

    def __init__(self, q0, qf, Tp: float = PAPER_TP):
        q0 = np.array(q0, dtype=float).ravel()
        qf = np.array(qf, dtype=float).ravel()
        if q0.size == 1 and qf.size > 1:
            q0 = np.full(qf.size, q0[0])
        if q0.shape != qf.shape:
            raise ValueError(f"q0 and qf must have the same length, got {q0.size} and {qf.size}")
        if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(qf))):
            raise ValueError("q0 and qf must be finite")
        Tp = float(Tp)
        if not (math.isfinite(Tp) and Tp > 0):
            raise ValueError(f"Tp must be a positive duration, got {Tp}")
        q0.flags.writeable = False
        qf.flags.writeable = False
        self.q0, self.qf, self.Tp = q0, qf, Tp

    @classmethod
    def paper(cls, Tp: float = PAPER_TP) -> Eq11Trajectory:
        """The paper's Fig. 4 motion of rrr: from q = 0 to (-pi/3, -pi/3, -pi/6) in Tp s."""
        return cls(np.zeros(3), PAPER_QF, Tp)

    @property
    def n(self) -> int:
        return self.q0.size

    def __call__(self, t):
        """(q, qd, qdd) at a time (each (n,)) or at an array of m times (each (m, n))."""
        tt = np.asarray(t, dtype=float)
        if tt.ndim > 1:
            raise ValueError(f"t must be a number or a 1-D array of times, got shape {tt.shape}")
        scalar = tt.ndim == 0
        tt = np.atleast_1d(tt)[:, None]
        w = 2.0 * math.pi / self.Tp
        slope = (self.qf - self.q0) / self.Tp
        inside = (tt >= 0.0) & (tt <= self.Tp)
        q = np.where(inside, self.q0 + slope * (tt - np.sin(w * tt) / w),
                     np.where(tt < 0.0, self.q0, self.qf))
        # (+ 0.0 turns the -0.0 of a falling coordinate at rest into 0.0)
        qd = np.where(inside, slope * (1.0 - np.cos(w * tt)), 0.0) + 0.0
        qdd = np.where(inside, slope * w * np.sin(w * tt), 0.0) + 0.0
        if scalar:
            return q[0], qd[0], qdd[0]
        return q, qd, qdd

    def __repr__(self) -> str:
        return (f"Eq11Trajectory(q0={self.q0.tolist()}, qf={self.qf.tolist()}, "
                f"Tp={self.Tp:g})")
