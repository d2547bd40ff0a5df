"""Direct and inverse dynamics runs that write their files: `simulate` and `inverse`.

simulate  direct dynamics (the paper's Fig. 2 and Fig. 3): the arm starts at rest at q = 0
          and a feedback law drives it for `duration` seconds. rrr: `paper_controller()`
          (PD toward (-60, -60, -30) deg with gravity compensation, kp = (500, 300, 200),
          kd = (300, 150, 100)). Other models: `default_controller` (PD toward -30 deg per
          revolute joint / 0.05 m per prismatic joint, clipped into the joint limits, with
          gravity compensation and gains from the mass matrix along the way).
          Writes simulate.csv (t, q, qd, tau), fig2_positions.png, fig3_arm.png and, with
          `gif`, arm.gif.
inverse   inverse dynamics along eq. 11 (the paper's Fig. 4) from q = 0 to qf in
          Tp = `duration` seconds. rrr: qf = (-60, -60, -30) deg; other models: the same
          default target as `simulate`. Writes inverse.csv (t, q, qd, qdd, tau) and
          fig4_inverse.png.

Both take values (not command-line strings) and return what they computed, so that a
caller (the command line, the paper's reproduction) uses the results in memory. Progress
goes to the `gagen.app.runs` logger at INFO; `print_*_report` prints the results.
"""

from __future__ import annotations

import csv
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..csvtext import text_cell
from ..sim.simulate import COMPILED_METHODS, SimulationResult

if TYPE_CHECKING:
    from ..model.model import Model

log = logging.getLogger(__name__)


@dataclass
class SimulateRun:
    """What `run_simulate` computed and wrote."""

    model: Model
    backend: str
    method: str
    result: SimulationResult
    files: list[Path] = field(default_factory=list)


@dataclass
class InverseRun:
    """What `run_inverse` computed and wrote: eq. 11 sampled at t, and the torques tau."""

    model: Model
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    seconds: float  # wall time of the inverse dynamics
    files: list[Path] = field(default_factory=list)


# ----------------------------------------------------------------------------- helpers


def to_model_units(values: Sequence[float], model) -> np.ndarray:
    """User values (degrees for rotating joints, metres for prismatic ones; one value for
    every coordinate, or one per coordinate) to SI units."""
    out = np.array(values, dtype=float).ravel()
    if out.size == 1:
        out = np.full(model.dof, out[0])
    if out.size != model.dof:
        raise ValueError(f"expected {model.dof} values (one per coordinate: "
                         f"{', '.join(model.coordinates)}), got {out.size}")
    for k, body in enumerate(model.moving_bodies):
        if body.joint.type != "prismatic":
            out[k] = math.radians(out[k])
    return out


def _joints_only(model) -> _JointView:
    return _JointView(model)


class _JointView:
    """What figures read of a model (name, coordinates, moving bodies), its joints only."""

    def __init__(self, model):
        self.name = model.name
        self.moving_bodies = [b for b in model.moving_bodies if not b.joint.floating]
        self.coordinates = [b.joint.name for b in self.moving_bodies]
        self.dof = len(self.coordinates)


def shown(values: np.ndarray, model) -> str:
    """Coordinates as the user reads them: 'q1 = -60.000 deg, d2 = 0.0500 m'."""
    parts = []
    for name, body, v in zip(model.coordinates, model.moving_bodies, values):
        if body.joint.type == "prismatic":
            parts.append(f"{name} = {v:.4f} m")
        else:
            parts.append(f"{name} = {math.degrees(v):.3f} deg")
    return ", ".join(parts)


def duration_text(seconds: float) -> str:
    if seconds < 1e-3:
        return f"{seconds * 1e6:.0f} us"
    if seconds < 1.0:
        return f"{seconds * 1e3:.2f} ms"
    return f"{seconds:.2f} s"


def default_out_dir(model) -> Path:
    """out/<identifier of the model's name>: a name can never choose where files go
    (`../../x` becomes out/x, an absolute path a folder inside out/)."""
    from ..codegen.render import c_identifier

    return Path("out") / c_identifier(model.name)


