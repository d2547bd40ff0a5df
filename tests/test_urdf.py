"""The URDF importer and the merging of fixed joints."""

from __future__ import annotations

import math
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

from gagen.model import (
    WORLD,
    Body,
    Joint,
    Limits,
    Model,
    ModelError,
    inertia_matrix,
    rotation_from_rpy,
    vector,
)
from gagen.model.merge import merge_fixed_joints
from gagen.model.urdf import load_urdf, parse_urdf_text

URDF_DIR = Path(__file__).resolve().parent / "data" / "urdf"

# file -> (coordinates, bodies left after merging fixed joints)
SHARED = {
    "panda.urdf": ([f"panda_joint{i}" for i in range(1, 8)]
                   + ["panda_finger_joint1", "panda_finger_joint2"], 9),
    "ur5_robot.urdf": (["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                        "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"], 6),
    "so100.urdf": (["shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll",
                    "gripper"], 6),
    "double_pendulum.urdf": (["joint1", "joint2"], 2),
}


def as_np(matrix) -> np.ndarray:
    return np.array(matrix.tolist(), dtype=float)


def numeric_mass_properties(model: Model, body: Body):
    """mass, com and inertia of a body with the model's parameter defaults substituted."""
    values = {sp.Symbol(k): v for k, v in model.parameters.items()}
    sub = lambda e: sp.sympify(e).xreplace(values)
    return (float(sub(body.mass)), as_np(body.com.applyfunc(sub)).ravel(),
            as_np(body.inertia.applyfunc(sub)))


def links_welded_to_root(path: Path) -> tuple[float, float]:
    """(sum of all link masses, mass of the root link and links fixed to it), read directly."""
    robot = ET.parse(path).getroot()
    masses = {}
    for link in robot.findall("link"):
        mass = link.find("inertial/mass")
        masses[link.get("name")] = float(mass.get("value")) if mass is not None else 0.0
    joints = [(j.get("type"), j.find("parent").get("link"), j.find("child").get("link"))
              for j in robot.findall("joint")]
    children = {c for _, _, c in joints}
    welded = {name for name in masses if name not in children}
    grown = True
    while grown:
        new = {c for t, p, c in joints if t == "fixed" and p in welded} - welded
        welded |= new
        grown = bool(new)
    return sum(masses.values()), sum(masses[n] for n in welded)


# --- the shared robots ----------------------------------------------------------------------

@pytest.mark.parametrize("filename", sorted(SHARED))
def test_shared_urdf_coordinates_and_merged_bodies(filename):
    model = load_urdf(URDF_DIR / filename)
    coordinates, n_bodies = SHARED[filename]
    assert model.coordinates == coordinates
    assert model.dof == len(coordinates)
    assert len(model.bodies) == n_bodies  # fixed joints merged away
    assert all(b.joint.moves for b in model.bodies)
    assert model.source == str(URDF_DIR / filename)
    assert model.parameters["g"] == 9.81
    assert model.gravity == vector([0, 0, -sp.Symbol("g")])


@pytest.mark.parametrize("filename", sorted(SHARED))
def test_shared_urdf_total_mass(filename):
    model = load_urdf(URDF_DIR / filename)
    total, fixed_to_world = links_welded_to_root(URDF_DIR / filename)
    mass = sum(numeric_mass_properties(model, b)[0] for b in model.bodies)
    assert mass == pytest.approx(total - fixed_to_world, rel=1e-12)


def test_total_mass_is_urdf_sum_minus_root_link():
    # Robots whose root link is the only link welded to the world.
    for filename, root_mass in (("panda.urdf", 0.629769), ("so100.urdf", 1.0),
                                ("double_pendulum.urdf", 0.10159)):
        total, fixed = links_welded_to_root(URDF_DIR / filename)
        assert fixed == pytest.approx(root_mass)
        model = load_urdf(URDF_DIR / filename)
        mass = sum(model.parameters[f"m_{b.name}"] for b in model.bodies)
        assert mass == pytest.approx(total - root_mass, rel=1e-12)
    # ur5: its root link is "world"; base_link (4 kg) is welded to it and never moves.
    ur5 = load_urdf(URDF_DIR / "ur5_robot.urdf")
    assert sum(ur5.parameters[f"m_{b.name}"] for b in ur5.bodies) == pytest.approx(16.9939)


def test_shared_urdf_names():
    assert load_urdf(URDF_DIR / "panda.urdf").name == "panda"
    assert load_urdf(URDF_DIR / "ur5_robot.urdf").name == "ur5"
    assert load_urdf(URDF_DIR / "so100.urdf").name == "so_arm100"
    assert load_urdf(URDF_DIR / "double_pendulum.urdf").name == "2dof_planar"


def test_panda_limits_and_mimic():
    model = load_urdf(URDF_DIR / "panda.urdf")
    joints = {b.joint.name: b.joint for b in model.bodies}
    assert joints["panda_joint4"].limits == Limits(lower=-3.0718, upper=-0.0698, effort=87.0,
                                                   velocity=2.175)
    assert joints["panda_finger_joint1"].limits == Limits(0.0, 0.04, 100.0, 0.2)
    assert joints["panda_finger_joint2"].mimic == "panda_finger_joint1"
    assert all(j.mimic is None for name, j in joints.items() if name != "panda_finger_joint2")
    # the mimic joint stays an independent coordinate
    assert "panda_finger_joint2" in model.coordinates


def test_so100_and_ur5_limits():
    so100 = {b.joint.name: b.joint for b in load_urdf(URDF_DIR / "so100.urdf").bodies}
    assert so100["elbow_flex"].limits == Limits(-3.14158, 0.0, 35.0, 1.0)
    ur5 = {b.joint.name: b.joint for b in load_urdf(URDF_DIR / "ur5_robot.urdf").bodies}
    assert ur5["wrist_1_joint"].limits == Limits(-6.28318530718, 6.28318530718, 28.0, 3.2)


def test_panda_hand_merged_into_link7():
    model = load_urdf(URDF_DIR / "panda.urdf")
    bodies = {b.name: b for b in model.bodies}
    # link8 (massless, fixed) and hand (fixed, rotated -pi/4) are folded into link7
    assert model.parameters["m_panda_link7"] == pytest.approx(0.735522 + 0.73)
    assert bodies["panda_link7"].mass == sp.Symbol("m_panda_link7")
    finger = bodies["panda_leftfinger"]
    assert finger.parent == "panda_link7"
    np.testing.assert_allclose(as_np(finger.joint.origin_xyz).ravel(), [0, 0, 0.107 + 0.0584],
                               atol=1e-15)
    c, s = math.cos(-math.pi / 4), math.sin(-math.pi / 4)
    np.testing.assert_allclose(as_np(finger.joint.origin_rotation),
                               [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-15)
    # hand: com (-0.01, 0, 0.03) in its frame, rotated by -pi/4 and lifted by 0.107
    hand_com = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ [-0.01, 0, 0.03] + [0, 0, 0.107]
    link7_com = np.array([1.0517e-02, -4.252e-03, 6.1597e-02])
    expected = (0.735522 * link7_com + 0.73 * hand_com) / (0.735522 + 0.73)
    _, com, _ = numeric_mass_properties(model, bodies["panda_link7"])
    np.testing.assert_allclose(com, expected, rtol=1e-12)


def test_ur5_children_of_world_welded_bodies():
    model = load_urdf(URDF_DIR / "ur5_robot.urdf")
    shoulder = model.bodies[0]
    assert shoulder.name == "shoulder_link" and shoulder.parent == WORLD
    np.testing.assert_allclose(as_np(shoulder.joint.origin_xyz).ravel(), [0, 0, 0.089159])


def test_mass_properties_are_parameters_with_urdf_defaults():
    model = load_urdf(URDF_DIR / "double_pendulum.urdf")
    link2 = model.bodies[1]
    p = model.parameters
    assert link2.mass == sp.Symbol("m_link2") and p["m_link2"] == 0.33238
    assert link2.com == vector(sp.symbols("cx_link2 cy_link2 cz_link2"))
    assert (p["cx_link2"], p["cy_link2"], p["cz_link2"]) == (-0.0050107, 1.9371e-10, 0.10088)
    assert link2.inertia[0, 2] == link2.inertia[2, 0] == sp.Symbol("Ixz_link2")
    assert (p["Ixx_link2"], p["Ixz_link2"], p["Izz_link2"]) == (0.0011753, -2.9304e-08, 1.4553e-05)
    assert list(p)[:11] == ["g", "m_link1", "cx_link1", "cy_link1", "cz_link1", "Ixx_link1",
                            "Iyy_link1", "Izz_link1", "Ixy_link1", "Ixz_link1", "Iyz_link1"]
    # kinematics stay numeric
    assert not model.bodies[1].joint.origin_xyz.free_symbols
    assert model.bodies[1].joint.axis == vector([1, 0, 0])


# --- small URDFs ----------------------------------------------------------------------------

INERTIAL = ('<inertial><origin xyz="0 0 0.1"/><mass value="1.0"/>'
            '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>')


def urdf(links: str | None = None, joints: str | None = None, robot: str = "toy") -> str:
    """A two-joint arm; pass links or joints to replace them."""
    if links is None:
        links = (f'<link name="base"/><link name="l1">{INERTIAL}</link>'
                 f'<link name="l2">{INERTIAL}</link>')
    if joints is None:
        joints = ('<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>'
                  '<axis xyz="0 0 1"/></joint>'
                  '<joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>'
                  '<origin xyz="0 0 0.5"/></joint>')
    return f'<?xml version="1.0"?>\n<robot name="{robot}">\n{links}\n{joints}\n</robot>\n'


def test_small_urdf_defaults():
    model = parse_urdf_text(urdf(), "toy.urdf")
    assert model.name == "toy" and model.source == "toy.urdf"
    assert model.coordinates == ["j1", "j2"]
    j2 = model.bodies[1].joint
    assert j2.axis == vector([1, 0, 0])  # URDF's default axis
    assert j2.origin_xyz == vector([0, 0, sp.Float(0.5)])
    assert j2.limits is None and j2.mimic is None


def test_link_without_inertial_is_massless_and_has_no_parameters():
    links = f'<link name="base"/><link name="l1"/><link name="l2">{INERTIAL}</link>'
    model = parse_urdf_text(urdf(links=links), "toy.urdf")
    l1 = model.bodies[0]
    assert l1.mass == 0 and l1.inertia == sp.zeros(3, 3) and l1.com == sp.zeros(3, 1)
    assert not [k for k in model.parameters if k.endswith("_l1")]
    assert "m_l2" in model.parameters


def test_inertial_rpy_rotates_inertia_into_body_axes():
    inertial = ('<inertial><origin xyz="0.1 0.2 0.3" rpy="0 0 1.5707963267948966"/>'
                '<mass value="2"/><inertia ixx="1" ixy="0" ixz="0" iyy="2" iyz="0" izz="3"/>'
                '</inertial>')
    links = f'<link name="base"/><link name="l1">{inertial}</link><link name="l2">{INERTIAL}</link>'
    model = parse_urdf_text(urdf(links=links), "toy.urdf")
    mass, com, inertia = numeric_mass_properties(model, model.bodies[0])
    assert mass == 2.0
    np.testing.assert_allclose(com, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(inertia, np.diag([2.0, 1.0, 3.0]), atol=1e-15)


def test_general_inertial_rotation_matches_r_i_rt():
    rpy = (0.3, -0.5, 1.1)
    tensor = np.array([[0.3, 0.01, -0.02], [0.01, 0.4, 0.03], [-0.02, 0.03, 0.5]])
    inertial = (f'<inertial><origin rpy="{rpy[0]} {rpy[1]} {rpy[2]}"/><mass value="2"/>'
                '<inertia ixx="0.3" ixy="0.01" ixz="-0.02" iyy="0.4" iyz="0.03" izz="0.5"/>'
                '</inertial>')
    links = f'<link name="base"/><link name="l1">{inertial}</link><link name="l2">{INERTIAL}</link>'
    model = parse_urdf_text(urdf(links=links), "toy.urdf")
    rot = as_np(rotation_from_rpy(*rpy))
    _, _, inertia = numeric_mass_properties(model, model.bodies[0])
    np.testing.assert_allclose(inertia, rot @ tensor @ rot.T, atol=1e-15)


def test_joint_types_limits_mimic_and_axis_normalisation():
    joints = ('<joint name="j1" type="continuous"><parent link="base"/><child link="l1"/>'
              '<axis xyz="0 0 -1"/><limit effort="5" velocity="2"/></joint>'
              '<joint name="j2" type="prismatic"><parent link="l1"/><child link="l2"/>'
              '<axis xyz="3 4 0"/><limit lower="-0.1" upper="0.2" effort="10" velocity="1"/>'
              '<mimic joint="j1" multiplier="2" offset="0.1"/></joint>')
    model = parse_urdf_text(urdf(joints=joints), "toy.urdf")
    j1, j2 = (b.joint for b in model.bodies)
    assert (j1.type, j2.type) == ("continuous", "prismatic")
    assert j1.axis == vector([0, 0, -1])
    np.testing.assert_allclose(as_np(j2.axis).ravel(), [0.6, 0.8, 0.0])
    assert j1.limits == Limits(None, None, 5.0, 2.0)
    assert j2.limits == Limits(-0.1, 0.2, 10.0, 1.0)
    assert j2.mimic == "j1" and model.dof == 2


def test_tree_order_is_pinocchios_depth_first_siblings_by_joint_name():
    """Depth-first, siblings in the byte order of their joints' names (urdfdom's map),
    whatever the file's order; a fixed joint's name places its subtree among its siblings."""
    links = "".join(f'<link name="{n}">{INERTIAL}</link>' for n in "rabcdef")
    limit = '<limit lower="-1" upper="1" effort="1" velocity="1"/>'  # Pinocchio needs one
    joints = "".join(
        f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
        f'{limit}</joint>'
        for name, kind, parent, child in (
            ("jd", "revolute", "c", "d"), ("jb", "revolute", "r", "b"),
            ("ja", "revolute", "r", "a"), ("jc", "revolute", "b", "c"),
            ("Zf", "revolute", "e", "f"), ("jz_e", "fixed", "r", "e")))
    text = urdf(links=links, joints=joints)
    model = parse_urdf_text(text, "toy.urdf")
    assert model.coordinates == ["ja", "jb", "jc", "jd", "Zf"]  # "jz_e" > "jb": e after b
    assert "m_r" not in model.parameters  # the root link's inertial is ignored
    pin = pytest.importorskip("pinocchio")
    assert model.coordinates == list(pin.buildModelFromXML(text).names)[1:]


def test_quarter_turns_written_with_eleven_digits_are_exact_and_fewer_digits_are_not():
    """QUARTER_TURN_TOLERANCE (1e-11 rad): Tiago's 1.57079632679 (4.9e-12 short) turns
    exactly a quarter; the Allegro hand's 1.5707963259 (9e-10 short) and Kinova's
    1.570796327 are taken as written, as Pinocchio takes them, so that snapping never moves
    a frame by more than 1e-11 times its distance from the joint."""
    assert rotation_from_rpy(0, 0, 1.57079632679) == sp.ImmutableMatrix(
        [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert rotation_from_rpy(-4.71238898038, 0, 0)[1, 2] == -1
    for angle in (1.5707963259, 1.570796327):
        rot = rotation_from_rpy(0, 0, angle)
        assert rot[0, 0] != 0 and float(rot[0, 0]) == math.cos(angle)


def test_fixed_chain_to_world_is_dropped():
    links = "".join(f'<link name="{n}">{INERTIAL}</link>' for n in ("r", "a", "b"))
    joints = ('<joint name="fa" type="fixed"><parent link="r"/><child link="a"/>'
              '<origin xyz="1 0 0" rpy="0 0 1.5707963267948966"/></joint>'
              '<joint name="jb" type="revolute"><parent link="a"/><child link="b"/>'
              '<origin xyz="1 0 0"/></joint>')
    model = parse_urdf_text(urdf(links=links, joints=joints), "toy.urdf")
    assert [b.name for b in model.bodies] == ["b"]
    b = model.bodies[0]
    assert b.parent == WORLD
    np.testing.assert_allclose(as_np(b.joint.origin_xyz).ravel(), [1, 1, 0], atol=1e-15)
    assert sum(1 for k in model.parameters if k.startswith("m_")) == 1


def test_load_urdf_reads_a_file(tmp_path):
    path = tmp_path / "toy.urdf"
    path.write_text(urdf())
    model = load_urdf(path)
    assert model.source == str(path) and model.dof == 2


# --- malformed URDFs ------------------------------------------------------------------------

def J(name="j1", jtype="revolute", parent="base", child="l1", extra=""):
    return (f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/>'
            f'<child link="{child}"/>{extra}</joint>')


J2 = J("j2", parent="l1", child="l2")


def L(name, inertial=INERTIAL):
    return f'<link name="{name}">{inertial}</link>'


def inertial(mass='value="1"', inertia='ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"',
             origin=""):
    return f"<inertial>{origin}<mass {mass}/><inertia {inertia}/></inertial>"


BASE_LINKS = L("base") + L("l1") + L("l2")

MALFORMED = {
    "xml syntax": ('<robot name="x"><link name="a"></robot>', ["line 1", "malformed XML"]),
    "not robot": ('<model name="x"/>', ["<model>", "must be <robot>"]),
    "no links": ('<robot name="x"/>', ["no <link>"]),
    "unknown child link": (urdf(joints=J() + J("j2", parent="l1", child="nowhere")),
                           ["joint 'j2', <child>", "unknown link 'nowhere'"]),
    "unknown parent link": (urdf(joints=J(parent="nowhere") + J2),
                            ["joint 'j1', <parent>", "unknown link 'nowhere'"]),
    "several roots": (urdf(links=BASE_LINKS + L("stray")), ["several root links", "stray"]),
    "child of two joints": (urdf(joints=J() + J2 + J("j3", parent="base", child="l2")),
                            ["link 'l2'", "child of both joint 'j2' and joint 'j3'", "tree"]),
    "cycle": (urdf(links=BASE_LINKS + L("l3"),
                   joints=J() + J("j2", parent="l3", child="l2") + J("j3", parent="l2",
                                                                     child="l3")),
              ["form a cycle", "l2", "l3"]),
    "self loop": (urdf(joints=J() + J("j2", parent="l2", child="l2")), ["cycle", "l2"]),
    "missing joint name": (urdf(joints=J() + J2.replace('name="j2" ', "")),
                           ["joint #2", "missing attribute 'name'"]),
    "missing joint type": (urdf(joints=J() + J2.replace('type="revolute"', "")),
                           ["joint 'j2'", "missing attribute 'type'"]),
    "missing parent": (urdf(joints=J() + J2.replace('<parent link="l1"/>', "")),
                       ["joint 'j2'", "missing <parent>"]),
    "missing parent link attribute": (urdf(joints=J() + J2.replace('parent link="l1"', "parent")),
                                      ["joint 'j2', <parent>", "missing attribute 'link'"]),
    "missing child link attribute": (urdf(joints=J() + J2.replace('child link="l2"', "child")),
                                     ["joint 'j2', <child>", "missing attribute 'link'"]),
    "missing mass value": (urdf(links=L("base") + L("l1") + L("l2", inertial(mass=""))),
                           ["link 'l2', inertial mass", "missing attribute 'value'"]),
    "missing mass element": (urdf(links=L("base") + L("l1") + L(
        "l2", '<inertial><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>')),
        ["link 'l2', inertial", "missing <mass>"]),
    "missing inertia element": (urdf(links=L("base") + L("l1") + L(
        "l2", '<inertial><mass value="1"/></inertial>')),
        ["link 'l2', inertial", "missing <inertia>"]),
    "missing inertia component": (urdf(links=L("base") + L("l1") + L(
        "l2", inertial(inertia='ixx="1" ixy="0" ixz="0" iyy="1" izz="1"'))),
        ["link 'l2', inertial inertia", "missing attribute 'iyz'"]),
    "mass not a number": (urdf(links=L("base") + L("l1") + L("l2", inertial(mass='value="abc"'))),
                          ["link 'l2', inertial mass", "'abc' is not a number"]),
    "inertia nan": (urdf(links=L("base") + L("l1") + L(
        "l2", inertial(inertia='ixx="nan" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"'))),
        ["link 'l2', inertial inertia ixx", "'nan' is not a finite number"]),
    "origin xyz wrong length": (urdf(joints=J() + J2.replace("</joint>",
                                                             '<origin xyz="0 1"/></joint>')),
                                ["joint 'j2', origin xyz", "expected 3 numbers", "'0 1'"]),
    "origin rpy not a number": (urdf(joints=J() + J2.replace("</joint>",
                                                             '<origin rpy="0 x 0"/></joint>')),
                                ["joint 'j2', origin rpy", "'x' is not a number"]),
    "inertial origin inf": (urdf(links=L("base") + L("l1") + L(
        "l2", inertial(origin='<origin xyz="0 inf 0"/>'))),
        ["link 'l2', inertial, origin xyz", "not a finite number"]),
    "axis wrong length": (urdf(joints=J() + J2.replace("</joint>", '<axis xyz="1 0 0 0"/></joint>')),
                          ["joint 'j2', axis", "expected 3 numbers"]),
    "zero axis": (urdf(joints=J() + J2.replace("</joint>", '<axis xyz="0 0 0"/></joint>')),
                  ["joint 'j2', axis", "zero joint axis"]),
    "limit not a number": (urdf(joints=J() + J2.replace("</joint>",
                                                        '<limit effort="lots"/></joint>')),
                           ["joint 'j2', limit effort", "'lots' is not a number"]),
    "negative mass": (urdf(links=L("base") + L("l1") + L("l2", inertial(mass='value="-1"'))),
                      ["link 'l2', inertial mass", "non-negative", "-1"]),
    "inertia not positive": (urdf(links=L("base") + L("l1") + L(
        "l2", inertial(inertia='ixx="-1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"'))),
        ["link 'l2', inertial inertia", "not positive semi-definite"]),
    "inertia triangle inequality": (urdf(links=L("base") + L("l1") + L(
        "l2", inertial(inertia='ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="3"'))),
        ["link 'l2', inertial inertia", "triangle inequality"]),
    "floating joint not at the root": (urdf(joints=J() + J2.replace("revolute", "floating")),
                                       ["joint 'j2'",
                                        "a floating joint must join a link to the root"]),
    "planar joint": (urdf(joints=J() + J2.replace("revolute", "planar")),
                     ["joint 'j2'", "'planar'", "unsupported"]),
    "unknown joint type": (urdf(joints=J() + J2.replace("revolute", "hinge")),
                           ["joint 'j2'", "unknown joint type 'hinge'"]),
    "duplicate link": (urdf(links=BASE_LINKS + L("l1")), ["link 'l1'", "duplicate link name"]),
    "duplicate joint": (urdf(joints=J() + J("j1", parent="l1", child="l2")),
                        ["joint 'j1'", "duplicate joint name"]),
    "mimic without joint": (urdf(joints=J() + J2.replace("</joint>", "<mimic/></joint>")),
                            ["joint 'j2', mimic", "missing attribute 'joint'"]),
    "nothing moves": (urdf(joints=J(jtype="fixed") + J("j2", "fixed", "l1", "l2")),
                      ["robot 'toy'", "nothing can move"]),
    "non-root world link": (urdf(links=L("base") + L("world") + L("l2"),
                                 joints=J(child="world") + J("j2", parent="world", child="l2")),
                            ["link 'world'", "reserved"]),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_urdf(case):
    text, expected = MALFORMED[case]
    with pytest.raises(ModelError) as info:
        parse_urdf_text(text, "bad.urdf")
    message = str(info.value)
    assert message.startswith("bad.urdf: ")
    for part in expected:
        assert part in message, f"{part!r} not in {message!r}"


def test_a_mimic_tag_naming_no_joint_warns_naming_it_and_loads():
    """example-robot-data's alex_psyonic_hands names `index_q1` for `Left_index_q1`: a
    mimic joint is an independent coordinate anyway, so the tag is dropped with a warning."""
    text = urdf(joints=J() + J2.replace("</joint>", '<mimic joint="ghost"/></joint>'))
    with pytest.warns(UserWarning, match=r"^bad\.urdf: joint 'j2', mimic: mimics unknown "
                      r"joint 'ghost'; the tag is ignored") as record:
        model = parse_urdf_text(text, "bad.urdf")
    assert len(record) == 1
    assert model.coordinates == ["j1", "j2"] and model.body("l2").joint.mimic is None
    # a mimic tag naming a joint of the file stays as metadata, without a warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        kept = parse_urdf_text(urdf(joints=J() + J2.replace(
            "</joint>", '<mimic joint="j1"/></joint>')), "good.urdf")
    assert kept.body("l2").joint.mimic == "j1"


def test_xml_syntax_error_names_the_line():
    text = '<?xml version="1.0"?>\n<robot name="x">\n  <link name="a">\n</robot>\n'
    with pytest.raises(ModelError, match=r"bad.urdf: line 4, column \d+: malformed XML"):
        parse_urdf_text(text, "bad.urdf")


def test_missing_file_is_a_model_error(tmp_path):
    with pytest.raises(ModelError, match="cannot read URDF file"):
        load_urdf(tmp_path / "absent.urdf")


# --- merge_fixed_joints on hand-made models --------------------------------------------------

def rot_np(rpy) -> np.ndarray:
    return as_np(rotation_from_rpy(*rpy))


def two_bodies_and_a_child():
    """a (revolute) carries b (fixed, rotated origin), which carries c (prismatic)."""
    m_a, c_a = 2.0, [0.1, 0.2, 0.3]
    i_a = [0.3, 0.4, 0.5, 0.01, -0.02, 0.03]  # ixx iyy izz ixy ixz iyz
    m_b, c_b = 1.5, [-0.2, 0.1, 0.05]
    i_b = [0.1, 0.2, 0.25, 0.004, 0.0, -0.01]
    xyz_f, rpy_f = [0.3, -0.1, 0.2], (0.4, -0.2, 0.9)
    xyz_c, rpy_c = [0.5, 0.0, 0.1], (0.0, 0.3, 0.0)
    bodies = (
        Body("a", WORLD, Joint("qa", "revolute", origin_xyz=vector([0, 0, 1]),
                               axis=vector([0, 1, 0])),
             sp.Float(m_a), vector(map(sp.Float, c_a)), inertia_matrix(*map(sp.Float, i_a))),
        Body("b", "a", Joint("fab", "fixed", origin_xyz=vector(map(sp.Float, xyz_f)),
                             origin_rotation=rotation_from_rpy(*rpy_f)),
             sp.Float(m_b), vector(map(sp.Float, c_b)), inertia_matrix(*map(sp.Float, i_b))),
        Body("c", "b", Joint("qc", "prismatic", origin_xyz=vector(map(sp.Float, xyz_c)),
                             origin_rotation=rotation_from_rpy(*rpy_c), axis=vector([1, 0, 0])),
             sp.Float(0.5), vector([0, sp.Float(0.1), 0]), inertia_matrix(0.01, 0.02, 0.025)),
    )
    model = Model("merge", bodies, {}, vector([0, 0, -9.81]))
    return model, {"m_a": m_a, "c_a": c_a, "i_a": i_a, "m_b": m_b, "c_b": c_b, "i_b": i_b,
                   "xyz_f": xyz_f, "rpy_f": rpy_f, "xyz_c": xyz_c, "rpy_c": rpy_c}


def tensor(i6) -> np.ndarray:
    ixx, iyy, izz, ixy, ixz, iyz = i6
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def test_merge_fixed_joint_mass_com_inertia():
    model, d = two_bodies_and_a_child()
    merged = merge_fixed_joints(model)
    assert [b.name for b in merged.bodies] == ["a", "c"]
    a, c = merged.bodies

    # hand computation: b's mass centre and inertia in a's frame, then parallel axes
    r_f = rot_np(d["rpy_f"])
    c_b = np.array(d["xyz_f"]) + r_f @ d["c_b"]
    i_b = r_f @ tensor(d["i_b"]) @ r_f.T
    mass = d["m_a"] + d["m_b"]
    com = (d["m_a"] * np.array(d["c_a"]) + d["m_b"] * c_b) / mass

    def shift(m, offset):
        return m * (offset @ offset * np.eye(3) - np.outer(offset, offset))

    inertia = (tensor(d["i_a"]) + shift(d["m_a"], np.array(d["c_a"]) - com)
               + i_b + shift(d["m_b"], c_b - com))
    assert float(a.mass) == pytest.approx(mass)
    np.testing.assert_allclose(as_np(a.com).ravel(), com, rtol=1e-13)
    np.testing.assert_allclose(as_np(a.inertia), inertia, rtol=1e-12, atol=1e-15)
    assert a.inertia == a.inertia.T
    assert a.joint == model.bodies[0].joint

    # c hangs from a now, through the composed origin
    assert c.parent == "a"
    np.testing.assert_allclose(as_np(c.joint.origin_xyz).ravel(),
                               np.array(d["xyz_f"]) + r_f @ d["xyz_c"], rtol=1e-14)
    np.testing.assert_allclose(as_np(c.joint.origin_rotation), r_f @ rot_np(d["rpy_c"]),
                               rtol=1e-14, atol=1e-16)
    assert (c.mass, c.com, c.inertia) == (model.bodies[2].mass, model.bodies[2].com,
                                          model.bodies[2].inertia)
    assert c.joint.axis == model.bodies[2].joint.axis
    assert all(isinstance(e, (sp.Float, sp.Integer)) for e in a.com)


def test_merge_keeps_a_model_without_fixed_joints():
    model, _ = two_bodies_and_a_child()
    moving = Model("m", (model.bodies[0],), {}, model.gravity)
    assert merge_fixed_joints(moving) is moving


def test_merge_into_world_drops_the_body():
    model, d = two_bodies_and_a_child()
    _, b, c = model.bodies
    welded = Model("w", (Body("b", WORLD, b.joint, b.mass, b.com, b.inertia),
                         Body("c", "b", c.joint, c.mass, c.com, c.inertia)), {}, model.gravity)
    merged = merge_fixed_joints(welded)
    assert [x.name for x in merged.bodies] == ["c"]
    assert merged.bodies[0].parent == WORLD
    r_f = rot_np(d["rpy_f"])
    np.testing.assert_allclose(as_np(merged.bodies[0].joint.origin_xyz).ravel(),
                               np.array(d["xyz_f"]) + r_f @ d["xyz_c"], rtol=1e-14)


def test_merge_chain_of_fixed_joints_and_massless_bodies():
    # a <- b (fixed, massless) <- e (fixed, massive): e's placement composes through b.
    rz = rotation_from_rpy(0, 0, sp.pi / 2)
    a = Body("a", WORLD, Joint("qa", "revolute"), sp.Integer(1), vector([0, 0, 0]),
             inertia_matrix(1, 1, 1))
    b = Body("b", "a", Joint("fb", "fixed", origin_xyz=vector([1, 0, 0]), origin_rotation=rz))
    e = Body("e", "b", Joint("fe", "fixed", origin_xyz=vector([1, 0, 0])), sp.Integer(1),
             vector([0, 0, 0]), inertia_matrix(1, 2, 3))
    merged = merge_fixed_joints(Model("chain", (a, b, e), {}, vector([0, 0, -1])))
    (only,) = merged.bodies
    # e sits at (1, 1, 0) in a's frame, its axes turned by 90 degrees about z
    assert only.mass == 2
    assert only.com == vector([sp.Rational(1, 2), sp.Rational(1, 2), 0])
    shift = np.array([[0.5, -0.5, 0], [-0.5, 0.5, 0], [0, 0, 1.0]])  # two unit masses
    expected = np.eye(3) + np.diag([2.0, 1.0, 3.0]) + shift
    np.testing.assert_allclose(as_np(only.inertia), expected, atol=1e-15)


def test_merge_zero_total_mass():
    a = Body("a", WORLD, Joint("qa", "revolute"), sp.Integer(0), vector([0, 0, 0]),
             inertia_matrix(0.1, 0.1, 0.1))
    b = Body("b", "a", Joint("fb", "fixed", origin_xyz=vector([1, 0, 0])), sp.Integer(0),
             vector([0, 0, 0]), inertia_matrix(0.2, 0.3, 0.4))
    (only,) = merge_fixed_joints(Model("z", (a, b), {}, vector([0, 0, -1]))).bodies
    assert only.mass == 0
    assert only.com == vector([0, 0, 0])
    np.testing.assert_allclose(as_np(only.inertia), np.diag([0.3, 0.4, 0.5]))


def test_merge_symbolic():
    m1, m2, L = sp.symbols("m1 m2 L")  # plain symbols, as the model declares them
    a = Body("a", WORLD, Joint("qa", "revolute"), m1, vector([0, 0, 0]), inertia_matrix(0, 0, 0))
    b = Body("b", "a", Joint("fb", "fixed", origin_xyz=vector([L, 0, 0])), m2,
             vector([0, 0, 0]), inertia_matrix(0, 0, 0))
    model = Model("s", (a, b), {"m1": 1.0, "m2": 2.0, "L": 0.5}, vector([0, 0, -1]))
    (only,) = merge_fixed_joints(model).bodies
    assert sp.simplify(only.mass - (m1 + m2)) == 0
    assert sp.simplify(only.com[0] - m2 * L / (m1 + m2)) == 0
    # two point masses a distance L apart: I = m1 m2 / (m1 + m2) L^2 about y and z
    reduced = m1 * m2 / (m1 + m2) * L**2
    assert sp.simplify(only.inertia[0, 0]) == 0
    assert sp.simplify(only.inertia[1, 1] - reduced) == 0
    assert sp.simplify(only.inertia[2, 2] - reduced) == 0
