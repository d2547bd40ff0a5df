"""The derivatives of the dynamics (gagen.symbolic.derivatives), in both backends (the
compiled one: the derivative module of codegen/derivatives.py): against Pinocchio's
analytical derivatives and Coriolis matrix, against central differences of gagen's own
functions, the Coriolis matrix's defining properties, the API's shapes, checks and fresh
memory, the derivative module's build on first use and its C used standalone."""

from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import sympy as sp
from conftest import SHARED_URDF
from random_trees import random_model
from test_joint_terms import with_random_joint_terms

import gagen
from gagen import NonFiniteStateError, SingularMassMatrixError
from gagen.codegen.derivatives import DERIVATIVE_MODULE_FILE
from gagen.model.resolve import resolve_model
from gagen.runtime.lambdify import LambdifyDynamics
from gagen.symbolic.derivation import derive_equations
from gagen.symbolic.derivatives import derive_derivatives
from gagen.symbolic.symbols import Acceleration, Torque

RTOL = 1e-9
RANDOM_TREE_SEEDS = (1, 4, 7, 12)

# (model, derivation, vary the parameters): a URDF's full inertia tensors do not stay
# positive definite under independent random scalings of their entries, so those run at
# their defaults
CASES = {
    "rrr": ("rrr", "gibbs-appell", True),
    "rrr-recursive": ("rrr", "recursive", True),
    **{f"random{s}": (f"random:{s}", "auto", True) for s in RANDOM_TREE_SEEDS},
    "random7-recursive": ("random:7", "recursive", True),
    # two prismatic and two revolute joints (and a fixed one) with damping, friction and
    # armature: 4 coordinates, so its derivatives take the analytical algorithm, whose M
    # and forcing add the joint terms themselves (symbolic/derivatives.py)
    "terms7": ("terms:7", "recursive", True),
    "chain5-recursive": ("chain:5", "recursive", True),
    "ur5": (str(SHARED_URDF / "ur5_robot.urdf"), "auto", False),
    "panda": (str(SHARED_URDF / "panda.urdf"), "auto", False),
}


def _model(name: str):
    if name.startswith("random:"):
        return random_model(np.random.default_rng(int(name.split(":")[1])), 6, symbolic=True)
    if name.startswith("terms:"):
        rng = np.random.default_rng(int(name.split(":")[1]))
        return with_random_joint_terms(random_model(rng, 5, symbolic=True), rng, True)
    return resolve_model(name)


@functools.cache
def lambdify_dynamics(case: str) -> LambdifyDynamics:
    name, derivation, _ = CASES[case]
    return LambdifyDynamics(derive_equations(_model(name), derivation))


@functools.cache
def compiled_dynamics(case: str):
    """Both compiled modules of a case (the derivative module built up front)."""
    name, derivation, _ = CASES[case]
    model = _model(name) if name.startswith(("random:", "terms:")) else name
    return gagen.load(model, derivation=derivation, derivatives=True)


def dynamics(case: str, backend: str):
    return lambdify_dynamics(case) if backend == "lambdify" else compiled_dynamics(case)


# The compiled cases of the default run; the others build two modules each (the Panda's
# and the UR5's take half a minute to a minute on a busy 2-core machine): slow.
COMPILED_DEFAULT = ("rrr", "rrr-recursive", "random7", "chain5-recursive", "terms7")


def backend_cases(cases, compiled=COMPILED_DEFAULT):
    """(case, backend) parameters: every case on lambdify, and compiled (slow unless in
    `compiled`)."""
    params = [pytest.param(case, "lambdify", id=f"{case}-lambdify") for case in cases]
    params += [pytest.param(case, "compiled", id=f"{case}-compiled",
                            marks=() if case in compiled else pytest.mark.slow)
               for case in cases]
    return params


def random_state(dyn, rng, vary: bool = True):
    """q, qd, qdd, tau and a parameter array (defaults scaled by 0.5..1.5 when `vary`)."""
    q = rng.uniform(-np.pi, np.pi, dyn.n)
    qd, qdd, tau = rng.normal(size=(3, dyn.n)) * 2.0
    p = dyn.parameter_vector()
    if vary:
        p = p * rng.uniform(0.5, 1.5, p.shape)
    return q, qd, qdd, tau, p


