"""Bugs the earlier suite would have let pass (issue 11, part 6): each test here fails on
a plausible wrong implementation, not only on a crash."""

from __future__ import annotations

import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import reference as ref
from conftest import REPO
from random_trees import random_model

import gagen
from gagen import PD, ComputedTorque, Eq11Trajectory
from gagen.model.modelfile import parse_model_text
from gagen.runtime.dynamics import SingularMassMatrixError

RRR_TEXT = (REPO / "src" / "gagen" / "model" / "rrr.yaml").read_text()


@pytest.fixture(scope="module")
def rrr(cache_dir):
    return gagen.load("rrr", cache_dir=cache_dir)


# ------------------------------------------------------ controllers honour the caller's p


@pytest.mark.parametrize("method", ["RK45", "dopri5"])
@pytest.mark.parametrize("kind", ["pd", "computed_torque"])
def test_controllers_use_the_parameters_the_simulation_is_given(rrr, cache_dir, method, kind):
    """With p={'m3': 80}, a PD with gravity compensation or a computed-torque law must use
    m3 = 80 in its model terms, exactly like a model whose default m3 is 80."""
    heavy = gagen.load(parse_model_text(RRR_TEXT.replace("m3: 40.0", "m3: 80.0"), "heavy.yaml"),
                       cache_dir=cache_dir, verbose=False)
    assert heavy.parameters["m3"] == 80.0
    if kind == "pd":
        law = PD(kp=[400, 300, 200], kd=[100, 80, 60], target=[0.3, -0.5, 0.4],
                 gravity_compensation=True)
    else:
        law = ComputedTorque(Eq11Trajectory([0, 0, 0], [0.3, -0.5, 0.4], 1.0), kp=50, kd=10)
    te = np.linspace(0, 1, 11)
    overridden = gagen.simulate(rrr, (0, 1), np.zeros(3), None, law, method=method,
                                p={"m3": 80.0}, t_eval=te)
    default = gagen.simulate(heavy, (0, 1), np.zeros(3), None, law, method=method, t_eval=te)
    light = gagen.simulate(rrr, (0, 1), np.zeros(3), None, law, method=method, t_eval=te)
    np.testing.assert_allclose(overridden.q, default.q, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(overridden.tau, default.tau, rtol=1e-9, atol=1e-9)
    assert np.abs(light.tau - default.tau).max() > 1.0  # the override matters here


# ------------------------------------------------------------ axes from parameters


AXIS_MODEL = """
name: axes
parameters: {g: 9.81, ax: 2.0, ay: 0.0, az: 0.0, L: 0.5}
bodies:
  - name: a
    joint: {type: revolute, axis: [ax, ay, az]}
    mass: 2.0
    com: [0, L, 0.1]
    inertia: [0.1, 0.2, 0.25, 0.01, 0, 0]
  - name: b
    parent: a
    joint: {type: prismatic, origin: {xyz: [0, L, 0]}, axis: [ay, ax, az]}
    mass: 1.0
    com: [0.1, 0, 0]
    inertia: [0.1, 0.1, 0.1, 0, 0, 0]
"""


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_joint_axes_given_by_unnormalised_parameters_are_normalised(cache_dir, backend):
    """An axis (ax, ay, az) = (2, 0, 0) is the x axis: the coordinate stays an angle (a
    distance), so the dynamics equal those with the literal unit axis, also when the
    parameters are overridden per call."""
    options = {"cache_dir": cache_dir, "verbose": False} if backend == "compiled" else {}
    symbolic = gagen.load(parse_model_text(AXIS_MODEL, "axes.yaml"), backend=backend, **options)
    literal_text = AXIS_MODEL.replace("[ax, ay, az]", "[1, 0, 0]").replace("[ay, ax, az]",
                                                                          "[0, 1, 0]")
    literal = gagen.load(parse_model_text(literal_text, "unit.yaml"), backend=backend, **options)
    tilted_text = literal_text.replace("[1, 0, 0]", "[0.6, 0, 0.8]").replace("[0, 1, 0]",
                                                                             "[0, 0.6, 0.8]")
    tilted = gagen.load(parse_model_text(tilted_text, "tilt.yaml"), backend=backend, **options)
    rng = np.random.default_rng(3)
    for _ in range(4):
        q, qd, tau = rng.normal(size=(3, 2))
        np.testing.assert_allclose(symbolic.mass_matrix(q), literal.mass_matrix(q), rtol=1e-12)
        np.testing.assert_allclose(symbolic.forward_dynamics(q, qd, tau),
                                   literal.forward_dynamics(q, qd, tau), rtol=1e-11)
        over = {"ax": 3.0, "az": 4.0}  # (0.6, 0, 0.8) after normalisation
        np.testing.assert_allclose(symbolic.forward_dynamics(q, qd, tau, p=over),
                                   tilted.forward_dynamics(q, qd, tau), rtol=1e-11)


# -------------------------------------------------------------------- fresh outputs


CALLS = {
    "mass_matrix": lambda d, q, qd, x: d.mass_matrix(q),
    "forcing": lambda d, q, qd, x: d.forcing(q, qd, x),
    "forward_dynamics": lambda d, q, qd, x: d.forward_dynamics(q, qd, x),
    "inverse_dynamics": lambda d, q, qd, x: d.inverse_dynamics(q, qd, x),
    "gravity": lambda d, q, qd, x: d.gravity(q),
    "energy": lambda d, q, qd, x: np.stack(d.energy(q, qd), axis=-1),
}


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
@pytest.mark.parametrize("stacked", [False, True])
def test_no_two_results_share_memory_and_no_call_changes_an_earlier_result(
        cache_dir, backend, stacked):
    """An output buffer shared between calls (or between forcing, inverse dynamics and
    gravity) corrupts SciPy's integrators after a rejected step."""
    options = {"cache_dir": cache_dir} if backend == "compiled" else {}
    dyn = gagen.load("rrr", backend=backend, **options)
    rng = np.random.default_rng(8)
    shape = (4, 3) if stacked else (3,)
    first = [rng.normal(size=shape) for _ in range(3)]
    results = {name: call(dyn, *first) for name, call in CALLS.items()}
    kept = {name: np.array(r, copy=True) for name, r in results.items()}
    for name, call in CALLS.items():  # every method again, at other states, twice
        for _ in range(2):
            call(dyn, *(rng.normal(size=shape) for _ in range(3)))
    for name, value in results.items():
        np.testing.assert_array_equal(value, kept[name], err_msg=name)
    arrays = list(results.values()) + [CALLS["forcing"](dyn, *first)]
    for i, a in enumerate(arrays):
        for b in arrays[i + 1:]:
            assert not np.shares_memory(a, b)


# -------------------------------------------------------- indefinite mass matrices


PLANAR = """
name: planar
parameters: {g: 9.81, m1: 1.0, m2: 1.0, L: 1.0, I2: 0.1}
bodies:
  - name: a
    joint: {type: revolute, axis: [0, 0, 1]}
    mass: m1
    com: [0.5, 0, 0]
    inertia: [0.1, 0.1, 0.1, 0, 0, 0]
  - name: b
    parent: a
    joint: {type: revolute, origin: {xyz: [L, 0, 0]}, axis: [0, 0, 1]}
    mass: m2
    com: [0.5, 0, 0]
    inertia: [0.1, 0.1, I2, 0, 0, 0]
"""


def test_indefinite_mass_matrix_with_positive_diagonal_is_refused(cache_dir):
    """With I2 = -0.24 (a runtime override no body can have), M has a positive diagonal and
    a negative eigenvalue; forward dynamics must refuse it, not return numbers."""
    model = parse_model_text(PLANAR, "planar.yaml")
    lam = gagen.load(model, backend="lambdify")
    compiled = gagen.load(model, cache_dir=cache_dir, verbose=False)
    p = {"I2": -0.24}
    q = np.array([0.0, 0.0])
    M = lam.mass_matrix(q, p)
    assert (np.diag(M) > 0).all() and np.linalg.eigvalsh(M).min() < 0
    for dyn in (lam, compiled):
        with pytest.raises(SingularMassMatrixError):
            dyn.forward_dynamics(q, np.zeros(2), np.zeros(2), p)
    with pytest.raises(SingularMassMatrixError):
        gagen.simulate(compiled, (0, 1), q, None, method="dopri5", p=p)


# ------------------------------------------------------- the cache key and the generator


def test_the_cache_key_changes_when_the_generator_changes(tmp_path):
    """A copy of gagen whose code generator differs by one comment gives another key, so a
    module built by another generator is never loaded."""
    copy = tmp_path / "src"
    shutil.copytree(REPO / "src" / "gagen", copy / "gagen",
                    ignore=shutil.ignore_patterns("*.so", "__pycache__"))
    script = textwrap.dedent("""
        import gagen
        from gagen.building.builder import source_key
        print(source_key(gagen.resolve_model("chain:2")))
    """)

    def key(root):
        return subprocess.run([sys.executable, "-c", script], env={"PYTHONPATH": str(root),
                              "PATH": "/usr/bin:/bin"}, capture_output=True, text=True,
                              check=True).stdout.strip()

    before = key(copy)
    assert before == key(REPO / "src")
    for module in ("codegen/render.py", "symbolic/kinematics.py",
                   "codegen/templates/model/rhs.c.j2"):
        path = copy / "gagen" / module
        path.write_text(path.read_text() + "\n# a change of the generator\n")
        after = key(copy)
        assert after != before, module
        before = after


# ---------------------------------------------- compiled against an independent reference


@pytest.mark.parametrize("seed", [21, 22])
def test_compiled_random_trees_match_an_independent_newton_euler(cache_dir, seed):
    """Not only compiled == lambdify (which share the derivation): the compiled module
    against tests/reference.py's world-frame Newton-Euler, which shares nothing."""
    rng = np.random.default_rng(seed)
    model = random_model(rng, 6, symbolic=True)
    dyn = gagen.load(model, cache_dir=cache_dir, verbose=False)
    override = {"g": 7.0} | {k: 1.3 * v for k, v in model.parameters.items() if k[0] == "m"}
    for p in (None, override):
        nm = ref.numeric_model(model, p)
        for _ in range(4):
            q, qd, qdd = rng.uniform(-2, 2, size=(3, dyn.n))
            tau = ref.rnea(nm, q, qd, qdd)
            np.testing.assert_allclose(dyn.inverse_dynamics(q, qd, qdd, p), tau,
                                       rtol=1e-10, atol=1e-10)
            np.testing.assert_allclose(dyn.mass_matrix(q, p), ref.mass_matrix(nm, q),
                                       rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(dyn.forward_dynamics(q, qd, tau, p), qdd, rtol=1e-8,
                                       atol=1e-9)


# ----------------------------------------------------- the other builds of the kernels


@pytest.mark.parametrize("options", [{"portable": True}, {"fast_math": True}])
def test_portable_and_fast_math_builds_compute_the_same_dynamics(cache_dir, options):
    """The kernels usually run as their FMA clone on this machine; the portable version
    (no clones) and the -ffast-math build are separate binaries that need their own check."""
    model = gagen.resolve_model("chain:3")
    built = gagen.load(model, cache_dir=cache_dir, verbose=False, **options)
    reference = gagen.load(model, backend="lambdify")
    rng = np.random.default_rng(4)
    for _ in range(5):
        q, qd, tau = rng.uniform(-2, 2, size=(3, 3))
        np.testing.assert_allclose(built.forward_dynamics(q, qd, tau),
                                   reference.forward_dynamics(q, qd, tau), rtol=1e-9)
        np.testing.assert_allclose(built.inverse_dynamics(q, qd, tau),
                                   reference.inverse_dynamics(q, qd, tau), rtol=1e-9, atol=1e-9)
    res = gagen.simulate(built, (0, 1), np.full(3, 0.2), None, method="dopri5")
    want = gagen.simulate(reference, (0, 1), np.full(3, 0.2), None, method="RK45")
    np.testing.assert_allclose(res.q[-1], want.q[-1], rtol=1e-6, atol=1e-8)
