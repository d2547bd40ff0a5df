"""The inverse-dynamics derivatives of a tree, fixed or floating, by an analytical algorithm
in one common frame, written symbolically; and the Coriolis matrix, M and the bias forces
from the same quantities.

Forward mode through the body-frame RNEA (`differentiate`) carries each of the 2n
directions through every body after it: O(n * depth) spatial transforms per direction.
Expressed in one frame, the derivative of every quantity of the subtree of joint j by q_j
is a cross product with the joint's motion vector S_j plus a few terms of its own, and
each entry of the Jacobians becomes one or two 6-dot products (Carpentier and Mansard,
"Analytical derivatives of rigid body dynamics algorithms", RSS 2018, who derive the same
quantities from the RNEA in Pinocchio's world frame). This module derives them afresh in
gagen's notation; tests/test_derivatives.py and tests/test_floating_derivatives.py check
them against forward mode, central differences and Pinocchio.

Spatial vectors are pairs of 3-vectors about the common origin: a motion (w, v) is an
angular velocity and the velocity of the body point at the origin; a force (n, f) is a
moment about the origin and a force. Cross products: (w1, v1) x (w2, v2) = (w1 x w2,
w1 x v2 + v1 x w2) for motions, (w, v) x* (n, f) = (w x n + v x f, w x f) on forces. An
inertia is (m, c, I): the mass, the first moment m r_C and the inertia about the origin;
it maps a motion to the momentum (I w + c x v, m v + w x c).

For body k (of path 1..k from the root), with S_k the motion vector of its joint and
lambda(k) its parent:

    v_k = v_lambda + S_k qd_k                      a_0 = (0, -g): gravity
    a_k = a_lambda + S_k qdd_k + (v_lambda x S_k) qd_k
    f_k = I_k a_k + v_k x* (I_k v_k)               tau_k = S_k . F_k,  F_k = sum over the subtree

Differentiating by q_j moves the whole subtree of j rigidly by S_j: the rigid part of
every derivative is S_j x (.) and cancels in tau_i = S_i . F_i for i in the subtree. What
remains are the joint's own terms

    dVdq_j = v_lambda(j) x S_j,   dAdq_j = a_lambda(j) x S_j + v_lambda(j) x dVdq_j,

with d v_k/d q_j = S_j x v_k + dVdq_j and d a_k/d q_j = S_j x a_k + dAdq_j + dVdq_j x v_k
for k in the subtree of j, and (by q_d) d v_k/d qd_j = S_j, d a_k/d qd_j = S_j x v_k +
X_j with X_j = 2 dVdq_j. With the subtree sums Y_i = sum I_k (composite inertia),
Ydot_i = sum (v_k x* I_k - I_k v_k x) (the rate of each inertia, again an inertia with no
mass), H_i = sum I_k v_k (momentum) and F_i = sum f_k, and B_i psi = Ydot_i psi + psi x* H_i:

    i an ancestor of j or j:  d tau_i/d q_j  = S_i . D_j,  D_j = S_j x* F_j + Y_j dAdq_j + B_j dVdq_j
                              d tau_i/d qd_j = S_i . E_j,  E_j = Y_j X_j + B_j S_j
    i a descendant of j:      d tau_i/d q_j  = u_i . dAdq_j + w_i . dVdq_j
                              d tau_i/d qd_j = u_i . X_j + w_i . S_j
    with u_i = Y_i S_i and w_i = B_i^T S_i = Ydot_i S_i - S_i x* H_i;

every other entry is zero. The joint terms (added by the caller) add damping_k to
d tau_k/d qd_k: Coulomb friction's sign(qd) has derivative 0 where it has one, and the
armature multiplies qdd.

A floating joint has six coordinates: the body's twist in its own axes (Pinocchio's
FreeFlyer), and d/dq is taken along those velocity directions, d/de f(q (+) e e_j), as
Pinocchio's derivatives are. Its motion vectors S_k are fixed in its body, so each moves
with the others: S_k's rate is Sdot_k = v x S_k (v: the body's velocity), and moving along
S_j turns S_k by S_j x S_k. Carried through the same steps: v = v_lambda + sum S_k qd_k,
a = a_lambda + sum S_k qdd_k + v_lambda x v (which is also a 1-dof joint's), dVdq_j and
dAdq_j as above, and X_j = dVdq_j + Sdot_j (for a 1-dof joint Sdot_j = v_lambda x S_j =
dVdq_j, hence its 2 dVdq_j). Within the joint its own rows are descendants' rows: row k,
column j of the six is u_k . dAdq_j + w_k . dVdq_j.

The Coriolis matrix is Pinocchio's (computeCoriolisMatrix), with G_j = Y_j Sdot_j +
B_j S_j / 2: C_ij = S_i . G_j for i an ancestor of j or j, C_ij = u_i . Sdot_j +
w_i . S_j / 2 for i a descendant. C qd = b and Mdot - 2C is skew-symmetric. Where every
joint has one coordinate, C = 1/2 d tau/d qd of the rigid body, the symmetric Christoffel
matrix (symbolic/derivatives.py); with a floating joint it is not (its rates are
quasi-velocities).

The common frame is the world's, or for a tree whose root floats, the root's own frame at
this instant (`common_frames`): then the root's six motion vectors are unit vectors, its
pose drops out, and only gravity turns with it, which halves ANYmal's program.
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
    """Whether this algorithm covers the model: every model gagen reads (1-dof joints, and
    floating joints, which attach to the world)."""
    return all(not b.joint.floating or b.parent == "world" for b in model.moving_bodies)


@dataclass
class RneaDerivatives:
    """The results of `rnea_derivatives`, n x n lists by rows (n-lists for `bias`)."""

    dtau_dq: list[list[sp.Expr]]
    dtau_dqd: list[list[sp.Expr]]     # of the rigid-body tau: 2 C on a fixed base, no damping
    mass_matrix: list[list[sp.Expr]]   # rigid-body M(q): M_ij = S_i . Y_j S_j, i above j
    bias: list[sp.Expr]                # rigid-body tau at qdd = 0: b(q, qd) - g(q)
    coriolis: list[list[sp.Expr]]      # C (module docstring), Pinocchio's computeCoriolisMatrix


def rnea_derivatives(model: Model, coords: CoordinateSymbols, rec: Recorder) -> RneaDerivatives:
    """d tau/d q (along the velocity directions) and d tau/d qd of the rigid-body tau =
    ID(q, qd, qdd), the Coriolis matrix, and the rigid-body mass matrix and bias forces from
    the same world-frame quantities (the forward-dynamics derivatives need them next to the
    others), named in `rec` (module docstring). The joint terms are the caller's to add."""
    links = _links(model, coords, rec)
    n = model.dof
    kin = _world_kinematics(links, coords, model.gravity, rec)
    sums = _subtree_sums(links, kin, rec)
    out = RneaDerivatives(*([[sp.Integer(0)] * n for _ in range(n)] for _ in range(3)),
                          bias=[sp.Integer(0)] * n,
                          coriolis=[[sp.Integer(0)] * n for _ in range(n)])
    vectors: dict[int, _ColumnVectors] = {}
    for j in range(len(links)):
        for col in kin.columns[j]:
            vectors[col.index] = _column_vectors(col, sums, rec)
    half = sp.Rational(1, 2)
    for j in range(len(links)):
        ancestors = [col for i in _ancestors(links, j) for col in kin.columns[i]]
        for col in kin.columns[j]:
            c, S, x = col.index, col.S, vectors[col.index]
            out.bias[c] = rec.name(_dot(S, sums.F0[j]))
            # rows above column c: its link's own columns (for a floating joint, the
            # joint's columns move with each other: the formula of the rows below), then
            # the ancestors' columns
            for own in kin.columns[j]:
                r, y = own.index, vectors[own.index]
                out.dtau_dq[r][c] = rec.name(_dot(own.S, x.D) if not col.free else
                                             _dot(col.dA, y.u) + _dot(col.dV, y.w))
                out.dtau_dqd[r][c] = rec.name(_dot(own.S, x.E))
                out.mass_matrix[r][c] = rec.name(_dot(own.S, x.u))
                out.coriolis[r][c] = (half * out.dtau_dqd[r][c] if not col.free
                                      else rec.name(_dot(own.S, x.G)))
            for above in ancestors:
                r = above.index
                out.dtau_dq[r][c] = rec.name(_dot(above.S, x.D))
                out.dtau_dqd[r][c] = rec.name(_dot(above.S, x.E))
                out.mass_matrix[r][c] = out.mass_matrix[c][r] = rec.name(_dot(above.S, x.u))
                out.coriolis[r][c] = (half * out.dtau_dqd[r][c] if not col.free
                                      else rec.name(_dot(above.S, x.G)))
                # row c, column r: column c's link is in the subtree of r's
                out.dtau_dq[c][r] = rec.name(_dot(above.dA, x.u) + _dot(above.dV, x.w))
                out.dtau_dqd[c][r] = rec.name(_dot(above.X, x.u) + _dot(above.S, x.w))
                out.coriolis[c][r] = (half * out.dtau_dqd[c][r] if not above.free else
                                      rec.name(_dot(above.Sdot, x.u)
                                               + half * _dot(above.S, x.w)))
    return out


