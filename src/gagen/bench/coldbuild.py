"""A cold build in a fresh process, measured from outside: wall time, stage times and the
peak memory of the whole process tree (Python and the compilers running at once).

`python -m gagen.bench.coldbuild MODEL CACHE_DIR [--derivatives] [--floating-base]
[--derivative-form=FORM]` builds one model (or its derivative module, in a given form)
into a cache folder and prints one JSON line: the build report (stages, operation counts,
module path). The
benchmark runs it as a subprocess through `measured_build`, which samples the resident
memory of the subprocess and all its descendants every 20 ms (Linux's /proc; elsewhere the
largest single process, from the OS's own accounting).
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import threading
import time
from pathlib import Path


def measured_build(name: str, cache_dir: Path, timeout: float = 1800.0,
                   derivatives: bool = False, floating_base: bool = False,
                   derivative_form: str | None = None) -> dict:
    """Build `name` (its derivative module with `derivatives`, in `derivative_form` if
    given; a URDF on a floating base with `floating_base`) cold in a fresh Python process;
    its report plus `wall_s`, `peak_mb`."""
    command = [sys.executable, "-m", "gagen.bench.coldbuild", str(name), str(cache_dir)]
    command += ["--derivatives"] if derivatives else []
    command += ["--floating-base"] if floating_base else []
    command += [f"--derivative-form={derivative_form}"] if derivative_form else []
    start = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    sampler = _TreeMemory(proc.pid)
    sampler.start()
    try:
        out, err = proc.communicate(timeout=timeout)
    finally:
        sampler.stop()
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(f"building {name} failed:\n{err.strip()[-2000:]}")
    report = json.loads(out.strip().splitlines()[-1])
    peak = sampler.peak_bytes or resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
    return {**report, "wall_s": wall, "peak_mb": peak / 2**20}


class _TreeMemory(threading.Thread):
    """Samples the summed resident memory of a process and its descendants."""

    def __init__(self, pid: int, interval: float = 0.02):
        super().__init__(daemon=True)
        self.pid, self.interval = pid, interval
        self.peak_bytes = 0
        self._done = threading.Event()

    def stop(self) -> None:
        self._done.set()
        self.join()

    def run(self) -> None:
        if not Path("/proc").is_dir():
            return
        page = os.sysconf("SC_PAGE_SIZE")
        while not self._done.is_set():
            self.peak_bytes = max(self.peak_bytes, _tree_pages(self.pid) * page)
            self._done.wait(self.interval)


def _tree_pages(root: int) -> int:
    """Resident pages of `root` and every process descending from it."""
    parents: dict[int, int] = {}
    pages: dict[int, int] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat") as fh:
                stat = fh.read()
            with open(f"/proc/{entry.name}/statm") as fh:
                resident = int(fh.read().split()[1])
        except (OSError, ValueError, IndexError):
            continue
        fields = stat[stat.rfind(")") + 2:].split()  # after the command name
        parents[int(entry.name)] = int(fields[1])
        pages[int(entry.name)] = resident
    tree, frontier = {root}, [root]
    while frontier:
        parent = frontier.pop()
        children = [pid for pid, ppid in parents.items() if ppid == parent and pid not in tree]
        tree.update(children)
        frontier.extend(children)
    return sum(pages.get(pid, 0) for pid in tree)


def main(argv: list[str] | None = None) -> int:
    from sympy.core.cache import clear_cache

    from ..building.builder import build
    from ..codegen.config import CodegenConfig
    from ..model.resolve import resolve_model

    args = argv or sys.argv[1:]
    name, cache_dir = args[:2]
    forms = [a.split("=", 1)[1] for a in args if a.startswith("--derivative-form=")]
    config = CodegenConfig(derivative_form=forms[0]) if forms else None
    clear_cache()
    model = resolve_model(name, floating_base="--floating-base" in args)
    path, report = build(model, cache_dir=Path(cache_dir), derivatives="--derivatives" in args,
                         config=config)
    print(json.dumps({"model": model.name, "dof": model.dof, "stages": report.stages,
                      "ops_before_cse": report.ops_before_cse,
                      "ops_after_cse": report.ops_after_cse, "cached": report.cached,
                      "module": str(path), "module_name": report.module_name}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
