"""The derivatives per call from Python, and what the derivative module costs to build.

Per model (rrr, and the Panda from Pinocchio's own URDF parse), interleaved in one run,
every result checked before anything is timed (against Pinocchio to 1e-9, the central
differences to 1e-5 of the largest entry):

  forward dynamics derivatives  gagen compiled, pinocchio.computeABADerivatives, and
                                central differences of gagen's compiled forward dynamics
                                (the 6n states q +- h e_j, qd +- h e_j, tau +- h e_j in one
                                stacked call, then the differences in NumPy)
  inverse dynamics derivatives  gagen compiled, pinocchio.computeRNEADerivatives
  Coriolis matrix               gagen compiled, pinocchio.computeCoriolisMatrix

Ratios are to gagen compiled's median per quantity and model (> 1: slower than gagen).

`build_rows` builds each model cold in fresh processes, the main module and then the
derivative module (each in a new cache folder): stage times, wall time and operation
counts, with and without the derivatives.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import peers
from .common import optional
from .percall import GAGEN, _candidate, rows_from
from .timing import Candidate, interleaved

QUANTITIES = ("forward dynamics derivatives", "inverse dynamics derivatives",
              "Coriolis matrix")
CENTRAL = "gagen central differences"
GOAL = 2.0  # the Panda's FD derivatives against pinocchio.computeABADerivatives
STEP = 1e-6


def central_differences(dyn, h: float = STEP):
    """(dqdd_dq, dqdd_dqd, dqdd_dtau) by central differences of `dyn.forward_dynamics`, the
    6n perturbed states in one stacked call."""
    n = dyn.n
    steps = np.vstack([np.eye(n) * h, -np.eye(n) * h])

    def derivatives(q, qd, tau):
        states = []
        for k in range(3):
            for j, x in enumerate((q, qd, tau)):
                states.append(x + steps if j == k else np.broadcast_to(x, (2 * n, n)))
        Q, QD, T = (np.vstack(states[j::3]) for j in range(3))
        qdd = dyn.forward_dynamics(Q, QD, T).reshape(3, 2, n, n)
        return tuple(((qdd[k, 0] - qdd[k, 1]) / (2 * h)).T for k in range(3))

    return derivatives


def _from_pinocchio(pm, X) -> np.ndarray:
    """A matrix over Pinocchio's velocity order in gagen's order (rows and columns)."""
    out = np.empty_like(np.asarray(X))
    out[np.ix_(pm.gagen_order, pm.gagen_order)] = X
    return out


def _agree(what: str, ours, theirs, rtol: float = 1e-9) -> None:
    for a, b in zip(ours, theirs):
        peers._agree(what, a, b, rtol)


def model_candidates(label: str, dyn, pm, q, qd, qdd, tau) -> list[Candidate]:
    """The candidates of one model, each checked first; `pm` is Pinocchio's model with
    `gagen_order` (None without Pinocchio)."""
    fd = central_differences(dyn)
    want = dyn.forward_dynamics_derivatives(q, qd, tau)
    _agree(f"{label}: gagen's FD derivatives and its central differences", want,
           fd(q, qd, tau), rtol=1e-5)
    cands = [
        _candidate("forward dynamics derivatives", GAGEN,
                   "dyn.forward_dynamics_derivatives(q, qd, tau)",
                   dyn.forward_dynamics_derivatives, (q, qd, tau)),
        _candidate("forward dynamics derivatives", CENTRAL,
                   "central differences: dyn.forward_dynamics on 6n stacked states", fd,
                   (q, qd, tau)),
        _candidate("inverse dynamics derivatives", GAGEN,
                   "dyn.inverse_dynamics_derivatives(q, qd, qdd)",
                   dyn.inverse_dynamics_derivatives, (q, qd, qdd)),
        _candidate("Coriolis matrix", GAGEN, "dyn.coriolis_matrix(q, qd)", dyn.coriolis_matrix,
                   (q, qd)),
    ]
    if pm is not None:
        cands += pinocchio_candidates(label, dyn, pm, q, qd, qdd, tau)
    for c in cands:
        c.name = f"{label}: {c.name}"
        c.group = f"{label}: {c.group}"
        c.info["model"] = label
    return cands


def pinocchio_candidates(label: str, dyn, pm, q, qd, qdd, tau) -> list[Candidate]:
    pin = optional("pinocchio")
    data = pm.createData()
    pq, pqd, pqdd, ptau = peers.to_pinocchio(pm, q, qd, qdd, tau)
    mine = {
        "ABA": dyn.forward_dynamics_derivatives(q, qd, tau),
        "RNEA": dyn.inverse_dynamics_derivatives(q, qd, qdd),
        "C": (dyn.coriolis_matrix(q, qd),),
    }
    # Pinocchio's derivatives leave out the URDF's joint damping and friction (gagen's
    # dynamics have them): its aba sees tau less those forces, and the damping adds
    # diag(damping) to dtau/dqd and -M^-1 diag(damping) to dqdd/dqd (friction's sign(qd)
    # has no derivative)
    forces = peers.joint_forces(pm, qd)
    damping = np.diag(peers.from_pinocchio(pm, pm.damping))
    (ptau_rigid,) = peers.to_pinocchio(pm, np.asarray(tau, float) - forces)
    aba = [_from_pinocchio(pm, np.array(v))
           for v in pin.computeABADerivatives(pm, data, pq, pqd, ptau_rigid)]
    aba[1] = aba[1] - aba[2] @ damping
    rnea = [_from_pinocchio(pm, np.array(v))
            for v in pin.computeRNEADerivatives(pm, data, pq, pqd, pqdd)]
    rnea[1] = rnea[1] + damping
    theirs = {"ABA": aba, "RNEA": rnea,
              "C": [_from_pinocchio(pm, np.array(pin.computeCoriolisMatrix(pm, data, pq, pqd)))]}
    for key, values in theirs.items():
        _agree(f"{label}: gagen and Pinocchio ({key})", mine[key], values)
    return [
        _candidate("forward dynamics derivatives", "Pinocchio",
                   "pinocchio.computeABADerivatives(model, data, q, v, tau)",
                   pin.computeABADerivatives, (pm, data, pq, pqd, ptau)),
        _candidate("inverse dynamics derivatives", "Pinocchio",
                   "pinocchio.computeRNEADerivatives(model, data, q, v, a)",
                   pin.computeRNEADerivatives, (pm, data, pq, pqd, pqdd)),
        _candidate("Coriolis matrix", "Pinocchio",
                   "pinocchio.computeCoriolisMatrix(model, data, q, v)",
                   pin.computeCoriolisMatrix, (pm, data, pq, pqd)),
    ]


def state(dyn, seed: int = 0):
    """A reproducible state inside the joint limits: q, qd, qdd and tau = ID(q, qd, qdd)."""
    lo, hi = [], []
    limits = {b.joint.name: b.joint.limits for b in dyn.model.bodies}
    for name in dyn.coordinates:
        lim = limits.get(name)
        ok = lim is not None and lim.lower is not None and lim.upper is not None
        lo.append(lim.lower if ok else -1.0)
        hi.append(lim.upper if ok else 1.0)
    rng = np.random.default_rng(seed)
    q = rng.uniform(lo, hi)
    qd, qdd = rng.normal(size=(2, dyn.n))
    return q, qd, qdd, dyn.inverse_dynamics(q, qd, qdd)


def derivative_rows(models: dict, repeats: int, target: float, progress=None) -> list[dict]:
    """Per-call rows of every model: `models` maps a label to (dyn, Pinocchio's model with
    gagen_order, or None)."""
    cands = []
    for label, (dyn, pm) in models.items():
        dyn.load_derivatives()
        cands += model_candidates(label, dyn, pm, *state(dyn))
    order = {(label, q): k for k, (label, q) in enumerate(
        (label, q) for label in models for q in QUANTITIES)}
    cands.sort(key=lambda c: order[c.info["model"], c.info["quantity"]])  # stable: gagen first
    if progress:
        progress(f"{len(cands)} candidates checked; timing {repeats} interleaved repeats")
    baseline = {c.group: c.name for c in cands if c.info["implementation"] == GAGEN}
    timings = interleaved(cands, repeats, target, baseline=baseline)
    rows = rows_from(timings, GAGEN)
    for row, c in zip(rows, cands):
        row["model"] = c.info["model"]
    return rows


def goal_note(rows: list[dict], label: str) -> str | None:
    """Whether the FD derivatives of `label` are at least GOAL times faster than Pinocchio's."""
    fd = {r["implementation"]: r for r in rows if r.get("model") == label
          and r["quantity"] == "forward dynamics derivatives"}
    if GAGEN not in fd or "Pinocchio" not in fd:
        return None
    speedup = fd["Pinocchio"]["median_us"] / fd[GAGEN]["median_us"]
    verdict = "met" if speedup >= GOAL else "NOT met"
    return (f"Goal: the {label}'s forward-dynamics derivatives from Python at least "
            f"{GOAL:g}x faster than pinocchio.computeABADerivatives: {verdict} "
            f"({speedup:.2f}x; gagen {fd[GAGEN]['median_us']:.2f} us, Pinocchio "
            f"{fd['Pinocchio']['median_us']:.2f} us).")


