"""The task-space functions' and the Coriolis matrix's analytic derivatives (issue 28): the
model's C kernels `<model>_frame_acceleration_derivatives`,
`_frame_jacobian_time_variation_derivatives` (LOCAL_WORLD_ALIGNED, the classical
acceleration), `_delassus_derivatives` and `_coriolis_matrix_derivatives` (by q along the
velocity directions), and the CasADi functions whose Jacobians they are.

On the paper's robot, the Panda (fixed, prismatic fingers) and ANYmal C (floating): the
kernels against Pinocchio's getFrameAccelerationDerivatives (1e-9) and against five-point
central differences of gagen's own task-space functions (1e-6); J's time variation by qd
against dJ/dq, and contracted with qd against the bias acceleration's derivatives (defining
identities); the Delassus matrix's (`<model>_delassus_derivatives`) against its formula
assembled from Pinocchio's RNEA derivatives (1e-9); the Coriolis matrix's
(`<model>_coriolis_matrix_derivatives`) against central differences and Mdot = C + C^T
differentiated; CasADi's jacobian() equal to the kernels (1e-12)."""

from __future__ import annotations

import ctypes
import functools
import warnings

import numpy as np
import pytest
from conftest import SHARED_URDF
from test_floating import random_state

import gagen

ca = pytest.importorskip("casadi", reason="gagen.casadi needs casadi (pip install gagen[casadi])")
pin = pytest.importorskip("pinocchio")
gc = pytest.importorskip("gagen.casadi")

from test_casadi import tangent_map  # after the importorskips
from test_taskspace import Twin

PINOCCHIO = 1e-9
DIFFERENCES = 1e-6
TIGHT = 1e-12

ROBOTS = {
    "rrr": ("rrr", False),
    "panda": (str(SHARED_URDF / "panda.urdf"), False),
    "anymal": (str(SHARED_URDF / "anymal_c.urdf"), True),
}


class Robot:
    """A robot's dynamics, its Pinocchio twin, the kernels called through ctypes from its
    compiled module, and its CasADi functions."""

    def __init__(self, name: str):
        source, floating = ROBOTS[name]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", gagen.InertiaWarning)  # ANYmal's CAD round-off
            self.dyn = dyn = gagen.load(source, floating_base=floating)
        if name == "rrr":
            from gagen.model.numeric import numeric_model
            from gagen.reference.pinocchio import pinocchio_model

            model = pinocchio_model(numeric_model(dyn.model))
        else:
            model = pin.buildModelFromUrdf(source, pin.JointModelFreeFlyer()) if floating \
                else pin.buildModelFromUrdf(source)
        self.twin = Twin(dyn, model)
        lib = ctypes.CDLL(dyn.module.__file__)
        double_p = np.ctypeslib.ndpointer(np.float64, flags="C")
        from gagen.casadi.build import model_ident

        ident = model_ident(dyn)
        self._acc = getattr(lib, f"{ident}_frame_acceleration_derivatives")
        self._acc.argtypes = [double_p, double_p, ctypes.c_void_p, double_p, ctypes.c_int,
                              double_p, double_p]
        self._dj = getattr(lib, f"{ident}_frame_jacobian_time_variation_derivatives")
        self._dj.argtypes = [double_p, double_p, double_p, ctypes.c_int, double_p, double_p]
        self._dc = getattr(lib, f"{ident}_coriolis_matrix_derivatives")
        self._dc.argtypes = [double_p, double_p, double_p, ctypes.c_void_p, double_p,
                             double_p]
        self._dg = getattr(lib, f"{ident}_delassus_derivatives")
        self._dg.argtypes = [double_p, double_p, ctypes.c_int, double_p, double_p]
        self.p = dyn.parameter_vector()
        # the frames checked: every one of a small model, a spread and the feet otherwise
        frames = dyn.frames
        self.frames = frames if len(frames) <= 12 else sorted(
            set(frames[::4]) | {f for f in frames if f.endswith(("FOOT", "hand_tcp"))})

    @functools.cached_property
    def fns(self) -> dict:
        """The CasADi functions (they build the derivative module and the library)."""
        return gc.functions(self.dyn)

    def acceleration_derivatives(self, q, qd, qdd, frame: str):
        """(da/dq, da/dqd), 6 x nv each, from the C kernel (qdd None: the bias's)."""
        n = self.dyn.nv
        dq, dqd = np.empty((6, n)), np.empty((6, n))
        qdd_p = None if qdd is None else np.ascontiguousarray(qdd, dtype=float)
        status = self._acc(q, qd, None if qdd_p is None else qdd_p.ctypes.data, self.p,
                           self.dyn.frames.index(frame), dq, dqd)
        assert status == 0
        return dq, dqd

    def time_variation_derivatives(self, q, qd, frame: str):
        """(d J̇/dq, d J̇/dqd), each (6, nv, nv): [r, k, j] = d J̇[r, k] / d(q or qd)_j."""
        n = self.dyn.nv
        dq, dqd = np.empty((6, n, n)), np.empty((6, n, n))
        assert self._dj(q, qd, self.p, self.dyn.frames.index(frame), dq, dqd) == 0
        return dq, dqd


    def coriolis_derivatives(self, q, qd, by_qd: bool = False):
        """dC/dq (or with by_qd dC/dqd), (nv, nv, nv): [i, j, k] = d C_ij / dq_k along the
        velocity directions."""
        n = self.dyn.nv
        dq, dqd = np.empty((n, n, n)), np.empty((n, n, n))
        assert self._dc(q, qd, self.p, None, dq, dqd) == 0
        return dqd if by_qd else dq


    def delassus_derivatives(self, q, frame: str):
        """(G, dG/dq): (6, 6) and (6, 6, nv), [a, b, k] = d G_ab / dq_k."""
        G, dG = np.empty((6, 6)), np.empty((6, 6, self.dyn.nv))
        assert self._dg(q, self.p, self.dyn.frames.index(frame), G, dG) == 0
        return G, dG


