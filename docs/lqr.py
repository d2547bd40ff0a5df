"""LQR on the paper's robot, designed on gagen's linearisation (the example of docs/lqr.md).

The arm is held at an inverted equilibrium q* (links 2 and 3 above the shoulder), where
the constant torque tau* = gravity(q*) balances it but any disturbance makes it fall. An
LQR gain designed on (A, B) = dyn.linearize(q*, 0, tau*) with
scipy.linalg.solve_continuous_are brings the nonlinear arm back from a perturbed start.

    python docs/lqr.py                      # prints the design, writes docs/figures/lqr.png
    python docs/lqr.py --out lqr.png

tests/test_lqr.py runs the same functions (design_lqr, simulate_from) without the figure.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.linalg import solve_continuous_are

import gagen

EQUILIBRIUM = np.array([0.5, 1.9, -0.6])         # rad: q*, links 2 and 3 above the shoulder
PERTURBATION = np.array([0.15, -0.2, 0.25])       # rad: the start is q* + this, at rest
Q_WEIGHTS = np.array([1e3, 1e3, 1e3, 10.0, 10.0, 10.0])   # on (q - q*, qd)
R_WEIGHTS = np.array([1e-3, 1e-3, 1e-3])                  # on tau - tau*
FIGURE = Path(__file__).parent / "figures" / "lqr.png"


@dataclass
class LqrDesign:
    """The equilibrium, its linearisation and the LQR gain tau = tau* - K (x - x*)."""

    q_eq: np.ndarray
    tau_eq: np.ndarray
    A: np.ndarray
    B: np.ndarray
    K: np.ndarray

    def controller(self):
        """The LQR law as a gagen.simulate controller (t, q, qd) -> tau."""
        def lqr(t, q, qd):
            return self.tau_eq - self.K @ np.concatenate([q - self.q_eq, qd])
        return lqr

    def hold(self):
        """The open loop: the constant torque that balances the arm at q*."""
        return lambda t, q, qd: self.tau_eq.copy()


def design_lqr(dyn, q_eq=EQUILIBRIUM, Q=None, R=None) -> LqrDesign:
    """Linearise dyn at (q*, 0, gravity(q*)) and solve the continuous algebraic Riccati
    equation: K = R^-1 B^T P minimises the integral of x^T Q x + u^T R u."""
    n = dyn.n
    Q = np.diag(Q_WEIGHTS) if Q is None else Q
    R = np.diag(R_WEIGHTS) if R is None else R
    q_eq = np.asarray(q_eq, dtype=float)
    tau_eq = dyn.gravity(q_eq)
    A, B = dyn.linearize(q_eq, np.zeros(n), tau_eq)
    P = solve_continuous_are(A, B, Q, R)
    return LqrDesign(q_eq, tau_eq, A, B, K=np.linalg.solve(R, B.T @ P))


def simulate_from(dyn, design: LqrDesign, controller, duration: float,
                  perturbation=PERTURBATION):
    """The nonlinear arm from q* + perturbation at rest, under `controller`."""
    q0 = design.q_eq + np.asarray(perturbation, dtype=float)
    return gagen.simulate(dyn, (0.0, duration), q0, np.zeros(dyn.n), controller=controller,
                          method="RK45", rtol=1e-8, atol=1e-10)


def figure(design: LqrDesign, closed, open_loop, path: Path) -> Path:
    """Joint errors under LQR and in open loop, and the LQR's torques."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 4), layout="constrained")
    FigureCanvasAgg(fig)
    ax, bx = fig.subplots(1, 2)
    colours = ("C0", "C1", "C2")
    for k, c in enumerate(colours):
        ax.plot(closed.t, np.degrees(closed.q[:, k] - design.q_eq[k]), c,
                label=f"q{k + 1} − q{k + 1}*")
        ax.plot(open_loop.t, np.degrees(open_loop.q[:, k] - design.q_eq[k]), c, ls="--", lw=1)
        bx.plot(closed.t, closed.tau[:, k] - design.tau_eq[k], c, label=f"τ{k + 1} − τ{k + 1}*")
    ax.set_ylim(-60, 60)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("deviation from q* (deg)")
    ax.set_title("rrr from a perturbed start: LQR (solid), open loop (dashed)")
    ax.plot([], [], "k--", lw=1, label="open loop, τ = τ*")
    ax.legend(fontsize=8, loc="lower right")
    bx.set_xlabel("t (s)")
    bx.set_ylabel("LQR torque − τ* (N m)")
    bx.set_title("LQR torques")
    bx.legend(fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=FIGURE, help="the figure (PNG)")
    args = parser.parse_args(argv)
    dyn = gagen.load("rrr", derivatives=True)
    design = design_lqr(dyn)
    np.set_printoptions(precision=3, suppress=True)
    print("q* =", design.q_eq, "rad;  tau* = gravity(q*) =", design.tau_eq, "N m")
    print("open-loop eigenvalues of A:", np.linalg.eigvals(design.A))
    print("closed-loop eigenvalues of A - B K:", np.linalg.eigvals(design.A - design.B @ design.K))
    closed = simulate_from(dyn, design, design.controller(), 2.0)
    open_loop = simulate_from(dyn, design, design.hold(), 1.0)
    error = np.concatenate([closed.q[-1] - design.q_eq, closed.qd[-1]])
    print(f"LQR: |x(2 s) - x*| = {np.abs(error).max():.1e}; open loop: |q(1 s) - q*| = "
          f"{np.abs(open_loop.q[-1] - design.q_eq).max():.2f} rad")
    print("figure:", figure(design, closed, open_loop, args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
