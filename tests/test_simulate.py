"""Direct and inverse dynamics of the paper's robot: gagen.simulate, controllers, eq. 11, CLI.

The robot is `rrr` with its default (heavy) parameters. Compiled builds go to a
session-scoped temporary cache.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

import gagen
from gagen.app.cli import main
from gagen.app.figures import arm_points, body_frames, rrr_points
from gagen.runtime import _native
from gagen.runtime.dynamics import SingularMassMatrixError
from gagen.sim.controllers import (
    PD,
    ComputedTorque,
    default_controller,
    default_target,
    paper_controller,
)
from gagen.sim.simulate import SimulationResult, inverse_dynamics_along, simulate
from gagen.sim.trajectory import PAPER_QF, Eq11Trajectory

Q0 = np.zeros(3)
QD0 = np.array([1.0, -0.5, 2.0])  # a generic, nonzero initial velocity
TIGHT = {"rtol": 1e-10, "atol": 1e-12}


@pytest.fixture(scope="session")
def sim_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("gagen-simulate-cache")


@pytest.fixture(scope="session")
def rrr(sim_cache):
    return gagen.load("rrr", cache_dir=sim_cache)


@pytest.fixture(scope="session")
def rrr_lambdify():
    return gagen.load("rrr", backend="lambdify")


def relative_energy_drift(dyn, res: SimulationResult) -> float:
    T, V = dyn.energy(res.q, res.qd)
    E = T + V
    return float(np.abs(E - E[0]).max() / abs(E[0]))


# ----------------------------------------------------------------------------- energy


@pytest.mark.parametrize("method", ["RK45", "DOP853", "dopri5"])
def test_torque_free_motion_conserves_energy(rrr, method):
    res = simulate(rrr, (0.0, 5.0), Q0, QD0, method=method, **TIGHT)
    assert res.t[-1] == 5.0
    # the arm really moves: it falls, trading some 330 J of potential energy
    assert np.ptp(res.q, axis=0).min() > 0.5
    assert relative_energy_drift(rrr, res) < 1e-8


def test_energy_with_lambdify_backend(rrr_lambdify):
    res = simulate(rrr_lambdify, (0.0, 1.0), Q0, QD0, method="DOP853", **TIGHT)
    assert res.stats["backend"] == "lambdify"
    assert relative_energy_drift(rrr_lambdify, res) < 1e-8


# ------------------------------------------------------- compiled dopri5 versus scipy


@pytest.mark.parametrize("case", ["torque-free", "paper-controller"])
def test_dopri5_takes_the_steps_of_scipy_rk45(rrr, case):
    if case == "torque-free":
        args = dict(q0=Q0, qd0=QD0, controller=None, **TIGHT)
    else:
        args = {"q0": Q0, "qd0": np.zeros(3), "controller": paper_controller()}
    ref = simulate(rrr, (0.0, 5.0), method="RK45", **args)
    res = simulate(rrr, (0.0, 5.0), method="dopri5", **args)
    assert res.stats["steps"] == ref.stats["steps"]
    assert res.stats["nfev"] == ref.stats["nfev"]
    np.testing.assert_array_equal(res.t, ref.t)
    np.testing.assert_allclose(res.q, ref.q, rtol=0, atol=1e-10)
    np.testing.assert_allclose(res.qd, ref.qd, rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.tau, ref.tau, rtol=0, atol=1e-8)


def test_scipy_path_same_on_both_backends(rrr, rrr_lambdify):
    args = {"controller": paper_controller(), "t_eval": np.linspace(0, 1, 11)}
    a = simulate(rrr, (0.0, 1.0), Q0, None, **args)
    b = simulate(rrr_lambdify, (0.0, 1.0), Q0, None, **args)
    assert a.stats["steps"] == b.stats["steps"]
    np.testing.assert_allclose(a.q, b.q, atol=1e-9)
    np.testing.assert_allclose(a.tau, b.tau, atol=1e-7)


def test_rk4_converges_with_fourth_order(rrr):
    ctrl = paper_controller()
    ref = simulate(rrr, (0.0, 1.0), Q0, None, ctrl, method="dopri5", rtol=1e-13, atol=1e-14)
    errors = []
    for h in (4e-3, 2e-3, 1e-3):
        res = simulate(rrr, (0.0, 1.0), Q0, None, ctrl, method="rk4", h=h)
        assert res.stats["steps"] == round(1.0 / h)
        errors.append(np.abs(res.q - ref.q).max())
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(orders > 3.5), (errors, orders)
    assert errors[-1] < 1e-8


def test_rk4_default_step(rrr):
    res = simulate(rrr, (0.0, 0.5), Q0, QD0, method="rk4")
    assert res.stats["steps"] == 500 and res.stats["method"] == "rk4"


# ---------------------------------------------------------------- eq. 11 and replay


def test_eq11_trajectory():
    traj = Eq11Trajectory(np.zeros(3), PAPER_QF, 5.0)
    q, qd, qdd = traj(np.array([-1.0, 0.0, 5.0, 7.0]))
    assert q.shape == qd.shape == qdd.shape == (4, 3)
    np.testing.assert_array_equal(q[0], 0.0)
    np.testing.assert_allclose(q[2], PAPER_QF, atol=1e-15)
    np.testing.assert_array_equal(q[3], PAPER_QF)
    assert np.all(qd[[0, 1, 3]] == 0.0) and np.all(qdd[[0, 3]] == 0.0)
    assert np.abs(qd[2]).max() < 1e-15  # rest at both ends
    # midpoint: half-way, at the peak speed 2 (qf - q0)/Tp
    qm, qdm, _qddm = traj(2.5)
    np.testing.assert_allclose(qm, np.array(PAPER_QF) / 2, atol=1e-15)
    np.testing.assert_allclose(qdm, 2 * np.array(PAPER_QF) / 5.0, atol=1e-15)
    # derivatives match finite differences
    t = np.linspace(0.3, 4.7, 9)
    eps = 1e-6
    qp, qdp, _ = traj(t + eps)
    qn, qdn, _ = traj(t - eps)
    _, qd_t, qdd_t = traj(t)
    np.testing.assert_allclose((qp - qn) / (2 * eps), qd_t, atol=1e-8)
    np.testing.assert_allclose((qdp - qdn) / (2 * eps), qdd_t, atol=1e-8)
    with pytest.raises(ValueError, match="Tp"):
        Eq11Trajectory(np.zeros(3), PAPER_QF, 0.0)
    with pytest.raises(ValueError, match="same length"):
        Eq11Trajectory(np.zeros(2), PAPER_QF)


def test_inverse_dynamics_along_matches_pointwise(rrr):
    traj = Eq11Trajectory.paper()
    t = np.linspace(0.0, 5.0, 51)
    q, qd, qdd, tau = inverse_dynamics_along(rrr, traj, t)
    assert tau.shape == (51, 3)
    for k in (0, 17, 50):
        np.testing.assert_allclose(tau[k], rrr.inverse_dynamics(q[k], qd[k], qdd[k]),
                                   rtol=1e-13, atol=1e-12)
    # the scale of the paper's Fig. 4 (DESIGN.md): T12x peaks at 300-400 N m,
    # T23x stays within 200 N m and T01z within about +-15 N m
    assert 300 < tau[:, 1].max() < 400
    assert np.abs(tau[:, 2]).max() < 200
    assert 10 < np.abs(tau[:, 0]).max() < 20


@pytest.mark.parametrize("method", ["RK45", "dopri5"])
def test_eq11_torques_driven_forward_reproduce_the_trajectory(rrr, method):
    traj = Eq11Trajectory.paper()
    replay = ComputedTorque(traj, kp=0.0, kd=0.0)  # tau = inverse dynamics of eq. 11
    res = simulate(rrr, (0.0, 5.0), Q0, None, replay, method=method, **TIGHT)
    q_ref, _, _, tau_ref = inverse_dynamics_along(rrr, traj, res.t)
    assert np.abs(res.q - q_ref).max() < 1e-6
    np.testing.assert_allclose(res.tau, tau_ref, atol=1e-4)


def test_open_loop_torque_replay_from_python(rrr):
    """The torques of eq. 11 as a function of time only (no feedback at all)."""
    traj = Eq11Trajectory.paper()

    def torques(t, q, qd):
        return inverse_dynamics_along(rrr, traj, [t])[3][0]

    res = simulate(rrr, (0.0, 5.0), Q0, None, torques, method="RK45", **TIGHT)
    assert np.abs(res.q - traj(res.t)[0]).max() < 1e-6


def test_computed_torque_tracks_from_a_wrong_start(rrr):
    traj = Eq11Trajectory.paper()
    ct = ComputedTorque(traj)  # kp = 100, kd = 20: critically damped error
    res = simulate(rrr, (0.0, 5.0), np.array([0.1, -0.1, 0.05]), None, ct, method="dopri5")
    err = np.abs(res.q - traj(res.t)[0])
    assert err[0].max() == pytest.approx(0.1)
    assert err[-1].max() < 1e-5


# ----------------------------------------------------------------------- controllers


def test_pd_with_gravity_compensation_reaches_its_target(rrr):
    target = np.array([0.4, 0.3, -0.5])
    pd = PD(kp=[500, 300, 200], kd=[300, 150, 100], target=target, gravity_compensation=True)
    res = simulate(rrr, (0.0, 8.0), Q0, None, pd, method="dopri5")
    np.testing.assert_allclose(res.q[-1], target, atol=1e-4)
    assert np.abs(res.qd[-1]).max() < 1e-4
    # at rest on the target the controller holds exactly the gravity torque
    np.testing.assert_allclose(res.tau[-1], rrr.inverse_dynamics(target, Q0, Q0), atol=0.1)


def test_pd_without_gravity_compensation_sags(rrr):
    pd = PD(kp=300, kd=150, target=0.0)
    res = simulate(rrr, (0.0, 8.0), Q0, None, pd, method="dopri5")
    assert res.q[-1, 1] < -0.5  # 334 N m of gravity against 300 N m/rad


def test_paper_run_ends_near_the_papers_figure(rrr):
    """Fig. 2: q1 and q2 go from 0 to about -60 deg, q3 to about -30 deg, smoothly."""
    res = simulate(rrr, (0.0, 5.0), Q0, None, paper_controller(), method="dopri5")
    deg = np.degrees(res.q)
    np.testing.assert_allclose(deg[-1], [-60.0, -60.0, -30.0], atol=0.01)
    assert deg.max() < 1e-6  # every coordinate goes one way only ...
    assert deg.min(axis=0) == pytest.approx([-60, -60, -30], abs=0.01)  # ... no overshoot
    assert np.all(np.abs(deg[100] - [-60, -60, -30]) > 1.0)  # still moving at t = 1 s
    ref = simulate(rrr, (0.0, 5.0), Q0, None, paper_controller(), method="RK45")
    np.testing.assert_allclose(ref.q, res.q, atol=1e-10)


def test_controllers_are_vectorised_and_reusable(rrr):
    pd = paper_controller()
    bound = pd.bind(rrr)
    rng = np.random.default_rng(3)
    q, qd = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    t = np.linspace(0, 1, 5)
    stacked = bound(t, q, qd)
    for k in range(5):
        np.testing.assert_allclose(stacked[k], bound(t[k], q[k], qd[k]), rtol=1e-14)
    assert not pd.bound and bound.bound
    with pytest.raises(RuntimeError, match="bind"):
        pd(0.0, q[0], qd[0])  # gravity compensation needs the dynamics
    ct = ComputedTorque(Eq11Trajectory.paper(), kp=[1, 2, 3], kd=4).bind(rrr)
    s = ct(t, q, qd)
    np.testing.assert_allclose(s[2], ct(t[2], q[2], qd[2]), rtol=1e-14)
    with pytest.raises(ValueError, match="coordinates"):
        PD(kp=[1, 2], kd=1).bind(rrr)


def test_c_controllers_match_python_controllers(rrr):
    """The torques the C integrator's controllers report equal the Python ones."""
    rng = np.random.default_rng(4)
    t = np.linspace(-0.5, 5.5, 7)
    y = rng.normal(size=(7, 6))
    for ctrl in (paper_controller(), PD(kp=10, kd=2, target=0.3),
                 ComputedTorque(Eq11Trajectory.paper(), kp=[50, 60, 70], kd=[8, 9, 10])):
        sim = _native.CompiledSimulation(rrr.kernels, None, **ctrl.c_spec(3))
        tau_c, status = sim.torques(t, y)
        assert status == 0
        np.testing.assert_allclose(tau_c, ctrl.bind(rrr)(t, y[:, :3], y[:, 3:]),
                                   rtol=1e-12, atol=1e-10)


