"""The Panda carrying a payload its model does not know: simulate, measure, identify.

Regenerates docs/figures/identification_heldout.png and the numbers of
docs/identification.md:

    python docs/examples/identify_payload.py [--out docs/figures]

1. The "real" robot: the Panda of tests/data/urdf/panda.urdf with 1.5 kg more on its last
   link (hand and payload: mass, mass centre and inertia of panda_link7 changed), and joint
   friction, damping and rotor inertia that the URDF does not have (its damping is 0.003).
2. It tracks exciting trajectories (finite Fourier series) under a computed-torque law that
   uses the nominal URDF model, simulated by gagen.simulate; the "sensors" sample q and the
   joint torques at 500 Hz, with noise.
3. The measurements go through a CSV with t, q and tau only, as a robot would log them;
   gagen.ident.read_measurements estimates qd and qdd with its Savitzky-Golay filter, and
   gagen.identify finds the base parameters (the same as `python -m gagen identify`).
4. On a second, held-out trajectory: the torques the identified model predicts against the
   measured ones, and against the nominal model's.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import gagen
from gagen.ident import FourierTrajectory, identify_consistent, read_measurements

REPO = Path(__file__).resolve().parents[2]
URDF = REPO / "tests" / "data" / "urdf" / "panda.urdf"
RATE = 500.0  # Hz
SECONDS = 40.0
HELD_OUT_SECONDS = 20.0
# the real robot: a payload on the hand, and friction the URDF does not model
PAYLOAD = {"m_panda_link7": 0.73 + 1.5, "cx_panda_link7": 0.01, "cy_panda_link7": -0.02,
           "cz_panda_link7": 0.13, "Ixx_panda_link7": 0.05, "Iyy_panda_link7": 0.045,
           "Izz_panda_link7": 0.02}
JOINT_TERMS = {**{f"damping_panda_joint{k}": d for k, d in zip(range(1, 8),
                                                              (0.4, 0.4, 0.3, 0.3, 0.1, 0.1, 0.1))},
               **{f"friction_panda_joint{k}": f for k, f in zip(range(1, 8),
                                                               (0.8, 0.9, 0.6, 0.7, 0.3, 0.3, 0.2))},
               **{f"armature_panda_joint{k}": a for k, a in zip(range(1, 8),
                                                               (0.2, 0.2, 0.15, 0.15, 0.05, 0.05, 0.05))}}
# the simulation's smooth Coulomb friction tanh(qd / w): sharper than gagen's default
REAL = {**PAYLOAD, **JOINT_TERMS, "coulomb_width": 0.002}
# Coulomb friction explains nothing at rest (any torque within +-friction holds a joint):
# leave out each arm joint's torque while it moves slower than 5 w (the fingers have none)
MIN_SPEED = np.array([0.01] * 7 + [0.0, 0.0])
CENTRE = np.array([0.0, 0.0, 0.0, -1.6, 0.0, 1.8, 0.8, 0.02, 0.02])
AMPLITUDE = np.array([1.2, 0.6, 1.2, 0.6, 1.2, 0.8, 1.2, 0.012, 0.012])
TORQUE_NOISE = np.array([0.2, 0.2, 0.2, 0.2, 0.05, 0.05, 0.05, 0.01, 0.01])  # N m, N
ANGLE_NOISE = 1e-5  # rad, m: encoder resolution


def experiment(dyn, trajectory, seconds: float, rng) -> dict:
    """The real robot tracking `trajectory` under computed torque with the nominal model;
    noisy samples of q and tau at RATE, and the exact torques."""
    kp, kd = 400.0, 40.0

    def controller(t, q, qd):
        qr, qdr, qddr = (x[0] for x in trajectory([t]))
        return dyn.inverse_dynamics(q, qd, qddr + kd * (qdr - qd) + kp * (qr - q))

    q0, qd0, _ = (x[0] for x in trajectory([0.0]))
    t = np.arange(0.0, seconds, 1.0 / RATE)
    run = gagen.simulate(dyn, (0.0, seconds), q0, qd0, controller=controller, method="RK45",
                         rtol=1e-8, atol=1e-9, t_eval=t, p=REAL)
    return {"t": t, "q": run.q + rng.normal(scale=ANGLE_NOISE, size=run.q.shape),
            "tau": run.tau + rng.normal(size=run.tau.shape) * TORQUE_NOISE,
            "tau_exact": run.tau, "q_exact": run.q, "qd_exact": run.qd,
            "nfev": run.stats["nfev"]}


def write_log(path: Path, data: dict, names: list[str]) -> Path:
    """t, q and tau only: what a robot logs (SimulationResult.to_csv's column names)."""
    header = ["t", *names, *(f"tau_{c}" for c in names)]
    rows = np.column_stack([data["t"], data["q"], data["tau"]])
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(repr(float(v)) for v in r)
                                                         for r in rows) + "\n")
    return path


def rms(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(x**2, axis=0))


