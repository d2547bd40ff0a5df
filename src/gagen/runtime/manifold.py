"""The configuration space of a model with floating joints, in NumPy (no SymPy).

A floating joint's configuration is its body's origin p (in the world, or in the joint's
origin frame) and a unit quaternion (x, y, z, w) for its orientation R; its velocity is
the origin's velocity v and the angular velocity w, both in the body's frame. These
follow Pinocchio's FreeFlyer, and so do `integrate` (q ⊕ v dt: the body moves along the
twist (v, w) held constant in its own frame for dt, SE(3)'s exponential) and
`difference` (its inverse, SE(3)'s logarithm). Every other coordinate is a number on a
line: q + v dt and q1 - q0.

`configuration_rate` is dq/dt of the equations of motion: p' = R v and
quat' = 1/2 quat ⊗ (w, 0), plus `QUATERNION_RESTORING` (1 - |quat|^2) quat, a pull back
to the unit sphere that is zero on it (the exact flow keeps |quat| = 1; an integrator's
error would otherwise drift off it step after step). The compiled integrators use the
same formula (codegen/templates/model/simulation.c.j2).
"""

from __future__ import annotations

import numpy as np

from ..manifest import QUATERNION_RESTORING


def floating_slices(info) -> list[tuple[int, int]]:
    """(first entry in q, first coordinate in v) of each floating joint of a ModelInfo."""
    return info.floating_joints()


def plain_entries(info) -> tuple[np.ndarray, np.ndarray]:
    """Indices (in q, in v) of the coordinates that are plain numbers on a line."""
    floating = floating_slices(info)
    in_q = np.ones(info.nq, dtype=bool)
    in_v = np.ones(info.dof, dtype=bool)
    for iq, iv in floating:
        in_q[iq: iq + 7] = False
        in_v[iv: iv + 6] = False
    return np.flatnonzero(in_q), np.flatnonzero(in_v)


def rotation(quaternion: np.ndarray) -> np.ndarray:
    """The rotation matrices of quaternions (..., 4) as (x, y, z, w), normalised first."""
    x, y, z, w = np.moveaxis(np.asarray(quaternion, dtype=float), -1, 0)
    s = 2.0 / (x * x + y * y + z * z + w * w)
    R = np.empty(np.shape(x) + (3, 3))
    R[..., 0, 0] = 1 - s * (y * y + z * z)
    R[..., 0, 1] = s * (x * y - w * z)
    R[..., 0, 2] = s * (x * z + w * y)
    R[..., 1, 0] = s * (x * y + w * z)
    R[..., 1, 1] = 1 - s * (x * x + z * z)
    R[..., 1, 2] = s * (y * z - w * x)
    R[..., 2, 0] = s * (x * z - w * y)
    R[..., 2, 1] = s * (y * z + w * x)
    R[..., 2, 2] = 1 - s * (x * x + y * y)
    return R


