"""The centroidal quantities' analytic derivatives (model/centroidal_derivatives.c.j2), the
kernels gagen.casadi's centroidal functions take their Jacobians from, called as C.

By q along the velocity directions (a floating joint's six as Pinocchio's), on the paper's
robot, the Panda (fixed base, prismatic fingers), ANYmal C (floating) and a random tree with
every joint type and a body welded to the world:
- against Pinocchio to 1e-9 where it has the quantity: computeCentroidalDynamicsDerivatives'
  dh_dq (the momentum's kernel; A_g's derivative contracted with qd; the time variation's by
  qd, contracted), its dhdot_dq and dhdot_dv at qdd = 0 (the bias's kernel; the time
  variation's by q, contracted with qd) and with a qdd (A_g's derivative, contracted with
  it), getCenterOfMassVelocityDerivatives (the centre of mass velocity's; J_com's,
  contracted);
- every kernel's every output against five-point central differences of gagen's own value
  function (q stepped by dyn.integrate) to 1e-6 relative.
"""

from __future__ import annotations

import ctypes
import warnings

import numpy as np
import pytest
from test_floating import URDF, Reference, random_state

import gagen
from gagen.casadi.build import model_ident  # the C names' prefix (no CasADi needed)
from gagen.model.numeric import numeric_model
from gagen.reference.pinocchio import pinocchio_model

RTOL = 1e-9          # against Pinocchio
DIFFERENCES = 1e-6   # against central differences

# kernel: (takes qd, its outputs' shapes in rows and the velocity coordinates' count: a
# matrix's derivative is rows x nv x nv, a vector's rows x nv)
KERNELS = {
    "com_jacobian_derivatives": (False, [(3, 2)]),
    "com_velocity_derivatives": (True, [(3, 1)]),
    "centroidal_map_derivatives": (False, [(6, 2)]),
    "centroidal_momentum_derivatives": (True, [(6, 1)]),
    "centroidal_map_time_variation_derivatives": (True, [(6, 2), (6, 2)]),
    "centroidal_bias_derivatives": (True, [(6, 1), (6, 1)]),
}


def kernel(dyn, name: str):
    """<model>_<name> of the model's compiled module as a function of (q, qd) returning its
    outputs as arrays (rows, nv) or (rows, nv, nv)."""
    lib = ctypes.CDLL(dyn.module.__file__)
    rates, shapes = KERNELS[name]
    function = getattr(lib, f"{model_ident(dyn)}_{name}")
    double_p = np.ctypeslib.ndpointer(np.float64, flags="C")
    function.argtypes = [double_p] * ((3 if rates else 2) + len(shapes))
    function.restype = None
    p = dyn.parameter_vector()
    n = dyn.nv

    def call(q, qd=None):
        outs = [np.full((rows,) + (n,) * order, np.nan) for rows, order in shapes]
        args = (q, qd, p) if rates else (q, p)
        function(*(np.ascontiguousarray(a, dtype=float) for a in args), *outs)
        return outs
    return call


def kernels(dyn, q, qd) -> dict[str, list[np.ndarray]]:
    return {name: kernel(dyn, name)(q, qd) for name in KERNELS}


# the value each kernel differentiates, per output: (gagen's call at (q, qd), by q or qd)
VALUES = {
    "com_jacobian_derivatives": [(lambda d, q, v: d.com_jacobian(q), "q")],
    "com_velocity_derivatives": [(lambda d, q, v: d.com_velocity(q, v), "q")],
    "centroidal_map_derivatives": [(lambda d, q, v: d.centroidal_map(q), "q")],
    "centroidal_momentum_derivatives": [(lambda d, q, v: d.centroidal_momentum(q, v), "q")],
    "centroidal_map_time_variation_derivatives": [
        (lambda d, q, v: d.centroidal_map_time_variation(q, v), "q"),
        (lambda d, q, v: d.centroidal_map_time_variation(q, v), "qd")],
    "centroidal_bias_derivatives": [(lambda d, q, v: d.centroidal_bias(q, v), "q"),
                                    (lambda d, q, v: d.centroidal_bias(q, v), "qd")],
}


def differences(dyn, f, q, qd, by: str, h: float = 1e-3) -> np.ndarray:
    """Five-point central differences of f(q, qd) by the velocity directions (q stepped
    as q (+) h e_i) or by qd, stacked along a last axis."""
    columns = []
    for i in range(dyn.nv):
        def at(s, i=i):
            step = np.zeros(dyn.nv)
            step[i] = s
            if by == "q":
                return np.asarray(f(dyn, dyn.integrate(q, step), qd))
            return np.asarray(f(dyn, q, qd + step))
        columns.append((-at(2 * h) + 8 * at(h) - 8 * at(-h) + at(-2 * h)) / (12 * h))
    return np.stack(columns, axis=-1)


def close(actual, expected, what: str, rtol: float) -> None:
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != {expected.shape}"
    scale = max(1.0, float(np.abs(expected).max()))
    error = float(np.abs(actual - expected).max())
    assert error <= rtol * scale, f"{what}: error {error:.3g} (scale {scale:.3g})"


# --- the robots, and Pinocchio's model of each ----------------------------------------------

def _anymal():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)  # ANYmal's CAD round-off
        return gagen.load(URDF / "anymal_c.urdf", floating_base=True)


def _tree():
    """test_centroidal's random tree: revolute, continuous, prismatic (below a revolute)
    and fixed joints, a body welded to the world (no part of the robot's mass)."""
    from test_centroidal import every_joint_type_tree

    return gagen.load(every_joint_type_tree())


ROBOTS = {"rrr": lambda: gagen.load("rrr"), "panda": lambda: gagen.load(URDF / "panda.urdf"),
          "anymal": _anymal, "tree": _tree}