@functools.cache
def robot_named(name: str) -> Robot:
    return Robot(name)


@pytest.fixture(scope="module", params=list(ROBOTS))
def robot(request, cache_dir):
    return robot_named(request.param)


# the CasADi functions' checks build each robot's derivative module and library (ANYmal C's
# take a minute and a half on two cores): the Panda's and ANYmal's run with the slow tests
@pytest.fixture(scope="module", params=[
    name if name == "rrr" else pytest.param(name, marks=pytest.mark.slow) for name in ROBOTS])
def casadi_robot(request, cache_dir):
    return robot_named(request.param)


def pinocchio_classical_derivatives(robot: Robot, q, qd, qdd, frame: str):
    """Pinocchio's derivatives of the classical LOCAL_WORLD_ALIGNED acceleration, in gagen's
    coordinates' order: from its LOCAL ones (the derivatives of the frame's own quantities;
    its LOCAL_WORLD_ALIGNED ones keep the frame's axes fixed), c = (a_lin + omega x v_lin,
    a_ang) in the frame's axes R, then d(R c)/dq_k = R dc/dq_k + w_k x (R c) with w_k the
    frame Jacobian's angular column k (world axes)."""
    twin, m, d = robot.twin, robot.twin.model, robot.twin.data
    qp, vp, ap = twin.q(q), twin.v(qd), twin.v(qdd)
    pin.computeForwardKinematicsDerivatives(m, d, qp, vp, ap)
    pin.updateFramePlacements(m, d)
    fid = twin.frame(frame)
    v_dq, a_dq, a_dv, _ = pin.getFrameAccelerationDerivatives(m, d, fid, pin.LOCAL)
    v = pin.getFrameVelocity(m, d, fid, pin.LOCAL).vector
    a = pin.getFrameAcceleration(m, d, fid, pin.LOCAL).vector
    J = pin.getFrameJacobian(m, d, fid, pin.LOCAL)
    R = d.oMf[fid].rotation
    w = twin.ours(pin.getFrameJacobian(m, d, fid, pin.LOCAL_WORLD_ALIGNED)[3:])
    lin, omega = v[:3], v[3:]
    c = np.concatenate([a[:3] + np.cross(omega, lin), a[3:]])

    def classical(da, dv):
        out = np.array(da, dtype=float)
        out[:3] += np.cross(dv[3:].T, lin).T + np.cross(omega, dv[:3].T).T
        return twin.ours(np.vstack([R @ out[:3], R @ out[3:]]))

    by_q = classical(a_dq, v_dq)
    for half in (slice(0, 3), slice(3, 6)):
        by_q[half] += np.cross(w.T, R @ c[half]).T
    return by_q, classical(a_dv, J)


