"""The inverse-dynamics derivatives of a fixed-base tree, by an analytical algorithm in
one common frame (the world's), written symbolically.

Forward mode through the body-frame RNEA (`differentiate`) carries each of the 2n
directions through every body after it: O(n * depth) spatial transforms per direction.
Expressed in one frame, the derivative of every quantity of the subtree of joint j by q_j
is a cross product with the joint's motion vector S_j plus a few terms of its own, and
each entry of the Jacobians becomes one or two 6-dot products (Carpentier and Mansard,
"Analytical derivatives of rigid body dynamics algorithms", RSS 2018, who derive the same
quantities from the RNEA in Pinocchio's world frame). This module derives them afresh in
gagen's notation; tests/test_derivatives.py checks them against forward mode and Pinocchio.

Spatial vectors are pairs of 3-vectors about the world origin: a motion (w, v) is an
angular velocity and the velocity of the body point at the origin; a force (n, f) is a
moment about the origin and a force. Cross products: (w1, v1) x (w2, v2) = (w1 x w2,
w1 x v2 + v1 x w2) for motions, (w, v) x* (n, f) = (w x n + v x f, w x f) on forces. An
inertia is (m, c, I): the mass, the first moment m r_C and the inertia about the origin;
it maps a motion to the momentum (I w + c x v, m v + w x c).

For body k (of path 1..k from the root), with S_k the world motion vector of its joint
and lambda(k) its parent:

    v_k = v_lambda + S_k qd_k                      a_0 = (0, -g): gravity
    a_k = a_lambda + S_k qdd_k + (v_lambda x S_k) qd_k
    f_k = I_k a_k + v_k x* (I_k v_k)               tau_k = S_k . F_k,  F_k = sum over the subtree

Differentiating by q_j moves the whole subtree of j rigidly by S_j: the rigid part of
every derivative is S_j x (.) and cancels in tau_i = S_i . F_i for i in the subtree. What
remains are the joint's own terms

    dVdq_j = v_lambda(j) x S_j,   dAdq_j = a_lambda(j) x S_j + v_lambda(j) x dVdq_j,

with d v_k/d q_j = S_j x v_k + dVdq_j and d a_k/d q_j = S_j x a_k + dAdq_j + dVdq_j x v_k
for k in the subtree of j, and (by q_d) d v_k/d qd_j = S_j, d a_k/d qd_j = S_j x v_k +
2 dVdq_j. With the subtree sums Y_i = sum I_k (composite inertia), Ydot_i = sum
(v_k x* I_k - I_k v_k x) (the rate of each inertia, again an inertia with no mass),
H_i = sum I_k v_k (momentum) and F_i = sum f_k, and B_i psi = Ydot_i psi + psi x* H_i:

    i an ancestor of j or j:  d tau_i/d q_j  = S_i . D_j,  D_j = S_j x* F_j + Y_j dAdq_j + B_j dVdq_j
                              d tau_i/d qd_j = S_i . E_j,  E_j = 2 Y_j dVdq_j + B_j S_j
    i a descendant of j:      d tau_i/d q_j  = u_i . dAdq_j + w_i . dVdq_j
                              d tau_i/d qd_j = 2 u_i . dVdq_j + w_i . S_j
    with u_i = Y_i S_i and w_i = B_i^T S_i = Ydot_i S_i - S_i x* H_i;

every other entry is zero. d tau/d qd of the rigid body is 2 C, twice the Coriolis
matrix (symbolic/derivatives.py). The joint terms (added by the caller) add damping_k to
d tau_k/d qd_k: Coulomb friction's sign(qd) has derivative 0 where it has one, and the
armature multiplies qdd.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from ..model.model import Model
from .kinematics import CoordinateSymbols, Recorder
from .recursive import Link, _links
from .recursive import _symmetric as _symmetric3
from .vec3 import as_mat, skew

Vec = sp.Matrix
Motion = tuple[Vec, Vec]   # (angular, linear at the origin)
Force = tuple[Vec, Vec]    # (moment about the origin, force)
ZERO = sp.zeros(3, 1)


@dataclass
class Inertia:
    """A spatial inertia about the world origin: mass, first moment, rotational inertia."""

    m: sp.Expr
    c: Vec
    I: sp.Matrix

    def apply(self, x: Motion, rec: Recorder) -> Force:
        """The momentum of a motion: (I w + c x v, m v + w x c)."""
        w, v = x
        return rec.vec(self.I * w + self.c.cross(v)), rec.vec(self.m * v + w.cross(self.c))

    def __add__(self, other: Inertia) -> Inertia:
        return Inertia(self.m + other.m, self.c + other.c, self.I + other.I)


def applies(model: Model) -> bool:
    """Whether this algorithm covers the model: every joint has at most one coordinate."""
    return not any(b.joint.floating for b in model.moving_bodies)


@dataclass
class RneaDerivatives:
    """The results of `rnea_derivatives`, n x n lists by rows (n-lists for `bias`)."""

    dtau_dq: list[list[sp.Expr]]
    dtau_dqd: list[list[sp.Expr]]     # of the rigid-body tau: 2 C, no damping
    mass_matrix: list[list[sp.Expr]]   # rigid-body M(q): M_ij = S_i . Y_j S_j, i above j
    bias: list[sp.Expr]                # rigid-body tau at qdd = 0: b(q, qd) - g(q)


def rnea_derivatives(model: Model, coords: CoordinateSymbols, rec: Recorder) -> RneaDerivatives:
    """d tau/d q and d tau/d qd of the rigid-body tau = ID(q, qd, qdd), and the rigid-body
    mass matrix and bias forces from the same world-frame quantities (the forward-dynamics
    derivatives need them next to the others), named in `rec` (module docstring). The
    joint terms are the caller's to add."""
    links = _links(model, coords, rec)
    n = model.dof
    kin = _world_kinematics(links, coords, model.gravity, rec)
    sums = _subtree_sums(links, kin, rec)
    out = RneaDerivatives(*([[sp.Integer(0)] * n for _ in range(n)] for _ in range(3)),
                          bias=[sp.Integer(0)] * n)
    for j, link in enumerate(links):
        if link.k is None:
            continue
        col, S = link.k, kin.S[j]
        D, E, u, w = _joint_vectors(j, kin, sums, rec)
        out.bias[col] = rec.name(_dot(S, sums.F0[j]))
        ancestors = _ancestors(links, j)
        for i in [j, *ancestors]:  # row i on j's path to the root (j included)
            row = links[i].k
            out.dtau_dq[row][col] = rec.name(_dot(kin.S[i], D))
            out.dtau_dqd[row][col] = rec.name(_dot(kin.S[i], E))
            out.mass_matrix[row][col] = out.mass_matrix[col][row] = rec.name(_dot(kin.S[i], u))
        for i in ancestors:  # row j, column i: j is in i's subtree
            out.dtau_dq[col][links[i].k] = rec.name(_dot(kin.dAdq[i], u)
                                                   + _dot(kin.dVdq[i], w))
            out.dtau_dqd[col][links[i].k] = rec.name(2 * _dot(kin.dVdq[i], u)
                                                    + _dot(kin.S[i], w))
    return out


