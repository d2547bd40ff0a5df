"""The viewer (gagen.viewer): visuals placed by dyn.frame_placement, checked against
Pinocchio's visual model and MuJoCo's geoms; meshes found as URDF users expect and read as
untrusted input; the self-contained HTML playback (read back from its embedded recording);
sweeps overlaid or in sequence; the live viewer's server; the CLI's --html and view."""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import time
import urllib.request
import warnings
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")
pytest.importorskip("trimesh")
pytest.importorskip("collada")

from viewer_robots import swing, toy_robot, toy_urdf
from viser_recording import read_recording

import gagen
from gagen.viewer import MeshWarning, read_run, start_viewer, write_html
from gagen.viewer import html as viewer_html
from gagen.viewer.meshes import (
    MeshBudget,
    MeshFinder,
    MeshRefused,
    read_mesh,
)
from gagen.viewer.placements import body_names
from gagen.viewer.scene import safe_name
from gagen.viewer.visuals import link_frame, mjcf_visuals, robot_visuals, urdf_visuals

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    folder = tmp_path_factory.mktemp("toy")
    urdf, packages = toy_robot(folder)
    return urdf, packages, gagen.load(urdf)


@pytest.fixture(scope="module")
def floating_toy(toy):
    urdf, packages, _ = toy
    return urdf, packages, gagen.load(urdf, floating_base=True)


def link_frames(dyn) -> list[str]:
    return [name for name, _, kind in dyn.info.frames if kind == "link"]


# --- placements: what the file draws ---------------------------------------------------------

