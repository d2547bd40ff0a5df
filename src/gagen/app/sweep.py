"""`python -m gagen sweep`: many runs of the `simulate` command's setup, each with its own
draw of parameters, initial state and gains, streamed to a file.

Each --vary draws every run's value independently and uniformly:

    NAME=LO:HI     between LO and HI (a parameter, or q0, qd0, kp, kd, target)
    NAME=P%        within +-P % of the default value (parameters, kp, kd)

NAME is a parameter (shell-style patterns allowed: 'm[123]=20%' varies m1, m2, m3
independently), or q0, qd0, kp, kd, target for every coordinate (each drawn on its own),
or one of them for one coordinate, q0.q2=-10:10. Angles are in degrees (q0, target) and
degrees per second (qd0), as in `simulate`; prismatic coordinates in m and m/s.

A floating base (nq = nv + 1 per floating joint) starts at the world's origin, unrotated,
and at rest, as in `simulate`. There, q0, qd0, kp, kd, target without a name vary the
joints only; q0.<entry> names an entry of q (`dyn.configuration`: a floating joint
base's position base_x, _y, _z in m), qd0.<coordinate> one of qd (`dyn.coordinates`:
base_vx, _vy, _vz in m/s, base_wx, _wy, _wz in degrees per second). A quaternion's entries (base_qx ... _qw)
cannot be drawn as angles and are refused, and so are kp, kd, target of a floating joint
(it has no actuator). q is stored as (runs, samples, nq), named by the file's
`configuration` attribute, qd and tau as (runs, samples, nv), named by `coordinates`; the
statistics cover every entry of q (a quaternion's unitless), the fan figure the joints.

Results go to a Zarr store (`.zarr`, chunked along the runs, written block by block, so a
sweep larger than memory streams to disk; `zarr.open_group(path)` or
`xarray.open_zarr(path)` read it) or to NumPy's `.npz` (kept in memory, then written;
`np.load(path)` reads it). Zarr is optional (`pip install gagen[zarr]`). Next to the
file: `<stem>_fan.png` (Fig. 2 with every run's trajectories, the 5-95 % band, the median
and the nominal run) and `<stem>_final.csv` (statistics of the final state).
"""

from __future__ import annotations

import csv
import fnmatch
import logging
import math
import os
import re
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..csvtext import text_cell
from ..manifest import CONFIGURATION, VELOCITY, joint_names
from ..sim.batch import BatchPlan, blocks, prepare_batch, run_batch
from .runs import default_out_dir, load_dynamics

log = logging.getLogger(__name__)

STATE_TARGETS = ("q0", "qd0", "kp", "kd", "target")
ANGLE_TARGETS = ("q0", "qd0", "target")  # given in degrees for rotating joints
BLOCK_BYTES = 256 * 2**20  # q, qd and tau of one block in memory
CHUNK_BYTES = 4 * 2**20  # one Zarr chunk of q (and of qd, tau), before compression
FAN_RUNS = 400  # runs drawn in the fan figure (the first ones: the draws are independent)
FAILURES_KEPT = 1000  # messages of failed runs stored in the file's attributes
_VARY = re.compile(r"^(?P<name>[^=\s]+)=(?P<value>.+)$")


@dataclass(frozen=True)
class Variation:
    """One --vary: what it changes and how (a range, or a percentage of the default)."""

    name: str  # a parameter pattern, or one of STATE_TARGETS
    coordinate: str | None  # STATE_TARGETS only: one coordinate, or None for all
    low: float | None = None
    high: float | None = None
    percent: float | None = None
    text: str = ""


