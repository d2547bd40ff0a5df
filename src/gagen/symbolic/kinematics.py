"""Symbolic kinematics of a tree of bodies (the paper's section 2.1, eqs. 1-4).

Every vector of body i is expressed in body i's own frame, built from its parent's by
one joint rotation. Working body by body, instead of multiplying world rotation
matrices, keeps each expression the size of one joint; each component is then named
by an intermediate symbol, so nothing grows with the depth of the tree.

For body i with origin O_i and mass centre C_i, in frame i:
- angular velocity w = sum_r Jw[r] qd_r and angular acceleration alpha = sum_r Jw[r] qdd_r + alpha0;
- velocity of C_i: v_C = sum_r JvC[r] qd_r, acceleration a_C = sum_r JvC[r] qdd_r + aC0.
Jw[r] = d w / d qd_r and JvC[r] = d v_C / d qd_r are the partial angular velocities and
partial velocities of eqs. 7-10; alpha0 and aC0 are the parts of eq. 4 free of qdd.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import TypeVar

import sympy as sp

from ..model.model import Body, Model
from .symbols import Acceleration, Coordinate, Internal, Rate, Torque
from .vec3 import (
    IDENTITY,
    Mat3,
    Vec3,
    add,
    as_mat,
    as_vec,
    expanded,
    mat_mat,
    mat_T_vec,
    mat_vec,
    product,
    scale,
    skew,
    total,
)

Vec = sp.Matrix
T = TypeVar("T")


class Recorder:
    """Names non-trivial subexpressions with intermediate symbols, in order of definition."""

    def __init__(self, prefix: str = "_g"):
        self.prefix = prefix
        self.definitions: list[tuple[Internal, sp.Expr]] = []
        self._by_expr: dict[sp.Expr, Internal] = {}
        self.next_index = 0  # the number of the next name (names are never reused)
        self._cache: dict[Hashable, object] = {}

    def name(self, expr) -> sp.Expr:
        expr = sp.sympify(expr)
        if _is_trivial(expr):
            return expr
        symbol = self._by_expr.get(expr)
        if symbol is None:
            symbol = Internal(f"{self.prefix}{self.next_index}")
            self.next_index += 1
            self.definitions.append((symbol, expr))
            self._by_expr[expr] = symbol
        return symbol

    def vec(self, v) -> Vec:
        return Vec([self.name(e) for e in v])

    def named(self, v) -> tuple[sp.Expr, ...]:
        """Each entry of a vector named, as a tuple (`vec3`'s vectors)."""
        return tuple(self.name(e) for e in v)

    def named_rows(self, A) -> Mat3:
        """Each entry of a 3x3 matrix (rows) named."""
        return tuple(self.named(row) for row in A)

    def cached(self, key: Hashable, compute: Callable[[], T]) -> T:
        """compute(), once per key in this program; later calls return the first result.

        For results that are a function of the key alone (an operation's name and its
        operands, which are named expressions of this program): the recursive passes
        rotate the same vectors and take the same products several times, and building
        them again in SymPy, only to find their names already defined, is most of what a
        repeated step costs."""
        if key not in self._cache:
            self._cache[key] = compute()
        return self._cache[key]


def _is_trivial(expr: sp.Expr) -> bool:
    if expr.is_Atom:
        return True
    # -x and 2*x are as cheap inline as through a name
    return expr.is_Mul and len(expr.args) == 2 and expr.args[0].is_Number and expr.args[1].is_Atom


@dataclass
class CoordinateSymbols:
    """The symbols of q, qd, qdd and tau; each kind is a class of its own (gagen.symbols),
    so none can equal a parameter or another kind whatever the joints are called."""

    q: list[Coordinate]
    qd: list[Rate]
    qdd: list[Acceleration]
    tau: list[Torque]

    @classmethod
    def for_model(cls, model: Model) -> CoordinateSymbols:
        """q has the model's nq configuration entries; qd, qdd, tau its nv coordinates."""
        names = model.coordinates
        return cls(
            q=[Coordinate(n) for n in model.configuration],
            qd=[Rate(f"{n}_d") for n in names],
            qdd=[Acceleration(f"{n}_dd") for n in names],
            tau=[Torque(f"tau_{n}") for n in names],
        )


@dataclass
class BodyKinematics:
    """Kinematic quantities of one body, in its own frame (see module docstring)."""

    body: Body
    Jw: dict[int, Vec] = field(default_factory=dict)
    Jv: dict[int, Vec] = field(default_factory=dict)  # of the origin O_i
    w: Vec = field(default_factory=lambda: sp.zeros(3, 1))
    alpha0: Vec = field(default_factory=lambda: sp.zeros(3, 1))
    a0: Vec = field(default_factory=lambda: sp.zeros(3, 1))  # of the origin O_i
    gravity: Vec = field(default_factory=lambda: sp.zeros(3, 1))
    position: Vec = field(default_factory=lambda: sp.zeros(3, 1))  # of O_i, world origin at 0
    JvC: dict[int, Vec] = field(default_factory=dict)
    aC0: Vec = field(default_factory=lambda: sp.zeros(3, 1))

    def alpha(self, qdd: list[sp.Symbol]) -> Vec:
        return _linear_form(self.Jw, qdd, self.alpha0)

    def a_C(self, qdd: list[sp.Symbol]) -> Vec:
        return _linear_form(self.JvC, qdd, self.aC0)

    def v_C(self, qd: list[sp.Symbol]) -> Vec:
        return _linear_form(self.JvC, qd, sp.zeros(3, 1))


def _linear_form(columns: dict[int, Vec], rates: list[sp.Symbol], constant: Vec) -> Vec:
    out = sp.Matrix(constant)
    for r, col in columns.items():
        out += col * rates[r]
    return out


def unit_axis(axis) -> Vec3:
    """The joint axis divided by its length (a float for a numeric axis)."""
    axis = as_vec(axis)
    norm2 = sp.expand(sum(a * a for a in axis))
    if norm2 == 1:
        return axis
    if norm2.is_Number:
        return scale(1 / sp.Float(float(sp.sqrt(norm2))), axis)
    return scale(1 / sp.sqrt(norm2), axis)


def axis_rotation(axis: Vec3, c: sp.Expr, s: sp.Expr) -> Mat3:
    """Rodrigues' rotation about a unit axis, given cos and sin of the angle:
    c E + s [axis] + (1 - c) axis axis^T, each entry expanded."""
    K = skew(axis)
    return tuple(tuple(expanded(total((product(c, IDENTITY[r][k]), product(s, K[r][k]),
                                       product(1 - c, product(axis[r], axis[k])))))
                       for k in range(3)) for r in range(3))


def joint_transform(joint, q: list, rec: Recorder) -> tuple[Mat3, Vec3]:
    """The parent-frame components of the child's axes, R, and the child's origin in the
    parent's frame, d, at the joint's configuration entries `q` (none for a fixed joint,
    one for a 1-dof joint, 7 for a floating one: position and quaternion x, y, z, w)."""
    R = as_mat(joint.origin_rotation)
    d = as_vec(joint.origin_xyz)
    if joint.floating:  # the joint's origin, then the free motion (Pinocchio's order)
        return (_expanded(mat_mat(R, quaternion_rotation(q[3:7], rec))),
                add(d, mat_vec(R, as_vec(q[:3]))))
    if joint.rotates:
        axis = unit_axis(joint.axis)
        c, s = rec.name(sp.cos(q[0])), rec.name(sp.sin(q[0]))
        R = _expanded(mat_mat(R, axis_rotation(axis, c, s)))
    elif joint.type == "prismatic":
        d = add(d, scale(q[0], mat_vec(R, unit_axis(joint.axis))))
    return R, d


def _expanded(A: Mat3) -> Mat3:
    """Each entry expanded: a product of rotations as sums of products, as before."""
    return tuple(tuple(expanded(e) for e in row) for row in A)


def quaternion_rotation(quaternion, rec: Recorder) -> Mat3:
    """The rotation of a quaternion (x, y, z, w), each entry named. Divided by its squared
    norm, so that any non-zero quaternion gives a rotation (an integrator's drift off the
    unit sphere changes nothing), and a unit one gives Eigen's / Pinocchio's matrix."""
    x, y, z, w = quaternion
    s = rec.name(2 / (x * x + y * y + z * z + w * w))
    xs, ys, zs = rec.name(x * s), rec.name(y * s), rec.name(z * s)
    entries = [[1 - (y * ys + z * zs), x * ys - w * zs, x * zs + w * ys],
               [x * ys + w * zs, 1 - (x * xs + z * zs), y * zs - w * xs],
               [x * zs - w * ys, y * zs + w * xs, 1 - (x * xs + y * ys)]]
    return rec.named_rows(entries)


def derive_kinematics(model: Model, coords: CoordinateSymbols, rec: Recorder) -> list[BodyKinematics]:
    index = model.indices()
    world = BodyKinematics(body=None, gravity=sp.Matrix(model.gravity))
    frames: dict[str, BodyKinematics] = {"world": world}
    out = []
    for body in model.bodies:
        parent = frames[body.parent]
        kin = _child_kinematics(body, parent, index.get(body.name), coords, rec)
        frames[body.name] = kin
        out.append(kin)
    return out


def _child_kinematics(body: Body, parent: BodyKinematics, start: tuple[int, int] | None,
                      coords: CoordinateSymbols, rec: Recorder) -> BodyKinematics:
    joint = body.joint
    iq, iv = start if start is not None else (0, 0)
    R, d = joint_transform(joint, coords.q[iq: iq + joint.nq], rec)
    d, axis = Vec(d), Vec(unit_axis(joint.axis))

    def to_child(v: Vec) -> Vec:
        return Vec(rec.named(mat_T_vec(R, v)))

    kin = BodyKinematics(body=body)
    for r, jw in parent.Jw.items():
        kin.Jw[r] = to_child(jw)
    zero = sp.zeros(3, 1)
    for r in sorted(set(parent.Jv) | set(parent.Jw)):
        kin.Jv[r] = to_child(parent.Jv.get(r, zero) + parent.Jw.get(r, zero).cross(d))
    w_in = to_child(parent.w)  # parent's angular velocity, in this frame
    kin.alpha0 = to_child(parent.alpha0)
    kin.a0 = to_child(parent.a0 + parent.alpha0.cross(d) + parent.w.cross(parent.w.cross(d)))
    kin.gravity = to_child(parent.gravity)
    kin.position = to_child(parent.position + d)
    kin.w = w_in
    if joint.floating:
        # quasi-velocities: the origin's velocity v and the angular velocity w, both in
        # this frame; the acceleration of the origin is then dv/dt + w x v (its components
        # turn with the frame), and the angular acceleration dw/dt
        v, w = sp.Matrix(coords.qd[iv: iv + 3]), sp.Matrix(coords.qd[iv + 3: iv + 6])
        for r in range(3):
            kin.Jv[iv + r] = sp.eye(3)[:, r]
            kin.Jw[iv + 3 + r] = sp.eye(3)[:, r]
        kin.w = w
        kin.a0 = rec.vec(kin.a0 + w.cross(v))
    elif joint.rotates:
        kin.Jw[iv] = axis
        relative = axis * coords.qd[iv]
        kin.w = rec.vec(w_in + relative)
        kin.alpha0 = rec.vec(kin.alpha0 + w_in.cross(relative))
    elif joint.type == "prismatic":
        kin.Jv[iv] = axis
        kin.a0 = rec.vec(kin.a0 + 2 * w_in.cross(axis * coords.qd[iv]))
    c_vec = sp.Matrix(body.com)
    for r in sorted(set(kin.Jv) | set(kin.Jw)):
        jv = kin.Jv.get(r, sp.zeros(3, 1))
        jw = kin.Jw.get(r, sp.zeros(3, 1))
        kin.JvC[r] = rec.vec(jv + jw.cross(c_vec))
    kin.aC0 = rec.vec(kin.a0 + kin.alpha0.cross(c_vec) + kin.w.cross(kin.w.cross(c_vec)))
    return kin
