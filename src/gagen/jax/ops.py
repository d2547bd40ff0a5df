"""The primal evaluations behind gagen.jax's functions, one class per target.

Each `Ops` evaluates a method of gagen.jax.registry.METHODS on JAX arrays whose leading
(batch) dimensions broadcast against each other, with p the full parameter array (or None:
the model's defaults), and returns the method's results shaped (lead..., per-state shape).
Nothing here is differentiated by JAX on the compiled targets: gagen.jax.functions wraps
the calls in custom JVP rules (gagen.jax.rules).

- `FFIOps`: the compiled kernels through gagen's XLA FFI handler (gagen.jax.ffi), one call
  per batch, on the CPU;
- `CallbackOps`: the same kernels through `jax.pure_callback` and gagen's own stacked calls
  (the fallback where the FFI is unavailable: no C++ compiler, a JAX without jax.ffi, a
  computation placed on another device);
- `PrintedOps` (gagen.jax.printed): the programs printed as JAX.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from gagen.jax.registry import KERNELS, METHODS, Method, output_shapes


class Ops:
    """What every target shares: the model's sizes and the shapes of each method's results."""

    target = ""

    def __init__(self, dyn, cache_dir=None):
        self.dyn = dyn
        self.cache_dir = cache_dir  # where the FFI shim and the printed modules are kept
        info = dyn.info
        self.sizes = {"nq": dyn.nq, "nv": dyn.nv, "np": len(dyn.parameters),
                      "nb": len(info.bodies), "nf": len(info.frames),
                      "nreg": len(info.regressor_names), "njac": dyn.nq + 2 * dyn.nv}

    def shapes(self, method: Method) -> list[tuple[int, ...]]:
        return output_shapes(KERNELS[method.kernel], self.sizes)

    def call(self, name: str, *states, p=None, frame: int = -1):
        """The results of method `name` at `states` (in its argument order)."""
        raise NotImplementedError

    def forward_dynamics_jacobian(self, q, qd, tau, p=None):
        """[∂q̈/∂q | ∂q̈/∂q̇ | M⁻¹] side by side, (..., nv, nq + 2 nv), ∂q̈/∂q by q's own
        entries: forward dynamics' derivative blocks as the one matrix its JVP rule
        multiplies."""
        from gagen.jax.rules import by_configuration, side_by_side

        dq, dqd, minv = self.call("forward_dynamics_derivatives", q, qd, tau, p=p)
        return side_by_side([by_configuration(self.dyn.info.joints, q, dq), dqd, minv])

    @staticmethod
    def lead(arrays) -> tuple[int, ...]:
        """The broadcast leading dimensions of arrays of one state each."""
        return tuple(np.broadcast_shapes(*(np.shape(a)[:-1] for a in arrays))) if arrays \
            else ()

    @staticmethod
    def results(method: Method, outputs: list):
        """A method's results from its outputs: one array, a tuple, or energy's pair."""
        if method.split:
            (out,) = outputs
            return out[..., 0], out[..., 1]
        return outputs[0] if len(outputs) == 1 else tuple(outputs)


def _dtype(states, p):
    """The working dtype: the states', else p's, else JAX's default float."""
    if states:
        return states[0].dtype
    return p.dtype if p is not None else jnp.asarray(0.0).dtype