def test_python_callable_controller_on_scipy_path(rrr, rrr_lambdify):
    kp, kd = np.array([500.0, 300.0, 200.0]), np.array([300.0, 150.0, 100.0])
    target = np.array(PAPER_QF)
    calls = []

    def my_pd(t, q, qd):
        calls.append(t)
        zero = np.zeros(3)
        return -kp * (q - target) - kd * qd + rrr.inverse_dynamics(q, zero, zero)

    res = simulate(rrr, (0.0, 2.0), Q0, None, my_pd, method="RK45")
    ref = simulate(rrr, (0.0, 2.0), Q0, None, paper_controller(), method="RK45")
    assert len(calls) >= res.stats["nfev"]
    np.testing.assert_allclose(res.q, ref.q, atol=1e-12)
    np.testing.assert_allclose(res.tau, ref.tau, atol=1e-9)
    # any backend, any scipy method, even an implicit one
    lam = simulate(rrr_lambdify, (0.0, 0.5), Q0, None, my_pd, method="Radau",
                   t_eval=[0.0, 0.25, 0.5])
    assert lam.q.shape == (3, 3) and lam.stats["method"] == "Radau"
    # the compiled integrators cannot call Python: a clear error pointing to scipy
    for method in ("dopri5", "rk4"):
        with pytest.raises(ValueError, match="RK45"):
            simulate(rrr, (0.0, 1.0), Q0, None, my_pd, method=method)
    with pytest.raises(ValueError, match="torques of shape"):
        simulate(rrr, (0.0, 1.0), Q0, None, lambda t, q, qd: np.zeros(2))


