"""What the runtime knows of a model without SymPy: names, joints, parameters.

A compiled module carries its manifest as hex-encoded JSON (`MANIFEST_HEX`): hex digits
are the only text of the model that reaches generated code, so no name from a description
can end a string or a comment there. Loading a cached model reads the manifest instead of
the model file, and SymPy is never imported.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from functools import cached_property

import numpy as np

from .constraints import Constraint, ConstraintInfo, constraint_infos

# joint kinds in the tables of frame kinematics (manifest, frames.c)
JOINT_KINDS = {"fixed": 0, "revolute": 1, "continuous": 1, "prismatic": 2, "floating": 3}

# per second: how fast the rate of a floating joint's quaternion pulls it back onto the unit
# sphere in simulations (gagen.runtime.manifold.configuration_rate; the compiled integrators
# print this number)
QUATERNION_RESTORING = 1.0

# the suffixes of a floating joint's configuration entries and velocity coordinates
# (gagen.model.model.FLOATING_CONFIGURATION / FLOATING_VELOCITY, repeated here because the
# runtime does not import the model stage)
CONFIGURATION = ("x", "y", "z", "qx", "qy", "qz", "qw")
VELOCITY = ("vx", "vy", "vz", "wx", "wy", "wz")


def joint_names(joint: JointInfo, suffixes: tuple[str, ...]) -> list[str]:
    """A joint's entry names: its own name, or for a floating joint one per suffix."""
    if joint.type == "floating":
        return [f"{joint.name}_{suffix}" for suffix in suffixes]
    return [joint.name]

# The runtime parameter that holds the width w of the smooth sign tanh(qd / w) with which
# simulations integrate Coulomb friction (gagen.model.model adds it to models with friction).
FRICTION_WIDTH = "coulomb_width"


@dataclass(frozen=True)
class JointInfo:
    """A moving joint: its coordinate's name, type and limits (None where not given)."""

    name: str
    type: str
    lower: float | None = None
    upper: float | None = None
    effort: float | None = None
    velocity: float | None = None


