"""gagen.casadi: the Jacobian's columns by the parameters p (the `_p` functions), each by
what the parameter is to the function (gagen.casadi.table.Param, gagen.casadi.build's
parameter_classes): zeros by structure, affine in gravity, exact stencils of polynomials in
the inertial parameters (through the regressor, or divided by the total mass), the
five-point stencil for lengths.

Every column against Richardson-extrapolated differences of gagen's own values (1e-8);
the exact ones against identities at 1e-11, which a central difference (~1e-7) fails:
dtau/dg = gravity(q) / g, dM/dp = (Y(q, 0, e_j) - Y(q, 0, 0)) dpi/dp, dG = -Y^T dM Y for the
Delassus matrix, the centre of mass from a NumPy assembly of the bodies' placements and pi;
the claim that D X is a polynomial in each inertial parameter (D the total mass, X a
centroidal value) checked by its fifth differences."""

from __future__ import annotations

import itertools
import warnings

import numpy as np
import pytest
from conftest import SHARED_URDF

import gagen
from gagen.errors import SingularMassMatrixError

ca = pytest.importorskip("casadi", reason="gagen.casadi needs casadi (pip install gagen[casadi])")
gc = pytest.importorskip("gagen.casadi")

from test_casadi import (
    arguments,
    call,
    casadi_layout,
    gagen_outputs,
    states,
    symbolic,
)

from gagen.casadi.build import parameter_classes
from gagen.casadi.table import ENTRIES, Param

EXACT = 1e-11       # where the method is exact (relative to the outputs' scale)
DIFFERENCES = 1e-8  # against Richardson-extrapolated differences

MODELS = {
    "rrr": ("rrr", False),
    "floating": (str(SHARED_URDF / "double_pendulum.urdf"), True),
    "panda": (str(SHARED_URDF / "panda.urdf"), False),
    "anymal": (str(SHARED_URDF / "anymal_c.urdf"), True),
}
SLOW = ("panda", "anymal")
DEPENDS = {entry.name: entry.depends for entry in ENTRIES}


@pytest.fixture(scope="module", params=[pytest.param(name, marks=pytest.mark.slow)
                                        if name in SLOW else name for name in MODELS])
def model(request, cache_dir):
    path, floating = MODELS[request.param]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)  # ANYmal's CAD round-off
        dyn = gagen.load(path, floating_base=floating, derivatives=True)
    return dyn, gc.functions(dyn, parameters=True), parameter_classes(dyn)


