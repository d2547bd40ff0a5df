"""The regressor: tau = Y(q, qd, qdd) pi (gagen.symbolic.regressor).

Checked: Y pi = inverse dynamics at random states and random parameters (rrr, chains,
random trees with fixed and prismatic joints, joint terms, the shared URDFs) on both
backends; against Pinocchio's computeJointTorqueRegressor (its columns lie in the span of
gagen's, the ranks agree, and on the URDFs its columns are gagen's body columns exactly);
pi against Pinocchio's toDynamicParameters; names, shapes, fresh arrays.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np
import pytest
from random_trees import random_model
from test_joint_terms import ARM, with_random_joint_terms

import gagen
from gagen.manifest import BODY_PARAMETERS
from gagen.model.modelfile import parse_model_text

URDF_DIR = Path(__file__).resolve().parent / "data" / "urdf"
URDFS = ("double_pendulum", "so100", "ur5_robot", "panda")


def random_parameters(dyn, rng, scale: float = 0.5) -> np.ndarray:
    """Every parameter scaled by a random factor in [1 - scale, 1 + scale] (also the
    kinematic ones: the identity Y pi = tau holds whatever they are)."""
    p = dyn.parameter_vector()
    return p * rng.uniform(1 - scale, 1 + scale, size=p.size)


def states(dyn, rng, count: int):
    return (rng.uniform(-math.pi, math.pi, (count, dyn.n)), rng.normal(size=(count, dyn.n)),
            rng.normal(size=(count, dyn.n)))


def assert_identity(dyn, rng, count: int = 6, rounds: int = 3) -> None:
    """Y pi == inverse dynamics, stacked and one state at a time, at random parameters."""
    for k in range(rounds):
        p = None if k == 0 else random_parameters(dyn, rng)
        q, qd, qdd = states(dyn, rng, count)
        Y = dyn.regressor(q, qd, qdd, p)
        pi = dyn.regressor_parameters(p)
        assert Y.shape == (count, dyn.n, len(dyn.regressor_names)) and pi.shape == Y.shape[-1:]
        tau = dyn.inverse_dynamics(q, qd, qdd, p)
        scale = max(1.0, np.abs(tau).max())
        np.testing.assert_allclose(Y @ pi, tau, rtol=1e-11, atol=1e-11 * scale)
        np.testing.assert_allclose(dyn.regressor(q[0], qd[0], qdd[0], p), Y[0], rtol=1e-14,
                                   atol=1e-14)


@functools.cache
def loaded(name: str, backend: str):
    """A built-in or shared URDF, loaded once per session."""
    target = URDF_DIR / f"{name}.urdf" if name in URDFS else name
    return gagen.load(target, backend=backend)


@pytest.mark.parametrize("name,backend", [("rrr", "compiled"), ("rrr", "lambdify"),
                                          ("chain:3", "compiled"), ("chain:5", "lambdify"),
                                          *((u, "lambdify") for u in URDFS)])
def test_regressor_times_parameters_is_inverse_dynamics(name, backend):
    assert_identity(loaded(name, backend), np.random.default_rng(1))


@pytest.mark.parametrize("seed,n_bodies", [(3, 5), (11, 7), (4, 6)])
def test_random_trees_with_joint_terms(seed, n_bodies):
    rng = np.random.default_rng(seed)
    model = with_random_joint_terms(random_model(rng, n_bodies, symbolic=True), rng, True)
    assert_identity(gagen.load(model, backend="lambdify"), rng)


def test_compiled_random_tree_matches_lambdify():
    rng = np.random.default_rng(7)
    model = with_random_joint_terms(random_model(rng, 3, symbolic=True), rng, True)
    compiled, lam = gagen.load(model), gagen.load(model, backend="lambdify")
    assert_identity(compiled, rng)
    p = random_parameters(compiled, rng)
    q, qd, qdd = states(compiled, rng, 5)
    np.testing.assert_allclose(compiled.regressor(q, qd, qdd, p), lam.regressor(q, qd, qdd, p),
                               rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(compiled.regressor_parameters(p), lam.regressor_parameters(p),
                               rtol=1e-13, atol=1e-15)


def test_fixed_bodies_are_merged_into_their_moving_parent():
    """ARM's tool is welded to the slider: one body of 10 columns, holding both masses."""
    model = parse_model_text(ARM, "arm.yaml")
    dyn = gagen.load(model, backend="lambdify")
    assert dyn.regressor_names[:10] == [f"{key}_upper" for key in BODY_PARAMETERS]
    assert dyn.regressor_names[10:20] == [f"{key}_slider" for key in BODY_PARAMETERS]
    assert dyn.regressor_names[20:] == ["damping_shoulder", "damping_slide", "friction_shoulder",
                                        "friction_slide", "armature_shoulder", "armature_slide"]
    pi = dyn.regressor_parameters()
    assert pi[10] == pytest.approx(0.7 + 0.3)
    np.testing.assert_allclose(pi[11:14], [0.7 * 0.01, 0.3 * 0.05, 0.7 * -0.05 + 0.3 * -0.12])
    np.testing.assert_allclose(pi[20:], [0.3, 1.5, 1.0, 0.25, 0.15, 0.05])
    assert_identity(dyn, np.random.default_rng(3))


