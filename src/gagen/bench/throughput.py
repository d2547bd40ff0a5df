"""Throughput of many simulations: `gagen.simulate_batch` on 1 thread and on every core, a
Python loop over `gagen.simulate`, MuJoCo's `rollout`, and Dask's overhead per chunk.

Workloads:
    paper  rrr's 5-s run of `python -m gagen simulate` (paper_controller(), dopri5,
           rtol = 1e-6, atol = 1e-8, 501 samples), N runs with m3 drawn in 40 ... 60 kg
    panda  the Panda (URDF) under `default_controller` (PD with gravity compensation),
           fixed-step RK4, h = 1 ms, 1 s, the state at every step; against MuJoCo's
           `rollout` on the same URDF (meshes and contacts left out, the joints'
           damping kept in both, as gagen reads it into its joint terms; constraints
           disabled, the same RK4 and step, the PD as position actuators
           with kp and kv, gravity compensation as gravcomp = 1 on every body): the
           choice a MuJoCo user would make. Both give the same trajectory (checked).

Each candidate is one call that runs all N simulations, timed interleaved. Reported:
median seconds per call, simulations per second and states per second (N times the
samples per run, over the median), and the ratio to gagen on one thread. Dask: the same
paper batch on a LocalCluster of two worker processes with one thread each, in chunks;
its overhead per chunk is (Dask's median - gagen's median on every core) / chunks.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..sim.batch import simulate_batch
from ..sim.controllers import default_controller, paper_controller
from ..sim.simulate import simulate
from .timing import Candidate, interleaved

THREAD_GOAL = 1.8  # speed-up of every core over one thread, on 2 cores
PAPER_SPAN, PANDA_SPAN, PANDA_H = (0.0, 5.0), (0.0, 1.0), 1e-3


def paper_workload(dyn, runs: int) -> dict:
    """simulate_batch's arguments for N paper runs with m3 drawn uniformly in 40 ... 60 kg."""
    m3 = np.random.default_rng(0).uniform(40.0, 60.0, runs)
    return {"args": (dyn, PAPER_SPAN, np.zeros((runs, 3)), None, paper_controller()),
            "kwargs": {"p": {"m3": m3}, "method": "dopri5"},
            "loop_p": [{"m3": v} for v in m3], "samples": 501}


def panda_workload(dyn, runs: int) -> dict:
    te = np.linspace(*PANDA_SPAN, round((PANDA_SPAN[1] - PANDA_SPAN[0]) / PANDA_H) + 1)
    return {"args": (dyn, PANDA_SPAN, np.zeros((runs, dyn.n)), None, default_controller(dyn)),
            "kwargs": {"method": "rk4", "h": PANDA_H, "t_eval": te},
            "loop_p": [None] * runs, "samples": te.size - 1}


def _python_loop(work: dict):
    dyn, span, q0, qd0, ctrl = work["args"]
    kwargs = dict(work["kwargs"])
    kwargs.pop("p", None)
    for i, p in enumerate(work["loop_p"]):
        simulate(dyn, span, q0[i], qd0, ctrl, p=p, **kwargs)


def gagen_candidates(work: dict, threads: int) -> list[Candidate]:
    def batch(k):
        return simulate_batch(*work["args"], threads=k, **work["kwargs"])

    return [Candidate("gagen, 1 thread", batch, (1,)),
            Candidate(f"gagen, {threads} threads", batch, (threads,)),
            Candidate("Python loop over gagen.simulate", _python_loop, (work,))]


# --------------------------------------------------------------------------- MuJoCo


def mujoco_panda(urdf: Path, ctrl_spec: dict, coordinates: list[str]):
    """MuJoCo's model of the URDF as a peer of gagen's PD run (see the module docstring)."""
    import mujoco

    root = ET.parse(urdf).getroot()
    for parent in list(root.iter("link")) + list(root.iter("joint")):
        for tag in ("visual", "collision"):
            for element in parent.findall(tag):
                parent.remove(element)
    spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_RK4
    spec.option.timestep = PANDA_H
    spec.option.disableflags |= (mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
                                 | mujoco.mjtDisableBit.mjDSBL_CONTACT)
    for body in spec.bodies:
        body.gravcomp = 1.0
    for k, name in enumerate(coordinates):
        actuator = spec.add_actuator()
        actuator.target = name
        actuator.trntype = mujoco.mjtTrn.mjTRN_JOINT
        actuator.set_to_position(kp=float(ctrl_spec["kp"][k]), kv=float(ctrl_spec["kd"][k]))
    model = spec.compile()
    if [model.joint(i).name for i in range(model.njnt)] != list(coordinates):
        raise RuntimeError("MuJoCo's joints are not gagen's coordinates")
    return model


