"""Many simulations at once: `simulate_batch` runs N compiled simulations over OS threads
(without the GIL), or over a Dask cluster (`client=`).

Every run is the C call that `gagen.simulate(method="dopri5" | "rk4")` makes, with its own
initial state, parameters and controller, so it gives exactly the numbers `simulate` gives.
A run that fails (a singular mass matrix, a diverging state, a used-up step budget) is
reported in `status` and `message` and leaves the others alone.

The inputs are checked once and laid out as tables the C batch reads (`BatchPlan`): one
row per run, or a single row that every run shares (a scalar parameter, one controller).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..runtime.compiled import native
from ..runtime.inputs import as_float_array
from .simulate import (
    COMPILED_METHODS,
    SUCCESS_MESSAGE,
    CompiledSettings,
    SimulationResult,
    _pair,
    _vector,
    checked_tolerances,
    compiled_settings,
    constant_wrenches,
    controller_spec,
    initial_configuration,
    nonfinite_origin,
    status_error,
    unit_quaternions,
)

# Columns of the C batch's per-run statistics (CompiledBatch: gagen_ode_stats and status).
STATUS, NFEV, NSTEPS, NACCEPTED, NREJECTED = range(5)
# A run of a Dask chunk that failed on its worker after its retries (not a C status).
STATUS_CHUNK_FAILED = -201
# Failed runs whose NaN is traced to its origin (nonfinite_origin: a few dynamics calls each)
DIAGNOSED_RUNS = 1000
# How often the waiting thread reports progress and notices Ctrl-C, in seconds.
_WAIT_SECONDS = 0.1
Progress = Callable[[int, int], None]


# ------------------------------------------------------------------------------- plan


@dataclass
class BatchPlan:
    """The runs of a batch, checked, as the C batch reads them (picklable: a Dask chunk
    is the plan of some of its rows).

    y0 (N, nq + nv): each run's (q0, qd0); p (N or 1, P); control: the controllers' tables
    (kind, gravity_compensation, kp, kd, target, traj_q0, traj_qf, traj_Tp), N or 1 rows;
    offset: the index of the first run in the whole batch; wrenches: the constant external
    wrenches every run shares, (frame numbers (k,), wrenches (k, 6)), or None.
    """

    settings: CompiledSettings
    y0: np.ndarray
    p: np.ndarray
    control: dict[str, np.ndarray]
    offset: int = 0
    wrenches: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def runs(self) -> int:
        return self.y0.shape[0]

    def rows(self, start: int, stop: int) -> BatchPlan:
        """The plan of runs start .. stop-1 (tables shared by every run stay shared)."""
        def pick(a: np.ndarray) -> np.ndarray:
            return a if a.shape[0] == 1 else a[start:stop]

        return BatchPlan(self.settings, self.y0[start:stop], pick(self.p),
                         {k: pick(v) for k, v in self.control.items()}, self.offset + start,
                         self.wrenches)


_CONTROL_VECTORS = ("kp", "kd", "target", "traj_q0", "traj_qf")


def prepare_batch(dyn, t_span, q0, qd0=None, controller=None, p=None, method: str = "dopri5",
                  rtol: float = 1e-6, atol=1e-8, t_eval=None, fext=None,
                  **options) -> BatchPlan:
    """Check a batch's inputs (the checks of `gagen.simulate`, per run) into a `BatchPlan`."""
    n, nq = dyn.nv, dyn.nq
    t0, t1 = _pair(t_span)
    if not (isinstance(method, str) and method in COMPILED_METHODS):
        raise ValueError(f"simulate_batch runs gagen's compiled integrators: method must be "
                         f"one of {', '.join(COMPILED_METHODS)}, got {method!r}")
    rtol, atol = checked_tolerances(method, rtol, atol, nq + n)
    settings = compiled_settings(dyn, method, t0, t1, rtol, atol, t_eval, options)
    controllers = _controller_list(controller)
    runs = _run_count(q0=_rows_of(q0, 2), qd0=_rows_of(qd0, 2), p=_parameter_rows(p),
                      controller=None if controllers is None else len(controllers))
    y0 = np.empty((runs, nq + n))
    y0[:, :nq] = _states(q0, runs, nq, "q0")
    y0[:, nq:] = _states(qd0, runs, n, "qd0")
    if nq != n:
        y0[:, :nq] = [initial_configuration(dyn, row) for row in y0[:, :nq]]
    table = _parameter_table(dyn, p, runs)
    specs = ([controller_spec(controller, method, n, "simulate_batch", dyn)]
             if controllers is None
             else [controller_spec(c, method, n, "simulate_batch", dyn) for c in controllers])
    return BatchPlan(settings, y0, table, _control_tables(specs, n, nq),
                     wrenches=constant_wrenches(dyn, fext))