@dataclass
class _ColumnVectors:
    """A column's D, E, u, w (module docstring) and G = Y Sdot + B S / 2 (the Coriolis
    matrix's; None where C is half of d tau/d qd, a 1-dof joint's column)."""

    D: Force
    E: Force
    u: Force
    w: Force
    G: Force | None


def _column_vectors(col: _Column, sums: _SubtreeSums, rec: Recorder) -> _ColumnVectors:
    """Column col's D, E, u, w and G, each entry named."""
    j = col.link
    S, dV, dA = col.S, col.dV, col.dA
    Y, Ydot, H = sums.Y[j], sums.Ydot[j], sums.H[j]
    BS = _b_apply(Ydot, H, S, rec)
    D = _add(_fcross(S, sums.F[j], rec), Y.apply(dA, rec), _b_apply(Ydot, H, dV, rec))
    E = _add(Y.apply(col.X, rec), BS) if col.free else _add(_scale(2, Y.apply(dV, rec)), BS)
    w = _sub(Ydot.apply(S, rec), _fcross(S, H, rec))
    G = _add(Y.apply(col.Sdot, rec), _scale(sp.Rational(1, 2), BS)) if col.free else None
    return _ColumnVectors(_named(D, rec), _named(E, rec), Y.apply(S, rec), _named(w, rec),
                          None if G is None else _named(G, rec))


