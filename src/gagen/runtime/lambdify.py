"""The reference backend: the derived expressions evaluated through `sympy.lambdify`."""

from __future__ import annotations

import logging
import time
from functools import cached_property

import numpy as np
import sympy as sp

from ..errors import NonFiniteStateError
from ..manifest import ModelInfo
from ..symbolic.derivatives import DerivativeEquations, derive_derivatives
from ..symbolic.differentiate import needed_definitions
from ..symbolic.gibbs_appell import Equations
from .dynamics import Dynamics, SingularMassMatrixError, as_states
from .inputs import check_quaternions, nonfinite_cause

log = logging.getLogger(__name__)


class LambdifyDynamics(Dynamics):
    """`gagen.load(..., backend="lambdify")`: NumPy functions made by `sympy.lambdify`.

    The intermediates of the derivation are handed to lambdify as its common
    subexpressions, so each is computed once per call, as in the derivation.
    """

    backend = "lambdify"

    def __init__(self, eqs: Equations):
        from ..symbolic.regressor import with_regressor

        eqs = with_regressor(eqs)
        self.__dict__["_model"] = eqs.model
        self.info = ModelInfo.from_model(eqs.model)
        self.equations = eqs
        c = eqs.coords
        outs = eqs.outputs()
        p = eqs.parameters
        self._mass = self._lambdify([c.q, p], outs["mass_matrix"])
        self._forcing = self._lambdify([c.q, c.qd, c.tau, p], outs["forcing"])
        self._inverse = self._lambdify([c.q, c.qd, c.qdd, p], outs["inverse_dynamics"])
        self._energy = self._lambdify([c.q, c.qd, p], outs["energy"])
        self._gravity = self._lambdify([c.q, p], outs["gravity"])
        if "placements" in outs:
            self._placement_function = self._lambdify([c.q, p], outs["placements"])
            self._offset_function = self._lambdify([p], outs["frame_offsets"])
        regressor = eqs.regressor_outputs()
        program = eqs.intermediates + eqs.regressor_intermediates
        self._regressor = self._lambdify([c.q, c.qd, c.qdd, p], regressor["regressor"], program)
        self._pi = self._lambdify([p], regressor["regressor_parameters"], program)
        n = self.n
        self._lower = np.tril_indices(n)

    def _lambdify(self, args, exprs, definitions=None):
        """A NumPy function of the flattened args; lambdify sees none of the users' names.

        `definitions` is the program the expressions are written in (default: the
        equations' intermediates). Arguments become `a<k>` and intermediates `t<k>`: a
        parameter called `sin` or a joint called like an intermediate cannot shadow
        anything in the generated code."""
        flat_args = [s for group in args for s in group]
        if definitions is None:
            definitions = self.equations.intermediates
        needed = needed_definitions(definitions, exprs)
        rename = {s: sp.Symbol(f"a{k}") for k, s in enumerate(flat_args)}
        rename.update({s: sp.Symbol(f"t{k}") for k, (s, _) in enumerate(needed)})
        definitions = [(rename[s], e.xreplace(rename)) for s, e in needed]
        renamed = [sp.sympify(e).xreplace(rename) for e in exprs]
        return sp.lambdify([rename[s] for s in flat_args], renamed, modules="numpy",
                           cse=lambda expressions: (definitions, expressions))

    def _call(self, fn, states, p, stacked):
        check_quaternions(states[0], self._quaternions)  # every kernel's first state is q
        pv = self.parameter_vector(p)
        columns = [col for s in states for col in (s.T if stacked else s)]
        values = fn(*columns, *pv)
        if stacked:
            count = states[0].shape[0]
            return np.stack([np.broadcast_to(v, (count,)) for v in values], axis=-1).astype(float)
        return np.array(values, dtype=float)

    def mass_matrix(self, q, p=None) -> np.ndarray:
        (q,), stacked = as_states(self.nq, q, names=("q",))
        lower = self._call(self._mass, [q], p, stacked)
        M = np.zeros(lower.shape[:-1] + (self.n, self.n))
        M[..., self._lower[0], self._lower[1]] = lower
        M[..., self._lower[1], self._lower[0]] = lower
        return M

    def forcing(self, q, qd, tau, p=None) -> np.ndarray:
        states, stacked = as_states(self._sizes, q, qd, tau, names=("q", "qd", "tau"))
        return self._call(self._forcing, states, p, stacked)

    def forward_dynamics(self, q, qd, tau, p=None, fext=None) -> np.ndarray:
        if fext is not None:
            (q, tau), _ = as_states(self._sizes[::2], q, tau, names=("q", "tau"))
            tau = tau + self.external_forces(q, fext, p)
        L = _cholesky(self.mass_matrix(q, p), q)
        return _cholesky_solve(L, self.forcing(q, qd, tau, p)[..., None])[..., 0]

    def inverse_dynamics(self, q, qd, qdd, p=None, fext=None) -> np.ndarray:
        states, stacked = as_states(self._sizes, q, qd, qdd, names=("q", "qd", "qdd"))
        tau = self._call(self._inverse, states, p, stacked)
        return tau if fext is None else tau - self.external_forces(q, fext, p)

    def _placements(self, q, p) -> np.ndarray:
        stacked = q.ndim == 2
        return self._call(self._placement_function, [q], p, stacked)

    def _frame_offsets(self, p) -> np.ndarray:
        return np.array(self._offset_function(*self.parameter_vector(p)), dtype=float)

    def gravity(self, q, p=None) -> np.ndarray:
        """The gravity torques g(q) = inverse_dynamics(q, 0, 0)."""
        (q,), stacked = as_states(self.nq, q, names=("q",))
        return self._call(self._gravity, [q], p, stacked)

    def energy(self, q, qd, p=None) -> tuple:
        states, stacked = as_states(self._sizes, q, qd, names=("q", "qd"))
        values = self._call(self._energy, states, p, stacked)
        if stacked:
            return values[:, 0].copy(), values[:, 1].copy()
        return float(values[0]), float(values[1])

    # --- derivatives (gagen.symbolic.derivatives: its docstring says how they compose) ----

    @cached_property
    def derivative_equations(self) -> DerivativeEquations:
        """The derivative kernels' program, derived on first use (not at load)."""
        start = time.perf_counter()
        derivatives = derive_derivatives(self.equations)
        log.info("%s: derivatives derived in %.2f s", self.info.name,
                 time.perf_counter() - start)
        return derivatives

    @cached_property
    def _derivative_functions(self) -> dict:
        d = self.derivative_equations
        args = d.arguments()
        return {name: self._lambdify(args[name], exprs, d.intermediates)
                for name, exprs in d.outputs().items()}

    def inverse_dynamics_derivatives(self, q, qd, qdd, p=None) -> tuple:
        states, stacked = as_states(self._sizes, q, qd, qdd, names=("q", "qd", "qdd"))
        fn = self._derivative_functions["inverse_dynamics_derivatives"]
        values = self._call(fn, states, p, stacked)
        both = values.reshape(values.shape[:-1] + (2, self.n, self.n))
        return both[..., 0, :, :].copy(), both[..., 1, :, :].copy()

    def coriolis_matrix(self, q, qd, p=None) -> np.ndarray:
        states, stacked = as_states(self._sizes, q, qd, names=("q", "qd"))
        values = self._call(self._derivative_functions["coriolis_matrix"], states, p, stacked)
        return values.reshape(values.shape[:-1] + (self.n, self.n))

    def forward_dynamics_derivatives(self, q, qd, tau, p=None) -> tuple:
        (q, qd, tau), _ = as_states(self._sizes, q, qd, tau, names=("q", "qd", "tau"))
        p = self.parameter_vector(p)
        L = _cholesky(self.mass_matrix(q, p), q)
        qdd = _cholesky_solve(L, self.forcing(q, qd, tau, p)[..., None])[..., 0]
        dtau_dq, dtau_dqd = self.inverse_dynamics_derivatives(q, qd, qdd, p)
        M_inv = _cholesky_solve(L, np.broadcast_to(np.eye(self.n), L.shape))
        M_inv = 0.5 * (M_inv + np.swapaxes(M_inv, -1, -2))  # symmetric, as M^-1 is
        return -_cholesky_solve(L, dtau_dq), -_cholesky_solve(L, dtau_dqd), M_inv


    def regressor(self, q, qd, qdd, p=None) -> np.ndarray:
        states, stacked = as_states(self._sizes, q, qd, qdd, names=("q", "qd", "qdd"))
        flat = self._call(self._regressor, states, p, stacked)
        return flat.reshape(flat.shape[:-1] + (self.n, -1))

    def regressor_parameters(self, p=None) -> np.ndarray:
        return np.array(self._pi(*self.parameter_vector(p)), dtype=float)


def _cholesky(M: np.ndarray, q=None) -> np.ndarray:
    """The lower Cholesky factor of M (or of each stacked M), with the runtime's errors."""
    if not np.isfinite(M).all():  # LAPACK may pass NaN through instead of failing
        if q is not None and np.ndim(q) == 2:
            row = int(np.flatnonzero(~np.isfinite(M.reshape(len(M), -1)).all(axis=1))[0])
            q = np.asarray(q)[row]
        raise NonFiniteStateError(
            f"the mass matrix is NaN or inf at this state: {nonfinite_cause(q)}")
    try:
        return np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        raise SingularMassMatrixError(
            "mass matrix is singular or not positive definite at this state") from None


def _cholesky_solve(L: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """X with L L^T X = rhs (rhs (..., n, k)): two triangular solves."""
    y = np.linalg.solve(L, rhs)
    return np.linalg.solve(np.swapaxes(L, -1, -2), y)