def drawn_links(recording, dyn, time_: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each link frame's world placement as the file draws it at `time_`."""
    nodes = recording.at(time_)
    frames = {safe_name(frame): frame for frame in link_frames(dyn)}
    out = {}
    for name in nodes:
        leaf = name.rsplit("/", 1)[-1]
        if nodes[name]["type"] == "FrameMessage" and leaf in frames and name.count("/") == 3:
            out[frames[leaf]] = recording.world_pose(nodes, name)
    return out


def visual_node(nodes: dict, dyn, link: str, ordinal: int) -> str:
    """The node of a URDF link's visual (its frame named as dyn.frames names it)."""
    leaf = safe_name(link_frame(dyn, link))
    parent = next(n for n in nodes if n.count("/") == 3 and n.endswith(f"/{leaf}"))
    return f"{parent}/visual_{ordinal + 1}"


@pytest.mark.parametrize("which", ["fixed", "floating"])
def test_drawn_placements_equal_frame_placement(which, toy, floating_toy, tmp_path):
    _, packages, dyn = toy if which == "fixed" else floating_toy
    t = np.linspace(0.0, 2.0, 41)
    q = swing(dyn, t)
    path = write_html(tmp_path / "run.html", dyn, t, q, package_dirs=[packages])
    recording = read_recording(path)
    assert recording.duration == pytest.approx(2.0)
    for i in (0, 7, 20, 33, 40):
        drawn = drawn_links(recording, dyn, t[i] - t[0])
        assert set(drawn) == set(link_frames(dyn))  # every link, merged ones too
        for link, (R, p) in drawn.items():
            R_ref, p_ref = dyn.frame_placement(q[i], link)
            np.testing.assert_allclose(R, R_ref, rtol=0, atol=1e-12, err_msg=link)
            np.testing.assert_allclose(p, p_ref, rtol=0, atol=1e-12, err_msg=link)


def pinocchio_visuals(urdf: Path, packages: Path, floating: bool):
    pin = pytest.importorskip("pinocchio")
    root = pin.JointModelFreeFlyer() if floating else None
    # (Pinocchio looks for a relative mesh path in its package directories)
    args = (str(urdf), [str(packages), str(urdf.parent)]) + ((root,) if root is not None
                                                             else ())
    model, _, visual = pin.buildModelsFromUrdf(*args)
    return pin, model, visual


def pinocchio_configuration(model, dyn, q: np.ndarray) -> np.ndarray:
    """gagen's q in Pinocchio's order, entry by entry by name (never by position)."""
    out = np.zeros(model.nq)
    names = dyn.configuration
    for j in range(1, model.njoints):
        name, iq, nq = model.names[j], model.idx_qs[j], model.nqs[j]
        if nq == 7:
            out[iq:iq + 7] = [q[names.index(f"root_joint_{s}")]
                              for s in ("x", "y", "z", "qx", "qy", "qz", "qw")]
        else:
            out[iq] = q[names.index(name)]
    return out


@pytest.mark.parametrize("which", ["fixed", "floating"])
def test_visuals_drawn_where_pinocchio_places_them(which, toy, floating_toy, tmp_path):
    """Each URDF visual's node, composed with its link's as the file draws them, sits
    where Pinocchio's visual model puts that geometry (updateGeometryPlacements)."""
    urdf, packages, dyn = toy if which == "fixed" else floating_toy
    pin, model, visual = pinocchio_visuals(urdf, packages, which == "floating")
    data, vdata = model.createData(), visual.createData()
    t = np.linspace(0.0, 1.0, 11)
    q = swing(dyn, t)
    recording = read_recording(write_html(tmp_path / "v.html", dyn, t, q,
                                          package_dirs=[packages]))
    for i in (0, 5, 10):
        pin.forwardKinematics(model, data, pinocchio_configuration(model, dyn, q[i]))
        pin.updateGeometryPlacements(model, data, visual, vdata)
        nodes = recording.at(t[i])
        for k, geometry in enumerate(visual.geometryObjects):
            link, ordinal = geometry.name.rsplit("_", 1)
            R, p = recording.world_pose(nodes, visual_node(nodes, dyn, link, int(ordinal)))
            np.testing.assert_allclose(R, vdata.oMg[k].rotation, atol=1e-9, err_msg=geometry.name)
            np.testing.assert_allclose(p, vdata.oMg[k].translation, atol=1e-9,
                                       err_msg=geometry.name)


MJCF = """<mujoco model="geoms">
  <compiler angle="radian"/>
  <asset><mesh name="m" file="part.stl"/></asset>
  <worldbody>
    <geom type="plane" size="1 1 0.1"/>
    <geom type="box" size="0.05 0.05 0.05" pos="0.5 0.5 0"/>
    <body name="base" pos="0.1 0 0.5" euler="0.1 0.2 0.3">
      <joint name="yaw" axis="0 0 1" pos="0.02 0 0.05" ref="0.3"/>
      <inertial pos="0 0 0.1" mass="2" diaginertia="0.03 0.04 0.02"/>
      <geom type="box" size="0.1 0.05 0.02" pos="0.01 0.02 0.03" quat="0.9 0.1 0.2 0.3"/>
      <body name="upper" pos="0 0.1 0.2" quat="0.9 0.1 0.2 0.3">
        <joint name="pitch" axis="0 1 0" pos="0 0 0.02"/>
        <joint name="roll" axis="1 0.5 0" pos="0.01 0 0"/>
        <inertial pos="0 0 0.2" mass="1.5" diaginertia="0.02 0.03 0.015"/>
        <geom type="capsule" size="0.02 0.1" pos="0 0 0.1"/>
        <geom type="mesh" mesh="m" pos="0 0.05 0.2" euler="0.3 0 0.1" rgba="0.2 0.8 0.2 1"/>
        <geom type="sphere" size="0.03" group="3"/>
        <body name="slider" pos="0 0 0.4">
          <joint name="s" type="slide" axis="0 0 1" ref="0.05" pos="0.03 0 0"/>
          <inertial pos="0.05 0 0" mass="0.5" diaginertia="0.001 0.002 0.0025"/>
          <geom type="cylinder" size="0.02 0.05" pos="0.02 0 0"/>
          <body name="tool" pos="0.1 0 0" euler="0 1 0">
            <inertial pos="0 0 0.03" mass="0.3" diaginertia="0.0005 0.0005 0.0002"/>
            <geom type="ellipsoid" size="0.02 0.03 0.04" pos="0 0.01 0.02"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_mjcf_geoms_drawn_where_mujoco_places_them(tmp_path):
    """MJCF visuals (anchors, refs, several joints on a body, a slide, a welded body,
    world geoms): placed with dyn.frame_placement, against MuJoCo's own geom_xpos and
    geom_xmat at random configurations."""
    mujoco = pytest.importorskip("mujoco")
    import trimesh

    trimesh.creation.box(extents=(0.04, 0.06, 0.02)).export(tmp_path / "part.stl")
    path = tmp_path / "geoms.xml"
    path.write_text(MJCF)
    dyn = gagen.load(path)
    visuals = mjcf_visuals(path, dyn)
    mj = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(mj)
    shown = [g for g in range(mj.ngeom) if mj.geom_group[g] < 3 and mj.geom_type[g] != 0]
    assert len(visuals.visuals) == len(shown) == 6
    rng = np.random.default_rng(3)
    for _ in range(4):
        data.qpos[:] = rng.uniform(-1, 1, mj.nq)
        mujoco.mj_kinematics(mj, data)
        q = np.array([data.qpos[mj.jnt_qposadr[mujoco.mj_name2id(mj, 3, name)]]
                      for name in dyn.configuration])
        for g, visual in zip(shown, visuals.visuals):
            R, p = (np.eye(3), np.zeros(3)) if not visual.frame else \
                dyn.frame_placement(q, visual.frame)
            np.testing.assert_allclose(R @ visual.p + p, data.geom_xpos[g], atol=1e-9)
            np.testing.assert_allclose(R @ visual.R, data.geom_xmat[g].reshape(3, 3), atol=1e-9)
    html = read_recording(write_html(tmp_path / "m.html", dyn, [0.0], dyn.neutral()[None]))
    assert sum(m["type"] == "GlbMessage" for _, m in html.messages) == 6


def test_models_without_meshes_are_inertia_boxes_and_sticks():
    dyn = gagen.load("rrr")
    visuals = robot_visuals(dyn)
    assert not visuals.from_description
    kinds = sorted(v.shape.kind for v in visuals.visuals)
    assert kinds.count("box") == 3 and kinds.count("cylinder") >= 3
    numeric = {b.name: b for b in __import__("gagen.model.numeric", fromlist=["x"])
               .numeric_model(dyn.model).bodies}
    for box in (v for v in visuals.visuals if v.shape.kind == "box"):
        body = numeric[box.frame]
        a, b, c = box.shape.size  # the box of uniform density has the body's moments
        moments = body.mass / 12 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
        np.testing.assert_allclose(box.R @ np.diag(moments) @ box.R.T, body.inertia,
                                   rtol=1e-9, atol=1e-9 * np.abs(body.inertia).max())
        np.testing.assert_allclose(box.p, body.com, atol=1e-12)


# --- meshes: found as URDF users expect, read as untrusted input -----------------------------

def test_package_relative_and_absolute_paths(toy, tmp_path, monkeypatch):
    urdf, packages, _ = toy
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    finder = MeshFinder(urdf.parent, [packages])
    base = packages / "toy_description" / "meshes" / "base.stl"
    assert finder.find("package://toy_description/meshes/base.stl").path == base
    assert finder.find("local/cap.stl").path == urdf.parent / "local" / "cap.stl"
    assert finder.find(str(base)).path == base  # absolute, inside a package directory
    assert finder.find(base.as_uri()).path == base
    # the package directory may be the package itself (ROS), and $ROS_PACKAGE_PATH counts
    assert MeshFinder(urdf.parent, [packages / "toy_description"]).find(
        "package://toy_description/meshes/base.stl").path == base
    monkeypatch.setenv("ROS_PACKAGE_PATH", f"/nonexistent{os.pathsep}{packages}")
    assert MeshFinder(urdf.parent).find("package://toy_description/meshes/base.stl").path == base


@pytest.fixture
def hostile(tmp_path):
    """A description folder, a package, and a secret file next to them."""
    secret = tmp_path / "secret.stl"
    secret.write_bytes(b"solid secret\nendsolid secret\n")
    package = tmp_path / "pkgs" / "p"
    (package / "meshes").mkdir(parents=True)
    description = tmp_path / "robot"
    description.mkdir()
    (description / "link.stl").symlink_to(secret)
    (package / "meshes" / "out.stl").symlink_to(secret)
    (description / "dir.stl").mkdir()
    os.mkfifo(description / "fifo.stl")
    return MeshFinder(description, [tmp_path / "pkgs"]), secret


@pytest.mark.parametrize("uri, reason", [
    ("missing.stl", "not found"),
    ("package://p/../../secret.stl", "outside the package folder"),
    ("package://p/meshes/out.stl", "through a symbolic link"),
    ("package://nope/x.stl", "package 'nope' not found"),
    ("package:///x.stl", "no package name"),
    ("../secret.stl", "outside the description's folder"),
    ("link.stl", "through a symbolic link"),
    ("/etc/passwd", "outside the allowed folders"),
    ("file:///etc/passwd", "outside the allowed folders"),
    ("file://host/x.stl", "another host"),
    ("http://example.com/x.stl", "nothing is fetched"),
    ("dir.stl", "not a regular file"),
    ("fifo.stl", "not a regular file"),
    ("a\\b.stl", "use '/'"),
])
def test_hostile_mesh_paths_are_refused(hostile, uri, reason):
    finder, _ = hostile
    with pytest.raises(MeshRefused, match=reason.replace("(", r"\(")):
        finder.find(uri)


def test_a_2_gb_mesh_is_refused_before_it_is_read(tmp_path, monkeypatch):
    big = tmp_path / "big.stl"
    with big.open("wb") as handle:  # sparse: nothing is written but the size
        handle.truncate(2 * 2**30)
    opened = []
    monkeypatch.setattr(Path, "open", lambda self, *a, **k: opened.append(self) or 1 / 0)
    finder = MeshFinder(tmp_path)
    with pytest.raises(MeshRefused, match="2,147,483,648 bytes; gagen reads mesh files of at "
                       "most 33,554,432"):
        read_mesh(finder.find("big.stl"), MeshBudget())
    assert opened == []


@pytest.mark.parametrize("name, data, reason", [
    ("bad.stl", b"\x00" * 80 + (10**6).to_bytes(4, "little") + b"\x01" * 50,
     "malformed STL|no triangles"),
    ("empty.stl", b"", "malformed STL|no triangles"),
    ("text.stl", b"solid x\nfacet nonsense\n", "malformed STL|no triangles"),
    ("bomb.dae", (b'<?xml version="1.0"?><!DOCTYPE c [<!ENTITY a "aaaa">]><COLLADA>&a;'
                  b"</COLLADA>"), "must not declare a DTD"),
    ("broken.dae", b"<COLLADA><library_geometries>", "malformed XML"),
    ("model.ply", b"ply\n", "STL, OBJ and COLLADA"),
])
def test_malformed_meshes_are_refused(tmp_path, name, data, reason):
    (tmp_path / name).write_bytes(data)
    with pytest.raises(MeshRefused, match=reason):
        read_mesh(MeshFinder(tmp_path).find(name), MeshBudget())


def test_non_finite_and_oversized_meshes_are_refused(tmp_path, monkeypatch):
    import trimesh

    box = trimesh.creation.box()
    triangles = np.zeros((2, 12), dtype="<f4")  # a normal and three vertices each
    triangles[:, 3:] = [[0, 0, 0, 1, 0, 0, np.nan, 1, 0], [0, 0, 0, 1, 0, 0, 0, 1, 0]]
    records = b"".join(row.tobytes() + b"\x00\x00" for row in triangles)
    (tmp_path / "nan.stl").write_bytes(b"\x00" * 80 + (2).to_bytes(4, "little") + records)
    try:  # refused, or the NaN triangle left out: nothing non-finite reaches the page
        scene = read_mesh(MeshFinder(tmp_path).find("nan.stl"), MeshBudget())
        assert all(np.isfinite(g.vertices).all() for g in scene.geometry.values())
    except MeshRefused as exc:
        assert "NaN" in str(exc)
    box.export(tmp_path / "box.stl")
    monkeypatch.setattr("gagen.viewer.meshes.MAX_FACES", 11)
    with pytest.raises(MeshRefused, match="12 faces; gagen draws meshes of at most"):
        read_mesh(MeshFinder(tmp_path).find("box.stl"), MeshBudget())
    monkeypatch.setattr("gagen.viewer.meshes.MAX_FACES", 100)
    monkeypatch.setattr("gagen.viewer.meshes.MAX_TOTAL_FACES", 20)
    budget = MeshBudget()
    read_mesh(MeshFinder(tmp_path).find("box.stl"), budget)
    with pytest.raises(MeshRefused, match="pass 20 faces in all"):
        read_mesh(MeshFinder(tmp_path).find("box.stl"), budget)


def test_files_a_mesh_refers_to_stay_in_its_folder(tmp_path):
    """An OBJ's material library and texture: read inside the mesh's folder, refused (and
    noted) outside it; the mesh is still drawn."""
    import trimesh

    (tmp_path / "secret.mtl").write_text("newmtl m\nKd 1 0 0\n")
    folder = tmp_path / "robot"
    folder.mkdir()
    obj = trimesh.exchange.obj.export_obj(trimesh.creation.box(), include_texture=False)
    (folder / "in.mtl").write_text("newmtl m\nKd 0 1 0\n")
    (folder / "ok.obj").write_text("mtllib in.mtl\nusemtl m\n" + obj)
    (folder / "out.obj").write_text("mtllib ../secret.mtl\nusemtl m\n" + obj)
    budget = MeshBudget()
    scene = read_mesh(MeshFinder(folder).find("ok.obj"), budget)
    colour = next(iter(scene.geometry.values())).visual.material
    assert budget.notes == [] and colour is not None
    scene = read_mesh(MeshFinder(folder).find("out.obj"), budget)
    assert len(budget.notes) == 1 and "resolves outside the mesh's folder" in budget.notes[0]


def test_a_missing_mesh_warns_and_draws_the_inertia_box(toy, tmp_path):
    urdf, packages, _ = toy
    broken = urdf.with_name("broken.urdf")
    broken.write_text(toy_urdf(base_mesh="package://toy_description/meshes/gone.stl"))
    missing = gagen.load(broken)
    with pytest.warns(MeshWarning, match=r"link 'base_link': mesh "
                      r"'package://toy_description/meshes/gone.stl': .*not found.*inertia box"):
        path = write_html(tmp_path / "b.html", missing, [0.0], missing.neutral()[None],
                          package_dirs=[packages])
    nodes = read_recording(path).at(0.0)
    base = [n for n in nodes if n.endswith("/base_link/visual_1")]
    assert base and nodes[base[0]]["type"] == "GlbMessage"
    # the box sits at the link's mass centre (0, 0, 0.05), not at the visual's origin
    np.testing.assert_allclose(nodes[base[0]]["position"], [0, 0, 0.05], atol=1e-12)


def test_bad_visual_elements_warn_and_fall_back(toy):
    urdf, packages, dyn = toy
    text = toy_urdf().replace('<sphere radius="0.03"/>', '<sphere radius="-1"/>')
    bad = urdf.with_name("bad.urdf")
    bad.write_text(text)
    with pytest.warns(MeshWarning, match=r"link 'tip', visual 1, <sphere> radius: sizes must "
                      "be positive"):
        visuals = urdf_visuals(bad, dyn, [packages])
    tip = [v for v in visuals.visuals if v.link == "tip"]
    assert len(tip) == 1 and tip[0].shape.kind == "box"


# --- the HTML file ---------------------------------------------------------------------------

def test_html_is_self_contained_and_written_whole(toy, tmp_path, monkeypatch):
    _, packages, dyn = toy
    t = np.linspace(0, 1, 11)
    path = write_html(tmp_path / "deep" / "r.html", dyn, t, swing(dyn, t),
                      package_dirs=[packages])
    page = path.read_text()
    assert "window.__VISER_EMBED_DATA__" in page and "<title>gagen: toy</title>" in page
    assert not [u for u in ("http://", "https://") if f'src="{u}' in page or f"href=\"{u}" in page]
    glbs = [m for _, m in read_recording(path).messages if m["type"] == "GlbMessage"]
    assert len(glbs) == 6  # every visual: 4 meshes, a cylinder, a sphere
    # a failure while writing leaves nothing behind
    monkeypatch.setattr(viewer_html, "_recording", lambda *a: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        write_html(tmp_path / "none.html", dyn, t, swing(dyn, t), package_dirs=[packages])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["deep"]


def test_names_inside_mesh_files_stay_out_of_the_page(toy, tmp_path):
    """A mesh file's node, geometry and material names are text from a description: the
    page's glTF carries numbered names instead."""
    import trimesh

    urdf, packages, _ = toy
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    dae = trimesh.exchange.dae.export_collada(box)
    for k, token in enumerate(sorted(set(re.findall(rb'"([0-9a-f]{32})"', dae)))):
        dae = dae.replace(token, b"SECRET_NAME_42_%d" % k)  # ids and names alike
    assert b'name="SECRET_NAME_42' in dae
    (tmp_path / "named.dae").write_bytes(dae)
    named = urdf.with_name("named.urdf")
    named.write_text(toy_urdf(base_mesh=str(tmp_path / "named.dae")))
    dyn = gagen.load(named)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MeshWarning)
        path = write_html(tmp_path / "n.html", dyn, [0.0], dyn.neutral()[None],
                          package_dirs=[packages, tmp_path])
    glbs = [bytes(m["props"]["glb_data"]) for _, m in read_recording(path).messages
            if m["type"] == "GlbMessage"]
    assert len(glbs) == 6 and not any(b"SECRET_NAME_42" in glb for glb in glbs)


