"""The Gibbs function and the Gibbs-Appell equations (the paper's eqs. 5-10).

S_i = 1/2 m_i a_Ci.a_Ci + 1/2 alpha_i.I_i.alpha_i + alpha_i.(w_i x I_i.w_i)        (eq. 5)
dS/dqdd_r = Q_r                                                                     (eq. 6)

S is quadratic in the accelerations qdd, so differentiating it once gives
dS/dqdd = M(q) qdd + b(q, qd): M is the derivative of that again, and b is its value
at qdd = 0. The differentiation runs over S in its structured form (the accelerations as
linear forms whose coefficients are named intermediates), so S is never expanded.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import sympy as sp

from ..model.model import Model
from .joints import add_joint_terms
from .kinematics import (
    BodyKinematics,
    CoordinateSymbols,
    Recorder,
    axis_rotation,
    derive_kinematics,
    unit_axis,
)


@dataclass
class Equations:
    """The equations of motion of a model, as SymPy expressions.

    Expressions refer to the coordinate symbols (q, qd, qdd, tau), the parameter symbols
    and the intermediate symbols of `intermediates`, each defined in terms of earlier ones.
    Use `explicit()` to substitute the intermediates away (only sensible for small models).
    """

    model: Model
    coords: CoordinateSymbols
    parameters: list[sp.Symbol]
    intermediates: list[tuple[sp.Symbol, sp.Expr]]
    gibbs: list[sp.Expr]                  # S_i per moving-or-fixed body (eq. 5)
    mass_matrix: sp.Matrix                # M(q), symmetric, with the joints' armatures
    velocity_terms: sp.Matrix             # b(q, qd) = dS/dqdd at qdd = 0 (rigid bodies)
    gravity_forces: sp.Matrix             # generalized active forces of gravity
    forcing: sp.Matrix                    # tau + gravity_forces - b - joint damping and
                                          # friction (symbolic.joints): M qdd = forcing
    inverse_dynamics: sp.Matrix           # tau = dS/dqdd - gravity_forces + joint terms
    kinetic_energy: sp.Expr
    potential_energy: sp.Expr
    kinematics: list[BodyKinematics] = field(repr=False, default_factory=list)
    seconds: float = 0.0
    # qdd by the articulated-body algorithm (symbolic/aba.py), when the derivation wrote it;
    # else forward dynamics is M \\ forcing. `pivots` are its D_k = s^T I^A s, positive
    # exactly when M is positive definite.
    forward_dynamics: sp.Matrix | None = None
    pivots: list[sp.Expr] | None = None
    derivation: str = "gibbs-appell"  # or "recursive" (symbolic/derivation.py)
    # where the bodies are in the world and the frames on their bodies (symbolic/frames.py)
    placements: list[sp.Expr] | None = None
    joint_transforms: list[sp.Expr] | None = None
    frame_offsets: list[sp.Expr] | None = None
    # per constrained frame its pose, motion and Jacobian columns (symbolic/frames.py)
    constraint_frames: list[sp.Expr] | None = None
    # Y(q, qd, qdd) with inverse_dynamics = Y pi, and pi in the parameters
    # (symbolic.regressor.attach_regressor; None until attached). Y is written in
    # `intermediates` followed by `regressor_intermediates`: a program of its own, so that
    # the dynamics' outputs and their CSE do not change with it.
    regressor: sp.Matrix | None = field(repr=False, default=None)
    regressor_parameters: list[sp.Expr] | None = field(repr=False, default=None)
    regressor_intermediates: list[tuple[sp.Symbol, sp.Expr]] = field(repr=False,
                                                                     default_factory=list)

    @property
    def n(self) -> int:
        """The number of velocity coordinates (nv): the size of qd, qdd, tau and M."""
        return len(self.coords.qd)

    @property
    def nq(self) -> int:
        """The number of configuration entries: the size of q (n, plus one per floating
        joint: its quaternion has four entries for three velocities)."""
        return len(self.coords.q)

    def substitutions(self) -> dict[sp.Symbol, sp.Expr]:
        subs: dict[sp.Symbol, sp.Expr] = {}
        for symbol, expr in self.intermediates:
            subs[symbol] = expr.xreplace(subs)
        return subs

    def explicit(self, expr):
        """The expression with every intermediate symbol replaced by its definition."""
        return expr.xreplace(self.substitutions())

    def outputs(self) -> dict[str, list[sp.Expr]]:
        """Every output, flattened: the lower triangle of M row by row, then vectors."""
        n = self.n
        outputs = {
            "mass_matrix": [self.mass_matrix[r, s] for r in range(n) for s in range(r + 1)],
            "forcing": list(self.forcing),
            "inverse_dynamics": list(self.inverse_dynamics),
            "gravity": [-g for g in self.gravity_forces],
            "energy": [self.kinetic_energy, self.potential_energy],
        }
        if self.forward_dynamics is not None:
            outputs["forward_dynamics"] = list(self.forward_dynamics)
            outputs["pivots"] = list(self.pivots)
        if self.placements is not None:
            outputs["placements"] = list(self.placements)
            outputs["joint_transforms"] = list(self.joint_transforms)
            outputs["frame_offsets"] = list(self.frame_offsets)
        if self.constraint_frames is not None:
            outputs["constraint_frames"] = list(self.constraint_frames)
        return outputs

    def regressor_outputs(self) -> dict[str, list[sp.Expr]]:
        """Y row by row and pi (the regressor must be attached); written in
        `intermediates + regressor_intermediates`."""
        if self.regressor is None:
            raise ValueError("no regressor attached (symbolic.regressor.attach_regressor)")
        return {"regressor": list(self.regressor),  # row-major
                "regressor_parameters": list(self.regressor_parameters)}


def derive(model: Model) -> Equations:
    """Derive the Gibbs-Appell equations of motion of a model."""
    start = time.perf_counter()
    coords = CoordinateSymbols.for_model(model)
    rec = Recorder()
    kinematics = derive_kinematics(model, coords, rec)
    n = model.dof
    qdd = coords.qdd
    gibbs = [gibbs_function(kin, qdd, rec) for kin in kinematics]

    dS = [sp.Integer(0)] * n   # dS/dqdd_r, with qdd still symbolic
    M = sp.zeros(n, n)
    b = sp.zeros(n, 1)
    zero_qdd = {a: sp.Integer(0) for a in qdd}
    for kin, S in zip(kinematics, gibbs):
        rows = sorted(kin.JvC)
        for r in rows:
            dS_r = sp.diff(S, qdd[r])
            dS[r] += dS_r
            b[r] += dS_r.xreplace(zero_qdd)
            for s in rows:
                if s <= r:
                    M[r, s] += sp.diff(dS_r, qdd[s])
    for r in range(n):
        for s in range(r):
            M[s, r] = M[r, s]
    Qg = gravity_forces(kinematics, n)
    tau = sp.Matrix(coords.tau)
    eqs = Equations(
        model=model,
        coords=coords,
        parameters=[sp.Symbol(k) for k in model.parameters],
        intermediates=rec.definitions,
        gibbs=gibbs,
        mass_matrix=M,
        velocity_terms=b,
        gravity_forces=Qg,
        forcing=tau + Qg - b,
        inverse_dynamics=sp.Matrix(dS) - Qg,
        kinetic_energy=kinetic_energy(kinematics, coords, rec),
        potential_energy=potential_energy(kinematics),
        kinematics=kinematics,
    )
    add_joint_terms(eqs)
    eqs.seconds = time.perf_counter() - start
    return eqs


def gibbs_function(kin: BodyKinematics, qdd: list[sp.Symbol], rec: Recorder) -> sp.Expr:
    """Eq. 5 for one body, with its accelerations as linear forms in qdd."""
    body = kin.body
    m, I = body.mass, sp.Matrix(body.inertia)
    a_C = kin.a_C(qdd)
    alpha = kin.alpha(qdd)
    gyroscopic = rec.vec(kin.w.cross(rec.vec(I * kin.w)))  # w x I w: free of qdd
    return (m * a_C.dot(a_C) / 2 + alpha.dot(I * alpha) / 2 + alpha.dot(gyroscopic))


def gravity_forces(kinematics: list[BodyKinematics], n: int) -> sp.Matrix:
    """Eqs. 7-10 for gravity: Q_r = sum_i dv_Ci/dqd_r . m_i g."""
    Q = sp.zeros(n, 1)
    for kin in kinematics:
        weight = kin.body.mass * kin.gravity
        for r, col in kin.JvC.items():
            Q[r] += col.dot(weight)
    return Q


def joint_torque_forces(model: Model, kinematics: list[BodyKinematics],
                        coords: CoordinateSymbols) -> sp.Matrix:
    """Eqs. 7-10 for the joint couples and forces, as the paper sums them.

    Joint k applies +tau_k along its axis to its child and -tau_k to its parent (action
    and reaction, at the same point for a prismatic joint). Projected on the partial
    (angular) velocities of both bodies this reduces to Q_r = tau_r, which is what
    `derive` uses for the forcing; the test-suite checks the reduction.
    """
    n = model.dof
    by_name = {kin.body.name: kin for kin in kinematics}
    index = model.indices()
    zero = sp.zeros(3, 1)
    Q = sp.zeros(n, 1)
    for body in model.moving_bodies:
        iq, k = index[body.name]
        child = by_name[body.name]
        parent = by_name.get(body.parent)
        if body.joint.floating:
            # the wrench (force at the origin, moment) on the body, in its frame; its
            # reaction acts on the world, which does not move
            force, moment = sp.Matrix(coords.tau[k: k + 3]), sp.Matrix(coords.tau[k + 3: k + 6])
            for r in range(n):
                Q[r] += child.Jv.get(r, zero).dot(force) + child.Jw.get(r, zero).dot(moment)
            continue
        axis = sp.Matrix(unit_axis(body.joint.axis))
        R = sp.Matrix(body.joint.origin_rotation)
        d = sp.Matrix(body.joint.origin_xyz)
        if body.joint.rotates:
            R = R * sp.Matrix(axis_rotation(axis, sp.cos(coords.q[iq]), sp.sin(coords.q[iq])))
        else:
            d = d + R * axis * coords.q[iq]
        action = axis * coords.tau[k]          # in the child's frame
        reaction = -(R * action)               # in the parent's frame
        for r in range(n):
            if body.joint.rotates:
                Q[r] += child.Jw.get(r, zero).dot(action)
                if parent is not None:
                    Q[r] += parent.Jw.get(r, zero).dot(reaction)
            else:
                Q[r] += child.Jv.get(r, zero).dot(action)
                if parent is not None:
                    point = parent.Jv.get(r, zero) + parent.Jw.get(r, zero).cross(d)
                    Q[r] += point.dot(reaction)
    return Q


def kinetic_energy(kinematics: list[BodyKinematics], coords: CoordinateSymbols,
                   rec: Recorder) -> sp.Expr:
    T = sp.Integer(0)
    for kin in kinematics:
        body = kin.body
        v = rec.vec(kin.v_C(coords.qd))
        T += body.mass * v.dot(v) / 2 + kin.w.dot(sp.Matrix(body.inertia) * kin.w) / 2
    return T


def potential_energy(kinematics: list[BodyKinematics]) -> sp.Expr:
    """V = -sum m g . r_C, zero at the world origin (dot products taken in body frames)."""
    V = sp.Integer(0)
    for kin in kinematics:
        V -= kin.body.mass * kin.gravity.dot(kin.position + sp.Matrix(kin.body.com))
    return V