def output_folder(out: str | Path | None, model) -> Path:
    """The folder to write into (created), `out` or `default_out_dir(model)`."""
    folder = Path(out) if out else default_out_dir(model)
    if folder.exists() and not folder.is_dir():
        raise NotADirectoryError(f"--out {folder}: exists and is not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def load_dynamics(model, backend: str = "compiled", cache_dir: str | Path | None = None,
                  strict: bool = False, floating_base: bool = False):
    """(Model, dynamics) of a model as the user names it, with progress on the log."""
    from ..loading import load
    from ..model.resolve import resolve_model

    resolved = resolve_model(model, strict, floating_base)
    log.info(f"loading '{resolved.name}' ({resolved.dof} coordinates) with the {backend} "
             "backend (the first compiled build of a model takes a few seconds)...")
    start = time.perf_counter()
    options = {"cache_dir": cache_dir} if backend == "compiled" else {}
    dyn = load(resolved, backend=backend, **options)
    log.info(f"loaded in {time.perf_counter() - start:.2f} s")
    return resolved, dyn


# --------------------------------------------------------------------------- simulate


def run_simulate(model="rrr", *, duration: float = 5.0, points: int = 501,
                 out: str | Path | None = None, backend: str = "compiled",
                 cache_dir: str | Path | None = None, method: str | None = None,
                 rtol: float = 1e-6, atol: float = 1e-8, step: float = 1e-3,
                 target: Sequence[float] | None = None, kp: Sequence[float] | None = None,
                 kd: Sequence[float] | None = None, gravity_compensation: bool = True,
                 gif: bool = False, strict: bool = False, floating_base: bool = False,
                 html: bool = False, package_dirs=None) -> SimulateRun:
    """Direct dynamics from rest at q = 0 under a PD law; writes the CSV and figures.

    A floating base starts at the world's origin, unrotated; the PD law drives the joints
    (a floating joint has no actuator), and the figures show the joints.

    `target` is in degrees (metres for prismatic joints); `target`, `kp`, `kd` each one
    value or one per coordinate, the controller's defaults (see the module) where None.
    `method` None: dopri5 with the compiled backend, RK45 with lambdify. `strict` refuses
    an inertia slightly off physical (gagen.load). `html` also writes simulate.html, the
    run in 3-D (`SimulationResult.to_html`; a URDF's meshes found through `package_dirs`).
    """
    from ..sim.controllers import PD, default_controller, is_paper_robot
    from ..sim.simulate import simulate

    method = method or ("dopri5" if backend == "compiled" else "RK45")
    if method in COMPILED_METHODS and backend != "compiled":
        raise ValueError(f"--method {method} needs --backend compiled; use a scipy method "
                         "(e.g. RK45) with the lambdify backend")
    model, dyn = load_dynamics(model, backend, cache_dir, strict, floating_base)
    controller = default_controller(dyn)
    if target is not None or kp is not None or kd is not None or not gravity_compensation:
        controller = PD(kp=controller.kp if kp is None else np.asarray(kp, dtype=float),
                        kd=controller.kd if kd is None else np.asarray(kd, dtype=float),
                        target=(controller.target if target is None
                                else to_model_units(target, model)),
                        gravity_compensation=gravity_compensation)
    which = "paper_controller()" if is_paper_robot(model) else "default_controller()"
    log.info(f"controller {which}: {controller!r}")
    options = {"h": step} if method == "rk4" else {}
    log.info(f"simulating {duration:g} s with {method} (rtol={rtol:g}, atol={atol:g})...")
    result = simulate(dyn, (0.0, duration), dyn.neutral(), np.zeros(dyn.n),
                      controller=controller, method=method, rtol=rtol, atol=atol,
                      t_eval=np.linspace(0.0, duration, points), **options)
    run = SimulateRun(model, dyn.backend, method, result)
    folder = output_folder(out, model)
    run.files.append(result.to_csv(folder / "simulate.csv"))
    if html:
        log.info("writing the 3-D playback (simulate.html)...")
        run.files.append(result.to_html(folder / "simulate.html", package_dirs))
    log.info("plotting...")
    from .figures import arm_gif, fig2_positions, fig3_arm

    if model.floating:
        from ..runtime.manifold import plain_entries

        plain_q, _ = plain_entries(dyn.info)
        run.files.append(fig2_positions(result.t, result.q[:, plain_q], _joints_only(model),
                                        folder / "fig2_positions.png"))
        log.info("no arm figure or animation for a floating base (the CSV has the base's "
                 "path)")
        return run
    run.files.append(fig2_positions(result.t, result.q, model, folder / "fig2_positions.png"))
    run.files.append(fig3_arm(model, result.q, folder / "fig3_arm.png", t=result.t))
    if gif:
        log.info("writing the animation (a few seconds)...")
        run.files.append(arm_gif(model, result.t, result.q, folder / "arm.gif"))
    return run


