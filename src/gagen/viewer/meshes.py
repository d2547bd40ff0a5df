"""A robot's mesh files: found as URDF users expect, read as untrusted input.

Where a mesh named by a description is looked for (the conventions of ROS and Pinocchio):

- `package://PKG/PATH`: PATH inside the package PKG, found in the package directories
  (`package_dirs`, then `$ROS_PACKAGE_PATH`, in order) as `DIR/PKG/PATH`, or as
  `DIR/PATH` when DIR is itself the folder PKG. The file must stay inside that package
  folder.
- `file:///ABS` and `/ABS`: read only when inside an allowed folder (below).
- a relative path: from the description's folder.

The allowed folders are the description's folder and the package directories. A mesh is
refused, with a reason, when its path resolves (symbolic links followed) outside the folder
it was found in, when it is not a regular file, is larger than MAX_MESH_BYTES, is not an STL,
OBJ or COLLADA (.dae) file, fails to decode, decodes to more than MAX_VERTICES vertices or
MAX_FACES faces or to non-finite coordinates, or when the robot's meshes together pass
MAX_TOTAL_BYTES, MAX_TOTAL_VERTICES or MAX_TOTAL_FACES. A COLLADA file is XML: like a URDF
it may not declare a DTD or entities. Files a mesh refers to (an OBJ's material library,
texture images) obey the same folder rules from the mesh's folder, at most
MAX_IMAGE_BYTES each and MAX_IMAGE_PIXELS pixels (checked from the image's header before
it is decoded). Meshes are decoded by trimesh (COLLADA through pycollada).
"""

from __future__ import annotations

import io
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from urllib.parse import unquote, urlsplit

import numpy as np

from ..errors import ModelError
from ..model.inputs import parse_untrusted_xml, quote

MAX_MESH_BYTES = 32 * 2**20  # a real robot's meshes are a few MB each
MAX_TOTAL_BYTES = 256 * 2**20  # as an MJCF model's assets (gagen.model.mjcf_files)
MAX_VERTICES = 2_000_000  # per mesh file
MAX_FACES = 4_000_000
MAX_TOTAL_VERTICES = 8_000_000  # per robot
MAX_TOTAL_FACES = 16_000_000
MAX_IMAGE_BYTES = 16 * 2**20
MAX_IMAGE_PIXELS = 4096 * 4096
MAX_REFERENCED_FILES = 64  # material libraries and textures of one mesh
MESH_SUFFIXES = {".stl": "stl", ".obj": "obj", ".dae": "dae"}


class MeshRefused(Exception):
    """A mesh (or a file it refers to) that gagen will not read; the message says why."""


def package_dirs_from(package_dirs=None) -> list[Path]:
    """The package directories: `package_dirs` (a folder or a list of them), then the
    entries of $ROS_PACKAGE_PATH."""
    if package_dirs is None:
        given = []
    elif isinstance(package_dirs, (str, os.PathLike)):
        given = [package_dirs]
    else:
        given = list(package_dirs)
    env = [p for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p]
    return [Path(p) for p in [*given, *env]]


@dataclass(frozen=True)
class FoundMesh:
    """A mesh file and the folder it must stay in."""

    path: Path  # the real path (symbolic links resolved)
    root: Path  # the real path of the folder it was found in


