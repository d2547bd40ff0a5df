"""gagen.casadi: the compiled dynamics as CasADi functions with gagen's analytic Jacobians.

Values and Jacobians of every function against gagen's own calls (the derivative kernels,
the frame functions) at random states, called with SX and with MX symbols, on the paper's
robot, a floating robot and a fixed-base arm; CasADi's jacobian() against central
differences in q's own entries (a quaternion off the unit sphere too); the parameters'
Jacobians; Function.map against the stacked call; second derivatives; a Function.generate'd
C program that calls the library; the exported library loaded by casadi.external in a
fresh process that never imports gagen."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_URDF

import gagen

ca = pytest.importorskip("casadi", reason="gagen.casadi needs casadi (pip install gagen[casadi])")
gc = pytest.importorskip("gagen.casadi")

TIGHT = 1e-12   # against gagen's own calls (relative to the outputs' scale)
DIFFERENCES = 1e-6  # against central differences
REPO = Path(__file__).resolve().parents[1]

def random_tree():
    """Two branches from the world, revolute and prismatic joints (a prismatic one below a
    revolute one), a fixed joint, rotated origins and odd axes; lengths and mass centres as
    parameters."""
    from random_trees import random_model

    return random_model(np.random.default_rng(2), 6, symbolic=True)


# the paper's robot; a floating robot (the double pendulum's root moves freely: 7 + 2 entries
# of q, 8 velocities); a fixed-base arm (SO-100, 6 joints); a branching random tree with
# prismatic joints
MODELS = {
    "rrr": lambda: "rrr",
    "floating": lambda: str(SHARED_URDF / "double_pendulum.urdf"),
    "arm": lambda: str(SHARED_URDF / "so100.urdf"),
    "tree": random_tree,
    # slow: the Panda (its prismatic fingers too) and ANYmal C (floating, 18 velocities)
    "panda": lambda: str(SHARED_URDF / "panda.urdf"),
    "anymal": lambda: str(SHARED_URDF / "anymal_c.urdf"),
}
SLOW = ("panda", "anymal")


@pytest.fixture(scope="module", params=[pytest.param(name, marks=pytest.mark.slow)
                                        if name in SLOW else name for name in MODELS])
def model(request, cache_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)  # ANYmal's CAD round-off
        dyn = gagen.load(MODELS[request.param](),
                         floating_base=request.param in ("floating", "anymal"),
                         derivatives=True)
    frames = dyn.frames
    return dyn, gc.functions(dyn), gc.functions(dyn, parameters=True), frames


def states(dyn, count: int = 3, seed: int = 0):
    """Random (q, qd, u): q from the neutral configuration along a random velocity."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        q = dyn.integrate(dyn.neutral(), rng.uniform(-1, 1, dyn.nv))
        out.append((q, rng.uniform(-1, 1, dyn.nv), rng.uniform(-1, 1, dyn.nv)))
    return out


def tangent_map(dyn, q) -> np.ndarray:
    """G(q) = d(q (+) v)/dv at v = 0 (nq x nv), written here from the manifold's formulas:
    a floating joint's position moves by R v, its quaternion by 1/2 quat (x) (w, 0)."""
    from gagen.casadi.generate import plain_coordinates
    from gagen.runtime.manifold import rotation

    G = np.zeros((dyn.nq, dyn.nv))
    for iq, iv in plain_coordinates(dyn.info):
        G[iq, iv] = 1.0
    for iq, iv in dyn.info.floating_joints():
        x, y, z, w = q[iq + 3: iq + 7]
        G[iq: iq + 3, iv: iv + 3] = rotation(q[iq + 3: iq + 7])
        rates = np.array([[w, z, -y, -x], [-z, w, x, -y], [y, -x, w, -z]]).T
        G[iq + 3: iq + 7, iv + 3: iv + 6] = 0.5 * rates
    return G


def call(function, args) -> list[np.ndarray]:
    """A CasADi function's outputs at numeric inputs, as NumPy arrays."""
    return [np.array(r.full()) for r in function.call([ca.DM(np.asarray(a, dtype=float))
                                                       for a in args])]