def assert_close(got, want, rtol=RTOL):
    """Entrywise within rtol of the matrix's largest entry (zeros of one are tiny in the
    other, so a purely entrywise relative test would compare rounding errors)."""
    want = np.asarray(want)
    np.testing.assert_allclose(got, want, rtol=rtol, atol=rtol * max(1.0, np.abs(want).max()))


# --- against Pinocchio ------------------------------------------------------------------

def matrix_from_pinocchio(pm, X) -> np.ndarray:
    """A matrix over Pinocchio's velocity order in gagen's coordinate order: the
    permutation applies to the rows and the columns."""
    X = np.asarray(X)
    out = np.empty_like(X)
    out[np.ix_(pm.gagen_order, pm.gagen_order)] = X
    return out


def test_the_random_trees_have_every_joint_type():
    types = {b.joint.type for s in RANDOM_TREE_SEEDS for b in _model(f"random:{s}").bodies}
    assert types == {"revolute", "continuous", "prismatic", "fixed"}


@pytest.mark.parametrize("case, backend", backend_cases(CASES))
def test_matches_pinocchio(case, backend):
    pin = pytest.importorskip("pinocchio")
    from gagen.reference.pinocchio import joint_forces, pinocchio_model, to_pinocchio

    dyn = dynamics(case, backend)
    rng = np.random.default_rng(11)
    for _ in range(3):
        q, qd, qdd, tau, p = random_state(dyn, rng, vary=CASES[case][2])
        pm = pinocchio_model(dyn.model, p)
        gagen_order = functools.partial(matrix_from_pinocchio, pm)
        # Pinocchio's rnea and aba (and derivatives) have the armature but not damping and
        # friction: those act as the torque -joint_forces(qd), of derivative -damping in qd
        qp, vp, ap, tp = to_pinocchio(pm, q, qd, qdd, tau - joint_forces(pm, qd))
        # Pinocchio returns views into its Data: copy them while each Data is alive
        data = pm.createData()
        rnea = [np.array(a) for a in pin.computeRNEADerivatives(pm, data, qp, vp, ap)]
        aba = [np.array(a) for a in pin.computeABADerivatives(pm, data, qp, vp, tp)]
        coriolis = np.array(pin.computeCoriolisMatrix(pm, data, qp, vp))
        rnea[1] = rnea[1] + np.diag(pm.damping)
        aba[1] = aba[1] - aba[2] @ np.diag(pm.damping)

        dtau_dq, dtau_dqd = dyn.inverse_dynamics_derivatives(q, qd, qdd, p)
        assert_close(dtau_dq, gagen_order(rnea[0]))
        assert_close(dtau_dqd, gagen_order(rnea[1]))
        dqdd_dq, dqdd_dqd, dqdd_dtau = dyn.forward_dynamics_derivatives(q, qd, tau, p)
        assert_close(dqdd_dq, gagen_order(aba[0]))
        assert_close(dqdd_dqd, gagen_order(aba[1]))
        assert_close(dqdd_dtau, gagen_order(aba[2]))
        assert_close(dyn.coriolis_matrix(q, qd, p), gagen_order(coriolis))
        A, B = dyn.linearize(q, qd, tau, p)
        assert_close(A[dyn.n:], np.hstack([gagen_order(aba[0]), gagen_order(aba[1])]))
        assert_close(B[dyn.n:], gagen_order(aba[2]))


