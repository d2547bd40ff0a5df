"""Frame kinematics in NumPy, from the bodies' placements and the frames' offsets.

`X` holds, per body, its orientation R (row-major), its origin p and its joint's axis in
the world (15 values: gagen.symbolic.frames); `F`, per frame, its axes and origin in its
body's frame (12 values). The tree comes from the manifest (`ModelInfo.bodies`:
parent, joint kind, first velocity coordinate; `ModelInfo.frames`: name, body). The C
of compiled models (codegen/templates/model/frames.c.j2) does the same arithmetic.

Conventions are Pinocchio's LOCAL_WORLD_ALIGNED: a frame's velocity and Jacobian rows are
the linear velocity of its origin, then its angular velocity, both in world axes; a wrench
on a frame is (force, torque) in world axes at its origin, and its generalised force is
J^T w.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..manifest import JOINT_KINDS, ModelInfo

REVOLUTE, PRISMATIC, FLOATING = (JOINT_KINDS[k] for k in ("revolute", "prismatic", "floating"))


def frame_index(info: ModelInfo, frame) -> int:
    """The index of a frame given by name (or by index); KeyError naming the choices."""
    if type(frame) is str:  # the common case first: np.integer's isinstance costs 0.3 us
        index = info.frame_indices.get(frame)
        if index is not None:
            return index
    elif isinstance(frame, (int, np.integer)) and not isinstance(frame, bool):
        if 0 <= frame < len(info.frames):
            return int(frame)
        raise KeyError(f"frame index {frame} out of range (the model has "
                       f"{len(info.frames)} frames)")
    index = info.frame_indices.get(frame) if isinstance(frame, str) else None
    if index is not None:
        return index
    names = [name for name, _, _ in info.frames]
    shown = ", ".join(names[:12]) + (", ..." if len(names) > 12 else "")
    raise KeyError(f"unknown frame {frame!r} (frames: {shown}; all in dyn.frames)")


def frame_indices(info: ModelInfo, frames) -> list[int]:
    """The indices of one frame or of a list (or tuple) of frames, by name or index."""
    if isinstance(frames, (list, tuple)):
        return [frame_index(info, frame) for frame in frames]
    return [frame_index(info, frames)]


def pose(info: ModelInfo, X: np.ndarray, F: np.ndarray, k: int
         ) -> tuple[np.ndarray, np.ndarray]:
    """(R, p) of frame k in the world, for placements X of shape (..., 15 nb)."""
    body = info.frames[k][1]
    R_f = F[12 * k: 12 * k + 9].reshape(3, 3)
    p_f = F[12 * k + 9: 12 * k + 12]
    if body < 0:
        shape = X.shape[:-1]
        return np.broadcast_to(R_f, shape + (3, 3)).copy(), np.broadcast_to(p_f, shape + (3,)).copy()
    R_b, p_b = _body_pose(X, body)
    return R_b @ R_f, p_b + (R_b @ p_f[:, None])[..., 0]


def _body_pose(X: np.ndarray, body: int) -> tuple[np.ndarray, np.ndarray]:
    block = X[..., 15 * body: 15 * body + 15]
    return block[..., :9].reshape(block.shape[:-1] + (3, 3)), block[..., 9:12]


def jacobian(info: ModelInfo, X: np.ndarray, F: np.ndarray, k: int, nv: int) -> np.ndarray:
    """The (..., 6, nv) Jacobian of frame k (module docstring)."""
    _, p_f = pose(info, X, F, k)
    J = np.zeros(X.shape[:-1] + (6, nv))
    body = info.frames[k][1]
    while body >= 0:
        parent, kind, column = info.bodies[body]
        R_b, p_b = _body_pose(X, body)
        if kind == REVOLUTE:
            axis = X[..., 15 * body + 12: 15 * body + 15]
            J[..., :3, column] = np.cross(axis, p_f - p_b)
            J[..., 3:, column] = axis
        elif kind == PRISMATIC:
            J[..., :3, column] = X[..., 15 * body + 12: 15 * body + 15]
        elif kind == FLOATING:
            arm = p_f - p_b
            J[..., :3, column: column + 3] = R_b
            J[..., 3:, column + 3: column + 6] = R_b
            J[..., :3, column + 3: column + 6] = np.cross(
                np.swapaxes(R_b, -1, -2), arm[..., None, :]).swapaxes(-1, -2)
        body = parent
    return J


def external_wrenches(info: ModelInfo, fext, rows: int | None) -> list[tuple[int, np.ndarray]]:
    """fext = {frame: wrench} as [(frame index, wrench (6,) or (rows, 6))], checked."""
    if fext is None:
        return []
    if not isinstance(fext, Mapping):
        raise TypeError("fext must be a dict {frame: (fx, fy, fz, tx, ty, tz)}")
    out = []
    for frame, wrench in fext.items():
        w = np.asarray(wrench, dtype=float)
        if w.shape == (6,) or (rows is not None and w.shape == (rows, 6)):
            if not np.all(np.isfinite(w)):
                raise ValueError(f"the wrench on frame {frame!r} must be finite")
            out.append((frame_index(info, frame), w))
        else:
            want = "(6,)" if rows is None else f"(6,) or ({rows}, 6)"
            raise ValueError(f"the wrench on frame {frame!r} must have shape {want} "
                             f"(force, then torque, world axes at the frame's origin); "
                             f"got {w.shape}")
    return out


def generalized_forces(info: ModelInfo, X: np.ndarray, F: np.ndarray, wrenches, nv: int
                       ) -> np.ndarray:
    """sum_f J_f^T w_f: the generalised force of wrenches [(frame, w)], shape (..., nv)."""
    total = np.zeros(X.shape[:-1] + (nv,))
    for k, w in wrenches:
        J = jacobian(info, X, F, k, nv)
        total += np.einsum("...ij,...i->...j", J, np.broadcast_to(w, J.shape[:-2] + (6,)))
    return total
