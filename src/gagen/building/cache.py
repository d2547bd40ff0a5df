"""The cache of compiled modules, and the SymPy-free way back to them.

A build is keyed by everything its module depends on (see `build_key`); a finished entry
holds the module, its sources and the module's SHA-256, checked before every import. An
index maps a key of the *input* (the bytes of the model file or URDF, the options, gagen's
version and pipeline, the ABI) to the module built from it, so that loading a model built
before reads neither the model nor SymPy.

A checksum says the bytes are those written, not that they are the right module: each
module carries its own key (`KEY`, the hash of its sources), which the index records and
the builder expects, and which is checked after every import from the cache. A module that
fails to import for any reason, or proves to be another (another model's, another
generator's), is damaged: it is warned about (CacheWarning), discarded and rebuilt. A
module once imported stays loaded in the process under its path (the dynamic loader and
Python both keep it), so its replacement is imported from a private copy.
"""

from __future__ import annotations

import atexit
import hashlib
import importlib
import importlib.machinery
import importlib.util
import json
import os
import platform
import shutil
import socket
import sys
import sysconfig
import tempfile
import time
from functools import cache as _memoized
from importlib import resources
from pathlib import Path

from .. import __version__

DEFAULT_FLAGS = ("-O3",)
FAST_MATH_FLAGS = ("-ffast-math",)
# One version of the kernels for any CPU of the architecture: no FMA clone (gagen_math.h)
PORTABLE_FLAGS = ("-DGAGEN_KERNEL=",)
# The kernels once, for this CPU's fused multiply-add (see compile_flags)
FMA_FLAGS = ("-mfma", "-DGAGEN_KERNEL=")
_loaded_modules: dict[str, object] = {}
# Paths whose module this process imported (or tried to) and then discarded as damaged: the
# dynamic loader would hand back the old library for that path, so the next import of a
# module there loads a copy (import_extension).
_stale_paths: set[str] = set()


# The sub-packages whose code (and templates) decides what the generated sources say.
GENERATOR_PACKAGES = ("symbolic", "codegen")


# ... and, for a key of the input bytes, the stage that reads them too.
PIPELINE_PACKAGES = ("model", *GENERATOR_PACKAGES)


def generator_digest() -> str:
    """A hash of the generator's own code and templates, so that a changed generator never
    reuses a build: every file of the symbolic and codegen stages, in a fixed order."""
    return _packages_digest(GENERATOR_PACKAGES)


@_memoized
def _packages_digest(packages: tuple[str, ...]) -> str:
    # memoized: the installed code does not change while a process runs (a test that edits
    # a copy of the package runs that copy in a fresh process)
    h = hashlib.sha256()
    for package in packages:
        root = resources.files(f"gagen.{package}")
        for path in sorted(_files(root), key=lambda item: item[0]):
            h.update(path[0].encode())
            h.update(path[1].read_bytes())
    return h.hexdigest()


def _files(folder, prefix: str = ""):
    """(relative name, traversable) of every source and template file under a folder."""
    for item in folder.iterdir():
        name = f"{prefix}{item.name}"
        if item.is_dir():
            if item.name != "__pycache__":
                yield from _files(item, name + "/")
        elif item.name.endswith((".py", ".j2", ".h", ".c")):
            yield name, item


def compile_flags(fast_math: bool = False, portable: bool = False) -> list[str]:
    """The compiler flags: -O3, plus -ffast-math on request, plus no per-CPU kernel clones
    with `portable` (for a module copied to other machines, and to test that version).

    Not portable, on a CPU with fused multiply-add, the kernels are compiled once for it
    (FMA_FLAGS) instead of twice, for any CPU and for FMA (gagen_math.h's GAGEN_KERNEL):
    the same code as the FMA clone at half the compile time. The flags are part of every
    cache key, so a machine without FMA never picks up such a module from a shared cache.
    """
    cpu = list(PORTABLE_FLAGS) if portable else list(native_fma_flags())
    return list(DEFAULT_FLAGS) + (list(FAST_MATH_FLAGS) if fast_math else []) + cpu


@_memoized
def native_fma_flags() -> tuple[str, ...]:
    """FMA_FLAGS where this machine is x86-64 Linux with FMA, else () (the clones stay)."""
    if sys.platform != "linux" or platform.machine() not in ("x86_64", "AMD64"):
        return ()
    try:
        text = Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:
        return ()
    flags = next((line.split(":", 1)[1].split() for line in text.splitlines()
                  if line.startswith("flags")), [])
    return FMA_FLAGS if "fma" in flags and "avx" in flags else ()


