"""simulate_batch(..., client=) on a Dask LocalCluster of two worker processes: the same
numbers as the local run, in order, also for a floating base (nq != nv); the module
reaches each worker once; a chunk that fails once is retried, and one that keeps failing
costs only its own runs; two workers installing the same module keep the first copy."""

from __future__ import annotations

import hashlib
import os
import sysconfig
from pathlib import Path

import numpy as np
import pytest
from distributed import Client, LocalCluster

import gagen
from gagen.building.cache import install_received_module
from gagen.sim.batch import STATUS_CHUNK_FAILED

URDF = Path(__file__).resolve().parent / "data" / "urdf"

N = 10
RNG = np.random.default_rng(4)
Q0 = RNG.uniform(-0.3, 0.3, (N, 3))
P = {"m3": RNG.uniform(40.0, 60.0, N), "m1": 55.0}
CONTROLLERS = [gagen.PD(kp=RNG.uniform(200, 400, 3), kd=150.0, target=[-1.0, -1.0, -0.5],
                        gravity_compensation=True) for _ in range(N)]
SPAN = (0.0, 1.0)


@pytest.fixture(scope="module")
def client(cache_dir):
    # the workers inherit GAGEN_CACHE_DIR: they keep received modules in the test cache
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as c:
        yield c


@pytest.fixture(scope="module")
def rrr():
    return gagen.load("rrr")


@pytest.fixture(scope="module")
def local(rrr):
    return gagen.simulate_batch(rrr, SPAN, Q0, None, CONTROLLERS, p=P, threads=2)


def _worker_loads(client):
    def loads():
        from gagen.sim import distributed

        return distributed.loads

    return client.run(loads)


def assert_same(a, b, rows=slice(None)):
    for name in ("q", "qd", "tau", "status", "nfev", "steps", "rejected"):
        assert np.array_equal(getattr(a, name)[rows], getattr(b, name)[rows]), name


def test_results_are_identical_to_the_local_run_and_in_order(client, rrr, local, cache_dir):
    seen = []
    res = gagen.simulate_batch(rrr, SPAN, Q0, None, CONTROLLERS, p=P, client=client,
                               chunk_size=3, progress=lambda d, t: seen.append(d))
    assert res.stats["chunks"] == 4 and seen[-1] == N
    assert_same(res, local)
    assert res.message == local.message
    again = gagen.simulate_batch(rrr, SPAN, Q0[::-1], None, CONTROLLERS, p=P, client=client,
                                 chunk_size=2)
    assert again.ok.all(), again.message[0]
    assert not np.array_equal(again.q[0], res.q[0])
    # each worker process imported the module once, whatever the number of chunks
    assert sorted(_worker_loads(client).values()) == [1, 1]
    assert any((cache_dir / "received").iterdir())


def test_a_floating_base_gives_the_local_run_s_numbers(client):
    """q has nq = nv + 1 entries (the base's quaternion): the cluster's results have the
    shapes and the very numbers of the threads' run."""
    dyn = gagen.load(URDF / "double_pendulum.urdf", floating_base=True)
    assert dyn.nq == dyn.nv + 1
    rng = np.random.default_rng(7)
    q0 = np.tile(dyn.neutral(), (6, 1))
    quaternions = rng.normal(size=(6, 4))
    q0[:, 3:7] = quaternions / np.linalg.norm(quaternions, axis=1, keepdims=True)
    q0[:, 7:] = rng.uniform(-1, 1, (6, dyn.nq - 7))
    v0 = rng.normal(size=(6, dyn.nv))
    for method, options in (("dopri5", {}), ("rk4", {"h": 1e-3})):
        local = gagen.simulate_batch(dyn, (0.0, 0.5), q0, v0, method=method, threads=2,
                                     **options)
        res = gagen.simulate_batch(dyn, (0.0, 0.5), q0, v0, method=method, client=client,
                                   chunk_size=2, **options)
        assert res.q.shape == (6, local.t.size, dyn.nq) and res.qd.shape[-1] == dyn.nv
        assert local.ok.all() and res.stats["chunks"] == 3
        assert_same(res, local)