def parse_variation(text: str) -> Variation:
    """'NAME=LO:HI' or 'NAME=P%' (see the module docstring); ValueError if malformed."""
    match = _VARY.match(text.replace(" ", ""))
    if not match:
        raise ValueError(f"--vary {text!r}: expected NAME=LO:HI or NAME=P%")
    name, value = match["name"], match["value"].replace(" ", "")
    coordinate = None
    head, _, tail = name.partition(".")
    if head in STATE_TARGETS:
        name, coordinate = head, (tail or None)
    try:
        if value.endswith("%"):
            percent = float(value[:-1])
            if not (math.isfinite(percent) and 0 <= percent < 100):
                raise ValueError
            return Variation(name, coordinate, percent=percent, text=text)
        low, high = (float(v) for v in value.split(":"))
    except ValueError:
        raise ValueError(f"--vary {text!r}: expected NAME=LO:HI (two numbers) or NAME=P% "
                         "(0 <= P < 100)") from None
    if not (math.isfinite(low) and math.isfinite(high) and low <= high):
        raise ValueError(f"--vary {text!r}: LO and HI must be finite with LO <= HI")
    if not math.isfinite(high - low):
        raise ValueError(f"--vary {text!r}: HI - LO overflows; the range must be narrower "
                         "than the largest float")
    return Variation(name, coordinate, low=low, high=high, text=text)


@dataclass
class SweepInputs:
    """Every run's draws: the parameter table's varied columns, states and gains."""

    p: dict[str, np.ndarray] = field(default_factory=dict)
    q0: np.ndarray | None = None
    qd0: np.ndarray | None = None
    kp: np.ndarray | None = None
    kd: np.ndarray | None = None
    target: np.ndarray | None = None


def draw_inputs(variations: list[Variation], runs: int, dyn, nominal, seed: int
                ) -> SweepInputs:
    """Draw each varied quantity for every run (uniformly, independently; in the order of
    `variations`, from one generator seeded with `seed`). q0 has dyn.nq entries (the
    rest: dyn.neutral()), the others dyn.nv."""
    rng = np.random.default_rng(seed)
    out = SweepInputs()
    defaults = dyn.parameters
    for v in variations:
        if v.name in STATE_TARGETS:
            _draw_state(out, v, runs, dyn, nominal, rng)
            continue
        names = [k for k in defaults if fnmatch.fnmatchcase(k, v.name)]
        if not names:
            raise KeyError(f"--vary {v.text!r}: no parameter matches '{v.name}' "
                           f"(parameters: {', '.join(defaults)})")
        for name in names:
            out.p[name] = _uniform(v, defaults[name], runs, rng)
    return out


@dataclass(frozen=True)
class Entry:
    """One entry of q (or of qd, kp, kd, target) as a sweep draws and reports it."""

    name: str
    unit: str  # "rad" (given and reported in degrees), "m", or "1" (a quaternion's entry)
    joint: str
    floating: bool  # an entry of a floating joint (which has no actuator)


def state_entries(info, configuration: bool) -> list[Entry]:
    """The entries of q (`configuration`, dyn.configuration's order) or of qd (dyn.coordinates'
    order), each with its unit and joint."""
    out = []
    for joint in info.joints:
        if joint.type == "floating":
            units = ("m",) * 3 + (("1",) * 4 if configuration else ("rad",) * 3)
            names = joint_names(joint, CONFIGURATION if configuration else VELOCITY)
            out += [Entry(name, unit, joint.name, True) for name, unit in zip(names, units)]
        else:
            unit = "m" if joint.type == "prismatic" else "rad"
            out.append(Entry(joint.name, unit, joint.name, False))
    return out


def _draw_state(out: SweepInputs, v: Variation, runs: int, dyn, nominal, rng) -> None:
    entries = state_entries(dyn.info, configuration=v.name == "q0")
    columns = _state_columns(v, entries, dyn.info.name)
    if v.percent is not None and v.name in ANGLE_TARGETS:
        raise ValueError(f"--vary {v.text!r}: give {v.name} as a range LO:HI (degrees)")
    n = dyn.nv
    base = {"q0": dyn.neutral(), "qd0": np.zeros(n), "kp": nominal.c_spec(n)["kp"],
            "kd": nominal.c_spec(n)["kd"], "target": nominal.c_spec(n)["target"]}[v.name]
    current = getattr(out, v.name)
    table = np.tile(base, (runs, 1)) if current is None else current
    for k in columns:
        values = _uniform(v, base[k], runs, rng)
        if v.percent is None and v.name in ANGLE_TARGETS and entries[k].unit == "rad":
            values = np.radians(values)
        table[:, k] = values
    setattr(out, v.name, table)