@pytest.mark.parametrize("case", ["random7", "random12"])
def test_the_loop_form_matches_pinocchio_on_a_fixed_base(case):
    """The derivative module in loop form (model/derivatives_loop.c.j2), which "auto" gives
    from DERIVATIVE_LOOP_FROM_DOF coordinates on, on small trees with every joint type."""
    pin = pytest.importorskip("pinocchio")
    from gagen.building.builder import load_derivative_module
    from gagen.codegen.config import CodegenConfig
    from gagen.reference.pinocchio import joint_forces, pinocchio_model, to_pinocchio

    model = _model(CASES[case][0])
    dyn = gagen.load(model)
    dyn.bind_derivatives(load_derivative_module(model,
                                                config=CodegenConfig(derivative_form="loop")))
    rng = np.random.default_rng(12)
    for _ in range(2):
        q, qd, qdd, tau, p = random_state(dyn, rng)
        pm = pinocchio_model(dyn.model, p)
        gagen_order = functools.partial(matrix_from_pinocchio, pm)
        qp, vp, ap, tp = to_pinocchio(pm, q, qd, qdd, tau - joint_forces(pm, qd))
        data = pm.createData()
        rnea = [np.array(a) for a in pin.computeRNEADerivatives(pm, data, qp, vp, ap)]
        aba = [np.array(a) for a in pin.computeABADerivatives(pm, data, qp, vp, tp)]
        coriolis = np.array(pin.computeCoriolisMatrix(pm, data, qp, vp))
        minv = np.triu(aba[2]) + np.triu(aba[2], 1).T
        dtau_dq, dtau_dqd = dyn.inverse_dynamics_derivatives(q, qd, qdd, p)
        assert_close(dtau_dq, gagen_order(rnea[0]))
        assert_close(dtau_dqd, gagen_order(rnea[1] + np.diag(pm.damping)))
        dqdd_dq, dqdd_dqd, dqdd_dtau = dyn.forward_dynamics_derivatives(q, qd, tau, p)
        assert_close(dqdd_dq, gagen_order(aba[0]))
        assert_close(dqdd_dqd, gagen_order(aba[1] - minv @ np.diag(pm.damping)))
        assert_close(dqdd_dtau, gagen_order(minv))
        assert_close(dyn.coriolis_matrix(q, qd, p), gagen_order(coriolis))


# --- against central differences of gagen's own functions -------------------------------

def central_difference(f, x, h=1e-6):
    """d f / d x (f: vector -> array of shape s) as an array of shape s + (len(x),)."""
    columns = []
    for j in range(x.size):
        e = np.zeros_like(x)
        e[j] = h
        columns.append((f(x + e) - f(x - e)) / (2 * h))
    return np.stack(columns, axis=-1)


@pytest.mark.parametrize("case, backend", backend_cases(
    ["rrr", "rrr-recursive", "random4", "random7", "chain5-recursive", "terms7"]))
def test_matches_central_differences(case, backend):
    dyn = dynamics(case, backend)
    rng = np.random.default_rng(5)
    n = dyn.n
    q, qd, qdd, tau, p = random_state(dyn, rng)
    rtol = 1e-6

    dtau_dq, dtau_dqd = dyn.inverse_dynamics_derivatives(q, qd, qdd, p)
    assert_close(dtau_dq, central_difference(lambda x: dyn.inverse_dynamics(x, qd, qdd, p), q),
                 rtol)
    assert_close(dtau_dqd, central_difference(lambda x: dyn.inverse_dynamics(q, x, qdd, p), qd),
                 rtol)

    derivatives = dyn.forward_dynamics_derivatives(q, qd, tau, p)
    for k, got in enumerate(derivatives):
        def fd(x, k=k):
            args = [q, qd, tau]
            args[k] = x
            return dyn.forward_dynamics(*args, p)
        assert_close(got, central_difference(fd, [q, qd, tau][k]), rtol)

    A, B = dyn.linearize(q, qd, tau, p)
    x = np.concatenate([q, qd])

    def f(x, u):
        return np.concatenate([x[n:], dyn.forward_dynamics(x[:n], x[n:], u, p)])
    assert_close(A, central_difference(lambda x: f(x, tau), x), rtol)
    assert_close(B, central_difference(lambda u: f(x, u), tau), rtol)


# --- the Coriolis matrix -------------------------------------------------------------

@pytest.mark.parametrize("case, backend", backend_cases(
    ["rrr", "rrr-recursive", "random1", "random12", "chain5-recursive", "panda", "terms7"]))
def test_coriolis_matrix_properties(case, backend):
    """C qd = the velocity terms; Mdot - 2C is skew-symmetric, with Mdot from central
    differences along qd; and dtau/dqd = 2C (the symmetry of the Christoffel symbols), plus
    the joints' damping."""
    dyn = dynamics(case, backend)
    rng = np.random.default_rng(8)
    for _ in range(2):
        q, qd, qdd, _, p = random_state(dyn, rng, vary=CASES[case][2])
        C = dyn.coriolis_matrix(q, qd, p)
        n = dyn.n  # the joints' damping and friction are not velocity terms
        damping, friction, _ = dyn.joint_terms(p)
        b = dyn.inverse_dynamics(q, qd, np.zeros(n), p) - dyn.gravity(q, p) \
            - damping * qd - friction * np.sign(qd)
        assert_close(C @ qd, b)
        h = 1e-6
        Mdot = (dyn.mass_matrix(q + h * qd, p) - dyn.mass_matrix(q - h * qd, p)) / (2 * h)
        S = Mdot - 2 * C
        assert np.abs(S).max() > 1e-3 * np.abs(C).max()  # C is not simply Mdot / 2
        np.testing.assert_allclose(S + S.T, 0, atol=1e-6 * max(1.0, np.abs(Mdot).max()))
        assert_close(dyn.inverse_dynamics_derivatives(q, qd, qdd, p)[1],
                     2 * C + np.diag(damping))