@dataclass
class _Column:
    """One velocity coordinate of a joint, in the world frame: its motion vector S, the
    terms dV and dA that its derivative adds to the subtree's velocities and
    accelerations, X (what d a_k/d qd_c adds to S x v_k in the subtree) and Sdot = v x S
    (v: the velocity of the joint's body). For a 1-dof joint X = 2 dV and Sdot = dV."""

    index: int       # the velocity coordinate
    link: int
    S: Motion
    dV: Motion
    dA: Motion
    X: Motion
    Sdot: Motion
    free: bool       # a floating joint's column


@dataclass
class _WorldKinematics:
    """Per link, in the world frame: the joint's columns (none for a fixed joint), the
    velocity, the acceleration (a0, free of qdd, plus alpha, linear in qdd) and the
    inertia."""

    columns: list[list[_Column]]
    v: list[Motion]
    a0: list[Motion]
    alpha: list[Motion]
    a: list[Motion]
    inertia: list[Inertia]


def _world_kinematics(links: list[Link], coords: CoordinateSymbols, gravity,
                      rec: Recorder) -> _WorldKinematics:
    """The forward pass: poses in the common frame, motion vectors, velocities and
    accelerations."""
    rest: Motion = (ZERO, ZERO)
    out = _WorldKinematics([], [], [], [], [], [])
    for j, (link, (R, p, base)) in enumerate(zip(links, common_frames(links, gravity, rec))):
        if link.parent is None:
            v_in, a0_in, alpha_in, a_in = rest, base, rest, base
        else:
            P = link.parent
            v_in, a0_in, alpha_in, a_in = out.v[P], out.a0[P], out.alpha[P], out.a[P]
        out.inertia.append(_world_inertia(link, R, p, rec))
        if link.k is None:
            out.columns.append([])
            out.v.append(v_in)
            out.a0.append(a0_in)
            out.alpha.append(alpha_in)
            out.a.append(a_in)
            continue
        motions = joint_motions(link, R, p, rec)
        if link.free:
            columns, v, a0, alpha = _free_joint(j, link, motions, v_in, a0_in, alpha_in,
                                                a_in, coords, rec)
        else:
            (S,) = motions
            dV = _mcross(v_in, S, rec)
            dA = _named(_add(_mcross(a_in, S, rec), _mcross(v_in, dV, rec)), rec)
            qd, qdd = coords.qd[link.k], coords.qdd[link.k]
            columns = [_Column(link.k, j, S, dV, dA, _scale(2, dV), dV, free=False)]
            v = _named(_add(v_in, _scale(qd, S)), rec)
            a0 = _named(_add(a0_in, _scale(qd, dV)), rec)
            alpha = _named(_add(alpha_in, _scale(qdd, S)), rec)
        out.columns.append(columns)
        out.v.append(v)
        out.a0.append(a0)
        out.alpha.append(alpha)
        out.a.append(_named(_add(a0, alpha), rec))
    return out


