"""Command line: `python -m gagen <command>`; one parser and one registry of commands.

Each command is a function of the parsed arguments that calls gagen's functions with
values (`COMMANDS`). Results go to stdout; progress (build stages, loading, plotting) is
logged by gagen's modules at INFO and shown on stderr as `gagen: <message>` lines, unless
--quiet.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .. import __version__
from ..bench import DESCRIPTION as BENCH_DESCRIPTION
from ..errors import ModelError, NonFiniteStateError
from ..sim.simulate import COMPILED_METHODS, SCIPY_METHODS

MODEL_HELP = ("built-in name (rrr, chain:N), model file (.yaml, .yml, .json), .urdf, or MuJoCo "
              "MJCF (.xml, .mjcf; needs pip install gagen[mjcf]) (default: rrr, the paper's "
              "robot)")


# ------------------------------------------------------------------- argument types


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


def _count(low: int, high: int, what: str) -> Callable[[str], int]:
    """An argument type: a whole number of `what` from low to high."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"expected {low:,} to {high:,} {what}, got {value}")
        return value

    return parse


_sample_count = _count(2, 10_000_000, "samples")
_run_count = _count(1, 100_000_000, "runs")
_thread_count = _count(1, 4096, "threads")
_seed = _count(0, 2**64 - 1, "(a seed)")
_degree = _count(2, 20, "(a polynomial degree)")


def _numbers(text: str) -> list[float]:
    """One finite number, or several separated by commas (the older `--target=-60,-60,-30`)."""
    parts = [part for part in text.replace(" ", "").split(",") if part]
    if not parts:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'")
    return [_finite(part) for part in parts]


def _flat(groups: list[list[float]] | None) -> list[float] | None:
    """The numbers of a `nargs="+"` list of `_numbers`, in order (None stays None)."""
    return None if groups is None else [v for group in groups for v in group]


def _add_numbers(p: argparse.ArgumentParser, flag: str, help: str, example: str) -> None:
    p.add_argument(flag, nargs="+", type=_numbers, metavar="V",
                   help=f"{help}, e.g. {flag} {example} (default: see above)")


# ------------------------------------------------------------------------ arguments


def _add_model(p: argparse.ArgumentParser, required: bool = False) -> None:
    if required:
        p.add_argument("model", help=MODEL_HELP.replace(" (default: rrr, the paper's robot)",
                                                        ""))
    else:
        p.add_argument("model", nargs="?", default="rrr", help=MODEL_HELP)
    p.add_argument("--strict", action="store_true",
                   help="refuse an inertia slightly off physical (CAD round-off), which "
                   "otherwise loads with a warning")
    p.add_argument("--floating-base", action="store_true",
                   help="a URDF's root link moves freely (a floating joint to the world, as "
                   "Pinocchio's FreeFlyer; model files and MJCF declare theirs)")


def _add_cache_dir(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cache-dir", metavar="DIR",
                   help="cache of compiled models (default: $GAGEN_CACHE_DIR, else the "
                   "user's cache folder, e.g. ~/.cache/gagen)")


def _add_package_path(p: argparse.ArgumentParser) -> None:
    p.add_argument("--package-path", action="append", default=None, metavar="DIR",
                   help="where a URDF's package://NAME/... meshes are found (DIR/NAME/...); "
                   "repeat for several; $ROS_PACKAGE_PATH is searched after them. Meshes are "
                   "read only inside these folders and the description's folder")


def _build_arguments(p: argparse.ArgumentParser) -> None:
    _add_model(p)
    p.add_argument("--out", metavar="DIR",
                   help="write sources and module here (default for rrr: generated/rrr; "
                   "other models: the cache)")
    _add_cache_dir(p)
    p.add_argument("--fast-math", action="store_true",
                   help="compile with -ffast-math (off by default: it may reorder floating point)")
    p.add_argument("--derivation", choices=("auto", "gibbs-appell", "recursive"), default="auto",
                   help="how the equations are derived: the paper's Gibbs-Appell form, or the "
                   "recursive Newton-Euler/CRBA form that builds big robots in seconds "
                   "(default auto: Gibbs-Appell up to 8 coordinates, recursive from 9)")
    p.add_argument("--derivatives", action="store_true",
                   help="also build the derivative module (inverse and forward dynamics "
                   "derivatives, Coriolis matrix, linearize; otherwise built on their first "
                   "use), into DIR/derivatives with --out")


def _info_arguments(p: argparse.ArgumentParser) -> None:
    _add_model(p)


def _export_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("target", choices=("casadi",),
                   help="casadi: CasADi external functions (casadi.external, acados)")
    _add_model(p, required=True)
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for the C sources and the library (created if needed)")
    _add_cache_dir(p)
    p.add_argument("--portable", action="store_true",
                   help="kernels for any CPU of this architecture (default: this CPU's "
                   "fused multiply-add where it has it)")