def _state_columns(v: Variation, entries: list[Entry], model_name: str) -> list[int]:
    """The entries a state --vary draws: the one it names, or every joint's (a floating
    joint's entries only when named: its position and velocity, never its quaternion)."""
    if v.coordinate is None:
        columns = [k for k, e in enumerate(entries) if not e.floating]
        if not columns and v.name in ("kp", "kd", "target"):
            raise ValueError(f"--vary {v.text!r}: '{model_name}' has no joint, only a "
                             f"floating base, which has no actuator: its {v.name} is not used")
        if not columns:
            floating = ", ".join(e.name for e in entries if e.unit != "1")
            raise ValueError(f"--vary {v.text!r}: '{model_name}' has no joint, only a "
                             f"floating base: name one of its entries, {v.name}.NAME "
                             f"(NAME one of {floating})")
        return columns
    names = [e.name for e in entries]
    if v.coordinate not in names:
        what = "entry of q" if v.name == "q0" else "coordinate"
        raise KeyError(f"--vary {v.text!r}: no {what} '{v.coordinate}' "
                       f"({v.name}: {', '.join(names)})")
    entry = entries[names.index(v.coordinate)]
    if entry.unit == "1":
        quaternion = ", ".join(e.name for e in entries if e.joint == entry.joint
                               and e.unit == "1")
        position = ", ".join(e.name for e in entries if e.joint == entry.joint
                             and e.unit == "m")
        raise ValueError(f"--vary {v.text!r}: {entry.name} is an entry of the unit "
                         f"quaternion of floating joint '{entry.joint}' ({quaternion}), which "
                         "cannot be drawn as an angle: vary the joints (q0=LO:HI) or the "
                         f"joint's position ({position}, in m)")
    if entry.floating and v.name in ("kp", "kd", "target"):
        raise ValueError(f"--vary {v.text!r}: {entry.name} is a coordinate of floating "
                         f"joint '{entry.joint}', which has no actuator: its {v.name} is "
                         "not used")
    return [names.index(v.coordinate)]


def _uniform(v: Variation, default: float, runs: int, rng) -> np.ndarray:
    if v.percent is not None:
        return default * (1.0 + rng.uniform(-v.percent, v.percent, runs) / 100.0)
    return rng.uniform(v.low, v.high, runs)


# ------------------------------------------------------------------------------ stores


def _result_widths(nq: int, nv: int) -> dict[str, int]:
    """The last axis of each result array: q has nq entries, qd and tau nv."""
    return {"q": nq, "qd": nv, "tau": nv}


class NpzStore:
    """The whole sweep in memory, written by np.savez_compressed at the end."""

    def __init__(self, path: Path, runs: int, t: np.ndarray, nq: int, nv: int, attrs: dict):
        self.path, self.attrs = path, attrs
        self.arrays = {name: np.empty((runs, t.size, width))
                       for name, width in _result_widths(nq, nv).items()}
        self.arrays["t"] = t

    def put(self, name: str, start: int, values: np.ndarray) -> None:
        if name not in self.arrays:
            runs = self.arrays["q"].shape[0]
            self.arrays[name] = np.empty((runs,) + values.shape[1:], values.dtype)
        self.arrays[name][start:start + len(values)] = values

    def close(self, attrs: dict) -> None:
        import json

        meta = np.array(json.dumps({**self.attrs, **attrs}))
        np.savez_compressed(self.path, attrs=meta, **self.arrays)