def _joint_vectors(j: int, kin: _WorldKinematics, sums: _SubtreeSums, rec: Recorder
                   ) -> tuple[Force, Force, Force, Force]:
    """Joint j's D_j, E_j, u_j and w_j (module docstring), each entry named."""
    S, dV, dA = kin.S[j], kin.dVdq[j], kin.dAdq[j]
    Y, Ydot, H = sums.Y[j], sums.Ydot[j], sums.H[j]
    D = _add(_fcross(S, sums.F[j], rec), Y.apply(dA, rec), _b_apply(Ydot, H, dV, rec))
    E = _add(_scale(2, Y.apply(dV, rec)), _b_apply(Ydot, H, S, rec))
    w = _sub(Ydot.apply(S, rec), _fcross(S, H, rec))
    return _named(D, rec), _named(E, rec), Y.apply(S, rec), _named(w, rec)


@dataclass
class _WorldKinematics:
    """Per link, in the world frame: the joint's motion vector (None for a fixed joint),
    velocity, acceleration (a0, free of qdd, plus alpha, linear in qdd), dVdq and dAdq
    (None for a fixed joint), and the inertia."""

    S: list[Motion | None]
    v: list[Motion]
    a0: list[Motion]
    alpha: list[Motion]
    a: list[Motion]
    dVdq: list[Motion | None]
    dAdq: list[Motion | None]
    inertia: list[Inertia]


