"""The derivatives of floating-base models (the analytical algorithm with a free flyer's six
coordinates, gagen.symbolic.rnea_derivatives), in both backends and both forms of the
compiled module (unrolled, loop):

- against Pinocchio's computeRNEADerivatives, computeABADerivatives and
  computeCoriolisMatrix on its FreeFlyer, to 1e-9 relative: ANYmal C, random floating
  trees with every joint type (default run), Talos reduced and full, Tiago (slow);
- against central differences along the tangent space (`integrate`);
- the Coriolis matrix's properties: C qd = b, and Mdot - 2C skew-symmetric with Mdot taken
  along `integrate`;
- stacked states, and the measured rules that choose the method and the form.
"""

from __future__ import annotations

import functools
import warnings
from pathlib import Path

import numpy as np
import pytest
from test_floating import Reference, floating_tree, random_state

import gagen
from gagen.building.builder import load_derivative_module
from gagen.codegen.config import CodegenConfig
from gagen.model.numeric import numeric_model
from gagen.model.resolve import resolve_model
from gagen.reference.pinocchio import pinocchio_model
from gagen.symbolic.derivatives import derivative_form, derivative_method

pin = pytest.importorskip("pinocchio")

URDF = Path(__file__).resolve().parent / "data" / "urdf"
RTOL = 1e-9
FORMS = ("unrolled", "loop")
# random floating trees: together they hold every joint type (checked below)
TREES = {"tree1": (1, 6), "tree3": (3, 6)}


