"""The assembly steps of the printed target in jax.numpy: frames from the printed bodies'
placements (gagen.runtime.frames, the same arithmetic), and the regressor from its printed
per-body kinematics (codegen/templates/model/regressor.c.j2, the same loop). The tree is
numbers from the manifest and the printed module; everything works over leading
dimensions."""

from __future__ import annotations

import jax.numpy as jnp

from gagen.runtime.frames import FLOATING, PRISMATIC, REVOLUTE


def _body_pose(X, body: int):
    block = X[..., 15 * body: 15 * body + 15]
    return block[..., :9].reshape(block.shape[:-1] + (3, 3)), block[..., 9:12]


def pose(info, X, F, k: int):
    """(R, p) of frame k in the world from placements X (..., 15 nb) and offsets F."""
    body = info.frames[k][1]
    R_f = F[..., 12 * k: 12 * k + 9].reshape(F.shape[:-1] + (3, 3))
    p_f = F[..., 12 * k + 9: 12 * k + 12]
    lead = jnp.broadcast_shapes(X.shape[:-1], F.shape[:-1])
    if body < 0:
        return jnp.broadcast_to(R_f, lead + (3, 3)), jnp.broadcast_to(p_f, lead + (3,))
    R_b, p_b = _body_pose(X, body)
    return R_b @ R_f, p_b + jnp.einsum("...ij,...j->...i", R_b, p_f)


def jacobian(info, X, F, k: int, nv: int):
    """The (..., 6, nv) LOCAL_WORLD_ALIGNED Jacobian of frame k (gagen.runtime.frames)."""
    _, p_f = pose(info, X, F, k)
    lead = p_f.shape[:-1]
    columns = [jnp.zeros(lead + (6,), X.dtype) for _ in range(nv)]
    body = info.frames[k][1]
    while body >= 0:
        parent, kind, column = info.bodies[body]
        R_b, p_b = _body_pose(X, body)
        axis = X[..., 15 * body + 12: 15 * body + 15]
        if kind == REVOLUTE:
            columns[column] = jnp.concatenate(
                [jnp.broadcast_to(jnp.cross(axis, p_f - p_b), lead + (3,)),
                 jnp.broadcast_to(axis, lead + (3,))], -1)
        elif kind == PRISMATIC:
            columns[column] = jnp.concatenate(
                [jnp.broadcast_to(axis, lead + (3,)), jnp.zeros(lead + (3,), X.dtype)], -1)
        elif kind == FLOATING:
            arm = p_f - p_b
            zero = jnp.zeros(lead + (3,), X.dtype)
            for c in range(3):
                e = jnp.broadcast_to(R_b[..., :, c], lead + (3,))
                columns[column + c] = jnp.concatenate([e, zero], -1)
                columns[column + 3 + c] = jnp.concatenate([jnp.cross(e, arm), e], -1)
        body = parent
    return jnp.stack(columns, axis=-1)


# --- the regressor: codegen/templates/model/regressor.c.j2 in jax.numpy ----------------------

def _axis(kind: int, r: int, axis):
    """Row r of a body's joint as (sigma_ang, sigma_lin) in its frame (gagen_reg_axis)."""
    zero = jnp.zeros_like(axis[..., 0])
    one = jnp.ones_like(zero)
    if kind == 1:
        entries = [axis[..., 0], axis[..., 1], axis[..., 2], zero, zero, zero]
    elif kind == 2:
        entries = [zero, zero, zero, axis[..., 0], axis[..., 1], axis[..., 2]]
    else:
        entries = [zero] * 6
        entries[3 + r if r < 3 else r - 3] = one
    return entries


