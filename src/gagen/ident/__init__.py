"""System identification on top of the regressor (NumPy and SciPy; no SymPy).

- `base`: the base parameters, the combinations of the dynamic parameters that the
  torques determine (`dyn.base_grouping`, `dyn.base_regressor`, `dyn.base_parameters`);
- `identification`: least squares on the base regressor (`gagen.identify`);
- `consistent`: every parameter, physically consistent (`identify_consistent`);
- `data`: measured trajectories from CSV, with q̇ and q̈ estimated from q when missing;
- `excitation`: exciting trajectories (finite Fourier series).
"""

from .base import BaseParameters
from .consistent import ConsistentIdentification, identify_consistent
from .data import Measurements, read_measurements
from .excitation import FourierTrajectory
from .identification import IdentificationResult, identify

__all__ = ["BaseParameters", "ConsistentIdentification", "FourierTrajectory",
           "IdentificationResult", "Measurements", "identify", "identify_consistent",
           "read_measurements"]