def build_key(src_key: str, flags: list[str]) -> str:
    """Hash of the sources plus what the binary depends on: flags and Python's ABI."""
    return _hash(src_key, " ".join(flags), *_binary_interface())


@_memoized
def _binary_interface() -> tuple[str, ...]:
    """What a compiled module depends on besides its sources: Python's ABI (the module is
    plain C; NumPy and Cython are in gagen's runtime, gagen.runtime._native, not in it)."""
    return (sysconfig.get_config_var("EXT_SUFFIX") or "", sys.version)


def _hash(*parts: str | bytes) -> str:
    h = hashlib.sha256()
    for part in parts:
        h.update(part.encode() if isinstance(part, str) else part)
        h.update(b"\0")
    return h.hexdigest()


# --- the index: input bytes -> module, without SymPy ----------------------------------------

def input_key(model, flags: list[str]) -> str | None:
    """A key of what the user named (a built-in's name and text, or a file's bytes), the
    compile flags, gagen's version and pipeline, and the ABI; None if the input cannot be
    read here (the model stage then reports why)."""
    text = str(model)
    if text == "rrr" or text.startswith("chain:"):
        source = resources.files("gagen.model").joinpath("rrr.yaml").read_bytes() \
            if text == "rrr" else b""
        kind = f"builtin:{text}"
    else:
        from ..model.inputs import MAX_FILE_BYTES

        path = Path(text)
        try:
            if not path.is_file() or path.stat().st_size > MAX_FILE_BYTES:
                return None
            source = path.read_bytes()
        except OSError:
            return None
        kind = f"file{path.suffix.lower()}"
    extra = _referenced_files(path) if kind in ("file.xml", "file.mjcf") else []
    if extra is None:
        return None
    return _hash("gagen-input", kind, source, " ".join(flags), __version__,
                 _packages_digest(PIPELINE_PACKAGES), *_binary_interface(), *extra)


def derivatives_input_key(key: str) -> str:
    """The index key of the derivative module built from the same input as the module of
    `key` (an `input_key`), so that it too is found without SymPy."""
    return _hash("gagen-derivatives", key)


def _referenced_files(path: Path) -> list[bytes] | None:
    """An MJCF model also depends on the files it includes, its assets and MuJoCo's version
    (None if they cannot be checked here: the model stage reports why)."""
    from ..errors import ModelError
    from ..model.mjcf_files import file_digest_parts

    try:
        return file_digest_parts(path)
    except (ModelError, OSError):
        return None


def index_lookup(cache: Path, key: str):
    """The module recorded for an input key, imported, or None (no record, a record of an
    earlier gagen without the module's key, or the module is gone or damaged: the caller
    builds again, which repairs the entry; a module that imports but is not the one
    recorded is discarded here with a CacheWarning)."""
    try:
        record = json.loads((cache / "index" / key[:40]).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict):
        return None
    if "shipped" in record:
        try:
            return importlib.import_module(f"gagen.shipped.{record['shipped']}")
        except ImportError:
            return None
    entry = cache / str(record.get("entry", ""))
    module_file = str(record.get("module", ""))
    expected = record.get("key")
    if not (module_file and isinstance(expected, str)) \
            or not cached_module_is_intact(entry, module_file):
        return None
    path = entry / module_file
    try:
        module = import_extension(path, module_file.split(".")[0])
    except Exception:  # noqa: BLE001 - any failure is damage, which the builder repairs
        return None
    problem = identity_problem(module, expected)
    if problem is not None:
        discard_damaged(path, problem)
        return None
    return module


def identity_problem(module, expected_key: str) -> str | None:
    """Why `module` is not the module of `expected_key` (its own KEY, checked after import),
    or None when it is."""
    key = getattr(module, "KEY", None)
    if key == expected_key:
        return None
    shown = key[:12] if isinstance(key, str) else "none"
    return (f"is not the module its cache entry names (its key {shown}, expected "
            f"{expected_key[:12]}: another model's or another build's)")


