"""Joint damping, Coulomb friction and armature (gagen.symbolic.joints).

References: a 1-DOF pendulum by hand; Pinocchio's rnea, crba and aba (armature included)
with damping and friction added by hand, and gagen's world-frame Newton-Euler in
tests/reference.py, on random trees; both derivations and the ABA against each other.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import sympy as sp
from random_trees import random_model
from reference import mass_matrix, numeric_model, pin_mass_matrix, pin_model, pin_rnea, rnea

import gagen
from gagen.errors import ModelError
from gagen.model.modelfile import parse_model_text
from gagen.model.urdf import parse_urdf_text
from gagen.runtime.lambdify import LambdifyDynamics
from gagen.symbolic.aba import forward_dynamics_aba
from gagen.symbolic.derivation import derive_equations

PENDULUM = """
name: pendulum1
gravity: [0, 0, -g]
parameters: {g: 9.81, m: 2.0, L: 0.5, I: 0.03, d: 0.4, f: 0.7, a: 0.2}
bodies:
  - name: link
    joint: {name: q, type: revolute, axis: [0, 1, 0], damping: d, friction: f, armature: a}
    mass: m
    com: [0, 0, -L]
    inertia: [I, I, I, 0, 0, 0]
"""

ARM = """
name: arm_terms
gravity: [0, 0, -g]
parameters: {g: 9.81, d1: 0.3, f1: 0.5, a1: 0.15, L: 0.4}
bodies:
  - name: upper
    joint: {name: shoulder, axis: [0, 1, 0], damping: d1, friction: 2*f1, armature: a1}
    mass: 2.0
    com: [0, 0, -0.2]
    inertia: [0.03, 0.03, 0.002, 0, 0, 0]
  - name: slider
    parent: upper
    joint: {name: slide, type: prismatic, axis: [0, 0, 1], origin: {xyz: [0, 0, -L]},
            damping: 1.5, friction: 0.25, armature: 0.05}
    mass: 0.7
    com: [0.01, 0, -0.05]
    inertia: [0.002, 0.002, 0.001, 0, 0, 0]
  - name: tool
    parent: slider
    joint: {type: fixed, origin: {xyz: [0, 0.05, -0.1]}}
    mass: 0.3
    com: [0, 0, -0.02]
    inertia: [0.0004, 0.0004, 0.0002, 0, 0, 0]
