"""The derivation core through the lambdify backend: against independent references,
against physics (energy balance), and the runtime API's handling of its inputs."""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest
import sympy as sp
import yaml
from random_trees import random_model
from reference import (
    energy,
    forward_dynamics,
    mass_matrix,
    numeric_model,
    pin_dynamics,
    pin_model,
    pin_rnea,
    rnea,
    welded_potential,
)

import gagen
from gagen import derive, resolve_model

RTOL = 1e-10
# (seed, bodies, symbolic): 1 to 7 bodies, numeric and parametrized trees
TREES = [(100 + k, 1 + k % 7, k % 3 == 1) for k in range(12)]


def assert_close(actual, expected, rtol: float = RTOL) -> None:
    """Relative to the largest entry, so entries near zero are not judged on their own."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, (actual.shape, expected.shape)
    scale = max(np.abs(expected).max(initial=0.0), 1e-300)
    err = np.abs(actual - expected).max(initial=0.0)
    assert err <= rtol * scale, f"error {err:.3g} > {rtol:g} * {scale:.3g}\n{actual}\n{expected}"


@functools.cache
def loaded(name: str):
    """Built-in model and its lambdify dynamics, derived once per test session."""
    model = resolve_model(name)
    return model, gagen.load(model, backend="lambdify")


@functools.cache
def tree(seed: int, n_bodies: int, symbolic: bool):
    """A random tree, its lambdify dynamics and (for symbolic trees) parameter overrides."""
    rng = np.random.default_rng(seed)
    model = random_model(rng, n_bodies, symbolic)
    overrides = {}
    if symbolic:
        # change every parameter but one by up to 30 %, gravity included
        names = list(model.parameters)[:-1]
        overrides = {k: model.parameters[k] * float(rng.uniform(0.7, 1.3)) for k in names}
        assert len(overrides) >= 2
    return model, gagen.load(model, backend="lambdify"), overrides


def random_state(model, rng: np.random.Generator):
    """Angles over a full turn, modest slides, unit-size rates and accelerations."""
    rotates = np.array([b.joint.rotates for b in model.moving_bodies])
    n = model.dof
    q = np.where(rotates, rng.uniform(-np.pi, np.pi, n), rng.uniform(-0.5, 0.5, n))
    return q, rng.normal(size=n), rng.normal(size=n)


# ------------------------------------------------------------ against the references


@pytest.mark.parametrize("seed,n_bodies,symbolic", TREES)
def test_random_tree_matches_newton_euler_reference(seed, n_bodies, symbolic):
    model, dyn, overrides = tree(seed, n_bodies, symbolic)
    rng = np.random.default_rng(seed + 1)
    for p in ([None, overrides] if overrides else [None]):
        nm = numeric_model(model, p)
        for _ in range(3):
            q, qd, qdd = random_state(model, rng)
            tau = rnea(nm, q, qd, qdd)
            assert_close(dyn.inverse_dynamics(q, qd, qdd, p), tau)
            M = mass_matrix(nm, q)
            assert_close(dyn.mass_matrix(q, p), M)
            # M qdd = forcing, with tau the reference's torques for qdd
            assert_close(dyn.forcing(q, qd, tau, p), M @ qdd)
            tau2 = rng.normal(scale=3.0, size=model.dof)
            assert_close(dyn.forward_dynamics(q, qd, tau2, p), forward_dynamics(nm, q, qd, tau2))
            # both energies, the reference's V also summing over all bodies from the world origin
            assert_close(dyn.energy(q, qd, p), energy(nm, q, qd))


def test_overrides_change_the_numbers():
    """The symbolic trees' overrides reach the evaluation (else the test above proves little)."""
    for seed, n_bodies, symbolic in TREES:
        if not symbolic:
            continue
        model, dyn, overrides = tree(seed, n_bodies, symbolic)
        q, qd, qdd = random_state(model, np.random.default_rng(0))
        a, b = dyn.inverse_dynamics(q, qd, qdd), dyn.inverse_dynamics(q, qd, qdd, overrides)
        assert np.abs(a - b).max() > 1e-6 * np.abs(a).max()


