"""Base parameters and identification (gagen.ident).

Base parameters: as many as the regressor's rank, and Y_b pi_b = tau exactly at fresh
states and parameters. Identification: the Panda carrying a payload unknown to its model,
noisy torques along exciting trajectories; the identified model predicts held-out torques
to within the noise. Measurements from CSV, with the derivatives estimated.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from random_trees import random_model
from test_joint_terms import with_random_joint_terms
from test_regressor import loaded, random_parameters, rank, states

import gagen
from gagen.app.cli import main as cli_main
from gagen.ident import FourierTrajectory, read_measurements
from gagen.ident.base import group_columns

PAYLOAD = {"m_panda_link7": 0.73 + 1.5, "cx_panda_link7": 0.02, "cy_panda_link7": -0.01,
           "cz_panda_link7": 0.12, "Ixx_panda_link7": 0.05, "Iyy_panda_link7": 0.045,
           "Izz_panda_link7": 0.02, "damping_panda_joint1": 0.4, "friction_panda_joint2": 0.8,
           "armature_panda_joint4": 0.1}


def stacked_rank(dyn, rng, p=None) -> int:
    q, qd, qdd = states(dyn, rng, 80)
    return rank(dyn.regressor(q, qd, qdd, p).reshape(-1, len(dyn.regressor_names)))


@pytest.mark.parametrize("name,backend", [("rrr", "compiled"), ("chain:5", "lambdify"),
                                          ("panda", "lambdify"), ("ur5_robot", "lambdify")])
def test_base_parameters_count_is_the_rank_and_predict_exactly(name, backend):
    dyn = loaded(name, backend)
    rng = np.random.default_rng(2)
    grouping = dyn.base_grouping()
    assert grouping.count == stacked_rank(dyn, rng) < len(dyn.regressor_names)
    for k in range(3):
        p = None if k == 0 else random_parameters(dyn, rng, scale=0.3)
        q, qd, qdd = states(dyn, rng, 8)
        Yb = dyn.base_regressor(q, qd, qdd, p)
        assert Yb.shape == (8, dyn.n, grouping.count)
        tau = dyn.inverse_dynamics(q, qd, qdd, p)
        np.testing.assert_allclose(Yb @ dyn.base_parameters(p), tau, rtol=1e-9,
                                   atol=1e-9 * max(1.0, np.abs(tau).max()))
    q, qd, qdd = states(dyn, rng, 60)
    Yb = dyn.base_regressor(q, qd, qdd).reshape(-1, grouping.count)
    assert rank(Yb) == grouping.count  # full column rank


def test_random_tree_base_parameters():
    rng = np.random.default_rng(13)
    model = with_random_joint_terms(random_model(rng, 6, symbolic=True), rng, True)
    dyn = gagen.load(model, backend="lambdify")
    assert dyn.base_grouping().count == stacked_rank(dyn, rng)
    q, qd, qdd = states(dyn, rng, 8)
    np.testing.assert_allclose(dyn.base_regressor(q, qd, qdd) @ dyn.base_parameters(),
                               dyn.inverse_dynamics(q, qd, qdd), rtol=1e-9, atol=1e-9)


def test_rrr_grouping_as_text():
    """The paper's robot: the first joint is vertical, so only the inertias about it count,
    and the links' masses regroup into their parents' (L2 = 0.4 m)."""
    dyn = gagen.load("rrr")
    grouping = dyn.base_grouping()
    text = grouping.text()
    assert len(text.splitlines()) == grouping.count == 22
    assert grouping.matrix.shape == (22, len(dyn.regressor_names))
    lines = dict(line.split(" = ", 1) for line in (s.replace("  ", " ").strip()
                                                  for s in text.splitlines()))
    lines = {k.strip(): v for k, v in lines.items()}
    assert lines["mcy_link2"] == "mcy_link2 + 0.4*m_link3"
    assert lines["IOxx_link2"] == "IOxx_link2 + 0.16*m_link3 + armature_q2"
    assert "m_link1" not in text and "armature_q1" in lines["IOzz_link1"]
    # other lengths, other coefficients: the grouping follows the kinematic parameters
    other = dyn.base_grouping({"L2": 0.5})
    assert "mcy_link2 + 0.5*m_link3" in other.expressions()
    assert str(grouping) == text


def test_group_columns_of_a_known_matrix():
    """Columns c0, c1 = 2 c0, c2, c3 = c0 - c2 and a zero column: two base parameters."""
    rng = np.random.default_rng(0)
    c0, c2 = rng.normal(size=(2, 50))
    W = np.column_stack([c0, 2 * c0, c2, c0 - c2, np.zeros(50)])
    g = group_columns(W, ["a", "b", "c", "d", "e"])
    assert g.names == ["a", "c"]
    np.testing.assert_allclose(g.matrix, [[1, 2, 0, 1, 0], [0, 0, 1, -1, 0]], atol=1e-14)
    assert g.text() == "a = a + 2*b + d\nc = c - d"


def test_base_parameters_at_the_edge_of_identifiability():
    """A weakly excited column, 1e-6 (relative) from the span of the others, is independent
    (a base parameter of its own: the smallest singular value of the kept columns is then
    about 1e-6 of the largest); one 1e-12 from it is dependent and regrouped (base.TOLERANCE
    = 1e-8 lies between). Columns of very different scales: the test is on unit-norm ones."""
    rng = np.random.default_rng(17)
    strong = rng.normal(size=(400, 5)) * [1e3, 1.0, 1e-2, 5.0, 0.3]
    off_span = np.linalg.qr(np.column_stack([strong, rng.normal(size=(400, 2))]))[0][:, 5:]

    def near_span(coefficients, distance, direction):
        column = strong @ coefficients
        return column + distance * np.linalg.norm(column) * direction

    weak = near_span([1e-3, 0.5, -20.0, 0.1, 1.0], 1e-6, off_span[:, 0])
    dependent = near_span([2e-3, -0.3, 50.0, 0.2, 3.0], 1e-12, off_span[:, 1])
    names = ["a", "b", "c", "d", "e", "weak", "dependent"]
    W = np.column_stack([strong, weak, dependent])
    g = group_columns(W, names)
    assert g.names == ["a", "b", "c", "d", "e", "weak"]
    unit = W[:, g.independent] / np.linalg.norm(W[:, g.independent], axis=0)
    singular = np.linalg.svd(unit, compute_uv=False)
    assert 1e-7 < singular[-1] / singular[0] < 1e-5
    # the dependent column is regrouped into the strong ones, with its coefficients
    np.testing.assert_allclose(g.matrix[:5, 6], [2e-3, -0.3, 50.0, 0.2, 3.0], rtol=1e-6)
    assert g.matrix[5, 6] == 0
    pi = rng.normal(size=7)
    np.testing.assert_allclose(W[:, g.independent] @ (g.matrix @ pi), W @ pi, rtol=1e-9,
                               atol=1e-9 * np.abs(W @ pi).max())


# ----------------------------------------------------------------------- identification


def payload_data(dyn, rng, seconds: float, rate: float, noise):
    """The Panda with PAYLOAD along a random Fourier trajectory: exact and noisy torques.
    `noise`: the noise's standard deviation per joint, or a number: that fraction of each
    joint's largest torque (at least 1 N m or N)."""
    centre = np.array([0, 0, 0, -1.6, 0, 1.8, 0.8, 0.02, 0.02])
    amplitude = np.array([1.0, 0.6, 1.0, 0.6, 1.0, 0.8, 1.0, 0.015, 0.015])
    trajectory = FourierTrajectory.random(dyn.n, rng, amplitude, centre, frequency=0.2)
    t = np.arange(0.0, seconds, 1.0 / rate)
    q, qd, qdd = trajectory(t)
    tau = dyn.inverse_dynamics(q, qd, qdd, PAYLOAD)
    scale = np.maximum(np.abs(tau).max(axis=0), 1.0) * noise if np.ndim(noise) == 0 else noise
    return t, q, qd, qdd, tau, tau + rng.normal(size=tau.shape) * scale, scale


