"""Constrained dynamics (issue 26): contacts and closed loops declared with a model, the
constrained forward dynamics, impulses, the constraints' rows, and constrained simulations.

References: Pinocchio 4.1's constraintDynamics and impulseDynamics (RigidConstraintModel,
CONTACT_3D and CONTACT_6D in LOCAL and LOCAL_WORLD_ALIGNED, ProximalSettings with mu = 0)
to 1e-9 relative on ANYmal C (every subset of its feet, 6-D feet, 6-D and 3-D loops,
Baumgarte's corrector) and random floating trees; a KKT system assembled in NumPy from
gagen's own M, frame Jacobians and bias accelerations for any subset of axes; a null-space
(reduced-coordinate) solution of the four-bar, from a model file and from MJCF's
<equality connect>, and Pinocchio's MJCF parse of it; physical identities (J q̈ + J̇ q̇ = 0,
the feet's forces carry the robot's weight, a passive loop keeps its energy).
"""

from __future__ import annotations

import functools
import itertools
import warnings
from pathlib import Path

import numpy as np
import pytest
from test_floating import random_state

import gagen
from gagen.model.numeric import numeric_model
from gagen.reference.pinocchio import pinocchio_model
from gagen.runtime.dynamics import Dynamics

DATA = Path(__file__).resolve().parent / "data"
URDF = DATA / "urdf"
FOURBAR = DATA / "constraints" / "fourbar.yaml"
FOURBAR_MJCF = DATA / "constraints" / "fourbar.xml"
FEET = ("LF_FOOT", "RF_FOOT", "LH_FOOT", "RH_FOOT")
RTOL = 1e-9


def close(actual, expected, what: str, rtol: float = RTOL, scale: float | None = None):
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != {expected.shape}"
    if scale is None:
        scale = float(np.abs(expected).max()) if expected.size else 1.0
    error = float(np.abs(actual - expected).max()) if actual.size else 0.0
    assert error <= rtol * max(scale, 1e-300), f"{what}: error {error:.3g}, scale {scale:.3g}"


# ----------------------------------------------------------------------------- the models

# ANYmal C with every kind of constraint the tests need, one build for the session: its
# feet as 3-D contacts in both references, two feet as 6-D contacts, a foot held on five
# axes, loops between two feet (6-D in both references, 3-D, one axis)
ANYMAL_CONSTRAINTS = (
    [gagen.Contact(f, name=f[:2]) for f in FEET]
    + [gagen.Contact(f, reference="local", name=f"{f[:2]}_local") for f in FEET]
    + [gagen.Contact("LF_FOOT", axes="6d", reference="local", name="LF6"),
       gagen.Contact("RH_FOOT", axes="6d", name="RH6"),
       gagen.Contact("RF_FOOT", axes=["x", "z", "rx", "ry", "rz"], reference="local",
                     name="RF5"),
       gagen.Loop("LF_FOOT", "RH_FOOT", axes="6d", reference="local", name="loop6_local"),
       gagen.Loop("LF_FOOT", "RH_FOOT", axes="6d", name="loop6"),
       gagen.Loop("LF_FOOT", "RF_FOOT", reference="local", name="loop3_local"),
       gagen.Loop("LH_FOOT", "RF_FOOT", name="loop3"),
       gagen.Loop("LH_FOOT", "RH_FOOT", axes=["y", "rz"], name="loop2")])