@pytest.mark.parametrize("seed,n_bodies,symbolic", [TREES[k] for k in (1, 4, 6, 10)])
def test_random_tree_matches_pinocchio(seed, n_bodies, symbolic):
    pytest.importorskip("pinocchio")
    model, dyn, overrides = tree(seed, n_bodies, symbolic)
    p = overrides or None
    nm = numeric_model(model, p)
    pm = pin_model(nm)
    rng = np.random.default_rng(seed + 2)
    for _ in range(3):
        q, qd, qdd = random_state(model, rng)
        tau = rng.normal(scale=3.0, size=model.dof)
        ref = pin_dynamics(pm, q, qd, tau)
        assert_close(dyn.mass_matrix(q, p), ref["M"])
        assert_close(dyn.inverse_dynamics(q, qd, qdd, p), pin_rnea(pm, q, qd, qdd))
        assert_close(dyn.forward_dynamics(q, qd, tau, p), ref["qdd"])
        kinetic, potential = dyn.energy(q, qd, p)
        # pinocchio leaves out the bodies welded to the world; gagen counts them
        expected = np.array([ref["kinetic"], ref["potential"] + welded_potential(nm)])
        assert_close([kinetic, potential], expected)


def test_builtins_match_reference():
    rng = np.random.default_rng(7)
    for name in ("rrr", "chain:5"):
        model, dyn = loaded(name)
        nm = numeric_model(model)
        for _ in range(3):
            q, qd, qdd = random_state(model, rng)
            assert_close(dyn.inverse_dynamics(q, qd, qdd), rnea(nm, q, qd, qdd))
            assert_close(dyn.mass_matrix(q), mass_matrix(nm, q))
            assert_close(dyn.energy(q, qd), energy(nm, q, qd))


# ------------------------------------------------------------------- energy balance


def _power_balance_scale(qd, tau, kinetic, potential):
    return max(np.abs(qd * tau).sum(), 1e-3 * (abs(kinetic) + abs(potential)))


def test_rrr_energy_balance_symbolic():
    """d(T + V)/dt = dE/dq.qd + dE/dqd.qdd, from the explicit expressions, equals qd.tau."""
    model, dyn = loaded("rrr")
    eqs = derive(model)
    c = eqs.coords
    E = eqs.explicit(eqs.kinetic_energy + eqs.potential_energy)
    assert not {s for s, _ in eqs.intermediates} & E.free_symbols
    rate = sum(E.diff(x) * xd for x, xd in zip(c.q + c.qd, c.qd + c.qdd))
    f = sp.lambdify([c.q, c.qd, c.qdd, eqs.parameters], rate, modules="numpy")
    rng = np.random.default_rng(11)
    overrides = {"m2": 20.0, "L3": 0.7, "g": 3.0, "I1z": 2.0}
    for p in (None, overrides):
        pv = dyn.parameter_vector(p)
        for _ in range(5):
            q, qd, _ = random_state(model, rng)
            tau = rng.normal(scale=50.0, size=3)
            qdd = dyn.forward_dynamics(q, qd, tau, p)
            power = qd @ tau
            scale = _power_balance_scale(qd, tau, *dyn.energy(q, qd, p))
            assert abs(f(q, qd, qdd, pv) - power) <= 1e-10 * scale
            # with a wrong acceleration the balance fails (the check can fail)
            assert abs(f(q, qd, qdd + 0.01, pv) - power) > 1e-6 * scale


def energy_rate(dyn, q, qd, qdd, p=None) -> float:
    """d(T + V)/dt along (qd, qdd): central differences of E(q + s qd, qd + s qdd) at s = 0,
    Richardson-extrapolated (truncation error O(h^4))."""
    h = 1e-3
    s = np.array([h, -h, h / 2, -h / 2])
    kinetic, potential = dyn.energy(q + s[:, None] * qd, qd + s[:, None] * qdd, p)
    E = kinetic + potential
    d_h = (E[0] - E[1]) / (2 * h)
    d_half = (E[2] - E[3]) / h
    return (4 * d_half - d_h) / 3