def close(actual, expected, what: str, rtol: float = RTOL) -> None:
    """Entrywise within rtol of the largest entry of `expected` (zeros of one are tiny
    numbers in the other)."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    scale = max(float(np.abs(expected).max()), 1.0)
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=rtol * scale, err_msg=what)


def _model(name: str):
    if name in TREES:
        return floating_tree(*TREES[name])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        return resolve_model(URDF / name, floating_base=True)


@functools.cache
def lambdify_dynamics(name: str):
    return gagen.load(_model(name), backend="lambdify")


@functools.cache
def compiled_dynamics(name: str, form: str):
    """The compiled model with its derivative module in `form` ("auto": by the rule)."""
    model = _model(name)
    dyn = gagen.load(model)
    config = None if form == "auto" else CodegenConfig(derivative_form=form)
    dyn.bind_derivatives(load_derivative_module(model, config=config))
    return dyn


def dynamics(name: str, backend: str):
    return lambdify_dynamics(name) if backend == "lambdify" else compiled_dynamics(name, backend)


# robots with continuous joints, which Pinocchio's URDF parse gives two coordinates (cos,
# sin) that Reference does not map: gagen's builder of Pinocchio's model instead
BUILT = {"tiago.urdf"}


@functools.cache
def reference(name: str) -> Reference:
    """Pinocchio's model: its own URDF parse for the robots, gagen's builder for the trees
    (and the robots in BUILT)."""
    dyn = lambdify_dynamics(name) if name in TREES else compiled_dynamics(name, "auto")
    if name in TREES or name in BUILT:
        return Reference(dyn, pinocchio_model(numeric_model(_model(name))))
    return Reference(dyn, pin.buildModelFromUrdf(str(URDF / name), pin.JointModelFreeFlyer()))


def check_against_pinocchio(dyn, ref: Reference, states: int = 2, seed: int = 3) -> None:
    """Every derivative method of `dyn` against Pinocchio at random states. Pinocchio's
    derivatives leave out the URDF joints' damping and friction (gagen's dynamics have them):
    its aba sees tau less those forces, and the damping adds diag(damping) to dtau/dqd and
    -M^-1 diag(damping) to dqdd/dqd."""
    m, d = ref.model, ref.data
    order = np.ix_(ref.v_order, ref.v_order)
    damping = np.diag(ref.ours(m.damping))
    rng = np.random.default_rng(seed)
    for _ in range(states):
        q, v, a = random_state(dyn, rng)
        qp, vp, ap = ref.q(q), ref.v(v), ref.v(a)
        dq, dv, _ = (np.array(x) for x in pin.computeRNEADerivatives(m, d, qp, vp, ap))
        dtau_dq, dtau_dqd = dyn.inverse_dynamics_derivatives(q, v, a)
        close(dtau_dq, dq[order], "dtau/dq")
        close(dtau_dqd, dv[order] + damping, "dtau/dqd")
        close(dyn.coriolis_matrix(q, v),
              np.array(pin.computeCoriolisMatrix(m, d, qp, vp))[order], "C")
        tau = dyn.inverse_dynamics(q, v, a) + rng.normal(size=dyn.nv)
        aba = [np.array(x) for x in pin.computeABADerivatives(
            m, d, qp, vp, ref.v(tau - ref.joint_forces(v)))]
        minv = (np.triu(aba[2]) + np.triu(aba[2], 1).T)[order]  # Pinocchio fills one triangle
        want = (aba[0][order], aba[1][order] - minv @ damping, minv)
        for got, expected, what in zip(dyn.forward_dynamics_derivatives(q, v, tau), want,
                                       ("dqdd/dq", "dqdd/dqd", "dqdd/dtau")):
            close(got, expected, what)
        A, B = dyn.linearize(q, v, tau)
        n = dyn.nv
        close(A, np.block([[np.zeros((n, n)), np.eye(n)], [want[0], want[1]]]), "A")
        close(B, np.vstack([np.zeros((n, n)), want[2]]), "B")


def test_the_random_trees_have_every_joint_type():
    types = {b.joint.type for name in TREES for b in _model(name).bodies}
    assert types == {"floating", "revolute", "continuous", "prismatic", "fixed"}


# the unrolled form compiles the whole program (half a minute on a busy 2-core machine):
# slow; the lambdify backend runs the same program in the default run
@pytest.mark.parametrize("name", list(TREES))
@pytest.mark.parametrize("backend", ["lambdify", "loop",
                                     pytest.param("unrolled", marks=pytest.mark.slow)])
def test_random_floating_trees_match_pinocchio(name, backend):
    check_against_pinocchio(dynamics(name, backend), reference(name))


@pytest.mark.parametrize("backend", ["auto", pytest.param("lambdify", marks=pytest.mark.slow)])
def test_anymal_matches_pinocchio(backend):
    dyn = dynamics("anymal_c.urdf", backend)
    assert (dyn.nq, dyn.nv) == (19, 18)
    check_against_pinocchio(dyn, reference("anymal_c.urdf"))


@pytest.mark.slow
@pytest.mark.parametrize("form", FORMS)
def test_anymal_in_both_forms_matches_pinocchio(form):
    check_against_pinocchio(compiled_dynamics("anymal_c.urdf", form),
                            reference("anymal_c.urdf"))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["talos_reduced.urdf", "talos_full_v2.urdf", "tiago.urdf"])
def test_big_robots_match_pinocchio(name):
    dyn = compiled_dynamics(name, "auto")
    check_against_pinocchio(dyn, reference(name), states=1)


# --- against central differences along the tangent space ----------------------------------

def tangent_differences(f, dyn, q, h=1e-6):
    """d f(q (+) e v) / de at 0 for each velocity direction v = e_j, by central differences
    of `integrate`: an array of f's shape plus (nv,)."""
    columns = []
    for j in range(dyn.nv):
        step = np.zeros(dyn.nv)
        step[j] = 1.0
        columns.append((f(dyn.integrate(q, step, h)) - f(dyn.integrate(q, step, -h))) / (2 * h))
    return np.stack(columns, axis=-1)


def plain_differences(f, x, h=1e-6):
    columns = []
    for j in range(x.size):
        e = np.zeros_like(x)
        e[j] = h
        columns.append((f(x + e) - f(x - e)) / (2 * h))
    return np.stack(columns, axis=-1)


@pytest.mark.parametrize("name, backend", [("tree1", "loop"), ("tree3", "lambdify"),
                                           ("anymal_c.urdf", "auto")])
def test_match_central_differences_along_the_tangent_space(name, backend):
    dyn = dynamics(name, backend)
    rng = np.random.default_rng(7)
    q, v, a = random_state(dyn, rng)
    tau = dyn.inverse_dynamics(q, v, a)
    rtol = 1e-6
    dtau_dq, dtau_dqd = dyn.inverse_dynamics_derivatives(q, v, a)
    close(dtau_dq, tangent_differences(lambda x: dyn.inverse_dynamics(x, v, a), dyn, q),
          "dtau/dq", rtol)
    close(dtau_dqd, plain_differences(lambda x: dyn.inverse_dynamics(q, x, a), v),
          "dtau/dqd", rtol)
    dqdd_dq, dqdd_dqd, dqdd_dtau = dyn.forward_dynamics_derivatives(q, v, tau)
    close(dqdd_dq, tangent_differences(lambda x: dyn.forward_dynamics(x, v, tau), dyn, q),
          "dqdd/dq", rtol)
    close(dqdd_dqd, plain_differences(lambda x: dyn.forward_dynamics(q, x, tau), v),
          "dqdd/dqd", rtol)
    close(dqdd_dtau, plain_differences(lambda x: dyn.forward_dynamics(q, v, x), tau),
          "dqdd/dtau", rtol)


