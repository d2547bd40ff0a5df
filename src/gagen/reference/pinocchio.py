"""One Pinocchio model builder, for the tests and the benchmarks (Pinocchio is optional:
`pip install gagen[bench]` or `gagen[test]`).

Pinocchio needs its joints in depth-first order, which gagen's parents-first body order
need not be, so joints are added depth-first and `pm.gagen_order[k]` is gagen's
coordinate index of Pinocchio's k-th velocity; `to_pinocchio` / `from_pinocchio` convert
vectors (one permutation serves qd, qdd and tau, and q when no joint floats;
`configuration_to_pinocchio` converts q).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import SingularMassMatrixError
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


# --- Pinocchio's own parse of a URDF, in its own order ---------------------------------------

def urdf_joint_names(model) -> list[str]:
    """The names of a gagen Model's (or Dynamics') moving joints, in coordinate order: for a
    URDF, `list(pinocchio.buildModelFromUrdf(path).names)[1:]` (README: joint order)."""
    model = getattr(model, "model", model)
    return [b.joint.name for b in model.moving_bodies]


def urdf_configuration(pm, q) -> np.ndarray:
    """gagen's q of a URDF -> the q of Pinocchio's parse of the same file, whose joints come
    in the same order: a continuous joint's angle becomes Pinocchio's (cos, sin); a free
    flyer's 7 entries and every other joint's one are the same in both."""
    q = np.asarray(q, dtype=float)
    out, k = [], 0
    for j in range(1, pm.njoints):
        if pm.nqs[j] == 2 and pm.nvs[j] == 1:  # JointModelRUB*: unbounded revolute
            out += [np.cos(q[k]), np.sin(q[k])]
            k += 1
        else:
            out += list(q[k: k + pm.nqs[j]])
            k += pm.nqs[j]
    if k != len(q):
        raise ValueError(f"q has {len(q)} entries; Pinocchio's joints take {k}")
    return np.array(out)


def urdf_frame_ids(pm, frames: list[str]) -> dict[str, int]:
    """Pinocchio's frame of each of gagen's frame names (links: Pinocchio's BODY frames;
    joints, `joint:<name>` where a link has the name: its JOINT or FIXED_JOINT frames);
    frames Pinocchio does not have are left out."""
    import pinocchio as pin

    link_ids = {f.name: k for k, f in enumerate(pm.frames) if f.type == pin.BODY}
    joint_ids = {f.name: k for k, f in enumerate(pm.frames)
                 if f.type in (pin.JOINT, pin.FIXED_JOINT)}
    out = {}
    for name in frames:
        if name.startswith("joint:"):
            found = joint_ids.get(name[len("joint:"):])
        else:
            found = link_ids.get(name, joint_ids.get(name))
        if found is not None:
            out[name] = found
    return out


def compare_with_urdf_parse(dyn, pm, rng: np.random.Generator, states: int = 3
                            ) -> dict[str, float]:
    """The largest relative differences between gagen's `dyn` of a URDF and Pinocchio's
    parse `pm` of the same file, each in its own order and with no permutation, at random
    states: M (crba), forward dynamics (aba), inverse dynamics (rnea), and every common
    frame's placement and Jacobian (LOCAL_WORLD_ALIGNED). Joint damping and friction are
    set to zero (Pinocchio's algorithms leave them out). ValueError if the joints differ;
    FD is NaN where gagen finds M(q) singular (`gagen.SingularMassMatrixError`: a joint
    that moves no mass, as Romeo's fingers)."""
    import pinocchio as pin

    names = urdf_joint_names(dyn)
    if names != list(pm.names)[1:]:
        raise ValueError("gagen's joints are not Pinocchio's, in order")
    data = pm.createData()
    rigid = {k: 0.0 for k in dyn.parameters if k.startswith(("damping_", "friction_"))}
    frames = urdf_frame_ids(pm, dyn.frames)
    errors = dict.fromkeys(("M", "FD", "ID", "placement", "jacobian"), 0.0)
    for _ in range(states):
        q = dyn.neutral() if hasattr(dyn, "neutral") else np.zeros(dyn.nq)
        q = np.array(q, dtype=float)
        moving = [k for k, name in enumerate(dyn.configuration)
                  if not name.endswith(("_qx", "_qy", "_qz", "_qw"))]
        q[moving] = rng.uniform(-1, 1, len(moving))
        if dyn.nq > dyn.nv:  # a floating base: any orientation
            quat = rng.normal(size=4)
            q[3:7] = quat / np.linalg.norm(quat)
        qd, u, qdd = (rng.uniform(-1, 1, dyn.nv) for _ in range(3))
        q_pin = urdf_configuration(pm, q)
        M = np.array(pin.crba(pm, data, q_pin))
        M = np.triu(M) + np.triu(M, 1).T
        errors["M"] = max(errors["M"], _relative(dyn.mass_matrix(q, p=rigid), M))
        # (random accelerations for the inverse dynamics: aba's can be large where M is
        # ill-conditioned, and tau's scale would then not be M qdd's)
        try:
            ours = dyn.forward_dynamics(q, qd, u, p=rigid)
        except SingularMassMatrixError:  # a joint that moves no mass: no FD (NaN here)
            errors["FD"] = math.nan
        else:
            fd = np.array(pin.aba(pm, data, q_pin, qd, u))
            errors["FD"] = _worse(errors["FD"], _relative(ours, fd))
        tau = np.array(pin.rnea(pm, data, q_pin, qd, qdd))
        errors["ID"] = max(errors["ID"], _relative(dyn.inverse_dynamics(q, qd, qdd, p=rigid),
                                                   tau))
        pin.computeJointJacobians(pm, data, q_pin)
        pin.updateFramePlacements(pm, data)
        for name, k in frames.items():
            R, p = dyn.frame_placement(q, name)
            placed = data.oMf[k]
            errors["placement"] = max(errors["placement"],
                                      _relative(np.hstack([R, p[:, None]]),
                                                np.hstack([placed.rotation,
                                                           placed.translation[:, None]])))
            J = pin.getFrameJacobian(pm, data, k, pin.LOCAL_WORLD_ALIGNED)
            errors["jacobian"] = max(errors["jacobian"],
                                     _relative(dyn.frame_jacobian(q, name), J))
    return errors


def _worse(a: float, b: float) -> float:
    """The larger of two errors; NaN (no value) wins."""
    return math.nan if math.isnan(a) or math.isnan(b) else max(a, b)


def _relative(actual, expected) -> float:
    """max |actual - expected| over max(max |expected|, 1)."""
    expected = np.asarray(expected, dtype=float)
    scale = max(float(np.abs(expected).max()), 1.0)
    return float(np.abs(np.asarray(actual, dtype=float) - expected).max()) / scale