def discard_damaged(path: Path, problem: str) -> None:
    """Warn (CacheWarning) that a cached module is damaged, and discard its entry so that
    the next build replaces it."""
    from ..errors import warn_user

    warn_user(f"gagen: the cached module {path} {problem}; rebuilding it", CacheWarning)
    forget_module(path)
    discard_cache_entry(path.parent)


def index_record(cache: Path, key: str, module) -> None:
    """Record which module an input key gave (best effort: a read-only cache just misses)."""
    path = Path(getattr(module, "__file__", "") or "")
    name = module.__name__
    if name.startswith("gagen.shipped."):
        record = {"shipped": name.rsplit(".", 1)[1]}
    elif path.parent.parent.resolve() == cache.resolve():
        record = {"entry": path.parent.name, "module": path.name,
                  "key": str(getattr(module, "KEY", ""))}
    else:
        return
    try:
        folder = cache / "index"
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{key[:40]}-{os.getpid()}"
        tmp.write_text(json.dumps(record))
        os.replace(tmp, folder / key[:40])
    except OSError:
        pass


def default_cache_dir() -> Path:
    """$GAGEN_CACHE_DIR, else the platform's user cache folder for gagen (platformdirs:
    $XDG_CACHE_HOME/gagen or ~/.cache/gagen on Linux, ~/Library/Caches/gagen on macOS,
    %LOCALAPPDATA%\\gagen\\Cache on Windows).

    A relative folder from the platform's settings (e.g. a relative $XDG_CACHE_HOME, which
    the XDG specification says to ignore) gives way to ~/.cache/gagen: the cache never lands
    relative to the working directory.
    """
    env = os.environ.get("GAGEN_CACHE_DIR", "").strip()
    if env:
        return Path(env).expanduser()
    import platformdirs

    folder = Path(platformdirs.user_cache_dir("gagen", appauthor=False))
    return folder if folder.is_absolute() else Path.home() / ".cache" / "gagen"



class CacheWarning(UserWarning):
    """The cache could not be used as it was: an entry was rebuilt, or a temporary folder
    stands in for an unwritable cache."""


# --- the cache's own integrity ---------------------------------------------------------------

_CHECKSUM_FILE = "module.sha256"
_OWNER_FILE = "building.pid"
ABANDONED_AFTER_SECONDS = 24 * 3600  # a build folder without an owner file: assume dead
_fallback_cache: Path | None = None


def _checksum(module: Path) -> str:
    """'<sha256> <size> <file name>' of a module, as stored next to it."""
    data = module.read_bytes()
    return f"{hashlib.sha256(data).hexdigest()} {len(data)} {module.name}\n"


def cached_module_is_intact(entry: Path, module_file: str) -> bool:
    """Whether a cache entry's module exists and matches its checksum.

    Checked before every import: importing a truncated shared library kills the process
    (SIGBUS) where no exception can be caught.
    """
    module = entry / module_file
    try:
        expected = (entry / _CHECKSUM_FILE).read_text().split()
        if len(expected) != 3 or expected[2] != module_file:
            return False
        if module.stat().st_size != int(expected[1]):
            return False
        return _checksum(module).split() == expected
    except (OSError, ValueError):
        return False


def discard_cache_entry(entry: Path) -> None:
    """Remove a cache entry: renamed aside first, so no process ever sees half of it."""
    trash = entry.with_name(f".{entry.name}-discarded-{os.getpid()}-{time.monotonic_ns()}")
    try:
        os.rename(entry, trash)
    except OSError:
        return  # gone already, or another process is discarding it
    shutil.rmtree(trash, ignore_errors=True)


def clean_abandoned_builds(cache: Path) -> None:
    """Remove build folders left by killed processes (`kill -9`, a power cut).

    A build folder holds its owner's host and pid; it is abandoned when that process no
    longer runs on this host, or, without an owner file, when it is a day old.
    """
    host = socket.gethostname()
    try:
        entries = [p for p in cache.iterdir() if p.name.startswith(".gagen_") and p.is_dir()]
    except OSError:
        return
    for folder in entries:
        if _is_abandoned(folder, host):
            shutil.rmtree(folder, ignore_errors=True)


def _is_abandoned(folder: Path, host: str) -> bool:
    try:
        owner = (folder / _OWNER_FILE).read_text().split()
    except OSError:
        try:
            return time.time() - folder.stat().st_mtime > ABANDONED_AFTER_SECONDS
        except OSError:
            return False
    if len(owner) != 2 or owner[0] != host or not owner[1].isdigit():
        return False  # another machine's build on a shared cache: not ours to judge
    try:
        os.kill(int(owner[1]), 0)
    except ProcessLookupError:
        return True
    except (PermissionError, OverflowError):
        return False
    return False


