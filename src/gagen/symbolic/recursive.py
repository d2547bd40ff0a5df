"""The equations of motion by recursive algorithms over the tree (Newton-Euler and CRBA).

`derive_recursive(model)` returns the same `Equations` as `gibbs_appell.derive`, with the
same symbols, but builds them the way numerical dynamics libraries compute them:

- the recursive Newton-Euler algorithm (RNEA) for the inverse dynamics, the velocity
  terms b(q, qd) (qdd = 0, no gravity) and the gravity forces (q alone);
- the composite-rigid-body algorithm (CRBA) for the mass matrix M(q).

Every vector is expressed in its body's own frame (as in `kinematics`), and every
component of every per-body quantity is named by an intermediate symbol, so each
definition is a few operations whatever the depth of the tree: the RNEA is O(n)
definitions and the CRBA O(n * depth), one short expression per entry of M.

Conventions (those of `kinematics`): body i's frame is its joint frame; the joint origin
(translation d and rotation R0, in the parent's frame) places it, then the joint rotates
by q about its unit axis s (R = R0 Rot(s, q)) or slides by q along it (d + R0 s q). A
vector v of the parent's frame is R^T v in the child's. Spatial quantities are taken
about the body frame's origin O_i: a body's inertia there is (m, h = m c, I_O) with
I_O = I_C + m [c]^T [c] (parallel axes). Gravity enters the RNEA as an acceleration
-g of the world frame.

The inverse dynamics is its own full RNEA pass (velocities, qdd and gravity together), so
the generated inverse_dynamics needs no M, b or g; the three passes share the joint
transforms and the angular velocities. Forward dynamics is still M \\ forcing (the
codegen's unrolled LDL^T); an articulated-body pass would be the next step.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import sympy as sp

from ..model.model import Body, Model
from .gibbs_appell import Equations
from .joints import add_joint_terms
from .kinematics import CoordinateSymbols, Recorder, joint_transform, unit_axis
from .vec3 import (
    IDENTITY,
    ZERO,
    Mat3,
    Terms,
    Vec3,
    add,
    as_mat,
    as_vec,
    cross,
    cross_terms,
    dot,
    expanded,
    is_zero,
    mat_add,
    mat_mat,
    mat_neg,
    mat_scale,
    mat_T_vec,
    mat_vec,
    mat_vec_terms,
    neg,
    outer,
    scale,
    scale_terms,
    skew,
    unit,
)


@dataclass
class Link:
    """One body of the tree with its joint's transform from the parent, named once."""

    body: Body
    parent: int | None          # index into the list of links, None for the world
    k: int | None               # first velocity coordinate, None for a fixed joint
    rotates: bool
    axis: Vec3                  # unit joint axis s, in this body's frame
    R: Mat3                     # parent-frame components of this frame's axes
    d: Vec3                     # O_i - O_parent, in the parent's frame
    mass: sp.Expr
    h: Vec3                     # first moment m c about O_i
    I_O: Mat3                   # inertia about O_i
    free: bool = False          # a floating joint: six velocity coordinates k ... k + 5,
    #                             the origin's velocity and the angular velocity in frame i

    def to_child(self, v: Vec3, rec: Recorder) -> Vec3:
        """R^T v, named: a vector of the parent's frame in this one (computed once per
        vector: every pass of the RNEA turns the parent's angular velocity)."""
        v = tuple(v)
        return rec.cached(("R^T v", self.R, v), lambda: rec.named(
            mat_T_vec(self.R, _name_shared(v, [_nonzeros(row) for row in self.R], rec))))

    def to_parent(self, v: Vec3, rec: Recorder) -> Vec3:
        """R v, named: a vector of this frame in the parent's."""
        v = tuple(v)
        return rec.cached(("R v", self.R, v), lambda: rec.named(
            mat_vec(self.R, _name_shared(v, [_nonzeros(col) for col in zip(*self.R)], rec))))


def _name_shared(v: Vec3, uses: list[int], rec: Recorder) -> Vec3:
    """v with the entries that more than one product reads (uses[k] of them read v[k])
    named: an unnamed sum would be written out again in each product that reads it (and
    a float coefficient distributed over its terms)."""
    return tuple(rec.name(e) if n > 1 else e for e, n in zip(v, uses))


