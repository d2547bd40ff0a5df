"""Derive, generate and compile a model into an extension module, kept in the cache.

A build happens in a private temporary folder next to its cache entry and is renamed
into place only when complete, so an interrupted build or two processes building the
same model never leave a half-written module that a later `load` would pick up.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import importlib.util
import os
import shlex
import shutil
import socket
import subprocess
import sysconfig
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from .. import __version__
from ..codegen.config import CodegenConfig
from ..codegen.derivatives import generate_derivatives
from ..codegen.render import (
    CONSTRAINED_DERIVATIVES_FILE,
    c_identifier,
    generate,
    write_sources,
)
from ..errors import BuildError, CompilerNotFoundError, warn_user
from ..model.model import Model
from ..runtime.compiled import CompiledDynamics
from ..symbolic.derivation import derivation_for, derive_equations
from ..symbolic.derivatives import derivative_form, derive_derivatives
from .cache import (  # noqa: F401 (re-exported: the cache's API was here)
    _CHECKSUM_FILE,
    _OWNER_FILE,
    CacheWarning,
    _checksum,
    build_key,
    cached_module_is_intact,
    clean_abandoned_builds,
    compile_flags,
    default_cache_dir,
    discard_cache_entry,
    discard_damaged,
    forget_module,
    generator_digest,
    identity_problem,
    import_extension,
    index_lookup,
    index_record,
    input_key,
    usable_cache_dir,
)


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
    source_key: str = ""  # the KEY the module carries (source_key)


def source_key(model: Model, derivation: str = "auto", config: CodegenConfig | None = None,
               derivatives: bool = False) -> str:
    """Hash of what the generated sources depend on: model, parameter names, the derivation
    used, the generator's code and templates, and the codegen's settings if not the default;
    with `derivatives`, of the model's derivative module (codegen/derivatives.py)."""
    h = hashlib.sha256()
    parts = [model.canonical(), ",".join(model.parameters), __version__, generator_digest(),
             derivation_for(model, derivation)]
    if config is not None and not derivatives:
        config = config.for_main_module()
    if config is not None and config != CodegenConfig():
        parts.append(repr(config))
    if derivatives:
        parts.append("derivatives")
    for part in parts:
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()


def module_name_for(model: Model, key: str | None = None, derivatives: bool = False) -> str:
    """The module's name: the model's identifier and a hash of the model alone (not of the
    generator), so the shipped golden sources keep their names when the generator's code
    changes; `_derivatives` after it for the derivative module. `key` is ignored (earlier
    versions took the source key)."""
    name = f"gagen_{c_identifier(model.name)}_{model_key(model)[:12]}"
    return f"{name}_derivatives" if derivatives else name


def model_key(model: Model) -> str:
    """A hash of the model: its canonical text, parameter names and gagen's version."""
    h = hashlib.sha256()
    for part in (model.canonical(), ",".join(model.parameters), __version__):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()


class Progress:
    """Logs each stage and its time at INFO (logger gagen.building.builder); `verbose` shows
    them on stderr for this build (gagen.diagnostics.showing_progress)."""

    def __init__(self, report: BuildReport, verbose: bool):
        self.report, self.verbose = report, verbose

    def stage(self, name: str, seconds: float, detail: str = "") -> None:
        self.report.stages[name] = seconds
        extra = f"  {detail}" if detail else ""
        self.say(f"{name:<9} {seconds:7.2f} s{extra}")

    def files(self, done: int, total: int) -> None:
        """A compile job (one C file) finished."""
        self.say(f"compiled {done}/{total}")

    def say(self, text: str) -> None:
        # imported here: a cached load never builds, and never pays for importing logging
        import logging

        from ..diagnostics import showing_progress

        with showing_progress(self.verbose):
            logging.getLogger(__name__).info(text)


