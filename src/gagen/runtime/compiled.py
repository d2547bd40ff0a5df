"""The compiled backend's dynamics object: a module built from generated C, bound to the
API of `Dynamics` (no SymPy: names and defaults come from the module's manifest)."""

from __future__ import annotations

from ..manifest import ModelInfo
from .dynamics import Dynamics
from .frames import frame_index

KERNEL_METHODS = ("mass_matrix", "forcing", "forward_dynamics", "inverse_dynamics",
                  "gravity", "energy", "regressor", "regressor_parameters")


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
        self.kernels = module.CompiledModel(self.parameter_vector, self.external_forces)
        for name in KERNEL_METHODS:
            setattr(self, name, getattr(self.kernels, name))

    # frames: the C of frames.c, one call per state (stacked states in one C loop)

    def _placements(self, q, p):
        return self.kernels.placements(q, p)

    def _frame_offsets(self, p):
        return self.kernels.frame_offsets(p)

    def frame_placement(self, q, frame, p=None):
        out = self.kernels.frame(0, frame_index(self.info, frame), q, None, p)
        return out[..., :9].reshape(out.shape[:-1] + (3, 3)), out[..., 9:].copy()

    def frame_jacobian(self, q, frame, p=None):
        out = self.kernels.frame(1, frame_index(self.info, frame), q, None, p)
        return out.reshape(out.shape[:-1] + (6, self.nv))

    def frame_velocity(self, q, qd, frame, p=None):
        return self.kernels.frame(2, frame_index(self.info, frame), q, qd, p)

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
