"""Inertias of real CAD exports: a small breach of positive-definiteness or of the triangle
inequality loads with a gagen.InertiaWarning, strict=True refuses it, a gross one is refused
with advice. The real case: the Allegro hand of example-robot-data (tests/data/urdf), whose
finger-tip links break the triangle inequality by 20 % of their largest moment."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import gagen
from gagen.app.cli import main as cli_main
from gagen.errors import InertiaWarning, ModelError
from gagen.model.model import (
    INERTIA_DEFINITE_TOLERANCE,
    INERTIA_TRIANGLE_TOLERANCE,
    check_inertia,
    round_off_floor,
)
from gagen.model.modelfile import parse_model_text
from gagen.model.resolve import resolve_model
from gagen.model.urdf import parse_urdf_text

ALLEGRO = Path(__file__).resolve().parent / "data" / "urdf" / "allegro_right_hand.urdf"
# The links whose moments break the triangle inequality (a copy of one finger's tip link
# design in each finger, and the thumb's tip)
# in coordinate order: Pinocchio's, where the thumb's joint_12.0 sorts before joint_4.0
ALLEGRO_DEFECTS = ("link_3.0", "link_15.0", "link_7.0", "link_11.0")


def principal(a: float, b: float, c: float) -> np.ndarray:
    """A tensor with principal moments a, b, c along tilted axes."""
    rot, _ = np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))
    tensor = rot @ np.diag([a, b, c]) @ rot.T
    return (tensor + tensor.T) / 2


def inertia_warnings(record) -> list[str]:
    return [str(w.message) for w in record if issubclass(w.category, InertiaWarning)]


# ------------------------------------------------------------------------- check_inertia


@pytest.mark.parametrize("moments, defect", [
    ((2.30e-6, 3.49e-6, 7.27e-6), "break the triangle inequality"),  # the Allegro's
    ((1.0, 1.0, 2.0 * (1 + INERTIA_TRIANGLE_TOLERANCE) - 1e-9), "triangle inequality"),
    ((-0.5 * INERTIA_DEFINITE_TOLERANCE, 1.0, 1.0), "not positive semi-definite"),
])
def test_borderline_inertia_warns_and_strict_refuses(moments, defect):
    tensor = principal(*moments)
    with pytest.warns(InertiaWarning, match=rf"robot\.urdf: link 'l1': .*{defect}.*"
                      r"strict=True refuses it"):
        check_inertia(tensor, "robot.urdf", "link 'l1'")
    with pytest.raises(ModelError, match=rf"link 'l1': .*{defect}.*refused because "
                       r"strict=True \(load with strict=False"):
        check_inertia(tensor, "robot.urdf", "link 'l1'", strict=True)


@pytest.mark.parametrize("moments, defect", [
    ((1.0, 1.0, 3.0), "break the triangle inequality"),
    ((0.1, 0.1, 0.3), "break the triangle inequality"),
    ((-2 * INERTIA_DEFINITE_TOLERANCE, 1.0, 1.0), "not positive semi-definite"),
    ((-1.0, 1.0, 1.0), "not positive semi-definite"),
])
def test_gross_inertia_is_refused_with_advice(moments, defect):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # refused, not warned about
        with pytest.raises(ModelError, match=rf"{defect}.*Fix the inertia in the file: gagen "
                           r"accepts the round-off of CAD exports with a warning \(unless "
                           r"strict=True\)"):
            check_inertia(principal(*moments), "robot.urdf", "link 'l1'")


@pytest.mark.parametrize("moments", [(1.0, 2.0, 3.0), (0.0, 1.0, 1.0), (1.0, 1.0, 2.0 + 1e-12),
                                     (-1e-12, 1.0, 1.0)])
def test_physical_inertia_and_rounding_pass_silently(moments):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_inertia(principal(*moments), "robot.urdf", "link 'l1'", strict=True)


# --------------------------------------------------------------- round-off around zero

# example-robot-data's icub.urdf, link r_hip_2: a point mass written with round-off
ICUB_HIP = {"mass": 0.526, "com": 0.03045, "moments": (-5.42101e-20, -5.42101e-20, 0.0)}


def test_round_off_around_a_zero_inertia_is_no_defect():
    """A point mass's largest moment is zero, so no defect is small relative to it: the
    floor tied to the body's mass and size (1e-9 of m l^2) accepts round-off there."""
    floor = round_off_floor(ICUB_HIP["mass"], ICUB_HIP["com"])
    assert floor == pytest.approx(1e-9 * 0.526 * 0.03045 ** 2)
    tensor = np.diag(ICUB_HIP["moments"])
    with pytest.raises(ModelError, match="not positive semi-definite"):
        check_inertia(tensor, "icub.urdf", "link 'r_hip_2'")  # no floor: refused
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_inertia(tensor, "icub.urdf", "link 'r_hip_2'", strict=True, floor=floor)
        for moments in ((0.0, 0.0, 0.0), (0.0, 1e-4, 1e-4), (-1e-19, 1e-4, 1e-4)):  # point,
            check_inertia(principal(*moments), "robot.urdf", "link 'l1'", strict=True,
                          floor=floor)  # rod, rod with round-off
    # the floor is at least 1 cm's worth: a mass centre at the origin does not remove it
    assert round_off_floor(0.526, 0.0) == pytest.approx(1e-9 * 0.526 * 1e-4)