def _run_arguments(p: argparse.ArgumentParser, what: str) -> None:
    """What `simulate` and `inverse` share."""
    _add_model(p)
    p.add_argument("--duration", type=_positive, default=5.0, metavar="S",
                   help=f"{what} in seconds (default: %(default)s, as in the paper)")
    p.add_argument("--points", type=_sample_count, default=501, metavar="N",
                   help="output samples, evenly spaced (default: %(default)s)")
    _add_output_and_backend(p, "equations of motion")


def _add_output_and_backend(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--out", metavar="DIR",
                   help="output folder (default: out/<model name>, e.g. out/rrr)")
    p.add_argument("--backend", choices=("compiled", "lambdify"), default="compiled",
                   help=f"{what} as compiled C or through sympy.lambdify "
                   "(default: %(default)s)")
    _add_cache_dir(p)


def _add_tolerances(p: argparse.ArgumentParser) -> None:
    """--rtol, --atol (adaptive methods) and --step (rk4)."""
    p.add_argument("--rtol", type=_positive, default=1e-6,
                   help="relative tolerance (default: %(default)s)")
    p.add_argument("--atol", type=_nonnegative, default=1e-8,
                   help="absolute tolerance (default: %(default)s)")
    p.add_argument("--step", type=_positive, default=1e-3, metavar="H",
                   help="fixed step of rk4 in seconds (default: %(default)s)")


def _simulate_arguments(p: argparse.ArgumentParser) -> None:
    _run_arguments(p, "simulated time")
    p.add_argument("--method", choices=COMPILED_METHODS + SCIPY_METHODS, default=None,
                   help="dopri5 or rk4: gagen's C integrators (compiled backend; dopri5 takes "
                   "the same steps as scipy's RK45, the paper's ode45); or any "
                   "scipy.integrate.solve_ivp method (default: dopri5 with the compiled "
                   "backend, RK45 with lambdify)")
    _add_tolerances(p)
    _add_numbers(p, "--target", "PD target, degrees (metres for prismatic joints), one value "
                 "or one per coordinate", "-60 -60 -30")
    _add_numbers(p, "--kp", "proportional gains, one value or one per coordinate",
                 "500 300 200")
    _add_numbers(p, "--kd", "derivative gains, one value or one per coordinate",
                 "300 150 100")
    p.add_argument("--no-gravity-compensation", action="store_true",
                   help="leave out the gravity torque g(q) of the PD law")
    p.add_argument("--gif", action="store_true",
                   help="also write arm.gif, an animation of the arm (a few seconds)")
    p.add_argument("--html", action="store_true",
                   help="also write simulate.html: the run played back in 3-D with the "
                   "robot's meshes, one self-contained file that plays offline in any "
                   "browser (needs pip install gagen[viewer])")
    _add_package_path(p)


def _sweep_arguments(p: argparse.ArgumentParser) -> None:
    _add_model(p)
    p.add_argument("--runs", type=_run_count, default=100, metavar="N",
                   help="number of simulations (default: %(default)s)")
    p.add_argument("--vary", action="append", default=[], metavar="NAME=LO:HI|NAME=P%",
                   help="draw NAME for every run, uniformly in [LO, HI] or within +-P %% of "
                   "its default; NAME is a parameter (patterns allowed: 'm[123]=20%%'), or "
                   "q0, qd0, kp, kd, target (degrees for angles), or one coordinate of them "
                   "(q0.q2=-10:10); repeat for several. A floating base: q0, qd0, ... vary "
                   "the joints only; q0.base_x (m), qd0.base_wx (deg/s) name the base's "
                   "entries; its quaternion cannot be varied (see above)")
    p.add_argument("--seed", type=_seed, default=0,
                   help="seed of the draws, a whole number >= 0 (default: 0)")
    p.add_argument("--duration", type=_positive, default=5.0, metavar="S",
                   help="simulated time in seconds (default: %(default)s)")
    p.add_argument("--points", type=_sample_count, default=501, metavar="N",
                   help="output samples per run, evenly spaced (default: %(default)s)")
    p.add_argument("--method", choices=COMPILED_METHODS, default="dopri5",
                   help="gagen's C integrator (default: %(default)s)")
    _add_tolerances(p)
    p.add_argument("--threads", type=_thread_count, default=None, metavar="K",
                   help="threads for the runs (default: every core)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a Dask cluster, e.g. tcp://host:8786 (needs gagen[dask])")
    p.add_argument("--out", metavar="FILE",
                   help="results: FILE.zarr (streamed in blocks; needs gagen[zarr]) or "
                   "FILE.npz (default: out/<model>/sweep.zarr, or .npz without Zarr)")
    p.add_argument("--no-plot", action="store_true", help="do not draw the fan figure")
    p.add_argument("--html", action="store_true",
                   help="also write FILE's stem + .html: chosen runs played back in 3-D, one "
                   "self-contained file (needs pip install gagen[viewer])")
    p.add_argument("--html-runs", nargs="+", type=_count(0, 100_000_000, "run numbers"),
                   metavar="I", help="the runs the HTML file shows (default: the nominal "
                   "run, then the first 9 runs)")
    p.add_argument("--html-mode", choices=("overlay", "sequence"), default="overlay",
                   help="overlay: the runs drawn together, all but the first ghosted; "
                   "sequence: one after the other (default: %(default)s)")
    _add_package_path(p)
    _add_cache_dir(p)


