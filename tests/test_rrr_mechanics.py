"""The paper's robot against an independent derivation with sympy.physics.mechanics (Kane)."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import gagen
from gagen.reference.kane import kane_rrr
from gagen.symbolic.gibbs_appell import derive, joint_torque_forces


@pytest.fixture(scope="module")
def both():
    km, q, u, T = kane_rrr()
    eqs = derive(gagen.resolve_model("rrr"))
    c = eqs.coords
    to_plain = {}
    for i in range(3):
        to_plain[u[i].diff()] = c.qdd[i]
        to_plain[u[i]] = c.qd[i]
        to_plain[q[i]] = c.q[i]
        to_plain[T[i]] = c.tau[i]
    M_kane = km.mass_matrix.subs(to_plain)
    F_kane = km.forcing.subs(to_plain)
    return eqs, M_kane, F_kane


def test_mass_matrix_equals_kane_symbolically(both):
    eqs, M_kane, _ = both
    M = eqs.explicit(eqs.mass_matrix)
    assert sp.simplify(M - M_kane) == sp.zeros(3, 3)


def test_forcing_equals_kane_symbolically(both):
    eqs, _, F_kane = both
    F = eqs.explicit(eqs.forcing)
    diff = (F - F_kane).applyfunc(lambda e: sp.simplify(sp.expand(e)))
    assert diff == sp.zeros(3, 1)


def test_inverse_dynamics_is_gibbs_appell(both):
    """tau = dS/dqdd - Q_gravity, with S the sum of the bodies' Gibbs functions."""
    eqs, M_kane, F_kane = both
    c = eqs.coords
    qdd = sp.Matrix(c.qdd)
    tau_kane = (M_kane * qdd - F_kane).subs({t: 0 for t in c.tau})
    rng = np.random.default_rng(0)
    for _ in range(5):
        values = {s: float(v) for s, v in zip(c.q + c.qd + c.qdd, rng.normal(size=9))}
        values.update({sp.Symbol(k): v for k, v in eqs.model.parameters.items()})
        ours = eqs.explicit(eqs.inverse_dynamics).xreplace(values)
        theirs = tau_kane.xreplace(values)
        np.testing.assert_allclose(np.array(ours, float), np.array(theirs, float), rtol=1e-12)


def test_gibbs_function_derivative_gives_mass_matrix(both):
    """Eq. 6: d(S1+S2+S3)/dqdd_r, differentiated here from the explicit S, equals (M qdd + b)_r."""
    eqs, _, _ = both
    c = eqs.coords
    S = eqs.explicit(sum(eqs.gibbs))
    grad = sp.Matrix([sp.diff(S, a) for a in c.qdd])
    lhs = eqs.explicit(eqs.mass_matrix * sp.Matrix(c.qdd) + eqs.velocity_terms)
    rng = np.random.default_rng(1)
    values = {s: float(v) for s, v in zip(c.q + c.qd + c.qdd, rng.normal(size=9))}
    values.update({sp.Symbol(k): v for k, v in eqs.model.parameters.items()})
    np.testing.assert_allclose(np.array(grad.xreplace(values), float),
                               np.array(lhs.xreplace(values), float), rtol=1e-12)


def test_joint_couples_reduce_to_tau(both):
    """Eqs. 7-10: the couples T01, T12, T23 and their reactions give Q_r = tau_r."""
    eqs, _, _ = both
    Q = joint_torque_forces(eqs.model, eqs.kinematics, eqs.coords)
    Q = eqs.explicit(Q).applyfunc(lambda e: sp.simplify(sp.expand(e)))
    assert Q == sp.Matrix(eqs.coords.tau)


def test_lambdify_backend_matches_kane_numerically(both):
    eqs, M_kane, F_kane = both
    dyn = gagen.load("rrr", backend="lambdify")
    c = eqs.coords
    params = {sp.Symbol(k): v for k, v in dyn.parameters.items()}
    fM = sp.lambdify(c.q, M_kane.xreplace(params))
    fF = sp.lambdify(c.q + c.qd + c.tau, F_kane.xreplace(params))
    rng = np.random.default_rng(2)
    for _ in range(20):
        q, qd, tau = rng.uniform(-3, 3, size=(3, 3))
        M = np.array(fM(*q), float)
        F = np.array(fF(*q, *qd, *tau), float).ravel()
        np.testing.assert_allclose(dyn.mass_matrix(q), M, rtol=1e-12, atol=1e-12 * np.abs(M).max())
        np.testing.assert_allclose(dyn.forcing(q, qd, tau), F, rtol=1e-12,
                                   atol=1e-12 * np.abs(F).max())
        np.testing.assert_allclose(dyn.forward_dynamics(q, qd, tau), np.linalg.solve(M, F),
                                   rtol=1e-10)
