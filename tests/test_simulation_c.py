"""The compiled simulation of any model: simulation.c and gagen_second_order.h.

Each model's forward dynamics runs in the integrators as a position stage and a velocity
stage (stage_split.py), inside Dormand-Prince and RK4 loops specialised for its state
size. Checked here on models other than the paper's robot (random trees with prismatic,
continuous and fixed joints, a 7-link chain) and for every controller: the same steps as
scipy's RK45 driving the same model from Python, RK4 against a numpy RK4, the controllers'
torques, the one-pass forward dynamics with gravity compensation, and failures mid-run.
"""

from __future__ import annotations

import numpy as np
import pytest
from random_trees import random_model

import gagen
from gagen.runtime import _native
from gagen.runtime.dynamics import SingularMassMatrixError
from gagen.sim.controllers import PD, ComputedTorque
from gagen.sim.simulate import simulate
from gagen.sim.trajectory import Eq11Trajectory

# the models of test_compiled.py (same seeds), so that the session's cache serves both
MODELS = ("tree3", "tree11", "chain:7")
TOL = {"rtol": 1e-8, "atol": 1e-10}


@pytest.fixture(scope="module")
def models(cache_dir):
    def model_of(name):
        if name.startswith("tree"):
            return random_model(np.random.default_rng(int(name[4:])), 5,
                                symbolic=int(name[4:]) % 2 == 1)
        return name

    return {name: gagen.load(model_of(name), cache_dir=cache_dir) for name in MODELS}


def controllers(dyn):
    """Every kind of controller, the PD gains scaled by each joint's inertia (about 5 rad/s,
    critically damped), so that the closed loop is no stiffer than the robot itself."""
    n = dyn.n
    rng = np.random.default_rng(n)
    target = rng.uniform(-0.5, 0.5, n)
    inertia = np.diagonal(dyn.mass_matrix(np.zeros(n)))
    kp, kd = 25.0 * inertia * rng.uniform(0.8, 1.2, n), 10.0 * inertia
    return {
        "none": None,
        "pd": PD(kp=kp, kd=kd, target=target),
        "pd+g": PD(kp=kp, kd=kd, target=target, gravity_compensation=True),
        "computed torque": ComputedTorque(Eq11Trajectory(np.zeros(n), target, 0.8),
                                          kp=100.0, kd=20.0),
    }


def start(dyn):
    rng = np.random.default_rng(dyn.n + 1)
    return rng.uniform(-0.3, 0.3, dyn.n), rng.uniform(-1, 1, dyn.n)


def scale(a):
    return max(1.0, float(np.abs(a).max()))


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("kind", ["none", "pd", "pd+g", "computed torque"])
def test_dopri5_takes_the_steps_of_scipy_rk45(models, name, kind):
    dyn = models[name]
    ctrl = controllers(dyn)[kind]
    q0, qd0 = start(dyn)
    te = np.linspace(0.0, 1.0, 23)
    ref = simulate(dyn, (0.0, 1.0), q0, qd0, ctrl, method="RK45", t_eval=te, **TOL)
    res = simulate(dyn, (0.0, 1.0), q0, qd0, ctrl, method="dopri5", t_eval=te, **TOL)
    assert (res.stats["steps"], res.stats["nfev"]) == (ref.stats["steps"], ref.stats["nfev"])
    assert ref.stats["steps"] > 5
    for got, want in ((res.q, ref.q), (res.qd, ref.qd), (res.tau, ref.tau)):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * scale(want))


def rk4_reference(dyn, ctrl, q0, qd0, t1, h):
    """Classical RK4 in numpy on gagen_rk4's grid, y at every grid point."""
    law = ctrl.bind(dyn) if ctrl is not None else (lambda t, q, qd: np.zeros(dyn.n))
    n = dyn.n

    def f(t, y):
        q, qd = y[:n], y[n:]
        return np.concatenate([qd, dyn.forward_dynamics(q, qd, law(t, q, qd))])

    y = np.concatenate([q0, qd0])
    out, t = [y], 0.0
    for k in range(round(t1 / h)):
        k1 = f(t, y)
        k2 = f(t + h / 2, y + h / 2 * k1)
        k3 = f(t + h / 2, y + h / 2 * k2)
        k4 = f(t + h, y + h * k3)
        y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        t = (k + 1) * h
        out.append(y)
    return np.array(out)


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("kind", ["pd+g", "computed torque"])
def test_rk4_is_classical_rk4(models, name, kind):
    dyn = models[name]
    ctrl = controllers(dyn)[kind]
    q0, qd0 = start(dyn)
    h = 0.002  # stable: the damping of the light distal links makes the loops stiff
    grid = np.arange(51) * h
    res = simulate(dyn, (0.0, 0.1), q0, qd0, ctrl, method="rk4", h=h, t_eval=grid)
    ref = rk4_reference(dyn, ctrl, q0, qd0, 0.1, h)
    assert res.stats["steps"] == 50
    got = np.hstack([res.q, res.qd])
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11 * scale(ref))


