"""Constraints onto a Model: checked (gagen.constraints), their frames the model's, and each
contact's anchor parameters given the frame's placement at the neutral configuration."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import sympy as sp

from ..constraints import ANCHOR_POSITION, ANCHOR_ROTATION, anchor_parameter, checked_constraints
from .model import Model


def attach_constraints(model: Model, entries, element: str = "constraints",
                       anchors: dict[str, tuple] | None = None) -> Model:
    """`model` with the constraints `entries` (gagen.Contact, gagen.Loop or model-file
    mappings) after its own. A new contact's anchor is its frame's placement at the neutral
    configuration (q = 0, unit quaternions) and the default parameters, unless `anchors`
    gives it: {name: (xyz, rpy)}. A parameter the model already declares keeps its value."""
    if entries is None or (isinstance(entries, (list, tuple)) and not entries):
        return model
    added = checked_constraints(entries, model.source, element, taken=model.constraints)
    declared = set(model.parameters)
    out = replace(model, constraints=model.constraints + added)  # checks the frames
    anchors = anchors or {}
    values = {}
    for c in added:
        names = [n for n in c.anchor_names() if n not in declared]
        if not names:
            continue
        xyz, rpy = anchors[c.name] if c.name in anchors else neutral_placement(out, c.frames[0])
        given = dict(zip(ANCHOR_POSITION + ANCHOR_ROTATION, list(xyz) + list(rpy)))
        for key, value in given.items():
            name = anchor_parameter(c.name, key)
            if name in names:
                values[name] = float(value)
    if not values:
        return out
    return replace(out, parameters={**out.parameters, **values})


def neutral_placement(model: Model, frame: str) -> tuple[np.ndarray, np.ndarray]:
    """(origin, roll-pitch-yaw) of a frame in the world at the neutral configuration and the
    model's default parameters."""
    from .numeric import body_frames, numeric_model

    entry = next(f for f in model.frames if f.name == frame)
    subs = {sp.Symbol(k): sp.Float(float(v), 30) for k, v in model.parameters.items()}
    xyz = np.array([float(sp.sympify(e).xreplace(subs).evalf(30)) for e in entry.xyz])
    R = np.array([float(sp.sympify(e).xreplace(subs).evalf(30))
                  for e in entry.rotation]).reshape(3, 3)
    if entry.body != "world":
        nm = numeric_model(model)
        origins, rotations = body_frames(nm, np.zeros(nm.dof))
        body = [b.name for b in model.bodies].index(entry.body)
        xyz = origins[body] + rotations[body] @ xyz
        R = rotations[body] @ R
    return xyz, rpy_of(R)


def rpy_of(R: np.ndarray) -> np.ndarray:
    """URDF's roll, pitch, yaw of a rotation R = Rz(yaw) Ry(pitch) Rx(roll)."""
    pitch = math.asin(max(-1.0, min(1.0, -float(R[2, 0]))))
    if abs(math.cos(pitch)) > 1e-9:
        roll = math.atan2(float(R[2, 1]), float(R[2, 2]))
        yaw = math.atan2(float(R[1, 0]), float(R[0, 0]))
    else:  # gimbal lock: yaw and roll turn about the same axis
        roll, yaw = 0.0, math.atan2(-float(R[0, 1]), float(R[1, 1]))
    return np.array([roll, pitch, yaw])
