"""How build time, memory and call time grow with the robot, against Pinocchio.

For each model: a cold build in a fresh process (a new cache folder), timed stage by
stage as `gagen.building.build` reports it (derive; generate; compile: the C compiler, in
parallel), with its wall time and the peak memory of the whole process tree
(gagen.bench.coldbuild); then the module is loaded and forward dynamics, inverse dynamics
and the mass matrix are timed per call from Python against Pinocchio's `aba`, `rnea` and
`crba` (interleaved), and per state in gagen's batched C loop (1000 stacked states),
against Pinocchio's algorithms in its own C++ loop where that can be compiled
(gagen.bench.pinocchio_cpp).

`derivation_rows` is the derivation-only study (no C): time, intermediates and operation
counts of the structured equations and after CSE.
"""

from __future__ import annotations

import math
import statistics
import time
from pathlib import Path

import numpy as np
import sympy as sp
from sympy.core.cache import clear_cache

from .common import PANDA, UR5, find_urdf_dir, fixed_state, optional
from .timing import DEFAULT_TARGET, Candidate, interleaved

REPEATS = 7
DEFAULT_CHAINS = (2, 4, 6)
FULL_CHAINS = (5, 10, 15, 20, 24, 30, 40, 50)
# the robots of the full study: arms, a quadruped and humanoids/mobile manipulators (fixed
# base), from the shared URDFs
FULL_URDFS = (UR5, PANDA, "anymal_c.urdf", "talos_reduced.urdf", "talos_full_v2.urdf",
              "tiago.urdf")
BATCH = 1000  # stacked states of the batched loop
KERNELS = (("fd", "forward_dynamics", "aba"), ("id", "inverse_dynamics", "rnea"),
           ("M", "mass_matrix", "crba"))
COLUMNS = ("model", "dof", "derive_s", "generate_s", "compile_s", "build_s", "peak_mb",
           "ops_before_cse", "ops_after_cse", "fd_us", "id_us", "M_us", "pin_fd_us",
           "pin_id_us", "pin_M_us", "fd_state_us", "id_state_us", "M_state_us",
           "cpp_fd_us", "cpp_id_us", "cpp_M_us", "cpp_stored_fd_us", "cpp_stored_id_us",
           "cpp_stored_M_us", "cached")


def scaling_models(full: bool = False, urdf_dir=None) -> tuple[list[str], list[str]]:
    """The models of the study and notes on what was left out.

    Default: chain:2, chain:4, chain:6 and the UR5; full: chain:5 ... chain:50, the arms
    (UR5, Panda), ANYmal C, Talos (reduced and full) and Tiago, with fixed bases. The URDFs
    come from `find_urdf_dir(urdf_dir)`.
    """
    models = [f"chain:{n}" for n in (FULL_CHAINS if full else DEFAULT_CHAINS)]
    notes = []
    for name in FULL_URDFS if full else (UR5,):
        folder = find_urdf_dir(urdf_dir, needed=name)
        if folder is None:
            where = f"in {urdf_dir}" if urdf_dir else "(no ../shared/urdf next to the " \
                "repository; pass --urdf-dir)"
            notes.append(f"{name} not found {where}: skipped in the scaling study.")
        else:
            models.append(str(folder / name))
    return models, notes


def display_name(name: str, model) -> str:
    """A built-in's name, a file's stem (Talos reduced and full share their robot name)."""
    if name.startswith("chain:") or not (name.endswith((".urdf", ".xml", ".yaml", ".yml"))
                                         or "/" in name):
        return name
    return Path(name).stem


def _slug(name: str) -> str:
    stem = Path(name).stem if name.endswith(".urdf") or "/" in name else name
    return "".join(c if c.isalnum() else "_" for c in stem)


def build_row(name: str, cache_dir: Path) -> tuple[dict, object]:
    """Build one model cold, in a fresh process, into `cache_dir`; its row (build columns
    only) and its dynamics, loaded from that cache entry."""
    from ..building.builder import import_extension, load_derivative_module
    from ..model.resolve import resolve_model
    from ..runtime.compiled import CompiledDynamics
    from .coldbuild import measured_build

    model = resolve_model(name)
    report = measured_build(name, cache_dir)
    nan = float("nan")
    stages = report["stages"]
    start = time.perf_counter()
    # its derivative module, should a later section need it, built into the same cache
    dyn = CompiledDynamics(import_extension(Path(report["module"]), report["module_name"]),
                           model, derivatives=lambda _: load_derivative_module(
                               model, cache_dir=cache_dir))
    row = {key: nan for key in COLUMNS}
    row.update({
        "model": display_name(name, model),
        "dof": model.dof,
        "derive_s": stages.get("derive", nan),
        "generate_s": stages.get("generate", nan),
        "compile_s": stages.get("compile", nan),
        "build_s": report["wall_s"],
        "peak_mb": report["peak_mb"],
        "ops_before_cse": report["ops_before_cse"],
        "ops_after_cse": report["ops_after_cse"],
        "load_s": time.perf_counter() - start,
        "cached": report["cached"],
    })
    return row, dyn


