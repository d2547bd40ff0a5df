"""Resolve what the user names (a built-in, a model file, a URDF, an MJCF file, a Model)
into a Model."""

from __future__ import annotations

from pathlib import Path

from ..errors import ModelError
from .builtin import is_builtin, load_builtin
from .model import Model, check_model_inertias
from .modelfile import load_model_file

MODEL_SUFFIXES = (".yaml", ".yml", ".json")
MJCF_SUFFIXES = (".xml", ".mjcf")


def resolve_model(model: str | Path | Model, strict: bool = False,
                  floating_base: bool = False, constraints=None) -> Model:
    """A Model from a built-in name (`rrr`, `chain:N`), a model file, a URDF, an MJCF file
    (.xml, .mjcf: through MuJoCo's compiler, `pip install gagen[mjcf]`), or a Model.

    An inertia slightly off physical (CAD round-off) loads with a
    `gagen.errors.InertiaWarning`; `strict=True` refuses it (also in a Model given as is).
    `floating_base=True` lets a URDF's root link move freely (a floating joint to the
    world); model files and MJCF declare their floating joints themselves (`type: floating`,
    `<freejoint/>`). `constraints` (gagen.Contact, gagen.Loop or mappings, as a model
    file's `constraints:` list) are added after the description's own.
    """
    resolved = _resolve(model, strict, floating_base)
    if constraints is None:
        return resolved
    from .constraints import attach_constraints

    return attach_constraints(resolved, constraints)


def _resolve(model, strict: bool, floating_base: bool) -> Model:
    if floating_base and not str(model).lower().endswith(".urdf"):
        raise ModelError(str(model), "floating_base", "floating_base=True applies to a URDF; "
                         "a model file declares a joint `type: floating`, an MJCF file a "
                         "<freejoint/>")
    if isinstance(model, Model):
        if strict:
            check_model_inertias(model, strict=True)
        return model
    text = str(model)
    if isinstance(model, str) and is_builtin(text):
        return load_builtin(text)
    path = Path(text)
    suffix = path.suffix.lower()
    if suffix == ".urdf":
        from .urdf import load_urdf

        return load_urdf(path, strict=strict, floating_base=floating_base)
    if suffix in MJCF_SUFFIXES:
        from .mjcf import load_mjcf

        return load_mjcf(path, strict=strict)
    if suffix in MODEL_SUFFIXES:
        return load_model_file(path, strict=strict)
    raise ModelError(text, "", "not a built-in model (rrr, chain:N) nor a file ending in "
                     + ", ".join(MODEL_SUFFIXES + (".urdf",) + MJCF_SUFFIXES))
