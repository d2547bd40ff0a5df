"""The Panda's tool follows a circle under an operational-space law (docs/taskspace.md).

The tool centre (frame `panda_hand_tcp`) tracks a vertical circle, 10 cm in radius, once
every 2 s, starting at rest 3 cm below the circle's centre. The law works in task space with
gagen's compiled task-space quantities: the tool's Jacobian J (its origin's velocity,
world axes), its bias acceleration J̇ q̇, and the operational-space inertia
Λ = (J M⁻¹ Jᵀ)⁻¹, per control step:

    a = ẍ_d + K_d (ẋ_d - ẋ) + K_p (x_d - x)           the task's acceleration
    τ = Jᵀ Λ (a - J̇ q̇) + Nᵀ τ₀ + h(q, q̇)                 N = I - M⁻¹ Jᵀ Λ J

with h = inverse_dynamics(q, q̇, 0) (Coriolis, gravity, joint damping) and τ₀ a joint PD
toward the start posture that acts in the task's null space only. Then ẍ = a exactly, so
the error obeys ë + K_d ė + K_p e = 0. Run again without J̇ q̇ (the drift of the task
left out), the tool lags the circle by millimetres.

    python examples/taskspace_circle.py              # writes docs/figures/taskspace_circle.png
    python examples/taskspace_circle.py --out circle.png --urdf path/to/panda.urdf

tests/test_taskspace.py runs `track` on a short horizon.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import gagen

REPO = Path(__file__).resolve().parents[1]
URDF = REPO / "tests" / "data" / "urdf" / "panda.urdf"
FIGURE = REPO / "docs" / "figures" / "taskspace_circle.png"
TOOL = "panda_hand_tcp"
START = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785, 0.02, 0.02])  # "ready"
RADIUS, PERIOD, GROWTH = 0.10, 2.0, 0.3  # m, s, s
OFFSET = np.array([0.0, 0.0, 0.03])  # m: the circle's centre from the tool's start
KP, KD = 400.0, 40.0  # task gains: 20 rad/s, critically damped
KP_NULL, KD_NULL = 20.0, 5.0  # the posture's, in the null space


@dataclass
class Circle:
    """x_d(t) on a circle in the world's y-z plane about `centre`, spiralling out from it:
    the radius grows as RADIUS (1 - exp(-t / GROWTH)), smooth for every t > 0."""

    centre: np.ndarray

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x_d, ẋ_d, ẍ_d) at time t."""
        w = 2 * np.pi / PERIOD
        fade = np.exp(-t / GROWTH)
        r, dr, ddr = RADIUS * (1 - fade), RADIUS * fade / GROWTH, -RADIUS * fade / GROWTH**2
        c, si = np.cos(w * t), np.sin(w * t)
        u = np.array([0.0, c, si])
        du, ddu = w * np.array([0.0, -si, c]), -w * w * u
        return (self.centre + r * u, dr * u + r * du, ddr * u + 2 * dr * du + r * ddu)


def operational_space_law(dyn, circle: Circle, drift: bool = True):
    """τ(t, q, q̇) of the module docstring; drift=False leaves J̇ q̇ out."""
    zero = np.zeros(dyn.nv)

    def law(t, q, qd):
        x_d, v_d, a_d = circle(t)
        _, x = dyn.frame_placement(q, TOOL)
        J = dyn.frame_jacobian(q, TOOL)[:3]  # the tool origin's velocity, world axes
        a = a_d + KD * (v_d - J @ qd) + KP * (x_d - x)
        if drift:
            a = a - dyn.frame_bias_acceleration(q, qd, TOOL)[:3]  # J̇ q̇, classical
        Lam = dyn.operational_space_inertia(q, TOOL, dims=3)
        M = dyn.mass_matrix(q)
        J_bar = np.linalg.solve(M, J.T) @ Lam  # the dynamically consistent inverse
        posture = -KP_NULL * (q - START) - KD_NULL * qd
        null = posture - J.T @ (J_bar.T @ posture)  # Nᵀ τ₀ = τ₀ - Jᵀ J̄ᵀ τ₀
        return J.T @ (Lam @ a) + null + dyn.inverse_dynamics(q, qd, zero)

    return law


@dataclass
class Tracking:
    """A run: times, the tool's path and the circle's, and the tracking error."""

    t: np.ndarray
    x: np.ndarray
    x_d: np.ndarray
    tau: np.ndarray

    @property
    def error(self) -> np.ndarray:
        return np.linalg.norm(self.x - self.x_d, axis=1)


def track(dyn, duration: float = 3 * PERIOD, drift: bool = True, samples: int = 601
          ) -> Tracking:
    """Simulate the Panda from rest at START under the law (SciPy's RK45, tight tolerances)."""
    circle = Circle(dyn.frame_placement(START, TOOL)[1] + OFFSET)
    res = gagen.simulate(dyn, (0.0, duration), START, np.zeros(dyn.nv),
                         controller=operational_space_law(dyn, circle, drift),
                         rtol=1e-9, atol=1e-11, t_eval=np.linspace(0, duration, samples))
    x = dyn.frame_placement(res.q, TOOL)[1]
    x_d = np.array([circle(t)[0] for t in res.t])
    return Tracking(res.t, x, x_d, res.tau)


def figure(with_drift: Tracking, without: Tracking, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 4))
    FigureCanvasAgg(fig)
    left, right = fig.subplots(1, 2)
    centre = with_drift.x_d[0]
    drift = r"$\dot J \dot q$"
    for run, style, label in ((with_drift, "-", f"with {drift}"),
                              (without, "--", f"without {drift}")):
        left.plot(1e2 * (run.x[:, 1] - centre[1]), 1e2 * (run.x[:, 2] - centre[2]), style,
                  label=f"tool, {label}")
        right.semilogy(run.t, 1e3 * np.maximum(run.error, 1e-15), style, label=label)
    left.plot(1e2 * (with_drift.x_d[:, 1] - centre[1]),
              1e2 * (with_drift.x_d[:, 2] - centre[2]), ":", color="k", label="desired")
    left.set_aspect("equal")
    left.set_xlabel("y − y₀ (cm)")
    left.set_ylabel("z − z₀ (cm)")
    left.set_title("The tool's path in the circle's plane")
    left.legend(loc="lower right", fontsize=8)
    right.set_xlabel("t (s)")
    right.set_ylabel("|x − x_d| (mm)")
    right.set_title("Tracking error")
    right.grid(alpha=0.3, which="both")
    right.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--urdf", type=Path, default=URDF)
    parser.add_argument("--out", type=Path, default=FIGURE)
    args = parser.parse_args()
    dyn = gagen.load(args.urdf)
    runs = [track(dyn, drift=True), track(dyn, drift=False)]
    for run, label in zip(runs, ("with J̇ q̇", "without J̇ q̇")):
        late = run.t >= 2 * PERIOD
        print(f"{label:>14}: error over the last period: max {1e3 * run.error[late].max():.3g} "
              f"mm; torques within {np.abs(run.tau).max():.1f} N m")
    figure(*runs, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