def common_frames(links: list[Link], gravity, rec: Recorder
                  ) -> list[tuple[sp.Matrix, Vec, Motion | None]]:
    """Per link: its frame's axes R and origin p in the common frame of its tree, and for
    a root the acceleration of that frame's origin that gravity stands for, (0, -g) in its
    axes (None for other links).

    The common frame is the world's, except for a tree whose root floats: there it is the
    root's own frame at this instant. Every quantity of the algorithm is a scalar of
    vectors in one frame (a derivative, a mass-matrix entry), so any frame fixed at the
    instant serves; in the root's own, its six motion vectors are unit vectors, its pose
    is the identity and the legs' poses are free of the base's, and only gravity turns
    with the base."""
    g = -sp.Matrix(gravity)
    out: list[tuple[sp.Matrix, Vec, Motion | None]] = []
    for link in links:
        if link.parent is None and link.free:
            out.append((sp.eye(3), ZERO, (ZERO, rec.vec(sp.Matrix(link.R).T * g))))
        elif link.parent is None:
            out.append((sp.Matrix(link.R), sp.Matrix(link.d), (ZERO, g)))
        else:
            R0, p0, _ = out[link.parent]
            out.append(((R0 * sp.Matrix(link.R)).applyfunc(rec.name),
                        rec.vec(p0 + R0 * sp.Matrix(link.d)), None))
    return out


def joint_motions(link: Link, R: sp.Matrix, p: Vec, rec: Recorder) -> list[Motion]:
    """The motion vectors of a joint's velocity coordinates in the common frame, for a
    link at (R, p) there: S = (z, p x z) for a revolute joint of axis z, (0, z) for a
    prismatic one; a floating joint's six (module docstring of `_free_joint`)."""
    if link.free:
        axes = [R[:, k] for k in range(3)]
        return [(ZERO, a) for a in axes] + [(a, rec.vec(p.cross(a))) for a in axes]
    z = rec.vec(R * sp.Matrix(link.axis))
    return [(z, rec.vec(p.cross(z))) if link.rotates else (ZERO, z)]


