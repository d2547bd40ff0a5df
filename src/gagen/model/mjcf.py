"""Read a MuJoCo MJCF model into a validated Model, through MuJoCo's own compiler.

gagen does not parse MJCF: `mujoco.MjModel.from_xml_path` compiles the file (defaults and
classes, `<include>`, `<frame>`, quat/euler/axisangle/xyaxes orientations, diaginertia and
fullinertia, inertias from geoms), after `mjcf_files.scan_mjcf` has checked every file it
will read. Bodies, joints, inertias and gravity are then read from the compiled `MjModel`:

- gagen's bodies are placed by joint frames. A MuJoCo joint sits at `jnt_pos` inside its
  body with `jnt_axis` in the body's axes, so each joint's gagen frame is the MuJoCo body
  frame moved to the joint's anchor. A body with several joints becomes a chain of
  massless bodies named `<body>_<joint>`, the last one (with the mass) named after the
  body; a body without a joint is welded to its parent (a fixed joint, merged away by
  `merge.py`). The frame named after a MuJoCo body is MuJoCo's body frame (`xpos`,
  `xmat`) wherever its joints are anchored: where the last anchor is away from the body's
  origin, an extra frame places it (`Model.frames`); the joint's frame is at its anchor.
- The coordinates are MuJoCo's `qpos` for hinge and slide joints: a joint's `ref` is
  folded into the joint's origin, so q = 0 is not the pose drawn in the file when
  ref != 0, exactly as in MuJoCo.
- Mass properties become the parameters `m_<body>`, `cx_<body>`, ... as for URDF
  (`parameters.py`); gravity is `-g` along the direction of `opt.gravity` (g = 0 when the
  model disables gravity).
- Unnamed bodies and joints are named `body<id>` and `joint<id>` (MuJoCo's ids).

Not modelled (they are not part of M(q) and the bias forces): contacts, equality
constraints, tendons, actuators, joint stiffness and `gravcomp`. Joint damping, friction
loss and armature are returned by `joint_terms`.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np
import sympy as sp

from ..errors import ModelError, one_line, warn_user
from .inputs import MAX_BODIES, name_field, quote
from .merge import merge_fixed_joints, symmetric
from .mjcf_files import scan_mjcf
from .model import (
    IDENTITY,
    WORLD,
    ZERO3,
    Body,
    Frame,
    Joint,
    Limits,
    Model,
    check_inertia,
    exact_units,
    round_off_floor,
    vector,
)
from .parameters import parameterize_joint_terms, parameterize_mass_properties

_MESSAGE_LENGTH = 500  # of MuJoCo's compile error, quoted in a ModelError
_FREE, _BALL, _SLIDE, _HINGE = 0, 1, 2, 3  # mujoco.mjtJoint
_GRAVITY_DISABLED = 1 << 7  # mujoco.mjtDisableBit.mjDSBL_GRAVITY


def load_mjcf(path: str | Path, strict: bool = False) -> Model:
    """Read an MJCF file through MuJoCo's compiler; errors are ModelError naming the file.

    An inertia slightly off physical warns (`gagen.errors.InertiaWarning`), or is refused
    when `strict` (MuJoCo's compiler refuses most such inertias itself).
    """
    return model_from_mjmodel(compile_mjcf(path), str(path), strict=strict)


def compile_mjcf(path: str | Path):
    """The `mujoco.MjModel` of an MJCF file whose files have been checked (`scan_mjcf`)."""
    source = str(path)
    scan_mjcf(path)
    mujoco = _import_mujoco(source)
    notes: list[str] = []
    try:
        with _warnings_collected(mujoco, notes):
            mj = mujoco.MjModel.from_xml_path(source)
    except MemoryError:
        raise ModelError(source, "MuJoCo's compiler", "ran out of memory compiling the "
                         "model") from None
    except Exception as exc:  # noqa: BLE001 - every error of MuJoCo's is the file's
        raise ModelError(source, "MuJoCo's compiler", _compile_error(exc)) from None
    for note in notes:
        warn_user(one_line(f"{source}: MuJoCo's compiler: {_shortened(note)}"), UserWarning)
    if mj.nbody - 1 > MAX_BODIES:
        raise ModelError(source, "<worldbody>", f"{mj.nbody - 1} bodies; gagen builds robots "
                         f"of at most {MAX_BODIES} bodies")
    return mj


@contextmanager
def _warnings_collected(mujoco, into: list[str]):
    """MuJoCo's own warnings into a list: by default MuJoCo appends them to a file
    MUJOCO_LOG.TXT in the current folder, and gagen writes nothing there."""
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(into.append)
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(previous)


def _compile_error(exc: Exception) -> str:
    """MuJoCo's message, or what its bindings say when the C++ threw something they do not
    translate (pybind11's "Caught an unknown exception!", an allocation that failed)."""
    text = _shortened(str(exc))
    if not text or "unknown exception" in text.lower():
        return (f"failed without saying why ({type(exc).__name__}: {text or 'no message'}; "
                "often memory running out)")
    return text


def _shortened(message: str) -> str:
    message = message.strip()
    return message if len(message) <= _MESSAGE_LENGTH else message[:_MESSAGE_LENGTH] + "..."


def _import_mujoco(source: str):
    try:
        import mujoco
    except ImportError:
        raise ModelError(source, "", "reading MJCF needs MuJoCo's compiler: "
                         "pip install gagen[mjcf]") from None
    return mujoco


def model_from_mjmodel(mj, source: str = "<mjcf>", strict: bool = False) -> Model:
    """The Model of a compiled `mujoco.MjModel` (see the module's docstring)."""
    names = _Names(mj, source)
    bodies: list[Body] = []
    # Per MuJoCo body: (the gagen body that carries it, the anchor of its last joint).
    tips: dict[int, tuple[str, np.ndarray]] = {0: (WORLD, np.zeros(3))}
    frames: list[Frame] = []
    for b in range(1, mj.nbody):  # MuJoCo orders bodies parents first
        chain, anchor = _body_chain(mj, b, names, tips[int(mj.body_parentid[b])], source)
        bodies.extend(chain[:-1])
        bodies.append(_with_mass(chain[-1], mj, b, anchor, source, strict))
        tips[b] = (chain[-1].name, anchor)
        if np.any(anchor):
            frames.append(_body_frame(chain[-1].name, anchor))
    if not any(body.joint.moves for body in bodies):
        raise ModelError(source, "<worldbody>", "no hinge or slide joint: nothing can move")
    g, direction = _gravity(mj)
    bodies = _with_joint_terms(bodies, joint_terms(mj, source))
    model = Model(name=names.model, bodies=tuple(bodies), parameters={"g": g},
                  gravity=vector([-sp.Symbol("g") * d for d in direction]), source=source,
                  extra_frames=tuple(frames))
    return parameterize_joint_terms(parameterize_mass_properties(merge_fixed_joints(model)))


def _with_joint_terms(bodies: list[Body], terms: dict[str, dict[str, float]]) -> list[Body]:
    """MuJoCo's damping, frictionloss and armature as gagen's joint terms (which become
    the runtime parameters damping_<joint>, friction_<joint>, armature_<joint>)."""
    out = []
    for body in bodies:
        values = terms.get(body.joint.name)
        if values is not None and body.joint.moves and not body.joint.floating:
            body = replace(body, joint=replace(body.joint, **{
                key: _number(value) for key, value in values.items()}))
        out.append(body)
    return out


def joint_terms(mj, source: str = "<mjcf>") -> dict[str, dict[str, float]]:
    """Per gagen coordinate (a hinge or slide joint's name), MuJoCo's `dof_damping`,
    `dof_frictionloss` and `dof_armature` as {"damping", "friction", "armature"}."""
    names = _Names(mj, source)
    terms = {}
    for j in range(mj.njnt):
        if int(mj.jnt_type[j]) in (_HINGE, _SLIDE):
            dof = int(mj.jnt_dofadr[j])
            terms[names.joint(j)] = {"damping": float(mj.dof_damping[dof]),
                                     "friction": float(mj.dof_frictionloss[dof]),
                                     "armature": float(mj.dof_armature[dof])}
    return terms


# --- names ----------------------------------------------------------------------------------

def body_names(mj, source: str = "<mjcf>") -> list[str]:
    """The names of MuJoCo's bodies 1, 2, ... in gagen's model of `mj`: each names the frame
    that is MuJoCo's body frame (`xpos`, `xmat`)."""
    names = _Names(mj, source)
    return [names.body(b) for b in range(1, mj.nbody)]


class _Names:
    """Stable names of a compiled model's bodies and joints: MuJoCo's, else `body<id>`,
    `joint<id>`; generated names never take a name the file uses."""

    def __init__(self, mj, source: str):
        self.mj, self.source = mj, source
        self._bodies = self._all("body", mj.nbody, 1, 1)
        self._joints = self._all("joint", mj.njnt, 3, 0)
        self._taken = set(self._bodies.values()) | {WORLD}
        self.model = self._model_name()

    def body(self, b: int) -> str:
        return self._bodies[b]

    def joint(self, j: int) -> str:
        return self._joints[j]

    def intermediate(self, body: str, joint: str) -> str:
        """A massless body between two joints of one MuJoCo body."""
        return self._fresh(f"{body}_{joint}")

    def _all(self, kind: str, count: int, obj: int, first: int) -> dict[int, str]:
        given = {i: self._given(obj, i, kind) for i in range(first, count)}
        taken = {n for n in given.values() if n}
        names = {}
        for i, name in given.items():
            if not name:
                name = f"{kind}{i}"
                while name in taken:
                    name += "_"
                taken.add(name)
            names[i] = name
        return names

    def _given(self, obj: int, i: int, kind: str) -> str | None:
        name = _mujoco().mj_id2name(self.mj, obj, i)
        if not name:
            return None
        return name_field(name, self.source, f"{kind} #{i}")

    def _fresh(self, name: str) -> str:
        while name in self._taken:
            name += "_"
        self._taken.add(name)
        return name

    def _model_name(self) -> str:
        name = bytes(self.mj.names).split(b"\0", 1)[0].decode("utf-8", "replace")
        if not name or name == "MuJoCo Model":  # MuJoCo's default when the file names none
            name = Path(self.source).stem
        return name_field(name, self.source, "<mujoco> model")


# --- bodies and joints ----------------------------------------------------------------------

def _body_chain(mj, b: int, names: _Names, parent: tuple[str, np.ndarray],
                source: str) -> tuple[list[Body], np.ndarray]:
    """The gagen bodies of MuJoCo body `b` (one per joint, or one welded body) and the
    anchor of its last joint in the body's frame."""
    parent_name, parent_anchor = parent
    name = names.body(b)
    rotation = _quat_matrix(mj.body_quat[b])
    xyz = mj.body_pos[b] - parent_anchor  # in the parent's axes
    first, count = int(mj.body_jntadr[b]), int(mj.body_jntnum[b])
    if count == 0:
        joint = Joint(name=f"{name}_fixed", type="fixed", origin_xyz=_vector(xyz),
                      origin_rotation=_rotation(rotation), axis=vector([0, 0, 1]))
        return [Body(name=name, parent=parent_name, joint=joint)], np.zeros(3)
    if int(mj.jnt_type[first]) == _FREE:
        # MuJoCo's free joint: the body's placement is its configuration (the body's pos
        # and quat in the file are only its initial qpos), about the body's origin
        joint = Joint(name=names.joint(first), type="floating")
        return [Body(name=name, parent=parent_name, joint=joint)], np.zeros(3)
    chain: list[Body] = []
    anchor = np.zeros(3)
    for k, j in enumerate(range(first, first + count)):
        _refuse_unsupported(mj, j, name, names, source)
        new_anchor = np.array(mj.jnt_pos[j], dtype=float)
        if k == 0:
            xyz = xyz + rotation @ new_anchor
        else:  # in the axes of the previous joint's frame: the body's axes after it moved
            xyz, rotation = new_anchor - anchor, np.eye(3)
        joint_name = names.joint(j)
        joint = _joint(mj, j, joint_name, xyz, rotation)
        last = k == count - 1
        body_name = name if last else names.intermediate(name, joint_name)
        chain.append(Body(name=body_name, parent=chain[-1].name if chain else parent_name,
                          joint=joint))
        anchor = new_anchor
    return chain, anchor


def _body_frame(name: str, anchor: np.ndarray) -> Frame:
    """MuJoCo's frame of a body (`xpos`, `xmat`) in the gagen body that carries it, whose
    frame is at the last joint's anchor with the body's axes (`Model.frames`: it places the
    body's own frame)."""
    return Frame(name, name, xyz=_vector(-np.asarray(anchor, dtype=float)))


def _refuse_unsupported(mj, j: int, body: str, names: _Names, source: str) -> None:
    """Ball joints, and a free joint after another joint: the one place that knows which
    MuJoCo joints gagen cannot model."""
    jtype = int(mj.jnt_type[j])
    if jtype == _FREE:  # MuJoCo allows a free joint only as a body's only joint
        raise ModelError(source, f"body {quote(body)}", "has a free joint after another "
                         "joint")
    if jtype == _BALL:
        raise ModelError(source, f"joint {quote(names.joint(j))}", "ball joints are not "
                         "supported; model it as three hinge joints with orthogonal axes "
                         "on the same body")


def _joint(mj, j: int, name: str, xyz: np.ndarray, rotation: np.ndarray) -> Joint:
    """A hinge or slide joint whose coordinate is MuJoCo's qpos (the ref folded in)."""
    axis = np.array(mj.jnt_axis[j], dtype=float)
    ref = float(mj.qpos0[mj.jnt_qposadr[j]])
    hinge = int(mj.jnt_type[j]) == _HINGE
    if ref != 0.0:
        if hinge:  # MuJoCo turns by qpos - ref: start the frame at -ref
            rotation = rotation @ _axis_angle_matrix(axis, -ref)
        else:
            xyz = xyz - ref * (rotation @ axis)
    limits = None
    if bool(mj.jnt_limited[j]):
        lower, upper = (float(v) for v in mj.jnt_range[j])
        limits = Limits(lower=lower, upper=upper)
    jtype = "prismatic" if not hinge else ("revolute" if limits else "continuous")
    return Joint(name=name, type=jtype, origin_xyz=_vector(xyz),
                 origin_rotation=_rotation(rotation), axis=_vector(axis), limits=limits)


def _with_mass(body: Body, mj, b: int, anchor: np.ndarray, source: str, strict: bool) -> Body:
    """The body with MuJoCo body `b`'s mass properties, in its frame (at the anchor)."""
    principal = _quat_matrix(mj.body_iquat[b])
    inertia = principal @ np.diag(np.asarray(mj.body_inertia[b], dtype=float)) @ principal.T
    inertia = (inertia + inertia.T) / 2
    ipos = np.asarray(mj.body_ipos[b], dtype=float)
    check_inertia(inertia, source, f"body {quote(body.name)}, inertia", strict,
                  floor=round_off_floor(float(mj.body_mass[b]), float(np.linalg.norm(ipos))))
    com = ipos - anchor
    return Body(name=body.name, parent=body.parent, joint=body.joint,
                mass=_number(mj.body_mass[b]), com=_vector(com),
                inertia=symmetric(sp.Matrix(3, 3, [_number(v) for v in inertia.ravel()])))


def _gravity(mj) -> tuple[float, list[sp.Expr]]:
    """(g, unit direction of gravity): gravity is -g times the negated direction."""
    gravity = np.asarray(mj.opt.gravity, dtype=float)
    scale = float(np.abs(gravity).max())
    g = scale * float(np.linalg.norm(gravity / scale)) if scale > 0 else 0.0  # no overflow
    if g == 0.0 or int(mj.opt.disableflags) & _GRAVITY_DISABLED:
        return 0.0, [sp.Integer(0), sp.Integer(0), sp.Integer(1)]
    return g, exact_units(-gravity / g)


# --- numbers --------------------------------------------------------------------------------

def _quat_matrix(quat) -> np.ndarray:
    """MuJoCo's rotation matrix of a (w, x, y, z) quaternion (as its kinematics uses it)."""
    out = np.zeros(9)
    _mujoco().mju_quat2Mat(out, np.asarray(quat, dtype=float))
    return out.reshape(3, 3)


def _axis_angle_matrix(axis: np.ndarray, angle: float) -> np.ndarray:
    quat = np.zeros(4)
    _mujoco().mju_axisAngle2Quat(quat, axis, angle)
    return _quat_matrix(quat)


def _mujoco():
    import mujoco

    return mujoco


def _rotation(matrix: np.ndarray) -> sp.ImmutableMatrix:
    if np.array_equal(matrix, np.eye(3)):
        return IDENTITY
    return sp.ImmutableMatrix(3, 3, exact_units(matrix.ravel()))


def _vector(values) -> sp.ImmutableMatrix:
    if not np.any(values):
        return ZERO3
    return vector(exact_units(values))


def _number(value) -> sp.Expr:
    value = float(value)
    return sp.Integer(0) if value == 0.0 else sp.Float(value)
