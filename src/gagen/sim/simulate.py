"""Direct dynamics (`simulate`) and inverse dynamics along a trajectory.

`simulate` integrates M(q) qdd = F(q, qd, tau) with tau from a controller, either through
`scipy.integrate.solve_ivp` (any method, any backend, any Python controller) or through
gagen's compiled C integrators ("dopri5", "rk4"), which run the whole simulation, gagen's
controllers included, without Python in the loop.

Coulomb friction, friction_k sign(qd_k), jumps at qd_k = 0; an adaptive integrator meeting
that jump at every reversal of a joint shrinks its steps to nothing (or chatters about 0).
So simulations, and only they, integrate it as friction_k tanh(qd_k / w), with the width w
the runtime parameter `coulomb_width` (FRICTION_WIDTH; default 0.01 rad/s or m/s, of every
model with friction): within 4e-9 of the exact force beyond |qd| > 10 w, a steep viscous
slope f / w below. The C integrators (the velocity stage of the generated simulation) and
the scipy path here use the same function with the same w; w = 0 gives the exact sign
(fine with fixed-step rk4). `dyn.forward_dynamics` and `dyn.inverse_dynamics` keep the
exact sign.
"""

from __future__ import annotations

import csv
import functools
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..csvtext import text_cell
from ..errors import NonFiniteStateError, SingularMassMatrixError
from ..manifest import FRICTION_WIDTH
from ..runtime.compiled import native
from .controllers import Controller

COMPILED_METHODS = ("dopri5", "rk4")
SCIPY_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")
DEFAULT_POINTS = 501
DEFAULT_RK4_STEP = 1e-3
# The compiled integrators stop after this many steps unless told otherwise (max_steps=):
# seconds to minutes of simulation on a big robot, where a stiff gain of 1e10 would
# otherwise run for most of an hour.
DEFAULT_MAX_STEPS = 1_000_000
_COMPILED_OPTIONS = {"dopri5": ("first_step", "max_step", "max_steps"),
                     "rk4": ("h", "max_steps")}
_NONFINITE = ("the state became NaN or inf (a controller's torques were not finite, or the "
              "motion diverged: check the gains, the parameters and the initial state)")
_STATUS = {
    -101: "the step size fell below the floating-point resolution of t (a stiff or "
          "exploding system: check the gains, the parameters and the initial state)",
    -102: f"the step budget (max_steps, default {DEFAULT_MAX_STEPS:,}) was used up; a stiff system needs a "
          "smaller gain or an implicit method such as method='Radau', or pass a larger "
          "max_steps",
    -103: "an argument was invalid (unsorted t_eval, t_eval outside t_span, NaN, ...)",
    -105: _NONFINITE,
    2: _NONFINITE,
}