def test_html_input_checks(toy, tmp_path):
    _, _, dyn = toy
    t = np.linspace(0, 1, 5)
    q = swing(dyn, t)
    for bad_t, bad_q, match in [(t[::-1], q, "increasing"), (t, q[:, :2], "must have shape"),
                                (t, np.where(q == q[2, 0], np.nan, q), "finite")]:
        with pytest.raises(ValueError, match=match):
            write_html(tmp_path / "x.html", dyn, bad_t, bad_q)
    with pytest.raises(ValueError, match="mode must be"):
        write_html(tmp_path / "x.html", dyn, t, q, mode="fan")
    assert not (tmp_path / "x.html").exists()


def test_long_runs_are_thinned_evenly(toy, tmp_path):
    _, packages, dyn = toy
    t = np.linspace(0, 1, 101)
    path = write_html(tmp_path / "t.html", dyn, t, swing(dyn, t), package_dirs=[packages],
                      max_frames=11)
    assert read_recording(path).times() == pytest.approx(list(np.linspace(0, 1, 11)))


def test_direct_recording_equals_the_public_handles(toy, tmp_path, monkeypatch):
    """The pose messages given to the serializer directly draw what viser's own handles
    draw (to their 1e-5 relative tolerance, within which they skip a change)."""
    _, packages, dyn = toy
    t = np.linspace(0, 1, 21)
    q = swing(dyn, t)
    direct = read_recording(write_html(tmp_path / "a.html", dyn, t, q, package_dirs=[packages]))
    original = viewer_html.PoseRecorder.__init__

    def handles_only(self, *args):
        original(self, *args)
        self._direct = None

    monkeypatch.setattr(viewer_html.PoseRecorder, "__init__", handles_only)
    public = read_recording(write_html(tmp_path / "b.html", dyn, t, q, package_dirs=[packages]))
    for time_ in (0.0, 0.5, 1.0):
        a, b = drawn_links(direct, dyn, time_), drawn_links(public, dyn, time_)
        for link in a:
            np.testing.assert_allclose(a[link][1], b[link][1], atol=1e-5)
            np.testing.assert_allclose(a[link][0], b[link][0], atol=1e-5)


