"""gagen inside JAX (issue 29): gagen.jax.functions on its three targets, the compiled
kernels through XLA's FFI, the same through jax.pure_callback, and the programs printed as
JAX: values equal gagen's own calls, jax.jacfwd / jacrev / grad equal gagen's analytic
derivatives and central differences, jax.vmap equals the stacked call and is one FFI call,
everything under jax.jit, float32 computed in double, the parameters' derivatives, the
errors. The paper's robot, the Panda (9 coordinates, prismatic fingers) and ANYmal C
(floating base) for the compiled path; the printed programs of the Panda and ANYmal take
tens of seconds to compile and are in the slow run."""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest
from conftest import SHARED_URDF

jax = pytest.importorskip("jax", reason="gagen.jax needs JAX (pip install gagen[jax])")
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp

import gagen
import gagen.jax as gj

RTOL = 1e-12
PANDA = str(SHARED_URDF / "panda.urdf")
ANYMAL = str(SHARED_URDF / "anymal_c.urdf")
_cache: dict = {}


def model(name: str):
    if name not in _cache:
        if name == "anymal":
            with warnings.catch_warnings():  # its sensor links' inertias (README)
                warnings.simplefilter("ignore", gagen.InertiaWarning)
                _cache[name] = gagen.load(ANYMAL, floating_base=True)
        else:
            _cache[name] = gagen.load({"rrr": "rrr", "panda": PANDA, "chain:6": "chain:6"}[name])
    return _cache[name]


def functions(name: str, target: str):
    key = (name, target)
    if key not in _cache:
        with warnings.catch_warnings():  # a first print reads the model again (warnings)
            warnings.simplefilter("ignore", gagen.InertiaWarning)
            _cache[key] = gj.functions(model(name), target=target)
    return _cache[key]


def state(dyn, seed=0, rows=None):
    """A random state; ANYmal's quaternion not normalised (the kernels divide by its norm)."""
    rng = np.random.default_rng(seed)
    shape = () if rows is None else (rows,)
    v = rng.normal(size=shape + (dyn.nv,)) * 0.6
    q = dyn.integrate(np.broadcast_to(dyn.neutral(), shape + (dyn.nq,)), v)
    if dyn.nq > dyn.nv:
        q[..., 3:7] *= 1.3
    qd, tau = rng.normal(size=(2,) + shape + (dyn.nv,))
    return q, qd, tau


def close(a, b, rtol=RTOL):
    """Equal to rtol of b's largest entry (the outputs' scale)."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape, (a.shape, b.shape)
    scale = max(1.0, float(np.max(np.abs(b)))) if b.size else 1.0
    err = float(np.max(np.abs(a - b))) if b.size else 0.0
    assert err <= rtol * scale, f"error {err:.3g} > {rtol:g} x {scale:.3g}"


def central(fun, x, h=1e-6):
    """Central differences of fun (NumPy) by x's entries: (..., x.size)."""
    columns = []
    for k in range(x.size):
        e = np.zeros_like(x)
        e[k] = h
        columns.append((np.asarray(fun(x + e)) - np.asarray(fun(x - e))) / (2 * h))
    return np.stack(columns, -1)


def reference(dyn, name, args, frame=None, p=None):
    """gagen's own call of a method (the compiled backend)."""
    if name == "regressor_parameters":
        return dyn.regressor_parameters(p)
    if frame is not None:
        return getattr(dyn, name)(*args, frame, p=p)
    return getattr(dyn, name)(*args, p=p)


CALLS = {  # method -> its state arguments from (q, qd, tau) and a frame (None: none)
    "mass_matrix": (("q",), None), "forcing": (("q", "qd", "tau"), None),
    "forward_dynamics": (("q", "qd", "tau"), None),
    "inverse_dynamics": (("q", "qd", "tau"), None), "gravity": (("q",), None),
    "energy": (("q", "qd"), None), "regressor": (("q", "qd", "tau"), None),
    "regressor_parameters": ((), None), "coriolis_matrix": (("q", "qd"), None),
    "inverse_dynamics_derivatives": (("q", "qd", "tau"), None),
    "forward_dynamics_derivatives": (("q", "qd", "tau"), None),
    "linearize": (("q", "qd", "tau"), None),
    "frame_placement": (("q",), "tip"), "frame_jacobian": (("q",), "tip"),
    "frame_velocity": (("q", "qd"), "tip"),
}
FRAMES = {"rrr": "link3", "panda": "panda_hand_tcp", "anymal": "LF_FOOT"}


def arguments(name, method, values):
    names, frame = CALLS[method]
    x = dict(zip(("q", "qd", "tau"), values))
    return [x[a] for a in names], (FRAMES[name] if frame else None)


def assert_results(got, want, rtol=RTOL):
    if isinstance(want, tuple):
        assert isinstance(got, tuple) and len(got) == len(want)
        for g, w in zip(got, want):
            close(g, w, rtol)
    else:
        close(got, want, rtol)


# --- values ------------------------------------------------------------------------------------

@pytest.mark.parametrize("target", ["ffi", "callback", "jax"])
@pytest.mark.parametrize("method", sorted(CALLS))
def test_every_function_equals_gagens_call_on_the_papers_robot(target, method):
    dyn, f = model("rrr"), functions("rrr", target)
    args, frame = arguments("rrr", method, state(dyn))
    want = reference(dyn, method, args, frame)
    call = f[method]
    extra = (frame,) if frame else ()
    assert_results(call(*args, *extra), want)
    jitted = jax.jit(call, static_argnums=(len(args),) if frame else ())
    assert_results(jitted(*args, *extra), want)