def test_computed_torque_with_a_python_trajectory(rrr):
    eq11 = Eq11Trajectory.paper()

    def traj(t):  # the same motion, but not an Eq11Trajectory: no C form
        return eq11(t)

    ct = ComputedTorque(traj, kp=0, kd=0)
    with pytest.raises(ValueError, match="RK45"):
        simulate(rrr, (0.0, 1.0), Q0, None, ct, method="dopri5")
    res = simulate(rrr, (0.0, 1.0), Q0, None, ct, method="RK45", **TIGHT)
    assert np.abs(res.q - eq11(res.t)[0]).max() < 1e-8


def test_default_controller_of_other_models(sim_cache):
    dyn = gagen.load("chain:2", cache_dir=sim_cache)
    ctrl = default_controller(dyn)
    np.testing.assert_allclose(ctrl.target, [-math.pi / 6] * 2)
    res = simulate(dyn, (0.0, 5.0), np.zeros(2), None, ctrl, method="dopri5")
    np.testing.assert_allclose(res.q[-1], ctrl.target, atol=1e-3)
    np.testing.assert_allclose(default_target(gagen.resolve_model("rrr")), PAPER_QF)


# ----------------------------------------------------------------- results and errors


def test_results_are_fresh_arrays(rrr):
    a = simulate(rrr, (0.0, 1.0), Q0, QD0, method="dopri5")
    b = simulate(rrr, (0.0, 1.0), Q0, QD0, method="dopri5")
    c = simulate(rrr, (0.0, 1.0), Q0, QD0, method="RK45")
    for res in (a, c):
        arrays = [res.t, res.q, res.qd, res.tau]
        for i, x in enumerate(arrays):
            assert x.flags.writeable and x.flags.c_contiguous
            for y in arrays[i + 1:]:
                assert not np.shares_memory(x, y)
    before = b.q.copy()
    a.q[:] = 123.0
    a.t[:] = -1.0
    np.testing.assert_array_equal(b.q, before)
    assert b.t[0] == 0.0
    q0 = Q0.copy()
    res = simulate(rrr, (0.0, 0.1), q0, QD0)
    res.q[0] = 9.0
    np.testing.assert_array_equal(q0, Q0)  # the inputs are never aliased either
    traj = Eq11Trajectory.paper()
    q, _, _ = traj(1.0)
    q[:] = 0.0
    assert traj(1.0)[0][0] != 0.0


