"""The paper's results from the command line: `python -m gagen simulate` and `... inverse`.

simulate  direct dynamics (the paper's Fig. 2 and Fig. 3): the arm starts at rest at q = 0
          and a feedback law drives it for --duration seconds. rrr: `paper_controller()`
          (PD toward (-60, -60, -30) deg with gravity compensation, kp = (500, 300, 200),
          kd = (300, 150, 100)). Other models: `default_controller` (PD toward -30 deg per
          revolute joint / 0.05 m per prismatic joint, clipped into the joint limits, with
          gravity compensation and gains from the mass matrix along the way).
          Writes simulate.csv (t, q, qd, tau), fig2_positions.png, fig3_arm.png and, with
          --gif, arm.gif.
inverse   inverse dynamics along eq. 11 (the paper's Fig. 4) from q = 0 to qf in
          Tp = --duration seconds. rrr: qf = (-60, -60, -30) deg; other models: the same
          default target as `simulate`. Writes inverse.csv (t, q, qd, qdd, tau) and
          fig4_inverse.png, and prints the peak torques.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from pathlib import Path

import numpy as np

from .cli import add_cache_dir_argument, add_model_argument

SCIPY_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")
COMPILED_METHODS = ("dopri5", "rk4")


def _say(text: str) -> None:
    print(f"gagen: {text}", flush=True)


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got '{text}'")
    return value


def _positive(text: str) -> float:
    value = _finite(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got '{text}'")
    return value


def _nonnegative(text: str) -> float:
    value = _finite(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got '{text}'")
    return value


def _sample_count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if not 2 <= value <= 10_000_000:
        raise argparse.ArgumentTypeError(f"expected 2 to 10,000,000 samples, got {value}")
    return value


def _floats(text: str, name: str) -> np.ndarray:
    try:
        return np.array([_finite(v) for v in text.replace(" ", "").split(",") if v],
                        dtype=float)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"{name}: expected comma-separated finite numbers, "
                                         f"got '{text}'") from None


def _degrees_to_model(values_deg: np.ndarray, model) -> np.ndarray:
    """Convert user values (degrees for rotating joints, metres for prismatic) to SI."""
    out = np.array(values_deg, dtype=float)
    if out.size == 1:
        out = np.full(model.dof, out[0])
    if out.size != model.dof:
        raise ValueError(f"expected {model.dof} values (one per coordinate: "
                         f"{', '.join(model.coordinates)}), got {out.size}")
    for k, body in enumerate(model.moving_bodies):
        if body.joint.type != "prismatic":
            out[k] = math.radians(out[k])
    return out


def _shown(values: np.ndarray, model) -> str:
    parts = []
    for name, body, v in zip(model.coordinates, model.moving_bodies, values):
        if body.joint.type == "prismatic":
            parts.append(f"{name} = {v:.4f} m")
        else:
            parts.append(f"{name} = {math.degrees(v):.3f} deg")
    return ", ".join(parts)


def _load(args):
    from ..loading import load
    from ..model.resolve import resolve_model

    model = resolve_model(args.model)
    _say(f"loading '{model.name}' ({model.dof} coordinates) with the {args.backend} backend "
         "(the first compiled build of a model takes a few seconds)...")
    start = time.perf_counter()
    options = {"cache_dir": args.cache_dir} if args.backend == "compiled" else {}
    dyn = load(model, backend=args.backend, **options)
    _say(f"loaded in {time.perf_counter() - start:.2f} s")
    return model, dyn


def default_out_dir(model) -> Path:
    """out/<identifier of the model's name>: a name can never choose where files go
    (`../../x` becomes out/x, an absolute path a folder inside out/)."""
    from ..codegen.render import c_identifier

    return Path("out") / c_identifier(model.name)


def _out_dir(args, model) -> Path:
    out = Path(args.out) if args.out else default_out_dir(model)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"--out {out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _fail(exc: Exception) -> int:
    print(f"gagen: error: {exc}", file=sys.stderr)
    return 1


# --------------------------------------------------------------------------- simulate


def _simulate(args: argparse.Namespace) -> int:
    from ..runtime.dynamics import SingularMassMatrixError
    from ..sim.controllers import PD, default_controller, is_paper_robot
    from ..sim.simulate import simulate

    method = args.method or ("dopri5" if args.backend == "compiled" else "RK45")
    if method in COMPILED_METHODS and args.backend != "compiled":
        return _fail(ValueError(f"--method {method} needs --backend compiled; use a scipy "
                                "method (e.g. RK45) with the lambdify backend"))
    model, dyn = _load(args)
    try:
        controller = default_controller(dyn)
        if args.target is not None or args.kp is not None or args.kd is not None:
            target = (controller.target if args.target is None
                      else _degrees_to_model(args.target, model))
            controller = PD(kp=controller.kp if args.kp is None else args.kp,
                            kd=controller.kd if args.kd is None else args.kd,
                            target=target, gravity_compensation=not args.no_gravity_compensation)
        elif args.no_gravity_compensation:
            controller = PD(controller.kp, controller.kd, controller.target, False)
    except ValueError as exc:
        return _fail(exc)
    which = "paper_controller()" if is_paper_robot(model) else "default_controller()"
    _say(f"controller {which}: {controller!r}")
    options = {"h": args.step} if method == "rk4" else {}
    t_eval = np.linspace(0.0, args.duration, args.points)
    _say(f"simulating {args.duration:g} s with {method} (rtol={args.rtol:g}, "
         f"atol={args.atol:g})...")
    try:
        res = simulate(dyn, (0.0, args.duration), np.zeros(dyn.n), np.zeros(dyn.n),
                       controller=controller, method=method, rtol=args.rtol, atol=args.atol,
                       t_eval=t_eval, **options)
    except (SingularMassMatrixError, RuntimeError, ValueError) as exc:
        return _fail(exc)
    st = res.stats
    _say(f"simulation wall time {_duration(st['wall_time'])} ({method}, {dyn.backend} "
         f"backend): {st['steps']} steps, {st['nfev']} right-hand side evaluations")
    _say(f"final position: {_shown(res.q[-1], model)}")
    out = _out_dir(args, model)
    files = [res.to_csv(out / "simulate.csv")]
    _say("plotting...")
    from .figures import arm_gif, fig2_positions, fig3_arm

    files.append(fig2_positions(res.t, res.q, model, out / "fig2_positions.png"))
    files.append(fig3_arm(model, res.q, out / "fig3_arm.png", t=res.t))
    if args.gif:
        _say("writing the animation (a few seconds)...")
        files.append(arm_gif(model, res.t, res.q, out / "arm.gif"))
    for f in files:
        _say(f"wrote {f}")
    return 0


def _duration(seconds: float) -> str:
    if seconds < 1e-3:
        return f"{seconds * 1e6:.0f} us"
    if seconds < 1.0:
        return f"{seconds * 1e3:.2f} ms"
    return f"{seconds:.2f} s"


# ---------------------------------------------------------------------------- inverse


def _inverse(args: argparse.Namespace) -> int:
    from ..sim.controllers import default_target
    from ..sim.simulate import inverse_dynamics_along
    from ..sim.trajectory import Eq11Trajectory
    from .figures import _torque_names, fig4_inverse

    model, dyn = _load(args)
    try:
        qf = default_target(model) if args.qf is None else _degrees_to_model(args.qf, model)
    except ValueError as exc:
        return _fail(exc)
    trajectory = Eq11Trajectory(np.zeros(dyn.n), qf, args.duration)
    _say(f"eq. 11 from q = 0 to {_shown(qf, model)} in Tp = {args.duration:g} s")
    t = np.linspace(0.0, args.duration, args.points)
    start = time.perf_counter()
    q, qd, qdd, tau = inverse_dynamics_along(dyn, trajectory, t)
    _say(f"inverse dynamics at {len(t)} times in {_duration(time.perf_counter() - start)}")
    labels, units = _torque_names(model, dyn.n)
    width = max(len(label) for label in labels)
    for k, label in enumerate(labels):
        i = int(np.argmax(np.abs(tau[:, k])))
        _say(f"peak {label:<{width}} {tau[i, k]:+10.2f} {units[k]:<3} at t = {t[i]:.2f} s "
             f"(range {tau[:, k].min():+.2f} .. {tau[:, k].max():+.2f})")
    out = _out_dir(args, model)
    csv_path = out / "inverse.csv"
    names = list(model.coordinates)
    header = (["t"] + names + [f"{c}_d" for c in names] + [f"{c}_dd" for c in names]
              + [f"tau_{c}" for c in names])
    with csv_path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        for row in np.column_stack([t, q, qd, qdd, tau]):
            writer.writerow([repr(float(v)) for v in row])
    _say("plotting...")
    fig = fig4_inverse(t, q, tau, model, out / "fig4_inverse.png")
    for f in (csv_path, fig):
        _say(f"wrote {f}")
    return 0


# ------------------------------------------------------------------------------ paper


def _paper(args: argparse.Namespace) -> int:
    """Both of the paper's computations on rrr, then how they compare with its figures."""
    from .cli import parser

    out = Path(args.out)
    common = ["--out", str(out)] + (["--cache-dir", args.cache_dir] if args.cache_dir else [])
    steps = [["simulate", "rrr", *common] + (["--gif"] if args.gif else []),
             ["inverse", "rrr", *common]]
    for argv in steps:
        _say(f"== python -m gagen {' '.join(argv)}")
        step = parser().parse_args(argv)
        code = step.run(step)
        if code:
            return code
    _summarize_paper(out)
    return 0


