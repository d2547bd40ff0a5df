"""What a robot looks like: its visual shapes, each fixed to one of gagen's frames.

- URDF: each link's `<visual>` elements (origin, mesh / box / cylinder / sphere / capsule,
  material colour), in the frame of that link (`dyn.frames` keeps links merged by fixed
  joints as frames). A mesh that cannot be used is a `MeshWarning` naming the link and the
  file, and the link is drawn as its inertia box instead (the box of uniform density with
  the link's mass and principal moments, at its mass centre along its principal axes).
- MJCF: the geoms of MuJoCo's compiled model (groups 0-2, those MuJoCo's viewer shows),
  its meshes as MuJoCo compiled them, in the frame of their body.
- Model files, built-ins (the paper's robot) and URDFs without visuals: each body's
  inertia box, and a stick from each body's frame to its children's.

Nothing here computes kinematics: shapes are placed in frames; `gagen.viewer.placements`
places the frames with `dyn.frame_placement`.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..errors import ModelError
from ..manifest import JOINT_KINDS
from ..model.inputs import parse_untrusted_xml, quote, read_description
from .meshes import MeshFinder

MAX_VISUALS = 5000
MAX_SIZE = 1e4  # metres: larger shapes and offsets are not a robot's
DEFAULT_RGBA = (0.75, 0.75, 0.78, 1.0)
INERTIA_RGBA = (0.35, 0.55, 0.85, 1.0)  # the bodies of models without visuals
MISSING_RGBA = (0.95, 0.55, 0.2, 0.7)  # a link whose mesh could not be read
STICK_RGBA = (0.2, 0.2, 0.2, 1.0)
MJCF_SUFFIXES = (".xml", ".mjcf")


class MeshWarning(UserWarning):
    """A visual that cannot be drawn as described (a missing or refused mesh), and what is
    drawn instead."""


@dataclass(frozen=True)
class Shape:
    """A visual's geometry, in its own frame (URDF's conventions: a box's full sides, a
    cylinder or capsule along z with its length, radii in metres)."""

    kind: str  # "mesh", "box", "cylinder", "capsule", "sphere", "ellipsoid" or "triangles"
    size: tuple[float, ...] = ()
    uri: str = ""  # "mesh": the file as the description names it
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    vertices: np.ndarray | None = None  # "triangles" (MJCF's compiled meshes)
    faces: np.ndarray | None = None


@dataclass(frozen=True)
class Visual:
    """A shape fixed to a frame of `dyn.frames` ("" for the world), placed in it by
    (R, p); `fallback` is drawn when the shape cannot be."""

    frame: str
    link: str  # the description's name of the link or body, for messages
    R: np.ndarray
    p: np.ndarray
    shape: Shape
    rgba: tuple[float, float, float, float] | None = None
    fallback: Visual | None = None


@dataclass
class RobotVisuals:
    """A robot's visuals; `finder` finds its mesh files (None: no meshes)."""

    source: str
    visuals: list[Visual] = field(default_factory=list)
    finder: MeshFinder | None = None
    from_description: bool = True  # False: inertia boxes and sticks (no visuals given)


def robot_visuals(dyn, package_dirs=None, p=None) -> RobotVisuals:
    """The visuals of a loaded model (module docstring); `package_dirs` find a URDF's
    package:// meshes, `p` gives the inertia boxes of models without visuals."""
    source = dyn.source
    suffix = Path(source).suffix.lower()
    if suffix == ".urdf":
        visuals = urdf_visuals(source, dyn, package_dirs)
    elif suffix in MJCF_SUFFIXES:
        visuals = mjcf_visuals(source, dyn)
    else:
        visuals = RobotVisuals(source)
    if not visuals.visuals:
        visuals.visuals = inertia_visuals(dyn, p)
        visuals.from_description = False
    return visuals


def link_frame(dyn, link: str) -> str | None:
    """The name in `dyn.frames` of a description's link (`link:<name>` where a joint took
    the name first), or None."""
    names = {name: kind for name, _, kind in dyn.info.frames}
    for name in (link, f"link:{link}"):
        if names.get(name) == "link":
            return name
    return None


