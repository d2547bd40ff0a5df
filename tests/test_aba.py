"""The symbolic articulated-body algorithm against M(q)^-1 forcing, and its O(n) structure."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import sympy as sp
from conftest import SHARED_URDF
from random_trees import random_model

import gagen
from gagen.model import Body, Joint, Model, inertia_matrix, rotation_from_rpy, vector
from gagen.model.resolve import resolve_model
from gagen.runtime.lambdify import LambdifyDynamics
from gagen.symbolic.aba import forward_dynamics_aba, forward_dynamics_aba_after
from gagen.symbolic.recursive import derive_recursive

RTOL = 1e-12


def branched_prismatic_model() -> Model:
    """A tree with prismatic joints, a fixed body carrying a moving child, a fixed body on
    the world carrying another, and symbolic masses and lengths.

    world -(fixed)- base -(revolute z)- b1 -(fixed)- b2 -(prismatic, odd axis)- b3
                                                                  -(revolute x)- b4
                                          b1 -(continuous y)- b5 -(prismatic z)- b6
    """
    m1, m2, m3, L, c = sp.symbols("m1 m2 m3 L c")
    params = {"g": 9.81, "m1": 2.0, "m2": 0.7, "m3": 1.3, "L": 0.4, "c": 0.05}

    def body(name, parent, jtype, xyz, rpy, axis, mass, com, diag):
        joint = Joint(name=f"j_{name}", type=jtype, origin_xyz=vector(xyz),
                      origin_rotation=rotation_from_rpy(*rpy), axis=vector(axis))
        inertia = mass * inertia_matrix(*diag, 0.002, -0.003, 0.001)
        return Body(name=name, parent=parent, joint=joint, mass=mass, com=vector(com),
                    inertia=sp.ImmutableMatrix(inertia))

    bodies = (
        body("base", "world", "fixed", [0.1, 0, 0.3], [0.2, 0, 0.1], [0, 0, 1], 3.0,
             [0, 0, 0.1], (0.2, 0.2, 0.1)),
        body("b1", "base", "revolute", [0, 0.1, L], [0, 0.3, 0], [0, 0, 1], m1,
             [c, 0, 0.2], (0.1, 0.12, 0.05)),
        body("b2", "b1", "fixed", [0.2, 0, 0.1], [0.5, -0.2, 0.4], [1, 0, 0], m2,
             [0.05, 0.02, 0], (0.05, 0.06, 0.07)),
        body("b3", "b2", "prismatic", [0, 0.1, 0], [0, 0, 0.7], [0.3, -0.5, 0.8], m3,
             [0, 0, c], (0.08, 0.05, 0.09)),
        body("b4", "b3", "revolute", [0.1, 0, L], [0.1, 0.2, 0.3], [-1, 0, 0], 0.9,
             [0, 0.1, 0], (0.03, 0.04, 0.05)),
        body("b5", "b1", "continuous", [0, 0, 0.3], [0, 0, 0], [0, 1, 0], 1.1,
             [0.1, 0, 0], (0.04, 0.05, 0.06)),
        body("b6", "b5", "prismatic", [0.2, 0, 0], [0, -0.4, 0], [0, 0, -1], m2,
             [0, 0.03, 0.02], (0.02, 0.03, 0.04)),
    )
    return Model(name="branched_prismatic", bodies=bodies, parameters=params,
                 gravity=vector([0, 0, -sp.Symbol("g")]), source="<test>",
                 description="prismatic joints and fixed bodies with children")


def _model(name: str) -> Model:
    if name == "random":
        return random_model(np.random.default_rng(3), 6, symbolic=True)
    if name == "branched":
        return branched_prismatic_model()
    if name == "ur5":
        return resolve_model(SHARED_URDF / "ur5_robot.urdf")
    return resolve_model(name)


def assert_aba_matches(program, reference, rng, states=4):
    """ABA's qdd equals the reference's forward dynamics at random states and parameters."""
    defaults = reference.parameter_vector()
    for _ in range(states):
        q, qd, tau = rng.uniform(-2, 2, size=(3, reference.n))
        p = defaults * rng.uniform(0.5, 1.5, size=defaults.shape)
        want = reference.forward_dynamics(q, qd, tau, p)
        got = program.evaluate(q, qd, tau, p)
        scale = max(1.0, np.abs(want).max())
        np.testing.assert_allclose(got, want, rtol=RTOL, atol=RTOL * scale)


@pytest.mark.parametrize("name", ["rrr", "chain:5", pytest.param("chain:12", marks=pytest.mark.slow),
                                  "ur5", "random", "branched"])
def test_aba_equals_lambdify_forward_dynamics(name):
    """Against gagen.load's lambdify backend (Gibbs-Appell M and forcing, Cholesky)."""
    model = _model(name)
    assert_aba_matches(forward_dynamics_aba(model), gagen.load(model, backend="lambdify"),
                       np.random.default_rng(7))