@pytest.mark.parametrize("name", ["rrr", "chain:4"])
def test_builtin_energy_balance(name):
    model, dyn = loaded(name)
    rng = np.random.default_rng(12)
    for _ in range(5):
        q, qd, _ = random_state(model, rng)
        tau = rng.normal(scale=20.0, size=model.dof)
        qdd = dyn.forward_dynamics(q, qd, tau)
        scale = _power_balance_scale(qd, tau, *dyn.energy(q, qd))
        assert abs(energy_rate(dyn, q, qd, qdd) - qd @ tau) <= 1e-8 * scale
        # gravity counts: without it the balance is broken by the power of the weights
        assert abs(energy_rate(dyn, q, qd, qdd, {"g": 0.0}) - qd @ tau) > 1e-6 * scale


@pytest.mark.parametrize("seed,n_bodies,symbolic", TREES)
def test_random_tree_energy_balance(seed, n_bodies, symbolic):
    model, dyn, overrides = tree(seed, n_bodies, symbolic)
    rng = np.random.default_rng(seed + 3)
    for p in ([None, overrides] if overrides else [None]):
        for _ in range(3):
            q, qd, qdd_guess = random_state(model, rng)
            tau = dyn.inverse_dynamics(q, qd, qdd_guess, p)
            qdd = dyn.forward_dynamics(q, qd, tau, p)
            assert_close(qdd, qdd_guess, rtol=1e-8)
            scale = _power_balance_scale(qd, tau, *dyn.energy(q, qd, p))
            assert abs(energy_rate(dyn, q, qd, qdd, p) - qd @ tau) <= 1e-8 * scale


# --------------------------------------------------------------------- stacked inputs


STACK_MODELS = ["rrr", "chain:1", "tree"]


def _stack_dyn(name):
    if name == "tree":
        model, dyn, _ = tree(*TREES[6])  # 7 bodies, fixed and prismatic joints among them
        assert len(model.bodies) > model.dof
        return model, dyn
    return loaded(name)


@pytest.mark.parametrize("name", STACK_MODELS)
def test_stacked_equals_row_by_row(name):
    model, dyn = _stack_dyn(name)
    n = model.dof
    rng = np.random.default_rng(21)
    N = 5
    q = rng.uniform(-np.pi, np.pi, (N, n)) * 0.1
    qd, qdd, tau = rng.normal(size=(3, N, n))
    rows = range(N)
    M = dyn.mass_matrix(q)
    assert M.shape == (N, n, n)
    for k in rows:
        np.testing.assert_array_equal(M[k], dyn.mass_matrix(q[k]))
    cases = {
        "forcing": (dyn.forcing, (q, qd, tau)),
        "forward_dynamics": (dyn.forward_dynamics, (q, qd, tau)),
        "inverse_dynamics": (dyn.inverse_dynamics, (q, qd, qdd)),
    }
    for label, (fn, args) in cases.items():
        out = fn(*args)
        assert out.shape == (N, n), label
        for k in rows:
            assert_close(out[k], fn(*(a[k] for a in args)), rtol=1e-14)
    kinetic, potential = dyn.energy(q, qd)
    assert kinetic.shape == potential.shape == (N,)
    for k in rows:
        T_k, V_k = dyn.energy(q[k], qd[k])
        assert isinstance(T_k, float) and isinstance(V_k, float)
        assert kinetic[k] == pytest.approx(T_k, rel=1e-14, abs=1e-300)
        assert potential[k] == pytest.approx(V_k, rel=1e-14, abs=1e-12)
    # a stack of one is still a stack
    assert dyn.mass_matrix(q[:1]).shape == (1, n, n)
    assert dyn.inverse_dynamics(q[:1], qd[:1], qdd[:1]).shape == (1, n)
    assert dyn.energy(q[:1], qd[:1])[0].shape == (1,)


def test_stacked_inputs_broadcast_single_states():
    _, dyn = loaded("rrr")
    rng = np.random.default_rng(22)
    q = rng.normal(size=(4, 3))
    qd, tau = rng.normal(size=(2, 3))
    out = dyn.forward_dynamics(q, qd, tau)
    assert out.shape == (4, 3)
    for k in range(4):
        assert_close(out[k], dyn.forward_dynamics(q[k], qd, tau), rtol=1e-14)
    out = dyn.inverse_dynamics(q[0], rng.normal(size=(4, 3)), tau)
    assert out.shape == (4, 3)