def _controller_list(controller) -> list | None:
    """A sequence of per-run controllers as a list; None for one controller (or none)."""
    if isinstance(controller, Sequence) and not isinstance(controller, (str, bytes)):
        if len(controller) == 0:
            raise ValueError("controller is an empty list: give one controller, or one per run")
        return list(controller)
    if isinstance(controller, np.ndarray):
        raise TypeError("controller must be None, a gagen controller or a list of them")
    return None


def _rows_of(x, stacked_ndim: int) -> int | None:
    """The number of runs an input gives (its first axis when stacked), None if shared."""
    if x is None or isinstance(x, (str, bytes, Mapping)):
        return None
    ndim = np.ndim(x)
    return int(np.shape(x)[0]) if ndim == stacked_ndim else None


def _parameter_rows(p) -> int | None:
    if isinstance(p, Mapping):
        sizes = {int(np.shape(v)[0]) for v in p.values()
                 if not isinstance(v, (str, bytes)) and np.ndim(v) == 1}
        if len(sizes) > 1:
            raise ValueError(f"the per-run parameters in p have different lengths: "
                             f"{sorted(sizes)}")
        return sizes.pop() if sizes else None
    return _rows_of(p, 2)


def _run_count(**rows: int | None) -> int:
    """The common number of runs of the stacked inputs (1 when nothing is stacked)."""
    given = {name: r for name, r in rows.items() if r is not None}
    if len(set(given.values())) > 1:
        raise ValueError("the stacked inputs disagree on the number of runs: "
                         + ", ".join(f"{name} has {r}" for name, r in given.items()))
    runs = next(iter(given.values()), 1)
    if runs < 1:
        raise ValueError("a batch needs at least one run; the stacked inputs have 0 rows")
    return runs


def _states(x, runs: int, n: int, name: str) -> np.ndarray:
    """Initial coordinates or rates: (n,) shared by every run, or (runs, n); finite."""
    if x is None or np.ndim(x) < 2:
        return _vector(x, n, name)
    arr = as_float_array(x, name)
    if arr.shape != (runs, n):
        raise ValueError(f"{name} must have shape ({n},) or (N, {n}); got {arr.shape}")
    _require_finite(arr, name)
    return arr


def _require_finite(arr: np.ndarray, name: str) -> None:
    bad = np.flatnonzero(~np.isfinite(arr.reshape(arr.shape[0], -1)).all(axis=1))
    if bad.size:
        raise ValueError(f"{name} must be finite; run {int(bad[0])} is {arr[bad[0]]}")


def _parameter_table(dyn, p, runs: int) -> np.ndarray:
    """p as (1, P) (one vector for every run) or (runs, P), in `dyn.parameters` order.

    p is None, a full vector, an (N, P) array, or a dict whose values are numbers or (N,)
    arrays; names and numbers are checked by `dyn.parameter_vector`, as in `simulate`.
    """
    if isinstance(p, Mapping):
        per_run = {k: v for k, v in p.items()
                   if not isinstance(v, (str, bytes)) and np.ndim(v) == 1}
        shared = {k: v for k, v in p.items() if k not in per_run}
        base = dyn.parameter_vector(shared)
        if not per_run:
            return base[None, :]
        index = {name: k for k, name in enumerate(dyn.parameters)}
        dyn.parameter_vector({k: 0.0 for k in per_run})  # unknown names: its KeyError
        table = np.tile(base, (runs, 1))
        for key, values in per_run.items():
            column = as_float_array(values, f"p['{key}']")
            _require_finite(column[:, None], f"p['{key}']")
            table[:, index[key]] = column
        return table
    if p is not None and np.ndim(p) == 2:
        table = np.ascontiguousarray(as_float_array(p, "p"))
        if table.shape != (runs, len(dyn.parameters)):
            raise ValueError(f"p must have shape (N, {len(dyn.parameters)}) (one row of "
                             f"dyn.parameters per run); got {table.shape}")
        _require_finite(table, "p")
        return table
    return dyn.parameter_vector(p)[None, :]


