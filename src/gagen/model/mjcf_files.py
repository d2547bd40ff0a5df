"""The files of an MJCF model, checked before MuJoCo sees them (no SymPy, no MuJoCo here).

An MJCF file may come from anyone, and MuJoCo's compiler opens whatever its `<include
file>` and asset paths (`<mesh file>`, `<texture file>`, `<hfield file>`, ...) name, and
allocates what some attributes and some files ask for. So gagen reads the XML itself
first, with expat and no DTD (as for URDF), follows the includes, and refuses:

- a path that is absolute, climbs with `..`, or resolves (through a symbolic link) outside
  the model file's folder; a file that is missing or too large;
- more bodies than gagen builds (`inputs.MAX_BODIES`, counting `<replicate>` copies);
- elements gagen does not model and that make MuJoCo generate or load content:
  deformables (`composite`, `flexcomp`, `flex`), model composition (`attach`, `model`),
  plugins (`extension`, `plugin`), builtin meshes;
- what would cost MuJoCo more than the bounds below (`BOUNDS`): they count what MuJoCo
  will build and allocate, not what the file says about itself. `<replicate>` counts
  every element it copies (nested ones multiply); an image (a texture's file or files, a
  height field's file) counts the pixels it decodes to, read from the image's own header
  (a PNG's IHDR, a custom height field's two integers) before MuJoCo decodes anything; a
  builtin cube or skybox texture counts its six faces of width x width (MuJoCo ignores
  its height).

MuJoCo then compiles the file from its path (`MjModel.from_xml_path`), with its own rules
for where included files and assets are found. MuJoCo's virtual file system is not used:
it keys files by their base name (two meshes `a/x.stl` and `b/x.stl` cannot both be
given) and falls back to the disk for a name it lacks, so it would contain nothing more
than this scan does. The bytes of every file found here are part of the cache's key
(`file_digest_parts`), so editing an included file or a mesh rebuilds the model.
"""

from __future__ import annotations

import os
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path, PurePath

from ..errors import ModelError
from .inputs import MAX_BODIES, MAX_FILE_BYTES, parse_untrusted_xml, quote, read_description

# The bounds on what an MJCF model may cost MuJoCo, in one place (the README's safety
# section lists them, with the tests that guard each: tests/test_mjcf.py,
# tests/test_hostile_input_round3.py).
MAX_INCLUDES = 200  # included files
MAX_ASSETS = 2000  # asset files
MAX_ASSET_BYTES = 256 * 2**20  # bytes of every asset file together (meshes: a few MB each)
MAX_ALLOCATION = 2**24  # entries one element's attributes may make MuJoCo allocate
MAX_REPLICATE = 10_000  # copies made by <replicate> (nested ones: their product)
# Elements MuJoCo builds, each counted once per copy a <replicate> makes of it: MuJoCo's
# compiler takes ~3 s for 20,000 geoms and its time grows faster than the count (80,000
# replicated sites: minutes); a robot has hundreds.
MAX_ELEMENTS = 20_000
# Decoded pixels of one image (a texture's faces together, a height field): 4096 x 4096.
# MuJoCo peaks at 9-15 bytes a pixel while it decodes a PNG (lodepng's buffers, then its
# own), so one such image is 150-250 MB.
MAX_IMAGE_PIXELS = 2**24
MAX_TOTAL_PIXELS = 2**25  # decoded pixels of all of a model's images together
BOUNDS = {"included files": MAX_INCLUDES, "asset files": MAX_ASSETS,
          "bytes of assets": MAX_ASSET_BYTES, "entries per element": MAX_ALLOCATION,
          "replicate copies": MAX_REPLICATE, "elements": MAX_ELEMENTS,
          "pixels per image": MAX_IMAGE_PIXELS, "pixels of all images": MAX_TOTAL_PIXELS}
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_KTX_SIGNATURES = (b"\xabKTX 11\xbb\r\n\x1a\n", b"\xabKTX 20\xbb\r\n\x1a\n")

# Elements gagen refuses, with the reason.
_REFUSED = {
    "composite": "deformable composites are not rigid bodies of a tree",
    "flexcomp": "deformable (flex) bodies are not rigid bodies of a tree",
    "flex": "deformable (flex) bodies are not rigid bodies of a tree",
    "attach": "<attach> is not supported; copy the bodies in, or use <include>",
    "model": "model assets (<model> for <attach>) are not supported; use <include>",
    "extension": "MuJoCo plugins are not supported",
    "plugin": "MuJoCo plugins are not supported",
}
# Attributes whose product is the size of something MuJoCo allocates for the element.
_ALLOCATING = {
    "hfield": ("nrow", "ncol"),
    "texture": ("width", "height"),
    "numeric": ("size",),
}
_IMAGES = ("texture", "hfield")  # elements whose files MuJoCo decodes as images
# Asset elements and the <compiler> folder they are looked up in (assetdir otherwise).
_ASSET_DIRS = {"mesh": "meshdir", "skin": "meshdir", "hfield": "meshdir",
               "texture": "texturedir"}
