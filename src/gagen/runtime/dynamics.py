"""The runtime API, written once for every backend: names, parameters, and the documented
dynamics methods (the backends supply the numbers)."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from ..errors import SingularMassMatrixError  # noqa: F401 (re-exported)
from ..manifest import ModelInfo
from .inputs import as_states, parameter_array  # noqa: F401 (as_states re-exported)


class Dynamics:
    """A model's equations of motion, M(q) q̈ = F(q, q̇, τ), evaluated numerically.

    Every method takes one state (arrays of shape (n,)) or N stacked states (shape (N, n))
    and returns fresh arrays: nothing returned is ever overwritten by a later call.
    `p` is None (the model's defaults), a dict of overrides by name, or a full array in
    `parameters` order.
    """

    backend: str
    info: ModelInfo
    _model_ref: object = None

    # --- names and parameters --------------------------------------------------------------

    @property
    def model(self):
        """The full `gagen.model.Model` (symbolic; read from its source on first use)."""
        model = self.__dict__.get("_model")
        if model is None:
            from ..model.resolve import resolve_model

            model = self.__dict__["_model"] = resolve_model(self._model_ref)
        return model

    @property
    def coordinates(self) -> list[str]:
        """The coordinates' names (the moving joints), in the order of q."""
        return list(self._coordinates)

    @property
    def parameters(self) -> dict[str, float]:
        """The parameters' names and default values, in the order of a p array."""
        return self.info.parameter_defaults

    @property
    def n(self) -> int:
        """The number of coordinates."""
        return len(self._coordinates)

    @cached_property
    def _coordinates(self) -> tuple[str, ...]:
        return tuple(self.info.coordinates)

    @cached_property
    def _parameter_names(self) -> list[str]:
        return [name for name, _ in self.info.parameters]

    @cached_property
    def _default_parameters(self) -> np.ndarray:
        return self.info.parameter_vector()

    def parameter_vector(self, p=None) -> np.ndarray:
        """Full parameter array in `parameters` order from None, a dict of overrides or an array."""
        return parameter_array(p, self._parameter_names, self._default_parameters)

    def __repr__(self) -> str:
        return (f"<gagen dynamics '{self.info.name}' backend={self.backend} "
                f"coordinates={self.coordinates}>")

    # --- the dynamics (each backend implements these) --------------------------------------

    def mass_matrix(self, q, p=None) -> np.ndarray:
        """M(q): shape (n, n), or (N, n, n) for stacked q. Symmetric positive definite."""
        raise NotImplementedError

    def forcing(self, q, qd, tau, p=None) -> np.ndarray:
        """F(q, q̇, τ) such that M(q) q̈ = F: shape (n,) or (N, n)."""
        raise NotImplementedError

    def forward_dynamics(self, q, qd, tau, p=None) -> np.ndarray:
        """q̈ = M(q)⁻¹ F(q, q̇, τ): shape (n,) or (N, n).

        Raises SingularMassMatrixError when M(q) is not positive definite (zero or negative
        masses or inertias), NonFiniteStateError when q holds NaN or inf."""
        raise NotImplementedError

    def inverse_dynamics(self, q, qd, qdd, p=None) -> np.ndarray:
        """The joint torques (forces for prismatic joints) τ that give q̈: shape (n,) or (N, n)."""
        raise NotImplementedError

    def gravity(self, q, p=None) -> np.ndarray:
        """The gravity torques g(q) = inverse_dynamics(q, 0, 0): shape (n,) or (N, n)."""
        raise NotImplementedError

    def energy(self, q, qd, p=None):
        """(kinetic, potential): floats, or arrays of shape (N,) for stacked states."""
        raise NotImplementedError

    # --- derivatives (how they are derived and composed: gagen.symbolic.derivatives) -------

    def inverse_dynamics_derivatives(self, q, qd, qdd, p=None) -> tuple:
        """(∂τ/∂q, ∂τ/∂q̇) of τ = inverse_dynamics(q, q̇, q̈): each (n, n), or (N, n, n) for
        stacked states; entry [i, j] is ∂τ_i/∂q_j. (∂τ/∂q̈ is `mass_matrix(q)`.)"""
        raise NotImplementedError

    def forward_dynamics_derivatives(self, q, qd, tau, p=None) -> tuple:
        """(∂q̈/∂q, ∂q̈/∂q̇, ∂q̈/∂τ) of q̈ = forward_dynamics(q, q̇, τ): each (n, n), or
        (N, n, n) for stacked states. ∂q̈/∂τ is M(q)⁻¹, and ∂q̈/∂x = −M⁻¹ ∂τ/∂x at
        q̈ = forward_dynamics(q, q̇, τ). Raises as `forward_dynamics` does."""
        raise NotImplementedError

    def coriolis_matrix(self, q, qd, p=None) -> np.ndarray:
        """C(q, q̇) from the Christoffel symbols of the first kind of M: shape (n, n), or
        (N, n, n) for stacked states. C q̇ is the velocity terms of the equations of motion
        (`inverse_dynamics(q, q̇, 0) - gravity(q)`) and Ṁ − 2C is skew-symmetric."""
        raise NotImplementedError

    def linearize(self, q, qd, tau, p=None) -> tuple:
        """(A, B) of ẋ = f(x, u) at x = (q, q̇), u = τ: A = ∂f/∂x of shape (2n, 2n),
        B = ∂f/∂u of shape (2n, n), or (N, 2n, 2n) and (N, 2n, n) for stacked states.

        A = [[0, I], [∂q̈/∂q, ∂q̈/∂q̇]] and B = [[0], [M⁻¹]], from
        `forward_dynamics_derivatives`."""
        dqdd_dq, dqdd_dqd, dqdd_dtau = self.forward_dynamics_derivatives(q, qd, tau, p)
        n, lead = self.n, dqdd_dq.shape[:-2]
        A = np.zeros(lead + (2 * n, 2 * n))
        A[..., :n, n:] = np.eye(n)
        A[..., n:, :n] = dqdd_dq
        A[..., n:, n:] = dqdd_dqd
        B = np.zeros(lead + (2 * n, n))
        B[..., n:, :] = dqdd_dtau
        return A, B


# The name of earlier versions, kept for code that imported it.
DynamicsInfo = Dynamics