def figure(path: Path, t, measured, identified, nominal, names) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(7, 1, figsize=(9, 13), sharex=True)
    window = t < t[0] + 10.0
    for k, ax in enumerate(axes):
        ax.plot(t[window], measured[window, k], color="0.6", lw=2.2, label="measured")
        ax.plot(t[window], nominal[window, k], color="tab:red", lw=1.0, ls="--",
                label="nominal URDF model")
        ax.plot(t[window], identified[window, k], color="tab:blue", lw=1.0,
                label="identified model")
        ax.set_ylabel(f"{names[k].replace('panda_', '')}\n[N m]")
        ax.grid(alpha=0.3)
        ax.text(0.01, 0.04, f"RMS error: identified {rms(identified - measured)[k]:.3g}, "
                f"nominal {rms(nominal - measured)[k]:.3g}", transform=ax.transAxes,
                fontsize=8, color="0.2")
    axes[0].legend(loc="upper right", ncol=3, fontsize=8)
    axes[0].set_title("Panda with an unknown 1.5 kg payload: held-out torques")
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main(argv=None) -> int:
    args = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    args.add_argument("--out", default=str(REPO / "docs" / "figures"))
    out = Path(args.parse_args(argv).out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(2024)
    dyn = gagen.load(URDF)
    names = dyn.coordinates
    log = []

    def say(text: str) -> None:
        print(text)
        log.append(text)

    start = time.perf_counter()
    train = experiment(dyn, FourierTrajectory.random(dyn.n, rng, AMPLITUDE, CENTRE, 5, 0.2),
                       SECONDS, rng)
    test = experiment(dyn, FourierTrajectory.random(dyn.n, rng, AMPLITUDE, CENTRE, 5, 0.25),
                      HELD_OUT_SECONDS, rng)
    say(f"simulated {SECONDS:g} s + {HELD_OUT_SECONDS:g} s of tracking in "
        f"{time.perf_counter() - start:.1f} s ({train['nfev'] + test['nfev']} evaluations)")
    csv = write_log(out / "panda_payload_log.csv", train, names)
    data = read_measurements(csv, names)
    csv.unlink()
    # the filter correlates neighbouring samples; every 12th (half its window) keeps the
    # residuals about independent, which the standard deviations assume
    step = 12
    q, qd, qdd, tau = (x[::step] for x in (data.q, data.qd, data.qdd, data.tau))
    say(f"{len(data.t)} samples, every {step}th used; estimated {data.estimated}")
    start = time.perf_counter()
    result = gagen.identify(dyn, q, qd, qdd, tau, weights=1 / TORQUE_NOISE**2,
                            min_speed=MIN_SPEED)
    say(f"identified {len(result.names)} base parameters of {len(dyn.regressor_names)} in "
        f"{time.perf_counter() - start:.2f} s; sigma {result.sigma:.3f}, condition number "
        f"{result.condition:.0f}")
    truth = dyn.base_parameters(REAL)
    z = np.abs(result.values - truth) / result.std
    say(f"estimates within 1 / 2 / 3 standard deviations of the truth: "
        f"{np.mean(z < 1):.0%} / {np.mean(z < 2):.0%} / {np.mean(z < 3):.0%}")
    start = time.perf_counter()
    consistent = identify_consistent(dyn, q, qd, qdd, tau, weights=1 / TORQUE_NOISE**2,
                                     min_speed=MIN_SPEED)
    identified_p = consistent.as_parameters()
    say(f"physically consistent identification in {time.perf_counter() - start:.1f} s: "
        f"m_panda_link7 = {identified_p['m_panda_link7']:.3f} kg (true "
        f"{REAL['m_panda_link7']:.3f}, URDF {dyn.parameters['m_panda_link7']:.3f})")

    held = read_measurements(write_log(out / "held_out.csv", test, names), names)
    (out / "held_out.csv").unlink()
    keep = np.searchsorted(test["t"], held.t)
    exact = test["tau_exact"][keep]
    identified = result.predict(held.q, held.qd, held.qdd)
    nominal = dyn.inverse_dynamics(held.q, held.qd, held.qdd)
    as_simulated = dyn.inverse_dynamics(held.q, held.qd, held.qdd, identified_p)
    moving = np.abs(held.qd) >= MIN_SPEED
    table = [("| joint | noise σ | nominal model | identified (base parameters) | identified "
              "(consistent, as parameters) | identified, moving |"), "|---|--:|--:|--:|--:|--:|"]
    for k, name in enumerate(names):
        error = identified[:, k] - exact[:, k]
        table.append(f"| {name} | {TORQUE_NOISE[k]:.3g} | {rms(nominal - exact)[k]:.3g} "
                     f"| {rms(identified - exact)[k]:.3g} | {rms(as_simulated - exact)[k]:.3g} "
                     f"| {rms(error[moving[:, k]]):.3g} |")
    say("held-out RMS torque error against the true (noise-free) torques, N m (N for the "
        "fingers):\n" + "\n".join(table))
    figure(out / "identification_heldout.png", held.t, held.tau, identified, nominal, names)
    say(f"wrote {out / 'identification_heldout.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
