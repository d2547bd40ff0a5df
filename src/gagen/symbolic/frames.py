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
from .vec3 import IDENTITY, ZERO, Mat3, Vec3, add, cross, mat_mat, mat_vec, scale, sub

PLACEMENT_SIZE = 15  # R (9), p (3), the joint's axis in the world (3)
TRANSFORM_SIZE = 15  # R_j (9), d_j (3), the joint's axis in the body's frame (3)
OFFSET_SIZE = 12  # R (9), p (3)


def add_frame_kinematics(eqs: Equations) -> Equations:
    """`eqs` with the outputs `placements` and `frame_offsets` (module docstring)."""
    model = eqs.model
    rec = recorder_after(eqs.intermediates)
    index = model.indices()
    placed: dict[str, tuple[Mat3, Vec3]] = {WORLD: (IDENTITY, ZERO)}
    axes: dict[str, Vec3] = {}
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
        axes[body.name] = axis
        placements += [*(e for row in R for e in row), *p, *axis]
        transforms += [*(e for row in R_j for e in row), *d_j, *local_axis]
    offsets: list[sp.Expr] = []
    for frame in model.frames:
        offsets += [*sp.Matrix(frame.rotation), *sp.Matrix(frame.xyz)]
    if model.constraints:
        eqs.constraint_frames = constraint_frame_terms(model, eqs.coords.qd, placed, axes, rec)
    eqs.intermediates = rec.definitions
    eqs.placements = placements
    eqs.joint_transforms = [sp.sympify(e) for e in transforms]
    eqs.frame_offsets = [sp.sympify(e) for e in offsets]
    return eqs


# The constrained frames' terms (`constraint_frame_terms`), per frame: its pose (R 9,
# row-major, and p 3), its velocity (its origin's, then angular: 6) and its classical
# acceleration at qdd = 0 (its origin's, then angular: 6), then 6 entries per column of its
# Jacobian, world axes (Pinocchio's LOCAL_WORLD_ALIGNED), as frames.c's gagen_frame_pose,
# gagen_frame_motion and gagen_frame_columns compute them at run time.
CONSTRAINT_FRAME_HEAD = 24


def constrained_frames(model) -> list[str]:
    """The frames the constraints of `model` (a Model or its manifest) hold, each once, in
    the order first named: the slots of `constraint_frame_terms`."""
    names: list[str] = []
    for constraint in model.constraints:
        names += [f for f in constraint.frames if f not in names]
    return names


def constraint_frame_terms(model, qd, placed: dict[str, tuple[Mat3, Vec3]],
                           axes: dict[str, Vec3], rec) -> list[sp.Expr]:
    """The constrained frames' terms (CONSTRAINT_FRAME_HEAD) in the placements' program:
    the constrained dynamics read them from the same program as M and F, where the C's
    loops over the bodies' tables cost ANYmal C's four feet a third of the call."""
    frames = {f.name: f for f in model.frames}
    names = constrained_frames(model)
    on_paths = set()
    for name in names:
        body = frames[name].body
        while body != WORLD:
            on_paths.add(body)
            body = model.body(body).parent
    motion = _body_motions(model, qd, placed, axes, rec, on_paths)
    out: list[sp.Expr] = []
    for name in names:
        frame = frames[name]
        offset = tuple(tuple(frame.rotation[i, j] for j in range(3)) for i in range(3))
        xyz = tuple(frame.xyz)
        if frame.body == WORLD:  # welded to the world: its offset, no motion, no columns
            out += [*(e for row in offset for e in row), *xyz] + [sp.Integer(0)] * 12
            continue
        R_b, o_b = placed[frame.body]
        R = rec.named_rows(mat_mat(R_b, offset))
        pos = rec.named(add(o_b, mat_vec(R_b, xyz)))
        omega, v, alpha, a = motion[frame.body]
        arm = rec.named(sub(pos, o_b))
        spin = rec.named(cross(omega, arm))
        velocity = rec.named(add(v, spin))
        acceleration = rec.named(add(a, cross(alpha, arm), cross(omega, spin)))
        out += [*(e for row in R for e in row), *pos, *velocity, *omega, *acceleration,
                *alpha]
        out += _frame_columns(model, frame.body, pos, placed, axes, rec)
    return [sp.sympify(e) for e in out]


def _body_motions(model, qd, placed, axes, rec, bodies: set[str]) -> dict:
    """Per body of `bodies` (with its ancestors), world axes: its angular velocity, its
    origin's velocity, and their rates at qdd = 0 (taskspace.c's gagen_body_motion):
        omega = omega_p + w            v = v_p + omega_p x r + u
        alpha = alpha_p + omega_p x w
        a = a_p + alpha_p x r + omega_p x (omega_p x r) + 2 omega_p x u + w x u (floating)
    with u, w the joint's motion at qd and r the origin less the parent's."""
    index = model.indices()
    motion = {WORLD: (ZERO, ZERO, ZERO, ZERO)}
    for body in model.bodies:
        if body.name not in bodies:
            continue
        joint = body.joint
        omega_p, v_p, alpha_p, a_p = motion[body.parent]
        R, o = placed[body.name]
        r = rec.named(sub(o, placed[body.parent][1]))
        iv = index.get(body.name, (0, 0))[1]
        u = w = ZERO
        if joint.floating:
            u = rec.named(mat_vec(R, tuple(qd[iv: iv + 3])))
            w = rec.named(mat_vec(R, tuple(qd[iv + 3: iv + 6])))
        elif joint.rotates:
            w = scale(qd[iv], axes[body.name])
        elif joint.type == "prismatic":
            u = scale(qd[iv], axes[body.name])
        spin = rec.named(cross(omega_p, r))
        omega = rec.named(add(omega_p, w))
        v = rec.named(add(v_p, spin, u))
        alpha = rec.named(add(alpha_p, cross(omega_p, w)))
        a = add(a_p, cross(alpha_p, r), cross(omega_p, spin), scale(2, cross(omega_p, u)))
        if joint.floating:
            a = add(a, cross(w, u))
        motion[body.name] = (omega, v, alpha, rec.named(a))
    return motion


def _frame_columns(model, body: str, pos: Vec3, placed, axes, rec) -> list[sp.Expr]:
    """The frame's Jacobian columns at `pos`, 6 each, from its body up to the world, in the
    order of frames.c's gagen_frame_columns (a floating joint: its three linear columns,
    then its three angular ones)."""
    out: list[sp.Expr] = []
    while body != WORLD:
        joint = model.body(body).joint
        R, o = placed[body]
        arm = rec.named(sub(pos, o))
        if joint.floating:
            linear = [tuple(R[i][r] for i in range(3)) for r in range(3)]
            out += [e for e3 in linear for e in (*e3, 0, 0, 0)]
            out += [e for e3 in linear for e in (*cross(e3, arm), *e3)]
        elif joint.rotates:
            out += [*cross(axes[body], arm), *axes[body]]
        elif joint.type == "prismatic":
            out += [*axes[body], 0, 0, 0]
        body = model.body(body).parent
    return out
