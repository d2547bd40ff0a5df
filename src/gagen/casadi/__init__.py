"""gagen's compiled dynamics as CasADi functions, with gagen's analytic derivatives.

    fns = gagen.casadi.functions(dyn)          # dyn = gagen.load(...): a compiled model
    qdd = fns["forward_dynamics"](q, qd, tau)  # DM, SX or MX

Each function is a `casadi.external` of one shared library (`library(dyn)`, built into
gagen's cache on first use): the model's C kernels behind CasADi's C API for external
functions, the same library `python -m gagen export casadi MODEL --out DIR` writes. Each
carries its Jacobian (`jac_<name>` in the library, CasADi's convention) computed by
gagen's derivative kernels, so `casadi.jacobian`, `Opti`, `nlpsol` and the integrators use
gagen's derivatives; CasADi builds its forward and reverse directional derivatives on that
Jacobian. Second derivatives (an exact Hessian) are central differences of the analytic
Jacobian, by CasADi's finite differences (the option `jacobian_options` below).

Which derivatives are analytic (gagen.casadi.table has the details):
- forward_dynamics, inverse_dynamics, gravity, mass_matrix: by q, qd, tau/qdd from the
  derivative module (forward/inverse_dynamics_derivatives, the mass matrix, M^-1);
- frame_placement, frame_jacobian, frame_velocity: from the frame Jacobian;
- frame_acceleration, frame_bias_acceleration, frame_jacobian_time_variation: by q and qd
  the model's task-space derivative kernels (<model>_frame_acceleration_derivatives,
  <model>_frame_jacobian_time_variation_derivatives: spatial algebra on the frame's path),
  by qdd the frame Jacobian;
- delassus: dG = dJ Y + Y^T dJ^T - Y^T dM Y (Y = M^-1 J^T), the model's kernel
  <model>_delassus_derivatives;
- coriolis_matrix: by q and qd the model's kernel <model>_coriolis_matrix_derivatives
  (Pinocchio's C in forward mode, spatial algebra);
- center_of_mass, com_velocity, com_jacobian, centroidal_map, centroidal_momentum,
  centroidal_map_time_variation, centroidal_bias: by q and qd from the model's centroidal
  C (com_jacobian, centroidal_map and the analytic *_derivatives kernels of
  model/centroidal_derivatives.c.j2);
- by the parameters p (the `_p` functions, `parameters=True`): column by column from the
  parameter's class (gagen.casadi.build.parameter_classes) and what the function depends
  on (gagen.casadi.table): zeros by structure without an evaluation; gravity g by one
  evaluation (every value is affine in it); the inertial parameters (masses, centres of
  mass, inertias, damping, friction, armature) through the regressor (dtau/dp = Y dpi/dp,
  -M^-1 dtau/dp, dM/dp = (Y(q, 0, e_j) - Y(q, 0, 0)) dpi/dp, the Delassus matrix's
  -Y^T dM Y) or by the five-point stencil, exact on polynomials of degree <= 4 (C; D X for
  the centroidal functions, D the total mass, and the quotient rule); a model file's
  lengths and angles by the five-point stencil with a small step (exact for polynomials
  of degree <= 4 in them, O(h^4) otherwise).

By q, a floating joint's quaternion columns are the derivative along its velocity
directions mapped back onto q's entries, orthogonal to the quaternion (the kernels
normalise it: no function depends on its norm). Function.map calls the compiled function
once per state (CasADi's Map: a loop in C, no Python).
"""

from __future__ import annotations

from pathlib import Path

from .build import export, library, library_functions
from .table import ENTRIES

# every function of the table; a model's library holds those whose kernels its C has (the
# centre of mass and centroidal ones where the model was built with them)
NAMES = tuple(entry.name for entry in ENTRIES)
FRAME_NAMES = tuple(entry.name for entry in ENTRIES if entry.per_frame)

# The options of every external: its Jacobian's own derivatives (second derivatives of the
# dynamics) by CasADi's central differences of gagen's analytic Jacobian.
EXTERNAL_OPTIONS = {"jacobian_options": {"enable_fd": True, "fd_method": "central"}}

__all__ = ["EXTERNAL_OPTIONS", "FRAME_NAMES", "NAMES", "export", "functions", "library",
           "library_functions"]