# --- the program --------------------------------------------------------------------

def _needed_symbols(program, exprs):
    from gagen.symbolic.differentiate import needed_definitions

    needed = needed_definitions(program.intermediates, exprs)
    return set().union(*(e.free_symbols for _, e in needed),
                       *(sp.sympify(e).free_symbols for e in exprs))


@pytest.mark.parametrize("name, derivation", [("rrr", "gibbs-appell"), ("chain:4", "recursive")])
def test_program_continues_the_equations_and_its_kernels_use_their_arguments(name, derivation):
    eqs = derive_equations(resolve_model(name), derivation)
    d = derive_derivatives(eqs)
    n = eqs.n
    assert d.intermediates[:len(eqs.intermediates)] == eqs.intermediates
    names = [s for s, _ in d.intermediates]
    assert len(names) == len(set(names))
    outputs = d.outputs()
    assert len(outputs["inverse_dynamics_derivatives"]) == 2 * n * n
    assert len(outputs["coriolis_matrix"]) == n * n
    for kernel, exprs in outputs.items():
        allowed = {s for group in d.arguments()[kernel] for s in group}
        used = {s for s in _needed_symbols(d, exprs) if not s.name.startswith("_g")}
        assert used <= allowed, (kernel, used - allowed)
    # dtau/dqd and C are free of the accelerations, and nothing uses the torques
    for exprs in (d.dtau_dqd, d.coriolis):
        assert not any(isinstance(s, (Acceleration, Torque)) for s in _needed_symbols(d, exprs))
    assert d.operation_count() >= d.operation_count("coriolis_matrix") > 0


ANALYTIC_CASES = ["random1", "random4", "random7", "random12", "chain5-recursive", "ur5"]


@pytest.mark.parametrize("case", ANALYTIC_CASES)
def test_analytical_algorithm_matches_forward_mode(case):
    """The world-frame algorithm (symbolic/rnea_derivatives.py) against forward mode
    through the equations' own program, at random states and parameters: d tau/d q,
    d tau/d qd, and the M and forcing it gives the forward-dynamics derivatives. Also on
    the closed form (chain:5 by Gibbs-Appell), whose program shares nothing with it."""
    name, derivation, vary = CASES[case]
    cases = [(derivation, vary)] + ([("gibbs-appell", True)] if case == "chain5-recursive"
                                    else [])
    for derivation, vary in cases:
        eqs = derive_equations(_model(name), derivation)
        dyn = LambdifyDynamics(eqs)
        c, p = eqs.coords, eqs.parameters
        args = [c.q, c.qd, c.qdd, c.tau, p]
        values = {}
        for method in ("forward", "analytic"):
            d = derive_derivatives(eqs, method)
            M = eqs.mass_matrix if d.mass_matrix is None else d.mass_matrix
            forcing = eqs.forcing if d.forcing is None else d.forcing
            exprs = [*d.dtau_dq, *d.dtau_dqd, *M, *forcing]
            values[method] = dyn._lambdify(args, exprs, d.intermediates)
        rng = np.random.default_rng(3)
        for _ in range(3):
            q, qd, qdd, tau, pv = random_state(dyn, rng, vary)
            flat = [*q, *qd, *qdd, *tau, *pv]
            got, want = (np.array(values[m](*flat), float) for m in ("analytic", "forward"))
            assert_close(got, want, rtol=1e-11)


def test_derivative_method_rule():
    from gagen.symbolic.derivatives import ANALYTIC_FROM_DOF, derivative_method

    assert derivative_method(resolve_model("rrr")) == "forward"
    assert derivative_method(resolve_model(f"chain:{ANALYTIC_FROM_DOF}")) == "analytic"
    assert derivative_method(resolve_model("rrr"), "analytic") == "analytic"
    floating = resolve_model(SHARED_URDF / "panda.urdf", floating_base=True)
    assert derivative_method(floating) == "analytic"  # whatever its size
    assert derivative_method(floating, "forward") == "forward"
    with pytest.raises(ValueError, match="unknown derivative method"):
        derivative_method(floating, "backward")


