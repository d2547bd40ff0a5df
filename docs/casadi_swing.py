"""The Panda's minimum-effort swing in casadi.Opti with IPOPT, on gagen's CasADi functions
and on adam's CasADi dynamics (docs/casadi.md): the same optimum, and IPOPT's times.

    python docs/casadi_swing.py [--out docs/figures/casadi_swing.png] [--urdf PANDA.urdf]

Needs casadi and adam-robotics (pip install gagen[casadi] adam-robotics liecasadi).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

import gagen
from gagen.casadi import functions
from gagen.casadi.swing import PANDA_GOAL, PANDA_START, joint_limits, swing
from gagen.reference import adam

REPO = Path(__file__).resolve().parents[1]
FINGERS = ["panda_finger_joint1", "panda_finger_joint2"]


def solve_both(urdf: Path, folder: Path, hessian: str = "exact") -> dict:
    """The swing with gagen's forward dynamics and with adam's: {name: SwingResult}."""
    # adam cannot model the Panda's prismatic fingers, nor joint damping and friction:
    # the same arm for both, with the fingers fixed and no <dynamics>
    arm = adam.fixed_joints_urdf(urdf, FINGERS, folder / "panda_arm.urdf")
    dyn = gagen.load(arm)
    lower, upper, effort = joint_limits(dyn)
    dynamics = {
        "gagen": functions(dyn, ["forward_dynamics"])["forward_dynamics"],
        "adam": adam.forward_dynamics(arm, dyn.coordinates, dyn.parameters["g"]),
    }
    return {name: swing(fd, PANDA_START, PANDA_GOAL, duration=1.0, intervals=40,
                        lower=lower, upper=upper, effort=effort,
                        ipopt={"hessian_approximation": hessian})
            for name, fd in dynamics.items()}


def draw(results: dict, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ours, theirs = results["gagen"], results["adam"]
    fig = Figure(figsize=(10, 4.2))
    FigureCanvasAgg(fig)
    left, right = fig.subplots(1, 2)
    colors = [f"C{k}" for k in range(ours.q.shape[1])]
    for k, color in enumerate(colors):
        left.plot(ours.t, ours.q[:, k], color=color, label=f"joint {k + 1}")
        left.plot(theirs.t, theirs.q[:, k], "o", color=color, markersize=3, mfc="none")
        right.step(ours.t[:-1], ours.tau[:, k], where="post", color=color)
        right.plot(theirs.t[:-1], theirs.tau[:, k], "o", color=color, markersize=3,
                   mfc="none")
    left.set(xlabel="t [s]", ylabel="q [rad]", title="joint angles")
    right.set(xlabel="t [s]", ylabel="tau [N m]", title="torques (piecewise constant)")
    left.legend(fontsize=7, ncol=2)
    fig.suptitle(f"Panda swing, 40 RK4 intervals: lines gagen ({ours.iterations} IPOPT "
                 f"iterations, {ours.seconds:.2f} s), circles adam ({theirs.iterations}, "
                 f"{theirs.seconds:.2f} s)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(REPO / "docs" / "figures" / "casadi_swing.png"))
    parser.add_argument("--urdf", default=str(REPO / "tests" / "data" / "urdf" / "panda.urdf"))
    parser.add_argument("--hessian", choices=("exact", "limited-memory"), default="exact")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        results = solve_both(Path(args.urdf), Path(folder), args.hessian)
    for name, r in results.items():
        print(f"{name:6s} {'converged' if r.success else 'FAILED'}: effort {r.effort:.9f}, "
              f"{r.iterations} iterations, {r.seconds:.3f} s "
              f"({r.seconds_per_iteration * 1e3:.2f} ms per iteration)")
    a, b = results["gagen"], results["adam"]
    print(f"largest difference of the optima: q {np.abs(a.q - b.q).max():.1e} rad, "
          f"tau {np.abs(a.tau - b.tau).max():.1e} N m")
    draw(results, Path(args.out))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
