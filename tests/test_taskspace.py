"""Task-space quantities (issue 25): frames' Jacobians and velocities in every reference,
their classical and spatial accelerations, the Jacobians' time variation, the
operational-space inertia and the Delassus matrix.

References: Pinocchio (getFrameJacobian, getFrameVelocity, getFrameClassicalAcceleration,
getFrameAcceleration, getFrameJacobianTimeVariation after computeJointJacobiansTimeVariation,
computeMinverse) to 1e-9 relative, on the Panda and ANYmal C (Pinocchio's own URDF parse,
joints matched by name), Talos (slow) and random fixed and floating trees with every joint
type (gagen's Pinocchio builder); then the defining identities against finite differences
of gagen's own functions along a trajectory: d/dt (J qd) = J qdd + J̇ qd, the classical
acceleration is the second derivative of the frame's origin, and Λ J M⁻¹ Jᵀ = I.
"""

from __future__ import annotations

import ctypes
import functools
import warnings
from pathlib import Path

import numpy as np
import pytest
from random_trees import random_model
from test_floating import floating_tree, pinocchio_frame, random_state

import gagen
from gagen.model.numeric import numeric_model
from gagen.reference.pinocchio import pinocchio_model

pin = pytest.importorskip("pinocchio")

URDF = Path(__file__).resolve().parent / "data" / "urdf"
RTOL = 1e-9
REFERENCES = ("local_world_aligned", "local", "world")
FEET = ("LF_FOOT", "RF_FOOT", "LH_FOOT", "RH_FOOT")


def close(actual, expected, what: str, rtol: float = RTOL, scale: float | None = None):
    """|actual - expected| <= rtol * scale (default: the largest entry of expected)."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != {expected.shape}"
    if scale is None:
        scale = float(np.abs(expected).max())
    error = float(np.abs(actual - expected).max()) if actual.size else 0.0
    assert error <= rtol * max(scale, 1e-300), f"{what}: error {error:.3g}, scale {scale:.3g}"


class Twin:
    """Pinocchio's model of the same robot, with the permutations between gagen's vectors
    and its own: gagen's builder gives them (`gagen_order`: gagen's coordinate of each of
    Pinocchio's velocities); for Pinocchio's URDF parse the joints are matched by name."""

    def __init__(self, dyn, model):
        self.dyn, self.model, self.data = dyn, model, model.createData()
        if hasattr(model, "gagen_order"):
            self.v_index = np.argsort(model.gagen_order)
            self.q_index = np.argsort(model.gagen_configuration_order)
        else:
            v_index, q_index = [], []
            base = 6 if dyn.nq != dyn.nv else 0
            v_index += range(base)
            q_index += range(base + (base > 0))
            for name in dyn.coordinates[base:]:
                joint = model.getJointId(name)
                assert model.nqs[joint] == 1, "no continuous joints in these robots"
                v_index.append(model.idx_vs[joint])
                q_index.append(model.idx_qs[joint])
            self.v_index, self.q_index = np.array(v_index), np.array(q_index)
        self.reference = {"world": pin.WORLD, "local": pin.LOCAL,
                          "local_world_aligned": pin.LOCAL_WORLD_ALIGNED}

    def q(self, q):
        out = np.empty(self.model.nq)
        out[self.q_index] = q
        return out

    def v(self, v):
        out = np.empty(self.model.nv)
        out[self.v_index] = v
        return out

    def ours(self, x):
        return np.asarray(x)[..., self.v_index]

    def frame(self, name: str) -> int:
        kind = {f: k for f, _, k in self.dyn.info.frames}[name]
        return pinocchio_frame(self.model, name, kind)

    def at(self, q, v, a):
        """Pinocchio's kinematics of (q, v, a), with the Jacobians and their time variation."""
        m, d = self.model, self.data
        qp, vp, ap = self.q(q), self.v(v), self.v(a)
        pin.forwardKinematics(m, d, qp, vp, ap)
        pin.updateFramePlacements(m, d)
        pin.computeJointJacobians(m, d, qp)
        pin.computeJointJacobiansTimeVariation(m, d, qp, vp)


