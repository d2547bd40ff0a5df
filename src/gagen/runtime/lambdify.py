"""The reference backend: the derived expressions evaluated through `sympy.lambdify`."""

from __future__ import annotations

import numpy as np
import sympy as sp

from ..errors import NonFiniteStateError
from ..manifest import ModelInfo
from ..symbolic.gibbs_appell import Equations
from .dynamics import Dynamics, SingularMassMatrixError, as_states


def _needed_intermediates(eqs: Equations, exprs) -> list[tuple[sp.Symbol, sp.Expr]]:
    """The intermediate definitions the expressions depend on, in definition order."""
    defined = {s: (k, e) for k, (s, e) in enumerate(eqs.intermediates)}
    needed: set[sp.Symbol] = set()
    stack = [s for x in exprs for s in sp.sympify(x).free_symbols if s in defined]
    while stack:
        s = stack.pop()
        if s not in needed:
            needed.add(s)
            stack.extend(t for t in defined[s][1].free_symbols if t in defined)
    return [eqs.intermediates[k] for k in sorted(defined[s][0] for s in needed)]


class LambdifyDynamics(Dynamics):
    """`gagen.load(..., backend="lambdify")`: NumPy functions made by `sympy.lambdify`.

    The intermediates of the derivation are handed to lambdify as its common
    subexpressions, so each is computed once per call, as in the derivation.
    """

    backend = "lambdify"

    def __init__(self, eqs: Equations):
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
        n = self.n
        self._lower = np.tril_indices(n)

    def _lambdify(self, args, exprs):
        """A NumPy function of the flattened args; lambdify sees none of the users' names.

        Arguments become `a<k>` and intermediates `t<k>`: a parameter called `sin` or a
        joint called like an intermediate cannot shadow anything in the generated code."""
        flat_args = [s for group in args for s in group]
        needed = _needed_intermediates(self.equations, exprs)
        rename = {s: sp.Symbol(f"a{k}") for k, s in enumerate(flat_args)}
        rename.update({s: sp.Symbol(f"t{k}") for k, (s, _) in enumerate(needed)})
        definitions = [(rename[s], e.xreplace(rename)) for s, e in needed]
        renamed = [sp.sympify(e).xreplace(rename) for e in exprs]
        return sp.lambdify([rename[s] for s in flat_args], renamed, modules="numpy",
                           cse=lambda expressions: (definitions, expressions))

    def _call(self, fn, states, p, stacked):
        pv = self.parameter_vector(p)
        columns = [col for s in states for col in (s.T if stacked else s)]
        values = fn(*columns, *pv)
        if stacked:
            count = states[0].shape[0]
            return np.stack([np.broadcast_to(v, (count,)) for v in values], axis=-1).astype(float)
        return np.array(values, dtype=float)

    def mass_matrix(self, q, p=None) -> np.ndarray:
        (q,), stacked = as_states(self.n, q, names=("q",))
        lower = self._call(self._mass, [q], p, stacked)
        M = np.zeros(lower.shape[:-1] + (self.n, self.n))
        M[..., self._lower[0], self._lower[1]] = lower
        M[..., self._lower[1], self._lower[0]] = lower
        return M

    def forcing(self, q, qd, tau, p=None) -> np.ndarray:
        states, stacked = as_states(self.n, q, qd, tau, names=("q", "qd", "tau"))
        return self._call(self._forcing, states, p, stacked)

    def forward_dynamics(self, q, qd, tau, p=None) -> np.ndarray:
        M = self.mass_matrix(q, p)
        F = self.forcing(q, qd, tau, p)
        if not np.isfinite(M).all():  # LAPACK may pass NaN through instead of failing
            raise NonFiniteStateError(
                "the mass matrix is NaN or inf at this state: q holds NaN or inf")
        try:
            L = np.linalg.cholesky(M)
        except np.linalg.LinAlgError:
            raise SingularMassMatrixError(
                "mass matrix is singular or not positive definite at this state") from None
        y = np.linalg.solve(L, F[..., None])
        return np.linalg.solve(np.swapaxes(L, -1, -2), y)[..., 0]

    def inverse_dynamics(self, q, qd, qdd, p=None) -> np.ndarray:
        states, stacked = as_states(self.n, q, qd, qdd, names=("q", "qd", "qdd"))
        return self._call(self._inverse, states, p, stacked)

    def gravity(self, q, p=None) -> np.ndarray:
        """The gravity torques g(q) = inverse_dynamics(q, 0, 0)."""
        (q,), stacked = as_states(self.n, q, names=("q",))
        return self._call(self._gravity, [q], p, stacked)

    def energy(self, q, qd, p=None) -> tuple:
        states, stacked = as_states(self.n, q, qd, names=("q", "qd"))
        values = self._call(self._energy, states, p, stacked)
        if stacked:
            return values[:, 0].copy(), values[:, 1].copy()
        return float(values[0]), float(values[1])