def quaternion_of(R: np.ndarray) -> np.ndarray:
    """The unit quaternion (x, y, z, w), w >= 0, of rotation matrices (..., 3, 3)."""
    R = np.asarray(R, dtype=float)
    t = np.trace(R, axis1=-2, axis2=-1)
    out = np.empty(R.shape[:-2] + (4,))
    cases = np.stack([t, R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]], axis=-1).argmax(-1)
    for case in range(4):
        m = cases == case
        if not np.any(m):
            continue
        r = R[m]
        if case == 0:
            s = np.sqrt(1.0 + t[m]) * 2
            q = [(r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                 (r[:, 1, 0] - r[:, 0, 1]) / s, s / 4]
        else:
            i = case - 1
            j, k = (i + 1) % 3, (i + 2) % 3
            s = np.sqrt(1.0 + r[:, i, i] - r[:, j, j] - r[:, k, k]) * 2
            q = [None] * 4
            q[i] = s / 4
            q[j] = (r[:, j, i] + r[:, i, j]) / s
            q[k] = (r[:, k, i] + r[:, i, k]) / s
            q[3] = (r[:, k, j] - r[:, j, k]) / s
        out[m] = np.stack(q, axis=-1)
    out *= np.where(out[..., 3:] < 0, -1.0, 1.0)
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def _hat(w: np.ndarray) -> np.ndarray:
    W = np.zeros(np.shape(w)[:-1] + (3, 3))
    W[..., 0, 1], W[..., 0, 2] = -w[..., 2], w[..., 1]
    W[..., 1, 0], W[..., 1, 2] = w[..., 2], -w[..., 0]
    W[..., 2, 0], W[..., 2, 1] = -w[..., 1], w[..., 0]
    return W


def _exp_coefficients(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """sin(t)/t, (1 - cos t)/t^2, (t - sin t)/t^3, by their series near 0."""
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    a = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, np.sin(t) / t)
    # 1 - cos t as 2 sin^2(t/2): no cancellation (at t = 1e-3, 1 - cos t keeps 6 digits)
    b = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, 2 * (np.sin(t / 2) / t) ** 2)
    c = np.where(small, 1 / 6 - t2 / 120 + t2 * t2 / 5040, (t - np.sin(t)) / (t * t * t))
    return a, b, c


def exp6(nu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """SE(3)'s exponential of twists (..., 6) = (linear, angular): (R, p)."""
    v, w = nu[..., :3], nu[..., 3:]
    theta = np.linalg.norm(w, axis=-1)
    a, b, c = _exp_coefficients(theta)
    W = _hat(w)
    W2 = W @ W
    eye = np.eye(3)
    R = eye + a[..., None, None] * W + b[..., None, None] * W2
    V = eye + b[..., None, None] * W + c[..., None, None] * W2
    return R, (V @ v[..., None])[..., 0]


def log_quaternion(quaternion: np.ndarray) -> np.ndarray:
    """The rotation vectors w (|w| <= pi) of quaternions (..., 4) as (x, y, z, w).

    w = 2 atan2(|v|, s) v / |v| for the unit quaternion (v, s) taken with s >= 0 (q and -q
    are one rotation). atan2 keeps every digit at both ends, where the angle from a
    rotation matrix's trace (arccos) loses half of them: near a half turn, whose axis then
    comes from v itself (exact at s = 0, where the matrix is symmetric and tells the axis
    only up to the signs of its entries), and near no turn."""
    q = np.asarray(quaternion, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., 3:] < 0, -q, q)
    v, s = q[..., :3], q[..., 3]
    norm = np.linalg.norm(v, axis=-1)
    small = norm < 1e-4  # then s > 0.99999999: 2 atan(x) / x by its series in x = |v| / s
    x2 = (norm / np.where(small, s, 1.0)) ** 2
    factor = np.where(small, 2 / np.where(small, s, 1.0) * (1 - x2 / 3 + x2 * x2 / 5),
                      2 * np.arctan2(norm, s) / np.where(small, 1.0, norm))
    return factor[..., None] * v


def log6(w: np.ndarray, p: np.ndarray) -> np.ndarray:
    """SE(3)'s logarithm: the twist (linear, angular) whose exponential is the rotation of
    rotation vector w (`log_quaternion`) with translation p."""
    theta = np.linalg.norm(w, axis=-1)
    small = theta < 1e-4
    W = _hat(w)
    # V^-1 = I - W/2 + d W^2, d = (1 - a/(2b)) / t^2 = (1 - (t/2) cot(t/2)) / t^2: written
    # with the cotangent, 1 - ... loses only the digits of d that W^2 (of size t^2) drops
    t = np.where(small, 1.0, theta)
    d = np.where(small, 1 / 12 + theta ** 2 / 720, (1 - t / 2 / np.tan(t / 2)) / (t * t))
    Vinv = np.eye(3) - W / 2 + d[..., None, None] * (W @ W)
    return np.concatenate([(Vinv @ p[..., None])[..., 0], w], axis=-1)


