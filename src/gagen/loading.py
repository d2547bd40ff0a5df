"""gagen.load: what the user names (built-in, model file, URDF, MJCF, Model) into dynamics
objects.

A model loaded before is found by a key of its input bytes in the cache's index, and
loads without SymPy; anything else is read, derived and built (gagen.building.builder).
"""

from __future__ import annotations

import os
from pathlib import Path

BACKENDS = ("compiled", "lambdify")
_COMPILED_OPTIONS = ("cache_dir", "fast_math", "verbose", "portable", "derivation",
                     "derivatives")


def load(model="rrr", backend: str = "compiled", strict: bool = False,
         floating_base: bool = False, constraints=None, **options):
    """Load the equations of motion of a model, with one API for every backend.

    `model` is a built-in name (`rrr`, `chain:N`), a model file (.yaml, .yml, .json), a
    .urdf file, an MJCF file (.xml, .mjcf; needs `pip install gagen[mjcf]`), or a
    `gagen.model.Model`. An inertia slightly off physical (CAD round-off) loads with a
    `gagen.InertiaWarning`; `strict=True` refuses it. `floating_base=True` lets a URDF's
    root link move freely (Pinocchio's FreeFlyer: q = [x, y, z, qx, qy, qz, qw, joints],
    velocities [linear, angular (both in the base frame), joints]; see `Dynamics.configuration`
    and `Dynamics.coordinates`). `constraints` declares contacts and closed loops for any
    description, after its own (a model file's `constraints:` list, MJCF's `<equality
    connect/weld>`): a list of `gagen.Contact(frame, axes="3d", reference=...)`,
    `gagen.Loop(frame_a, frame_b, ...)` or mappings as a model file's entries; they are part
    of the cache key (`Dynamics.constraints`, `constrained_forward_dynamics`).
    `backend` is "compiled" (generated C, built on first use and cached) or "lambdify"
    (SymPy's lambdify, no compiler).
    Options of the compiled backend: `cache_dir`, `fast_math`, `verbose` (show the build's
    progress), `portable` (kernels for any CPU of the architecture: by default
    they are compiled for this CPU's fused multiply-add where it has it),
    `derivatives` (build the derivative module now rather than on the first call of a
    derivative method: it is a second module, so the default build stays as fast). Both
    backends take `derivation`: "auto" (default: the paper's Gibbs-Appell form up to 5
    coordinates, the recursive Newton-Euler/CRBA/articulated-body form from 6 on, by
    measurement: gagen.symbolic.derivation), "gibbs-appell" or "recursive"; they give the
    same equations.

    Returns a `gagen.runtime.dynamics.Dynamics`: `mass_matrix`, `forcing`,
    `forward_dynamics`, `inverse_dynamics`, `gravity`, `energy`, the derivatives
    (`inverse_dynamics_derivatives`, `forward_dynamics_derivatives`, `coriolis_matrix`,
    `linearize`), and the model's names.
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend '{backend}' (expected one of {', '.join(BACKENDS)})")
    if backend == "lambdify":
        derivation = options.pop("derivation", "auto")
        if options:
            raise TypeError(f"the lambdify backend takes only the option derivation, got "
                            f"{', '.join(options)}")
        return _load_lambdify(model, derivation, strict, floating_base, constraints)
    unknown = [key for key in options if key not in _COMPILED_OPTIONS]
    if unknown:
        raise TypeError(f"unknown option(s) {', '.join(unknown)} of the compiled backend "
                        f"(options: {', '.join(_COMPILED_OPTIONS)})")
    return _load_compiled(model, strict=strict, floating_base=floating_base,
                          constraints=constraints, **options)


def _load_lambdify(model, derivation: str, strict: bool, floating_base: bool, constraints):
    from .model.resolve import resolve_model
    from .runtime.lambdify import LambdifyDynamics
    from .symbolic.derivation import derive_equations

    return LambdifyDynamics(derive_equations(
        resolve_model(model, strict, floating_base, constraints), derivation))


def _load_compiled(model, cache_dir=None, fast_math: bool = False, verbose=None,
                   portable: bool = False, derivation: str = "auto", strict: bool = False,
                   floating_base: bool = False, derivatives: bool = False, constraints=None):
    dyn = _compiled_dynamics(model, cache_dir, fast_math, verbose, portable, derivation, strict,
                             floating_base, constraints)
    if derivatives:
        dyn.load_derivatives()
    return dyn


def _constraints_key(model, constraints) -> list[str]:
    """The cache key's text of the constraints given to gagen.load (checked here, so that a
    malformed entry fails before any lookup)."""
    from .constraints import checked_constraints

    if constraints is None:
        return []
    checked = checked_constraints(constraints, str(model))
    return ["constraints=" + ";".join(c.canonical() for c in checked)]


def _compiled_dynamics(model, cache_dir, fast_math, verbose, portable, derivation, strict,
                       floating_base, constraints=None):
    from .building import cache

    digest = None
    build_options = {"cache_dir": cache_dir, "fast_math": fast_math, "verbose": verbose,
                     "portable": portable, "derivation": derivation}
    reference = (model, floating_base, constraints)
    if isinstance(model, (str, os.PathLike)):
        # strict is in the key: a model accepted with a warning must not skip a strict check
        options = [*cache.compile_flags(fast_math, portable), f"derivation={derivation}",
                   f"strict={bool(strict)}"] + (["floating_base"] if floating_base else []) \
            + _constraints_key(model, constraints)
        digest = cache.input_key(model, options)
        folder = Path(cache_dir) if cache_dir else cache.default_cache_dir()
        module = cache.index_lookup(folder, digest) if digest else None
        if module is not None:
            from .runtime.compiled import CompiledDynamics

            return CompiledDynamics(module, reference,
                                    derivatives=_DerivativeModule(digest, build_options))
    from .building.builder import load_compiled
    from .model.resolve import resolve_model

    return load_compiled(resolve_model(model, strict, floating_base, constraints),
                         model_ref=reference, input_digest=digest,
                         derivatives=_DerivativeModule(digest, build_options), **build_options)


class _DerivativeModule:
    """Finds or builds the derivative module of a dynamics object loaded from what the user
    named: by the input's key in the cache's index first (no SymPy), else from the model."""

    def __init__(self, digest: str | None, build_options: dict):
        self.digest, self.build_options = digest, build_options

    def __call__(self, dyn):
        from .building import cache

        key = cache.derivatives_input_key(self.digest) if self.digest else None
        if key is not None:
            cache_dir = self.build_options["cache_dir"]
            folder = Path(cache_dir) if cache_dir else cache.default_cache_dir()
            module = cache.index_lookup(folder, key)
            if module is not None:
                return module
        from .building.builder import load_derivative_module

        return load_derivative_module(dyn.model, input_digest=key, **self.build_options)