def _carry(K, s):
    """sigma of a child from its parent's (gagen_reg_carry)."""
    R = [K[..., k] for k in range(9)]
    d = [K[..., 9 + k] for k in range(3)]
    a0, a1, a2 = s[0], s[1], s[2]
    t0 = s[3] + a1 * d[2] - a2 * d[1]
    t1 = s[4] + a2 * d[0] - a0 * d[2]
    t2 = s[5] + a0 * d[1] - a1 * d[0]
    return [R[0] * a0 + R[3] * a1 + R[6] * a2, R[1] * a0 + R[4] * a1 + R[7] * a2,
            R[2] * a0 + R[5] * a1 + R[8] * a2, R[0] * t0 + R[3] * t1 + R[6] * t2,
            R[1] * t0 + R[4] * t1 + R[7] * t2, R[2] * t0 + R[5] * t1 + R[8] * t2]


def _columns(K, s):
    """The ten coefficients of (m, h, I_O) in a body's row (gagen_reg_columns)."""
    w0, w1, w2 = K[..., 12], K[..., 13], K[..., 14]
    l0, l1, l2 = K[..., 15], K[..., 16], K[..., 17]
    a0, a1, a2 = K[..., 18], K[..., 19], K[..., 20]
    A0, A1, A2, L0, L1, L2 = s
    u0, u1, u2 = w1 * L2 - w2 * L1, w2 * L0 - w0 * L2, w0 * L1 - w1 * L0
    b0, b1, b2 = A1 * w2 - A2 * w1, A2 * w0 - A0 * w2, A0 * w1 - A1 * w0
    return [L0 * a0 + L1 * a1 + L2 * a2,
            L1 * l2 - L2 * l1 + w1 * u2 - w2 * u1 + a1 * A2 - a2 * A1,
            L2 * l0 - L0 * l2 + w2 * u0 - w0 * u2 + a2 * A0 - a0 * A2,
            L0 * l1 - L1 * l0 + w0 * u1 - w1 * u0 + a0 * A1 - a1 * A0,
            A0 * l0 + b0 * w0,
            A0 * l1 + A1 * l0 + b0 * w1 + b1 * w0,
            A1 * l1 + b1 * w1,
            A0 * l2 + A2 * l0 + b0 * w2 + b2 * w0,
            A1 * l2 + A2 * l1 + b1 * w2 + b2 * w1,
            A2 * l2 + b2 * w2]


def regressor(main, q, qd, qdd, p):
    """Y (..., nv, nreg) from the printed module's per-body kinematics."""
    parents, kinds, rows, joint_rows = main.REGRESSOR_TREE
    nb, nk, nreg, nv = len(parents), main.PER_BODY, main.NREG, main.NV
    K = main.regressor_kinematics(q, qd, qdd, p)
    lead = jnp.broadcast_shapes(K.shape[:-1], qd.shape[:-1], qdd.shape[:-1])
    K = jnp.broadcast_to(K, lead + K.shape[-1:])
    body = [K[..., nk * i: nk * (i + 1)] for i in range(nb)]
    zero = jnp.zeros(lead, K.dtype)
    Y = [[zero] * nreg for _ in range(nv)]
    for i in range(nb):
        count = 6 if kinds[i] == 3 else 0 if kinds[i] == 0 else 1
        for r in range(count):
            row = rows[i] + r
            sigma = {i: _axis(kinds[i], r, body[i][..., 21:24])}
            Y[row][10 * i: 10 * i + 10] = _columns(body[i], sigma[i])
            for k in range(i + 1, nb):
                parent = parents[k]
                if parent >= i and parent in sigma:
                    sigma[k] = _carry(body[k], sigma[parent])
                    Y[row][10 * k: 10 * k + 10] = _columns(body[k], sigma[k])
    m = len(joint_rows)
    qd = jnp.broadcast_to(qd, lead + qd.shape[-1:])
    qdd = jnp.broadcast_to(qdd, lead + qdd.shape[-1:])
    for k, row in enumerate(joint_rows):
        Y[row][10 * nb + k] = qd[..., row]
        Y[row][10 * nb + m + k] = jnp.sign(qd[..., row])
        Y[row][10 * nb + 2 * m + k] = qdd[..., row]
    return jnp.stack([jnp.stack(r, -1) for r in Y], -2)