def _summarize_paper(out: Path) -> None:
    sim = np.genfromtxt(out / "simulate.csv", delimiter=",", names=True)
    inv = np.genfromtxt(out / "inverse.csv", delimiter=",", names=True)
    final = [math.degrees(sim[c][-1]) for c in ("q1", "q2", "q3")]
    torques = {c: (inv[f"tau_{c}"].min(), inv[f"tau_{c}"].max()) for c in ("q1", "q2", "q3")}
    print("\nThe paper's results, reproduced (files in " + str(out) + "):")
    print("  Fig. 2  final q1, q2, q3: {:.1f}, {:.1f}, {:.1f} deg   (paper: about -60, -60, -30)"
          .format(*final))
    print("  Fig. 3  the arm's successive positions: fig3_arm.png")
    print("  Fig. 4  T01z {:+.1f} .. {:+.1f} N m  (paper: within about +-15)".format(
        *torques["q1"]))
    print("          T12x {:+.1f} .. {:+.1f} N m  (paper: peaks at roughly 300-400)".format(
        *torques["q2"]))
    print("          T23x {:+.1f} .. {:+.1f} N m  (paper: within 200)".format(*torques["q3"]))


# ---------------------------------------------------------------------------- parsers


def _common(p: argparse.ArgumentParser, what: str) -> None:
    add_model_argument(p)
    p.add_argument("--duration", type=_positive, default=5.0, metavar="S",
                   help=f"{what} in seconds (default: %(default)s, as in the paper)")
    p.add_argument("--points", type=_sample_count, default=501, metavar="N",
                   help="output samples, evenly spaced (default: %(default)s)")
    p.add_argument("--out", metavar="DIR",
                   help="output folder (default: out/<model name>, e.g. out/rrr)")
    p.add_argument("--backend", choices=("compiled", "lambdify"), default="compiled",
                   help="equations of motion as compiled C or through sympy.lambdify "
                   "(default: %(default)s)")
    add_cache_dir_argument(p)


