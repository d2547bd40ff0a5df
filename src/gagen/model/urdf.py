"""Read a URDF robot description into a validated Model (DESIGN.md section 4).

Only what the equations of motion need is read: links' <inertial> and joints' origin, axis,
limits, mimic and <dynamics>. Visuals, collisions, transmissions and gazebo tags are
ignored. The root link becomes the world, fixed joints are merged away, and every remaining
body's mass properties become named parameters (defaults from the file) so a payload can be
changed without regenerating the equations.

Every moving joint gets three parameters too: `damping_<joint>` and `friction_<joint>`
from its <dynamics damping friction> (0 where absent), and `armature_<joint>`, the rotor
inertia reflected at the joint, default 0. URDF has no armature, but real drives have one,
identification estimates it (it is a column of the regressor, gagen.ident) and a simulation
of the identified robot needs it: as a parameter it can be set without a rebuild, at the
cost of one addition per diagonal entry of M.
"""

from __future__ import annotations

import math
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import sympy as sp

from ..errors import one_line
from .expressions import MAX_MAGNITUDE
from .inputs import check_body_count, name_field, parse_untrusted_xml, quote, read_description
from .merge import merge_fixed_joints, symmetric
from .model import (
    JOINT_TYPES,
    WORLD,
    ZERO3,
    Body,
    Frame,
    Joint,
    Limits,
    Model,
    ModelError,
    check_model_inertias,
    check_tensor,
    naming,
    rotation_from_rpy,
    vector,
)
from .parameters import parameterize_joint_terms, parameterize_mass_properties

GRAVITY = 9.81
_LINK_INERTIA = ("link", "inertial inertia")  # how messages name a link's inertia
_UNSUPPORTED = ("planar",)
# The name of the floating joint that floating_base=True puts between the world and the
# root link (Pinocchio's name for it)
ROOT_JOINT = "root_joint"
_INERTIA_KEYS = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")


@dataclass(frozen=True)
class _Link:
    name: str
    mass: sp.Expr
    com: sp.ImmutableMatrix
    inertia: sp.ImmutableMatrix


@dataclass(frozen=True)
class _UrdfJoint:
    parent: str
    child: str
    joint: Joint


def load_urdf(path: str | Path, strict: bool = False, floating_base: bool = False) -> Model:
    """Read a URDF file; errors are ModelError naming the file, the element and the reason.

    An inertia slightly off physical (CAD round-off) loads with a
    `gagen.errors.InertiaWarning`, or is refused when `strict`. With `floating_base`, the
    root link moves freely: a floating joint `root_joint` joins it to the world (as
    Pinocchio's `buildModelFromUrdf(path, JointModelFreeFlyer())` does)."""
    return parse_urdf_text(read_description(path, "URDF file"), str(path), strict,
                           floating_base)


def parse_urdf_text(text: str | bytes, source: str = "<urdf>", strict: bool = False,
                    floating_base: bool = False) -> Model:
    """Build the Model of a URDF document given as text or bytes; source names it in errors.

    Bytes are decoded as their XML declaration says (UTF-8 when there is none). The root
    link is welded to the world, or with `floating_base` attached to it by a floating joint.
    """
    robot = _parse_xml(text, source)
    links = _parse_links(robot, source)
    joints = _parse_joints(robot, links, source)
    root, ordered = _tree_order(links, joints, source)
    if floating_base and root == WORLD:
        root, links, ordered = _floating_world_link(links, ordered)
    bodies = [_body(j, links[j.child], None if floating_base else root, source)
              for j in ordered]
    if floating_base:
        if any(j.joint.floating for j in ordered):
            raise ModelError(source, f"link {quote(root)}", "floating_base=True adds a floating "
                             "joint to the root link, but the URDF has a floating joint already")
        bodies.insert(0, _root_body(links[root]))
    if not any(b.joint.moves for b in bodies):
        raise ModelError(source, f"robot {quote(_robot_name(robot, source))}",
                         "no revolute, continuous, prismatic or floating joint: nothing can "
                         "move (floating_base=True lets the root link move freely)")
    g = sp.Symbol("g")
    with naming(*_LINK_INERTIA):  # before merging: a message names the link, welded or not
        model = Model(name=_robot_name(robot, source), bodies=tuple(bodies),
                      parameters={"g": GRAVITY}, gravity=vector([0, 0, -g]), source=source,
                      # a root link welded to the world is a frame of it
                      extra_frames=() if floating_base else (Frame(root, WORLD),))
    check_model_inertias(model, strict, *_LINK_INERTIA)
    return parameterize_joint_terms(parameterize_mass_properties(merge_fixed_joints(model)))