@pytest.mark.parametrize("name", MODELS)
def test_controller_torques_match_the_python_controllers(models, name):
    dyn = models[name]
    n = dyn.n
    rng = np.random.default_rng(8)
    t = np.linspace(-0.3, 1.2, 9)  # before, during and after the eq. 11 motion
    y = rng.normal(size=(9, 2 * n))
    for kind, ctrl in controllers(dyn).items():
        if ctrl is None:
            continue
        sim = _native.CompiledSimulation(dyn.kernels, None, **ctrl.c_spec(n))
        tau, status = sim.torques(t, y)
        assert status == 0
        want = ctrl.bind(dyn)(t, y[:, :n], y[:, n:])
        np.testing.assert_allclose(tau, want, rtol=0, atol=1e-11 * scale(want), err_msg=kind)


@pytest.mark.parametrize("name", MODELS)
def test_position_and_velocity_stages_are_forward_dynamics(models, name):
    """forward_dynamics_gc(q, qd, u) = forward_dynamics(q, qd, u + g(q)), via a PD law
    with gravity compensation evaluated as the integrator does (one-step rk4)."""
    dyn = models[name]
    n = dyn.n
    rng = np.random.default_rng(5)
    for _ in range(3):
        q, qd = rng.uniform(-1, 1, (2, n))
        pd = PD(kp=rng.uniform(1, 5, n), kd=1.0, target=rng.uniform(-1, 1, n),
                gravity_compensation=True)
        h = 1e-3
        res = simulate(dyn, (0.0, h), q, qd, pd, method="rk4", h=h, t_eval=[0.0, h])
        ref = rk4_reference(dyn, pd, q, qd, h, h)[-1]
        np.testing.assert_allclose(np.hstack([res.q[-1], res.qd[-1]]), ref, rtol=0,
                                   atol=1e-13 * scale(ref))


def folding_inertia(rrr) -> dict:
    """rrr parameters whose M[0, 0] (the inertia about the vertical axis) is positive with
    the arm stretched out, at q = 0, and negative once it has folded halfway to the
    paper's target: a mass matrix that stops being positive definite mid-run."""
    stretched = rrr.mass_matrix(np.zeros(3))[0, 0]
    folded = rrr.mass_matrix(np.radians([-30.0, -30.0, -15.0]))[0, 0]
    assert folded < stretched
    base = rrr.parameters["I1z"]
    return {"I1z": base - (stretched + folded) / 2}


@pytest.mark.parametrize("method", ["dopri5", "rk4"])
def test_a_mass_matrix_failing_mid_run_stops_the_simulation(cache_dir, method):
    rrr = gagen.load("rrr", cache_dir=cache_dir)
    p = folding_inertia(rrr)
    pd = PD(kp=[500, 300, 200], kd=[300, 150, 100], target=np.radians([-60, -60, -30]))
    te = np.linspace(0.0, 5.0, 501)
    sim = _native.CompiledSimulation(rrr.kernels, rrr.parameter_vector(p), **pd.c_spec(3))
    q, _, tau, status, _ = sim.run(method, 0.0, 5.0, np.zeros(3), np.zeros(3), te)
    assert status == 1  # <model>_ERR_NOT_POSITIVE_DEFINITE
    reached = ~np.isnan(q).any(axis=1)
    k = int(reached.sum())
    assert 0 < k < te.size and reached[:k].all()  # the rows reached, then NaN
    assert np.isnan(tau).all()
    # up to the failure, the same motion as scipy's RK45 (which stops there too)
    with pytest.raises(SingularMassMatrixError, match="after t = "):
        simulate(rrr, (0.0, 5.0), np.zeros(3), None, pd, method=method, p=p)
    with pytest.raises(SingularMassMatrixError):
        simulate(rrr, (0.0, 5.0), np.zeros(3), None, pd, method="RK45", p=p)
    ref = simulate(rrr, (0.0, te[k - 1]), np.zeros(3), None, pd, method="RK45", p=p,
                   t_eval=te[:k])
    atol = 1e-9 if method == "dopri5" else 1e-6
    np.testing.assert_allclose(q[:k], ref.q, rtol=0, atol=atol)


def test_bad_controllers_are_refused_by_the_c_code(cache_dir):
    rrr = gagen.load("rrr", cache_dir=cache_dir)
    te = np.linspace(0.0, 1.0, 3)
    for spec in ({"kind": 7}, {"kind": -1}):
        sim = _native.CompiledSimulation(rrr.kernels, None, **spec)
        for method in ("dopri5", "rk4"):
            q, _, _, status, _ = sim.run(method, 0.0, 1.0, np.zeros(3), np.zeros(3), te)
            assert status == -103 and np.isnan(q).all()  # GAGEN_ERR_BAD_ARG
        assert sim.torques(te, np.zeros((3, 6)))[1] == -103
    with pytest.raises(ValueError, match="unknown compiled method"):
        sim.run("euler", 0.0, 1.0, np.zeros(3), np.zeros(3), te)
