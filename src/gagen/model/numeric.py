"""One numeric evaluator of a Model: its bodies as floats at given parameter values, and
their world placements at given coordinates (NumPy only once evaluated).

Used by the figures, the benchmarks, the Pinocchio builder and the tests' independent
references; the symbolic pipeline never needs it.

Conventions (gagen.model, as URDF): each body's frame is its joint frame; the joint origin
(R0, xyz0) places the joint frame in the parent's frame; a revolute or continuous joint
then rotates by q about its unit axis, a prismatic joint slides by q along it; fixed
joints have no q.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy as sp

from .model import JOINT_TERMS, Model


@dataclass(frozen=True)
class NumericBody:
    """One body with every entry a float."""

    name: str
    parent: int  # index into NumericModel.bodies, -1 for the world
    joint_type: str  # "revolute", "continuous", "prismatic", "fixed" or "floating"
    origin_R: np.ndarray  # 3x3, joint frame orientation in the parent frame
    origin_xyz: np.ndarray  # (3,), joint frame origin in the parent frame
    axis: np.ndarray  # (3,), unit axis in the joint (= body) frame
    mass: float
    com: np.ndarray  # (3,), mass centre in the body frame
    inertia: np.ndarray  # 3x3 central inertia in the body frame
    coordinate: int | None  # first velocity coordinate, None for a fixed joint
    configuration: int | None = None  # first entry of q (a floating joint has 7)
    joint_name: str = ""
    damping: float = 0.0  # the joint terms (gagen.symbolic.joints)
    friction: float = 0.0
    armature: float = 0.0

    @property
    def rotates(self) -> bool:
        return self.joint_type in ("revolute", "continuous")


@dataclass(frozen=True)
class NumericModel:
    """A model's tree with floats at one set of parameter values."""

    bodies: tuple[NumericBody, ...]
    gravity: np.ndarray  # (3,), world frame
    coordinates: tuple[str, ...]
    nq: int = 0  # the size of q (the number of coordinates unless a joint floats)

    @property
    def dof(self) -> int:
        return len(self.coordinates)

    def welded_to_world(self) -> list[bool]:
        """Per body: True if no moving joint lies between it and the world."""
        welded: list[bool] = []
        for b in self.bodies:
            parent_welded = True if b.parent < 0 else welded[b.parent]
            welded.append(parent_welded and b.coordinate is None)
        return welded

    def depth_first(self) -> list[int]:
        """Body indices depth-first from the world, children in body order."""
        children: dict[int, list[int]] = {}
        for i, b in enumerate(self.bodies):
            children.setdefault(b.parent, []).append(i)
        visit: list[int] = []
        stack = list(reversed(children.get(-1, [])))
        while stack:
            i = stack.pop()
            visit.append(i)
            stack.extend(reversed(children.get(i, [])))
        return visit


def parameter_values(model: Model, p=None) -> dict[str, float]:
    """The model's parameter defaults, overridden by `p` (a dict by name, or a full array)."""
    values = {name: float(v) for name, v in model.parameters.items()}
    if p is None:
        return values
    if isinstance(p, dict):
        unknown = set(p) - set(values)
        if unknown:
            raise KeyError(f"unknown parameter(s) {', '.join(sorted(unknown))}")
        values.update({k: float(v) for k, v in p.items()})
        return values
    arr = np.asarray(p, dtype=float).ravel()
    if arr.size != len(values):
        raise ValueError(f"p must have {len(values)} entries in the model's parameter order")
    return dict(zip(values, arr.tolist()))


def numeric_model(model: Model, p=None) -> NumericModel:
    """Evaluate every SymPy entry of `model` at its parameter defaults, overridden by `p`."""
    subs = {sp.Symbol(k): sp.Float(v, 30) for k, v in parameter_values(model, p).items()}
    index = {b.name: i for i, b in enumerate(model.bodies)}
    starts = model.indices()
    bodies = []
    for b in model.bodies:
        j = b.joint
        axis = _floats(j.axis, subs).reshape(3)
        if j.moves and not j.floating:
            axis = axis / np.linalg.norm(axis)  # only the direction matters
        bodies.append(NumericBody(
            name=b.name, parent=index.get(b.parent, -1), joint_type=j.type,
            origin_R=_floats(j.origin_rotation, subs).reshape(3, 3),
            origin_xyz=_floats(j.origin_xyz, subs).reshape(3), axis=axis,
            mass=float(sp.sympify(b.mass).xreplace(subs).evalf(30)),
            com=_floats(b.com, subs).reshape(3), inertia=_floats(b.inertia, subs).reshape(3, 3),
            coordinate=starts[b.name][1] if j.moves else None,
            configuration=starts[b.name][0] if j.moves else None, joint_name=j.name,
            **{key: _float(getattr(j, key), subs) for key in JOINT_TERMS}))
    return NumericModel(tuple(bodies), _floats(model.gravity, subs).reshape(3),
                        tuple(model.coordinates), model.nq)


def _float(expr, subs) -> float:
    return float(sp.sympify(expr).xreplace(subs).evalf(30))


def _floats(matrix, subs) -> np.ndarray:
    # 30 digits, so that e.g. cos(pi/7) in a joint origin is exact to double precision
    return np.array([float(sp.sympify(e).xreplace(subs).evalf(30)) for e in matrix], dtype=float)


def skew(v: np.ndarray) -> np.ndarray:
    """The matrix of v × ."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotation_about(axis: np.ndarray, angles) -> np.ndarray:
    """Rodrigues' formula for a unit axis: (3, 3) for one angle, (m, 3, 3) for m angles."""
    K = skew(np.asarray(axis, dtype=float))
    a = np.asarray(angles, dtype=float)
    s, c = np.sin(a)[..., None, None], np.cos(a)[..., None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def body_frames(nm: NumericModel, q) -> tuple[np.ndarray, np.ndarray]:
    """World origins (m, nb, 3) and rotations (m, nb, 3, 3) of every body frame, for q of
    shape (n,) (then (nb, 3) and (nb, 3, 3)) or (m, n)."""
    q = np.asarray(q, dtype=float)
    if q.ndim not in (1, 2) or q.shape[-1] != nm.dof:
        raise ValueError(f"q must have shape ({nm.dof},) or (m, {nm.dof}); got {q.shape}")
    q2 = q.reshape(-1, nm.dof)
    m = q2.shape[0]
    origins = np.zeros((m, len(nm.bodies), 3))
    rotations = np.zeros((m, len(nm.bodies), 3, 3))
    for i, b in enumerate(nm.bodies):
        if b.parent < 0:
            R_par, o_par = np.broadcast_to(np.eye(3), (m, 3, 3)), np.zeros((m, 3))
        else:
            R_par, o_par = rotations[:, b.parent], origins[:, b.parent]
        R_joint = R_par @ b.origin_R
        o = o_par + R_par @ b.origin_xyz
        x = q2[:, b.coordinate] if b.coordinate is not None else np.zeros(m)
        R = R_joint @ rotation_about(b.axis, x) if b.rotates else R_joint
        if b.joint_type == "prismatic":
            o = o + (R_joint @ b.axis) * x[:, None]
        origins[:, i], rotations[:, i] = o, R
    if q.ndim == 1:
        return origins[0], rotations[0]
    return origins, rotations


def mass_centres(nm: NumericModel, q) -> np.ndarray:
    """World positions of the bodies' mass centres: (nb, 3), or (m, nb, 3) for stacked q."""
    origins, rotations = body_frames(nm, q)
    coms = np.array([b.com for b in nm.bodies])
    return origins + np.einsum("...bij,bj->...bi", rotations, coms)