def build_rows(models: list[str], cache_dir: Path, progress=None) -> list[dict]:
    """Each model's main module and then its derivative module, built cold in fresh
    processes (a new cache folder per model)."""
    from .coldbuild import measured_build

    rows = []
    for k, name in enumerate(models):
        folder = Path(cache_dir) / f"model{k}"
        for derivatives in (False, True):
            report = measured_build(name, folder, derivatives=derivatives)
            stages = report["stages"]
            rows.append({
                "model": report["model"], "dof": report["dof"],
                "module": "derivatives" if derivatives else "main",
                "derive_s": stages.get("derive"), "generate_s": stages.get("generate"),
                "compile_s": stages.get("compile"), "wall_s": report["wall_s"],
                "peak_mb": report["peak_mb"], "ops_before_cse": report["ops_before_cse"],
                "ops_after_cse": report["ops_after_cse"]})
            if progress:
                progress(f"{report['model']} {rows[-1]['module']} module built cold in "
                         f"{report['wall_s']:.1f} s")
    return rows


def build_table(rows: list[dict]) -> str:
    lines = [("| model | dof | module | derive s | generate s | compile s | wall s | peak MB "
             "| ops before → after CSE |"),
             "|---|--:|---|--:|--:|--:|--:|--:|--:|"]
    for r in rows:
        lines.append(f"| {r['model']} | {r['dof']} | {r['module']} | {r['derive_s']:.2f} "
                     f"| {r['generate_s']:.2f} | {r['compile_s']:.2f} | {r['wall_s']:.1f} "
                     f"| {r['peak_mb']:.0f} | {r['ops_before_cse']:,} → "
                     f"{r['ops_after_cse']:,} |")
    return "\n".join(lines)
