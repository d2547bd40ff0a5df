"""Where every body is in the world, and where every named frame is on its body.

`add_frame_kinematics(eqs)` continues the program of an `Equations` with two outputs:

- `placements`: per body (in the model's order) 15 values in q and the parameters: its
  frame's orientation R (the world components of its axes, row-major 3x3), its origin p in
  the world, and its joint's axis in the world (R s; zero for a fixed or floating joint).
  R = R_parent R_joint and p = p_parent + R_parent d_joint, one body at a time, each entry
  named: the size is O(bodies).
- `joint_transforms`: per body 15 values in its own coordinates and the parameters: its
  joint's rotation R_j (row-major), the origin's offset d_j in the parent's frame, and
  the joint's unit axis in the body's frame (zero for a fixed or floating joint). The C
  places one frame's path from these alone (R = R_parent R_j, ...), not every body.
- `frame_offsets`: per frame of `Model.frames` 12 values in the parameters only: the
  frame's axes and origin in its body's frame (a merged link's placement; the identity for
  a body's own frames; a frame welded to the world is placed in the world).

From these, the runtime places any frame (R_body R_f, p_body + R_body p_f) and writes its
Jacobian in Pinocchio's LOCAL_WORLD_ALIGNED convention (linear velocity of the frame's
origin, then angular velocity, both in world axes), walking the ancestors' joints:

    revolute (world axis a at o):  [a x (p_f - o); a]        prismatic:  [a; 0]
    floating (R_b, o_b): linear r: [R_b e_r; 0],  angular r: [(R_b e_r) x (p_f - o_b); R_b e_r]

(gagen.runtime.frames in NumPy, codegen/templates/model/frames.c.j2 in C.)
"""

from __future__ import annotations

import sympy as sp

from ..model.model import WORLD
from .differentiate import recorder_after
from .gibbs_appell import Equations
from .kinematics import joint_transform, unit_axis
from .vec3 import IDENTITY, ZERO, Mat3, Vec3, add, mat_mat, mat_vec

PLACEMENT_SIZE = 15  # R (9), p (3), the joint's axis in the world (3)
TRANSFORM_SIZE = 15  # R_j (9), d_j (3), the joint's axis in the body's frame (3)
OFFSET_SIZE = 12  # R (9), p (3)


def add_frame_kinematics(eqs: Equations) -> Equations:
    """`eqs` with the outputs `placements` and `frame_offsets` (module docstring)."""
    model = eqs.model
    rec = recorder_after(eqs.intermediates)
    index = model.indices()
    placed: dict[str, tuple[Mat3, Vec3]] = {WORLD: (IDENTITY, ZERO)}
    placements: list[sp.Expr] = []
    transforms: list[sp.Expr] = []
    for body in model.bodies:
        joint = body.joint
        iq = index.get(body.name, (0, 0))[0]
        R_j, d_j = joint_transform(joint, eqs.coords.q[iq: iq + joint.nq], rec)
        # named as the derivation named them (the same names): each entry is read by
        # three products below, and a sum would be written out in each
        R_j, d_j = rec.named_rows(R_j), rec.named(d_j)
        R_p, p_p = placed[body.parent]
        R = rec.named_rows(mat_mat(R_p, R_j))
        p = rec.named(add(p_p, mat_vec(R_p, d_j)))
        has_axis = joint.moves and not joint.floating
        local_axis = unit_axis(joint.axis) if has_axis else ZERO
        axis = rec.named(mat_vec(R, local_axis)) if has_axis else ZERO
        placed[body.name] = (R, p)
        placements += [*(e for row in R for e in row), *p, *axis]
        transforms += [*(e for row in R_j for e in row), *d_j, *local_axis]
    offsets: list[sp.Expr] = []
    for frame in model.frames:
        offsets += [*sp.Matrix(frame.rotation), *sp.Matrix(frame.xyz)]
    eqs.intermediates = rec.definitions
    eqs.placements = placements
    eqs.joint_transforms = [sp.sympify(e) for e in transforms]
    eqs.frame_offsets = [sp.sympify(e) for e in offsets]
    return eqs