def test_outputs_are_fresh_arrays():
    dyn = gagen.load("rrr")
    q = np.zeros(3)
    a, b = dyn.regressor(q, q, q), dyn.regressor(q, q, q)
    assert a is not b and not np.shares_memory(a, b)
    assert dyn.regressor_parameters() is not dyn.regressor_parameters()
    with pytest.raises(ValueError):
        dyn.regressor(np.zeros(2), q, q)


def test_friction_column_is_the_sign_of_the_rate():
    dyn = gagen.load("rrr")
    n, P = dyn.n, len(dyn.regressor_names)
    Y = dyn.regressor(np.zeros(n), np.array([0.0, -2.0, 1e-300]), np.zeros(n))
    friction = Y[:, P - 2 * n:P - n]
    np.testing.assert_array_equal(friction, np.diag([0.0, -1.0, 1.0]))


# ------------------------------------------------------------------------- Pinocchio


class PinUrdf:
    """Pinocchio's own URDF parser, rows and joints in gagen's coordinate order."""

    def __init__(self, name: str, coordinates: list[str]):
        pin = pytest.importorskip("pinocchio")
        self.pin = pin
        self.model = pin.buildModelFromUrdf(str(URDF_DIR / f"{name}.urdf"))
        self.data = self.model.createData()
        ids = [self.model.getJointId(c) for c in coordinates]
        self.iq = [self.model.idx_qs[j] for j in ids]
        self.nq = [self.model.nqs[j] for j in ids]
        self.iv = [self.model.idx_vs[j] for j in ids]
        self.ids = ids

    def q(self, q):
        out = self.pin.neutral(self.model)
        for k, (i, n) in enumerate(zip(self.iq, self.nq)):
            out[i:i + n] = [q[k]] if n == 1 else [math.cos(q[k]), math.sin(q[k])]
        return out

    def v(self, x):
        out = np.zeros(self.model.nv)
        out[self.iv] = x
        return out

    def regressor(self, q, qd, qdd) -> np.ndarray:
        """computeJointTorqueRegressor: rows and 10-column blocks in gagen's order."""
        Y = np.array(self.pin.computeJointTorqueRegressor(
            self.model, self.data, self.q(q), self.v(qd), self.v(qdd)))
        blocks = [Y[:, 10 * (j - 1):10 * j] for j in self.ids]
        return np.hstack(blocks)[self.iv]

    def dynamic_parameters(self) -> np.ndarray:
        return np.concatenate([self.model.inertias[j].toDynamicParameters() for j in self.ids])


@pytest.mark.parametrize("name", URDFS)
def test_urdf_regressor_is_pinocchios(name):
    """Same convention: gagen's body columns are Pinocchio's columns, pi its parameters."""
    dyn = loaded(name, "lambdify")
    ref = PinUrdf(name, dyn.coordinates)
    rng = np.random.default_rng(5)
    nb = 10 * dyn.n
    np.testing.assert_allclose(dyn.regressor_parameters()[:nb], ref.dynamic_parameters(),
                               rtol=1e-12, atol=1e-14)
    for q, qd, qdd in zip(*states(dyn, rng, 4)):
        expected = ref.regressor(q, qd, qdd)
        np.testing.assert_allclose(dyn.regressor(q, qd, qdd)[:, :nb], expected, rtol=1e-10,
                                   atol=1e-10 * max(1.0, np.abs(expected).max()))


def rank(A: np.ndarray) -> int:
    s = np.linalg.svd(A, compute_uv=False)
    return int(np.count_nonzero(s > 1e-9 * s[0]))


