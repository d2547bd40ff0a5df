"""The robot model: a tree of rigid bodies joined by joints, with symbolic parameters.

Frames follow URDF: each body's frame is its joint frame. A joint's origin places the
joint frame in the parent's frame; the joint then rotates about (revolute, continuous)
or slides along (prismatic) its axis, given in the joint frame.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import math
from dataclasses import dataclass, field, replace

import numpy as np
import sympy as sp

from ..errors import InertiaWarning, ModelError, one_line, warn_user
from ..manifest import FRICTION_WIDTH

JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating")
# A floating joint (Pinocchio's FreeFlyer) has 7 configuration entries, the position of its
# body's origin in the world and its orientation as a unit quaternion (x, y, z, w), and 6
# velocity coordinates, the velocity of the origin and the angular velocity, both in the
# body's frame; its generalised force is the wrench (force, moment about the origin) on the
# body, in the body's frame. Their names are the joint's with these suffixes.
FLOATING_CONFIGURATION = ("x", "y", "z", "qx", "qy", "qz", "qw")
FLOATING_VELOCITY = ("vx", "vy", "vz", "wx", "wy", "wz")
WORLD = "world"
# The width of the smooth sign tanh(qd / w) that simulations use for Coulomb friction
# (gagen.sim.simulate, the compiled integrators) is the runtime parameter FRICTION_WIDTH of
# every model with friction, added with this default (rad/s or m/s) unless the model
# declares it. 0 means the exact sign.
FRICTION_WIDTH_DEFAULT = 0.01
JOINT_TERMS = ("damping", "friction", "armature")


def rotation_from_rpy(roll, pitch, yaw) -> sp.ImmutableMatrix:
    """URDF's fixed-axis roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    R = _rot_z(yaw) * _rot_y(pitch) * _rot_x(roll)
    return sp.ImmutableMatrix(R.applyfunc(lambda e: _exact_unit(float(e)) if e.is_Float else e))


# A numeric angle within this of a multiple of pi/2 is that multiple (see _trig).
QUARTER_TURN_TOLERANCE = 1e-11


def _trig(angle):
    """(cos, sin) of an angle; a number within QUARTER_TURN_TOLERANCE rad of a multiple of
    pi/2 turns exactly that multiple. URDFs write pi/2 with 11 or 12 digits (Tiago's, ANYmal's,
    Talos's and the UR arms' 1.57079632679, 4.9e-12 short; 4.71238898038, 4.7e-12): the
    intent is a quarter turn, and the residue makes every rotation matrix dense (a quarter
    more operations in Tiago's mass matrix). The tolerance keeps the change far below the
    1e-9 to which gagen matches Pinocchio: each snapped angle moves a frame by at most 1e-11
    times its distance from the joint. Fewer digits (Kinova's 1.570796327, 2.1e-10 off; the
    Allegro hand's 1.5707963259, 9e-10) are taken as written, as Pinocchio takes them."""
    if isinstance(angle, (int, float)) or (isinstance(angle, sp.Basic) and angle.is_Number):
        value = float(angle)
        quarters = round(value / (math.pi / 2))
        if abs(value - quarters * math.pi / 2) < QUARTER_TURN_TOLERANCE:
            return ((1, 0), (0, 1), (-1, 0), (0, -1))[quarters % 4]
        return _exact_unit(math.cos(value)), _exact_unit(math.sin(value))
    return sp.cos(angle), sp.sin(angle)


def _exact_unit(x: float) -> sp.Expr:
    """x, with the rounding of floating point removed near 0 and +-1: cos(pi/2) is 6.1e-17,
    not 0, and that residue makes rotation matrices dense (about 30 % more operations in
    the generated code for the Panda). Entries within 1e-15 of 0 or +-1 become exact; the
    change is below the double precision of the angle itself."""
    if abs(x) < 1e-15:
        return sp.Integer(0)
    if abs(abs(x) - 1.0) < 1e-15:
        return sp.Integer(1 if x > 0 else -1)
    return sp.Float(x)