@pytest.mark.parametrize("moments, defect", [
    ((-1e-9, 0.0, 0.0), "not positive semi-definite"),  # 2000 floors below zero
    ((0.0, 0.0, 1e-9), "triangle inequality"),  # a rod about its own axis only
])
def test_a_defect_beyond_the_floor_is_still_refused(moments, defect):
    floor = round_off_floor(ICUB_HIP["mass"], ICUB_HIP["com"])
    with pytest.raises(ModelError, match=defect):
        check_inertia(principal(*moments), "robot.urdf", "link 'l1'", floor=floor)


def test_a_urdf_point_mass_with_round_off_loads_silently():
    ixx, iyy, izz = ICUB_HIP["moments"]
    text = f"""<robot name="hip"><link name="base"/>
      <link name="hip"><inertial><mass value="{ICUB_HIP['mass']}"/>
        <origin xyz="0 0 {ICUB_HIP['com']}"/>
        <inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" ixy="0" ixz="0" iyz="0"/></inertial></link>
      <link name="flange"/>
      <joint name="j" type="revolute"><parent link="base"/><child link="hip"/>
        <axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
      <joint name="weld" type="fixed"><parent link="hip"/><child link="flange"/></joint>
    </robot>"""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = parse_urdf_text(text, "hip.urdf", strict=True)
    assert model.dof == 1 and model.parameters["m_hip"] == ICUB_HIP["mass"]


# ------------------------------------------------------------------------ the Allegro hand


def test_allegro_loads_with_one_warning_per_defective_link():
    with pytest.warns(InertiaWarning) as record:
        model = resolve_model(ALLEGRO)
    messages = inertia_warnings(record)
    assert len(messages) == len(ALLEGRO_DEFECTS)
    for link, message in zip(ALLEGRO_DEFECTS, messages, strict=True):
        assert f"link '{link}', inertial inertia" in message
        assert "break the triangle inequality" in message
    assert model.dof == 16


def test_allegro_strict_is_refused():
    with pytest.raises(ModelError, match=r"allegro_right_hand\.urdf: link 'link_3\.0', "
                       r"inertial inertia: principal moments .*2\.30064.*triangle inequality"
                       r".*strict=True"):
        resolve_model(ALLEGRO, strict=True)
    for backend in ("lambdify", "compiled"):  # refused before anything is derived or built
        with pytest.raises(ModelError, match="strict=True"):
            gagen.load(ALLEGRO, backend=backend, strict=True)


@pytest.mark.slow
def test_allegro_dynamics_match_pinocchio():
    pin = pytest.importorskip("pinocchio")
    with pytest.warns(InertiaWarning):
        dyn = gagen.load(ALLEGRO, backend="lambdify")
    model = pin.buildModelFromUrdf(str(ALLEGRO))
    data = model.createData()
    order = [model.getJointId(name) - 1 for name in dyn.coordinates]
    rng = np.random.default_rng(0)
    for _ in range(3):
        q = rng.uniform(-1, 1, dyn.n)
        q_pin = np.zeros(model.nq)
        q_pin[order] = q
        mass = pin.crba(model, data, q_pin)
        mass = np.triu(mass) + np.triu(mass, 1).T
        np.testing.assert_allclose(dyn.mass_matrix(q), mass[np.ix_(order, order)],
                                   rtol=1e-9, atol=1e-12)


def test_cli_strict_flag(capsys):
    assert cli_main(["info", "--strict", str(ALLEGRO)]) != 0
    assert "strict=True" in capsys.readouterr().err
    assert cli_main(["info", str(ALLEGRO)]) == 0
    out, err = capsys.readouterr()
    assert "coordinates  16" in out
    # the command line shows a warning as one line
    assert "gagen: warning: " in err and "link 'link_3.0'" in err