def _world_kinematics(links: list[Link], coords: CoordinateSymbols, gravity,
                      rec: Recorder) -> _WorldKinematics:
    """The forward pass: world poses, motion vectors, velocities and accelerations."""
    rest: Motion = (ZERO, ZERO)
    base: Motion = (ZERO, -sp.Matrix(gravity))
    out = _WorldKinematics([], [], [], [], [], [], [], [])
    R0: list[sp.Matrix] = []
    p0: list[Vec] = []
    for link in links:
        if link.parent is None:
            R, p, v_in, a0_in, alpha_in, a_in = (sp.Matrix(link.R), sp.Matrix(link.d), rest,
                                                 base, rest, base)
        else:
            P = link.parent
            R = (R0[P] * sp.Matrix(link.R)).applyfunc(rec.name)
            p = rec.vec(p0[P] + R0[P] * sp.Matrix(link.d))
            v_in, a0_in, alpha_in, a_in = out.v[P], out.a0[P], out.alpha[P], out.a[P]
        R0.append(R)
        p0.append(p)
        out.inertia.append(_world_inertia(link, R, p, rec))
        if link.k is None:
            out.S.append(None)
            out.dVdq.append(None)
            out.dAdq.append(None)
            out.v.append(v_in)
            out.a0.append(a0_in)
            out.alpha.append(alpha_in)
            out.a.append(a_in)
            continue
        z = rec.vec(R * sp.Matrix(link.axis))
        S = (z, rec.vec(p.cross(z))) if link.rotates else (ZERO, z)
        dV = _mcross(v_in, S, rec)
        dA = _add(_mcross(a_in, S, rec), _mcross(v_in, dV, rec))
        qd, qdd = coords.qd[link.k], coords.qdd[link.k]
        out.S.append(S)
        out.dVdq.append(dV)
        out.dAdq.append((rec.vec(dA[0]), rec.vec(dA[1])))
        out.v.append(_named(_add(v_in, _scale(qd, S)), rec))
        a0 = _named(_add(a0_in, _scale(qd, dV)), rec)
        alpha = _named(_add(alpha_in, _scale(qdd, S)), rec)
        out.a0.append(a0)
        out.alpha.append(alpha)
        out.a.append(_named(_add(a0, alpha), rec))
    return out


def _world_inertia(link: Link, R: sp.Matrix, p: Vec, rec: Recorder) -> Inertia:
    """A body's inertia about the world origin, from its inertia about its frame's origin
    (at p, axes R): rotated, then moved by the parallel-axes terms. With h the rotated
    first moment about the frame's origin, those are m (|p|^2 E - p p^T) + 2 (p.h) E -
    (p h^T + h p^T) = 2 (p.g) E - (p g^T + g p^T) with g = h + m p / 2."""
    h = rec.vec(R * sp.Matrix(link.h))
    RI = (R * sp.Matrix(link.I_O)).applyfunc(rec.name)
    g = rec.vec(h + link.mass / 2 * p)
    pg = rec.name(p.dot(g))
    I = RI * R.T + 2 * pg * sp.eye(3) - (p * g.T + g * p.T)
    return Inertia(link.mass, rec.vec(h + link.mass * p), _symmetric(I, rec))


@dataclass
class _SubtreeSums:
    """Per link, sums over its subtree: composite inertia Y, inertia rate Ydot, momentum H,
    force F and F0, the part of F free of qdd."""

    Y: list[Inertia]
    Ydot: list[Inertia]
    H: list[Force]
    F0: list[Force]
    F: list[Force]