@dataclass(frozen=True)
class ModelInfo:
    """The numbers and names of a model that the runtime needs (no symbolic content)."""

    name: str
    joints: tuple[JointInfo, ...]
    parameters: tuple[tuple[str, float], ...]
    source: str = ""
    # the tree, for frame kinematics: per body (parent body or -1, joint kind, its first
    # velocity coordinate or -1); per named frame (name, body or -1 for the world, and
    # "link" or "joint")
    bodies: tuple[tuple[int, int, int], ...] = ()
    frames: tuple[tuple[str, int, str], ...] = ()
    # the moving bodies (fixed ones merged in), in coordinate order: the regressor's
    # columns are named after them
    moving_bodies: tuple[str, ...] = ()
    # contacts and closed loops (gagen.constraints), in declaration order
    constraints: tuple[Constraint, ...] = ()

    @cached_property
    def constraint_infos(self) -> tuple[ConstraintInfo, ...]:
        """`dyn.constraints`: each constraint with its rows in the stacked forces."""
        return tuple(constraint_infos(self.constraints))

    @property
    def constraint_rows(self) -> int:
        """The rows of every declared constraint together."""
        return sum(c.dimension for c in self.constraints)

    @cached_property
    def frame_indices(self) -> dict[str, int]:
        """Frame name -> index in `frames` (looked up on every frame call)."""
        indices: dict[str, int] = {}
        for k, (name, _, _) in enumerate(self.frames):
            indices.setdefault(name, k)
        return indices

    @cached_property
    def moving_tree(self) -> tuple[tuple[int, int, int, int], ...]:
        """Per moving body (in `bodies`' order, parents first: the order of the regressor's
        parameters and of `moving_bodies`): (its index in `bodies`, its nearest moving
        ancestor's index in this list or -1, its joint's kind, its first velocity
        coordinate). A fixed body belongs to its moving ancestor; one welded to the world
        to nothing that moves (the centre of mass leaves it out, as Pinocchio does)."""
        fixed = JOINT_KINDS["fixed"]
        slot: dict[int, int] = {}
        tree = []
        for body, (parent, kind, column) in enumerate(self.bodies):
            if kind == fixed:
                continue
            while parent >= 0 and parent not in slot:  # a fixed ancestor: look past it
                parent = self.bodies[parent][0]
            slot[body] = len(tree)
            tree.append((body, slot[parent] if parent >= 0 else -1, kind, column))
        return tuple(tree)

    @property
    def coordinates(self) -> list[str]:
        """The velocity coordinates' names (a floating joint's six: `<joint>_vx` ...)."""
        return [name for joint in self.joints for name in joint_names(joint, VELOCITY)]

    @property
    def configuration(self) -> list[str]:
        """The configuration entries' names, in the order of q (`<joint>_x` ... `_qw`)."""
        return [name for joint in self.joints for name in joint_names(joint, CONFIGURATION)]

    @property
    def dof(self) -> int:
        """The number of velocity coordinates (nv)."""
        return len(self.coordinates)

    @property
    def nq(self) -> int:
        return len(self.configuration)

    def floating_joints(self) -> list[tuple[int, int]]:
        """(first entry in q, first coordinate in qd) of each floating joint."""
        out, iq, iv = [], 0, 0
        for joint in self.joints:
            if joint.type == "floating":
                out.append((iq, iv))
            iq += len(joint_names(joint, CONFIGURATION))
            iv += len(joint_names(joint, VELOCITY))
        return out

    def quaternions(self) -> tuple[tuple[int, str], ...]:
        """(first entry in q, description) of each floating joint's quaternion, for the
        input checks (gagen.runtime.inputs.check_quaternions)."""
        out = []
        for (iq, _), joint in zip(self.floating_joints(),
                                  [j for j in self.joints if j.type == "floating"]):
            names = ", ".join(joint_names(joint, CONFIGURATION)[3:])
            label = (f"q[{iq + 3}:{iq + 7}] ({names}), the quaternion of floating joint "
                     f"{joint.name!r},")
            out.append((iq + 3, label))
        return tuple(out)

    @property
    def parameter_defaults(self) -> dict[str, float]:
        return dict(self.parameters)

    def jointed_coordinates(self) -> list[int]:
        """The velocity coordinate of each 1-dof joint (a floating joint's six skipped): the
        coordinates of the regressor's damping, friction and armature columns."""
        out, k = [], 0
        for joint in self.joints:
            if joint.type == "floating":
                k += len(VELOCITY)
            else:
                out.append(k)
                k += 1
        return out

    @property
    def regressor_names(self) -> list[str]:
        """The names of the regressor's columns (`regressor_names`)."""
        return regressor_names(self.moving_bodies, [j.name for j in self.joints
                                                    if j.type != "floating"])

    def parameter_vector(self) -> np.ndarray:
        """The default parameters in declaration order."""
        return np.array([value for _, value in self.parameters], dtype=float)

    def to_hex(self) -> str:
        """The manifest as hex digits of UTF-8 JSON, safe to print into any source file."""
        data = {"name": self.name, "source": self.source,
                "joints": [asdict(joint) for joint in self.joints],
                "parameters": [list(item) for item in self.parameters],
                "bodies": [list(item) for item in self.bodies],
                "frames": [list(item) for item in self.frames],
                "moving_bodies": list(self.moving_bodies)}
        if self.constraints:  # absent otherwise: unconstrained models' manifests as before
            data["constraints"] = [[c.name, c.type, list(c.frames), list(c.axes), c.reference]
                                   for c in self.constraints]
        return json.dumps(data, sort_keys=True, ensure_ascii=False).encode().hex()

    @classmethod
    def from_hex(cls, text: str) -> ModelInfo:
        data = json.loads(bytes.fromhex(text).decode())
        return cls(name=data["name"], source=data["source"],
                   joints=tuple(JointInfo(**joint) for joint in data["joints"]),
                   parameters=tuple((name, float(value)) for name, value in data["parameters"]),
                   bodies=tuple(tuple(int(x) for x in b) for b in data.get("bodies", ())),
                   frames=tuple((str(name), int(b), str(kind))
                                for name, b, kind in data.get("frames", ())),
                   moving_bodies=tuple(data.get("moving_bodies", ())),
                   constraints=tuple(
                       Constraint(str(name), str(kind), tuple(str(f) for f in frames),
                                  tuple(int(a) for a in axes), str(reference))
                       for name, kind, frames, axes, reference in data.get("constraints", ())))

    @classmethod
    def from_model(cls, model) -> ModelInfo:
        """The manifest of a `gagen.model.Model` (duck-typed: no import of the model stage)."""
        joints = []
        for body in model.moving_bodies:
            limits = body.joint.limits
            values = {} if limits is None else {key: getattr(limits, key) for key in
                                                ("lower", "upper", "effort", "velocity")}
            joints.append(JointInfo(body.joint.name, body.joint.type,
                                    **{k: None if v is None else float(v)
                                       for k, v in values.items()}))
        index = {b.name: k for k, b in enumerate(model.bodies)}
        starts = model.indices()
        bodies = tuple((index.get(b.parent, -1), JOINT_KINDS[b.joint.type],
                        starts.get(b.name, (0, -1))[1]) for b in model.bodies)
        frames = tuple((f.name, index.get(f.body, -1), f.kind) for f in model.frames)
        return cls(name=model.name, joints=tuple(joints), source=str(model.source or ""),
                   parameters=tuple((name, float(value))
                                    for name, value in model.parameters.items()),
                   bodies=bodies, frames=frames,
                   moving_bodies=tuple(body.name for body in model.moving_bodies),
                   constraints=tuple(getattr(model, "constraints", ())))


