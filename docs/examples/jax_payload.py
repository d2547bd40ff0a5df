"""The Panda's unknown payload (mass and mass centre) fitted by gradient descent through a
differentiable rollout in JAX, and compared with gagen.identify.

Regenerates docs/figures/jax_payload.png and the numbers of docs/jax.md:

    python docs/examples/jax_payload.py [--out docs/figures]

1. The "real" robot: the Panda of tests/data/urdf/panda.urdf with 1 kg more on its last
   link, off its axis (m, cx, cy, cz of panda_link7 changed). Sixteen runs of 0.6 s under a
   PD law toward random targets, with the nominal model's gravity at the target as
   feed-forward, simulated by gagen's compiled rk4 (h = 2 ms); the "encoders" sample q
   at every step (500 Hz) with noise 1e-4 rad, and the controller's torques are logged.
2. Gradient descent (Adam) on (m, cx, cy, cz) from the URDF's values: the loss is the mean
   squared difference between the measured positions and a rollout of the same PD law
   and the same RK4 steps in JAX (jax.lax.scan), through gagen.jax's forward dynamics
   (the compiled kernels through XLA's FFI, the runs vmapped: one C loop per stage).
   Its gradient is exact: gagen's analytic derivatives by q, q̇, τ, and by the parameters
   through the regressor. Only positions are used: no velocities, accelerations or
   torques to estimate.
3. The same prior through the regressor: gagen's least squares on τ = Y π with every body
   known but panda_link7 (its ten inertial parameters unknown), on q̇ and q̈ estimated by
   gagen.ident's Savitzky-Golay filter and the logged torques; and gagen.identify with
   nothing known (the base parameters, in which the payload's mass alone is not one).
4. On a held-out run: the torques each model predicts against the true ones.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
URDF = REPO / "tests" / "data" / "urdf" / "panda.urdf"
UNKNOWN = ("m_panda_link7", "cx_panda_link7", "cy_panda_link7", "cz_panda_link7")
TRUE = {"m_panda_link7": 1.465522 + 1.0, "cx_panda_link7": 0.03, "cy_panda_link7": -0.02,
        "cz_panda_link7": 0.14}
# the optimiser's variables: the mass and the first moment h = m c (kg, kg m), in which the
# dynamics are nearly linear (the mass alone trades off against the mass centre's height)
SCALE = np.array([1.0, 0.1, 0.1, 0.1])
H = 2e-3
STEPS = 300
RUNS = 16
NOISE = 1e-4  # rad (m for the fingers)
# PD gains: the wrist's and fingers' small inertias want small damping, or the explicit
# RK4 steps of 2 ms go unstable (kd / I h < 2.8)
KP = np.array([60.0] * 4 + [20.0] * 5)
KD = np.array([8.0] * 4 + [2.0] * 3 + [1.0, 1.0])
CENTRE = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8, 0.02, 0.02])
# how far initial states and targets are drawn from CENTRE: the wrist turns the payload
# around (its mass centre's x and y show only as its orientation changes)
SPREAD = np.array([0.6, 0.5, 0.6, 0.5, 1.5, 1.0, 1.5, 0.01, 0.01])
ITERATIONS = 300


def experiments(dyn, rng, runs: int, p: dict):
    """Runs of the real robot: (q0, qd0, target, feed-forward, q samples, torques)."""
    import gagen

    out = []
    t = np.arange(STEPS + 1) * H
    for _ in range(runs):
        q0 = CENTRE + rng.uniform(-1.0, 1.0, dyn.nv) * SPREAD
        target = CENTRE + rng.uniform(-1.0, 1.0, dyn.nv) * SPREAD
        ff = dyn.gravity(target)  # the nominal model's: what the controller knows
        pd = gagen.PD(kp=KP, kd=KD, target=target, feedforward=ff)
        run = gagen.simulate(dyn, (0.0, t[-1]), q0, np.zeros(dyn.nv), controller=pd,
                             method="rk4", h=H, t_eval=t, p=p)
        out.append({"q0": q0, "qd0": np.zeros(dyn.nv), "target": target, "ff": ff,
                    "q": run.q, "qd": run.qd, "tau": run.tau, "t": t})
    return out


def rollout_loss(f):
    """loss(theta, runs): mean squared position error of the JAX rollouts of all runs."""
    import jax
    import jax.numpy as jnp

    fd = f["forward_dynamics"]
    kp, kd = jnp.asarray(KP), jnp.asarray(KD)

    def rollout(theta, q0, qd0, target, ff):
        p = dict(zip(UNKNOWN, theta))  # (m, cx, cy, cz)

        def rates(q, qd):
            tau = ff - kp * (q - target) - kd * qd
            return qd, fd(q, qd, tau, p=p)

        def step(state, _):
            q, qd = state
            k1q, k1v = rates(q, qd)
            k2q, k2v = rates(q + 0.5 * H * k1q, qd + 0.5 * H * k1v)
            k3q, k3v = rates(q + 0.5 * H * k2q, qd + 0.5 * H * k2v)
            k4q, k4v = rates(q + H * k3q, qd + H * k3v)
            q = q + H / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
            qd = qd + H / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
            return (q, qd), q

        _, qs = jax.lax.scan(step, (q0, qd0), None, length=STEPS)
        return qs

    batched = jax.vmap(rollout, in_axes=(None, 0, 0, 0, 0))

    def loss(theta, data):
        qs = batched(theta, data["q0"], data["qd0"], data["target"], data["ff"])
        return jnp.mean((qs - data["q"][:, 1:]) ** 2)

    return batched, loss


def moments(theta):
    """(m, cx, cy, cz) -> (m, m cx, m cy, m cz)."""
    return np.r_[theta[0], theta[0] * np.asarray(theta[1:])]


def adam(loss, theta0, data, iterations: int, rate: float = 0.1, final_rate: float = 0.002):
    """Adam on (m, h) = moments(theta0) + SCALE * u (the loss takes (m, c)), its step
    decaying geometrically from `rate` to `final_rate`; the history of (loss, (m, c)) and
    the seconds of the first (compiling) call."""
    import jax
    import jax.numpy as jnp

    start = jnp.asarray(moments(np.asarray(theta0)))

    def physical(u):
        mh = start + SCALE * u
        return jnp.concatenate([mh[:1], mh[1:] / mh[0]])

    grad_loss = jax.jit(jax.value_and_grad(lambda u, d: loss(physical(u), d)))

    def loss_of_u(u):
        return grad_loss(u, data)

    began = time.perf_counter()
    jax.block_until_ready(loss_of_u(jnp.zeros(4)))
    compile_s = time.perf_counter() - began

    u = jnp.zeros(4)
    m = v = jnp.zeros_like(u)
    history = []
    for k in range(1, iterations + 1):
        value, g = loss_of_u(u)
        history.append((float(value), np.asarray(physical(u))))
        m = 0.9 * m + 0.1 * g
        v = 0.999 * v + 0.001 * g * g
        step = rate * (final_rate / rate) ** ((k - 1) / max(1, iterations - 1))
        u = u - step * (m / (1 - 0.9**k)) / (jnp.sqrt(v / (1 - 0.999**k)) + 1e-12)
    history.append((float(loss_of_u(u)[0]), np.asarray(physical(u))))
    return history, compile_s


def regressor_fit(dyn, runs):
    """Least squares on tau = Y pi with every body known but panda_link7 (its ten
    columns), on Savitzky-Golay estimates of qd and qdd: (m, c) and the parameters."""
    from gagen.ident.data import estimate_derivatives

    parts = [estimate_derivatives(r["t"], r["q"], None, r["tau"]) for r in runs]
    q, qd, qdd, tau = (np.vstack([getattr(m, k) for m in parts])
                       for k in ("q", "qd", "qdd", "tau"))
    Y = dyn.regressor(q, qd, qdd)
    names = dyn.regressor_names
    unknown = [k for k, name in enumerate(names) if name.endswith("_panda_link7")
               and not name.startswith(("damping", "friction", "armature"))]
    known = [k for k in range(len(names)) if k not in unknown]
    pi = dyn.regressor_parameters()
    rhs = (tau - Y[:, :, known] @ pi[known]).ravel()
    A = Y[:, :, unknown].reshape(-1, len(unknown))
    solution, *_ = np.linalg.lstsq(A, rhs, rcond=None)
    pi = pi.copy()
    pi[unknown] = solution
    mass = solution[0]
    return mass, solution[1:4] / mass, pi, (q, qd, qdd, tau)


def figure(path: Path, history, truth, regressor, nominal, fitted, measured) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    losses = np.array([h[0] for h in history])
    thetas = np.array([h[1] for h in history])
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    ax = axes[0]
    ax.semilogy(losses, color="tab:blue")
    ax.axhline(NOISE**2, color="0.5", ls=":", label="noise variance")
    ax.set_xlabel("iteration")
    ax.set_ylabel("mean squared position error [rad²]")
    ax.set_title("gradient descent through the rollout")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax = axes[1]
    labels = ["m [kg]", "cx [m]", "cy [m]", "cz [m]"]
    colors = ["tab:blue", "tab:orange", "tab:green", "tab:red"]
    scale = np.array([1.0, 10.0, 10.0, 10.0])
    for k in range(4):
        ax.plot(thetas[:, k] * scale[k], color=colors[k],
                label=labels[k] + (" x10" if k else ""))
        ax.axhline(truth[k] * scale[k], color=colors[k], ls=":", lw=1)
        ax.plot([len(thetas) - 1], [regressor[k] * scale[k]], marker="x", color=colors[k],
                ms=9)
    ax.set_xlabel("iteration")
    ax.set_title("estimates (dotted: truth; x: regressor least squares)")
    ax.legend(fontsize=8, ncol=2)
    ax.grid(alpha=0.3)
    ax = axes[2]
    t = np.arange(STEPS + 1) * H
    for j, color in ((1, "tab:blue"), (3, "tab:red")):
        ax.plot(t, measured[:, j], color="0.6", lw=2.5)
        ax.plot(t[1:], nominal[:, j], color=color, ls="--", lw=1)
        ax.plot(t[1:], fitted[:, j], color=color, lw=1)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("q [rad]")
    ax.set_title("joints 2 and 4, one run: measured (grey),\nnominal model (dashed), "
                 "fitted (solid)")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main(argv=None) -> int:
    args = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    args.add_argument("--out", default=str(REPO / "docs" / "figures"))
    args.add_argument("--iterations", type=int, default=ITERATIONS)
    options = args.parse_args(argv)
    out = Path(options.out)
    out.mkdir(parents=True, exist_ok=True)
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    import gagen
    import gagen.jax

    rng = np.random.default_rng(29)
    dyn = gagen.load(URDF)
    start = time.perf_counter()
    runs = experiments(dyn, rng, RUNS + 1, TRUE)
    held_out, runs = runs[-1], runs[:-1]
    for r in runs:
        r["q"] = r["q"] + rng.normal(scale=NOISE, size=r["q"].shape)
    print(f"simulated {RUNS} + 1 runs of {STEPS} rk4 steps in "
          f"{time.perf_counter() - start:.2f} s")
    f = gagen.jax.functions(dyn)
    batched, loss = rollout_loss(f)
    data = {k: jnp.asarray(np.stack([r[k] for r in runs])) for k in ("q0", "qd0", "target",
                                                                       "ff", "q")}
    truth = np.array([TRUE[k] for k in UNKNOWN])
    nominal = np.array([dyn.parameters[k] for k in UNKNOWN])
    # the JAX rollout is gagen's rk4: at the true parameters, the same states
    exact = np.asarray(batched(jnp.asarray(truth), *(data[k] for k in ("q0", "qd0", "target",
                                                                          "ff"))))
    clean = np.stack([r["q"] for r in experiments(dyn, np.random.default_rng(29), RUNS + 1,
                                                  TRUE)[:RUNS]])
    print(f"JAX rollout at the true parameters against gagen.simulate's rk4: largest "
          f"difference {np.abs(exact - clean[:, 1:]).max():.1e} rad")
    start = time.perf_counter()
    history, compile_s = adam(loss, nominal, data, options.iterations)
    seconds = time.perf_counter() - start - compile_s
    fitted = history[-1][1]
    print(f"gradient descent: {options.iterations} iterations in {seconds:.1f} s "
          f"({seconds / options.iterations * 1e3:.0f} ms per loss and gradient over "
          f"{RUNS} x {STEPS} RK4 steps; first call with JIT {compile_s:.1f} s); loss "
          f"{history[0][0]:.3g} -> {history[-1][0]:.3g} rad²")
    start = time.perf_counter()
    mass, centre, pi_fit, samples = regressor_fit(dyn, runs)
    regressor_s = time.perf_counter() - start
    regressor = np.r_[mass, centre]
    result = gagen.identify(dyn, *samples)
    for label, values in (("truth", truth), ("URDF (start)", nominal),
                          ("gradient descent, rollout", fitted),
                          (f"regressor least squares ({regressor_s:.2f} s)", regressor)):
        error = "" if values is truth else (
            f"; off by {abs(values[0] - truth[0]) * 1e3:.2g} g, "
            f"{np.linalg.norm(values[1:] - truth[1:]) * 1e3:.2g} mm")
        print(f"  {label:<38} m = {values[0]:.4f} kg, c = ({values[1]:+.4f}, "
              f"{values[2]:+.4f}, {values[3]:+.4f}) m{error}")
    # held out: the torques each model predicts along the true motion
    q, qd = held_out["q"], held_out["qd"]
    qdd = dyn.forward_dynamics(q, qd, held_out["tau"], p=TRUE)
    true_tau = held_out["tau"]
    predictions = {
        "nominal URDF": dyn.inverse_dynamics(q, qd, qdd),
        "gradient descent (rollout)": dyn.inverse_dynamics(q, qd, qdd,
                                                           p=dict(zip(UNKNOWN, fitted))),
        "regressor least squares": dyn.regressor(q, qd, qdd) @ pi_fit,
        "gagen.identify (base parameters)": result.predict(q, qd, qdd),
    }
    print("held-out run, RMS torque error against the true torques [N m], joints 1-7:")
    for label, tau in predictions.items():
        rms = np.sqrt(np.mean((tau - true_tau) ** 2, axis=0))[:7]
        print(f"  {label:<34} " + " ".join(f"{x:.3g}" for x in rms))
    nominal_run = np.asarray(batched(jnp.asarray(nominal), *(data[k][:1] for k in (
        "q0", "qd0", "target", "ff"))))[0]
    fitted_run = np.asarray(batched(jnp.asarray(fitted), *(data[k][:1] for k in (
        "q0", "qd0", "target", "ff"))))[0]
    figure(out / "jax_payload.png", history, truth, regressor, nominal_run, fitted_run,
           np.asarray(data["q"][0]))
    print(f"wrote {out / 'jax_payload.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
