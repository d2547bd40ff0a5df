"""MuJoCo's own quantities in gagen's coordinates, for the tests and the sweep of public
robots (MuJoCo is optional: `pip install gagen[mjcf]` or `gagen[test]`).

gagen reads an MJCF file in MuJoCo's `qpos` order, with two differences at a free joint
(the README's floating-base conventions): its quaternion is (x, y, z, w) where MuJoCo
writes w first, and its linear velocity is the body origin's in the body's axes where
MuJoCo's `qvel` has it in world axes (both have the angular velocity in the body's axes).
With qvel = T qd (T holds the body's rotation R in each free joint's linear block, the
identity elsewhere), qvel' = T qdd + T' qd, so

    M = T^T M_mj T,    bias = T^T (bias_mj + M_mj T' qd),    J = J_mj T,

and a generalised force of MuJoCo's, Q_mj, is T^T Q_mj in gagen's coordinates.
"""

from __future__ import annotations

import numpy as np

FREE, BALL, SLIDE, HINGE = 0, 1, 2, 3  # mujoco.mjtJoint


def _mujoco():
    import mujoco

    return mujoco


def to_mujoco_qpos(mj, q) -> np.ndarray:
    """A gagen configuration -> MuJoCo's qpos (a free joint's quaternion w first)."""
    qpos = np.array(q, dtype=float)
    for j in _free_joints(mj):
        a = int(mj.jnt_qposadr[j])
        qpos[a + 3: a + 7] = np.r_[q[a + 6], q[a + 3: a + 6]]
    return qpos


def from_mujoco_qpos(mj, qpos) -> np.ndarray:
    """MuJoCo's qpos -> a gagen configuration (a free joint's quaternion w last)."""
    q = np.array(qpos, dtype=float)
    for j in _free_joints(mj):
        a = int(mj.jnt_qposadr[j])
        q[a + 3: a + 7] = np.r_[qpos[a + 4: a + 7], qpos[a + 3]]
    return q


def random_configuration(mj, rng: np.random.Generator, spread: float = 1.0) -> np.ndarray:
    """A gagen configuration: hinges and slides uniform in (-spread, spread) about MuJoCo's
    qpos0, free bodies anywhere in the same box with a random orientation."""
    qpos = np.array(mj.qpos0, dtype=float)
    for j in range(mj.njnt):
        a, kind = int(mj.jnt_qposadr[j]), int(mj.jnt_type[j])
        if kind == FREE:
            quat = rng.normal(size=4)
            qpos[a: a + 7] = np.r_[rng.uniform(-spread, spread, 3), quat / np.linalg.norm(quat)]
        elif kind in (HINGE, SLIDE):
            qpos[a] += rng.uniform(-spread, spread)
    return from_mujoco_qpos(mj, qpos)


def _free_joints(mj) -> list[int]:
    return [j for j in range(mj.njnt) if int(mj.jnt_type[j]) == FREE]


class MujocoState:
    """MuJoCo's kinematics and dynamics of `mj` at gagen's (q, qd), in gagen's coordinates."""

    def __init__(self, mj, q, qd=None):
        mujoco = _mujoco()
        self.mj, self.data = mj, mujoco.MjData(mj)
        self.data.qpos[:] = to_mujoco_qpos(mj, q)
        mujoco.mj_kinematics(mj, self.data)
        self.qd = np.zeros(mj.nv) if qd is None else np.asarray(qd, dtype=float)
        self.T, self.Tdot_qd = self._velocity_map()
        self.data.qvel[:] = self.T @ self.qd
        mujoco.mj_forward(mj, self.data)

    def _velocity_map(self) -> tuple[np.ndarray, np.ndarray]:
        """T (qvel = T qd) and T' qd."""
        T, Tdot_qd = np.eye(self.mj.nv), np.zeros(self.mj.nv)
        for j in _free_joints(self.mj):
            d, body = int(self.mj.jnt_dofadr[j]), int(self.mj.jnt_bodyid[j])
            R = self.data.xmat[body].reshape(3, 3)
            T[d: d + 3, d: d + 3] = R
            v, w = self.qd[d: d + 3], self.qd[d + 3: d + 6]
            Tdot_qd[d: d + 3] = R @ np.cross(w, v)
        return T, Tdot_qd

    def mass_matrix(self) -> np.ndarray:
        """mj_fullM (armature included), in gagen's coordinates."""
        return self.T.T @ self._full_mass_matrix() @ self.T

    def bias(self) -> np.ndarray:
        """qfrc_bias (Coriolis, centrifugal, gravity: the inverse dynamics at qdd = 0 without
        damping and friction), in gagen's coordinates."""
        return self.T.T @ (self.data.qfrc_bias + self._full_mass_matrix() @ self.Tdot_qd)

    def _full_mass_matrix(self) -> np.ndarray:
        mujoco, dense = _mujoco(), np.zeros((self.mj.nv, self.mj.nv))
        try:  # MuJoCo 4: (m, d, dst); 3: (m, dst, qM)
            mujoco.mj_fullM(self.mj, self.data, dense)
        except TypeError:
            mujoco.mj_fullM(self.mj, dense, self.data.qM)
        return dense

    def body_placement(self, body: int) -> tuple[np.ndarray, np.ndarray]:
        """(R, p): MuJoCo's body frame (xmat, xpos) in the world."""
        return self.data.xmat[body].reshape(3, 3).copy(), self.data.xpos[body].copy()

    def body_jacobian(self, body: int) -> np.ndarray:
        """mj_jacBody: the (6, nv) Jacobian of the body frame's origin, linear then angular,
        world axes (Pinocchio's LOCAL_WORLD_ALIGNED), in gagen's coordinates."""
        jacp, jacr = np.zeros((3, self.mj.nv)), np.zeros((3, self.mj.nv))
        _mujoco().mj_jacBody(self.mj, self.data, jacp, jacr, body)
        return np.vstack([jacp, jacr]) @ self.T

    def body_wrench_force(self, body: int, wrench) -> np.ndarray:
        """mj_applyFT: the generalised force of a wrench (force, torque; world axes) acting at
        the body frame's origin, in gagen's coordinates."""
        out = np.zeros(self.mj.nv)
        wrench = np.asarray(wrench, dtype=float)
        _mujoco().mj_applyFT(self.mj, self.data, wrench[:3].copy(), wrench[3:].copy(),
                             self.data.xpos[body].copy(), body, out)
        return self.T.T @ out


def body_names(mj) -> list[str]:
    """The frame names of MuJoCo's bodies 1, 2, ... in the loaded model (MuJoCo's names,
    `body<id>` where unnamed)."""
    from ..model.mjcf import body_names as names

    return names(mj)
