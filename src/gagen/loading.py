"""gagen.load: what the user names (built-in, model file, URDF, Model) into dynamics objects.

A model loaded before is found by a key of its input bytes in the cache's index, and
loads without SymPy; anything else is read, derived and built (gagen.build.builder).
"""

from __future__ import annotations

import os
from pathlib import Path

BACKENDS = ("compiled", "lambdify")
_COMPILED_OPTIONS = ("cache_dir", "fast_math", "verbose", "portable")


def load(model="rrr", backend: str = "compiled", **options):
    """Load the equations of motion of a model, with one API for every backend.

    `model` is a built-in name (`rrr`, `chain:N`), a model file (.yaml, .yml, .json), a
    .urdf file, or a `gagen.model.Model`. `backend` is "compiled" (generated C through
    Cython, built on first use and cached) or "lambdify" (SymPy's lambdify, no compiler).
    Options of the compiled backend: `cache_dir`, `fast_math`, `verbose`, `portable` (one
    version of the kernels for any CPU, no FMA clone).

    Returns a `gagen.runtime.dynamics.Dynamics`: `mass_matrix`, `forcing`,
    `forward_dynamics`, `inverse_dynamics`, `gravity`, `energy`, and the model's names.
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend '{backend}' (expected one of {', '.join(BACKENDS)})")
    if backend == "lambdify":
        if options:
            raise TypeError(f"the lambdify backend takes no options, got {', '.join(options)}")
        return _load_lambdify(model)
    unknown = [key for key in options if key not in _COMPILED_OPTIONS]
    if unknown:
        raise TypeError(f"unknown option(s) {', '.join(unknown)} of the compiled backend "
                        f"(options: {', '.join(_COMPILED_OPTIONS)})")
    return _load_compiled(model, **options)


def _load_lambdify(model):
    from .model.resolve import resolve_model
    from .runtime.lambdify import LambdifyDynamics
    from .symbolic.gibbs_appell import derive

    return LambdifyDynamics(derive(resolve_model(model)))


def _load_compiled(model, cache_dir=None, fast_math: bool = False, verbose=None,
                   portable: bool = False):
    from .build import cache

    digest = None
    if isinstance(model, (str, os.PathLike)):
        digest = cache.input_key(model, cache.compile_flags(fast_math, portable))
        folder = Path(cache_dir) if cache_dir else cache.default_cache_dir()
        module = cache.index_lookup(folder, digest) if digest else None
        if module is not None:
            from .runtime.compiled import CompiledDynamics

            return CompiledDynamics(module, model)
    from .build.builder import load_compiled
    from .model.resolve import resolve_model

    return load_compiled(resolve_model(model), cache_dir=cache_dir, fast_math=fast_math,
                         verbose=verbose, portable=portable, model_ref=model,
                         input_digest=digest)