def _nonzeros(entries) -> int:
    return sum(1 for e in entries if not is_zero(e))


def derive_recursive(model: Model) -> Equations:
    """The equations of motion of a model by the RNEA and the CRBA (see module docstring)."""
    start = time.perf_counter()
    coords = CoordinateSymbols.for_model(model)
    rec = Recorder()
    links = _links(model, coords, rec)
    gravity = as_vec(model.gravity)
    w = _angular_velocities(links, coords, rec)
    inverse = sp.Matrix(_rnea(links, coords, rec, w, coords.qdd, gravity))
    # b - Qg in one pass (velocities and gravity, no qdd): the forcing is tau minus it
    nonlinear = sp.Matrix(_rnea(links, coords, rec, w, None, gravity))
    b = sp.Matrix(_rnea(links, coords, rec, w, None, None))
    Qg = -sp.Matrix(_rnea(links, coords, rec, None, None, gravity))
    M = _crba(links, model.dof, rec)
    tau = sp.Matrix(coords.tau)
    T, V = _energies(links, coords, rec, w, gravity)
    eqs = Equations(
        model=model,
        coords=coords,
        parameters=[sp.Symbol(k) for k in model.parameters],
        intermediates=rec.definitions,
        gibbs=[],  # no Gibbs function here; nothing downstream of derive() reads it
        mass_matrix=M,
        velocity_terms=b,
        gravity_forces=Qg,
        forcing=tau - nonlinear,
        inverse_dynamics=inverse,
        kinetic_energy=T,
        potential_energy=V,
        derivation="recursive",
    )
    add_joint_terms(eqs)
    eqs.seconds = time.perf_counter() - start
    return eqs


def _links(model: Model, coords: CoordinateSymbols, rec: Recorder) -> list[Link]:
    """The joint transforms and the inertias about the frame origins, parents first."""
    position = {b.name: i for i, b in enumerate(model.bodies)}
    index = model.indices()
    links = []
    for body in model.bodies:
        joint = body.joint
        iq, iv = index.get(body.name, (0, None))
        R, d = joint_transform(joint, coords.q[iq: iq + joint.nq], rec)
        m = sp.sympify(body.mass)
        c_vec = as_vec(body.com)
        links.append(Link(
            body=body,
            parent=position.get(body.parent),
            k=iv,
            rotates=joint.rotates,
            axis=unit_axis(joint.axis),
            R=rec.named_rows(R),
            d=rec.named(d),
            mass=m,
            h=rec.named(scale(m, c_vec)),
            I_O=_symmetric(mat_add(as_mat(body.inertia), mat_scale(m, _cross_square(c_vec))),
                           rec),
            free=joint.floating,
        ))
    return links


def free_velocities(link: Link, rates: list) -> tuple[Vec3, Vec3]:
    """A floating joint's coordinates as (linear, angular) 3-vectors (rates or torques)."""
    return tuple(rates[link.k: link.k + 3]), tuple(rates[link.k + 3: link.k + 6])


def _cross_square(c: Vec3) -> Mat3:
    """[c]^T [c] = (c.c) E - c c^T: the parallel-axes term per unit mass."""
    A = mat_add(mat_scale(dot(c, c), IDENTITY), mat_neg(outer(c, c)))
    return tuple(tuple(expanded(e) for e in row) for row in A)


def _symmetric(A: Mat3, rec: Recorder) -> Mat3:
    """A symmetric matrix with its 6 distinct entries (the upper triangle's) named."""
    return _named_symmetric(lambda r, c: A[r][c], rec)


def _named_symmetric(entry: Callable[[int, int], sp.Expr], rec: Recorder) -> Mat3:
    """The symmetric matrix whose upper-triangle entries (r <= c) are entry(r, c),
    expanded and named row by row; the lower triangle is never computed."""
    upper = {(r, c): rec.name(expanded(entry(r, c))) for r in range(3) for c in range(r, 3)}
    return tuple(tuple(upper[min(r, c), max(r, c)] for c in range(3)) for r in range(3))