def _control_tables(specs: list[dict], n: int, nq: int) -> dict[str, np.ndarray]:
    """The controllers' C descriptions as tables, one row per spec (absent arrays: zeros,
    which the C controller reads as it reads NULL); gains and targets have n entries, the
    trajectory's configurations nq."""
    rows = len(specs)
    tables = {"kind": np.zeros((rows, 1), np.int32),
              "gravity_compensation": np.zeros((rows, 1), np.int32),
              "traj_Tp": np.ones((rows, 1))}
    tables.update({name: np.zeros((rows, nq if name.startswith("traj_q") else n))
                   for name in _CONTROL_VECTORS})
    for r, spec in enumerate(specs):
        tables["kind"][r] = spec["kind"]
        tables["gravity_compensation"][r] = bool(spec.get("gravity_compensation", False))
        tables["traj_Tp"][r] = float(spec.get("traj_Tp", 1.0))
        for name in _CONTROL_VECTORS:
            if spec.get(name) is not None:
                tables[name][r] = spec[name]
    return tables


# ----------------------------------------------------------------------------- running


def default_threads() -> int:
    """The cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def run_plan(dyn, plan: BatchPlan, threads: int = 1, progress: Progress | None = None):
    """Run a plan here, over `threads` OS threads: (q, qd, tau, stats (N, 5) int64)."""
    s = plan.settings
    runs, m, n = plan.runs, s.t_eval.size, dyn.nv
    q = np.empty((runs, m, dyn.nq))
    qd, tau = (np.empty((runs, m, n)) for _ in range(2))
    stats = np.zeros((runs, 5), np.int64)
    c = plan.control
    frames, wrenches = plan.wrenches if plan.wrenches is not None else (None, None)
    batch = native().CompiledBatch(
        dyn.kernels, s.method, s.t0, s.t1, s.t_eval, s.rtol, s.atol, s.first_step, s.max_step,
        s.max_steps, s.h, plan.y0, plan.p, c["kind"], c["gravity_compensation"], c["kp"],
        c["kd"], c["target"], c["traj_q0"], c["traj_qf"], c["traj_Tp"], q, qd, tau, stats,
        frames=frames, wrenches=wrenches)
    _run_on_threads(batch, runs, threads, progress)
    return unit_quaternions(dyn, q.reshape(-1, dyn.nq)).reshape(q.shape), qd, tau, stats


def _run_on_threads(batch, runs: int, threads: int, progress: Progress | None) -> None:
    """batch.run over slices of runs, handed out one at a time to `threads` threads (a slow
    run does not hold up a fixed share); this thread waits, reports progress and catches
    Ctrl-C, which it passes on to the runs through batch.stop()."""
    threads = max(1, min(threads, runs))
    size = max(1, min(256, runs // (threads * 16)))
    slices = iter(range(0, runs, size))
    lock = threading.Lock()
    done = [0]
    errors: list[BaseException] = []

    def work() -> None:
        try:
            while True:
                with lock:
                    start = next(slices, None)
                if start is None:
                    return
                stop = min(start + size, runs)
                if not batch.run(start, stop):
                    return
                with lock:
                    done[0] += stop - start
        except BaseException as exc:  # noqa: BLE001 - handed to the waiting thread
            errors.append(exc)
            batch.stop()

    workers = [threading.Thread(target=work, name=f"gagen-batch-{k}", daemon=True)
               for k in range(threads)]
    for w in workers:
        w.start()
    try:
        for w in workers:
            while w.is_alive():
                w.join(_WAIT_SECONDS)
                if progress is not None:
                    progress(done[0], runs)
    except BaseException:
        batch.stop()
        for w in workers:
            w.join()
        raise
    if errors:
        raise errors[0]
    if progress is not None:
        progress(runs, runs)


# ------------------------------------------------------------------------------ result


@dataclass
class BatchResult:
    """N simulations sampled on one time grid.

    t (m,); q, qd, tau (N, m, n); per run: `status` (0: reached the end; otherwise the
    compiled integrator's code, as `gagen.simulate` would raise it), `message` (the text of
    that exception, or the success message), `nfev` (right-hand side evaluations), `steps`
    (accepted steps) and `rejected` (rejected step attempts; 0 for rk4). A failed run's
    samples after its last good one are NaN, and so are all its torques. `stats` describes
    the whole batch: method, backend, runs, failed, threads, chunks, wall_time.
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    tau: np.ndarray
    status: np.ndarray
    message: list[str]
    nfev: np.ndarray
    steps: np.ndarray
    rejected: np.ndarray
    coordinates: list[str]
    stats: dict = field(default_factory=dict)
    # the dynamics object and the parameter table (N or 1 rows) of the runs
    dyn: object = field(default=None, repr=False, compare=False)
    p: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.status)

    @property
    def ok(self) -> np.ndarray:
        """Which runs reached the end of the span (a boolean mask of shape (N,))."""
        return self.status == 0

    def run(self, i: int) -> SimulationResult:
        """Run i as `gagen.simulate` returns it (fresh arrays)."""
        stats = {"method": self.stats.get("method"), "backend": self.stats.get("backend"),
                 "nfev": int(self.nfev[i]), "steps": int(self.steps[i]),
                 "rejected": int(self.rejected[i]), "message": self.message[i]}
        nq = self.q.shape[-1]
        return SimulationResult(self.t.copy(), np.array(self.q[i]), np.array(self.qd[i]),
                                np.array(self.tau[i]), list(self.coordinates), stats,
                                None if nq == len(self.coordinates) else
                                list(getattr(self.dyn, "configuration", [])) or None,
                                dyn=self.dyn, p=self._parameters(i))

    def _parameters(self, i: int) -> np.ndarray | None:
        if self.p is None:
            return None
        return np.array(self.p[0 if self.p.shape[0] == 1 else i])

    def to_html(self, path, runs=None, mode: str = "overlay", package_dirs=None):
        """One self-contained HTML file that plays chosen runs back in 3-D (needs
        `pip install gagen[viewer]`): `runs` (indices; default the first 10 that reached
        the end) drawn together, the first opaque and the others ghosted (`mode="overlay"`),
        or one after the other, labelled (`mode="sequence"`). Each run is placed with its
        own parameters. Returns the path (gagen.viewer.write_html)."""
        if self.dyn is None:
            raise ValueError("this batch has no dynamics object (dyn)")
        chosen = chosen_runs(self.ok, runs)
        from ..viewer import write_html

        return write_html(path, self.dyn, self.t, self.q[chosen],
                          [self._parameters(i) for i in chosen], package_dirs=package_dirs,
                          mode=mode, labels=[f"run {i}" for i in chosen])

    def __repr__(self) -> str:
        return (f"<BatchResult {len(self)} runs ({int((~self.ok).sum())} failed), "
                f"{len(self.t)} samples, t in [{self.t[0]:g}, {self.t[-1]:g}], "
                f"method={self.stats.get('method')}>")


