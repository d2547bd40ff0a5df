"""Independent numerical references for checking the symbolic Gibbs-Appell derivation.

The model's numbers come from gagen.model.numeric (a plain evaluation of its entries);
everything else here is plain numpy and deliberately takes a different route from a
body-frame symbolic derivation: poses, velocities, accelerations, forces and inertias
are all expressed in the WORLD frame, and the dynamics come from a recursive
Newton-Euler pass. A second, fully external reference is built with pinocchio.

Conventions (shared with gagen.model):
- each body's frame is its joint frame; the joint origin (R0, xyz0) places the joint
  frame in the parent's frame; a revolute/continuous joint then rotates by q about its
  (normalized) axis, a prismatic joint translates by q along it; fixed joints have no q;
- coordinates are the moving bodies' joints in body order;
- the generalized force of a joint is the torque (revolute) or force (prismatic) that the
  parent applies to the child along the joint axis;
- potential energy is V = -sum_i m_i g . r_Ci (world positions, zero at the world origin),
  summed over ALL bodies, including those rigidly fixed to the world.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from gagen.model.numeric import (  # noqa: F401 (re-exported for the tests)
    NumericBody,
    NumericModel,
    numeric_model,
    rotation_about,
    skew,
)
from gagen.reference.pinocchio import (
    from_pinocchio,
    joint_forces,
    pinocchio_model,
    to_pinocchio,
)


def homogeneous(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


@dataclass
class BodyState:
    """World-frame kinematics of one body; `origin` is its joint/body frame origin."""

    T: np.ndarray  # 4x4 pose of the body frame in the world
    axis: np.ndarray  # joint axis in the world (unit)
    omega: np.ndarray  # angular velocity
    alpha: np.ndarray  # angular acceleration
    v: np.ndarray  # velocity of the frame origin
    a: np.ndarray  # acceleration of the frame origin

    @property
    def R(self) -> np.ndarray:
        return self.T[:3, :3]

    @property
    def origin(self) -> np.ndarray:
        return self.T[:3, 3]


def forward_kinematics(nm: NumericModel, q, qd=None, qdd=None) -> list[BodyState]:
    """Poses, velocities and accelerations of every body in the world frame."""
    q = np.asarray(q, dtype=float)
    qd = np.zeros(nm.dof) if qd is None else np.asarray(qd, dtype=float)
    qdd = np.zeros(nm.dof) if qdd is None else np.asarray(qdd, dtype=float)
    world = BodyState(np.eye(4), np.zeros(3), *(np.zeros(3) for _ in range(4)))
    states: list[BodyState] = []
    for b in nm.bodies:
        parent = world if b.parent < 0 else states[b.parent]
        states.append(_child_state(b, parent, q, qd, qdd))
    return states


def _child_state(b: NumericBody, parent: BodyState, q, qd, qdd) -> BodyState:
    # joint frame before the motion, as a 4x4 transform chained in the world
    T_joint = parent.T @ homogeneous(b.origin_R, b.origin_xyz)
    axis_w = T_joint[:3, :3] @ b.axis
    k = b.coordinate
    x, xd, xdd = (0.0, 0.0, 0.0) if k is None else (q[k], qd[k], qdd[k])
    if b.rotates:
        T = T_joint @ homogeneous(rotation_about(b.axis, x), np.zeros(3))
    elif b.joint_type == "prismatic":
        T = T_joint @ homogeneous(np.eye(3), b.axis * x)
    else:
        T = T_joint
    # origin relative to the parent's origin; the axis is fixed in the parent, so its
    # world derivative is omega_parent x axis (source of the Coriolis terms below)
    r = T[:3, 3] - parent.origin
    w_p, al_p = parent.omega, parent.alpha
    v = parent.v + np.cross(w_p, r)
    a = parent.a + np.cross(al_p, r) + np.cross(w_p, np.cross(w_p, r))
    omega, alpha = w_p.copy(), al_p.copy()
    if b.rotates:
        omega = w_p + axis_w * xd
        alpha = al_p + np.cross(w_p, axis_w) * xd + axis_w * xdd
    elif b.joint_type == "prismatic":
        v = v + axis_w * xd
        a = a + 2.0 * np.cross(w_p, axis_w) * xd + axis_w * xdd
    return BodyState(T, axis_w, omega, alpha, v, a)


def com_world(b: NumericBody, s: BodyState) -> np.ndarray:
    return s.origin + s.R @ b.com


# -------------------------------------------------------------------------- dynamics


def rnea(nm: NumericModel, q, qd, qdd, gravity: np.ndarray | None = None) -> np.ndarray:
    """Generalized forces that produce accelerations qdd at (q, qd) (world-frame Newton-Euler),
    with the joints' armature, damping and Coulomb friction added by hand.

    `gravity` overrides the model's gravity (the mass matrix uses zero gravity).
    """
    g = nm.gravity if gravity is None else np.asarray(gravity, dtype=float)
    qd, qdd = np.asarray(qd, dtype=float), np.asarray(qdd, dtype=float)
    states = forward_kinematics(nm, q, qd, qdd)
    # f: force the parent applies to the body; n: moment of it about the body's origin
    f = [np.zeros(3) for _ in nm.bodies]
    n = [np.zeros(3) for _ in nm.bodies]
    for i, (b, s) in enumerate(zip(nm.bodies, states)):
        F, N_c = _inertial_wrench(b, s, g)
        f[i] += F
        n[i] += N_c + np.cross(com_world(b, s) - s.origin, F)
    tau = np.zeros(nm.dof)
    for i in reversed(range(len(nm.bodies))):
        b, s = nm.bodies[i], states[i]
        if b.coordinate is not None:
            k = b.coordinate
            # the joint terms, by hand: rotor inertia, viscous and Coulomb friction
            tau[k] = s.axis @ (n[i] if b.rotates else f[i]) + b.armature * qdd[k] \
                + b.damping * qd[k] + b.friction * np.sign(qd[k])
        if b.parent >= 0:
            # the child's load acts on the parent; move its moment to the parent's origin
            p = b.parent
            f[p] += f[i]
            n[p] += n[i] + np.cross(s.origin - states[p].origin, f[i])
    return tau


def _inertial_wrench(b: NumericBody, s: BodyState, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Net force and moment about the mass centre the body needs, minus gravity's share."""
    rc = s.R @ b.com
    a_c = s.a + np.cross(s.alpha, rc) + np.cross(s.omega, np.cross(s.omega, rc))
    I_w = s.R @ b.inertia @ s.R.T
    F = b.mass * (a_c - g)
    N = I_w @ s.alpha + np.cross(s.omega, I_w @ s.omega)
    return F, N


