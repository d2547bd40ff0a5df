"""Forward dynamics by Featherstone's articulated-body algorithm (ABA), symbolically.

`forward_dynamics_aba(model)` returns a straight-line program: intermediate definitions
(each a few operations) and the joint accelerations qdd, in the symbols of
`recursive.derive_recursive` (same q, qd, tau, parameters and per-body setup: joint
transforms R, d and inertias about the frame origins). Its size is O(n) for chains and
trees, against O(n * depth) for M by the CRBA plus an O(n^3) LDL^T solve.

Conventions (those of `recursive`). Body i's frame is its joint frame; R holds the parent
-frame components of its axes and d = O_i - O_parent in the parent's frame. Spatial
vectors are pairs of 3-vectors in frame i, taken about O_i (Featherstone's convention):

- motion m = (w, v): angular velocity, and velocity of the body point at O_i;
- force f = (n, f): moment about O_i, and force;
- acceleration: the time derivative of a motion vector, (alpha, a_O - w x v_O), not the
  classical acceleration of O_i; gravity enters as the base acceleration (0, -g).

Transforms. A parent motion (w_p, v_p) is, in frame i,
    w = R^T w_p,   v = R^T (v_p + w_p x d)          i.e. X = [R^T 0; -R^T [d] R^T],
and a child force (n, f) is, in the parent frame (X^T, the dual),
    f_p = R f,     n_p = R n + d x f_p.
A spatial inertia I = [A B; B^T C] (A, C symmetric 3x3, about O_i in frame i) moves to the
parent as X^T I X, in two steps: rotate each block (A_r = R A R^T, B_r = R B R^T,
C_r = R C R^T) and shift its reference point from O_i to O_p, with K = B_r [d] and
Q = [d] C_r:
    A' = A_r - K - K^T - Q [d],   B' = B_r + Q,   C' = C_r.
(For one rigid body, A = I_O, B = [h], C = m E, this gives I_O - [h][d] - [d][h] - m[d][d]
and [h + m d], the CRBA's parallel-axes step.) The rigid body's momentum is
    I (w, v) = (I_O w + h x v,  m v + w x h).

Spatial cross products: for m = (w, v), m x (a, b) = (w x a, w x b + v x a) on motions and
m x* (n, f) = (w x n + v x f, w x f) on forces.

Algorithm (Featherstone, RBDA, table 7.1), with s the joint's motion subspace, (axis, 0)
for a revolute joint and (0, axis) for a prismatic one (axis is constant in frame i):
  forward:  v_i = X v_p + s qd_i,  c_i = v_i x s qd_i,  p_i = v_i x* I_i v_i;
  backward: U_i = I^A_i s, D_i = s^T U_i, u_i = tau_i - s^T p^A_i, and into the parent
            I^a = I^A_i - U_i U_i^T / D_i,  p^a = p^A_i + I^a c_i + U_i u_i / D_i;
  forward:  a'_i = X a_p + c_i,  qdd_i = (u_i - U_i^T a'_i) / D_i,  a_i = a'_i + s qdd_i.
A fixed joint has no motion subspace: its body's I^A and p^A pass to the parent whole
(c_i = 0), and a_i = X a_p.

Every component is named by an intermediate; 1/D_i once per joint. For an axis along a
coordinate axis (+-e_j, most joints of real robots) the exact consequences of the algebra
are put in instead of computed: U/D has component +-1, and I^a's row and column along the
axis are zero (see `_exact_articulated`). Definitions that no qdd needs (the accelerations
of leaves, say) are dropped at the end. `forward_dynamics_aba_after(eqs)` builds the same
program as a continuation of `derive_recursive`'s intermediates, for one program with both.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import sympy as sp

from ..model.model import Model
from .differentiate import needed_definitions as _needed
from .differentiate import recorder_after
from .gibbs_appell import Equations
from .joints import armatures, dissipative_forces
from .kinematics import CoordinateSymbols, Recorder
from .recursive import (
    Link,
    _links,
    _named_symmetric,
    _rotate_inertia,
    _symmetric,
    free_velocities,
)
from .vec3 import (
    IDENTITY,
    ZERO,
    Mat3,
    Terms,
    Vec3,
    add,
    as_vec,
    cross,
    cross_terms,
    dot,
    mat_add,
    mat_mat,
    mat_mat_T,
    mat_scale,
    mat_sub,
    mat_T_vec_terms,
    mat_vec_terms,
    neg,
    outer,
    scale,
    skew,
    sub,
    sum_of_products,
    transpose,
)


@dataclass
class Inertia:
    """A spatial inertia [A B; B^T C] about a frame's origin, in that frame's axes."""

    A: Mat3   # symmetric
    B: Mat3
    C: Mat3   # symmetric

    def __add__(self, other: Inertia) -> Inertia:
        return Inertia(mat_add(self.A, other.A), mat_add(self.B, other.B),
                       mat_add(self.C, other.C))

    def named(self, rec: Recorder) -> Inertia:
        """The 21 distinct entries named."""
        return Inertia(_symmetric(self.A, rec), rec.named_rows(self.B),
                       _symmetric(self.C, rec))

    def times(self, w: Vec3, v: Vec3) -> tuple[Vec3, Vec3]:
        """I (w, v): the force (moment, force) of a motion."""
        n, f = self.times_terms(w, v)
        return n.vec(), f.vec()

    def times_terms(self, w: Vec3, v: Vec3) -> tuple[Terms, Terms]:
        """I (w, v) as terms."""
        return (mat_vec_terms(self.A, w) + mat_vec_terms(self.B, v),
                mat_T_vec_terms(self.B, w) + mat_vec_terms(self.C, v))

    def matrix(self) -> sp.Matrix:
        """The 6x6 matrix, angular rows and columns first."""
        return sp.Matrix([[*a, *b] for a, b in zip(self.A, self.B)]
                         + [[*bt, *c] for bt, c in zip(transpose(self.B), self.C)])


def _ldlt(A: sp.Matrix, rec: Recorder) -> tuple[sp.Matrix, list, list]:
    """A = L D L^T of a small symmetric positive definite matrix, unrolled and named:
    (unit lower L, the pivots D, their reciprocals)."""
    n = A.shape[0]
    L = sp.eye(n)
    D: list = []
    Dinv: list = []
    for j in range(n):
        D.append(rec.name(A[j, j] - sum(L[j, k] ** 2 * D[k] for k in range(j))))
        Dinv.append(rec.name(1 / D[j]))
        for i in range(j + 1, n):
            L[i, j] = rec.name((A[i, j] - sum(L[i, k] * L[j, k] * D[k] for k in range(j)))
                               * Dinv[j])
    return L, D, Dinv


def _ldlt_solve(L: sp.Matrix, Dinv: list, b: list, rec: Recorder) -> list:
    """x with L D L^T x = b, named."""
    n = len(b)
    y: list = []
    for i in range(n):
        y.append(rec.name(b[i] - sum(L[i, k] * y[k] for k in range(i))))
    x: list = [None] * n
    for i in reversed(range(n)):
        x[i] = rec.name(y[i] * Dinv[i] - sum(L[k, i] * x[k] for k in range(i + 1, n)))
    return x


@dataclass
class AbaProgram:
    """The articulated-body forward dynamics as a straight-line program.

    `qdd[k]` is an expression (here a symbol of `intermediates`) in q, qd, tau and the
    parameters; each intermediate is defined from the earlier ones.
    """

    model: Model
    coords: CoordinateSymbols
    parameters: list[sp.Symbol]
    intermediates: list[tuple[sp.Symbol, sp.Expr]]
    qdd: list[sp.Expr]
    # D_k = s^T I^A s per joint k: a rigid tree's are > 0; the generated code can check
    # them (as its LDL^T checks its pivots) before dividing by them
    pivots: list[sp.Expr] = field(default_factory=list)
    seconds: float = 0.0
    _function: object = field(default=None, repr=False)

    def operation_count(self) -> int:
        """`sympy.count_ops` over the intermediates and the outputs."""
        return (sum(sp.count_ops(e) for _, e in self.intermediates)
                + sum(sp.count_ops(e) for e in self.qdd))

    def lambdify(self):
        """A NumPy function f(q, qd, tau, p) -> qdd evaluating the program in order.

        Only the definitions the qdd need are evaluated. Like the lambdify backend,
        lambdify sees none of the users' names: arguments become `a<k>` and intermediates
        `t<k>`."""
        if self._function is None:
            c = self.coords
            flat = [*c.q, *c.qd, *c.tau, *self.parameters]
            rename = {s: sp.Symbol(f"a{k}") for k, s in enumerate(flat)}
            needed = _needed(self.intermediates, self.qdd)  # not the rest of a shared program
            rename.update({s: sp.Symbol(f"t{k}") for k, (s, _) in enumerate(needed)})
            definitions = [(rename[s], e.xreplace(rename)) for s, e in needed]
            outputs = [sp.sympify(e).xreplace(rename) for e in self.qdd]
            self._function = sp.lambdify([rename[s] for s in flat], outputs, modules="numpy",
                                         cse=lambda exprs: (definitions, exprs))
        return self._function

    def evaluate(self, q, qd, tau, p=None) -> np.ndarray:
        """qdd at one state (p: the parameter vector, default the model's)."""
        p = self.model.parameter_vector() if p is None else np.asarray(p, dtype=float)
        values = self.lambdify()(*np.asarray(q, float), *np.asarray(qd, float),
                                 *np.asarray(tau, float), *p)
        return np.array(values, dtype=float)


def forward_dynamics_aba(model: Model) -> AbaProgram:
    """qdd(q, qd, tau) of a model by the articulated-body algorithm (module docstring)."""
    return _program(model, CoordinateSymbols.for_model(model), Recorder())


def forward_dynamics_aba_after(eqs: Equations) -> AbaProgram:
    """The ABA as a continuation of `eqs` (e.g. `derive_recursive`'s), for one program
    holding both: its intermediates are all of `eqs.intermediates` followed by the new
    definitions the qdd need, numbered after them (no name is defined twice), and every
    expression `eqs` already named (sin and cos, joint transforms, inertias) is reused."""
    return _program(eqs.model, eqs.coords, recorder_after(eqs.intermediates))


def _program(model: Model, coords: CoordinateSymbols, rec: Recorder) -> AbaProgram:
    start = time.perf_counter()
    given = len(rec.definitions)
    links = _links(model, coords, rec)
    c, bias = _velocity_pass(links, coords, rec)
    U, D, Dinv, u = _articulated_pass(links, coords, rec, c, bias, model)
    qdd = _acceleration_pass(links, coords, rec, c, U, Dinv, u, neg(as_vec(model.gravity)))
    pivots = [p for i, link in enumerate(links) if link.k is not None
              for p in (D[i] if link.free else [D[i]])]
    new = _needed(rec.definitions, qdd + pivots, first=given)
    program = AbaProgram(model=model, coords=coords,
                         parameters=[sp.Symbol(k) for k in model.parameters],
                         intermediates=rec.definitions[:given] + new, qdd=qdd,
                         pivots=pivots)
    program.seconds = time.perf_counter() - start
    return program


def _rigid_inertia(link: Link) -> Inertia:
    return Inertia(link.I_O, skew(link.h), mat_scale(link.mass, IDENTITY))


def _joint_motion(link: Link, rate) -> tuple[Vec3, Vec3]:
    """s * rate as (angular, linear); zero for a fixed joint."""
    if link.k is None:
        return ZERO, ZERO
    if link.rotates:
        return scale(rate, link.axis), ZERO
    return ZERO, scale(rate, link.axis)


def _project(link: Link, n: Vec3, f: Vec3) -> sp.Expr:
    """s^T (n, f): the component of a force along the joint's motion subspace."""
    return dot(link.axis, n if link.rotates else f)


def _motion_to_child(link: Link, w_p: Vec3, v_p: Vec3, rec: Recorder) -> tuple[Vec3, Vec3]:
    """X (w_p, v_p): a parent-frame motion (or spatial acceleration) in this frame."""
    return (link.to_child(w_p, rec),
            link.to_child((Terms.of(v_p) + cross_terms(w_p, link.d)).vec(), rec))


def _velocity_pass(links: list[Link], coords: CoordinateSymbols, rec: Recorder):
    """Velocity-product accelerations c_i and bias forces p_i = v_i x* I_i v_i."""
    v: list[tuple[Vec3, Vec3]] = []
    c: list[tuple[Vec3, Vec3]] = []
    bias: list[tuple[Vec3, Vec3]] = []
    for link in links:
        if link.parent is None:
            w_in, v_in = ZERO, ZERO
        else:
            w_in, v_in = _motion_to_child(link, *v[link.parent], rec)
        if link.free:  # the world is at rest: the joint's motion is the body's
            v_lin, v_ang = free_velocities(link, coords.qd)
            s_w, s_v = v_ang, v_lin
        else:
            s_w, s_v = _joint_motion(link, coords.qd[link.k] if link.k is not None else 0)
        w, vel = rec.named(add(w_in, s_w)), rec.named(add(v_in, s_v))
        # v_i x (s qd) = (w x s_w, w x s_v + v x s_w); s x s = 0 lets w_in stand for w
        c.append((rec.named(cross(w_in, s_w)),
                  rec.named((cross_terms(w_in, s_v) + cross_terms(v_in, s_w)).vec())))
        v.append((w, vel))
        L, P = _rigid_inertia(link).times(w, vel)
        L, P = rec.named(L), rec.named(P)
        bias.append((rec.named((cross_terms(w, L) + cross_terms(vel, P)).vec()),
                     rec.named(cross(w, P))))
    return c, bias


def _articulated_pass(links: list[Link], coords: CoordinateSymbols, rec: Recorder,
                      c: list, bias: list, model: Model):
    """Articulated inertias and bias forces, leaves to root; per joint U, D, 1/D and u.

    The joint terms (symbolic.joints) enter here: the armature adds to D (a rotor inertia
    that only joint k's acceleration drives), damping and friction are subtracted from the
    joint force, u = tau - damping qd - friction sign(qd) - s^T p^A."""
    armature = armatures(model)
    # named once: u and the exact-axis step both read it (and sign(qd) is a call in C)
    force = [rec.name(t - f) for t, f in zip(coords.tau, dissipative_forces(model, coords))]
    IA = [_rigid_inertia(link) for link in links]
    pA = [list(b) for b in bias]
    U: list = [None] * len(links)
    D: list = [None] * len(links)
    Dinv: list = [None] * len(links)
    u: list = [None] * len(links)
    for i in reversed(range(len(links))):
        link = links[i]
        IA[i] = IA[i].named(rec)
        n_i, f_i = rec.named(pA[i][0]), rec.named(pA[i][1])
        Ia = IA[i]
        if link.free:  # a floating root: its 6x6 articulated inertia, factorised
            L, D[i], Dinv[i] = _ldlt(IA[i].matrix(), rec)
            U[i], u[i] = (IA[i], L), (n_i, f_i)
            continue
        if link.k is not None:
            U_n, U_f = IA[i].times(*_joint_motion(link, 1))
            U_n, U_f = rec.named(U_n), rec.named(U_f)
            D[i] = rec.name(_project(link, U_n, U_f) + armature[link.k])
            Dinv[i] = rec.name(1 / D[i])
            u[i] = rec.name(force[link.k] - _project(link, n_i, f_i))
            U[i] = (U_n, U_f)
            if link.parent is None:
                continue
            W_n, W_f = rec.named(scale(Dinv[i], U_n)), rec.named(scale(Dinv[i], U_f))  # U / D
            exact = armature[link.k].is_zero is True  # else s^T U != D: no exact shortcuts
            if exact:
                W_n, W_f = _exact_gain(link, W_n, W_f)
            Ia = Inertia(mat_sub(IA[i].A, outer(W_n, U_n)), mat_sub(IA[i].B, outer(W_n, U_f)),
                         mat_sub(IA[i].C, outer(W_f, U_f)))
            n_a, f_a = add(n_i, scale(u[i], W_n)), add(f_i, scale(u[i], W_f))
            if exact:
                Ia, n_a, f_a = _exact_articulated(link, force[link.k], Ia, n_a, f_a)
            Ia = Ia.named(rec)
            In, If = Ia.times_terms(*c[i])
            n_i, f_i = rec.named((Terms.of(n_a) + In).vec()), rec.named((Terms.of(f_a) + If).vec())
        if link.parent is None:
            continue
        up = _inertia_to_parent(link, Ia, rec)
        IA[link.parent] = IA[link.parent] + up
        f_up = link.to_parent(f_i, rec)
        n_up = rec.named((mat_vec_terms(link.R, n_i) + cross_terms(link.d, f_up)).vec())
        pA[link.parent][0] = add(pA[link.parent][0], n_up)
        pA[link.parent][1] = add(pA[link.parent][1], f_up)
    return U, D, Dinv, u


def _coordinate_axis(link: Link) -> tuple[int, int] | None:
    """(j, sign) when the joint axis is sign * e_j, else None."""
    nonzero = [j for j, a in enumerate(link.axis) if a != 0]
    if len(nonzero) == 1 and abs(link.axis[nonzero[0]]) == 1:
        j = nonzero[0]
        return j, (1 if link.axis[j] > 0 else -1)
    return None


def _exact_gain(link: Link, W_n: Vec3, W_f: Vec3) -> tuple[Vec3, Vec3]:
    """For an axis sign * e_j: s^T W = s^T U / D = 1, so W's component j is sign exactly,
    not the operation D * (1/D). Returns (W_n, W_f) with it put in."""
    found = _coordinate_axis(link)
    if found is None:
        return W_n, W_f
    j, sign = found
    if link.rotates:
        return _with_entry(W_n, j, sp.Integer(sign)), W_f
    return W_n, _with_entry(W_f, j, sp.Integer(sign))


def _exact_articulated(link: Link, tau, Ia: Inertia, n_a: Vec3, f_a: Vec3
                       ) -> tuple[Inertia, Vec3, Vec3]:
    """For an axis sign * e_j, the exact zeros and torque of I^a and p^a: (I^a, n^a, f^a)
    with them put in.

    I^a s = I^A s - U (s^T U) / D = 0, so I^a's row and column along the axis vanish; and
    s^T p^a = s^T p^A + u = tau makes p^a's component j sign * tau (tau: the joint force
    less damping and friction). Left to SymPy these would be x - W_j x computed at run
    time. Both need D = s^T U, i.e. no armature."""
    found = _coordinate_axis(link)
    if found is None:
        return Ia, n_a, f_a
    j, sign = found
    if link.rotates:  # the angular row and column j: A's, and B's row j
        Ia = Inertia(_without_row_and_column(Ia.A, j), _without_row(Ia.B, j), Ia.C)
        return Ia, _with_entry(n_a, j, sign * tau), f_a
    # the linear row and column j: C's, and B's column j
    Ia = Inertia(Ia.A, _without_column(Ia.B, j), _without_row_and_column(Ia.C, j))
    return Ia, n_a, _with_entry(f_a, j, sign * tau)


def _with_entry(v: Vec3, j: int, value: sp.Expr) -> Vec3:
    """v with its entry j replaced by value."""
    return tuple(value if i == j else e for i, e in enumerate(v))


def _without_row(A: Mat3, j: int) -> Mat3:
    """A with its row j exact zeros."""
    return tuple(ZERO if r == j else row for r, row in enumerate(A))


def _without_column(A: Mat3, j: int) -> Mat3:
    """A with its column j exact zeros."""
    return tuple(_with_entry(row, j, sp.S.Zero) for row in A)


def _without_row_and_column(A: Mat3, j: int) -> Mat3:
    return _without_column(_without_row(A, j), j)


def _inertia_to_parent(link: Link, I: Inertia, rec: Recorder) -> Inertia:
    """X^T I X: rotate the blocks into the parent's axes, then shift to O_parent."""
    R = link.R
    A_r = _rotate_inertia(R, I.A, rec)
    B_r = rec.named_rows(mat_mat_T(rec.named_rows(mat_mat(R, I.B)), R))
    C_r = _rotate_inertia(R, I.C, rec)
    d = skew(link.d)
    K = rec.named_rows(mat_mat(B_r, d))
    Q = rec.named_rows(mat_mat(d, C_r))
    # A_r - K - K^T - Q [d], only its upper triangle
    A = _named_symmetric(lambda r, c: A_r[r][c] - K[r][c] - K[c][r]
                         - sum_of_products((Q[r][k], d[k][c]) for k in range(3)), rec)
    return Inertia(A, rec.named_rows(mat_add(B_r, Q)), C_r)


def _acceleration_pass(links: list[Link], coords: CoordinateSymbols, rec: Recorder, c: list,
                       U: list, Dinv: list, u: list, base: Vec3) -> list[sp.Expr]:
    """Spatial accelerations root to leaves, with each joint's qdd on the way."""
    acc: list[tuple[Vec3, Vec3]] = []
    qdd: list[sp.Expr] = [sp.Integer(0)] * len(coords.qd)
    for i, link in enumerate(links):
        if link.parent is None:
            alpha, a = ZERO, link.to_child(base, rec)
        else:
            alpha, a = _motion_to_child(link, *acc[link.parent], rec)
        alpha, a = rec.named(add(alpha, c[i][0])), rec.named(add(a, c[i][1]))
        if link.free:
            # I^A (a' + x) + p^A = tau: the joint's acceleration x = (dw/dt, dv/dt) of the
            # body-frame components, Pinocchio's FreeFlyer acceleration
            (IA, L), (n_A, f_A) = U[i], u[i]
            tau_f, tau_n = free_velocities(link, coords.tau)
            In, If = IA.times(alpha, a)
            x = _ldlt_solve(L, Dinv[i], [*sub(sub(tau_n, n_A), In), *sub(sub(tau_f, f_A), If)],
                            rec)
            qdd[link.k: link.k + 6] = [*x[3:], *x[:3]]
            alpha, a = rec.named(add(alpha, x[:3])), rec.named(add(a, x[3:]))
        elif link.k is not None:
            U_n, U_f = U[i]
            qdd[link.k] = rec.name(Dinv[i] * (u[i] - dot(U_n, alpha) - dot(U_f, a)))
            s_w, s_v = _joint_motion(link, qdd[link.k])
            alpha, a = rec.named(add(alpha, s_w)), rec.named(add(a, s_v))
        acc.append((alpha, a))
    return qdd