def batch_result(dyn, plan: BatchPlan, q, qd, tau, stats: np.ndarray,
                 failures: Mapping[int, str] | None = None) -> BatchResult:
    """Assemble a result; `failures` maps runs that have no C status (a failed Dask chunk)
    to their message."""
    s = plan.settings
    status = stats[:, STATUS].astype(np.int32)
    message = [SUCCESS_MESSAGE] * len(status)
    diagnosed = 0
    for i in np.flatnonzero(status):
        origin = None
        if status[i] in (2, -105) and diagnosed < DIAGNOSED_RUNS:
            origin = _nonfinite_origin(dyn, plan, int(i))
            diagnosed += 1
        message[i] = (failures or {}).get(int(i)) or str(
            status_error(int(status[i]), s.method, s.t_eval, np.asarray(q[i]), dyn.info.name,
                         origin))
    return BatchResult(s.t_eval.copy(), q, qd, tau, status, message,
                       stats[:, NFEV].copy(), stats[:, NACCEPTED].copy(),
                       stats[:, NREJECTED].copy(), list(dyn.coordinates),
                       {"method": s.method, "backend": dyn.backend, "runs": len(status),
                        "failed": int(np.count_nonzero(status))}, dyn=dyn, p=plan.p)


HTML_RUNS = 10  # runs a batch's HTML file shows by default


def chosen_runs(ok: np.ndarray, runs=None) -> list[int]:
    """The runs to draw: `runs` (indices, each of a run that reached the end), or the first
    HTML_RUNS that did."""
    if runs is None:
        chosen = [int(i) for i in np.flatnonzero(ok)[:HTML_RUNS]]
        if not chosen:
            raise ValueError("no run reached the end: nothing to draw")
        return chosen
    chosen = [int(i) for i in np.atleast_1d(runs)]
    for i in chosen:
        if not 0 <= i < len(ok):
            raise ValueError(f"run {i} is not one of the {len(ok)} runs")
        if not ok[i]:
            raise ValueError(f"run {i} did not reach the end (its samples stop): choose "
                             "another")
    if not chosen:
        raise ValueError("runs is empty")
    return chosen


