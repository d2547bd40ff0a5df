"""Task-space kinematics in NumPy: frames' velocities, accelerations, Jacobians and their
time variation in Pinocchio's three references, and the operational-space inertia.

The lambdify backend computes these here, from the bodies' placements X and the frames'
offsets F (gagen.runtime.frames); compiled models do the same arithmetic in C
(codegen/templates/model/taskspace.c.j2).

Motion along a frame's path to the world, one body after its parent, all in world axes at
each body's origin (ω, v: angular velocity and its origin's velocity; α, a: their rates,
the classical accelerations). A joint moves its body relative to its parent by u (the
origin's velocity) and w (the angular velocity), with r the body's origin less its
parent's (a revolute joint: w = s q̇ about its world axis s; prismatic: u = s q̇; floating:
u = R v, w = R ω of its six velocities in the body's frame):

    ω = ω_p + w                       v = v_p + ω_p × r + u
    α = α_p + ω_p × w + S_ω q̈          a = a_p + α_p × r + ω_p × (ω_p × r) + 2 ω_p × u + w × u + S_v q̈

(the joint's axes move with the parent: d/dt s = ω_p × s). A frame at p on its body then
has v_f = v + ω × (p - o), a_f = a + α × (p - o) + ω × (ω × (p - o)).

References (Pinocchio's ReferenceFrame): "local_world_aligned" (at the frame's origin,
world axes), "local" (at the frame's origin, its own axes), "world" (at the world's origin,
world axes). A velocity, a Jacobian's columns and a spatial acceleration are motion vectors
and change reference as such; the spatial acceleration is (a_f - ω × v_f, α) at the
frame's origin, and the classical one in any reference is the spatial one plus
(ω × v, 0) of the velocity in that reference (Pinocchio's getFrameClassicalAcceleration):
at the frame's origin, the acceleration of that point.
"""

from __future__ import annotations

import numpy as np

from ..manifest import ModelInfo
from .frames import FLOATING, PRISMATIC, REVOLUTE, frame_indices, pose
from .frames import jacobian as aligned_jacobian

# Pinocchio's ReferenceFrame numbers (pin.WORLD, pin.LOCAL, pin.LOCAL_WORLD_ALIGNED); the
# C functions take these
REFERENCES = {"world": 0, "local": 1, "local_world_aligned": 2}
WORLD, LOCAL, LOCAL_WORLD_ALIGNED = 0, 1, 2
KINDS = {"classical": 0, "spatial": 1}
CLASSICAL, SPATIAL = 0, 1


def reference_code(reference) -> int:
    """The number of a reference given by name; ValueError naming the choices."""
    code = REFERENCES.get(reference) if isinstance(reference, str) else None
    if code is None:
        raise ValueError(f"reference must be 'local_world_aligned', 'local' or 'world'; "
                         f"got {reference!r}")
    return code


def kind_code(kind) -> int:
    """The number of an acceleration's kind given by name; ValueError naming the choices."""
    code = KINDS.get(kind) if isinstance(kind, str) else None
    if code is None:
        raise ValueError(f"kind must be 'classical' or 'spatial'; got {kind!r}")
    return code


def task_dims(dims) -> int:
    """dims of a task (6: linear and angular rows, 3: linear only), checked."""
    if isinstance(dims, bool) or dims not in (3, 6):
        raise ValueError(f"dims must be 6 (linear and angular rows) or 3 (linear rows "
                         f"only); got {dims!r}")
    return int(dims)


# --- motion along a path -------------------------------------------------------------------

def path(info: ModelInfo, body: int) -> list[int]:
    """The bodies from the world's child down to `body` (empty for the world)."""
    out = []
    while body >= 0:
        out.append(body)
        body = info.bodies[body][0]
    return out[::-1]


def _block(X: np.ndarray, body: int, start: int, stop: int) -> np.ndarray:
    return X[..., 15 * body + start: 15 * body + stop]


def _rotation(X: np.ndarray, body: int) -> np.ndarray:
    block = _block(X, body, 0, 9)
    return block.reshape(block.shape[:-1] + (3, 3))