def test_identification_predicts_the_payload_robot_within_the_noise():
    dyn = loaded("panda", "lambdify")
    rng = np.random.default_rng(4)
    *_, q, qd, qdd, _, measured, scale = payload_data(dyn, rng, 25.0, 80.0, 0.01)
    result = gagen.identify(dyn, q, qd, qdd, measured, weights=1 / scale**2)
    assert result.sigma == pytest.approx(1.0, rel=0.1)  # the weights were the noise's
    assert result.condition < 1e4
    # held-out: another trajectory
    *_, q2, qd2, qdd2, exact, measured2, _ = payload_data(dyn, rng, 10.0, 80.0, scale)
    predicted = result.predict(q2, qd2, qdd2)
    error = np.sqrt(np.mean((predicted - exact) ** 2, axis=0))
    assert (error < 0.5 * scale).all(), error / scale  # well within the noise (0.04-0.25)
    fit = np.sqrt(np.mean((predicted - measured2) ** 2, axis=0))
    np.testing.assert_allclose(fit, scale, rtol=0.15)  # what is left is the noise
    nominal = np.sqrt(np.mean((dyn.inverse_dynamics(q2, qd2, qdd2) - exact) ** 2, axis=0))
    assert (nominal[1:7] > 5 * scale[1:7]).any()  # without identification, the payload shows
    # the estimates: about 68 % within one standard deviation of the true base parameters
    truth = dyn.base_parameters(PAYLOAD)
    z = np.abs(result.values - truth) / result.std
    assert 0.5 < np.mean(z < 1) and np.mean(z < 3) > 0.95