def _nonfinite_origin(dyn, plan: BatchPlan, i: int) -> str | None:
    """Where run i's NaN or inf came from, when its initial state is the cause."""
    nq = dyn.nq
    p = plan.p[i if plan.p.shape[0] > 1 else 0]
    fext = None if plan.wrenches is None else dict(zip(plan.wrenches[0].tolist(),
                                                       plan.wrenches[1]))
    return nonfinite_origin(dyn, plan.y0[i, :nq], plan.y0[i, nq:], p, fext=fext)


def simulate_batch(dyn, t_span, q0, qd0=None, controller=None, p=None, method: str = "dopri5",
                   rtol: float = 1e-6, atol=1e-8, t_eval=None, threads: int | None = None,
                   client=None, *, progress: Progress | None = None,
                   chunk_size: int | None = None, retries: int = 2, fext=None,
                   **options) -> BatchResult:
    """Run N simulations of `dyn` at once, in C, on every core or on a Dask cluster.

    dyn         a compiled dynamics object from `gagen.load`.
    t_span      (t0, t1), shared by every run; so are method, rtol, atol and t_eval.
    q0, qd0     (N, n), or (n,) for every run; qd0=None means at rest.
    controller  None, a gagen controller (PD, ComputedTorque on an Eq11Trajectory,
                paper_controller()) for every run, or a list of N of them (per-run gains
                and targets). A Python callable cannot run in C and is refused.
    p           None (defaults), a full parameter vector, an (N, P) array in
                `dyn.parameters` order, or a dict whose values are numbers (every run) or
                (N,) arrays (one per run).
    method      "dopri5" (the steps of scipy's RK45) or "rk4" (option h, default 1e-3 s).
    threads     OS threads for the runs (default: every core); each runs without the GIL.
    client      a `dask.distributed.Client`: the runs go to its workers in chunks of
                `chunk_size` runs (default: about 4 chunks per worker thread, at most
                10,000 runs); a failing chunk is retried `retries` times, and if it still
                fails its runs get status -201 and the others are kept.
    progress    called as progress(done, N) while the runs go on.
    fext        constant wrenches on frames, {frame: (fx, fy, fz, tx, ty, tz)} in world
                axes at the frames' origins, the same for every run (as in `simulate`).
    options     dopri5: first_step, max_step, max_steps; rk4: h, max_steps.

    Every run gives exactly the numbers `gagen.simulate(..., method=method)` gives for the
    same inputs. A run that fails does not stop the others: see `BatchResult.status`.
    Ctrl-C stops every thread and raises KeyboardInterrupt. Returns a `BatchResult`.
    """
    plan = prepare_batch(dyn, t_span, q0, qd0, controller, p, method, rtol, atol, t_eval,
                         fext, **options)
    return run_batch(dyn, plan, threads=threads, client=client, progress=progress,
                     chunk_size=chunk_size, retries=retries)


def run_batch(dyn, plan: BatchPlan, threads: int | None = None, client=None,
              progress: Progress | None = None, chunk_size: int | None = None,
              retries: int = 2) -> BatchResult:
    """Run a checked plan here (threads) or on a Dask cluster (client)."""
    start = time.perf_counter()
    failures: dict[int, str] = {}
    if client is None:
        threads = default_threads() if threads is None else _positive_int(threads, "threads")
        q, qd, tau, stats = run_plan(dyn, plan, threads, progress)
        chunks = None
    else:
        from .distributed import run_on_cluster

        q, qd, tau, stats, failures, chunks = run_on_cluster(
            client, dyn, plan, chunk_size=chunk_size, retries=retries, progress=progress)
    result = batch_result(dyn, plan, q, qd, tau, stats, failures)
    result.stats.update(threads=threads, chunks=chunks, wall_time=time.perf_counter() - start)
    return result


def _positive_int(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def blocks(runs: int, size: int) -> list[tuple[int, int]]:
    """(start, stop) of consecutive blocks of at most `size` runs."""
    return [(a, min(a + size, runs)) for a in range(0, runs, size)]
