"""Forward dynamics' JVP product on the FFI target, J(q, q̇, τ) t, as one JAX primitive.

`jax.jacfwd` pushes the standard basis through a JVP rule as a batch of tangents (under its
own `jax.vmap`). Written as XLA operations, the rule's J t is the derivative kernel's call,
its Jacobian written out over the batch, and a dot of every state's J by the basis, another
array over the batch: nv (nq + 2 nv)² multiply-adds per state where the answer is J itself,
and on the CPU every fresh array of that size costs its pages' first touch as much as the
arithmetic. JAX cannot tell that the tangents are the basis: they are a traced array, even
under `jax.jit`.

`gagen_jacobian_product` is linear in t. Its batching rule, for tangents batched where the
state is not (jax.jacfwd's basis, the same for every state), is one FFI call of the kernel
`forward_dynamics_jacobian_product`: the shim computes each state's Jacobian (∂q̈/∂q by q's
own entries) and multiplies it by the tangents in the same C loop, the result in jacfwd's
layout (the basis' axis last), and where the tangents are the identity (checked once per
call, n² comparisons) it writes the Jacobian's rows as they are. Any other batching is the
primitive again over the batch; unbatched, it lowers to the kernel's Jacobian and a dot.
Its transpose (jax.grad, jax.jacrev) is Jᵀ by the cotangent, from the same kernel.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.core import Primitive
from jax.interpreters import ad, batching, mlir

jacobian_product_p = Primitive("gagen_jacobian_product")

_TANGENT = 3  # the operands: q, qd, tau, the tangent, then p where given


def jacobian_product(ops, q, qd, tau, p, tangent):
    """J t over leading dimensions (..., nv): J = [∂q̈/∂q | ∂q̈/∂q̇ | ∂q̈/∂τ] (q by its own
    entries) of `ops` (an FFIOps) at (q, q̇, τ, p), t (..., nq + 2 nv) the stacked tangents."""
    operands = (q, qd, tau, tangent) + (() if p is None else (p,))
    return jacobian_product_p.bind(*operands, ops=ops, has_p=p is not None)


def _split(operands, has_p):
    q, qd, tau, tangent = operands[:4]
    return q, qd, tau, tangent, (operands[4] if has_p else None)


def _product(*operands, ops, has_p):
    q, qd, tau, tangent, p = _split(operands, has_p)
    jacobian = ops.forward_dynamics_jacobian(q, qd, tau, p=p)
    return jnp.einsum("...ij,...j->...i", jacobian, tangent)


def _abstract(*operands, ops, has_p):
    lead = np.broadcast_shapes(*(x.shape[:-1] for x in operands))
    return jax.core.ShapedArray(tuple(lead) + (ops.dyn.nv,), operands[_TANGENT].dtype)


jacobian_product_p.def_impl(_product)
jacobian_product_p.def_abstract_eval(_abstract)
mlir.register_lowering(jacobian_product_p, mlir.lower_fun(_product, multiple_results=False))


def _jvp(primals, tangents, *, ops, has_p):
    """Linear in the tangent t; the Jacobian's own derivative (second derivatives) is not
    on the compiled path."""
    if any(type(t) is not ad.Zero for k, t in enumerate(tangents) if k != _TANGENT):
        raise NotImplementedError(
            "gagen.jax: forward_dynamics has no second derivatives on the compiled path "
            "(target='ffi'); use gagen.jax.functions(dyn, target='jax')")
    out = jacobian_product_p.bind(*primals, ops=ops, has_p=has_p)
    dt = tangents[_TANGENT]
    if type(dt) is ad.Zero:
        return out, ad.Zero(jax.core.ShapedArray(out.shape, out.dtype))
    moved = list(primals)
    moved[_TANGENT] = dt
    return out, jacobian_product_p.bind(*moved, ops=ops, has_p=has_p)


def _transpose(ct, *operands, ops, has_p):
    """The tangent's cotangent: Jᵀ ct, summed over the dimensions t was broadcast along."""
    if any(ad.is_undefined_primal(x) for k, x in enumerate(operands) if k != _TANGENT):
        raise NotImplementedError("gagen.jax: forward dynamics' JVP product is linear in its "
                                  "tangent only")
    tangent = operands[_TANGENT]
    if type(ct) is ad.Zero:
        return [None] * len(operands)
    q, qd, tau, _, p = _split(operands, has_p)
    jacobian = ops.forward_dynamics_jacobian(q, qd, tau, p=p)
    back = jnp.einsum("...ij,...i->...j", jacobian, ct)
    out = [None] * len(operands)
    out[_TANGENT] = _unbroadcast(back, tangent.aval.shape)
    return out


def _unbroadcast(x, shape):
    """x summed over the leading dimensions that `shape` lacks or holds as 1."""
    extra = x.ndim - len(shape)
    x = jnp.sum(x, axis=tuple(range(extra))) if extra else x
    ones = tuple(k for k, n in enumerate(shape) if n == 1 and x.shape[k] != 1)
    return jnp.sum(x, axis=ones, keepdims=True) if ones else x


ad.primitive_jvps[jacobian_product_p] = _jvp
ad.primitive_transposes[jacobian_product_p] = _transpose


def _batched(args, dims, *, ops, has_p):
    tangent, tangent_dim = args[_TANGENT], dims[_TANGENT]
    others = [d for k, d in enumerate(dims) if k != _TANGENT]
    if tangent_dim is not None and all(d is None for d in others):
        return _by_tangent_batch(ops, args, jnp.moveaxis(tangent, tangent_dim, 0), has_p)
    rank = max(x.ndim - 1 - (d is not None) for x, d in zip(args, dims))
    moved = []
    for x, d in zip(args, dims):
        own = x.ndim - 1 - (d is not None)
        if d is None:
            x = x.reshape((1,) * (rank - own + 1) + x.shape)
        else:
            x = jnp.moveaxis(x, d, 0)
            x = x.reshape(x.shape[:1] + (1,) * (rank - own) + x.shape[1:])
        moved.append(x)
    return jacobian_product_p.bind(*moved, ops=ops, has_p=has_p), 0


def _by_tangent_batch(ops, args, tangents, has_p):
    """J (..., nv, n) times every tangent of `tangents` (b, ..., n): (..., nv, b), the batch
    axis last (where jax.jacfwd puts it). For b = n, one FFI call of the Jacobian times the
    tangents (the Jacobian itself where they are the identity); else the Jacobian and a dot."""
    q, qd, tau, _, p = _split(args, has_p)
    b, n = tangents.shape[0], tangents.shape[-1]
    if b != n:
        jacobian = ops.forward_dynamics_jacobian(q, qd, tau, p=p)
        return jnp.einsum("...ij,b...j->...ib", jacobian, tangents), jacobian.ndim - 1
    # each state's tangents as one row-major n x n input: (..., n * n)
    flat = jnp.moveaxis(tangents, 0, -2)
    flat = flat.reshape(flat.shape[:-2] + (n * n,))
    out = ops.jacobian_times(q, qd, tau, flat, p=p)
    return out, out.ndim - 1


batching.primitive_batchers[jacobian_product_p] = _batched
