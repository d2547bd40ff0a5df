"""Where the viewer's frames are: every placement comes from gagen's compiled
`dyn.frame_placement`; nothing here is kinematics of its own.

The scene has a node per moving body, placed in the world at each sample, and under it a
node per link frame fixed to that body (a link merged into it by a fixed joint, or the
body's own link), placed once: the frame's placement in its body's frame, taken from
`dyn.frame_placement` of both at the neutral configuration (a rigid offset, the same at
every configuration). Frames welded to the world are placed in the world the same way.
"""

from __future__ import annotations

import numpy as np


def body_names(dyn) -> list[str]:
    """Per body (in `dyn.info.bodies` order), the name of its own link frame."""
    names: dict[int, str] = {}
    for name, body, kind in dyn.info.frames:
        if kind == "link" and body >= 0 and body not in names:
            names[body] = name
    return [names[b] for b in range(len(dyn.info.bodies))]


def frame_bodies(dyn) -> dict[str, int]:
    """Frame name -> the index of the body it is fixed to (-1: the world)."""
    return {name: body for name, body, _ in dyn.info.frames}


def frame_offsets(dyn, frames, p=None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each frame's placement (R, p) in its body's frame (in the world for frames welded
    to the world), from dyn.frame_placement at the neutral configuration."""
    q0 = dyn.neutral()
    bodies, names = frame_bodies(dyn), body_names(dyn)
    out = {}
    for frame in frames:
        R, origin = dyn.frame_placement(q0, frame, p)
        body = bodies[frame]
        if body < 0:
            out[frame] = (R, origin)
            continue
        Rb, ob = dyn.frame_placement(q0, names[body], p)
        out[frame] = (Rb.T @ R, Rb.T @ (origin - ob))
    return out


def body_placements(dyn, q, p=None) -> tuple[np.ndarray, np.ndarray]:
    """Every body's placement at each configuration of q (N, nq): rotations (N, B, 3, 3)
    and origins (N, B, 3), in the world."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    names = body_names(dyn)
    R = np.empty((q.shape[0], len(names), 3, 3))
    origin = np.empty((q.shape[0], len(names), 3))
    for b, name in enumerate(names):
        R[:, b], origin[:, b] = dyn.frame_placement(q, name, p)
    return R, origin


def wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) of rotation matrices (..., 3, 3), w >= 0."""
    from scipy.spatial.transform import Rotation

    shape = R.shape[:-2]
    xyzw = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    out = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    out[out[:, 0] < 0] *= -1
    return out.reshape(*shape, 4)


def rotation(wxyz_: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions (..., 4) given as (w, x, y, z)."""
    from scipy.spatial.transform import Rotation

    q = np.asarray(wxyz_, dtype=float)
    shape = q.shape[:-1]
    flat = q.reshape(-1, 4)
    return Rotation.from_quat(np.concatenate([flat[:, 1:], flat[:, :1]], axis=1)) \
        .as_matrix().reshape(*shape, 3, 3)