def test_result_stats_and_csv(rrr, tmp_path):
    res = simulate(rrr, (0.0, 1.0), Q0, None, paper_controller(), method="dopri5",
                   t_eval=np.linspace(0, 1, 11))
    assert res.t.shape == (11,) and res.q.shape == res.qd.shape == res.tau.shape == (11, 3)
    st = res.stats
    assert st["method"] == "dopri5" and st["backend"] == "compiled"
    assert st["nfev"] > 6 * st["steps"] > 0 and st["wall_time"] > 0
    path = res.to_csv(tmp_path / "sub" / "run.csv")
    with path.open() as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["t", "q1", "q2", "q3", "q1_d", "q2_d", "q3_d",
                       "tau_q1", "tau_q2", "tau_q3"]
    data = np.array(rows[1:], dtype=float)
    np.testing.assert_array_equal(data, np.column_stack([res.t, res.q, res.qd, res.tau]))
    # default grid: 501 points; scipy's own steps on request
    assert len(simulate(rrr, (0.0, 1.0), Q0, QD0).t) == 501
    steps = simulate(rrr, (0.0, 1.0), Q0, QD0, t_eval="steps")
    assert len(steps.t) == steps.stats["steps"] + 1


def test_clear_errors(rrr, rrr_lambdify):
    with pytest.raises(ValueError, match="compiled backend"):
        simulate(rrr_lambdify, (0.0, 1.0), Q0, QD0, method="dopri5")
    with pytest.raises(ValueError, match="unknown method"):
        simulate(rrr, (0.0, 1.0), Q0, QD0, method="Euler")
    with pytest.raises(ValueError, match="q0"):
        simulate(rrr, (0.0, 1.0), [0.0, 0.0], QD0)
    with pytest.raises(ValueError, match="t_span"):
        simulate(rrr, (0.0, 2.0), Q0, QD0, t_eval=[0.0, 3.0])
    with pytest.raises(TypeError, match="h"):
        simulate(rrr, (0.0, 1.0), Q0, QD0, method="RK45", h=1e-3)
    with pytest.raises(TypeError, match="takes the options"):
        simulate(rrr, (0.0, 1.0), Q0, QD0, method="dopri5", h=1e-3)
    with pytest.raises(RuntimeError, match="max_steps"):
        simulate(rrr, (0.0, 1.0), Q0, QD0, method="dopri5", max_steps=5)
    massless = {name: 0.0 for name in rrr.parameters if name[0] in "mI"}
    for dyn, method in ((rrr, "dopri5"), (rrr, "rk4"), (rrr, "RK45"), (rrr_lambdify, "RK45")):
        with pytest.raises(SingularMassMatrixError):
            simulate(dyn, (0.0, 1.0), Q0, QD0, method=method, p=massless)