def test_structural_zeros_are_exact():
    """chain:N's first joint turns about the vertical: nothing depends on its angle."""
    d = derive_derivatives(derive_equations(resolve_model("chain:4"), "recursive"))
    n = 4
    assert all(d.dtau_dq[i * n] == 0 for i in range(n))
    assert any(e != 0 for e in d.dtau_dq)


def test_program_is_deterministic_across_hash_seeds():
    code = ("from gagen.model.resolve import resolve_model\n"
            "from gagen.symbolic.derivation import derive_equations\n"
            "from gagen.symbolic.derivatives import derive_derivatives\n"
            "d = derive_derivatives(derive_equations(resolve_model('chain:3'), 'recursive'))\n"
            "print([(str(s), str(e)) for s, e in d.intermediates], d.outputs())\n")
    outs = {subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           check=True, env={"PYTHONHASHSEED": seed, "PATH": ""}).stdout
            for seed in ("1", "2")}
    assert len(outs) == 1


# --- the API ------------------------------------------------------------------------

def _all_methods(dyn, q, qd, x, p=None):
    """Every derivative method's outputs at one (possibly stacked) state, as a flat list."""
    return [*dyn.inverse_dynamics_derivatives(q, qd, x, p),
            *dyn.forward_dynamics_derivatives(q, qd, x, p),
            dyn.coriolis_matrix(q, qd, p), *dyn.linearize(q, qd, x, p)]


BACKENDS = ("lambdify", "compiled")


@pytest.mark.parametrize("backend", BACKENDS)
def test_shapes_and_stacked_inputs_match_single_calls(backend):
    dyn = dynamics("rrr", backend)
    n = dyn.n
    rng = np.random.default_rng(2)
    Q, QD, X = rng.normal(size=(3, 5, n))
    stacked = _all_methods(dyn, Q, QD, X)
    assert [a.shape for a in stacked] == [(5, n, n)] * 6 + [(5, 2 * n, 2 * n), (5, 2 * n, n)]
    for k in range(5):
        single = _all_methods(dyn, Q[k], QD[k], X[k])
        assert [a.shape for a in single] == [(n, n)] * 6 + [(2 * n, 2 * n), (2 * n, n)]
        for s, one in zip(stacked, single):
            np.testing.assert_allclose(s[k], one, rtol=1e-13, atol=1e-13)
    # a single state broadcasts against stacked ones
    mixed = _all_methods(dyn, Q[0], QD, X)
    for s, m in zip(_all_methods(dyn, np.broadcast_to(Q[0], Q.shape), QD, X), mixed):
        np.testing.assert_array_equal(s, m)


@pytest.mark.parametrize("backend", BACKENDS)
def test_every_call_returns_fresh_memory(backend):
    dyn = dynamics("rrr", backend)
    q, qd, x = np.full((3, 3), 0.3)
    first = _all_methods(dyn, q, qd, x)
    second = _all_methods(dyn, q, qd, x)
    for a, b in zip(first, second):
        assert not np.shares_memory(a, b)
        a[...] = np.nan
        assert np.isfinite(b).all()
    assert not np.shares_memory(*dyn.inverse_dynamics_derivatives(q, qd, x))