def check_frames_against_pinocchio(dyn, twin: Twin, frames, seed: int = 0,
                                   states: int = 2) -> None:
    """Every reference and both kinds, for each frame at random states."""
    rng = np.random.default_rng(seed)
    m, d = twin.model, twin.data
    for _ in range(states):
        q, v, a = random_state(dyn, rng)
        zero = np.zeros(dyn.nv)
        bias_at = {}
        twin.at(q, v, zero)  # the bias accelerations: Pinocchio at a = 0
        for frame in frames:
            fid = twin.frame(frame)
            for reference in REFERENCES:
                rf = twin.reference[reference]
                bias_at[frame, reference] = (
                    pin.getFrameClassicalAcceleration(m, d, fid, rf).vector,
                    pin.getFrameAcceleration(m, d, fid, rf).vector)
        twin.at(q, v, a)
        for frame in frames:
            fid = twin.frame(frame)
            expected = {}
            for reference in REFERENCES:
                rf = twin.reference[reference]
                expected[reference] = {
                    "J": twin.ours(pin.getFrameJacobian(m, d, fid, rf)),
                    "v": pin.getFrameVelocity(m, d, fid, rf).vector,
                    "classical": pin.getFrameClassicalAcceleration(m, d, fid, rf).vector,
                    "spatial": pin.getFrameAcceleration(m, d, fid, rf).vector,
                    "dJ": twin.ours(pin.getFrameJacobianTimeVariation(m, d, fid, rf)),
                    "bias classical": bias_at[frame, reference][0],
                    "bias spatial": bias_at[frame, reference][1],
                }
            # one scale per quantity and frame, over the references: a LOCAL J̇ can be
            # exactly zero (a frame on a floating base) where the WORLD one is not; and
            # at least 1e-4 (the states are O(1)) for what is zero in every reference
            # (the spatial acceleration of a free body at qdd = 0)
            scales = {key: max(float(np.abs(expected[r][key]).max()) for r in REFERENCES)
                      for key in expected[REFERENCES[0]]}
            for reference in REFERENCES:
                ours = {
                    "J": dyn.frame_jacobian(q, frame, reference),
                    "v": dyn.frame_velocity(q, v, frame, reference),
                    "classical": dyn.frame_acceleration(q, v, a, frame, reference),
                    "spatial": dyn.frame_acceleration(q, v, a, frame, reference, "spatial"),
                    "dJ": dyn.frame_jacobian_time_variation(q, v, frame, reference),
                    "bias classical": dyn.frame_bias_acceleration(q, v, frame, reference),
                    "bias spatial": dyn.frame_bias_acceleration(q, v, frame, reference,
                                                                kind="spatial"),
                }
                for key, value in ours.items():
                    close(value, expected[reference][key], f"{frame} {reference} {key}",
                          scale=max(scales[key], 1e-4))


# ------------------------------------------------------------------------ random trees

def fixed_tree():
    """test_compiled's tree (one build for both), and test_floating's floating trees."""
    return random_model(np.random.default_rng(3), 5, symbolic=True)


TREES = {"fixed3": fixed_tree, "floating1": lambda: floating_tree(1),
         "floating2": lambda: floating_tree(2)}


@functools.cache
def load_tree(tree: str, backend: str, cache_dir: Path):
    """A tree's dynamics, derived once per test session (the lambdify backend derives on
    every load; the compiled one reads the session's cache)."""
    options = {"cache_dir": cache_dir} if backend == "compiled" else {}
    return gagen.load(TREES[tree](), backend=backend, **options)


def test_the_trees_have_every_joint_type():
    types = {b.joint.type for tree in TREES.values() for b in tree().bodies}
    assert types == {"revolute", "continuous", "prismatic", "fixed", "floating"}


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
@pytest.mark.parametrize("tree", list(TREES))
def test_random_trees_match_pinocchio(tree, backend, cache_dir):
    dyn = load_tree(tree, backend, cache_dir)
    twin = Twin(dyn, pinocchio_model(numeric_model(TREES[tree]())))
    check_frames_against_pinocchio(dyn, twin, dyn.frames, seed=len(tree))


# -------------------------------------------------------------------------- real robots

@pytest.fixture(scope="module")
def panda(cache_dir):
    return gagen.load(URDF / "panda.urdf", cache_dir=cache_dir)