@dataclass
class SimulationResult:
    """Samples of one simulation: t (m,), q (m, nq), qd and tau (m, nv), and how it went.

    (nq = nv = n unless a joint floats: see `Dynamics.configuration`.) `stats` holds `method`, `backend`, `nfev` (right-hand side evaluations), `steps`
    (accepted steps), `rejected` (rejected step attempts, adaptive methods), `wall_time`
    (seconds, integration plus torques) and `controller` (its repr).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    tau: np.ndarray
    coordinates: list[str]
    stats: dict = field(default_factory=dict)
    configuration: list[str] | None = None  # the names of q's entries, if not coordinates
    # the dynamics object and parameter vector of the run (set by gagen.simulate), which
    # to_html draws the robot with
    dyn: object = field(default=None, repr=False, compare=False)
    p: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def n(self) -> int:
        return self.qd.shape[1]

    def columns(self) -> list[str]:
        """CSV header: t, q's entries, the rates (`<name>_d`), the torques (`tau_<name>`)."""
        c = self.coordinates
        return (["t"] + list(self.configuration or c) + [f"{name}_d" for name in c]
                + [f"tau_{name}" for name in c])

    def to_csv(self, path) -> Path:
        """Write t, q, qd, tau (one row per sample, SI units, radians) to a CSV file; a
        name that a spreadsheet would take for a formula is escaped (gagen.csvtext)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        data = np.column_stack([self.t, self.q, self.qd, self.tau])
        with path.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow([text_cell(name) for name in self.columns()])
            writer.writerows([repr(float(v)) for v in row] for row in data)
        return path

    def to_html(self, path, package_dirs=None) -> Path:
        """Write one self-contained HTML file that plays the run back in 3-D: the robot with
        its meshes (a URDF's, found through `package_dirs` and $ROS_PACKAGE_PATH; MJCF
        geoms; inertia boxes for models without), a time slider, play/pause and speed.
        It plays offline in any current browser and fetches nothing. Needs
        `pip install gagen[viewer]` (gagen.viewer.write_html). Returns the path."""
        if self.dyn is None:
            raise ValueError("this result has no dynamics object (dyn): made by hand? "
                             "gagen.viewer.write_html(path, dyn, t, q) draws any run")
        from ..viewer import write_html

        return write_html(path, self.dyn, self.t, self.q, self.p, package_dirs=package_dirs)

    def __repr__(self) -> str:
        return (f"<SimulationResult {len(self.t)} samples, t in [{self.t[0]:g}, {self.t[-1]:g}], "
                f"coordinates={self.coordinates}, method={self.stats.get('method')}>")


_UNIT_GRID = np.arange(DEFAULT_POINTS, dtype=float)
_FLOAT64 = np.dtype(np.float64)


@functools.lru_cache(maxsize=16)
def _default_grid(t0: float, t1: float) -> np.ndarray:
    """np.linspace(t0, t1, 501), kept: simulations over the same span reuse it (copied)."""
    te = _UNIT_GRID * ((t1 - t0) / (DEFAULT_POINTS - 1)) + t0
    te[-1] = t1
    te.flags.writeable = False
    return te


def _vector(x, n: int, name: str) -> np.ndarray:
    """x as n finite floats; an array that already is one is returned as it is (read only)."""
    if x is None:
        return np.zeros(n)
    if type(x) is np.ndarray and x.dtype is _FLOAT64 and x.shape == (n,):
        arr = x
    else:
        arr = _converted_vector(x, n, name)
    if not all(map(math.isfinite, arr.tolist())):  # 7x faster than numpy for a few entries
        raise ValueError(f"{name} must be finite, got {arr}")
    return arr


def _converted_vector(x, n: int, name: str) -> np.ndarray:
    if isinstance(x, (str, bytes)):
        raise TypeError(f"{name} must be an array of {n} numbers, got {type(x).__name__}")
    try:
        arr = np.array(x, dtype=float).ravel()
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be an array of {n} numbers, got {x!r}") from None
    if arr.size == 1 and n > 1 and np.ndim(x) == 0:
        arr = np.full(n, arr[0])
    if arr.size != n:
        raise ValueError(f"{name} must have {n} entries (one per coordinate), got {arr.size}")
    return arr


def _time_grid(t_eval, t0: float, t1: float, allow_steps: bool) -> np.ndarray | None:
    if isinstance(t_eval, str):
        if t_eval == "steps" and allow_steps:
            return None
        raise ValueError("t_eval must be None (501 evenly spaced points), an array of times"
                         + (" or 'steps' (the solver's own steps)" if allow_steps else
                            " ('steps' is available with scipy methods only)"))
    if t_eval is None:
        return _default_grid(t0, t1).copy()
    te = np.array(t_eval, dtype=float).ravel()
    if te.size == 0:
        raise ValueError("t_eval is empty")
    lo, hi = min(t0, t1), max(t0, t1)
    if not (np.isfinite(te).all() and te.min() >= lo and te.max() <= hi):
        raise ValueError(f"t_eval must lie within t_span [{lo:g}, {hi:g}]")
    if te.size > 1 and ((te[1:] - te[:-1]) * (1.0 if t1 >= t0 else -1.0) < 0).any():
        raise ValueError("t_eval must be sorted in the direction of integration")
    return te


def _python_controller(controller, n: int):
    """A checked wrapper around a plain callable (t, q, qd) -> tau."""
    name = getattr(controller, "__name__", type(controller).__name__)

    def law(t, q, qd):
        tau = np.asarray(controller(t, q.copy(), qd.copy()), dtype=float)
        if tau.shape != (n,):
            if tau.size != n:
                raise ValueError(f"controller {name} returned torques of shape {tau.shape}; "
                                 f"expected ({n},)")
            tau = tau.reshape(n)
        if not np.isfinite(tau).all():
            raise NonFiniteStateError(f"controller {name} returned torques that are not "
                                      f"finite at t = {t:g}: {tau}")
        return tau

    return law


def simulate(dyn, t_span, q0, qd0=None, controller=None, method: str = "RK45",
             rtol: float = 1e-6, atol=1e-8, t_eval=None, p=None, fext=None,
             **options) -> SimulationResult:
    """Integrate the equations of motion of `dyn` over `t_span` from (q0, qd0).

    dyn         a dynamics object from `gagen.load` (any backend for scipy methods).
    t_span      (t0, t1); t1 < t0 integrates backwards.
    q0, qd0     initial configuration, shape (nq,), and rates, shape (nv,) (nq = nv = n
                unless a joint floats); qd0=None means at rest. A floating joint's
                quaternion is normalised; it stays on the unit sphere (dq/dt pulls it
                back, gagen.runtime.manifold) and the returned q has unit quaternions.
    controller  None (no joint torques), a gagen controller (`PD`, `ComputedTorque`,
                `paper_controller()`; bound to `dyn` and `p` here), or any callable
                (t, q, qd) -> tau of shape (n,).
    method      any `scipy.integrate.solve_ivp` method ("RK45", "DOP853", "Radau", ...),
                or "dopri5" / "rk4": gagen's C integrators (compiled backend only). "dopri5"
                takes exactly the steps of scipy's "RK45" at the same tolerances; "rk4" is
                classical fixed-step RK4 with step `h` (option, default 1e-3 s).
    rtol, atol  tolerances of the adaptive methods (atol: scalar or one per state entry).
    t_eval      times of the output samples; default (None) 501 evenly spaced points over
                t_span for every method. With scipy methods, t_eval="steps" returns the
                solver's own steps instead. Samples between steps come from the
                method's dense output (rk4: cubic Hermite), accurate to the tolerances.
    p           None (defaults), a dict of parameter overrides, or a full array. With
                Coulomb friction, its `coulomb_width` is the width w of the smooth sign
                tanh(qd / w) the integration uses (module docstring; 0: exact sign).
    fext        constant wrenches on frames, {frame: (fx, fy, fz, tx, ty, tz)} in world
                axes at the frames' origins (a support, a payload's weight): their
                generalised force J(q)^T w acts with the controller's torques (tau reports
                the controller's torques alone).
    options     scipy methods: passed on to solve_ivp (first_step, max_step, ...);
                dopri5: first_step, max_step, max_steps; rk4: h.

    A plain Python callable controller cannot run inside the C integrators: with "dopri5"
    or "rk4" it raises ValueError, pointing to method="RK45" (the same Dormand-Prince
    steps through scipy). So does a ComputedTorque whose trajectory is not an
    Eq11Trajectory.

    Returns a `SimulationResult` (fresh arrays). Raises `SingularMassMatrixError` if the
    mass matrix becomes singular, RuntimeError naming the cause if the integration fails.
    """
    t0, t1 = _pair(t_span)
    q0 = initial_configuration(dyn, _vector(q0, dyn.nq, "q0"))
    qd0 = _vector(qd0, dyn.nv, "qd0")
    rtol, atol_arr = checked_tolerances(method, rtol, atol, dyn.nq + dyn.nv)
    pvec = dyn.parameter_vector(p)
    if controller is not None and not callable(controller):
        raise TypeError("controller must be None, a gagen controller or a callable "
                        "(t, q, qd) -> tau")
    wrenches = constant_wrenches(dyn, fext)
    if isinstance(method, str) and method in COMPILED_METHODS:
        result = _simulate_compiled(dyn, t0, t1, q0, qd0, controller, method, rtol, atol_arr,
                                    t_eval, pvec, options, wrenches)
    else:
        result = _simulate_scipy(dyn, t0, t1, q0, qd0, controller, method, rtol, atol_arr,
                                 t_eval, pvec, options, wrenches)
    result.dyn, result.p = dyn, pvec
    return result


def constant_wrenches(dyn, fext) -> tuple[np.ndarray, np.ndarray] | None:
    """fext = {frame: wrench} as (frame numbers (k,), wrenches (k, 6)), checked; or None."""
    if not fext:
        return None
    from ..runtime.frames import external_wrenches

    pairs = external_wrenches(dyn.info, fext, None)
    return (np.array([k for k, _ in pairs], dtype=np.int32),
            np.array([w for _, w in pairs], dtype=float))


def initial_configuration(dyn, q0: np.ndarray) -> np.ndarray:
    """q0, with each floating joint's quaternion normalised (ValueError for one that cannot
    be: zero, or with a squared norm that overflows or underflows)."""
    if dyn.nq == dyn.nv:
        return q0
    from ..runtime.inputs import check_quaternions
    from ..runtime.manifold import normalized

    check_quaternions(q0, dyn.info.quaternions(), "q0")
    return normalized(dyn.info, q0)


def checked_tolerances(method, rtol, atol, size: int):
    """(rtol, atol) checked: the method a name or a solver class, rtol positive and finite,
    atol nonnegative and finite (a float, or one entry per state: `size` = nq + nv)."""
    if not isinstance(method, str) and not isinstance(method, type):
        raise TypeError(f"method must be a string, got {type(method).__name__}")
    rtol = float(rtol)
    if not (rtol > 0 and math.isfinite(rtol)):
        raise ValueError(f"rtol must be a positive finite number, got {rtol}")
    return rtol, _atol(atol, size)


def _atol(atol, size: int):
    """A nonnegative finite float, or an array of one such entry per state."""
    if isinstance(atol, (float, int)) and not isinstance(atol, bool) and 0 <= atol < math.inf:
        return float(atol)
    try:
        arr = np.array(atol, dtype=float)
    except (TypeError, ValueError):
        arr = np.array([np.nan])
    if arr.ndim > 1 or (arr.ndim == 1 and arr.size != size) \
            or not ((arr >= 0) & np.isfinite(arr)).all():
        raise ValueError(f"atol must be a nonnegative finite number or an array of {size} "
                         "such entries (q then qd)")
    return arr


def _pair(t_span):
    try:
        t0, t1 = t_span
        t0, t1 = float(t0), float(t1)
    except (TypeError, ValueError):
        raise ValueError(f"t_span must be a pair (t0, t1) of numbers, got {t_span!r}") from None
    if not (math.isfinite(t0) and math.isfinite(t1)):
        raise ValueError(f"t_span must be finite, got {t_span!r}")
    return t0, t1


def _simulate_scipy(dyn, t0, t1, q0, qd0, controller, method, rtol, atol, t_eval, pvec,
                    options, wrenches=None) -> SimulationResult:
    from scipy.integrate import OdeSolver, solve_ivp

    if isinstance(method, type) and issubclass(method, OdeSolver):
        pass
    elif method not in SCIPY_METHODS:
        raise ValueError(f"unknown method '{method}': use a scipy.integrate.solve_ivp method "
                         f"({', '.join(SCIPY_METHODS)}) or one of gagen's compiled "
                         f"integrators ({', '.join(COMPILED_METHODS)})")
    if "h" in options:
        raise TypeError("option 'h' (fixed step) belongs to method 'rk4'")
    for key in ("dense_output", "events", "vectorized", "args"):
        if key in options:
            raise TypeError(f"option '{key}' is not supported by gagen.simulate")
    te = _time_grid(t_eval, t0, t1, allow_steps=True)
    n, nq = dyn.nv, dyn.nq
    if controller is None:
        law = None
        vectorised = None
    elif isinstance(controller, Controller):
        law = controller.bind(dyn, pvec)
        vectorised = law
    else:
        law = _python_controller(controller, n)
        vectorised = None
    zero = np.zeros(n)
    fd = dyn.forward_dynamics
    rate = _configuration_rate(dyn)
    fext = None if wrenches is None else dict(zip(wrenches[0].tolist(), wrenches[1]))
    smoothing = smooth_friction(dyn, pvec)

    reached = [t0]  # the last time the right-hand side was evaluated at

    def rhs(t, y):
        reached[0] = t
        q = y[:nq]
        qd = y[nq:]
        tau = zero if law is None else law(t, q, qd)
        if smoothing is not None:
            tau = tau + smoothing(qd)
        return np.concatenate((rate(q, qd), fd(q, qd, tau, pvec, fext=fext)))

    start = time.perf_counter()
    name = method if isinstance(method, str) else method.__name__
    y0 = np.concatenate((q0, qd0))
    if t0 == t1:  # solve_ivp returns no samples for an empty span: the state stays y0
        t = np.full(1 if te is None else te.size, t0)
        y = np.tile(y0, (t.size, 1))
        sol = _EmptySpan(t.size)
    else:
        try:
            sol = solve_ivp(rhs, (t0, t1), y0, method=method, t_eval=te, rtol=rtol,
                            atol=atol, dense_output=True, **options)
        except NonFiniteStateError:
            tau0 = None
            if law is not None:
                with np.errstate(all="ignore"):
                    try:
                        tau0 = np.asarray(law(t0, q0, qd0), dtype=float)
                    except NonFiniteStateError as exc:
                        raise NonFiniteStateError(f"{name} failed at the initial state: "
                                                  f"{exc}") from None
            origin = nonfinite_origin(dyn, q0, qd0, pvec, tau0, fext)
            if origin is None:
                raise NonFiniteStateError(f"{name} failed at t = {reached[0]:g}: "
                                          f"{_NONFINITE}") from None
            raise NonFiniteStateError(f"{name} failed at the initial state: {origin}") from None
        if sol.status < 0:
            raise RuntimeError(f"{name} failed: {sol.message} (at t = {sol.t[-1]:g} of "
                               f"[{t0:g}, {t1:g}])")
        t = np.array(sol.t, dtype=float)
        y = np.array(sol.y.T, dtype=float)
    q, qd = unit_quaternions(dyn, y[:, :nq].copy()), y[:, nq:].copy()
    if law is None:
        tau = np.zeros_like(qd)
    elif vectorised is not None:
        tau = np.array(vectorised(t, q, qd), dtype=float).reshape(len(t), n)
    else:
        tau = np.array([law(ti, qi, qdi) for ti, qi, qdi in zip(t, q, qd)],
                       dtype=float).reshape(len(t), n)
    wall = time.perf_counter() - start
    steps = len(sol.sol.ts) - 1 if sol.sol is not None else (0 if t0 == t1 else len(t) - 1)
    stats = {"method": name, "backend": dyn.backend, "nfev": int(sol.nfev),
             "steps": int(steps), "rejected": None, "njev": int(sol.njev),
             "nlu": int(sol.nlu), "wall_time": wall, "controller": _name(controller),
             "message": sol.message}
    return _result(dyn, t, q, qd, tau, stats)


def _result(dyn, t, q, qd, tau, stats) -> SimulationResult:
    configuration = None if dyn.nq == dyn.nv else list(dyn.configuration)
    return SimulationResult(t, q, qd, tau, list(dyn.coordinates), stats, configuration)


def _configuration_rate(dyn):
    """dq/dt as a function of (q, qd): qd itself unless a joint floats."""
    if dyn.nq == dyn.nv:
        return lambda q, qd: qd
    from ..runtime.manifold import configuration_rate

    return lambda q, qd: configuration_rate(dyn.info, q, qd)


def unit_quaternions(dyn, q: np.ndarray) -> np.ndarray:
    """Samples of q, (m, nq), with each floating joint's quaternion of unit norm (in place)."""
    if dyn.nq == dyn.nv:
        return q
    from ..runtime.manifold import normalized

    q[:] = normalized(dyn.info, q)
    return q


