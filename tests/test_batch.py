"""gagen.simulate_batch (issue 17): every run gives exactly gagen.simulate's numbers, runs
fail alone, inputs are checked as simulate checks them, Ctrl-C stops every thread, and
importing it needs no Dask. The Dask cluster's tests are in test_batch_dask.py."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from interrupting import seconds_to_stop

import gagen
from gagen import ComputedTorque, Eq11Trajectory
from gagen.building.cache import cached_module_is_intact, install_received_module
from gagen.runtime import _native
from gagen.sim.distributed import ModulePayload

N = 6
RNG = np.random.default_rng(17)
Q0 = RNG.uniform(-0.4, 0.4, (N, 3))
QD0 = RNG.uniform(-0.5, 0.5, (N, 3))
M3 = RNG.uniform(40.0, 60.0, N)
TARGETS = RNG.uniform(-1.0, 0.0, (N, 3))
KP = RNG.uniform(150.0, 500.0, (N, 3))

CONTROLLERS = {
    "none": None,
    "pd": gagen.PD(kp=300.0, kd=[100.0, 80.0, 60.0], target=[-0.5, -0.4, 0.2]),
    "pd+gravity": gagen.paper_controller(),
    "computed-torque": ComputedTorque(Eq11Trajectory.paper(), kp=100.0, kd=20.0),
}


@pytest.fixture(scope="module")
def rrr():
    return gagen.load("rrr")


def _per_run_p(p, i):
    if isinstance(p, dict):
        return {k: (v[i] if np.ndim(v) == 1 else v) for k, v in p.items()}
    return p[i] if p is not None and np.ndim(p) == 2 else p


def assert_identical_to_simulate(dyn, res, span, q0, qd0, controllers, p, method, **options):
    """Run i of `res` against gagen.simulate with the inputs of run i, bit for bit."""
    for i in range(len(res)):
        ctrl = controllers[i] if isinstance(controllers, list) else controllers
        one = gagen.simulate(dyn, span, q0[i] if np.ndim(q0) == 2 else q0,
                             qd0[i] if np.ndim(qd0) == 2 else qd0, ctrl, method=method,
                             p=_per_run_p(p, i), **options)
        assert res.status[i] == 0 and res.message[i] == one.stats["message"]
        assert np.array_equal(res.t, one.t)
        for name in ("q", "qd", "tau"):
            assert np.array_equal(getattr(res, name)[i], getattr(one, name)), (name, i)
        assert res.nfev[i] == one.stats["nfev"] and res.steps[i] == one.stats["steps"]
        if method == "dopri5":
            assert res.rejected[i] == one.stats["rejected"]


@pytest.mark.parametrize("method", ["dopri5", "rk4"])
@pytest.mark.parametrize("name", list(CONTROLLERS))
def test_each_run_is_bit_identical_to_simulate(rrr, method, name):
    options = {"h": 2e-3} if method == "rk4" else {}
    p = {"m3": M3, "L2": 0.45}
    res = gagen.simulate_batch(rrr, (0.0, 1.5), Q0, QD0, CONTROLLERS[name], p=p,
                               method=method, threads=2, **options)
    assert res.q.shape == res.qd.shape == res.tau.shape == (N, 501, 3)
    assert_identical_to_simulate(rrr, res, (0.0, 1.5), Q0, QD0, CONTROLLERS[name], p, method,
                                 **options)


@pytest.mark.parametrize("method", ["dopri5", "rk4"])
def test_per_run_gains_targets_and_parameter_rows(rrr, method):
    controllers = [gagen.PD(kp=KP[i], kd=100.0, target=TARGETS[i],
                            gravity_compensation=bool(i % 2)) for i in range(N - 1)]
    controllers.append(ComputedTorque(Eq11Trajectory(np.zeros(3), TARGETS[-1], 1.0), kp=50.0))
    table = np.tile(rrr.parameter_vector(), (N, 1))
    table[:, list(rrr.parameters).index("m2")] = RNG.uniform(40.0, 60.0, N)
    options = {"h": 1e-3} if method == "rk4" else {}
    te = np.linspace(0.0, 1.0, 37)
    res = gagen.simulate_batch(rrr, (0.0, 1.0), np.zeros(3), QD0, controllers, p=table,
                               method=method, t_eval=te, threads=2, rtol=1e-7, atol=1e-9,
                               **options)
    assert res.q.shape == (N, 37, 3)
    assert_identical_to_simulate(rrr, res, (0.0, 1.0), np.zeros(3), QD0, controllers, table,
                                 method, t_eval=te, rtol=1e-7, atol=1e-9, **options)


def test_another_model_and_one_shared_state(cache_dir):
    dyn = gagen.load("chain:3")
    ctrl = gagen.PD(kp=40.0, kd=12.0, target=0.3, gravity_compensation=True)
    p = {"m2": np.linspace(0.5, 2.0, 4)}
    res = gagen.simulate_batch(dyn, (0.0, 2.0), [0.1, -0.2, 0.3], None, ctrl, p=p, threads=3)
    assert len(res) == 4 and res.ok.all()
    assert_identical_to_simulate(dyn, res, (0.0, 2.0), np.array([0.1, -0.2, 0.3]), None, ctrl,
                                 p, "dopri5")
    assert not np.array_equal(res.q[0], res.q[-1])  # the masses did change the runs


def test_threads_do_not_change_the_numbers_and_arrays_are_fresh(rrr):
    args = ((0.0, 1.0), Q0, QD0, gagen.paper_controller())
    one = gagen.simulate_batch(rrr, *args, p={"m3": M3}, threads=1)
    two = gagen.simulate_batch(rrr, *args, p={"m3": M3}, threads=4)
    for name in ("q", "qd", "tau", "status", "nfev", "steps", "rejected"):
        assert np.array_equal(getattr(one, name), getattr(two, name))
    assert not np.shares_memory(one.q, two.q) and two.q.flags.c_contiguous
    run = two.run(2)
    assert np.array_equal(run.q, two.q[2]) and not np.shares_memory(run.q, two.q)
    assert one.stats["threads"] == 1 and two.stats["runs"] == N


def test_a_failing_run_is_reported_and_leaves_the_others_alone(rrr):
    m3 = M3.copy()
    m3[2] = -50.0  # not positive definite from the start
    stiff = [gagen.paper_controller() for _ in range(N)]
    stiff[4] = gagen.PD(kp=1e10, kd=1.0)
    p = {"m3": m3}
    res = gagen.simulate_batch(rrr, (0.0, 1.0), Q0, None, stiff, p=p, max_steps=2000)
    assert list(res.status) == [0, 0, 1, 0, -102, 0]
    assert not res.ok[[2, 4]].any() and res.stats["failed"] == 2
    for i in (2, 4):
        with pytest.raises((gagen.SingularMassMatrixError, RuntimeError)) as info:
            gagen.simulate(rrr, (0.0, 1.0), Q0[i], None, stiff[i], method="dopri5",
                           p=_per_run_p(p, i), max_steps=2000)
        assert res.message[i] == str(info.value)
        # the samples as the compiled integrator leaves them: NaN where not reached
        sim = _native.CompiledSimulation(rrr.kernels, rrr.parameter_vector(_per_run_p(p, i)),
                                            **stiff[i].c_spec(3))
        q, qd, tau, status, _ = sim.run("dopri5", 0.0, 1.0, Q0[i], np.zeros(3), res.t,
                                        max_steps=2000)
        assert status == res.status[i] and np.isnan(res.tau[i]).all()
        for mine, theirs in ((res.q[i], q), (res.qd[i], qd), (res.tau[i], tau)):
            assert np.array_equal(mine, theirs, equal_nan=True)
        assert np.isnan(res.q[i, -1]).all() and np.isnan(res.q[i, 0]).any() == (i == 2)
    assert "singular" in res.message[2] and "step budget" in res.message[4]
    good = [0, 1, 3, 5]
    assert_identical_to_simulate(rrr, _subset(res, good), (0.0, 1.0), Q0[good], None,
                                 gagen.paper_controller(), {"m3": m3[good]}, "dopri5",
                                 max_steps=2000)


def _subset(res, rows):
    return gagen.BatchResult(res.t, res.q[rows], res.qd[rows], res.tau[rows],
                             res.status[rows], [res.message[i] for i in rows],
                             res.nfev[rows], res.steps[rows], res.rejected[rows],
                             res.coordinates, res.stats)


def test_python_controllers_and_other_methods_are_refused(rrr):
    with pytest.raises(ValueError, match="cannot call a Python controller.*gagen.simulate"):
        gagen.simulate_batch(rrr, (0, 1), Q0, None, lambda t, q, qd: -10 * qd)
    with pytest.raises(ValueError, match="cannot call a Python controller"):
        gagen.simulate_batch(rrr, (0, 1), Q0[:2], None, [gagen.paper_controller(), print])
    with pytest.raises(ValueError, match="dopri5, rk4"):
        gagen.simulate_batch(rrr, (0, 1), Q0, method="RK45")
    lam = gagen.load("rrr", backend="lambdify")
    with pytest.raises(ValueError, match="compiled backend"):
        gagen.simulate_batch(lam, (0, 1), Q0)


@pytest.mark.parametrize("kwargs, error, match", [
    ({"q0": np.zeros((4, 3)), "qd0": np.zeros((5, 3))}, ValueError, "q0 has 4, qd0 has 5"),
    ({"q0": np.zeros((4, 3)), "p": {"m3": np.ones(5)}}, ValueError, "q0 has 4, p has 5"),
    ({"q0": np.zeros((4, 2))}, ValueError, "shape"),
    ({"q0": [[0, 0, 0], [0, np.nan, 0]]}, ValueError, "run 1"),
    ({"p": {"m9": np.ones(4)}}, KeyError, "m9"),
    ({"p": {"m3": [1.0, np.inf]}}, ValueError, "p\\['m3'\\].*run 1"),
    ({"p": {"m3": np.ones(2), "m2": np.ones(3)}}, ValueError, "different lengths"),
    ({"p": np.ones((2, 4))}, ValueError, "shape \\(N, "),
    ({"controller": []}, ValueError, "empty"),
    ({"threads": 0}, ValueError, "threads"),
    ({"rtol": -1.0}, ValueError, "rtol"),
    ({"h": 0.1}, TypeError, "options"),
])
def test_bad_inputs_are_refused_with_simulates_checks(rrr, kwargs, error, match):
    args = {"q0": np.zeros(3), **kwargs}
    q0 = args.pop("q0")
    with pytest.raises(error, match=match):
        gagen.simulate_batch(rrr, (0, 0.1), q0, **args)


def test_progress_is_reported_up_to_the_total(rrr):
    seen = []
    gagen.simulate_batch(rrr, (0, 0.2), np.zeros((40, 3)), progress=lambda d, t: seen.append((d, t)))
    assert seen[-1] == (40, 40) and all(t == 40 and 0 <= d <= 40 for d, t in seen)


def test_ctrl_c_stops_every_thread(cache_dir):
    call = ("gagen.simulate_batch(dyn, (0, 1e6), np.full((8, 3), 0.1), method='rk4', "
            "h=1e-9, max_steps=2**60, threads=2)")
    assert seconds_to_stop(call) < 5.0


def test_importing_gagen_and_running_a_batch_does_not_import_dask():
    script = ("import sys, gagen; dyn = gagen.load('rrr'); "
              "gagen.simulate_batch(dyn, (0, 0.1), [[0, 0, 0], [0.1, 0, 0]]); "
              "print(sorted(m for m in sys.modules if m.split('.')[0] in "
              "('dask', 'distributed')))")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


def test_a_received_module_is_checked_before_it_is_kept(rrr, tmp_path):
    payload = ModulePayload.of(rrr)
    path = install_received_module(tmp_path, payload.file_name, payload.data, payload.sha256)
    assert path.read_bytes() == payload.data
    assert cached_module_is_intact(path.parent, payload.file_name)
    assert install_received_module(tmp_path, payload.file_name, payload.data,
                                   payload.sha256) == path
    with pytest.raises(ValueError, match="damaged"):
        install_received_module(tmp_path, payload.file_name, payload.data[:-1], payload.sha256)
    with pytest.raises(ValueError, match="another platform"):
        install_received_module(tmp_path, "gagen_rrr.cpython-39-darwin.so", payload.data,
                                payload.sha256)