# --- URDF ------------------------------------------------------------------------------------

def urdf_visuals(path: str | Path, dyn, package_dirs=None) -> RobotVisuals:
    """Each link's <visual> elements; errors in them are MeshWarnings (the model loaded)."""
    source = str(path)
    robot = parse_untrusted_xml(read_description(path, "URDF file"), source, "a URDF")
    materials = _named_materials(robot, source)
    out = RobotVisuals(source, finder=MeshFinder(Path(source).parent, package_dirs))
    for link in robot.findall("link"):
        name = link.get("name", "")
        frame = link_frame(dyn, name)
        elements = link.findall("visual")
        if frame is None or not elements:
            continue
        box = _link_inertia_box(link, frame, name, source)
        for k, element in enumerate(elements):
            if len(out.visuals) >= MAX_VISUALS:
                raise ModelError(source, "<visual>", f"more than {MAX_VISUALS} visuals")
            where = f"link {quote(name)}, visual {k + 1}"
            try:
                visual = _urdf_visual(element, frame, name, materials, source, where)
            except ModelError as exc:
                _warn(f"{exc}; drawn as the link's inertia box instead" if box
                      else f"{exc}; not drawn")
                visual = box
            if visual is not None:
                out.visuals.append(replace(visual, fallback=box) if visual is not box
                                   else visual)
    return out


def _warn(message: str) -> None:
    warnings.warn(message, MeshWarning, stacklevel=3)


def _named_materials(robot, source: str) -> dict[str, tuple]:
    out = {}
    for material in robot.findall("material"):
        color = material.find("color")
        if material.get("name") and color is not None:
            out[material.get("name")] = _rgba(color, source, "material "
                                              f"{quote(material.get('name'))}")
    return out


def _urdf_visual(element, frame: str, link: str, materials: dict, source: str,
                 where: str) -> Visual:
    R, p = _origin(element, source, where)
    geometry = element.find("geometry")
    if geometry is None or len(geometry) == 0:
        raise ModelError(source, where, "no <geometry>")
    shape = _urdf_shape(geometry[0], source, f"{where}, <{quote(str(geometry[0].tag))[1:-1]}>")
    rgba = None
    material = element.find("material")
    if material is not None:
        color = material.find("color")
        if color is not None:
            rgba = _rgba(color, source, f"{where}, material")
        else:
            rgba = materials.get(material.get("name", ""))
    return Visual(frame, link, R, p, shape, rgba)


def _urdf_shape(geometry, source: str, where: str) -> Shape:
    tag = geometry.tag
    if tag == "mesh":
        uri = geometry.get("filename", "")
        if not uri.strip():
            raise ModelError(source, where, "missing attribute 'filename'")
        scale = tuple(_numbers(geometry.get("scale", "1 1 1"), 3, source, f"{where} scale"))
        return Shape("mesh", uri=uri.strip(), scale=scale)
    if tag == "box":
        return Shape("box", _sizes(geometry.get("size", ""), 3, source, f"{where} size"))
    if tag in ("cylinder", "capsule"):
        radius = _size(geometry, "radius", source, where)
        return Shape(tag, (radius, _size(geometry, "length", source, where)))
    if tag == "sphere":
        return Shape("sphere", (_size(geometry, "radius", source, where),))
    raise ModelError(source, where, "unknown geometry (URDF has mesh, box, cylinder, sphere; "
                     "capsule is read too)")


def _size(element, key: str, source: str, where: str) -> float:
    return _sizes(element.get(key, ""), 1, source, f"{where} {key}")[0]


def _sizes(text: str, count: int, source: str, where: str) -> tuple[float, ...]:
    values = _numbers(text, count, source, where)
    if any(v <= 0 for v in values):
        raise ModelError(source, where, f"sizes must be positive, got {quote(text)}")
    return tuple(values)


def _numbers(text: str, count: int, source: str, where: str) -> list[float]:
    parts = (text or "").split()
    if len(parts) != count:
        raise ModelError(source, where, f"expected {count} numbers, got {quote(text or '')}")
    try:
        values = [float(v) for v in parts]
    except ValueError:
        raise ModelError(source, where, f"{quote(text)} holds a value that is not a number") \
            from None
    if not all(math.isfinite(v) and abs(v) <= MAX_SIZE for v in values):
        raise ModelError(source, where, f"{quote(text)}: numbers must be finite and at most "
                         f"{MAX_SIZE:g} in magnitude")
    return values