def test_stacked_with_parameter_overrides():
    _, dyn = loaded("chain:3")
    rng = np.random.default_rng(23)
    q, qd = rng.normal(size=(2, 6, 3))
    p = {"m2": 5.0, "g": 1.62}
    M = dyn.mass_matrix(q, p)
    T, V = dyn.energy(q, qd, p)
    for k in range(6):
        np.testing.assert_array_equal(M[k], dyn.mass_matrix(q[k], p))
        assert T[k] == pytest.approx(0.5 * qd[k] @ M[k] @ qd[k], rel=1e-12)
        assert V[k] == pytest.approx(dyn.energy(q[k], qd[k], p)[1], rel=1e-14, abs=1e-12)


# -------------------------------------------------------------------- parameters, errors


@pytest.mark.parametrize("name", ["rrr", "tree"])
def test_overrides_by_dict_and_by_full_array_agree(name):
    model, dyn = _stack_dyn(name)
    names = list(dyn.parameters)
    assert names == list(model.parameters)
    rng = np.random.default_rng(24)
    overrides = {names[0]: 4.2, names[-1]: dyn.parameters[names[-1]] * 1.5}
    full = np.array([overrides.get(k, v) for k, v in dyn.parameters.items()])
    q, qd, qdd = random_state(model, rng)
    tau = rng.normal(size=model.dof)
    for p_array in (full, list(full), tuple(full)):
        np.testing.assert_array_equal(dyn.mass_matrix(q, overrides), dyn.mass_matrix(q, p_array))
        np.testing.assert_array_equal(dyn.forcing(q, qd, tau, overrides),
                                      dyn.forcing(q, qd, tau, p_array))
        np.testing.assert_array_equal(dyn.forward_dynamics(q, qd, tau, overrides),
                                      dyn.forward_dynamics(q, qd, tau, p_array))
        np.testing.assert_array_equal(dyn.inverse_dynamics(q, qd, qdd, overrides),
                                      dyn.inverse_dynamics(q, qd, qdd, p_array))
        assert dyn.energy(q, qd, overrides) == dyn.energy(q, qd, p_array)
    # the defaults as a dict, as an empty dict, as an array and as None are the same
    defaults = np.array(list(dyn.parameters.values()))
    for p in ({}, dict(dyn.parameters), defaults):
        np.testing.assert_array_equal(dyn.inverse_dynamics(q, qd, qdd, p),
                                      dyn.inverse_dynamics(q, qd, qdd))
    # and the override is not ignored
    assert not np.array_equal(dyn.inverse_dynamics(q, qd, qdd, overrides),
                              dyn.inverse_dynamics(q, qd, qdd))
    # the caller's dict is left alone, and dyn.parameters is a copy
    assert overrides == {names[0]: 4.2, names[-1]: model.parameters[names[-1]] * 1.5}
    dyn.parameters[names[0]] = -1.0
    assert dyn.parameters[names[0]] == model.parameters[names[0]]


def test_unknown_parameter_name_raises_key_error():
    _, dyn = loaded("rrr")
    q = np.zeros(3)
    with pytest.raises(KeyError, match="nope"):
        dyn.mass_matrix(q, {"nope": 1.0})
    with pytest.raises(KeyError, match="G"):
        dyn.forcing(q, q, q, {"g": 1.0, "G": 1.0})
    with pytest.raises(KeyError):
        dyn.energy(q, q, {"q1": 1.0})  # a coordinate is not a parameter


def test_non_numeric_override_value_is_not_an_unknown_name():
    _, dyn = loaded("rrr")
    with pytest.raises((TypeError, ValueError)):
        dyn.mass_matrix(np.zeros(3), {"g": "abc"})


def test_wrong_shapes_raise_value_error():
    _, dyn = loaded("rrr")
    z = np.zeros(3)
    bad_q = [np.zeros(2), np.zeros(4), np.zeros((5, 2)), np.zeros((2, 2, 3)), np.float64(0.0),
             np.zeros((3, 1)), [], np.zeros((0,))]
    for q in bad_q:
        with pytest.raises(ValueError):
            dyn.mass_matrix(q)
        with pytest.raises(ValueError):
            dyn.forward_dynamics(q, z, z)
        with pytest.raises(ValueError):
            dyn.energy(z, q)
        with pytest.raises(ValueError):
            dyn.inverse_dynamics(z, z, q)
    with pytest.raises(ValueError, match="rows"):
        dyn.forcing(np.zeros((4, 3)), np.zeros((5, 3)), z)
    with pytest.raises(ValueError, match="rows"):
        dyn.inverse_dynamics(z, np.zeros((2, 3)), np.zeros((3, 3)))
    for p in (np.zeros(len(dyn.parameters) - 1), np.zeros(len(dyn.parameters) + 1),
              np.zeros((1, len(dyn.parameters))), 9.81):
        with pytest.raises(ValueError):
            dyn.mass_matrix(z, p)