def test_parameters_reach_the_integrators(rrr):
    light = {"m1": 6.0, "m2": 5.0, "m3": 4.0}
    a = simulate(rrr, (0.0, 1.0), Q0, QD0, method="dopri5", p=light)
    b = simulate(rrr, (0.0, 1.0), Q0, QD0, method="RK45", p=light)
    c = simulate(rrr, (0.0, 1.0), Q0, QD0, method="dopri5")
    np.testing.assert_allclose(a.q, b.q, atol=1e-9)
    assert np.abs(a.q - c.q).max() > 1e-3


# ------------------------------------------------------------------------- geometry


def test_arm_points_general_kinematics_match_the_paper_geometry():
    model = gagen.resolve_model("rrr")
    rng = np.random.default_rng(5)
    q = rng.uniform(-3, 3, size=(20, 3))
    closed = rrr_points(q, model=model)
    origins, rotations = body_frames(model, q)
    np.testing.assert_allclose(origins[:, 1], closed[:, 1], atol=1e-14)
    np.testing.assert_allclose(origins[:, 2], closed[:, 2], atol=1e-14)
    tip = origins[:, 2] + rotations[:, 2] @ np.array([0.0, 0.4, 0.0])
    np.testing.assert_allclose(tip, closed[:, 3], atol=1e-14)
    pts, edges = arm_points(model, q)
    assert pts.shape == (20, 4, 3) and edges == [(0, 1), (1, 2), (2, 3)]
    # at the paper's final position the arm hangs 0.75 m below its base
    final = rrr_points(np.array(PAPER_QF), model=model)
    np.testing.assert_allclose(final[3], [0.3 * math.sqrt(3), 0.3, -0.2 * math.sqrt(3) - 0.4],
                               atol=1e-15)


