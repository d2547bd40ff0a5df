"""One Pinocchio model builder, for the tests and the benchmarks (Pinocchio is optional:
`pip install gagen[bench]` or `gagen[test]`).

Pinocchio needs its joints in depth-first order, which gagen's parents-first body order
need not be, so joints are added depth-first and `pm.gagen_order[k]` is gagen's
coordinate index of Pinocchio's k-th velocity; `to_pinocchio` / `from_pinocchio` convert
vectors (one permutation serves qd, qdd and tau, and q when no joint floats;
`configuration_to_pinocchio` converts q).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..model.numeric import NumericModel, numeric_model


def pinocchio_model(model, p=None, aligned: bool = False) -> Any:
    """A pinocchio.Model with the same tree, inertias and gravity as a gagen Model (at its
    defaults overridden by `p`) or a NumericModel. ImportError if Pinocchio is missing.

    With `aligned`, a joint whose axis is a coordinate axis is Pinocchio's specialised
    RX/RY/RZ (PX/PY/PZ), as Pinocchio's URDF parser makes it, instead of the general
    "unaligned" joint: the fair peer for timing."""
    import pinocchio as pin

    nm = model if isinstance(model, NumericModel) else numeric_model(model, p)
    pm = pin.Model()
    joint_of: dict[int, int] = {}  # per body: the Pinocchio joint carrying it
    placement: dict[int, Any] = {}  # and its frame's placement in that joint
    order: list[int] = []
    config_order: list[int] = []
    terms: list[tuple[float, float, float]] = []  # (armature, damping, friction) per velocity
    for i in nm.depth_first():
        b = nm.bodies[i]
        parent_joint = 0 if b.parent < 0 else joint_of[b.parent]
        parent_place = pin.SE3.Identity() if b.parent < 0 else placement[b.parent]
        origin = parent_place * pin.SE3(b.origin_R, b.origin_xyz)
        if b.coordinate is None:
            joint_id, body_place = parent_joint, origin
            pm.addFrame(pin.Frame(b.joint_name, joint_id, origin, pin.FIXED_JOINT))
        else:
            joint = pin.JointModelFreeFlyer() if b.joint_type == "floating" \
                else _joint_model(pin, b.axis, b.rotates, aligned)
            joint_id = pm.addJoint(parent_joint, joint, origin, b.joint_name)
            pm.addJointFrame(joint_id)
            body_place = pin.SE3.Identity()
            size = 6 if b.joint_type == "floating" else 1
            order.extend(range(b.coordinate, b.coordinate + size))
            config_order.extend(range(b.configuration, b.configuration + size + (size == 6)))
            terms.extend([(b.armature, b.damping, b.friction)] * size)  # 0 for floating
        pm.appendBodyToJoint(joint_id, pin.Inertia(b.mass, b.com, b.inertia), body_place)
        pm.addFrame(pin.Frame(b.name, joint_id, body_place, pin.BODY))  # the link's frame
        joint_of[i], placement[i] = joint_id, body_place
    pm.gravity = pin.Motion(np.asarray(nm.gravity, dtype=float), np.zeros(3))
    if pm.nv != nm.dof or pm.nq != (nm.nq or nm.dof):
        raise RuntimeError(f"the Pinocchio model has nq={pm.nq}, nv={pm.nv}; expected "
                           f"{nm.nq or nm.dof}, {nm.dof}")
    pm.gagen_order = np.array(order, dtype=int)
    pm.gagen_configuration_order = np.array(config_order, dtype=int)
    if terms:
        # Pinocchio (3 and later) adds the armature in crba, rnea and aba; it keeps damping
        # and friction only as data: `joint_forces` applies them
        pm.armature, pm.damping, pm.friction = (np.array(column, dtype=float)
                                                for column in zip(*terms))
    return pm


def _joint_model(pin, axis, rotates: bool, aligned: bool):
    unit = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    if aligned:
        for k, name in enumerate("XYZ"):
            if np.array_equal(unit, np.eye(3)[k]):
                return getattr(pin, f"JointModel{'R' if rotates else 'P'}{name}")()
    return (pin.JointModelRevoluteUnaligned(unit) if rotates
            else pin.JointModelPrismaticUnaligned(unit))


def joint_forces(pm, qd) -> np.ndarray:
    """damping qd + friction sign(qd) of Pinocchio model `pm`'s joints, in gagen's order."""
    qd_pin = np.asarray(qd, dtype=float)[pm.gagen_order]
    return from_pinocchio(pm, pm.damping * qd_pin + pm.friction * np.sign(qd_pin))


def to_pinocchio(pm, *vectors) -> list[np.ndarray]:
    """Vectors in gagen's coordinate order -> Pinocchio's (contiguous float64)."""
    return [np.ascontiguousarray(np.asarray(v, dtype=np.float64)[pm.gagen_order])
            for v in vectors]


def configuration_to_pinocchio(pm, q) -> np.ndarray:
    """A configuration in gagen's order -> Pinocchio's (a floating joint's 7 entries are in
    the same order in both: position, then quaternion x, y, z, w)."""
    return np.ascontiguousarray(np.asarray(q, dtype=np.float64)[pm.gagen_configuration_order])


def from_pinocchio(pm, vector) -> np.ndarray:
    """A vector in Pinocchio's velocity order -> gagen's coordinate order."""
    out = np.empty(pm.nv)
    out[pm.gagen_order] = np.asarray(vector)
    return out


def pinocchio_mass_matrix(pm, data, q_pin) -> np.ndarray:
    """crba's upper triangle, completed, in gagen's order."""
    import pinocchio as pin

    M = np.array(pin.crba(pm, data, q_pin))
    M = np.triu(M) + np.triu(M, 1).T
    out = np.empty_like(M)
    out[np.ix_(pm.gagen_order, pm.gagen_order)] = M
    return out