def _free_joint(j: int, link: Link, columns: list[Motion], v_in: Motion, a0_in: Motion,
                alpha_in: Motion, a_in: Motion, coords: CoordinateSymbols, rec: Recorder
                ) -> tuple[list[_Column], Motion, Motion, Motion]:
    """A floating joint's six columns, its body's velocity v and acceleration (a0, alpha).

    Its velocity coordinates are the body's linear velocity (of its origin) and angular
    velocity in its own axes (Pinocchio's FreeFlyer): column k moves the body with the
    motion S_k = (0, R e_k) (linear) or (R e_k, p x R e_k) (angular), fixed in the
    body, so Sdot_k = v x S_k, and a = a_in + S qdd + v_in x v (v_in: the parent's
    velocity, zero for the world)."""
    qd, qdd = coords.qd[link.k: link.k + 6], coords.qdd[link.k: link.k + 6]
    v = _named(_add(v_in, *(_scale(r, S) for r, S in zip(qd, columns))), rec)
    a0 = _named(_add(a0_in, _mcross(v_in, v, rec)), rec)
    alpha = _named(_add(alpha_in, *(_scale(r, S) for r, S in zip(qdd, columns))), rec)
    out = []
    for k, S in enumerate(columns):
        dV = _mcross(v_in, S, rec)
        dA = _named(_add(_mcross(a_in, S, rec), _mcross(v_in, dV, rec)), rec)
        Sdot = _mcross(v, S, rec)
        out.append(_Column(link.k + k, j, S, dV, dA, _named(_add(dV, Sdot), rec), Sdot,
                           free=True))
    return out, v, a0, alpha


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


# --- the loop form's geometry --------------------------------------------------------------

INERTIA_ENTRIES = 10  # m, h (3), I: xx, yy, zz, xy, xz, yz


@dataclass
class TreeGeometry:
    """What the derivative module's loop form (codegen/derivatives.py) reads: the tree's
    geometry at q as expressions in named intermediates, and the tree as numbers. The
    compiled loop runs the algorithm of the module docstring over it, so the generated code
    grows with the bodies, not with the (ancestor, descendant) pairs.

    Moving links are the bodies with a joint coordinate, parents first, each with the
    bodies welded to it by fixed joints. Per moving link, `inertia` holds its spatial
    inertia in the common frame (`common_frames`): the mass, the first moment m c and the
    rotational inertia about the origin (xx, yy, zz, xy, xz, yz); a root also has `base`,
    the linear acceleration (-g in the common axes) its frame's origin stands in for. Per
    velocity coordinate ("column"), `motion` holds S (angular, then linear)."""

    inertia: list[list[sp.Expr]]
    motion: list[list[sp.Expr]]
    base: list[list[sp.Expr]]          # per root moving link, in the order of `roots`
    parents: list[int]                 # per moving link: its moving parent, -1 for none
    roots: list[int]                   # the moving links without one
    free_roots: list[bool]             # per moving link: a floating root (its own frame is
    #                                    the common frame: its S are unit vectors)
    columns: list[list[int]]           # per moving link: its velocity coordinates
    armature: list[sp.Expr]            # per velocity coordinate: the joint terms
    damping: list[sp.Expr]
    dissipative: list[sp.Expr]         # damping qd + friction sign(qd)
    intermediates: list[tuple[sp.Symbol, sp.Expr]]

    @property
    def column_link(self) -> list[int]:
        out = [0] * len(self.motion)
        for b, cols in enumerate(self.columns):
            for c in cols:
                out[c] = b
        return out

    @property
    def column_parent(self) -> list[int]:
        """Per velocity coordinate, the one before it on its path to the root (-1: none):
        a floating joint's six in a row, a link's first after its parent link's last.
        M's non-zero entries lie on these paths, and the factorisation follows them."""
        out = [-1] * len(self.motion)
        for b, cols in enumerate(self.columns):
            P = self.parents[b]
            previous = self.columns[P][-1] if P >= 0 else -1
            for c in cols:
                out[c] = previous
                previous = c
        return out

    @property
    def column_order(self) -> list[int]:
        """The velocity coordinates depth first (a link's coordinates, then its children's
        subtrees in turn): each coordinate's descendants come right after it."""
        children: list[list[int]] = [[] for _ in self.parents]
        for b, P in enumerate(self.parents):
            if P >= 0:
                children[P].append(b)
        order: list[int] = []
        stack = list(reversed(self.roots))
        while stack:
            b = stack.pop()
            order += self.columns[b]
            stack += reversed(children[b])
        return order

    @property
    def column_descendants(self) -> list[int]:
        """Per position of `column_order`, how many positions after it are its
        descendants (a floating joint's later coordinates count as its earlier ones')."""
        order, up = self.column_order, self.column_parent
        count = dict.fromkeys(order, 0)
        for c in order:
            r = up[c]
            while r >= 0:
                count[r] += 1
                r = up[r]
        return [count[c] for c in order]


