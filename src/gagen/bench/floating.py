"""Floating bases per call: a quadruped and a humanoid against Pinocchio and MuJoCo.

ANYmal C (18 velocity coordinates) and Talos (50), each on Pinocchio's FreeFlyer, from
their URDFs: gagen's forward dynamics, inverse dynamics, mass matrix and a foot's frame
Jacobian (LOCAL_WORLD_ALIGNED) against `pinocchio.aba`, `rnea`, `crba` and
`computeFrameJacobian` on Pinocchio's own URDF parse, and against MuJoCo's `mj_forward`
on the same URDF with a floating joint and no contacts (MuJoCo's one call computes the
kinematics, M, the bias forces and qacc together: the peer of forward dynamics, where it
applies). Results are checked against Pinocchio's before anything is timed.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np

from .common import optional
from .percall import GAGEN, _candidate, rows_from
from .timing import Candidate, interleaved

ROBOTS = (("anymal_c.urdf", "LF_FOOT"), ("talos_full_v2.urdf", "left_sole_link"))
QUANTITIES = ("forward dynamics", "inverse dynamics", "mass matrix", "frame Jacobian")



def floating_rows(urdf_dir: Path, cache_dir: Path, repeats: int, target: float,
                  progress=None) -> list[dict]:
    """Rows of `percall.rows_from` per robot (a `robot` key added), ratios to gagen."""
    import warnings

    import gagen

    rows = []
    for name, frame in ROBOTS:
        path = Path(urdf_dir) / name
        if not path.exists():
            if progress:
                progress(f"{name} not found in {urdf_dir}: skipped")
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", gagen.InertiaWarning)
            dyn = gagen.load(path, floating_base=True, cache_dir=cache_dir)
        if progress:
            progress(f"{name}: nq {dyn.nq}, nv {dyn.nv} built; timing")
        robot = f"{dyn.info.name} (floating, nv = {dyn.nv})"
        for row in _robot_rows(dyn, path, frame, repeats, target):
            rows.append({**row, "quantity": f"{robot}: {row['quantity']}"})
    return rows


def _robot_rows(dyn, path: Path, frame: str, repeats: int, target: float) -> list[dict]:
    rng = np.random.default_rng(0)
    q = dyn.neutral()
    q[2] = 0.5
    joints = [k for k, name in enumerate(dyn.configuration) if name in dyn.coordinates]
    q[joints] = rng.uniform(-0.5, 0.5, len(joints))
    qd, qdd = rng.normal(size=dyn.nv), rng.normal(size=dyn.nv)
    tau = dyn.inverse_dynamics(q, qd, qdd)
    cands = [
        _candidate("forward dynamics", GAGEN, "dyn.forward_dynamics(q, qd, tau)",
                   dyn.forward_dynamics, (q, qd, tau)),
        _candidate("inverse dynamics", GAGEN, "dyn.inverse_dynamics(q, qd, qdd)",
                   dyn.inverse_dynamics, (q, qd, qdd)),
        _candidate("mass matrix", GAGEN, "dyn.mass_matrix(q)", dyn.mass_matrix, (q,)),
        _candidate("frame Jacobian", GAGEN, f"dyn.frame_jacobian(q, {frame!r})",
                   dyn.frame_jacobian, (q, frame)),
    ]
    cands += _pinocchio(dyn, path, frame, q, qd, qdd, tau)
    cands += _mujoco(dyn, path, q, qd, tau)
    base = {quantity: f"{quantity} / {GAGEN}" for quantity in QUANTITIES}
    return rows_from(interleaved(cands, repeats, target, baseline=base), GAGEN)


def _pinocchio(dyn, path: Path, frame: str, q, qd, qdd, tau) -> list[Candidate]:
    pin = optional("pinocchio")
    if pin is None:
        return []
    model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    data = model.createData()
    ids = [model.getJointId(n) for n in dyn.coordinates[6:]]
    v_order = np.array([*range(6), *(model.idx_vs[j] for j in ids)])
    q_order = np.array([*range(7), *(model.idx_qs[j] for j in ids)])

    def ours_to_pin(x, order, size):
        out = np.zeros(size)
        out[order] = x
        return out

    pq = ours_to_pin(q, q_order, model.nq)
    pqd, pqdd, ptau = (ours_to_pin(x, v_order, model.nv) for x in (qd, qdd, tau))
    fid = model.getFrameId(frame)
    # the results agree before anything is timed; Pinocchio's aba leaves out the URDF's
    # joint damping and friction (Talos has them), which gagen's dynamics include
    friction = model.damping * pqd + model.friction * np.sign(pqd)
    np.testing.assert_allclose(pin.aba(model, data, pq, pqd, ptau - friction)[v_order],
                               dyn.forward_dynamics(q, qd, tau), rtol=1e-8, atol=1e-8)
    J = pin.computeFrameJacobian(model, data, pq, fid, pin.LOCAL_WORLD_ALIGNED)
    np.testing.assert_allclose(J[:, v_order], dyn.frame_jacobian(q, frame), atol=1e-10)
    return [
        _candidate("forward dynamics", "Pinocchio", "pinocchio.aba(model, data, q, v, tau)",
                   pin.aba, (model, data, pq, pqd, ptau)),
        _candidate("inverse dynamics", "Pinocchio", "pinocchio.rnea(model, data, q, v, a)",
                   pin.rnea, (model, data, pq, pqd, pqdd)),
        _candidate("mass matrix", "Pinocchio", "pinocchio.crba(model, data, q)", pin.crba,
                   (model, data, pq)),
        _candidate("frame Jacobian", "Pinocchio",
                   "pinocchio.computeFrameJacobian(model, data, q, frame, "
                   "LOCAL_WORLD_ALIGNED)", pin.computeFrameJacobian,
                   (model, data, pq, fid, pin.LOCAL_WORLD_ALIGNED)),
    ]


def _mujoco(dyn, path: Path, q, qd, tau) -> list[Candidate]:
    """mj_forward on MuJoCo's import of the URDF with a floating joint to the world (its
    geometry stripped: no meshes, no contacts); skipped when MuJoCo is missing or refuses
    the file (its compiler checks inertias more strictly than Pinocchio)."""
    mujoco = optional("mujoco")
    if mujoco is None:
        return []
    text = _floating_urdf(path.read_text(), dyn.model.bodies[0].name)
    with tempfile.TemporaryDirectory() as folder:
        copy = Path(folder) / path.name
        copy.write_text(text)
        try:
            model = mujoco.MjModel.from_xml_path(str(copy))
        except ValueError:
            return []
    data = mujoco.MjData(model)
    if model.nv != dyn.nv:
        return []
    if model.nq == dyn.nq:  # MuJoCo's free joint: quaternion w first
        data.qpos[:] = np.concatenate([q[:3], [q[6]], q[3:6], q[7:]])
    data.qvel[:] = qd
    data.qfrc_applied[:] = tau
    return [_candidate("forward dynamics", "MuJoCo", "mujoco.mj_forward(model, data)",
                       mujoco.mj_forward, (model, data))]


def _floating_urdf(text: str, root: str) -> str:
    """The URDF without geometry, its root link on a floating joint to a `world` link."""
    text = re.sub(r"<(visual|collision)\b.*?</\1>", "", text, flags=re.DOTALL)
    start = text.index("<link")
    joint = (f'<link name="world"/><joint name="floating_base" type="floating">'
             f'<parent link="world"/><child link="{root}"/></joint>')
    return text[:start] + joint + text[start:]