def _subtree_sums(links: list[Link], kin: _WorldKinematics, rec: Recorder) -> _SubtreeSums:
    """The backward pass (module docstring), each entry named. F = F0 + the sum of
    I_k alpha_k, so that M and the bias forces come from the qdd-free stage and only the
    rest depends on qdd."""
    Y = list(kin.inertia)
    Ydot = [_inertia_rate(I, v, rec) for I, v in zip(kin.inertia, kin.v)]
    H: list[Force] = []
    F0: list[Force] = []
    Fa: list[Force] = []
    for I, v, a0, alpha in zip(kin.inertia, kin.v, kin.a0, kin.alpha):
        h = I.apply(v, rec)
        H.append(h)
        F0.append(_add(I.apply(a0, rec), _fcross(v, h, rec)))
        Fa.append(I.apply(alpha, rec))
    for i in reversed(range(len(links))):
        Y[i], Ydot[i] = _named_inertia(Y[i], rec), _named_inertia(Ydot[i], rec)
        H[i], F0[i], Fa[i] = _named(H[i], rec), _named(F0[i], rec), _named(Fa[i], rec)
        P = links[i].parent
        if P is not None:
            Y[P], Ydot[P] = Y[P] + Y[i], Ydot[P] + Ydot[i]
            H[P], F0[P], Fa[P] = _add(H[P], H[i]), _add(F0[P], F0[i]), _add(Fa[P], Fa[i])
    F = [_named(_add(f0, fa), rec) for f0, fa in zip(F0, Fa)]
    return _SubtreeSums(Y, Ydot, H, F0, F)


def _inertia_rate(I: Inertia, x: Motion, rec: Recorder) -> Inertia:
    """d/dt of an inertia moving with the motion x = (w, v): x x* I - I x x, which is again
    an inertia (massless): c' = m v + w x c, I' = 2 (c.v) E - (v c^T + c v^T) + [w]I - I[w]."""
    w, v = x
    c_rate = rec.vec(I.m * v + w.cross(I.c))
    cv = rec.name(I.c.dot(v))
    Wx = sp.Matrix(skew(w))
    I_rate = 2 * cv * sp.eye(3) - (v * I.c.T + I.c * v.T) + Wx * I.I - I.I * Wx
    return Inertia(sp.Integer(0), c_rate, _symmetric(I_rate, rec))


def _b_apply(Ydot: Inertia, H: Force, x: Motion, rec: Recorder) -> Force:
    """B x = Ydot x + x x* H."""
    return _add(Ydot.apply(x, rec), _fcross(x, H, rec))


def _ancestors(links: list[Link], i: int) -> list[int]:
    """The links with a coordinate on the path from link i's parent to the root."""
    out = []
    P = links[i].parent
    while P is not None:
        if links[P].k is not None:
            out.append(P)
        P = links[P].parent
    return out


def _mcross(x: Motion, y: Motion, rec: Recorder) -> Motion:
    return rec.vec(x[0].cross(y[0])), rec.vec(x[0].cross(y[1]) + x[1].cross(y[0]))


def _fcross(x: Motion, f: Force, rec: Recorder) -> Force:
    return rec.vec(x[0].cross(f[0]) + x[1].cross(f[1])), rec.vec(x[0].cross(f[1]))


def _dot(x: Motion, f: Force) -> sp.Expr:
    return x[0].dot(f[0]) + x[1].dot(f[1])


def _add(*xs):
    return sum((x[0] for x in xs[1:]), xs[0][0]), sum((x[1] for x in xs[1:]), xs[0][1])


def _sub(x, y):
    return x[0] - y[0], x[1] - y[1]


def _scale(s, x):
    return s * x[0], s * x[1]


def _named(x, rec: Recorder):
    return rec.vec(x[0]), rec.vec(x[1])


def _named_inertia(I: Inertia, rec: Recorder) -> Inertia:
    return Inertia(rec.name(I.m), rec.vec(I.c), _symmetric(I.I, rec))


def _symmetric(A: sp.Matrix, rec: Recorder) -> sp.Matrix:
    """`recursive._symmetric` (the 6 distinct entries named) of a sympy.Matrix."""
    return sp.Matrix(_symmetric3(as_mat(A), rec))