def generate_sources(model: Model, folder: Path, progress: Progress | None = None,
                     report: BuildReport | None = None, derivation: str = "auto",
                     config: CodegenConfig | None = None, derivatives: bool = False
                     ) -> BuildReport:
    """Derive and generate a model's sources into `folder` (no compilation); `config` is
    the code generator's settings (default: CodegenConfig()); `derivatives`: the sources of
    the model's derivative module instead of its main module."""
    key = source_key(model, derivation, config, derivatives)
    name = module_name_for(model, key, derivatives)
    report = report or BuildReport(model.name, name, folder)
    progress = progress or Progress(report, verbose=False)
    method = derivation_for(model, derivation)
    progress.say(f"deriving the equations ({method})...")
    start = time.perf_counter()
    eqs = derive_equations(model, method)
    if derivatives:
        form = derivative_form(model, (config or CodegenConfig()).derivative_form)
        deq = derive_derivatives(eqs, form=form)
        detail = (f"{model.dof} coordinates, {len(deq.intermediates)} intermediates "
                  f"(equations {eqs.seconds:.2f} s, derivatives {deq.seconds:.2f} s; "
                  f"{form} form)")
    else:
        detail = f"{model.dof} coordinates, {len(eqs.intermediates)} intermediates"
    progress.stage("derive", time.perf_counter() - start, detail)
    progress.say("generating C (one CSE pass over every output)...")
    start = time.perf_counter()
    if derivatives:
        code = generate_derivatives(deq, name, key, source_key(model, derivation, config),
                                    config)
    else:
        code = generate(eqs, name, key, config)
    write_sources(code, folder)
    report.ops_before_cse, report.ops_after_cse = code.ops_before, code.ops_after
    progress.stage("generate", time.perf_counter() - start,
                   f"{code.ops_before} operations before CSE, {code.ops_after} after "
                   f"(CSE {code.cse_seconds:.2f} s)")
    return report


def compiler_command() -> list[str]:
    """The C compiler as a command: $CC if set (and not blank), else Python's own compiler."""
    for candidate in (os.environ.get("CC", ""), sysconfig.get_config_var("CC") or "", "cc"):
        try:
            words = shlex.split(candidate)
        except ValueError:
            words = []
        if words and words[0].strip():
            return words
    return ["cc"]


def check_compiler() -> list[str]:
    """The compiler command, or CompilerNotFoundError saying what to install or use instead."""
    cc = compiler_command()
    if shutil.which(cc[0]) is None:
        raise CompilerNotFoundError(
            f"no C compiler found (looked for '{cc[0]}'); install one (e.g. gcc), or use the "
            "pure-Python backend: gagen.load(model, backend=\"lambdify\")")
    return cc


def _config_words(name: str) -> list[str]:
    return shlex.split(sysconfig.get_config_var(name) or "")


def _env_words(name: str) -> list[str]:
    try:
        return shlex.split(os.environ.get(name, ""))
    except ValueError:
        return []


def _compile_commands(cc: list[str], folder: Path, sources: list[str],
                      flags: list[str]) -> dict[str, list[str]]:
    """One compiler command per C file (largest first, so the biggest overlaps the rest).

    Python's own flags (CFLAGS, CCSHARED) as distutils would use them, then $CFLAGS and
    $CPPFLAGS, then gagen's. The sources include each other with quotes, found next to
    them; "." is not on the include path, so a model header cannot shadow a system
    header (a model named `math`).
    """
    includes = [f"-I{sysconfig.get_paths()['include']}"]
    # Python's -g would make the compiler write debug information for very large functions
    python_flags = [w for w in _config_words("CFLAGS") if w != "-g"]
    base = [*cc, *python_flags, *_config_words("CCSHARED"), *_env_words("CPPFLAGS"),
            *_env_words("CFLAGS"), *includes]

    def size(name: str) -> int:
        path = folder / name
        return path.stat().st_size if path.exists() else 0

    ordered = sorted(set(sources), key=lambda name: (-size(name), name))
    return {source: [*base, "-c", source, "-o", f"{source}.o", *flags] for source in ordered}