def _angular_velocities(links: list[Link], coords: CoordinateSymbols,
                        rec: Recorder) -> list[Vec3]:
    """w_i = R^T w_parent (+ s qd_i for a rotating joint), in each body's frame."""
    w: list[Vec3] = []
    for link in links:
        w_in = ZERO if link.parent is None else link.to_child(w[link.parent], rec)
        if link.free:
            w_in = free_velocities(link, coords.qd)[1]
        elif link.rotates:
            w_in = rec.named(add(w_in, scale(coords.qd[link.k], link.axis)))
        w.append(w_in)
    return w


def _rnea(links: list[Link], coords: CoordinateSymbols, rec: Recorder,
          w: list[Vec3] | None, qdd: list | None, gravity: Vec3 | None) -> list[sp.Expr]:
    """The joint forces of the recursive Newton-Euler algorithm.

    Velocities w (None: at rest), accelerations qdd (None: zero) and gravity (None: none)
    each enter only when given, so the same pass yields the inverse dynamics, the velocity
    terms and the gravity forces. Forward: accelerations of each frame origin; backward:
    the force F and moment N (about O_i) that the parent exerts through joint i.
    """
    alpha, acc = accelerations(links, coords, rec, w, qdd, gravity)
    # the wrenches, as terms until all children have added theirs
    F: list[Terms] = []
    N: list[Terms] = []
    for i, link in enumerate(links):
        f, n = _body_wrench(link, alpha[i], acc[i], None if w is None else w[i], rec)
        F.append(Terms.of(f))
        N.append(Terms.of(n))
    tau: list[sp.Expr] = [sp.Integer(0)] * len(coords.qd)
    for i in reversed(range(len(links))):
        link = links[i]
        f, n = rec.named(F[i].vec()), rec.named(N[i].vec())
        if link.free:  # the wrench on the body: force, then moment about its origin
            tau[link.k: link.k + 6] = [*f, *n]
        elif link.k is not None:
            tau[link.k] = rec.name(dot(link.axis, n if link.rotates else f))
        if link.parent is not None:
            f_up = link.to_parent(f, rec)
            F[link.parent] += Terms.of(f_up)
            N[link.parent] += Terms.of(link.to_parent(n, rec)) + cross_terms(link.d, f_up)
    return tau


def accelerations(links: list[Link], coords: CoordinateSymbols, rec: Recorder,
                  w: list[Vec3] | None, qdd: list | None, gravity: Vec3 | None
                  ) -> tuple[list[Vec3], list[Vec3]]:
    """The RNEA's forward pass: each body's angular acceleration and the acceleration of
    its frame origin (gravity entering as an acceleration -g of the world), in its frame."""
    base = ZERO if gravity is None else neg(gravity)
    alpha: list[Vec3] = []
    acc: list[Vec3] = []
    for i, link in enumerate(links):
        alpha_p, a_p = _parent_accelerations(link, alpha, acc, w, base, rec)
        alpha_in, a_in = Terms.of(alpha_p), Terms.of(a_p)
        w_in = None
        if w is not None and link.parent is not None:
            w_in = link.to_child(w[link.parent], rec)
        s = link.axis
        if link.free:
            v_lin, _ = free_velocities(link, coords.qd)
            if qdd is not None:
                a_lin, a_ang = free_velocities(link, qdd)
                alpha_in, a_in = alpha_in + Terms.of(a_ang), a_in + Terms.of(a_lin)
            if w is not None:  # the origin's acceleration: d/dt of v's components + w x v
                a_in += cross_terms(w[i], v_lin)
        elif link.k is not None and link.rotates:
            if qdd is not None:
                alpha_in += scale_terms(qdd[link.k], s)
            if w_in is not None:
                alpha_in += Terms.of(_joint_bias(w_in, s, coords.qd[link.k], rec))
        elif link.k is not None:
            if qdd is not None:
                a_in += scale_terms(qdd[link.k], s)
            if w_in is not None:
                a_in += scale_terms(2, _joint_bias(w_in, s, coords.qd[link.k], rec))
        alpha.append(rec.named(alpha_in.vec()))
        acc.append(rec.named(a_in.vec()))
    return alpha, acc