def smooth_friction(dyn, pvec: np.ndarray):
    """The torque that turns the exact Coulomb friction of `dyn.forward_dynamics` into the
    simulations' smooth one (module docstring): qd -> friction * (sign(qd) - tanh(qd / w)),
    added to the joint torques; None when there is nothing to smooth."""
    names = list(dyn.parameters)
    if FRICTION_WIDTH not in names:
        return None
    width = float(pvec[names.index(FRICTION_WIDTH)])
    friction = dyn.joint_terms(pvec)[1]
    if width <= 0 or not friction.any():
        return None
    return lambda qd: friction * (np.sign(qd) - np.tanh(qd / width))


@dataclass
class _EmptySpan:
    """What the statistics read of solve_ivp's result, for a span of zero length."""

    samples: int
    nfev: int = 0
    njev: int = 0
    nlu: int = 0
    sol: None = None
    message: str = "The span has zero length: the state stays the initial state."


@dataclass(frozen=True)
class CompiledSettings:
    """What every run of a compiled integration shares: the arguments of
    `CompiledSimulation.run` besides the initial state, checked once (`compiled_settings`)."""

    method: str
    t0: float
    t1: float
    t_eval: np.ndarray
    rtol: float
    atol: float | np.ndarray
    first_step: float
    max_step: float
    max_steps: int
    h: float

    def run(self, sim, q0, qd0):
        """sim.run(...) from (q0, qd0): (q, qd, tau, status, info)."""
        return sim.run(self.method, self.t0, self.t1, q0, qd0, self.t_eval, self.rtol,
                       self.atol, self.first_step, self.max_step, self.max_steps, self.h)


