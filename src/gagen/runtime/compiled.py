"""The compiled backend's dynamics object: a module built from generated C, bound to the
API of `Dynamics` (no SymPy: names and defaults come from the module's manifest)."""

from __future__ import annotations

from ..manifest import ModelInfo
from .dynamics import Dynamics

KERNEL_METHODS = ("mass_matrix", "forcing", "forward_dynamics", "inverse_dynamics",
                  "gravity", "energy")


class CompiledDynamics(Dynamics):
    """`gagen.load(..., backend="compiled")`: the dynamics of a compiled extension module.

    The module's kernel methods are bound to the instance, so a call costs no Python frame
    of gagen's; they check their inputs like every backend (gagen.runtime.inputs).
    """

    backend = "compiled"

    def __init__(self, module, model_ref=None):
        self.module = module
        self.info = ModelInfo.from_hex(module.MANIFEST_HEX)
        self._model_ref = model_ref
        self.kernels = module.CompiledModel(self.parameter_vector)
        for name in KERNEL_METHODS:
            setattr(self, name, getattr(self.kernels, name))

    # The derivative kernels are generated in the next step (issue 15, phase 2); until
    # then the compiled backend says so instead of computing them some slower way.

    def inverse_dynamics_derivatives(self, q, qd, qdd, p=None):
        raise NotImplementedError(_NO_DERIVATIVES_YET)

    def forward_dynamics_derivatives(self, q, qd, tau, p=None):
        raise NotImplementedError(_NO_DERIVATIVES_YET)

    def coriolis_matrix(self, q, qd, p=None):
        raise NotImplementedError(_NO_DERIVATIVES_YET)


_NO_DERIVATIVES_YET = (
    "the compiled backend does not have the derivatives yet (compiled derivative kernels "
    "are coming in the next step); use gagen.load(model, backend=\"lambdify\") for "
    "inverse_dynamics_derivatives, forward_dynamics_derivatives, coriolis_matrix and "
    "linearize for now")