def test_simulation_result_to_html(toy, tmp_path):
    _, packages, dyn = toy
    res = gagen.simulate(dyn, (0.0, 0.5), dyn.neutral(), None, method="rk4",
                         p={"m_arm": 1.5}, t_eval=np.linspace(0, 0.5, 6))
    assert res.dyn is dyn and res.p[list(dyn.parameters).index("m_arm")] == 1.5
    recording = read_recording(res.to_html(tmp_path / "s.html", package_dirs=[packages]))
    drawn = drawn_links(recording, dyn, 0.5)
    np.testing.assert_allclose(drawn["tip"][1], dyn.frame_placement(res.q[-1], "tip")[1],
                               atol=1e-12)
    bare = gagen.SimulationResult(res.t, res.q, res.qd, res.tau, res.coordinates)
    with pytest.raises(ValueError, match="no dynamics object"):
        bare.to_html(tmp_path / "x.html")


def test_sweep_overlay_and_sequence(tmp_path):
    """Runs of a batch, each with its own link length: overlaid (all but the first ghosted)
    or one after the other; each run drawn with its own parameters."""
    dyn = gagen.load("rrr")
    lengths = np.array([0.4, 0.6, 0.8])
    batch = gagen.simulate_batch(dyn, (0.0, 0.5), np.zeros(3), None,
                                 gagen.paper_controller(), p={"L1": lengths},
                                 t_eval=np.linspace(0, 0.5, 6))
    overlay = read_recording(batch.to_html(tmp_path / "o.html", runs=[2, 0]))
    nodes = overlay.at(0.5)
    for k, run in enumerate((2, 0)):
        _, p = overlay.world_pose(nodes, f"/gagen/run_{k}/link2")
        np.testing.assert_allclose(p, dyn.frame_placement(batch.q[run, -1], "link2",
                                                          {"L1": lengths[run]})[1], atol=1e-12)
    glbs = {m["name"]: m for _, m in overlay.messages if m["type"] == "GlbMessage"}
    opaque = [n for n in glbs if n.startswith("/gagen/run_0/")]
    ghosts = [n for n in glbs if n.startswith("/gagen/run_1/")]
    assert opaque and len(opaque) == len(ghosts)
    assert all(b"BLEND" in bytes(glbs[n]["props"]["glb_data"]) for n in ghosts)
    sequence = read_recording(batch.to_html(tmp_path / "s.html", runs=[0, 1, 2],
                                            mode="sequence"))
    assert sequence.duration == pytest.approx(3 * 0.5 + 2 * 0.1)
    shown = [[n for n in (f"/gagen/run_{k}" for k in range(3))
              if sequence.at(time_)[n]["visible"]] for time_ in (0.2, 0.8, 1.5)]
    assert shown == [["/gagen/run_0"], ["/gagen/run_1"], ["/gagen/run_2"]]
    with pytest.raises(ValueError, match="run 7 is not one of the 3 runs"):
        batch.to_html(tmp_path / "x.html", runs=[7])


