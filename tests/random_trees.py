"""Random trees of rigid bodies for testing: odd axes, rotated origins, full inertias."""

from __future__ import annotations

import numpy as np
import sympy as sp

from gagen.model import Body, Joint, Model, inertia_matrix, rotation_from_rpy, vector

MOVING_TYPES = ("revolute", "continuous", "prismatic")


def random_model(rng: np.random.Generator, n_bodies: int, symbolic: bool = False) -> Model:
    """A random tree of `n_bodies` bodies, each parented to the world or an earlier body.

    Joint types mix revolute, continuous, prismatic and fixed (at least one moving).
    With `symbolic`, masses, a few lengths and the inertias' mass scale are parameters.
    """
    if n_bodies < 1:
        raise ValueError("need at least one body")
    types = _joint_types(rng, n_bodies)
    params: dict[str, float] = {"g": 9.81}
    bodies = []
    for i, jtype in enumerate(types, start=1):
        parent = int(rng.integers(0, i))  # 0 is the world, k >= 1 is body k
        bodies.append(_random_body(rng, i, parent, jtype, params, symbolic))
    return Model(name=f"random{n_bodies}", bodies=tuple(bodies), parameters=params,
                 gravity=vector([0, 0, -sp.Symbol("g")]), source="<random>",
                 description="random tree for tests")


def _joint_types(rng: np.random.Generator, n: int) -> list[str]:
    types = [str(t) for t in rng.choice((*MOVING_TYPES, "fixed"), size=n, p=(0.3, 0.25, 0.25, 0.2))]
    if all(t == "fixed" for t in types):
        types[int(rng.integers(0, n))] = str(rng.choice(MOVING_TYPES))
    return types


def _random_body(rng: np.random.Generator, i: int, parent: int, jtype: str,
                 params: dict[str, float], symbolic: bool) -> Body:
    xyz = [float(x) for x in rng.uniform(-0.5, 0.5, 3)]
    mass = float(rng.uniform(0.5, 5.0))
    com = [float(x) for x in rng.uniform(-0.3, 0.3, 3)]
    unit_inertia = random_unit_inertia(rng)  # inertia per unit mass
    m_expr: sp.Expr = sp.Float(mass)
    xyz_expr: list[sp.Expr] = [sp.Float(x) for x in xyz]
    com_expr: list[sp.Expr] = [sp.Float(c) for c in com]
    if symbolic:
        m_expr = sp.Symbol(f"m{i}")
        params[f"m{i}"] = mass
        if i % 2 == 1:  # a few lengths: one origin offset and one mass-centre offset
            params[f"L{i}"], xyz_expr[2] = xyz[2], sp.Symbol(f"L{i}")
            params[f"c{i}"], com_expr[0] = com[0], sp.Symbol(f"c{i}")
    inertia = m_expr * inertia_matrix(*(sp.Float(v) for v in _upper(unit_inertia)))
    rpy = rng.uniform(-np.pi, np.pi, 3)
    joint = Joint(name=f"q{i}", type=jtype, origin_xyz=vector(xyz_expr),
                  origin_rotation=rotation_from_rpy(*(float(a) for a in rpy)),
                  axis=vector([sp.Float(float(a)) for a in random_axis(rng)]))
    return Body(name=f"b{i}", parent="world" if parent == 0 else f"b{parent}", joint=joint,
                mass=m_expr, com=vector(com_expr), inertia=sp.ImmutableMatrix(inertia))


def random_axis(rng: np.random.Generator) -> np.ndarray:
    """A non-axis-aligned direction with a non-unit length (0.5 to 2)."""
    while True:
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        if np.abs(d).min() > 0.1:  # keep away from the coordinate planes
            return d * rng.uniform(0.5, 2.0)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation matrix (QR of a Gaussian matrix, signs fixed)."""
    Q, R = np.linalg.qr(rng.normal(size=(3, 3)))
    Q = Q * np.sign(np.diag(R))
    return Q if np.linalg.det(Q) > 0 else -Q


def random_unit_inertia(rng: np.random.Generator) -> np.ndarray:
    """A central inertia per unit mass, full (rotated) and physically valid.

    Principal moments s2+s3, s1+s3, s1+s2 from positive second moments s_k always satisfy
    the triangle inequality, as a real mass distribution's do.
    """
    s = rng.uniform(0.002, 0.05, 3)
    moments = np.array([s[1] + s[2], s[0] + s[2], s[0] + s[1]])
    Q = random_rotation(rng)
    inertia = Q @ np.diag(moments) @ Q.T
    return 0.5 * (inertia + inertia.T)


def _upper(inertia: np.ndarray) -> list[float]:
    """The (ixx, iyy, izz, ixy, ixz, iyz) that inertia_matrix takes."""
    return [float(inertia[0, 0]), float(inertia[1, 1]), float(inertia[2, 2]),
            float(inertia[0, 1]), float(inertia[0, 2]), float(inertia[1, 2])]
