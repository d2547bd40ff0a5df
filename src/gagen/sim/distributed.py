"""`simulate_batch(..., client=...)`: chunks of runs as tasks on a Dask cluster.

Dask is optional (`pip install gagen[dask]`); only this module imports it, and only when a
client is given.

How the compiled module reaches a worker, which may be another machine: the client sends
the module's bytes with their SHA-256 (`ModulePayload`), scattered once to the workers;
Dask keeps the payload in each worker's memory and hands the same object to every chunk.
A worker checks the hash and that the module fits its platform, stores it in its own cache
under `received/<sha256>` (written and verified like a build, so a restarted worker reuses
it) and imports it once per process (`worker_dynamics` keeps it): a chunk never rebuilds
or reimports. The alternative, rebuilding from the model's source on each worker, would
need SymPy, a C compiler and the model file on every worker and take seconds to minutes
per worker; and the bytes sent are the very module that ran on the client, so the workers
compute with the same code. Its cost is that the workers must run the client's Python
version on the same platform (checked, with a clear message), as Dask itself recommends.
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .batch import STATUS, STATUS_CHUNK_FAILED, BatchPlan, Progress, blocks, run_plan

# Chunks per worker thread by default: enough to balance uneven runs and to keep losses
# small when a chunk fails, few enough that Dask's per-task overhead stays small.
CHUNKS_PER_THREAD = 4
MAX_CHUNK_RUNS = 10_000


@dataclass(frozen=True)
class ModulePayload:
    """A compiled module as the client sends it: its bytes and their SHA-256."""

    module_name: str  # the name its init function carries
    file_name: str
    sha256: str
    data: bytes = field(repr=False)

    @classmethod
    def of(cls, dyn) -> ModulePayload:
        path = Path(dyn.module.__file__)
        data = path.read_bytes()
        return cls(dyn.module.__name__.rsplit(".", 1)[-1], path.name,
                   hashlib.sha256(data).hexdigest(), data)


_received: dict[str, object] = {}  # sha256 -> CompiledDynamics, in this worker process
_received_lock = threading.Lock()  # a worker's threads may start chunks at the same time
loads = 0  # modules imported by this process from payloads (the tests count them)


def worker_dynamics(payload: ModulePayload):
    """The dynamics of a payload's module in this process: installed in the cache and
    imported on first use, then kept."""
    global loads
    with _received_lock:
        dyn = _received.get(payload.sha256)
        if dyn is None:
            from ..building.cache import (
                default_cache_dir,
                import_extension,
                install_received_module,
                usable_cache_dir,
            )
            from ..runtime.compiled import CompiledDynamics

            path = install_received_module(usable_cache_dir(default_cache_dir()),
                                           payload.file_name, payload.data, payload.sha256)
            dyn = CompiledDynamics(import_extension(path, payload.module_name))
            _received[payload.sha256] = dyn
            loads += 1
    return dyn


def run_chunk(payload: ModulePayload, plan: BatchPlan):
    """A Dask task: the runs of one chunk on this worker, in one thread (a worker's threads
    run chunks side by side). Returns (q, qd, tau, stats) of the chunk."""
    return run_plan(worker_dynamics(payload), plan, threads=1)


def default_chunk_size(client, runs: int) -> int:
    """About CHUNKS_PER_THREAD chunks per worker thread of the cluster."""
    threads = max(1, sum(client.nthreads().values()))
    return max(1, min(MAX_CHUNK_RUNS, -(-runs // (CHUNKS_PER_THREAD * threads))))


def run_on_cluster(client, dyn, plan: BatchPlan, chunk_size: int | None = None,
                   retries: int = 2, progress: Progress | None = None):
    """Run a plan on a Dask cluster: (q, qd, tau, stats, failures, chunks), in run order.

    A chunk whose task still fails after `retries` retries gives its runs the status
    STATUS_CHUNK_FAILED and a message naming the error (`failures`); NaN samples."""
    from distributed import as_completed

    size = default_chunk_size(client, plan.runs) if chunk_size is None else int(chunk_size)
    if size < 1:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    # q has nq entries, qd and tau nv: they differ where a joint floats (a quaternion)
    runs, m, nq, nv = plan.runs, plan.settings.t_eval.size, dyn.nq, dyn.nv
    q = np.empty((runs, m, nq))
    qd, tau = (np.empty((runs, m, nv)) for _ in range(2))
    stats = np.zeros((runs, 5), np.int64)
    failures: dict[int, str] = {}
    # a key of its own per batch (hash=False): a content-hashed key could be the one a
    # previous batch is just releasing, and its chunks would find the data gone
    remote = client.scatter(ModulePayload.of(dyn), broadcast=True, hash=False)
    spans = blocks(runs, size)
    futures = {client.submit(run_chunk, remote, plan.rows(a, b), retries=retries, pure=False):
               (a, b) for a, b in spans}
    done = 0
    try:
        for future in as_completed(list(futures)):
            a, b = futures[future]
            if future.status == "finished":
                q[a:b], qd[a:b], tau[a:b], stats[a:b] = future.result()
            else:
                exc = (future.exception() if future.status == "error"
                       else RuntimeError(f"the task was {future.status}"))
                _chunk_failed(exc, a, b, retries, (q, qd, tau), stats, failures)
            future.release()
            done += b - a
            if progress is not None:
                progress(done, runs)
    except BaseException:
        client.cancel(list(futures))
        raise
    return q, qd, tau, stats, failures, len(spans)


def _chunk_failed(exc, a: int, b: int, retries: int, arrays, stats, failures) -> None:
    for arr in arrays:
        arr[a:b] = np.nan
    stats[a:b] = 0
    stats[a:b, STATUS] = STATUS_CHUNK_FAILED
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    message = (f"the Dask task of runs {a} to {b - 1} failed on its worker, also after "
               f"{retries} retries: {text}")
    failures.update(dict.fromkeys(range(a, b), message))