class ZarrStore:
    """A Zarr group: arrays chunked along the runs, written block by block."""

    def __init__(self, path: Path, runs: int, t: np.ndarray, nq: int, nv: int, attrs: dict):
        try:
            import zarr
        except ImportError:
            raise ImportError("writing a .zarr store needs Zarr: pip install 'gagen[zarr]' "
                              "(or write .npz: --out sweep.npz)") from None
        if path.exists() and not (path / "zarr.json").exists():
            raise FileExistsError(f"--out {path}: exists and is not a Zarr store; not "
                                  "overwriting it")
        self.group = zarr.open_group(str(path), mode="w")
        self.group.attrs.update(attrs)
        self.chunk = max(1, CHUNK_BYTES // (t.size * max(nq, nv) * 8))
        self.runs = runs
        self.group.create_array("t", data=t)
        for name, width in _result_widths(nq, nv).items():
            self.group.create_array(name, shape=(runs, t.size, width), dtype="f8",
                                    chunks=(min(self.chunk, runs), t.size, width))

    def put(self, name: str, start: int, values: np.ndarray) -> None:
        if name not in self.group:
            self.group.create_array(name, shape=(self.runs,) + values.shape[1:],
                                    dtype=values.dtype,
                                    chunks=(min(self.runs, 65536),) + values.shape[1:])
        self.group[name][start:start + len(values)] = values

    def close(self, attrs: dict) -> None:
        self.group.attrs.update(attrs)


def open_store(path: Path, runs: int, t: np.ndarray, nq: int, nv: int, attrs: dict):
    """A store for `path` by its suffix: .zarr (streamed) or .npz (in memory); q has nq
    entries per sample, qd and tau nv."""
    suffix = path.suffix.lower()
    if suffix == ".zarr":
        return ZarrStore(path, runs, t, nq, nv, attrs)
    if suffix == ".npz":
        return NpzStore(path, runs, t, nq, nv, attrs)
    raise ValueError(f"--out {path}: the file must end in .zarr or .npz")


def default_out(model) -> Path:
    """out/<model>/sweep.zarr, or sweep.npz when Zarr is not installed."""
    import importlib.util

    name = "sweep.zarr" if importlib.util.find_spec("zarr") else "sweep.npz"
    return default_out_dir(model) / name  # created when the sweep writes, not before


# --------------------------------------------------------------- will it fit? (before anything)

# What one run keeps in memory besides its results, beyond its inputs' numbers: a PD
# controller of its own (a Python object and three arrays) when gains or targets vary.
CONTROLLER_BYTES = 1024


@dataclass(frozen=True)
class StoreSize:
    """What a sweep will hold, in bytes: `results` (q, qd, tau of every run), `inputs` (each
    run's q0, qd0, parameters, gains, target and statistics, as stored), and `memory`
    (what the process holds besides an .npz store: the draws and the batch's tables,
    about three copies of the inputs, the final states, one block of results, and the
    runs' own controllers)."""

    results: int
    inputs: int
    memory: int

    def in_memory(self, suffix: str) -> int:
        return self.memory + (self.results + self.inputs if suffix == ".npz" else 0)

    @property
    def on_disk(self) -> int:
        return self.results + self.inputs  # uncompressed: the worst case


def store_size(runs: int, points: int, nq: int, nv: int, parameters: int,
               per_run_controllers: bool = False) -> StoreSize:
    """The sizes of a sweep of `runs` runs of `points` samples (StoreSize)."""
    results = 8 * runs * points * (nq + 2 * nv)
    inputs = 8 * runs * (nq + 4 * nv + parameters + 4)
    block = min(results, BLOCK_BYTES)
    memory = 3 * inputs + 8 * runs * nv + block + (
        CONTROLLER_BYTES * runs if per_run_controllers else 0)
    return StoreSize(results, inputs, memory)


def check_store_fits(path: Path, runs: int, points: int, nq: int, nv: int, parameters: int,
                     per_run_controllers: bool = False) -> None:
    """Refuse (ValueError naming --runs and --points) a sweep whose store cannot fit: in
    memory for .npz (and for every store, the inputs and one block), on disk for both."""
    size = store_size(runs, points, nq, nv, parameters, per_run_controllers)
    suffix = path.suffix.lower()
    shape = (f"--runs {runs:,} x --points {points:,} x {nq + 2 * nv} values (q, qd, tau of "
             f"{nv} coordinates)")
    need, free = size.in_memory(suffix), available_memory()
    if free is not None and need > free:
        advice = ("write --out FILE.zarr (streamed to disk) or use fewer --runs or --points"
                  if suffix == ".npz" else "use fewer --runs")
        raise ValueError(f"{shape}: the sweep needs {_bytes(need)} of memory"
                         + (" (an .npz store is kept in memory until written)"
                            if suffix == ".npz" else " (the runs' inputs and one block)")
                         + f", and {_bytes(free)} is available: {advice}")
    disk = free_disk(path)
    if disk is not None and size.on_disk > disk:
        raise ValueError(f"{shape}: --out {path} needs up to {_bytes(size.on_disk)} on disk "
                         f"(uncompressed), and {_bytes(disk)} is free there: use fewer --runs "
                         "or --points, or another folder")


def available_memory() -> int | None:
    """Bytes of memory this process can still take: the system's available memory, or
    the cgroup's limit less its use (a container) if lower; None where neither is known."""
    values = []
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                values.append(int(line.split()[1]) * 1024)
    except (OSError, ValueError, IndexError):
        pass
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        used = int(Path("/sys/fs/cgroup/memory.current").read_text().strip())
        if limit.isdigit():
            values.append(max(0, int(limit) - used))
    except (OSError, ValueError):
        pass
    if not values:
        try:
            values.append(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (ValueError, OSError, AttributeError):
            pass
    room = _address_space_left()
    if room is not None:
        values.append(room)
    return min(values) if values else None


def _address_space_left() -> int | None:
    """What this process's address-space limit (ulimit -v) leaves, or None (no limit)."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft == resource.RLIM_INFINITY:
            return None
        status = Path("/proc/self/status").read_text()
        size = next(int(line.split()[1]) * 1024 for line in status.splitlines()
                    if line.startswith("VmSize:"))
        return max(0, soft - size)
    except (ImportError, OSError, ValueError, StopIteration):
        return None


def free_disk(path: Path) -> int | None:
    """Free bytes on the file system `path` would be written to (its nearest existing
    folder); None where it cannot be told."""
    folder = Path(os.path.abspath(path)).parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        return shutil.disk_usage(folder).free
    except OSError:
        return None


def _bytes(count: int) -> str:
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if count >= size:
            return f"{count / size:,.1f} {unit}"
    return f"{count} bytes"


# ------------------------------------------------------------------------------- sweep


@dataclass
class SweepRun:
    """What `run_sweep` computed and wrote."""

    model: object
    runs: int
    failed: int
    final: np.ndarray  # (runs, nq) final configurations, NaN for failed runs
    nominal_final: np.ndarray  # (nq,)
    seconds: float
    files: list[Path] = field(default_factory=list)
    statistics: list[dict] = field(default_factory=list)


def run_sweep(model="rrr", *, runs: int, variations: list[str], seed: int = 0,
              duration: float = 5.0, points: int = 501, method: str = "dopri5",
              rtol: float = 1e-6, atol: float = 1e-8, step: float = 1e-3,
              threads: int | None = None, scheduler: str | None = None,
              out: str | Path | None = None, cache_dir=None, plot: bool = True,
              block_runs: int | None = None, html: bool = False, html_runs=None,
              html_mode: str = "overlay", package_dirs=None, strict: bool = False,
              floating_base: bool = False) -> SweepRun:
    """Run `runs` simulations of `model` under the `simulate` command's controller, with the
    --vary draws; stream them to `out` in blocks; plot the fan and write the statistics.

    Every run starts from `dyn.neutral()` at rest, but for its draws (a floating base: at
    the world's origin, unrotated; see the module docstring for what q0 and qd0 vary
    there). `strict` and `floating_base` are `gagen.load`'s.

    `html` also writes `out`'s stem + .html: the runs `html_runs` (default: the nominal run,
    then the first HTML_RUNS - 1 runs that reached the end) in 3-D, overlaid with all but
    the first ghosted, or one after the other (`html_mode` "sequence")."""
    from ..model.resolve import resolve_model
    from ..sim.controllers import PD, default_controller
    from ..sim.simulate import simulate

    parsed = [parse_variation(text) for text in variations]
    for i in html_runs or ():
        if not 0 <= i < runs:
            raise ValueError(f"--html-runs {i}: there are runs 0 to {runs - 1}")
    if out:  # a first look with one coordinate, before the model is even read
        check_store_fits(Path(out), runs, points, 1, 1, 0)
    model = resolve_model(model, strict, floating_base)
    path = Path(out) if out else default_out(model)
    check_store_fits(path, runs, points, model.nq, model.dof, len(model.parameters),
                     per_run_controllers=any(v.name in ("kp", "kd", "target") for v in parsed))
    model, dyn = load_dynamics(model, "compiled", cache_dir)
    nominal = default_controller(dyn)
    draws = draw_inputs(parsed, runs, dyn, nominal, seed)
    controller = nominal
    if draws.kp is not None or draws.kd is not None or draws.target is not None:
        spec = nominal.c_spec(dyn.nv)
        controller = [PD(kp=_row(draws.kp, i, spec["kp"]), kd=_row(draws.kd, i, spec["kd"]),
                         target=_row(draws.target, i, spec["target"]),
                         gravity_compensation=nominal.gravity_compensation)
                      for i in range(runs)]
    options = {"h": step} if method == "rk4" else {}
    span, t_eval = (0.0, duration), np.linspace(0.0, duration, points)
    q0 = draws.q0 if draws.q0 is not None else np.tile(dyn.neutral(), (runs, 1))
    plan = prepare_batch(dyn, span, q0, draws.qd0, controller, draws.p or None, method, rtol,
                         atol, t_eval, **options)
    try:
        nominal_run = simulate(dyn, span, dyn.neutral(), None, nominal, method=method,
                               rtol=rtol, atol=atol, t_eval=t_eval, **options)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:  # say which run
        raise type(exc)(f"the nominal run (no --vary draw): {exc}") from None
    path.parent.mkdir(parents=True, exist_ok=True)
    attrs = {"model": model.name, "configuration": list(dyn.configuration),
             "coordinates": list(dyn.coordinates), "parameters": list(dyn.parameters),
             "method": method, "rtol": rtol, "atol": atol, "duration": duration,
             "runs": runs, "seed": seed, "vary": [v.text for v in parsed],
             "controller": repr(nominal)}
    store = open_store(path, runs, t_eval, dyn.nq, dyn.nv, attrs)
    size = block_runs or _block_runs(runs, points, dyn.nq + 2 * dyn.nv,
                                     getattr(store, "chunk", 1))
    log.info(f"{runs:,} runs of {duration:g} s with {method}, in {len(blocks(runs, size))} "
             f"block(s) of up to {size:,} runs, to {path}")
    start = time.perf_counter()
    client = _client(scheduler)
    picked = PickedRuns(html_runs, HTML_RUNS - 1) if html else None
    try:
        final, fan, failures = _run_blocks(dyn, plan, store, size, threads, client, picked)
    finally:
        if client is not None:
            client.close()
    seconds = time.perf_counter() - start
    failed = int(np.isnan(final).any(axis=1).sum())
    store.close({"failed": failed, "failures": failures, "wall_time": seconds})
    run = SweepRun(model, runs, failed, final, nominal_run.q[-1], seconds, [path])
    run.statistics = final_statistics(run, dyn)
    run.files.append(write_statistics(run, path.with_name(f"{path.stem}_final.csv")))
    if plot:
        figure = _plot_fan(t_eval, fan, nominal_run.q, model, dyn,
                           path.with_name(f"{path.stem}_fan.png"), runs)
        run.files += [figure] if figure is not None else []
    if picked is not None:
        run.files.append(_write_html(path.with_name(f"{path.stem}.html"), dyn, plan,
                                     nominal_run, picked, html_runs is None, html_mode,
                                     package_dirs))
    return run


def _plot_fan(t, fan, nominal_q, model, dyn, path: Path, total: int) -> Path | None:
    """The fan figure of the joints (a floating base's entries left out: its path is in
    the store); None, with a log line, for a model with no joint."""
    from .figures import fig2_fan

    shown = model
    if dyn.nq != dyn.nv:
        from ..runtime.manifold import plain_entries
        from .runs import _joints_only

        joints, _ = plain_entries(dyn.info)
        if not joints.size:
            log.info("no fan figure: the model has no joint, only a floating base (its path "
                     "is in the store)")
            return None
        fan, nominal_q, shown = fan[:, :, joints], nominal_q[:, joints], _joints_only(model)
    log.info("plotting...")
    return fig2_fan(t, fan, nominal_q, shown, path, total=total)


HTML_RUNS = 10  # runs the HTML file shows by default (the nominal one and 9 more)


class PickedRuns:
    """The runs the HTML file shows, kept block by block as the sweep goes: the runs
    `wanted`, or the first `count` runs that reached the end."""

    def __init__(self, wanted, count: int):
        self.wanted = None if wanted is None else list(dict.fromkeys(wanted))
        self.count = count
        self.q: dict[int, np.ndarray] = {}

    def take(self, start: int, res) -> None:
        if self.wanted is None:
            for i in np.flatnonzero(res.ok):
                if len(self.q) >= self.count:
                    return
                self.q[start + int(i)] = np.array(res.q[i])
            return
        for i in self.wanted:
            if start <= i < start + len(res.ok):
                if res.ok[i - start]:
                    self.q[i] = np.array(res.q[i - start])
                else:
                    log.warning(f"--html-runs {i}: the run did not reach the end; left out "
                                "of the HTML file")


def _write_html(path: Path, dyn, plan: BatchPlan, nominal, picked: PickedRuns,
                with_nominal: bool, mode: str, package_dirs) -> Path:
    from ..viewer import write_html

    order = [i for i in (picked.wanted or sorted(picked.q)) if i in picked.q]
    q = [picked.q[i] for i in order]
    p = [plan.p[0 if plan.p.shape[0] == 1 else i] for i in order]
    labels = [f"run {i}" for i in order]
    if with_nominal:
        q, p, labels = [nominal.q, *q], [nominal.p, *p], ["nominal", *labels]
    if not q:
        raise ValueError("--html: none of the chosen runs reached the end")
    log.info(f"writing the 3-D playback of {len(q)} runs ({path.name})...")
    return write_html(path, dyn, nominal.t, np.array(q), p, mode=mode, labels=labels,
                      package_dirs=package_dirs)


def _run_blocks(dyn, plan: BatchPlan, store, size: int, threads, client,
                picked: PickedRuns | None = None):
    """Run the plan block by block into the store: (final q (N, nq), NaN for failed runs;
    the first FAN_RUNS runs' q; the messages of up to FAILURES_KEPT failed runs); the
    runs of the HTML file go to `picked`."""
    runs = plan.runs
    progress = ProgressBar(runs)
    final = np.full((runs, dyn.nq), np.nan)
    fan = None
    failures: dict[str, str] = {}
    for a, b in blocks(runs, size):
        res = run_batch(dyn, plan.rows(a, b), threads=threads, client=client,
                        progress=lambda done, _total, a=a: progress(a + done))
        _store_block(store, plan, a, b, res, dyn.nq)
        final[a:b][res.ok] = res.q[res.ok, -1]
        for i in np.flatnonzero(~res.ok)[: max(0, FAILURES_KEPT - len(failures))]:
            failures[str(a + i)] = res.message[i]
        if fan is None:
            fan = res.q[:FAN_RUNS].copy()
        if picked is not None:
            picked.take(a, res)
    return final, fan, failures


def _row(table, i: int, default):
    return default if table is None else table[i]


def _client(scheduler: str | None):
    if scheduler is None:
        return None
    try:
        from distributed import Client
    except ImportError:
        raise ImportError("--scheduler needs Dask: pip install 'gagen[dask]'") from None
    log.info(f"connecting to the Dask scheduler at {scheduler}...")
    return Client(scheduler, timeout=30)


def _block_runs(runs: int, points: int, width: int, chunk: int) -> int:
    """Runs per block: q, qd, tau of a block (`width` = nq + 2 nv values a sample) within
    BLOCK_BYTES, a whole number of chunks."""
    size = max(1, BLOCK_BYTES // (points * width * 8))
    return min(runs, max(chunk, size // chunk * chunk))


def _store_block(store, plan: BatchPlan, a: int, b: int, res, nq: int) -> None:
    """Runs a .. b-1 into the store: results, statistics and inputs (q0 (., nq), qd0, kp,
    kd, target (., nv))."""
    for name in ("q", "qd", "tau"):
        store.put(name, a, getattr(res, name))
    for name in ("status", "nfev", "steps", "rejected"):
        store.put(name, a, getattr(res, name))
    nv = plan.y0.shape[1] - nq
    store.put("q0", a, plan.y0[a:b, :nq])
    store.put("qd0", a, plan.y0[a:b, nq:])
    rows = plan.rows(a, b)
    store.put("p", a, np.broadcast_to(rows.p, (b - a, plan.p.shape[1])))
    for name in ("kp", "kd", "target"):
        store.put(name, a, np.broadcast_to(rows.control[name], (b - a, nv)))


class ProgressBar:
    """Progress as `gagen: sweep [####......] 40 % 400/1,000 runs, 2.1 s, ~3.2 s left` log
    lines (stderr, hidden by --quiet): at most one a second, and the last."""

    def __init__(self, total: int, every: float = 1.0, width: int = 24):
        self.total, self.every, self.width = total, every, width
        self.start = time.perf_counter()
        self.shown = -math.inf
        self.last = -1

    def __call__(self, done: int) -> None:
        now = time.perf_counter()
        if done == self.last or (now - self.shown < self.every and done < self.total):
            return
        self.shown, self.last = now, done
        elapsed = now - self.start
        filled = int(self.width * done / max(self.total, 1))
        left = f", ~{elapsed / done * (self.total - done):.1f} s left" \
            if 0 < done < self.total else ""
        log.info(f"sweep [{'#' * filled}{'.' * (self.width - filled)}] "
                 f"{100 * done / max(self.total, 1):3.0f} % {done:,}/{self.total:,} runs, "
                 f"{elapsed:.1f} s{left}")


# -------------------------------------------------------------------------- statistics

STAT_COLUMNS = ("coordinate", "unit", "nominal", "mean", "std", "min", "p5", "median", "p95",
                "max")


def final_statistics(run: SweepRun, dyn) -> list[dict]:
    """Per entry of q (`dyn.configuration`): the final value's nominal, mean, std, min,
    percentiles and max over the runs that reached the end (degrees for rotating joints,
    m for prismatic ones and a floating base's position, unitless "1" for its quaternion)."""
    good = run.final[~np.isnan(run.final).any(axis=1)]
    rows = []
    for k, entry in enumerate(state_entries(dyn.info, configuration=True)):
        degrees = entry.unit == "rad"
        scale = 180.0 / math.pi if degrees else 1.0
        x = good[:, k] * scale
        row = {"coordinate": entry.name, "unit": "deg" if degrees else entry.unit,
               "nominal": run.nominal_final[k] * scale}
        if x.size:
            p5, median, p95 = np.percentile(x, [5, 50, 95])
            row.update(mean=x.mean(), std=x.std(ddof=1) if x.size > 1 else 0.0, min=x.min(),
                       p5=p5, median=median, p95=p95, max=x.max())
        rows.append(row)
    return rows


def write_statistics(run: SweepRun, path: Path) -> Path:
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(STAT_COLUMNS)
        for row in run.statistics:
            writer.writerow([text_cell(row.get(c, "")) if c in ("coordinate", "unit")
                             else repr(float(row[c])) if c in row else "" for c in STAT_COLUMNS])
    return path


def print_sweep_report(run: SweepRun) -> None:
    """Runs, failures, time and the final-state statistics, on stdout."""
    rate = run.runs / run.seconds if run.seconds > 0 else math.inf
    print(f"gagen: {run.runs:,} runs in {run.seconds:.2f} s ({rate:,.0f} runs/s); "
          f"{run.failed:,} failed")
    print(f"gagen: final state over the runs that reached the end "
          f"({run.runs - run.failed:,}):")
    w = max([10] + [len(row["coordinate"]) + 1 for row in run.statistics])
    print(f"  {'':<{w}}{'unit':>5}{'nominal':>10}{'mean':>10}{'std':>9}{'p5':>10}{'p95':>10}")
    for row in run.statistics:
        if "mean" not in row:
            print(f"  {row['coordinate']:<{w}}{row['unit']:>5}{row['nominal']:>10.3f}   (no run)")
            continue
        print(f"  {row['coordinate']:<{w}}{row['unit']:>5}{row['nominal']:>10.3f}"
              f"{row['mean']:>10.3f}{row['std']:>9.3f}{row['p5']:>10.3f}{row['p95']:>10.3f}")
    for f in run.files:
        print(f"gagen: wrote {f}")