def mujoco_candidates(model, target, runs: int, threads: int) -> tuple[list[Candidate], object]:
    """Rollouts of `runs` Panda runs on 1 and `threads` threads; and a function that
    returns the states of one rollout (to check them against gagen's)."""
    import mujoco
    from mujoco import rollout

    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state0 = np.zeros(mujoco.mj_stateSize(model, full))
    mujoco.mj_getState(model, mujoco.MjData(model), state0, full)
    initial = np.tile(state0, (runs, 1))
    control = np.asarray(target, dtype=float).reshape(1, 1, -1)
    nstep = round((PANDA_SPAN[1] - PANDA_SPAN[0]) / PANDA_H)
    datas = {k: [mujoco.MjData(model) for _ in range(k)] for k in (1, threads)}

    def run(k):
        return rollout.rollout(model, datas[k], initial, control, nstep=nstep)[0]

    return ([Candidate("MuJoCo rollout, 1 thread", run, (1,)),
             Candidate(f"MuJoCo rollout, {threads} threads", run, (threads,))],
            lambda: run(1))


# --------------------------------------------------------------------------- rows


def timing_rows(candidates: list[Candidate], runs: int, samples: int, repeats: int,
                target: float, workload: str) -> list[dict]:
    timings = interleaved(candidates, repeats, target, baseline="gagen, 1 thread")
    return [{"workload": workload, "candidate": t.name, "runs": runs, "median_s": t.median,
             "q1_s": t.q1, "q3_s": t.q3, "repeats": len(t.samples),
             "sims_per_s": runs / t.median, "states_per_s": runs * samples / t.median,
             "ratio": t.ratio} for t in timings]


def dask_rows(dyn, runs: int, chunks: int, repeats: int, local_median: float) -> list[dict]:
    """The paper batch on a 2-process LocalCluster in `chunks` chunks: time and overhead."""
    import logging

    from distributed import Client, LocalCluster

    work = paper_workload(dyn, runs)
    # the cluster's own INFO lines would bury the bench's progress
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None, silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        def batch():
            return simulate_batch(*work["args"], client=client, chunk_size=-(-runs // chunks),
                                  **work["kwargs"])

        batch()  # the workers receive and import the module once, before the timing
        [t] = interleaved([Candidate("gagen on Dask", batch)], repeats, 0.0)
    return [{"workload": "paper", "candidate": f"gagen on Dask (2 workers, {chunks} chunks)",
             "runs": runs, "median_s": t.median, "q1_s": t.q1, "q3_s": t.q3,
             "repeats": len(t.samples), "sims_per_s": runs / t.median,
             "states_per_s": runs * work["samples"] / t.median, "ratio": None,
             "overhead_per_chunk_s": (t.median - local_median) / chunks}]


def markdown_table(rows: list[dict]) -> str:
    lines = ["| workload | candidate | N | median | sims/s | states/s | vs gagen, 1 thread |",
             "|---|---|--:|--:|--:|--:|--:|"]
    for r in rows:
        ratio = "" if r.get("ratio") is None else f"{r['ratio']:.2f}"
        lines.append(f"| {r['workload']} | {r['candidate']} | {r['runs']} "
                     f"| {r['median_s'] * 1e3:.1f} ms | {r['sims_per_s']:,.0f} "
                     f"| {r['states_per_s']:,.0f} | {ratio} |")
    return "\n".join(lines)


def thread_speedups(rows: list[dict]) -> dict[str, float]:
    """Per workload: gagen's one-thread median over its all-cores median."""
    out = {}
    for workload in {r["workload"] for r in rows}:
        mine = {r["candidate"]: r for r in rows if r["workload"] == workload}
        many = [r for name, r in mine.items()
                if name.startswith("gagen, ") and name != "gagen, 1 thread"]
        if "gagen, 1 thread" in mine and many:
            out[workload] = mine["gagen, 1 thread"]["median_s"] / many[0]["median_s"]
    return out