def _inverse_arguments(p: argparse.ArgumentParser) -> None:
    _run_arguments(p, "motion time Tp")
    _add_numbers(p, "--qf", "final position, degrees (metres for prismatic joints), one value "
                 "or one per coordinate", "-60 -60 -30")


def _identify_arguments(p: argparse.ArgumentParser) -> None:
    _add_model(p, required=True)
    p.add_argument("data", help="CSV of measurements: t, the coordinates, their rates "
                   "<name>_d, optionally <name>_dd, and the torques tau_<name>")
    _add_output_and_backend(p, "the regressor")
    p.add_argument("--window", type=_positive, default=None, metavar="S",
                   help="Savitzky-Golay window in seconds for missing rates and "
                   "accelerations (default: 0.05)")
    p.add_argument("--polyorder", type=_degree, default=4, metavar="K",
                   help="Savitzky-Golay polynomial degree, 2 to 20 (default: %(default)s)")
    p.add_argument("--min-speed", type=_nonnegative, default=0.0, metavar="V",
                   help="leave out each joint's torque where it moves slower than V (rad/s, "
                   "m/s): Coulomb friction at rest holds any torque within its bound "
                   "(default: %(default)s)")


def _view_arguments(p: argparse.ArgumentParser) -> None:
    _add_model(p, required=True)
    p.add_argument("--run", metavar="RUN.csv",
                   help="play this run back (a CSV as simulate writes it: the columns t and "
                   "the model's configuration, read by name)")
    _add_package_path(p)
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default: %(default)s, this machine only; "
                   "0.0.0.0 shares the viewer on the network)")
    p.add_argument("--port", type=_count(0, 65535, "port number"), default=8080,
                   help="first port tried; the next free one is taken (default: %(default)s; "
                   "0: any free port)")
    p.add_argument("--no-browser", action="store_true",
                   help="do not open a browser, only print the address")
    p.add_argument("--backend", choices=("compiled", "lambdify"), default="compiled",
                   help="placements from compiled C or sympy.lambdify (default: %(default)s)")
    _add_cache_dir(p)


def _paper_arguments(p: argparse.ArgumentParser) -> None:
    from .paper import DEFAULT_OUT

    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help="output folder (default: %(default)s)")
    p.add_argument("--gif", action="store_true", help="also write an animation, arm.gif")
    _add_cache_dir(p)


def _bench_arguments(p: argparse.ArgumentParser) -> None:
    from ..bench.run import SECTIONS

    p.add_argument("--out", default="bench-out", metavar="DIR",
                   help="output folder for report.md, results.json and the plots "
                   "(default: %(default)s)")
    p.add_argument("--full", action="store_true",
                   help="the complete study, in tens of minutes (the sections it adds "
                   "are listed above)")
    p.add_argument("--urdf-dir", metavar="DIR",
                   help="folder holding ur5_robot.urdf and panda.urdf (default: "
                   "$GAGEN_URDF_DIR, else ../shared/urdf next to the repository)")
    p.add_argument("--cache-dir", metavar="DIR",
                   help="where rrr is built for the per-call, batched and simulation "
                   "sections (default: a fresh temporary folder; the scaling study always "
                   "builds cold in one)")
    p.add_argument("--only", nargs="+", choices=SECTIONS, metavar="SECTION",
                   help=f"run only these sections ({', '.join(SECTIONS)})")
    p.add_argument("--models", nargs="+", metavar="MODEL",
                   help="models of the scaling study instead of the mode's list "
                   "(built-in names, model files, URDFs)")
    p.add_argument("--smoke", action="store_true", help=argparse.SUPPRESS)


# ------------------------------------------------------------------------- commands


def build_command(args: argparse.Namespace) -> int:
    """Derive, generate and compile a model; print what was done."""
    from ..building.builder import build
    from ..model.resolve import resolve_model

    model = resolve_model(args.model, strict=args.strict, floating_base=args.floating_base)
    out = Path(args.out) if args.out else (Path("generated") / model.name if args.model == "rrr"
                                           else None)
    start = time.perf_counter()
    path, report = build(model, out=out, cache_dir=args.cache_dir, fast_math=args.fast_math,
                         derivation=args.derivation)
    _print_build(model, "", path, report, time.perf_counter() - start)
    if args.derivatives:
        start = time.perf_counter()
        path, report = build(model, out=out / "derivatives" if out else None,
                             cache_dir=args.cache_dir, fast_math=args.fast_math,
                             derivation=args.derivation, derivatives=True)
        _print_build(model, "the derivatives of ", path, report, time.perf_counter() - start)
    return 0


