"""What every benchmark section shares: the machine, the URDFs, cold builds, progress."""

from __future__ import annotations

import datetime
import os
import platform
import shutil
import subprocess
import sys
import sysconfig
import time
from importlib import metadata
from pathlib import Path

import numpy as np

URDF_ENV = "GAGEN_URDF_DIR"
UR5 = "ur5_robot.urdf"
PANDA = "panda.urdf"


# ----------------------------------------------------------------------------- machine


def cpu_model() -> str:
    """The CPU's name from /proc/cpuinfo (Linux), else platform.processor()."""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                if key.strip() in ("model name", "Hardware", "cpu model") and value.strip():
                    return value.strip()
    except OSError:
        pass
    if sys.platform == "darwin":
        try:
            out = subprocess.run(["sysctl", "-n", "machdep.cpu.brand_string"],
                                 capture_output=True, text=True, timeout=5, check=False)
            if out.stdout.strip():
                return out.stdout.strip()
        except (OSError, subprocess.SubprocessError):
            pass
    return platform.processor() or platform.machine() or "unknown"


def usable_cores() -> int | None:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count()


def compiler_version() -> str:
    """First line of `<CC> --version` (the compiler the compiled backend uses)."""
    cc = (os.environ.get("CC") or sysconfig.get_config_var("CC") or "gcc").split()[0]
    for candidate in (cc, "gcc"):
        if shutil.which(candidate) is None:
            continue
        try:
            out = subprocess.run([candidate, "--version"], capture_output=True, text=True,
                                 timeout=10, check=False)
        except (OSError, subprocess.SubprocessError):
            continue
        first = out.stdout.strip().splitlines()
        if first:
            return first[0]
    return "not found"


def version_of(distribution: str, module: str | None = None) -> str | None:
    """Installed version of a package, None if it is missing."""
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        pass
    if module:
        try:
            mod = __import__(module)
        except ImportError:
            return None
        return getattr(mod, "__version__", "unknown")
    return None


def machine_info() -> dict:
    """What the report's header says about the machine and the software."""
    from .. import __version__

    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "usable_cores": usable_cores(),
        "machine": platform.machine(),
        "system": f"{platform.system()} {platform.release()}",
        "python": f"{platform.python_version()} ({platform.python_implementation()})",
        "numpy": version_of("numpy"),
        "scipy": version_of("scipy"),
        "sympy": version_of("sympy"),
        "cython": version_of("Cython", "Cython"),
        "compiler": compiler_version(),
        "gagen": __version__,
        "pinocchio": version_of("pin", "pinocchio"),
        "pydy": version_of("pydy", "pydy"),
        "mujoco": version_of("mujoco"),
        "dask": version_of("distributed"),
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
    }


# ------------------------------------------------------------------------------ models


def repo_root() -> Path | None:
    """The source checkout gagen runs from (src layout), if it runs from one."""
    here = Path(__file__).resolve()
    root = here.parents[3]  # src/gagen/bench/common.py -> the repository
    return root if (root / "pyproject.toml").exists() else None


def find_urdf_dir(urdf_dir: str | Path | None = None, needed: str = UR5) -> Path | None:
    """The folder holding the benchmark URDFs (UR5, Panda), or None if there is none.

    Looked for, in order: `urdf_dir` (--urdf-dir), $GAGEN_URDF_DIR, then `../shared/urdf`
    next to the repository root (the checkout gagen runs from, and the current folder).
    """
    if urdf_dir is not None:
        path = Path(urdf_dir).expanduser()
        return path if (path / needed).exists() else None
    candidates = []
    if os.environ.get(URDF_ENV):
        candidates.append(Path(os.environ[URDF_ENV]).expanduser())
    roots = [r for r in (repo_root(), Path.cwd()) if r is not None]
    candidates += [root.parent / "shared" / "urdf" for root in roots]
    candidates += [root / "shared" / "urdf" for root in roots]
    for path in candidates:
        if (path / needed).exists():
            return path
    return None


def fixed_state(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A reproducible, generic (q, qd, tau-or-qdd) of size n: no zeros to take shortcuts."""
    rng = np.random.default_rng(seed)
    return (rng.uniform(-1.0, 1.0, n) * 0.8, rng.normal(size=n), rng.normal(scale=2.0, size=n))


def compiled(model, cache_dir: Path, verbose: bool = False):
    """Build a model into `cache_dir` (cold if the folder is new) and load that module.

    Returns (dyn, report, {"build_s", "load_s"}). Unlike `gagen.load`, never picks a
    module shipped with the package: the module timed is the one just built (and its
    derivative module is built into the same folder on first use).
    """
    from ..building.builder import build, import_extension, load_derivative_module
    from ..runtime.compiled import CompiledDynamics

    start = time.perf_counter()
    path, report = build(model, cache_dir=cache_dir, verbose=verbose)
    build_s = time.perf_counter() - start
    start = time.perf_counter()
    module = import_extension(path, report.module_name)
    dyn = CompiledDynamics(module, model, derivatives=lambda _: load_derivative_module(
        model, cache_dir=cache_dir, verbose=verbose))
    dyn.__dict__["_model"] = model
    return dyn, report, {"build_s": build_s, "load_s": time.perf_counter() - start}


def optional(module: str):
    """Import an optional peer library, None if it is not installed (or fails to import)."""
    try:
        return __import__(module)
    except Exception:  # noqa: BLE001 - a broken optional install counts as missing
        return None


# ----------------------------------------------------------------------------- progress


class Progress:
    """Prints `[elapsed] section: text` lines, flushed, so a long run shows where it is."""

    def __init__(self, stream=None, quiet: bool = False):
        self.start = time.perf_counter()
        self.stream = stream
        self.quiet = quiet

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.start

    def __call__(self, section: str, text: str) -> None:
        if self.quiet:
            return
        print(f"[{self.elapsed:7.1f} s] {section}: {text}", file=self.stream or sys.stdout,
              flush=True)
