"""target="jax": a model's programs printed as JAX (gagen.jax.printer), kept in the cache.

Each model has two printed modules, as it has two compiled ones: its dynamics, printed on
the first use of target="jax" (or of a parameter derivative on the compiled path, which
needs π(p) and the list of kinematic parameters), and its derivatives, printed on the
first use of a derivative. They are keyed like the C: by the compiled module's KEY (the
model, the derivation, gagen's generator and version) and the printer's own code, written
into the cache with their SHA-256 (checked before every import, as the compiled modules'
are), and imported without SymPy. Only a miss derives the equations (SymPy) and prints.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import tempfile
import threading
from functools import cache
from importlib import resources
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from gagen.building.cache import (
    _CHECKSUM_FILE,
    _checksum,
    cached_module_is_intact,
    default_cache_dir,
    discard_cache_entry,
    usable_cache_dir,
)
from gagen.errors import BuildError
from gagen.jax import frames as jframes
from gagen.jax import linalg
from gagen.jax.ops import Ops, _dtype
from gagen.jax.registry import METHODS

_lock = threading.Lock()
_modules: dict[str, object] = {}


@cache
def printer_digest() -> str:
    """A hash of the printer's code: a changed printer never reuses a printed module."""
    h = hashlib.sha256()
    for name in ("printer.py",):
        h.update(resources.files("gagen.jax").joinpath(name).read_bytes())
    return h.hexdigest()


def module_key(dyn, kind: str) -> str:
    """The key of a model's printed module `kind` ("dynamics" or "derivatives")."""
    h = hashlib.sha256()
    for part in ("gagen-jax-printed", kind, str(dyn.module.KEY), printer_digest()):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()


def printed_module(dyn, kind: str, cache_dir=None):
    """The printed module `kind` of a compiled model: imported from the cache (no SymPy),
    or printed now from the model's equations."""
    key = module_key(dyn, kind)
    with _lock:
        module = _modules.get(key)
        if module is not None:
            return module
        root = usable_cache_dir(Path(cache_dir) if cache_dir else default_cache_dir())
        name = f"gagen_jax_{kind}_{key[:16]}"
        entry = root / name
        file = f"{name}.py"
        if not cached_module_is_intact(entry, file):
            if entry.exists():
                discard_cache_entry(entry)
            _write(entry, file, _print(dyn, kind))
        spec = importlib.util.spec_from_file_location(name, entry / file)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        _modules[key] = module
        return module


def _write(entry: Path, file: str, text: str) -> None:
    """Write a printed module and its checksum into place in one rename."""
    tmp = Path(tempfile.mkdtemp(prefix=f".{entry.name}-", dir=entry.parent))
    try:
        (tmp / file).write_text(text)
        (tmp / _CHECKSUM_FILE).write_text(_checksum(tmp / file))
        try:
            os.rename(tmp, entry)
        except OSError:
            if not cached_module_is_intact(entry, file):
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _print(dyn, kind: str) -> str:
    """Derive the model's equations as its compiled module was (SymPy) and print them."""
    from gagen.building.builder import source_key
    from gagen.jax.printer import print_derivatives, print_main
    from gagen.symbolic.derivation import derive_equations
    from gagen.symbolic.derivatives import derive_derivatives

    model = dyn.model
    for derivation in ("auto", "gibbs-appell", "recursive"):
        if source_key(model, derivation) == dyn.module.KEY:
            break
    else:
        raise BuildError(f"gagen.jax: the module of '{dyn.info.name}' was not built by this "
                         "gagen with its default settings; load it again with gagen.load")
    eqs = derive_equations(model, derivation)
    if kind == "dynamics":
        return print_main(eqs)
    return print_derivatives(derive_derivatives(eqs))


class PrintedOps(Ops):
    """The methods of METHODS from the printed programs: pure JAX, any backend."""

    target = "jax"

    def __init__(self, dyn, cache_dir=None):
        super().__init__(dyn, cache_dir)
        self.main = printed_module(dyn, "dynamics", cache_dir)
        self.defaults = np.asarray(dyn.info.parameter_vector(), dtype=np.float64)

    @property
    def derivatives(self):
        return printed_module(self.dyn, "derivatives", self.cache_dir)

    def parameters(self, p, dtype):
        return jnp.asarray(self.defaults, dtype) if p is None else p

    def call(self, name: str, *states, p=None, frame: int = -1):
        method = METHODS[name]
        dtype = _dtype(states, p)
        p = self.parameters(p, dtype)
        lead = self.lead(list(states) + [p])
        outputs = self._evaluate(name, states, p, frame)
        if not isinstance(outputs, tuple):
            outputs = (outputs,)
        shapes = self.shapes(method)
        outputs = [jnp.broadcast_to(o.astype(dtype), lead + s) for o, s in zip(outputs, shapes)]
        return self.results(method, outputs)

    def _evaluate(self, name, states, p, frame):
        main, nv = self.main, self.dyn.nv
        if name == "mass_matrix":
            return linalg.symmetric(main.mass_matrix_lower(*states, p), nv)
        if name in ("forcing", "forward_dynamics", "inverse_dynamics", "gravity", "energy",
                    "regressor_parameters"):
            return getattr(main, name)(*states, p)
        if name == "regressor":
            return jframes.regressor(main, *states, p)
        if name.startswith("frame_"):
            X = main.placements(states[0], p)
            F = main.frame_offsets(p)
            if name == "frame_placement":
                return jframes.pose(self.dyn.info, X, F, frame)
            J = jframes.jacobian(self.dyn.info, X, F, frame, nv)
            if name == "frame_jacobian":
                return J
            return jnp.einsum("...ij,...j->...i", J, states[1])
        derivatives = self.derivatives
        if name == "linearize":
            return linearize(*derivatives.forward_dynamics_derivatives(*states, p))
        return getattr(derivatives, name)(*states, p)

    def kinematic(self) -> tuple[int, ...]:
        return tuple(self.main.KINEMATIC)


def linearize(dq, dqd, Minv):
    """(A, B) of ẋ = f(x, τ) from the forward-dynamics derivatives (Dynamics.linearize)."""
    n = dq.shape[-1]
    lead = dq.shape[:-2]
    eye = jnp.broadcast_to(jnp.eye(n, dtype=dq.dtype), lead + (n, n))
    zero = jnp.zeros(lead + (n, n), dq.dtype)
    A = jnp.concatenate([jnp.concatenate([zero, eye], -1), jnp.concatenate([dq, dqd], -1)], -2)
    B = jnp.concatenate([zero, Minv], -2)
    return A, B
