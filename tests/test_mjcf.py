"""MJCF through MuJoCo's compiler: gagen's dynamics against MuJoCo's own (mj_fullM,
qfrc_bias) at random states, the reading of names, joints and joint terms, and the checks
made before MuJoCo sees a file.

The MJCF files compared are written by MuJoCo itself from the shared URDFs
(`MjModel.from_xml_path` on a copy without visual and collision geometry, whose meshes are
not here, then `mj_saveLastXML`), plus the hand-written tests/data/mjcf/features.xml.
"""

from __future__ import annotations

import os
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import gagen
from gagen.app.cli import main as cli_main
from gagen.building import cache
from gagen.errors import ModelError
from gagen.model.inputs import MAX_BODIES
from gagen.model.mjcf import compile_mjcf, joint_terms, load_mjcf
from gagen.model.resolve import resolve_model

mujoco = pytest.importorskip("mujoco")

DATA = Path(__file__).resolve().parent / "data"
FEATURES = DATA / "mjcf" / "features.xml"
CONVERTED = ("double_pendulum", "so100", "ur5_robot", "panda")
RTOL = 1e-9
STATES = 5


# ------------------------------------------------------------------------------ helpers


def mjcf_from_urdf(name: str, folder: Path) -> Path:
    """MuJoCo's MJCF of a shared URDF, written by MuJoCo (geometry stripped: no meshes)."""
    robot = ET.parse(DATA / "urdf" / f"{name}.urdf").getroot()
    for link in robot.iter("link"):
        for tag in ("visual", "collision"):
            for elem in link.findall(tag):
                link.remove(elem)
    urdf = folder / f"{name}.urdf"
    urdf.write_bytes(ET.tostring(robot))
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda text: None)  # not into ./MUJOCO_LOG.TXT
    try:
        model = mujoco.MjModel.from_xml_path(str(urdf))
    finally:
        mujoco.set_mju_user_warning(previous)
    path = folder / f"{name}.xml"
    mujoco.mj_saveLastXML(str(path), model)
    return path


@pytest.fixture(scope="module")
def converted(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("mjcf")
    return {name: mjcf_from_urdf(name, folder) for name in CONVERTED}


def full_mass_matrix(model, data) -> np.ndarray:
    """mj_fullM across MuJoCo 3 (m, dst, qM) and 4 (m, d, dst)."""
    dense = np.zeros((model.nv, model.nv))
    try:
        mujoco.mj_fullM(model, data, dense)
    except TypeError:
        mujoco.mj_fullM(model, dense, data.qM)
    return dense


def mujoco_reference(model, q, qd) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's M(q) (with armature) and bias forces C(q, qd) qd + g(q)."""
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = q, qd
    mujoco.mj_forward(model, data)
    return full_mass_matrix(model, data), data.qfrc_bias.copy()


def assert_matches_mujoco(dyn, path: Path, seed: int = 0) -> None:
    """gagen's M (which holds the joints' armature) and inverse dynamics at qdd = 0
    without the joints' damping and friction (MuJoCo keeps those in qfrc_passive and its
    constraints) equal MuJoCo's mj_fullM and qfrc_bias at random states, coordinates in
    MuJoCo's qpos order."""
    model = mujoco.MjModel.from_xml_path(str(path))
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}"
             for j in range(model.njnt)]
    assert dyn.coordinates == names
    terms = joint_terms(model)
    for name, values in terms.items():  # MuJoCo's joint terms are gagen's parameters
        for key, value in values.items():
            assert dyn.parameters[f"{key}_{name}"] == pytest.approx(value)
    rigid = {f"{key}_{name}": 0.0 for name in terms for key in ("damping", "friction")}
    rng = np.random.default_rng(seed)
    for _ in range(STATES):
        q, qd = rng.uniform(-1.5, 1.5, model.nq), rng.uniform(-2, 2, model.nv)
        mass, bias = mujoco_reference(model, q, qd)
        ours = dyn.mass_matrix(q)
        np.testing.assert_allclose(ours, mass, rtol=RTOL, atol=RTOL * np.abs(mass).max())
        tau = dyn.inverse_dynamics(q, qd, np.zeros(model.nv), p=rigid)
        np.testing.assert_allclose(tau, bias, rtol=RTOL, atol=RTOL * np.abs(bias).max())


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


BODY = ('<body name="{name}" pos="0 0 0.1"><joint name="j_{name}" axis="1 0 0"/>'
        '<inertial pos="0 0 0.05" mass="1" diaginertia="0.01 0.01 0.005"/>{inner}</body>')


