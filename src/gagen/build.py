"""Derive, generate and compile a model into an extension module, with an on-disk cache.

A build happens in a private temporary folder next to its cache entry and is renamed
into place only when complete, so an interrupted build or two processes building the
same model never leave a half-written module that a later `load` would pick up.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib
import importlib.util
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from . import __version__
from .codegen import MODEL_C_FILES, c_identifier, generate, templates_digest, write_sources
from .dynamics import DynamicsInfo
from .gibbs_appell import derive
from .model import Model

DEFAULT_FLAGS = ("-O3",)
FAST_MATH_FLAGS = ("-ffast-math",)
# One version of the kernels for any CPU of the architecture: no FMA clone (gagen_math.h)
PORTABLE_FLAGS = ("-DGAGEN_KERNEL=",)
_loaded_modules: dict[str, object] = {}


class BuildError(RuntimeError):
    """Generated code did not compile; the message holds the compiler's output."""


class CompilerNotFoundError(BuildError):
    """No C compiler: the compiled backend cannot be built here."""


@dataclass
class BuildReport:
    """What a build did, stage by stage (seconds) and the operation counts."""

    model: str
    module_name: str
    folder: Path
    stages: dict[str, float] = field(default_factory=dict)
    ops_before_cse: int = 0
    ops_after_cse: int = 0
    cached: bool = False


# The modules whose code decides what the generated sources say.
GENERATOR_MODULES = ("kinematics.py", "gibbs_appell.py", "cse.py", "stage_split.py", "codegen.py")


def generator_digest() -> str:
    """A hash of the generator's own code, so that a changed generator never reuses a build."""
    h = hashlib.sha256()
    folder = resources.files("gagen")
    for name in GENERATOR_MODULES:
        h.update(folder.joinpath(name).read_bytes())
    return h.hexdigest()


def source_key(model: Model) -> str:
    """Hash of what the generated sources depend on: model, parameter names, generator, templates."""
    h = hashlib.sha256()
    for part in (model.canonical(), ",".join(model.parameters), __version__, generator_digest(),
                 templates_digest()):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()


def module_name_for(model: Model, key: str) -> str:
    return f"gagen_{c_identifier(model.name)}_{key[:12]}"


def compile_flags(fast_math: bool = False, portable: bool = False) -> list[str]:
    """The compiler flags: -O3, plus -ffast-math on request, plus no per-CPU kernel clones
    with `portable` (for a module copied to other machines, and to test that version)."""
    return (list(DEFAULT_FLAGS) + (list(FAST_MATH_FLAGS) if fast_math else [])
            + (list(PORTABLE_FLAGS) if portable else []))


def build_key(src_key: str, flags: list[str]) -> str:
    """Hash of the sources plus what the binary depends on: flags, Python ABI, NumPy, Cython."""
    import Cython
    import numpy

    h = hashlib.sha256()
    for part in (src_key, " ".join(flags), sysconfig.get_config_var("EXT_SUFFIX") or "",
                 numpy.__version__, Cython.__version__, sys.version):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()


def default_cache_dir() -> Path:
    """$GAGEN_CACHE_DIR, else the user's cache folder ($XDG_CACHE_HOME or ~/.cache)/gagen."""
    env = os.environ.get("GAGEN_CACHE_DIR")
    if env:
        return Path(env).expanduser()
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / "gagen"
    if os.name == "nt":
        return Path(os.environ.get("LOCALAPPDATA", Path.home())) / "gagen" / "Cache"
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "gagen"


class Progress:
    """Prints each stage and its time when verbose."""

    def __init__(self, report: BuildReport, verbose: bool):
        self.report, self.verbose = report, verbose

    def stage(self, name: str, seconds: float, detail: str = "") -> None:
        self.report.stages[name] = seconds
        if self.verbose:
            extra = f"  {detail}" if detail else ""
            print(f"gagen: {name:<9} {seconds:7.2f} s{extra}", file=sys.stderr, flush=True)

    def say(self, text: str) -> None:
        if self.verbose:
            print(f"gagen: {text}", file=sys.stderr, flush=True)