@pytest.mark.parametrize("name", ["panda", "anymal"])
@pytest.mark.parametrize("method", sorted(CALLS))
def test_the_ffi_functions_equal_gagens_calls_on_the_panda_and_anymal(name, method):
    dyn, f = model(name), functions(name, "ffi")
    args, frame = arguments(name, method, state(dyn, 1))
    want = reference(dyn, method, args, frame)
    assert_results(jax.jit(lambda *a: f[method](*a, *((frame,) if frame else ())))(*args),
                   want)


@pytest.mark.parametrize("target", ["ffi", "callback", "jax"])
def test_vmap_equals_the_stacked_call_and_is_one_ffi_call(target):
    dyn, f = model("rrr"), functions("rrr", target)
    q, qd, tau = state(dyn, 2, rows=64)
    p = dyn.parameter_vector() * np.linspace(0.9, 1.1, len(dyn.parameters))
    fd = jax.jit(jax.vmap(f["forward_dynamics"], in_axes=(0, 0, None)))
    fd(q, qd, tau[0]).block_until_ready()  # compiled
    before = gj.ffi_calls()
    got = fd(q, qd, tau[0]).block_until_ready()
    if target == "ffi":
        assert gj.ffi_calls() == before + 1  # the whole batch in one call of the C loop
    close(got, dyn.forward_dynamics(q, qd, np.broadcast_to(tau[0], qd.shape)))
    # parameters per state, and nested vmaps (inputs batched along different axes)
    P = np.broadcast_to(p, (64, len(p))).copy()
    P[:, 1] *= np.linspace(0.5, 1.5, 64)
    got = jax.vmap(lambda a, b, c, pp: f["inverse_dynamics"](a, b, c, p=pp))(q, qd, tau, P)
    close(got, np.stack([dyn.inverse_dynamics(q[k], qd[k], tau[k], P[k]) for k in range(64)]))
    nested = jax.vmap(jax.vmap(f["inverse_dynamics"], in_axes=(0, None, None)),
                      in_axes=(None, 0, None))(q[:5], qd[:7], tau[0])
    want = np.stack([dyn.inverse_dynamics(q[:5], np.broadcast_to(qd[j], (5, 3)),
                                          np.broadcast_to(tau[0], (5, 3))) for j in range(7)])
    close(nested, want)
    # leading dimensions without vmap: the stacked call's own form
    close(f["mass_matrix"](q), dyn.mass_matrix(q))


def test_a_batch_of_10000_states_is_one_vmapped_call():
    dyn, f = model("panda"), functions("panda", "ffi")
    q, qd, tau = state(dyn, 3, rows=10_000)
    fd = jax.jit(jax.vmap(f["forward_dynamics"]))
    before = gj.ffi_calls()
    got = fd(q, qd, tau).block_until_ready()
    assert gj.ffi_calls() == before + 1
    close(got, dyn.forward_dynamics(q, qd, tau))


@pytest.mark.parametrize("name", ["panda", "anymal"])
def test_a_vmapped_jacfwd_is_one_ffi_call_and_no_product(name):
    """jax.jit(jax.vmap(jax.jacfwd(forward_dynamics))) over (q, q̇, τ): one call of the
    derivative kernel for the whole batch, which writes the Jacobian in jacfwd's layout and
    multiplies it by jacfwd's basis in its C loop (gagen.jax.product: the identity, so the
    Jacobian's rows as they are): no dot, no transpose, no array over the batch but the
    result (the FFI's overhead over the stacked call, issue 29); equal to the stacked
    derivatives."""
    dyn, f = model(name), functions(name, "ffi")
    q, qd, tau = state(dyn, 7, rows=32)
    jac = jax.vmap(jax.jacfwd(f["forward_dynamics"], argnums=(0, 1, 2)))
    program = str(jax.make_jaxpr(jac)(q, qd, tau))
    compiled = jax.jit(jac).lower(q, qd, tau).compile()
    hlo = compiled.as_text()
    assert program.count("dot_general[") == 0
    assert hlo.count('custom_call_target="gagen_kernel"') == 1  # the primal's call is dropped
    assert " dot(" not in hlo and "__ynn_fusion" not in hlo
    # transposes: only of a floating base's rotation (per state), never of the basis' rows
    basis = str(dyn.nq + 2 * dyn.nv)
    shapes = re.findall(r"f64\[([\d,]*)\](?:\{[\d,]*\})? transpose\(", hlo)
    shapes += re.findall(r":f64\[([\d,]*)\] = transpose\[", program)
    assert all(basis not in shape.split(",") for shape in shapes), shapes
    before = gj.ffi_calls()
    got = jax.block_until_ready(compiled(q, qd, tau))
    assert gj.ffi_calls() == before + 1
    dq, dqd, dtau = dyn.forward_dynamics_derivatives(q, qd, tau)
    tangent_maps = np.stack([_tangent_map(dyn, q[k]) for k in range(len(q))])
    close(np.asarray(got[0]) @ tangent_maps, dq, 1e-11)
    close(got[1], dqd)
    close(got[2], dtau)
    if name == "panda":  # float32: the kernel's blocks in double, rounded once (the dot by
        # jacfwd's basis of ones and zeros is exact)
        low = [x.astype(np.float32) for x in (q, qd, tau)]
        got = jax.jit(jac)(*low)
        want = dyn.forward_dynamics_derivatives(*(x.astype(np.float64) for x in low))
        for g, w in zip(got, want):
            assert g.dtype == jnp.float32
            np.testing.assert_array_equal(np.asarray(g), w.astype(np.float32))


