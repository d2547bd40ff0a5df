"""The shared library of a model's CasADi functions: the wrapper's C (gagen.casadi.generate)
compiled with the model's C kernels and its derivative kernels, into one library that
CasADi loads with `casadi.external` and that C programs link. It needs no Python.

`library(dyn)` finds it in gagen's cache or builds it there (keyed by the model's two
modules and the wrapper's generator); `export(dyn, folder)` writes the sources and the
library into a folder of the user's. `gagen.casadi.functions` loads from `library`, so
Python and C use the same compiled code.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import shutil
import socket
import tempfile
from importlib import resources
from pathlib import Path

import numpy as np

from .. import __version__
from ..building import cache as cache_module
from ..errors import BuildError
from .generate import declared_kernels, generate_casadi, prefix_of

# the main module's and the derivative module's C files that hold their Python entry points
# (the library has none)
_PYTHON_FILES = ("module.c", "derivatives_module.c")
_MODULE_NAME = re.compile(r"(?:.*\.)?gagen_([A-Za-z_][A-Za-z0-9_]*)_[0-9a-f]{12}\Z")


def model_ident(dyn) -> str:
    """The C identifier that names a compiled model's kernels, from its module's name
    (`gagen_<ident>_<hash>`, gagen.building.builder.module_name_for)."""
    match = _MODULE_NAME.match(dyn.module.__name__)
    if match is None:
        raise BuildError(f"cannot tell the C names of module {dyn.module.__name__}")
    return match.group(1)


def library_name(dyn) -> str:
    """The library's file name: lib<ident>_casadi.so (.dylib on macOS)."""
    suffix = ".dylib" if os.uname().sysname == "Darwin" else ".so"
    return f"lib{prefix_of(model_ident(dyn))}{suffix}"


def generator_digest() -> str:
    """A hash of the wrapper's generator: this package's code and templates."""
    h = hashlib.sha256()
    root = resources.files("gagen.casadi")
    for name in ("table.py", "generate.py", "build.py", "templates/casadi.c.j2",
                 "templates/casadi.h.j2"):
        h.update(name.encode())
        h.update(root.joinpath(*name.split("/")).read_bytes())
    return h.hexdigest()


def library_key(dyn, flags: list[str]) -> str:
    """What the library depends on: the model's two modules (their source keys), the
    wrapper's generator, gagen's version and the compiler flags."""
    dyn.load_derivatives()
    h = hashlib.sha256()
    for part in ("gagen-casadi", dyn.module.KEY, dyn.derivative_module.KEY,
                 generator_digest(), __version__, " ".join(flags), os.uname().machine):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()


def parameter_classes(dyn, states: int = 3) -> list[int]:
    """Per parameter, its class (gagen.casadi.table's flags), which picks how the wrapper
    computes its Jacobian columns, told from the compiled model at random states (q, qd,
    qdd all non-zero) by what changes, to the bit, when the parameter alone changes:

    - GRAVITY: the regressor Y changes, affinely, and neither the bodies' placements, the
      frames' offsets nor pi do (the model's gravity, `g`);
    - SIMULATION: `coulomb_width` (FRICTION_WIDTH), when nothing changes with it (only
      simulations use it);
    - BODY, ARMATURE, DRAG (or several): only pi changes, and as a polynomial of degree 4 or
      less (its fifth difference vanishes): the flags of the entries of pi that change
      (a body's ten, armature, damping and friction);
    - KINEMATIC: anything else (the placements change: lengths, angles; or nothing seen to
      change, which costs a few evaluations and is never wrong).
    """
    from ..manifest import FRICTION_WIDTH
    from .table import Param

    names = list(dyn.parameters)
    rng = np.random.default_rng(0)
    n = dyn.nv
    q = dyn.integrate(np.tile(dyn.neutral(), (states, 1)), rng.uniform(-1, 1, (states, n)))
    qd, qdd = rng.uniform(-1, 1, (2, states, n))
    kinds = np.array([Param.ARMATURE if name.startswith("armature_") else
                      Param.DRAG if name.startswith(("damping_", "friction_")) else Param.BODY
                      for name in dyn.regressor_names], dtype=int)

    def seen(p):
        return (np.concatenate([np.ravel(dyn._placements(q, p)), dyn._frame_offsets(p)]),
                dyn.regressor(q, qd, qdd, p), dyn.regressor_parameters(p))

    p0 = dyn.parameter_vector()
    kinematics0, Y0, pi0 = seen(p0)
    classes = []
    for k in range(len(p0)):
        p = p0.copy()
        p[k] = p0[k] * 1.5 + 0.25
        kinematics, Y, pi = seen(p)
        moved = ~np.equal(pi, pi0)
        columns = ~np.equal(Y, Y0).reshape(-1, len(pi0)).all(axis=0)
        if not np.array_equal(kinematics, kinematics0) or (moved.any() and columns.any()):
            classes.append(Param.KINEMATIC)
        elif columns.any():
            classes.append(Param.GRAVITY if _affine(dyn, q, qd, qdd, p0, k)
                           else Param.KINEMATIC)
        elif moved.any() and _pi_degree(dyn, p0, k):
            classes.append(int(np.bitwise_or.reduce(kinds[moved])))
        elif not moved.any() and names[k] == FRICTION_WIDTH:
            classes.append(Param.SIMULATION)
        else:
            classes.append(Param.KINEMATIC)
    return [int(c) for c in classes]


