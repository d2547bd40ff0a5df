"""Real robots: gagen's dynamics of the shared URDFs against pinocchio's own URDF parser.

The reference here is `pinocchio.buildModelFromUrdf`, which reads the file itself, so
nothing of gagen's importer (tree order, merging of fixed joints, inertial frames, axis
normalisation) is shared with the reference. Coordinates are matched by joint name.

Conventions checked on the way:
- pinocchio's `mimic` argument is False by default, so a <mimic> joint (the Panda's second
  finger) is an independent coordinate there as in gagen;
- pinocchio appends the root link (and links fixed to it) to the universe joint, which its
  potential energy leaves out; gagen drops bodies welded to the world. Potential energies
  are compared as differences between states, so neither choice matters for the check.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

import gagen
from gagen.app.cli import main as cli_main
from gagen.building.builder import build
from gagen.model.resolve import resolve_model

pin = pytest.importorskip("pinocchio")

URDF_DIR = Path(__file__).resolve().parent / "data" / "urdf"

ROBOTS = ("double_pendulum", "so100", "ur5_robot", "panda")
BACKENDS = ("lambdify", "compiled")
RTOL = 1e-9
STATES = 5
# The Panda's hand (panda_hand, merged through the fixed joints panda_joint8 and
# panda_hand_joint) ends up in the body of the last arm joint: that is where a payload goes.
PANDA_PAYLOAD_BODY = "panda_link7"


# ------------------------------------------------------------------------------ fixtures


@pytest.fixture(scope="session")
def urdf_cache(tmp_path_factory) -> Path:
    """One fresh cache for the session: every compiled module is built once, cold."""
    return tmp_path_factory.mktemp("gagen-cache")


_loaded: dict[tuple[str, str, Path], object] = {}


def load_robot(name: str, backend: str, cache: Path):
    """gagen's dynamics of a shared URDF, loaded (and for "compiled", built) once a session."""
    key = (name, backend, cache)
    if key not in _loaded:
        options = {"cache_dir": cache, "verbose": False} if backend == "compiled" else {}
        _loaded[key] = gagen.load(URDF_DIR / f"{name}.urdf", backend=backend, **options)
    return _loaded[key]


@pytest.fixture(params=[(r, b) for r in ROBOTS for b in BACKENDS],
                ids=lambda rb: f"{rb[0]}-{rb[1]}")
def robot(request, urdf_cache):
    """(gagen dynamics, pinocchio reference) of one URDF with one backend."""
    name, backend = request.param
    dyn = load_robot(name, backend, urdf_cache)
    return dyn, PinRobot(URDF_DIR / f"{name}.urdf", dyn.coordinates)


# ---------------------------------------------------------------------- pinocchio helper


class PinRobot:
    """pinocchio's model of a URDF, taking and returning vectors in gagen's coordinate order."""

    def __init__(self, path: Path, coordinates: list[str]):
        self.model = pin.buildModelFromUrdf(str(path))  # mimic=False: mimic joints independent
        self.data = self.model.createData()
        m = self.model
        ids = [m.getJointId(name) for name in coordinates]
        missing = [c for c, j in zip(coordinates, ids) if j >= m.njoints]
        assert not missing, f"pinocchio has no joints {missing}"
        # every pinocchio joint but the universe is one of ours, and each moves one way
        assert sorted(m.names[1:]) == sorted(coordinates)
        assert m.nv == len(coordinates)
        self.joint_ids = ids
        self.iq = [m.idx_qs[j] for j in ids]
        self.nqs = [m.nqs[j] for j in ids]
        self.iv = [m.idx_vs[j] for j in ids]
        assert all(m.nvs[j] == 1 for j in ids)
        assert all(n in (1, 2) for n in self.nqs)  # 2: continuous joints as (cos, sin)

    def q(self, q) -> np.ndarray:
        out = pin.neutral(self.model)
        for k, (i, n) in enumerate(zip(self.iq, self.nqs)):
            if n == 1:
                out[i] = q[k]
            else:
                out[i], out[i + 1] = math.cos(q[k]), math.sin(q[k])
        return out

    def v(self, v) -> np.ndarray:
        out = np.zeros(self.model.nv)
        out[self.iv] = v
        return out

    def ours(self, v) -> np.ndarray:
        return np.asarray(v)[self.iv]

    def mass_matrix(self, q) -> np.ndarray:
        M = np.array(pin.crba(self.model, self.data, self.q(q)))
        M = np.triu(M) + np.triu(M, 1).T  # crba fills the upper triangle
        return M[np.ix_(self.iv, self.iv)]

    def joint_forces(self, qd) -> np.ndarray:
        """The joint terms pinocchio's rnea and aba leave out, by hand from the damping and
        friction its URDF parser read from <dynamics> (its armature is in rnea and aba)."""
        v = self.v(qd)
        return self.ours(self.model.damping * v + self.model.friction * np.sign(v))

    def forward_dynamics(self, q, qd, tau) -> np.ndarray:
        tau = self.v(tau) - self.v(self.joint_forces(qd))
        return self.ours(pin.aba(self.model, self.data, self.q(q), self.v(qd), tau))

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        tau = pin.rnea(self.model, self.data, self.q(q), self.v(qd), self.v(qdd))
        return self.ours(tau) + self.joint_forces(qd)

    def kinetic(self, q, qd) -> float:
        return float(pin.computeKineticEnergy(self.model, self.data, self.q(q), self.v(qd)))

    def potential(self, q) -> float:
        return float(pin.computePotentialEnergy(self.model, self.data, self.q(q)))