def _floating_world_link(links: dict[str, _Link], ordered: list[_UrdfJoint]
                         ) -> tuple[str, dict[str, _Link], list[_UrdfJoint]]:
    """floating_base=True on a URDF whose root link is `world` (the ROS convention for a
    robot welded to the world: the UR arms, xArm, Z1): Pinocchio floats that link, and so
    does gagen, under the name `world_link` (`world` is gagen's fixed frame), or the first
    name the file leaves free after it."""
    name = "world_link"
    while name in links:
        name += "_"
    links = {(name if key == WORLD else key): (replace(link, name=name) if key == WORLD
                                                else link) for key, link in links.items()}
    ordered = [replace(j, parent=name) if j.parent == WORLD else j for j in ordered]
    return name, links, ordered


def _root_body(link: _Link) -> Body:
    """The root link on a floating joint to the world (floating_base=True)."""
    return Body(name=link.name, parent=WORLD, joint=Joint(name=ROOT_JOINT, type="floating"),
                mass=link.mass, com=link.com, inertia=link.inertia)


# --- XML structure --------------------------------------------------------------------------

def _parse_xml(text: str | bytes, source: str) -> ET.Element:
    root = parse_untrusted_xml(text, source, "a URDF")
    if root.tag != "robot":
        raise ModelError(source, f"<{quote(str(root.tag))[1:-1]}>",
                         "the root element of a URDF must be <robot>")
    return root


def _robot_name(robot: ET.Element, source: str) -> str:
    return name_field(robot.get("name") or Path(source).stem, source, "<robot> name")


def _name_attr(elem: ET.Element, key: str, source: str, element: str) -> str:
    """An attribute that names something: present, non-empty and of bounded length."""
    return name_field(_attr(elem, key, source, element), source, f"{element} {key}")


def _attr(elem: ET.Element, key: str, source: str, element: str) -> str:
    value = elem.get(key)
    if value is None or not value.strip():
        raise ModelError(source, element, f"missing attribute '{key}' of <{elem.tag}>")
    return value.strip()


def _child(elem: ET.Element, tag: str, source: str, element: str) -> ET.Element:
    found = elem.find(tag)
    if found is None:
        raise ModelError(source, element, f"missing <{tag}>")
    return found


def _number(text: str, source: str, element: str) -> sp.Expr:
    """A finite number; exact integers stay exact, the rest become sympy Floats."""
    try:
        value = float(text)
    except ValueError:
        raise ModelError(source, element, f"{quote(text)} is not a number") from None
    if not math.isfinite(value) or abs(value) > MAX_MAGNITUDE:
        raise ModelError(source, element, f"{quote(text)} is not a finite number of at most "
                         f"{MAX_MAGNITUDE:g} in magnitude")
    if value.is_integer() and abs(value) < 2**53:
        return sp.Integer(int(value))
    return sp.Float(value)


def _numbers(text: str, count: int, source: str, element: str) -> list[sp.Expr]:
    parts = text.split()
    if len(parts) != count:
        raise ModelError(source, element,
                         f"expected {count} numbers separated by spaces, got {quote(text)}")
    return [_number(p, source, element) for p in parts]


def _origin(parent: ET.Element, source: str, element: str) -> tuple[list, list]:
    """xyz and rpy of an optional <origin> (both default to zeros, as in URDF)."""
    origin = parent.find("origin")
    if origin is None:
        return [0, 0, 0], [0, 0, 0]
    xyz = _numbers(origin.get("xyz", "0 0 0"), 3, source, f"{element}, origin xyz")
    rpy = _numbers(origin.get("rpy", "0 0 0"), 3, source, f"{element}, origin rpy")
    return xyz, rpy


# --- links ----------------------------------------------------------------------------------

def _parse_links(robot: ET.Element, source: str) -> dict[str, _Link]:
    links: dict[str, _Link] = {}
    elements = robot.findall("link")
    check_body_count(len(elements), source, "<robot>")
    for k, elem in enumerate(elements):
        name = _name_attr(elem, "name", source, f"link #{k + 1}")
        if name in links:
            raise ModelError(source, f"link {quote(name)}", "duplicate link name")
        links[name] = _parse_link(elem, name, source)
    if not links:
        raise ModelError(source, "<robot>", "no <link> elements")
    return links