def _joint_bias(w_in: Vec3, s: Vec3, qd: sp.Expr, rec: Recorder) -> Vec3:
    """w_in x (s qd): the acceleration a joint's rate adds as the parent turns (the same
    in every pass with velocities)."""
    return rec.cached(("w x s qd", w_in, s, qd), lambda: cross(w_in, scale(qd, s)))


def _parent_accelerations(link: Link, alpha: list[Vec3], acc: list[Vec3],
                          w: list[Vec3] | None, base: Vec3, rec: Recorder
                          ) -> tuple[Vec3, Vec3]:
    """The parent's angular acceleration and the acceleration of the point O_i of the
    parent, both in this body's frame (before the joint's own contribution)."""
    if link.parent is None:
        return ZERO, link.to_child(base, rec)
    p = link.parent
    a = Terms.of(acc[p]) + cross_terms(alpha[p], link.d)
    if w is not None:  # the same in every pass with velocities
        a += rec.cached(("w x (w x d)", w[p], link.d),
                        lambda: cross_terms(w[p], rec.named(cross(w[p], link.d))))
    return link.to_child(alpha[p], rec), link.to_child(a.vec(), rec)


def _body_wrench(link: Link, alpha: Vec3, a: Vec3, w: Vec3 | None,
                 rec: Recorder) -> tuple[Vec3, Vec3]:
    """The rate of change of a body's momentum: force and moment about O_i.

    f = m a_O + alpha x h + w x (w x h);  n = I_O alpha + w x I_O w + h x a_O.
    """
    f = scale_terms(link.mass, a) + cross_terms(alpha, link.h)
    n = mat_vec_terms(link.I_O, alpha) + cross_terms(link.h, a)
    if w is not None and not all(is_zero(e) for e in w):  # not at rest
        f_w, n_w = rec.cached(("w x (w x h), w x I_O w", w, link.h, link.I_O),
                              lambda: _velocity_wrench(link, w, rec))
        f, n = f + f_w, n + n_w
    return rec.named(f.vec()), rec.named(n.vec())


def _velocity_wrench(link: Link, w: Vec3, rec: Recorder) -> tuple[Terms, Terms]:
    """The terms of a body's momentum rate due to its angular velocity alone (the same in
    every pass with velocities): w x (w x h) and w x I_O w."""
    return (cross_terms(w, rec.named(cross(w, link.h))),
            cross_terms(w, rec.named(mat_vec(link.I_O, w))))


def composite_inertias(links: list[Link], rec: Recorder) -> list[tuple]:
    """Per link, its subtree's (mass, first moment, inertia about O_i) in its own frame, each
    named: the CRBA's backward pass, each body's gathering its children's, moved into its
    frame (also the centroidal map's)."""
    mass = [link.mass for link in links]
    h = [link.h for link in links]
    I_O = [link.I_O for link in links]
    for i in reversed(range(len(links))):
        link = links[i]
        mass[i] = rec.name(mass[i])
        h[i] = rec.named(h[i])
        I_O[i] = _symmetric(I_O[i], rec)
        p = link.parent
        if p is None:
            continue
        h_up = link.to_parent(h[i], rec)
        I_up = _rotate_inertia(link.R, I_O[i], rec)
        d = skew(link.d)
        mass[p] = mass[p] + mass[i]
        h[p] = add(h[p], h_up, scale(mass[i], link.d))
        # inertia about O_p: I - [h][d] - [d][h] - m [d][d], with h about O_i in p's frame
        H = skew(h_up)
        I_O[p] = mat_add(I_O[p], I_up, mat_neg(mat_mat(H, d)), mat_neg(mat_mat(d, H)),
                         mat_neg(mat_mat(mat_scale(mass[i], d), d)))
    return list(zip(mass, h, I_O))


