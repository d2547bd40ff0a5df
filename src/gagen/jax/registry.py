"""Which `Dynamics` method is which compiled kernel, and which derivative rule it has: the
table gagen.jax builds its functions from (one entry per method).

`KERNELS` are the C functions of a model's tables (codegen/templates/c/gagen_api.h) as the
FFI shim calls them: `member(inputs..., p, [frame,] outputs...)`; the shim's C++ dispatch
is rendered from this table (gagen.jax.ffi), so a kernel added to gagen_api.h is one entry
here. `METHODS` are the functions `gagen.jax.functions` returns: a method's arguments, its
kernel, how its flat outputs become its results, and the names of its derivative rules
(gagen.jax.rules): `rule` for the state arguments, `parameter_rule` for p through the
regressor. A method without a rule has no derivative: differentiating it raises a
NotImplementedError naming it (the printed target differentiates its program instead).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gagen.runtime.taskspace import LOCAL_WORLD_ALIGNED

# the state arguments of the methods and the size of each
ARGUMENT_SIZES = {"q": "nq", "qd": "nv", "qdd": "nv", "tau": "nv"}


@dataclass(frozen=True)
class Kernel:
    """A C kernel of a model's table: `table` "model" (gagen_model_api) or "derivatives"
    (gagen_derivatives_api), its `member`, the sizes of its state inputs (before p), its
    outputs' per-state shapes (each dimension a size field of the table: nq, nv, np, nb,
    nf, nreg; a number; or a tuple of those to multiply), whether it takes a frame index
    (after p) and then a reference (always LOCAL_WORLD_ALIGNED: the frame's origin, world
    axes, the Dynamics methods' default), whether it returns a status (0: success), and
    `blocks`: 0, or the number of square nv x nv blocks the member writes, which the shim
    joins side by side (row by row) into the kernel's one output, and `configuration`:
    whether the shim writes the first of them by q's own entries (nq columns: a floating
    joint's columns through its quaternion's rates, gagen.jax.rules.by_configuration).
    `tangents`: whether the last state input is a (njac x njac) matrix of tangents (row b
    the tangent b, passed to the shim, not to the member) that the shim multiplies each row
    of the Jacobian by (gagen.jax.product). Sizes: a table's fields, and njac = nq + 2 nv."""

    table: str
    member: str
    inputs: tuple[str, ...]
    outputs: tuple[tuple, ...]
    frame: bool = False
    status: bool = False
    reference: bool = False
    blocks: int = 0
    configuration: bool = False
    tangents: bool = False

    def c_arguments(self) -> str:
        """The C call's arguments, from the shim's arrays `in` and `out` (or its square
        `block`s, for a kernel whose blocks are joined) and `frame`."""
        states = len(self.inputs) - (1 if self.tangents else 0)
        names = [f"in[{k}]" for k in range(states)] + [f"in[{len(self.inputs)}]"]
        names += ["frame"] if self.frame else []
        names += [str(LOCAL_WORLD_ALIGNED)] if self.reference else []
        if self.blocks:
            return ", ".join(names + [f"block[{k}]" for k in range(self.blocks)])
        return ", ".join(names + [f"out[{k}]" for k in range(len(self.outputs))])

    def c_widths(self) -> list[str]:
        """Each output's per-state width as a C expression in the table's sizes."""
        return [" * ".join(str(f) for f in _factors(shape)) or "1" for shape in self.outputs]