def test_reported_deviations_match_the_spread_over_many_draws():
    """The paper's robot at 12 fixed states, torques with known noise (0.5, 2, 1) and the
    weights 1 / noise^2, four of joint 1's torques left out (weight 0): over 2000 draws of
    the noise the estimates scatter as the reported standard deviations say (within 5 %,
    each of the 22 base parameters), sigma^2 averages 1, and they are unbiased. With
    m = 32 weighted rows and r = 22 parameters, sigma^2 must divide by m - r = 10: by m it
    would average 0.31, and the deviations come out 0.56 of the spread."""
    dyn = gagen.load("rrr")
    rng = np.random.default_rng(23)
    q, qd, qdd = states(dyn, rng, 12)
    exact = dyn.inverse_dynamics(q, qd, qdd)
    noise = np.array([0.5, 2.0, 1.0])
    weights = np.tile(1 / noise**2, (12, 1))
    weights[:4, 0] = 0.0
    draws = 2000
    values, variances, sigma2 = [], [], []
    for _ in range(draws):
        result = gagen.identify(dyn, q, qd, qdd, exact + rng.normal(size=exact.shape) * noise,
                                weights=weights)
        values.append(result.values)
        variances.append(result.std**2)
        sigma2.append(result.sigma**2)
    r = result.grouping.count
    assert (r, np.count_nonzero(weights)) == (22, 32)
    spread = np.std(values, axis=0, ddof=1)
    reported = np.sqrt(np.mean(variances, axis=0))
    np.testing.assert_allclose(reported / spread, 1.0, atol=0.05)
    assert np.mean(sigma2) == pytest.approx(1.0, abs=0.03)
    bias = np.abs(np.mean(values, axis=0) - dyn.base_parameters())
    assert (bias < 0.1 * spread).all()  # 4.5 standard errors of the mean
    # the covariance is sigma^2 times the inverse of the weighted normal matrix
    A = dyn.base_regressor(q, qd, qdd).reshape(-1, r) * np.sqrt(weights).reshape(-1, 1)
    np.testing.assert_allclose(result.covariance / result.sigma**2, np.linalg.inv(A.T @ A),
                               rtol=1e-8, atol=1e-12 * np.abs(np.linalg.inv(A.T @ A)).max())


def test_identify_checks_its_inputs():
    dyn = gagen.load("rrr")
    q = np.zeros((3, 3))
    with pytest.raises(ValueError, match="more samples"):
        gagen.identify(dyn, q, q, q, q)
    big = np.zeros((50, 3))
    with pytest.raises(ValueError, match="weights"):
        gagen.identify(dyn, big, big, big, big, weights=np.ones(2))
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        gagen.identify(dyn, np.zeros(3), big, big, big)


def test_result_files(tmp_path):
    dyn = gagen.load("rrr")
    rng = np.random.default_rng(3)
    q, qd, qdd = states(dyn, rng, 300)
    tau = dyn.inverse_dynamics(q, qd, qdd) + rng.normal(scale=0.1, size=q.shape)
    result = gagen.identify(dyn, q, qd, qdd, tau)
    data = json.loads(result.to_json(tmp_path / "r.json").read_text())
    assert [b["name"] for b in data["base_parameters"]] == result.names
    assert np.allclose(data["grouping"], result.grouping.matrix)
    rows = (tmp_path / "r.csv")
    result.to_csv(rows)
    lines = rows.read_text().splitlines()
    assert lines[0] == "name,value,std,relative_std_percent,expression"
    assert len(lines) == 1 + len(result.names)
    assert "residual RMS per joint" in result.summary()


# ----------------------------------------------------------------------------- CSV


