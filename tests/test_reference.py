"""Checks of the numerical references themselves: against pinocchio and against physics."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from random_trees import random_model
from reference import (
    energy,
    forward_dynamics,
    mass_matrix,
    numeric_model,
    pin_dynamics,
    pin_energy,
    pin_mass_matrix,
    pin_model,
    pin_rnea,
    rnea,
    welded_potential,
)

from gagen.model import Body, Joint, Model, inertia_matrix, vector

# (seed, bodies, symbolic): small and larger trees, numeric and parametrized
TREES = [(seed, 1 + seed % 8, seed % 3 == 0) for seed in range(10)]
RTOL = 1e-10


def assert_close(actual, expected, rtol: float = RTOL) -> None:
    """Norm-wise relative comparison: entries near zero are judged against the largest."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    scale = max(np.abs(expected).max(initial=0.0), np.abs(actual).max(initial=0.0), 1e-12)
    err = np.abs(actual - expected).max(initial=0.0)
    assert err <= rtol * scale, f"error {err:.3g} > {rtol:g} * {scale:.3g}\n{actual}\n{expected}"


def random_state(nm, rng: np.random.Generator):
    """Angles over a full turn, modest slides, unit-size rates."""
    rotates = np.array([b.rotates for b in nm.bodies if b.coordinate is not None], dtype=bool)
    q = np.where(rotates, rng.uniform(-np.pi, np.pi, nm.dof), rng.uniform(-0.5, 0.5, nm.dof))
    return q, rng.normal(size=nm.dof), rng.normal(size=nm.dof), rng.normal(scale=3.0, size=nm.dof)


def tree(seed: int, n: int, symbolic: bool):
    rng = np.random.default_rng(seed)
    return numeric_model(random_model(rng, n, symbolic)), rng


# --------------------------------------------------------------------- random trees


@pytest.mark.parametrize("seed,n,symbolic", TREES)
def test_random_model_is_valid_and_mixed(seed, n, symbolic):
    model = random_model(np.random.default_rng(seed), n, symbolic)
    assert len(model.bodies) == n and model.dof >= 1
    assert model.parameters["g"] == 9.81
    if symbolic:
        assert any(k.startswith("m") for k in model.parameters)
    for b in model.moving_bodies:
        axis = np.array([float(a) for a in b.joint.axis])
        assert np.abs(axis).min() > 0.05 and not np.isclose(np.linalg.norm(axis), 1.0)


def test_random_models_cover_all_joint_types():
    types = {b.joint.type for seed in range(10)
             for b in random_model(np.random.default_rng(seed), 8).bodies}
    assert types == {"revolute", "continuous", "prismatic", "fixed"}


def test_numeric_model_overrides_parameters():
    model = random_model(np.random.default_rng(3), 4, symbolic=True)
    assert_close(numeric_model(model).gravity, [0, 0, -9.81])
    nm = numeric_model(model, {"g": 1.5, "m1": 7.0})
    assert_close(nm.gravity, [0, 0, -1.5])
    assert nm.bodies[0].mass == 7.0
    # the inertia is m1 times a fixed unit inertia, so it scales with the override
    base = numeric_model(model).bodies[0]
    assert_close(nm.bodies[0].inertia, base.inertia * 7.0 / base.mass)
    with pytest.raises(KeyError):
        numeric_model(model, {"nope": 1.0})


# ------------------------------------------------------------------------ pinocchio


@pytest.mark.parametrize("seed,n,symbolic", TREES)
def test_rnea_matches_pinocchio(seed, n, symbolic):
    pytest.importorskip("pinocchio")
    nm, rng = tree(seed, n, symbolic)
    pm = pin_model(nm)
    for _ in range(3):
        q, qd, qdd, _tau = random_state(nm, rng)
        assert_close(rnea(nm, q, qd, qdd), pin_rnea(pm, q, qd, qdd))


@pytest.mark.parametrize("seed,n,symbolic", TREES)
def test_mass_matrix_matches_pinocchio_crba(seed, n, symbolic):
    pytest.importorskip("pinocchio")
    nm, rng = tree(seed, n, symbolic)
    pm = pin_model(nm)
    for _ in range(3):
        q = random_state(nm, rng)[0]
        M = mass_matrix(nm, q)
        assert_close(M, pin_mass_matrix(pm, q))
        assert np.linalg.eigvalsh(M).min() > 0


@pytest.mark.parametrize("seed,n,symbolic", TREES)
def test_energy_and_forward_dynamics_match_pinocchio(seed, n, symbolic):
    pytest.importorskip("pinocchio")
    nm, rng = tree(seed, n, symbolic)
    pm = pin_model(nm)
    offset = welded_potential(nm)  # pinocchio leaves out bodies welded to the world
    for _ in range(3):
        q, qd, _qdd, tau = random_state(nm, rng)
        kinetic, potential = energy(nm, q, qd)
        pin_kinetic, pin_potential = pin_energy(pm, q, qd)
        assert_close(kinetic, pin_kinetic)
        assert_close(potential, pin_potential + offset)
        assert_close(forward_dynamics(nm, q, qd, tau), pin_dynamics(pm, q, qd, tau)["qdd"], 1e-9)


