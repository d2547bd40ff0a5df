"""gagen.load: what the user names (built-in, model file, URDF, Model) into dynamics objects."""

from __future__ import annotations

BACKENDS = ("compiled", "lambdify")


def load(model="rrr", backend: str = "compiled", **options):
    """Load the equations of motion of a model, with one API for every backend.

    `model` is a built-in name (`rrr`, `chain:N`), a model file (.yaml, .yml, .json), a
    .urdf file, or a `gagen.model.Model`. `backend` is "compiled" (generated C through
    Cython, built on first use and cached) or "lambdify" (SymPy's lambdify, no compiler).
    Options of the compiled backend: `cache_dir`, `fast_math`, `verbose`, `portable` (one
    version of the kernels for any CPU, no FMA clone).
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend '{backend}' (expected one of {', '.join(BACKENDS)})")
    from .model.resolve import resolve_model

    resolved = resolve_model(model)
    if backend == "lambdify":
        if options:
            raise TypeError(f"the lambdify backend takes no options, got {', '.join(options)}")
        from .runtime.lambdify import LambdifyDynamics
        from .symbolic.gibbs_appell import derive

        return LambdifyDynamics(derive(resolved))
    from .build.builder import load_compiled

    return load_compiled(resolved, **options)