def _crba(links: list[Link], n: int, rec: Recorder) -> sp.Matrix:
    """The mass matrix by the composite-rigid-body algorithm.

    Backward, each body's composite inertia (mass, first moment, inertia about O_i) gathers
    its children's, moved into its frame. Then for each joint i the composite's momentum
    for a unit rate of joint i (a spatial force) is carried to each ancestor joint j, where
    its projection on j's axis is M_ij. (Expressing every inertia and motion subspace once
    in a common frame, so that M_ij is one 6-dot product, measured slower: the local
    frames keep the joints' sparse rotations, and Talos's M took 4.2 us instead of 2.3.)
    """
    mass, h, I_O = zip(*composite_inertias(links, rec))
    M = sp.zeros(n, n)
    for i, link in enumerate(links):
        for column, (f, m_) in _unit_momenta(link, mass[i], h[i], I_O[i], rec):
            for row, value in _projections(link, f, m_, rec):
                if row >= column:
                    M[row, column] = M[column, row] = value
            j, child = link.parent, link
            while j is not None:
                f_up = child.to_parent(f, rec)
                m_ = rec.named((mat_vec_terms(child.R, m_) + cross_terms(child.d, f_up)).vec())
                f = f_up
                ancestor = links[j]
                for row, value in _projections(ancestor, f, m_, rec):
                    M[row, column] = M[column, row] = value
                j, child = ancestor.parent, ancestor
    return M


def _unit_momenta(link: Link, mass, h: Vec3, I_O: Mat3, rec: Recorder):
    """(coordinate, (force, moment)): the momentum of the composite body at O_i for a unit
    rate of each of the joint's coordinates: P = m v + w x h, L = I_O w + h x v."""
    if link.k is None:
        return []
    if link.free:
        linear = [(link.k + r, (rec.named(scale(mass, unit(r))), rec.named(cross(h, unit(r)))))
                  for r in range(3)]
        angular = [(link.k + 3 + r, (rec.named(cross(unit(r), h)),
                                     rec.named(mat_vec(I_O, unit(r)))))
                   for r in range(3)]
        return linear + angular
    s = link.axis
    if link.rotates:
        return [(link.k, (rec.named(cross(s, h)), rec.named(mat_vec(I_O, s))))]
    return [(link.k, (rec.named(scale(mass, s)), rec.named(cross(h, s))))]


def _projections(link: Link, f: Vec3, m_: Vec3, rec: Recorder) -> list[tuple[int, sp.Expr]]:
    """(coordinate, value): a spatial force projected on each of a joint's coordinates."""
    if link.k is None:
        return []
    if link.free:
        return [(link.k + r, rec.name(e)) for r, e in enumerate([*f, *m_])]
    return [(link.k, rec.name(dot(link.axis, m_ if link.rotates else f)))]


def _rotate_inertia(R: Mat3, I: Mat3, rec: Recorder) -> Mat3:
    """R I R^T, named: a child's inertia in its parent's axes."""
    RI = rec.named_rows(mat_mat(R, I))
    return _named_symmetric(lambda r, c: dot(RI[r], R[c]), rec)


def _energies(links: list[Link], coords: CoordinateSymbols, rec: Recorder, w: list[Vec3],
              gravity: Vec3) -> tuple[sp.Expr, sp.Expr]:
    """Kinetic and potential energy, body by body in body frames.

    T_i = 1/2 m v_O.v_O + v_O.(w x h) + 1/2 w.I_O w; V_i = -g_i.(m p_i + h), where p_i is
    the world origin's offset to O_i and g_i gravity, both in frame i.
    """
    T, V = sp.Integer(0), sp.Integer(0)
    v: list[Vec3] = []
    p: list[Vec3] = []
    g: list[Vec3] = []
    for i, link in enumerate(links):
        if link.parent is None:
            v_in, p_in, g_in = ZERO, link.to_child(link.d, rec), link.to_child(gravity, rec)
        else:
            j = link.parent
            v_in = link.to_child(add(v[j], cross(w[j], link.d)), rec)
            p_in = link.to_child(add(p[j], link.d), rec)
            g_in = link.to_child(g[j], rec)
        if link.free:
            v_in = free_velocities(link, coords.qd)[0]
        elif link.k is not None and not link.rotates:
            v_in = rec.named(add(v_in, scale(coords.qd[link.k], link.axis)))
        v.append(v_in)
        p.append(p_in)
        g.append(g_in)
        wi = w[i]
        T_i = link.mass * dot(v_in, v_in) / 2 + dot(v_in, cross(wi, link.h)) \
            + dot(wi, mat_vec(link.I_O, wi)) / 2
        T += rec.name(T_i)
        V += rec.name(-dot(g_in, add(scale(link.mass, p_in), link.h)))
    return T, V
