"""Physically consistent identification: every parameter of the robot, not only the base
combinations, with masses positive, inertias that a real mass distribution can have, and
damping, friction and armature non-negative.

Least squares on the base parameters may give a model no rigid body can have (a negative
mass, an inertia breaking the triangle inequality), and says nothing about the
combinations the data cannot see. Here each moving body's ten parameters are written in
the log-Cholesky parameterisation of Rucker and Wensing ("Smooth parameterization of
rigid-body inertia", IEEE RA-L 2022): with theta = (alpha, d1, d2, d3, s12, s23, s13, t1,
t2, t3),

    U = e^alpha [[e^d1, s12, s13, t1], [0, e^d2, s23, t2], [0, 0, e^d3, t3], [0, 0, 0, 1]],
    J = U U^T = [[Sigma, h], [h^T, m]],  I_O = tr(Sigma) E - Sigma,

where J is the body's pseudo-inertia (Sigma = the second moment of its mass about O): every
theta gives a positive definite J, i.e. a physically consistent body, and every one is
reached. Damping, friction and armature are bounded below by 0. Then

    minimise  (K pi - pi_b)^T A^T W A (K pi - pi_b) / sigma^2  +  lambda |(pi - pi_0) / s|^2

over theta, by scipy.optimize.least_squares (trust region reflective, exact Jacobian).
The first term is the weighted squared residual of the torques less its least-squares
minimum (pi_b, A, sigma: the unconstrained estimate, base regressor and residual standard
deviation of `identify`, K the grouping), in units of the noise: moving a base parameter
by one standard deviation costs 1. The data enter as r numbers instead of N n. The second
term pulls what the data leaves undetermined towards a prior pi_0 (default: the model's
own parameters), each parameter relative to s = max(|pi_0|, 1e-3): with lambda = 1e-2
(default) a 100 % change of one parameter costs as much as moving a base parameter by a
tenth of its standard deviation, so the prior decides the directions the data cannot see
and barely touches the others.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .identification import IdentificationResult, identify, residuals

# (row, column) of I_O for a body's last six parameters (Pinocchio's order)
_INERTIA = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))
_FLIP = np.eye(4)[::-1]
MAX_EVALUATIONS = 2000


@dataclass
class ConsistentIdentification:
    """What `identify_consistent` found.

    parameters     pi, every regressor parameter (names: `names`), physically consistent
    base_values    K pi, the base parameters it implies (compare with `unconstrained`)
    unconstrained  the IdentificationResult of plain least squares on the same data
    residual, rms  tau - Y pi per sample and joint, and its RMS per joint
    success        whether the optimiser converged; `message` says how
    """

    parameters: np.ndarray
    names: list[str]
    base_values: np.ndarray
    unconstrained: IdentificationResult
    residual: np.ndarray
    rms: np.ndarray
    success: bool
    message: str
    dyn: object = field(default=None, repr=False)

    def predict(self, q, qd, qdd) -> np.ndarray:
        """The torques of the identified robot, Y(q, qd, qdd) pi."""
        return self.dyn.regressor(q, qd, qdd, self.unconstrained.p) @ self.parameters

    def bodies(self) -> dict[str, tuple[float, np.ndarray, np.ndarray]]:
        """Per moving body: (mass, mass centre, central inertia), in its frame."""
        out = {}
        for i in range(len(self.names) // 10):
            if not self.names[10 * i].startswith("m_"):
                break
            body = self.names[10 * i][2:]
            m, h, I_O = _unpack(self.parameters[10 * i:10 * i + 10])
            c = h / m
            out[body] = (m, c, I_O - m * (c @ c * np.eye(3) - np.outer(c, c)))
        return out

    def as_parameters(self) -> dict[str, float]:
        """The identified robot as overrides of the model's parameters, for models that
        name them as gagen's URDF reader does (`m_<link>`, `cx_<link>`, `Ixx_<link>`
        (central), ..., `damping_<joint>`, `friction_<joint>`, `armature_<joint>`): pass it
        as `p=` to simulate the identified robot. KeyError when the model does not."""
        names = set(self.dyn.parameters)
        out: dict[str, float] = {}
        for body, (m, c, I_C) in self.bodies().items():
            out[f"m_{body}"] = m
            out.update({f"c{a}_{body}": c[k] for k, a in enumerate("xyz")})
            for key, (r, s) in (("Ixx", (0, 0)), ("Iyy", (1, 1)), ("Izz", (2, 2)),
                                ("Ixy", (0, 1)), ("Ixz", (0, 2)), ("Iyz", (1, 2))):
                out[f"{key}_{body}"] = I_C[r, s]
        joints = [j.name for j in self.dyn.info.joints if j.type != "floating"]
        m = len(joints)
        terms = self.parameters[len(self.parameters) - 3 * m:]
        for k, key in enumerate(("damping", "friction", "armature")):
            out.update({f"{key}_{name}": terms[k * m + j] for j, name in enumerate(joints)})
        missing = sorted(set(out) - names)
        if missing:
            raise KeyError(f"the model has no parameters {', '.join(missing[:5])}"
                           + (" ..." if len(missing) > 5 else ""))
        return {k: float(v) for k, v in out.items()}


def identify_consistent(dyn, q, qd, qdd, tau, weights=None, p=None, min_speed=0.0,
                        prior=None, regularization: float = 1e-2) -> ConsistentIdentification:
    """Identify every parameter of the robot, physically consistent (module docstring).

    q, qd, qdd, tau, weights, p and min_speed as for `identify`. `prior`: the parameter vector pi_0
    (as `dyn.regressor_parameters()`) that fills in what the data cannot determine, and
    the starting point; default `dyn.regressor_parameters(p)`. `regularization`: lambda.
    """
    from scipy.optimize import least_squares

    base = identify(dyn, q, qd, qdd, tau, weights, p, min_speed)
    pv = base.p
    prior = dyn.regressor_parameters(pv) if prior is None else np.asarray(prior, dtype=float)
    P, m = len(dyn.regressor_names), len(dyn.info.jointed_coordinates())
    bodies = (P - 3 * m) // 10
    if prior.shape != (P,):
        raise ValueError(f"prior must have {P} entries (dyn.regressor_names)")
    K = base.grouping.matrix
    L = np.linalg.cholesky(base.information) / base.sigma  # information / sigma^2 = L L^T
    scale = np.maximum(np.abs(prior), 1e-3)
    weight = np.sqrt(regularization)

    def parameters(theta: np.ndarray) -> np.ndarray:
        return np.concatenate([*(_from_log_cholesky(theta[10 * i:10 * i + 10])
                                 for i in range(bodies)), theta[10 * bodies:]])

    def residual(theta: np.ndarray) -> np.ndarray:
        pi = parameters(theta)
        return np.concatenate([L.T @ (K @ pi - base.values), weight * (pi - prior) / scale])

    outer = np.vstack([L.T @ K, np.diag(weight / scale)])  # d residual / d pi

    def jacobian(theta: np.ndarray) -> np.ndarray:
        dpi = np.zeros((P, P))  # d pi / d theta: block diagonal, identity for joint terms
        for i in range(bodies):
            block = slice(10 * i, 10 * i + 10)
            dpi[block, block] = _log_cholesky_jacobian(theta[block])
        dpi[10 * bodies:, 10 * bodies:] = np.eye(P - 10 * bodies)
        return outer @ dpi

    theta0 = np.concatenate([*(_to_log_cholesky(prior[10 * i:10 * i + 10])
                               for i in range(bodies)), np.maximum(prior[10 * bodies:], 0.0)])
    lower = np.concatenate([np.full(10 * bodies, -np.inf), np.zeros(3 * m)])
    fit = least_squares(residual, theta0, jac=jacobian, bounds=(lower, np.inf),
                        method="trf", x_scale="jac", max_nfev=MAX_EVALUATIONS)
    pi = parameters(fit.x)
    q, qd, qdd, tau = (np.asarray(a, dtype=float) for a in (q, qd, qdd, tau))
    res = residuals(dyn, q, qd, qdd, tau, pi, pv)
    return ConsistentIdentification(
        parameters=pi, names=list(dyn.regressor_names), base_values=K @ pi, unconstrained=base,
        residual=res, rms=np.sqrt(np.mean(res**2, axis=0)), success=bool(fit.success),
        message=str(fit.message), dyn=dyn)


def pseudo_inertia(body: np.ndarray) -> np.ndarray:
    """J = [[Sigma, h], [h^T, m]] of a body's ten parameters (Pinocchio's order)."""
    m, h, I_O = _unpack(body)
    J = np.empty((4, 4))
    J[:3, :3] = 0.5 * np.trace(I_O) * np.eye(3) - I_O
    J[:3, 3] = J[3, :3] = h
    J[3, 3] = m
    return J


def _unpack(body: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    I_O = np.empty((3, 3))
    for (r, c), value in zip(_INERTIA, body[4:]):
        I_O[r, c] = I_O[c, r] = value
    return float(body[0]), np.asarray(body[1:4], dtype=float), I_O


# where each of theta's entries d1 .. t3 sits in U (alpha scales all of U)
_ENTRIES = ((0, 0), (1, 1), (2, 2), (0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3))


def _factor(theta: np.ndarray) -> np.ndarray:
    # exponents clipped: a trial step of the optimiser must not overflow (e^40 kg is no mass)
    alpha, d1, d2, d3 = np.clip(theta[:4], -40.0, 40.0)
    s12, s23, s13, t1, t2, t3 = theta[4:]
    return np.exp(alpha) * np.array([[np.exp(d1), s12, s13, t1], [0.0, np.exp(d2), s23, t2],
                                     [0.0, 0.0, np.exp(d3), t3], [0.0, 0.0, 0.0, 1.0]])


def _parameters_of(J: np.ndarray) -> np.ndarray:
    """A body's ten parameters from its pseudo-inertia (linear in J)."""
    Sigma = J[:3, :3]
    I_O = np.trace(Sigma) * np.eye(3) - Sigma
    return np.array([J[3, 3], *J[:3, 3], *(I_O[r, c] for r, c in _INERTIA)])


