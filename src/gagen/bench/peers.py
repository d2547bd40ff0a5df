"""The peers gagen is measured against: Pinocchio, PyDy's Cython backend, plain SymPy.

- `pinocchio_model(model)`: a Pinocchio model of any gagen Model (same tree, inertias,
  gravity), so pinocchio.aba / rnea / crba can be timed on exactly the same robot;
- `pydy_rrr(parameters)`: the paper's robot written with sympy.physics.mechanics'
  KanesMethod and compiled by PyDy's Cython code generator; its rhs(x, t, r, p) returns
  (qd, qdd), i.e. forward dynamics;
- `naive_sympy(eqs)`: what a SymPy user gets without gagen: `sympy.lambdify` of the fully
  substituted M and F (no CSE), then `numpy.linalg.solve`.

Pinocchio and PyDy are optional (`pip install gagen[bench]`): each builder returns None
when its library is missing.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from ..reference.kane import kane_rrr
from ..reference.pinocchio import (
    from_pinocchio,
    joint_forces,
    pinocchio_mass_matrix,
    to_pinocchio,
)
from ..reference.pinocchio import pinocchio_model as _build_pinocchio
from .common import optional

# ------------------------------------------------------------------------------ pinocchio


def pinocchio_model(model, p: dict[str, float] | None = None):
    """The Pinocchio model of a gagen Model (gagen.reference.pinocchio), or None without
    Pinocchio."""
    if optional("pinocchio") is None:
        return None
    return _build_pinocchio(model, p)


def check_pinocchio(dyn, pm, q, qd, qdd, tau, rtol: float = 1e-9) -> None:
    """Raise if Pinocchio and gagen disagree at this state (checked before any timing).

    Pinocchio's rnea and aba leave out the joints' damping and friction (a URDF's
    <dynamics>; its armature they include): they are added here, as gagen includes them."""
    pin = optional("pinocchio")
    data = pm.createData()
    forces = joint_forces(pm, qd)
    pq, pqd, pqdd, ptau = to_pinocchio(pm, q, qd, qdd, np.asarray(tau, float) - forces)
    checks = (
        ("forward dynamics", from_pinocchio(pm, pin.aba(pm, data, pq, pqd, ptau)),
         dyn.forward_dynamics(q, qd, tau)),
        ("mass matrix", pinocchio_mass_matrix(pm, data, pq), dyn.mass_matrix(q)),
        ("inverse dynamics", from_pinocchio(pm, pin.rnea(pm, data, pq, pqd, pqdd)) + forces,
         dyn.inverse_dynamics(q, qd, qdd)),
    )
    for quantity, theirs, ours in checks:
        _agree(f"gagen and Pinocchio on the {quantity} of '{dyn.model.name}'", ours, theirs,
               rtol)


def _agree(what: str, ours, theirs, rtol: float) -> None:
    ours, theirs = np.asarray(ours, float), np.asarray(theirs, float)
    scale = max(np.abs(theirs).max(), 1e-300)
    if ours.shape != theirs.shape or not np.allclose(ours, theirs, rtol=rtol,
                                                     atol=rtol * scale):
        raise RuntimeError(f"{what} disagree:\n{ours}\nvs\n{theirs}")


# ------------------------------------------------------------------------------- pydy


def pydy_rrr(parameter_names: list[str]):
    """PyDy's Cython right-hand side of the rrr robot, or None without PyDy.

    The minimal form M(q) u' = F(q, u, r), q' = u (a 3x3 solve by numpy.linalg.solve,
    PyDy's default), constants and specifieds passed as arrays (PyDy's fast path).
    `rhs(x, t, r, p)` with x = (q, qd), r = the three joint torques and p the parameters
    in `parameter_names` order returns (qd, qdd).
    """
    codegen = optional("pydy.codegen.ode_function_generators")
    if codegen is None:
        return None
    from pydy.codegen.ode_function_generators import generate_ode_function

    kane, q, u, T = kane_rrr()
    constants = [sp.Symbol(name) for name in parameter_names]
    return generate_ode_function(kane.forcing, q, u, constants=constants,
                                 mass_matrix=kane.mass_matrix,
                                 coordinate_derivatives=sp.Matrix(u), specifieds=list(T),
                                 generator="cython", constants_arg_type="array",
                                 specifieds_arg_type="array")


# ------------------------------------------------------------------------- naive sympy


def naive_sympy(eqs):
    """Forward dynamics the plain SymPy way: lambdify explicit M and F, then solve.

    M(q) and F(q, qd, tau) with every intermediate substituted (`eqs.explicit`), each
    lambdified without common subexpressions; `fd(q, qd, tau)` unpacks the state into
    the generated function's scalar arguments and calls numpy.linalg.solve.
    """
    c = eqs.coords
    M = eqs.explicit(eqs.mass_matrix)
    F = eqs.explicit(eqs.forcing)
    p = [float(v) for v in eqs.model.parameters.values()]
    f_M = sp.lambdify(list(c.q) + eqs.parameters, M, modules="numpy")
    f_F = sp.lambdify(list(c.q) + list(c.qd) + list(c.tau) + eqs.parameters, F,
                      modules="numpy")
    solve = np.linalg.solve

    def fd(q, qd, tau):
        return solve(f_M(*q, *p), f_F(*q, *qd, *tau, *p)).ravel()

    return fd


# --------------------------------------------------------------- the Panda, from its URDF


def pinocchio_from_urdf(dyn, urdf):
    """Pinocchio's own URDF parse of a robot gagen also loaded, with gagen's order mapping.

    Returns the model, with `gagen_order` as in `pinocchio_model` (so `to_pinocchio` and
    `from_pinocchio` apply), or None without pinocchio. Mimic joints stay independent, as
    in gagen.
    """
    pin = optional("pinocchio")
    if pin is None:
        return None
    model = pin.buildModelFromUrdf(str(urdf))
    if model.nq != model.nv or model.nv != dyn.n:
        raise RuntimeError("expected one q entry per coordinate (no continuous joints)")
    # Pinocchio's velocity index of each gagen coordinate; gagen_order is its inverse
    index = np.array([model.idx_vs[model.getJointId(name)] for name in dyn.coordinates])
    order = np.empty(model.nv, dtype=int)
    order[index] = np.arange(model.nv)
    model.gagen_order = order
    return model