@pytest.mark.parametrize("name", ["panda", "anymal"])
def test_the_jvp_product_takes_any_tangents(name):
    """The FFI's JVP product (gagen.jax.product) against the callback target's (the
    kernel's blocks through gagen's stacked call, ∂q̈/∂q mapped by XLA, an einsum), for
    tangents that are not jacfwd's basis: a batch of n shared by every state that is not
    the identity (the shim's product in C: a permutation, random ones), a batch of another
    size (the dot), a tangent per state (the primitive over the batch); and jax.jacrev (its
    transpose) by a batch of cotangents."""
    dyn = model(name)
    ffi_fd, ref_fd = (functions(name, t)["forward_dynamics"] for t in ("ffi", "callback"))
    q, qd, tau = state(dyn, 11, rows=6)
    n = dyn.nq + 2 * dyn.nv
    rng = np.random.default_rng(5)

    def pushed(fd):
        def per_state(q, qd, tau, tangents):
            def jvp(t):
                parts = (t[:dyn.nq], t[dyn.nq: dyn.nq + dyn.nv], t[dyn.nq + dyn.nv:])
                return jax.jvp(fd, (q, qd, tau), parts)[1]
            return jax.vmap(jvp)(tangents)
        return jax.jit(jax.vmap(per_state, in_axes=(0, 0, 0, None)))

    for tangents in (np.eye(n)[rng.permutation(n)], rng.normal(size=(n, n)),
                     rng.normal(size=(5, n)), np.eye(n)):
        close(pushed(ffi_fd)(q, qd, tau, tangents), pushed(ref_fd)(q, qd, tau, tangents),
              1e-12)
    per_state = rng.normal(size=(6, n))

    def jvp(fd):
        def one(q, qd, tau, t):
            return jax.jvp(fd, (q, qd, tau), (t[:dyn.nq], t[dyn.nq: dyn.nq + dyn.nv],
                                              t[dyn.nq + dyn.nv:]))[1]
        return jax.jit(jax.vmap(one))

    close(jvp(ffi_fd)(q, qd, tau, per_state), jvp(ref_fd)(q, qd, tau, per_state), 1e-12)
    rev = [jax.jit(jax.vmap(jax.jacrev(fd, argnums=(0, 1, 2))))(q, qd, tau)
           for fd in (ffi_fd, ref_fd)]
    for got, want in zip(*rev):
        close(got, want, 1e-12)


@pytest.mark.parametrize("target", ["ffi", "callback"])
def test_float32_is_computed_in_double_and_rounded_once(target):
    dyn, f = model("panda"), functions("panda", target)
    q, qd, tau = (x.astype(np.float32) for x in state(dyn, 4, rows=16))
    got = f["forward_dynamics"](q, qd, tau)
    assert got.dtype == jnp.float32
    want = dyn.forward_dynamics(*(x.astype(np.float64) for x in (q, qd, tau)))
    np.testing.assert_array_equal(np.asarray(got), want.astype(np.float32))


# --- derivatives -------------------------------------------------------------------------------

def _derivative_cases(dyn, f, q, qd, tau, frame):
    """(label, JAX function of one argument, NumPy reference, point)."""
    fd, idyn = f["forward_dynamics"], f["inverse_dynamics"]
    return [
        ("fd/q", lambda x: fd(x, qd, tau), lambda x: dyn.forward_dynamics(x, qd, tau), q),
        ("fd/qd", lambda x: fd(q, x, tau), lambda x: dyn.forward_dynamics(q, x, tau), qd),
        ("fd/tau", lambda x: fd(q, qd, x), lambda x: dyn.forward_dynamics(q, qd, x), tau),
        ("id/q", lambda x: idyn(x, qd, tau), lambda x: dyn.inverse_dynamics(x, qd, tau), q),
        ("id/qd", lambda x: idyn(q, x, tau), lambda x: dyn.inverse_dynamics(q, x, tau), qd),
        ("id/qdd", lambda x: idyn(q, qd, x), lambda x: dyn.inverse_dynamics(q, qd, x), tau),
        ("M/q", lambda x: f["mass_matrix"](x), lambda x: dyn.mass_matrix(x), q),
        ("g/q", lambda x: f["gravity"](x), lambda x: dyn.gravity(x), q),
        ("F/q", lambda x: f["forcing"](x, qd, tau), lambda x: dyn.forcing(x, qd, tau), q),
        ("F/qd", lambda x: f["forcing"](q, x, tau), lambda x: dyn.forcing(q, x, tau), qd),
        ("T/q", lambda x: f["energy"](x, qd)[0], lambda x: dyn.energy(x, qd)[0], q),
        ("T/qd", lambda x: f["energy"](q, x)[0], lambda x: dyn.energy(q, x)[0], qd),
        ("V/q", lambda x: f["energy"](x, qd)[1], lambda x: dyn.energy(x, qd)[1], q),
        ("C/qd", lambda x: f["coriolis_matrix"](q, x), lambda x: dyn.coriolis_matrix(q, x),
         qd),
        ("pos/q", lambda x: f["frame_placement"](x, frame)[1],
         lambda x: dyn.frame_placement(x, frame)[1], q),
        ("R/q", lambda x: f["frame_placement"](x, frame)[0],
         lambda x: dyn.frame_placement(x, frame)[0], q),
        ("v/qd", lambda x: f["frame_velocity"](q, x, frame),
         lambda x: dyn.frame_velocity(q, x, frame), qd),
    ]


