"""Small robots with mesh files, written by the viewer's tests (no downloaded assets).

`toy_robot(folder)` writes a package `toy_description` under `folder/pkgs` with an STL, an
OBJ and a COLLADA mesh, and a URDF that names them through package://, a relative path and
primitives: a static base on the left (red), an arm turning about z on the right (blue),
a forearm turning about y, a tool merged into it by a fixed joint (a scaled COLLADA mesh)
and a sliding tip (a sphere).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

INERTIAL = ('<inertial><origin xyz="{c}"/><mass value="{m}"/><inertia ixx="{i}" ixy="0" '
            'ixz="0" iyy="{i}" iyz="0" izz="{i}"/></inertial>')


def inertial(mass: float = 1.0, com: str = "0 0 0", moment: float = 0.01) -> str:
    return INERTIAL.format(c=com, m=mass, i=moment)


def write_meshes(meshes: Path) -> None:
    import trimesh

    meshes.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=(0.3, 0.3, 0.1)).export(meshes / "base.stl")
    arm = trimesh.creation.box(extents=(0.4, 0.08, 0.08))
    arm.apply_translation((0.2, 0.0, 0.0))
    (meshes / "arm.obj").write_text(trimesh.exchange.obj.export_obj(arm, include_texture=False))
    tool = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    (meshes / "tool.dae").write_bytes(trimesh.exchange.dae.export_collada(tool))


def toy_urdf(base_mesh: str = "package://toy_description/meshes/base.stl",
             extra_links: str = "") -> str:
    return f"""<?xml version="1.0"?>
<robot name="toy">
  <material name="red"><color rgba="0.9 0.1 0.1 1"/></material>
  <link name="base_link">
    {inertial(5.0, "0 0 0.05", 0.1)}
    <visual><origin xyz="-0.6 0 0.05"/><geometry><mesh filename="{base_mesh}"/></geometry>
      <material name="red"/></visual>
  </link>
  <joint name="j1" type="revolute"><parent link="base_link"/><child link="arm"/>
    <origin xyz="0.6 0 0.1"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="10" velocity="1"/></joint>
  <link name="arm">
    {inertial(1.0, "0.2 0 0")}
    <visual><geometry><mesh filename="package://toy_description/meshes/arm.obj"/></geometry>
      <material name="blue"><color rgba="0.1 0.2 0.9 1"/></material></visual>
  </link>
  <joint name="j2" type="revolute"><parent link="arm"/><child link="forearm"/>
    <origin xyz="0.4 0 0" rpy="0.3 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="10" velocity="1"/></joint>
  <link name="forearm">
    {inertial(0.5, "0.15 0 0")}
    <visual><origin xyz="0.15 0 0" rpy="0 1.5707963267948966 0"/>
      <geometry><cylinder radius="0.03" length="0.3"/></geometry>
      <material name="blue"/></visual>
    <visual><origin xyz="0.3 0 0"/><geometry><mesh filename="local/cap.stl"/></geometry>
    </visual>
  </link>
  <joint name="tool_mount" type="fixed"><parent link="forearm"/><child link="tool"/>
    <origin xyz="0.3 0.02 0.01" rpy="0.1 0.2 0.3"/></joint>
  <link name="tool">
    {inertial(0.1, "0 0 0.02", 0.001)}
    <visual><origin xyz="0 0 0.03" rpy="0.5 0 0"/>
      <geometry><mesh filename="package://toy_description/meshes/tool.dae" scale="1 1 2"/>
      </geometry></visual>
  </link>
  <joint name="slide" type="prismatic"><parent link="tool"/><child link="tip"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>
    <limit lower="-0.1" upper="0.1" effort="10" velocity="1"/></joint>
  <link name="tip">
    {inertial(0.05, "0 0 0", 0.0005)}
    <visual><geometry><sphere radius="0.03"/></geometry></visual>
  </link>
  {extra_links}
</robot>
"""


def toy_robot(folder: Path, **options) -> tuple[Path, Path]:
    """(the URDF, the package directory) of the toy robot, written under `folder`."""
    import trimesh

    packages = folder / "pkgs"
    package = packages / "toy_description"
    write_meshes(package / "meshes")
    local = package / "urdf" / "local"
    local.mkdir(parents=True, exist_ok=True)
    trimesh.creation.icosphere(radius=0.04).export(local / "cap.stl")
    urdf = package / "urdf" / "toy.urdf"
    urdf.write_text(toy_urdf(**options))
    return urdf, packages


def swing(dyn, t: np.ndarray, rest_after: float | None = None) -> np.ndarray:
    """Configurations (m, nq) that move every joint (the arm's j1 within [0, 1.2] rad);
    held still from `rest_after` on."""
    q = np.tile(dyn.neutral(), (len(t), 1))
    moving = t if rest_after is None else np.minimum(t, rest_after)
    names = dyn.configuration
    for name, values in (("j1", 1.2 * np.sin(0.5 * np.pi * moving / max(moving.max(), 1e-9))),
                         ("j2", 0.8 * np.sin(2.0 * moving)), ("slide", 0.05 * np.sin(moving))):
        q[:, names.index(name)] = values
    if "root_joint_x" in names:
        k = names.index("root_joint_x")
        q[:, k:k + 3] = np.column_stack([0.1 * moving, -0.2 * moving, 0.3 * np.sin(moving)])
        half = 0.4 * moving / 2
        q[:, k + 3:k + 7] = np.column_stack([np.sin(half) * 0.6, np.sin(half) * 0.8,
                                             np.zeros_like(half), np.cos(half)])
    return q