def tangent_differences(f, dyn, q, h: float = 1e-3) -> np.ndarray:
    """Five-point central differences of f(q) along the velocity directions (q (+) h e_k)."""
    columns = []
    for k in range(dyn.nv):
        def at(s, k=k):
            return np.asarray(f(dyn.integrate(q, s * np.eye(dyn.nv)[k])), dtype=float)
        columns.append((-at(2 * h) + 8 * at(h) - 8 * at(-h) + at(-2 * h)) / (12 * h))
    return np.stack(columns, axis=-1)


def differences(f, x: np.ndarray, h: float = 1e-3) -> np.ndarray:
    columns = []
    for k in range(len(x)):
        def at(s, k=k):
            y = x.copy()
            y[k] += s
            return np.asarray(f(y), dtype=float)
        columns.append((-at(2 * h) + 8 * at(h) - 8 * at(-h) + at(-2 * h)) / (12 * h))
    return np.stack(columns, axis=-1)


def close(actual, expected, what: str, rtol: float) -> None:
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != {expected.shape}"
    scale = max(1.0, float(np.abs(expected).max(initial=0.0)))
    error = float(np.abs(actual - expected).max(initial=0.0))
    assert error <= rtol * scale, f"{what}: error {error:.3g} (scale {scale:.3g})"


def pinocchio_jacobian_derivative(robot: Robot, q, frame: str) -> np.ndarray:
    """dJ/dq (6, nv, nv) of the frame's LOCAL_WORLD_ALIGNED Jacobian, [r, i, k] = d J[r, i]/dq_k:
    Pinocchio's LOCAL frame velocity derivatives at qd = e_i, turned into world axes."""
    twin, m, d = robot.twin, robot.twin.model, robot.twin.data
    n = robot.dyn.nv
    out = np.empty((6, n, n))
    for i in range(n):
        pin.computeForwardKinematicsDerivatives(m, d, twin.q(q), twin.v(np.eye(n)[i]),
                                                np.zeros(m.nv))
        pin.updateFramePlacements(m, d)
        fid = twin.frame(frame)
        v_dq, _ = pin.getFrameVelocityDerivatives(m, d, fid, pin.LOCAL)
        R = d.oMf[fid].rotation
        column = pin.getFrameVelocity(m, d, fid, pin.LOCAL_WORLD_ALIGNED).vector
        w = twin.ours(pin.getFrameJacobian(m, d, fid, pin.LOCAL_WORLD_ALIGNED)[3:])
        # d(R x)/dq_k = R dx/dq_k + w_k x (R x), as for the accelerations
        for half in (slice(0, 3), slice(3, 6)):
            out[half, i, :] = R @ twin.ours(v_dq[half]) + np.cross(w.T, column[half]).T
    return out


def test_acceleration_derivatives_match_pinocchio(robot):
    """The classical acceleration's derivatives by q and qd, with qdd and at qdd = 0 (the
    bias acceleration's), against Pinocchio's getFrameAccelerationDerivatives."""
    rng = np.random.default_rng(5)
    for _ in range(2):
        q, qd, qdd = random_state(robot.dyn, rng)
        for frame in robot.frames:
            for acc in (qdd, None):
                ours = robot.acceleration_derivatives(q, qd, acc, frame)
                expected = pinocchio_classical_derivatives(
                    robot, q, qd, np.zeros_like(qdd) if acc is None else acc, frame)
                for port, a, b in zip(("q", "qd"), ours, expected):
                    close(a, b, f"{frame} da/d{port} (qdd {'0' if acc is None else 'random'})",
                          PINOCCHIO)


def test_kernels_match_central_differences_of_gagen_s_functions(robot):
    dyn = robot.dyn
    rng = np.random.default_rng(6)
    q, qd, qdd = random_state(dyn, rng)
    for frame in robot.frames:
        by_q, by_qd = robot.acceleration_derivatives(q, qd, qdd, frame)
        close(by_q, tangent_differences(lambda x, f=frame: dyn.frame_acceleration(x, qd, qdd, f),
                                        dyn, q), f"{frame} da/dq", DIFFERENCES)
        close(by_qd, differences(lambda x, f=frame: dyn.frame_acceleration(q, x, qdd, f), qd),
              f"{frame} da/dqd", DIFFERENCES)
        by_q, by_qd = robot.time_variation_derivatives(q, qd, frame)
        close(by_q, tangent_differences(
            lambda x, f=frame: dyn.frame_jacobian_time_variation(x, qd, f), dyn, q),
            f"{frame} dJdot/dq", DIFFERENCES)
        close(by_qd, differences(
            lambda x, f=frame: dyn.frame_jacobian_time_variation(q, x, f), qd),
            f"{frame} dJdot/dqd", DIFFERENCES)