def mjcf(inner: str = "", top: str = "", body_inner: str = "") -> str:
    """A one-link MJCF document with extra elements."""
    return (f'<mujoco model="toy">{top}<worldbody>'
            f'{BODY.format(name="link", inner=body_inner)}{inner}</worldbody></mujoco>')


# ------------------------------------------------------------------ against MuJoCo itself


@pytest.mark.parametrize("name", CONVERTED)
def test_mjcf_written_by_mujoco_from_shared_urdf(converted, name):
    assert_matches_mujoco(gagen.load(converted[name], backend="lambdify"), converted[name])


def test_mjcf_and_urdf_of_one_robot_agree(converted):
    """MuJoCo rounds the saved file to 6 digits, so the URDF's dynamics agree to that."""
    from_mjcf = gagen.load(converted["double_pendulum"], backend="lambdify")
    from_urdf = gagen.load(DATA / "urdf" / "double_pendulum.urdf", backend="lambdify")
    assert from_mjcf.coordinates == from_urdf.coordinates
    q = np.random.default_rng(1).uniform(-1, 1, 2)
    np.testing.assert_allclose(from_mjcf.mass_matrix(q), from_urdf.mass_matrix(q), rtol=1e-4,
                               atol=1e-5)


@pytest.fixture(scope="module")
def features():
    return gagen.load(FEATURES, backend="lambdify")


def test_handwritten_features_against_mujoco(features):
    assert_matches_mujoco(features, FEATURES, seed=2)


@pytest.mark.slow
def test_handwritten_features_compiled_against_mujoco(tmp_path):
    assert_matches_mujoco(gagen.load(FEATURES, cache_dir=tmp_path, verbose=False), FEATURES)


def test_mass_parameters_follow_mujoco_body_mass(features):
    """m_<body> is a runtime parameter with MuJoCo's value as default."""
    dyn = features
    model = mujoco.MjModel.from_xml_path(str(FEATURES))
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "upper")
    assert dyn.parameters["m_upper"] == pytest.approx(model.body_mass[body])
    model.body_mass[body] = 4.0
    q = np.random.default_rng(3).uniform(-1, 1, model.nq)
    mass, _ = mujoco_reference(model, q, np.zeros(model.nv))
    np.testing.assert_allclose(dyn.mass_matrix(q, p={"m_upper": 4.0}), mass,
                               rtol=RTOL, atol=RTOL)


# -------------------------------------------------------------------- reading the model


def test_features_bodies_names_and_gravity():
    model = load_mjcf(FEATURES)
    # two joints on "upper": a massless body between them; "tool" (welded) merged into
    # the unnamed body3; the wrist comes from the included file
    assert [b.name for b in model.bodies] == ["base", "upper_pitch", "upper", "body3", "wrist"]
    assert model.coordinates == ["yaw", "pitch", "roll", "joint3", "joint4"]
    assert [b.joint.type for b in model.bodies] == [
        "continuous", "revolute", "continuous", "prismatic", "continuous"]
    assert model.bodies[1].mass == 0 and "m_upper_pitch" not in model.parameters
    assert model.bodies[1].joint.limits.lower == pytest.approx(-np.pi / 2)
    assert model.bodies[3].joint.limits.upper == pytest.approx(0.2)
    assert model.parameters["g"] == pytest.approx(np.hypot(3, 9))
    direction = np.array([float(e.subs("g", 1)) for e in model.gravity])
    np.testing.assert_allclose(direction, np.array([0, -3, -9]) / np.hypot(3, 9))
    assert {"m_base", "Ixy_base", "m_body3", "m_wrist"} <= set(model.parameters)
    assert model.parameters["m_body3"] == pytest.approx(0.5 + 0.3)  # tool merged in


def test_joint_terms_from_defaults_and_classes():
    terms = joint_terms(compile_mjcf(FEATURES))
    assert list(terms) == ["yaw", "pitch", "roll", "joint3", "joint4"]
    assert terms["yaw"] == {"damping": 0.1, "friction": 0.0, "armature": 0.01}
    assert terms["pitch"] == {"damping": 0.1, "friction": 0.2, "armature": 0.05}  # class
    assert terms["roll"]["armature"] == 0.03  # the joint's own value wins over its class
    assert terms["joint3"] == {"damping": 0.5, "friction": 0.0, "armature": 0.02}
    assert terms["joint4"] == {"damping": 0.3, "friction": 0.2, "armature": 0.05}  # childclass