def _rgba(color, source: str, where: str) -> tuple:
    values = _numbers(color.get("rgba", ""), 4, source, f"{where} rgba")
    return tuple(min(1.0, max(0.0, v)) for v in values)


def _origin(element, source: str, where: str) -> tuple[np.ndarray, np.ndarray]:
    origin = element.find("origin")
    if origin is None:
        return np.eye(3), np.zeros(3)
    xyz = _numbers(origin.get("xyz", "0 0 0"), 3, source, f"{where}, origin xyz")
    rpy = _numbers(origin.get("rpy", "0 0 0"), 3, source, f"{where}, origin rpy")
    return rotation_rpy(*rpy), np.array(xyz)


def rotation_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF's fixed-axis roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _link_inertia_box(link, frame: str, name: str, source: str) -> Visual | None:
    """The link's inertia box from its <inertial>, or None (massless, or unreadable)."""
    inertial = link.find("inertial")
    if inertial is None:
        return None
    where = f"link {quote(name)}, inertial"
    try:
        R, p = _origin(inertial, source, where)
        mass_element, tensor = inertial.find("mass"), inertial.find("inertia")
        if mass_element is None or tensor is None:
            return None
        mass = _numbers(mass_element.get("value", ""), 1, source, f"{where} mass")[0]
        i = {key: _numbers(tensor.get(key, ""), 1, source, f"{where} {key}")[0]
             for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
    except ModelError:
        return None  # the model loaded, so its inertial was read; a box is only a drawing
    inertia = np.array([[i["ixx"], i["ixy"], i["ixz"]], [i["ixy"], i["iyy"], i["iyz"]],
                        [i["ixz"], i["iyz"], i["izz"]]])
    box = inertia_box(frame, name, mass, p, R @ inertia @ R.T)
    return None if box is None else replace(box, rgba=MISSING_RGBA)


def inertia_box(frame: str, link: str, mass: float, com: np.ndarray,
                inertia: np.ndarray) -> Visual | None:
    """The box of uniform density with this mass and central inertia (in the frame's axes),
    at the mass centre along the principal axes; None for no mass."""
    if not (mass > 0 and np.isfinite(inertia).all()):
        return None
    moments, axes = np.linalg.eigh((inertia + inertia.T) / 2)
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    total = moments.sum()
    # I_x = m (b^2 + c^2) / 12, ...: a^2 = 6 (I_y + I_z - I_x) / m
    sides = np.sqrt(np.maximum(6.0 * (total - 2.0 * moments) / mass, 0.0))
    floor = max(1e-3, 0.02 * float(sides.max())) if sides.max() > 0 else 1e-3
    sides = np.maximum(sides, floor)  # a rod or a point mass still shows
    return Visual(frame, link, axes, np.asarray(com, dtype=float),
                  Shape("box", tuple(float(s) for s in sides)), INERTIA_RGBA)


# --- MJCF ------------------------------------------------------------------------------------

_PLANE, _HFIELD, _SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH = range(8)
_SHOWN_GROUPS = 3  # MuJoCo's viewer shows geom groups 0, 1, 2 by default


def mjcf_visuals(path: str | Path, dyn) -> RobotVisuals:
    """The shown geoms of MuJoCo's compiled model, in gagen's frames of their bodies."""
    from ..model.mjcf import body_names, compile_mjcf

    source = str(path)
    mj = compile_mjcf(path)
    names = ["world", *body_names(mj, source)]  # each names MuJoCo's body frame
    out = RobotVisuals(source)
    for g in range(mj.ngeom):
        if int(mj.geom_group[g]) >= _SHOWN_GROUPS:
            continue
        matid = int(mj.geom_matid[g])
        rgba = tuple(float(v) for v in (mj.mat_rgba[matid] if matid >= 0 else mj.geom_rgba[g]))
        shape = _mjcf_shape(mj, g)
        if shape is None or rgba[3] <= 0:
            continue
        body = int(mj.geom_bodyid[g])
        name = names[body]
        frame = "" if body == 0 else (link_frame(dyn, name) or "")
        R = np.zeros(9)
        _mujoco().mju_quat2Mat(R, np.asarray(mj.geom_quat[g], dtype=float))
        out.visuals.append(Visual(frame, name, R.reshape(3, 3),
                                  np.asarray(mj.geom_pos[g], dtype=float), shape, rgba))
        if len(out.visuals) > MAX_VISUALS:
            raise ModelError(source, "<geom>", f"more than {MAX_VISUALS} shown geoms")
    return out


def _mjcf_shape(mj, g: int) -> Shape | None:
    kind, size = int(mj.geom_type[g]), [float(v) for v in mj.geom_size[g]]
    if kind == _SPHERE:
        return Shape("sphere", (size[0],))
    if kind in (_CAPSULE, _CYLINDER):
        return Shape("capsule" if kind == _CAPSULE else "cylinder", (size[0], 2 * size[1]))
    if kind == _ELLIPSOID:
        return Shape("ellipsoid", tuple(size))
    if kind == _BOX:
        return Shape("box", tuple(2 * s for s in size))
    if kind == _MESH:
        mesh = int(mj.geom_dataid[g])
        v0, nv = int(mj.mesh_vertadr[mesh]), int(mj.mesh_vertnum[mesh])
        f0, nf = int(mj.mesh_faceadr[mesh]), int(mj.mesh_facenum[mesh])
        return Shape("triangles", vertices=np.array(mj.mesh_vert[v0:v0 + nv], dtype=float),
                     faces=np.array(mj.mesh_face[f0:f0 + nf], dtype=np.int64))
    return None  # planes, height fields and SDFs are scenery, not the robot


def _mujoco():
    import mujoco

    return mujoco


# --- models without visuals ------------------------------------------------------------------

def inertia_visuals(dyn, p=None) -> list[Visual]:
    """Each body's inertia box and a stick from each body's frame to its children's (the
    3-D stick figure of models without visuals)."""
    from .placements import body_names

    names = body_names(dyn)
    q0 = dyn.neutral()
    placed = {name: dyn.frame_placement(q0, name, p) for name in names}
    out = _body_boxes(dyn, names, p)
    boxes = {v.frame: v for v in out}
    origins = np.array([placed[name][1] for name in names])
    size = max(float(np.linalg.norm(origins - origins[0], axis=1).max()), 0.1)
    radius = 0.012 * size
    parents = [parent for parent, _, _ in dyn.info.bodies]
    for b, name in enumerate(names):
        parent, kind = parents[b], dyn.info.bodies[b][1]
        if parent >= 0:  # in the parent's frame, to this body's origin
            R, origin = placed[names[parent]]
            out.append(_stick(names[parent], name, np.zeros(3),
                              R.T @ (placed[name][1] - origin), radius))
        elif kind != JOINT_KINDS["floating"]:  # from the world's origin
            out.append(_stick("", name, np.zeros(3), placed[name][1], radius))
        if b not in parents and name in boxes:  # a tip: to twice its mass centre
            out.append(_stick(name, name, np.zeros(3), 2 * boxes[name].p, radius))
    return [v for v in out if v is not None]


def _body_boxes(dyn, names: list[str], p) -> list[Visual]:
    from ..model.numeric import numeric_model

    numeric = numeric_model(dyn.model, p)
    boxes = {b.name: inertia_box(b.name, b.name, b.mass, b.com, b.inertia)
             for b in numeric.bodies}
    return [boxes[name] for name in names if boxes.get(name) is not None]


def _stick(frame: str, link: str, start: np.ndarray, end: np.ndarray,
           radius: float) -> Visual | None:
    """A cylinder from start to end (in the frame)."""
    d = np.asarray(end, dtype=float) - start
    length = float(np.linalg.norm(d))
    if length < 1e-9:
        return None
    z = d / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    return Visual(frame, link, R, (np.asarray(start, dtype=float) + end) / 2,
                  Shape("cylinder", (radius, length)), STICK_RGBA)
