"""Constraints a model is built with: contacts (a frame held in the world) and loops (two
frames held together), their axes and reference (Pinocchio's meanings), checked; no SymPy.

A constraint holds some of the six axes of a frame's motion, in the order x, y, z (the
translation of its origin) then rx, ry, rz (the rotation), in `reference`:
"local_world_aligned" (world axes, at the frame's origin: the default) or "local" (the
frame's own axes). Its rows follow Pinocchio's RigidConstraintModel:

- a constraint of translation axes only holds a point (Pinocchio's CONTACT_3D): its rows
  are the velocity of frame A's origin less that of frame B's (of the world: zero), and its
  drift J̇ q̇ is their classical accelerations' difference;
- a constraint with a rotation axis holds a frame (CONTACT_6D): its rows are the relative
  spatial velocity of A's body and B's, at A's origin, and its drift their spatial
  accelerations' difference (plus, in "local", the cross product of the two velocities).

A subset of axes is those rows of the 3-D (translation only) or 6-D (with a rotation)
constraint. In "local" the rows are those of "local_world_aligned" turned into frame A's
axes. Forces are in the same axes: the force (and moment) that the constraint applies to
frame A's body at A's origin (and its opposite to B's body).

A contact holds its frame at an anchor in the world: the runtime parameters
`anchor_<name>_x`, `_y`, `_z` (where its origin is held) and, with a rotation axis,
`anchor_<name>_roll`, `_pitch`, `_yaw` (URDF's roll-pitch-yaw of its axes), by default the
frame's placement at the neutral configuration. Only the Baumgarte correction and the
reported violation read them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from .errors import ModelError

AXES = ("x", "y", "z", "rx", "ry", "rz")
REFERENCES = ("local_world_aligned", "local")
TYPES = ("contact", "loop")
# Bounds on what a description can make the generated code hold: the compiled kernels keep
# a constraint set's rows (m x nv Jacobian, m x m Delassus matrix) on the stack.
MAX_CONSTRAINTS = 64
MAX_ROWS = 120
MAX_ROW_ENTRIES = 65536  # rows x nv
ANCHOR_POSITION = ("x", "y", "z")
ANCHOR_ROTATION = ("roll", "pitch", "yaw")


@dataclass(frozen=True)
class Contact:
    """A frame held in the world: `axes` "3d" (its origin), "6d" (the frame) or a subset of
    ["x", "y", "z", "rx", "ry", "rz"], in `reference` "local_world_aligned" or "local"
    (Pinocchio's meanings). `name` defaults to the frame's."""

    frame: str
    axes: str | Sequence[str] = "3d"
    reference: str = "local_world_aligned"
    name: str | None = None


@dataclass(frozen=True)
class Loop:
    """Two frames held together (a closed kinematic loop): frame_a's origin on frame_b's
    ("3d"), the frames on each other ("6d"), or a subset of the axes, in `reference` of
    frame_a. `name` defaults to "<frame_a>_<frame_b>"."""

    frame_a: str
    frame_b: str
    axes: str | Sequence[str] = "3d"
    reference: str = "local_world_aligned"
    name: str | None = None


@dataclass(frozen=True)
class Constraint:
    """A checked constraint of a model: its name, type, frames (one for a contact, two for a
    loop), axes (indices into AXES, in order) and reference."""

    name: str
    type: str
    frames: tuple[str, ...]
    axes: tuple[int, ...]
    reference: str

    @property
    def dimension(self) -> int:
        return len(self.axes)

    @property
    def holds_frame(self) -> bool:
        """Whether it has a rotation axis: the 6-D (spatial) convention, else the 3-D (point)."""
        return any(a >= 3 for a in self.axes)

    @property
    def axis_names(self) -> tuple[str, ...]:
        return tuple(AXES[a] for a in self.axes)

    def anchor_names(self) -> list[str]:
        """A contact's anchor parameters (module docstring); none for a loop."""
        if self.type != "contact":
            return []
        keys = ANCHOR_POSITION + (ANCHOR_ROTATION if self.holds_frame else ())
        return [anchor_parameter(self.name, key) for key in keys]

    def canonical(self) -> str:
        """Everything that defines it, as text (models' hashes)."""
        return "|".join([self.name, self.type, ",".join(self.frames),
                         ",".join(map(str, self.axes)), self.reference])


def anchor_parameter(constraint: str, key: str) -> str:
    """The name of a contact's anchor parameter: `anchor_<constraint>_<key>`."""
    return f"anchor_{constraint}_{key}"


@dataclass(frozen=True)
class ConstraintInfo:
    """One of `dyn.constraints`: its name, type ("contact" or "loop"), frames, axes in the
    order of its rows, reference, dimension (its number of rows) and `rows`, its rows in the
    forces that `constrained_forward_dynamics` and `impulse_dynamics` return (every declared
    constraint's, in declaration order)."""

    name: str
    type: str
    frames: tuple[str, ...]
    axes: tuple[str, ...]
    reference: str
    dimension: int
    rows: slice

    @property
    def holds_frame(self) -> bool:
        """True: the 6-D convention (a rotation axis); False: the 3-D one (a point)."""
        return any(a.startswith("r") for a in self.axes)


def constraint_infos(constraints: Sequence[Constraint]) -> list[ConstraintInfo]:
    """`dyn.constraints` of checked constraints."""
    out, row = [], 0
    for c in constraints:
        out.append(ConstraintInfo(c.name, c.type, c.frames, c.axis_names, c.reference,
                                  c.dimension, slice(row, row + c.dimension)))
        row += c.dimension
    return out


# --- reading what a user or a description declares -----------------------------------------

def checked_constraints(entries, source: str, element: str = "constraints",
                        taken: Sequence[Constraint] = ()) -> tuple[Constraint, ...]:
    """Entries (Contact, Loop, or dicts as in a model file's `constraints:` list) as checked
    Constraints; ModelError naming the entry for anything wrong. Frames are checked against
    the model later (gagen.model.model); names must be unique, also among `taken`."""
    if isinstance(entries, (Contact, Loop, Mapping)):
        entries = [entries]
    if isinstance(entries, (str, bytes)) or not isinstance(entries, Sequence):
        raise ModelError(source, element, "expected a list of constraints (gagen.Contact, "
                         "gagen.Loop, or mappings with type, frame(s), axes, reference)")
    if len(entries) + len(taken) > MAX_CONSTRAINTS:
        raise ModelError(source, element, f"{len(entries) + len(taken)} constraints; a "
                         f"model has at most {MAX_CONSTRAINTS}")
    out = list(taken)
    for k, entry in enumerate(entries):
        where = f"{element}[{k}]"
        constraint = _one(entry, source, where)
        if any(c.name == constraint.name for c in out):
            raise ModelError(source, where, f"duplicate constraint name "
                             f"{_quote(constraint.name)}")
        out.append(constraint)
    if sum(c.dimension for c in out) > MAX_ROWS:
        raise ModelError(source, element, f"{sum(c.dimension for c in out)} constrained "
                         f"rows; a model has at most {MAX_ROWS}")
    return tuple(out[len(taken):])


def _one(entry, source: str, where: str) -> Constraint:
    from .model.inputs import name_field

    if isinstance(entry, Contact):
        kind, frames = "contact", (entry.frame,)
        axes, reference, name = entry.axes, entry.reference, entry.name
    elif isinstance(entry, Loop):
        kind, frames = "loop", (entry.frame_a, entry.frame_b)
        axes, reference, name = entry.axes, entry.reference, entry.name
    elif isinstance(entry, Mapping):
        kind, frames, axes, reference, name = _from_mapping(entry, source, where)
    else:
        raise ModelError(source, where, f"expected gagen.Contact, gagen.Loop or a mapping, "
                         f"got {type(entry).__name__}")
    frames = tuple(name_field(f, source, f"{where}, frame") for f in frames)
    if kind == "loop" and frames[0] == frames[1]:
        raise ModelError(source, where, f"a loop needs two different frames, got "
                         f"{_quote(frames[0])} twice")
    if name is None:
        name = "_".join(frames)
    name = name_field(name, source, f"{where}, name")
    if not isinstance(reference, str) or reference not in REFERENCES:
        raise ModelError(source, f"{where}, reference", f"expected 'local_world_aligned' or "
                         f"'local', got {_describe(reference)}")
    return Constraint(name, kind, frames, _axes(axes, source, f"{where}, axes"), reference)


def _from_mapping(entry: Mapping, source: str, where: str):
    allowed = {"name", "type", "frame", "frames", "axes", "reference"}
    extra = [key for key in entry if key not in allowed]
    if extra:
        shown = ", ".join(sorted(_describe(key) for key in extra[:10]))
        raise ModelError(source, where, f"unknown key(s) {shown} (expected: "
                         f"{', '.join(sorted(allowed))})")
    kind = entry.get("type")
    if kind not in TYPES:
        raise ModelError(source, f"{where}, type", f"expected 'contact' or 'loop', got "
                         f"{_describe(kind)}")
    if kind == "contact":
        if "frames" in entry or "frame" not in entry:
            raise ModelError(source, where, "a contact names one frame: frame: NAME")
        frames = (entry["frame"],)
    else:
        value = entry.get("frames")
        if "frame" in entry or not isinstance(value, (list, tuple)) or len(value) != 2:
            raise ModelError(source, where, "a loop names two frames: frames: [A, B]")
        frames = tuple(value)
    return (kind, frames, entry.get("axes", "3d"),
            entry.get("reference", "local_world_aligned"), entry.get("name"))


def _axes(axes, source: str, where: str) -> tuple[int, ...]:
    if isinstance(axes, str):
        if axes in ("3d", "6d"):
            return (0, 1, 2) if axes == "3d" else (0, 1, 2, 3, 4, 5)
        raise ModelError(source, where, f"expected '3d', '6d' or a list of "
                         f"{', '.join(AXES)}; got {_describe(axes)}")
    if not isinstance(axes, Sequence) or not axes or len(axes) > len(AXES):
        raise ModelError(source, where, f"expected '3d', '6d' or a non-empty list of "
                         f"{', '.join(AXES)}; got {_describe(axes)}")
    picked = set()
    for axis in axes:
        if not isinstance(axis, str) or axis not in AXES:
            raise ModelError(source, where, f"unknown axis {_describe(axis)} (axes: "
                             f"{', '.join(AXES)})")
        if axis in picked:
            raise ModelError(source, where, f"axis {axis} given twice")
        picked.add(axis)
    return tuple(k for k, axis in enumerate(AXES) if axis in picked)


def _quote(text: str) -> str:
    from .model.inputs import quote

    return quote(text)


def _describe(value) -> str:
    from .model.inputs import describe

    return describe(value)
