"""How build time, code size and call time grow with the robot.

For each model: a cold build (SymPy's cache cleared, a fresh cache folder) timed stage by
stage as `gagen.build.build` reports it (derive; generate, which includes CSE; compile,
which is Cython and the C compiler in a subprocess), the operation counts before and
after CSE; then every built module is loaded and `forward_dynamics` at a fixed state is
timed, all models interleaved in one run.

`derivation_rows` is the derivation-only study (no C): time, intermediates and operation
counts of the structured equations and after CSE.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import sympy as sp
from sympy.core.cache import clear_cache

from .common import PANDA, UR5, compiled, find_urdf_dir, fixed_state
from .timing import DEFAULT_TARGET, Candidate, interleaved

REPEATS = 7
DEFAULT_CHAINS = (2, 4, 6)
FULL_CHAINS = tuple(range(2, 13))
COLUMNS = ("model", "dof", "derive_s", "generate_s", "compile_s", "build_s", "ops_before_cse",
           "ops_after_cse", "cse_ratio", "load_s", "fd_us", "fd_iqr_us", "cached")


def scaling_models(full: bool = False, urdf_dir=None) -> tuple[list[str], list[str]]:
    """The models of the study and notes on what was left out.

    Default: chain:2, chain:4, chain:6 and the UR5; full: chain:2 ... chain:12, the UR5
    and the Panda. The URDFs come from `find_urdf_dir(urdf_dir)`.
    """
    models = [f"chain:{n}" for n in (FULL_CHAINS if full else DEFAULT_CHAINS)]
    notes = []
    for name in (UR5, PANDA) if full else (UR5,):
        folder = find_urdf_dir(urdf_dir, needed=name)
        if folder is None:
            where = f"in {urdf_dir}" if urdf_dir else "(no ../shared/urdf next to the " \
                "repository; pass --urdf-dir)"
            notes.append(f"{name} not found {where}: skipped in the scaling study.")
        else:
            models.append(str(folder / name))
    return models, notes


def display_name(name: str, model) -> str:
    return name if name.startswith("chain:") else model.name


def _slug(name: str) -> str:
    stem = Path(name).stem if name.endswith(".urdf") or "/" in name else name
    return "".join(c if c.isalnum() else "_" for c in stem)


def build_row(name: str, cache_dir: Path) -> tuple[dict, object]:
    """Build one model cold into `cache_dir`; the row (without FD timing) and its dynamics."""
    from ..model.resolve import resolve_model

    model = resolve_model(name)
    clear_cache()  # a cold derivation: nothing reused from earlier models
    dyn, report, times = compiled(model, cache_dir)
    nan = float("nan")
    stages = report.stages
    row = {
        "model": display_name(name, model),
        "dof": model.dof,
        "derive_s": stages.get("derive", nan),
        "generate_s": stages.get("generate", nan),
        "compile_s": stages.get("compile", nan),
        "build_s": times["build_s"],
        "ops_before_cse": report.ops_before_cse,
        "ops_after_cse": report.ops_after_cse,
        "cse_ratio": (report.ops_before_cse / report.ops_after_cse
                      if report.ops_after_cse else nan),
        "load_s": times["load_s"],
        "fd_us": nan,
        "fd_iqr_us": nan,
        "cached": report.cached,
    }
    return row, dyn


def scaling_rows(models, cache_dir, repeats: int = REPEATS, target: float = DEFAULT_TARGET,
                 progress=None, loaded: dict | None = None) -> list[dict]:
    """One row per model, each built in its own sub-folder of `cache_dir`.

    `progress(row)` is called after each build (fd_us still NaN). The forward dynamics
    of all models are timed at the end, interleaved. `loaded`, a dict, receives each
    model's dynamics object under its name in `models`.
    """
    rows, cands = [], []
    for k, name in enumerate(models):
        row, dyn = build_row(name, Path(cache_dir) / f"{k:02d}-{_slug(name)}")
        q, qd, tau = fixed_state(dyn.n)
        dyn.forward_dynamics(q, qd, tau)  # fail here rather than in the timer
        cands.append(Candidate(row["model"], dyn.forward_dynamics, (q, qd, tau)))
        rows.append(row)
        if loaded is not None:
            loaded[name] = dyn
        if progress:
            progress(row)
    if cands:
        for row, t in zip(rows, interleaved(cands, repeats, target)):
            row["fd_us"], row["fd_iqr_us"] = t.median * 1e6, t.iqr * 1e6
    return rows


def markdown_table(rows: list[dict]) -> str:
    head = ("| model | dof | derive s | generate s (incl. CSE) | compile s | ops before CSE "
            "| ops after CSE | ratio | FD µs/call (IQR) |")
    lines = [head, "|---|--:|--:|--:|--:|--:|--:|--:|--:|"]
    for r in rows:
        cached = " (cached)" if r["cached"] else ""
        lines.append(
            f"| {r['model']}{cached} | {r['dof']} | {r['derive_s']:.2f} | {r['generate_s']:.2f} "
            f"| {r['compile_s']:.2f} | {r['ops_before_cse']} | {r['ops_after_cse']} "
            f"| {r['cse_ratio']:.2f} | {r['fd_us']:.2f} ({r['fd_iqr_us']:.2f}) |")
    return "\n".join(lines)


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
