"""Floating bases, frames and external wrenches, against Pinocchio's own algorithms.

References: `pinocchio.buildModelFromUrdf(path, JointModelFreeFlyer())` (Pinocchio's URDF
parse, nothing of gagen's shared) for the shared robots, and gagen's Pinocchio builder
(`gagen.reference.pinocchio`) for random floating trees. Checked at random states to
1e-9 relative: M, forward and inverse dynamics, gravity, energy, integrate, difference,
every frame's placement, velocity and Jacobian (LOCAL_WORLD_ALIGNED), and aba / rnea with
external forces; integrate and difference up to and at a half turn of the base. Then the
simulations: a torque-free tumbling body keeps its energy and a unit quaternion and turns
as Pinocchio's own integration of it does, gagen's dopri5 takes SciPy RK45's steps, and a
quadruped standing on four feet (contact forces by least squares on the feet's Jacobians)
stays still.
"""

from __future__ import annotations

import ctypes
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from random_trees import random_model

import gagen
from gagen.model import Body, Joint, Model
from gagen.model.numeric import numeric_model
from gagen.reference.pinocchio import pinocchio_model

pin = pytest.importorskip("pinocchio")

URDF = Path(__file__).resolve().parent / "data" / "urdf"
RTOL = 1e-9
FEET = ("LF_FOOT", "RF_FOOT", "LH_FOOT", "RH_FOOT")


def close(actual, expected, what: str, rtol: float = RTOL) -> None:
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    scale = max(float(np.abs(expected).max()), 1e-300)
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=rtol * scale, err_msg=what)


class Reference:
    """Pinocchio's model of the same robot, taking and giving gagen's vectors."""

    def __init__(self, dyn, model):
        self.model, self.data = model, model.createData()
        if hasattr(model, "gagen_order"):  # gagen's builder: gagen's index of Pinocchio's k-th
            # entry; v_order and q_order are the other way round: Pinocchio's index of ours
            self.v_order = np.argsort(model.gagen_order)
            self.q_order = np.argsort(model.gagen_configuration_order)
        else:  # Pinocchio's URDF parse: match the joints by name, the base first
            names = dyn.coordinates[6:]
            ids = [model.getJointId(n) for n in names]
            assert all(model.nqs[j] == 1 for j in ids), "no continuous joints in these robots"
            self.v_order = np.array([*range(6), *(model.idx_vs[j] for j in ids)])
            self.q_order = np.array([*range(7), *(model.idx_qs[j] for j in ids)])

    def q(self, q):
        out = np.empty(self.model.nq)
        out[self.q_order] = q
        return out

    def v(self, v):
        out = np.empty(self.model.nv)
        out[self.v_order] = v
        return out

    def ours(self, v):
        return np.asarray(v)[..., self.v_order]

    def joint_forces(self, v):
        """The URDF joints' damping and Coulomb friction as Pinocchio parsed them, which gagen
        puts in the dynamics and Pinocchio's rnea and aba leave out."""
        v = self.v(v)
        return self.ours(self.model.damping * v + self.model.friction * np.sign(v))

    def mass_matrix(self, q):
        M = np.array(pin.crba(self.model, self.data, self.q(q)))
        M = np.triu(M) + np.triu(M, 1).T
        return M[np.ix_(self.v_order, self.v_order)]

    def fext(self, q, fid: int, wrench):
        """Pinocchio's external forces (per joint, in the joint's frame) of a wrench in
        world axes at the origin of its frame `fid`."""
        m, d = self.model, self.data
        pin.framesForwardKinematics(m, d, self.q(q))
        joint = m.frames[fid].parentJoint
        at_origin = pin.SE3(np.eye(3), d.oMf[fid].translation)
        force = at_origin.act(pin.Force(np.asarray(wrench[:3]), np.asarray(wrench[3:])))
        forces = [pin.Force.Zero() for _ in range(m.njoints)]
        forces[joint] = d.oMi[joint].actInv(force)
        return forces


def random_state(dyn, rng):
    q = dyn.neutral()
    for iq, _ in dyn.info.floating_joints():
        quaternion = rng.normal(size=4)
        q[iq: iq + 3] = rng.normal(size=3)
        q[iq + 3: iq + 7] = quaternion / np.linalg.norm(quaternion)
    plain = [k for k, name in enumerate(dyn.configuration) if name in dyn.coordinates]
    q[plain] = rng.uniform(-1.2, 1.2, len(plain))
    return q, rng.normal(size=dyn.nv), rng.normal(size=dyn.nv)