def _c_files(folder: Path) -> list[str]:
    """The C files of a build folder that its module compiles: the module's table
    (module.c), the model's kernels (their number grows with the model:
    codegen/segments.py) and gagen's integrator; not the constrained dynamics' derivatives
    (constrained_derivatives.c), which call the derivative module's kernels and are there
    for C programs that link both (the runtime runs the same C through the modules)."""
    return sorted(path.name for path in folder.glob("*.c")
                  if path.name != CONSTRAINED_DERIVATIVES_FILE)


def _link_command(cc: list[str], folder: Path, module_name: str, suffix: str) -> list[str]:
    """The link command as distutils builds it: $LDSHARED, else Python's LDSHARED with its
    compiler replaced by $CC when that is set."""
    ldshared = os.environ.get("LDSHARED", "").strip() or sysconfig.get_config_var("LDSHARED") or ""
    python_cc = sysconfig.get_config_var("CC") or ""
    if os.environ.get("CC", "").strip() and python_cc and ldshared.startswith(python_cc):
        ldshared = shlex.join(cc) + ldshared[len(python_cc):]
    linker = shlex.split(ldshared) or [*cc, "-shared"]
    objects = [f"{source}.o" for source in _c_files(folder)]
    return [*linker, *_env_words("LDFLAGS"), *objects, "-o", f"{module_name}{suffix}", "-lm"]


@dataclass
class Job:
    """A command of the build; `then` is a job that may start once this one succeeded."""

    command: list[str]
    what: str
    then: Job | None = None


def _run_jobs(jobs: list[Job], folder: Path, workers: int = 2, progress=None) -> None:
    """Run jobs in `folder`, `workers` at a time, each as soon as a worker is free (a job's
    `then` first in line once it succeeded). BuildError with the tools' own output; on any
    interruption the tools still running are stopped. `progress(done, total)` is called
    as jobs finish."""
    failures = []
    pending = list(jobs)
    total = len(jobs) + sum(_chain_length(job) for job in jobs)
    done = 0
    running: list[tuple[Job, subprocess.Popen, object]] = []
    with contextlib.ExitStack() as logs:  # each tool's output, read when it ends
        try:
            while pending or running:
                while pending and len(running) < workers and not failures:
                    job = pending.pop(0)
                    log = logs.enter_context(tempfile.TemporaryFile(mode="w+",
                                                                    errors="replace"))
                    running.append((job, subprocess.Popen(job.command, cwd=folder, stdout=log,
                                                          stderr=subprocess.STDOUT), log))
                if not running:
                    break
                finished = [item for item in running if item[1].poll() is not None]
                if not finished:
                    time.sleep(0.02)
                    continue
                for item in finished:
                    running.remove(item)
                    job, proc, log = item
                    log.seek(0)
                    done += 1
                    if proc.returncode != 0:
                        failures.append((job, log.read()))
                    elif job.then is not None:
                        pending.insert(0, job.then)
                    if progress is not None:
                        progress(done, total)
        finally:
            for _, proc, _ in running:  # interrupted: stop the tools still running
                proc.kill()
                proc.wait()
    if failures:
        job = failures[0][0]
        shown = "\n".join(f"$ {' '.join(j.command[:1] + j.command[-6:])}\n{out.strip()}"
                          for j, out in failures)
        lines = shown.splitlines()
        if len(lines) > 60:
            shown = "\n".join(lines[:60] + [f"... ({len(lines) - 60} more lines)"])
        raise BuildError(f"{job.what} failed in {folder}:\n{shown}")


def _chain_length(job: Job) -> int:
    count = 0
    while job.then is not None:
        job, count = job.then, count + 1
    return count