def test_non_numeric_inputs_raise_type_error():
    _, dyn = loaded("rrr")
    z = np.zeros(3)
    for bad in ("abc", "0 0 0", b"abc", None, ["a", "b", "c"], [None, None, None],
                np.array([1j, 0, 0])):
        with pytest.raises(TypeError):
            dyn.mass_matrix(bad)
        with pytest.raises(TypeError):
            dyn.forcing(z, bad, z)
        with pytest.raises(TypeError):
            dyn.forward_dynamics(z, z, bad)
        with pytest.raises(TypeError):
            dyn.inverse_dynamics(z, z, bad)
        with pytest.raises(TypeError):
            dyn.energy(bad, z)
    # integers and booleans are numbers
    np.testing.assert_array_equal(dyn.mass_matrix([0, 0, 0]), dyn.mass_matrix(z))
    np.testing.assert_array_equal(dyn.mass_matrix(np.zeros(3, dtype=bool)), dyn.mass_matrix(z))


# -------------------------------------------------------------------------- chain:N


@pytest.mark.parametrize("n", range(1, 9))
def test_chain_mass_matrix_spd_and_kinetic_energy(n):
    model, dyn = loaded(f"chain:{n}")
    assert dyn.coordinates == [f"q{i}" for i in range(1, n + 1)]
    assert len(dyn.parameters) == 1 + 5 * n
    nm = numeric_model(model)
    rng = np.random.default_rng(30 + n)
    q = rng.uniform(-np.pi, np.pi, (6, n))
    qd = rng.normal(size=(6, n))
    M = dyn.mass_matrix(q)
    kinetic, potential = dyn.energy(q, qd)
    for k in range(6):
        np.testing.assert_allclose(M[k], M[k].T, rtol=0, atol=1e-14 * np.abs(M[k]).max())
        eig = np.linalg.eigvalsh(M[k])
        assert eig.min() > 1e-9 * eig.max()
        np.linalg.cholesky(M[k])
        assert kinetic[k] == pytest.approx(0.5 * qd[k] @ M[k] @ qd[k], rel=1e-12)
        assert_close(M[k], mass_matrix(nm, q[k]))
        assert potential[k] == pytest.approx(energy(nm, q[k], qd[k])[1], rel=1e-10, abs=1e-10)


def test_chain_derivation_structure():
    eqs = derive(resolve_model("chain:6"))
    n = eqs.n
    assert n == 6 and eqs.mass_matrix.shape == (6, 6)
    assert eqs.mass_matrix == eqs.mass_matrix.T
    assert len(eqs.gibbs) == 6 and eqs.seconds > 0
    # the intermediates are defined in order, each in terms of earlier ones only
    seen: set[sp.Symbol] = set()
    names = {s for s, _ in eqs.intermediates}
    for symbol, expr in eqs.intermediates:
        assert (expr.free_symbols & names) <= seen, symbol
        seen.add(symbol)
    # M is free of velocities and torques; the inverse dynamics of torques; forcing of qdd
    c = eqs.coords
    subs = eqs.substitutions()
    explicit_syms = set().union(*(subs[s].free_symbols for s in names))
    assert not explicit_syms & set(c.qdd + c.tau)
    assert not eqs.explicit(eqs.mass_matrix).free_symbols & set(c.qd + c.qdd + c.tau)
    assert not eqs.explicit(eqs.inverse_dynamics).free_symbols & set(c.tau)
    assert not eqs.explicit(eqs.forcing).free_symbols & set(c.qdd)
    out = eqs.outputs()
    assert len(out["mass_matrix"]) == n * (n + 1) // 2 and len(out["energy"]) == 2


# ------------------------------------------------------------------------ model files


