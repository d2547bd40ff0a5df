"""gagen: compiled Gibbs-Appell equations of motion for trees of rigid bodies."""

from .dynamics import SingularMassMatrixError
from .gibbs_appell import Equations, derive
from .loading import load, resolve_model
from .model import Model, ModelError

__version__ = "0.1.0"

__all__ = [
           "Equations",
           "Model",
           "ModelError",
           "SingularMassMatrixError",
           "__version__",
           "derive",
           "load",
           "resolve_model",
]