# --- run files ---------------------------------------------------------------------------------

def test_run_csv_columns_are_read_by_name(floating_toy, tmp_path):
    _, _, dyn = floating_toy
    t = np.linspace(0, 1, 5)
    q = swing(dyn, t)
    names = ["t", *dyn.configuration]
    order = [0, *range(len(names) - 1, 0, -1)]  # reversed, with an extra column
    rows = [",".join([*(repr(float(v)) for v in np.r_[t[i], q[i]][order]), "7"])
            for i in range(len(t))]
    (tmp_path / "r.csv").write_text(",".join([names[k] for k in order] + ["extra"]) + "\n"
                                    + "\n".join(rows) + "\n")
    t_read, q_read = read_run(tmp_path / "r.csv", dyn)
    np.testing.assert_array_equal(t_read, t)
    np.testing.assert_array_equal(q_read, q)
    (tmp_path / "m.csv").write_text("t,j1\n0,1\n")
    with pytest.raises(ValueError, match="m.csv: no column 'root_joint_x'"):
        read_run(tmp_path / "m.csv", dyn)
    (tmp_path / "n.csv").write_text(",".join(names) + "\n" + ",".join(["nan"] * len(names)))
    with pytest.raises(ValueError, match="line 2: NaN"):
        read_run(tmp_path / "n.csv", dyn)