def random_states(dyn, seed: int, count: int = STATES):
    """(q, qd, qdd) within the joint limits; continuous or unlimited joints in [-pi, pi]."""
    rng = np.random.default_rng(seed)
    limits = {b.joint.name: b.joint.limits for b in dyn.model.bodies}
    lo, hi = [], []
    for name in dyn.coordinates:
        lim = limits[name]
        if lim is None or lim.lower is None or lim.upper is None or lim.lower >= lim.upper:
            lo.append(-math.pi)
            hi.append(math.pi)
        else:
            lo.append(lim.lower)
            hi.append(lim.upper)
    for _ in range(count):
        yield (rng.uniform(lo, hi), rng.normal(scale=1.5, size=dyn.n),
               rng.normal(scale=2.0, size=dyn.n))


def assert_close(actual, expected, what: str, rtol: float = RTOL) -> None:
    """Entry-wise, relative to the largest entry of the reference (entries may vanish)."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != {expected.shape}"
    scale = float(np.max(np.abs(expected)))
    assert scale > 0, f"{what}: the reference is all zeros, the check would be empty"
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=rtol * scale, err_msg=what)


# --------------------------------------------------------------------------------- tests


def test_pinocchio_reads_mimic_joints_as_independent():
    pm = pin.buildModelFromUrdf(str(URDF_DIR / "panda.urdf"))
    assert "panda_finger_joint2" in pm.names
    assert pm.nv == 9
    assert "panda_finger_joint2" in resolve_model(URDF_DIR / "panda.urdf").coordinates


@pytest.mark.parametrize("name", ROBOTS)
def test_merged_mass_properties_match_pinocchio(name):
    """Per moving joint, gagen's body parameters are pinocchio's (merged) joint inertia."""
    model = resolve_model(URDF_DIR / f"{name}.urdf")
    pm = pin.buildModelFromUrdf(str(URDF_DIR / f"{name}.urdf"))
    p = model.parameters
    assert len(model.bodies) == pm.njoints - 1
    for body in model.bodies:
        inertia = pm.inertias[pm.getJointId(body.joint.name)]
        link = body.name
        assert p[f"m_{link}"] == pytest.approx(inertia.mass, rel=1e-12, abs=1e-15)
        com = [p[f"c{a}_{link}"] for a in "xyz"]
        np.testing.assert_allclose(com, inertia.lever, rtol=1e-10, atol=1e-12, err_msg=link)
        I = np.array([[p[f"Ixx_{link}"], p[f"Ixy_{link}"], p[f"Ixz_{link}"]],
                      [p[f"Ixy_{link}"], p[f"Iyy_{link}"], p[f"Iyz_{link}"]],
                      [p[f"Ixz_{link}"], p[f"Iyz_{link}"], p[f"Izz_{link}"]]])
        np.testing.assert_allclose(I, inertia.inertia, rtol=1e-9,
                                   atol=1e-12 * max(1.0, np.abs(I).max()), err_msg=link)


def test_mass_matrix(robot):
    dyn, ref = robot
    for k, (q, _, _) in enumerate(random_states(dyn, seed=1)):
        M = dyn.mass_matrix(q)
        assert_close(M, M.T, f"{dyn.model.name} state {k}: M symmetric", rtol=1e-14)
        assert_close(M, ref.mass_matrix(q), f"{dyn.model.name} state {k}: mass matrix")


def test_forward_dynamics(robot):
    dyn, ref = robot
    for k, (q, qd, qdd) in enumerate(random_states(dyn, seed=2)):
        # torques that give accelerations of order one at every joint, light fingers included
        tau = ref.inverse_dynamics(q, qd, qdd)
        expected = ref.forward_dynamics(q, qd, tau)
        np.testing.assert_allclose(expected, qdd, rtol=1e-7, atol=1e-7)  # pinocchio agrees
        assert_close(dyn.forward_dynamics(q, qd, tau), expected,
                     f"{dyn.model.name} state {k}: forward dynamics")


def test_forward_dynamics_with_random_torques(robot):
    dyn, ref = robot
    rng = np.random.default_rng(3)
    for k, (q, qd, _) in enumerate(random_states(dyn, seed=3)):
        tau = rng.normal(scale=5.0, size=dyn.n)
        assert_close(dyn.forward_dynamics(q, qd, tau), ref.forward_dynamics(q, qd, tau),
                     f"{dyn.model.name} state {k}: forward dynamics, random torques")
        assert_close(dyn.forcing(q, qd, tau), tau - ref.inverse_dynamics(q, qd, np.zeros(dyn.n)),
                     f"{dyn.model.name} state {k}: forcing = tau - bias")


def test_inverse_dynamics(robot):
    dyn, ref = robot
    for k, (q, qd, qdd) in enumerate(random_states(dyn, seed=4)):
        assert_close(dyn.inverse_dynamics(q, qd, qdd), ref.inverse_dynamics(q, qd, qdd),
                     f"{dyn.model.name} state {k}: inverse dynamics")


def test_energy(robot):
    dyn, ref = robot
    states = list(random_states(dyn, seed=5))
    potentials, references = [], []
    for k, (q, qd, _) in enumerate(states):
        kinetic, potential = dyn.energy(q, qd)
        expected = ref.kinetic(q, qd)
        assert expected > 0
        assert kinetic == pytest.approx(expected, rel=RTOL), f"state {k}: kinetic energy"
        potentials.append(potential)
        references.append(ref.potential(q))
    # differences between states: blind to the constant of bodies welded to the world
    ours = np.array(potentials[1:]) - potentials[0]
    theirs = np.array(references[1:]) - references[0]
    assert_close(ours, theirs, f"{dyn.model.name}: potential energy differences")


@pytest.mark.parametrize("backend", BACKENDS)
def test_panda_payload_mass_override(backend, urdf_cache):
    """A heavier hand through `p` gives what pinocchio gives with the same inertia changed."""
    dyn = load_robot("panda", backend, urdf_cache)
    ref = PinRobot(URDF_DIR / "panda.urdf", dyn.coordinates)
    key = f"m_{PANDA_PAYLOAD_BODY}"
    assert key in dyn.parameters, sorted(k for k in dyn.parameters if k.startswith("m_"))
    jid = ref.model.getJointId("panda_joint7")
    old = ref.model.inertias[jid]
    # the default is the merged mass: link7 + link8 + hand (+ the massless tcp)
    assert dyn.parameters[key] == pytest.approx(old.mass, rel=1e-12)
    assert dyn.parameters[key] > 1.0
    heavier = old.mass + 2.5
    ref.model.inertias[jid] = pin.Inertia(heavier, old.lever, old.inertia)
    ref.data = ref.model.createData()
    p = {key: heavier}
    for k, (q, qd, qdd) in enumerate(random_states(dyn, seed=6, count=3)):
        what = f"panda {backend} state {k} with {key}={heavier}"
        M = dyn.mass_matrix(q, p)
        assert_close(M, ref.mass_matrix(q), f"{what}: mass matrix")
        assert not np.allclose(M, dyn.mass_matrix(q), rtol=1e-3), "the override changed nothing"
        tau = dyn.inverse_dynamics(q, qd, qdd, p)
        assert_close(tau, ref.inverse_dynamics(q, qd, qdd), f"{what}: inverse dynamics")
        assert_close(dyn.forward_dynamics(q, qd, tau, p), ref.forward_dynamics(q, qd, tau),
                     f"{what}: forward dynamics")
        np.testing.assert_allclose(dyn.forward_dynamics(q, qd, tau, p), qdd, rtol=1e-7,
                                   atol=1e-7)
        kinetic, _ = dyn.energy(q, qd, p)
        assert kinetic == pytest.approx(ref.kinetic(q, qd), rel=RTOL)
    q0, q1 = (s[0] for s in random_states(dyn, seed=7, count=2))
    ours = dyn.energy(q1, q0 * 0, p)[1] - dyn.energy(q0, q0 * 0, p)[1]
    theirs = ref.potential(q1) - ref.potential(q0)
    assert ours == pytest.approx(theirs, rel=RTOL, abs=1e-12)


def test_cli_build_prints_stages(tmp_path, capsys):
    path = URDF_DIR / "ur5_robot.urdf"
    assert cli_main(["build", str(path), "--cache-dir", str(tmp_path)]) == 0
    out, err = capsys.readouterr()
    for stage in ("derive", "generate", "compile"):
        assert re.search(rf"^gagen: {stage}\s+\d+\.\d+ s", err, re.MULTILINE), err
    assert re.search(r"\d+ operations before CSE, \d+ after", out), out
    module = Path(re.search(r"^gagen: module (.+)$", out, re.MULTILINE).group(1))
    assert module.is_file() and tmp_path in module.parents
    # the module is now in the cache: a second build reuses it, and it loads and agrees
    _, report = build(resolve_model(path), cache_dir=tmp_path)
    assert report.cached
    dyn = gagen.load(path, cache_dir=tmp_path)
    ref = PinRobot(path, dyn.coordinates)
    q, qd, qdd = next(random_states(dyn, seed=8))
    assert_close(dyn.inverse_dynamics(q, qd, qdd), ref.inverse_dynamics(q, qd, qdd), "ur5 cli")