def _print_build(model, what: str, path: Path, report, total: float) -> None:
    if report.cached:
        print(f"gagen: {what}'{model.name}' is up to date in the cache")
    print(f"gagen: {what}{model.name}: {model.dof} coordinates, {report.ops_before_cse} "
          f"operations before CSE, {report.ops_after_cse} after; total {total:.2f} s")
    print(f"gagen: module {path}")


def info_command(args: argparse.Namespace) -> int:
    """A model's coordinates, parameters and the API of its dynamics object."""
    from ..manifest import ModelInfo
    from ..model.resolve import resolve_model

    model = resolve_model(args.model, strict=args.strict, floating_base=args.floating_base)
    print(f"model        {model.name}  ({model.source})")
    if model.description:
        print(f"description  {model.description}")
    print(f"bodies       {len(model.bodies)}")
    if model.nq != model.nv:
        print(f"q            {model.nq}: {', '.join(model.configuration)}")
    print(f"coordinates  {model.dof}: {', '.join(model.coordinates)}")
    frames = [f.name for f in model.frames]
    shown = ", ".join(frames[:8]) + (", ..." if len(frames) > 8 else "")
    print(f"frames       {len(frames)}: {shown}")
    print("parameters")
    for name, value in model.parameters.items():
        print(f"  {name:<24} {value:g}")
    _print_methods(model.dof, model.nq, len(ModelInfo.from_model(model).regressor_names))
    return 0


# (call, what it returns); {n} and {m} (= 2n) become the model's sizes. The starred ones
# are in the compiled backend's second module, built on their first use.
_METHODS = (
    ("mass_matrix(q)", "M: ({n}, {n})"),
    ("forcing(q, qd, tau)", "F with M qdd = F: ({n},)"),
    ("forward_dynamics(q, qd, tau)", "qdd: ({n},)"),
    ("inverse_dynamics(q, qd, qdd)", "tau: ({n},)"),
    ("gravity(q)", "tau that holds q at rest: ({n},)"),
    ("energy(q, qd)", "(kinetic, potential)"),
    ("neutral()", "q with every coordinate 0, every quaternion the identity: ({nq},)"),
    ("integrate(q, v, dt)", "q moved by v dt (Pinocchio's integrate): ({nq},)"),
    ("difference(q0, q1)", "v with integrate(q0, v) = q1: ({n},)"),
    ("frame_placement(q, frame)", "(R, p): (3, 3), (3,) in the world"),
    ("frame_velocity(q, qd, frame, reference)", "linear, angular: (6,)"),
    ("frame_jacobian(q, frame, reference)",
     "'local_world_aligned' (default), 'local', 'world': (6, {n}); a list of k: (k, 6, {n})"),
    ("frame_acceleration(q, qd, qdd, frame, ...)",
     "reference=, kind='classical' (default) or 'spatial': (6,)"),
    ("frame_bias_acceleration(q, qd, frame, ...)", "the same at qdd = 0: dJ/dt qd, (6,)"),
    ("frame_jacobian_time_variation(q, qd, frame)",
     "dJ/dt, as Pinocchio's getFrameJacobianTimeVariation: (6, {n})"),
    ("delassus(q, frames, dims)", "J M^-1 J^T of k frames' rows (6 or 3 each): (k dims, k dims)"),
    ("operational_space_inertia(q, frames, dims)", "its inverse, from M's factors: (k dims, k dims)"),
    ("external_forces(q, fext)", "sum of J^T w of wrenches {{frame: w}}: ({n},)"),
    ("center_of_mass(q)", "the centre of mass, in the world: (3,)"),
    ("com_velocity(q, qd)", "the centre of mass's velocity: (3,)"),
    ("com_jacobian(q)", "J_com, com_velocity = J_com qd: (3, {n})"),
    ("centroidal_map(q)", "A_g: at the CoM, world axes, linear first: (6, {n})"),
    ("centroidal_momentum(q, qd)", "h_g = A_g qd (angular: about the CoM): (6,)"),
    ("centroidal_map_time_variation(q, qd)", "d/dt A_g: (6, {n})"),
    ("centroidal_bias(q, qd)", "d/dt A_g qd: d/dt h_g = A_g qdd + this: (6,)"),
    ("inverse_dynamics_derivatives(q, qd, qdd) *", "(dtau_dq, dtau_dqd): ({n}, {n}) each"),
    ("forward_dynamics_derivatives(q, qd, tau) *",
     "(dqdd_dq, dqdd_dqd, dqdd_dtau = M^-1): ({n}, {n}) each"),
    ("coriolis_matrix(q, qd) *", "C with C qd = velocity terms: ({n}, {n})"),
    ("linearize(q, qd, tau) *", "(A, B) of x' = f(x, tau), x = (q, qd): ({m}, {m}), ({m}, {n})"),
    ("regressor(q, qd, qdd)", "Y with tau = Y pi: ({n}, {P})"),
    ("regressor_parameters()", "pi: ({P},), names: dyn.regressor_names"),
    ("joint_terms()", "(damping, friction, armature): ({n},) each"),
    ("base_grouping()", "the base parameters (r = rank Y of them; .text())"),
    ("base_regressor(q, qd, qdd)", "Y_b with tau = Y_b pi_b: ({n}, r)"),
    ("base_parameters()", "pi_b: (r,)"),
)