@pytest.mark.parametrize("backend", BACKENDS)
def test_parameters_and_bad_inputs(backend):
    dyn = dynamics("rrr", backend)
    q, qd, x = np.full((3, 3), 0.3)
    heavy = dyn.coriolis_matrix(q, qd, p={"m3": 80.0})
    assert not np.allclose(heavy, dyn.coriolis_matrix(q, qd))
    np.testing.assert_array_equal(heavy, dyn.coriolis_matrix(
        q, qd, p=dyn.parameter_vector({"m3": 80.0})))
    for method in (dyn.inverse_dynamics_derivatives, dyn.forward_dynamics_derivatives,
                   dyn.linearize):
        with pytest.raises(ValueError, match="shape"):
            method(np.zeros(4), qd, x)
        with pytest.raises(ValueError, match="rows"):
            method(np.zeros((2, 3)), np.zeros((3, 3)), x)
        with pytest.raises(TypeError):
            method("q", qd, x)
        with pytest.raises(KeyError, match="unknown parameter"):
            method(q, qd, x, p={"mass_of_the_moon": 1.0})
    with pytest.raises(ValueError, match="shape"):
        dyn.coriolis_matrix(q, np.zeros(2))
    massless = {name: 0.0 for name in dyn.parameters if name[0] in "mI"}
    with pytest.raises(SingularMassMatrixError):
        dyn.forward_dynamics_derivatives(q, qd, x, p=massless)
    with pytest.raises(NonFiniteStateError):
        dyn.linearize([0.1, np.nan, 0.3], qd, x)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_singular_row_of_stacked_states_is_named(backend):
    dyn = dynamics("rrr", backend)
    massless = dyn.parameter_vector({name: 0.0 for name in dyn.parameters if name[0] in "mI"})
    q = np.zeros((4, 3))
    q[2, 1] = np.nan
    with pytest.raises(NonFiniteStateError, match="row 2" if backend == "compiled" else None):
        dyn.forward_dynamics_derivatives(q, q, q)
    with pytest.raises(SingularMassMatrixError):
        dyn.linearize(np.zeros((4, 3)), q, q, p=massless)
    # the other methods do not factor M: they compute at any parameters
    assert np.isfinite(dyn.coriolis_matrix(np.ones(3), np.ones(3), p=massless)).all()


def test_stacked_compiled_calls_run_the_c_loop_with_fresh_outputs():
    """Large stacks (the GIL-free loop) match the single calls row by row; a single state
    broadcasts against the stacked ones."""
    dyn = compiled_dynamics("chain5-recursive")
    rng = np.random.default_rng(3)
    Q, QD, X = rng.normal(size=(3, 200, dyn.n))
    stacked = _all_methods(dyn, Q, QD, X)
    for k in (0, 117, 199):
        for s, one in zip(stacked, _all_methods(dyn, Q[k], QD[k], X[k])):
            np.testing.assert_array_equal(s[k], one)
    for s, m in zip(stacked, _all_methods(dyn, Q, QD[5], X)):
        assert s.shape == m.shape
    np.testing.assert_array_equal(_all_methods(dyn, Q, QD[5], X)[0][9],
                                  _all_methods(dyn, Q[9], QD[5], X[9])[0])


# --- the derivative module: built on first use, found again without SymPy ----------------

def _entries(cache) -> list[str]:
    """The compiled modules of a cache folder (its entries, not the index)."""
    return sorted(p.name.rsplit("-", 1)[0] for p in cache.iterdir()
                  if p.is_dir() and p.name.startswith("gagen_"))


FIRST_USE = """
import json, sys
import numpy as np
import gagen
dyn = gagen.load(sys.argv[1], cache_dir=sys.argv[2], derivatives=sys.argv[3] == "up-front")
loaded = "sympy" in sys.modules
q = np.full(dyn.n, 0.2)
values = [a.tolist() for a in dyn.forward_dynamics_derivatives(q, q, q)]
print(json.dumps({"sympy after load": loaded, "sympy after the derivatives": "sympy" in
                  sys.modules, "values": values}))
"""


def _first_use(model: str, cache, mode: str) -> dict:
    proc = subprocess.run([sys.executable, "-c", FIRST_USE, model, str(cache), mode],
                          capture_output=True, text=True, timeout=900, check=False)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


def test_the_derivative_module_is_built_on_first_use_and_found_without_sympy(tmp_path):
    model = "chain:2"
    dyn = gagen.load(model, cache_dir=tmp_path)
    assert _entries(tmp_path) == [f"{dyn.module.__name__}"]  # a plain load: one module
    assert dyn.derivative_module is None
    q = np.full(2, 0.2)
    C = dyn.coriolis_matrix(q, q)  # the first derivative call builds the second module
    assert _entries(tmp_path) == sorted([dyn.module.__name__, dyn.derivative_module.__name__])
    assert dyn.derivative_module.__name__ == dyn.module.__name__ + "_derivatives"
    np.testing.assert_array_equal(dyn.coriolis_matrix(q, q), C)
    # a fresh process finds both modules by the input's key: no SymPy, no build
    again = _first_use(model, tmp_path, "on-first-use")
    assert again["sympy after load"] is False and again["sympy after the derivatives"] is False
    assert len(_entries(tmp_path)) == 2
    up_front = _first_use(model, tmp_path, "up-front")
    assert up_front["sympy after load"] is False
    np.testing.assert_array_equal(up_front["values"], again["values"])
    want = dyn.forward_dynamics_derivatives(q, q, q)
    np.testing.assert_array_equal(np.array(again["values"]), np.array(want))


