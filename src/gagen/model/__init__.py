"""Stage 1: robot descriptions (model files, URDF, built-ins) into a validated `Model`.

The names below are imported on first use, so that importing a sympy-free module of this
package (`gagen.model.info`) does not import SymPy.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "Model": "model", "Body": "model", "Joint": "model", "Limits": "model",
    "ModelError": "model", "inertia_matrix": "model", "rotation_from_rpy": "model",
    "vector": "model", "WORLD": "model",
}


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