def exact_units(values) -> list[sp.Expr]:
    """Floats as SymPy numbers, entries within 1e-15 of 0 or +-1 made exact (see
    `_exact_unit`): for rotation matrices, axes and offsets computed in floating point."""
    return [_exact_unit(float(v)) for v in values]


def _rot_x(a):
    c, s = _trig(a)
    return sp.Matrix([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rot_y(a):
    c, s = _trig(a)
    return sp.Matrix([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rot_z(a):
    c, s = _trig(a)
    return sp.Matrix([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def vector(values) -> sp.ImmutableMatrix:
    return sp.ImmutableMatrix(3, 1, [sp.sympify(v) for v in values])


def inertia_matrix(ixx, iyy, izz, ixy=0, ixz=0, iyz=0) -> sp.ImmutableMatrix:
    return sp.ImmutableMatrix(
        [[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]
    ).applyfunc(sp.sympify)


IDENTITY = sp.ImmutableMatrix(sp.eye(3))
ZERO3 = sp.ImmutableMatrix(sp.zeros(3, 1))
ZERO33 = sp.ImmutableMatrix(sp.zeros(3, 3))
ZERO = sp.Integer(0)


@dataclass(frozen=True)
class Limits:
    lower: float | None = None
    upper: float | None = None
    effort: float | None = None
    velocity: float | None = None


@dataclass(frozen=True)
class Joint:
    """The joint that attaches a body to its parent."""

    name: str
    type: str
    origin_xyz: sp.ImmutableMatrix = ZERO3
    origin_rotation: sp.ImmutableMatrix = IDENTITY
    axis: sp.ImmutableMatrix = field(default_factory=lambda: vector([0, 0, 1]))
    limits: Limits | None = None
    mimic: str | None = None  # metadata only: a mimic joint is an independent coordinate
    # Joint terms (numbers or expressions in the parameters, >= 0 at the defaults):
    # viscous damping (tau += damping * qd), Coulomb friction (tau += friction * sign(qd))
    # and armature, the rotor inertia reflected at the joint (M_kk += armature).
    damping: sp.Expr = ZERO
    friction: sp.Expr = ZERO
    armature: sp.Expr = ZERO

    @property
    def moves(self) -> bool:
        return self.type != "fixed"

    @property
    def rotates(self) -> bool:
        return self.type in ("revolute", "continuous")

    @property
    def floating(self) -> bool:
        return self.type == "floating"

    @property
    def nq(self) -> int:
        """Configuration entries: 7 for a floating joint, 1 for a moving one, else 0."""
        return 7 if self.floating else int(self.moves)

    @property
    def nv(self) -> int:
        """Velocity coordinates: 6 for a floating joint, 1 for a moving one, else 0."""
        return 6 if self.floating else int(self.moves)

    @property
    def configuration_names(self) -> list[str]:
        if self.floating:
            return [f"{self.name}_{suffix}" for suffix in FLOATING_CONFIGURATION]
        return [self.name] if self.moves else []

    @property
    def velocity_names(self) -> list[str]:
        if self.floating:
            return [f"{self.name}_{suffix}" for suffix in FLOATING_VELOCITY]
        return [self.name] if self.moves else []


@dataclass(frozen=True)
class Body:
    """A rigid body; mass centre and central inertia are given in the body's frame."""

    name: str
    parent: str
    joint: Joint
    mass: sp.Expr = ZERO
    com: sp.ImmutableMatrix = ZERO3
    inertia: sp.ImmutableMatrix = ZERO33


@dataclass(frozen=True)
class Frame:
    """A named frame fixed to a body (or to the world): a link or a joint of the
    description whose body was merged into another (fixed joints), or welded to the world.
    `xyz` and `rotation` place it in the body's frame (rotation: its axes' components)."""

    name: str
    body: str
    xyz: sp.ImmutableMatrix = ZERO3
    rotation: sp.ImmutableMatrix = IDENTITY
    kind: str = "link"  # or "joint"


@dataclass(frozen=True)
class Model:
    """A validated tree of bodies. Bodies are stored parents first.

    `extra_frames` are the frames that are not a body's own: links merged into a body by
    fixed joints, their joints, links welded to the world. `frames` lists all of them."""

    name: str
    bodies: tuple[Body, ...]
    parameters: dict[str, float]
    gravity: sp.ImmutableMatrix
    source: str = "<model>"
    description: str = ""
    extra_frames: tuple[Frame, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "bodies", tuple(_tree_order(self.bodies, self.source)))
        object.__setattr__(self, "parameters", _with_friction_width(self.bodies,
                                                                    self.parameters))
        _validate(self)

    @property
    def moving_bodies(self) -> list[Body]:
        return [b for b in self.bodies if b.joint.moves]

    @property
    def coordinates(self) -> list[str]:
        """The names of the velocity coordinates, in the order of qd, qdd and tau (a
        floating joint's six first among its own: linear, then angular)."""
        return [name for b in self.moving_bodies for name in b.joint.velocity_names]

    @property
    def configuration(self) -> list[str]:
        """The names of the configuration entries, in the order of q (a floating joint's
        position, then its quaternion x, y, z, w)."""
        return [name for b in self.moving_bodies for name in b.joint.configuration_names]

    @property
    def dof(self) -> int:
        """The number of velocity coordinates (nv)."""
        return sum(b.joint.nv for b in self.moving_bodies)

    @property
    def nv(self) -> int:
        return self.dof

    @property
    def nq(self) -> int:
        """The number of configuration entries (nv plus one per floating joint)."""
        return sum(b.joint.nq for b in self.moving_bodies)

    @property
    def floating(self) -> bool:
        """Whether some body moves freely (a floating joint)."""
        return any(b.joint.floating for b in self.bodies)

    @property
    def frames(self) -> list[Frame]:
        """Every named frame: each body's own (its link, and its joint, whose frame is the
        body's: gagen's body frames are joint frames), then `extra_frames`. Names are
        unique: a joint named like a link (ANYmal C's link and joint `LF_HAA`) is listed
        as `joint:<name>`.

        A body's link frame is its joint frame unless `extra_frames` has a link frame named
        like the body and fixed to it: that one places it, in the body's place in the list
        (an MJCF body whose joints are anchored away from its origin: its frame is MuJoCo's
        body frame, its joint frame is at the last joint's anchor)."""
        frames: dict[str, Frame] = {}
        own = {f.name: f for f in self.extra_frames if f.kind == "link" and f.body == f.name}
        listed = [f for b in self.bodies
                  for f in (own.get(b.name, Frame(b.name, b.name)),
                            Frame(b.joint.name, b.name, kind="joint"))]
        placed = {id(f) for f in own.values()}
        entries = listed + [f for f in self.extra_frames if id(f) not in placed]
        # links keep their names wherever a joint of the same name comes in the list (an
        # MJCF body `tail1` whose first joint `tail1` sits on an intermediate body)
        links = {f.name for f in entries if f.kind == "link"}
        for f in entries:
            name = f"{f.kind}:{f.name}" if f.kind != "link" and f.name in links else f.name
            if name not in frames:
                frames[name] = replace(f, name=name)
        return list(frames.values())

    def body(self, name: str) -> Body:
        """The body called `name`."""
        for b in self.bodies:
            if b.name == name:
                return b
        raise KeyError(name)

    def indices(self) -> dict[str, tuple[int, int]]:
        """For each moving body, where its joint starts in q and in qd: (iq, iv)."""
        out, iq, iv = {}, 0, 0
        for b in self.moving_bodies:
            out[b.name] = (iq, iv)
            iq, iv = iq + b.joint.nq, iv + b.joint.nv
        return out

    @property
    def has_friction(self) -> bool:
        """Whether any joint has Coulomb friction (not structurally zero)."""
        return any(has_friction(b.joint) for b in self.bodies)

    @property
    def symbols(self) -> dict[str, sp.Symbol]:
        return {name: sp.Symbol(name) for name in self.parameters}

    def parameter_vector(self) -> np.ndarray:
        """The default parameters as a fresh array, in `parameters` order."""
        return np.fromiter(self.parameters.values(), dtype=float, count=len(self.parameters))

    def canonical(self) -> str:
        """A deterministic text of everything that defines the equations (for hashing)."""
        lines = [f"name={self.name}", f"gravity={sp.srepr(self.gravity)}"]
        lines += [f"param {k}={float(v)!r}" for k, v in self.parameters.items()]
        for b in self.bodies:
            j = b.joint
            lines.append(
                "|".join(
                    [
                        b.name, b.parent, j.name, j.type,
                        sp.srepr(j.origin_xyz), sp.srepr(j.origin_rotation), sp.srepr(j.axis),
                        sp.srepr(b.mass), sp.srepr(b.com), sp.srepr(b.inertia),
                    ] + _joint_terms_text(j)
                )
            )
        lines += ["frame " + "|".join([f.name, f.body, f.kind, sp.srepr(f.xyz),
                                        sp.srepr(f.rotation)]) for f in self.extra_frames]
        return "\n".join(lines)

    def content_hash(self) -> str:
        return hashlib.sha256(self.canonical().encode()).hexdigest()


def _joint_terms_text(joint: Joint) -> list[str]:
    """The joint terms for the canonical text; none when all are zero, so the keys of
    models without joint terms are what they were before joint terms existed."""
    terms = [sp.sympify(getattr(joint, key)) for key in JOINT_TERMS]
    if all(t.is_zero is True for t in terms):
        return []
    return [f"{key}={sp.srepr(t)}" for key, t in zip(JOINT_TERMS, terms)]


def has_friction(joint: Joint) -> bool:
    """Whether a joint's Coulomb friction is not structurally zero."""
    return joint.moves and not joint.floating and sp.sympify(joint.friction).is_zero is not True


def _with_friction_width(bodies, parameters) -> dict[str, float]:
    """The parameters, with the smooth-sign width added when a joint has friction."""
    out = dict(parameters)
    if FRICTION_WIDTH not in out and any(has_friction(b.joint) for b in bodies):
        out[FRICTION_WIDTH] = FRICTION_WIDTH_DEFAULT
    return out


def _tree_order(bodies, source: str) -> list[Body]:
    """Order bodies parents-first, keeping the given order where it already is one."""
    seen: set[str] = set()
    for b in bodies:
        if b.name in seen:
            raise ModelError(source, f"body '{b.name}'", "duplicate body name")
        if b.name == WORLD:
            raise ModelError(source, f"body '{b.name}'", f"'{WORLD}' is reserved for the fixed frame")
        seen.add(b.name)
    for b in bodies:
        if b.parent != WORLD and b.parent not in seen:
            raise ModelError(source, f"body '{b.name}'", f"unknown parent '{b.parent}'")
    placed = {WORLD}
    ordered: list[Body] = []
    remaining = list(bodies)
    while remaining:
        ready = [b for b in remaining if b.parent in placed]
        if not ready:
            cycle = ", ".join(sorted(b.name for b in remaining))
            raise ModelError(source, f"body '{remaining[0].name}'",
                             f"cyclic parent chain among bodies {cycle}: a model must be a tree")
        first = ready[0]
        ordered.append(first)
        placed.add(first.name)
        remaining.remove(first)
    return ordered


def _free_symbol_names(expr) -> set[str]:
    return {s.name for s in sp.sympify(expr).free_symbols}


def _numeric(expr, values: dict[sp.Symbol, float], source: str, element: str) -> float:
    """The value at the default parameters, which must be a finite real number."""
    try:
        value = complex(sp.sympify(expr).xreplace(values).evalf())
    except (TypeError, ValueError):
        raise ModelError(source, element, f"cannot evaluate '{expr}' to a number") from None
    if value.imag != 0:
        raise ModelError(source, element, f"'{expr}' is not real")
    if not math.isfinite(value.real):
        raise ModelError(source, element, f"'{expr}' is not finite at the default parameters")
    return value.real


def _validate(model: Model) -> None:
    src = model.source
    params = model.parameters
    for name, value in params.items():
        if not name:
            raise ModelError(src, "parameters", "a parameter needs a non-empty name")
        try:
            val = float(value)
        except (TypeError, ValueError):
            raise ModelError(src, f"parameter '{name}'", f"default value {value!r} is not a number") from None
        if not math.isfinite(val):
            raise ModelError(src, f"parameter '{name}'", f"default value {value!r} is not finite")
    declared = set(params)
    values = {sp.Symbol(k): sp.Float(float(v)) for k, v in params.items()}

    def check_symbols(expr, element: str) -> None:
        unknown = _free_symbol_names(expr) - declared
        if unknown:
            raise ModelError(src, element, "undeclared symbol(s) " + ", ".join(sorted(unknown))
                             + " (declare them under 'parameters')")

    check_symbols(model.gravity, "gravity")
    for entry in model.gravity:
        _numeric(entry, values, src, "gravity")
    coords: dict[str, str] = {}
    for b in model.bodies:
        j = b.joint
        where = f"body '{b.name}'"
        if j.type not in JOINT_TYPES:
            raise ModelError(src, f"{where}, joint '{j.name}'",
                             f"unknown joint type '{j.type}' (expected one of {', '.join(JOINT_TYPES)})")
        for label, expr in (("origin", j.origin_xyz), ("origin rotation", j.origin_rotation),
                            ("axis", j.axis), ("mass", b.mass), ("com", b.com),
                            ("inertia", b.inertia), ("damping", j.damping),
                            ("friction", j.friction), ("armature", j.armature)):
            check_symbols(expr, f"{where}, {label}")
        _check_joint_terms(j, values, src, f"{where}, joint '{j.name}'")
        if j.floating and b.parent != WORLD:
            raise ModelError(src, f"{where}, joint '{j.name}'", "a floating joint must attach "
                             f"its body to '{WORLD}' (its parent is '{b.parent}')")
        for name in dict.fromkeys(j.configuration_names + j.velocity_names):
            if name in coords:
                raise ModelError(src, f"{where}, joint '{j.name}'",
                                 f"duplicate coordinate name '{name}' (also used by body "
                                 f"'{coords[name]}')")
            coords[name] = b.name
        if j.moves and not j.floating:
            axis = np.array([_numeric(a, values, src, f"{where}, axis") for a in j.axis])
            if not np.linalg.norm(axis) > 1e-12:
                raise ModelError(src, f"{where}, joint '{j.name}'", "zero joint axis")
        for label, vec in (("joint origin xyz", j.origin_xyz), ("com", b.com)):
            for entry in vec:
                _numeric(entry, values, src, f"{where}, {label}")
        mass = _numeric(b.mass, values, src, f"{where}, mass")
        if mass < 0 or not math.isfinite(mass):
            raise ModelError(src, f"{where}, mass", f"mass must be non-negative, got {mass:g}")
        check_tensor(_inertia_value(b, values, src), src, f"{where}, inertia")
    # The reader of the file warned about (or refused) a borderline inertia once; what is
    # physical or not is the inertia of each rigid unit (a moving body and the bodies
    # welded to it), which is what enters the equations.
    for unit in rigid_units(model, values):
        check_inertia(unit.inertia, src, unit.element(*_NAMING.get()), borderline="accept",
                      floor=unit.floor)
    if model.has_friction and float(params[FRICTION_WIDTH]) < 0:
        raise ModelError(src, f"parameter '{FRICTION_WIDTH}'",
                         "the width of the smoothed Coulomb friction must be >= 0")


def _check_joint_terms(joint: Joint, values: dict, source: str, element: str) -> None:
    """Damping, friction and armature: finite and non-negative at the defaults; only a
    1-dof joint has them (a fixed joint has no coordinate to act on, a floating one is no
    drive)."""
    for key in JOINT_TERMS:
        expr = sp.sympify(getattr(joint, key))
        if expr.is_zero is True:
            continue
        if not joint.moves or joint.floating:
            raise ModelError(source, f"{element}, {key}",
                             f"a {joint.type} joint cannot have damping, friction or "
                             "armature (only revolute, continuous and prismatic joints)")
        value = _numeric(expr, values, source, f"{element}, {key}")
        if value < 0:
            raise ModelError(source, f"{element}, {key}",
                             f"{key} must be non-negative, got {value:g}")


def _inertia_value(body: Body, values: dict[sp.Symbol, float], source: str) -> np.ndarray:
    where = f"body '{body.name}', inertia"
    return np.array([[_numeric(e, values, source, where) for e in row]
                     for row in body.inertia.tolist()])


def check_model_inertias(model: Model, strict: bool = False, noun: str = "body",
                         field: str = "inertia") -> None:
    """Check a Model's inertias at its default parameters, as the readers of files do.

    What must be physical is each rigid unit: a moving body together with the bodies welded
    to it by fixed joints (a sensor or a flange on a link), since that combined inertia is
    what the equations contain; bodies welded to the world do not move and are not
    checked. A borderline unit warns (`InertiaWarning`), or is refused when `strict`; a
    grossly non-physical one is refused. A welded part whose own inertia is off while its
    unit's is physical (CAD exports give sensor links such inertias: ANYmal C's depth
    cameras, Tiago's antennas) is accepted with a warning naming it, or refused when
    `strict`. Errors and warnings name each body as the file does (`noun`, `field`: a URDF
    says "link 'x', inertial inertia")."""
    values = {sp.Symbol(k): sp.Float(float(v)) for k, v in model.parameters.items()}
    for unit in rigid_units(model, values):
        check_inertia(unit.inertia, model.source, unit.element(noun, field), strict=strict,
                      floor=unit.floor)
        if not unit.parts:
            continue  # the unit is its body: checked just now
        for name, inertia, floor in unit.members:
            defect, _ = _inertia_defect(np.linalg.eigvalsh(inertia), floor)
            if defect is None:
                continue
            element = f"{noun} '{name}', {field}"
            unit_text = f"the rigid unit of {noun} '{unit.body}' and the {noun}s welded to it"
            if strict:
                raise ModelError(model.source, element, f"{defect}; refused because "
                                 f"strict=True ({unit_text} has a physical combined inertia: "
                                 "load with strict=False to accept it with a warning)")
            warn_user(one_line(f"{model.source}: {element}: {defect}; accepted: "
                               f"{unit_text} has a physical combined inertia, which is "
                               "what moves (strict=True refuses it)"), InertiaWarning)


# How errors about bodies name them: a URDF reader says "link 'x', inertial inertia"
# while it builds its Model (`naming`).
_NAMING: contextvars.ContextVar[tuple[str, str]] = contextvars.ContextVar(
    "gagen_body_naming", default=("body", "inertia"))


@contextlib.contextmanager
def naming(noun: str, field: str):
    """Within the block, Models name their bodies' inertias as `<noun> 'x', <field>`."""
    token = _NAMING.set((noun, field))
    try:
        yield
    finally:
        _NAMING.reset(token)


@dataclass(frozen=True)
class RigidUnit:
    """A moving body and the bodies welded to it: their combined central inertia (in the
    moving body's axes) and, for each welded part, its own central inertia; each with the
    size below which a defect of it is round-off (`round_off_floor`)."""

    body: str
    inertia: np.ndarray
    parts: tuple[tuple[str, np.ndarray, float], ...]  # (name, own inertia, floor)
    own: np.ndarray  # the moving body's own central inertia
    floor: float = 0.0  # of the combined inertia
    own_floor: float = 0.0

    @property
    def members(self) -> tuple[tuple[str, np.ndarray, float], ...]:
        """Every body of the unit with its own central inertia and its round-off floor, the
        moving one first."""
        return ((self.body, self.own, self.own_floor), *self.parts)

    def element(self, noun: str = "body", field: str = "inertia") -> str:
        """How an error names the unit: `body 'x' (with 2 welded bodies), inertia`."""
        count = len(self.parts)
        plural = {"body": "bodies"}.get(noun, noun + "s") if count != 1 else noun
        welded = f" (with {count} welded {plural})" if count else ""
        return f"{noun} '{self.body}'{welded}, {field}"


def rigid_units(model: Model, values: dict[sp.Symbol, float]) -> list[RigidUnit]:
    """The rigid units of a model (numerically, at `values`): each moving body with the
    bodies welded to it through fixed joints."""
    frames: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}  # body -> (unit, R, d)
    members: dict[str, list[tuple[Body, np.ndarray, np.ndarray]]] = {}
    for b in model.bodies:
        if b.joint.moves:
            frames[b.name] = (b.name, np.eye(3), np.zeros(3))
            members[b.name] = [(b, np.eye(3), np.zeros(3))]
        elif b.parent in frames:
            unit, R, d = frames[b.parent]
            R0 = _numeric_matrix(b.joint.origin_rotation, values, model.source,
                                 f"body '{b.name}', origin rotation")
            d0 = _numeric_matrix(b.joint.origin_xyz, values, model.source,
                                 f"body '{b.name}', joint origin xyz").ravel()
            frames[b.name] = (unit, R @ R0, d + R @ d0)
            members[unit].append((b, R @ R0, d + R @ d0))
    units = []
    for name, parts in members.items():
        mass, first, inertia, own, reach = 0.0, np.zeros(3), np.zeros((3, 3)), [], 0.0
        for b, R, d in parts:
            where = f"body '{b.name}'"
            m = _numeric(b.mass, values, model.source, f"{where}, mass")
            com = _numeric_matrix(b.com, values, model.source, f"{where}, com").ravel()
            c = d + R @ com
            I_c = R @ _inertia_value(b, values, model.source) @ R.T
            mass, first = mass + m, first + m * c
            inertia += I_c + m * (c @ c * np.eye(3) - np.outer(c, c))
            reach = max(reach, float(np.linalg.norm(c)))
            own.append((b.name, _inertia_value(b, values, model.source),
                        round_off_floor(m, float(np.linalg.norm(com)))))
        centre = first / mass if mass > 0 else np.zeros(3)
        central = inertia - mass * (centre @ centre * np.eye(3) - np.outer(centre, centre))
        # the combined inertia sums the parts' m c c^T about the body's origin: its
        # round-off scales with the farthest mass centre
        (_, own_inertia, own_floor), *welded = own
        units.append(RigidUnit(name, (central + central.T) / 2, tuple(welded), own_inertia,
                               round_off_floor(mass, reach), own_floor))
    return units


def _numeric_matrix(matrix, values, source: str, element: str) -> np.ndarray:
    return np.array([[_numeric(e, values, source, element) for e in row]
                     for row in sp.Matrix(matrix).tolist()])


# Real CAD exports round their inertias, and some are hand-tuned: the Allegro hand of
# example-robot-data has links whose largest principal moment exceeds the sum of the other
# two by 20 % of itself (2.30e-6 + 3.49e-6 < 7.27e-6), and Pinocchio loads it. Such a
# tensor is accepted with an InertiaWarning up to these margins, as fractions of the largest
# principal moment; strict=True refuses it, and anything beyond them is refused always.
# The triangle inequality only decides whether some mass distribution has these moments
# (the equations stay well posed), so its margin is wide; a negative principal moment can
# make M(q) indefinite, so that margin is narrow.
INERTIA_TRIANGLE_TOLERANCE = 0.25
INERTIA_DEFINITE_TOLERANCE = 1e-2
# Below this (relative) no defect is reported at all: floating-point rounding of R I R^T.
_ROUNDING = 1e-9
# Round-off around a zero inertia: a point mass has a largest principal moment of zero,
# so no defect is small relative to it, yet exporters write such inertias with
# round-off (example-robot-data's icub: ixx = iyy = -5.4e-20, izz = 0, on a 0.53 kg link
# whose mass centre is 3 cm from its frame; 5.4e-20 = 2^-64 is the largest rounding error
# of a number near m |c|^2 = 4.9e-4). A defect is also round-off when it is below _ROUNDING
# of m l^2, the moment of the body's mass at the distance l of its mass centre from the
# body's frame (l at least ROUND_OFF_LENGTH): the scale of what the body adds to M(q).
ROUND_OFF_LENGTH = 0.01  # m
BORDERLINE = ("warn", "refuse", "accept")


def round_off_floor(mass: float, length: float) -> float:
    """The size below which a defect of the central inertia of a body of `mass` whose mass
    centre is `length` from its frame is round-off (see ROUND_OFF_LENGTH)."""
    return _ROUNDING * max(mass, 0.0) * max(length, ROUND_OFF_LENGTH) ** 2


def check_inertia(inertia: np.ndarray, source: str, element: str, strict: bool = False,
                  borderline: str | None = None, floor: float = 0.0) -> None:
    """Refuse a central inertia tensor that no rigid body can have; warn for CAD round-off.

    A tensor that breaks positive-definiteness or the triangle inequality by at most
    `INERTIA_DEFINITE_TOLERANCE` / `INERTIA_TRIANGLE_TOLERANCE` of its largest principal
    moment is borderline: it gets a `gagen.errors.InertiaWarning` naming the element and
    the defect, or a ModelError when `strict`. `borderline` ("warn", "refuse", "accept")
    overrides that choice: a Model's own validation accepts silently, since the reader
    of the file has already warned or refused once. A defect below `floor` (kg m^2,
    `round_off_floor` of the body's mass and size) or below 1e-9 of the largest moment is
    round-off, not a defect: a point mass or a rod written with round-off is physical.
    """
    mode = borderline or ("refuse" if strict else "warn")
    if mode not in BORDERLINE:
        raise ValueError(f"borderline must be one of {', '.join(BORDERLINE)}, got {mode!r}")
    check_tensor(inertia, source, element)
    defect, tolerance = _inertia_defect(np.linalg.eigvalsh(inertia), floor)
    if defect is None:
        return
    if not tolerance:
        raise ModelError(source, element, f"{defect}. Fix the inertia in the file: gagen "
                         "accepts the round-off of CAD exports with a warning (unless "
                         f"strict=True), up to {INERTIA_DEFINITE_TOLERANCE:g} of the largest "
                         f"moment below zero and {INERTIA_TRIANGLE_TOLERANCE:g} of it beyond "
                         "the triangle inequality, not this far")
    if mode == "refuse":
        raise ModelError(source, element, f"{defect}; within what gagen accepts from CAD "
                         f"exports ({tolerance}) but refused because strict=True (load with "
                         "strict=False to accept it with a warning, or fix the inertia)")
    if mode == "warn":
        warn_user(one_line(f"{source}: {element}: {defect}; within what gagen accepts "
                           f"from CAD exports ({tolerance}), loaded anyway (strict=True "
                           "refuses it)"), InertiaWarning)


def check_tensor(inertia: np.ndarray, source: str, element: str) -> None:
    """An inertia tensor at all: finite and symmetric (physical or not is another check)."""
    if not np.all(np.isfinite(inertia)):
        raise ModelError(source, element, "inertia has non-finite entries")
    if not np.allclose(inertia, inertia.T, rtol=0, atol=1e-12 * max(1.0, np.abs(inertia).max())):
        raise ModelError(source, element, "inertia tensor is not symmetric")


def _inertia_defect(eig: np.ndarray, floor: float = 0.0) -> tuple[str | None, str]:
    """(the defect of sorted principal moments, or None; the tolerance it is within, or "").
    Defects below `floor` or _ROUNDING of the largest moment are round-off (no defect)."""
    scale = max(1e-300, np.abs(eig).max())
    round_off = max(_ROUNDING * scale, floor)
    moments = eig.tolist()
    a, b, c = eig
    if a < -round_off:
        defect = f"inertia tensor is not positive semi-definite (principal moments {moments})"
        within = -a <= INERTIA_DEFINITE_TOLERANCE * scale
        return defect, f"{INERTIA_DEFINITE_TOLERANCE:g} of the largest moment" if within else ""
    excess = (c - a - b) / scale
    if c - a - b > round_off:
        defect = (f"principal moments {moments} break the triangle inequality (each must be "
                  f"at most the sum of the other two; the largest exceeds it by {excess:.3g} "
                  "of itself)")
        within = excess <= INERTIA_TRIANGLE_TOLERANCE
        return defect, f"{INERTIA_TRIANGLE_TOLERANCE:g} of the largest moment" if within else ""
    return None, ""