# --- the live viewer ---------------------------------------------------------------------------

def _scene_names(port: int, timeout: float = 20.0) -> set[str]:
    """The scene nodes a client receives from the viewer's websocket (viser's wire format:
    [8-byte size][8-byte compressed size][zstd msgpack of the messages][binary buffers])."""
    import msgspec
    import viser
    import zstandard
    from websockets.sync.client import connect

    names: set[str] = set()
    deadline = time.monotonic() + timeout
    with connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"],
                 max_size=2**28) as ws:
        while time.monotonic() < deadline and not any("visual" in n for n in names):
            data = ws.recv(timeout=max(0.1, deadline - time.monotonic()))
            size, compressed = (int.from_bytes(data[k:k + 8], "little") for k in (0, 8))
            inner = zstandard.ZstdDecompressor().decompress(data[16:16 + compressed],
                                                            max_output_size=size)
            for message in msgspec.msgpack.decode(inner)["messages"]:
                if message.get("type") == "GlbMessage":
                    names.add(message["name"])
    return names


def test_live_viewer_serves_the_scene_and_plays_a_run(toy):
    _, packages, dyn = toy
    t = np.linspace(0, 1, 11)
    q = swing(dyn, t)
    viewer = start_viewer(dyn, run=(t, q), package_dirs=[packages], port=0)
    try:
        with urllib.request.urlopen(viewer.url, timeout=20) as response:
            assert response.status == 200 and b"<title>Viser</title>" in response.read()
        names = _scene_names(viewer.port)
        assert {"/gagen/arm/arm/visual_1", "/gagen/tool/tool/visual_1"} <= {
            n.replace("forearm/tool", "tool/tool") for n in names} | names
        viewer.advance(0.55)  # playing from the start: at the sample of t = 0.5
        np.testing.assert_allclose(viewer.q, q[5])
        _, p = dyn.frame_placement(q[5], "forearm")
        body = body_names(dyn).index("forearm")
        np.testing.assert_allclose(viewer.robot.handles[body].position, p, atol=1e-12)
        viewer.pause()
        viewer.set_configuration(q[2])
        viewer._show_frames(True)
        assert viewer._frames.batched_positions.shape == (len(dyn.frames), 3)
    finally:
        viewer.stop()
    with pytest.raises(OSError):
        urllib.request.urlopen(viewer.url, timeout=2)