class MeshFinder:
    """Finds the files that a description's mesh URIs name (module docstring)."""

    def __init__(self, description_dir: str | Path, package_dirs=None):
        self.description_dir = _real(Path(description_dir))
        self.package_dirs = package_dirs_from(package_dirs)
        self.allowed = [self.description_dir] + [_real(p) for p in self.package_dirs]

    def find(self, uri: str) -> FoundMesh:
        """The mesh that `uri` names; MeshRefused saying why there is none."""
        if not uri or "\x00" in uri or "\\" in uri:
            raise MeshRefused(f"{quote(uri)} is not a file name (use '/' between folders)")
        parts = urlsplit(uri)
        scheme = parts.scheme.lower()
        if scheme == "package":
            return self._package(uri, unquote(parts.netloc), unquote(parts.path))
        if scheme == "file":
            if parts.netloc not in ("", "localhost"):
                raise MeshRefused(f"{quote(uri)} names another host")
            return self._absolute(uri, Path(unquote(parts.path)))
        if scheme and len(scheme) > 1:  # (a one-letter scheme is a Windows drive)
            raise MeshRefused(f"{quote(uri)}: gagen reads package://, file:// and file paths, "
                              f"not {scheme}:// (nothing is fetched from a network)")
        path = Path(uri)
        if path.is_absolute():
            return self._absolute(uri, path)
        return self._inside(uri, self.description_dir / path, [self.description_dir],
                            "the description's folder")

    def _package(self, uri: str, package: str, rest: str) -> FoundMesh:
        if not package or package in (".", "..") or "/" in package:
            raise MeshRefused(f"{quote(uri)}: no package name after package://")
        relative = rest.lstrip("/")
        if not relative:
            raise MeshRefused(f"{quote(uri)} names a package, not a file")
        if not self.package_dirs:
            raise MeshRefused(f"{quote(uri)}: package {quote(package)} not found: no package "
                              "directories (give --package-path / package_dirs= or "
                              "$ROS_PACKAGE_PATH)")
        for folder in self.package_dirs:
            for root in (folder / package, folder) if folder.name == package else (
                    folder / package,):
                if root.is_dir():
                    return self._inside(uri, root / relative, [_real(root)],
                                        f"the package folder {quote(str(root))}")
        raise MeshRefused(f"{quote(uri)}: package {quote(package)} not found in the package "
                          f"directories ({', '.join(quote(str(p)) for p in self.package_dirs)})")

    def _absolute(self, uri: str, path: Path) -> FoundMesh:
        return self._inside(uri, path, self.allowed,
                            "the allowed folders (the description's folder and the package "
                            "directories; add one with --package-path / package_dirs=)")

    def _inside(self, uri: str, path: Path, roots: list[Path], where: str) -> FoundMesh:
        real = _real(path)
        for root in roots:
            if real.is_relative_to(root):
                _check_regular(real, uri)
                return FoundMesh(real, root)
        if not os.path.lexists(path):
            raise MeshRefused(f"{quote(uri)} is outside {where}")
        raise MeshRefused(f"{quote(uri)} resolves outside {where}"
                          + (" (through a symbolic link)" if real != Path(os.path.abspath(path))
                             else ""))


def _real(path: Path) -> Path:
    return Path(os.path.realpath(path))


def _check_regular(path: Path, uri: str) -> os.stat_result:
    try:
        info = path.stat()
    except FileNotFoundError:
        raise MeshRefused(f"{quote(uri)}: file not found ({quote(str(path))})") from None
    except OSError as exc:
        raise MeshRefused(f"{quote(uri)}: cannot read: {exc.strerror or exc}") from None
    if not stat.S_ISREG(info.st_mode):
        raise MeshRefused(f"{quote(uri)} is not a regular file")
    return info


def read_bounded(path: Path, limit: int, what: str) -> bytes:
    """The bytes of a regular file of at most `limit` bytes (checked before reading)."""
    info = _check_regular(path, str(path))
    too_large = f"gagen reads {what}s of at most {limit:,} bytes"
    if info.st_size > limit:
        raise MeshRefused(f"{quote(str(path))} has {info.st_size:,} bytes; {too_large}")
    try:
        with path.open("rb") as handle:
            data = handle.read(limit + 1)
    except OSError as exc:
        raise MeshRefused(f"{quote(str(path))}: cannot read: {exc.strerror or exc}") from None
    if len(data) > limit:
        raise MeshRefused(f"{quote(str(path))} grew while it was read; {too_large}")
    return data


@dataclass
class MeshBudget:
    """What the meshes of one robot have used so far (the totals' bounds)."""

    bytes: int = 0
    vertices: int = 0
    faces: int = 0
    notes: list[str] = field(default_factory=list)  # files a mesh referred to, refused

    def spend(self, nbytes: int = 0, vertices: int = 0, faces: int = 0) -> None:
        self.bytes += nbytes
        self.vertices += vertices
        self.faces += faces
        for used, limit, what in ((self.bytes, MAX_TOTAL_BYTES, "bytes of mesh files"),
                                  (self.vertices, MAX_TOTAL_VERTICES, "vertices"),
                                  (self.faces, MAX_TOTAL_FACES, "faces")):
            if used > limit:
                raise MeshRefused(f"the robot's meshes pass {limit:,} {what} in all")