_DIR_ATTRIBUTES = ("meshdir", "texturedir", "assetdir")


@dataclass
class MjcfFiles:
    """What the scan found: the main file and every file the model reads."""

    main: Path
    includes: list[Path] = field(default_factory=list)
    assets: list[Path] = field(default_factory=list)
    body_count: int = 0
    element_count: int = 0  # each element once per copy <replicate> makes of it
    pixels: int = 0  # decoded pixels of every image (texture, height field) together

    @property
    def folder(self) -> Path:
        return self.main.parent


@dataclass
class _Image:
    """A texture or height field: what MuJoCo decodes for it, counted once its files are
    found (`_check_images`)."""

    element: ET.Element
    where: str
    copies: int
    files: list[tuple[Path, str]] = field(default_factory=list)  # (path, what names it)


@dataclass
class _Scan:
    files: MjcfFiles
    source: str
    root: Path  # the real path of the model's folder
    compiler: dict[str, str] = field(default_factory=dict)
    # (tag, value, including folder, what names it, the image it belongs to)
    asset_refs: list[tuple[str, str, Path, str, _Image | None]] = field(default_factory=list)
    images: list[_Image] = field(default_factory=list)
    xml_bytes: int = 0


def scan_mjcf(path: str | Path) -> MjcfFiles:
    """Check an MJCF file and everything it includes; the files MuJoCo will read.

    Raises ModelError naming the file, the element and the reason.
    """
    path = Path(path)
    source = str(path)
    scan = _Scan(MjcfFiles(path), source, Path(os.path.realpath(path.parent)))
    data = read_description(path, "MJCF file")
    scan.xml_bytes = len(data)
    root = parse_untrusted_xml(data, source, "an MJCF file")
    _check_root(root, source, source)
    _walk(root, scan, path.parent, 1, source)
    for tag, value, including_dir, element, image in scan.asset_refs:
        path = _asset_path(scan, tag, value, including_dir, element)
        scan.files.assets.append(path)
        if image is not None:
            image.files.append((path, element))
    _check_asset_sizes(scan)
    _check_images(scan)
    return scan.files


def file_digest_parts(path: str | Path) -> list[bytes]:
    """What an MJCF model depends on besides gagen: MuJoCo's version, and each file's
    path (relative to the model's folder) and bytes. Raises ModelError like `scan_mjcf`."""
    files = scan_mjcf(path)
    parts = [f"mujoco={_mujoco_version()}".encode()]
    for file in [files.main, *files.includes, *sorted(set(files.assets))]:
        parts += [os.path.relpath(file, files.folder).encode(), file.read_bytes()]
    return parts


def _mujoco_version() -> str:
    try:
        return metadata.version("mujoco")
    except metadata.PackageNotFoundError:
        return "none"


def _check_root(root: ET.Element, source: str, file: str) -> None:
    if root.tag != "mujoco":
        raise ModelError(source, f"<{quote(str(root.tag))[1:-1]}> in {file}",
                         "the root element of an MJCF file must be <mujoco>")


def _walk(element: ET.Element, scan: _Scan, including_dir: Path, copies: int,
          file: str) -> None:
    """Visit an element's subtree (iteratively: nesting depth is the file's to choose)."""
    stack = [(element, copies)]
    while stack:
        elem, copies = stack.pop()
        tag = str(elem.tag)
        where = f"<{quote(tag)[1:-1]}> in {file}"
        if tag in _REFUSED:
            raise ModelError(scan.source, where, _REFUSED[tag])
        scan.files.element_count += copies
        if scan.files.element_count > MAX_ELEMENTS:
            raise ModelError(scan.source, where, f"more than {MAX_ELEMENTS:,} elements "
                             "(counting each copy <replicate> makes); MuJoCo's compiler "
                             "would take minutes")
        _check_allocation(elem, tag, scan.source, where)
        image = None
        if tag in _IMAGES:
            image = _Image(elem, where, copies)
            scan.images.append(image)
        if tag == "body":
            scan.files.body_count += copies
            if scan.files.body_count > MAX_BODIES:
                raise ModelError(scan.source, where, f"more than {MAX_BODIES} bodies; gagen "
                                 f"builds robots of at most {MAX_BODIES} bodies")
        elif tag == "replicate":
            copies *= _count(elem, "count", MAX_REPLICATE, scan.source, where)
            if copies > MAX_REPLICATE:
                raise ModelError(scan.source, where, f"nested <replicate> make more than "
                                 f"{MAX_REPLICATE:,} copies")
        elif tag == "compiler":
            _record_compiler(elem, scan, where)
        elif tag == "mesh" and elem.get("builtin") is not None:
            raise ModelError(scan.source, where, "builtin meshes are not supported (their "
                             "size is set by parameters); give the mesh as a file")
        elif tag == "include":
            _include(elem, scan, including_dir, copies, where)
        for key, value in elem.attrib.items():
            if key.startswith("file") and tag != "include":
                scan.asset_refs.append((tag, value, including_dir, f"{where}, {key}", image))
        stack.extend((child, copies) for child in reversed(list(elem)))