def test_generated_names_never_take_a_name_of_the_file(tmp_path):
    # body 2 is unnamed while another body is called "body2"; joint 1 likewise
    text = mjcf(body_inner='<body pos="0 0 0.1"><joint axis="0 1 0"/>'
                '<inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>'
                '<body name="body2" pos="0 0 0.1"><joint name="joint1" axis="0 1 0"/>'
                '<inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body></body>')
    model = load_mjcf(write(tmp_path, "m.xml", text))
    assert [b.name for b in model.bodies] == ["link", "body2_", "body2"]
    assert model.coordinates == ["j_link", "joint1_", "joint1"]


def test_model_name_from_file_or_stem(tmp_path):
    assert load_mjcf(write(tmp_path, "a.xml", mjcf())).name == "toy"
    unnamed = mjcf().replace(' model="toy"', "")
    assert load_mjcf(write(tmp_path, "robot_b.mjcf", unnamed)).name == "robot_b"


def test_disabled_gravity_is_zero(tmp_path):
    text = mjcf(top='<option><flag gravity="disable"/></option>')
    assert load_mjcf(write(tmp_path, "m.xml", text)).parameters["g"] == 0.0


MASS = '<inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>'
FREE_BODY = f'<body name="drone"><freejoint/>{MASS}</body>'
BALL_BODY = f'<body pos="0 0 0.1"><joint name="shoulder" type="ball"/>{MASS}</body>'


def test_ball_joints_are_refused_naming_them(tmp_path):
    with pytest.raises(ModelError, match=r"joint 'shoulder': ball joints are not supported; "
                       "model it as three"):
        load_mjcf(write(tmp_path, "m.xml", mjcf(body_inner=BALL_BODY)))


def test_a_free_joint_is_a_floating_joint(tmp_path):
    model = load_mjcf(write(tmp_path, "m.xml", mjcf(inner=FREE_BODY)))
    body = model.body("drone")
    assert body.joint.floating and body.parent == "world"
    assert model.nq == model.nv + 1


def test_nothing_moves_is_refused(tmp_path):
    text = ('<mujoco><worldbody><body><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>'
            '</body></worldbody></mujoco>')
    with pytest.raises(ModelError, match="nothing can move"):
        load_mjcf(write(tmp_path, "m.xml", text))


def test_mujoco_compile_error_names_the_file(tmp_path):
    text = mjcf(body_inner='<joint name="j2" type="hinge" axis="0 0 0"/>')
    path = write(tmp_path, "bad.xml", text)
    with pytest.raises(ModelError, match=r"bad\.xml: MuJoCo's compiler: .*axis") as info:
        load_mjcf(path)
    assert "\n" not in str(info.value)


def test_mujoco_writes_nothing_in_the_current_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    previous = mujoco.get_mju_user_warning()
    load_mjcf(FEATURES)
    with pytest.raises(ModelError):
        load_mjcf(write(tmp_path / "m", "bad.xml", mjcf(body_inner='<joint axis="0 0 0"/>')))
    assert [p.name for p in tmp_path.iterdir()] == ["m"]
    assert mujoco.get_mju_user_warning() is previous


def test_without_mujoco_says_how_to_install(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)
    with pytest.raises(ModelError, match=r"pip install gagen\[mjcf\]"):
        resolve_model(write(tmp_path, "m.xml", mjcf()))


# ------------------------------------------------- untrusted files: checked before MuJoCo


