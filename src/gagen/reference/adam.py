"""adam's CasADi dynamics (adam-robotics, `pip install gagen[bench]`): the peer that the
CasADi example and benchmark compare gagen's CasADi functions with.

adam rebuilds the rigid-body algorithms as a CasADi expression graph (SX) from a URDF.
Its forward dynamics here: for a fixed base, the joint block of its mass matrix and bias
force at the base fixed in the world, solved, qdd = M_jj^-1 (tau - h_j) (adam's floating
base algorithms with the base held: what the issue's comparison asks); for a floating base
its articulated-body algorithm `aba` in the body-fixed representation (Pinocchio's and
gagen's LOCAL velocities). adam does not handle prismatic joints (it fails on the Panda's
fingers): `fixed_joints_urdf` writes a copy of a URDF with such joints fixed.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np


def fixed_joints_urdf(path: str | Path, joints: list[str], out: str | Path,
                      rigid: bool = True) -> Path:
    """A copy of a URDF in which the named joints are fixed (e.g. the Panda's two finger
    joints, which adam cannot model), and with `rigid` no joint's <dynamics> (damping and
    friction, which adam does not model either); returns `out`."""
    tree = ET.parse(path)
    found = set()
    for joint in tree.getroot().iter("joint"):
        if rigid:
            for child in joint.findall("dynamics"):
                joint.remove(child)
        if joint.get("name") in joints:
            joint.set("type", "fixed")
            for child in list(joint):
                if child.tag in ("axis", "limit", "mimic", "dynamics", "safety_controller"):
                    joint.remove(child)
            found.add(joint.get("name"))
    missing = sorted(set(joints) - found)
    if missing:
        raise ValueError(f"{path}: no joint named {', '.join(missing)}")
    tree.write(out)
    return Path(out)


def computations(urdf: str | Path, joints: list[str], gravity: float, root_link=None):
    """adam's KinDynComputations of a URDF with the joints in gagen's order and gagen's g."""
    from adam.casadi import KinDynComputations

    return KinDynComputations(str(urdf), list(joints), root_link,
                              gravity=np.array([0.0, 0.0, -gravity, 0.0, 0.0, 0.0]))


def forward_dynamics(urdf: str | Path, joints: list[str], gravity: float,
                     floating: bool = False, root_link=None):
    """adam's forward dynamics as an SX casadi.Function (q, qd, tau) -> qdd in gagen's
    conventions (module docstring): for a floating base q = [xyz, quaternion (x, y, z, w),
    joints], qd = [body-frame linear and angular velocity, joints], tau's first six (the
    base's wrench) zero."""
    import casadi as ca

    kd = computations(urdf, joints, gravity, root_link)
    n = len(joints)
    if not floating:
        q, qd, tau = ca.SX.sym("q", n), ca.SX.sym("qd", n), ca.SX.sym("tau", n)
        H, vb = ca.SX.eye(4), ca.SX.zeros(6)
        M = kd.mass_matrix(H, q)[6:, 6:]
        h = kd.bias_force(H, q, vb, qd)[6:]
        return ca.Function("adam_forward_dynamics", [q, qd, tau], [ca.solve(M, tau - h)],
                           ["q", "qd", "tau"], ["qdd"])
    from adam.core.constants import Representations

    kd.set_frame_velocity_representation(Representations.BODY_FIXED_REPRESENTATION)
    q, qd, tau = ca.SX.sym("q", n + 7), ca.SX.sym("qd", n + 6), ca.SX.sym("tau", n + 6)
    x, y, z, w = q[3], q[4], q[5], q[6]
    s = 2 / (x * x + y * y + z * z + w * w)
    R = ca.vertcat(ca.horzcat(1 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)),
                   ca.horzcat(s * (x * y + w * z), 1 - s * (x * x + z * z), s * (y * z - w * x)),
                   ca.horzcat(s * (x * z - w * y), s * (y * z + w * x), 1 - s * (x * x + y * y)))
    H = ca.vertcat(ca.horzcat(R, q[:3]), ca.horzcat(ca.SX.zeros(1, 3), 1))
    acc = kd.aba(H, q[7:], qd[:6], qd[6:], tau[6:])
    return ca.Function("adam_forward_dynamics", [q, qd, tau], [acc], ["q", "qd", "tau"],
                       ["qdd"])