def close(actual, expected, what: str, rtol: float = TIGHT) -> None:
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != {expected.shape}"
    scale = max(1.0, float(np.abs(expected).max(initial=0.0)))
    error = float(np.abs(actual - expected).max(initial=0.0))
    assert error <= rtol * scale, f"{what}: error {error:.3g} (scale {scale:.3g})"


def casadi_layout(M: np.ndarray) -> np.ndarray:
    """A matrix output's entries in CasADi's order (column-major)."""
    return np.asarray(M).reshape(M.shape[0], -1).T.ravel() if np.ndim(M) == 2 else M


# --- gagen's own calls, per function: values and (tangent) Jacobians -------------------------

def reference(dyn, name: str, q, qd, u, frame=None):
    """(outputs, {input: d outputs / d input along the velocity directions, or None where
    gagen has no derivative kernel}) of gagen's own calls; outputs as CasADi orders them."""
    n = dyn.nv
    if name == "forward_dynamics":
        dq, dqd, dtau = dyn.forward_dynamics_derivatives(q, qd, u)
        return [dyn.forward_dynamics(q, qd, u)], {"q": [dq], "qd": [dqd], "tau": [dtau]}
    if name == "inverse_dynamics":
        dq, dqd = dyn.inverse_dynamics_derivatives(q, qd, u)
        return [dyn.inverse_dynamics(q, qd, u)], {"q": [dq], "qd": [dqd],
                                                  "qdd": [dyn.mass_matrix(q)]}
    if name == "gravity":
        dq, _ = dyn.inverse_dynamics_derivatives(q, np.zeros(n), np.zeros(n))
        return [dyn.gravity(q)], {"q": [dq]}
    if name == "mass_matrix":
        return [casadi_layout(dyn.mass_matrix(q))], {"q": None}
    if name == "coriolis_matrix":
        by_qd = np.stack([casadi_layout(dyn.coriolis_matrix(q, e)) for e in np.eye(n)], axis=1)
        return [casadi_layout(dyn.coriolis_matrix(q, qd))], {"q": None, "qd": [by_qd]}
    if name == "frame_placement":
        R, pos = dyn.frame_placement(q, frame)
        return [casadi_layout(R), pos], {"q": None}
    if name == "frame_jacobian":
        return [casadi_layout(dyn.frame_jacobian(q, frame))], {"q": None}
    if name == "frame_velocity":
        return [dyn.frame_velocity(q, qd, frame)], {"q": None,
                                                    "qd": [dyn.frame_jacobian(q, frame)]}
    # the centre of mass and centroidal functions, where the model's C has them: their
    # derivatives from the model's centroidal derivative kernels, called as C
    if name == "center_of_mass":
        return [dyn.center_of_mass(q)], {"q": [dyn.com_jacobian(q)]}
    if name == "com_velocity":
        dv_dq, = centroidal_kernel(dyn, "com_velocity_derivatives", q, qd)
        return [dyn.com_velocity(q, qd)], {"q": [dv_dq], "qd": [dyn.com_jacobian(q)]}
    if name == "centroidal_momentum":
        dh_dq, = centroidal_kernel(dyn, "centroidal_momentum_derivatives", q, qd)
        return [dyn.centroidal_momentum(q, qd)], {"q": [dh_dq], "qd": [dyn.centroidal_map(q)]}
    if name in CENTROIDAL_MATRICES:
        blocks = centroidal_kernel(dyn, CENTROIDAL_KERNELS[name], q, qd)
        return [casadi_layout(np.asarray(CENTROIDAL_MATRICES[name](dyn, q, qd)))], dict(
            zip(("q", "qd"), ([casadi_rows(b)] for b in blocks)))
    # task space: by qdd the frame Jacobian, the rest by central differences only
    if name == "frame_acceleration":
        return [dyn.frame_acceleration(q, qd, u, frame)], {
            "q": None, "qd": None, "qdd": [dyn.frame_jacobian(q, frame)]}
    if name in TASK_SPACE:
        return [casadi_layout(np.asarray(TASK_SPACE[name](dyn, q, qd, u, frame)))], {
            port: None for port in ("q", "qd")}
    raise KeyError(name)