# --- the Coriolis matrix ---------------------------------------------------------------

@pytest.mark.parametrize("name, backend", [("tree1", "lambdify"), ("tree3", "loop"),
                                           ("anymal_c.urdf", "auto")])
def test_coriolis_matrix_properties_with_a_floating_base(name, backend):
    """C qd = b; Mdot - 2C is skew-symmetric, Mdot from central differences of M along
    integrate(q, +-h qd). (1/2 dtau/dqd, which is C with a fixed base, is not: its
    Mdot - 2C has a symmetric part as large as C itself.)"""
    dyn = dynamics(name, backend)
    rng = np.random.default_rng(8)
    for _ in range(2):
        q, v, _ = random_state(dyn, rng)
        C = dyn.coriolis_matrix(q, v)
        damping, friction, _ = dyn.joint_terms()
        b = dyn.inverse_dynamics(q, v, np.zeros(dyn.nv)) - dyn.gravity(q) \
            - damping * v - friction * np.sign(v)
        close(C @ v, b, "C qd = b")
        h = 1e-6
        Mdot = (dyn.mass_matrix(dyn.integrate(q, v, h))
                - dyn.mass_matrix(dyn.integrate(q, v, -h))) / (2 * h)
        scale = max(1.0, np.abs(Mdot).max())
        S = Mdot - 2 * C
        np.testing.assert_allclose(S + S.T, 0, atol=1e-6 * scale)
        half = dyn.inverse_dynamics_derivatives(q, v, np.zeros(dyn.nv))[1] / 2 \
            - np.diag(damping) / 2
        S_half = Mdot - 2 * half
        assert np.abs(S_half + S_half.T).max() > 1e-3 * scale


# --- stacked states ---------------------------------------------------------------------

@pytest.mark.parametrize("form", FORMS)
def test_stacked_states_match_single_calls(form):
    dyn = compiled_dynamics("tree1", form)
    rng = np.random.default_rng(2)
    states = [random_state(dyn, rng) for _ in range(5)]
    Q, V, X = (np.array(x) for x in zip(*states))
    calls = {
        "inverse_dynamics_derivatives": lambda q, v, x: dyn.inverse_dynamics_derivatives(q, v, x),
        "forward_dynamics_derivatives": lambda q, v, x: dyn.forward_dynamics_derivatives(q, v, x),
        "coriolis_matrix": lambda q, v, x: (dyn.coriolis_matrix(q, v),),
        "linearize": lambda q, v, x: dyn.linearize(q, v, x),
    }
    for name, call in calls.items():
        stacked = call(Q, V, X)
        for k in range(len(states)):
            for s, one in zip(stacked, call(*states[k])):
                np.testing.assert_allclose(s[k], one, rtol=1e-14, atol=1e-14, err_msg=name)


# --- the rules ------------------------------------------------------------------------------

def test_floating_models_take_the_analytical_method():
    assert derivative_method(_model("tree1")) == "analytic"
    assert derivative_method(_model("anymal_c.urdf")) == "analytic"


def test_forward_mode_on_a_floating_base_takes_the_coriolis_matrix_of_the_analytical_pass():
    """Forward mode's 1/2 db/dqd is not the floating base's C: the analytical pass gives it."""
    from gagen.runtime.lambdify import LambdifyDynamics
    from gagen.symbolic.derivation import derive_equations
    from gagen.symbolic.derivatives import derive_derivatives

    eqs = derive_equations(_model("tree3"))
    forward = LambdifyDynamics(eqs)
    forward.__dict__["derivative_equations"] = derive_derivatives(eqs, "forward")
    analytic = lambdify_dynamics("tree3")
    q, v, a = random_state(analytic, np.random.default_rng(4))
    close(forward.coriolis_matrix(q, v), analytic.coriolis_matrix(q, v), "C")
    for mine, theirs in zip(forward.inverse_dynamics_derivatives(q, v, a),
                            analytic.inverse_dynamics_derivatives(q, v, a)):
        close(mine, theirs, "ID derivatives", 1e-11)