def write_csv(path: Path, columns: dict[str, np.ndarray]) -> Path:
    header = list(columns)
    data = np.column_stack([columns[h] for h in header])
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(repr(float(v)) for v in row)
                                                         for row in data) + "\n")
    return path


def test_derivatives_estimated_from_positions(tmp_path):
    """q only: Savitzky-Golay gives qd and qdd of a smooth trajectory to about 3e-5."""
    dyn = gagen.load("rrr")
    trajectory = FourierTrajectory.random(3, np.random.default_rng(1), 1.0, frequency=0.5)
    t = np.arange(0, 4, 1e-3)
    q, qd, qdd = trajectory(t)
    tau = dyn.inverse_dynamics(q, qd, qdd)
    names = dyn.coordinates
    columns = {"t": t, **{c: q[:, k] for k, c in enumerate(names)},
               **{f"tau_{c}": tau[:, k] for k, c in enumerate(names)}}
    data = read_measurements(write_csv(tmp_path / "q.csv", columns), names)
    assert "qd and qdd from q" in data.estimated
    keep = slice(25, len(t) - 25)  # window 0.05 s = 51 samples: 25 dropped at each end
    np.testing.assert_allclose(data.t, t[keep])
    np.testing.assert_allclose(data.qd, qd[keep], atol=1e-4 * np.abs(qd).max())
    np.testing.assert_allclose(data.qdd, qdd[keep], atol=1e-4 * np.abs(qdd).max())
    # with qd given, qdd comes from it; with everything given, nothing is estimated
    columns.update({f"{c}_d": qd[:, k] for k, c in enumerate(names)})
    assert "qdd from qd" in read_measurements(write_csv(tmp_path / "qd.csv", columns),
                                              names).estimated
    columns.update({f"{c}_dd": qdd[:, k] for k, c in enumerate(names)})
    full = read_measurements(write_csv(tmp_path / "all.csv", columns), names)
    assert full.estimated == "" and np.array_equal(full.qdd, qdd)


def test_read_measurements_errors(tmp_path):
    path = write_csv(tmp_path / "bad.csv", {"t": np.arange(5.0), "q1": np.zeros(5)})
    with pytest.raises(ValueError, match="missing column"):
        read_measurements(path, ["q1", "q2"])
    uneven = write_csv(tmp_path / "uneven.csv", {"t": np.array([0, 1, 3, 4.0] * 1).cumsum(),
                                                  "q1": np.zeros(4), "tau_q1": np.zeros(4)})
    with pytest.raises(ValueError, match="evenly spaced"):
        read_measurements(uneven, ["q1"])