# gagen's own task-space calls (LOCAL_WORLD_ALIGNED, classical), by name
TASK_SPACE = {
    "frame_acceleration":
        lambda dyn, q, qd, u, frame, p=None: dyn.frame_acceleration(q, qd, u, frame, p=p),
    "frame_bias_acceleration":
        lambda dyn, q, qd, u, frame, p=None: dyn.frame_bias_acceleration(q, qd, frame, p=p),
    "frame_jacobian_time_variation":
        lambda dyn, q, qd, u, frame, p=None: dyn.frame_jacobian_time_variation(q, qd, frame,
                                                                               p=p),
    "delassus": lambda dyn, q, qd, u, frame, p=None: dyn.delassus(q, [frame], p=p),
}


def centroidal_kernel(dyn, name: str, q, qd) -> list[np.ndarray]:
    """The outputs of the model's centroidal derivative kernel <model>_<name>."""
    from test_centroidal_derivatives import kernel

    return kernel(dyn, name)(q, qd)


def casadi_rows(D: np.ndarray) -> np.ndarray:
    """A derivative (rows, nv) of a vector, or (rows, cols, nv) of a matrix (rows x cols,
    row-major) as CasADi's Jacobian block: one row per entry in column-major order."""
    return D if D.ndim == 2 else D.transpose(1, 0, 2).reshape(-1, D.shape[-1])


# gagen's own calls of the centroidal matrix functions, and the kernel of their derivatives
# (by q; by q and qd for those of qd)
CENTROIDAL_KERNELS = {
    "com_jacobian": "com_jacobian_derivatives",
    "centroidal_map": "centroidal_map_derivatives",
    "centroidal_map_time_variation": "centroidal_map_time_variation_derivatives",
    "centroidal_bias": "centroidal_bias_derivatives",
}
CENTROIDAL_MATRICES = {
    "com_jacobian": lambda dyn, q, qd, p=None: dyn.com_jacobian(q, p),
    "centroidal_map": lambda dyn, q, qd, p=None: dyn.centroidal_map(q, p),
    "centroidal_map_time_variation":
        lambda dyn, q, qd, p=None: dyn.centroidal_map_time_variation(q, qd, p),
    "centroidal_bias": lambda dyn, q, qd, p=None: dyn.centroidal_bias(q, qd, p),
}


def gagen_outputs(dyn, name, q, qd, u, frame, p=None):
    """gagen's outputs (CasADi's order, flattened and joined) at q, qd, u and p."""
    outs, _ = reference_at(dyn, name, q, qd, u, frame, p)
    return np.concatenate([np.ravel(o) for o in outs])


def reference_at(dyn, name, q, qd, u, frame, p):
    if p is None:
        return reference(dyn, name, q, qd, u, frame)
    n = dyn.nv
    calls = {
        "forward_dynamics": lambda: [dyn.forward_dynamics(q, qd, u, p)],
        "inverse_dynamics": lambda: [dyn.inverse_dynamics(q, qd, u, p)],
        "gravity": lambda: [dyn.gravity(q, p)],
        "mass_matrix": lambda: [casadi_layout(dyn.mass_matrix(q, p))],
        "coriolis_matrix": lambda: [casadi_layout(dyn.coriolis_matrix(q, qd, p))],
        "frame_placement": lambda: [casadi_layout(dyn.frame_placement(q, frame, p=p)[0]),
                                    dyn.frame_placement(q, frame, p=p)[1]],
        "frame_jacobian": lambda: [casadi_layout(dyn.frame_jacobian(q, frame, p=p))],
        "frame_velocity": lambda: [dyn.frame_velocity(q, qd, frame, p=p)],
        "center_of_mass": lambda: [dyn.center_of_mass(q, p)],
        "com_velocity": lambda: [dyn.com_velocity(q, qd, p)],
        "centroidal_momentum": lambda: [dyn.centroidal_momentum(q, qd, p)],
        **{key: (lambda key=key: [casadi_layout(np.asarray(
            CENTROIDAL_MATRICES[key](dyn, q, qd, p)))]) for key in CENTROIDAL_MATRICES},
        **{key: (lambda key=key: [casadi_layout(np.asarray(
            TASK_SPACE[key](dyn, q, qd, u, frame, p)))]) for key in TASK_SPACE},
    }
    del n
    return calls[name](), None