def _affine(dyn, q, qd, qdd, p0, k) -> bool:
    """Whether the regressor is affine in parameter k: its second difference, at steps of
    max(|p_k|, 1), vanishes to rounding."""
    h = max(abs(p0[k]), 1.0)
    Y = [dyn.regressor(q, qd, qdd, _stepped(p0, k, s * h)) for s in (-1, 0, 1)]
    scale = max(float(np.abs(y).max(initial=0.0)) for y in Y)
    return float(np.abs(Y[0] - 2 * Y[1] + Y[2]).max(initial=0.0)) <= 1e-11 * max(scale, 1e-300)


def pi_degrees(dyn, classes: list[int]) -> list[int]:
    """Per parameter of an inertial class, the degree of pi in it (1, 2 or 4: at most), 0
    for the others: which stencil is exact for it (a central difference for degree <= 2,
    the five-point stencil for <= 4; a value quadratic in pi, such as the total mass times
    a centroidal quantity, has twice pi's degree)."""
    from .table import INERTIAL

    p0 = dyn.parameter_vector()
    return [_pi_degree(dyn, p0, k) if c and not c & ~int(INERTIAL) else 0
            for k, c in enumerate(classes)]


def mass_parameters(dyn) -> list[bool]:
    """Per parameter, whether the moving bodies' total mass D changes with it (to the bit):
    the centroidal values' columns by the others need no quotient rule (X = P / D with D
    fixed is a polynomial itself)."""
    masses = [10 * b for b in range(len(dyn.info.moving_bodies))]
    p0 = dyn.parameter_vector()
    total = dyn.regressor_parameters(p0)[masses].sum()
    return [bool(dyn.regressor_parameters(_stepped(p0, k, 0.5 * p0[k] + 0.25))[masses].sum()
                 != total) for k in range(len(p0))]


def _pi_degree(dyn, p0, k) -> int:
    """The least of 1, 2, 4 that pi's degree in parameter k does not exceed (its next
    difference, at the wrapper's stencil's step 0.25 max(|p_k|, 1), vanishes to rounding),
    or 0 if none does."""
    h = 0.25 * max(abs(p0[k]), 1.0)
    pis = {s: dyn.regressor_parameters(_stepped(p0, k, s * h)) for s in range(-3, 3)}
    scale = max(max(float(np.abs(pi).max(initial=0.0)) for pi in pis.values()), 1e-300)
    # the (degree + 1)-th difference over the points first .. first + degree + 1
    for degree, first in ((1, -1), (2, -1), (4, -3)):
        order = degree + 1
        difference = sum(math.comb(order, j) * (-1) ** (order - j) * pis[first + j]
                         for j in range(order + 1))
        if float(np.abs(difference).max(initial=0.0)) <= 1e-10 * scale:
            return degree
    return 0


def _stepped(p0, k, step):
    p = p0.copy()
    p[k] = p0[k] + step
    return p


def write_sources(dyn, folder: Path) -> list[str]:
    """The library's C sources into `folder`: the model's kernels, its derivative kernels
    and the wrapper; returns the C files. The model's sources are copied from its modules'
    build folders (for the module shipped with gagen, generated again and checked against
    its key)."""
    dyn.load_derivatives()
    main, deriv = dyn.module, dyn.derivative_module
    ident = model_ident(dyn)
    files: dict[str, bytes] = {}
    _collect(_sources_of(dyn, main, folder), main.KEY, files)
    _collect(Path(deriv.__file__).parent, deriv.KEY, files)
    headers = [files[name].decode() for name in (f"{ident}.h", f"{ident}_derivatives.h")
               if name in files]
    classes = parameter_classes(dyn)
    generated = generate_casadi(dyn.info, ident, len(dyn.regressor_names), classes,
                                degrees=pi_degrees(dyn, classes),
                                masses=mass_parameters(dyn),
                                kernels=declared_kernels(ident, headers))
    for name, text in generated.items():
        files[name] = text.encode()
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return sorted(name for name in files if name.endswith(".c"))


def _sources_of(dyn, module, scratch: Path) -> Path:
    """The folder of a module's C sources: its build folder, or (the shipped module, whose
    sources are not installed) the sources generated again into a folder of `scratch`."""
    folder = Path(module.__file__).parent
    if (folder / "module.c").is_file():
        return folder
    from ..building.builder import generate_sources

    out = scratch / ".main-sources"
    out.mkdir()
    generate_sources(dyn.model, out)
    return out