"""


def by_hand(q, qd, qdd, v):
    """The pendulum: (I + m L^2 + a) qdd + m g L sin q + d qd + f sign(qd)."""
    J = v["I"] + v["m"] * v["L"] ** 2 + v["a"]
    return J * qdd + v["m"] * v["g"] * v["L"] * math.sin(q) + v["d"] * qd \
        + v["f"] * np.sign(qd), J


@pytest.fixture(scope="module")
def pendulum_model():
    return parse_model_text(PENDULUM, "pendulum.yaml")


@pytest.fixture(scope="module", params=["lambdify", "compiled"])
def pendulum(request, pendulum_model):
    return gagen.load(pendulum_model, backend=request.param)


def test_pendulum_by_hand(pendulum):
    dyn = pendulum
    rng = np.random.default_rng(1)
    for overrides in ({}, {"d": 1.1, "f": 0.05, "a": 0.9, "m": 3.0}):
        v = {**dyn.parameters, **overrides}
        for q, qd, qdd in rng.normal(size=(5, 3)):
            tau, J = by_hand(q, qd, qdd, v)
            assert dyn.inverse_dynamics([q], [qd], [qdd], overrides)[0] == pytest.approx(
                tau, rel=1e-13, abs=1e-13)
            assert dyn.mass_matrix([q], overrides)[0, 0] == pytest.approx(J, rel=1e-14)
            assert dyn.forward_dynamics([q], [qd], [tau], overrides)[0] == pytest.approx(
                qdd, rel=1e-12, abs=1e-12)
            assert dyn.forcing([q], [qd], [tau], overrides)[0] == pytest.approx(
                J * qdd, rel=1e-12, abs=1e-12)
            kinetic, _ = dyn.energy([q], [qd], overrides)
            assert kinetic == pytest.approx(J * qd**2 / 2, rel=1e-14)


def test_coulomb_friction_is_the_exact_sign(pendulum):
    """sign(0) = 0, and forward/inverse dynamics never smooth it, whatever coulomb_width."""
    dyn = pendulum
    v = dyn.parameters
    assert v["coulomb_width"] == 0.01
    for qd in (0.0, 1e-9, -1e-6, 2.0):
        tau, _J = by_hand(0.3, qd, 0.0, v)
        assert dyn.inverse_dynamics([0.3], [qd], [0.0])[0] == pytest.approx(tau, rel=1e-13)
        assert dyn.forward_dynamics([0.3], [qd], [tau])[0] == pytest.approx(0.0, abs=1e-12)
        assert dyn.forward_dynamics([0.3], [qd], [tau], {"coulomb_width": 5.0})[0] == \
            pytest.approx(0.0, abs=1e-12)
    friction = dyn.inverse_dynamics([0.3], [1e-9], [0.0])[0] - \
        dyn.inverse_dynamics([0.3], [0.0], [0.0])[0]
    assert friction == pytest.approx(v["f"], rel=1e-6)


def test_arm_with_fixed_body_matches_references():
    """Revolute and prismatic joints with expressions, a fixed body: gagen's own world-frame
    Newton-Euler and Pinocchio (rnea, crba) with the joint terms added by hand."""
    pytest.importorskip("pinocchio")
    model = parse_model_text(ARM, "arm.yaml")
    overrides = {"d1": 0.8, "f1": 0.1, "a1": 0.4}
    rng = np.random.default_rng(2)
    for derivation in ("gibbs-appell", "recursive"):
        dyn = LambdifyDynamics(derive_equations(model, derivation))
        for p in (None, overrides):
            nm = numeric_model(model, p)
            pm = pin_model(nm)
            for q, qd, qdd in rng.normal(size=(4, 3, 2)):
                tau = dyn.inverse_dynamics(q, qd, qdd, p)
                np.testing.assert_allclose(tau, rnea(nm, q, qd, qdd), rtol=1e-11, atol=1e-11)
                np.testing.assert_allclose(tau, pin_rnea(pm, q, qd, qdd), rtol=1e-10,
                                           atol=1e-10)
                np.testing.assert_allclose(dyn.mass_matrix(q, p), pin_mass_matrix(pm, q),
                                           rtol=1e-11, atol=1e-12)
                np.testing.assert_allclose(dyn.mass_matrix(q, p), mass_matrix(nm, q),
                                           rtol=1e-11, atol=1e-12)
                np.testing.assert_allclose(dyn.forward_dynamics(q, qd, tau, p), qdd,
                                           rtol=1e-9, atol=1e-9)


def with_random_joint_terms(model, rng, symbolic: bool):
    """The model with random damping, friction and armature on every moving joint (numbers,
    or parameters `d<k>`, `f<k>`, `a<k>` with random defaults)."""
    parameters = dict(model.parameters)
    bodies = []
    for k, body in enumerate(model.bodies):
        if not body.joint.moves:
            bodies.append(body)
            continue
        values = dict(zip(("damping", "friction", "armature"), rng.uniform(0.05, 1.0, 3)))
        if symbolic:
            for key, value in values.items():
                parameters[f"{key[0]}{k}"] = float(value)
            values = {key: sp.Symbol(f"{key[0]}{k}") for key in values}
        else:
            values = {key: sp.Float(float(v)) for key, v in values.items()}
        bodies.append(replace(body, joint=replace(body.joint, **values)))
    return replace(model, bodies=tuple(bodies), parameters=parameters)


@pytest.mark.parametrize("seed,n_bodies,symbolic", [(3, 4, False), (5, 6, True), (8, 5, True)])
def test_random_trees_match_pinocchio(seed, n_bodies, symbolic):
    pytest.importorskip("pinocchio")
    rng = np.random.default_rng(seed)
    model = with_random_joint_terms(random_model(rng, n_bodies, symbolic), rng, symbolic)
    assert model.has_friction and "coulomb_width" in model.parameters
    nm = numeric_model(model)
    pm = pin_model(nm)
    dyns = [LambdifyDynamics(derive_equations(model, d)) for d in ("gibbs-appell", "recursive")]
    aba = forward_dynamics_aba(model)
    for q, qd, qdd in rng.normal(size=(3, 3, model.dof)):
        tau = pin_rnea(pm, q, qd, qdd)
        for dyn in dyns:
            np.testing.assert_allclose(dyn.inverse_dynamics(q, qd, qdd), tau, rtol=1e-10,
                                       atol=1e-10 * np.abs(tau).max())
            np.testing.assert_allclose(dyn.forward_dynamics(q, qd, tau), qdd, rtol=1e-8,
                                       atol=1e-8)
        np.testing.assert_allclose(aba.evaluate(q, qd, tau), qdd, rtol=1e-8, atol=1e-8)


# ------------------------------------------------------------------------ model files


def test_joint_terms_change_the_canonical_text_only_when_present():
    base = parse_model_text(PENDULUM.replace(", damping: d, friction: f, armature: a", ""),
                            "p.yaml")
    zeros = parse_model_text(PENDULUM.replace("damping: d, friction: f, armature: a",
                                              "damping: 0, friction: 0, armature: 0"), "p.yaml")
    full = parse_model_text(PENDULUM, "p.yaml")
    other = parse_model_text(PENDULUM.replace("damping: d", "damping: 2*d"), "p.yaml")
    assert "damping=" not in base.canonical() and base.canonical() == zeros.canonical()
    assert len({base.content_hash(), full.content_hash(), other.content_hash()}) == 3
    assert "coulomb_width" not in base.parameters and "coulomb_width" in full.parameters
    assert not base.has_friction and full.has_friction


@pytest.mark.parametrize("edit,reason", [
    ("damping: d", "damping: -d"),
    ("friction: f", "friction: zz"),
    ("armature: a", "armature: -0.5"),
])
def test_bad_joint_terms_are_refused(edit, reason):
    with pytest.raises(ModelError, match="non-negative|undeclared"):
        parse_model_text(PENDULUM.replace(edit, reason), "bad.yaml")


def test_fixed_joint_cannot_have_friction():
    text = ARM.replace("joint: {type: fixed,", "joint: {type: fixed, friction: 0.2,")
    with pytest.raises(ModelError, match="fixed joint"):
        parse_model_text(text, "bad.yaml")


def test_declared_coulomb_width_is_kept():
    text = PENDULUM.replace("a: 0.2}", "a: 0.2, coulomb_width: 0.002}")
    assert parse_model_text(text, "w.yaml").parameters["coulomb_width"] == 0.002
    with pytest.raises(ModelError, match="coulomb_width"):
        parse_model_text(PENDULUM.replace("a: 0.2}", "a: 0.2, coulomb_width: -1}"), "w.yaml")


# ------------------------------------------------------------------------------ URDF

URDF = """<?xml version="1.0"?>
<robot name="two">
  <link name="base"/>
  <link name="l1"><inertial><mass value="1.5"/><origin xyz="0 0 0.1"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.002" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l2"><inertial><mass value="0.5"/><origin xyz="0.1 0 0"/>
    <inertia ixx="0.001" iyy="0.003" izz="0.003" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="tip"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <axis xyz="0 0 1"/><dynamics damping="0.5" friction="0.2"/></joint>
  <joint name="j2" type="continuous"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><dynamics damping="0.1"/></joint>
  <joint name="j3" type="fixed"><parent link="l2"/><child link="tip"/>
    <dynamics damping="9"/></joint>