def test_load_with_derivatives_builds_both_modules_up_front(tmp_path):
    dyn = gagen.load("chain:2", cache_dir=tmp_path, derivatives=True)
    assert dyn.derivative_module is not None
    assert len(_entries(tmp_path)) == 2
    # bound to the instance: the C methods themselves, no Python frame of gagen's
    for name in ("inverse_dynamics_derivatives", "forward_dynamics_derivatives",
                 "coriolis_matrix", "linearize"):
        assert type(getattr(dyn, name).__self__).__name__ == "CompiledDerivatives"


def test_a_derivative_module_of_other_equations_is_refused():
    rrr = compiled_dynamics("rrr")
    other = compiled_dynamics("rrr-recursive")  # the same model, the other derivation
    fresh = gagen.load("rrr")
    with pytest.raises(gagen.BuildError, match="not built from the equations"):
        fresh.bind_derivatives(other.derivative_module)
    fresh.bind_derivatives(rrr.derivative_module)
    q = np.full(3, 0.4)
    np.testing.assert_array_equal(fresh.coriolis_matrix(q, q), rrr.coriolis_matrix(q, q))


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_floating_base_derivatives_match_pinocchio(backend, tmp_path):
    """A random floating tree (the quaternion in q): d/dq along the velocity directions,
    as Pinocchio's computeRNEADerivatives and computeABADerivatives take it, to 1e-9;
    C qd = b; the stacked call gives the single calls' numbers."""
    pin = pytest.importorskip("pinocchio")
    from test_floating import Reference, close, floating_tree, random_state

    from gagen.model.numeric import numeric_model
    from gagen.reference.pinocchio import pinocchio_model

    model = floating_tree(3, bodies=4)
    options = {"cache_dir": tmp_path} if backend == "compiled" else {}
    dyn = gagen.load(model, backend=backend, **options)
    ref = Reference(dyn, pinocchio_model(numeric_model(model)))
    m, d = ref.model, ref.data
    order = np.ix_(ref.v_order, ref.v_order)
    rng = np.random.default_rng(5)
    states = [random_state(dyn, rng) for _ in range(2)]
    for q, v, a in states:
        qp, vp, ap = ref.q(q), ref.v(v), ref.v(a)
        dq, dv, _ = (np.array(x) for x in pin.computeRNEADerivatives(m, d, qp, vp, ap))
        ours = dyn.inverse_dynamics_derivatives(q, v, a)
        close(ours[0], dq[order], "dtau/dq")
        close(ours[1], dv[order], "dtau/dqd")
        tau = dyn.inverse_dynamics(q, v, a)
        fd = pin.computeABADerivatives(m, d, qp, vp, ref.v(tau))
        for mine, theirs, what in zip(dyn.forward_dynamics_derivatives(q, v, tau), fd,
                                      ("dqdd/dq", "dqdd/dqd", "M^-1")):
            theirs = np.array(theirs)
            if what == "M^-1":  # Pinocchio fills its upper triangle
                theirs = np.triu(theirs) + np.triu(theirs, 1).T
            close(mine, theirs[order], what)
        close(dyn.coriolis_matrix(q, v) @ v,
              dyn.inverse_dynamics(q, v, np.zeros(dyn.nv)) - dyn.gravity(q), "C qd = b")
        A, B = dyn.linearize(q, v, tau)
        assert A.shape == (2 * dyn.nv, 2 * dyn.nv) and B.shape == (2 * dyn.nv, dyn.nv)
    Q, V, Acc = (np.array(x) for x in zip(*states))
    stacked = dyn.inverse_dynamics_derivatives(Q, V, Acc)
    np.testing.assert_allclose(stacked[0][1], dyn.inverse_dynamics_derivatives(*states[1])[0],
                               rtol=1e-13, atol=1e-13)


