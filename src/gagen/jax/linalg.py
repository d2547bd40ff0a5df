"""The linear algebra the printed JAX programs share: the outputs' assembly and the LDLᵀ
factorisation and solves of M, unrolled over M's structure as the C does (the plan of
gagen.codegen.ldlt, printed into each module as numbers). Runtime code: no SymPy.

M is given as its lower triangle, row by row ((..., n (n + 1) / 2)); the factors keep
U = L D in its place (the C's layout: every update is (U U) / D) and 1/D. Sums run in the
C's order, so the printed functions round as the compiled kernels do.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax.lax import optimization_barrier


def stack(entries, shape: tuple[int, ...]):
    """Entries (arrays over the same leading dimensions, or numbers) as one array of shape
    (leading..., *shape)."""
    arrays = [jnp.asarray(e) for e in entries]
    lead = jnp.broadcast_shapes(*(a.shape for a in arrays))
    dtype = jnp.result_type(*arrays)
    out = jnp.stack([jnp.broadcast_to(a, lead).astype(dtype) for a in arrays], axis=-1)
    return out.reshape(lead + tuple(shape))


def lower_index(r: int, s: int) -> int:
    """The position of M's entry (r, s), s <= r, in its lower triangle row by row."""
    return r * (r + 1) // 2 + s


def symmetric(lower, n: int):
    """The full (..., n, n) matrix of a lower triangle."""
    index = [[lower_index(max(r, s), min(r, s)) for s in range(n)] for r in range(n)]
    return lower[..., jnp.array(index)]


def kept(dtype):
    """1.0 behind an optimization barrier: a value divided by it is x exactly, in an array of
    its own. XLA's CPU fusion copies every cheap elementwise producer into each loop that
    reads it; a factor's entry or a solve's entry, read by several later steps, would carry
    the whole chain of updates behind it into each (see solve_tree and gagen.jax.printer's
    DUPLICATED). Kept, ANYmal C's printed jax.jacfwd of forward dynamics (the derivatives'
    factors, q̈ and the three solves by rows) ran in 57 instead of 204 ms per 4,096 states,
    compiled in 24 instead of 60 s."""
    return optimization_barrier(jnp.asarray(1.0, dtype))


def factor(lower, plan):
    """(U, Dinv) of M = L D Lᵀ, unrolled along `plan` (gagen.codegen.ldlt.LDLTPlan as
    numbers: n, pivots (j, terms, updates), forward, backward); each updated entry kept."""
    n, pivots = plan[0], plan[1]
    unit = kept(lower.dtype)
    U = {(r, s): lower[..., lower_index(r, s)] for r in range(n) for s in range(r)}
    dinv = [None] * n
    for j, terms, updates in pivots:
        d = lower[..., lower_index(j, j)]
        for k in terms:
            d = d - (U[j, k] * U[j, k]) * dinv[k]
        dinv[j] = 1.0 / d
        for i, ks in updates:
            u = U[i, j]
            for k in ks:
                u = u - (U[i, k] * U[j, k]) * dinv[k]
            U[i, j] = u / unit if ks else u
    return U, dinv


def solve_factored(factors, F, plan):
    """M⁻¹ F with the factors: L y = F (z = D⁻¹ y), then Lᵀ x = z."""
    U, dinv = factors
    unit = kept(F.dtype)
    n, forward, backward = plan[0], plan[2], plan[3]
    y, z, x = [None] * n, [None] * n, [None] * n
    for i, ks in forward:
        yi = F[..., i]
        for k in ks:
            yi = yi - U[i, k] * z[k]
        y[i] = yi / unit
        z[i] = yi * dinv[i]
    for i, ks in backward:
        if ks:
            xi = y[i]
            for k in ks:
                xi = xi - U[k, i] * x[k]
            x[i] = (xi * dinv[i]) / unit
        else:
            x[i] = z[i] / unit
    return stack(x, (n,))


def solve_lower(lower, F, plan):
    """M⁻¹ F for M given by its lower triangle."""
    return solve_factored(factor(lower, plan), F, plan)


