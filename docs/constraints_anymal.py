"""ANYmal C standing on its four feet under a sideways push (the example of
docs/constraints.md).

The four feet are 3-D point contacts, held where they stand at the start; a PD about the
standing posture, with a feedforward of the torques that hold the robot still (its weight
carried by the feet), drives the legs. The run has three phases, each one gagen.simulate
call (the compiled dopri5, the constrained dynamics with Baumgarte's correction): standing
still, a push of PUSH newtons on the base along y, and the robot after the push. The
contact forces at every sample come with the result; the figure shows each foot's normal
force and the feet's total sideways force against the push.

    python docs/constraints_anymal.py      # prints a summary, writes the figure
    python docs/constraints_anymal.py --out push.png

tests/test_constraints.py runs `run_push` on its own build of ANYmal C.
"""

from __future__ import annotations

import argparse
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import gagen

REPO = Path(__file__).resolve().parents[1]
URDF = REPO / "tests" / "data" / "urdf" / "anymal_c.urdf"
FIGURE = Path(__file__).parent / "figures" / "constraints_anymal_push.png"
FEET = ("LF_FOOT", "RF_FOOT", "LH_FOOT", "RH_FOOT")
PUSH = 80.0                         # N, on the base along world y
PHASES = ((0.0, 0.3, 0.0), (0.3, 0.8, PUSH), (0.8, 1.5, 0.0))  # (t0, t1, push)
POSTURE = {"HAA": 0.0, "HFE": 0.6, "KFE": -1.0}  # front legs; the hind legs mirrored


@dataclass
class PushRun:
    """The three phases joined: times, q, the four feet's forces (N, 4, 3) in world axes,
    the push at each sample, and the largest constraint violation of the run (m)."""

    t: np.ndarray
    q: np.ndarray
    forces: np.ndarray
    push: np.ndarray
    violation: float
    weight: float


def load(urdf: Path = URDF, cache_dir=None):
    """ANYmal C on a floating base with its four feet as 3-D contacts."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        return gagen.load(urdf, floating_base=True, cache_dir=cache_dir,
                          constraints=[gagen.Contact(foot) for foot in FEET])


def standing_posture(dyn) -> np.ndarray:
    """The base 0.5 m up, level; the legs bent as POSTURE."""
    q = dyn.neutral()
    q[2] = 0.5
    for k, name in enumerate(dyn.configuration):
        for joint, angle in POSTURE.items():
            if name.endswith(joint):
                q[k] = angle if name.startswith(("LF", "RF")) else -angle
    return q


def standing_torques(dyn, q, held) -> np.ndarray:
    """The joint torques that hold the robot still at q on its feet: the feet's forces that
    carry its weight with no moment on the base (least norm, from the base's rows of
    J^T lambda = gravity), the joints' torques the rest of the gravity torques."""
    J = dyn.constraint_jacobian(q, held)
    g = dyn.gravity(q)
    forces = np.linalg.lstsq(J[:, :6].T, g[:6], rcond=None)[0]
    tau = g - J.T @ forces
    tau[:6] = 0.0
    return tau


def run_push(dyn, active=None, samples_per_second: int = 200) -> PushRun:
    """Simulate the three phases; `active` names the feet's constraints (None: all of the
    model's, which must then be the four feet's)."""
    feet = list(active) if active is not None else [c.name for c in dyn.constraints]
    held = [c.name in feet for c in dyn.constraints]
    rows = np.concatenate([np.arange(c.rows.start, c.rows.stop) for c in dyn.constraints
                           if c.name in feet])
    q0 = standing_posture(dyn)
    ctrl = gagen.PD(kp=200.0, kd=5.0, target=[0.0] * 6 + list(q0[7:]),
                    feedforward=standing_torques(dyn, q0, held))
    q, qd, p = q0, np.zeros(dyn.nv), None  # the first run anchors the feet; the rest keep p
    parts = []
    for t0, t1, push in PHASES:
        t_eval = np.linspace(t0, t1, round((t1 - t0) * samples_per_second) + 1)
        res = gagen.simulate(dyn, (t0, t1), q, qd, controller=ctrl, method="dopri5",
                             rtol=1e-8, atol=1e-10, constraints=held, p=p, t_eval=t_eval,
                             fext={"base": [0.0, push, 0.0, 0.0, 0.0, 0.0]})
        keep = slice(None) if not parts else slice(1, None)  # each phase starts at the last
        parts.append((res.t[keep], res.q[keep], res.constraint_forces[keep][:, rows],
                      np.full(len(res.t[keep]), push), res.stats["constraint_violation"]))
        q, qd, p = res.q[-1], res.qd[-1], res.p
    t, qs, forces, pushes, violations = zip(*parts)
    mass = sum(value for name, value in zip(dyn.regressor_names, dyn.regressor_parameters())
               if name.startswith("m_"))
    return PushRun(np.concatenate(t), np.concatenate(qs),
                   np.concatenate(forces).reshape(-1, len(feet), 3), np.concatenate(pushes),
                   max(violations), 9.81 * mass)


def plot(run: PushRun, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (normal, side) = plt.subplots(2, 1, figsize=(7.5, 6.0), sharex=True)
    for k, foot in enumerate(FEET):
        normal.plot(run.t, run.forces[:, k, 2], label=foot)
    normal.plot(run.t, run.forces[:, :, 2].sum(axis=1) / 4, "k:", lw=1,
                label="their mean")
    normal.set_ylabel("normal force (N)")
    normal.legend(ncol=5, fontsize=8, loc="lower left")
    normal.set_title(f"ANYmal C on four 3-D contacts, a {PUSH:g} N push on the base "
                     f"({PHASES[1][0]:g} to {PHASES[1][1]:g} s)")
    side.plot(run.t, run.forces[:, :, 1].sum(axis=1), label="feet's total y force")
    side.plot(run.t, -run.push, "k--", lw=1, label="minus the push")
    side.set_ylabel("sideways force (N)")
    side.set_xlabel("t (s)")
    side.legend(fontsize=8)
    for ax in (normal, side):
        ax.axvspan(PHASES[1][0], PHASES[1][1], color="0.92")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--urdf", type=Path, default=URDF, help="ANYmal C's URDF")
    parser.add_argument("--out", type=Path, default=FIGURE, help="the figure's file")
    args = parser.parse_args(argv)
    dyn = load(args.urdf)
    run = run_push(dyn)
    total = run.forces.sum(axis=1)
    print(f"weight {run.weight:.2f} N; the feet's normal forces sum to "
          f"{total[0, 2]:.2f} N standing, {total[:, 2].min():.2f} to {total[:, 2].max():.2f}"
          f" N over the run")
    during = (run.t > PHASES[1][0] + 0.2) & (run.t <= PHASES[1][1])
    print(f"under the push ({PUSH:g} N): the feet's y force {total[during, 1].mean():.2f} N "
          f"on average over its last 0.3 s")
    print(f"largest constraint violation over the run: {run.violation:.2e} m")
    plot(run, args.out)
    print(f"figure: {args.out}")


if __name__ == "__main__":
    main()
