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

from typing import Any

import numpy as np
import sympy as sp

from .common import optional

# ------------------------------------------------------------------------------ pinocchio


def _evaluate(matrix, subs) -> np.ndarray:
    # 30 digits, so that e.g. cos(pi/7) in a joint origin is exact to double precision
    return np.array([float(sp.sympify(e).xreplace(subs).evalf(30)) for e in matrix],
                    dtype=float)


def _depth_first(parents: list[int]) -> list[int]:
    children: dict[int, list[int]] = {}
    for i, parent in enumerate(parents):
        children.setdefault(parent, []).append(i)
    visit: list[int] = []
    stack = list(reversed(children.get(-1, [])))
    while stack:
        i = stack.pop()
        visit.append(i)
        stack.extend(reversed(children.get(i, [])))
    return visit


def pinocchio_model(model, p: dict[str, float] | None = None) -> Any:
    """A pinocchio.Model with the same tree, inertias and gravity as a gagen Model.

    Parameters take their defaults, overridden by `p`. Pinocchio needs its joints in
    depth-first order, which gagen's parents-first body order need not be, so joints are
    added depth-first and `pm.gagen_order[k]` is gagen's coordinate index of Pinocchio's
    k-th velocity: `to_pinocchio` / `from_pinocchio` convert vectors. Returns None if
    pinocchio is not installed.
    """
    pin = optional("pinocchio")
    if pin is None:
        return None
    values = {name: float(v) for name, v in model.parameters.items()}
    values.update({k: float(v) for k, v in (p or {}).items()})
    subs = {sp.Symbol(k): sp.Float(v, 30) for k, v in values.items()}
    index = {b.name: i for i, b in enumerate(model.bodies)}
    coordinate = {name: k for k, name in enumerate(model.coordinates)}
    parents = [index.get(b.parent, -1) for b in model.bodies]

    pm = pin.Model()
    joint_of: dict[int, int] = {}
    placement: dict[int, Any] = {}
    order: list[int] = []
    for i in _depth_first(parents):
        body, joint = model.bodies[i], model.bodies[i].joint
        parent = parents[i]
        parent_joint = 0 if parent < 0 else joint_of[parent]
        parent_place = pin.SE3.Identity() if parent < 0 else placement[parent]
        origin = parent_place * pin.SE3(_evaluate(joint.origin_rotation, subs).reshape(3, 3),
                                        _evaluate(joint.origin_xyz, subs))
        if not joint.moves:
            joint_id, body_place = parent_joint, origin
        else:
            axis = _evaluate(joint.axis, subs)
            axis = axis / np.linalg.norm(axis)
            kind = (pin.JointModelPrismaticUnaligned if joint.type == "prismatic"
                    else pin.JointModelRevoluteUnaligned)
            joint_id = pm.addJoint(parent_joint, kind(axis), origin, joint.name)
            body_place = pin.SE3.Identity()
            order.append(coordinate[joint.name])
        inertia = pin.Inertia(float(sp.sympify(body.mass).xreplace(subs).evalf(30)),
                              _evaluate(body.com, subs),
                              _evaluate(body.inertia, subs).reshape(3, 3))
        pm.appendBodyToJoint(joint_id, inertia, body_place)
        joint_of[i], placement[i] = joint_id, body_place
    pm.gravity = pin.Motion(_evaluate(model.gravity, subs), np.zeros(3))
    if not (pm.nq == pm.nv == model.dof):  # every joint has nq = nv = 1
        raise RuntimeError(f"pinocchio model of '{model.name}' has nq={pm.nq}, nv={pm.nv}, "
                           f"expected {model.dof}")
    pm.gagen_order = np.array(order, dtype=int)
    return pm


def to_pinocchio(pm, *vectors) -> list[np.ndarray]:
    """Vectors in gagen's coordinate order -> Pinocchio's (contiguous float64)."""
    return [np.ascontiguousarray(np.asarray(v, dtype=np.float64)[pm.gagen_order])
            for v in vectors]


