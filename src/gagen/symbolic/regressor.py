"""The regressor: the inverse dynamics as a linear function of the dynamic parameters.

    tau = Y(q, qd, qdd) pi

The rigid-body inverse dynamics is linear in each moving body's inertial parameters taken
about its frame's origin O: the mass m, the first moment h = m c and the inertia I_O =
I_C + m [c]^T [c] (the Newton-Euler equations about O, `recursive._body_wrench`, are linear
in them, and nothing else in the algorithm depends on them). The joint terms are linear in
damping, friction and armature. So

    pi = (m, h_x, h_y, h_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz  per moving body,
          damping per joint, friction per joint, armature per joint),

the bodies in Pinocchio's convention (`Inertia.toDynamicParameters`); bodies welded by
fixed joints count as one, as Pinocchio's URDF parser merges them (model.merge).

Y is written row by row over the tree, in body frames. Body k's wrench about its origin,
f = m a + alpha x h + w x (w x h) and n = I_O alpha + w x (I_O w) + h x a (w, alpha, a: its
angular velocity, angular acceleration and origin acceleration, gravity included, from the
RNEA's forward pass), is linear in (m, h, I_O). Joint i's torque takes the wrenches of the
bodies k of its subtree carried to its own frame and projected on its axis; the same
number is the wrench of k projected on joint i's axis carried down to k's frame, a motion
vector (sigma_ang, sigma_lin) with tau_i = sigma_ang . n_k + sigma_lin . f_k. Carrying one
6-vector down the tree per (joint, body) pair is far cheaper than carrying ten columns of
wrenches up (the forward-mode derivative of the RNEA by its inertial parameters that an
earlier version took: three times the operations, and most of a 50-link chain's build).
Y depends on q, qd, qdd and the kinematic parameters (lengths, gravity); pi on the inertial
and joint parameters.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import sympy as sp

from ..manifest import regressor_names
from ..model.merge import mass_pieces, merge_fixed_joints
from ..model.model import ZERO3, ZERO33, Model
from .differentiate import needed_definitions, recorder_after
from .joints import jointed
from .kinematics import CoordinateSymbols, Recorder
from .recursive import _angular_velocities, _cross_square, _links, accelerations
from .vec3 import ZERO, Vec3, add, as_vec, cross, dot, unit

# (row, column) of I_O for the last six of a body's ten parameters (Pinocchio's order)
_INERTIA_ENTRIES = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))


@dataclass
class Regressor:
    """Y (n x P, in the named intermediates of `intermediates`), pi (P expressions in the
    model's parameters) and the names of the P columns."""

    matrix: sp.Matrix
    parameters: list[sp.Expr]
    names: list[str]
    intermediates: list[tuple[sp.Symbol, sp.Expr]]


def derive_regressor(model: Model, coords: CoordinateSymbols | None = None,
                     rec: Recorder | None = None) -> Regressor:
    """The regressor of `model` (module docstring). With `rec` (e.g. `recorder_after` of
    derived equations), the program continues it: names it already has are reused, and
    `intermediates` holds its definitions followed by those Y needs."""
    coords = coords or CoordinateSymbols.for_model(model)
    rec = rec or Recorder()
    given = len(rec.definitions)
    pieces = mass_pieces(model)
    links = _bare_links(model, coords, rec)
    w = _angular_velocities(links, coords, rec)
    alpha, acc = accelerations(links, coords, rec, w, coords.qdd, as_vec(model.gravity))
    rigid = sp.zeros(model.dof, 10 * len(links))
    children: list[list[int]] = [[] for _ in links]
    for k, link in enumerate(links):
        if link.parent is not None:
            children[link.parent].append(k)
    for i, link in enumerate(links):
        for row, axis in _joint_axes(link):
            stack = [(i, axis)]
            while stack:  # joint i's axis carried down to every body of its subtree
                k, (ang, lin) = stack.pop()
                columns = _body_columns(ang, lin, w[k], alpha[k], acc[k], rec)
                rigid[row, 10 * k: 10 * k + 10] = sp.Matrix([columns])
                for child in children[k]:
                    c = links[child]
                    stack.append((child, (c.to_child(ang, rec),
                                          c.to_child(add(lin, cross(ang, c.d)), rec))))
    Y = rigid.row_join(_joint_columns(model, coords))
    new = needed_definitions(rec.definitions, list(Y), first=given)
    pi = regressor_parameters(model)
    names = regressor_names([body.name for body, _ in pieces],
                            [joint.name for _, joint in jointed(model)])
    return Regressor(Y, pi, names, rec.definitions[:given] + new)


KINEMATICS_PER_BODY = 24  # R (9, row-major), d, w, alpha, a, the joint axis (3 each)
NO_JOINT, REVOLUTE, PRISMATIC, FLOATING = 0, 1, 2, 3


@dataclass
class RegressorKinematics:
    """What the compiled regressor needs per moving body, in a program of named
    intermediates, and the tree as numbers: the C function (model/regressor.c.j2) runs
    the pair loop of `derive_regressor` over them, so the generated code grows with the
    bodies, not with the (joint, body) pairs.

    `values` holds KINEMATICS_PER_BODY expressions per body, in the order of
    `mass_pieces`: its rotation R (the parent's components of its axes), its origin's
    offset d from the parent's (in the parent's frame), its angular velocity w, angular
    acceleration alpha and origin acceleration a (gravity included), in its own frame, and
    its joint's unit axis. `parents` (-1: the world), `kinds` (NO_JOINT, REVOLUTE,
    PRISMATIC, FLOATING) and `rows` (first velocity coordinate, -1 for none) per body;
    `joint_rows` the velocity coordinate of each 1-dof joint (the joint columns)."""

    values: list[sp.Expr]
    parents: list[int]
    kinds: list[int]
    rows: list[int]
    joint_rows: list[int]
    intermediates: list[tuple[sp.Symbol, sp.Expr]]


def regressor_kinematics(eqs) -> RegressorKinematics:
    """The regressor's per-body kinematics as a continuation of `eqs`'s program."""
    model, coords = eqs.model, eqs.coords
    rec = recorder_after(eqs.intermediates)
    given = len(rec.definitions)
    links = _bare_links(model, coords, rec)
    w = _angular_velocities(links, coords, rec)
    alpha, acc = accelerations(links, coords, rec, w, coords.qdd, as_vec(model.gravity))
    values = []
    for k, link in enumerate(links):
        R = [e for row in link.R for e in row]  # row-major
        values += [*R, *link.d, *w[k], *alpha[k], *acc[k], *link.axis]
    kinds = [NO_JOINT if link.k is None else FLOATING if link.free
             else REVOLUTE if link.rotates else PRISMATIC for link in links]
    new = needed_definitions(rec.definitions, values, first=given)
    return RegressorKinematics(
        values=values,
        parents=[-1 if link.parent is None else link.parent for link in links],
        kinds=kinds,
        rows=[-1 if link.k is None else link.k for link in links],
        joint_rows=[k for k, _ in jointed(model)],
        intermediates=rec.definitions[:given] + new)


def regressor_parameters(model: Model) -> list[sp.Expr]:
    """pi, the regressor's parameters (module docstring), in the model's parameters."""
    return [v for body, parts in mass_pieces(model) for v in body_parameters(parts)] \
        + joint_parameters(model)


def attach_regressor(eqs) -> None:
    """Add the regressor to derived `Equations` (in place): `eqs.regressor`,
    `eqs.regressor_parameters`, and the definitions it adds to `eqs.intermediates` (whose
    names it reuses) as `eqs.regressor_intermediates`."""
    reg = derive_regressor(eqs.model, eqs.coords, recorder_after(eqs.intermediates))
    eqs.regressor_intermediates = reg.intermediates[len(eqs.intermediates):]
    eqs.regressor, eqs.regressor_parameters = reg.matrix, reg.parameters


def with_regressor(eqs):
    """`eqs` if its regressor is attached, else a copy of it with the regressor attached."""
    if eqs.regressor is not None:
        return eqs
    eqs = copy.copy(eqs)
    attach_regressor(eqs)
    return eqs


def _bare_links(model: Model, coords: CoordinateSymbols, rec: Recorder):
    """`recursive`'s links of the model with fixed joints merged away (one per moving
    body, in the order of `mass_pieces`), without mass: only their kinematics is used."""
    merged = merge_fixed_joints(model)
    # without mass, _links names no inertia of its own (zeros are never named)
    bare = Model(name=merged.name, parameters=merged.parameters, gravity=merged.gravity,
                 source=merged.source, bodies=tuple(replace(b, mass=sp.Integer(0), com=ZERO3,
                                                            inertia=ZERO33)
                                                    for b in merged.bodies))
    return _links(bare, coords, rec)


def _joint_axes(link) -> list[tuple[int, tuple[Vec3, Vec3]]]:
    """(row, (sigma_ang, sigma_lin)) per velocity coordinate of a link's joint, in its
    frame: the joint's torque is sigma_ang . N + sigma_lin . F of the wrench (F, N) about
    its origin. A floating joint's six rows are the wrench's components."""
    if link.k is None:
        return []
    if link.free:
        return [(link.k + r, (ZERO, unit(r))) for r in range(3)] + \
            [(link.k + 3 + r, (unit(r), ZERO)) for r in range(3)]
    if link.rotates:
        return [(link.k, (link.axis, ZERO))]
    return [(link.k, (ZERO, link.axis))]


def _body_columns(ang: Vec3, lin: Vec3, w: Vec3, alpha: Vec3, a: Vec3,
                  rec: Recorder) -> list[sp.Expr]:
    """The ten coefficients of (m, h, I_O) in ang . n + lin . f, the body's wrench (f, n)
    about its origin (module docstring), each named."""
    h = rec.named(add(cross(lin, alpha), cross(w, rec.named(cross(w, lin))), cross(a, ang)))
    b = rec.named(cross(ang, w))
    inertia = []
    for r, c in _INERTIA_ENTRIES:
        if r == c:
            inertia.append(ang[r] * alpha[r] + b[r] * w[r])
        else:
            inertia.append(ang[r] * alpha[c] + ang[c] * alpha[r] + b[r] * w[c] + b[c] * w[r])
    return [rec.name(e) for e in [dot(lin, a), *h, *inertia]]


def _joint_columns(model: Model, coords: CoordinateSymbols) -> sp.Matrix:
    """The damping (qd_k), friction (sign qd_k) and armature (qdd_k) columns of each 1-dof
    joint, in the row of its coordinate k."""
    joints = jointed(model)
    m = len(joints)
    columns = sp.zeros(model.dof, 3 * m)
    for j, (k, _) in enumerate(joints):
        columns[k, j] = coords.qd[k]
        columns[k, m + j] = sp.sign(coords.qd[k])
        columns[k, 2 * m + j] = coords.qdd[k]
    return columns


def body_parameters(parts) -> list[sp.Expr]:
    """(m, h, I_O) of rigidly joined pieces (mass, mass centre, central inertia) in one
    frame, in Pinocchio's order: sums, no division by the total mass (which may be 0)."""
    m, h, I_O = sp.Integer(0), sp.zeros(3, 1), sp.zeros(3, 3)
    for mass, com, inertia in parts:
        c = sp.Matrix(com)
        m += mass
        h += mass * c
        I_O += sp.Matrix(inertia) + mass * sp.Matrix(_cross_square(c))
    return [m, *h, *(I_O[r, c] for r, c in _INERTIA_ENTRIES)]


def joint_parameters(model: Model) -> list[sp.Expr]:
    """damping per 1-dof joint, then friction, then armature."""
    joints = [joint for _, joint in jointed(model)]
    return [sp.sympify(getattr(joint, key)) for key in ("damping", "friction", "armature")
            for joint in joints]