def test_aba_equals_recursive_forward_dynamics_on_chain12():
    """chain:12 against M \\ forcing of derive_recursive (itself checked against
    Gibbs-Appell in test_recursive), a few seconds instead of the Gibbs-Appell's ten."""
    model = resolve_model("chain:12")
    assert_aba_matches(forward_dynamics_aba(model), LambdifyDynamics(derive_recursive(model)),
                       np.random.default_rng(7))


@pytest.mark.parametrize("seed", [11, 17, 23])
def test_aba_on_random_trees_with_every_joint_type(seed):
    """Prismatic, revolute, continuous and fixed joints, odd axes, rotated origins."""
    model = random_model(np.random.default_rng(seed), 6, symbolic=seed % 2 == 1)
    assert_aba_matches(forward_dynamics_aba(model), LambdifyDynamics(derive_recursive(model)),
                       np.random.default_rng(seed), states=3)


def test_branched_model_exercises_prismatic_and_fixed_parents():
    model = branched_prismatic_model()
    types = {b.name: b.joint.type for b in model.bodies}
    parents = {b.parent for b in model.bodies}
    assert "prismatic" in types.values()
    axes = [tuple(b.joint.axis) for b in model.bodies if b.joint.moves]
    assert (0, 0, -1) in axes and (-1, 0, 0) in axes  # negative coordinate axes, too
    assert {name for name, t in types.items() if t == "fixed"} <= parents  # fixed with children


def test_aba_inverts_the_recursive_inverse_dynamics():
    """qdd -> RNEA -> tau -> ABA gives qdd back (independent of M and its solve)."""
    model = _model("branched")
    program = forward_dynamics_aba(model)
    rnea = LambdifyDynamics(derive_recursive(model))
    rng = np.random.default_rng(4)
    q, qd, qdd = rng.uniform(-2, 2, size=(3, model.dof))
    tau = rnea.inverse_dynamics(q, qd, qdd)
    np.testing.assert_allclose(program.evaluate(q, qd, tau), qdd, rtol=RTOL, atol=RTOL)


def test_same_symbols_as_the_recursive_equations():
    model = _model("branched")
    program, eqs = forward_dynamics_aba(model), derive_recursive(model)
    assert program.coords == eqs.coords and program.parameters == eqs.parameters
    allowed = set(eqs.coords.q) | set(eqs.coords.qd) | set(eqs.coords.tau) | set(eqs.parameters)
    allowed |= {s for s, _ in program.intermediates}
    for e in program.qdd:
        assert e.free_symbols <= allowed
    assert not any(e.free_symbols & set(eqs.coords.qdd) for _, e in program.intermediates)