def compiled_settings(dyn, method: str, t0: float, t1: float, rtol: float, atol, t_eval,
                      options: dict) -> CompiledSettings:
    """Check what a compiled integration needs (the compiled backend, the method's options,
    the time grid, the step sizes and budget) and gather it."""
    if getattr(dyn, "backend", None) != "compiled" or not hasattr(dyn, "kernels"):
        raise ValueError(f"method '{method}' is gagen's compiled integrator and needs the "
                         f"compiled backend (gagen.load(model, backend='compiled')); this "
                         f"dynamics object uses the '{getattr(dyn, 'backend', '?')}' backend: "
                         "use a scipy method such as method='RK45' instead")
    allowed = _COMPILED_OPTIONS[method]
    unknown = [k for k in options if k not in allowed]
    if unknown:
        raise TypeError(f"method '{method}' takes the options {', '.join(allowed)}; "
                        f"got {', '.join(unknown)}")
    te = _time_grid(t_eval, t0, t1, allow_steps=False)
    h = float(options.get("h", DEFAULT_RK4_STEP))
    if method == "rk4" and not (math.isfinite(h) and h > 0):
        raise ValueError(f"h must be a positive step size, got {h}")
    first_step = float(options.get("first_step") or 0.0)
    max_step = options.get("max_step")
    max_step = 0.0 if max_step is None or not math.isfinite(max_step) else float(max_step)
    max_steps = _max_steps(options.get("max_steps"))
    if first_step < 0 or max_step < 0:
        raise ValueError("first_step and max_step must be positive")
    if method == "rk4" and abs(t1 - t0) / h > max_steps:
        raise ValueError(f"rk4 with h = {h:g} over {abs(t1 - t0):g} s takes "
                         f"{abs(t1 - t0) / h:.3g} steps, more than max_steps = {max_steps:,}: "
                         "use a larger h, or pass a larger max_steps")
    return CompiledSettings(method, t0, t1, te, rtol, atol, first_step, max_step, max_steps, h)


