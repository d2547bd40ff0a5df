"""The runtime API shared by every backend: names, parameters and input checks."""

from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property

import numpy as np

from ..errors import SingularMassMatrixError  # noqa: F401 (re-exported)
from ..model.model import Model


class DynamicsInfo:
    """Names and parameter handling, mixed into every backend's dynamics object."""

    model: Model
    backend: str

    @property
    def coordinates(self) -> list[str]:
        return list(self._coordinates)

    @property
    def parameters(self) -> dict[str, float]:
        return dict(self.model.parameters)

    @property
    def n(self) -> int:
        return len(self._coordinates)

    @cached_property
    def _coordinates(self) -> tuple[str, ...]:
        # the model is fixed once its equations are built; walking its tree on every
        # call would cost microseconds in the simulation loop
        return tuple(self.model.coordinates)

    def parameter_vector(self, p=None) -> np.ndarray:
        """Full parameter array in `parameters` order from None, a dict of overrides or an array."""
        if p is None:
            cached = self.__dict__.get("_default_parameters")
            if cached is None:
                # the defaults are fixed when the equations are built (the compiled module
                # bakes them in), so they are read from the model once
                cached = self.__dict__["_default_parameters"] = self.model.parameter_vector()
            return cached.copy()
        defaults = self.model.parameter_vector()
        if isinstance(p, Mapping):
            names = list(self.model.parameters)
            out = defaults.copy()
            index = {name: k for k, name in enumerate(names)}
            for key, value in p.items():
                if key not in index:
                    raise KeyError(f"unknown parameter '{key}' (parameters: {', '.join(names)})")
                if isinstance(value, (str, bytes)) or value is None:
                    raise TypeError(f"parameter '{key}' must be a number, got {value!r}")
                out[index[key]] = float(value)
            return _finite_parameters(out)
        arr = np.asarray(p)
        if arr.dtype.kind not in "biuf":
            raise TypeError(f"p must hold real numbers, got dtype {arr.dtype}")
        arr = arr.astype(float)
        if arr.shape != defaults.shape:
            raise ValueError(f"p must be None, a dict of overrides or an array of "
                             f"{defaults.size} parameters in dyn.parameters order; got shape {arr.shape}")
        return _finite_parameters(np.ascontiguousarray(arr))

    def __repr__(self) -> str:
        return (f"<gagen dynamics '{self.model.name}' backend={self.backend} "
                f"coordinates={self.coordinates}>")


def _finite_parameters(values: np.ndarray) -> np.ndarray:
    """Refuse NaN and inf parameters: they would poison every output without a word."""
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise ValueError(f"parameters must be finite; entry {int(bad[0])} is {values[bad[0]]}")
    return values


def as_states(n: int, *arrays, names: tuple[str, ...]) -> tuple[list[np.ndarray], bool]:
    """Check and convert inputs of shape (n,) or stacked (N, n); say whether they were stacked."""
    out = []
    stacked_shape = None
    for name, a in zip(names, arrays):
        arr = _as_float_array(a, name)
        if arr.ndim == 1 and arr.shape[0] == n:
            pass
        elif arr.ndim == 2 and arr.shape[1] == n:
            if stacked_shape is not None and arr.shape[0] != stacked_shape:
                raise ValueError(f"{name} has {arr.shape[0]} rows, other inputs have {stacked_shape}")
            stacked_shape = arr.shape[0]
        else:
            raise ValueError(f"{name} must have shape ({n},) or (N, {n}); got {arr.shape}")
        out.append(arr)
    stacked = stacked_shape is not None
    if stacked:
        out = [np.broadcast_to(a, (stacked_shape, n)) if a.ndim == 1 else a for a in out]
    return out, stacked


def _as_float_array(a, name: str) -> np.ndarray:
    if isinstance(a, (str, bytes)) or a is None:
        raise TypeError(f"{name} must be an array of numbers, got {type(a).__name__}")
    arr = np.asarray(a)
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise TypeError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    return arr.astype(float, copy=False)