def _include(elem: ET.Element, scan: _Scan, including_dir: Path, copies: int,
             where: str) -> None:
    value = elem.get("file")
    if not value:
        raise ModelError(scan.source, where, "missing attribute 'file' of <include>")
    path = _existing(scan, [scan.files.folder, including_dir], value, f"{where}, file")
    if path in scan.files.includes or path == scan.files.main:
        raise ModelError(scan.source, f"{where}, file",
                         f"{quote(value)} is included twice (or includes itself)")
    if len(scan.files.includes) >= MAX_INCLUDES:
        raise ModelError(scan.source, where, f"more than {MAX_INCLUDES} included files")
    scan.files.includes.append(path)
    data = read_description(path, "MJCF file")
    scan.xml_bytes += len(data)
    if scan.xml_bytes > MAX_FILE_BYTES:
        raise ModelError(scan.source, where, f"the model and its includes have more than "
                         f"{MAX_FILE_BYTES:,} bytes of XML")
    root = parse_untrusted_xml(data, str(path), "an MJCF file")
    _check_root(root, scan.source, str(path))
    for child in root:
        _walk(child, scan, path.parent, copies, str(path))


def _record_compiler(elem: ET.Element, scan: _Scan, where: str) -> None:
    for key in _DIR_ATTRIBUTES:
        value = elem.get(key)
        if value is not None:
            _relative_parts(value, scan.source, f"{where}, {key}")
            scan.compiler[key] = value


def _asset_path(scan: _Scan, tag: str, value: str, including_dir: Path, element: str) -> Path:
    folder = scan.compiler.get(_ASSET_DIRS.get(tag, "assetdir")) or scan.compiler.get(
        "assetdir", "")
    return _existing(scan, [scan.files.folder / folder, including_dir], value, element)


def _existing(scan: _Scan, folders: list[Path], value: str, element: str) -> Path:
    """The first of the places MuJoCo looks for `value` that exists; every one that exists
    must stay inside the model's folder."""
    parts = _relative_parts(value, scan.source, element)
    found = []
    for folder in folders:
        candidate = folder.joinpath(*parts)
        if candidate.is_file():
            real = Path(os.path.realpath(candidate))
            if not real.is_relative_to(scan.root):
                raise ModelError(scan.source, element, f"{quote(value)} resolves outside the "
                                 "model file's folder (through a symbolic link)")
            found.append(candidate)
    if not found:
        raise ModelError(scan.source, element, f"file {quote(value)} not found in the model "
                         "file's folder")
    return found[0]


def _relative_parts(value: str, source: str, element: str) -> tuple[str, ...]:
    """The parts of a path that must stay inside the model's folder: relative, no `..`."""
    if "\\" in value or "\x00" in value:
        raise ModelError(source, element, f"{quote(value)}: use '/' to separate folders")
    pure = PurePath(value)
    if pure.is_absolute() or value.startswith("/") or ":" in value:
        raise ModelError(source, element, f"{quote(value)} is an absolute path; gagen reads "
                         "only files inside the model file's folder")
    if ".." in pure.parts:
        raise ModelError(source, element, f"{quote(value)} leaves the model file's folder "
                         "('..'); gagen reads only files inside it")
    return pure.parts


def _check_allocation(elem: ET.Element, tag: str, source: str, where: str) -> None:
    keys = _ALLOCATING.get(tag, ())
    if tag == "size":
        keys = tuple(k for k in elem.attrib if k.startswith("nuser") or k == "nkey")
    total = 1
    for key in keys:
        if elem.get(key) is not None:
            total *= _count(elem, key, MAX_ALLOCATION, source, where)
            if total > MAX_ALLOCATION:
                raise ModelError(source, where, f"{', '.join(keys)} ask for more than "
                                 f"{MAX_ALLOCATION:,} entries")