def test_a_second_install_of_a_received_module_keeps_the_first(tmp_path, monkeypatch):
    """Two workers of one machine receive the same module at once: the second finds the
    first's copy only after writing its own, and must not discard it (the first may be
    importing it: 'cannot open shared object file')."""
    from gagen.building import cache

    data = b"not really a module"
    sha = hashlib.sha256(data).hexdigest()
    name = "gagen_x" + sysconfig.get_config_var("EXT_SUFFIX")
    first = install_received_module(tmp_path, name, data, sha)
    inode = first.stat().st_ino
    looks = []

    def late(entry, module_file, real=cache.cached_module_is_intact):
        looks.append(entry)  # the second's first look: the first's copy is not there yet
        return len(looks) > 1 and real(entry, module_file)

    monkeypatch.setattr(cache, "cached_module_is_intact", late)
    second = install_received_module(tmp_path, name, data, sha)
    assert second == first and second.stat().st_ino == inode


def test_default_chunks_and_rk4(client, rrr):
    ctrl = gagen.paper_controller()
    res = gagen.simulate_batch(rrr, SPAN, Q0, None, ctrl, method="rk4", h=2e-3, client=client)
    ref = gagen.simulate_batch(rrr, SPAN, Q0, None, ctrl, method="rk4", h=2e-3)
    assert res.stats["chunks"] == 5  # 4 per worker thread, 2 threads: ceil(10 / 8) = 2 runs each
    assert_same(res, ref)


def _install_faults(client, marker: Path, transient: int, permanent: int):
    """Make the workers' chunk starting at run `transient` fail on its first attempt (one
    attempt in the whole cluster: O_EXCL), and the one at `permanent` fail every time;
    each attempt at either is logged in `marker`.log."""
    def install():
        from gagen.sim import distributed

        original = distributed.__dict__.setdefault("_original_run_plan", distributed.run_plan)

        def faulty(dyn, plan, threads=1, progress=None):
            if plan.offset in (transient, permanent):
                with open(f"{marker}.log", "a") as log:
                    log.write(f"{plan.offset}\n")
            if plan.offset == permanent:
                raise RuntimeError("injected fault that stays")
            if plan.offset == transient:
                try:
                    os.close(os.open(marker, os.O_CREAT | os.O_EXCL))
                    raise RuntimeError("injected fault, once")
                except FileExistsError:
                    pass
            return original(dyn, plan, threads, progress)

        distributed.run_plan = faulty

    def uninstall():
        from gagen.sim import distributed

        distributed.run_plan = distributed.__dict__.pop("_original_run_plan",
                                                        distributed.run_plan)

    client.run(install)
    return lambda: client.run(uninstall)


def test_a_failing_chunk_is_retried_and_a_lost_one_costs_only_its_runs(client, rrr, local,
                                                                      tmp_path):
    marker = tmp_path / "fault"
    uninstall = _install_faults(client, marker, transient=3, permanent=6)
    try:
        res = gagen.simulate_batch(rrr, SPAN, Q0, None, CONTROLLERS, p=P, client=client,
                                   chunk_size=3, retries=2)
    finally:
        uninstall()
    attempts = Path(f"{marker}.log").read_text().split()
    assert attempts.count("3") == 2 and attempts.count("6") == 3  # retried; 1 + 2 retries
    lost = [6, 7, 8]
    kept = [i for i in range(N) if i not in lost]
    assert_same(res, local, kept)
    assert (res.status[lost] == STATUS_CHUNK_FAILED).all() and np.isnan(res.q[lost]).all()
    assert all("injected fault that stays" in res.message[i] and "runs 6 to 8" in res.message[i]
               for i in lost)
    assert res.stats["failed"] == 3


def test_the_sweep_command_runs_on_a_scheduler_address(client, tmp_path, cache_dir, capsys):
    from gagen.app.cli import main

    address = client.scheduler.address
    out = tmp_path / "mc.npz"
    assert main(["sweep", "rrr", "--runs", "6", "--vary", "m3=40:60", "--duration", "0.5",
                 "--points", "11", "--no-plot", "--scheduler", address, "--out", str(out),
                 "--cache-dir", str(cache_dir)]) == 0
    assert "6 runs in" in capsys.readouterr().out
    local = tmp_path / "local.npz"
    assert main(["-q", "sweep", "rrr", "--runs", "6", "--vary", "m3=40:60", "--duration",
                 "0.5", "--points", "11", "--no-plot", "--out", str(local)]) == 0
    with np.load(out) as a, np.load(local) as b:
        for name in ("q", "qd", "tau", "p", "status"):
            assert np.array_equal(a[name], b[name]), name
