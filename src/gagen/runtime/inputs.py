"""The one set of input checks of the runtime, shared by both backends (the compiled
module's slow path calls these too): states as float arrays of shape (n,) or (N, n),
parameters as a finite float array, and floating joints' quaternions that can be
normalised in double precision."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..errors import NonFiniteStateError

# The smallest normal double: a quaternion's squared norm below it has lost its precision
# (subnormal) or vanished, and 2 / |quat|^2, by which the kinematics scale the rotation,
# overflows; above the largest double the squared norm is inf and the rotation would be
# the identity. Either way the quaternion cannot be normalised as it is.
SMALLEST_NORMAL = float(np.finfo(float).tiny)


def as_float_array(a, name: str) -> np.ndarray:
    """`a` as a float64 array; TypeError for text, None and non-numeric dtypes."""
    if isinstance(a, (str, bytes)) or a is None:
        raise TypeError(f"{name} must be an array of numbers, got {type(a).__name__}")
    arr = np.asarray(a)
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise TypeError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    return arr.astype(float, copy=False)


def as_states(n, *arrays, names: tuple[str, ...]) -> tuple[list[np.ndarray], bool]:
    """Check and convert inputs of shape (n,) or stacked (N, n); say whether they were stacked.

    `n` is one size for every array, or a size per array (q has nq entries, qd nv)."""
    sizes = tuple(n) if isinstance(n, (tuple, list)) else (n,) * len(arrays)
    out = []
    stacked_shape = None
    for name, a, size in zip(names, arrays, sizes):
        arr = as_float_array(a, name)
        if arr.ndim == 1 and arr.shape[0] == size:
            pass
        elif arr.ndim == 2 and arr.shape[1] == size:
            if stacked_shape is not None and arr.shape[0] != stacked_shape:
                raise ValueError(f"{name} has {arr.shape[0]} rows, other inputs have {stacked_shape}")
            stacked_shape = arr.shape[0]
        else:
            raise ValueError(f"{name} must have shape ({size},) or (N, {size}); got {arr.shape}")
        out.append(arr)
    stacked = stacked_shape is not None
    if stacked:
        out = [np.broadcast_to(a, (stacked_shape, a.shape[0])) if a.ndim == 1 else a
               for a in out]
    return out, stacked


def parameter_array(p, names: list[str], defaults: np.ndarray) -> np.ndarray:
    """The full parameter array from None, a dict of overrides or an array (fresh, finite)."""
    if p is None:
        return defaults.copy()
    if isinstance(p, Mapping):
        out = defaults.copy()
        index = {name: k for k, name in enumerate(names)}
        for key, value in p.items():
            if key not in index:
                raise KeyError(f"unknown parameter '{key}' (parameters: {', '.join(names)})")
            if isinstance(value, (str, bytes)) or value is None:
                raise TypeError(f"parameter '{key}' must be a number, got {value!r}")
            if isinstance(value, complex) or np.iscomplexobj(value):
                raise TypeError(f"parameter '{key}' must be a real number, got {value!r}")
            out[index[key]] = float(value)
        return finite_parameters(out)
    arr = np.asarray(p)
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"p must hold real numbers, got dtype {arr.dtype}")
    arr = arr.astype(float)
    if arr.shape != defaults.shape:
        raise ValueError(f"p must be None, a dict of overrides or an array of {defaults.size} "
                         f"parameters in dyn.parameters order; got shape {arr.shape}")
    return finite_parameters(np.ascontiguousarray(arr))


def finite_parameters(values: np.ndarray) -> np.ndarray:
    """Refuse NaN and inf parameters: they would poison every output without a word."""
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise ValueError(f"parameters must be finite; entry {int(bad[0])} is {values[bad[0]]}")
    return values


def check_quaternions(q: np.ndarray, quaternions, name: str = "q") -> None:
    """Refuse a floating joint's quaternion whose squared norm overflows (inf) or
    underflows (below the smallest normal double): the rotation of such a quaternion
    cannot be computed (an overflowing one would silently be the identity). A quaternion
    holding NaN or inf is a NonFiniteStateError (the orientation alone may not show in
    the mass matrix, so the dynamics' own NaN check would not see it). `quaternions`:
    (first entry in q, description) of each, as `ModelInfo.quaternions()` gives them; q
    is (nq,) or stacked (N, nq)."""
    for offset, label in quaternions:
        quat = q[..., offset: offset + 4]
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            norm2 = np.sum(quat * quat, axis=-1)
        bad = ~((norm2 >= SMALLEST_NORMAL) & (norm2 < np.inf))
        if np.any(bad):
            row = int(np.flatnonzero(np.atleast_1d(bad))[0]) if q.ndim == 2 else -1
            raise quaternion_error(name, label, row, quat[row] if row >= 0 else quat)


def quaternion_error(name: str, label: str, row: int, quat) -> ValueError:
    """The one-line error for a quaternion that cannot be normalised (check_quaternions;
    the compiled runtime raises the same)."""
    quat = np.asarray(quat, dtype=float)
    where = f" (stacked input, row {row})" if row >= 0 else ""
    label = label.replace("q[", f"{name}[", 1) if name != "q" else label
    if not np.isfinite(quat).all():
        return NonFiniteStateError(f"{label} holds NaN or inf{where}")
    largest = float(np.abs(quat).max())
    with np.errstate(over="ignore", under="ignore"):
        overflows = not np.isfinite(np.sum(quat * quat))
    what = (f"its squared norm overflows (an entry of {largest:.3g})" if overflows else
            "it is zero" if largest == 0 else
            f"its squared norm underflows (entries of at most {largest:.3g})")
    return ValueError(f"{label} cannot be normalised in double precision{where}: {what}; "
                      "give it at a scale near 1, e.g. (0, 0, 0, 1) for no rotation")


def nonfinite_cause(q) -> str:
    """Why the dynamics at q came out NaN or inf: q holds NaN or inf, or, q being finite,
    a product of its entries and the parameters overflowed."""
    if q is None:
        return "q holds NaN or inf"
    q = np.asarray(q, dtype=float)
    if not np.isfinite(q).all():
        k = int(np.flatnonzero(~np.isfinite(q))[0])
        return f"q holds NaN or inf (q[{k}] is {q[k]})"
    return (f"q is finite (largest |entry| {np.abs(q).max():.3g}), so a product of the "
            "parameters and q's entries overflowed: check the scale of the parameters (p=) "
            "and of q")
