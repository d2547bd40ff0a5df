"""A planar four-bar linkage driven at its crank: the loop's closure error over time (the
example of docs/constraints.md).

The linkage is tests/data/constraints/fourbar.yaml: three bodies on three hinges in a
chain that is open as a tree, closed by a loop constraint (the coupler's tip held to the
rocker's on the plane's two axes). A velocity servo on the crank alone (the other two
joints are passive) drives it at OMEGA rad/s from rest; gagen.simulate integrates the
constrained dynamics in C and reports the closure error at every sample. Three runs:
dopri5 and rk4 with Baumgarte's correction (gagen's default, kp 400, kd 40), and dopri5
without it, where the error that the integration leaves grows unchecked.

    python docs/constraints_fourbar.py     # prints the largest errors, writes the figure
    python docs/constraints_fourbar.py --out fourbar.png

tests/test_constraints.py runs `run_fourbar` and checks the errors printed here.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import gagen

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "tests" / "data" / "constraints" / "fourbar.yaml"
FIGURE = Path(__file__).parent / "figures" / "constraints_fourbar.png"
LENGTHS = (0.3, 1.0, 0.8, 1.0)  # crank, coupler, rocker, ground (the model file's)
OMEGA = 2 * np.pi                # rad/s: one turn of the crank per second
SERVO = 5.0                      # N m s/rad: the crank's velocity gain
DURATION = 5.0
RUNS = {  # label: simulate's options
    "dopri5 (rtol 1e-8), Baumgarte": {"method": "dopri5", "rtol": 1e-8, "atol": 1e-10},
    "rk4 (h = 1 ms), Baumgarte": {"method": "rk4", "h": 1e-3},
    "dopri5 (rtol 1e-8), no Baumgarte": {"method": "dopri5", "rtol": 1e-8, "atol": 1e-10,
                                          "baumgarte": (0.0, 0.0)},
}


def closed(crank: float) -> np.ndarray:
    """q with the loop closed at a crank angle (the coupler's tip on the rocker's: the
    intersection of two circles, the elbow up)."""
    a, b, c, d = LENGTHS
    B, D = np.array([a * np.cos(crank), a * np.sin(crank)]), np.array([d, 0.0])
    L = np.linalg.norm(D - B)
    ex = (D - B) / L
    x = (b * b - c * c + L * L) / (2 * L)
    C = B + x * ex + np.sqrt(b * b - x * x) * np.array([-ex[1], ex[0]])
    coupler, rocker = np.arctan2(*(C - B)[::-1]), np.arctan2(*(C - D)[::-1])
    return np.array([crank, coupler - crank, rocker])


def crank_servo():
    """Torque on the crank alone, SERVO (OMEGA - its speed), as a gagen.PD (which the C
    integrators run without calling back into Python)."""
    return gagen.PD(kp=0.0, kd=[SERVO, 0.0, 0.0], feedforward=[SERVO * OMEGA, 0.0, 0.0])


def run_fourbar(dyn, duration: float = DURATION, samples: int = 1001) -> dict:
    """{label: SimulationResult} of the runs in RUNS, from the loop closed at rest."""
    q0 = closed(0.0)
    t_eval = np.linspace(0.0, duration, samples)
    return {label: gagen.simulate(dyn, (0.0, duration), q0, controller=crank_servo(),
                                  constraints=True, t_eval=t_eval, **options)
            for label, options in RUNS.items()}


def plot(runs: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (angles, error) = plt.subplots(2, 1, figsize=(7.5, 6.0), sharex=True)
    first = next(iter(runs.values()))
    for k, name in enumerate(("crank", "coupler", "rocker")):
        angles.plot(first.t, first.q[:, k], label=name)
    angles.set_ylabel("joint angle (rad)")
    angles.legend(fontsize=8)
    angles.set_title(f"Four-bar driven at its crank ({OMEGA:.3g} rad/s servo), "
                     "the loop closed by a constraint")
    for label, res in runs.items():
        error.semilogy(res.t, np.maximum(res.constraint_violation, 1e-17), label=label)
    error.set_ylabel("closure error (m)")
    error.set_xlabel("t (s)")
    error.legend(fontsize=8)
    for ax in (angles, error):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=FIGURE, help="the figure's file")
    args = parser.parse_args(argv)
    dyn = gagen.load(MODEL)
    runs = run_fourbar(dyn)
    for label, res in runs.items():
        turns = (res.q[-1, 0] - res.q[0, 0]) / (2 * np.pi)
        print(f"{label}: largest closure error {res.stats['constraint_violation']:.2e} m, "
              f"at the end {res.constraint_violation[-1]:.2e} m; the crank turned "
              f"{turns:.2f} times")
    plot(runs, args.out)
    print(f"figure: {args.out}")


if __name__ == "__main__":
    main()
