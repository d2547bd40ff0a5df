"""The centre of mass and the centroidal dynamics, against Pinocchio and their definitions.

Pinocchio's conventions (centerOfMass, ccrba, dccrba): 6-vectors and the rows of 6 x nv
matrices are linear then angular, in world axes, about the centre of mass. Checked to 1e-9
relative, in both backends, on random trees with every joint type (bodies welded to the
world among them: no part of the robot's mass), a random floating tree, the Panda, ANYmal C and Talos: centerOfMass, the centre of mass's velocity (data.vcom),
jacobianCenterOfMass, computeCentroidalMap, computeCentroidalMomentum,
computeCentroidalMapTimeVariation, ccrba and dccrba (A_g, h_g, d/dt A_g) and
computeCentroidalMomentumTimeVariation at qdd = 0 (the bias).

Then the defining identities against gagen's own functions: A_g qd = h_g and J_com = A_g's
linear rows over the mass at a state; along a path of constant velocity (q(t) = q0 ⊕ v t,
whose velocity is v throughout), finite differences of the centre of mass, A_g and h_g give
J_com v, d/dt A_g and its bias; and for a floating robot under external wrenches (forward
dynamics with fext), A_g qdd + bias is m g plus the wrenches about the centre of mass, and
so is the finite difference of h_g along the simulated motion.
"""

from __future__ import annotations

import ctypes
import warnings

import numpy as np
import pytest
from random_trees import random_model
from test_floating import URDF, Reference, floating_tree, random_state

import gagen
from gagen.model.numeric import numeric_model
from gagen.reference.pinocchio import pinocchio_model

pin = pytest.importorskip("pinocchio")

RTOL = 1e-9
METHODS = ("center_of_mass", "com_velocity", "com_jacobian", "centroidal_map",
           "centroidal_momentum", "centroidal_map_time_variation", "centroidal_bias")


def close(actual, expected, what: str, rtol: float = RTOL) -> None:
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    scale = max(float(np.abs(expected).max()), 1e-300)
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=rtol * scale, err_msg=what)


def check_against_pinocchio(dyn, ref: Reference, seed: int = 0, states: int = 3) -> None:
    """Every centroidal quantity of gagen's against Pinocchio's at random states."""
    rng = np.random.default_rng(seed)
    m, d = ref.model, ref.data
    for _ in range(states):
        q, v, _ = random_state(dyn, rng)
        qp, vp = ref.q(q), ref.v(v)
        close(dyn.center_of_mass(q), pin.centerOfMass(m, d, qp), "centerOfMass")
        pin.centerOfMass(m, d, qp, vp)
        close(dyn.com_velocity(q, v), d.vcom[0], "vcom")
        close(dyn.com_jacobian(q), ref.ours(pin.jacobianCenterOfMass(m, d, qp)),
              "jacobianCenterOfMass")
        A = dyn.centroidal_map(q)
        close(A, ref.ours(pin.computeCentroidalMap(m, d, qp)), "computeCentroidalMap")
        h = dyn.centroidal_momentum(q, v)
        close(h, pin.computeCentroidalMomentum(m, d, qp, vp).vector,
              "computeCentroidalMomentum")
        dA = dyn.centroidal_map_time_variation(q, v)
        close(dA, ref.ours(pin.computeCentroidalMapTimeVariation(m, d, qp, vp)),
              "computeCentroidalMapTimeVariation")
        close(A, ref.ours(pin.ccrba(m, d, qp, vp)), "ccrba's A_g")
        close(h, d.hg.vector, "ccrba's h_g")
        close(dA, ref.ours(pin.dccrba(m, d, qp, vp)), "dccrba's dA_g")  # its return value
        close(A, ref.ours(d.Ag), "dccrba's A_g")
        bias = pin.computeCentroidalMomentumTimeVariation(m, d, qp, vp, np.zeros(m.nv))
        close(dyn.centroidal_bias(q, v), bias.vector, "dh_g at qdd = 0")


class FixedBaseReference(Reference):
    """Pinocchio's URDF parse of a fixed-base robot, its joints matched by name."""

    def __init__(self, dyn, model):
        self.model, self.data = model, model.createData()
        ids = [model.getJointId(name) for name in dyn.coordinates]
        self.v_order = self.q_order = np.array([model.idx_vs[j] for j in ids])


