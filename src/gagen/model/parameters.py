"""Mass properties as runtime parameters, for the readers of robot descriptions (URDF, MJCF).

Each massive body's mass, mass centre and central inertia become the parameters
`m_<body>`, `cx_<body>`, `cy_<body>`, `cz_<body>`, `Ixx_<body>`, ... `Iyz_<body>` with the
file's values as defaults, so a payload can be changed without regenerating the equations.
Each moving joint's damping, friction and armature become `damping_<joint>`,
`friction_<joint>` and `armature_<joint>` (`parameterize_joint_terms`).
"""

from __future__ import annotations

from dataclasses import replace

import sympy as sp

from .model import JOINT_TERMS, Body, Joint, Model, vector

# Parameter prefix -> (row, column) of the inertia tensor, in the order they are declared.
INERTIA_PARAMS = (("Ixx", 0, 0), ("Iyy", 1, 1), ("Izz", 2, 2),
                  ("Ixy", 0, 1), ("Ixz", 0, 2), ("Iyz", 1, 2))


def parameterize_mass_properties(model: Model) -> Model:
    """Turn each massive body's mass, mass centre and inertia into named parameters.

    Massless bodies keep plain zeros: there is nothing to tune, and zeros keep the
    generated code small.
    """
    parameters = dict(model.parameters)
    bodies = []
    for body in model.bodies:
        if _is_zero(body.mass) and all(_is_zero(e) for e in body.inertia):
            bodies.append(body)
            continue
        parameters.update(_body_parameters(body))
        bodies.append(_symbolic_body(body))
    return replace(model, bodies=tuple(bodies), parameters=parameters)


def parameterize_joint_terms(model: Model) -> Model:
    """Turn each 1-dof joint's damping, friction and armature (0 where the description
    has none) into the parameters `<term>_<joint>`, with its values as defaults: all three
    for every joint, so that they can be set without a rebuild and every regressor column
    (gagen.symbolic.regressor) can be fed back from identification."""
    parameters = dict(model.parameters)
    bodies = []
    for body in model.bodies:
        if body.joint.moves and not body.joint.floating:
            parameters.update({f"{key}_{body.joint.name}": float(getattr(body.joint, key))
                               for key in JOINT_TERMS})
            body = replace(body, joint=_symbolic_joint(body.joint))
        bodies.append(body)
    return replace(model, bodies=tuple(bodies), parameters=parameters)


def _symbolic_joint(joint: Joint) -> Joint:
    return replace(joint, **{key: sp.Symbol(f"{key}_{joint.name}") for key in JOINT_TERMS})


def _symbolic_body(body: Body) -> Body:
    link = body.name
    inertia = sp.ImmutableMatrix(3, 3, lambda r, c: sp.Symbol(_inertia_name(r, c, link)))
    return replace(body, mass=sp.Symbol(f"m_{link}"),
                   com=vector([sp.Symbol(f"c{a}_{link}") for a in "xyz"]), inertia=inertia)


def _body_parameters(body: Body) -> dict[str, float]:
    link = body.name
    values = {f"m_{link}": float(body.mass)}
    values.update({f"c{a}_{link}": float(body.com[i]) for i, a in enumerate("xyz")})
    values.update({f"{key}_{link}": float(body.inertia[r, c]) for key, r, c in INERTIA_PARAMS})
    return values


def _inertia_name(r: int, c: int, link: str) -> str:
    r, c = min(r, c), max(r, c)
    key = next(k for k, kr, kc in INERTIA_PARAMS if (kr, kc) == (r, c))
    return f"{key}_{link}"


def _is_zero(expr) -> bool:
    return sp.sympify(expr).is_zero is True