_PYTHON_CONTROLLER_ADVICE = {
    "simulate": "or a scipy method such as method='RK45' (the same Dormand-Prince 5(4) "
                "steps as 'dopri5')",
    "simulate_batch": "or a list of them, one per run; for a Python controller, loop over "
                      "gagen.simulate with a scipy method such as method='RK45'",
}


def controller_spec(controller, method: str, n: int, caller: str = "simulate",
                    dyn=None) -> dict:
    """The keyword arguments of `CompiledSimulation` for a controller (None or a gagen
    controller with a C form); ValueError for a Python callable, which C cannot call."""
    if controller is None:
        return {"kind": 0}
    if isinstance(controller, Controller):
        if dyn is not None:
            controller.bind(dyn)  # checks that the law suits the model (a floating base)
        spec = controller.c_spec(n)  # checks the sizes against the model
        if spec is None:
            raise ValueError(f"{controller!r} has no C form (only an Eq11Trajectory runs in "
                             f"the compiled integrator): use a scipy method such as "
                             f"method='RK45'")
        return spec
    if caller == "simulate_batch":
        raise ValueError("gagen.simulate_batch runs every run in C and cannot call a Python "
                         f"controller ({_name(controller)}): use a gagen controller (PD, "
                         "ComputedTorque with an Eq11Trajectory), "
                         + _PYTHON_CONTROLLER_ADVICE[caller])
    raise ValueError(f"method '{method}' runs the whole simulation in C and cannot call a "
                     "Python controller: use a gagen controller (PD, ComputedTorque with "
                     "an Eq11Trajectory), " + _PYTHON_CONTROLLER_ADVICE[caller])


