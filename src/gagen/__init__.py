"""gagen: compiled Gibbs-Appell equations of motion for trees of rigid bodies.

`import gagen` and loading a model that is already built need neither SymPy nor a compiler:
the names that derive equations (`derive`, `Equations`, `Model`, `resolve_model`) are
imported on first use.
"""

from __future__ import annotations

import importlib

from .errors import (
    BuildError,
    InertiaWarning,
    ModelError,
    NonFiniteStateError,
    SingularMassMatrixError,
    SingularTaskError,
)
from .ident import identify
from .loading import load
from .sim.batch import BatchResult, simulate_batch
from .sim.controllers import PD, ComputedTorque, paper_controller
from .sim.simulate import SimulationResult, inverse_dynamics_along, simulate
from .sim.trajectory import Eq11Trajectory

__version__ = "0.1.0"

_LAZY = {
    "derive": ".symbolic.gibbs_appell",
    "Equations": ".symbolic.gibbs_appell",
    "Model": ".model.model",
    "resolve_model": ".model.resolve",
}

__all__ = [
    "PD",
    "BatchResult",
    "BuildError",
    "ComputedTorque",
    "Eq11Trajectory",
    "Equations",
    "InertiaWarning",
    "Model",
    "ModelError",
    "NonFiniteStateError",
    "SimulationResult",
    "SingularMassMatrixError",
    "SingularTaskError",
    "__version__",
    "derive",
    "identify",
    "inverse_dynamics_along",
    "load",
    "paper_controller",
    "resolve_model",
    "simulate",
    "simulate_batch",
]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module 'gagen' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
