"""gagen inside JAX: a model's dynamics as JAX functions (`pip install gagen[jax]`).

    import jax, gagen, gagen.jax
    jax.config.update("jax_enable_x64", True)
    dyn = gagen.load("panda.urdf")
    f = gagen.jax.functions(dyn)                  # the compiled kernels, through XLA's FFI
    qdd = jax.jit(jax.vmap(f["forward_dynamics"]))(Q, QD, TAU)   # one C loop per batch
    J = jax.jacfwd(f["forward_dynamics"])(q, qd, tau)            # gagen's analytic derivatives
    g = gagen.jax.functions(dyn, target="jax")    # the same programs printed as JAX

`functions(dyn, target=...)` returns a dict of functions keyed by the `Dynamics` method
they are (gagen.jax.registry.METHODS): forward_dynamics(q, qd, tau, p=None),
inverse_dynamics(q, qd, qdd, p=None), mass_matrix(q, p=None), gravity, forcing, energy,
frame_placement(q, frame, p=None), frame_jacobian, frame_velocity(q, qd, frame, p=None),
coriolis_matrix, regressor, regressor_parameters(p=None), and the derivatives
(inverse_dynamics_derivatives, forward_dynamics_derivatives, linearize). Each takes JAX
(or NumPy) arrays of shape (size,) or with leading batch dimensions, works under jax.jit
and jax.vmap, and returns what the method returns.

Targets:

- "ffi" (default): gagen's compiled kernels through XLA's foreign-function interface: one
  typed FFI handler (gagen.jax.ffi), compiled once per jaxlib version into gagen's cache,
  that calls any model's kernels through the table its module exports. Under jax.vmap the
  whole batch is one call of its C loop. CPU only.
- "callback": the same kernels through `jax.pure_callback` and gagen's stacked calls: the
  fallback where the FFI is unavailable (no C++ compiler, a JAX without jax.ffi) or the
  computation runs on another device (the arrays are copied to the host).
- "jax": the model's optimised programs (the same CSE'd assignments as the C) printed as
  JAX (gagen.jax.printer), for any backend jax.jit compiles for (CPU, GPU, TPU).

Derivatives: `jax.jvp`, `jax.jacfwd`, `jax.jacrev`, `jax.grad` use gagen's analytic
derivatives through custom JVP rules (gagen.jax.rules): the derivative kernels on the
compiled targets, the printed derivative programs on "jax". Parameters (`p`: None, a dict
of overrides, or a full array): see gagen.jax.functions (the module) for which are
differentiable on each target.

Precision: the compiled targets compute in double; float32 inputs are widened, computed in
double and the results rounded to float32 once. The printed target computes in the inputs'
dtype (float64 needs `jax.config.update("jax_enable_x64", True)`).
"""

from __future__ import annotations

try:
    import jax  # noqa: F401 (the real JAX: this package's absolute imports never shadow it)
except ImportError as exc:  # pragma: no cover - the extra is missing
    raise ImportError("gagen.jax needs JAX: pip install gagen[jax]") from exc

from gagen.jax.registry import KERNELS, METHODS, Kernel, Method

TARGETS = ("ffi", "callback", "jax")

__all__ = ["KERNELS", "METHODS", "TARGETS", "Kernel", "Method", "ffi_calls", "functions",
           "kinematic_parameters"]


def functions(dyn, target: str = "ffi", cache_dir=None) -> dict:
    """The model's dynamics as JAX functions, keyed by method name (module docstring).

    `dyn` is a compiled dynamics object (`gagen.load(model)`); `target` is "ffi" (the
    compiled kernels through XLA's FFI, CPU), "callback" (the same through
    jax.pure_callback) or "jax" (the programs printed as JAX: any backend). The FFI shim
    and the printed modules are built on first use into gagen's cache (`cache_dir`, else
    gagen's default); the derivative module and printed derivatives on first use of a
    derivative."""
    if target not in TARGETS:
        raise ValueError(f"unknown target '{target}' (expected one of {', '.join(TARGETS)})")
    if getattr(dyn, "backend", None) != "compiled":
        raise TypeError("gagen.jax.functions needs a compiled dynamics object "
                        "(gagen.load(model), backend='compiled')")
    from gagen.jax.builder import Builder

    if target == "ffi":
        from gagen.jax.ops import FFIOps

        builder = Builder(FFIOps(dyn, cache_dir))
    elif target == "callback":
        from gagen.jax.ops import CallbackOps

        builder = Builder(CallbackOps(dyn, cache_dir))
    else:
        from gagen.jax.printed import PrintedOps

        ops = PrintedOps(dyn, cache_dir)
        builder = Builder(ops, parameter_program=ops.main)
    return {name: builder.function(method) for name, method in METHODS.items()}


def kinematic_parameters(dyn, cache_dir=None) -> list[str]:
    """The parameters the regressor's kinematics read (lengths, gravity): on the compiled
    targets, derivatives with respect to them raise a ValueError (target="jax" has them)."""
    from gagen.jax.printed import printed_module

    module = printed_module(dyn, "dynamics", cache_dir)
    names = list(dyn.parameters)
    return [names[k] for k in module.KINEMATIC]


def ffi_calls() -> int:
    """How many times gagen's FFI handler has run in this process (a batch counts once);
    0 before the shim is loaded."""
    from gagen.jax import ffi

    return 0 if ffi._shim is None else ffi._shim.calls()