def mass_matrix(nm: NumericModel, q) -> np.ndarray:
    """Columns of rnea with unit accelerations, zero velocity and zero gravity."""
    zero = np.zeros(nm.dof)
    cols = [rnea(nm, q, zero, e, gravity=np.zeros(3)) for e in np.eye(nm.dof)]
    M = np.array(cols).T
    return 0.5 * (M + M.T)


def bias_forces(nm: NumericModel, q, qd) -> np.ndarray:
    """Coriolis, centrifugal and gravity forces: rnea with zero acceleration."""
    return rnea(nm, q, qd, np.zeros(nm.dof))


def forward_dynamics(nm: NumericModel, q, qd, tau) -> np.ndarray:
    return np.linalg.solve(mass_matrix(nm, q), np.asarray(tau, dtype=float) - bias_forces(nm, q, qd))


def energy(nm: NumericModel, q, qd) -> tuple[float, float]:
    """(kinetic, potential) with V = -sum m g . r_C over all bodies."""
    states = forward_kinematics(nm, q, qd)
    kinetic = potential = 0.0
    for b, s in zip(nm.bodies, states):
        rc = s.R @ b.com
        v_c = s.v + np.cross(s.omega, rc)
        I_w = s.R @ b.inertia @ s.R.T
        kinetic += 0.5 * b.mass * (v_c @ v_c) + 0.5 * (s.omega @ I_w @ s.omega)
        if b.coordinate is not None:  # the rotor's
            kinetic += 0.5 * b.armature * np.asarray(qd, dtype=float)[b.coordinate] ** 2
        potential -= b.mass * (nm.gravity @ (s.origin + rc))
    return float(kinetic), float(potential)


