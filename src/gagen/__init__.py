"""gagen: compiled Gibbs-Appell equations of motion for trees of rigid bodies."""

from .controllers import PD, ComputedTorque, paper_controller
from .dynamics import SingularMassMatrixError
from .gibbs_appell import Equations, derive
from .loading import load, resolve_model
from .model import Model, ModelError
from .simulate import SimulationResult, inverse_dynamics_along, simulate
from .trajectory import Eq11Trajectory

__version__ = "0.1.0"

__all__ = [
           "PD",
           "ComputedTorque",
           "Eq11Trajectory",
           "Equations",
           "Model",
           "ModelError",
           "SimulationResult",
           "SingularMassMatrixError",
           "__version__",
           "derive",
           "inverse_dynamics_along",
           "load",
           "paper_controller",
           "resolve_model",
           "simulate",
]