def functions(dyn, names=None, *, frames=(), parameters: bool = False, p=None,
              cache_dir: str | Path | None = None, options: dict | None = None) -> dict:
    """gagen's functions of a compiled model as a dict of `casadi.Function`s.

    Keys (`NAMES`): forward_dynamics(q, qd, tau) -> qdd, inverse_dynamics(q, qd, qdd) -> tau,
    mass_matrix(q) -> M, gravity(q) -> g, coriolis_matrix(q, qd) -> C,
    frame_placement(q, frame) -> (R, pos), frame_jacobian(q, frame) -> J (6 x nv,
    LOCAL_WORLD_ALIGNED), frame_velocity(q, qd, frame) -> v; `frame` is the frame's number
    in `dyn.frames`. `frames` (names or numbers) adds, for each, `"<function>:<frame>"`
    (e.g. "frame_jacobian:panda_hand") without the frame input. `names` picks some of the
    keys (default: every function, and those of `frames`).

    `parameters=True`: each function takes the parameters p (dyn.parameters order) as its
    last input, e.g. a payload's mass as an optimisation variable; otherwise p is the
    model's defaults, or `p` (None, a dict of overrides or a full array) fixed.
    `options` are added to each `casadi.external`'s options (`EXTERNAL_OPTIONS`).
    """
    import casadi

    if parameters and p is not None:
        raise ValueError("give parameters=True or p=, not both: p= fixes the parameters "
                         "that parameters=True makes an input")
    built = library(dyn, cache_dir=cache_dir)
    path, available = str(built), library_functions(built)
    from .build import model_ident
    from .generate import function_name, prefix_of

    prefix = prefix_of(model_ident(dyn))
    opts = {**EXTERNAL_OPTIONS, **(options or {})}
    frame_numbers = [_frame_number(dyn, frame) for frame in frames]
    wanted = _wanted(names, dyn, frame_numbers, available)
    fixed = None if p is None else dyn.parameter_vector(p)
    out = {}
    for name in available:
        keys = [key for key in wanted if key == name or key.startswith(name + ":")]
        if not keys:
            continue
        external = casadi.external(function_name(prefix, name, parameters or fixed is not None),
                                   path, opts)
        if fixed is not None:
            external = _with_parameters(casadi, external, fixed, name)
        for key in keys:
            out[key] = external if key == name else _bound(casadi, external, key, dyn)
    return {key: out[key] for key in wanted}


def _frame_number(dyn, frame) -> int:
    from ..runtime.frames import frame_index

    return frame_index(dyn.info, frame)


def _wanted(names, dyn, frame_numbers: list[int], available: list[str]) -> list[str]:
    """The keys asked for, in the table's order, checked against the library's functions."""
    frame_names = [dyn.frames[k] for k in frame_numbers]
    per_frame = [kind for kind in FRAME_NAMES if kind in available]
    every = list(available) + [f"{kind}:{frame}" for frame in frame_names
                               for kind in per_frame]
    if names is None:
        return every
    if isinstance(names, str):
        names = [names]
    keys = []
    for key in names:
        kind, _, frame = str(key).partition(":")
        if kind not in available or (frame and (kind not in per_frame
                                                 or frame not in dyn.info.frame_indices)):
            raise ValueError(f"unknown CasADi function '{key}' (this model's: "
                             f"{', '.join(available)}, or '<frame function>:<frame>' for a "
                             "frame of dyn.frames)")
        keys.append(str(key))
    return list(dict.fromkeys(keys))


def _symbols(casadi, function):
    """SX symbols shaped as a function's inputs, with its names."""
    return [casadi.SX.sym(function.name_in(i), function.sparsity_in(i))
            for i in range(function.n_in())]


def _with_parameters(casadi, external, p, name: str):
    """The function of `external` (a `_p` function) at fixed parameters p: an SX function
    that calls it (its derivatives still the external's)."""
    args = _symbols(casadi, external)[:-1]
    outs = external(*args, casadi.DM(p))
    outs = outs if isinstance(outs, (list, tuple)) else [outs]
    return casadi.Function(name, args, list(outs), [external.name_in(i) for i in
                                                    range(len(args))],
                           [external.name_out(i) for i in range(external.n_out())])


def _bound(casadi, function, key: str, dyn):
    """A frame function at one frame: `function` with its input `frame` fixed."""
    kind, _, frame = key.partition(":")
    number = dyn.info.frame_indices[frame]
    symbols = _symbols(casadi, function)
    slot = [function.name_in(i) for i in range(function.n_in())].index("frame")
    args = list(symbols)
    args[slot] = casadi.SX(float(number))
    outs = function(*args)
    outs = outs if isinstance(outs, (list, tuple)) else [outs]
    names = [function.name_in(i) for i in range(function.n_in())]
    return casadi.Function(f"{kind}_{number}", symbols[:slot] + symbols[slot + 1:], list(outs),
                           names[:slot] + names[slot + 1:],
                           [function.name_out(i) for i in range(function.n_out())])