def _print_methods(n: int, nq: int, P: int) -> None:
    """The API of `gagen.load(model)` with this model's array shapes (P: the regressor's
    columns)."""
    print("methods      dyn = gagen.load(MODEL); stacked (N, ...) inputs give stacked outputs")
    for call, returns in _METHODS:
        print(f"  {call:<44} {returns.format(n=n, m=2 * n, nq=nq, P=P)}")
    print("  * compiled: a second module, built on first use; gagen.load(MODEL, "
          "derivatives=True) or\n    python -m gagen build MODEL --derivatives builds it up "
          "front")


def export_command(args: argparse.Namespace) -> int:
    """A model's functions for another tool: the CasADi library (gagen.casadi.build.export)."""
    from ..casadi.build import export, model_ident
    from ..casadi.generate import function_name, prefix_of
    from ..casadi.table import ENTRIES
    from ..loading import load

    dyn = load(args.model, strict=args.strict, floating_base=args.floating_base,
               cache_dir=args.cache_dir, derivatives=True)
    path = export(dyn, Path(args.out), portable=args.portable)
    prefix = prefix_of(model_ident(dyn))
    print(f"gagen: wrote {path} and its sources ({prefix}.c, {prefix}.h: the functions, "
          "their inputs and outputs, the frames' numbers) into " + str(Path(args.out)))
    names = ", ".join(function_name(prefix, entry.name) for entry in ENTRIES)
    print(f"gagen: functions {names}; each F with jac_F (its Jacobian) and F_p (the "
          "parameters p as a last input)")
    print(f"gagen: load one with casadi.external(\"{function_name(prefix, 'forward_dynamics')}\", "
          f"\"{path}\")")
    return 0


def simulate_command(args: argparse.Namespace) -> int:
    """Direct dynamics under a PD law (gagen.app.runs.run_simulate)."""
    from .runs import print_simulate_report, run_simulate

    run = run_simulate(args.model, duration=args.duration, points=args.points, out=args.out,
                       backend=args.backend, cache_dir=args.cache_dir, method=args.method,
                       rtol=args.rtol, atol=args.atol, step=args.step,
                       target=_flat(args.target), kp=_flat(args.kp), kd=_flat(args.kd),
                       gravity_compensation=not args.no_gravity_compensation, gif=args.gif,
                       strict=args.strict, floating_base=args.floating_base, html=args.html,
                       package_dirs=args.package_path)
    print_simulate_report(run)
    return 0


def inverse_command(args: argparse.Namespace) -> int:
    """Inverse dynamics along eq. 11 (gagen.app.runs.run_inverse)."""
    from .runs import print_inverse_report, run_inverse

    run = run_inverse(args.model, duration=args.duration, points=args.points, out=args.out,
                      backend=args.backend, cache_dir=args.cache_dir, qf=_flat(args.qf),
                      strict=args.strict, floating_base=args.floating_base)
    print_inverse_report(run)
    return 0


def sweep_command(args: argparse.Namespace) -> int:
    """Many simulations with varied parameters, states and gains (gagen.app.sweep)."""
    from .sweep import print_sweep_report, run_sweep

    run = run_sweep(args.model, runs=args.runs, variations=args.vary, seed=args.seed,
                    duration=args.duration, points=args.points, method=args.method,
                    rtol=args.rtol, atol=args.atol, step=args.step, threads=args.threads,
                    scheduler=args.scheduler, out=args.out, cache_dir=args.cache_dir,
                    plot=not args.no_plot, html=args.html, html_runs=args.html_runs,
                    html_mode=args.html_mode, package_dirs=args.package_path,
                    strict=args.strict, floating_base=args.floating_base)
    print_sweep_report(run)
    return 0


def identify_command(args: argparse.Namespace) -> int:
    """Identify a model's base parameters from a CSV of measurements (gagen.ident)."""
    from ..ident import identify, read_measurements
    from .runs import load_dynamics, output_folder

    model, dyn = load_dynamics(args.model, args.backend, args.cache_dir, args.strict)
    data = read_measurements(args.data, dyn.coordinates, args.window, args.polyorder)
    result = identify(dyn, data.q, data.qd, data.qdd, data.tau, min_speed=args.min_speed)
    folder = output_folder(args.out, model)
    files = [result.to_csv(folder / "identified.csv"), result.to_json(folder / "identified.json")]
    print(f"gagen: {len(data.t)} samples of '{model.name}' from {args.data}"
          + (f"; estimated {data.estimated}" if data.estimated else ""))
    print(result.summary())
    for path in files:
        print(f"gagen: wrote {path}")
    return 0