KERNELS: dict[str, Kernel] = {
    "mass_matrix": Kernel("model", "mass_matrix", ("nq",), (("nv", "nv"),)),
    "forcing": Kernel("model", "forcing", ("nq", "nv", "nv"), (("nv",),)),
    "forward_dynamics": Kernel("model", "forward_dynamics", ("nq", "nv", "nv"), (("nv",),),
                               status=True),
    "inverse_dynamics": Kernel("model", "inverse_dynamics", ("nq", "nv", "nv"), (("nv",),)),
    "energy": Kernel("model", "energy", ("nq", "nv"), ((2,),)),
    "gravity": Kernel("model", "gravity", ("nq",), (("nv",),)),
    "frame_placement": Kernel("model", "frame_placement", ("nq",), ((3, 3), (3,)),
                              frame=True, status=True),
    "frame_jacobian": Kernel("model", "frame_jacobian", ("nq",), ((6, "nv"),), frame=True,
                             status=True, reference=True),
    "frame_velocity": Kernel("model", "frame_velocity", ("nq", "nv"), ((6,),), frame=True,
                             status=True, reference=True),
    "regressor": Kernel("model", "regressor", ("nq", "nv", "nv"), (("nv", "nreg"),)),
    "regressor_parameters": Kernel("model", "regressor_parameters", (), (("nreg",),)),
    "inverse_dynamics_derivatives": Kernel("derivatives", "inverse_dynamics_derivatives",
                                           ("nq", "nv", "nv"), (("nv", "nv"), ("nv", "nv"))),
    "forward_dynamics_derivatives": Kernel("derivatives", "forward_dynamics_derivatives",
                                           ("nq", "nv", "nv"),
                                           (("nv", "nv"), ("nv", "nv"), ("nv", "nv")),
                                           status=True),
    # the same kernel, its three nv x nv blocks joined side by side into one (nv, nq + 2 nv)
    # Jacobian per state ([∂q̈/∂q | ∂q̈/∂q̇ | M⁻¹], ∂q̈/∂q by q's own entries): the form the
    # JVP rule multiplies, written in the C loop (while the blocks are in cache) rather than
    # mapped and joined by XLA in passes over the batch
    "forward_dynamics_jacobian": Kernel("derivatives", "forward_dynamics_derivatives",
                                        ("nq", "nv", "nv"), (("nv", "njac"),), status=True,
                                        blocks=3, configuration=True),
    # the same Jacobian times tangents (njac x njac) in the same loop: jax.jacfwd's product
    # by its basis without the Jacobian written out and read back (gagen.jax.product)
    "forward_dynamics_jacobian_product": Kernel(
        "derivatives", "forward_dynamics_derivatives", ("nq", "nv", "nv", "njac * njac"),
        (("nv", "njac"),), status=True, blocks=3, configuration=True, tangents=True),
    "coriolis_matrix": Kernel("derivatives", "coriolis_matrix", ("nq", "nv"), (("nv", "nv"),)),
    "linearize": Kernel("derivatives", "linearize", ("nq", "nv", "nv"),
                        (((2, "nv"), (2, "nv")), ((2, "nv"), "nv")), status=True),
}


@dataclass(frozen=True)
class Method:
    """A function of `gagen.jax.functions`: the `Dynamics` method `name`, its state
    arguments (in order; `p` follows, and `frame` for frame methods, as the method takes
    them), its kernel, whether its outputs come back as a tuple (`split`: energy's two
    numbers as (kinetic, potential)), and its derivative rules (gagen.jax.rules; None:
    none) for the state arguments and for p (through the regressor)."""

    name: str
    args: tuple[str, ...]
    kernel: str
    rule: str | None = None
    parameter_rule: str | None = None
    split: bool = False

    @property
    def frame(self) -> bool:
        return KERNELS[self.kernel].frame


METHODS: dict[str, Method] = {m.name: m for m in (
    Method("mass_matrix", ("q",), "mass_matrix", "mass_matrix", "mass_matrix"),
    Method("forcing", ("q", "qd", "tau"), "forcing", "forcing", "forcing"),
    Method("forward_dynamics", ("q", "qd", "tau"), "forward_dynamics", "forward_dynamics",
           "forward_dynamics"),
    Method("inverse_dynamics", ("q", "qd", "qdd"), "inverse_dynamics", "inverse_dynamics",
           "inverse_dynamics"),
    Method("gravity", ("q",), "gravity", "gravity", "gravity"),
    Method("energy", ("q", "qd"), "energy", "energy", split=True),
    Method("frame_placement", ("q",), "frame_placement", "frame_placement"),
    Method("frame_jacobian", ("q",), "frame_jacobian"),
    Method("frame_velocity", ("q", "qd"), "frame_velocity", "frame_velocity"),
    Method("regressor", ("q", "qd", "qdd"), "regressor"),
    Method("regressor_parameters", (), "regressor_parameters", None, "regressor_parameters"),
    Method("inverse_dynamics_derivatives", ("q", "qd", "qdd"),
           "inverse_dynamics_derivatives"),
    Method("forward_dynamics_derivatives", ("q", "qd", "tau"),
           "forward_dynamics_derivatives"),
    Method("coriolis_matrix", ("q", "qd"), "coriolis_matrix", "coriolis_matrix"),
    Method("linearize", ("q", "qd", "tau"), "linearize"),
)}


def _factors(shape: tuple) -> list:
    """The factors of a shape's dimensions, flattened."""
    return [f for dim in shape for f in (dim if isinstance(dim, tuple) else (dim,))]


def output_shapes(kernel: Kernel, sizes: dict[str, int]) -> list[tuple[int, ...]]:
    """The per-state shape of each output of `kernel` for a model of these sizes."""

    def value(factor) -> int:
        if isinstance(factor, str):
            return sizes[factor]
        return factor

    return [tuple(math.prod(value(f) for f in (dim if isinstance(dim, tuple) else (dim,)))
                  for dim in shape) for shape in kernel.outputs]