def check_against_pinocchio(dyn, ref: Reference, seed: int = 0, states: int = 3) -> None:
    rng = np.random.default_rng(seed)
    m, d = ref.model, ref.data
    for _ in range(states):
        q, v, a = random_state(dyn, rng)
        qp, vp, ap = ref.q(q), ref.v(v), ref.v(a)
        close(dyn.mass_matrix(q), ref.mass_matrix(q), "M")
        friction = ref.joint_forces(v)
        tau = a + friction  # the torque Pinocchio's aba sees is a less the joint forces
        close(dyn.inverse_dynamics(q, v, a),
              ref.ours(pin.rnea(m, d, qp, vp, ap)) + friction, "rnea")
        close(dyn.forward_dynamics(q, v, tau), ref.ours(pin.aba(m, d, qp, vp, ap)), "aba")
        close(dyn.gravity(q), ref.ours(pin.computeGeneralizedGravity(m, d, qp)), "gravity")
        close(dyn.energy(q, v)[0], pin.computeKineticEnergy(m, d, qp, vp), "kinetic energy")
        q2, _, _ = random_state(dyn, rng)
        close(dyn.energy(q2, v)[1] - dyn.energy(q, v)[1],
              pin.computePotentialEnergy(m, d, ref.q(q2)) - pin.computePotentialEnergy(m, d, qp),
              "potential energy")
        moved = dyn.integrate(q, v, 0.3)
        expected = pin.integrate(m, qp, vp * 0.3)
        # the same configuration (a quaternion and its negative are one orientation)
        assert np.abs(dyn.difference(moved, _ours_q(ref, expected))).max() < 1e-12
        close(dyn.difference(q, q2), ref.ours(pin.difference(m, qp, ref.q(q2))), "difference")
        pin.forwardKinematics(m, d, qp, vp)
        pin.updateFramePlacements(m, d)
        pin.computeJointJacobians(m, d, qp)
        for frame, _, kind in dyn.info.frames:
            fid = pinocchio_frame(m, frame, kind)
            R, p = dyn.frame_placement(q, frame)
            close(R, d.oMf[fid].rotation, f"{frame} rotation")
            close(p, d.oMf[fid].translation, f"{frame} position")
            J = pin.getFrameJacobian(m, d, fid, pin.LOCAL_WORLD_ALIGNED)
            close(dyn.frame_jacobian(q, frame), ref.ours(J), f"{frame} Jacobian")
            velocity = pin.getFrameVelocity(m, d, fid, pin.LOCAL_WORLD_ALIGNED).vector
            close(dyn.frame_velocity(q, v, frame), velocity, f"{frame} velocity")
        frame = dyn.info.frames[-1][0]
        assert frame.split(":")[-1] == m.frames[pinocchio_frame(m, *dyn.info.frames[-1][::2])].name
        wrench = rng.normal(size=6)
        forces = ref.fext(q, pinocchio_frame(m, *dyn.info.frames[-1][::2]), wrench)
        close(dyn.forward_dynamics(q, v, tau, fext={frame: wrench}),
              ref.ours(pin.aba(m, d, qp, vp, ap, forces)), "aba with fext")
        close(dyn.inverse_dynamics(q, v, a, fext={frame: wrench}),
              ref.ours(pin.rnea(m, d, qp, vp, ap, forces)) + friction, "rnea with fext")


def pinocchio_frame(model, name: str, kind: str) -> int:
    """Pinocchio's frame of one of gagen's: a link is a BODY frame, a joint a JOINT (or, for
    a fixed joint, FIXED_JOINT) frame; `joint:<name>` is the joint of a name both share."""
    name = name.split(":", 1)[1] if name.startswith(("joint:", "link:")) else name
    if kind == "link":
        return model.getFrameId(name, pin.BODY)
    for frame_type in (pin.JOINT, pin.FIXED_JOINT):
        if model.existFrame(name, frame_type):
            return model.getFrameId(name, frame_type)
    raise KeyError(name)


def _ours_q(ref: Reference, q_pin) -> np.ndarray:
    return np.asarray(q_pin)[ref.q_order]


# --------------------------------------------------------------------- the real robots