def _parse_link(elem: ET.Element, name: str, source: str) -> _Link:
    where = f"link {quote(name)}, inertial"
    inertial = elem.find("inertial")
    if inertial is None:  # URDF: a link without <inertial> has no mass
        return _Link(name, sp.Integer(0), ZERO3, sp.ImmutableMatrix(sp.zeros(3, 3)))
    xyz, rpy = _origin(inertial, source, where)
    mass_elem = _child(inertial, "mass", source, where)
    mass = _number(_attr(mass_elem, "value", source, f"{where} mass"), source, f"{where} mass")
    if mass < 0:
        raise ModelError(source, f"{where} mass", f"mass must be non-negative, got {float(mass):g}")
    inertia_elem = _child(inertial, "inertia", source, where)
    values = {key: _number(_attr(inertia_elem, key, source, f"{where} inertia"), source,
                           f"{where} inertia {key}") for key in _INERTIA_KEYS}
    tensor = sp.Matrix([[values["ixx"], values["ixy"], values["ixz"]],
                        [values["ixy"], values["iyy"], values["iyz"]],
                        [values["ixz"], values["iyz"], values["izz"]]])
    check_tensor(np.array(tensor.tolist(), dtype=float), source, f"{where} inertia")
    # URDF gives the inertia in the inertial frame; gagen wants it along the body's axes.
    if any(a != 0 for a in rpy):
        rot = rotation_from_rpy(*rpy)
        tensor = symmetric(rot * tensor * rot.T)
    return _Link(name, mass, vector(xyz), sp.ImmutableMatrix(tensor))


# --- joints ---------------------------------------------------------------------------------

def _parse_joints(robot: ET.Element, links: dict[str, _Link], source: str) -> list[_UrdfJoint]:
    joints: list[_UrdfJoint] = []
    names: set[str] = set()
    for k, elem in enumerate(robot.findall("joint")):
        joint = _parse_joint(elem, k, links, source)
        if joint.joint.name in names:
            raise ModelError(source, f"joint {quote(joint.joint.name)}", "duplicate joint name")
        names.add(joint.joint.name)
        joints.append(joint)
    return [_without_dangling_mimic(j, names, source) for j in joints]


def _without_dangling_mimic(j: _UrdfJoint, names: set[str], source: str) -> _UrdfJoint:
    """A mimic tag naming no joint of the file (example-robot-data's alex_psyonic_hands
    names `index_q1` for `Left_index_q1`) is dropped with a warning: gagen's mimic joints
    are independent coordinates, so the tag changes nothing in the equations, and Pinocchio
    loads such a file too."""
    mimic = j.joint.mimic
    if mimic is None or mimic in names:
        return j
    warnings.warn(one_line(f"{source}: joint {quote(j.joint.name)}, mimic: mimics unknown "
                           f"joint {quote(mimic)}; the tag is ignored (a mimic joint is an "
                           "independent coordinate in gagen)"), stacklevel=4)
    return replace(j, joint=replace(j.joint, mimic=None))


def _parse_joint(elem: ET.Element, k: int, links: dict[str, _Link], source: str) -> _UrdfJoint:
    name = _name_attr(elem, "name", source, f"joint #{k + 1}")
    where = f"joint {quote(name)}"
    jtype = _attr(elem, "type", source, where)
    if jtype in _UNSUPPORTED:
        raise ModelError(source, where, f"joint type {quote(jtype)} is unsupported "
                         f"(gagen supports {', '.join(JOINT_TYPES)})")
    if jtype not in JOINT_TYPES:
        raise ModelError(source, where, f"unknown joint type {quote(jtype)} "
                         f"(gagen supports {', '.join(JOINT_TYPES)})")
    parent = _link_ref(elem, "parent", links, source, where)
    child = _link_ref(elem, "child", links, source, where)
    xyz, rpy = _origin(elem, source, where)
    joint = Joint(name=name, type=jtype, origin_xyz=vector(xyz),
                  origin_rotation=rotation_from_rpy(*rpy), axis=_axis(elem, jtype, source, where),
                  limits=_limits(elem, source, where), mimic=_mimic(elem, source, where),
                  **_dynamics(elem, jtype, source, where))
    return _UrdfJoint(parent, child, joint)


def _dynamics(elem: ET.Element, jtype: str, source: str, where: str) -> dict[str, sp.Expr]:
    """damping and friction of an optional <dynamics> (0 where absent; ignored on a fixed
    joint, which has no coordinate for them to act on)."""
    dynamics = elem.find("dynamics")
    if dynamics is None or jtype == "fixed":
        return {}
    values = {}
    for key in ("damping", "friction"):
        text = dynamics.get(key)
        if text is None:
            continue
        value = _number(text, source, f"{where}, dynamics {key}")
        if value < 0:
            raise ModelError(source, f"{where}, dynamics {key}",
                             f"{key} must be non-negative, got {float(value):g}")
        values[key] = value
    return values


