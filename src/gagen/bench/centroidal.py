"""Centroidal dynamics per call: ANYmal C (the whole robot) against Pinocchio.

gagen's `centroidal_map` (A_g), `centroidal_bias` (d/dt A_g qd), both together,
`centroidal_map_time_variation` and `center_of_mass` against Pinocchio's
`computeCentroidalMap` and `ccrba` (A_g, and h_g with it), `dccrba` (A_g and d/dt A_g: the
peer of A_g and its bias together, what a centroidal MPC asks for at each step),
`computeCentroidalMapTimeVariation` and `centerOfMass`, on Pinocchio's FreeFlyer and its
own URDF parse. Results are checked against Pinocchio's before anything is timed.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from .common import optional
from .percall import GAGEN, rows_from
from .timing import Candidate, interleaved

ROBOT = "anymal_c.urdf"
QUANTITIES = ("A_g", "A_g and its bias d/dt A_g qd", "d/dt A_g", "centre of mass")
GOAL = 1.5  # Pinocchio's time over gagen's, for A_g alone and with its bias


def _candidate(quantity: str, implementation: str, call: str, fn, args) -> Candidate:
    return Candidate(f"{quantity} / {implementation}", fn, tuple(args), group=quantity,
                     info={"quantity": quantity, "implementation": implementation,
                           "call": call})


def centroidal_rows(urdf_dir: Path, cache_dir: Path, repeats: int, target: float,
                    progress=None) -> list[dict]:
    """Rows of `percall.rows_from` for ANYmal C (a `robot` prefix on the quantity), ratios
    to gagen; [] when the URDF is missing."""
    import gagen

    path = Path(urdf_dir) / ROBOT
    if not path.exists():
        if progress:
            progress(f"{ROBOT} not found in {urdf_dir}: skipped")
        return []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        dyn = gagen.load(path, floating_base=True, cache_dir=cache_dir)
    if progress:
        progress(f"{ROBOT}: nq {dyn.nq}, nv {dyn.nv} built; timing")
    robot = f"{dyn.info.name} (floating, nv = {dyn.nv})"
    rows = _rows(dyn, path, repeats, target)
    return [{**row, "quantity": f"{robot}: {row['quantity']}"} for row in rows]


def _rows(dyn, path: Path, repeats: int, target: float) -> list[dict]:
    rng = np.random.default_rng(0)
    q = dyn.neutral()
    q[2] = 0.5
    joints = [k for k, name in enumerate(dyn.configuration) if name in dyn.coordinates]
    q[joints] = rng.uniform(-0.5, 0.5, len(joints))
    qd = rng.normal(size=dyn.nv)

    def map_and_bias(q, qd):
        return dyn.centroidal_map(q), dyn.centroidal_bias(q, qd)

    cands = [
        _candidate("A_g", GAGEN, "dyn.centroidal_map(q)", dyn.centroidal_map, (q,)),
        _candidate("A_g and its bias d/dt A_g qd", GAGEN,
                   "dyn.centroidal_map(q), dyn.centroidal_bias(q, qd)", map_and_bias, (q, qd)),
        _candidate("d/dt A_g", GAGEN, "dyn.centroidal_map_time_variation(q, qd)",
                   dyn.centroidal_map_time_variation, (q, qd)),
        _candidate("centre of mass", GAGEN, "dyn.center_of_mass(q)", dyn.center_of_mass,
                   (q,)),
    ]
    cands += _pinocchio(dyn, path, q, qd)
    base = {quantity: f"{quantity} / {GAGEN}" for quantity in QUANTITIES}
    return rows_from(interleaved(cands, repeats, target, baseline=base), GAGEN)


def _pinocchio(dyn, path: Path, q, qd) -> list[Candidate]:
    pin = optional("pinocchio")
    if pin is None:
        return []
    model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    data = model.createData()
    ids = [model.getJointId(n) for n in dyn.coordinates[6:]]
    v_order = np.array([*range(6), *(model.idx_vs[j] for j in ids)])
    q_order = np.array([*range(7), *(model.idx_qs[j] for j in ids)])
    pq = np.zeros(model.nq)
    pq[q_order] = q
    pqd = np.zeros(model.nv)
    pqd[v_order] = qd
    # the results agree before anything is timed
    dA = pin.dccrba(model, data, pq, pqd)
    np.testing.assert_allclose(data.Ag[:, v_order], dyn.centroidal_map(q), rtol=1e-9,
                               atol=1e-9)
    np.testing.assert_allclose(dA[:, v_order], dyn.centroidal_map_time_variation(q, qd),
                               rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(dA @ pqd, dyn.centroidal_bias(q, qd), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(pin.centerOfMass(model, data, pq), dyn.center_of_mass(q),
                               rtol=1e-9, atol=1e-12)
    return [
        _candidate("A_g", "Pinocchio", "pinocchio.computeCentroidalMap(model, data, q)",
                   pin.computeCentroidalMap, (model, data, pq)),
        _candidate("A_g", "Pinocchio ccrba (A_g and h_g)", "pinocchio.ccrba(model, data, q, v)",
                   pin.ccrba, (model, data, pq, pqd)),
        _candidate("A_g and its bias d/dt A_g qd", "Pinocchio",
                   "pinocchio.dccrba(model, data, q, v)", pin.dccrba, (model, data, pq, pqd)),
        _candidate("d/dt A_g", "Pinocchio",
                   "pinocchio.computeCentroidalMapTimeVariation(model, data, q, v)",
                   pin.computeCentroidalMapTimeVariation, (model, data, pq, pqd)),
        _candidate("centre of mass", "Pinocchio", "pinocchio.centerOfMass(model, data, q)",
                   pin.centerOfMass, (model, data, pq)),
    ]


def goal_notes(rows: list[dict]) -> list[str]:
    """The goal (Pinocchio at least GOAL times slower) for A_g against ccrba and for A_g with
    its bias against dccrba, met or not, from the rows' ratios."""
    notes = []
    for quantity, peer in (("A_g", "Pinocchio ccrba (A_g and h_g)"),
                           ("A_g and its bias d/dt A_g qd", "Pinocchio")):
        ratio = next((r["ratio"] for r in rows if r["quantity"].endswith(": " + quantity)
                      and r["implementation"] == peer), None)
        if ratio is None:
            continue
        verdict = "met" if ratio >= GOAL else "NOT met"
        call = "ccrba" if "ccrba" in peer else "dccrba"
        notes.append(f"Goal: {quantity} per call from Python at least {GOAL}x faster than "
                     f"Pinocchio's {call} on ANYmal C: {verdict} ({ratio:.2f}x).")
    return notes