def view_command(args: argparse.Namespace) -> int:
    """The live 3-D viewer in the browser, until Ctrl-C (gagen.viewer.live)."""
    from ..viewer import read_run, require, start_viewer
    from .runs import load_dynamics

    require()
    _, dyn = load_dynamics(args.model, args.backend, args.cache_dir, args.strict,
                           args.floating_base)
    run = read_run(args.run, dyn) if args.run else None
    viewer = start_viewer(dyn, run=run, package_dirs=args.package_path, host=args.host,
                          port=args.port, open_browser=not args.no_browser)
    print(f"gagen: viewer at {viewer.url} (Ctrl-C to stop)", flush=True)
    try:
        viewer.serve_forever()
    except KeyboardInterrupt:
        print("gagen: viewer stopped", file=sys.stderr)
    return 0


def paper_command(args: argparse.Namespace) -> int:
    """The paper's reproduction (gagen.app.paper.reproduce_paper)."""
    from .paper import reproduce_paper

    reproduce_paper(args.out, gif=args.gif, cache_dir=args.cache_dir)
    return 0


def bench_command(args: argparse.Namespace) -> int:
    """The benchmark suite (gagen.bench.run.run); 0 if every section worked."""
    from ..bench.run import run

    mode = "smoke" if args.smoke else ("full" if args.full else "default")
    command = "python -m gagen bench --out " + str(args.out) + (
        " --full" if args.full else "") + (" --smoke" if args.smoke else "")
    return run(out=Path(args.out), mode=mode, urdf_dir=args.urdf_dir, cache_dir=args.cache_dir,
               sections=args.only, scaling_models=args.models, command=command)


@dataclass(frozen=True)
class Command:
    """A command of the command line: its function and its parser's texts and arguments."""

    run: Callable[[argparse.Namespace], int]
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    description: str | None = None
    preformatted: bool = False  # the description keeps its line breaks


SIMULATE_DESCRIPTION = (
    "Direct dynamics: the arm starts at rest at q = 0 and a PD law with gravity\n"
    "compensation drives it for --duration seconds.\n\n"
    "  rrr:    paper_controller(): target (-60, -60, -30) deg, kp = (500, 300, 200) N m/rad,\n"
    "          kd = (300, 150, 100) N m s/rad (the paper's Fig. 2 and 3)\n"
    "  others: target -30 deg per revolute joint, 0.05 m per prismatic joint (clipped\n"
    "          into the joint limits); kp = 16 I_i, kd = 8 I_i, I_i the largest M_ii at\n"
    "          q = 0, half-way and at the target\n\n"
    "Writes simulate.csv (t, q, qd, tau; SI units, radians), fig2_positions.png, "
    "fig3_arm.png\nand, with --gif, arm.gif, with --html, simulate.html (the run in 3-D, "
    "one file) into\n--out. Put MODEL before the lists (--target, --kp, --kd).")

INVERSE_DESCRIPTION = (
    "Inverse dynamics: the torques that move the arm along eq. 11,\n"
    "  q(t) = q0 + (qf - q0)/Tp (t - Tp/(2 pi) sin(2 pi t/Tp)),  0 <= t <= Tp,\n"
    "from rest at q0 = 0 to rest at qf. Default qf: rrr (-60, -60, -30) deg, as in the paper;\n"
    "other models -30 deg per revolute joint, 0.05 m per prismatic joint (clipped into\n"
    "the joint limits). Writes inverse.csv (t, q, qd, qdd, tau) and fig4_inverse.png into\n"
    "--out and prints the peak torques. Put MODEL before --qf.")