def read_mesh(found: FoundMesh, budget: MeshBudget):
    """The mesh as a `trimesh.Scene` (its materials and textures kept), in metres.

    Raises MeshRefused saying why it cannot be used (module docstring)."""
    import trimesh

    kind = MESH_SUFFIXES.get(found.path.suffix.lower())
    if kind is None:
        raise MeshRefused(f"{quote(found.path.name)}: gagen reads STL, OBJ and COLLADA (.dae) "
                          "meshes")
    data = read_bounded(found.path, MAX_MESH_BYTES, "mesh file")
    budget.spend(nbytes=len(data))
    if kind == "dae":
        try:
            parse_untrusted_xml(data, str(found.path), "a COLLADA mesh")
        except ModelError as exc:
            raise MeshRefused(str(exc)) from None
    resolver = FolderResolver(found.path.parent, found.root, budget)
    try:
        scene = trimesh.load(io.BytesIO(data), file_type=kind, resolver=resolver,
                             force="scene")
    except (MemoryError, RecursionError):
        raise MeshRefused(f"{quote(found.path.name)} is too complex to decode") from None
    except Exception as exc:  # noqa: BLE001 - a third-party decoder on untrusted bytes
        raise MeshRefused(f"{quote(found.path.name)}: malformed {kind.upper()} file "
                          f"({type(exc).__name__})") from None
    _check_decoded(scene, found.path.name, budget)
    return _in_metres(scene)


def _check_decoded(scene, name: str, budget: MeshBudget) -> None:
    geometries = list(scene.geometry.values())
    vertices = sum(len(g.vertices) for g in geometries)
    faces = sum(len(getattr(g, "faces", ())) for g in geometries)
    if faces == 0:
        raise MeshRefused(f"{quote(name)}: no triangles (an empty or malformed mesh)")
    if vertices > MAX_VERTICES or faces > MAX_FACES:
        raise MeshRefused(f"{quote(name)} has {vertices:,} vertices and {faces:,} faces; "
                          f"gagen draws meshes of at most {MAX_VERTICES:,} and {MAX_FACES:,}")
    if not all(np.isfinite(g.vertices).all() for g in geometries):
        raise MeshRefused(f"{quote(name)}: vertex coordinates that are NaN or infinite")
    budget.spend(vertices=vertices, faces=faces)


def _in_metres(scene):
    """COLLADA declares its unit (<unit meter="0.001"/>); URDF means metres."""
    units = scene.units
    if units and units not in ("m", "meters", "meter"):
        try:
            scene = scene.convert_units("meters", guess=False)
        except (ValueError, KeyError):
            pass  # an unknown unit: drawn as given, as RViz does
    return scene


class FolderResolver:
    """trimesh's hook for the files a mesh refers to: only regular files inside the mesh's
    root, bounded in size and (images) in pixels; refusals are kept in the budget's notes."""

    def __init__(self, folder: Path, root: Path, budget: MeshBudget):
        self.folder, self.root, self.budget = folder, root, budget
        self.count = 0

    def get(self, name: str) -> bytes:
        try:
            return self._get(name)
        except MeshRefused as exc:
            self.budget.notes.append(str(exc))
            raise

    def _get(self, name: str) -> bytes:
        self.count += 1
        if self.count > MAX_REFERENCED_FILES:
            raise MeshRefused(f"more than {MAX_REFERENCED_FILES} files referred to")
        text = str(name)
        if not text or "\x00" in text or "\\" in text:
            raise MeshRefused(f"{quote(text)} is not a file name")
        parts = urlsplit(text)
        if parts.scheme and len(parts.scheme) > 1 and parts.scheme.lower() != "file":
            raise MeshRefused(f"{quote(text)}: not a local file (nothing is fetched)")
        path = Path(unquote(parts.path)) if parts.scheme.lower() == "file" else Path(text)
        real = _real(path if path.is_absolute() else self.folder / PurePosixPath(text))
        if not real.is_relative_to(self.root):
            raise MeshRefused(f"{quote(text)} resolves outside the mesh's folder "
                              f"{quote(str(self.root))}")
        data = read_bounded(real, MAX_IMAGE_BYTES, "file referred to by a mesh")
        self.budget.spend(nbytes=len(data))
        _check_image_size(data, text)
        return data

    # trimesh's Resolver interface besides get
    def __getitem__(self, name: str) -> bytes:
        return self.get(name)

    def keys(self):
        return iter(())

    def namespaced(self, namespace: str) -> FolderResolver:
        return FolderResolver(self.folder / namespace, self.root, self.budget)

    def write(self, name, data):
        raise MeshRefused("gagen writes nothing next to a mesh")


def _check_image_size(data: bytes, name: str) -> None:
    """An image's pixel count from its header (no decoding); other files pass."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(data)) as image:
            width, height = image.size
    except (UnidentifiedImageError, OSError, ValueError):
        return  # not an image (an OBJ's material library): read as text by trimesh
    except Image.DecompressionBombError:
        width = height = MAX_IMAGE_PIXELS + 1
    if width * height > MAX_IMAGE_PIXELS:
        raise MeshRefused(f"texture {quote(name)} has {width} x {height} pixels; gagen reads "
                          f"images of at most {MAX_IMAGE_PIXELS:,} pixels")