class FFIOps(Ops):
    """The compiled kernels of a model's modules through gagen's FFI handler."""

    target = "ffi"

    def __init__(self, dyn, cache_dir=None):
        from gagen.jax.ffi import floating_attribute, shim

        super().__init__(dyn, cache_dir)
        self.shim = shim(cache_dir)
        self.ids = {name: k for k, name in enumerate(KERNELS)}
        self.floating = floating_attribute(dyn.info.joints)
        self._tables: dict[str, tuple[int, int]] = {}

    def table(self, kind: str) -> tuple[int, int]:
        """(slot, key) of the model's table `kind`; the derivative module is found or built
        on first use (as dyn's derivative methods do)."""
        found = self._tables.get(kind)
        if found is None:
            if kind == "model":
                module = self.dyn.module
            else:
                self.dyn.load_derivatives()
                module = self.dyn.derivative_module
            found = self._tables[kind] = self.shim.register(module, kind)
        return found

    def call(self, name: str, *states, p=None, frame: int = -1):
        method = METHODS[name]
        return self.results(method, self._kernel(method.kernel, states, p, frame))

    def forward_dynamics_jacobian(self, q, qd, tau, p=None):
        """The derivative kernel's blocks, the first by q's own entries, joined side by
        side in the shim's C loop (one pass over the batch, no map or join by XLA)."""
        (jacobian,) = self._kernel("forward_dynamics_jacobian", (q, qd, tau), p, -1)
        return jacobian

    def jacobian_times(self, q, qd, tau, tangents, p=None):
        """That Jacobian times tangents (..., n n), each state's n x n row-major (row b the
        tangent b, n = nq + 2 nv), in the same C loop: (..., nv, n), the tangents' index
        last; the Jacobian itself where they are the identity (gagen.jax.product)."""
        tangents = tangents.astype(_dtype((q,), p))
        (out,) = self._kernel("forward_dynamics_jacobian_product", (q, qd, tau, tangents), p,
                              -1)
        return out

    def _kernel(self, name: str, states, p, frame: int) -> list:
        """The outputs of KERNELS[name] at states, shaped (lead..., per-state shape)."""
        from gagen.jax.ffi import call_kernel

        kernel = KERNELS[name]
        dtype = _dtype(states, p)
        slot, key = self.table(kernel.table)
        arrays = list(states) + ([] if p is None else [p])
        lead = self.lead(arrays)
        shapes = output_shapes(kernel, self.sizes)
        flat = call_kernel(self.ids[name], kernel, slot, key, list(states), p, frame,
                           lead, [int(np.prod(s)) for s in shapes], dtype, self.floating)
        return [f.reshape(lead + s) for f, s in zip(flat, shapes)]


class CallbackOps(Ops):
    """The compiled kernels through `jax.pure_callback` and gagen's stacked calls: one
    Python callback per batch (vmap_method="expand_dims"), on any device JAX copies from."""

    target = "callback"

    def call(self, name: str, *states, p=None, frame: int = -1):
        method = METHODS[name]
        dtype = _dtype(states, p)
        arrays = list(states) + ([] if p is None else [p])
        lead = self.lead(arrays)
        shapes = self.shapes(method)
        result_shapes = [jax.ShapeDtypeStruct(lead + s, dtype) for s in shapes]
        evaluate = _host_call(self.dyn, method, frame, p is not None, shapes)
        out = jax.pure_callback(evaluate, result_shapes, *arrays, vmap_method="expand_dims")
        return self.results(method, list(out))


def _host_call(dyn, method: Method, frame: int, has_p: bool, shapes):
    """The host function of a callback: gagen's stacked call on the broadcast states (one
    per row; parameters per row when they vary), in double, rounded to the inputs' dtype."""

    def evaluate(*arrays):
        dtype = arrays[0].dtype if arrays else np.float64
        states = [np.asarray(a, dtype=np.float64) for a in arrays[:len(method.args)]]
        p = np.asarray(arrays[-1], dtype=np.float64) if has_p else None
        lead = np.broadcast_shapes(*(a.shape[:-1] for a in arrays)) if arrays else ()
        rows = int(np.prod(lead))
        flat = [np.broadcast_to(a, lead + a.shape[-1:]).reshape(rows, a.shape[-1])
                for a in states]
        if p is not None and p.ndim > 1:
            pr = np.broadcast_to(p, lead + p.shape[-1:]).reshape(rows, p.shape[-1])
            parts = [_evaluate(dyn, method, [s[k] for s in flat], pr[k], frame)
                     for k in range(rows)]
            outputs = [np.stack([part[o] for part in parts]) for o in range(len(shapes))]
        else:
            outputs = _evaluate(dyn, method, flat, p, frame)
            if not method.args:
                outputs = [o[None] for o in outputs]
        return tuple(np.asarray(o, dtype=np.float64).reshape(lead + s).astype(dtype)
                     for o, s in zip(outputs, shapes))

    return evaluate


def _evaluate(dyn, method: Method, states, p, frame: int) -> list[np.ndarray]:
    """gagen's own (stacked) call of a method, as a list of its outputs."""
    if method.name == "regressor_parameters":
        return [dyn.regressor_parameters(p)]
    if method.frame:
        if method.name == "frame_placement":
            R, pos = dyn.frame_placement(*states, frame, p=p)
            return [R, pos]
        return [getattr(dyn, method.name)(*states, frame, p=p)]
    out = getattr(dyn, method.name)(*states, p=p)
    if method.split:
        return [np.stack(out, axis=-1)]
    return list(out) if isinstance(out, tuple) else [out]