def _from_log_cholesky(theta: np.ndarray) -> np.ndarray:
    U = _factor(theta)
    return _parameters_of(U @ U.T)


def _log_cholesky_jacobian(theta: np.ndarray) -> np.ndarray:
    """d pi / d theta (10 x 10): dJ = dU U^T + U dU^T, and pi is linear in J."""
    U = _factor(theta)
    columns = [_parameters_of(2 * U @ U.T)]  # dU/d alpha = U
    for k, (r, c) in enumerate(_ENTRIES):
        dU = np.zeros((4, 4))
        dU[r, c] = U[r, c] if k < 3 else U[3, 3]  # e^(alpha + d) or e^alpha
        columns.append(_parameters_of(dU @ U.T + U @ dU.T))
    return np.column_stack(columns)


def _to_log_cholesky(body: np.ndarray) -> np.ndarray:
    """theta of a body (its pseudo-inertia nudged to positive definite if it is not:
    a point mass or a massless body of the prior)."""
    J = pseudo_inertia(body)
    J = 0.5 * (J + J.T)
    floor = 1e-6 * max(1e-3, np.abs(J).max())
    eigenvalues, vectors = np.linalg.eigh(J)
    J = (vectors * np.maximum(eigenvalues, floor)) @ vectors.T
    U = _FLIP @ np.linalg.cholesky(_FLIP @ J @ _FLIP) @ _FLIP  # upper: J = U U^T
    scale = U[3, 3]
    diag = np.diag(U)[:3] / scale
    return np.array([np.log(scale), *np.log(diag), U[0, 1] / scale, U[1, 2] / scale,
                     U[0, 2] / scale, *(U[:3, 3] / scale)])