def print_simulate_report(run: SimulateRun) -> None:
    """The run's cost, final position and files, on stdout."""
    st = run.result.stats
    print(f"gagen: simulation wall time {duration_text(st['wall_time'])} ({run.method}, "
          f"{run.backend} backend): {st['steps']} steps, {st['nfev']} right-hand side "
          "evaluations")
    final = run.result.q[-1]
    if run.model.floating:
        base = ", ".join(f"{name} = {value:.4f} m" for name, value in
                         zip(run.model.configuration[:3], final[:3]))
        joints = [k for k, name in enumerate(run.model.configuration)
                  if name in run.model.coordinates]
        print(f"gagen: final base position: {base}")
        final, shown_model = final[joints], _joints_only(run.model)
    else:
        shown_model = run.model
    print(f"gagen: final position: {shown(final, shown_model)}")
    for f in run.files:
        print(f"gagen: wrote {f}")


# ---------------------------------------------------------------------------- inverse


def run_inverse(model="rrr", *, duration: float = 5.0, points: int = 501,
                out: str | Path | None = None, backend: str = "compiled",
                cache_dir: str | Path | None = None,
                qf: Sequence[float] | None = None, strict: bool = False,
                floating_base: bool = False) -> InverseRun:
    """Inverse dynamics along eq. 11 from q = 0 to `qf` (degrees, metres for prismatic
    joints; one value or one per coordinate; None: the default target) in `duration` s.
    `strict` refuses an inertia slightly off physical (gagen.load)."""
    from ..sim.controllers import default_target
    from ..sim.simulate import inverse_dynamics_along
    from ..sim.trajectory import Eq11Trajectory
    from .figures import fig4_inverse

    model, dyn = load_dynamics(model, backend, cache_dir, strict, floating_base)
    if model.floating:
        raise ValueError("eq. 11 moves every coordinate along a line from q = 0; a floating "
                         "base is not a coordinate on a line (inverse dynamics along a "
                         "trajectory of your own: gagen.inverse_dynamics_along)")
    final = default_target(model) if qf is None else to_model_units(qf, model)
    trajectory = Eq11Trajectory(np.zeros(dyn.n), final, duration)
    log.info(f"eq. 11 from q = 0 to {shown(final, model)} in Tp = {duration:g} s")
    t = np.linspace(0.0, duration, points)
    start = time.perf_counter()
    q, qd, qdd, tau = inverse_dynamics_along(dyn, trajectory, t)
    run = InverseRun(model, t, q, qd, qdd, tau, time.perf_counter() - start)
    folder = output_folder(out, model)
    run.files.append(_write_inverse_csv(run, folder / "inverse.csv"))
    log.info("plotting...")
    run.files.append(fig4_inverse(t, q, tau, model, folder / "fig4_inverse.png"))
    return run


def _write_inverse_csv(run: InverseRun, path: Path) -> Path:
    names = list(run.model.coordinates)
    header = (["t"] + names + [f"{c}_d" for c in names] + [f"{c}_dd" for c in names]
              + [f"tau_{c}" for c in names])
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow([text_cell(name) for name in header])
        for row in np.column_stack([run.t, run.q, run.qd, run.qdd, run.tau]):
            writer.writerow([repr(float(v)) for v in row])
    return path


def print_inverse_report(run: InverseRun) -> None:
    """The run's cost, each generalized force's peak and range, and the files, on stdout."""
    from .figures import _torque_names

    t, tau = run.t, run.tau
    print(f"gagen: inverse dynamics at {len(t)} times in {duration_text(run.seconds)}")
    labels, units = _torque_names(run.model, tau.shape[1])
    width = max(len(label) for label in labels)
    for k, label in enumerate(labels):
        i = int(np.argmax(np.abs(tau[:, k])))
        print(f"gagen: peak {label:<{width}} {tau[i, k]:+10.2f} {units[k]:<3} at "
              f"t = {t[i]:.2f} s (range {tau[:, k].min():+.2f} .. {tau[:, k].max():+.2f})")
    for f in run.files:
        print(f"gagen: wrote {f}")