def arguments(function, q, qd, u, frame, p=None) -> list:
    """The function's inputs by name."""
    values = {"q": q, "qd": qd, "tau": u, "qdd": u, "frame": frame, "p": p}
    return [values[function.name_in(i)] for i in range(function.n_in())]


def symbolic(function, kind):
    """(symbols, Function of the same inputs calling `function` on them: SX or MX)."""
    sym = ca.SX.sym if kind == "SX" else ca.MX.sym
    symbols = [sym(function.name_in(i), function.sparsity_in(i)) for i in range(function.n_in())]
    outs = function(*symbols)
    outs = list(outs) if isinstance(outs, (list, tuple)) else [outs]
    return symbols, outs


def frames_of(dyn, frames):
    """Every frame of a small model; a spread of them otherwise, and the last link's."""
    if len(frames) <= 14:
        return list(range(len(frames)))
    return sorted(set(range(0, len(frames), 3)) | {dyn.info.frames.index(max(
        dyn.info.frames, key=lambda f: f[1]))})


@pytest.mark.parametrize("kind", ["SX", "MX"])
def test_values_and_jacobians_equal_gagen_s_own_calls(model, kind):
    dyn, fns, _, frames = model
    for name, function in fns.items():
        symbols, outs = symbolic(function, kind)
        joined = ca.vertcat(*[ca.vec(o) for o in outs])
        ports = [function.name_in(i) for i in range(function.n_in())]
        differentiable = [s for s, port in zip(symbols, ports) if port != "frame"]
        jac = ca.Function("jacobian", symbols, [ca.jacobian(joined, s) for s in differentiable])
        value = ca.Function("value", symbols, [joined])
        for frame in (frames_of(dyn, frames) if "frame" in ports else [None]):
            for q, qd, u in states(dyn):
                args = arguments(function, q, qd, u, frame)
                expected, derivatives = reference(dyn, name, q, qd, u, frame)
                what = f"{name}({kind}) frame {frame}"
                close(np.ravel(call(value, args)[0]),
                      np.concatenate([np.ravel(e) for e in expected]), what)
                blocks = dict(zip([p for p in ports if p != "frame"], call(jac, args)))
                G = tangent_map(dyn, q)
                for port, reference_blocks in derivatives.items():
                    if reference_blocks is None:
                        continue
                    block = blocks[port] @ G if port == "q" else blocks[port]
                    close(block, np.vstack([np.reshape(b, (-1, dyn.nv))
                                            for b in reference_blocks]), f"d{what}/d{port}")


def central(f, x: np.ndarray, steps=None) -> np.ndarray:
    """Five-point central differences of f (array -> flat array) by x's entries, with
    steps 1e-3 max(1, |x|) unless given: error h^4 f^(5) and eps |f| / h, both far below
    the tests' 1e-6 (the light SO-100's accelerations are 1e4 times their derivatives by
    some parameters: a two-point difference small enough to be exact is all round-off)."""
    x = np.asarray(x, dtype=float)
    steps = 1e-3 * np.maximum(1.0, np.abs(x)) if steps is None else steps
    columns = []
    for k, h in enumerate(steps):
        def at(s, k=k):
            y = x.copy()
            y[k] += s
            return f(y)
        columns.append((-at(2 * h) + 8 * at(h) - 8 * at(-h) + at(-2 * h)) / (12 * h))
    return np.stack(columns, axis=-1)


