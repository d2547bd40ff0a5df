"""Per-call time from Python: gagen's backends against Pinocchio, PyDy and plain SymPy.

On the paper's robot `rrr`, at one fixed state, every candidate is checked against
gagen's compiled result and then timed, all interleaved in one run:

  mass matrix       gagen compiled, gagen lambdify, pinocchio.crba
  forward dynamics  gagen compiled, gagen lambdify, PyDy Cython rhs, plain sympy.lambdify
                    + numpy.linalg.solve, pinocchio.aba
  inverse dynamics  gagen compiled, gagen lambdify, pinocchio.rnea

Ratios are to gagen compiled's median for the same quantity. `panda_rows` does the same
for the Panda against Pinocchio's own URDF parse.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import peers
from .common import fixed_state, optional
from .timing import DEFAULT_REPEATS, DEFAULT_TARGET, Candidate, interleaved

QUANTITIES = ("mass matrix", "forward dynamics", "inverse dynamics")
GAGEN = "gagen compiled"


def _candidate(quantity: str, implementation: str, call: str, fn, args) -> Candidate:
    """A timed call, grouped by quantity (every section's rows: rows_from)."""
    return Candidate(f"{quantity} / {implementation}", fn, tuple(args), group=quantity,
                     info={"quantity": quantity, "implementation": implementation,
                           "call": call})


def gagen_candidates(dyn, q, qd, qdd, tau, implementation: str) -> list[Candidate]:
    return [
        _candidate("mass matrix", implementation, "dyn.mass_matrix(q)", dyn.mass_matrix,
                   (q,)),
        _candidate("forward dynamics", implementation, "dyn.forward_dynamics(q, qd, tau)",
                   dyn.forward_dynamics, (q, qd, tau)),
        _candidate("inverse dynamics", implementation, "dyn.inverse_dynamics(q, qd, qdd)",
                   dyn.inverse_dynamics, (q, qd, qdd)),
    ]


def pinocchio_candidates(pm, q, qd, qdd, tau) -> list[Candidate]:
    pin = optional("pinocchio")
    data = pm.createData()
    pq, pqd, pqdd, ptau = peers.to_pinocchio(pm, q, qd, qdd, tau)
    return [
        _candidate("mass matrix", "Pinocchio", "pinocchio.crba(model, data, q)", pin.crba,
                   (pm, data, pq)),
        _candidate("forward dynamics", "Pinocchio", "pinocchio.aba(model, data, q, qd, tau)",
                   pin.aba, (pm, data, pq, pqd, ptau)),
        _candidate("inverse dynamics", "Pinocchio",
                   "pinocchio.rnea(model, data, q, qd, qdd)", pin.rnea,
                   (pm, data, pq, pqd, pqdd)),
    ]


def _check(what: str, ours, reference) -> None:
    peers._agree(what, ours, reference, rtol=1e-9)


def rrr_candidates(dyn, dyn_lambdify, pydy: bool = True, pinocchio: bool = True,
                   naive: bool = True, notes: list[str] | None = None) -> list[Candidate]:
    """Every per-call candidate on rrr, checked to agree with gagen compiled first."""
    notes = notes if notes is not None else []
    q, qd, tau = fixed_state(dyn.n)
    qdd = np.array(dyn.forward_dynamics(q, qd, tau))
    cands = gagen_candidates(dyn, q, qd, qdd, tau, GAGEN)
    lam = gagen_candidates(dyn_lambdify, q, qd, qdd, tau, "gagen lambdify")
    for c in lam:
        _check(f"gagen lambdify ({c.group})", c.fn(*c.args),
               next(d for d in cands if d.group == c.group).fn(*c.args))
    cands += lam
    if naive:
        fd = peers.naive_sympy(dyn_lambdify.equations)
        _check("plain sympy.lambdify (forward dynamics)", fd(q, qd, tau), qdd)
        cands.append(_candidate("forward dynamics", "SymPy lambdify (naive)",
                                "solve(M(*q, *p), F(*q, *qd, *tau, *p))", fd, (q, qd, tau)))
    if pydy:
        rhs = peers.pydy_rrr(list(dyn.parameters))
        if rhs is None:
            notes.append("PyDy is not installed: its row is skipped (pip install pydy).")
        else:
            x, p = np.concatenate([q, qd]), dyn.parameter_vector()
            _check("PyDy Cython rhs (forward dynamics)", rhs(x, 0.0, tau, p)[dyn.n:], qdd)
            cands.append(_candidate("forward dynamics", "PyDy Cython",
                                    "rhs(x, t, r, p)  # returns (qd, qdd)", rhs,
                                    (x, 0.0, tau, p)))
    if pinocchio:
        pm = peers.pinocchio_model(dyn.model)
        if pm is None:
            notes.append("Pinocchio is not installed: its rows are skipped (pip install pin).")
        else:
            peers.check_pinocchio(dyn, pm, q, qd, qdd, tau)
            cands += pinocchio_candidates(pm, q, qd, qdd, tau)
    order = {quantity: k for k, quantity in enumerate(QUANTITIES)}
    return sorted(cands, key=lambda c: order[c.group])  # stable: gagen first per quantity


def rows_from(timings, baseline_label: str) -> list[dict]:
    """Table rows (microseconds) from per-call timings."""
    rows = []
    for t in timings:
        rows.append({
            "quantity": t.info["quantity"], "implementation": t.info["implementation"],
            "call": t.info["call"], "median_us": t.median * 1e6, "q1_us": t.q1 * 1e6,
            "q3_us": t.q3 * 1e6, "iqr_us": t.iqr * 1e6, "ratio": t.ratio,
            "baseline": baseline_label if t.ratio is not None else None,
            "number": t.number, "repeats": len(t.samples), "samples_s": list(t.samples),
        })
    return rows


def percall_rows(dyn, dyn_lambdify, repeats: int = DEFAULT_REPEATS,
                 target: float = DEFAULT_TARGET, notes: list[str] | None = None,
                 progress=None, **which) -> list[dict]:
    """The per-call table on rrr: one row per (quantity, implementation)."""
    cands = rrr_candidates(dyn, dyn_lambdify, notes=notes, **which)
    if progress:
        progress(f"{len(cands)} candidates checked; timing {repeats} interleaved repeats")
    timings = interleaved(cands, repeats, target,
                          baseline={q: f"{q} / {GAGEN}" for q in QUANTITIES})
    return rows_from(timings, GAGEN)


def panda_rows(dyn, urdf: Path, repeats: int = DEFAULT_REPEATS, target: float = 0.05,
               baseline: str = "pinocchio") -> list[dict]:
    """Per-call rows for a URDF robot, gagen compiled against Pinocchio's own URDF parse.

    Implementations "gagen compiled" and "Pinocchio"; `baseline` is "pinocchio" or
    "gagen": whose median each ratio divides by. Without pinocchio only gagen is timed
    (no ratios).
    """
    limits = {b.joint.name: b.joint.limits for b in dyn.model.bodies}
    lo, hi = [], []
    for name in dyn.coordinates:
        lim = limits[name]
        ok = lim is not None and lim.lower is not None and lim.upper is not None
        lo.append(lim.lower if ok else -np.pi)
        hi.append(lim.upper if ok else np.pi)
    rng = np.random.default_rng(0)
    q = rng.uniform(lo, hi)
    qd, qdd = rng.normal(size=dyn.n), rng.normal(size=dyn.n)
    tau = dyn.inverse_dynamics(q, qd, qdd)
    cands = gagen_candidates(dyn, q, qd, qdd, tau, GAGEN)
    pm = peers.pinocchio_from_urdf(dyn, urdf)
    if pm is not None:
        peers.check_pinocchio(dyn, pm, q, qd, qdd, tau)
        cands += pinocchio_candidates(pm, q, qd, qdd, tau)
    label = "Pinocchio" if baseline == "pinocchio" else GAGEN
    base = {q_: f"{q_} / {label}" for q_ in QUANTITIES} if pm is not None else None
    order = {quantity: k for k, quantity in enumerate(QUANTITIES)}
    cands.sort(key=lambda c: order[c.group])
    timings = interleaved(cands, repeats, target, baseline=base)
    return rows_from(timings, label)