def from_pinocchio(pm, vector) -> np.ndarray:
    out = np.empty(pm.nv)
    out[pm.gagen_order] = np.asarray(vector)
    return out


def pinocchio_mass_matrix(pm, data, q_pin) -> np.ndarray:
    """crba's upper triangle, completed, in gagen's order."""
    pin = optional("pinocchio")
    M = np.array(pin.crba(pm, data, q_pin))
    M = np.triu(M) + np.triu(M, 1).T
    out = np.empty_like(M)
    out[np.ix_(pm.gagen_order, pm.gagen_order)] = M
    return out


def check_pinocchio(dyn, pm, q, qd, qdd, tau, rtol: float = 1e-9) -> None:
    """Raise if Pinocchio and gagen disagree at this state (checked before any timing)."""
    pin = optional("pinocchio")
    data = pm.createData()
    pq, pqd, pqdd, ptau = to_pinocchio(pm, q, qd, qdd, tau)
    checks = (
        ("forward dynamics", from_pinocchio(pm, pin.aba(pm, data, pq, pqd, ptau)),
         dyn.forward_dynamics(q, qd, tau)),
        ("mass matrix", pinocchio_mass_matrix(pm, data, pq), dyn.mass_matrix(q)),
        ("inverse dynamics", from_pinocchio(pm, pin.rnea(pm, data, pq, pqd, pqdd)),
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


def kane_rrr():
    """The paper's robot from its figure with sympy.physics.mechanics' KanesMethod.

    The same model as gagen's built-in `rrr` (the same parameter names): link 1 turns
    about the vertical z axis, links 2 and 3 about their x axes, links along y, mass
    centres mid-link, joint couples T01z, T12x, T23x. Returns (kane, q, u, T); u = q'.
    """
    import sympy.physics.mechanics as me

    q = me.dynamicsymbols("q1:4")
    u = me.dynamicsymbols("u1:4")
    g, L1, L2, L3, m1, m2, m3 = sp.symbols("g L1 L2 L3 m1 m2 m3")
    Ix = sp.symbols("I1x I2x I3x")
    Iy = sp.symbols("I1y I2y I3y")
    Iz = sp.symbols("I1z I2z I3z")
    T = me.dynamicsymbols("T01z T12x T23x")
    N = me.ReferenceFrame("N")
    F1 = N.orientnew("F1", "Axis", (q[0], N.z))
    F2 = F1.orientnew("F2", "Axis", (q[1], F1.x))
    F3 = F2.orientnew("F3", "Axis", (q[2], F2.x))
    O = me.Point("O")
    O.set_vel(N, 0)
    A = O.locatenew("A", L1 * F1.y)
    B = A.locatenew("B", L2 * F2.y)
    centres = (O.locatenew("C1", L1 / 2 * F1.y), A.locatenew("C2", L2 / 2 * F2.y),
               B.locatenew("C3", L3 / 2 * F3.y))
    frames, masses = (F1, F2, F3), (m1, m2, m3)
    for C in centres:
        C.set_vel(N, C.pos_from(O).dt(N))
    bodies = [me.RigidBody(f"B{i + 1}", centres[i], frames[i], masses[i],
                           (me.inertia(frames[i], Ix[i], Iy[i], Iz[i]), centres[i]))
              for i in range(3)]
    loads = [(centres[i], -masses[i] * g * N.z) for i in range(3)]
    loads += [(F1, T[0] * F1.z - T[1] * F2.x), (F2, T[1] * F2.x - T[2] * F3.x),
              (F3, T[2] * F3.x)]
    kane = me.KanesMethod(N, q_ind=q, u_ind=u, kd_eqs=[q[i].diff() - u[i] for i in range(3)])
    kane.kanes_equations(bodies, loads)
    return kane, q, u, T


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