def test_floating_base_sliders_set_position_and_orientation(floating_toy):
    _, packages, dyn = floating_toy
    viewer = start_viewer(dyn, package_dirs=[packages], port=0)
    try:
        values = {"root_joint x (m)": 0.3, "root_joint z (m)": -0.2, "root_joint roll (rad)": 0.4,
                  "root_joint yaw (rad)": -1.1, "j2 (rad)": 0.7}
        for slider, _ in viewer.sliders:
            slider.value = values.get(slider.label, slider.value)
        q = viewer._configuration_from_sliders()
        names = dyn.configuration
        assert q[names.index("root_joint_x")] == 0.3 and q[names.index("j2")] == 0.7
        R, p = dyn.frame_placement(q, "base_link")
        from gagen.viewer.visuals import rotation_rpy

        np.testing.assert_allclose(R, rotation_rpy(0.4, 0.0, -1.1), atol=1e-12)
        np.testing.assert_allclose(p, [0.3, 0.0, -0.2], atol=1e-12)
    finally:
        viewer.stop()


def test_without_the_extra_the_viewer_says_what_to_install(toy, monkeypatch, tmp_path):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "viser" else real(name, *a))
    _, _, dyn = toy
    with pytest.raises(ImportError,
                       match=r"the viewer needs viser: pip install 'gagen\[viewer\]'"):
        write_html(tmp_path / "x.html", dyn, [0.0], dyn.neutral()[None])
    res = gagen.simulate(dyn, (0, 0.1), dyn.neutral(), method="rk4")
    with pytest.raises(ImportError, match="gagen\\[viewer\\]"):
        res.to_html(tmp_path / "x.html")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_view_command_serves_until_interrupted(toy, tmp_path):
    urdf, packages, dyn = toy
    t = np.linspace(0, 1, 5)
    res = gagen.SimulationResult(t, swing(dyn, t), np.zeros((5, dyn.nv)),
                                 np.zeros((5, dyn.nv)), dyn.coordinates)
    res.to_csv(tmp_path / "run.csv")
    # The child runs the interpreter and the installation this test runs with (CI installs
    # the project, non-editable, so the source tree has no compiled runtime to import).
    process = subprocess.Popen(
        [sys.executable, "-m", "gagen", "view", str(urdf), "--run", str(tmp_path / "run.csv"),
         "--package-path", str(packages), "--no-browser", "--port", str(_free_port())],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = process.stdout.readline()
        assert line.startswith("gagen: viewer at http://127.0.0.1:"), process.stderr.read()
        url = line.split()[3]
        with urllib.request.urlopen(url, timeout=20) as response:
            assert response.status == 200
        assert any("visual" in n for n in _scene_names(int(url.rsplit(":", 1)[1])))
    finally:
        process.send_signal(2)  # Ctrl-C
        _, err = process.communicate(timeout=30)
    assert process.returncode == 0, err
    assert "viewer stopped" in err


# --- the command line --------------------------------------------------------------------------

def test_simulate_and_sweep_write_html(toy, tmp_path):
    from gagen.app.cli import main

    urdf, packages, _ = toy
    assert main(["-q", "simulate", str(urdf), "--duration", "0.2", "--points", "5", "--html",
                 "--package-path", str(packages), "--out", str(tmp_path / "s")]) == 0
    recording = read_recording(tmp_path / "s" / "simulate.html")
    assert sum(m["type"] == "GlbMessage" for _, m in recording.messages) == 6
    with warnings.catch_warnings():
        warnings.simplefilter("error", MeshWarning)  # every mesh found
        assert main(["-q", "sweep", str(urdf), "--runs", "4", "--vary", "q0=-5:5",
                     "--duration", "0.2", "--points", "5", "--no-plot", "--html",
                     "--html-runs", "3", "1", "--package-path", str(packages),
                     "--out", str(tmp_path / "w" / "sw.npz")]) == 0
    names = {m["name"].split("/")[2] for _, m in read_recording(tmp_path / "w" / "sw.html")
             .messages if m.get("type") == "GlbMessage"}
    assert names == {"run_0", "run_1"}


# --- real robots (example-robot-data's meshes, where it is installed) -------------------------

def robot_data() -> Path | None:
    """example-robot-data's `share` folder (the package of package://example-robot-data/)."""
    for root in {sys.prefix, sys.base_prefix}:
        for found in Path(root).glob("lib/python3*/site-packages/cmeel.prefix/share"):
            if (found / "example-robot-data" / "robots").is_dir():
                return found
    return None


@pytest.mark.slow
@pytest.mark.skipif(robot_data() is None, reason="example-robot-data is not installed "
                    "(pip install example-robot-data)")
@pytest.mark.parametrize("robot, floating", [
    ("anymal_c_simple_description/urdf/anymal.urdf", True),
    ("panda_description/urdf/panda.urdf", False)])
def test_real_robots_meshes_drawn_where_pinocchio_places_them(robot, floating, tmp_path):
    """ANYmal C (textured COLLADA) and the Panda: every visual read (no MeshWarning) and
    drawn where Pinocchio's visual model places it; ANYmal's 10-s, 1,001-sample file is
    under 10 MB."""
    share = robot_data()
    urdf = share / "example-robot-data" / "robots" / robot
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        dyn = gagen.load(urdf, floating_base=floating)
    t = np.linspace(0.0, 10.0, 1001)
    q = np.tile(dyn.neutral(), (len(t), 1))
    rng = np.random.default_rng(0)
    joints = [k for k, name in enumerate(dyn.configuration) if not name.startswith("root")]
    q[:, joints] = 0.5 * np.sin(np.outer(t, rng.uniform(0.2, 1.0, len(joints))))
    if floating:
        q[:, :3] = np.column_stack([0.1 * t, np.sin(t), 0.2 * np.cos(t)])
    with warnings.catch_warnings():
        warnings.simplefilter("error", MeshWarning)
        path = write_html(tmp_path / "robot.html", dyn, t, q, package_dirs=[share])
    assert path.stat().st_size < 10 * 2**20
    pin, model, visual = pinocchio_visuals(urdf, share, floating)
    data, vdata = model.createData(), visual.createData()
    recording = read_recording(path)
    glbs = [m for _, m in recording.messages if m["type"] == "GlbMessage"]
    assert len(glbs) == len(visual.geometryObjects)
    for i in (0, 500, 1000):
        pin.forwardKinematics(model, data, pinocchio_configuration(model, dyn, q[i]))
        pin.updateGeometryPlacements(model, data, visual, vdata)
        nodes = recording.at(t[i])
        for k, geometry in enumerate(visual.geometryObjects):
            link, ordinal = geometry.name.rsplit("_", 1)
            R, p = recording.world_pose(nodes, visual_node(nodes, dyn, link, int(ordinal)))
            np.testing.assert_allclose(R, vdata.oMg[k].rotation, atol=1e-9)
            np.testing.assert_allclose(p, vdata.oMg[k].translation, atol=1e-9)