def _count(elem: ET.Element, key: str, limit: int, source: str, where: str) -> int:
    text = elem.get(key, "").strip()
    try:
        value = int(text)
    except ValueError:
        raise ModelError(source, f"{where}, {key}", f"{quote(text)} is not an integer") from None
    if value > limit:
        raise ModelError(source, f"{where}, {key}", f"{value} is more than {limit:,}")
    return max(value, 0)


def _check_asset_sizes(scan: _Scan) -> None:
    assets = sorted(set(scan.files.assets))
    if len(assets) > MAX_ASSETS:
        raise ModelError(scan.source, "<asset>", f"more than {MAX_ASSETS} asset files")
    total = 0
    for asset in assets:
        try:
            total += asset.stat().st_size
        except OSError as exc:
            raise ModelError(scan.source, str(asset), f"cannot read: {exc.strerror}") from None
        if total > MAX_ASSET_BYTES:
            raise ModelError(scan.source, "<asset>", f"the asset files have more than "
                             f"{MAX_ASSET_BYTES:,} bytes")


# --- images: what MuJoCo decodes, from each image's own header --------------------------

def _check_images(scan: _Scan) -> None:
    """Refuse an image that decodes to more than MAX_IMAGE_PIXELS, or images that together
    decode to more than MAX_TOTAL_PIXELS (each counted once per element that loads it)."""
    for image in scan.images:
        pixels = _image_pixels(image, scan.source)
        if pixels > MAX_IMAGE_PIXELS:
            raise ModelError(scan.source, image.where, f"decodes to {pixels:,} pixels; gagen "
                             f"reads images of at most {MAX_IMAGE_PIXELS:,} pixels (4096 x "
                             "4096)")
        scan.files.pixels += pixels * image.copies
        if scan.files.pixels > MAX_TOTAL_PIXELS:
            raise ModelError(scan.source, image.where, f"the model's images decode to more "
                             f"than {MAX_TOTAL_PIXELS:,} pixels together")


def _image_pixels(image: _Image, source: str) -> int:
    """The pixels MuJoCo decodes for a texture or height field element: its files' (from
    their headers), or what its attributes ask for (a builtin texture, a height field
    without a file)."""
    elem, tag = image.element, str(image.element.tag)
    pixels = sum(_file_pixels(path, tag, source, where) for path, where in image.files)
    if tag == "texture" and elem.get("builtin", "none").strip() != "none":
        width = _count(elem, "width", MAX_ALLOCATION, source, image.where) \
            if elem.get("width") is not None else 0
        if elem.get("type", "cube").strip() in ("cube", "skybox"):
            pixels += 6 * width * width  # six square faces; MuJoCo ignores the height
        elif elem.get("height") is not None:
            pixels += width * _count(elem, "height", MAX_ALLOCATION, source, image.where)
    elif tag == "hfield" and not image.files:
        pixels += _attribute_product(elem, ("nrow", "ncol"), source, image.where)
    return pixels


def _attribute_product(elem: ET.Element, keys: tuple[str, ...], source: str,
                       where: str) -> int:
    if any(elem.get(key) is None for key in keys):
        return 0
    product = 1
    for key in keys:
        product *= _count(elem, key, MAX_ALLOCATION, source, where)
    return product


def _file_pixels(path: Path, tag: str, source: str, where: str) -> int:
    """The pixels an image file decodes to, from its header: a PNG's IHDR; a KTX texture
    is kept as it is (its bytes count with the assets'); anything else as MuJoCo's custom
    format, two 32-bit integers (rows and columns, or width and height) first."""
    try:
        with path.open("rb") as handle:
            head = handle.read(33)
    except OSError as exc:
        raise ModelError(source, where, f"cannot read: {exc.strerror}") from None
    if head.startswith(_PNG_SIGNATURE):
        return _png_pixels(head, source, where)
    if tag == "texture" and head.startswith(_KTX_SIGNATURES):
        return 0
    if len(head) < 8:
        return 0  # MuJoCo refuses a file too short for the custom header
    first, second = struct.unpack("<ii", head[:8])
    return max(first, 0) * max(second, 0)


def _png_pixels(head: bytes, source: str, where: str) -> int:
    """width x height from a PNG's header chunk (IHDR: the first chunk, 13 bytes)."""
    if len(head) < 33 or head[12:16] != b"IHDR" or struct.unpack(">I", head[8:12])[0] != 13:
        raise ModelError(source, where, "a PNG file without its header chunk (IHDR) first; "
                         "gagen reads the size of an image from its header")
    width, height = struct.unpack(">II", head[16:24])
    return width * height