def test_cli_identify(tmp_path, capsys):
    """A simulation's CSV (t, q, qd, tau: SimulationResult.to_csv) identifies the robot
    that produced it: qdd is estimated from qd."""
    dyn = gagen.load("rrr")
    trajectory = FourierTrajectory.random(3, np.random.default_rng(6), 0.8, frequency=0.4)

    def controller(t, q, qd):  # track the trajectory with the exact model
        qr, qdr, qddr = (x[0] for x in trajectory([t]))
        return dyn.inverse_dynamics(q, qd, qddr + 40 * (qdr - qd) + 400 * (qr - q))

    q0, qd0, _ = (x[0] for x in trajectory([0.0]))
    run = gagen.simulate(dyn, (0, 10), q0, qd0, controller=controller, method="RK45",
                         rtol=1e-10, atol=1e-10, t_eval=np.arange(0, 10, 2e-3))
    csv_path = run.to_csv(tmp_path / "run.csv")
    out = tmp_path / "ident"
    assert cli_main(["identify", "rrr", str(csv_path), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "qdd from qd" in text and "base parameters" in text
    data = json.loads((out / "identified.json").read_text())
    values = np.array([b["value"] for b in data["base_parameters"]])
    np.testing.assert_allclose(values, dyn.base_parameters(), rtol=1e-3,
                               atol=1e-3 * np.abs(dyn.base_parameters()).max())
    assert (out / "identified.csv").is_file()
    assert math.isfinite(data["condition"])


def test_householder_fallback_agrees_with_the_normal_equations(monkeypatch):
    """Past QR_CONDITION the least squares is solved by QR: same answer on a problem both
    solve well, and QR where the normal equations would lose too many digits."""
    import gagen.ident.identification as fit

    dyn = gagen.load("rrr")
    rng = np.random.default_rng(8)
    q, qd, qdd = states(dyn, rng, 400)
    tau = dyn.inverse_dynamics(q, qd, qdd) + rng.normal(scale=0.1, size=q.shape)
    gram = gagen.identify(dyn, q, qd, qdd, tau)
    monkeypatch.setattr(fit, "QR_CONDITION", 0.0)
    qr = gagen.identify(dyn, q, qd, qdd, tau)
    np.testing.assert_allclose(qr.values, gram.values, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(qr.std, gram.std, rtol=1e-9)
    assert qr.condition == pytest.approx(gram.condition, rel=1e-9)
    # a nearly rank-deficient problem: the normal equations give up, QR answers
    A = rng.normal(size=(200, 3))
    A[:, 2] = A[:, 0] + 1e-9 * rng.normal(size=200)
    b = A @ [1.0, 2.0, 3.0]
    blocks = [(A, b)]
    *_, condition = fit._normal_equations(iter(blocks), 3)
    assert condition > fit.QR_CONDITION
    x, *_, condition = fit._householder(iter(blocks), 3)
    np.testing.assert_allclose(A @ x, b, atol=1e-8)


# ------------------------------------------------------------- physically consistent


def test_consistent_identification_rrr():
    """Every parameter, physically consistent; as good as least squares on the data; what
    the data cannot see (the first link's mass: its joint is vertical) stays at the prior."""
    from gagen.ident import identify_consistent
    from gagen.ident.consistent import pseudo_inertia

    dyn = gagen.load("rrr")
    rng = np.random.default_rng(21)
    trajectory = FourierTrajectory.random(3, rng, [2.0, 1.0, 1.0], frequency=0.2)
    q, qd, qdd = trajectory(np.arange(0.0, 20.0, 0.02))
    exact = dyn.inverse_dynamics(q, qd, qdd, {"m3": 55.0})  # a heavier last link
    noise = 0.01 * np.abs(exact).max(axis=0)
    measured = exact + rng.normal(size=exact.shape) * noise
    result = identify_consistent(dyn, q, qd, qdd, measured, weights=1 / noise**2)
    assert result.success, result.message
    pi = result.parameters
    for i in range(3):  # J >= 0: a mass distribution exists (a rod's J is singular)
        eigenvalues = np.linalg.eigvalsh(pseudo_inertia(pi[10 * i:10 * i + 10]))
        assert eigenvalues[0] >= -1e-12 * eigenvalues[-1]
    assert (pi[30:] >= 0).all()
    plain = result.unconstrained
    np.testing.assert_allclose(result.rms, plain.rms, rtol=0.02)
    assert np.max(np.abs(result.base_values - plain.values) / plain.std) < 3
    assert pi[0] == pytest.approx(dyn.regressor_parameters()[0], rel=1e-3)  # m_link1
    q2, qd2, qdd2 = trajectory(np.arange(0.011, 10.0, 0.05))
    error = result.predict(q2, qd2, qdd2) - dyn.inverse_dynamics(q2, qd2, qdd2, {"m3": 55.0})
    assert (np.sqrt(np.mean(error**2, axis=0)) < 0.5 * noise).all()
    with pytest.raises(KeyError, match="no parameters Ixx_link1"):
        result.as_parameters()  # rrr's parameters are lengths and principal moments


def test_consistent_identification_as_parameters():
    """For a URDF robot the identified parameters are the model's own: `as_parameters()`
    passed as p reproduces the identified torques, and the bodies are valid inertias."""
    from gagen.ident import identify_consistent

    dyn = loaded("double_pendulum", "lambdify")
    rng = np.random.default_rng(5)
    trajectory = FourierTrajectory.random(2, rng, 1.5, frequency=0.3)
    q, qd, qdd = trajectory(np.arange(0.0, 10.0, 0.02))
    truth = {"m_link2": 1.7, "friction_joint1": 0.2, "armature_joint2": 0.05}
    tau = dyn.inverse_dynamics(q, qd, qdd, truth) + rng.normal(scale=0.01, size=q.shape)
    result = identify_consistent(dyn, q, qd, qdd, tau)
    p = result.as_parameters()
    np.testing.assert_allclose(dyn.inverse_dynamics(q, qd, qdd, p), result.predict(q, qd, qdd),
                               rtol=1e-10, atol=1e-10)
    assert p["friction_joint1"] == pytest.approx(0.2, abs=0.01)
    for mass, _, inertia in result.bodies().values():
        assert mass > 0 and np.linalg.eigvalsh(inertia).min() >= -1e-12