def every_joint_type_tree():
    """A random tree with revolute, continuous, prismatic and fixed joints: a body welded to
    the world, one welded to it that carries a moving subtree, and a fixed body under a
    moving one (4 coordinates: the Gibbs-Appell route)."""
    model = random_model(np.random.default_rng(4), 7)
    types = {b.joint.type for b in model.bodies}
    assert types == {"revolute", "continuous", "prismatic", "fixed"}
    parents = {b.name: b.parent for b in model.bodies}
    fixed = [b for b in model.bodies if b.joint.type == "fixed"]
    assert any(b.parent == "world" and b.name in parents.values() for b in fixed)
    assert any(b.parent != "world" for b in fixed)
    return model


@pytest.fixture(scope="module")
def anymal(cache_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        return gagen.load(URDF / "anymal_c.urdf", floating_base=True, cache_dir=cache_dir)


@pytest.fixture(scope="module")
def anymal_reference(anymal):
    model = pin.buildModelFromUrdf(str(URDF / "anymal_c.urdf"), pin.JointModelFreeFlyer())
    return Reference(anymal, model)


# ------------------------------------------------------------------- against Pinocchio

@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_a_tree_with_every_joint_type_matches_pinocchio(backend, cache_dir):
    model = every_joint_type_tree()
    options = {"cache_dir": cache_dir} if backend == "compiled" else {}
    dyn = gagen.load(model, backend=backend, **options)
    check_against_pinocchio(dyn, Reference(dyn, pinocchio_model(numeric_model(model))))


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_a_random_floating_tree_matches_pinocchio(backend, cache_dir):
    model = floating_tree(1)  # test_floating's too: one build for both
    options = {"cache_dir": cache_dir} if backend == "compiled" else {}
    dyn = gagen.load(model, backend=backend, **options)
    check_against_pinocchio(dyn, Reference(dyn, pinocchio_model(numeric_model(model))), 1)


def test_anymal_matches_pinocchio(anymal, anymal_reference):
    check_against_pinocchio(anymal, anymal_reference, 2)


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_the_panda_matches_pinocchio(backend, cache_dir):
    """A fixed base from Pinocchio's own URDF parse (its root link's mass is the world's)."""
    path = URDF / "panda.urdf"
    options = {"cache_dir": cache_dir} if backend == "compiled" else {}
    dyn = gagen.load(path, backend=backend, **options)
    check_against_pinocchio(dyn, FixedBaseReference(dyn, pin.buildModelFromUrdf(str(path))), 3)


@pytest.mark.slow
def test_talos_matches_pinocchio(cache_dir):
    path = URDF / "talos_full_v2.urdf"
    dyn = gagen.load(path, floating_base=True, cache_dir=cache_dir)
    model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    check_against_pinocchio(dyn, Reference(dyn, model), 5, states=2)


def test_parameters_change_the_mass(anymal):
    """p= as in every other method: a heavier base moves the centre of mass, A_g and the
    bias as they move in Pinocchio's model built at those parameters."""
    p = {"m_base": 2.5 * anymal.parameters["m_base"],
         "cx_base": anymal.parameters["cx_base"] + 0.1}
    ref = Reference(anymal, pinocchio_model(numeric_model(anymal.model, p)))
    m, d = ref.model, ref.data
    q, v, _ = random_state(anymal, np.random.default_rng(3))
    qp, vp = ref.q(q), ref.v(v)
    close(anymal.center_of_mass(q, p=p), pin.centerOfMass(m, d, qp), "com")
    close(anymal.centroidal_map(q, p=p), ref.ours(pin.computeCentroidalMap(m, d, qp)), "A_g")
    close(anymal.centroidal_bias(q, v, p=anymal.parameter_vector(p)),
          pin.computeCentroidalMomentumTimeVariation(m, d, qp, vp, np.zeros(m.nv)).vector,
          "bias")
    assert np.abs(anymal.center_of_mass(q) - anymal.center_of_mass(q, p=p)).max() > 1e-2


# -------------------------------------------------------------- the defining identities

def _stencil(f, h: float):
    """d/dt f at 0 by the five-point central difference (error O(h^4))."""
    return (f(-2 * h) - 8 * f(-h) + 8 * f(h) - f(2 * h)) / (12 * h)


@pytest.mark.parametrize("which", ["anymal", "tree"])
def test_the_identities_along_a_path_of_constant_velocity(which, anymal, cache_dir):
    """On q(t) = q0 ⊕ v t the velocity is v throughout and qdd = 0: d/dt com = J_com v,
    d/dt A_g = centroidal_map_time_variation, d/dt h_g = d/dt A_g v = centroidal_bias, and
    at each state A_g v = h_g and J_com = A_g's linear rows over the mass."""
    dyn = anymal if which == "anymal" else gagen.load(every_joint_type_tree(),
                                                      cache_dir=cache_dir)
    rng = np.random.default_rng(11)
    mass = dyn.regressor_parameters()[:10 * len(dyn.info.moving_tree):10].sum()
    for _ in range(2):
        q0, v, _ = random_state(dyn, rng)

        def at(t, q0=q0, v=v):
            return dyn.integrate(q0, v, t)

        A = dyn.centroidal_map(q0)
        close(A @ v, dyn.centroidal_momentum(q0, v), "A_g v = h_g", 1e-12)
        close(dyn.com_jacobian(q0), A[:3] / mass, "J_com = A_g[:3] / m", 1e-12)
        close(dyn.com_jacobian(q0) @ v, dyn.com_velocity(q0, v), "J_com v = vcom", 1e-12)
        h = 1e-3
        close(_stencil(lambda t: dyn.center_of_mass(at(t)), h), dyn.com_velocity(q0, v),
              "d/dt com", 1e-9)
        dA = dyn.centroidal_map_time_variation(q0, v)
        close(_stencil(lambda t: dyn.centroidal_map(at(t)), h), dA, "d/dt A_g", 1e-9)
        bias = dyn.centroidal_bias(q0, v)
        close(dA @ v, bias, "d/dt A_g v = bias", 1e-12)
        close(_stencil(lambda t, v=v: dyn.centroidal_momentum(at(t), v), h), bias,
              "d/dt h_g", 1e-9)


FEET = ("LF_FOOT", "RH_FOOT")


def _newton_euler(dyn, q, wrenches: dict) -> np.ndarray:
    """m g plus the wrenches (force, torque at the frame, world axes) about the centre of
    mass: what the rate of the centroidal momentum must be."""
    com = dyn.center_of_mass(q)
    mass = dyn.regressor_parameters()[:10 * len(dyn.info.moving_tree):10].sum()
    total = np.concatenate([mass * np.array([0.0, 0.0, -dyn.parameters["g"]]), np.zeros(3)])
    for frame, w in wrenches.items():
        _, origin = dyn.frame_placement(q, frame)
        total += np.concatenate([w[:3], w[3:] + np.cross(origin - com, w[:3])])
    return total


def test_the_momentum_rate_is_gravity_and_the_external_wrenches(anymal):
    """A floating robot: whatever the joint torques, A_g qdd + bias = m g + the external
    wrenches about the centre of mass, with qdd = forward_dynamics(..., fext)."""
    dyn = anymal
    rng = np.random.default_rng(5)
    for _ in range(3):
        q, v, _ = random_state(dyn, rng)
        tau = np.concatenate([np.zeros(6), rng.normal(scale=20.0, size=dyn.nv - 6)])
        fext = {foot: rng.normal(scale=50.0, size=6) for foot in FEET}
        qdd = dyn.forward_dynamics(q, v, tau, fext=fext)
        rate = dyn.centroidal_map(q) @ qdd + dyn.centroidal_bias(q, v)
        close(rate, _newton_euler(dyn, q, fext), "A_g qdd + bias = m g + wrenches")


def test_the_momentum_rate_along_a_simulated_motion(anymal):
    """The finite difference of h_g along a simulation under external wrenches is m g plus
    the wrenches about the centre of mass (to the integration's accuracy)."""
    dyn = anymal
    rng = np.random.default_rng(6)
    q0, v0, _ = random_state(dyn, rng)
    fext = {foot: rng.normal(scale=50.0, size=6) for foot in FEET}
    h, mid = 1e-3, 0.01
    run = gagen.simulate(dyn, (0.0, 0.02), q0, v0, method="RK45", rtol=1e-12, atol=1e-12,
                         t_eval=mid + h * np.arange(-2, 3), fext=fext)
    momenta = dyn.centroidal_momentum(run.q, run.qd)
    rate = (momenta[0] - 8 * momenta[1] + 8 * momenta[3] - momenta[4]) / (12 * h)
    q, v = run.q[2], run.qd[2]
    close(rate, _newton_euler(dyn, q, fext), "d/dt h_g = m g + wrenches", 1e-6)
    qdd = dyn.forward_dynamics(q, v, np.zeros(dyn.nv), fext=fext)
    close(rate, dyn.centroidal_map(q) @ qdd + dyn.centroidal_bias(q, v),
          "d/dt h_g = A_g qdd + bias", 1e-6)


# ---------------------------------------------------------------- the API and the C API

def test_stacked_states_fresh_arrays_and_checked_inputs(anymal):
    dyn = anymal
    rng = np.random.default_rng(8)
    states = [random_state(dyn, rng) for _ in range(3)]
    Q = np.stack([s[0] for s in states])
    V = np.stack([s[1] for s in states])
    shapes = {"center_of_mass": (3,), "com_velocity": (3,), "com_jacobian": (3, dyn.nv),
              "centroidal_map": (6, dyn.nv), "centroidal_momentum": (6,),
              "centroidal_map_time_variation": (6, dyn.nv), "centroidal_bias": (6,)}
    for name in METHODS:
        method = getattr(dyn, name)
        rates = name in ("com_velocity", "centroidal_momentum",
                         "centroidal_map_time_variation", "centroidal_bias")
        stacked = method(Q, V) if rates else method(Q)
        assert stacked.shape == (3, *shapes[name]), name
        for k in range(3):
            one = method(Q[k], V[k]) if rates else method(Q[k])
            assert one.shape == shapes[name]
            close(stacked[k], one, f"stacked {name}", 1e-15)
        if rates:  # one q with stacked velocities, as elsewhere
            close(method(Q[0], V)[1], method(Q[0], V[1]), f"{name}, broadcast q", 1e-15)
        first = method(Q[0], V[0]) if rates else method(Q[0])
        again = method(Q[1], V[1]) if rates else method(Q[1])
        assert not np.shares_memory(first, again), name
        with pytest.raises(ValueError, match=r"q must have shape \(19,\)"):
            method(Q[0][:-1], V[0]) if rates else method(Q[0][:-1])
        with pytest.raises(TypeError, match="q must be an array of numbers"):
            method("q", V[0]) if rates else method("q")
        if rates:
            with pytest.raises(ValueError, match=r"qd must have shape \(18,\)"):
                method(Q[0], V[0][:-1])
            with pytest.raises(ValueError, match="qd has 2 rows"):
                method(Q, V[:2])
    with pytest.raises(KeyError, match="unknown parameter"):
        dyn.center_of_mass(Q[0], p={"no such mass": 1.0})


def test_the_backends_agree(cache_dir):
    model = floating_tree(1)
    compiled = gagen.load(model, cache_dir=cache_dir)
    reference = gagen.load(model, backend="lambdify")
    rng = np.random.default_rng(2)
    Q, V = zip(*[random_state(compiled, rng)[:2] for _ in range(2)])
    Q, V = np.array(Q), np.array(V)
    for name in METHODS:
        args = (Q, V) if name in ("com_velocity", "centroidal_momentum",
                                  "centroidal_map_time_variation", "centroidal_bias") else (Q,)
        close(getattr(compiled, name)(*args), getattr(reference, name)(*args), name, 1e-12)


def test_the_c_api(anymal):
    """<model>_centroidal_map and the others, called as C functions."""
    lib = ctypes.CDLL(anymal.module.__file__)
    ident = anymal.info.name
    double_p = np.ctypeslib.ndpointer(np.float64, flags="C")
    q, v, _ = random_state(anymal, np.random.default_rng(9))
    p = anymal.parameter_vector()
    for name, rows, cols in (("center_of_mass", 3, 1), ("com_velocity", 3, 1),
                             ("com_jacobian", 3, anymal.nv), ("centroidal_map", 6, anymal.nv),
                             ("centroidal_momentum", 6, 1),
                             ("centroidal_map_time_variation", 6, anymal.nv),
                             ("centroidal_bias", 6, 1)):
        function = getattr(lib, f"{ident}_{name}")
        rates = name in ("com_velocity", "centroidal_momentum",
                         "centroidal_map_time_variation", "centroidal_bias")
        function.argtypes = [double_p] * (4 if rates else 3)
        function.restype = None
        out = np.full(rows * cols, np.nan)
        function(q, v, p, out) if rates else function(q, p, out)
        expected = getattr(anymal, name)(q, v) if rates else getattr(anymal, name)(q)
        close(out, np.ravel(expected), f"C {name}", 1e-15)

