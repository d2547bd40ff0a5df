"""The derivatives per call from Python, and what the derivative module costs to build.

Per model (rrr, the Panda, and ANYmal C and Talos reduced on a floating base, the robots
from Pinocchio's own URDF parse, on its FreeFlyer for the floating ones), interleaved in
one run, every result checked before anything is timed (against Pinocchio to 1e-9, the
central differences to 1e-5 of the largest entry):

  forward dynamics derivatives  gagen compiled, pinocchio.computeABADerivatives, and
                                central differences of gagen's compiled forward dynamics
                                (the 6n states q +- h e_j, qd +- h e_j, tau +- h e_j in one
                                stacked call, then the differences in NumPy)
  inverse dynamics derivatives  gagen compiled, pinocchio.computeRNEADerivatives
  Coriolis matrix               gagen compiled, pinocchio.computeCoriolisMatrix

(The central differences are left out on a floating base, whose q is not a vector space.)
Ratios are to gagen compiled's median per quantity and model (> 1: slower than gagen).

`build_rows` builds each model cold in fresh processes, the main module and then the
derivative module (each in a new cache folder): stage times, wall time and operation
counts, with and without the derivatives. On a floating base the derivatives are also
timed in C against CasADi's generated Jacobian of adam's articulated-body algorithm
(bench/casadi_c.py).
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
# ... the floating robots' FD and ID derivatives against Pinocchio's, from Python
FLOATING_GOAL = 2.0
FLOATING_ROBOTS = (("ANYmal C", "anymal_c.urdf"), ("Talos reduced", "talos_reduced.urdf"))
# gagen's forward-dynamics derivatives against CasADi's Jacobian of adam's ABA, in C
CASADI_GOAL = 1.5
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
    cands = [
        _candidate("forward dynamics derivatives", GAGEN,
                   "dyn.forward_dynamics_derivatives(q, qd, tau)",
                   dyn.forward_dynamics_derivatives, (q, qd, tau))]
    if dyn.nq == dyn.nv:  # central differences in q: not on a floating base
        fd = central_differences(dyn)
        want = dyn.forward_dynamics_derivatives(q, qd, tau)
        _agree(f"{label}: gagen's FD derivatives and its central differences", want,
               fd(q, qd, tau), rtol=1e-5)
        cands.append(_candidate("forward dynamics derivatives", CENTRAL,
                                "central differences: dyn.forward_dynamics on 6n stacked "
                                "states", fd, (q, qd, tau)))
    cands += [
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
    from ..reference.pinocchio import configuration_to_pinocchio

    pin = optional("pinocchio")
    data = pm.createData()
    pq, pqd, pqdd, ptau = peers.to_pinocchio(pm, q, qd, qdd, tau)
    if dyn.nq != dyn.nv:
        pq = configuration_to_pinocchio(pm, q)
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
    aba[2] = np.triu(aba[2]) + np.triu(aba[2], 1).T  # its M^-1 may fill one triangle
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
    """A reproducible state inside the joint limits: q, qd, qdd and tau = ID(q, qd, qdd); a
    floating joint at a random position and orientation."""
    lo, hi = [], []
    limits = {b.joint.name: b.joint.limits for b in dyn.model.bodies}
    plain = [k for k, name in enumerate(dyn.configuration) if name in dyn.coordinates]
    for k in plain:
        lim = limits.get(dyn.configuration[k])
        ok = lim is not None and lim.lower is not None and lim.upper is not None
        lo.append(lim.lower if ok else -1.0)
        hi.append(lim.upper if ok else 1.0)
    rng = np.random.default_rng(seed)
    q = dyn.neutral()
    q[plain] = rng.uniform(lo, hi)
    for iq, _ in dyn.info.floating_joints():
        quaternion = rng.normal(size=4)
        q[iq: iq + 3], q[iq + 3: iq + 7] = rng.normal(size=3), quaternion / np.linalg.norm(
            quaternion)
    qd, qdd = rng.normal(size=(2, dyn.n))
    return q, qd, qdd, dyn.inverse_dynamics(q, qd, qdd)


def pinocchio_floating(dyn, urdf: Path):
    """Pinocchio's own URDF parse on its FreeFlyer, with `gagen_order` (gagen's velocity
    index of each of Pinocchio's) and `gagen_configuration_order` (the same for q), as
    gagen's Pinocchio builder gives them; None without Pinocchio."""
    pin = optional("pinocchio")
    if pin is None:
        return None
    pm = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    ids = [pm.getJointId(name) for name in dyn.coordinates[6:]]
    v_of = np.array([*range(6), *(pm.idx_vs[j] for j in ids)])  # Pinocchio's of gagen's
    q_of = np.array([*range(7), *(pm.idx_qs[j] for j in ids)])
    pm.gagen_order, pm.gagen_configuration_order = np.argsort(v_of), np.argsort(q_of)
    return pm


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