def test_time_variation_derivatives_meet_their_identities(robot):
    """J̇ = sum_j (dJ/dq_j) qd_j, so d J̇/dqd = dJ/dq (here Pinocchio's); the bias
    acceleration is J̇ qd, so its derivatives are (d J̇/dq) qd and J̇ + (d J̇/dqd) qd (the
    two kernels against each other)."""
    dyn = robot.dyn
    q, qd, _ = random_state(dyn, np.random.default_rng(7))
    for frame in robot.frames:
        by_q, by_qd = robot.time_variation_derivatives(q, qd, frame)
        close(by_qd, pinocchio_jacobian_derivative(robot, q, frame),
              f"{frame} dJdot/dqd = dJ/dq", PINOCCHIO)
        bias_q, bias_qd = robot.acceleration_derivatives(q, qd, None, frame)
        close(bias_q, np.einsum("rkj,k->rj", by_q, qd), f"{frame} d(J̇ qd)/dq", TIGHT)
        close(bias_qd, dyn.frame_jacobian_time_variation(q, qd, frame)
              + np.einsum("rkj,k->rj", by_qd, qd), f"{frame} d(J̇ qd)/dqd", TIGHT)


def casadi_jacobians(function, q, qd, u, frame: int) -> dict[str, np.ndarray]:
    ports = [function.name_in(i) for i in range(function.n_in())]
    symbols = [ca.MX.sym(port, function.sparsity_in(i)) for i, port in enumerate(ports)]
    out = ca.vec(function(*symbols))
    wanted = [(port, s) for port, s in zip(ports, symbols) if port != "frame"]
    jac = ca.Function("j", symbols, [ca.jacobian(out, s) for _, s in wanted])
    values = {"q": q, "qd": qd, "qdd": u, "frame": frame}
    blocks = jac.call([ca.DM(np.atleast_1d(np.asarray(values[p], dtype=float))) for p in ports])
    return {port: np.array(b.full()) for (port, _), b in zip(wanted, blocks)}


def test_casadi_jacobians_are_the_kernels(casadi_robot):
    robot = casadi_robot
    dyn = robot.dyn
    q, qd, qdd = random_state(dyn, np.random.default_rng(8))
    G = tangent_map(dyn, q)
    for frame in robot.frames:
        number = dyn.frames.index(frame)
        acc = casadi_jacobians(robot.fns["frame_acceleration"], q, qd, qdd, number)
        by_q, by_qd = robot.acceleration_derivatives(q, qd, qdd, frame)
        close(acc["q"] @ G, by_q, f"{frame} frame_acceleration by q", TIGHT)
        close(acc["qd"], by_qd, f"{frame} frame_acceleration by qd", TIGHT)
        close(acc["qdd"], dyn.frame_jacobian(q, frame), f"{frame} by qdd", TIGHT)
        bias = casadi_jacobians(robot.fns["frame_bias_acceleration"], q, qd, qdd, number)
        by_q, by_qd = robot.acceleration_derivatives(q, qd, None, frame)
        close(bias["q"] @ G, by_q, f"{frame} frame_bias_acceleration by q", TIGHT)
        close(bias["qd"], by_qd, f"{frame} frame_bias_acceleration by qd", TIGHT)
        tv = casadi_jacobians(robot.fns["frame_jacobian_time_variation"], q, qd, qdd, number)
        by_q, by_qd = robot.time_variation_derivatives(q, qd, frame)

        def casadi_order(D):  # rows J̇[r, k] in CasADi's column-major order: k 6 + r
            return D.transpose(1, 0, 2).reshape(6 * dyn.nv, dyn.nv)
        close(tv["q"] @ G, casadi_order(by_q), f"{frame} J̇ by q", TIGHT)
        close(tv["qd"], casadi_order(by_qd), f"{frame} J̇ by qd", TIGHT)
        dG = casadi_jacobians(robot.fns["delassus"], q, qd, qdd, number)["q"] @ G
        # CasADi's rows are G's entries column-major: b 6 + a
        close(dG.reshape(6, 6, dyn.nv).transpose(1, 0, 2),
              robot.delassus_derivatives(q, frame)[1], f"{frame} delassus by q", TIGHT)


