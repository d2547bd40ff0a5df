"""A robot in a viser scene: its nodes, its meshes as glTF, and its poses.

Scene tree (node names are made of safe characters only; a description's names never
reach the page as anything but text):

    /gagen[/run_K]/<body>                 a moving body, placed in the world per sample
    /gagen[/run_K]/<body>/<link>          a link frame fixed to it (placements.frame_offsets)
    /gagen[/run_K]/<body>/<link>/visual_N a visual, placed in its link as described
    /gagen[/run_K]/world/<link>           links welded to the world, and world geoms

Meshes become binary glTF (GLB) through trimesh, with their materials; textures are
scaled down to MAX_TEXTURE_EDGE pixels (the file embeds them). A ghost (overlaid sweep
runs) is the same robot with translucent materials.
"""

from __future__ import annotations

import contextlib
import copy
import io
import logging
import math
import re
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from .meshes import MeshBudget, MeshRefused, read_mesh
from .placements import body_names, frame_bodies, frame_offsets, wxyz
from .visuals import DEFAULT_RGBA, MeshWarning, RobotVisuals, Visual

log = logging.getLogger(__name__)

MAX_TEXTURE_EDGE = 1024  # pixels; ANYmal C's textures are 2048 x 2048 JPEGs
ROOT = "/gagen"
_UNSAFE = re.compile(r"[^A-Za-z0-9_.\-]")


def safe_name(name: str) -> str:
    """A scene-node name from a description's name: letters, digits, `_`, `.`, `-` only."""
    text = _UNSAFE.sub("_", name)[:80].strip(".") or "_"
    return text


class _Names:
    """Unique safe names within one parent node."""

    def __init__(self):
        self.taken: set[str] = set()

    def __call__(self, name: str) -> str:
        base = candidate = safe_name(name)
        k = 2
        while candidate in self.taken:
            candidate, k = f"{base}_{k}", k + 1
        self.taken.add(candidate)
        return candidate


@contextlib.contextmanager
def quiet_server(host: str = "127.0.0.1", port: int = 0) -> Iterator:
    """A viser server that prints nothing (viser prints its address table and "Server
    stopped" on stdout, where gagen's results go); stopped on exit."""
    import viser

    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host=host, port=port, verbose=False)
    try:
        yield server
    finally:
        with contextlib.redirect_stdout(io.StringIO()):
            server.stop()


# --- glTF ------------------------------------------------------------------------------------

@dataclass
class MeshLibrary:
    """Each visual's GLB, mesh files read once; refusals become MeshWarnings."""

    visuals: RobotVisuals
    budget: MeshBudget = field(default_factory=MeshBudget)
    _meshes: dict = field(default_factory=dict)  # uri -> trimesh.Scene or MeshRefused
    _glb: dict = field(default_factory=dict)
    _textures: dict = field(default_factory=dict)
    _warned: set = field(default_factory=set)

    def glb(self, visual: Visual, ghost: float | None = None
            ) -> tuple[bytes, Visual] | tuple[None, None]:
        """(GLB, the visual drawn): the visual, or its fallback where its mesh cannot be
        read (with a MeshWarning); (None, None) when nothing can be drawn."""
        try:
            return self._glb_of(visual, ghost), visual
        except MeshRefused as exc:
            if visual.fallback is None:
                self._warn(f"link {visual.link!r}: mesh {visual.shape.uri!r}: {exc}; "
                           "not drawn (the link has no inertia to draw instead)")
                return None, None
            self._warn(f"link {visual.link!r}: mesh {visual.shape.uri!r}: {exc}; drawn as "
                       "the link's inertia box instead")
            return self._glb_of(visual.fallback, ghost), visual.fallback

    def _warn(self, message: str) -> None:
        if message not in self._warned:  # once, though the robot is drawn for several runs
            self._warned.add(message)
            warnings.warn(message, MeshWarning, stacklevel=4)

    def _glb_of(self, visual: Visual, ghost: float | None) -> bytes:
        shape = visual.shape
        key = (shape.kind, shape.uri, shape.size, id(shape.vertices), visual.rgba, ghost)
        if key not in self._glb:
            scene = self._mesh(shape.uri) if shape.kind == "mesh" else _primitive(visual)
            self._glb[key] = _export(scene, visual.rgba, ghost, self._textures)
        return self._glb[key]

    def _mesh(self, uri: str):
        if uri not in self._meshes:
            try:
                finder = self.visuals.finder
                if finder is None:
                    raise MeshRefused("the description's meshes cannot be located")
                notes = len(self.budget.notes)
                self._meshes[uri] = read_mesh(finder.find(uri), self.budget)
                for note in self.budget.notes[notes:]:
                    warnings.warn(f"mesh {uri!r}: {note}; drawn without it", MeshWarning,
                                  stacklevel=5)
            except MeshRefused as exc:
                self._meshes[uri] = exc
        found = self._meshes[uri]
        if isinstance(found, MeshRefused):
            raise found
        return found