def generate_sources(model: Model, folder: Path, progress: Progress | None = None,
                     report: BuildReport | None = None) -> BuildReport:
    """Derive and generate a model's sources into `folder` (no compilation)."""
    key = source_key(model)
    name = module_name_for(model, key)
    report = report or BuildReport(model.name, name, folder)
    progress = progress or Progress(report, verbose=False)
    progress.say("deriving the Gibbs-Appell equations...")
    start = time.perf_counter()
    eqs = derive(model)
    progress.stage("derive", time.perf_counter() - start,
                   f"{model.dof} coordinates, {len(eqs.intermediates)} intermediates")
    progress.say("generating C (one CSE pass over every output)...")
    start = time.perf_counter()
    code = generate(eqs, name, key)
    write_sources(code, folder)
    report.ops_before_cse, report.ops_after_cse = code.ops_before, code.ops_after
    progress.stage("generate", time.perf_counter() - start,
                   f"{code.ops_before} operations before CSE, {code.ops_after} after "
                   f"(CSE {code.cse_seconds:.2f} s)")
    return report


def check_compiler() -> None:
    cc = (os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc").split()[0]
    if shutil.which(cc) is None:
        raise CompilerNotFoundError(
            f"no C compiler found (looked for '{cc}'); install one (e.g. gcc), or use the "
            "pure-Python backend: gagen.load(model, backend=\"lambdify\")")


# Runs in a subprocess inside the build folder. Two workers compile the C files (each one gcc
# process), the largest first, so that the biggest kernel file and the Cython wrapper
# overlap; then setuptools links them into one module.
_BUILD_SCRIPT = """
import os, sys, sysconfig, numpy
from concurrent.futures import ThreadPoolExecutor
from distutils.ccompiler import new_compiler
from distutils.sysconfig import customize_compiler
from Cython.Build import cythonize
from setuptools import Extension
name, flags = sys.argv[1], sys.argv[2].split()
# not ".": the sources include each other with quotes (found next to them), and a model
# header on the include path could shadow a system header (a model named `math`)
includes = [numpy.get_include(), sysconfig.get_paths()["include"]]
macros = [("NPY_NO_DEPRECATED_API", "NPY_1_7_API_VERSION")]
cythonize([Extension(name, [name + ".pyx"])], quiet=True, language_level=3)
cc = new_compiler()
customize_compiler(cc)

def compile_all(sources):
    return cc.compile(sources, output_dir="_build", include_dirs=includes, macros=macros,
                      extra_postargs=flags)

sources = sorted([name + ".c"] + sys.argv[3].split(), key=lambda s: -os.path.getsize(s))
with ThreadPoolExecutor(max_workers=2) as pool:
    parts = list(pool.map(compile_all, [[s] for s in sources]))
cc.link_shared_object([o for part in parts for o in part],
                      name + sysconfig.get_config_var("EXT_SUFFIX"), libraries=["m"])
"""


def compile_sources(folder: Path, module_name: str, flags: list[str], verbose: bool) -> Path:
    """Cythonize and compile the sources in `folder` in a subprocess; return the module path."""
    check_compiler()
    proc = subprocess.run([sys.executable, "-c", _BUILD_SCRIPT, module_name, " ".join(flags),
                           " ".join(MODEL_C_FILES)],
                          cwd=folder, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise BuildError(f"compiling {module_name} in {folder} failed:\n{proc.stdout}\n{proc.stderr}")
    if verbose and proc.stderr.strip():
        print(proc.stderr, file=sys.stderr)
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    path = folder / f"{module_name}{suffix}"
    if not path.exists():
        raise BuildError(f"the compiler reported success but {path} is missing:\n{proc.stdout}")
    for scratch in ("_build", "build"):
        shutil.rmtree(folder / scratch, ignore_errors=True)
    return path


def build(model: Model, out: Path | None = None, cache_dir: Path | None = None,
          fast_math: bool = False, verbose: bool = False, portable: bool = False
          ) -> tuple[Path, BuildReport]:
    """Derive, generate and compile; return the extension's path and what was done.

    With `out`, the sources and the module are written there. Otherwise the cache is used:
    an up-to-date entry is reused as it is.
    """
    flags = compile_flags(fast_math, portable)
    src_key = source_key(model)
    name = module_name_for(model, src_key)
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    if out is None:
        cache = Path(cache_dir) if cache_dir else default_cache_dir()
        final = cache / f"{name}-{build_key(src_key, flags)[:16]}"
        if (final / f"{name}{suffix}").exists():
            report = BuildReport(model.name, name, final, cached=True)
            return final / f"{name}{suffix}", report
    else:
        final = Path(out)
    report = BuildReport(model.name, name, final)
    progress = Progress(report, verbose)
    progress.say(f"building '{model.name}' ({model.dof} coordinates) into {final}")
    created = _make_parents(final.parent)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=final.parent))
    try:
        generate_sources(model, tmp, progress, report)
        progress.say(f"compiling with {' '.join(flags)} (Cython and the C compiler, "
                     "usually 5-15 s)...")
        start = time.perf_counter()
        compile_sources(tmp, name, flags, verbose)
        progress.stage("compile", time.perf_counter() - start, " ".join(flags))
        _publish(tmp, final, replace=out is not None)
        created = []
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        for folder in reversed(created):  # a failed build leaves no new folders behind
            with contextlib.suppress(OSError):
                folder.rmdir()
    return final / f"{name}{suffix}", report


