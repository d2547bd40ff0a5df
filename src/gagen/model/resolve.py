"""Resolve what the user names (a built-in, a model file, a URDF, a Model) into a Model."""

from __future__ import annotations

from pathlib import Path

from ..errors import ModelError
from .builtin import is_builtin, load_builtin
from .model import Model
from .modelfile import load_model_file

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