def _solve_rows(factors, rows, plan):
    """M⁻¹ X for X given by its rows (each (..., m)), as the C's solve_columns."""
    U, dinv = factors
    unit = kept(dinv[0].dtype)
    forward, backward = plan[2], plan[3]
    X = list(rows)
    for i, ks in forward:
        xi = X[i]
        for k in ks:
            xi = xi - U[i, k][..., None] * X[k]
        X[i] = (xi * dinv[i][..., None]) / unit
    for i, ks in backward:
        if not ks:
            continue
        total = None
        for k in ks:
            term = U[k, i][..., None] * X[k]
            total = term if total is None else total + term
        X[i] = (X[i] - dinv[i][..., None] * total) / unit
    return jnp.stack(X, axis=-2)


def forward_derivatives(factors, dtau_dq, dtau_dqd, plan):
    """(∂q̈/∂q, ∂q̈/∂q̇, M⁻¹) = (−M⁻¹ ∂τ/∂q, −M⁻¹ ∂τ/∂q̇, M⁻¹) at q̈ = M⁻¹ F."""
    n = plan[0]
    dq = _solve_rows(factors, [-dtau_dq[..., i, :] for i in range(n)], plan)
    dqd = _solve_rows(factors, [-dtau_dqd[..., i, :] for i in range(n)], plan)
    lead = jnp.broadcast_shapes(dq.shape[:-2], factors[1][0].shape)
    eye = jnp.broadcast_to(jnp.eye(n, dtype=dq.dtype), lead + (n, n))
    Minv = _solve_rows(factors, [eye[..., i, :] for i in range(n)], plan)
    return dq, dqd, Minv


def solve_tree(lower, F, parents, unit=1.0):
    """M⁻¹ F for M given by its lower triangle, by M = Lᵀ D L along the tree (Featherstone's
    factorisation: no fill-in outside each coordinate's ancestors) and the solves
    x = L⁻¹ D⁻¹ L⁻ᵀ F, the steps and sums of the C's gagen_ltdl, gagen_cn_back and
    gagen_cn_forward in their order. `parents`: per coordinate the one before it on its
    path to the world (-1: none).

    `unit`: 1.0, as an array XLA cannot fold (the printed modules pass one number behind an
    optimization barrier where the tree branches, 1 + 0 q₀ per state along a chain: the
    barrier made the Panda arm's solve 25% slower, XLA fusing its back substitution into
    the loop that writes the result, ANYmal C's and the Panda's 8-13% faster;
    gagen.jax.printer._tree_unit). The
    factors' entries and the solves' entries, each read by several later steps, are
    divided by it, which keeps each in an array of its own (see gagen.jax.printer's
    DUPLICATED): left to XLA's fusion, the chains of updates behind them were copied into
    every reader (ANYmal C's printed forward dynamics: 10,492 operations per state in XLA's
    loops, 9,103 with them kept; 1.22 against 1.08 µs per state, medians of 31 interleaved
    runs at 4,096 states; the Panda arm's 0.37 against 0.31). x / 1.0 is x exactly."""
    n = len(parents)

    def ancestors(k):
        i = parents[k]
        while i >= 0:
            yield i
            i = parents[i]

    A = {(i, j): lower[..., lower_index(i, j)] for i in range(n)
         for j in (i, *ancestors(i))}
    for k in reversed(range(n)):
        r = 1.0 / A[k, k]
        for i in ancestors(k):
            a = (A[k, i] * r) / unit
            for j in (i, *ancestors(i)):
                A[i, j] = A[i, j] - A[k, j] * a
            A[k, i] = a
    x = [F[..., j] for j in range(n)]
    for k in reversed(range(n)):
        x[k] = x[k] / unit
        for i in ancestors(k):
            x[i] = x[i] - A[k, i] * x[k]
    x = [x[k] / A[k, k] for k in range(n)]
    for k in range(n):
        for i in ancestors(k):
            x[k] = x[k] - A[k, i] * x[i]
        x[k] = x[k] / unit
    return stack(x, (n,))