def _collect(folder: Path, key: str, files: dict[str, bytes]) -> None:
    """Add a module's .c and .h files (but its Python entry point) to `files`, after
    checking that they are the sources of the module with this key; a file already there
    (a header both modules carry) must be the same."""
    entry = next((folder / name for name in _PYTHON_FILES if (folder / name).is_file()), None)
    if entry is None or f'"{key}"' not in entry.read_text(errors="replace"):
        raise BuildError(f"the sources in {folder} are not those of the compiled module "
                         f"(key {key[:12]}); rebuild the model (gagen.load)")
    for path in sorted(folder.iterdir()):
        if path.suffix not in (".c", ".h") or path.name in _PYTHON_FILES:
            continue
        data = path.read_bytes()
        if files.setdefault(path.name, data) != data:
            raise BuildError(f"{path.name} differs between the model's two modules")


def compile_library(folder: Path, sources: list[str], name: str, flags: list[str]) -> Path:
    """Compile the C files in `folder` into the shared library `name` (symbols hidden but
    those the wrapper exports); BuildError with the compiler's output on failure."""
    from ..building.builder import (
        Job,
        _compile_commands,
        _run_jobs,
        build_workers,
        check_compiler,
    )

    cc = check_compiler()
    compile_flags = [*flags, "-fPIC", "-fvisibility=hidden"]
    jobs = [Job(command, f"compiling {name}") for command in
            _compile_commands(cc, folder, sources, compile_flags).values()]
    _run_jobs(jobs, folder, workers=build_workers())
    objects = [f"{source}.o" for source in sources]
    link = [*cc, "-shared", *objects, "-o", name, "-lm"]
    _run_jobs([Job(link, f"linking {name}")], folder)
    for obj in objects:
        (folder / obj).unlink(missing_ok=True)
    path = folder / name
    if not path.is_file():
        raise BuildError(f"the compiler reported success but {path} is missing")
    return path


def library_functions(path: Path) -> list[str]:
    """The table's functions that a built library holds, from its header (next to it)."""
    from .table import ENTRIES

    prefix = path.name[3:].split(".")[0]
    text = (path.parent / f"{prefix}.h").read_text()
    declared = set(re.findall(r"GAGEN_CASADI_DECLARE\((\w+)\)", text))
    return [e.name for e in ENTRIES if f"{prefix}_{e.name}" in declared]


def library(dyn, cache_dir: Path | None = None, portable: bool = False) -> Path:
    """The path of the CasADi library of a compiled dynamics object, from gagen's cache or
    built into it now (its derivative module too, if it was not built yet)."""
    if getattr(dyn, "backend", None) != "compiled":
        raise TypeError("gagen.casadi needs a compiled model: gagen.load(model) (the "
                        "lambdify backend has no C)")
    flags = cache_module.compile_flags(portable=portable)
    key = library_key(dyn, flags)
    name = library_name(dyn)
    cache = cache_module.usable_cache_dir(
        Path(cache_dir) if cache_dir else cache_module.default_cache_dir())
    final = cache / f"casadi_{model_ident(dyn)}-{key[:16]}"
    if cache_module.cached_module_is_intact(final, name):
        return final / name
    if final.exists():
        cache_module.discard_cache_entry(final)
    tmp = Path(tempfile.mkdtemp(prefix=f".gagen_casadi_{model_ident(dyn)}-", dir=cache))
    try:
        (tmp / cache_module._OWNER_FILE).write_text(f"{socket.gethostname()} {os.getpid()}\n")
        sources = write_sources(dyn, tmp)
        shutil.rmtree(tmp / ".main-sources", ignore_errors=True)
        path = compile_library(tmp, sources, name, flags)
        (tmp / cache_module._CHECKSUM_FILE).write_text(cache_module._checksum(path))
        (tmp / cache_module._OWNER_FILE).unlink()
        try:
            os.rename(tmp, final)
        except OSError:
            if not cache_module.cached_module_is_intact(final, name):
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return final / name


def export(dyn, out: Path, portable: bool = False) -> Path:
    """Write the library's C sources and the compiled library into the folder `out`
    (created if needed; files of the same names replaced); return the library's path.
    Written in a temporary folder first: a failed build leaves `out` as it was."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out} is a file, not a folder: give --out a folder")
    out.mkdir(parents=True, exist_ok=True)
    flags = cache_module.compile_flags(portable=portable)
    tmp = Path(tempfile.mkdtemp(prefix=".gagen-export-", dir=out))
    try:
        sources = write_sources(dyn, tmp)
        shutil.rmtree(tmp / ".main-sources", ignore_errors=True)
        compile_library(tmp, sources, library_name(dyn), flags)
        for item in sorted(tmp.iterdir()):
            os.replace(item, out / item.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out / library_name(dyn)