# the cases the other targets repeat (their rules are the same code; what differs is the
# evaluation under them)
SHARED_CASES = ("fd/q", "fd/tau", "id/qd", "M/q", "T/q", "pos/q")


# the other targets on the big robots: test_printed_* (slow)
@pytest.mark.parametrize("name, target", [("rrr", "ffi"), ("rrr", "callback"), ("rrr", "jax"),
                                          ("panda", "ffi"), ("anymal", "ffi")])
def test_jacfwd_and_jacrev_equal_central_differences(name, target):
    dyn, f = model(name), functions(name, target)
    q, qd, tau = state(dyn, 5)
    for label, fun, ref, x in _derivative_cases(dyn, f, q, qd, tau, FRAMES[name]):
        if target != "ffi" and label not in SHARED_CASES:
            continue
        want = central(ref, x)
        scale = max(1.0, float(np.max(np.abs(want))))
        for mode in (jax.jacfwd, jax.jacrev):
            got = np.asarray(jax.jit(mode(fun))(x))
            err = float(np.max(np.abs(got - want)))
            assert err <= 1e-6 * scale, f"{label} {mode.__name__}: {err:.3g} (scale {scale:.3g})"


# the printed programs of the big robots: test_printed_* (slow)
@pytest.mark.parametrize("name, target", [("rrr", "ffi"), ("rrr", "jax"), ("panda", "ffi"),
                                          ("anymal", "ffi")])
def test_the_jacobians_are_gagens_analytic_derivatives(name, target):
    dyn, f = model(name), functions(name, target)
    q, qd, tau = state(dyn, 6)
    fd = dyn.forward_dynamics_derivatives(q, qd, tau)
    tangent_map = _tangent_map(dyn, q)  # d/dv = d/dq G(q)
    for mode in (jax.jacfwd, jax.jacrev):
        got = jax.jit(mode(f["forward_dynamics"], argnums=(0, 1, 2)))(q, qd, tau)
        close(np.asarray(got[0]) @ tangent_map, fd[0], 1e-11)
        close(got[1], fd[1])
        close(got[2], fd[2])
        did = dyn.inverse_dynamics_derivatives(q, qd, tau)
        got = mode(f["inverse_dynamics"], argnums=(0, 1, 2))(q, qd, tau)
        close(np.asarray(got[0]) @ tangent_map, did[0], 1e-11)
        close(got[1], did[1])
        close(got[2], dyn.mass_matrix(q))
    # jax.grad of a scalar: the same derivative, transposed
    weights = np.linspace(-1, 1, dyn.nv)
    grad = jax.grad(lambda x: jnp.dot(weights, f["forward_dynamics"](q, x, tau)))(qd)
    close(grad, weights @ fd[1])