@pytest.fixture(scope="module")
def anymal(cache_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        return gagen.load(URDF / "anymal_c.urdf", floating_base=True, cache_dir=cache_dir,
                          constraints=ANYMAL_CONSTRAINTS)


@functools.cache
def fourbar(backend: str, cache_dir: Path):
    options = {"cache_dir": cache_dir} if backend == "compiled" else {}
    return gagen.load(FOURBAR, backend=backend, **options)


def mask(dyn, *names):
    return [c.name in names for c in dyn.constraints]


def standing(dyn, rng, noise: float = 0.05):
    """ANYmal near a standing posture (its legs' Jacobians well conditioned), with random
    velocities and torques."""
    q = dyn.neutral()
    q[2] = 0.5
    quat = np.array([0.0, 0.0, 0.0, 1.0]) + rng.normal(scale=noise, size=4)
    q[3:7] = quat / np.linalg.norm(quat)
    posture = {"HAA": 0.0, "HFE": 0.6, "KFE": -1.0}
    for k, name in enumerate(dyn.configuration):
        for joint, angle in posture.items():
            if name.endswith(joint):
                front = name.startswith(("LF", "RF"))
                q[k] = (angle if front else -angle) + rng.normal(scale=noise)
    return q, rng.normal(size=dyn.nv), rng.normal(size=dyn.nv) * 10


# ------------------------------------------------------------------------ Pinocchio

class PinConstraints:
    """Pinocchio's constraintDynamics and impulseDynamics of gagen's constraints, on
    Pinocchio's model of the same robot (`Twin` of test_taskspace: the permutations)."""

    def __init__(self, dyn, twin):
        import pinocchio as pin

        self.pin, self.dyn, self.twin = pin, dyn, twin
        self.model, self.data = twin.model, twin.data

    def frame(self, name):
        f = self.model.frames[self.twin.frame(name)]
        return f.parentJoint, f.placement

    def constraint(self, c, kp=0.0, kd=0.0, p=None):
        pin = self.pin
        kind = pin.ContactType.CONTACT_6D if c.holds_frame else pin.ContactType.CONTACT_3D
        ref = pin.LOCAL if c.reference == "local" else pin.LOCAL_WORLD_ALIGNED
        j1, p1 = self.frame(c.frames[0])
        if c.type == "loop":
            j2, p2 = self.frame(c.frames[1])
        else:
            j2, p2 = 0, self.anchor(c, p)
        model = pin.RigidConstraintModel(kind, self.model, j1, p1, j2, p2, ref)
        model.setBaumgarteCorrectorParameters(pin.BaumgarteCorrectorParameters(kp, kd))
        return model

    def anchor(self, c, p):
        from gagen.runtime.constraints import rpy_matrix

        pv = self.dyn.parameter_vector(p)
        names = list(self.dyn.parameters)

        def value(key):
            return pv[names.index(f"anchor_{c.name}_{key}")]
        R = rpy_matrix(value("roll"), value("pitch"), value("yaw")) if c.holds_frame \
            else np.eye(3)
        return self.pin.SE3(R, np.array([value("x"), value("y"), value("z")]))

    def _models(self, names, kp=0.0, kd=0.0, p=None):
        """Pinocchio's models of gagen's constraints given by name (or as constraints)."""
        pin = self.pin
        models = pin.StdVec_RigidConstraintModel()
        chosen = [c for c in self.dyn.constraints if c.name in names] \
            if all(isinstance(n, str) for n in names) else names
        for c in chosen:
            models.append(self.constraint(c, kp, kd, p))
        datas = pin.StdVec_RigidConstraintData()
        for model in models:
            datas.append(model.createData())
        pin.initConstraintDynamics(self.model, self.data, models, datas)
        return models, datas

    def forward(self, names, q, v, tau, kp=0.0, kd=0.0, p=None, mu=0.0, iterations=1):
        models, datas = self._models(names, kp, kd, p)
        settings = self.pin.ProximalSettings(1e-14, mu, iterations)
        a = self.pin.constraintDynamics(self.model, self.data, self.twin.q(q),
                                        self.twin.v(v), self.twin.v(tau), models, datas,
                                        settings)
        return self.twin.ours(a), np.array(self.data.lambda_c)

    def impulse(self, names, q, v, restitution):
        models, datas = self._models(names)
        settings = self.pin.ProximalSettings(1e-14, 0.0, 1)
        v_plus = self.pin.impulseDynamics(self.model, self.data, self.twin.q(q),
                                          self.twin.v(v), models, datas, restitution,
                                          settings)
        return self.twin.ours(v_plus), np.array(self.data.impulse_c)


def conditioned_state(dyn, names, rng, limit: float = 1e5):
    """A random state at which the Delassus matrix of the named constraints has a condition
    number below `limit`: in double precision both gagen's and Pinocchio's solutions are
    then within 1e-9 of the exact one (a 6-D loop between two of ANYmal's feet holds its
    base and two legs square: near symmetric postures the matrix is singular)."""
    on = mask(dyn, *names)
    for _ in range(50):
        q, v, tau = random_state(dyn, rng)
        J = dyn.constraint_jacobian(q, on)
        G = J @ np.linalg.solve(dyn.mass_matrix(q), J.T)
        if np.linalg.cond(G) < limit:
            return q, v, tau
    raise AssertionError(f"no state of condition below {limit:g} for {names}")


def rows_of(dyn, names):
    return np.concatenate([np.arange(c.rows.start, c.rows.stop) for c in dyn.constraints
                           if c.name in names])


def check_against_pinocchio(dyn, ref: PinConstraints, names, q, v, tau, kp=0.0, kd=0.0,
                            rtol=RTOL, p=None):
    qdd, forces = dyn.constrained_forward_dynamics(q, v, tau, mask(dyn, *names), (kp, kd),
                                                   p=p)
    a, lam = ref.forward(names, q, v, tau, kp, kd, p)
    what = f"{dyn.info.name} {', '.join(names)} (kp {kp}, kd {kd})"
    close(qdd, a, f"q̈ of {what}", rtol)
    close(forces[rows_of(dyn, names)], lam, f"forces of {what}", rtol)
    inactive = np.setdiff1d(np.arange(len(forces)), rows_of(dyn, names))
    assert np.all(forces[inactive] == 0.0), "the inactive constraints' forces are zero"


@pytest.fixture(scope="module")
def anymal_pin(anymal):
    pytest.importorskip("pinocchio")
    from test_taskspace import urdf_twin

    return PinConstraints(anymal, urdf_twin(anymal, "anymal_c.urdf", True))


def test_anymal_every_subset_of_feet_matches_pinocchio(anymal, anymal_pin):
    """3-D point contacts in LOCAL_WORLD_ALIGNED, every non-empty subset of the feet."""
    rng = np.random.default_rng(0)
    q, v, tau = random_state(anymal, rng)
    for count in range(1, 5):
        for feet in itertools.combinations(("LF", "RF", "LH", "RH"), count):
            check_against_pinocchio(anymal, anymal_pin, feet, q, v, tau)


@pytest.mark.parametrize("backend", ["compiled", "numpy"])
def test_anymal_contacts_and_loops_match_pinocchio(anymal, anymal_pin, backend):
    """LOCAL and LOCAL_WORLD_ALIGNED, 3-D and 6-D, contacts and loops, with and without
    Baumgarte's corrector; the NumPy path (the lambdify backend's) on the same robot."""
    dyn = anymal
    if backend == "numpy":  # the base class's NumPy implementation, on the compiled kernels
        class Numpy:
            info, constraints = anymal.info, anymal.constraints

            def constrained_forward_dynamics(self, *args, **kwargs):
                return Dynamics.constrained_forward_dynamics(anymal, *args, **kwargs)
        dyn = Numpy()
    rng = np.random.default_rng(1)
    sets = [("LF_local", "RF_local", "LH_local", "RH_local"), ("LF6",), ("RH6", "LF_local"),
            ("LF6", "RH6"), ("loop6_local",), ("loop6",), ("loop3_local", "LH"),
            ("loop3", "RH6")]
    for names in sets:
        q, v, tau = conditioned_state(anymal, names, rng)
        check_against_pinocchio(dyn, anymal_pin, names, q, v, tau)
        check_against_pinocchio(dyn, anymal_pin, names, q, v, tau, kp=30.0, kd=7.0)


def test_anymal_impulses_match_pinocchio(anymal, anymal_pin):
    rng = np.random.default_rng(2)
    for names in (("LF", "RH"), ("LF", "RF", "LH", "RH"), ("LF_local", "RF"), ("RH6",),
                  ("LF6", "RF_local")):
        for restitution in (0.0, 0.4):
            q, v, _ = standing(anymal, rng)
            v_plus, impulses = anymal.impulse_dynamics(q, v, mask(anymal, *names),
                                                       restitution)
            v_pin, impulses_pin = anymal_pin.impulse(names, q, v, restitution)
            close(v_plus, v_pin, f"q̇⁺ {names} r {restitution}")
            close(impulses[rows_of(anymal, names)], impulses_pin,
                  f"impulses {names} r {restitution}")
            J = anymal.constraint_jacobian(q, mask(anymal, *names))
            close(J @ v_plus, -restitution * (J @ v), f"J q̇⁺ = -r J q̇⁻ {names}",
                  scale=float(np.abs(J @ v).max()))


@pytest.mark.slow
def test_talos_two_6d_feet_match_pinocchio(cache_dir):
    pytest.importorskip("pinocchio")
    from test_taskspace import urdf_twin

    feet = [gagen.Contact("left_sole_link", axes="6d", name="left"),
            gagen.Contact("right_sole_link", axes="6d", reference="local",
                          name="right")]
    dyn = gagen.load(URDF / "talos_reduced.urdf", floating_base=True, cache_dir=cache_dir,
                     constraints=feet)
    ref = PinConstraints(dyn, urdf_twin(dyn, "talos_reduced.urdf", True))
    # Talos's URDF gives its joints damping and friction, which gagen's dynamics carry and
    # Pinocchio's algorithms leave out
    joint_forces_off = {k: 0.0 for k in dyn.parameters
                        if k.startswith(("damping_", "friction_"))}
    assert joint_forces_off
    rng = np.random.default_rng(3)
    for _ in range(2):
        q, v, tau = random_state(dyn, rng)
        q[[k for k, n in enumerate(dyn.configuration) if n in dyn.coordinates]] *= 0.3
        check_against_pinocchio(dyn, ref, ("left", "right"), q, v, tau,
                                p=joint_forces_off)
        check_against_pinocchio(dyn, ref, ("left",), q, v, tau, kp=10.0, kd=3.0,
                                p=joint_forces_off)


# ---------------------------------------------------------------------- random trees

def branched_tree(seed: int):
    """A random floating base with two branches of three moving joints (revolute,
    continuous, prismatic: random axes, origins, inertias), each ending in a welded tip."""
    from dataclasses import replace

    from random_trees import MOVING_TYPES, _random_body

    from gagen.model import Body, Joint, Model, vector

    rng = np.random.default_rng(seed)
    params = {"g": 9.81}
    bodies = []
    for i, parent in enumerate([0, 1, 2, 3, 1, 5, 6], start=1):
        kind = "floating" if i == 1 else str(rng.choice(MOVING_TYPES))
        body = _random_body(rng, i, parent, "revolute" if i == 1 else kind, params, True)
        if i == 1:
            body = replace(body, joint=Joint(name="base", type="floating"))
        bodies.append(body)
    for tip, parent in (("tip_a", "b4"), ("tip_b", "b7")):
        bodies.append(Body(tip, parent, Joint(f"{tip}_joint", "fixed",
                                              origin_xyz=vector([0.2, -0.1, 0.3]))))
    return Model(name=f"branched{seed}", bodies=tuple(bodies), parameters=params,
                 gravity=vector([0, 0, -9.81]), source="<branched tree>")


def tree_with_constraints(seed: int):
    """The branched tree with a 6-D contact on its base, 3-D contacts on its tips and a
    3-D loop between them, in both references."""
    from gagen.model.constraints import attach_constraints

    return attach_constraints(branched_tree(seed), [
        gagen.Contact("b1", axes="6d", reference="local", name="base"),
        gagen.Contact("tip_a", name="leaf_a"),
        gagen.Contact("tip_b", reference="local", name="leaf_b"),
        gagen.Loop("tip_a", "tip_b", name="loop"),
        gagen.Loop("tip_b", "tip_a", reference="local", name="loop_local")])


@functools.cache
def load_tree(seed: int, backend: str, cache_dir: Path):
    options = {"cache_dir": cache_dir} if backend == "compiled" else {}
    return gagen.load(tree_with_constraints(seed), backend=backend, **options)


# the second compiled tree is built by test_stacked_inputs too; the first's build (~20 s)
# runs with the slow tests
@pytest.mark.parametrize("seed, backend", [
    (1, "lambdify"), (2, "lambdify"), (2, "compiled"),
    pytest.param(1, "compiled", marks=pytest.mark.slow)])
def test_random_floating_trees_match_pinocchio(seed, backend, cache_dir):
    pytest.importorskip("pinocchio")
    from test_taskspace import Twin

    dyn = load_tree(seed, backend, cache_dir)
    ref = PinConstraints(dyn, Twin(dyn, pinocchio_model(numeric_model(dyn.model))))
    rng = np.random.default_rng(seed)
    for names in (("leaf_a",), ("leaf_b",), ("leaf_a", "leaf_b"), ("loop",),
                  ("loop_local",), ("base",), ("base", "loop")):
        q, v, tau = random_state(dyn, rng)
        check_against_pinocchio(dyn, ref, names, q, v, tau)
        check_against_pinocchio(dyn, ref, names, q, v, tau, kp=5.0, kd=2.0)
    q, v, _ = random_state(dyn, rng)
    v_plus, impulses = dyn.impulse_dynamics(q, v, mask(dyn, "leaf_a", "leaf_b"), 0.5)
    v_pin, impulses_pin = ref.impulse(("leaf_a", "leaf_b"), q, v, 0.5)
    close(v_plus, v_pin, "impulse q̇⁺")
    close(impulses[rows_of(dyn, ("leaf_a", "leaf_b"))], impulses_pin, "impulses")


# ------------------------------------------------------- any axes: a NumPy KKT system

def kkt_reference(dyn, q, v, tau, specs, kp=0.0, kd=0.0, p=None):
    """(q̈, λ) of the KKT system assembled from gagen's own M, forcing, frame Jacobians,
    bias accelerations and placements (not gagen.runtime.constraints): each spec is
    (frame_a, frame_b or None, axes, reference); a point's rows (translation axes only)
    are the classical acceleration's, a frame's the spatial one's."""
    M = dyn.mass_matrix(q, p)
    F = dyn.forcing(q, v, tau, p)
    Js, rhs = [], []
    for a, b, axes, reference in specs:
        rows = [gagen.constraints.AXES.index(x) for x in axes]
        frame = any(r >= 3 for r in rows)
        kind = "spatial" if frame else "classical"
        Ra, pa = dyn.frame_placement(q, a, p)
        Ja = dyn.frame_jacobian(q, a, "local_world_aligned", p)
        da = dyn.frame_bias_acceleration(q, v, a, "local_world_aligned", kind, p)
        if b is None:
            Jb, db, pb = np.zeros_like(Ja), np.zeros(6), pa
        else:
            _, pb = dyn.frame_placement(q, b, p)
            Jb = dyn.frame_jacobian(q, b, "local_world_aligned", p)
            db = dyn.frame_bias_acceleration(q, v, b, "local_world_aligned", kind, p)
            if frame:  # body B's motion at A's origin: move the linear rows
                arm = pa - pb
                Jb = Jb.copy()
                Jb[:3] -= np.cross(arm[:, None], Jb[3:], axis=0)
                db = db.copy()
                db[:3] += np.cross(db[3:], arm)
        J = Ja - Jb
        drift = da - db
        if reference == "local":
            R6 = np.kron(np.eye(2), Ra.T)
            if frame and b is not None:  # + V_A x V_B at A's origin
                Va, Vb = Ja @ v, Jb @ v
                drift = drift + np.concatenate([np.cross(Va[3:], Vb[:3])
                                                + np.cross(Va[:3], Vb[3:]),
                                                np.cross(Va[3:], Vb[3:])])
            J, drift = R6 @ J, R6 @ drift
        Js.append(J[rows])
        rhs.append(-drift[rows] - kd * (J[rows] @ v))
    J = np.concatenate(Js)
    m = len(J)
    K = np.block([[M, -J.T], [J, np.zeros((m, m))]])
    sol = np.linalg.solve(K, np.concatenate([F, np.concatenate(rhs)]))
    return sol[:dyn.nv], sol[dyn.nv:]


def test_any_axes_match_a_numpy_kkt_system(anymal):
    """A 5-D contact, a 2-D loop, 3-D and 6-D constraints together, against the KKT
    system assembled from the frames' own kinematics (J q̈ + J̇ q̇ = 0 built in)."""
    rng = np.random.default_rng(4)
    cases = [(("RF5",), [("RF_FOOT", None, ["x", "z", "rx", "ry", "rz"], "local")]),
             (("LF", "loop2"), [("LF_FOOT", None, ["x", "y", "z"], "local_world_aligned"),
                                ("LH_FOOT", "RH_FOOT", ["y", "rz"], "local_world_aligned")]),
             (("loop6_local",), [("LF_FOOT", "RH_FOOT", list(gagen.constraints.AXES),
                                  "local")]),
             (("RH6", "loop3_local"), [("RH_FOOT", None, list(gagen.constraints.AXES),
                                        "local_world_aligned"),
                                       ("LF_FOOT", "RF_FOOT", ["x", "y", "z"], "local")])]
    for names, specs in cases:  # (specs in the constraints' order)
        q, v, tau = conditioned_state(anymal, names, rng)
        qdd, forces = anymal.constrained_forward_dynamics(q, v, tau, mask(anymal, *names),
                                                          (0.0, 3.0))
        qdd_ref, lam_ref = kkt_reference(anymal, q, v, tau, specs, kd=3.0)
        close(qdd, qdd_ref, f"q̈ {names}", rtol=1e-8)
        close(forces[rows_of(anymal, names)], lam_ref, f"forces {names}", rtol=1e-8)


def test_constrained_accelerations_hold_the_constraints(anymal):
    """J q̈ + J̇ q̇ = 0 for every constraint set, J q̇ their velocity (finite differences of
    the position error along the motion), the drift J̇ q̇ the error's second derivative."""
    rng = np.random.default_rng(5)
    for names in (("LF", "RF", "LH", "RH"), ("RF5",), ("loop6", "LF_local"), ("loop2",)):
        on = mask(anymal, *names)
        q, v, tau = standing(anymal, rng)
        qdd, _ = anymal.constrained_forward_dynamics(q, v, tau, on)
        J, drift = anymal.constraint_jacobian(q, on), anymal.constraint_drift(q, v, on)
        close(J @ qdd + drift, np.zeros(len(drift)), f"J q̈ + J̇ q̇ {names}", rtol=1e-10,
              scale=float(np.abs(drift).max()))
    # the error's rates along q(t) = q ⊕ (t v + t²/2 a): a point's rows (LOCAL_WORLD_ALIGNED)
    q, v, a = standing(anymal, rng)
    on = mask(anymal, "loop3")
    J, drift = anymal.constraint_jacobian(q, on), anymal.constraint_drift(q, v, on)

    def error(t):
        return anymal.constraint_error(anymal.integrate(q, t * v + 0.5 * t * t * a), on)
    h = 1e-4
    close((error(h) - error(-h)) / (2 * h), J @ v, "d/dt error = J q̇", rtol=1e-7)
    close((error(h) - 2 * error(0.0) + error(-h)) / h**2, J @ a + drift,
          "d²/dt² error = J q̈ + J̇ q̇", rtol=1e-5)


# ------------------------------------------------------------------------ the four-bar

def closed_fourbar(crank: float) -> np.ndarray:
    """The four-bar's q with its loop closed at a crank angle (fourbar.yaml's lengths)."""
    a, b, c, d = 0.3, 1.0, 0.8, 1.0
    B, D = np.array([a * np.cos(crank), a * np.sin(crank)]), np.array([d, 0.0])
    L = np.linalg.norm(D - B)
    ex = (D - B) / L
    x = (b * b - c * c + L * L) / (2 * L)
    C = B + x * ex + np.sqrt(b * b - x * x) * np.array([-ex[1], ex[0]])
    coupler, rocker = np.arctan2(*(C - B)[::-1]), np.arctan2(*(C - D)[::-1])
    return np.array([crank, coupler - crank, rocker])


def null_space_solution(dyn, q, v, tau):
    """(q̈, λ) of the four-bar by reduced coordinates: q̈ = q̈_p + N z with J N = 0, the
    equations of motion projected on N; λ from Jᵀ λ = M q̈ − F."""
    M, F = dyn.mass_matrix(q), dyn.forcing(q, v, tau)
    J, drift = dyn.constraint_jacobian(q), dyn.constraint_drift(q, v)
    particular = -np.linalg.pinv(J) @ drift
    N = np.linalg.svd(J)[2][len(J):].T
    z = np.linalg.solve(N.T @ M @ N, N.T @ (F - M @ particular))
    qdd = particular + N @ z
    lam = np.linalg.lstsq(J.T, M @ qdd - F, rcond=None)[0]
    return qdd, lam


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_fourbar_matches_a_null_space_solution(backend, cache_dir):
    dyn = fourbar(backend, cache_dir)
    assert [(c.name, c.type, c.frames, c.axes) for c in dyn.constraints] == \
        [("closure", "loop", ("coupler_tip", "rocker_tip"), ("x", "y"))]
    rng = np.random.default_rng(6)
    for crank in (0.0, 1.0, 2.5, -2.0):
        q = closed_fourbar(crank)
        close(dyn.constraint_error(q), np.zeros(2), "closed", scale=1.0, rtol=1e-14)
        v, tau = rng.normal(size=3), rng.normal(size=3)
        qdd, forces = dyn.constrained_forward_dynamics(q, v, tau)
        qdd_ref, lam_ref = null_space_solution(dyn, q, v, tau)
        close(qdd, qdd_ref, f"q̈ at crank {crank}", rtol=1e-10)
        close(forces, lam_ref, f"forces at crank {crank}", rtol=1e-10)


def test_fourbar_matches_pinocchio_loop(cache_dir):
    """A loop CONTACT_3D between the coupler's tip and the rocker's, on Pinocchio's model
    of the same tree: the planar mechanism's out-of-plane row is zero, so Pinocchio's
    proximal iterations (mu > 0) find the solution gagen's two-axis loop gives exactly."""
    pytest.importorskip("pinocchio")
    from test_taskspace import Twin

    dyn = fourbar("compiled", cache_dir)
    ref = PinConstraints(dyn, Twin(dyn, pinocchio_model(numeric_model(dyn.model))))
    rng = np.random.default_rng(7)
    for crank in (0.5, 2.0):
        q, v, tau = closed_fourbar(crank), rng.normal(size=3), rng.normal(size=3)
        loop3 = gagen.constraints.Constraint("closure", "loop", ("coupler_tip", "rocker_tip"),
                                             (0, 1, 2), "local_world_aligned")
        a, lam = ref.forward([loop3], q, v, tau, mu=1e-6, iterations=500)
        qdd, forces = dyn.constrained_forward_dynamics(q, v, tau)
        close(qdd, a, "q̈ against Pinocchio's 3-D loop", rtol=1e-9)
        close(forces, lam[:2], "forces against Pinocchio's", rtol=1e-9)
        assert abs(lam[2]) <= 1e-9 * np.abs(lam).max()


def test_fourbar_from_mjcf_equality_connect(cache_dir):
    """<equality connect> becomes a 3-D loop; the planar mechanism makes its z row zero: a
    clear error, and with damping the model file's motion. Pinocchio's MJCF parse of the
    same file (buildModelAndLegacyConstraintsFromMJCF) agrees."""
    pytest.importorskip("mujoco")
    dyn = gagen.load(FOURBAR_MJCF, backend="lambdify")
    assert [(c.name, c.type, c.axes) for c in dyn.constraints] == \
        [("closure", "loop", ("x", "y", "z"))]
    yaml = fourbar("compiled", cache_dir)
    offset = closed_fourbar(0.0) - np.array([0.0, 0.0, 0.0])  # MJCF's q = 0 is this one
    rng = np.random.default_rng(8)
    q_yaml = closed_fourbar(1.3)
    q = q_yaml - offset
    close(dyn.constraint_error(q), np.zeros(3), "the connect holds at the closed q",
          scale=1.0, rtol=1e-12)
    v, tau = rng.normal(size=3), rng.normal(size=3)
    with pytest.raises(gagen.SingularConstraintError, match=r"row closure\.z"):
        dyn.constrained_forward_dynamics(q, v, tau)
    qdd, forces = dyn.constrained_forward_dynamics(q, v, tau, damping=1e-12)
    qdd_yaml, forces_yaml = yaml.constrained_forward_dynamics(q_yaml, v, tau)
    close(qdd, qdd_yaml, "MJCF connect (damped) = the model file's loop", rtol=1e-9)
    close(forces[:2], forces_yaml, "forces", rtol=1e-9)
    assert abs(forces[2]) < 1e-9 * np.abs(forces).max()

    pin = pytest.importorskip("pinocchio")
    model, constraints = pin.buildModelAndLegacyConstraintsFromMJCF(str(FOURBAR_MJCF))[:2]
    model.gravity = pin.Motion(np.array([0.0, -9.81, 0.0, 0.0, 0.0, 0.0]))  # not parsed
    data = model.createData()
    models = pin.StdVec_RigidConstraintModel()
    models.append(constraints[0])
    datas = pin.StdVec_RigidConstraintData()
    datas.append(constraints[0].createData())
    pin.initConstraintDynamics(model, data, models, datas)
    a = pin.constraintDynamics(model, data, q, v, tau, models, datas,
                               pin.ProximalSettings(1e-14, 1e-6, 500))
    close(a, qdd_yaml, "Pinocchio's MJCF parse of the connect", rtol=1e-8)


# ------------------------------------------------------------------------ simulations

@pytest.mark.parametrize("method", ["dopri5", "rk4", "RK45"])
def test_the_loop_stays_closed_in_simulation(method, cache_dir):
    dyn = fourbar("compiled", cache_dir)
    q0 = closed_fourbar(0.3)
    J = dyn.constraint_jacobian(q0)
    qd0 = np.linalg.svd(J)[2][-1] * 3.0  # a velocity the loop allows
    driven = gagen.PD(kp=0.0, kd=[0.2, 0.0, 0.0], feedforward=[8.0, 0.0, 0.0])
    options = {"h": 1e-3} if method == "rk4" else {"rtol": 1e-8, "atol": 1e-10}
    res = gagen.simulate(dyn, (0.0, 3.0), q0, qd0, controller=driven, method=method,
                         constraints=True, **options)
    assert res.constraint_error.shape == (len(res.t), 2)
    assert res.constraint_rows == ["closure.x", "closure.y"]
    # the integrator's tolerance, or rk4's error at this step (the crank at 30 rad/s)
    assert res.stats["constraint_violation"] < (1e-6 if method == "rk4" else 1e-8)
    close(res.constraint_violation, np.abs(res.constraint_error).max(axis=1), "violation",
          rtol=0, scale=1.0)
    # the crank turned over: the linkage moved through its cycle
    assert res.q[-1, 0] - res.q[0, 0] > 2 * np.pi
    _, forces = dyn.constrained_forward_dynamics(res.q[-1], res.qd[-1],
                                                 res.tau[-1], baumgarte=(400.0, 40.0))
    close(res.constraint_forces[-1], forces, "the run's forces at its last sample",
          rtol=1e-9)


def test_compiled_and_scipy_constrained_runs_agree(cache_dir):
    dyn = fourbar("compiled", cache_dir)
    q0 = closed_fourbar(1.0)
    compiled = gagen.simulate(dyn, (0, 1), q0, method="dopri5", constraints=True)
    scipy = gagen.simulate(dyn, (0, 1), q0, method="RK45", constraints=True)
    assert compiled.stats["nfev"] == scipy.stats["nfev"]
    close(compiled.q, scipy.q, "dopri5 = RK45 step for step", rtol=1e-12)
    close(compiled.constraint_forces, scipy.constraint_forces, "forces", rtol=1e-10)


def test_a_passive_loop_keeps_its_energy(cache_dir):
    dyn = fourbar("compiled", cache_dir)
    q0 = closed_fourbar(-1.0)
    qd0 = np.linalg.svd(dyn.constraint_jacobian(q0))[2][-1] * 4.0
    res = gagen.simulate(dyn, (0.0, 4.0), q0, qd0, method="dopri5", constraints=True,
                         rtol=1e-10, atol=1e-12)
    kinetic, potential = dyn.energy(res.q, res.qd)
    total = kinetic + potential
    assert np.ptp(total) < 1e-8 * np.abs(kinetic).max()
    assert res.stats["constraint_violation"] < 1e-10


def test_standing_anymal_feet_carry_its_weight(anymal):
    """At rest with the torques that hold it (from gagen's gravity torques), the constrained
    dynamics give q̈ = 0, and the feet's forces carry the robot's weight (their sum) and
    its moment about the centre of mass."""
    rng = np.random.default_rng(9)
    q, _, _ = standing(anymal, rng)
    feet = mask(anymal, "LF", "RF", "LH", "RH")
    J = anymal.constraint_jacobian(q, feet)
    g = anymal.gravity(q)
    # base rows: J_baseᵀ λ = g_base (least norm); the joints' torques then hold the rest
    lam = np.linalg.lstsq(J[:, :6].T, g[:6], rcond=None)[0]
    tau = g - J.T @ lam
    tau[:6] = 0.0
    zero = np.zeros(anymal.nv)
    qdd, forces = anymal.constrained_forward_dynamics(q, zero, tau, feet)
    close(qdd, zero, "standing still", rtol=1e-10, scale=1.0)
    f = forces[:12].reshape(4, 3)
    mass = sum(value for name, value in zip(anymal.regressor_names,
                                            anymal.regressor_parameters())
               if name.startswith("m_"))
    weight = mass * 9.81
    close(f.sum(axis=0), [0.0, 0.0, weight], "the feet carry the weight", rtol=1e-9,
          scale=weight)
    com = anymal.center_of_mass(q)
    feet_at = np.array([anymal.frame_placement(q, foot)[1] for foot in FEET])
    close(np.cross(feet_at - com, f).sum(axis=0), np.zeros(3), "no moment about the CoM",
          rtol=1e-9, scale=weight)


def test_a_push_on_a_standing_anymal(anymal):
    """Four feet held under a push on the base, with a PD holding the legs: the feet stay
    at their anchors (the violation stays at the tolerance), and at every sample the feet's
    forces, the push and the weight make the rate of the robot's linear momentum (its
    centroidal dynamics, computed apart: d/dt h = A_g q̈ + ȧ_g)."""
    rng = np.random.default_rng(10)
    q0, _, _ = standing(anymal, rng, noise=0.0)
    feet = mask(anymal, "LF", "RF", "LH", "RH")
    ctrl = gagen.PD(kp=200.0, kd=5.0, target=[0.0] * 6 + list(q0[7:]),
                    gravity_compensation=True)
    push = [0.0, 60.0, 0.0, 0.0, 0.0, 0.0]
    res = gagen.simulate(anymal, (0.0, 0.5), q0, controller=ctrl, method="dopri5",
                         constraints=feet, fext={"base": push}, rtol=1e-8, atol=1e-10,
                         t_eval=np.linspace(0.0, 0.5, 6))
    assert res.stats["constraint_violation"] < 1e-7
    mass = sum(value for name, value in zip(anymal.regressor_names,
                                            anymal.regressor_parameters())
               if name.startswith("m_"))
    for k in range(len(res.t)):
        q, qd, tau = res.q[k], res.qd[k], res.tau[k]
        qdd, forces = anymal.constrained_forward_dynamics(
            q, qd, tau, feet, (400.0, 40.0), {"base": push}, p=res.p)
        close(forces, res.constraint_forces[k], "the run's forces", rtol=1e-9)
        rate = anymal.centroidal_map(q) @ qdd + anymal.centroidal_bias(q, qd)
        total = forces[:12].reshape(4, 3).sum(axis=0) + push[:3] + [0.0, 0.0, -9.81 * mass]
        close(rate[:3], total, f"Newton at t = {res.t[k]:g}", rtol=1e-9, scale=9.81 * mass)


def test_simulate_batch_runs_the_constrained_dynamics(cache_dir):
    dyn = fourbar("compiled", cache_dir)
    Q0 = np.stack([closed_fourbar(c) for c in (0.2, 1.2, 2.2)])
    batch = gagen.simulate_batch(dyn, (0.0, 0.5), Q0, method="dopri5", constraints=True)
    for k in range(3):
        one = gagen.simulate(dyn, (0.0, 0.5), Q0[k], method="dopri5", constraints=True)
        assert np.array_equal(batch.q[k], one.q)
        assert np.array_equal(batch.constraint_forces[k], one.constraint_forces)
        assert np.array_equal(batch.constraint_error[k], one.constraint_error)


def test_a_constrained_run_writes_its_forces_to_csv(cache_dir, tmp_path):
    dyn = fourbar("compiled", cache_dir)
    res = gagen.simulate(dyn, (0.0, 0.1), closed_fourbar(0.5), method="rk4",
                         constraints=True, t_eval=[0.0, 0.05, 0.1])
    lines = res.to_csv(tmp_path / "run.csv").read_text().splitlines()
    assert lines[0].endswith("force_closure.x,force_closure.y,error_closure.x,"
                             "error_closure.y")
    assert len(lines) == 4


# --------------------------------------------------------------- rank, errors, the API

@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_dependent_rows_are_a_clear_error_or_a_damped_solve(backend, cache_dir):
    dyn = load_tree(2, backend, cache_dir)  # the tree the default run builds
    rng = np.random.default_rng(11)
    q, v, tau = random_state(dyn, rng)
    # the loop's rows are the two contacts' difference: dependent on theirs
    both = mask(dyn, "leaf_a", "leaf_b", "loop")
    with pytest.raises(gagen.SingularConstraintError,
                       match=r"row loop\.x is zero or depends"):
        dyn.constrained_forward_dynamics(q, v, tau, both)
    with pytest.raises(gagen.SingularConstraintError, match="stacked input, row 0"):
        dyn.constrained_forward_dynamics(np.stack([q, q]), v, tau, both)
    with pytest.raises(gagen.SingularConstraintError):
        dyn.impulse_dynamics(q, v, both)
    qdd, forces = dyn.constrained_forward_dynamics(q, v, tau, both, damping=1e-9)
    assert np.isfinite(qdd).all() and np.isfinite(forces).all()
    exact, _ = dyn.constrained_forward_dynamics(q, v, tau, mask(dyn, "leaf_a", "leaf_b"))
    close(qdd, exact, "the damped solve of the redundant set", rtol=1e-6)


def test_a_singular_configuration_says_so(cache_dir):
    """The four links on one line (a configuration off the loop, which this crank-rocker
    never reaches closed): every column of the loop's rows is parallel, rank 1."""
    dyn = fourbar("compiled", cache_dir)
    flat = np.zeros(3)
    with pytest.raises(gagen.SingularConstraintError,
                       match=r"row closure\.x is zero or depends"):
        dyn.constrained_forward_dynamics(flat, np.zeros(3), np.zeros(3))
    for method in ("dopri5", "RK45"):
        with pytest.raises(gagen.SingularConstraintError, match="damping"):
            gagen.simulate(dyn, (0.0, 0.1), flat, method=method, constraints=True)


def test_a_damped_simulation_of_redundant_rows(cache_dir):
    """MJCF's connect holds the planar loop in 3-D: its z row is zero, and with damping the
    run is the model file's (whose loop holds x and y)."""
    pytest.importorskip("mujoco")
    mjcf = gagen.load(FOURBAR_MJCF, cache_dir=cache_dir)
    yaml = fourbar("compiled", cache_dir)
    q0 = closed_fourbar(0.7)
    with pytest.raises(gagen.SingularConstraintError, match=r"closure\.z"):
        gagen.simulate(mjcf, (0.0, 0.5), q0 - closed_fourbar(0.0), method="rk4",
                       constraints=True)
    damped = gagen.simulate(mjcf, (0.0, 0.5), q0 - closed_fourbar(0.0), method="rk4",
                            constraints=True, damping=1e-12)
    exact = gagen.simulate(yaml, (0.0, 0.5), q0, method="rk4", constraints=True)
    close(damped.q + closed_fourbar(0.0), exact.q, "the damped run", rtol=1e-9, scale=1.0)
    assert damped.stats["constraint_violation"] < 1e-8


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_stacked_inputs_give_stacked_fresh_outputs(backend, cache_dir):
    dyn = load_tree(2, backend, cache_dir)
    rng = np.random.default_rng(12)
    states = [random_state(dyn, rng) for _ in range(3)]
    Q, V, T = (np.stack([s[k] for s in states]) for k in range(3))
    on = mask(dyn, "leaf_a", "loop_local")
    calls = {
        "forward": lambda q, v, t: dyn.constrained_forward_dynamics(q, v, t, on, (2.0, 1.0)),
        "impulse": lambda q, v, t: dyn.impulse_dynamics(q, v, on, 0.3),
        "jacobian": lambda q, v, t: (dyn.constraint_jacobian(q, on),),
        "drift": lambda q, v, t: (dyn.constraint_drift(q, v, on),),
        "error": lambda q, v, t: (dyn.constraint_error(q, on),),
    }
    for name, call in calls.items():
        stacked = call(Q, V, T)
        for k in range(3):
            one = call(Q[k], V[k], T[k])
            for s, o in zip(stacked, one):
                close(s[k], o, f"stacked {name}", rtol=1e-14, scale=1.0)
        again = call(Q[0], V[0], T[0])
        assert all(a is not o and not np.shares_memory(a, o) for a, o in zip(again, one))
    rows = dyn.constraints[1].dimension + dyn.constraints[4].dimension
    assert dyn.constraint_jacobian(Q[0], on).shape == (rows, dyn.nv)
    assert dyn.constrained_forward_dynamics(Q, V, T, on)[1].shape == \
        (3, dyn.info.constraint_rows)


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_bad_arguments_are_refused_with_one_line(backend, cache_dir):
    dyn = fourbar(backend, cache_dir)
    q, v = closed_fourbar(0.5), np.zeros(3)
    with pytest.raises(ValueError, match="active must have 1 booleans"):
        dyn.constrained_forward_dynamics(q, v, v, [True, False])
    with pytest.raises(KeyError, match="unknown constraint 'foot'"):
        dyn.constraint_jacobian(q, ["foot"])
    with pytest.raises(TypeError, match="active must be None"):
        dyn.constraint_drift(q, v, "closure")
    with pytest.raises(ValueError, match="baumgarte gains must be finite and >= 0"):
        dyn.constrained_forward_dynamics(q, v, v, baumgarte=(-1.0, 0.0))
    with pytest.raises(TypeError, match="baumgarte must be a pair"):
        dyn.constrained_forward_dynamics(q, v, v, baumgarte=3.0)
    with pytest.raises(ValueError, match="damping must be finite and >= 0"):
        dyn.constrained_forward_dynamics(q, v, v, damping=float("nan"))
    with pytest.raises(ValueError, match="restitution must be in"):
        dyn.impulse_dynamics(q, v, restitution=1.5)
    with pytest.raises(ValueError, match="qd must have shape"):
        dyn.constrained_forward_dynamics(q, np.zeros(2), v)
    with pytest.raises(ValueError, match="constraints=True"):
        gagen.simulate(dyn, (0, 1), q, damping=1e-3)
    assert dyn.constrained_forward_dynamics(q, v, v, [False])[1].tolist() == [0.0, 0.0]


# ------------------------------------------------------------------------ declaring them

def test_constraints_are_part_of_the_cache_key(cache_dir):
    from gagen.building import cache
    from gagen.loading import _constraints_key

    first = gagen.load(URDF / "double_pendulum.urdf", cache_dir=cache_dir,
                       constraints=[gagen.Contact("link2", axes=["x"])])
    again = gagen.load(URDF / "double_pendulum.urdf", cache_dir=cache_dir,
                       constraints=[{"type": "contact", "frame": "link2", "axes": ["x"]}])
    assert first.module is again.module or first.module.__name__ == again.module.__name__
    # another axis is another input key (one build fewer: the key is what finds a module)
    keys = [cache.input_key(URDF / "double_pendulum.urdf", _constraints_key(
        URDF / "double_pendulum.urdf", [gagen.Contact("link2", axes=[axis])]))
        for axis in ("x", "z")]
    assert keys[0] != keys[1]
    other = gagen.load(URDF / "double_pendulum.urdf", backend="lambdify",
                       constraints=[gagen.Contact("link2", axes=["z"])])
    assert [c.axes for c in other.constraints] == [("z",)]
    assert first.constraints[0].name == "link2"
    plain = gagen.load(URDF / "double_pendulum.urdf", backend="lambdify")
    assert plain.constraints == [] and "anchor_link2_x" not in plain.parameters
    # the anchor: the frame's placement at the neutral configuration
    assert first.parameters["anchor_link2_x"] == pytest.approx(
        first.frame_placement(np.zeros(first.nq), "link2")[1][0], abs=1e-15)


@pytest.mark.parametrize("entry, message", [
    ({"type": "contact", "frame": "nowhere"}, "unknown frame 'nowhere'"),
    ({"type": "contact", "frame": "link2", "axes": ["x", "w"]}, "unknown axis 'w'"),
    ({"type": "contact", "frame": "link2", "axes": ["x", "x"]}, "axis x given twice"),
    ({"type": "contact", "frame": "link2", "axes": "2d"}, "expected '3d', '6d'"),
    ({"type": "contact", "frame": "link2", "reference": "world"}, "'local_world_aligned' or"),
    ({"type": "weld", "frame": "link2"}, "expected 'contact' or 'loop'"),
    ({"type": "loop", "frames": ["link2", "link2"]}, "two different frames"),
    ({"type": "loop", "frame": "link2"}, "a loop names two frames"),
    ({"type": "contact", "frame": "link2", "axis": "3d"}, "unknown key"),
])
def test_bad_constraints_are_refused_naming_them(entry, message):
    with pytest.raises(gagen.ModelError, match=message) as info:
        gagen.load(URDF / "double_pendulum.urdf", backend="lambdify", constraints=[entry])
    assert "\n" not in str(info.value)


def test_a_model_file_refuses_duplicate_constraint_names(tmp_path):
    text = FOURBAR.read_text() + """  - name: closure
    type: contact
    frame: crank
"""
    path = tmp_path / "twice.yaml"
    path.write_text(text)
    with pytest.raises(gagen.ModelError, match="duplicate constraint name 'closure'"):
        gagen.load(path, backend="lambdify")


def test_constraint_wrenches_give_the_constraint_forces(anymal):
    """The forces as external wrenches on frames (what the constrained derivatives build
    on): Σ J_frameᵀ w = Jᵀ λ, contacts and loops, both references."""
    from gagen.runtime.constraints import active_mask, constraint_wrenches

    rng = np.random.default_rng(13)
    q, _, _ = standing(anymal, rng)
    forces = rng.normal(size=anymal.info.constraint_rows)
    on = np.ones(len(anymal.constraints), dtype=bool)
    wrenches = constraint_wrenches(anymal, q, forces, mask=active_mask(anymal.info, None))
    total = sum(anymal.frame_jacobian(q, k).T @ w for k, w in wrenches)
    J = anymal.constraint_jacobian(q, on)
    close(total, J.T @ forces, "Σ J_frameᵀ w = Jᵀ λ", rtol=1e-12)


# ------------------------------------------------------------------------ the bench section

def test_the_bench_section_reports_ratios_and_the_goal():
    from gagen.bench.constraints import goal_notes
    from gagen.bench.report import markdown

    def row(quantity, implementation, median, ratio):
        return {"quantity": quantity, "implementation": implementation, "call": "f(x)",
                "median_us": median, "q1_us": median, "q3_us": median, "iqr_us": 0.0,
                "ratio": ratio}
    rows = [row("constrained FD", "gagen compiled", 5.0, 1.0),
            row("constrained FD", "Pinocchio", 9.5, 1.9),
            row("impulse", "gagen compiled", 4.0, 1.0), row("impulse", "Pinocchio", 12.0, 3.0)]
    assert goal_notes(rows) == [
        ("Goal: constrained forward dynamics of ANYmal C on four 3-D contacts at least 2.0x "
         "faster than Pinocchio's constraintDynamics per call: NOT met (1.90x).")]
    rows[1]["ratio"] = 2.2
    assert goal_notes(rows)[0].endswith("met (2.20x).") and "NOT" not in goal_notes(rows)[0]
    text = markdown({"constraints": {"rows": rows, "repeats": 3}})
    assert "## Constrained dynamics per call" in text
    assert "| constrained FD | Pinocchio | `f(x)` | 9.50 |" in text


# ------------------------------------------------------------------------ the docs' examples

def docs_example(name: str):
    import importlib.util
    import sys

    path = Path(__file__).resolve().parents[1] / "docs" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_docs_fourbar_loop_stays_closed(cache_dir):
    """docs/constraints.md: the driven four-bar's closure error stays at the integrators'
    tolerance with Baumgarte's correction, and grows without it."""
    example = docs_example("constraints_fourbar")
    runs = example.run_fourbar(fourbar("compiled", cache_dir), duration=2.0, samples=201)
    with_dopri5, with_rk4, without = runs.values()
    for res in (with_dopri5, with_rk4):
        assert res.stats["constraint_violation"] < 2e-9
        assert res.q[-1, 0] - res.q[0, 0] > 2 * (2 * np.pi) * 0.9  # about two turns
    assert without.constraint_violation[-1] > 10 * with_dopri5.stats["constraint_violation"]
    error = without.constraint_violation
    assert error[150:].mean() > 3 * error[50:100].mean()  # it grows


def test_docs_anymal_push(anymal):
    """docs/constraints.md: ANYmal standing still carries its weight on its feet, the push
    moves the load between its left and right feet, and the feet stay where they are."""
    example = docs_example("constraints_anymal")
    run = example.run_push(anymal, active=("LF", "RF", "LH", "RH"), samples_per_second=40)
    close(run.forces[0].sum(axis=0), [0.0, 0.0, run.weight], "standing still", rtol=1e-9,
          scale=run.weight)
    pushed = (run.t > example.PHASES[1][0]) & (run.t <= example.PHASES[1][1])
    left, right = run.forces[pushed][:, [0, 2], 2].sum(axis=1), \
        run.forces[pushed][:, [1, 3], 2].sum(axis=1)
    assert (left - right).max() > 100.0  # a push along +y loads the left feet
    assert run.violation < 1e-9


@pytest.mark.parametrize("count, axes, message", [
    (65, ["x"], "65 constraints; a model has at most 64"),
    (41, "3d", "123 constrained rows; a model has at most 120")])
def test_the_constraints_a_model_holds_are_bounded(count, axes, message):
    """The compiled kernels keep the rows on the stack: a description cannot make them
    hold more than the bounds (before anything is derived)."""
    entries = [gagen.Contact("link2", axes=axes, name=f"c{k}") for k in range(count)]
    with pytest.raises(gagen.ModelError, match=message) as info:
        gagen.load(URDF / "double_pendulum.urdf", backend="lambdify", constraints=entries)
    assert "\n" not in str(info.value)


def test_impulse_defaults_give_the_checked_arguments_numbers(cache_dir):
    """impulse_dynamics's defaults (every constraint, no restitution, no damping) skip the
    compiled runtime's argument checks: the same numbers, bit for bit, as the arguments
    spelled out (which take them), for one state and stacked ones; the lambdify backend's
    to round-off; and a restitution or damping that is not 0.0 is still checked."""
    dyn, ref = fourbar("compiled", cache_dir), fourbar("lambdify", cache_dir)
    rng = np.random.default_rng(11)
    qs = np.array([closed_fourbar(a) for a in rng.uniform(-np.pi, np.pi, 3)])
    vs = rng.normal(size=(3, dyn.nv))
    for q, v in zip(qs, vs):
        fast = dyn.impulse_dynamics(q, v)
        spelled = dyn.impulse_dynamics(q, v, [True], 0, 0)
        for ours, checked, theirs in zip(fast, spelled, ref.impulse_dynamics(q, v)):
            np.testing.assert_array_equal(ours, checked)
            close(ours, theirs, "impulse defaults vs lambdify", rtol=1e-9)
    for ours, checked in zip(dyn.impulse_dynamics(qs, vs),
                             dyn.impulse_dynamics(qs, vs, ["closure"], 0, 0)):
        np.testing.assert_array_equal(ours, checked)
    with pytest.raises(ValueError, match="restitution must be finite"):
        dyn.impulse_dynamics(qs[0], vs[0], restitution=float("nan"))
    with pytest.raises(ValueError, match="damping must be finite"):
        dyn.impulse_dynamics(qs[0], vs[0], damping=-1.0)


def test_the_written_and_the_table_driven_solves_agree(cache_dir, tmp_path, monkeypatch):
    """Up to a size, a model's C writes out each constraint's rows of J L^-1 and each block
    of the Delassus matrix with their coordinates as constants; past it, loops read the same
    runs from tables. Both give the same constrained dynamics (the four-bar built both ways,
    the table-driven one into a cache of its own)."""
    from gagen.codegen import render

    written = fourbar("compiled", cache_dir)
    monkeypatch.setattr(render, "CONSTRAINT_UNROLLED", 0)
    monkeypatch.setattr(render, "CONSTRAINT_BLOCKS_WRITTEN", 0)
    tables = gagen.load(FOURBAR, cache_dir=tmp_path / "tables")
    sources = {name: (Path(dyn.module.__file__).parent / "frames.c").read_text()
               for name, dyn in (("written", written), ("tables", tables))}
    assert "gagen_cn_block_written" in sources["written"]
    assert "gagen_cn_block_written" not in sources["tables"]
    rng = np.random.default_rng(5)
    for _ in range(3):
        q = closed_fourbar(rng.uniform(-np.pi, np.pi))
        v, tau = rng.normal(size=written.nv), rng.normal(size=written.nv)
        for ours, theirs in zip(written.constrained_forward_dynamics(q, v, tau, damping=1e-3),
                                tables.constrained_forward_dynamics(q, v, tau, damping=1e-3)):
            close(ours, theirs, "written vs tables", rtol=1e-12)