# A moving body's inertial parameters in the regressor, Pinocchio's order (its
# Inertia.toDynamicParameters): mass, first moment m c, and the inertia about the body
# frame's origin O (not about the mass centre, unlike a URDF's <inertia>).
BODY_PARAMETERS = ("m", "mcx", "mcy", "mcz", "IOxx", "IOxy", "IOyy", "IOxz", "IOyz", "IOzz")
# Then, per 1-dof joint (not a floating one), the joint terms (gagen.symbolic.joints).
JOINT_PARAMETERS = ("damping", "friction", "armature")


def regressor_names(bodies, joints) -> list[str]:
    """The regressor's columns: `<parameter>_<body>` for each moving body's 10 inertial
    parameters (BODY_PARAMETERS), then `damping_<joint>` for every 1-dof joint,
    `friction_<joint>` and `armature_<joint>`."""
    names = [f"{key}_{body}" for body in bodies for key in BODY_PARAMETERS]
    return names + [f"{key}_{joint}" for key in JOINT_PARAMETERS for joint in joints]


def dof_parents(bodies, n: int) -> list[int]:
    """Per velocity coordinate, the one before it on its path to the world (-1: none), from
    the tree (parent, joint kind, first coordinate) per body: Featherstone's λ, the sparsity
    of M that its factorisation M = Lᵀ D L keeps (the generated C's and the runtime's)."""
    sizes = {JOINT_KINDS["fixed"]: 0, JOINT_KINDS["floating"]: 6}
    last: list[int] = []  # per body, the last coordinate on its path (-1: none)
    out = [-1] * n
    for parent, kind, column in bodies:
        before = last[parent] if parent >= 0 else -1
        size = sizes.get(kind, 1)
        for k in range(size):
            out[column + k] = before if k == 0 else column + k - 1
        last.append(column + size - 1 if size else before)
    return out