def _tangent_map(dyn, q, check=False):
    """G(q) = d(q ⊕ v)/dv at v = 0, written out: the identity for a fixed base; for the
    floating base the position moves by R(quat) v_lin and the quaternion (x, y, z, w) by
    ½ quat ⊗ (w, 0) (Pinocchio's integrate; the derivative kernels' tangent map, which
    takes q's quaternion as it is). Checked against central differences of dyn.integrate
    at a unit quaternion (integrate normalises)."""
    if dyn.nq == dyn.nv:
        return np.eye(dyn.nv)
    if not check:
        unit = q.copy()
        unit[3:7] /= np.linalg.norm(q[3:7])
        numeric = central(lambda v: dyn.integrate(unit, v), np.zeros(dyn.nv), 1e-7)
        assert np.max(np.abs(numeric - _tangent_map(dyn, unit, True))) < 1e-6
    G = np.zeros((dyn.nq, dyn.nv))
    G[7:, 6:] = np.eye(dyn.nv - 6)
    x, y, z, w = q[3:7] / np.linalg.norm(q[3:7])
    G[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    x, y, z, w = q[3:7]
    G[3:7, 3:6] = 0.5 * np.array([[w, -z, y], [z, w, -x], [-y, x, w], [-x, -y, -z]])
    return G


def test_grad_through_a_rollout_equals_central_differences():
    """A differentiable rollout: 20 explicit steps of forward dynamics under jax.lax.scan."""
    dyn, f = model("rrr"), functions("rrr", "ffi")
    q0, qd0, _ = state(dyn, 7)
    h = 0.01

    def rollout(tau):
        def step(x, _):
            q, qd = x
            qdd = f["forward_dynamics"](q, qd, tau)
            return (q + h * qd, qd + h * qdd), None
        (q, _), _ = jax.lax.scan(step, (q0, qd0), None, length=20)
        return jnp.sum(q * q)

    def numpy_rollout(tau):
        q, qd = q0.copy(), qd0.copy()
        for _ in range(20):
            q, qd = q + h * qd, qd + h * dyn.forward_dynamics(q, qd, tau)
        return np.sum(q * q)

    tau = np.array([1.0, 300.0, 80.0])
    got = jax.jit(jax.grad(rollout))(tau)
    want = central(numpy_rollout, tau, 1e-4)
    close(got, want, 1e-7)


# --- parameters --------------------------------------------------------------------------------

@pytest.mark.parametrize("target", ["ffi", "callback", "jax"])
def test_parameter_derivatives_through_the_regressor(target):
    dyn, f = model("rrr"), functions("rrr", target)
    q, qd, tau = state(dyn, 8)
    names = ["m3", "I2x", "m1"]
    base = np.array([dyn.parameters[k] for k in names])
    methods = (("forward_dynamics", (q, qd, tau)), ("inverse_dynamics", (q, qd, tau)),
               ("mass_matrix", (q,)), ("gravity", (q,)), ("forcing", (q, qd, tau)))
    for method, args in methods if target == "ffi" else methods[:2]:
        def fun(values, method=method, args=args):
            return f[method](*args, p=dict(zip(names, values)))

        def ref(values, method=method, args=args):
            return getattr(dyn, method)(*args, p=dict(zip(names, values)))

        want = central(ref, base, 1e-5)
        for mode in (jax.jacfwd, jax.jacrev):
            close(jax.jit(mode(fun))(base), want, 1e-8)
    # the whole parameter array, and regressor_parameters's own derivative
    pi = jax.jacfwd(lambda p: f["regressor_parameters"](p={"m3": p}))(50.0)
    close(pi, central(lambda p: dyn.regressor_parameters({"m3": p[0]}), np.array([50.0]))[:, 0],
          1e-8)


def test_kinematic_parameters_are_refused_on_the_compiled_path_and_differentiated_printed():
    dyn = model("rrr")
    assert gj.kinematic_parameters(dyn) == ["g", "L1", "L2"]
    q, qd, tau = state(dyn, 9)
    for target in ("ffi", "callback"):
        f = functions("rrr", target)
        with pytest.raises(ValueError, match="L1 is a kinematic parameter"):
            jax.jacfwd(lambda v, f=f: f["forward_dynamics"](q, qd, tau, p={"L1": v}))(0.4)
        with pytest.raises(ValueError, match="full parameter array"):
            jax.grad(lambda p, f=f: f["gravity"](q, p=p)[1])(dyn.parameter_vector())
        # passing one without differentiating it is fine
        f["forward_dynamics"](q, qd, tau, p={"L1": 0.5})
    f = functions("rrr", "jax")
    got = jax.jacfwd(lambda v: f["forward_dynamics"](q, qd, tau, p={"L1": v}))(0.4)
    want = central(lambda v: dyn.forward_dynamics(q, qd, tau, p={"L1": v[0]}), np.array([0.4]))
    close(got, want[:, 0], 1e-8)
    grad = jax.grad(lambda p: f["gravity"](q, p=p)[1])(jnp.asarray(dyn.parameter_vector()))
    close(grad, central(lambda p: dyn.gravity(q, p)[1], dyn.parameter_vector()), 1e-7)


# --- errors ------------------------------------------------------------------------------------

def test_what_has_no_derivative_says_so():
    dyn, f = model("rrr"), functions("rrr", "ffi")
    q, qd, _ = state(dyn, 10)
    with pytest.raises(NotImplementedError, match="frame_jacobian has no derivative"):
        jax.jacfwd(lambda x: f["frame_jacobian"](x, "link3"))(q)
    with pytest.raises(NotImplementedError, match="coriolis_matrix has no derivative with "
                                                  "respect to q"):
        jax.jacfwd(lambda x: f["coriolis_matrix"](x, qd))(q)
    # the printed target differentiates the program instead
    g = functions("rrr", "jax")
    got = jax.jacfwd(lambda x: g["frame_jacobian"](x, "link3"))(q)
    close(got, central(lambda x: dyn.frame_jacobian(x, "link3"), q), 1e-7)


def test_inputs_are_checked_as_gagens_calls_check_them():
    f = functions("rrr", "ffi")
    with pytest.raises(ValueError, match=r"q must have shape \(3,\) or \(\.\.\., 3\); got \(4,\)"):
        f["mass_matrix"](np.zeros(4))
    with pytest.raises(TypeError, match="q must be an array of numbers"):
        f["mass_matrix"]("abc")
    with pytest.raises(KeyError, match="unknown parameter 'nope'"):
        f["gravity"](np.zeros(3), p={"nope": 1.0})
    with pytest.raises(ValueError, match="p must have shape"):
        f["gravity"](np.zeros(3), p=np.zeros(2))
    with pytest.raises(KeyError, match="unknown frame"):
        f["frame_placement"](np.zeros(3), "nope")
    with pytest.raises(TypeError, match="takes q, qd, tau"):
        f["forward_dynamics"](np.zeros(3), np.zeros(3))


def test_a_singular_mass_matrix_is_an_error_not_a_crash():
    dyn, f = model("rrr"), functions("rrr", "ffi")
    zero_masses = {k: 0.0 for k in dyn.parameters if k[0] in "mI"}
    with pytest.raises(Exception, match="singular or not positive definite"):
        jax.block_until_ready(f["forward_dynamics"](np.zeros(3), np.zeros(3), np.zeros(3),
                                                    p=zero_masses))


def test_a_big_batch_runs_on_xla_s_threads_and_reports_its_first_failing_state():
    """A batch of many pieces (the shim splits it among XLA's CPU threads) gives the
    stacked call's numbers, in float64 and in float32 (computed in double, rounded once),
    and a failure names the batch's first failing state as a single loop would, whichever
    thread met it first."""
    dyn, f = model("panda"), functions("panda", "ffi")
    q, qd, tau = state(dyn, 5, rows=3000)
    fd = jax.jit(jax.vmap(f["forward_dynamics"]))
    want = dyn.forward_dynamics(q, qd, tau)
    np.testing.assert_array_equal(np.asarray(fd(q, qd, tau)), want)  # the same C, bit for bit
    got32 = np.asarray(fd(*(np.asarray(x, np.float32) for x in (q, qd, tau))))
    assert got32.dtype == np.float32
    np.testing.assert_array_equal(got32, dyn.forward_dynamics(
        *(np.asarray(x, np.float32).astype(np.float64) for x in (q, qd, tau))).astype(np.float32))
    P = np.tile(dyn.parameter_vector(), (len(q), 1))
    massless = [k for k, name in enumerate(dyn.parameters) if name.startswith(("m_", "I"))]
    P[np.ix_([2999, 1700, 1234], massless)] = 0.0  # M singular at these states
    with_p = jax.jit(jax.vmap(lambda a, b, c, pp: f["forward_dynamics"](a, b, c, p=pp)))
    with pytest.raises(Exception, match=r"singular .* \(state 1234 of the batch\)"):
        jax.block_until_ready(with_p(q, qd, tau, P))


def test_the_shim_refuses_a_model_it_does_not_know():
    """A computation that names a slot with another key (compiled in another process, or a
    forged call) gets an error from the handler, not another model's kernels."""
    from gagen.jax import ffi

    functions("rrr", "ffi")
    call = ffi._call_for(((3,),), "float64")
    with pytest.raises(Exception, match="has not registered"):
        jax.block_until_ready(call(np.zeros(3), model=np.int64(0), key=np.int64(12345),
                                   kernel=np.int32(5), frame=np.int32(-1),
                                   has_p=np.int32(0), floating=np.zeros(1, np.int64)))


@pytest.mark.parametrize("floating", [[1, 0, 0], [1], [2, 0, 0], [-1]])
def test_the_shim_refuses_floating_joints_that_do_not_fit_the_model(floating):
    """The floating joints' attribute (where the shim maps ∂q̈/∂v to ∂q̈/∂q) is checked
    against the model's sizes before any state is touched: one that would read or write
    out of bounds is an error, not a crash."""
    from gagen.jax import ffi
    from gagen.jax.registry import KERNELS

    dyn, f = model("rrr"), functions("rrr", "ffi")
    jax.block_until_ready(f["forward_dynamics"](np.zeros(3), np.zeros(3), np.zeros(3)))
    from gagen.jax.ops import FFIOps

    ops = FFIOps(dyn)
    slot, key = ops.table("derivatives")
    kernel = list(KERNELS).index("forward_dynamics_jacobian")
    call = ffi._call_for(((dyn.nv * (dyn.nq + 2 * dyn.nv),),), "float64")
    with pytest.raises(Exception, match="floating joints attribute"):
        jax.block_until_ready(call(np.zeros(3), np.zeros(3), np.zeros(3),
                                   model=np.int64(slot), key=np.int64(key),
                                   kernel=np.int32(kernel), frame=np.int32(-1),
                                   has_p=np.int32(0), floating=np.asarray(floating, np.int64)))


def test_a_cached_printed_module_loads_without_sympy(tmp_path):
    """The printed module is written into the cache by the first process (SymPy) and read by
    the next one without SymPy."""
    script = textwrap.dedent("""
        import sys, json, jax, numpy as np
        jax.config.update("jax_enable_x64", True)
        import gagen, gagen.jax
        dyn = gagen.load("rrr", cache_dir=sys.argv[1])
        f = gagen.jax.functions(dyn, target="jax", cache_dir=sys.argv[1])
        out = f["forward_dynamics"](np.ones(3), np.ones(3), np.ones(3))
        print(json.dumps({"sympy": "sympy" in sys.modules, "out": np.asarray(out).tolist()}))
    """)
    runs = [subprocess.run([sys.executable, "-c", script, str(tmp_path)], capture_output=True,
                           text=True, check=False, timeout=600) for _ in range(2)]
    for run in runs:
        assert run.returncode == 0, run.stderr
    import json

    first, second = (json.loads(r.stdout.splitlines()[-1]) for r in runs)
    assert second["sympy"] is False
    assert second["out"] == first["out"]


def _arithmetic(fn, *args) -> tuple[int, int]:
    """(operations XLA runs, operations printed) of jax.jit(fn) at args."""
    lowered = jax.jit(fn).lower(*args)
    arithmetic = ("multiply", "add", "subtract", "negate", "divide", "sine", "cosine")
    printed = sum(len(re.findall(rf"stablehlo\.{op}\b", lowered.as_text())) for op in arithmetic)
    compiled = lowered.compile().as_text()
    ran = sum(len(re.findall(rf"= f64\[[\d,]*\]\S* {op}\(", compiled)) for op in arithmetic)
    return ran, printed


def test_xla_duplicates_little_of_a_printed_program():
    """XLA's CPU fusion inlines a cheap value into every reader; the printer keeps a value
    whose duplication would cost more than a few operations in an array of its own (x / 1.0).
    The compiled program's arithmetic is within 1.5x of the printed one's (every value
    inlined: 1.74x on this program; twentyfold on the Panda's). The angles' sines and
    cosines (gagen.jax.trig: both branches of its check, the sine and cosine loops each
    with their polynomials) are counted apart."""
    from gagen.jax.trig import sincos_stacked

    dyn, f = model("rrr"), functions("rrr", "jax")
    q, qd, qdd = state(dyn, 3, rows=8)
    ran, printed = _arithmetic(f["inverse_dynamics_derivatives"], q, qd, qdd)
    trig_ran, trig_printed = _arithmetic(
        lambda q: sincos_stacked(tuple(q[..., k] for k in range(dyn.nq))), q)
    ran, printed = ran - trig_ran, printed - trig_printed
    assert printed > 100
    assert ran <= 1.5 * printed, (ran, printed)


def test_xla_keeps_the_solves_of_the_printed_derivatives():
    """The derivatives' LDLᵀ factors, q̈ and the solves by rows keep their entries in arrays
    of their own (gagen.jax.linalg.kept): XLA ran 3.3x the printed arithmetic of the
    Panda's forward-dynamics derivatives without them (every chain of updates copied into
    each later step), 1.3x with them."""
    dyn, f = model("panda"), functions("panda", "jax")
    q, qd, tau = state(dyn, 3, rows=8)
    ran, printed = _arithmetic(f["forward_dynamics_derivatives"], q, qd, tau)
    assert printed > 1000
    assert ran <= 1.5 * printed, (ran, printed)


def test_xla_writes_a_chains_forward_dynamics_from_kept_values():
    """Along a chain the tree solve divides by 1 + 0 q₀ (gagen.jax.printer._tree_unit): with
    the optimization barrier's 1.0 instead, XLA fused the whole back substitution into the
    loop that writes q̈, a concatenation that evaluates each entry's chain apart (the Panda
    arm's printed forward dynamics 25 % slower). That loop reads the kept entries: 14
    operations on chain:6, 171 with the barrier."""
    from gagen.jax.printed import printed_module

    dyn, f = model("chain:6"), functions("chain:6", "jax")
    with open(printed_module(dyn, "dynamics").__file__) as file:
        assert "_linalg.solve_tree(M, F, PARENTS, " in file.read()
    q, qd, tau = state(dyn, 3, rows=8)
    compiled = jax.jit(f["forward_dynamics"]).lower(q, qd, tau).compile().as_text()
    entry = compiled[compiled.index("ENTRY"):]
    root = re.search(r"ROOT \S+ = \S+ fusion\([^)]*\), kind=\w+, calls=%?([\w.\-]+)", entry)
    assert root, "the result is not written by a fusion"
    body = re.search(r"\n%?" + re.escape(root.group(1)) + r" [^\n]*\{\n(.*?)\n\}", compiled,
                     re.DOTALL).group(1)
    operations = len(re.findall(r" (multiply|add|subtract|divide|negate)\(", body))
    assert operations <= 3 * dyn.nv, operations


# --- the printed programs' sines and cosines (gagen.jax.trig) -------------------------------

def _ulps(got, want):
    """|got − want| in units of want's last place (0 where both are equal, NaN included)."""
    got, want = np.asarray(got), np.asarray(want)
    same = (got == want) | (np.isnan(got) & np.isnan(want))
    return np.where(same, 0.0, np.abs(got - want) / np.spacing(np.abs(want)))


def _trig_points():
    rng = np.random.default_rng(29)
    return np.concatenate([
        rng.uniform(-4.0, 4.0, 300_000),  # joint angles
        rng.uniform(-1e5, 1e5, 400_000),
        np.exp(rng.uniform(np.log(1e-300), np.log(1e5), 100_000)) * rng.choice([-1, 1], 100_000),
        # at and next to the multiples of π/2, where the reduction cancels (its 2nd, 3rd rounds)
        np.round(rng.uniform(-6e4, 6e4, 100_000)) * (np.pi / 2),
        np.nextafter(np.round(rng.uniform(-6e4, 6e4, 50_000)) * (np.pi / 2), np.inf),
        np.nextafter(np.round(rng.uniform(-6e4, 6e4, 50_000)) * (np.pi / 2), -np.inf),
        # every quadrant, both signs
        np.arange(-40, 41)[:, None] * (np.pi / 2) + np.array([-0.7, -0.3, 0.0, 0.3, 0.7]),
    ], axis=None)


def test_sincos_is_within_one_ulp_of_numpy_below_its_bound():
    """A million points below 2^20 (joint angles, |x| < 1e5, tiny ones, the multiples of π/2
    and their neighbours, every quadrant): the fast path within 1 ulp of NumPy's sin and cos
    (both within about half an ulp of the exact value: at most 1 apart)."""
    from gagen.jax import trig

    x = _trig_points()
    assert len(x) >= 1_000_000 and np.max(np.abs(x)) < trig.BOUND
    s, c = jax.jit(trig.sincos)(jnp.asarray(x))
    assert np.max(_ulps(s, np.sin(x))) <= 1.0
    assert np.max(_ulps(c, np.cos(x))) <= 1.0
    fs, fc = jax.jit(trig.sincos_fast)(jnp.asarray(x))  # the same numbers as the checked call
    np.testing.assert_array_equal(fs, s)
    np.testing.assert_array_equal(fc, c)


def test_sincos_quadrants_and_signs():
    """The quadrant chosen right: sin and cos of k π/2 + y against NumPy for k = -40 … 40,
    including k π/2 itself (0 or ±1 up to the reduction's rounding); sin(±0) = ±0."""
    from gagen.jax import trig

    k = np.arange(-40, 41)
    for y in (0.0, 0.25, -0.25, 0.75, -0.75):
        x = k * (np.pi / 2) + y
        s, c = trig.sincos(jnp.asarray(x))
        if y:
            assert np.max(_ulps(s, np.sin(x))) <= 1.0 and np.max(_ulps(c, np.cos(x))) <= 1.0
        else:  # sin(k π/2) and cos(k π/2) of the double nearest k π/2: 0 up to ~1e-16 k, ±1
            assert np.max(np.abs(s - np.sin(x))) <= 1e-16 * np.max(np.abs(x))
            assert np.max(np.abs(c - np.cos(x))) <= 1e-16 * np.max(np.abs(x))
    s, c = trig.sincos(jnp.asarray([0.0, -0.0]))
    assert list(np.signbit(s)) == [False, True] and list(np.asarray(c)) == [1.0, 1.0]


def test_sincos_hardest_reductions_are_within_one_ulp_of_the_exact_value():
    """The doubles nearest the multiples of π/2 and the hardest ones to reduce in each binade
    below 2^20 (those of tests/test_fast_trig.py, which need the reduction's second and third
    rounds): within 1 ulp of sin and cos computed by mpmath."""
    mpmath = pytest.importorskip("mpmath")
    from test_fast_trig import hardest_reductions, near_multiples_of_pi_2

    from gagen.jax import trig

    hardest = hardest_reductions()
    x = np.concatenate([hardest, near_multiples_of_pi_2(300)])
    s, c = jax.jit(trig.sincos)(jnp.asarray(x))
    with mpmath.workprec(300):
        exact_s = np.array([float(mpmath.sin(mpmath.mpf(v))) for v in x.tolist()])
        exact_c = np.array([float(mpmath.cos(mpmath.mpf(v))) for v in x.tolist()])
    assert np.max(_ulps(s, exact_s)) <= 1.0
    assert np.max(_ulps(c, exact_c)) <= 1.0
    # the hardest are correctly rounded (without the third round: 1 ulp off, sin's)
    assert np.max(_ulps(s[:len(hardest)], exact_s[:len(hardest)])) == 0.0


@pytest.mark.parametrize("vmapped", [False, True])
@pytest.mark.parametrize("special", [2.0 ** 20, -3e6, 1e22, -1e300, np.inf, -np.inf, np.nan])
def test_sincos_beyond_its_bound_is_jnp_sin(special, vmapped):
    """A batch holding an angle not below 2^20, inf or NaN takes jnp.sin and jnp.cos for
    those (NaN for inf and NaN, as jnp.sin), the fast path for the rest: under jax.vmap too
    (the check is over the whole batch)."""
    from gagen.jax import trig

    big = np.array([special, 1.5 * special])
    x = jnp.asarray(np.concatenate([big, [0.5, -2.0, 1e5]]))
    f = jax.jit(jax.vmap(trig.sincos) if vmapped else trig.sincos)
    s, c = f(x)
    np.testing.assert_array_equal(s[:len(big)], jnp.sin(x[:len(big)]))
    np.testing.assert_array_equal(c[:len(big)], jnp.cos(x[:len(big)]))
    assert np.max(_ulps(s[len(big):], np.sin(x[len(big):]))) <= 1.0
    assert np.max(_ulps(c[len(big):], np.cos(x[len(big):]))) <= 1.0


def test_sincos_derivatives_and_batches():
    """jax.grad, jacfwd and vmap of sincos_stacked: (cos, −sin) exactly, stacked results equal
    one at a time, angles of different batches (one batched, one not) under vmap."""
    from gagen.jax import trig

    x = np.linspace(-7.0, 7.0, 29)
    g = jax.jit(jax.vmap(jax.grad(lambda a: trig.sincos(a)[0])))(jnp.asarray(x))
    np.testing.assert_array_equal(g, trig.sincos(jnp.asarray(x))[1])
    jac = jax.jacfwd(lambda a: jnp.stack(trig.sincos_stacked((a[0], a[1]))))(jnp.asarray([0.3, 2.0]))
    s, c = np.asarray(trig.sincos(jnp.asarray([0.3, 2.0])))
    np.testing.assert_array_equal(jac, [[c[0], 0], [-s[0], 0], [0, c[1]], [0, -s[1]]])
    out = jax.vmap(lambda a, b: jnp.stack(trig.sincos_stacked((a, b))), in_axes=(0, None))(
        jnp.asarray(x), 2.0)
    np.testing.assert_array_equal(out[:, 0], trig.sincos(jnp.asarray(x))[0])
    np.testing.assert_array_equal(out[:, 3], np.broadcast_to(c[1], x.shape))


def test_the_printed_module_holds_only_checked_names_and_numbers():
    """Nothing of the description reaches the printed module as text: a model whose names
    are hostile prints names of the printer's own (q3, p7, t12) only."""
    from gagen.jax.printed import printed_module

    dyn = gagen.load("rrr")
    with open(printed_module(dyn, "dynamics").__file__) as file:
        text = file.read()
    for name in list(dyn.parameters) + dyn.coordinates + dyn.frames:
        if len(name) > 3:
            assert name not in text


# --- the printed programs of the big robots ---------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("name", ["panda", "anymal"])
def test_printed_functions_equal_the_c_on_the_big_robots(name):
    dyn, f = model(name), functions(name, "jax")
    q, qd, tau = state(dyn, 11, rows=8)
    for method in ("forward_dynamics", "inverse_dynamics", "mass_matrix", "gravity", "forcing",
                   "energy", "frame_placement", "frame_jacobian", "regressor_parameters"):
        args, frame = arguments(name, method, (q, qd, tau))
        extra = (frame,) if frame else ()
        assert_results(jax.jit(lambda *a, m=method, e=extra: f[m](*a, *e))(*args),
                       reference(dyn, method, args, frame))
    fd = jax.jit(f["forward_dynamics_derivatives"])(q, qd, tau)
    assert_results(tuple(fd), dyn.forward_dynamics_derivatives(q, qd, tau))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["panda", "anymal"])
def test_printed_jacobians_equal_gagens_analytic_derivatives(name):
    dyn, f = model(name), functions(name, "jax")
    q, qd, tau = state(dyn, 12)
    fd = dyn.forward_dynamics_derivatives(q, qd, tau)
    got = jax.jit(jax.jacfwd(f["forward_dynamics"], argnums=(0, 1, 2)))(q, qd, tau)
    close(np.asarray(got[0]) @ _tangent_map(dyn, q), fd[0], 1e-11)
    close(got[1], fd[1])
    close(got[2], fd[2])