def test_casadi_jacobians_match_central_differences(model):
    """casadi.jacobian of every function (q's own entries, with a quaternion off the unit
    sphere for the floating robot) against central differences of gagen's own functions."""
    dyn, fns, _, frames = model
    for name, function in fns.items():
        symbols, outs = symbolic(function, "MX")
        ports = [function.name_in(i) for i in range(function.n_in())]
        joined = ca.vertcat(*[ca.vec(o) for o in outs])
        jac = ca.Function("jacobian", symbols, [ca.jacobian(joined, s)
                                           for s, port in zip(symbols, ports) if port != "frame"])
        cases = [(frame, state) for frame in (frames_of(dyn, frames) if "frame" in ports
                                              else [None])
                 for state in states(dyn, 2, seed=3)]
        for frame, (q, qd, u) in cases:
            for iq, _ in dyn.info.floating_joints():
                q[iq + 3: iq + 7] *= 1.3  # the functions normalise the quaternion
            values = {"q": q, "qd": qd, "u": u}
            blocks = call(jac, arguments(function, q, qd, u, frame))
            for port, block in zip([p for p in ports if p != "frame"], blocks):
                key = "u" if port in ("tau", "qdd") else port

                def f(x, key=key, values=values, name=name, frame=frame):
                    args = dict(values, **{key: x})
                    return gagen_outputs(dyn, name, args["q"], args["qd"], args["u"], frame)
                close(block, central(f, values[key]), f"d{name}/d{port}", DIFFERENCES)


def test_parameter_jacobians_match_central_differences(model):
    """The `_p` functions: values at other parameters (heavier bodies, weaker gravity), and
    the Jacobian by p (gagen.casadi.table's methods per parameter class; the exact checks
    are tests/test_casadi_params.py's) against central differences of gagen's functions in
    p; forward dynamics' as
    -M^-1 dtau/dp with dtau/dp so differenced (its own differences are ill-conditioned)."""
    dyn, _, fns, frames = model
    names = list(dyn.parameters)
    p = dyn.parameter_vector({name: value * (0.9 if name == "g" else 1.1)
                              for name, value in dyn.parameters.items()
                              if name == "g" or re.match(r"m(_|\d)", name)})
    (q, qd, u), = states(dyn, 1, seed=7)
    acc = dyn.forward_dynamics(q, qd, u, p)
    dtau_dp = central(lambda x: dyn.inverse_dynamics(q, qd, acc, x), p)
    for name, function in fns.items():
        symbols, outs = symbolic(function, "SX")
        joined = ca.vertcat(*[ca.vec(o) for o in outs])
        frame = len(frames) - 1 if "frame" in [function.name_in(i)
                                               for i in range(function.n_in())] else None
        fn = ca.Function("f", symbols, [joined, ca.jacobian(joined, symbols[-1])])
        value, block = call(fn, arguments(function, q, qd, u, frame, p))
        close(np.ravel(value), gagen_outputs(dyn, name, q, qd, u, frame, p), f"{name}(p)")
        if name == "forward_dynamics":
            Minv = dyn.forward_dynamics_derivatives(q, qd, u, p)[2]
            expected = -Minv @ dtau_dp
        else:
            # G factorises M, which refuses a light link's inertia stepped below zero: steps
            # relative to each parameter for it
            steps = (1e-4 * np.maximum(np.abs(p), 1e-4) if name == "delassus"
                     else None)
            expected = central(lambda x, name=name, frame=frame:
                               gagen_outputs(dyn, name, q, qd, u, frame, x), p, steps)
        close(block, expected, f"d{name}/dp", DIFFERENCES)
    assert len(names) == len(p)


def test_the_frame_functions_of_named_frames(model):
    dyn, _, _, frames = model
    frame = frames[-1]
    fns = gc.functions(dyn, [f"frame_jacobian:{frame}", "frame_placement"])
    assert list(fns) == [f"frame_jacobian:{frame}", "frame_placement"]
    (q, _, _), = states(dyn, 1)
    close(call(fns[f"frame_jacobian:{frame}"], [q])[0], dyn.frame_jacobian(q, frame), frame)
    with pytest.raises(ValueError, match="unknown CasADi function 'frame_jacobian:nowhere'"):
        gc.functions(dyn, ["frame_jacobian:nowhere"])
    with pytest.raises(ValueError, match="unknown CasADi function 'mass_matrix:"):
        gc.functions(dyn, [f"mass_matrix:{frame}"])
    # a frame number that is not one fails the call (CasADi's error), never reads elsewhere
    for bad in (-1, len(frames), 0.5, float("nan")):
        with pytest.raises(RuntimeError):
            call(fns["frame_placement"], [q, bad])