def usable_cache_dir(cache: Path) -> Path:
    """`cache`, created if needed, or a private temporary folder (with a CacheWarning) when
    it cannot be written: a path that is a file, read-only, or unreachable."""
    global _fallback_cache
    try:
        cache.mkdir(parents=True, exist_ok=True)
        probe = Path(tempfile.mkdtemp(prefix=".gagen-probe-", dir=cache))
        probe.rmdir()
        return cache
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
    if _fallback_cache is None:
        _fallback_cache = Path(tempfile.mkdtemp(prefix="gagen-cache-"))
        # the process's private cache goes with the process (its modules stay mapped)
        atexit.register(shutil.rmtree, _fallback_cache, ignore_errors=True)
    from ..errors import warn_user

    warn_user(f"gagen: cannot write the cache folder {cache} ({reason}); building in "
              f"{_fallback_cache} for this process instead (removed when it ends). Set "
              "GAGEN_CACHE_DIR or cache_dir= to a writable folder to keep builds.",
              CacheWarning)
    return _fallback_cache


def install_received_module(cache: Path, file_name: str, data: bytes, sha256: str) -> Path:
    """Put a module received from another machine (a Dask client) into this cache, under
    received/<sha256>, and return its path; an intact copy already there is kept.

    The bytes must have the SHA-256 the sender gave (nothing damaged on the way), and the
    entry is written in a temporary folder renamed into place with its checksum, as a build
    is, so that `cached_module_is_intact` guards every later import.
    """
    if hashlib.sha256(data).hexdigest() != sha256:
        raise ValueError(f"the module {file_name} arrived damaged: its SHA-256 is not the "
                         "one the client sent")
    suffix = file_name[file_name.find("."):]  # e.g. .cpython-311-x86_64-linux-gnu.so
    if Path(file_name).name != file_name or suffix not in importlib.machinery.EXTENSION_SUFFIXES:
        raise ValueError(f"the module {file_name} was built for another platform or Python "
                         f"than this worker's ({sysconfig.get_config_var('EXT_SUFFIX')}): "
                         "run the workers on the client's Python version and platform")
    entry = cache / "received" / sha256[:40]
    if cached_module_is_intact(entry, file_name):
        return entry / file_name
    entry.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".gagen_received-", dir=entry.parent))
    try:
        (tmp / file_name).write_bytes(data)
        (tmp / _CHECKSUM_FILE).write_text(_checksum(tmp / file_name))
        # damaged: set aside, then replaced; but another worker process of this machine may
        # have just installed an intact copy, which it is importing: that one stays
        if entry.exists() and not cached_module_is_intact(entry, file_name):
            discard_cache_entry(entry)
        os.rename(tmp, entry)
    except OSError:
        if not cached_module_is_intact(entry, file_name):  # another process's copy wins
            raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return entry / file_name


def import_extension(path: Path, module_name: str):
    """The extension module at `path`, imported once per process. A path whose earlier
    module was discarded as damaged (`forget_module`) is imported from a private copy: the
    dynamic loader and Python would otherwise return the old module for it. An import that
    fails marks the path the same way (the loader may keep the library it opened)."""
    key = str(path.resolve())
    module = _loaded_modules.get(key)
    if module is not None:
        return module
    copy = None
    try:
        source = path
        if key in _stale_paths:
            copy = Path(tempfile.mkdtemp(prefix="gagen-reload-"))
            source = copy / path.name
            shutil.copyfile(path, source)
        spec = importlib.util.spec_from_file_location(module_name, source)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except BaseException:
        _stale_paths.add(key)
        raise
    finally:
        if copy is not None:  # a loaded library needs no file on disk
            shutil.rmtree(copy, ignore_errors=True)
    _loaded_modules[key] = module
    _stale_paths.discard(key)
    return module


def forget_module(path: Path) -> None:
    """This process's import of the module at `path` is no longer to be used (its entry is
    being discarded); a later import there loads the new file (import_extension)."""
    key = str(Path(path).resolve())
    _loaded_modules.pop(key, None)
    _stale_paths.add(key)