SUCCESS_MESSAGE = "The solver successfully reached the end of the integration interval."


def _simulate_compiled(dyn, t0, t1, q0, qd0, controller, method, rtol, atol, t_eval, pvec,
                       options, wrenches=None) -> SimulationResult:
    settings = compiled_settings(dyn, method, t0, t1, rtol, atol, t_eval, options)
    spec = controller_spec(controller, method, dyn.n, dyn=dyn)
    if wrenches is not None:
        spec = {**spec, "frames": wrenches[0], "wrenches": wrenches[1]}
    start = time.perf_counter()
    sim = native().CompiledSimulation(dyn.kernels, pvec, **spec)
    q, qd, tau, status, info = settings.run(sim, q0, qd0)
    q = unit_quaternions(dyn, q)
    te = settings.t_eval
    if status != 0:
        origin = None
        if status in (2, -105):
            tau0 = sim.torques(np.array([t0]), np.concatenate((q0, qd0))[None, :])[0][0]
            fext = None if wrenches is None else dict(zip(wrenches[0].tolist(), wrenches[1]))
            origin = nonfinite_origin(dyn, q0, qd0, pvec, tau0, fext)
        raise status_error(status, method, te, q, dyn.info.name, origin)
    wall = time.perf_counter() - start
    stats = {"method": method, "backend": dyn.backend, "nfev": info["nfev"],
             "steps": info["naccepted"],
             "rejected": info["nrejected"] if method == "dopri5" else None,
             "wall_time": wall, "controller": _name(controller),
             "message": SUCCESS_MESSAGE}
    return _result(dyn, te, q, qd, tau, stats)