def _make_parents(folder: Path) -> list[Path]:
    """Create a folder and its missing parents; return those created, outermost first."""
    missing = []
    while not folder.exists():
        missing.append(folder)
        folder = folder.parent
    for path in reversed(missing):
        path.mkdir(exist_ok=True)
    return list(reversed(missing))


def _publish(tmp: Path, final: Path, replace: bool) -> None:
    """Move a finished build into place in one rename."""
    if replace and final.exists():
        for item in tmp.iterdir():
            os.replace(item, final / item.name)
        return
    try:
        os.rename(tmp, final)
    except OSError:
        if not (final.exists() and any(final.iterdir())):
            raise
        # another process finished the same build first: keep theirs


def import_extension(path: Path, module_name: str):
    key = str(path.resolve())
    module = _loaded_modules.get(key)
    if module is None:
        spec = importlib.util.spec_from_file_location(module_name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        _loaded_modules[key] = module
    return module


def shipped_module(model: Model, fast_math: bool, portable: bool = False):
    """The module compiled at install time from `generated/`, if it matches this model."""
    if fast_math or portable:
        return None
    name = module_name_for(model, source_key(model))
    try:
        return importlib.import_module(f"gagen.shipped.{name}")
    except ImportError:
        return None


@functools.cache
def dynamics_class(module):
    """The user-facing class: the compiled kernels plus the shared names and parameters."""
    return type("CompiledDynamics", (module.CompiledModel, DynamicsInfo),
                {"backend": "compiled", "__module__": "gagen.build"})


def load_compiled(model: Model, cache_dir: Path | None = None, fast_math: bool = False,
                  verbose: bool | None = None, portable: bool = False):
    """The compiled backend of `gagen.load`: shipped module, cached module, or a new build."""
    key = source_key(model)
    module = shipped_module(model, fast_math, portable)
    if module is None:
        path, report = build(model, cache_dir=cache_dir, fast_math=fast_math,
                             verbose=True if verbose is None else verbose, portable=portable)
        module = import_extension(path, report.module_name)
    if module.KEY != key:
        raise BuildError(f"module {module.__name__} was not built from this version of "
                         f"model '{model.name}' (its key {module.KEY[:12]}, expected {key[:12]})")
    dyn = dynamics_class(module)()
    dyn.model = model
    dyn.module = module
    return dyn