</robot>
"""


def test_urdf_dynamics_become_parameters():
    model = parse_urdf_text(URDF, "two.urdf")
    p = model.parameters
    assert (p["damping_j1"], p["friction_j1"], p["armature_j1"]) == (0.5, 0.2, 0.0)
    assert (p["damping_j2"], p["friction_j2"], p["armature_j2"]) == (0.1, 0.0, 0.0)
    assert not any(k.endswith("_j3") for k in p)  # a fixed joint has none
    assert p["coulomb_width"] == 0.01
    dyn = gagen.load(model, backend="lambdify")
    q, qd, qdd = np.array([0.3, -0.4]), np.array([0.5, -2.0]), np.array([0.1, 0.2])
    base = dyn.inverse_dynamics(q, qd, qdd, {"damping_j1": 0, "friction_j1": 0,
                                             "damping_j2": 0})
    extra = np.array([0.5 * 0.5 + 0.2, 0.1 * -2.0])
    np.testing.assert_allclose(dyn.inverse_dynamics(q, qd, qdd) - base, extra, rtol=1e-13)
    armature = dyn.inverse_dynamics(q, qd, qdd, {"armature_j2": 0.7}) - dyn.inverse_dynamics(
        q, qd, qdd)
    np.testing.assert_allclose(armature, [0.0, 0.7 * 0.2], atol=1e-14)


def test_urdf_negative_damping_is_refused():
    with pytest.raises(ModelError, match="dynamics damping.*non-negative"):
        parse_urdf_text(URDF.replace('damping="0.5"', 'damping="-0.5"'), "bad.urdf")


# ------------------------------------------------------------------------- simulation


@pytest.fixture(scope="module")
def compiled_pendulum(pendulum_model):
    return gagen.load(pendulum_model)


def test_simulation_smooths_friction_alike_in_c_and_scipy(compiled_pendulum, pendulum_model):
    """The C integrator's velocity stage and the scipy path use the same tanh(qd / w):
    dopri5 takes RK45's steps, so the trajectories agree to rounding; the lambdify backend
    (NumPy's tanh) too. The friction stops the pendulum, and no integrator stalls."""
    dyn = compiled_pendulum
    lam = gagen.load(pendulum_model, backend="lambdify")
    for width in (0.01, 0.05):
        p = {"coulomb_width": width}
        runs = [gagen.simulate(dyn, (0, 4), [1.0], [0.0], method="dopri5", p=p),
                gagen.simulate(dyn, (0, 4), [1.0], [0.0], method="RK45", p=p),
                gagen.simulate(lam, (0, 4), [1.0], [0.0], method="RK45", p=p)]
        for run in runs[1:]:
            np.testing.assert_allclose(run.q, runs[0].q, rtol=0, atol=1e-9)
            np.testing.assert_allclose(run.qd, runs[0].qd, rtol=0, atol=1e-8)
        assert runs[0].stats["nfev"] == runs[1].stats["nfev"] < 3000
        # at rest within the friction cone: m g L sin q < f, creeping at most ~w
        q_end, qd_end = runs[0].q[-1, 0], runs[0].qd[-1, 0]
        assert abs(math.sin(q_end)) < 0.7 / (2.0 * 9.81 * 0.5) and abs(qd_end) < 3 * width
    smooth = gagen.simulate(dyn, (0, 4), [1.0], [0.0], method="dopri5")
    wide = gagen.simulate(dyn, (0, 4), [1.0], [0.0], method="dopri5", p={"coulomb_width": 0.05})
    assert np.abs(smooth.q - wide.q).max() > 1e-4  # the width reaches the C stage


def test_exact_sign_with_zero_width_in_rk4(compiled_pendulum):
    """coulomb_width = 0 is the exact sign in the C stage too: rk4's first step from rest
    above the friction cone equals one rk4 step of the exact dynamics by hand."""
    dyn = compiled_pendulum
    v = dyn.parameters
    h = 1e-3
    run = gagen.simulate(dyn, (0, h), [1.0], [0.5], method="rk4", h=h, t_eval=[0.0, h],
                         p={"coulomb_width": 0.0})

    def f(y):
        q, qd = y
        tau, J = by_hand(q, qd, 0.0, v)
        return np.array([qd, -(tau) / J])

    y = np.array([1.0, 0.5])
    k1 = f(y)
    k2 = f(y + h / 2 * k1)
    k3 = f(y + h / 2 * k2)
    k4 = f(y + h * k3)
    expected = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose([run.q[-1, 0], run.qd[-1, 0]], expected, rtol=1e-13)


def test_frictionless_joint_in_the_c_stage(compiled_pendulum, pendulum_model):
    """friction = 0 (as on most URDF joints) skips the smooth sign in C (gagen_coulomb):
    still the same trajectory as scipy's, and as the frictionless dynamics."""
    lam = gagen.load(pendulum_model, backend="lambdify")
    p = {"f": 0.0}
    c = gagen.simulate(compiled_pendulum, (0, 2), [1.0], [0.0], method="dopri5", p=p)
    s = gagen.simulate(lam, (0, 2), [1.0], [0.0], method="RK45", p=p)
    np.testing.assert_allclose(c.q, s.q, rtol=0, atol=1e-9)
    assert abs(c.q[-1, 0]) > 0.1  # no Coulomb friction: still swinging