def pinocchio_reference(name: str, dyn) -> Reference:
    """Pinocchio's model of the robot: its own URDF parse for the Panda and ANYmal C,
    gagen's builder's for the others."""
    pin = pytest.importorskip("pinocchio")
    if name == "panda":
        from test_centroidal import FixedBaseReference

        return FixedBaseReference(dyn, pin.buildModelFromUrdf(str(URDF / "panda.urdf")))
    if name == "anymal":
        return Reference(dyn, pin.buildModelFromUrdf(str(URDF / "anymal_c.urdf"),
                                                     pin.JointModelFreeFlyer()))
    return Reference(dyn, pinocchio_model(numeric_model(dyn.model)))


@pytest.fixture(scope="module", params=list(ROBOTS))
def robot(request, cache_dir):
    return request.param, ROBOTS[request.param]()


def test_the_kernels_match_pinocchio(robot):
    pin = pytest.importorskip("pinocchio")
    name, dyn = robot
    ref = pinocchio_reference(name, dyn)
    m, d = ref.model, ref.data
    rng = np.random.default_rng(5)
    for _ in range(3):
        q, v, a = random_state(dyn, rng)
        qp, vp, ap = ref.q(q), ref.v(v), ref.v(a)
        out = kernels(dyn, q, v)
        zero = np.zeros(m.nv)
        dh_dq, dhdot_dq, dhdot_dv, _ = (np.array(x) for x in
                                        pin.computeCentroidalDynamicsDerivatives(m, d, qp, vp,
                                                                                 zero))
        dh_dq, dhdot_dq, dhdot_dv = (ref.ours(x) for x in (dh_dq, dhdot_dq, dhdot_dv))
        _, with_a, _, _ = pin.computeCentroidalDynamicsDerivatives(m, d, qp, vp, ap)
        with_a = ref.ours(np.array(with_a))
        pin.computeAllTerms(m, d, qp, vp)
        dv_dq = ref.ours(np.array(pin.getCenterOfMassVelocityDerivatives(m, d)))

        close(out["centroidal_momentum_derivatives"][0], dh_dq, "dh_dq", RTOL)
        close(out["com_velocity_derivatives"][0], dv_dq, "dvcom_dq", RTOL)
        db_dq, db_dqd = out["centroidal_bias_derivatives"]
        close(db_dq, dhdot_dq, "bias: dhdot_dq at qdd = 0", RTOL)
        close(db_dqd, dhdot_dv, "bias: dhdot_dv at qdd = 0", RTOL)
        # dhdot/dq = (dAg/dq) qdd + db/dq: A_g's derivative, contracted with qdd
        dAg = out["centroidal_map_derivatives"][0]
        close(np.einsum("rki,k->ri", dAg, a) + db_dq, with_a, "dAg_dq qdd", RTOL)
        close(np.einsum("rki,k->ri", dAg, v), dh_dq, "dAg_dq qd", RTOL)
        dA_dq, dA_dqd = out["centroidal_map_time_variation_derivatives"]
        close(np.einsum("rki,k->ri", dA_dq, v), dhdot_dq, "ddAg_dq qd", RTOL)
        close(np.einsum("rki,k->ri", dA_dqd, v), dh_dq, "ddAg_dqd qd", RTOL)
        dJ = out["com_jacobian_derivatives"][0]
        close(np.einsum("rki,k->ri", dJ, v), dv_dq, "dJcom_dq qd", RTOL)


def test_the_kernels_match_central_differences(robot):
    """Every output of every kernel against five-point differences of gagen's own value
    functions (error h^4 f^(5) and eps |f| / h, both far below 1e-6 at h = 1e-3)."""
    _, dyn = robot
    rng = np.random.default_rng(6)
    for _ in range(2):
        q, v, _ = random_state(dyn, rng)
        out = kernels(dyn, q, v)
        for name, values in VALUES.items():
            for k, (f, by) in enumerate(values):
                close(out[name][k], differences(dyn, f, q, v, by), f"{name}[{k}] by {by}",
                      DIFFERENCES)


def test_the_kernels_agree_with_each_other(robot):
    """The defining identities between the kernels, to rounding: J_com's derivative is A_g's
    linear rows' over the mass, the time variation's by qd is A_g's by q, the bias's by q is
    the time variation's times qd and by qd dAg + dh/dq, the centre of mass velocity's is
    the momentum's linear rows over the mass."""
    _, dyn = robot
    rng = np.random.default_rng(7)
    q, v, _ = random_state(dyn, rng)
    out = kernels(dyn, q, v)
    dAg = out["centroidal_map_derivatives"][0]
    J = dyn.com_jacobian(q)
    mass = float(np.sum(dyn.centroidal_map(q)[:3] * J) / np.sum(J * J))  # A_lin = m J_com
    close(out["com_jacobian_derivatives"][0], dAg[:3] / mass, "dJcom = dAg_lin / m", 1e-12)
    close(out["centroidal_map_time_variation_derivatives"][1], dAg, "ddAg_dqd = dAg_dq", 1e-12)
    # the bias's by q (its own O(nv) sum) is the time variation's by q (pair by pair) times qd
    close(out["centroidal_bias_derivatives"][0],
          np.einsum("rki,k->ri", out["centroidal_map_time_variation_derivatives"][0], v),
          "db_dq = ddAg_dq qd", 1e-12)
    close(out["centroidal_bias_derivatives"][1],
          dyn.centroidal_map_time_variation(q, v) + out["centroidal_momentum_derivatives"][0],
          "db_dqd = dAg + dh_dq", 1e-12)
    close(out["com_velocity_derivatives"][0],
          out["centroidal_momentum_derivatives"][0][:3] / mass, "dvcom = dh_lin / m", 1e-12)