def test_fixed_parameters_are_honoured(model):
    dyn, *_ = model
    p = dyn.parameter_vector() * 1.05
    fns = gc.functions(dyn, ["inverse_dynamics"], p=p)
    (q, qd, qdd), = states(dyn, 1)
    f = fns["inverse_dynamics"]
    assert f.n_in() == 3
    close(np.ravel(call(f, [q, qd, qdd])[0]), dyn.inverse_dynamics(q, qd, qdd, p),
          "inverse_dynamics(p)")
    J = ca.Function("J", [s := ca.SX.sym("qdd", dyn.nv)], [ca.jacobian(f(q, qd, s), s)])
    close(call(J, [qdd])[0], dyn.mass_matrix(q, p), "M(p)")


def test_map_equals_the_stacked_call(model):
    dyn, fns, _, _ = model
    N = 7
    rng = np.random.default_rng(2)
    q = dyn.integrate(np.tile(dyn.neutral(), (N, 1)), rng.uniform(-1, 1, (N, dyn.nv)))
    qd, tau = rng.uniform(-1, 1, (2, N, dyn.nv))
    fd = fns["forward_dynamics"]
    for mode in ("serial", "thread"):
        mapped = fd.map(N, mode, 2) if mode == "thread" else fd.map(N)
        np.testing.assert_array_equal(call(mapped, [q.T, qd.T, tau.T])[0].T,
                                      dyn.forward_dynamics(q, qd, tau))
    # and the Jacobian of the mapped function, state by state
    Q, QD, T = (ca.MX.sym(n, dyn.nq if n == "q" else dyn.nv, N) for n in ("q", "qd", "tau"))
    out = fd.map(N)(Q, QD, T)
    jac = ca.Function("j", [Q, QD, T], [ca.jacobian(ca.vec(out), ca.vec(T))])
    J = call(jac, [q.T, qd.T, tau.T])[0]
    Minv = dyn.forward_dynamics_derivatives(q, qd, tau)[2]
    for k in range(N):
        close(J[k * dyn.nv:(k + 1) * dyn.nv, k * dyn.nv:(k + 1) * dyn.nv], Minv[k], "map jac")


def test_second_derivatives_are_differences_of_the_analytic_jacobian():
    dyn = gagen.load("rrr", derivatives=True)
    fd = gc.functions(dyn, ["forward_dynamics"])["forward_dynamics"]
    q, qd, tau = (ca.SX.sym(n, 3) for n in ("q", "qd", "tau"))
    w = np.array([0.3, -1.2, 0.7])
    x = ca.vertcat(q, qd)
    H = ca.Function("H", [x, tau], [ca.hessian(ca.dot(w, fd(q, qd, tau)), x)[0]])
    (q0, qd0, u0), = states(dyn, 1, seed=4)
    x0 = np.concatenate([q0, qd0])

    def gradient(xv):
        dq, dqd, _ = dyn.forward_dynamics_derivatives(xv[:3], xv[3:], u0)
        return np.concatenate([w @ dq, w @ dqd])

    expected = central(gradient, x0)
    close(call(H, [x0, u0])[0], 0.5 * (expected + expected.T), "hessian", 1e-6)


HOSTILE = """
name: "9 lives__arm */ x"
gravity: [0, 0, -9.81]
parameters: {m: 2.0}
bodies:
  - name: "link */ one"
    parent: world
    joint: {name: "q__1", type: revolute, axis: [0, 0, 1]}
    mass: m
    com: [0.1, 0.0, 0.0]
    inertia: [0.01, 0.02, 0.03, 0, 0, 0]
"""


def test_a_hostile_model_name_gives_valid_casadi_names(tmp_path):
    """A name with a comment's end, a leading digit and runs of underscores: the C names
    are checked identifiers, CasADi's names have no double underscore, and the header
    carries no text of the description."""
    path = tmp_path / "hostile.yaml"
    path.write_text(HOSTILE)
    dyn = gagen.load(path, derivatives=True)
    fns = gc.functions(dyn)
    assert all("__" not in f.name() for f in fns.values())
    close(np.ravel(call(fns["gravity"], [[0.3]])[0]), dyn.gravity([0.3]), "gravity")
    folder = gc.library(dyn).parent
    for source in folder.glob("*casadi*.[ch]"):
        text = source.read_text()
        assert "*/ x" not in text and "*/ one" not in text, source.name