def _max_steps(value) -> int:
    """The step budget of a compiled integrator: a positive integer, DEFAULT_MAX_STEPS if None."""
    if value is None:
        return DEFAULT_MAX_STEPS
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0 \
            or value > 2**62:
        raise ValueError(f"max_steps must be a positive integer, got {value!r}")
    return int(value)


def _name(controller) -> str | None:
    if controller is None:
        return None
    return getattr(controller, "__name__", None) or type(controller).__name__


def nonfinite_origin(dyn, q0, qd0, p, tau0=None, fext=None) -> str | None:
    """What is not finite at a simulation's initial state, and which entry made it so: the
    controller's first torques, the mass matrix at q0, the external wrenches' forces, or the
    velocity and gravity terms (the entry of q0 or qd0 whose products overflow); None when
    the initial state is sound (the motion diverged later)."""
    q0, qd0 = np.asarray(q0, dtype=float), np.asarray(qd0, dtype=float)
    zero = np.zeros(dyn.nv)
    with np.errstate(all="ignore"):
        if tau0 is not None and not np.isfinite(tau0).all():
            return ("the controller's torques at the initial state are not finite ("
                    + _largest(np.where(np.isfinite(tau0), 0.0, np.inf), "tau", dyn.coordinates)
                    + "): check its gains and target")
        try:
            mass = dyn.mass_matrix(q0, p)
            forces = None if not fext else dyn.external_forces(q0, fext, p)
            still = dyn.forcing(q0, zero, zero if tau0 is None else tau0, p)
            moving = dyn.forcing(q0, qd0, zero if tau0 is None else tau0, p)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            return None
    if not np.isfinite(mass).all():
        return ("the mass matrix at the initial q0 is not finite: "
                + _largest(q0, "q0", dyn.configuration) + " is too large for its products")
    if forces is not None and not np.isfinite(forces).all():
        return "the external wrenches' joint forces at the initial q0 are not finite"
    if not np.isfinite(still).all():
        return ("the gravity and position terms at the initial q0 are not finite: "
                + _largest(q0, "q0", dyn.configuration) + " is too large for their products")
    if not np.isfinite(moving).all():
        return ("the velocity terms at the initial qd0 are not finite: "
                + _largest(qd0, "qd0", dyn.coordinates) + " is too large for their products "
                "(its square overflows)")
    return None