def test_derivative_form_rule():
    from gagen.symbolic.derivatives import DERIVATIVE_LOOP_FROM_DOF

    with pytest.raises(ValueError, match="unknown derivative form"):
        derivative_form(_model("tree1"), "rolled")
    assert derivative_form(_model("tree1"), "unrolled") == "unrolled"
    assert derivative_form(_model("anymal_c.urdf")) == "loop"
    assert derivative_form(resolve_model(f"chain:{DERIVATIVE_LOOP_FROM_DOF}")) == "loop"
    assert derivative_form(resolve_model(f"chain:{DERIVATIVE_LOOP_FROM_DOF - 1}")) == "unrolled"
    floating_pendulum = resolve_model(URDF / "double_pendulum.urdf", floating_base=True)
    assert floating_pendulum.dof < DERIVATIVE_LOOP_FROM_DOF
    assert derivative_form(floating_pendulum) == "unrolled"


# --- the loop form's C on its own -----------------------------------------------------------

STANDALONE = r"""
#include <stdio.h>
#include "%(ident)s_derivatives.h"

int main(void)
{
    const double p[%(np)d] = {%(p)s};
    const double q[%(nq)d] = {%(q)s}, qd[%(nv)d] = {%(v)s}, x[%(nv)d] = {%(x)s};
    double a[%(nn)d], b[%(nn)d], c[%(nn)d];
    int k, rc;
    %(ident)s_inverse_dynamics_derivatives(q, qd, x, p, a, b);
    for (k = 0; k < %(nn)d; ++k)
        printf("%%.17g %%.17g\n", a[k], b[k]);
    rc = %(ident)s_forward_dynamics_derivatives(q, qd, x, p, a, b, c);
    for (k = 0; k < %(nn)d; ++k)
        printf("%%.17g %%.17g %%.17g\n", a[k], b[k], c[k]);
    %(ident)s_coriolis_matrix(q, qd, p, a);
    for (k = 0; k < %(nn)d; ++k)
        printf("%%.17g\n", a[k]);
    return rc;
}
"""


def test_the_loop_form_is_plain_c99_with_no_writable_static_data(tmp_path):
    """The loop form's C compiles on its own as strict C99 (-Wall -Wextra -Werror
    -pedantic), holds no global or static data but constant tables, and computes the numbers
    the module computes."""
    import shutil
    import subprocess

    from gagen.building.builder import generate_sources

    if shutil.which("gcc") is None:
        pytest.skip("gcc is not installed")
    model = _model("tree3")
    generate_sources(model, tmp_path, derivatives=True,
                     config=CodegenConfig(derivative_form="loop"))
    dyn = compiled_dynamics("tree3", "loop")
    q, v, x = random_state(dyn, np.random.default_rng(9))
    ident = next(tmp_path.glob("*_derivatives.h")).name[: -len("_derivatives.h")]
    numbers = ", ".join
    (tmp_path / "main.c").write_text(STANDALONE % {
        "ident": ident, "np": len(dyn.parameters), "nq": dyn.nq, "nv": dyn.nv,
        "nn": dyn.nv ** 2, "p": numbers(repr(float(e)) for e in dyn.parameter_vector()),
        "q": numbers(map(repr, map(float, q))), "v": numbers(map(repr, map(float, v))),
        "x": numbers(map(repr, map(float, x)))})
    sources = sorted(p.name for p in tmp_path.glob("*.c") if p.name != "derivatives_module.c")
    exe = tmp_path / "demo"
    subprocess.run(["gcc", "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic",
                    "-o", str(exe), *sources, "-lm"], cwd=tmp_path, check=True)
    out = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout
    values = np.array(out.split(), dtype=float)
    n2 = dyn.nv ** 2
    want = np.concatenate([
        np.column_stack([m.ravel() for m in dyn.inverse_dynamics_derivatives(q, v, x)]).ravel(),
        np.column_stack([m.ravel() for m in dyn.forward_dynamics_derivatives(q, v, x)]).ravel(),
        dyn.coriolis_matrix(q, v).ravel()])
    assert values.size == 6 * n2
    np.testing.assert_allclose(values, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    for source in sources:
        if source == "main.c":
            continue
        obj = tmp_path / f"{source}.o"
        subprocess.run(["gcc", "-std=c99", "-O2", "-c", source, "-o", str(obj)],
                       cwd=tmp_path, check=True)
        symbols = subprocess.run(["nm", str(obj)], capture_output=True, text=True,
                                 check=True).stdout.split("\n")
        data = [s for s in symbols if len(s.split()) == 3 and s.split()[1] in "BDdbCG"]
        assert data == [], f"{source} defines writable global or static data: {data}"