@pytest.mark.parametrize("model", ["panda", "ur5_robot", "tree"])
def test_pinocchio_columns_lie_in_the_span_and_ranks_agree(model):
    """Stacked over random states: [Y, Y_pin] has the rank of Y, and Pinocchio's regressor
    the rank of gagen's body columns (the joint columns add one rank each per joint,
    less the armatures that coincide with an inertia about a joint's axis)."""
    pin = pytest.importorskip("pinocchio")
    from reference import numeric_model, pin_model, to_pinocchio

    rng = np.random.default_rng(9)
    if model == "tree":
        gmodel = random_model(rng, 6, symbolic=True)
        dyn = gagen.load(gmodel, backend="lambdify")
        pm = pin_model(numeric_model(gmodel))
        data = pm.createData()

        def pin_regressor(q, qd, qdd):
            Y = pin.computeJointTorqueRegressor(pm, data, *to_pinocchio(pm, q, qd, qdd))
            out = np.empty_like(Y)
            out[pm.gagen_order] = Y
            return out
    else:
        dyn = loaded(model, "lambdify")
        ref = PinUrdf(model, dyn.coordinates)
        pin_regressor = ref.regressor
    q, qd, qdd = states(dyn, rng, 40)
    ours = dyn.regressor(q, qd, qdd).reshape(-1, len(dyn.regressor_names))
    theirs = np.vstack([pin_regressor(*s) for s in zip(q, qd, qdd)])
    nb = 10 * dyn.n
    assert rank(np.hstack([ours, theirs])) == rank(ours)
    assert rank(theirs) == rank(ours[:, :nb])
    assert rank(ours) > rank(ours[:, :nb])  # the joint terms are identifiable too


def test_c_header_declares_the_regressor():
    header = (Path(__file__).resolve().parents[1] / "generated" / "rrr" / "rrr.h").read_text()
    assert "void rrr_regressor(const double *q, const double *qd, const double *qdd," in header
    assert "void rrr_regressor_parameters(const double *p, double *pi);" in header
    assert "#define RRR_NREG 39" in header


def test_floating_base_regressor_is_pinocchios():
    """A floating base (Pinocchio's FreeFlyer, the same q and qd layout): 10 more columns
    for the base body, no joint terms for its six coordinates; Y pi = tau and the body
    columns equal Pinocchio's."""
    pin = pytest.importorskip("pinocchio")
    dyn = gagen.load(URDF_DIR / "panda.urdf", backend="lambdify", floating_base=True)
    assert (dyn.n, dyn.nq, len(dyn.regressor_names)) == (15, 16, 10 * 10 + 3 * 9)
    pm = pin.buildModelFromUrdf(str(URDF_DIR / "panda.urdf"), pin.JointModelFreeFlyer())
    data = pm.createData()
    rng = np.random.default_rng(12)
    for _ in range(3):
        q = pin.randomConfiguration(pm, -np.ones(pm.nq), np.ones(pm.nq))
        qd, qdd = rng.normal(size=(2, dyn.n))
        Y = dyn.regressor(q, qd, qdd)
        np.testing.assert_allclose(Y @ dyn.regressor_parameters(), dyn.inverse_dynamics(q, qd, qdd),
                                   rtol=1e-11, atol=1e-11)
        theirs = np.array(pin.computeJointTorqueRegressor(pm, data, q, qd, qdd))
        np.testing.assert_allclose(Y[:, :100], theirs, rtol=1e-10, atol=1e-10)
        assert not Y[:6, 100:].any()  # the base's rows have no joint terms
    damping, _, _ = dyn.joint_terms()
    assert not damping[:6].any() and damping[6] == 0.003


def test_compiled_floating_tree_regressor(cache_dir):
    """The compiled regressor of a floating tree (q: nq entries, qd: nv) as the lambdify
    one, and Y pi = tau (the tree test_floating builds too: one build for both)."""
    from test_floating import floating_tree, random_state

    model = floating_tree(1)
    compiled = gagen.load(model, cache_dir=cache_dir)
    lam = gagen.load(model, backend="lambdify")
    rng = np.random.default_rng(4)
    for _ in range(3):
        q, qd, qdd = random_state(compiled, rng)
        Y = compiled.regressor(q, qd, qdd)
        np.testing.assert_allclose(Y, lam.regressor(q, qd, qdd), rtol=1e-11, atol=1e-11)
        np.testing.assert_allclose(Y @ compiled.regressor_parameters(),
                                   compiled.inverse_dynamics(q, qd, qdd), rtol=1e-11, atol=1e-11)