def pinocchio_peer(name: str, model):
    """Pinocchio's model of the same robot, as its users build it (its own URDF parser; for
    built-ins and model files gagen's builder with Pinocchio's specialised joints), or None
    when Pinocchio is not installed."""
    pin = optional("pinocchio")
    if pin is None:
        return None
    if str(name).lower().endswith(".urdf"):
        return pin.buildModelFromUrdf(str(name))
    from ..reference.pinocchio import pinocchio_model

    return pinocchio_model(model, aligned=True)


def time_model(row: dict, dyn, peer, repeats: int, target: float) -> None:
    """Per call from Python (gagen and Pinocchio, interleaved) and per state in gagen's
    batched loop, into `row`."""
    pin = optional("pinocchio")
    n = dyn.n
    q, qd, tau = fixed_state(n)
    stack = [np.tile(x, (BATCH, 1)) for x in (q, qd, tau)]
    candidates = []
    for key, method, peer_name in KERNELS:
        fn = getattr(dyn, method)
        args = (q,) if key == "M" else (q, qd, tau)
        candidates.append(Candidate(f"{key}_us", fn, args))
        candidates.append(Candidate(f"{key}_state_us", fn,
                                    tuple(stack[:1] if key == "M" else stack)))
        if peer is not None:
            data = peer.createData()
            pq = _peer_configuration(pin, peer, n)
            pargs = (peer, data, pq) if key == "M" else (peer, data, pq, qd, tau)
            candidates.append(Candidate(f"pin_{key}_us", getattr(pin, peer_name), pargs))
    for cand, timing in zip(candidates, interleaved(candidates, repeats, target)):
        per = BATCH if cand.name.endswith("_state_us") else 1
        row[cand.name] = timing.median * 1e6 / per


CPP_ROUNDS = 9  # alternations of gagen's batched loop and the C++ harness
CPP_PASSES = 3  # passes of the harness per round (it reports their median)
CPP_KEYS = {"fd": "aba", "id": "rnea", "M": "crba"}


def time_batched_against_cpp(row: dict, dyn, harness, peer, folder: Path,
                             rounds: int = CPP_ROUNDS) -> None:
    """Per state, gagen's batched loop and Pinocchio's C++ loop (gagen.bench.pinocchio_cpp)
    timed in alternation, round after round, so that both meet the machine in the same
    states; the medians over the rounds go into `row` (`<key>_state_us`, `cpp_<key>_us`,
    `cpp_stored_<key>_us`), replacing time_model's batched figures."""
    from .pinocchio_cpp import cpp_times

    q, qd, tau = (np.tile(x, (BATCH, 1)) for x in fixed_state(dyn.n))
    samples: dict[str, list[float]] = {}
    for _ in range(rounds):
        for key, method, _ in KERNELS:
            args = (q,) if key == "M" else (q, qd, tau)
            start = time.perf_counter()
            getattr(dyn, method)(*args)
            samples.setdefault(f"{key}_state_us", []).append(
                (time.perf_counter() - start) * 1e6 / BATCH)
        times = cpp_times(harness, peer, folder, states=BATCH, repeats=CPP_PASSES)
        for key, algorithm in CPP_KEYS.items():
            samples.setdefault(f"cpp_{key}_us", []).append(times[algorithm])
            samples.setdefault(f"cpp_stored_{key}_us", []).append(times[f"{algorithm}_stored"])
    row.update({name: statistics.median(values) for name, values in samples.items()})


def _peer_configuration(pin, peer, n: int) -> np.ndarray:
    """A configuration of Pinocchio's model of the robot (its nq can exceed n: continuous
    joints as cos/sin pairs)."""
    if peer.nq == n:
        return fixed_state(n)[0]
    return pin.neutral(peer)


def scaling_rows(models, cache_dir, repeats: int = REPEATS, target: float = DEFAULT_TARGET,
                 progress=None, loaded: dict | None = None, cpp: bool = False) -> list[dict]:
    """One row per model, each built cold in its own sub-folder of `cache_dir`, then timed.

    `progress(text)` reports each step. `loaded`, a dict, receives each model's dynamics
    under its name in `models`. With `cpp`, Pinocchio's algorithms are also timed in C++
    over stacked states (gagen.bench.pinocchio_cpp), the peer of the batched loop.
    """
    from ..model.resolve import resolve_model

    for name in models:  # a wrong name fails now, not after minutes of building the others
        resolve_model(name)
    harness, why = (None, "")
    if cpp:
        from .pinocchio_cpp import build_harness, harness_folder

        if progress:
            progress("the Pinocchio C++ harness (compiled once, a few minutes, then reused)")
        harness, why = build_harness(harness_folder())
        if harness is None and progress:
            progress(f"no C++ peer: {why}")
    rows = []
    for k, name in enumerate(models):
        row, dyn = build_row(name, Path(cache_dir) / f"{k:02d}-{_slug(name)}")
        if progress:
            progress(f"{row['model']:<14} built in {row['build_s']:6.1f} s (derive "
                     f"{row['derive_s']:.1f}, generate {row['generate_s']:.1f}, compile "
                     f"{row['compile_s']:.1f}), peak {row['peak_mb']:.0f} MB")
        peer = pinocchio_peer(name, dyn.model)
        time_model(row, dyn, peer, repeats, target)
        if harness is not None and peer is not None:
            time_batched_against_cpp(row, dyn, harness, peer, Path(cache_dir) / "pinocchio-cpp")
        if progress:
            progress(f"{row['model']:<14} per call FD {row['fd_us']:.2f} µs (Pinocchio "
                     f"{row['pin_fd_us']:.2f}), ID {row['id_us']:.2f} ({row['pin_id_us']:.2f}), "
                     f"M {row['M_us']:.2f} ({row['pin_M_us']:.2f}); batched per state FD "
                     f"{row['fd_state_us']:.2f} (C++ {_peer_times(row, 'fd')}), ID "
                     f"{row['id_state_us']:.2f} ({_peer_times(row, 'id')}), M "
                     f"{row['M_state_us']:.2f} ({_peer_times(row, 'M')})")
        rows.append(row)
        if loaded is not None:
            loaded[name] = dyn
    return rows