def _primitive(visual: Visual):
    import trimesh

    shape, size = visual.shape, visual.shape.size
    if shape.kind == "box":
        mesh = trimesh.creation.box(extents=size)
    elif shape.kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=size[0], height=size[1], sections=32)
    elif shape.kind == "capsule":
        mesh = trimesh.creation.capsule(height=size[1], radius=size[0], count=[24, 24])
    elif shape.kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=size[0])
    elif shape.kind == "ellipsoid":
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
        mesh.apply_scale(size)
    elif shape.kind == "triangles":
        mesh = trimesh.Trimesh(shape.vertices, shape.faces, process=False)
    else:
        raise MeshRefused(f"unknown shape {shape.kind!r}")
    return trimesh.Scene(mesh)


def _export(scene, rgba, ghost: float | None, textures: dict) -> bytes:
    """The scene as GLB: the description's colour where the mesh has none, textures scaled
    down, translucent for a ghost (the scene itself is left as it is)."""
    import trimesh

    # The mesh file's own names (of nodes, meshes, materials) stay out of the page: the
    # glTF gets numbered ones.
    out = trimesh.Scene(base_frame="root")
    made: dict[str, tuple[str, trimesh.Trimesh]] = {}
    for k, node in enumerate(scene.graph.nodes_geometry):
        transform, name = scene.graph[node]
        geometry = scene.geometry.get(name)
        if not isinstance(geometry, trimesh.Trimesh) or len(geometry.faces) == 0:
            continue
        if name not in made:
            material = _material(geometry, rgba, textures)
            if ghost is not None:
                material = _ghosted(material, ghost)
            material.name = f"material{len(made)}"
            made[name] = (f"mesh{len(made)}", trimesh.Trimesh(
                geometry.vertices, geometry.faces, visual=_visual_with(geometry, material),
                process=False))
        geom_name, mesh = made[name]
        out.add_geometry(mesh, node_name=f"node{k}", geom_name=geom_name, transform=transform)
    if not out.geometry:
        raise MeshRefused("no triangles to draw")
    return out.export(file_type="glb")


def _material(geometry, rgba, textures: dict):
    """The geometry's own material (textures scaled down); the description's colour
    `rgba` where the mesh has no colour of its own (no texture, white or no material);
    DEFAULT_RGBA where neither has one."""
    from trimesh.visual.material import PBRMaterial

    visual = geometry.visual
    material = getattr(visual, "material", None)
    if visual.kind == "texture" and material is not None:
        material = material.to_pbr() if hasattr(material, "to_pbr") else material
        material = copy.copy(material)  # (a shallow copy: the texture is not copied)
        if getattr(material, "baseColorTexture", None) is not None:
            material.baseColorTexture = _smaller(material.baseColorTexture, textures)
        for attribute in ("emissiveTexture", "normalTexture", "metallicRoughnessTexture",
                          "occlusionTexture"):
            if getattr(material, attribute, None) is not None:
                setattr(material, attribute, None)  # colour only: a smaller file
        if material.baseColorTexture is not None or _has_colour(material) or rgba is None:
            return material
    elif visual.kind in ("vertex", "face") and visual.defined:
        colour = np.asarray(visual.face_colors if visual.kind == "face"
                            else visual.vertex_colors, dtype=float).mean(axis=0) / 255.0
        return PBRMaterial(baseColorFactor=_bytes(colour), metallicFactor=0.0,
                           roughnessFactor=0.7)
    rgba = DEFAULT_RGBA if rgba is None else rgba
    return PBRMaterial(baseColorFactor=_bytes(rgba), metallicFactor=0.0, roughnessFactor=0.7,
                       alphaMode="BLEND" if rgba[3] < 1 else "OPAQUE")


def _has_colour(material) -> bool:
    factor = getattr(material, "baseColorFactor", None)
    return factor is not None and not np.array_equal(np.asarray(factor), [255, 255, 255, 255])


def _bytes(rgba) -> list[int]:
    return [round(255 * min(1.0, max(0.0, float(v)))) for v in rgba]


def _ghosted(material, alpha: float):
    material = copy.copy(material)
    factor = np.array(material.baseColorFactor if material.baseColorFactor is not None
                      else [255, 255, 255, 255], dtype=float)
    factor[3] = round(factor[3] * alpha)
    material.baseColorFactor = factor.astype(np.uint8)
    material.alphaMode = "BLEND"
    return material


