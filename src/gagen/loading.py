"""Resolve what the user names (built-in, model file, URDF, Model) into dynamics objects."""

from __future__ import annotations

from pathlib import Path

from .builtin import is_builtin, load_builtin
from .model import Model, ModelError
from .modelfile import load_model_file

BACKENDS = ("compiled", "lambdify")
MODEL_SUFFIXES = (".yaml", ".yml", ".json")


def resolve_model(model: str | Path | Model) -> Model:
    """A Model from a built-in name (`rrr`, `chain:N`), a model file, a URDF, or a Model."""
    if isinstance(model, Model):
        return model
    text = str(model)
    if isinstance(model, str) and is_builtin(text):
        return load_builtin(text)
    path = Path(text)
    suffix = path.suffix.lower()
    if suffix == ".urdf":
        from .urdf import load_urdf

        return load_urdf(path)
    if suffix in MODEL_SUFFIXES:
        return load_model_file(path)
    raise ModelError(text, "", "not a built-in model (rrr, chain:N) nor a file ending in "
                     + ", ".join(MODEL_SUFFIXES + (".urdf",)))


def load(model: str | Path | Model = "rrr", backend: str = "compiled", **options):
    """Load the equations of motion of a model, with one API for every backend.

    `model` is a built-in name (`rrr`, `chain:N`), a model file (.yaml, .yml, .json), a
    .urdf file, or a `gagen.model.Model`. `backend` is "compiled" (generated C through
    Cython, built on first use and cached) or "lambdify" (SymPy's lambdify, no compiler).
    Options of the compiled backend: `cache_dir`, `fast_math`, `verbose`, `portable` (one
    version of the kernels for any CPU, no FMA clone).
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend '{backend}' (expected one of {', '.join(BACKENDS)})")
    resolved = resolve_model(model)
    if backend == "lambdify":
        if options:
            raise TypeError(f"the lambdify backend takes no options, got {', '.join(options)}")
        from .gibbs_appell import derive
        from .lambdify_backend import LambdifyDynamics

        return LambdifyDynamics(derive(resolved))
    from .build import load_compiled

    return load_compiled(resolved, **options)
