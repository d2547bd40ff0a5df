"""The centre of mass and the centroidal dynamics in NumPy, in Pinocchio's conventions.

As `centerOfMass`, `ccrba` and `dccrba` give them: every 6-vector is linear then angular, in
world axes, about the centre of mass g; the angular part of the centroidal momentum h_g is
the angular momentum about g. The robot's mass is that of its moving bodies (a fixed body
merged into its moving ancestor, a body welded to the world left out), read from the
regressor's parameters pi (per moving body: m, m c and the inertia about its origin, in its
frame) and placed by the bodies' placements X (gagen.runtime.frames).

Every body is taken in world axes about the point fixed in space where g is now: its mass
m, first moment h = m (c - g) and inertia I about g; its velocity V = (v, w), the velocity
of its point at g and its angular velocity; its momentum (P, L) = (m v + w x h, I w + h x v).
A joint coordinate's motion S (V of a unit rate) is (a x (g - o), a) for a revolute joint
of world axis a at o, (a, 0) for a prismatic one, and for a floating body (R e_r, 0) and
((R e_r) x (g - o), R e_r).

- A_g's column j is the momentum of the subtree of j's body (its composite inertia) under
  S_j; J_com is its linear rows over the total mass.
- d/dt A_g's column j is that momentum's rate, dI_s S_j + I_s (V x S_j) (S_j turns with the
  body), where dI_s sums each body's dI = (dh = P, [w] I - I [w] - [v][h] - [h][v]) over
  the subtree, less (0, dg/dt x A_g's linear rows) as g moves.
- The bias d/dt A_g qd is the sum of the bodies' momentum rates I A + V x* (P, L) at
  qdd = 0, with the spatial accelerations of the velocity pass, A = A_parent + V x (S qd).

The C of compiled models (codegen/templates/model/centroidal.c.j2) does the same arithmetic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..manifest import JOINT_KINDS, ModelInfo

REVOLUTE, PRISMATIC, FLOATING = (JOINT_KINDS[k] for k in ("revolute", "prismatic", "floating"))
# pi's inertia about a body's origin, in Pinocchio's order (xx, xy, yy, xz, yz, zz), as 3x3
_INERTIA = np.array([[0, 1, 3], [1, 2, 4], [3, 4, 5]])


@dataclass
class Links:
    """The moving bodies about g in world axes (arrays (..., K, ...) over the stacked
    states and the K moving bodies of `ModelInfo.moving_tree`)."""

    R: np.ndarray     # (..., K, 3, 3) orientation
    o: np.ndarray     # (..., K, 3) origin
    axis: np.ndarray  # (..., K, 3) joint axis
    m: np.ndarray     # (K,) mass
    h: np.ndarray     # (..., K, 3) first moment about g
    I: np.ndarray     # (..., K, 3, 3) inertia about g
    g: np.ndarray     # (..., 3) the centre of mass
    mass: float


def links(info: ModelInfo, X: np.ndarray, pi: np.ndarray) -> Links:
    """The moving bodies about the centre of mass, from the placements X (..., 15 nb) and
    the regressor's parameters pi (P,)."""
    tree = info.moving_tree
    K = len(tree)
    blocks = X.reshape(X.shape[:-1] + (len(info.bodies), 15))[..., [t[0] for t in tree], :]
    R = blocks[..., :9].reshape(blocks.shape[:-1] + (3, 3))
    o, axis = blocks[..., 9:12], blocks[..., 12:15]
    P = np.asarray(pi[:10 * K], dtype=float).reshape(K, 10)
    m = P[:, 0]
    h = np.einsum("...kij,kj->...ki", R, P[:, 1:4])  # about each origin, world axes
    I = np.einsum("...kij,kjl,...kml->...kim", R, P[:, 4:10][:, _INERTIA], R)
    mass = float(m.sum())
    g = (m[:, None] * o + h).sum(axis=-2) / mass
    d = o - g[..., None, :]
    # parallel axes from o to g: I + (2 h.d + m d.d) E - (d h^T + h d^T + m d d^T)
    s = 2 * (h * d).sum(axis=-1) + m * (d * d).sum(axis=-1)
    I = I + s[..., None, None] * np.eye(3) - (
        d[..., :, None] * h[..., None, :] + h[..., :, None] * d[..., None, :]
        + m[:, None, None] * d[..., :, None] * d[..., None, :])
    return Links(R, o, axis, m, h + m[:, None] * d, I, g, mass)