def configuration_rate(info, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """dq/dt at (q, v) (module docstring), for one state (nq,) or stacked (N, nq)."""
    q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
    out = np.empty_like(q)
    plain_q, plain_v = plain_entries(info)
    out[..., plain_q] = v[..., plain_v]
    for iq, iv in floating_slices(info):
        quat = q[..., iq + 3: iq + 7]
        lin, w = v[..., iv: iv + 3], v[..., iv + 3: iv + 6]
        out[..., iq: iq + 3] = (rotation(quat) @ lin[..., None])[..., 0]
        x, y, z, s = np.moveaxis(quat, -1, 0)
        a, b, c = np.moveaxis(w, -1, 0)
        norm2 = x * x + y * y + z * z + s * s
        pull = QUATERNION_RESTORING * (1 - norm2)
        out[..., iq + 3] = 0.5 * (s * a + y * c - z * b) + pull * x
        out[..., iq + 4] = 0.5 * (s * b + z * a - x * c) + pull * y
        out[..., iq + 5] = 0.5 * (s * c + x * b - y * a) + pull * z
        out[..., iq + 6] = -0.5 * (x * a + y * b + z * c) + pull * s
    return out


def checked_step(info, v: np.ndarray, dt) -> np.ndarray:
    """v * dt, refused (ValueError) unless dt is a finite number and the step is finite with
    each floating joint's rotation vector of a finite norm (a norm that overflows leaves no
    angle to turn by)."""
    if isinstance(dt, (bool, str, bytes)) or np.ndim(dt) != 0:
        raise TypeError(f"dt must be a number, got {type(dt).__name__}")
    dt = float(dt)
    if not np.isfinite(dt):
        raise ValueError(f"dt must be finite, got {dt}")
    with np.errstate(over="ignore"):
        step = np.asarray(v, dtype=float) * dt
        if not np.isfinite(step).all():
            raise ValueError("v * dt overflows: it must be finite")
        for _, iv in floating_slices(info):
            w = step[..., iv + 3: iv + 6]
            if not np.isfinite(np.sum(w * w, axis=-1)).all():
                raise ValueError(f"v[{iv + 3}:{iv + 6}] * dt, a floating joint's rotation "
                                 "vector, has a norm that overflows")
    return step


def integrate(info, q, v, dt=1.0) -> np.ndarray:
    """q ⊕ v dt, as Pinocchio's `integrate(model, q, v * dt)`: fresh array(s)."""
    q = np.array(q, dtype=float)
    step = np.asarray(v, dtype=float) * dt
    plain_q, plain_v = plain_entries(info)
    out = q.copy() if q.ndim == step.ndim else np.broadcast_to(q, step.shape[:-1] + q.shape[-1:]).copy()
    out[..., plain_q] = out[..., plain_q] + step[..., plain_v]
    for iq, iv in floating_slices(info):
        quat = out[..., iq + 3: iq + 7]
        _, dp = exp6(step[..., iv: iv + 6])
        out[..., iq: iq + 3] = out[..., iq: iq + 3] + (rotation(quat) @ dp[..., None])[..., 0]
        # quat ⊗ exp(w dt / 2): the quaternion moves continuously (no sign flips), as
        # Pinocchio's does
        turned = _multiply(quat, _exp_quaternion(step[..., iv + 3: iv + 6]))
        out[..., iq + 3: iq + 7] = turned / np.linalg.norm(turned, axis=-1, keepdims=True)
    return out


def _exp_quaternion(w: np.ndarray) -> np.ndarray:
    """The unit quaternion (x, y, z, w) of the rotation vector w."""
    theta = np.linalg.norm(w, axis=-1)
    half = theta / 2
    small = theta < 1e-4
    sinc = np.where(small, 0.5 - theta ** 2 / 48, np.sin(half) / np.where(small, 1.0, theta))
    return np.concatenate([sinc[..., None] * w, np.cos(half)[..., None]], axis=-1)


def _multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton's product of quaternions (x, y, z, w)."""
    av, aw = a[..., :3], a[..., 3:]
    bv, bw = b[..., :3], b[..., 3:]
    vector = aw * bv + bw * av + np.cross(av, bv)
    scalar = aw * bw - np.sum(av * bv, axis=-1, keepdims=True)
    return np.concatenate([vector, scalar], axis=-1)


def difference(info, q0, q1) -> np.ndarray:
    """The v with `integrate(q0, v) == q1` (Pinocchio's `difference(model, q0, q1)`)."""
    q0, q1 = np.asarray(q0, dtype=float), np.asarray(q1, dtype=float)
    shape = np.broadcast_shapes(q0.shape[:-1], q1.shape[:-1]) + (info.dof,)
    out = np.empty(shape)
    plain_q, plain_v = plain_entries(info)
    out[..., plain_v] = q1[..., plain_q] - q0[..., plain_q]
    for iq, iv in floating_slices(info):
        quat0, quat1 = q0[..., iq + 3: iq + 7], q1[..., iq + 3: iq + 7]
        R0T = np.swapaxes(rotation(quat0), -1, -2)
        dp = (R0T @ (q1[..., iq: iq + 3] - q0[..., iq: iq + 3])[..., None])[..., 0]
        # the relative rotation as a quaternion, conj(quat0) ⊗ quat1, not as R0^T R1: its
        # angle keeps every digit near a half turn (log_quaternion)
        relative = _multiply(quat0 * [-1.0, -1.0, -1.0, 1.0], quat1)
        out[..., iv: iv + 6] = log6(log_quaternion(relative), dp)
    return out


def floating_velocities(info) -> np.ndarray:
    """The indices in v of the floating joints' coordinates (no actuator drives them)."""
    return np.array([iv + k for _, iv in floating_slices(info) for k in range(6)], dtype=int)


def configuration_of(info, values) -> np.ndarray:
    """The configuration with the plain coordinates at `values` (one per velocity
    coordinate; a floating joint's entries ignored) and every quaternion the identity."""
    q = neutral(info)
    plain_q, plain_v = plain_entries(info)
    q[plain_q] = np.asarray(values, dtype=float)[plain_v]
    return q


def neutral(info) -> np.ndarray:
    """The configuration with every coordinate 0 and every quaternion the identity."""
    q = np.zeros(info.nq)
    for iq, _ in floating_slices(info):
        q[iq + 6] = 1.0
    return q


def normalized(info, q) -> np.ndarray:
    """q with each floating joint's quaternion scaled to unit norm (a fresh array; see
    `unit_quaternion` for quaternions whose squared norm overflows, zero or NaN ones)."""
    q = np.array(q, dtype=float)
    for iq, _ in floating_slices(info):
        q[..., iq + 3: iq + 7] = unit_quaternion(q[..., iq + 3: iq + 7])
    return q


def unit_quaternion(quat: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) divided by their norms, without a NumPy warning: one whose
    squared norm overflows or underflows (the last samples of a diverging simulation) is
    scaled by its largest entry first, and one that is zero or holds NaN or inf becomes
    NaN (its simulation's status says why)."""
    with np.errstate(over="ignore"):
        norm = np.linalg.norm(quat, axis=-1, keepdims=True)
    fine = np.isfinite(norm) & (norm > 0)
    if fine.all():
        return quat / norm  # the usual case, one division
    with np.errstate(all="ignore"):
        scaled = quat / np.max(np.abs(quat), axis=-1, keepdims=True)  # NaN: zero, inf, NaN
        scaled /= np.linalg.norm(scaled, axis=-1, keepdims=True)
        return np.where(fine, quat / norm, scaled)