def markdown_table(rows: list[dict]) -> str:
    """Build columns, then each kernel: gagen per call and Pinocchio's ratio to it."""
    head = ("| model | dof | derive s | generate s | compile s | build s | peak MB "
            "| FD µs (Pinocchio ×) | ID µs (×) | M µs (×) "
            "| batched FD µs/state (C++ ×, C++ storing ×) | ID (×, ×) | M (×, ×) |")
    lines = [head, "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|"]
    for r in rows:
        cells = [f"{r[k]:.2f}" for k in ("derive_s", "generate_s", "compile_s")]
        cells += [f"{r['build_s']:.1f}", f"{r['peak_mb']:.0f}"]
        for key in ("fd", "id", "M"):
            cells.append(_with_ratio(r[f"{key}_us"], r[f"pin_{key}_us"]))
        for key in ("fd", "id", "M"):
            cells.append(_with_ratio(r[f"{key}_state_us"], r[f"cpp_{key}_us"],
                                     r.get(f"cpp_stored_{key}_us")))
        cached = " (cached)" if r.get("cached") else ""
        lines.append(f"| {r['model']}{cached} | {r['dof']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _with_ratio(mine: float, peer: float, *more: float | None) -> str:
    """`mine` and each peer's time as a multiple of it (> 1: gagen is faster)."""
    peers = [x for x in (peer, *more) if x is not None and math.isfinite(x)]
    if not peers:
        return f"{mine:.2f}"
    return f"{mine:.2f} (" + ", ".join(f"{x / mine:.1f}×" for x in peers) + ")"


def _peer_times(row: dict, key: str) -> str:
    """The C++ peer's per-state times for the progress line: result left, result stored."""
    times = [row.get(f"cpp_{key}_us"), row.get(f"cpp_stored_{key}_us")]
    return ", stored ".join(f"{t:.2f}" for t in times if t is not None and math.isfinite(t))


# --------------------------------------------------------------------------- derivation

DERIVATION_COLUMNS = [
    ("model", "model", "{}"),
    ("dof", "dof", "{}"),
    ("derive_seconds", "derive (s, median)", "{:.3f}"),
    ("intermediates", "intermediates", "{}"),
    ("ops_structured", "ops (structured)", "{}"),
    ("ops_after_cse", "ops after CSE", "{}"),
    ("cse_seconds", "CSE (s)", "{:.2f}"),
]


def structured_ops(eqs) -> int:
    """count_ops over every intermediate definition and every output, intermediates kept."""
    exprs = [e for _, e in eqs.intermediates]
    exprs += [e for values in eqs.outputs().values() for e in values]
    return sum(sp.count_ops(e) for e in exprs)


def derivation_rows(names, repeats: int = 3) -> list[dict]:
    """One dict per model: derivation time (median of `repeats`), sizes and op counts.

    SymPy's cache is cleared before each timed derivation: a repeat would otherwise reuse
    the previous run's results and take a fraction of the time of a first derivation.
    """
    from ..codegen.cse import CSEResult
    from ..model.resolve import resolve_model
    from ..symbolic.gibbs_appell import derive

    rows = []
    for name in names:
        model = resolve_model(name)
        times = []
        eqs = None
        for _ in range(max(1, repeats)):
            clear_cache()
            start = time.perf_counter()
            eqs = derive(model)
            times.append(time.perf_counter() - start)
        cse = CSEResult(eqs)
        rows.append({
            "model": name,
            "dof": model.dof,
            "derive_seconds": statistics.median(times),
            "intermediates": len(eqs.intermediates),
            "ops_structured": structured_ops(eqs),
            "ops_after_cse": cse.ops_after,
            "cse_seconds": cse.seconds,
        })
    return rows


def derivation_table(rows: list[dict]) -> str:
    cols = DERIVATION_COLUMNS
    lines = ["| " + " | ".join(title for _, title, _ in cols) + " |",
             "|" + "|".join("---" if key == "model" else "---:" for key, _, _ in cols) + "|"]
    for row in rows:
        lines.append("| " + " | ".join(fmt.format(row[key]) for key, _, fmt in cols) + " |")
    return "\n".join(lines)
