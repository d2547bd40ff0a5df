"""Task space per call: a frame's J̇ q̇, its J̇ and an operational-space inertia against
Pinocchio, on the Panda's tool frame and an ANYmal C foot.

Pinocchio's way to each, from Python, on its own URDF parse: the bias acceleration as
`forwardKinematics(q, v, 0)` then `getFrameClassicalAcceleration` (LOCAL_WORLD_ALIGNED);
J̇ as `computeJointJacobiansTimeVariation` then `getFrameJacobianTimeVariation`; Λ as
`computeMinverse` (its upper triangle, completed) then (J M⁻¹ Jᵀ)⁻¹ with
`computeFrameJacobian` and NumPy. Results are checked against gagen's before anything is
timed; the ratios are Pinocchio's time over gagen's (> 1: gagen is faster).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from .common import optional
from .percall import GAGEN, rows_from
from .timing import Candidate, interleaved

# (URDF, floating base, frame, rows of Λ: 6 for a tool's pose, 3 for a foot's point contact)
ROBOTS = (("panda.urdf", False, "panda_hand_tcp", 6), ("anymal_c.urdf", True, "LF_FOOT", 3))
QUANTITIES = ("J̇ q̇", "J̇", "Λ")
GOAL = 1.5  # Pinocchio's time over gagen's, on each quantity


def _candidate(quantity: str, implementation: str, call: str, fn, args) -> Candidate:
    return Candidate(f"{quantity} / {implementation}", fn, tuple(args), group=quantity,
                     info={"quantity": quantity, "implementation": implementation,
                           "call": call})


def taskspace_rows(urdf_dir: Path, cache_dir: Path, repeats: int, target: float,
                   progress=None) -> list[dict]:
    """Rows of `percall.rows_from` per robot, its name in `quantity`; ratios to gagen."""
    import gagen

    rows = []
    for name, floating, frame, dims in ROBOTS:
        path = Path(urdf_dir) / name
        if not path.exists():
            if progress:
                progress(f"{name} not found in {urdf_dir}: skipped")
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", gagen.InertiaWarning)
            dyn = gagen.load(path, floating_base=floating, cache_dir=cache_dir)
        if progress:
            progress(f"{name}: nv {dyn.nv} built; timing {frame}")
        robot = f"{dyn.info.name} ({frame})"
        for row in _robot_rows(dyn, path, floating, frame, dims, repeats, target):
            rows.append({**row, "robot": robot, "quantity": f"{robot}: {row['quantity']}"})
    return rows


def goal_notes(rows: list[dict]) -> list[str]:
    """One line per robot: Pinocchio's time over gagen's on each quantity, and the goal."""
    notes = []
    for robot in dict.fromkeys(r["robot"] for r in rows):
        ratios = {r["quantity"].split(": ", 1)[1]: r["ratio"] for r in rows
                  if r["robot"] == robot and r["implementation"] == "Pinocchio"}
        if not ratios:
            continue
        met = all(ratio >= GOAL for ratio in ratios.values())
        shown = ", ".join(f"{q} {ratio:.2f}x" for q, ratio in ratios.items())
        notes.append(f"Goal: task space on {robot} at least {GOAL}x faster than Pinocchio "
                     f"per call: {'met' if met else 'NOT met'} ({shown}).")
    return notes


def _state(dyn, rng):
    q = dyn.neutral()
    if dyn.nq != dyn.nv:
        q[2] = 0.5
    joints = [k for k, name in enumerate(dyn.configuration) if name in dyn.coordinates]
    q[joints] = rng.uniform(-0.5, 0.5, len(joints))
    if "panda_joint4" in dyn.coordinates:  # the Panda's elbow bent, away from a singularity
        q[dyn.coordinates.index("panda_joint4")] = -1.5
    return q, rng.normal(size=dyn.nv)


def _robot_rows(dyn, path: Path, floating: bool, frame: str, dims: int, repeats: int,
                target: float) -> list[dict]:
    q, qd = _state(dyn, np.random.default_rng(0))
    cands = [
        _candidate("J̇ q̇", GAGEN, f"dyn.frame_bias_acceleration(q, qd, {frame!r})",
                   dyn.frame_bias_acceleration, (q, qd, frame)),
        _candidate("J̇", GAGEN, f"dyn.frame_jacobian_time_variation(q, qd, {frame!r})",
                   dyn.frame_jacobian_time_variation, (q, qd, frame)),
        _candidate("Λ", GAGEN, f"dyn.operational_space_inertia(q, {frame!r}, {dims})",
                   dyn.operational_space_inertia, (q, frame, dims)),
    ]
    cands += _pinocchio(dyn, path, floating, frame, dims, q, qd)
    base = {quantity: f"{quantity} / {GAGEN}" for quantity in QUANTITIES}
    return rows_from(interleaved(cands, repeats, target, baseline=base), GAGEN)


def _pinocchio(dyn, path: Path, floating: bool, frame: str, dims: int, q, qd
               ) -> list[Candidate]:
    pin = optional("pinocchio")
    if pin is None:
        return []
    model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer()) if floating \
        else pin.buildModelFromUrdf(str(path))
    data = model.createData()
    base = 6 if floating else 0
    ids = [model.getJointId(n) for n in dyn.coordinates[base:]]
    v_order = np.array([*range(base), *(model.idx_vs[j] for j in ids)])
    q_order = np.array([*range(base + (base > 0)), *(model.idx_qs[j] for j in ids)])
    pq, pv = np.zeros(model.nq), np.zeros(model.nv)
    pq[q_order], pv[v_order] = q, qd
    zero = np.zeros(model.nv)
    fid = model.getFrameId(frame)
    aligned = pin.LOCAL_WORLD_ALIGNED

    def bias(model, data, q, v, a, fid):
        pin.forwardKinematics(model, data, q, v, a)
        return pin.getFrameClassicalAcceleration(model, data, fid, aligned)

    def time_variation(model, data, q, v, fid):
        pin.computeJointJacobiansTimeVariation(model, data, q, v)
        return pin.getFrameJacobianTimeVariation(model, data, fid, aligned)

    def inertia(model, data, q, fid):
        Minv = pin.computeMinverse(model, data, q)  # its upper triangle
        Minv = np.triu(Minv) + np.triu(Minv, 1).T
        J = pin.computeFrameJacobian(model, data, q, fid, aligned)[:dims]
        return np.linalg.inv(J @ Minv @ J.T)

    # the same numbers first
    np.testing.assert_allclose(bias(model, data, pq, pv, zero, fid).vector,
                               dyn.frame_bias_acceleration(q, qd, frame), rtol=1e-9,
                               atol=1e-9)
    np.testing.assert_allclose(time_variation(model, data, pq, pv, fid)[:, v_order],
                               dyn.frame_jacobian_time_variation(q, qd, frame), rtol=1e-9,
                               atol=1e-9)
    np.testing.assert_allclose(inertia(model, data, pq, fid),
                               dyn.operational_space_inertia(q, frame, dims), rtol=1e-7,
                               atol=1e-9)
    return [
        _candidate("J̇ q̇", "Pinocchio", "forwardKinematics(model, data, q, v, 0); "
                   "getFrameClassicalAcceleration(model, data, frame, LOCAL_WORLD_ALIGNED)",
                   bias, (model, data, pq, pv, zero, fid)),
        _candidate("J̇", "Pinocchio", "computeJointJacobiansTimeVariation(model, data, q, v); "
                   "getFrameJacobianTimeVariation(model, data, frame, LOCAL_WORLD_ALIGNED)",
                   time_variation, (model, data, pq, pv, fid)),
        _candidate("Λ", "Pinocchio", "computeMinverse(model, data, q) completed; J = "
                   "computeFrameJacobian(..., LOCAL_WORLD_ALIGNED); inv(J Minv Jᵀ)",
                   inertia, (model, data, pq, fid)),
    ]