def hostile_cases(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    outside = write(tmp_path, "outside/secret.xml", "<mujoco/>")
    inner = tmp_path / "model"
    write(inner, "parts/ok.xml", "<mujoco/>")
    os.symlink(outside, inner / "parts" / "link.xml")
    bodies = "".join(BODY.format(name=f"b{k}", inner="") for k in range(MAX_BODIES + 1))
    return {
        "include climbs out": (mjcf(top='<include file="../outside/secret.xml"/>'), r"'\.\.'"),
        "include absolute": (mjcf(top=f'<include file="{outside}"/>'), "absolute path"),
        "include through a symlink": (mjcf(top='<include file="parts/link.xml"/>'),
                                      "outside the model file's folder"),
        "include missing": (mjcf(top='<include file="parts/none.xml"/>'), "not found"),
        "include twice": (mjcf(top='<include file="parts/ok.xml"/><include file="parts/ok.xml"/>'),
                          "included twice"),
        "mesh absolute": (mjcf(top=f'<asset><mesh file="{outside}"/></asset>'), "absolute path"),
        "meshdir absolute": (mjcf(top='<compiler meshdir="/etc"/>'), "absolute path"),
        "texture climbs out": (mjcf(top='<asset><texture type="2d" file="../x.png"/></asset>'),
                               r"'\.\.'"),
        "DTD": ('<!DOCTYPE m [<!ENTITY a "aaaa">]>' + mjcf(), "must not declare a DTD"),
        "not MJCF": ("<robot/>", "root element of an MJCF file must be <mujoco>"),
        "too many bodies": (mjcf(inner=bodies), f"more than {MAX_BODIES} bodies"),
        "replicate bomb": (mjcf(inner='<replicate count="1000"><replicate count="1000">'
                                '<geom size="1"/></replicate></replicate>'),
                           "copies"),
        "replicated bodies": (mjcf(inner='<replicate count="600" offset="0 0 1">'
                                   + BODY.format(name="r", inner="") + "</replicate>"),
                              f"more than {MAX_BODIES} bodies"),
        "huge height field": (mjcf(top='<asset><hfield name="h" nrow="100000" ncol="100000" '
                                   'size="1 1 1 1"/></asset>'), "entries"),
        "huge texture": (mjcf(top='<asset><texture name="t" type="2d" builtin="checker" '
                              'width="100000" height="100000"/></asset>'), "entries"),
        "user data": (mjcf(top='<size nuser_body="100000000"/>'), "more than"),
        "composite": (mjcf(inner='<composite type="particle" count="10 10 10"/>'),
                      "not rigid bodies"),
        "plugin": (mjcf(top='<extension><plugin plugin="mujoco.pid"/></extension>'),
                   "plugins are not supported"),
        "builtin mesh": (mjcf(top='<asset><mesh name="s" builtin="sphere" params="20"/></asset>'),
                         "builtin meshes"),
    }


def test_hostile_mjcf_is_refused_before_mujoco(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(mujoco.MjModel, "from_xml_path",
                        lambda *a, **k: calls.append(a) or pytest.fail("MuJoCo was called"))
    for case, (text, reason) in hostile_cases(tmp_path).items():
        path = write(tmp_path / "model", f"{case.replace(' ', '_')}.xml", text)
        with pytest.raises(ModelError, match=reason):
            resolve_model(path)
        assert cache.input_key(path, []) is None, case
    assert calls == []


def test_assets_and_includes_inside_the_folder_are_read(tmp_path):
    folder = tmp_path / "robot"
    write(folder, "meshes/tet.obj",
          "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    write(folder, "parts/arm.xml", '<mujoco><asset><mesh name="tet" file="tet.obj"/></asset>'
          "</mujoco>")
    text = mjcf(top='<compiler meshdir="meshes"/><include file="parts/arm.xml"/>',
                body_inner='<body pos="0 0 0.1"><joint axis="0 1 0"/>'
                '<geom type="mesh" mesh="tet" density="10"/></body>')
    model = load_mjcf(write(folder, "m.xml", text))
    assert model.parameters["m_body2"] == pytest.approx(10 / 6)  # a tetrahedron of volume 1/6


# ------------------------------------------------------------------------ the cache key


def test_input_key_covers_included_files_and_strict(tmp_path):
    write(tmp_path, "parts/wrist.xml", (DATA / "mjcf" / "parts" / "wrist.xml").read_text())
    path = write(tmp_path, "features.xml", FEATURES.read_text())
    key = cache.input_key(path, ["strict=False"])
    assert key is not None and key == cache.input_key(path, ["strict=False"])
    assert key != cache.input_key(path, ["strict=True"])
    write(tmp_path, "parts/wrist.xml",
          (DATA / "mjcf" / "parts" / "wrist.xml").read_text().replace("800", "900"))
    assert cache.input_key(path, ["strict=False"]) != key


# ------------------------------------------------------------------------------ the CLI


def test_cli_info_reads_mjcf(capsys):
    assert cli_main(["info", str(FEATURES)]) == 0
    out = capsys.readouterr().out
    assert "coordinates  5: yaw, pitch, roll, joint3, joint4" in out
    assert "m_wrist" in out


def test_cli_help_mentions_mjcf(capsys):
    with pytest.raises(SystemExit):
        cli_main(["build", "--help"])
    out = capsys.readouterr().out
    assert "MJCF" in out and "--strict" in out


@pytest.mark.slow
def test_cli_build_mjcf(tmp_path, capsys):
    assert cli_main(["build", str(FEATURES), "--cache-dir", str(tmp_path)]) == 0
    assert "features: 5 coordinates" in capsys.readouterr().out