RRR_DOC = {
    "name": "rrr_file",
    "gravity": [0, 0, "-g"],
    "parameters": {"g": 9.81, "L1": 0.4, "L2": 0.4, "L3": 0.4, "m1": 60.0, "m2": 50.0,
                   "m3": 40.0, "I1x": 0.8, "I1y": 0.075, "I1z": 0.8,
                   "I2x": 0.6666666666666666, "I2y": 0.0625, "I2z": 0.6666666666666666,
                   "I3x": 0.5333333333333333, "I3y": 0.05, "I3z": 0.5333333333333333},
    "bodies": [
        {"name": "link1", "parent": "world",
         "joint": {"name": "q1", "type": "revolute", "origin": {"xyz": [0, 0, 0]},
                   "axis": [0, 0, 1]},
         "mass": "m1", "com": [0, "L1/2", 0], "inertia": ["I1x", "I1y", "I1z", 0, 0, 0]},
        {"name": "link2", "parent": "link1",
         "joint": {"name": "q2", "type": "revolute", "origin": {"xyz": [0, "L1", 0]},
                   "axis": [1, 0, 0]},
         "mass": "m2", "com": [0, "L2/2", 0], "inertia": ["I2x", "I2y", "I2z", 0, 0, 0]},
        {"name": "link3", "parent": "link2",
         "joint": {"name": "q3", "type": "revolute", "origin": {"xyz": [0, "L2", 0]},
                   "axis": [1, 0, 0]},
         "mass": "m3", "com": [0, "L3/2", 0], "inertia": ["I3x", "I3y", "I3z", 0, 0, 0]},
    ],
}

RRR_YAML = """\
# the paper's robot, written out by hand
name: rrr_file
gravity: [0, 0, -g]
parameters:
  {g: 9.81, L1: 0.4, L2: 0.4, L3: 0.4, m1: 60.0, m2: 50.0, m3: 40.0,
   I1x: 0.8, I1y: 0.075, I1z: 0.8, I2x: 0.6666666666666666, I2y: 0.0625,
   I2z: 0.6666666666666666, I3x: 0.5333333333333333, I3y: 0.05, I3z: 0.5333333333333333}
bodies:
  - name: link1
    joint: {type: revolute, axis: [0, 0, 1]}          # name q1 and parent world by default
    mass: m1
    com: [0, L1/2, 0]
    inertia: [I1x, I1y, I1z, 0, 0, 0]
  - name: link2
    parent: link1
    joint: {name: q2, type: revolute, origin: {xyz: [0, L1, 0], rpy: [0, 0, 0]}, axis: [1, 0, 0]}
    mass: m2
    com: [0, L2 / 2, 0]
    inertia: [I2x, I2y, I2z, 0, 0, 0]
  - name: link3
    parent: link2
    joint: {name: q3, origin: {xyz: [0, L2, 0]}, axis: [1, 0, 0]}   # revolute by default
    mass: m3
    com: [0, 0.5*L3, 0]
    inertia: [I3x, I3y, I3z, 0, 0, 0]
"""


def _rrr_files(tmp_path):
    paths = {"yaml": tmp_path / "rrr.yaml", "yml": tmp_path / "rrr_copy.yml",
             "json": tmp_path / "rrr.json", "dumped": tmp_path / "dumped.yaml"}
    paths["yaml"].write_text(RRR_YAML)
    paths["yml"].write_text(RRR_YAML)
    paths["json"].write_text(json.dumps(RRR_DOC, indent=1))
    paths["dumped"].write_text(yaml.safe_dump(RRR_DOC))
    return paths