def tree_geometry(eqs) -> TreeGeometry:
    """The loop form's geometry of `eqs`'s model, a continuation of its program."""
    from .differentiate import needed_definitions, recorder_after
    from .joints import armatures, dampings, dissipative_forces

    model, coords = eqs.model, eqs.coords
    rec = recorder_after(eqs.intermediates)
    given = len(rec.definitions)
    links = _links(model, coords, rec)
    frames = common_frames(links, model.gravity, rec)
    owner: list[int | None] = []   # per link: the moving link it moves with (None: the world)
    moving: list[int] = []         # moving link -> link
    for j, link in enumerate(links):
        if link.k is not None:
            owner.append(len(moving))
            moving.append(j)
        else:
            owner.append(None if link.parent is None else owner[link.parent])
    inertias: list[Inertia | None] = [None] * len(moving)
    for j, (link, (R, p, _)) in enumerate(zip(links, frames)):
        b = owner[j]
        if b is None or (link.mass == 0 and all(e == 0 for e in link.h)):
            continue
        I = _world_inertia(link, R, p, rec)
        inertias[b] = I if inertias[b] is None else inertias[b] + I
    parents, roots, base, inertia, columns, motion, free_roots = [], [], [], [], [], {}, []
    for b, j in enumerate(moving):
        link, (R, p, acceleration) = links[j], frames[j]
        P = None if link.parent is None else owner[link.parent]
        parents.append(-1 if P is None else P)
        free_roots.append(P is None and link.free and link.parent is None)
        if P is None:
            roots.append(b)
            # a moving link welded to the world through fixed joints: the world's frame
            acceleration = acceleration or (ZERO, -sp.Matrix(model.gravity))
            base.append([rec.name(e) for e in acceleration[1]])
        I = inertias[b] or Inertia(sp.Integer(0), ZERO, sp.zeros(3, 3))
        I = _named_inertia(I, rec)
        inertia.append([I.m, *I.c, I.I[0, 0], I.I[1, 1], I.I[2, 2], I.I[0, 1], I.I[0, 2],
                        I.I[1, 2]])
        width = 6 if link.free else 1
        columns.append(list(range(link.k, link.k + width)))
        for c, S in zip(columns[-1], joint_motions(link, R, p, rec)):
            motion[c] = [rec.name(e) for e in (*S[0], *S[1])]
    motions = [motion[c] for c in range(model.dof)]
    values = [e for row in inertia + motions + base for e in row]
    armature, damping = armatures(model), dampings(model)
    dissipative = dissipative_forces(model, coords)
    new = needed_definitions(rec.definitions, values + armature + damping + dissipative,
                             first=given)
    return TreeGeometry(inertia, motions, base, parents, roots, free_roots, columns, armature,
                        damping, dissipative, rec.definitions[:given] + new)