@pytest.fixture(scope="module")
def anymal(cache_dir):  # the session's cache: test_centroidal and test_taskspace load it
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        return gagen.load(URDF / "anymal_c.urdf", floating_base=True, cache_dir=cache_dir)


def test_anymal_floating_matches_pinocchio(anymal):
    assert (anymal.nq, anymal.nv) == (19, 18)
    assert anymal.configuration[:7] == [f"root_joint_{s}" for s in
                                        ("x", "y", "z", "qx", "qy", "qz", "qw")]
    assert anymal.coordinates[:6] == [f"root_joint_{s}" for s in
                                      ("vx", "vy", "vz", "wx", "wy", "wz")]
    model = pin.buildModelFromUrdf(str(URDF / "anymal_c.urdf"), pin.JointModelFreeFlyer())
    check_against_pinocchio(anymal, Reference(anymal, model))


@pytest.mark.slow
def test_talos_floating_matches_pinocchio(tmp_path):
    path = URDF / "talos_full_v2.urdf"
    dyn = gagen.load(path, floating_base=True, cache_dir=tmp_path)
    model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    check_against_pinocchio(dyn, Reference(dyn, model), states=2)


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_panda_tool_frame_matches_pinocchio(backend, cache_dir):
    """A fixed base: the frames of links merged by fixed joints (the hand's tool centre)."""
    path = URDF / "panda.urdf"
    options = {"cache_dir": cache_dir} if backend == "compiled" else {}
    dyn = gagen.load(path, backend=backend, **options)
    assert "panda_hand_tcp" in dyn.frames and "panda_hand_tcp_joint" in dyn.frames
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    ids = [model.getJointId(n) for n in dyn.coordinates]
    order = np.array([model.idx_vs[j] for j in ids])
    rng = np.random.default_rng(4)
    for _ in range(3):
        q = rng.uniform(-1, 1, dyn.n)
        qp = np.empty(model.nq)
        qp[order] = q
        pin.computeJointJacobians(model, data, qp)
        pin.updateFramePlacements(model, data)
        fid = model.getFrameId("panda_hand_tcp")
        R, p = dyn.frame_placement(q, "panda_hand_tcp")
        close(R, data.oMf[fid].rotation, "tcp rotation")
        close(p, data.oMf[fid].translation, "tcp position")
        J = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
        close(dyn.frame_jacobian(q, "panda_hand_tcp"), J[:, order], "tcp Jacobian")


# ----------------------------------------------------------------- random floating trees

def floating_tree(seed: int, bodies: int = 5) -> Model:
    """A random tree whose first body floats, every other root re-attached to it."""
    tree = random_model(np.random.default_rng(seed), bodies)
    first = tree.bodies[0]
    root = Body(name=first.name, parent="world", joint=Joint(name="base", type="floating"),
                mass=first.mass if float(first.mass) > 0 else 1.0, com=first.com,
                inertia=first.inertia)
    rest = [b if b.parent != "world" else Body(b.name, first.name, b.joint, b.mass, b.com,
                                                 b.inertia) for b in tree.bodies[1:]]
    return Model(name=f"floating{seed}", bodies=(root, *rest), parameters=tree.parameters,
                 gravity=tree.gravity, source="<floating tree>")


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_random_floating_trees_match_pinocchio(seed, backend, cache_dir):
    model = floating_tree(seed)
    options = {"cache_dir": cache_dir} if backend == "compiled" else {}
    dyn = gagen.load(model, backend=backend, **options)
    check_against_pinocchio(dyn, Reference(dyn, pinocchio_model(numeric_model(model))), seed)


def test_recursive_and_gibbs_appell_agree_on_a_floating_tree():
    """The quasi-velocities through both derivations (GA: the paper's route)."""
    model = floating_tree(3, bodies=4)
    ga = gagen.load(model, backend="lambdify", derivation="gibbs-appell")
    rec = gagen.load(model, backend="lambdify", derivation="recursive")
    rng = np.random.default_rng(0)
    q, v, a = random_state(ga, rng)
    for name in ("mass_matrix", "inverse_dynamics", "forward_dynamics"):
        args = (q,) if name == "mass_matrix" else (q, v, a)
        close(getattr(ga, name)(*args), getattr(rec, name)(*args), name, rtol=1e-12)


# ------------------------------------------------------------------------- simulations