def test_derivative_sources_are_identical_across_hash_seeds(tmp_path):
    script = ("import sys, pathlib, gagen\n"
              "from gagen.building.builder import generate_sources\n"
              "generate_sources(gagen.resolve_model('chain:3'), pathlib.Path(sys.argv[1]),"
              " derivatives=True)\n")
    digests = []
    for seed in ("1", "2"):
        folder = tmp_path / seed
        subprocess.run([sys.executable, "-c", script, str(folder)], check=True,
                       env={**os.environ, "PYTHONHASHSEED": seed})
        digests.append({p.name: hashlib.sha256(p.read_bytes()).hexdigest()
                        for p in sorted(folder.iterdir())})
    assert digests[0] == digests[1]
    assert {"derivatives.c", "gagen_math.h"} <= set(digests[0])
    assert any(name.endswith("_derivatives.h") for name in digests[0])


# --- the generated C on its own ------------------------------------------------------

STANDALONE = r"""
#include <stdio.h>
#include "rrr_derivatives.h"

static void print(const double *x, int count)
{
    int k;
    for (k = 0; k < count; ++k)
        printf("%%.17g\n", x[k]);
}

int main(void)
{
    const double p[RRR_NP] = {%(params)s};
    const double q[3] = {0.3, -0.7, 1.1}, qd[3] = {0.5, -1.5, 2.0}, x[3] = {1.0, 20.0, -5.0};
    double a[9], b[9], c[9], A[36], B[18], massless[RRR_NP];
    int k;
    rrr_inverse_dynamics_derivatives(q, qd, x, p, a, b);
    print(a, 9);
    print(b, 9);
    rrr_coriolis_matrix(q, qd, p, c);
    print(c, 9);
    printf("%%d\n", rrr_forward_dynamics_derivatives(q, qd, x, p, a, b, c));
    print(a, 9);
    print(b, 9);
    print(c, 9);
    printf("%%d\n", rrr_linearize(q, qd, x, p, A, B));
    print(A, 36);
    print(B, 18);
    for (k = 0; k < RRR_NP; ++k)
        massless[k] = k == 0 ? p[0] : 0.0;  /* g, then lengths, masses, inertias */
    for (k = 1; k < 4; ++k)
        massless[k] = p[k];
    printf("%%d\n", rrr_forward_dynamics_derivatives(q, qd, x, massless, a, b, c));
    return 0;
}
"""


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc is not installed")
def test_standalone_c_program_computes_the_same_numbers(tmp_path):
    from gagen.building.builder import generate_sources

    generate_sources(gagen.resolve_model("rrr"), tmp_path, derivatives=True)
    ref = lambdify_dynamics("rrr")
    assert list(ref.parameters)[:4] == ["g", "L1", "L2", "L3"]
    params = ", ".join(repr(v) for v in ref.parameters.values())
    (tmp_path / "main.c").write_text(STANDALONE % {"params": params})
    # every C file but the module's table for Python (derivatives_module.c)
    sources = sorted(p.name for p in tmp_path.glob("*.c") if p.name != DERIVATIVE_MODULE_FILE)
    exe = tmp_path / "derivatives_demo"
    subprocess.run(["gcc", "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic",
                    "-o", str(exe), *sources, "-lm"], cwd=tmp_path, check=True)
    values = np.array(subprocess.run([str(exe)], capture_output=True, text=True,
                                     check=True).stdout.split(), dtype=float)
    q, qd, x = np.array([0.3, -0.7, 1.1]), np.array([0.5, -1.5, 2.0]), np.array([1.0, 20, -5])
    want = [*ref.inverse_dynamics_derivatives(q, qd, x), ref.coriolis_matrix(q, qd), [0],
            *ref.forward_dynamics_derivatives(q, qd, x), [0], *ref.linearize(q, qd, x),
            [1]]  # RRR_ERR_NOT_POSITIVE_DEFINITE without masses
    np.testing.assert_allclose(values, np.concatenate([np.ravel(w) for w in want]),
                               rtol=1e-12, atol=1e-12)
    # no global or static data in any object
    for source in sources:
        if source == "main.c":
            continue
        obj = tmp_path / f"{source}.o"
        subprocess.run(["gcc", "-std=c99", "-O2", "-c", source, "-o", str(obj)],
                       cwd=tmp_path, check=True)
        symbols = subprocess.run(["nm", str(obj)], capture_output=True, text=True,
                                 check=True).stdout.split("\n")
        data = [s for s in symbols if len(s.split()) == 3 and s.split()[1] in "BDdbCG"]
        assert data == [], f"{source} defines global or static data: {data}"