def test_loading_a_built_library_needs_no_sympy():
    """Once built, a model's CasADi functions load from the cache without SymPy, as the
    model does (a fresh process)."""
    gc.functions(gagen.load("rrr", derivatives=True))
    code = ("import sys, gagen, gagen.casadi\n"
            "fns = gagen.casadi.functions(gagen.load('rrr'))\n"
            "assert float(fns['gravity']([0, 0.5, 0.2])[1]) != 0\n"
            "assert 'sympy' not in sys.modules, 'sympy imported'\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=False)
    assert run.returncode == 0, run.stderr


def test_parameters_and_fixed_p_exclude_each_other():
    dyn = gagen.load("rrr")
    with pytest.raises(ValueError, match="parameters=True or p="):
        gc.functions(dyn, parameters=True, p={"m3": 50.0})
    with pytest.raises(TypeError, match="compiled model"):
        gc.functions(gagen.load("rrr", backend="lambdify"))


# --- C: generated code, the exported library ------------------------------------------------

def test_generated_code_that_calls_the_library_compiles_and_runs(tmp_path):
    """A Function.generate'd C program (CasADi's own main) calling forward dynamics and its
    Jacobian, linked against the library, gives the numbers of the Python call."""
    dyn = gagen.load("rrr", derivatives=True)
    fd = gc.functions(dyn, ["forward_dynamics"])["forward_dynamics"]
    library = gc.library(dyn)
    q, qd, tau = (ca.MX.sym(n, 3) for n in ("q", "qd", "tau"))
    qdd = fd(q, qd, tau)
    step = ca.Function("step", [q, qd, tau], [qdd, ca.jacobian(qdd, ca.vertcat(q, qd))])
    generator = ca.CodeGenerator("step.c", {"main": True})
    generator.add(step)
    generator.generate(str(tmp_path) + "/")
    exe = tmp_path / "step"
    subprocess.run(["cc", "-O2", str(tmp_path / "step.c"), "-o", str(exe), str(library),
                    f"-Wl,-rpath,{library.parent}", "-lm"], check=True, capture_output=True)
    (q0, qd0, u0), = states(dyn, 1, seed=9)
    text = " ".join(repr(float(v)) for v in np.concatenate([q0, qd0, u0]))
    run = subprocess.run([str(exe), "step"], input=text, capture_output=True, text=True,
                         check=True)
    numbers = np.array(run.stdout.split(), dtype=float)
    expected = call(step, [q0, qd0, u0])
    close(numbers[:3], np.ravel(expected[0]), "qdd from C")
    close(numbers[3:], np.ravel(expected[1], order="F"), "jacobian from C")
    dq, dqd, _ = dyn.forward_dynamics_derivatives(q0, qd0, u0)
    close(expected[1], np.hstack([dq, dqd]), "jacobian")


FRESH = textwrap.dedent("""
    import json, sys
    import numpy as np
    import casadi
    folder, data = sys.argv[1], json.loads(sys.argv[2])
    lib = folder + "/" + data["library"]
    out = {}
    for name, args in data["calls"].items():
        f = casadi.external(name, lib)
        out[name] = [np.ravel(np.array(r)).tolist() for r in f.call([casadi.DM(a) for a in args])]
    assert not any(m == "gagen" or m.startswith("gagen.") for m in sys.modules), "gagen imported"
    print(json.dumps(out))
""")


def test_the_exported_library_works_without_gagen(tmp_path):
    from gagen.app.cli import main

    folder = tmp_path / "export"
    path = str(SHARED_URDF / "double_pendulum.urdf")
    assert main(["-q", "export", "casadi", path, "--floating-base", "--out", str(folder)]) == 0
    dyn = gagen.load(path, floating_base=True, derivatives=True)
    prefix = gc.build.prefix_of(gc.build.model_ident(dyn))
    assert (folder / f"{prefix}.c").is_file() and (folder / f"{prefix}.h").is_file()
    assert main(["-q", "export", "casadi", path, "--out", str(folder / f"{prefix}.c")]) == 2
    (q, qd, tau), = states(dyn, 1, seed=11)
    frame = len(dyn.frames) - 1
    calls = {f"{prefix}_forward_dynamics": [q, qd, tau],
             f"jac_{prefix}_forward_dynamics": [q, qd, tau, np.zeros(dyn.nv)],
             f"{prefix}_frame_jacobian": [q, [frame]],
             f"{prefix}_inverse_dynamics_p": [q, qd, tau, dyn.parameter_vector()]}
    data = {"library": gc.build.library_name(dyn),
            "calls": {k: [np.asarray(a, dtype=float).tolist() for a in v]
                      for k, v in calls.items()}}
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    run = subprocess.run([sys.executable, "-c", FRESH, str(folder), json.dumps(data)],
                         capture_output=True, text=True, env=env, cwd=tmp_path, check=False)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    close(out[f"{prefix}_forward_dynamics"][0], dyn.forward_dynamics(q, qd, tau), "fd")
    dq, dqd, Minv = dyn.forward_dynamics_derivatives(q, qd, tau)
    jac = [np.reshape(b, (dyn.nv, -1)) for b in out[f"jac_{prefix}_forward_dynamics"]]
    close(jac[0] @ tangent_map(dyn, q), dq, "dqdd/dq")
    close(jac[1], dqd, "dqdd/dqd")
    close(jac[2], Minv, "dqdd/dtau")
    close(np.reshape(out[f"{prefix}_frame_jacobian"][0], (6, -1)),
          dyn.frame_jacobian(q, frame), "J")
    close(out[f"{prefix}_inverse_dynamics_p"][0], dyn.inverse_dynamics(q, qd, tau), "tau")


# --- optimisation: casadi.Opti and IPOPT on gagen's functions -------------------------------

def test_ipopt_solves_a_swing_of_the_paper_s_robot_on_gagen_s_functions():
    """A small swing (docs/casadi.md's problem on rrr): IPOPT converges with the exact
    Hessian (differences of gagen's Jacobian) and with the limited-memory one, and each
    optimum's torques replayed through gagen's own forward dynamics (RK4 in NumPy) reach
    the goal at rest."""
    from gagen.casadi.swing import swing

    dyn = gagen.load("rrr", derivatives=True)
    fd = gc.functions(dyn, ["forward_dynamics"])["forward_dynamics"]
    start, goal, h = np.zeros(3), np.array([-1.0, -0.8, -0.4]), 2.0 / 12
    for hessian in ("exact", "limited-memory"):
        r = swing(fd, start, goal, duration=2.0, intervals=12,
                  ipopt={"hessian_approximation": hessian})
        assert r.success, hessian
        x = np.zeros(6)
        for tau in r.tau:
            def rate(x, tau=tau):
                return np.concatenate([x[3:], dyn.forward_dynamics(x[:3], x[3:], tau)])
            k1 = rate(x)
            k2 = rate(x + h / 2 * k1)
            k3 = rate(x + h / 2 * k2)
            k4 = rate(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        close(x, np.concatenate([goal, np.zeros(3)]), f"replayed ({hessian})", 1e-8)


@pytest.mark.slow
def test_the_swing_example_reaches_adam_s_optimum(tmp_path):
    """docs/casadi_swing.py: the Panda's swing on gagen's functions and on adam's CasADi
    dynamics converges to the same optimum (1e-6), and draws its figure."""
    pytest.importorskip("adam.casadi", reason="the comparison needs adam-robotics")
    import importlib.util

    spec = importlib.util.spec_from_file_location("casadi_swing",
                                                  REPO / "docs" / "casadi_swing.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    results = example.solve_both(SHARED_URDF / "panda.urdf", tmp_path)
    ours, theirs = results["gagen"], results["adam"]
    assert ours.success and theirs.success
    close(ours.q, theirs.q, "q", 1e-6)
    close(ours.tau, theirs.tau, "tau", 1e-6)
    assert abs(ours.effort - theirs.effort) <= 1e-6 * ours.effort
    example.draw(results, tmp_path / "swing.png")
    assert (tmp_path / "swing.png").stat().st_size > 10_000