def compile_sources(folder: Path, module_name: str, flags: list[str], verbose: bool,
                    progress=None) -> Path:
    """Compile the C sources in `folder` into the extension module `module_name`; return
    the module's path.

    The compiler (the one Python was built with, or $CC) runs on the C files, as many at a
    time as there are cores, then links the objects. The module is plain C: its kernels
    and their table (module.c), which gagen's runtime (gagen.runtime._native, compiled
    when gagen was installed) calls through, so no Cython runs here. A failure raises
    BuildError with the tool's own messages, never a traceback of gagen's.
    `progress(done, total)` is called as files are compiled.
    """
    cc = check_compiler()
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    compile_jobs = [Job(command, f"compiling {module_name}") for command in
                    _compile_commands(cc, folder, _c_files(folder), flags).values()]
    _run_jobs(compile_jobs, folder, workers=build_workers(), progress=progress)
    _run_jobs([Job(_link_command(cc, folder, module_name, suffix), f"linking {module_name}")],
              folder)
    path = folder / f"{module_name}{suffix}"
    if not path.exists():
        raise BuildError(f"the compiler reported success but {path} is missing")
    for obj in folder.glob("*.o"):
        obj.unlink()
    return path


def build_workers() -> int:
    """How many compilers run at once: $GAGEN_BUILD_JOBS, else the cores this process may use."""
    value = os.environ.get("GAGEN_BUILD_JOBS", "").strip()
    if value.isdigit() and int(value) > 0:
        return int(value)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def build(model: Model, out: Path | None = None, cache_dir: Path | None = None,
          fast_math: bool = False, verbose: bool = False, portable: bool = False,
          derivation: str = "auto", config: CodegenConfig | None = None,
          derivatives: bool = False) -> tuple[Path, BuildReport]:
    """Derive, generate and compile; return the extension's path and what was done.

    With `out`, the sources and the module are written there. Otherwise the cache is used
    (its key covers `config`, the code generator's settings, when not the default):
    an entry whose module matches its stored checksum is reused as it is; a corrupt or
    incomplete one is rebuilt with a CacheWarning. `derivatives`: the model's derivative
    module (codegen/derivatives.py), a module and a cache entry of its own.
    """
    flags = compile_flags(fast_math, portable)
    src_key = source_key(model, derivation, config, derivatives)
    name = module_name_for(model, src_key, derivatives)
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    if out is None:
        cache = usable_cache_dir(Path(cache_dir) if cache_dir else default_cache_dir())
        final = cache / f"{name}-{build_key(src_key, flags)[:16]}"
        if cached_module_is_intact(final, f"{name}{suffix}"):
            return final / f"{name}{suffix}", BuildReport(model.name, name, final, cached=True,
                                                          source_key=src_key)
        if final.exists():
            warn_user(f"gagen: the cache entry {final} is corrupt or incomplete (its module "
                      "does not match its checksum); rebuilding it", CacheWarning)
            forget_module(final / f"{name}{suffix}")
            discard_cache_entry(final)
        clean_abandoned_builds(cache)
    else:
        final = Path(out)
    report = BuildReport(model.name, name, final, source_key=src_key)
    progress = Progress(report, verbose)
    what = "the derivatives of " if derivatives else ""
    progress.say(f"building {what}'{model.name}' ({model.dof} coordinates) into {final}")
    created = _make_parents(final.parent)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=final.parent))
    try:
        (tmp / _OWNER_FILE).write_text(f"{socket.gethostname()} {os.getpid()}\n")
        generate_sources(model, tmp, progress, report, derivation, config, derivatives)
        workers = build_workers()
        progress.say(f"compiling with {' '.join(flags)} (the C compiler, {workers} at a "
                     "time)...")
        start = time.perf_counter()
        module = compile_sources(tmp, name, flags, verbose, progress=progress.files)
        if out is None:  # the cache checks its modules before import; an --out folder is the user's
            (tmp / _CHECKSUM_FILE).write_text(_checksum(module))
        (tmp / _OWNER_FILE).unlink()
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


def shipped_module(model: Model, fast_math: bool, portable: bool = False,
                   derivation: str = "auto"):
    """The module compiled at install time from `generated/`, if it was built from this model
    by this generator (a golden file left behind by a generator change is not used)."""
    if fast_math or portable:
        return None
    try:
        module = importlib.import_module(f"gagen.shipped.{module_name_for(model)}")
    except ImportError:
        return None
    return module if module.KEY == source_key(model, derivation) else None


