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