def _apply(R: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.einsum("...ij,...j->...i", R, x)


def _relative(info: ModelInfo, X: np.ndarray, body: int, rate: np.ndarray | None):
    """(u, w): the joint's velocities (or acceleration terms S q̈, for rate = q̈) in world
    axes; None for zero."""
    _, kind, column = info.bodies[body]
    if rate is None or kind not in (REVOLUTE, PRISMATIC, FLOATING):
        return None, None
    if kind == FLOATING:
        R = _rotation(X, body)
        return (_apply(R, rate[..., column: column + 3]),
                _apply(R, rate[..., column + 3: column + 6]))
    along = _block(X, body, 12, 15) * rate[..., column, None]
    return (None, along) if kind == REVOLUTE else (along, None)


def _add(*terms):
    out = None
    for t in terms:
        if t is not None:
            out = t if out is None else out + t
    return out


def _cross(a, b):
    return None if a is None or b is None else np.cross(a, b)


def path_motion(info: ModelInfo, X: np.ndarray, qd: np.ndarray, qdd: np.ndarray | None,
                body: int) -> dict[int, tuple]:
    """{b: (ω, v, α, a)} for `body` and its ancestors (module docstring), each (..., 3);
    qdd None: q̈ = 0."""
    zero = np.zeros(np.broadcast_shapes(X.shape[:-1], qd.shape[:-1]) + (3,))
    omega = vel = alpha = acc = None
    origin = None
    out = {}
    for b in path(info, body):
        o = _block(X, b, 9, 12)
        r = o if origin is None else o - origin
        u, w = _relative(info, X, b, qd)
        su, sw = _relative(info, X, b, qdd)
        acc = _add(acc, _cross(alpha, r), _cross(omega, _cross(omega, r)),
                   None if u is None or omega is None else 2.0 * np.cross(omega, u),
                   _cross(w, u), su)
        alpha = _add(alpha, _cross(omega, w), sw)
        vel = _add(vel, _cross(omega, r), u)
        omega = _add(omega, w)
        origin = o
        out[b] = tuple(zero if x is None else zero + x for x in (omega, vel, alpha, acc))
    return out


def frame_motion(info: ModelInfo, X, F, k: int, qd, qdd) -> tuple:
    """(R, p, ω, v_f, α, a_f) of frame k: its placement, and the motion of its origin."""
    R, p = pose(info, X, F, k)
    body = info.frames[k][1]
    if body < 0:  # welded to the world
        zero = np.zeros(np.broadcast_shapes(X.shape[:-1], qd.shape[:-1]) + (3,))
        return R, p, zero, zero, zero, zero
    omega, vel, alpha, acc = path_motion(info, X, qd, qdd, body)[body]
    arm = p - _block(X, body, 9, 12)
    vel = vel + np.cross(omega, arm)
    acc = acc + np.cross(alpha, arm) + np.cross(omega, np.cross(omega, arm))
    return R, p, omega, vel, alpha, acc


# --- references ----------------------------------------------------------------------------

def _columns_to(reference: int, R: np.ndarray, p: np.ndarray, linear: np.ndarray,
                angular: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A Jacobian's columns (linear rows (..., 3, nv) at the frame's origin, angular rows;
    world axes) in `reference`: motion vectors, as `_vectors_to`."""
    if reference == LOCAL:
        Rt = np.swapaxes(R, -1, -2)
        return Rt @ linear, Rt @ angular
    if reference == WORLD:
        return linear + _cross_columns(p, angular), angular
    return linear, angular


def _cross_columns(a: np.ndarray, B: np.ndarray) -> np.ndarray:
    """a × each column of B (B (..., 3, n))."""
    return np.cross(a[..., None, :], np.swapaxes(B, -1, -2)).swapaxes(-1, -2)


def velocity(info: ModelInfo, X, F, k: int, qd, reference: int) -> np.ndarray:
    """Frame k's velocity (..., 6), linear then angular, in `reference`."""
    R, p, omega, vel, _, _ = frame_motion(info, X, F, k, qd, None)
    return np.concatenate(_vectors_to(reference, R, p, vel, omega), axis=-1)


def _vectors_to(reference: int, R: np.ndarray, p: np.ndarray, linear: np.ndarray,
                angular: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A motion vector (linear (..., 3) at the frame's origin, angular; world axes) in
    `reference`: LOCAL turns it into the frame's axes, WORLD moves the linear part's point
    to the world's origin (v_O = v_p + p × ω)."""
    if reference == LOCAL:
        Rt = np.swapaxes(R, -1, -2)
        return _apply(Rt, linear), _apply(Rt, angular)
    if reference == WORLD:
        return linear + np.cross(p, angular), angular
    return linear, angular


def acceleration(info: ModelInfo, X, F, k: int, qd, qdd, reference: int,
                 kind: int) -> np.ndarray:
    """Frame k's acceleration (..., 6) in `reference`: classical or spatial (module
    docstring); qdd None: the bias acceleration J̇ q̇ of that convention."""
    R, p, omega, vel, alpha, acc = frame_motion(info, X, F, k, qd, qdd)
    lin, ang = _vectors_to(reference, R, p, acc - np.cross(omega, vel), alpha)
    if kind == CLASSICAL:
        v_lin, v_ang = _vectors_to(reference, R, p, vel, omega)
        lin = lin + np.cross(v_ang, v_lin)
    return np.concatenate([lin, ang], axis=-1)


# --- Jacobians -----------------------------------------------------------------------------

def jacobian(info: ModelInfo, X, F, k: int, nv: int, reference: int) -> np.ndarray:
    """Frame k's Jacobian (..., 6, nv) in `reference`."""
    J = aligned_jacobian(info, X, F, k, nv)
    if reference == LOCAL_WORLD_ALIGNED:
        return J
    R, p = pose(info, X, F, k)
    lin, ang = _columns_to(reference, R, p, J[..., :3, :], J[..., 3:, :])
    return np.concatenate([lin, ang], axis=-2)


def jacobian_time_variation(info: ModelInfo, X, F, k: int, qd, nv: int,
                            reference: int) -> np.ndarray:
    """dJ/dt (..., 6, nv) of frame k's Jacobian in `reference` at velocities qd (Pinocchio's
    getFrameJacobianTimeVariation): each column of the joints on the frame's path, as
    the joint's axis turns with its body (d/dt s = ω × s) and the frame's arm stretches
    (d/dt (p_f - o) = v_f - v)."""
    R, p, omega_f, vel_f, _, _ = frame_motion(info, X, F, k, qd, None)
    J = aligned_jacobian(info, X, F, k, nv)
    dJ = np.zeros_like(J)
    body = info.frames[k][1]
    motion = path_motion(info, X, qd, None, body) if body >= 0 else {}
    while body >= 0:
        parent, kind, column = info.bodies[body]
        omega, vel, _, _ = motion[body]
        arm, stretch = p - _block(X, body, 9, 12), vel_f - vel
        if kind in (REVOLUTE, PRISMATIC):
            axes = [(column, _block(X, body, 12, 15), kind == REVOLUTE)]
        elif kind == FLOATING:
            Rb = _rotation(X, body)
            axes = [(column + r, Rb[..., :, r % 3], r >= 3) for r in range(6)]
        else:
            axes = []
        for c, s, turns in axes:
            ds = np.cross(omega, s)
            if turns:  # [s × arm; s]
                dJ[..., :3, c] = np.cross(ds, arm) + np.cross(s, stretch)
                dJ[..., 3:, c] = ds
            else:  # [s; 0]
                dJ[..., :3, c] = ds
        body = parent
    lin, ang = J[..., :3, :], J[..., 3:, :]
    dlin, dang = dJ[..., :3, :], dJ[..., 3:, :]
    if reference == LOCAL:  # d/dt (Rᵀ x) = Rᵀ (ẋ - ω × x)
        Rt = np.swapaxes(R, -1, -2)
        dlin = Rt @ (dlin - _cross_columns(omega_f, lin))
        dang = Rt @ (dang - _cross_columns(omega_f, ang))
    elif reference == WORLD:  # d/dt (x + p × y) = ẋ + v_f × y + p × ẏ
        dlin = dlin + _cross_columns(vel_f, ang) + _cross_columns(p, dang)
    return np.concatenate([dlin, dang], axis=-2)


# --- the operational-space inertia ---------------------------------------------------------

def task_jacobian(info: ModelInfo, X, F, frames: list[int], nv: int, dims: int) -> np.ndarray:
    """The frames' LOCAL_WORLD_ALIGNED Jacobians' first `dims` rows, stacked: (..., m, nv)
    with m = dims · len(frames)."""
    return np.concatenate([aligned_jacobian(info, X, F, k, nv)[..., :dims, :]
                           for k in frames], axis=-2)


def task_frames(info: ModelInfo, frames) -> list[int]:
    """The indices of a task's frames (one, or a list), at least one."""
    indices = frame_indices(info, frames)
    if not indices:
        raise ValueError("frames must name at least one frame")
    return indices


def singular_task(info: ModelInfo, indices: list[int], dims: int, row: int):
    """The SingularTaskError of a task whose rows are dependent (at stacked row `row`, -1:
    not stacked), naming its frames."""
    from ..errors import SingularTaskError, one_line

    names = ", ".join(repr(info.frames[k][0]) for k in indices)
    where = "" if row < 0 else f" (stacked input, row {row})"
    rows = "rows" if dims == 6 else "linear rows"
    return SingularTaskError(one_line(
        f"the operational-space inertia of frames {names} ({rows}) is singular at this "
        f"state{where}: their Jacobian's rows are linearly dependent (a singular "
        f"configuration, a frame that cannot move, more rows than coordinates, or rows "
        f"that constrain the same motion); delassus() is defined there"))


def delassus(dyn, q, frames, dims, p=None) -> np.ndarray:
    """J M⁻¹ Jᵀ of the task (Dynamics.delassus), through M's Cholesky factor L: with
    Y = L⁻¹ Jᵀ, G = Yᵀ Y (M is never inverted)."""
    return _delassus(dyn, q, task_frames(dyn.info, frames), task_dims(dims), p)


def _delassus(dyn, q, indices, dims, p):
    X, F, _ = dyn._frame_data(q, p)
    J = task_jacobian(dyn.info, X, F, indices, dyn.nv, dims)
    L = _mass_cholesky(dyn.mass_matrix(q, p))
    Y = np.linalg.solve(L, np.swapaxes(J, -1, -2))
    G = np.swapaxes(Y, -1, -2) @ Y
    return 0.5 * (G + np.swapaxes(G, -1, -2))


# a pivot of J M⁻¹ Jᵀ's factorisation at most this fraction of its diagonal entry: the rows
# are dependent, exactly up to rounding (the C uses the same number)
SINGULAR_PIVOT = 1e-11


def operational_space_inertia(dyn, q, frames, dims, p=None) -> np.ndarray:
    """(J M⁻¹ Jᵀ)⁻¹ of the task (Dynamics.operational_space_inertia), through the Cholesky
    factor of G = J M⁻¹ Jᵀ scaled to a unit diagonal; SingularTaskError when a pivot is at
    most SINGULAR_PIVOT (or not positive)."""
    indices, dims = task_frames(dyn.info, frames), task_dims(dims)
    G = _delassus(dyn, q, indices, dims, p)
    stacked = G.ndim == 3
    Gs = G if stacked else G[None]
    out = np.empty_like(Gs)
    eye = np.eye(G.shape[-1])
    for row, g in enumerate(Gs):
        d = np.sqrt(np.diag(g))
        if g.shape[0] > dyn.nv or not np.all(d > 0):
            raise singular_task(dyn.info, indices, dims, row if stacked else -1)
        scaled = g / d[:, None] / d[None, :]
        try:
            C = np.linalg.cholesky(scaled)
        except np.linalg.LinAlgError:
            C = None
        if C is None or not np.all(np.diag(C) ** 2 > SINGULAR_PIVOT):
            raise singular_task(dyn.info, indices, dims, row if stacked else -1)
        inv = np.linalg.solve(C.T, np.linalg.solve(C, eye))
        out[row] = inv / d[:, None] / d[None, :]
    out = 0.5 * (out + np.swapaxes(out, -1, -2))
    return out if stacked else out[0]


def _mass_cholesky(M: np.ndarray) -> np.ndarray:
    """M's lower Cholesky factor, with forward dynamics's errors."""
    from ..errors import NonFiniteStateError, SingularMassMatrixError

    if not np.isfinite(M).all():
        raise NonFiniteStateError(
            "the mass matrix is NaN or inf at this state: q holds NaN or inf")
    try:
        return np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        raise SingularMassMatrixError(
            "mass matrix is singular or not positive definite at this state") from None
