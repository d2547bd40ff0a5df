"""`python -m gagen bench`: every benchmark section in one run, then the report.

Sections: per call on rrr (gagen's backends, Pinocchio, PyDy, plain SymPy), batched
forward dynamics, the paper's 5-s simulation with each integrator, the scaling study
(cold builds of chains and URDF robots), the derivatives (per call on rrr and the Panda
against Pinocchio and central differences; the derivative module's cold build) and, with
--full, the Panda, the floating bases, the regressor and the centroidal dynamics against
Pinocchio.
Writes results.json (after every section, so an interrupted run keeps what it measured),
report.md and the PNG plots into the output folder.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
import time
import traceback
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import peers
from .common import PANDA, Progress, compiled, find_urdf_dir, machine_info, optional

SECTIONS = ("percall", "batched", "simulation", "throughput", "scaling", "derivatives",
            "panda", "floating", "regressor", "centroidal",
            "taskspace", "constraints", "casadi", "jax")


@dataclass
class Settings:
    """Repeats, loop targets and sizes of one mode ("default", "full" or "smoke")."""

    mode: str = "default"
    target_s: float = 0.05
    percall_repeats: int = 31
    batched_repeats: int = 21
    batched_sizes: tuple[int, ...] = (1, 10, 100, 1000, 10000)
    simulation_repeats: int = 11
    scaling_repeats: int = 21
    panda_repeats: int = 31
    throughput_repeats: int = 5
    throughput_runs: int = 256  # paper runs per batch
    throughput_panda_runs: int = 32  # Panda runs per batch (none: the Panda is left out)
    throughput_dask_chunks: int = 16  # 0: Dask is left out
    regressor_repeats: int = 31
    identify_repeats: int = 5
    identify_samples: int = 10_000
    derivatives_repeats: int = 21
    casadi_repeats: int = 11
    casadi_solve_repeats: int = 1
    jax_repeats: int = 7
    jax_states: int = 4096
    sections: tuple[str, ...] = ("percall", "batched", "simulation", "throughput", "scaling",
                                 "derivatives")
    scaling_models: list[str] | None = None  # None: the mode's default list
    extra: dict = field(default_factory=dict)

    @classmethod
    def for_mode(cls, mode: str) -> Settings:
        if mode == "full":
            return cls(mode="full", sections=SECTIONS)
        if mode == "smoke":
            return cls(mode="smoke", target_s=1e-3, percall_repeats=3, batched_repeats=3,
                       batched_sizes=(1, 10, 100), simulation_repeats=2, scaling_repeats=3,
                       panda_repeats=3, scaling_models=["chain:2"], throughput_repeats=2,
                       throughput_runs=8, throughput_panda_runs=0, throughput_dask_chunks=0,
                       regressor_repeats=3, identify_repeats=1, identify_samples=500,
                       derivatives_repeats=3, casadi_repeats=3, jax_repeats=2,
                       jax_states=64)
        return cls()


class Bench:
    """One benchmark run: settings, the shared rrr models, results and progress."""

    def __init__(self, out: Path, settings: Settings, urdf_dir=None, cache_dir=None,
                 command: str = "python -m gagen bench", progress: Progress | None = None):
        self.out = Path(out)
        self.settings = settings
        self.urdf_dir = urdf_dir
        self.progress = progress or Progress()
        self.scratch = Path(tempfile.mkdtemp(prefix="gagen-bench-"))
        self.cache_dir = Path(cache_dir) if cache_dir else self.scratch / "rrr"
        self.user_cache_dir = cache_dir
        self._rrr: dict | None = None
        self._rrr_error: str | None = None
        self.loaded: dict = {}  # scaling study's models, by name, for later sections
        self.results: dict = {
            "machine": machine_info(),
            "settings": {"mode": settings.mode, "command": command,
                         "target_s": settings.target_s,
                         "sections": list(settings.sections),
                         "repeats": {"percall": settings.percall_repeats,
                                     "batched": settings.batched_repeats,
                                     "simulation": settings.simulation_repeats,
                                     "scaling": settings.scaling_repeats,
                                     "panda": settings.panda_repeats,
                                     "throughput": settings.throughput_repeats,
                                     "regressor": settings.regressor_repeats,
                                     "identify": settings.identify_repeats,
                                     "derivatives": settings.derivatives_repeats,
                                     "casadi": settings.casadi_repeats,
                                     "jax": settings.jax_repeats}},
            "notes": [],
        }

    # -- shared models ---------------------------------------------------------------

    def rrr(self) -> dict:
        """rrr's compiled (built into the bench's cache) and lambdify dynamics, once."""
        if self._rrr is None and self._rrr_error:
            raise RuntimeError(f"rrr could not be built: {self._rrr_error}")
        if self._rrr is None:
            from ..model.resolve import resolve_model
            from ..runtime.lambdify import LambdifyDynamics
            from ..symbolic.gibbs_appell import derive

            model = resolve_model("rrr")
            self.progress("setup", f"building rrr into {self.cache_dir}")
            dyn, report, times = compiled(model, self.cache_dir)
            self.results["rrr_build"] = {"stages": dict(report.stages), "cached": report.cached,
                                         "ops_before_cse": report.ops_before_cse,
                                         "ops_after_cse": report.ops_after_cse, **times}
            self.progress("setup", f"rrr compiled in {times['build_s']:.1f} s"
                          + (" (cached)" if report.cached else "") + "; lambdify backend")
            self._rrr = {"compiled": dyn, "lambdify": LambdifyDynamics(derive(model))}
        return self._rrr

    # -- sections --------------------------------------------------------------------

    def percall(self) -> dict:
        from .percall import percall_rows

        s = self.settings
        dyns = self.rrr()
        rows = percall_rows(dyns["compiled"], dyns["lambdify"], s.percall_repeats, s.target_s,
                            notes=self.results["notes"],
                            progress=lambda text: self.progress("per call", text))
        return {"rows": rows, "repeats": s.percall_repeats}

    def batched(self) -> dict:
        from .batched import batched_rows

        s = self.settings
        rows = batched_rows(self.rrr(), s.batched_sizes, s.batched_repeats, s.target_s,
                            progress=lambda text: self.progress("batched", text))
        return {"rows": rows, "repeats": s.batched_repeats}

    def simulation(self) -> dict:
        from .simulation import GOAL, simulation_rows

        s = self.settings
        rows = simulation_rows(self.rrr(), s.simulation_repeats, s.target_s,
                               progress=lambda text: self.progress("simulation", text))
        c = next(r for r in rows if r["case"] == "c")
        verdict = "met" if c["speedup"] >= GOAL else "NOT met"
        self.results["notes"].append(
            f"Goal: compiled dopri5 at least {GOAL:,.0f}x faster than scipy RK45 on the "
            f"lambdify backend: {verdict} ({c['speedup']:,.0f}x).")
        return {"rows": rows, "repeats": s.simulation_repeats}

    def throughput(self) -> dict:
        from ..sim.batch import default_threads
        from . import throughput as tp

        s = self.settings
        threads = default_threads()
        def say(text: str) -> None:
            self.progress("throughput", text)

        dyn = self.rrr()["compiled"]
        paper = tp.paper_workload(dyn, s.throughput_runs)
        say(f"paper: {s.throughput_runs} runs per call, 1 and {threads} threads, Python loop")
        rows = tp.timing_rows(tp.gagen_candidates(paper, threads), s.throughput_runs,
                              paper["samples"], s.throughput_repeats, s.target_s, "paper")
        section = {"threads": threads, "repeats": s.throughput_repeats}
        if s.throughput_panda_runs:
            rows += self._panda_throughput(tp, threads, section)
        if s.throughput_dask_chunks and optional("distributed") is None:
            self._note("throughput", "Dask is not installed: its overhead is not measured "
                       "(pip install gagen[dask]).")
        elif s.throughput_dask_chunks:
            say(f"Dask: a LocalCluster of 2 worker processes, {s.throughput_dask_chunks} chunks")
            local = next(r["median_s"] for r in rows if r["workload"] == "paper"
                         and r["candidate"] == f"gagen, {threads} threads")
            rows += tp.dask_rows(dyn, s.throughput_runs, s.throughput_dask_chunks,
                                 s.throughput_repeats, local)
        section["speedups"] = tp.thread_speedups(rows)
        for workload, speedup in sorted(section["speedups"].items()):
            verdict = "met" if speedup >= tp.THREAD_GOAL or threads < 2 else "NOT met"
            self.results["notes"].append(
                f"Goal: simulate_batch on {threads} threads at least {tp.THREAD_GOAL}x faster "
                f"than on 1 ({workload}): {verdict} ({speedup:.2f}x; the cores are shared).")
        section["rows"] = rows
        return section

    def _panda_throughput(self, tp, threads: int, section: dict) -> list[dict]:
        from ..model.resolve import resolve_model
        from ..sim.batch import simulate_batch

        s = self.settings
        folder = find_urdf_dir(self.urdf_dir, needed=PANDA)
        if folder is None:
            self._note("throughput", f"{PANDA} not found: the Panda workload is skipped.")
            return []
        urdf = folder / PANDA
        dyn = self.loaded.get(str(urdf))
        if dyn is None:
            dyn, _, times = compiled(resolve_model(urdf), self.scratch / "panda")
            self.loaded[str(urdf)] = dyn
            self.progress("throughput", f"Panda built in {times['build_s']:.1f} s")
        runs = s.throughput_panda_runs
        work = tp.panda_workload(dyn, runs)
        candidates = tp.gagen_candidates(work, threads)
        if optional("mujoco") is None:
            self._note("throughput", "MuJoCo is not installed: its rollout is not timed "
                       "(pip install mujoco).")
        else:
            ctrl = work["args"][4].c_spec(dyn.n)
            model = tp.mujoco_panda(urdf, ctrl, list(dyn.coordinates))
            peers, one_rollout = tp.mujoco_candidates(model, ctrl["target"], runs, threads)
            candidates += peers
            ours = simulate_batch(*work["args"], threads=1, **work["kwargs"]).q[0, 1:]
            theirs = one_rollout()[0, :, 1:1 + dyn.n]
            section["mujoco_max_dev_rad"] = float(np.abs(ours - theirs).max())
        self.progress("throughput", f"Panda: {runs} runs per call")
        return tp.timing_rows(candidates, runs, work["samples"], s.throughput_repeats,
                              s.target_s, "panda")

    def _note(self, section: str, text: str) -> None:
        self.results["notes"].append(text)
        self.progress(section, text)

    def scaling(self) -> dict:
        from .scaling import scaling_models, scaling_rows

        s = self.settings
        if s.scaling_models is not None:
            models = list(s.scaling_models)
        else:
            models, notes = scaling_models(s.mode == "full", self.urdf_dir)
            self.results["notes"].extend(notes)
            for note in notes:
                self.progress("scaling", note)
        cache = self.scratch / "scaling"
        self.progress("scaling", f"cold builds of {', '.join(_short(m) for m in models)} "
                      f"into {cache}")
        rows = scaling_rows(models, cache, s.scaling_repeats, s.target_s,
                            progress=lambda text: self.progress("scaling", text),
                            loaded=self.loaded, cpp=s.mode == "full")
        return {"rows": rows, "repeats": s.scaling_repeats}

    def floating(self) -> dict:
        from .common import PANDA
        from .floating import floating_rows

        s = self.settings
        folder = find_urdf_dir(self.urdf_dir, needed=PANDA)
        if folder is None:
            note = "the shared URDFs were not found: the floating-base section is skipped"
            self.results["notes"].append(note)
            return {"rows": [], "skipped": note}
        rows = floating_rows(folder, self.scratch / "floating", s.panda_repeats, s.target_s,
                             progress=lambda text: self.progress("floating", text))
        return {"rows": rows, "repeats": s.panda_repeats}
    def centroidal(self) -> dict:
        from .centroidal import ROBOT, centroidal_rows, goal_notes

        s = self.settings
        folder = find_urdf_dir(self.urdf_dir, needed=ROBOT)
        if folder is None:
            note = f"{ROBOT} was not found: the centroidal section is skipped (--urdf-dir)"
            self.results["notes"].append(note)
            return {"rows": [], "skipped": note}
        rows = centroidal_rows(folder, self.scratch / "centroidal", s.panda_repeats,
                               s.target_s, progress=lambda text: self.progress("centroidal",
                                                                               text))
        for note in goal_notes(rows):
            self._note("centroidal", note)
        return {"rows": rows, "repeats": s.panda_repeats}

    def taskspace(self) -> dict:
        from .common import PANDA
        from .taskspace import goal_notes, taskspace_rows

        s = self.settings
        folder = find_urdf_dir(self.urdf_dir, needed=PANDA)
        if folder is None:
            note = "the shared URDFs were not found: the task-space section is skipped"
            self.results["notes"].append(note)
            return {"rows": [], "skipped": note}
        rows = taskspace_rows(folder, self.scratch / "taskspace", s.panda_repeats,
                              s.target_s, progress=lambda text: self.progress("taskspace", text))
        for note in goal_notes(rows):
            self._note("taskspace", note)
        return {"rows": rows, "repeats": s.panda_repeats}

    def constraints(self) -> dict:
        from .constraints import ROBOT, constraints_rows, goal_notes

        s = self.settings
        folder = find_urdf_dir(self.urdf_dir, needed=ROBOT)
        if folder is None:
            note = f"{ROBOT} was not found: the constraints section is skipped (--urdf-dir)"
            self.results["notes"].append(note)
            return {"rows": [], "skipped": note}
        rows = constraints_rows(folder, self.scratch / "constraints", s.panda_repeats,
                                s.target_s, progress=lambda text: self.progress("constraints",
                                                                                text))
        for note in goal_notes(rows):
            self._note("constraints", note)
        return {"rows": rows, "repeats": s.panda_repeats}

    def derivatives(self) -> dict:
        import gagen

        from ..model.resolve import resolve_model
        from .casadi_c import harness_folder
        from .derivatives import (
            FLOATING_GOAL,
            FLOATING_ROBOTS,
            build_notes,
            build_rows,
            casadi_rows,
            derivative_rows,
            goal_note,
            pinocchio_floating,
        )

        s = self.settings
        def say(text):
            self.progress("derivatives", text)

        models = {"rrr": (self.rrr()["compiled"], peers.pinocchio_model(resolve_model("rrr")))}
        folder = find_urdf_dir(self.urdf_dir, needed=PANDA) if s.mode != "smoke" else None
        builds: list = ["rrr"]
        floating = {}
        if folder is not None:
            urdf = folder / PANDA
            dyn = self.loaded.get(str(urdf))
            if dyn is None:
                dyn = compiled(resolve_model(urdf), self.scratch / "panda")[0]
            say("building the Panda's derivative module")
            models["Panda"] = (dyn, peers.pinocchio_from_urdf(dyn, urdf))
            builds.append(str(urdf))
            for label, name in FLOATING_ROBOTS:
                path = folder / name
                if not path.exists():
                    self._note("derivatives", f"{name} not found: {label} is left out.")
                    continue
                say(f"building {label} on a floating base, with its derivative module")
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", gagen.InertiaWarning)
                    dyn = gagen.load(path, floating_base=True,
                                     cache_dir=self.scratch / "floating-derivatives")
                models[label] = (dyn, pinocchio_floating(dyn, path))
                floating[label] = (dyn, path)
                builds.append((str(path), True))
        elif s.mode != "smoke":
            self.results["notes"].append(f"{PANDA} not found: the derivatives section runs "
                                         "on rrr only (--urdf-dir).")
        rows = derivative_rows(models, s.derivatives_repeats, s.target_s, progress=say)
        for label in models:
            notes = [goal_note(rows, label)] if label == "Panda" else []
            if label in floating:
                notes = [goal_note(rows, label, quantity, FLOATING_GOAL) for quantity in
                         ("forward dynamics derivatives", "inverse dynamics derivatives")]
            for note in notes:
                if note:
                    self.results["notes"].append(note)
                    say(note)
        casadi, casadi_notes = casadi_rows(floating, harness_folder(), progress=say)
        for note in casadi_notes:
            self._note("derivatives", note)
        names = [_short(m if isinstance(m, str) else m[0]) for m in builds]
        say(f"cold builds of {', '.join(names)}, with and without the derivatives")
        build = build_rows(builds, self.scratch / "derivative-builds", progress=say)
        floating_builds = dict.fromkeys(r["model"] for r in build  # once per model
                                        if r["model"].endswith("(floating)"))
        for note in build_notes(build, list(floating_builds)):
            self._note("derivatives", note)
        return {"rows": rows, "builds": build, "casadi": casadi,
                "repeats": s.derivatives_repeats}

    def _panda(self, section: str):
        """(dyn, urdf) of the Panda, built once (or by the scaling study); None, note."""
        from ..model.resolve import resolve_model

        folder = find_urdf_dir(self.urdf_dir, needed=PANDA)
        if folder is None:
            note = f"{PANDA} not found: the {section} section is skipped (--urdf-dir)."
            self.results["notes"].append(note)
            self.progress(section, note)
            return None, note
        urdf = folder / PANDA
        dyn = self.loaded.get(str(urdf))  # built by the scaling study if it ran
        if dyn is None:
            dyn, _, times = compiled(resolve_model(urdf), self.scratch / "panda")
            self.loaded[str(urdf)] = dyn
            self.progress(section, f"Panda built in {times['build_s']:.1f} s")
        return dyn, urdf

    def panda(self) -> dict:
        from .percall import panda_rows

        s = self.settings
        dyn, urdf = self._panda("panda")
        if dyn is None:
            return {"rows": [], "skipped": urdf}
        self.progress("panda", "timing")
        rows = panda_rows(dyn, urdf, s.panda_repeats, s.target_s, baseline="gagen")
        if not any(r["implementation"] == "Pinocchio" for r in rows):
            self.results["notes"].append("Pinocchio is not installed: the Panda section "
                                         "times gagen only.")
        return {"rows": rows, "repeats": s.panda_repeats}

    def regressor(self) -> dict:
        from .regressor import identification_rows, regressor_rows

        s = self.settings
        dyn, urdf = self._panda("regressor")
        if dyn is None:
            return {"rows": [], "skipped": urdf}
        self.progress("regressor", "timing the regressor per call")
        rows = regressor_rows(dyn, urdf, s.regressor_repeats, s.target_s)
        self.progress("regressor", f"timing identification from {s.identify_samples:,} "
                      "samples")
        identify = identification_rows(dyn, urdf, s.identify_repeats, s.identify_samples)
        return {"rows": rows, "identify": identify, "repeats": s.regressor_repeats,
                "identify_repeats": s.identify_repeats}

    def casadi(self) -> dict:
        from .casadi import casadi_section, goal_notes

        s = self.settings
        folder = find_urdf_dir(self.urdf_dir, needed=PANDA)
        # adam's compiled Jacobians take minutes: kept from run to run in gagen's cache (or
        # --cache-dir), by a hash of their C
        from ..building.cache import default_cache_dir

        cache = Path(self.user_cache_dir or default_cache_dir()) / "bench-casadi"
        section = casadi_section(folder, self.scratch / "casadi", cache, s.casadi_repeats,
                                 s.casadi_solve_repeats, s.target_s,
                                 progress=lambda text: self.progress("casadi", text))
        if section.get("skipped"):
            self._note("casadi", f"The casadi section is skipped: {section['skipped']}.")
        for note in goal_notes(section):
            self._note("casadi", note)
        return section

    def jax(self) -> dict:
        from .jaxbench import jax_rows

        s = self.settings
        # the models' builds and printed JAX: in --cache-dir when given (kept between runs)
        cache = Path(self.user_cache_dir) if self.user_cache_dir else None
        section = jax_rows(self.urdf_dir, self.scratch / "jax", s.jax_repeats, s.target_s,
                           progress=lambda text: self.progress("jax", text),
                           states=s.jax_states, cache_dir=cache)
        self.results["notes"].extend(section.get("notes", []))
        section["repeats"] = s.jax_repeats
        return section

    # -- the run ---------------------------------------------------------------------

    def save(self) -> Path:
        self.out.mkdir(parents=True, exist_ok=True)
        path = self.out / "results.json"
        path.write_text(json.dumps(_jsonable(self.results), indent=1) + "\n")
        return path

    def run(self) -> int:
        failed = 0
        titles = {"percall": "per call", "batched": "batched", "simulation": "simulation",
                  "throughput": "throughput", "scaling": "scaling",
                  "derivatives": "derivatives", "panda": "panda", "floating": "floating",
                  "regressor": "regressor", "centroidal": "centroidal",
                  "taskspace": "task space", "constraints": "constraints",
                  "casadi": "casadi", "jax": "jax"}
        try:
            if {"percall", "batched", "simulation", "throughput"} & set(self.settings.sections):
                start = time.perf_counter()
                try:
                    self.rrr()
                except Exception as exc:  # noqa: BLE001 - the scaling study may still run
                    text = self._rrr_error = f"{type(exc).__name__}: {exc}"
                    self.results["notes"].append(f"Building rrr failed: {text}")
                    self.progress("setup", f"FAILED: {text}")
                self.results.setdefault("rrr_build", {})["setup_s"] = time.perf_counter() - start
            for key in self.settings.sections:
                self.progress(titles[key], "start")
                load = load_average()
                start = time.perf_counter()
                try:
                    section = getattr(self, key)()
                except Exception as exc:  # noqa: BLE001 - keep the other sections' results
                    failed += 1
                    text = f"{type(exc).__name__}: {exc}"
                    section = {"error": text, "traceback": traceback.format_exc()}
                    self.results["notes"].append(f"Section {key} failed: {text}")
                    self.progress(titles[key], f"FAILED: {text}")
                section["elapsed_s"] = time.perf_counter() - start
                if load is not None:
                    section["load"] = [load, load_average()]
                self.results[key] = section
                self.progress(titles[key], f"done in {section['elapsed_s']:.1f} s")
                self.save()
            self.results["elapsed_s"] = self.progress.elapsed
            self.save()
            from .report import write_report

            path = write_report(self.results, self.out)
            self.progress("report", f"wrote {path}, results.json and the plots")
        finally:
            shutil.rmtree(self.scratch, ignore_errors=True)
        return 1 if failed else 0


def load_average() -> float | None:
    """The 1-minute load average, where the platform has one: the report gives it at each
    section's start and end, so a reader can tell a quiet run from a busy one (the machines
    are shared; ratios move with the load)."""
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):
        return None


def _short(name: str) -> str:
    return Path(name).name if name.endswith(".urdf") else name


def _jsonable(value):
    """NaN and inf as null (strict JSON); numpy scalars as Python numbers."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return value


def run(out="bench-out", mode: str = "default", urdf_dir=None, cache_dir=None,
        sections=None, scaling_models=None, command: str | None = None,
        progress: Progress | None = None) -> int:
    """Run the benchmarks of a mode and write the report; 0 if every section worked."""
    settings = Settings.for_mode(mode)
    if sections:
        settings.sections = tuple(s for s in SECTIONS if s in sections)
    if scaling_models:
        settings.scaling_models = list(scaling_models)
    bench = Bench(Path(out), settings, urdf_dir, cache_dir,
                  command or f"python -m gagen bench --out {out}"
                  + (" --full" if mode == "full" else ""), progress)
    return bench.run()