# ------------------------------------------------------------------------- pinocchio
#
# Pinocchio's computePotentialEnergy returns -sum_i m_i g . c_i with g = model.gravity
# .linear and c_i the world mass centre of the inertia attached to joint i: the SAME sign
# and zero (world origin) as energy() above. It sums over joints 1..njoints only, so
# mass appended to the universe joint 0 (bodies welded to the world) is left out: the
# two differ by the constant  -sum_{welded} m g . r_C  (see welded_potential()).


def pin_model(nm: NumericModel) -> Any:
    """The Pinocchio model of `nm` (gagen.reference.pinocchio: one builder for the tests and
    the benchmarks); the pin_* helpers below take and return vectors in gagen's order."""
    return pinocchio_model(nm)


def welded_potential(nm: NumericModel) -> float:
    """Potential energy of the bodies welded to the world (which pinocchio leaves out)."""
    states = forward_kinematics(nm, np.zeros(nm.dof))
    return float(-sum(b.mass * (nm.gravity @ com_world(b, s))
                      for b, s, w in zip(nm.bodies, states, nm.welded_to_world()) if w))


def pin_mass_matrix(pm: Any, q) -> np.ndarray:
    import pinocchio as pin

    M = np.array(pin.crba(pm, pm.createData(), *to_pinocchio(pm, q)))
    # crba fills only the upper triangle
    M = np.triu(M) + np.triu(M, 1).T
    out = np.empty_like(M)
    out[np.ix_(pm.gagen_order, pm.gagen_order)] = M
    return out


def pin_rnea(pm: Any, q, qd, qdd) -> np.ndarray:
    """pinocchio's rnea (armature included) plus the joints' damping and friction."""
    import pinocchio as pin

    tau = from_pinocchio(pm, pin.rnea(pm, pm.createData(), *to_pinocchio(pm, q, qd, qdd)))
    return tau + joint_forces(pm, qd)


def pin_forward_dynamics(pm: Any, q, qd, tau) -> np.ndarray:
    """pinocchio's aba (armature included) under tau less the joints' damping and friction."""
    import pinocchio as pin

    tau = np.asarray(tau, dtype=float) - joint_forces(pm, qd)
    return from_pinocchio(pm, pin.aba(pm, pm.createData(), *to_pinocchio(pm, q, qd, tau)))


def pin_energy(pm: Any, q, qd) -> tuple[float, float]:
    """(kinetic, potential) as pinocchio defines them (potential without welded bodies)."""
    import pinocchio as pin

    data = pm.createData()
    q, qd = to_pinocchio(pm, q, qd)
    kinetic = pin.computeKineticEnergy(pm, data, q, qd)
    potential = pin.computePotentialEnergy(pm, data, q)
    return float(kinetic), float(potential)


def pin_dynamics(pm: Any, q, qd, tau) -> dict[str, Any]:
    """Everything pinocchio says about the state: M, bias, qdd, kinetic, potential."""
    kinetic, potential = pin_energy(pm, q, qd)
    return {
        "M": pin_mass_matrix(pm, q),
        "bias": pin_rnea(pm, q, qd, np.zeros(pm.nv)),
        "qdd": pin_forward_dynamics(pm, q, qd, tau),
        "kinetic": kinetic,
        "potential": potential,
    }