def test_body_frames_match_the_reference_kinematics():
    from conftest import SHARED_URDF
    from reference import forward_kinematics, numeric_model

    path = SHARED_URDF / "ur5_robot.urdf"
    model = gagen.resolve_model(str(path))
    nm = numeric_model(model)
    rng = np.random.default_rng(6)
    for q in rng.uniform(-2, 2, size=(3, model.dof)):
        origins, rotations = body_frames(model, q)
        states = forward_kinematics(nm, q)
        for i, s in enumerate(states):
            np.testing.assert_allclose(origins[i], s.origin, atol=1e-12)
            np.testing.assert_allclose(rotations[i], s.R, atol=1e-12)


# ------------------------------------------------------------------------------- CLI


def test_cli_simulate_writes_its_files(sim_cache, tmp_path, capsys):
    out = tmp_path / "sim"
    code = main(["simulate", "--duration", "0.5", "--points", "26", "--out", str(out),
                 "--cache-dir", str(sim_cache), "--gif"])
    assert code == 0
    for name in ("simulate.csv", "fig2_positions.png", "fig3_arm.png", "arm.gif"):
        assert (out / name).stat().st_size > 1000, name
    text = capsys.readouterr().out
    assert "wall time" in text and "fig2_positions.png" in text
    with (out / "simulate.csv").open() as fh:
        rows = list(csv.reader(fh))
    assert rows[0][:4] == ["t", "q1", "q2", "q3"] and len(rows) == 27
    assert float(rows[-1][0]) == 0.5


def test_cli_simulate_scipy_method_and_options(sim_cache, tmp_path):
    out = tmp_path / "sim"
    code = main(["simulate", "rrr", "--duration", "0.2", "--method", "RK45", "--out", str(out),
                 "--cache-dir", str(sim_cache), "--target", "-10", "-10", "-10", "--kp", "200"])
    assert code == 0
    data = np.loadtxt(out / "simulate.csv", delimiter=",", skiprows=1)
    assert data.shape == (501, 10)
    assert main(["simulate", "--duration", "0.2", "--out", str(out), "--backend", "lambdify",
                 "--method", "rk4"]) == 2  # bad input, refused before loading anything


def test_cli_inverse_writes_its_files(sim_cache, tmp_path, capsys):
    out = tmp_path / "inv"
    code = main(["inverse", "--out", str(out), "--cache-dir", str(sim_cache)])
    assert code == 0
    assert (out / "fig4_inverse.png").stat().st_size > 1000
    data = np.loadtxt(out / "inverse.csv", delimiter=",", skiprows=1)
    assert data.shape == (501, 13)
    np.testing.assert_allclose(np.degrees(data[-1, 1:4]), [-60, -60, -30], atol=1e-9)
    text = capsys.readouterr().out
    assert "peak T12x" in text and "+333.54 N m" in text
    assert "T01z" in text and "T23x" in text