@pytest.fixture(scope="module")
def tumbler(tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "tumbler.yaml"
    path.write_text(TUMBLER)
    return gagen.load(path, cache_dir=tmp_path_factory.mktemp("cache"))


TUMBLER = """
name: tumbler
gravity: [0, 0, -g]
parameters: {g: 9.81, m: 2.0}
bodies:
  - name: box
    joint: {name: base, type: floating}
    mass: m
    com: [0.1, 0, 0]
    inertia: [0.1, 0.2, 0.3, 0.01, 0, 0]
  - name: arm
    parent: box
    joint: {name: hinge, type: revolute, axis: [0, 1, 0], origin: {xyz: [0.2, 0, 0]}}
    mass: 1.0
    com: [0, 0, -0.2]
    inertia: [0.02, 0.02, 0.001, 0, 0, 0]
"""


# the tumble: from a turned, displaced base; g = 0
TUMBLE_Q0 = np.array([0.1, -0.2, 0.3, *(np.array([0.3, -0.5, 0.2, 0.8]) / math.sqrt(1.02)), 0.4])
TUMBLE_V0 = np.array([0.3, 0.0, 0.1, 1.0, 2.0, 0.5, 3.0])
TUMBLE_T = np.linspace(0.0, 5.0, 501)


@pytest.fixture(scope="module")
def tumble_reference():
    """The tumble integrated with Pinocchio alone, by SciPy's DOP853 at 1e-13: aba for the
    accelerations, and its tangent map (q' = T(q) v, Pinocchio's integrate differentiated)
    for the configuration's rate, so the base's velocity moves its quaternion as Pinocchio
    says, in the base's frame."""
    from scipy.integrate import solve_ivp

    from gagen.model.modelfile import parse_model_text

    ref = Reference(None, pinocchio_model(parse_model_text(TUMBLER, "tumbler.yaml"),
                                          {"g": 0.0}))
    m, d, nq = ref.model, ref.data, ref.model.nq

    def rate(t, y):
        q, v = y[:nq].copy(), y[nq:]
        q[3:7] /= np.linalg.norm(q[3:7])
        qp, vp = ref.q(q), ref.v(v)
        qdd = ref.ours(pin.aba(m, d, qp, vp, np.zeros(m.nv)))
        return np.concatenate([_ours_q(ref, pin.tangentMap(m, qp) @ vp), qdd])

    y0 = np.concatenate([TUMBLE_Q0, TUMBLE_V0])
    sol = solve_ivp(rate, (0.0, 5.0), y0, method="DOP853", rtol=1e-13, atol=1e-13,
                    t_eval=TUMBLE_T)
    assert sol.success, sol.message
    return sol.y[:nq].T


@pytest.mark.parametrize("method", ["dopri5", "RK45", "rk4"])
def test_torque_free_tumbling_keeps_energy_and_a_unit_quaternion(tumbler, tumble_reference,
                                                                   method):
    """Energy and a unit quaternion, and the motion itself: the base's orientation and
    position and the hinge against Pinocchio's tumble (tumble_reference), so a quaternion
    turned by the angular velocity in the wrong frame (world for body) fails."""
    options = {"h": 1e-3} if method == "rk4" else {"rtol": 1e-10, "atol": 1e-12}
    result = gagen.simulate(tumbler, (0.0, 5.0), TUMBLE_Q0, TUMBLE_V0, method=method,
                            p={"g": 0.0}, **options)
    kinetic = tumbler.energy(result.q, result.qd, p={"g": 0.0})[0]
    assert np.abs(kinetic - kinetic[0]).max() < 1e-8 * kinetic[0]
    assert np.abs(np.linalg.norm(result.q[:, 3:7], axis=1) - 1).max() < 1e-14
    assert result.q.shape == (501, 8) and result.qd.shape == (501, 7)
    assert result.columns()[:3] == ["t", "base_x", "base_y"]
    np.testing.assert_array_equal(result.t, TUMBLE_T)
    # the body really tumbled: its orientation changed by much more than the tolerance
    assert np.abs(result.q[-1, 3:7] - result.q[0, 3:7]).max() > 0.1
    want = tumble_reference
    sign = np.where(np.sum(result.q[:, 3:7] * want[:, 3:7], axis=1) < 0, -1.0, 1.0)
    orientation = np.abs(result.q[:, 3:7] - sign[:, None] * want[:, 3:7]).max()
    position = np.abs(result.q[:, [0, 1, 2, 7]] - want[:, [0, 1, 2, 7]]).max()
    assert orientation < 1e-8 and position < 1e-8, (orientation, position)


def test_dopri5_takes_scipy_rk45_steps_with_a_floating_base(tumbler):
    q0 = tumbler.neutral()
    v0 = np.array([0.3, 0.0, 0.1, 1.0, 2.0, 0.5, 3.0])
    c = gagen.simulate(tumbler, (0.0, 2.0), q0, v0, method="dopri5")
    s = gagen.simulate(tumbler, (0.0, 2.0), q0, v0, method="RK45")
    assert c.stats["nfev"] == s.stats["nfev"]
    np.testing.assert_allclose(c.q, s.q, rtol=1e-10, atol=1e-10)
    total = sum(tumbler.energy(c.q, c.qd))  # gravity on: kinetic + potential is conserved
    assert np.abs(total - total[0]).max() < 2e-4 * np.abs(total).max()  # at rtol 1e-6


def test_a_quadruped_stands_still_on_four_feet(anymal):
    """Contact forces from a least-squares solve on the feet's Jacobians (the base's six
    equations), joint torques for the rest: qdd = 0, and 2 s of simulation keep it still."""
    dyn = anymal
    q0 = dyn.neutral()
    q0[2] = 0.6
    posture = {"HAA": 0.0, "HFE": 0.5, "KFE": -1.0}
    for k, name in enumerate(dyn.coordinates[6:]):
        sign = -1 if name.startswith(("LH", "RH")) else 1
        q0[7 + k] = sign * posture[name.split("_")[1]]
    gravity = dyn.gravity(q0)
    JT = np.concatenate([dyn.frame_jacobian(q0, foot)[:3] for foot in FEET]).T  # nv x 12
    forces, *_ = np.linalg.lstsq(JT[:6], gravity[:6], rcond=None)
    torques = gravity - JT @ forces
    assert np.abs(torques[:6]).max() < 1e-9 * np.abs(gravity).max()
    assert forces[2::3].min() > 100  # each foot carries its share of about 51 kg
    fext = {foot: np.concatenate([forces[3 * k: 3 * k + 3], np.zeros(3)])
            for k, foot in enumerate(FEET)}
    assert np.abs(dyn.forward_dynamics(q0, np.zeros(dyn.nv), torques, fext=fext)).max() < 1e-10
    target = np.zeros(dyn.nv)
    target[6:] = q0[7:]
    hold = gagen.PD(kp=100.0, kd=5.0, target=target, feedforward=torques)
    for method in ("dopri5", "RK45"):
        run = gagen.simulate(dyn, (0.0, 2.0), q0, None, controller=hold, method=method,
                             fext=fext)
        drift = dyn.difference(np.tile(q0, (len(run.t), 1)), run.q)
        assert np.abs(drift).max() < 1e-5, method
        assert np.abs(run.qd).max() < 1e-4, method


def test_a_floating_batch_gives_simulate_s_numbers(tumbler):
    rng = np.random.default_rng(2)
    velocities = rng.normal(size=(3, tumbler.nv))
    batch = gagen.simulate_batch(tumbler, (0.0, 1.0), tumbler.neutral(), velocities)
    for k in range(3):
        single = gagen.simulate(tumbler, (0.0, 1.0), tumbler.neutral(), velocities[k],
                                method="dopri5")
        assert np.array_equal(batch.q[k], single.q) and np.array_equal(batch.qd[k], single.qd)


# --------------------------------------------------------------------- inputs and the C API

def test_inputs_are_checked_against_nq_and_nv(tumbler):
    with pytest.raises(ValueError, match=r"q must have shape \(8,\)"):
        tumbler.mass_matrix(np.zeros(7))
    with pytest.raises(ValueError, match=r"qd must have shape \(7,\)"):
        tumbler.forward_dynamics(tumbler.neutral(), np.zeros(8), np.zeros(7))
    with pytest.raises(ValueError, match="quaternion .* is zero"):
        gagen.simulate(tumbler, (0, 1), np.zeros(8), None)
    with pytest.raises(KeyError, match="unknown frame 'hand'"):
        tumbler.frame_jacobian(tumbler.neutral(), "hand")
    with pytest.raises(ValueError, match="ComputedTorque .* floating"):
        gagen.simulate(tumbler, (0, 1), tumbler.neutral(), None, method="RK45",
                       controller=gagen.ComputedTorque(gagen.Eq11Trajectory(
                           np.zeros(7), np.zeros(7), 1.0)))
    with pytest.raises(gagen.ModelError, match="floating_base=True applies to a URDF"):
        gagen.load("rrr", floating_base=True)


def test_an_urdf_floating_joint_is_honoured(tmp_path):
    text = (URDF / "double_pendulum.urdf").read_text()
    root = gagen.resolve_model(URDF / "double_pendulum.urdf", floating_base=True).bodies[0].name
    first_link = text.index("<link")
    text = (text[:first_link] + f'<link name="world"/>\n  <joint name="free" type="floating">'
            f'<parent link="world"/><child link="{root}"/></joint>\n  ' + text[first_link:])
    path = tmp_path / "floating.urdf"
    path.write_text(text)
    dyn = gagen.load(path, backend="lambdify")
    via_option = gagen.load(URDF / "double_pendulum.urdf", backend="lambdify",
                            floating_base=True)
    assert dyn.coordinates[:6] == [f"free_{s}" for s in ("vx", "vy", "vz", "wx", "wy", "wz")]
    rng = np.random.default_rng(1)
    q, v, a = random_state(dyn, rng)
    close(dyn.inverse_dynamics(q, v, a), via_option.inverse_dynamics(q, v, a), "rnea")


def test_the_c_api_applies_wrenches_on_frames(anymal):
    """<model>_forward_dynamics_ext and _frame_jacobian, called as C functions."""
    lib = ctypes.CDLL(anymal.module.__file__)
    ident = anymal.info.name
    double_p = np.ctypeslib.ndpointer(np.float64, flags="C")
    fd = getattr(lib, f"{ident}_forward_dynamics_ext")
    fd.argtypes = [double_p, double_p, double_p, double_p, ctypes.c_int,
                   np.ctypeslib.ndpointer(np.int32, flags="C"), double_p, double_p]
    fd.restype = ctypes.c_int
    rng = np.random.default_rng(9)
    q, v, tau = random_state(anymal, rng)
    frames = np.array([anymal.frames.index(f) for f in FEET[:2]], dtype=np.int32)
    wrenches = rng.normal(size=(2, 6))
    out = np.empty(anymal.nv)
    assert fd(q, v, tau, anymal.parameter_vector(), 2, frames, wrenches.ravel(), out) == 0
    expected = anymal.forward_dynamics(q, v, tau, fext=dict(zip(FEET[:2], wrenches)))
    close(out, expected, "C forward dynamics with wrenches", rtol=1e-12)
    assert fd(q, v, tau, anymal.parameter_vector(), 1, np.array([10**6], np.int32),
              wrenches.ravel(), out) != 0  # a bad frame number is refused


def test_frames_accept_stacked_states_and_return_fresh_arrays(anymal):
    rng = np.random.default_rng(5)
    states = [random_state(anymal, rng) for _ in range(4)]
    Q = np.stack([s[0] for s in states])
    V = np.stack([s[1] for s in states])
    J = anymal.frame_jacobian(Q, "LF_FOOT")
    R, p = anymal.frame_placement(Q, "LF_FOOT")
    vel = anymal.frame_velocity(Q, V, "LF_FOOT")
    assert J.shape == (4, 6, anymal.nv) and R.shape == (4, 3, 3) and p.shape == (4, 3)
    for k in range(4):
        close(J[k], anymal.frame_jacobian(Q[k], "LF_FOOT"), "stacked Jacobian", 1e-15)
        close(vel[k], J[k] @ V[k], "velocity = J qd", 1e-12)
    first = anymal.frame_jacobian(Q[0], "LF_FOOT")
    again = anymal.frame_jacobian(Q[1], "LF_FOOT")
    assert not np.shares_memory(first, again)
    assert math.isclose(np.linalg.det(R[0]), 1.0, rel_tol=1e-12)


# ------------------------------------------------------------ integrate and difference

# relative rotations of the base: none, tiny, a turn of 1 rad, and within 1e-3 .. 1e-12 of a
# half turn and exactly one, where the angle from a rotation matrix's trace loses half its
# digits and a symmetric matrix gives the axis only up to its entries' signs
HALF_TURN = np.pi
ANGLES = (0.0, 1e-12, 1e-7, 1e-3, 1.0, HALF_TURN - 1e-3, HALF_TURN - 1e-6, HALF_TURN - 1e-7,
          HALF_TURN - 1e-9, HALF_TURN - 1e-12, HALF_TURN)
# axes with mixed signs (a half turn's matrix shows only |n_i| and the products n_i n_j)
AXES = ((1.0, -1.0, 0.0), (0.0, 0.0, -1.0), (0.3, -0.5, 0.8), (-2.0, 1.0, 3.0))


@pytest.fixture(scope="module")
def anymal_reference(anymal):
    model = pin.buildModelFromUrdf(str(URDF / "anymal_c.urdf"), pin.JointModelFreeFlyer())
    return Reference(anymal, model)


def turned(q, angle: float, axis) -> np.ndarray:
    """q with its base turned by `angle` about `axis` (in the base's frame): the quaternion
    q ⊗ (sin(angle/2) n, cos(angle/2)), written out here."""
    n = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    r = np.append(np.sin(angle / 2) * n, np.cos(angle / 2))
    (x, y, z, w), (a, b, c, d) = q[3:7], r
    out = np.array(q, dtype=float)
    out[3:7] = [w * a + d * x + y * c - z * b, w * b + d * y + z * a - x * c,
                w * c + d * z + x * b - y * a, w * d - x * a - y * b - z * c]
    return out


def assert_same_configuration(a, b, what: str) -> None:
    """Equal positions and joints, and quaternions equal up to sign (one orientation)."""
    a, b = np.asarray(a), np.asarray(b)
    plain = np.r_[0:3, 7:a.size]
    np.testing.assert_allclose(a[plain], b[plain], rtol=0, atol=1e-12, err_msg=what)
    sign = 1.0 if np.dot(a[3:7], b[3:7]) >= 0 else -1.0
    np.testing.assert_allclose(a[3:7], sign * b[3:7], rtol=0, atol=1e-12, err_msg=what)


@pytest.mark.parametrize("angle", ANGLES, ids=lambda a: f"pi-{np.pi - a:.0e}" if a > 3 else
                         f"{a:.0e}")
def test_integrate_and_difference_near_a_half_turn(anymal, anymal_reference, angle):
    """integrate(q0, difference(q0, q1)) == q1 and difference(q0, integrate(q0, v)) == v
    (to 1e-12) for base rotations up to and at a half turn, both against Pinocchio's
    integrate and difference; q1's quaternion and its negative give the same difference.
    At exactly a half turn w and -w are one rotation: either answer must reach q1."""
    dyn, ref = anymal, anymal_reference
    m = ref.model
    rng = np.random.default_rng(31)
    for axis in AXES:
        q0, u, _ = random_state(dyn, rng)
        q1 = random_state(dyn, rng)[0]
        q1[3:7] = turned(q0, angle, axis)[3:7]
        v = dyn.difference(q0, q1)
        assert abs(np.linalg.norm(v[3:6]) - angle) <= 1e-12, "the angle of the rotation"
        assert_same_configuration(dyn.integrate(q0, v), q1, "integrate(q0, difference)")
        flipped = q1.copy()
        flipped[3:7] *= -1
        np.testing.assert_allclose(dyn.difference(q0, flipped), v, rtol=0, atol=1e-12)
        theirs = ref.ours(pin.difference(m, ref.q(q0), ref.q(q1)))
        if angle < HALF_TURN:
            np.testing.assert_allclose(v, theirs, rtol=0, atol=1e-12, err_msg="difference")
        else:
            assert_same_configuration(dyn.integrate(q0, theirs), q1, "Pinocchio's answer")
        # the inverse: a velocity whose rotation vector has this length
        u[3:6] = angle * np.asarray(axis) / np.linalg.norm(axis)
        moved = dyn.integrate(q0, u)
        assert_same_configuration(moved, _ours_q(ref, pin.integrate(m, ref.q(q0), ref.v(u))),
                                  "integrate")
        back = dyn.difference(q0, moved)
        if angle < HALF_TURN:
            np.testing.assert_allclose(back, u, rtol=0, atol=1e-12, err_msg="the inverse")
        else:
            assert abs(np.linalg.norm(back[3:6]) - HALF_TURN) <= 1e-12
            assert_same_configuration(dyn.integrate(q0, back), moved, "the inverse at pi")