@pytest.fixture(scope="module")
def anymal(cache_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        return gagen.load(URDF / "anymal_c.urdf", floating_base=True, cache_dir=cache_dir)


def urdf_twin(dyn, name: str, floating: bool) -> Twin:
    path = str(URDF / name)
    model = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating \
        else pin.buildModelFromUrdf(path)
    return Twin(dyn, model)


def test_panda_matches_pinocchio(panda):
    check_frames_against_pinocchio(panda, urdf_twin(panda, "panda.urdf", False),
                                   panda.frames, seed=1)


def test_panda_lambdify_matches_pinocchio():
    dyn = gagen.load(URDF / "panda.urdf", backend="lambdify")
    check_frames_against_pinocchio(dyn, urdf_twin(dyn, "panda.urdf", False),
                                   ["panda_hand_tcp", "panda_link4", "panda_rightfinger"],
                                   seed=2, states=1)


def test_anymal_matches_pinocchio(anymal):
    check_frames_against_pinocchio(anymal, urdf_twin(anymal, "anymal_c.urdf", True),
                                   anymal.frames, seed=3)


@pytest.mark.slow
def test_talos_matches_pinocchio(cache_dir):
    dyn = gagen.load(URDF / "talos_full_v2.urdf", floating_base=True, cache_dir=cache_dir)
    check_frames_against_pinocchio(dyn, urdf_twin(dyn, "talos_full_v2.urdf", True),
                                   dyn.frames, seed=4, states=1)


# ------------------------------------------------------- identities, finite differences

def trajectory(dyn, q0, v0, a, t):
    """q(t) = q0 ⊕ (t v0 + t²/2 a), v(t) = v0 + t a: the velocity of q(t) is v(t) up to
    O(t²) terms even in t, which a central difference cancels."""
    return dyn.integrate(q0, t * v0 + 0.5 * t * t * a), v0 + t * a


def central(f, h: float):
    return (f(h) - f(-h)) / (2 * h)


@pytest.mark.parametrize("robot", ["panda", "anymal"])
def test_identities_along_a_trajectory(robot, request):
    """d/dt (J qd) = J qdd + J̇ qd in every reference; the classical acceleration in
    LOCAL_WORLD_ALIGNED is the second derivative of the frame's origin, the spatial one
    in LOCAL the rate of the LOCAL velocity; J qdd + bias = the acceleration."""
    dyn = request.getfixturevalue(robot)
    frame = "panda_hand_tcp" if robot == "panda" else "LF_FOOT"
    rng = np.random.default_rng(7)
    for _ in range(3):
        check_identities(dyn, frame, *random_state(dyn, rng))


def check_identities(dyn, frame: str, q0, v0, a) -> None:
    h = 1e-5
    for reference in REFERENCES:
        def Jv(t, reference=reference):
            q, v = trajectory(dyn, q0, v0, a, t)
            return dyn.frame_jacobian(q, frame, reference) @ v
        J = dyn.frame_jacobian(q0, frame, reference)
        dJ = dyn.frame_jacobian_time_variation(q0, v0, frame, reference)
        close(J @ a + dJ @ v0, central(Jv, h), f"d/dt (J qd), {reference}", rtol=1e-7)
        kind = "classical" if reference == "local_world_aligned" else "spatial"
        close(dyn.frame_acceleration(q0, v0, a, frame, reference, kind), J @ a + dJ @ v0,
              f"{kind} acceleration = J qdd + J̇ qd, {reference}", rtol=1e-12)
        for kind in ("classical", "spatial"):
            close(dyn.frame_acceleration(q0, v0, a, frame, reference, kind),
                  J @ a + dyn.frame_bias_acceleration(q0, v0, frame, reference, kind),
                  f"{kind} = J qdd + bias, {reference}", rtol=1e-12)

    def origin(t):
        return dyn.frame_placement(trajectory(dyn, q0, v0, a, t)[0], frame)[1]
    h2 = 1e-4
    second = (origin(h2) - 2 * origin(0.0) + origin(-h2)) / h2**2
    close(dyn.frame_acceleration(q0, v0, a, frame)[:3], second,
          "classical acceleration = the origin's second derivative", rtol=1e-5)

    def local_velocity(t):
        return dyn.frame_velocity(*trajectory(dyn, q0, v0, a, t), frame, "local")
    close(dyn.frame_acceleration(q0, v0, a, frame, "local", "spatial"),
          central(local_velocity, h), "spatial LOCAL = d/dt of the LOCAL velocity",
          rtol=1e-7)


def test_operational_space_inertia_inverts_the_delassus_matrix(anymal, panda):
    rng = np.random.default_rng(11)
    for dyn, frames, dims in ((panda, ["panda_hand_tcp"], 6), (panda, "panda_hand_tcp", 3),
                              (anymal, list(FEET), 3), (anymal, ["LF_FOOT", "RH_FOOT"], 6)):
        q, _, _ = random_state(dyn, rng)
        G = dyn.delassus(q, frames, dims)
        names = [frames] if isinstance(frames, str) else frames
        J = np.concatenate([dyn.frame_jacobian(q, f)[:dims] for f in names])
        M = dyn.mass_matrix(q)
        close(G, J @ np.linalg.solve(M, J.T), f"delassus {names} {dims}", rtol=1e-11)
        Lam = dyn.operational_space_inertia(q, frames, dims)
        close(Lam @ G, np.eye(len(G)), f"Λ J M⁻¹ Jᵀ = I, {names} {dims}", rtol=1e-9, scale=1.0)
        assert np.array_equal(Lam, Lam.T) and np.array_equal(G, G.T)


def test_delassus_matches_pinocchio_minverse(anymal):
    twin = urdf_twin(anymal, "anymal_c.urdf", True)
    m, d = twin.model, twin.data
    rng = np.random.default_rng(12)
    q, _, _ = random_state(anymal, rng)
    qp = twin.q(q)
    Minv = np.array(pin.computeMinverse(m, d, qp))
    Minv = np.triu(Minv) + np.triu(Minv, 1).T
    pin.computeJointJacobians(m, d, qp)
    pin.updateFramePlacements(m, d)
    J = np.concatenate([pin.getFrameJacobian(m, d, twin.frame(f), pin.LOCAL_WORLD_ALIGNED)[:3]
                        for f in FEET])
    G = J @ Minv @ J.T
    close(anymal.delassus(q, FEET, 3), G, "delassus against computeMinverse")
    close(anymal.operational_space_inertia(q, FEET, 3), np.linalg.inv(G),
          "Λ against inv(J Minv Jᵀ)", rtol=1e-8)


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_a_singular_task_is_a_clear_error_naming_its_frames(backend, cache_dir):
    dyn = load_tree("floating1", backend, cache_dir)
    q, _, _ = random_state(dyn, np.random.default_rng(0))
    frame = dyn.frames[-1]
    dyn.operational_space_inertia(q, frame)  # one frame's six rows: fine
    with pytest.raises(gagen.SingularTaskError, match=f"frames '{frame}', '{frame}'"):
        dyn.operational_space_inertia(q, [frame, frame], dims=3)  # the same rows twice
    with pytest.raises(gagen.SingularTaskError, match="stacked input, row 0"):
        Q = np.stack([q, q])
        dyn.operational_space_inertia(Q, [frame, frame], dims=3)
    # two points of the base, b1's origin and b2's (welded to it): their six linear rows
    # have rank 5 (a turn about the line through them moves neither), which rounding
    # leaves as a pivot of either sign, as small as 1e-15 of its row's scale
    assert [dyn.info.bodies[dyn.info.frames[dyn.frames.index(f)][1]][1] for f in
            ("b1", "b2")] == [3, 0]
    rng = np.random.default_rng(3)
    for _ in range(8):
        with pytest.raises(gagen.SingularTaskError):
            dyn.operational_space_inertia(random_state(dyn, rng)[0], ["b1", "b2"], dims=3)
    G = dyn.delassus(q, [frame, frame], dims=6)  # defined: rank-deficient, 12 x 12
    assert G.shape == (12, 12) and np.linalg.matrix_rank(G) == 6
    with pytest.raises(gagen.SingularTaskError, match="singular"):
        dyn.operational_space_inertia(q, [frame, frame], dims=6)  # more rows than nv
    with pytest.raises(ValueError, match="dims must be 6"):
        dyn.delassus(q, frame, dims=4)
    with pytest.raises(ValueError, match="at least one frame"):
        dyn.delassus(q, [])
    with pytest.raises(gagen.NonFiniteStateError):
        dyn.operational_space_inertia(np.full(dyn.nq, np.nan), frame)
    tree = load_tree("fixed3", backend, cache_dir)
    massless = {name: 0.0 for name in tree.parameters if name.startswith("m")}
    with pytest.raises(gagen.SingularMassMatrixError):
        tree.delassus(np.zeros(tree.nq), tree.frames[-1], p=massless)


# --------------------------------------------------------------- the API's contract

@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_stacked_inputs_give_stacked_fresh_outputs(backend, cache_dir):
    dyn = load_tree("floating2", backend, cache_dir)
    rng = np.random.default_rng(5)
    states = [random_state(dyn, rng) for _ in range(3)]
    Q, V, A = (np.stack([s[k] for s in states]) for k in range(3))
    frame, frames = dyn.frames[-1], dyn.frames[-3:]
    calls = {
        "jacobian": lambda q, v, a: dyn.frame_jacobian(q, frame, "local"),
        "jacobians": lambda q, v, a: dyn.frame_jacobian(q, frames, "world"),
        "velocity": lambda q, v, a: dyn.frame_velocity(q, v, frame, "world"),
        "acceleration": lambda q, v, a: dyn.frame_acceleration(q, v, a, frame, "local",
                                                               "spatial"),
        "bias": lambda q, v, a: dyn.frame_bias_acceleration(q, v, frame),
        "time variation": lambda q, v, a: dyn.frame_jacobian_time_variation(q, v, frame,
                                                                            "world"),
        "delassus": lambda q, v, a: dyn.delassus(q, frames[:2], 3),
        "inertia": lambda q, v, a: dyn.operational_space_inertia(q, frame),
    }
    for name, call in calls.items():
        stacked = call(Q, V, A)
        assert stacked.shape[0] == 3, name
        for k in range(3):
            one = call(Q[k], V[k], A[k])
            close(stacked[k], one, f"stacked {name}", rtol=1e-15, scale=1.0)
        again = call(Q[0], V[0], A[0])
        assert again is not one and not np.shares_memory(again, one), name
    # a list of frames: each frame's Jacobian, as one call gives it
    J = dyn.frame_jacobian(Q[0], frames, "local")
    assert J.shape == (3, 6, dyn.nv)
    for k, f in enumerate(frames):
        assert np.array_equal(J[k], dyn.frame_jacobian(Q[0], f, "local"))
    assert dyn.frame_jacobian(Q, frames).shape == (3, 3, 6, dyn.nv)


def test_bad_arguments_are_refused_with_one_line(anymal):
    q, v, a = random_state(anymal, np.random.default_rng(1))
    with pytest.raises(ValueError, match="reference must be 'local_world_aligned'"):
        anymal.frame_jacobian(q, "LF_FOOT", "LOCAL")
    with pytest.raises(ValueError, match="reference must be"):
        anymal.frame_velocity(q, v, "LF_FOOT", 2)
    with pytest.raises(ValueError, match="kind must be 'classical' or 'spatial'"):
        anymal.frame_acceleration(q, v, a, "LF_FOOT", kind="classic")
    with pytest.raises(KeyError, match="unknown frame 'LF_FOOTX'"):
        anymal.frame_bias_acceleration(q, v, "LF_FOOTX")
    with pytest.raises(KeyError, match="unknown frame"):
        anymal.frame_jacobian(q, ["LF_FOOT", "nope"])
    with pytest.raises(ValueError, match=r"qdd must have shape \(18,\)"):
        anymal.frame_acceleration(q, v, a[:3], "LF_FOOT")
    with pytest.raises(ValueError, match=r"q must have shape \(19,\)"):
        anymal.frame_jacobian_time_variation(v, v, "LF_FOOT")


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_a_quaternion_that_cannot_be_normalised_is_refused(backend, cache_dir):
    """As every method taking q (test_hostile_input_round3): one line naming the joint."""
    dyn = load_tree("floating2", backend, cache_dir)
    v, frame = np.zeros(dyn.nv), dyn.frames[-1]
    for quaternion, says in (([0.0] * 4, "is zero"), ([1e200, 0, 0, 1e200], "overflows")):
        q = dyn.neutral()
        q[3:7] = quaternion
        calls = ((dyn.frame_jacobian, (q, [frame], "world")),
                 (dyn.frame_acceleration, (q, v, v, frame)),
                 (dyn.frame_bias_acceleration, (q, v, frame, "local")),
                 (dyn.frame_jacobian_time_variation, (q, v, frame)),
                 (dyn.delassus, (q, frame)),
                 (dyn.operational_space_inertia, (np.stack([dyn.neutral(), q]), frame)))
        for call, args in calls:
            with pytest.raises(ValueError, match=f"quaternion of floating joint 'base'.*{says}"
                               ) as error:
                call(*args)
            assert "\n" not in str(error.value)


def test_the_c_api_has_the_task_space_functions(anymal):
    """<model>_frame_acceleration, _frame_jacobian_time_variation and
    _operational_space_inertia, called as C functions."""
    lib = ctypes.CDLL(anymal.module.__file__)
    ident = anymal.info.name
    double_p = np.ctypeslib.ndpointer(np.float64, flags="C")
    int_p = np.ctypeslib.ndpointer(np.int32, flags="C")
    q, v, a = random_state(anymal, np.random.default_rng(2))
    p = anymal.parameter_vector()
    foot = anymal.frames.index("LF_FOOT")
    acc = getattr(lib, f"{ident}_frame_acceleration")
    acc.argtypes = [double_p, double_p, double_p, double_p] + [ctypes.c_int] * 3 + [double_p]
    out = np.empty(6)
    assert acc(q, v, a, p, foot, 1, 1, out) == 0  # LOCAL, spatial
    close(out, anymal.frame_acceleration(q, v, a, "LF_FOOT", "local", "spatial"), "C", 1e-15)
    assert acc(q, v, a, p, foot, 3, 0, out) != 0  # no such reference
    dj = getattr(lib, f"{ident}_frame_jacobian_time_variation")
    dj.argtypes = [double_p, double_p, double_p, ctypes.c_int, ctypes.c_int, double_p]
    dJ = np.empty((6, anymal.nv))
    assert dj(q, v, p, foot, 0, dJ) == 0
    close(dJ, anymal.frame_jacobian_time_variation(q, v, "LF_FOOT", "world"), "C J̇", 1e-15)
    osi = getattr(lib, f"{ident}_operational_space_inertia")
    osi.argtypes = [double_p, double_p, ctypes.c_int, int_p, ctypes.c_int, double_p, double_p]
    frames = np.array([anymal.frames.index(f) for f in FEET], dtype=np.int32)
    work, Lam = np.empty(12 * anymal.nv), np.empty((12, 12))
    assert osi(q, p, 4, frames, 3, work, Lam) == 0
    close(Lam, anymal.operational_space_inertia(q, FEET, 3), "C Λ", 1e-15)


def test_the_bench_section_reports_ratios_and_the_goal():
    from gagen.bench.report import markdown
    from gagen.bench.taskspace import goal_notes

    def row(quantity, implementation, median, ratio):
        return {"robot": "panda (panda_hand_tcp)", "quantity": f"panda (panda_hand_tcp): "
                f"{quantity}", "implementation": implementation, "call": "f(x)",
                "median_us": median, "q1_us": median, "q3_us": median, "iqr_us": 0.0,
                "ratio": ratio}
    rows = [row("J̇ q̇", "gagen compiled", 1.0, 1.0), row("J̇ q̇", "Pinocchio", 2.0, 2.0),
            row("Λ", "gagen compiled", 2.0, 1.0), row("Λ", "Pinocchio", 2.8, 1.4)]
    notes = goal_notes(rows)
    assert notes == [("Goal: task space on panda (panda_hand_tcp) at least 1.5x faster "
                      "than Pinocchio per call: NOT met (J̇ q̇ 2.00x, Λ 1.40x).")]
    text = markdown({"taskspace": {"rows": rows, "repeats": 3}})
    assert "## Task space per call" in text
    assert "| panda (panda_hand_tcp): Λ | Pinocchio | `f(x)` | 2.80 |" in text


@pytest.fixture(scope="module")
def example():
    import importlib.util

    from conftest import REPO

    path = REPO / "examples" / "taskspace_circle.py"
    spec = importlib.util.spec_from_file_location("taskspace_circle", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_circle_example_tracks_with_the_drift_and_lags_without(example, panda):
    """docs/taskspace.md: the operational-space law with J̇ q̇ brings the 3-cm error down by
    six orders of magnitude within a second; without J̇ q̇ the tool stays off the circle."""
    with_drift = example.track(panda, duration=1.0, samples=11)
    without = example.track(panda, duration=1.0, drift=False, samples=11)
    start = with_drift.error[0]
    assert abs(start - 0.03) < 1e-12
    assert with_drift.error[-1] < 1e-6 * start
    assert without.error[-1] > 1e-4