def motions(L: Links, k: int, kind: int) -> np.ndarray:
    """(..., c, 6): the motions at g of unit rates of moving body k's c joint coordinates."""
    arm = L.g - L.o[..., k, :]
    axis = L.axis[..., k, :]
    zero = np.zeros_like(arm)
    if kind == REVOLUTE:
        return np.concatenate([np.cross(axis, arm), axis], axis=-1)[..., None, :]
    if kind == PRISMATIC:
        return np.concatenate([axis, zero], axis=-1)[..., None, :]
    e = np.swapaxes(L.R[..., k, :, :], -1, -2)  # (..., 3, 3): row r is the body's axis r
    linear = np.concatenate([e, np.zeros_like(e)], axis=-1)
    angular = np.concatenate([np.cross(e, arm[..., None, :]), e], axis=-1)
    return np.concatenate([linear, angular], axis=-2)


def momentum(m, h: np.ndarray, I: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(m v + w x h, I w + h x v) of the inertia (m, h, I) under motions S (..., 6)."""
    m = np.asarray(m)[..., None]
    v, w = S[..., :3], S[..., 3:]
    return np.concatenate([m * v + np.cross(w, h), np.einsum("...ij,...j->...i", I, w)
                           + np.cross(h, v)], axis=-1)


def motion_cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b of motions (linear, angular): (wa x vb + va x wb, wa x wb)."""
    return np.concatenate([np.cross(a[..., 3:], b[..., :3]) + np.cross(a[..., :3], b[..., 3:]),
                           np.cross(a[..., 3:], b[..., 3:])], axis=-1)


def _composites(info: ModelInfo, L: Links) -> tuple[list, list, list]:
    """The subtrees' composite inertias about g: masses, first moments, inertias."""
    m = [L.m[k] for k in range(len(L.m))]
    h = [L.h[..., k, :] for k in range(len(m))]
    I = [L.I[..., k, :, :] for k in range(len(m))]
    for k in reversed(range(len(m))):
        parent = info.moving_tree[k][1]
        if parent >= 0:
            m[parent], h[parent], I[parent] = m[parent] + m[k], h[parent] + h[k], I[parent] + I[k]
    return m, h, I


def _velocities(info: ModelInfo, L: Links, qd: np.ndarray) -> tuple[list, list]:
    """The bodies' velocities at g and their joints' own parts S qd, each (..., 6)."""
    V, rel = [], []
    for k, (_, parent, kind, column) in enumerate(info.moving_tree):
        S = motions(L, k, kind)
        own = np.einsum("...cj,...c->...j", S, qd[..., column: column + S.shape[-2]])
        V.append(own if parent < 0 else V[parent] + own)
        rel.append(own)
    return V, rel


def center_of_mass(info: ModelInfo, X: np.ndarray, pi: np.ndarray) -> np.ndarray:
    """The centre of mass in the world, (..., 3)."""
    return links(info, X, pi).g


def _total_momentum(info: ModelInfo, L: Links, qd: np.ndarray) -> np.ndarray:
    V, _ = _velocities(info, L, qd)
    return sum(momentum(L.m[k], L.h[..., k, :], L.I[..., k, :, :], V[k])
               for k in range(len(V)))


def com_velocity(info: ModelInfo, X: np.ndarray, pi: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """The centre of mass's velocity, (..., 3): the linear momentum over the mass."""
    L = links(info, X, pi)
    return _total_momentum(info, L, qd)[..., :3] / L.mass


def centroidal_momentum(info: ModelInfo, X: np.ndarray, pi: np.ndarray,
                        qd: np.ndarray) -> np.ndarray:
    """h_g, (..., 6)."""
    return _total_momentum(info, links(info, X, pi), qd)


def centroidal_map(info: ModelInfo, X: np.ndarray, pi: np.ndarray, nv: int) -> np.ndarray:
    """A_g, (..., 6, nv)."""
    L = links(info, X, pi)
    m, h, I = _composites(info, L)
    A = np.zeros(L.g.shape[:-1] + (6, nv))
    for k, (_, _, kind, column) in enumerate(info.moving_tree):
        S = motions(L, k, kind)
        f = momentum(m[k], h[k][..., None, :], I[k][..., None, :, :], S)
        A[..., :, column: column + S.shape[-2]] = np.swapaxes(f, -1, -2)
    return A


def com_jacobian(info: ModelInfo, X: np.ndarray, pi: np.ndarray, nv: int) -> np.ndarray:
    """J_com, (..., 3, nv): A_g's linear rows over the total mass."""
    return centroidal_map(info, X, pi, nv)[..., :3, :] / links(info, X, pi).mass


def centroidal_map_time_variation(info: ModelInfo, X: np.ndarray, pi: np.ndarray,
                                  qd: np.ndarray, nv: int) -> np.ndarray:
    """d/dt A_g, (..., 6, nv)."""
    L = links(info, X, pi)
    m, h, I = _composites(info, L)
    V, _ = _velocities(info, L, qd)
    dh, dI = [], []
    for k in range(len(V)):
        v, w = V[k][..., :3], V[k][..., 3:]
        hk, Ik = L.h[..., k, :], L.I[..., k, :, :]
        dh.append(momentum(L.m[k], hk, Ik, V[k])[..., :3])
        WI = np.cross(w[..., :, None], Ik, axis=-2)  # [w] I, column by column
        dI.append(WI + np.swapaxes(WI, -1, -2) - hk[..., :, None] * v[..., None, :]
                  - v[..., :, None] * hk[..., None, :]
                  + 2 * (v * hk).sum(axis=-1)[..., None, None] * np.eye(3))
    for k in reversed(range(len(V))):
        parent = info.moving_tree[k][1]
        if parent >= 0:
            dh[parent], dI[parent] = dh[parent] + dh[k], dI[parent] + dI[k]
    vcom = sum(dh[k] for k, t in enumerate(info.moving_tree) if t[1] < 0) / L.mass
    out = np.zeros(L.g.shape[:-1] + (6, nv))
    for k, (_, _, kind, column) in enumerate(info.moving_tree):
        S = motions(L, k, kind)
        f = momentum(m[k], h[k][..., None, :], I[k][..., None, :, :],
                     motion_cross(V[k][..., None, :], S))
        Sv, Sw = S[..., :3], S[..., 3:]
        f[..., :3] += np.cross(Sw, dh[k][..., None, :])
        f[..., 3:] += np.einsum("...ij,...cj->...ci", dI[k], Sw) + np.cross(dh[k][..., None, :], Sv)
        linear = m[k] * Sv + np.cross(Sw, h[k][..., None, :])
        f[..., 3:] -= np.cross(vcom[..., None, :], linear)
        out[..., :, column: column + S.shape[-2]] = np.swapaxes(f, -1, -2)
    return out


def centroidal_bias(info: ModelInfo, X: np.ndarray, pi: np.ndarray,
                    qd: np.ndarray) -> np.ndarray:
    """d/dt A_g qd, (..., 6): the rate of h_g at qdd = 0."""
    L = links(info, X, pi)
    V, rel = _velocities(info, L, qd)
    acc: list[np.ndarray] = []
    total = 0.0
    for k, (_, parent, _, _) in enumerate(info.moving_tree):
        a = motion_cross(V[k], rel[k])
        if parent >= 0:
            a = a + acc[parent]
        acc.append(a)
        hk, Ik = L.h[..., k, :], L.I[..., k, :, :]
        f = momentum(L.m[k], hk, Ik, V[k])
        v, w = V[k][..., :3], V[k][..., 3:]
        rate = momentum(L.m[k], hk, Ik, a) + np.concatenate(
            [np.cross(w, f[..., :3]), np.cross(w, f[..., 3:]) + np.cross(v, f[..., :3])],
            axis=-1)
        total = total + rate
    return total