def test_program_is_linear_in_size_with_small_ordered_definitions():
    """Each definition O(1) and defined before use; the total grows linearly with n."""
    counts, ops = {}, {}
    for n in (4, 8, 16):
        program = forward_dynamics_aba(resolve_model(f"chain:{n}"))
        names = {s for s, _ in program.intermediates}
        defined: set[sp.Symbol] = set()
        for symbol, expr in program.intermediates:
            assert expr.free_symbols & names <= defined, symbol
            defined.add(symbol)
        assert max(sp.count_ops(e) for _, e in program.intermediates) <= 30
        counts[n], ops[n] = len(program.intermediates), program.operation_count()
    # a constant cost per added body: the increments from 4 to 8 and from 8 to 16 bodies
    # agree per body (within 2%: the first bodies, at rest and unrotated, are cheaper)
    for size in (counts, ops):
        per_body_late, per_body_early = (size[16] - size[8]) / 8, (size[8] - size[4]) / 4
        assert abs(per_body_late - per_body_early) <= 0.02 * per_body_late, size


def test_evaluate_returns_fresh_arrays():
    program = forward_dynamics_aba(resolve_model("rrr"))
    a = program.evaluate(np.zeros(3), np.zeros(3), np.zeros(3))
    b = program.evaluate(np.zeros(3), np.zeros(3), np.zeros(3))
    assert a is not b and a.shape == (3,)


def test_aba_after_recursive_equations_shares_their_definitions():
    """One program for M, forcing and the ABA: no symbol defined twice, the per-body
    setup reused, and the same qdd."""
    model = _model("branched")
    eqs = derive_recursive(model)
    alone, after = forward_dynamics_aba(model), forward_dynamics_aba_after(eqs)
    assert after.intermediates[:len(eqs.intermediates)] == eqs.intermediates
    symbols = [s for s, _ in after.intermediates]
    assert len(set(symbols)) == len(symbols)
    added = len(after.intermediates) - len(eqs.intermediates)
    assert added < len(alone.intermediates)  # sin, cos, R, d, h and I_O come from eqs
    rng = np.random.default_rng(12)
    q, qd, tau = rng.uniform(-2, 2, size=(3, model.dof))
    np.testing.assert_allclose(after.evaluate(q, qd, tau), alone.evaluate(q, qd, tau),
                               rtol=RTOL, atol=RTOL)


@pytest.mark.parametrize("name", ["branched", "panda",
                                  pytest.param("talos", marks=pytest.mark.slow)])
def test_aba_equals_pinocchio_aba(name):
    """An external reference: Pinocchio's own ABA on the same tree (Talos: 44 DOF)."""
    pytest.importorskip("pinocchio")
    from reference import numeric_model, pin_forward_dynamics, pin_model

    urdf = {"talos": "talos_full_v2.urdf", "panda": "panda.urdf"}.get(name)
    model = resolve_model(SHARED_URDF / urdf) if urdf else _model(name)
    program = forward_dynamics_aba(model)
    rng = np.random.default_rng(21)
    for _ in range(2):
        scale = rng.uniform(0.5, 1.5, size=len(model.parameters))
        values = dict(zip(model.parameters, model.parameter_vector() * scale))
        pm = pin_model(numeric_model(model, values))
        q, qd, tau = rng.uniform(-2, 2, size=(3, model.dof))
        want = pin_forward_dynamics(pm, q, qd, tau)
        got = program.evaluate(q, qd, tau, np.array(list(values.values())))
        np.testing.assert_allclose(got, want, rtol=RTOL, atol=RTOL * max(1.0, np.abs(want).max()))


def test_pivots_are_positive_and_multiply_to_det_of_mass_matrix():
    """D_k, one per joint: the pivots of eliminating M leaves first, so prod D_k = det M."""
    model = _model("branched")
    program = forward_dynamics_aba(model)
    assert len(program.pivots) == model.dof
    as_outputs = dataclasses.replace(program, qdd=program.pivots, _function=None)
    reference = LambdifyDynamics(derive_recursive(model))
    rng = np.random.default_rng(6)
    for _ in range(3):
        q, qd, tau = rng.uniform(-2, 2, size=(3, model.dof))
        D = as_outputs.evaluate(q, qd, tau)
        assert (D > 0).all()
        det = np.linalg.det(reference.mass_matrix(q))
        np.testing.assert_allclose(np.prod(D), det, rtol=1e-10)