def register(subparsers) -> None:
    """Add the `simulate` and `inverse` commands to gagen's command line."""
    p = subparsers.add_parser(
        "simulate", help="direct dynamics under feedback: the paper's Fig. 2 and 3",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Direct dynamics: the arm starts at rest at q = 0 and a PD law with "
        "gravity\ncompensation drives it for --duration seconds.\n\n"
        "  rrr:    paper_controller(): target (-60, -60, -30) deg, kp = (500, 300, 200) "
        "N m/rad,\n          kd = (300, 150, 100) N m s/rad (the paper's Fig. 2 and 3)\n"
        "  others: target -30 deg per revolute joint, 0.05 m per prismatic joint (clipped\n"
        "          into the joint limits); kp = 16 I_i, kd = 8 I_i, I_i the largest M_ii at\n"
        "          q = 0, half-way and at the target\n\n"
        "Writes simulate.csv (t, q, qd, tau; SI units, radians), fig2_positions.png, "
        "fig3_arm.png\nand, with --gif, arm.gif into --out.")
    _common(p, "simulated time")
    p.add_argument("--method", choices=COMPILED_METHODS + SCIPY_METHODS, default=None,
                   help="dopri5 or rk4: gagen's C integrators (compiled backend; dopri5 takes "
                   "the same steps as scipy's RK45, the paper's ode45); or any "
                   "scipy.integrate.solve_ivp method (default: dopri5 with the compiled "
                   "backend, RK45 with lambdify)")
    p.add_argument("--rtol", type=_positive, default=1e-6,
                   help="relative tolerance (default: %(default)s)")
    p.add_argument("--atol", type=_nonnegative, default=1e-8,
                   help="absolute tolerance (default: %(default)s)")
    p.add_argument("--step", type=_positive, default=1e-3, metavar="H",
                   help="fixed step of rk4 in seconds (default: %(default)s)")
    p.add_argument("--target", type=lambda s: _floats(s, "--target"), metavar="V1,V2,...",
                   help="PD target, degrees (metres for prismatic joints), one value or one "
                   "per coordinate; write --target=-60,-60,-30 (default: see above)")
    p.add_argument("--kp", type=lambda s: _floats(s, "--kp"), metavar="K1,K2,...",
                   help="proportional gains, one value or one per coordinate "
                   "(default: see above)")
    p.add_argument("--kd", type=lambda s: _floats(s, "--kd"), metavar="K1,K2,...",
                   help="derivative gains, one value or one per coordinate "
                   "(default: see above)")
    p.add_argument("--no-gravity-compensation", action="store_true",
                   help="leave out the gravity torque g(q) of the PD law")
    p.add_argument("--gif", action="store_true",
                   help="also write arm.gif, an animation of the arm (a few seconds)")
    p.set_defaults(run=_simulate)

    p = subparsers.add_parser(
        "inverse", help="inverse dynamics along eq. 11: the paper's Fig. 4",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Inverse dynamics: the torques that move the arm along eq. 11,\n"
        "  q(t) = q0 + (qf - q0)/Tp (t - Tp/(2 pi) sin(2 pi t/Tp)),  0 <= t <= Tp,\n"
        "from rest at q0 = 0 to rest at qf. Default qf: rrr (-60, -60, -30) deg, as in the "
        "paper;\nother models -30 deg per revolute joint, 0.05 m per prismatic joint "
        "(clipped into\nthe joint limits). Writes inverse.csv (t, q, qd, qdd, tau) and "
        "fig4_inverse.png into\n--out and prints the peak torques.")
    _common(p, "motion time Tp")
    p.add_argument("--qf", type=lambda s: _floats(s, "--qf"), metavar="V1,V2,...",
                   help="final position, degrees (metres for prismatic joints), one value or "
                   "one per coordinate; write --qf=-60,-60,-30 (default: see above)")
    p.set_defaults(run=_inverse)

    p = subparsers.add_parser(
        "paper", help="reproduce the paper: Fig. 2, 3 (direct) and Fig. 4 (inverse dynamics)",
        description="Runs `simulate rrr` and `inverse rrr` with the paper's settings and "
        "compares the results with the paper's figures.")
    p.add_argument("--out", default="out/rrr", metavar="DIR",
                   help="output folder (default: %(default)s)")
    p.add_argument("--gif", action="store_true", help="also write an animation, arm.gif")
    add_cache_dir_argument(p)
    p.set_defaults(run=_paper)