def goal_note(rows: list[dict], label: str, quantity: str = "forward dynamics derivatives",
              goal: float = GOAL) -> str | None:
    """Whether gagen's `quantity` of `label` is at least `goal` times faster than
    Pinocchio's, from Python."""
    found = {r["implementation"]: r for r in rows if r.get("model") == label
             and r["quantity"] == quantity}
    if GAGEN not in found or "Pinocchio" not in found:
        return None
    speedup = found["Pinocchio"]["median_us"] / found[GAGEN]["median_us"]
    verdict = "met" if speedup >= goal else "NOT met"
    peer = {"forward dynamics derivatives": "computeABADerivatives",
            "inverse dynamics derivatives": "computeRNEADerivatives"}.get(quantity, quantity)
    return (f"Goal: {label}'s {quantity} from Python at least {goal:g}x faster than "
            f"pinocchio.{peer}: {verdict} ({speedup:.2f}x; gagen "
            f"{found[GAGEN]['median_us']:.2f} us, Pinocchio "
            f"{found['Pinocchio']['median_us']:.2f} us).")


def casadi_rows(robots: dict, folder: Path, progress=None) -> tuple[list[dict], list[str]]:
    """Per floating robot (label -> (dyn, urdf)): gagen's forward-dynamics derivatives and
    CasADi's Jacobian of adam's ABA in one C harness (bench/casadi_c.py); rows and notes."""
    from .casadi_c import c_times

    rows, notes = [], []
    for label, (dyn, urdf) in robots.items():
        times, why = c_times(dyn, urdf, folder, progress=progress)
        if times is None:
            notes.append(f"{label}: CasADi's C is not timed: {why}")
            continue
        ratio = times["casadi"] / times["gagen"]
        rows.append({"model": label, "nv": dyn.nv, "gagen_us": times["gagen"],
                     "casadi_us": times["casadi"], "ratio": ratio})
        verdict = "met" if ratio >= CASADI_GOAL else "NOT met"
        notes.append(f"Goal: {label}'s forward-dynamics derivatives in C at least "
                     f"{CASADI_GOAL:g}x faster than CasADi's generated Jacobian of adam's "
                     f"aba: {verdict} ({ratio:.2f}x; gagen {times['gagen']:.2f} us, CasADi "
                     f"{times['casadi']:.2f} us per evaluation).")
    return rows, notes


def casadi_table(rows: list[dict]) -> str:
    lines = [("| model | nv | gagen `forward_dynamics_derivatives` µs | CasADi Jacobian of "
              "adam's `aba` µs | CasADi / gagen |"), "|---|--:|--:|--:|--:|"]
    for r in rows:
        lines.append(f"| {r['model']} | {r['nv']} | {r['gagen_us']:.2f} | "
                     f"{r['casadi_us']:.2f} | {r['ratio']:.2f} |")
    return "\n".join(lines)


def build_rows(models: list, cache_dir: Path, progress=None) -> list[dict]:
    """Each model's main module and then its derivative module, built cold in fresh
    processes (a new cache folder per model). A model is a name, or (name, floating_base)."""
    from .coldbuild import measured_build

    rows = []
    for k, spec in enumerate(models):
        name, floating = spec if isinstance(spec, tuple) else (spec, False)
        folder = Path(cache_dir) / f"model{k}"
        for derivatives in (False, True):
            report = measured_build(name, folder, derivatives=derivatives,
                                    floating_base=floating)
            stages = report["stages"]
            rows.append({
                "model": report["model"] + (" (floating)" if floating else ""),
                "dof": report["dof"],
                "module": "derivatives" if derivatives else "main",
                "derive_s": stages.get("derive"), "generate_s": stages.get("generate"),
                "compile_s": stages.get("compile"), "wall_s": report["wall_s"],
                "peak_mb": report["peak_mb"], "ops_before_cse": report["ops_before_cse"],
                "ops_after_cse": report["ops_after_cse"]})
            if progress:
                progress(f"{report['model']} {rows[-1]['module']} module built cold in "
                         f"{report['wall_s']:.1f} s")
    return rows


def build_notes(rows: list[dict], models: list[str]) -> list[str]:
    """Whether each of `models`' derivative module builds cold no slower than its main
    module."""
    notes = []
    for model in models:
        walls = {r["module"]: r["wall_s"] for r in rows if r["model"] == model}
        if len(walls) == 2:
            verdict = "met" if walls["derivatives"] <= walls["main"] else "NOT met"
            notes.append(f"Goal: {model}'s derivative module built cold no slower than its "
                         f"main module: {verdict} ({walls['derivatives']:.1f} s against "
                         f"{walls['main']:.1f} s).")
    return notes


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