def load_compiled(model: Model, cache_dir: Path | None = None, fast_math: bool = False,
                  verbose: bool | None = None, portable: bool = False, model_ref=None,
                  input_digest: str | None = None, derivation: str = "auto",
                  derivatives=None) -> CompiledDynamics:
    """The compiled backend of `gagen.load`: shipped module, cached module, or a new build.

    With `input_digest` (gagen.load's key of the input bytes), the module found is recorded
    in the cache's index, so the next load of the same input needs no SymPy. `derivatives`
    finds or builds the derivative module on first use (`CompiledDynamics`); by default
    `load_derivative_module` with these options.
    """
    options = {"cache_dir": cache_dir, "fast_math": fast_math, "portable": portable,
               "verbose": bool(verbose), "derivation": derivation}
    module = shipped_module(model, fast_math, portable, derivation)
    if module is None:
        module = _import_built(model, options)
    _checked_and_recorded(module, source_key(model, derivation), model, cache_dir,
                          input_digest)
    if derivatives is None:
        def derivatives(dyn):
            return load_derivative_module(dyn.model, **options)
    dyn = CompiledDynamics(module, model if model_ref is None else model_ref,
                           derivatives=derivatives)
    dyn.__dict__["_model"] = model
    return dyn


def load_derivative_module(model: Model, cache_dir: Path | None = None, fast_math: bool = False,
                           verbose: bool | None = None, portable: bool = False,
                           derivation: str = "auto", input_digest: str | None = None,
                           config: CodegenConfig | None = None):
    """The derivative module of a model (codegen/derivatives.py): from the cache, or built
    now, showing its progress as `build` does. With `input_digest` (the derivative key of
    gagen.load's input key, `cache.derivatives_input_key`), it is recorded in the cache's
    index, so the next load of the same input finds it without SymPy. `config`: the code
    generator's settings (its derivative module's form, say), as `build` takes them."""
    module = _import_built(model, {"cache_dir": cache_dir, "fast_math": fast_math,
                                   "portable": portable, "verbose": bool(verbose),
                                   "derivation": derivation, "derivatives": True,
                                   "config": config})
    _checked_and_recorded(module, source_key(model, derivation, config, derivatives=True),
                          model, cache_dir, input_digest)
    return module


def _checked_and_recorded(module, key: str, model: Model, cache_dir, input_digest) -> None:
    """BuildError unless `module` was built from these sources; then, with `input_digest`,
    record it in the cache's index."""
    if module.KEY != key:
        raise BuildError(f"module {module.__name__} was not built from this version of "
                         f"model '{model.name}' (its key {module.KEY[:12]}, expected {key[:12]})")
    if input_digest is not None:
        index_record(usable_cache_dir(Path(cache_dir) if cache_dir else default_cache_dir()),
                     input_digest, module)


def _import_built(model: Model, options: dict):
    """Build (or find in the cache) and import a module, checked to be the module of these
    sources (its KEY). A cached module that fails to import for any reason (a library it
    links against changed, another model's module in its place) or proves to be another
    is damaged: it is rebuilt once, with a CacheWarning."""
    path, report = build(model, **options)
    module, problem = _imported(path, report)
    if problem is None:
        return module
    if not report.cached:
        raise BuildError(f"the module just built for '{model.name}' {problem}")
    discard_damaged(path, problem)
    path, report = build(model, **options)
    module, problem = _imported(path, report)
    if problem is not None:
        raise BuildError(f"the module rebuilt for '{model.name}' {problem}")
    return module


def _imported(path: Path, report: BuildReport):
    """(module, None), or (None or the module, why it cannot be used)."""
    try:
        module = import_extension(path, report.module_name)
    except Exception as exc:  # noqa: BLE001 - whatever a damaged library's import raises
        return None, f"does not import ({type(exc).__name__}: {exc})"
    return module, identity_problem(module, report.source_key)