def _visual_with(geometry, material):
    import trimesh

    uv = getattr(geometry.visual, "uv", None) if geometry.visual.kind == "texture" else None
    if material.baseColorTexture is not None and uv is None:
        material = copy.copy(material)
        material.baseColorTexture = None
    return trimesh.visual.TextureVisuals(uv=uv, material=material)


def _smaller(image, textures: dict):
    """The texture at most MAX_TEXTURE_EDGE pixels on a side, JPEG unless it has alpha."""
    from PIL import Image

    key = id(image)
    if key not in textures:
        smaller = image
        if max(image.size) > MAX_TEXTURE_EDGE:  # box-filtered by a whole factor: fast
            smaller = image.reduce(math.ceil(max(image.size) / MAX_TEXTURE_EDGE))
        if smaller.mode in ("RGB", "L") and (smaller is not image or image.format != "JPEG"):
            buffer = io.BytesIO()
            smaller.convert("RGB").save(buffer, format="JPEG", quality=85)
            smaller = Image.open(io.BytesIO(buffer.getvalue()))
        textures[key] = (image, smaller)  # the original kept: its id stays unique
    return textures[key][1]


# --- the robot's nodes -----------------------------------------------------------------------

class RobotScene:
    """One robot's nodes in a viser scene (module docstring): a frame node per body, whose
    poses `set_pose` and `pose_arrays` give, with the link frames and visuals under it."""

    def __init__(self, scene, dyn, visuals: RobotVisuals, library: MeshLibrary,
                 prefix: str = ROOT, p=None, ghost: float | None = None, q0=None):
        self.dyn, self.p, self.prefix = dyn, p, prefix
        self.bodies = body_names(dyn)
        names = _Names()
        self.root = scene.add_frame(prefix, show_axes=False)
        self.body_nodes = [f"{prefix}/{names(b)}" for b in self.bodies]
        self.world_node = f"{prefix}/{names('world')}"
        q0 = dyn.neutral() if q0 is None else np.asarray(q0, dtype=float)
        R, origin = _placed(dyn, q0, p)
        self.handles = [scene.add_frame(node, show_axes=False, position=tuple(origin[b]),
                                        wxyz=tuple(wxyz(R[b])))
                        for b, node in enumerate(self.body_nodes)]
        scene.add_frame(self.world_node, show_axes=False)
        self.link_nodes = self._links(scene, dyn, p)
        self.drawn = self._visuals(scene, visuals, library, ghost)

    def _links(self, scene, dyn, p) -> dict[str, str]:
        """A node per link frame of dyn.frames, under its body (or the world)."""
        bodies = frame_bodies(dyn)
        links = [name for name, _, kind in dyn.info.frames if kind == "link"]
        offsets = frame_offsets(dyn, links, p)
        taken: dict[str, _Names] = {}
        out = {}
        for link in links:
            body = bodies[link]
            parent = self.world_node if body < 0 else self.body_nodes[body]
            node = f"{parent}/{taken.setdefault(parent, _Names())(link)}"
            R, origin = offsets[link]
            scene.add_frame(node, show_axes=False, position=tuple(origin), wxyz=tuple(wxyz(R)))
            out[link] = node
        return out

    def _visuals(self, scene, visuals: RobotVisuals, library: MeshLibrary,
                 ghost: float | None) -> int:
        counts: dict[str, int] = {}
        drawn = 0
        for visual in visuals.visuals:
            parent = self.link_nodes.get(visual.frame, self.world_node)
            glb, visual = library.glb(visual, ghost)
            if glb is None:
                continue
            k = counts[parent] = counts.get(parent, 0) + 1
            scene.add_glb(f"{parent}/visual_{k}", glb, scale=tuple(visual.shape.scale),
                          position=tuple(float(v) for v in visual.p),
                          wxyz=tuple(float(v) for v in wxyz(visual.R)),
                          cast_shadow=ghost is None, receive_shadow=ghost is None)
            drawn += 1
        return drawn

    def pose_arrays(self, q) -> tuple[np.ndarray, np.ndarray]:
        """Every body's position (N, B, 3) and orientation (N, B, 4: w, x, y, z) at q."""
        R, origin = _placed(self.dyn, q, self.p)
        return origin, wxyz(R)

    def set_pose(self, q) -> None:
        """Move the bodies to the configuration q (live scenes)."""
        origin, quaternion = self.pose_arrays(np.atleast_2d(q))
        for b, handle in enumerate(self.handles):
            handle.wxyz = tuple(float(v) for v in quaternion[0, b])
            handle.position = tuple(float(v) for v in origin[0, b])


def _placed(dyn, q, p):
    from .placements import body_placements

    R, origin = body_placements(dyn, q, p)
    return (R[0], origin[0]) if np.ndim(q) == 1 else (R, origin)