def test_delassus_derivative_matches_its_formula_on_pinocchio_s_terms(robot):
    """<model>_delassus_derivatives: G as delassus gives it, and dG/dq = dJ Y + Y^T dJ^T
    - Y^T dM Y (Y = M^-1 J^T), with dM y from Pinocchio's RNEA derivatives at (q, 0, y)
    less those at (q, 0, 0) and dJ column by column from Pinocchio's frame velocity
    derivatives at qd = e_i (d(J e_i)/dq); and against central differences."""
    dyn, twin = robot.dyn, robot.twin
    m, d = twin.model, twin.data
    q, _, _ = random_state(dyn, np.random.default_rng(9))
    zero = np.zeros(dyn.nv)
    qp = twin.q(q)

    def dtau_dq(acc):
        dq, _, _ = pin.computeRNEADerivatives(m, d, qp, twin.v(zero), twin.v(acc))
        return twin.ours(dq[twin.v_index])

    gravity = dtau_dq(zero)
    M = dyn.mass_matrix(q)
    for frame in robot.frames:
        G, ours = robot.delassus_derivatives(q, frame)
        close(G, dyn.delassus(q, [frame]), f"{frame} G", TIGHT)
        J = dyn.frame_jacobian(q, frame)
        Y = np.linalg.solve(M, J.T)
        dJ = pinocchio_jacobian_derivative(robot, q, frame)
        dMY = np.stack([dtau_dq(Y[:, b]) - gravity for b in range(6)], axis=1)  # (nv, 6, nv)
        expected = (np.einsum("aik,ib->abk", dJ, Y) + np.einsum("ia,bik->abk", Y, dJ)
                    - np.einsum("ia,ibk->abk", Y, dMY))
        close(ours, expected, f"{frame} dG/dq", PINOCCHIO)
        close(ours, tangent_differences(lambda x, f=frame: dyn.delassus(x, [f]), dyn, q),
              f"{frame} dG/dq (differences)", DIFFERENCES)


# ------------------------------------------------------------------ the Coriolis matrix

def test_coriolis_derivative_matches_central_differences(robot):
    """<model>_coriolis_matrix_derivatives against five-point differences of gagen's
    coriolis_matrix along the velocity directions (Pinocchio has no dC/dq), and by qd
    against C(q, e_k)."""
    dyn = robot.dyn
    rng = np.random.default_rng(10)
    for _ in range(2):
        q, qd, _ = random_state(dyn, rng)
        close(robot.coriolis_derivatives(q, qd),
              tangent_differences(lambda x, qd=qd: dyn.coriolis_matrix(x, qd), dyn, q),
              "dC/dq", DIFFERENCES)
        # C is linear in qd: dC/dqd_k = C(q, e_k)
        close(robot.coriolis_derivatives(q, qd, by_qd=True),
              np.stack([dyn.coriolis_matrix(q, e) for e in np.eye(dyn.nv)], axis=-1),
              "dC/dqd", TIGHT)


def test_coriolis_derivative_meets_mdot_identity(casadi_robot):
    """Mdot = C + C^T, differentiated: d Mdot/dq_k = dC/dq_k + (dC/dq_k)^T, with
    Mdot(q, qd) = sum_j dM/dq_j qd_j from the CasADi mass matrix's analytic Jacobian (the
    inverse-dynamics derivatives) and its derivative by central differences; and CasADi's
    jacobian() of coriolis_matrix by q is the kernel."""
    robot = casadi_robot
    dyn = robot.dyn
    n = dyn.nv
    mass = robot.fns["mass_matrix"]
    s = ca.MX.sym("q", dyn.nq)
    jac_m = ca.Function("jm", [s], [ca.jacobian(ca.vec(mass(s)), s)])
    q, qd, _ = random_state(dyn, np.random.default_rng(11))

    def mdot(x):  # CasADi's entries column-major: row j n + i is M[i, j]
        dM = np.array(jac_m(x).full()) @ tangent_map(dyn, x)
        return (dM @ qd).reshape(n, n).T

    dC = robot.coriolis_derivatives(q, qd)
    close(dC + dC.transpose(1, 0, 2), tangent_differences(mdot, dyn, q),
          "d(C + C^T)/dq = d Mdot/dq", DIFFERENCES)
    blocks = casadi_jacobians(robot.fns["coriolis_matrix"], q, qd, qd, 0)
    close(blocks["q"] @ tangent_map(dyn, q), dC.transpose(1, 0, 2).reshape(n * n, n),
          "CasADi's dC/dq", TIGHT)
    close(blocks["qd"], robot.coriolis_derivatives(q, qd, by_qd=True).transpose(1, 0, 2)
          .reshape(n * n, n), "CasADi's dC/dqd", TIGHT)