def _largest(values: np.ndarray, name: str, names: list[str]) -> str:
    """'qd0[2] (q3) = 1e+200': the entry of largest magnitude."""
    k = int(np.argmax(np.abs(values)))
    return f"{name}[{k}] ({names[k]}) = {values[k]:.3g}"


def status_error(status: int, method: str, te, q, model_name: str,
                 origin: str | None = None) -> Exception:
    """The exception for a compiled integration's nonzero status, saying where it stopped
    (q holds NaN in the rows not reached) and, for NaN or inf, where it came from when the
    initial state was the cause (`origin`, from nonfinite_origin)."""
    reached = ~np.isnan(q).any(axis=1)
    where = f" after t = {te[reached][-1]:g}" if reached.any() else " before the first sample"
    if status in (2, -105) and origin:
        return NonFiniteStateError(f"{method} failed{where}: {origin}")
    if status == 1:
        return SingularMassMatrixError(
            f"{method}: the mass matrix of '{model_name}' became singular or not positive "
            f"definite{where}; check the parameters (zero or negative masses, inertias) and "
            "the state for NaN or inf")
    if status in (2, -105):
        return NonFiniteStateError(f"{method} failed{where}: {_NONFINITE}")
    cause = _STATUS.get(status, f"the model returned error code {status}")
    return RuntimeError(f"{method} failed{where}: {cause} (status {status})")


def inverse_dynamics_along(dyn, trajectory, t, p=None):
    """(q, qd, qdd, tau) of `trajectory` sampled at the times t, each of shape (m, n).

    `trajectory` maps an array of times to (q, qd, qdd) of shape (m, n) (e.g. an
    `Eq11Trajectory`); the torques come from one stacked `dyn.inverse_dynamics` call.
    """
    tt = np.atleast_1d(np.asarray(t, dtype=float))
    if tt.ndim != 1:
        raise ValueError(f"t must be a 1-D array of times, got shape {tt.shape}")
    q, qd, qdd = (np.array(a, dtype=float).reshape(tt.size, dyn.n) for a in trajectory(tt))
    tau = np.array(dyn.inverse_dynamics(q, qd, qdd, p), dtype=float).reshape(tt.size, dyn.n)
    return q, qd, qdd, tau
