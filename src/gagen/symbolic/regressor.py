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

Y is derived, not written down: the recursive Newton-Euler algorithm of `recursive` runs
with fresh symbols for every body's (m, h, I_O), and `differentiate` takes its
derivatives with respect to them through the named intermediates. Y depends on q, qd, qdd
and the kinematic parameters (lengths, gravity); pi on the inertial and joint parameters.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import sympy as sp

from ..manifest import regressor_names
from ..model.merge import mass_pieces, merge_fixed_joints
from ..model.model import ZERO3, ZERO33, Model
from .differentiate import differentiate, needed_definitions, recorder_after
from .joints import jointed
from .kinematics import CoordinateSymbols, Recorder
from .recursive import _angular_velocities, _cross_square, _links, _rnea
from .symbols import Internal

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
    symbols = [[Internal(f"_pi{10 * i + j}") for j in range(10)] for i in range(len(pieces))]
    links = _symbolic_links(model, coords, rec, symbols)
    w = _angular_velocities(links, coords, rec)
    tau = _rnea(links, coords, rec, w, coords.qdd, sp.Matrix(model.gravity))
    flat = [s for body in symbols for s in body]
    rigid = differentiate(rec.definitions, tau, flat, rec)
    Y = sp.Matrix(rigid).row_join(_joint_columns(model, coords))
    new = needed_definitions(rec.definitions, list(Y), first=given)
    leaked = set(flat) & set().union(*(e.free_symbols for _, e in new), *(e.free_symbols for e in Y))
    if leaked:
        raise RuntimeError("internal error: the regressor depends on the inertial parameters")
    pi = [v for body, parts in pieces for v in body_parameters(parts)] + joint_parameters(model)
    names = regressor_names([body.name for body, _ in pieces],
                            [joint.name for _, joint in jointed(model)])
    return Regressor(Y, pi, names, rec.definitions[:given] + new)


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


def _symbolic_links(model: Model, coords: CoordinateSymbols, rec: Recorder, symbols):
    """`recursive`'s links of the model with fixed joints merged away, each moving body's
    (m, h, I_O) replaced by its ten symbols."""
    merged = merge_fixed_joints(model)
    # without mass, _links names no inertia of its own (zeros are never named)
    bare = Model(name=merged.name, parameters=merged.parameters, gravity=merged.gravity,
                 source=merged.source, bodies=tuple(replace(b, mass=sp.Integer(0), com=ZERO3,
                                                            inertia=ZERO33)
                                                    for b in merged.bodies))
    links = []
    for link, s in zip(_links(bare, coords, rec), symbols):
        I_O = sp.zeros(3, 3)
        for (r, c), value in zip(_INERTIA_ENTRIES, s[4:]):
            I_O[r, c] = I_O[c, r] = value
        links.append(replace(link, mass=s[0], h=sp.Matrix(s[1:4]), I_O=I_O))
    return links


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
        I_O += sp.Matrix(inertia) + mass * _cross_square(c)
    return [m, *h, *(I_O[r, c] for r, c in _INERTIA_ENTRIES)]


def joint_parameters(model: Model) -> list[sp.Expr]:
    """damping per 1-dof joint, then friction, then armature."""
    joints = [joint for _, joint in jointed(model)]
    return [sp.sympify(getattr(joint, key)) for key in ("damping", "friction", "armature")
            for joint in joints]