def chain_order(bodies, body: int, nv: int) -> np.ndarray:
    """order[k, j] = 1 where coordinates k and j are on the body's chain to the world and
    k's joint is j's or above it (a floating joint's six coordinates are each other's)."""
    joints = []
    while body >= 0:
        parent, kind, column = bodies[body]
        if kind:  # fixed joints (0) have no coordinate
            joints.append(range(column, column + (6 if kind == JOINT_KINDS["floating"] else 1)))
        body = parent
    rank = np.full(nv, -1)
    for r, columns in enumerate(reversed(joints)):
        rank[list(columns)] = r
    on = rank >= 0
    return (on[:, None] & on[None, :] & (rank[:, None] <= rank[None, :])).astype(float)


# a constraint's row of the derivatives' table (gagen_constraint_derivatives.h's
# GAGEN_CD_TABLE): frame A, frame B (-1: the world), holds a frame, local, its number of
# axes, its axes
CONSTRAINT_TABLE = 11


def constraint_derivative_layout(info: ModelInfo) -> dict[str, np.ndarray]:
    """The tables of gagen_constraint_derivatives.h's gagen_cd_model for every declared
    constraint (the generated C prints them; the runtime's C reads them): the table (frames
    numbered among the constraints' distinct frames, in order of first appearance), those
    frames' numbers and bodies, each one's chain of coordinates root first (chain,
    chain_len), per chain position its joint's first and one-past-last position
    (group_start, group_end), the chains' order (f, nv, nv), the coordinates' parents and
    descendants (CSR: desc_ptr, desc) and where each quaternion starts in q. int32 arrays
    but order (float64)."""
    nv = info.dof
    names = list(dict.fromkeys(f for c in info.constraints
                               for f in c.frames[:2 if c.type == "loop" else 1]))
    index = {name: i for i, name in enumerate(names)}
    table = np.zeros((len(info.constraints), CONSTRAINT_TABLE), dtype=np.int32)
    for row, c in enumerate(info.constraints):
        table[row, :5] = (index[c.frames[0]], index[c.frames[1]] if c.type == "loop" else -1,
                          c.holds_frame, c.reference == "local", len(c.axes))
        table[row, 5: 5 + len(c.axes)] = c.axes
    frames = np.array([info.frame_indices[name] for name in names], dtype=np.int32)
    bodies = np.array([info.frames[k][1] for k in frames], dtype=np.int32)
    order = np.zeros((len(names), nv, nv))
    for f, body in enumerate(bodies):
        order[f] = chain_order(info.bodies, int(body), nv)
    chain = np.zeros((len(names), nv), dtype=np.int32)
    chain_len = np.zeros(len(names), dtype=np.int32)
    start, end = np.zeros_like(chain), np.zeros_like(chain)
    for f in range(len(names)):
        on = np.flatnonzero(np.diagonal(order[f]))
        chain[f, :len(on)] = on  # coordinates in q's order: a root's before its subtree's
        chain_len[f] = len(on)
        for i in range(len(on)):  # a joint's coordinates are each other's (a floating one)
            joined = i > 0 and order[f, on[i], on[i - 1]] != 0
            start[f, i] = start[f, i - 1] if joined else i
        for i in range(len(on) - 1, -1, -1):
            joined = i + 1 < len(on) and start[f, i + 1] == start[f, i]
            end[f, i] = end[f, i + 1] if joined else i + 1
    parents = dof_parents(info.bodies, nv)
    below: list[list[int]] = [[] for _ in range(nv)]  # each coordinate's descendants
    for k in range(nv):
        i = parents[k]
        while i >= 0:
            below[i].append(k)
            i = parents[i]
    return {"table": table, "frames": frames, "bodies": bodies, "chain": chain,
            "chain_len": chain_len, "group_start": start, "group_end": end, "order": order,
            "parent": np.array(parents, dtype=np.int32),
            "desc_ptr": np.cumsum([0] + [len(b) for b in below]).astype(np.int32),
            "desc": np.array([k for b in below for k in b] or [0], dtype=np.int32),
            "quat": np.array([offset for offset, _ in info.quaternions()], dtype=np.int32)}