SWEEP_DESCRIPTION = (
    "Many runs of `simulate`'s setup (from rest at q = 0 under its PD law, rrr: the paper's),\n"
    "each with its own uniform draw of every --vary, run in C on every core\n"
    "(gagen.simulate_batch) or on a Dask cluster (--scheduler). Example, the paper's Fig. 2\n"
    "under +-20 % mass uncertainty:\n\n"
    "  python -m gagen sweep rrr --runs 1000 --vary 'm[123]=20%' --out out/rrr/sweep.zarr\n\n"
    "Writes FILE (.zarr: t, q (N, m, nq), qd, tau (N, m, nv), status, nfev, steps, rejected,\n"
    "q0, qd0, p, kp, kd, target; streamed in blocks; read it with zarr.open_group or\n"
    "xarray.open_zarr. .npz: the same arrays, read with np.load; the attributes name q's\n"
    "entries (configuration) and qd's (coordinates)), FILE's stem + _fan.png (every run's\n"
    "q(t), 5-95 % band, median, nominal, deviation from the nominal), + _final.csv\n"
    "(statistics of the final state, also printed) and, with --html, + .html (chosen runs\n"
    "in 3-D).\n\n"
    "A floating base (--floating-base on a URDF, a model file's or MJCF's floating joint)\n"
    "starts at the origin, unrotated, at rest. There q0, qd0, kp, kd, target without a\n"
    "name vary the joints only. Name a base entry to vary it (names after its joint, here\n"
    "base; a URDF's is root_joint): q0.base_x=-0.1:0.1 (m; q0 names dyn.configuration),\n"
    "qd0.base_vz=0:1 (m/s), qd0.base_wx=-10:10 (deg/s; qd0 names dyn.coordinates). Its\n"
    "quaternion (base_qx ... base_qw) cannot be drawn as angles and is refused, and so are\n"
    "its kp, kd, target (it has no actuator). The statistics cover every entry of q (the\n"
    "quaternion's unitless); the fan figure shows the joints only.")

VIEW_DESCRIPTION = (
    "A live 3-D view of MODEL in the browser (viser; needs pip install gagen[viewer]): the\n"
    "robot in its neutral configuration with its meshes (a URDF's visuals, found through\n"
    "--package-path and $ROS_PACKAGE_PATH; MJCF geoms; inertia boxes for models without),\n"
    "a slider per joint, its frames on demand, and with --run a simulation's playback\n"
    "(time slider, play/pause, speed). Runs until Ctrl-C. Example:\n\n"
    "  python -m gagen simulate robot.urdf --out out/robot\n"
    "  python -m gagen view robot.urdf --run out/robot/simulate.csv")

IDENTIFY_DESCRIPTION = (
    "Identification: least squares on the base regressor, tau = Y_b(q, qd, qdd) pi_b.\n\n"
    "DATA is a CSV with the columns t, <coordinate>, <coordinate>_d, optionally\n"
    "<coordinate>_dd, and tau_<coordinate> (SimulationResult.to_csv writes them). Missing\n"
    "rates and accelerations are estimated by a Savitzky-Golay filter (--window, --polyorder;\n"
    "evenly spaced samples; q and tau are smoothed by the same window and the half-windows\n"
    "at both ends dropped). Writes identified.csv (name, value, std, relative std,\n"
    "expression) and identified.json (also the grouping matrix and covariance) into --out\n"
    "and prints the estimates.")

EXPORT_DESCRIPTION = (
    "Export a model's dynamics and their analytic derivatives for another tool.\n\n"
    "  casadi: C sources that follow CasADi's C API for external functions, and the shared\n"
    "          library compiled from them with the model's C kernels (no Python at run\n"
    "          time): forward_dynamics, inverse_dynamics, mass_matrix, gravity,\n"
    "          coriolis_matrix, frame_placement, frame_jacobian, frame_velocity, each F\n"
    "          with its Jacobian jac_F and F_p (the parameters as a last input). Load them\n"
    "          with casadi.external(NAME, LIBRARY), or link the library from C (CasADi's\n"
    "          generated code, acados' generic external functions). <model>_casadi.h lists\n"
    "          them, their inputs and outputs, and the frames' numbers.\n\n"
    "Example: python -m gagen export casadi robot.urdf --out casadi_robot")

COMMANDS: dict[str, Command] = {
    "build": Command(
        build_command, "derive, generate C and compile a model", _build_arguments,
        "Derive the Gibbs-Appell equations, generate C with CSE and compile it into an "
        "extension module. Shows each stage with its time and prints the operation counts before and "
        "after CSE."),
    "info": Command(info_command, "show a model's coordinates, parameters and API", _info_arguments),
    "export": Command(export_command,
                      "write a model's functions for another tool: CasADi, acados",
                      _export_arguments, EXPORT_DESCRIPTION, preformatted=True),
    "simulate": Command(simulate_command,
                        "direct dynamics under feedback: the paper's Fig. 2 and 3",
                        _simulate_arguments, SIMULATE_DESCRIPTION, preformatted=True),
    "inverse": Command(inverse_command, "inverse dynamics along eq. 11: the paper's Fig. 4",
                       _inverse_arguments, INVERSE_DESCRIPTION, preformatted=True),
    "sweep": Command(sweep_command,
                     "many simulations at once under varied parameters: Monte-Carlo, sweeps",
                     _sweep_arguments, SWEEP_DESCRIPTION, preformatted=True),
    "view": Command(view_command, "a live 3-D view of a model (and a run) in the browser",
                    _view_arguments, VIEW_DESCRIPTION, preformatted=True),
    "identify": Command(identify_command,
                        "identify the base parameters from measured motion and torques",
                        _identify_arguments, IDENTIFY_DESCRIPTION, preformatted=True),
    "paper": Command(
        paper_command,
        "reproduce the paper: Fig. 2, 3 (direct) and Fig. 4 (inverse dynamics)",
        _paper_arguments,
        "Runs `simulate rrr` and `inverse rrr` with the paper's settings and compares the "
        "results with the paper's figures."),
    "bench": Command(bench_command,
                     "benchmarks: per call, batched, simulation, scaling; writes report.md",
                     _bench_arguments, BENCH_DESCRIPTION, preformatted=True),
}