def _link_ref(elem: ET.Element, tag: str, links: dict[str, _Link], source: str,
              where: str) -> str:
    link = _name_attr(_child(elem, tag, source, where), "link", source, f"{where}, <{tag}>")
    if link not in links:
        raise ModelError(source, f"{where}, <{tag}>", f"unknown link {quote(link)}")
    return link


def _axis(elem: ET.Element, jtype: str, source: str, where: str) -> sp.ImmutableMatrix:
    axis_elem = elem.find("axis")
    text = axis_elem.get("xyz", "1 0 0") if axis_elem is not None else "1 0 0"
    axis = _numbers(text, 3, source, f"{where}, axis")
    if jtype in ("fixed", "floating"):
        return vector(axis)
    norm = math.sqrt(sum(float(a) ** 2 for a in axis))
    if norm < 1e-12:
        raise ModelError(source, f"{where}, axis", "zero joint axis")
    # URDF parsers normalise the axis, so the coordinate is an angle or a distance.
    if abs(norm - 1.0) > 1e-12:
        axis = [sp.Float(float(a) / norm) if a != 0 else sp.Integer(0) for a in axis]
    return vector(axis)


def _limits(elem: ET.Element, source: str, where: str) -> Limits | None:
    limit = elem.find("limit")
    if limit is None:
        return None
    values = {}
    for key in ("lower", "upper", "effort", "velocity"):
        text = limit.get(key)
        values[key] = None if text is None else float(_number(text, source, f"{where}, limit {key}"))
    return Limits(**values)


def _mimic(elem: ET.Element, source: str, where: str) -> str | None:
    mimic = elem.find("mimic")
    if mimic is None:
        return None
    return _name_attr(mimic, "joint", source, f"{where}, mimic")


def _names(names: list[str], shown: int = 5) -> str:
    listed = ", ".join(quote(n) for n in names[:shown])
    return listed + (f" and {len(names) - shown} more" if len(names) > shown else "")


# --- tree -----------------------------------------------------------------------------------

def _tree_order(links: dict[str, _Link], joints: list[_UrdfJoint],
                source: str) -> tuple[str, list[_UrdfJoint]]:
    """The root link and the joints depth-first from it in Pinocchio's order.

    Pinocchio's URDF parser (urdfdom) keeps a link's child joints in a map by name, so
    siblings come in the byte order of their joints' names (Python's order of str: UTF-8
    preserves code-point order), whatever their order in the file. A q taken from
    `pinocchio.buildModelFromUrdf` of the same file is then gagen's q."""
    parent_joint: dict[str, _UrdfJoint] = {}
    children: dict[str, list[_UrdfJoint]] = {name: [] for name in links}
    for j in joints:
        if j.child in parent_joint:
            raise ModelError(source, f"link {quote(j.child)}",
                             f"child of both joint {quote(parent_joint[j.child].joint.name)} and joint "
                             f"{quote(j.joint.name)}: a URDF must be a tree (no loops)")
        parent_joint[j.child] = j
        children[j.parent].append(j)
    roots = [name for name in links if name not in parent_joint]
    if len(roots) > 1:
        raise ModelError(source, "<robot>", f"several root links ({_names(roots)}): "
                         "every link but one must be the child of a joint")
    if not roots:
        raise ModelError(source, "<robot>", "no root link: the joints form a cycle")
    root = roots[0]
    for siblings in children.values():
        siblings.sort(key=lambda j: j.joint.name)
    ordered: list[_UrdfJoint] = []
    stack = list(reversed(children[root]))
    while stack:
        j = stack.pop()
        ordered.append(j)
        stack.extend(reversed(children[j.child]))
    reached = {root} | {j.child for j in ordered}
    unreached = [name for name in links if name not in reached]
    if unreached:
        raise ModelError(source, f"link {quote(unreached[0])}",
                         f"links {_names(unreached)} form a cycle (not reachable from the "
                         f"root link {quote(root)})")
    for name in links:
        if name == WORLD and name != root:
            raise ModelError(source, f"link {quote(name)}",
                             f"'{WORLD}' is reserved for the root link (the fixed frame)")
    return root, ordered


def _body(j: _UrdfJoint, link: _Link, root: str | None, source: str) -> Body:
    # A root link welded to the world is the world (root None: the root link is a body).
    parent = WORLD if j.parent == root else j.parent
    if j.joint.floating and parent != WORLD:
        raise ModelError(source, f"joint {quote(j.joint.name)}", "a floating joint must join "
                         "a link to the root link (the world): gagen's floating joints are "
                         "free bases")
    return Body(name=link.name, parent=parent, joint=j.joint, mass=link.mass, com=link.com,
                inertia=link.inertia)