# --------------------------------------------------------- model files and Model objects


BORDERLINE_YAML = """
name: tip
parameters: {g: 9.81}
bodies:
  - name: tip
    parent: world
    joint: {name: q1, type: revolute, axis: [0, 0, 1]}
    mass: 1
    com: [0.1, 0, 0]
    inertia: [1.0, 1.0, 2.2, 0, 0, 0]
"""


def test_model_file_borderline_inertia_warns_once_and_strict_refuses():
    with pytest.warns(InertiaWarning) as record:
        model = parse_model_text(BORDERLINE_YAML, "tip.yaml")
    assert inertia_warnings(record) == [m for m in inertia_warnings(record)
                                        if "tip.yaml: body 'tip', inertia" in m]
    assert len(inertia_warnings(record)) == 1
    with pytest.raises(ModelError, match=r"tip\.yaml: body 'tip', inertia: .*strict=True"):
        parse_model_text(BORDERLINE_YAML, "tip.yaml", strict=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert resolve_model(model) is model  # a Model is taken as it is...
    with pytest.raises(ModelError, match="strict=True"):
        resolve_model(model, strict=True)  # ...unless strict


@pytest.mark.slow
def test_cached_model_accepted_with_a_warning_is_still_refused_when_strict(tmp_path):
    path = tmp_path / "tip.yaml"
    path.write_text(BORDERLINE_YAML)
    with pytest.warns(InertiaWarning):
        gagen.load(path, cache_dir=tmp_path / "cache", verbose=False)
    with pytest.raises(ModelError, match="strict=True"):
        gagen.load(path, cache_dir=tmp_path / "cache", strict=True)


# ------------------------------------------------------- rigid units: welded parts, sensors

def _welded_sensor_urdf(sensor_moments: tuple[float, float, float], arm_moments=(1, 1, 1)):
    """An arm link on a revolute joint with a camera welded to it (a fixed joint)."""
    ixx, iyy, izz = sensor_moments
    ax, ay, az = arm_moments
    return f"""<robot name="welded">
      <link name="base"/>
      <link name="arm"><inertial><mass value="2.0"/><origin xyz="0 0 0.2"/>
        <inertia ixx="{ax}" iyy="{ay}" izz="{az}" ixy="0" ixz="0" iyz="0"/></inertial></link>
      <link name="camera"><inertial><mass value="0.01"/>
        <inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" ixy="0" ixz="0" iyz="0"/></inertial></link>
      <joint name="shoulder" type="revolute"><parent link="base"/><child link="arm"/>
        <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
      <joint name="mount" type="fixed"><parent link="arm"/><child link="camera"/>
        <origin xyz="0 0.1 0.3"/></joint>
    </robot>"""


def test_a_welded_part_judged_by_its_rigid_unit():
    """ANYmal C's depth cameras break the triangle inequality by half their largest moment:
    what moves is the link they are welded to, whose combined inertia is physical; the
    camera's own inertia is accepted with a warning naming it, and refused by strict."""
    from gagen.model.urdf import parse_urdf_text

    text = _welded_sensor_urdf((1e-6, 1e-5, 3e-5))
    with pytest.warns(InertiaWarning) as record:
        model = parse_urdf_text(text, "welded.urdf")
    (message,) = inertia_warnings(record)
    assert "link 'camera', inertial inertia" in message and "rigid unit of link 'arm'" in message
    assert model.dof == 1
    with pytest.raises(ModelError, match=r"welded\.urdf: link 'camera'.*strict=True"):
        parse_urdf_text(text, "welded.urdf", strict=True)


def test_a_rigid_unit_that_is_not_physical_is_refused_with_its_parts_named():
    from gagen.model.urdf import parse_urdf_text

    text = _welded_sensor_urdf((1e-6, 1e-6, 1e-6), arm_moments=(1, 1, 3))
    with pytest.raises(ModelError, match=r"link 'arm' \(with 1 welded link\), inertial "
                       r"inertia: .*triangle inequality.*Fix the inertia"):
        parse_urdf_text(text, "welded.urdf")


def test_parts_welded_to_the_world_do_not_move_and_are_not_checked():
    """ANYmal C on a fixed base: its cameras and hatch are welded to the base, which is
    welded to the world; they load silently."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", InertiaWarning)
        model = resolve_model(Path(ALLEGRO).parent / "anymal_c.urdf")
    assert model.dof == 12