def test_rrr_model_files_match_builtin(tmp_path):
    _, builtin = loaded("rrr")
    rng = np.random.default_rng(40)
    states = rng.normal(size=(4, 5, 3))
    q, qd, qdd, tau = states
    p = {"m3": 10.0, "L2": 0.9, "g": 1.0}
    for kind, path in _rrr_files(tmp_path).items():
        dyn = gagen.load(path, backend="lambdify")
        assert dyn.model.source == str(path), kind
        assert dyn.coordinates == builtin.coordinates == ["q1", "q2", "q3"]
        assert dyn.parameters == builtin.parameters
        for pp in (None, p):
            assert_close(dyn.mass_matrix(q, pp), builtin.mass_matrix(q, pp), rtol=1e-14)
            assert_close(dyn.forcing(q, qd, tau, pp), builtin.forcing(q, qd, tau, pp), rtol=1e-14)
            assert_close(dyn.forward_dynamics(q, qd, tau, pp),
                         builtin.forward_dynamics(q, qd, tau, pp), rtol=1e-12)
            assert_close(dyn.inverse_dynamics(q, qd, qdd, pp),
                         builtin.inverse_dynamics(q, qd, qdd, pp), rtol=1e-14)
            assert_close(dyn.energy(q, qd, pp), builtin.energy(q, qd, pp), rtol=1e-14)
        # also the same model, up to its name and source
        model = resolve_model(path)
        assert model.name == "rrr_file"
        assert model.dof == 3 and [b.parent for b in model.bodies] == ["world", "link1", "link2"]


WEIRD_YAML = """\
name: weird
gravity: [0.5, -1, -g]
parameters:
  g: 9.81
  m.1: 2.0
  "I_{xx}": 0.3
  lambda: 0.25
  d: 0.4
bodies:
  - name: base_plate          # welded to the world: no coordinate, but it has weight
    joint: {type: fixed, origin: {xyz: [0.1, 0, 0.2], rpy: [0, 0.2, 0]}}
    mass: 3.0
    com: [0, 0, 0.05]
    inertia: [0.02, 0.02, 0.03, 0, 0, 0]
  - name: b1
    parent: base_plate
    joint: {name: shoulder, type: revolute, axis: [1, 1, 0], origin: {xyz: [0, 0, d]}}
    mass: m.1
    com: [0, d/2, lambda]
    inertia: ["I_{xx}", "0.8*I_{xx}", "I_{xx}*0.6", 0.01, 0, 0]
  - name: tool
    parent: b1
    joint: {type: fixed, origin: {xyz: [0, d, 0], rpy: [0.3, -0.2, 1.0]}}
    mass: 2*m.1
    com: [0, 0, 0.1]
    inertia: [0.01, 0.012, 0.015, 0, 0, 0.001]
  - name: slider
    parent: tool
    joint: {type: prismatic, axis: [0, 1, 2]}
    mass: 0.5 + lambda
    com: [0.05, 0, 0]
    inertia: [0.001, 0.002, 0.002, 0, 0, 0]
  - name: wrist
    parent: b1
    joint: {type: continuous, axis: [0, 0, 1], origin: {xyz: [0, d, 0]}}
    mass: "m.1 / 2"
    com: [0, 0.05, 0]
    inertia: ["I_{xx} / 10", "I_{xx} / 10", "I_{xx} / 20", 0, 0, 0]
"""


@pytest.mark.parametrize("fmt", ["yaml", "json"])
def test_odd_parameter_names_and_fixed_joints(tmp_path, fmt):
    path = tmp_path / f"weird.{fmt}"
    path.write_text(WEIRD_YAML if fmt == "yaml" else json.dumps(yaml.safe_load(WEIRD_YAML)))
    model = resolve_model(path)
    assert set(model.parameters) == {"g", "m.1", "I_{xx}", "lambda", "d"}
    assert sp.Symbol("m.1") in model.bodies[1].mass.free_symbols
    # coordinates: moving joints only, named or numbered in file order (q2 is the slider)
    assert model.coordinates == ["shoulder", "q2", "q3"]
    assert len(model.bodies) == 5 and model.dof == 3
    dyn = gagen.load(path, backend="lambdify")
    rng = np.random.default_rng(41)
    for p in (None, {"m.1": 3.5, "I_{xx}": 0.5, "lambda": -0.1, "g": 5.0}):
        nm = numeric_model(model, p)
        for _ in range(3):
            q, qd, qdd = random_state(model, rng)
            assert_close(dyn.inverse_dynamics(q, qd, qdd, p), rnea(nm, q, qd, qdd))
            assert_close(dyn.mass_matrix(q, p), mass_matrix(nm, q))
            tau = rng.normal(size=3)
            assert_close(dyn.forward_dynamics(q, qd, tau, p), forward_dynamics(nm, q, qd, tau))
            assert_close(dyn.energy(q, qd, p), energy(nm, q, qd))
    # the welded base has weight, so the potential energies above counted it
    assert abs(welded_potential(numeric_model(model))) > 0.1