def test_pinocchio_potential_convention():
    """A point mass at height h above the world origin: pinocchio's V = +m g h = -m g.r."""
    pytest.importorskip("pinocchio")
    nm = numeric_model(pendulum(length=-2.0, axis=(1, 0, 0)))  # mass centre at z = +2
    pm = pin_model(nm)
    assert_close(pin_energy(pm, [0.0], [0.0])[1], 3.0 * 9.81 * 2.0)
    assert_close(energy(nm, [0.0], [0.0])[1], 3.0 * 9.81 * 2.0)


# -------------------------------------------------------------------------- physics


def pendulum(length: float = 0.7, axis=(2, 0, 0), mass: float = 3.0, ixx: float = 0.05) -> Model:
    """A single body hinged at the world origin, mass centre at z = -length."""
    joint = Joint(name="q", type="revolute", axis=vector(axis))
    body = Body(name="bob", parent="world", joint=joint, mass=sp.Float(mass),
                com=vector([0, 0, -length]), inertia=inertia_matrix(ixx, 0.02, 0.03))
    return Model(name="pendulum", bodies=(body,), parameters={"g": 9.81},
                 gravity=vector([0, 0, -sp.Symbol("g")]))


def test_pendulum_matches_textbook():
    m, l_, ixx, g = 3.0, 0.7, 0.05, 9.81
    nm = numeric_model(pendulum(l_, axis=(2, 0, 0), mass=m, ixx=ixx))  # non-unit axis
    rng = np.random.default_rng(0)
    for q, qd, qdd in rng.normal(size=(5, 3)):
        expected = (ixx + m * l_**2) * qdd + m * g * l_ * np.sin(q)
        assert_close(rnea(nm, [q], [qd], [qdd]), [expected])
        kinetic, potential = energy(nm, [q], [qd])
        assert_close(kinetic, 0.5 * (ixx + m * l_**2) * qd**2)
        assert_close(potential, -m * g * l_ * np.cos(q))


def test_prismatic_body_in_gravity():
    """A slider along a tilted axis: tau = m (qdd - g . axis), independent of q."""
    axis = np.array([1.0, 2.0, -2.0])
    joint = Joint(name="s", type="prismatic", axis=vector(axis))
    body = Body(name="slider", parent="world", joint=joint, mass=sp.Float(2.0),
                com=vector([0.1, 0.2, 0.3]), inertia=inertia_matrix(0.1, 0.1, 0.1))
    model = Model(name="slider", bodies=(body,), parameters={"g": 9.81},
                  gravity=vector([0, 0, -sp.Symbol("g")]))
    nm = numeric_model(model)
    u = axis / 3.0
    assert_close(rnea(nm, [0.4], [1.3], [0.7]), [2.0 * (0.7 - np.array([0, 0, -9.81]) @ u)])


def rk4_step(nm, q, qd, tau, h):
    def f(x):
        return np.concatenate([x[nm.dof:], forward_dynamics(nm, x[:nm.dof], x[nm.dof:], tau)])

    x = np.concatenate([q, qd])
    k1 = f(x)
    k2 = f(x + 0.5 * h * k1)
    k3 = f(x + 0.5 * h * k2)
    k4 = f(x + h * k3)
    x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x[:nm.dof], x[nm.dof:]


@pytest.mark.parametrize("seed,n,symbolic", TREES)
def test_energy_balance_along_trajectory(seed, n, symbolic):
    """d/dt (T + V) = qd . tau, by a central difference over one RK4 step each way."""
    nm, rng = tree(seed, n, symbolic)
    q, qd, _qdd, tau = random_state(nm, rng)
    h = 1e-4
    total = [sum(energy(nm, *rk4_step(nm, q, qd, tau, s))) for s in (-h, h)]
    rate = (total[1] - total[0]) / (2 * h)
    power = qd @ tau
    scale = max(abs(power), np.abs(qd) @ np.abs(tau), abs(rate))
    assert abs(rate - power) <= 1e-6 * scale


@pytest.mark.parametrize("seed,n,symbolic", TREES[:5])
def test_lagrangian_consistency(seed, n, symbolic):
    """T = qd.M.qd/2, gravity forces = dV/dq, and rnea inverts forward dynamics."""
    nm, rng = tree(seed, n, symbolic)
    q, qd, _qdd, tau = random_state(nm, rng)
    M = mass_matrix(nm, q)
    assert_close(energy(nm, q, qd)[0], 0.5 * qd @ M @ qd)
    h = 1e-6
    dV = [(energy(nm, q + h * e, qd)[1] - energy(nm, q - h * e, qd)[1]) / (2 * h)
          for e in np.eye(nm.dof)]
    zero = np.zeros(nm.dof)
    assert_close(rnea(nm, q, zero, zero), dV, 1e-7)
    assert_close(rnea(nm, q, qd, forward_dynamics(nm, q, qd, tau)), tau)