# --------------------------------------------------------------------------- parser


def parser() -> argparse.ArgumentParser:
    """The whole command line: every command of COMMANDS with its arguments."""
    top = argparse.ArgumentParser(
        prog="python -m gagen",
        description="Compiled Gibbs-Appell equations of motion for trees of rigid bodies.",
    )
    top.add_argument("--version", action="version", version=f"gagen {__version__}")
    top.add_argument("--traceback", action="store_true",
                     help="on an error, show Python's traceback instead of one line")
    top.add_argument("-q", "--quiet", action="store_true",
                     help="show no progress on stderr (results and errors only)")
    # the same option after the command; SUPPRESS keeps a subparser from resetting it
    quiet = argparse.ArgumentParser(add_help=False)
    quiet.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                       help="show no progress on stderr (results and errors only)")
    sub = top.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, command in COMMANDS.items():
        p = sub.add_parser(name, help=command.help, description=command.description,
                           parents=[quiet],
                           formatter_class=(argparse.RawDescriptionHelpFormatter
                                            if command.preformatted else argparse.HelpFormatter))
        command.add_arguments(p)
    return top


# ---------------------------------------------------------------------------- main


# What a user can cause, and the exit code each gets: bad input (2) or a run that failed (1),
# out of memory or a missing optional package included. Anything else is a bug in gagen and
# keeps its traceback.
def _exit_code(exc: BaseException) -> int | None:
    from ..building.builder import BuildError
    from ..runtime.dynamics import SingularMassMatrixError

    if isinstance(exc, (BuildError, SingularMassMatrixError, NonFiniteStateError, OSError,
                        RuntimeError, MemoryError, ImportError)):
        return 1
    if isinstance(exc, (ModelError, ValueError, TypeError, KeyError, ArithmeticError)):
        return 2
    return None


# The options that decide how much memory a command takes (named when it runs out).
_SIZING_OPTIONS = {"sweep": "--runs and --points", "simulate": "--points and --duration",
                   "inverse": "--points", "identify": "the rows of DATA",
                   "build": "the model's size", "bench": "--full and --models"}
# Optional packages and the extra of gagen that brings each (pyproject.toml).
_EXTRAS = {"mujoco": "mjcf", "zarr": "zarr", "dask": "dask", "distributed": "dask",
           "pinocchio": "bench", "pydy": "bench", "cmeel": "bench"}


def _message(exc: BaseException, command: str) -> str:
    """The one line the CLI prints for a user's error (see _exit_code)."""
    if isinstance(exc, MemoryError):
        return (f"out of memory running '{command}'"
                + (f": {_SIZING_OPTIONS[command]} decide how much it takes"
                   if command in _SIZING_OPTIONS else ""))
    if isinstance(exc, ImportError) and "pip install" not in str(exc):
        name = (getattr(exc, "name", None) or "").split(".")[0]
        if name in _EXTRAS:
            return (f"'{command}' needs the optional package {name}: pip install "
                    f"'gagen[{_EXTRAS[name]}]'")
        return f"cannot import {name or 'a module'}: {_one_line(exc)}"
    if isinstance(exc, ArithmeticError):
        return (f"a number overflowed in '{command}' ({type(exc).__name__}: "
                f"{_one_line(exc)}); check the options' ranges")
    return _one_line(exc)


def main(argv: list[str] | None = None) -> int:
    """Run one command; a user's error prints one line `gagen: error: ...` (exit 1 or 2).

    Progress is shown on stderr while the command runs (gagen.diagnostics), unless --quiet.
    """
    from ..diagnostics import showing_progress

    args = parser().parse_args(argv)
    try:
        with showing_progress(level=logging.WARNING if args.quiet else logging.INFO), \
                warnings.catch_warnings():
            warnings.showwarning = _warning_line
            return COMMANDS[args.command].run(args)
    except KeyboardInterrupt:
        print("gagen: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        code = _exit_code(exc)
        if code is None or args.traceback:
            raise
        print(f"gagen: error: {_message(exc, args.command)}", file=sys.stderr)
        return code


def _warning_line(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as the CLI shows it: one line `gagen: warning: ...` on stderr."""
    print(f"gagen: warning: {message}", file=sys.stderr)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, KeyError):  # str(KeyError) is the repr of its argument
        text = str(exc.args[0]) if exc.args else text
    return text if len(text) <= 2000 else text[:2000] + " ..."


if __name__ == "__main__":
    sys.exit(main())
