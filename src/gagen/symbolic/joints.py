"""The joint terms: viscous damping, Coulomb friction and armature (rotor inertia).

Each moving joint k adds to the rigid-body equations

    tau_k = (M q̈ + b - g)_k + armature_k q̈_k + damping_k q̇_k + friction_k sign(q̇_k),

so the armature is added to M's diagonal (and ½ armature_k q̇_k² to the kinetic energy,
which keeps T = ½ q̇ᵀ M q̇), and the dissipative forces damping_k q̇_k + friction_k sign(q̇_k)
are subtracted from the forcing. sign(0) = 0: at rest, Coulomb friction exerts nothing
(SymPy's `sign`, NumPy's `np.sign` and the generated C's `gagen_sign` agree on that).
Simulations replace sign by a smooth tanh(q̇ / w) (gagen.model.model.FRICTION_WIDTH);
these exact equations do not.
"""

from __future__ import annotations

import sympy as sp

from ..model.model import Model
from .kinematics import CoordinateSymbols


def jointed(model: Model) -> list[tuple[int, object]]:
    """(velocity coordinate, joint) of each 1-dof joint, in coordinate order: the joints
    that have joint terms (a floating joint's six coordinates have none)."""
    starts = model.indices()
    return [(starts[b.name][1], b.joint) for b in model.moving_bodies if not b.joint.floating]


def _per_coordinate(model: Model, key: str) -> list[sp.Expr]:
    out = [sp.Integer(0)] * model.dof
    for k, joint in jointed(model):
        out[k] = sp.sympify(getattr(joint, key))
    return out


def armatures(model: Model) -> list[sp.Expr]:
    """armature_k per velocity coordinate (0 for a floating joint's)."""
    return _per_coordinate(model, "armature")


def dampings(model: Model) -> list[sp.Expr]:
    """damping_k per velocity coordinate (0 for a floating joint's)."""
    return _per_coordinate(model, "damping")


def dissipative_forces(model: Model, coords: CoordinateSymbols) -> list[sp.Expr]:
    """damping_k q̇_k + friction_k sign(q̇_k) per velocity coordinate (zero terms left out)."""
    damping, friction = _per_coordinate(model, "damping"), _per_coordinate(model, "friction")
    return [d * qd + f * sp.sign(qd) for d, f, qd in zip(damping, friction, coords.qd)]


def add_joint_terms(eqs) -> None:
    """Add the joint terms of `eqs.model` to derived rigid-body `Equations` (in place):
    the armature to the mass matrix, the inverse dynamics and the kinetic energy, the
    dissipative forces to the inverse dynamics and (subtracted) to the forcing. The
    velocity terms and gravity forces keep their rigid-body meaning."""
    model, coords = eqs.model, eqs.coords
    inertia = armatures(model)
    forces = dissipative_forces(model, coords)
    if all(a == 0 for a in inertia) and all(f == 0 for f in forces):
        return
    M = sp.Matrix(eqs.mass_matrix)
    tau = sp.Matrix(eqs.inverse_dynamics)
    forcing = sp.Matrix(eqs.forcing)
    T = eqs.kinetic_energy
    for k, (a, f) in enumerate(zip(inertia, forces)):
        M[k, k] += a
        tau[k] += a * coords.qdd[k] + f
        forcing[k] -= f
        T += a * coords.qd[k] ** 2 / 2
    eqs.mass_matrix, eqs.inverse_dynamics, eqs.forcing, eqs.kinetic_energy = M, tau, forcing, T