def scaled(a, b) -> float:
    """max |a - b| over the scale of b (at least 1)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, (a.shape, b.shape)
    return float(np.abs(a - b).max(initial=0.0)) / max(1.0, float(np.abs(b).max(initial=0.0)))


def p_jacobian(function, q, qd, u, frame, p) -> np.ndarray:
    """The CasADi Jacobian of a `_p` function's outputs (joined, CasADi's order) by p."""
    symbols, outs = symbolic(function, "SX")
    joined = ca.vertcat(*[ca.vec(o) for o in outs])
    jac = ca.Function("jp", symbols, [ca.jacobian(joined, symbols[-1])])
    return call(jac, arguments(function, q, qd, u, frame, p))[0]


def stencil(f, p, k, h) -> np.ndarray:
    """The five-point stencil of f (p -> flat array) by p_k with step h."""
    def at(s):
        x = p.copy()
        x[k] += s * h
        return f(x)
    return (-at(2) + 8 * at(1) - 8 * at(-1) + at(-2)) / (12 * h)


def richardson(f, p, k, h) -> np.ndarray:
    """The five-point stencil at h and h/2, extrapolated: error O(h^6)."""
    return (64 * stencil(f, p, k, h / 2) - stencil(f, p, k, h)) / 63


def converged(f, p, k) -> np.ndarray:
    """The Richardson estimate at the steps where two successive ones agree best, steps by
    factors of 3 from 1e-2 max(|p|, 1) down to 3e-5 max(|p|, 1e-3) (forward dynamics of a
    light base, 0.1 kg and 2e-5 kg m^2, vary on the scale of its smallest inertia, and the
    Delassus matrix factorises M: a light link's inertia must not be stepped through zero;
    a centre of mass at 0 varies on the scale of the link)."""
    hi, lo = 1e-2 * max(abs(p[k]), 1.0), 3e-5 * max(abs(p[k]), 1e-3)
    steps = hi / 3.0 ** np.arange(int(np.ceil(np.log(hi / lo) / np.log(3))) + 1)
    estimates = []
    for h in steps:
        try:
            estimates.append(richardson(f, p, k, h))
        except SingularMassMatrixError:  # a large step took an inertia through zero
            continue
    gaps = [float(np.abs(a - b).max(initial=0.0)) for a, b in itertools.pairwise(estimates)]
    return estimates[int(np.argmin(gaps)) + 1]


def frames_to_check(dyn) -> list[int]:
    """The last frame (a leaf's) and one on the way to it."""
    last = len(dyn.frames) - 1
    return sorted({last, len(dyn.frames) // 2})


def perturbed(dyn) -> np.ndarray:
    """The defaults, masses and gravity moved a little (no special values)."""
    p = dyn.parameter_vector()
    rng = np.random.default_rng(5)
    return p * (1 + 0.05 * rng.uniform(-1, 1, p.size))


def cases(dyn, fns):
    """(name, function, frame) of every `_p` function, frame functions at a few frames."""
    for name, function in fns.items():
        ports = [function.name_in(i) for i in range(function.n_in())]
        for frame in (frames_to_check(dyn) if "frame" in ports else [None]):
            yield name, function, frame


def test_every_column_matches_richardson_differences_and_structural_zeros_are_zero(model):
    """Each `_p` function's Jacobian by p against Richardson-extrapolated five-point
    differences of gagen's own values in p (1e-8 of the outputs' scale), at two states; the
    columns of the classes a function does not depend on exactly zero."""
    dyn, fns, classes = model
    p = perturbed(dyn)
    for q, qd, u in states(dyn, 2, seed=11):
        for name, function, frame in cases(dyn, fns):
            block = p_jacobian(function, q, qd, u, frame, p)
            for k, cls in enumerate(classes):
                what = f"d{name}/d{list(dyn.parameters)[k]} (frame {frame})"
                if not cls & DEPENDS[name]:
                    assert not block[:, k].any(), f"{what}: not zero by structure"
                    continue
                expected = converged(lambda x, name=name, frame=frame, q=q, qd=qd, u=u:
                                     gagen_outputs(dyn, name, q, qd, u, frame, x), p, k)
                error = scaled(block[:, k], expected)
                assert error <= DIFFERENCES, f"{what}: error {error:.3g}"


def dpi_dp(dyn, p) -> np.ndarray:
    """dpi/dp (P x np) in the inertial columns: five-point stencils of pi at two steps, which
    agree to rounding (pi is a polynomial of degree <= 4 in each: the stencil is exact)."""
    classes = parameter_classes(dyn)
    out = np.zeros((len(dyn.regressor_names), p.size))
    for k, cls in enumerate(classes):
        if cls & ~int(Param.BODY | Param.ARMATURE | Param.DRAG):
            continue
        scale = max(abs(p[k]), 1.0)
        a = stencil(dyn.regressor_parameters, p, k, 0.5 * scale)
        b = stencil(dyn.regressor_parameters, p, k, 0.05 * scale)
        assert scaled(a, b) <= 1e-12, dyn.parameters
        out[:, k] = a
    return out


def inertial(classes) -> np.ndarray:
    return np.array([c and not c & ~int(Param.BODY | Param.ARMATURE | Param.DRAG)
                     for c in classes], dtype=bool)


def test_exact_columns_meet_their_identities(model):
    """At 1e-11 of the outputs' scale, where a central difference is ~1e-7 off: dtau/dg =
    gravity(q) / g (and -M^-1 of it for forward dynamics); dtau/dp = Y dpi/dp;
    dM/dp = (Y(q, 0, e_j) - Y(q, 0, 0)) dpi/dp; dG/dp = -Y^T dM Y (Y = M^-1 J^T)."""
    dyn, fns, classes = model
    p = perturbed(dyn)
    names = list(dyn.parameters)
    k_g = names.index("g")
    assert classes[k_g] == Param.GRAVITY
    mask = inertial(classes)
    dpi = dpi_dp(dyn, p)
    n = dyn.nv
    for q, qd, u in states(dyn, 2, seed=13):
        grav = dyn.gravity(q, p)
        M = dyn.mass_matrix(q, p)
        Minv = np.linalg.inv(M)
        acc = dyn.forward_dynamics(q, qd, u, p)
        # gravity's column
        for name, expected in (("inverse_dynamics", grav / p[k_g]), ("gravity", grav / p[k_g]),
                               ("forward_dynamics", -Minv @ grav / p[k_g])):
            block = p_jacobian(fns[name], q, qd, u, None, p)
            assert scaled(block[:, k_g], expected) <= EXACT, f"d{name}/dg"
        # the inertial columns through the regressor
        expected = {
            "inverse_dynamics": dyn.regressor(q, qd, u, p) @ dpi,
            "gravity": dyn.regressor(q, np.zeros(n), np.zeros(n), p) @ dpi,
            "forward_dynamics": -Minv @ dyn.regressor(q, qd, acc, p) @ dpi,
        }
        Y0 = dyn.regressor(q, np.zeros(n), np.zeros(n), p)
        dM = np.stack([(dyn.regressor(q, np.zeros(n), e, p) - Y0) @ dpi for e in np.eye(n)],
                      axis=1)  # (n, n, np): [i, j, k]
        expected["mass_matrix"] = dM.transpose(1, 0, 2).reshape(n * n, -1)  # CasADi's order
        for name, reference in expected.items():
            block = p_jacobian(fns[name], q, qd, u, None, p)
            error = scaled(block[:, mask], reference[:, mask])
            assert error <= EXACT, f"d{name}/dp (inertial): error {error:.3g}"
        for frame in frames_to_check(dyn):
            J = dyn.frame_jacobian(q, frame, p=p)
            Y = Minv @ J.T
            dG = -np.einsum("ia,ijk,jb->abk", Y, dM, Y)  # (6, 6, np)
            block = p_jacobian(fns["delassus"], q, qd, u, frame, p)
            error = scaled(block[:, mask], dG.transpose(1, 0, 2).reshape(36, -1)[:, mask])
            assert error <= EXACT, f"ddelassus/dp (frame {frame}): error {error:.3g}"


def test_center_of_mass_columns_equal_a_numpy_assembly(model):
    """com = sum_b (R_b h_b + m_b o_b) / D over the moving bodies (placements R_b, o_b and
    pi's m_b, h_b): its derivative by the inertial parameters from dpi/dp, at 1e-11."""
    dyn, fns, classes = model
    if "center_of_mass" not in fns:
        pytest.skip("the model's C has no centre of mass")
    p = perturbed(dyn)
    mask = inertial(classes)
    dpi = dpi_dp(dyn, p)
    pi = dyn.regressor_parameters(p)
    moving = [body for body, *_ in dyn.info.moving_tree]
    for q, qd, u in states(dyn, 2, seed=17):
        X = dyn._placements(q, p).reshape(-1, 15)
        P, dP = np.zeros(3), np.zeros((3, p.size))
        for b, body in enumerate(moving):
            R, origin = X[body, :9].reshape(3, 3), X[body, 9:12]
            P += R @ pi[10 * b + 1: 10 * b + 4] + pi[10 * b] * origin
            dP += R @ dpi[10 * b + 1: 10 * b + 4] + np.outer(origin, dpi[10 * b])
        D, dD = pi[0::10][:len(moving)].sum(), dpi[0: 10 * len(moving): 10].sum(axis=0)
        np.testing.assert_allclose(P / D, dyn.center_of_mass(q, p), rtol=0, atol=1e-12)
        expected = (dP - np.outer(P / D, dD)) / D
        block = p_jacobian(fns["center_of_mass"], q, qd, u, None, p)
        error = scaled(block[:, mask], expected[:, mask])
        assert error <= EXACT, f"dcom/dp: error {error:.3g}"


CENTROIDAL = ("center_of_mass", "com_velocity", "com_jacobian", "centroidal_map",
              "centroidal_momentum", "centroidal_map_time_variation", "centroidal_bias")


def test_polynomial_columns_are_exact_whatever_the_step(model):
    """The values the wrapper differences by an exact stencil (C, and D X for the centroidal
    ones) are polynomials of degree <= 4 in each inertial parameter: their fifth differences
    vanish at large steps, and the CasADi columns equal Python stencils with another step to
    1e-11 (a central difference is ~1e-7 off)."""
    dyn, fns, classes = model
    p = perturbed(dyn)
    mask = inertial(classes)
    ks = np.flatnonzero(mask)
    if dyn.nv > 12:  # ANYmal: a spread of its 166 inertial parameters (each kind's)
        ks = ks[::3]
    masses = [10 * b for b in range(len(dyn.info.moving_bodies))]

    def total(x):
        return dyn.regressor_parameters(x)[masses].sum()

    (q, qd, u), = states(dyn, 1, seed=19)
    for name in ("coriolis_matrix",) + tuple(n for n in CENTROIDAL if n in fns):
        block = p_jacobian(fns[name], q, qd, u, None, p)
        quotient = name in CENTROIDAL

        def value(x, name=name, quotient=quotient):
            out = gagen_outputs(dyn, name, q, qd, u, None, x)
            return out * total(x) if quotient else out

        X, D = gagen_outputs(dyn, name, q, qd, u, None, p), total(p)
        for k in ks:
            h = 0.1 * max(abs(p[k]), 1.0)
            points = [value(p + s * h * np.eye(p.size)[k]) for s in range(-3, 3)]
            fifth = sum(c * v for c, v in zip((-1, 5, -10, 10, -5, 1), points))
            scale = max(1.0, max(float(np.abs(v).max()) for v in points))
            assert float(np.abs(fifth).max()) <= 1e-10 * scale, \
                f"{name}: D X is not a polynomial of degree <= 4 in {list(dyn.parameters)[k]}"
            d = stencil(value, p, k, h)
            if quotient:
                d = (d - X * stencil(lambda x: np.array([total(x)]), p, k, h)) / D
            error = scaled(block[:, k], d)
            assert error <= EXACT, f"d{name}/d{list(dyn.parameters)[k]}: error {error:.3g}"


def test_classes_of_the_paper_s_robot_and_a_urdf():
    """rrr: L1, L2 place its joints (kinematic), g is gravity, the rest pi alone (L3 only
    the last link's centre of mass and inertia); a URDF's coulomb_width only simulations
    use."""
    dyn = gagen.load("rrr")
    by_name = dict(zip(dyn.parameters, parameter_classes(dyn)))
    assert by_name["g"] == Param.GRAVITY
    assert by_name["L1"] == by_name["L2"] == Param.KINEMATIC
    assert all(c == Param.BODY for name, c in by_name.items()
               if name not in ("g", "L1", "L2")), by_name
    urdf = gagen.load(str(SHARED_URDF / "double_pendulum.urdf"))
    by_name = dict(zip(urdf.parameters, parameter_classes(urdf)))
    assert by_name["coulomb_width"] == Param.SIMULATION
    assert {c for name, c in by_name.items() if name.startswith("m_")} == {Param.BODY}
    assert casadi_layout(np.eye(2)).shape == (4,)


ODD = """
name: odd_parameters
parameters: {g: 9.81, tilt: 0.3, m0: 1.5, s: 0.2, L: 0.4}
gravity: [0, "-g*sin(tilt)", "-g*cos(tilt)"]
bodies:
  - name: one
    parent: world
    joint: {name: j1, type: revolute, axis: [0, 1, 0]}
    mass: "m0*exp(s)"
    com: ["L/2", 0, 0]
    inertia: [0.01, 0.02, 0.03, 0, 0, 0]
  - name: two
    parent: one
    joint: {name: j2, type: revolute, axis: [0, 1, 0], origin: {xyz: [L, 0, 0]}}
    mass: m0
    com: [0.1, 0, 0]
    inertia: [0.01, 0.02, "0.01 + m0*L**2/12", 0, 0, 0]
"""


@pytest.mark.slow  # builds a model: about 10 s
def test_parameters_outside_the_classes_fall_back_to_the_stencil(tmp_path):
    """A model file's gravity tilted by a parameter (Y not affine in it), a mass
    m0 exp(s) (pi not a polynomial in s), a length in a joint's origin and an inertia: the
    tilt, s and L are kinematic (the five-point stencil), g still gravity, m0 a body's;
    every column against Richardson differences."""
    path = tmp_path / "odd.yaml"
    path.write_text(ODD)
    dyn = gagen.load(path, derivatives=True)
    classes = dict(zip(dyn.parameters, parameter_classes(dyn)))
    assert classes == {"g": Param.GRAVITY, "tilt": Param.KINEMATIC, "m0": Param.BODY,
                       "s": Param.KINEMATIC, "L": Param.KINEMATIC}, classes
    fns = gc.functions(dyn, ["inverse_dynamics", "forward_dynamics", "mass_matrix",
                             "center_of_mass"], parameters=True)
    p = perturbed(dyn)
    for q, qd, u in states(dyn, 2, seed=23):
        for name, function in fns.items():
            block = p_jacobian(function, q, qd, u, None, p)
            for k in range(p.size):
                expected = converged(lambda x, name=name, q=q, qd=qd, u=u:
                                     gagen_outputs(dyn, name, q, qd, u, None, x), p, k)
                error = scaled(block[:, k], expected)
                assert error <= DIFFERENCES, f"d{name}/d{list(dyn.parameters)[k]}: {error:.3g}"
