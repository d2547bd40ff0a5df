"""Sine and cosine of the joint angles for the printed JAX programs: gagen_math.h's method
(fdlibm's) in elementwise jax.numpy, so XLA fuses and vectorises it. Runtime code: no SymPy.

XLA's float64 sin and cos on the CPU are calls per element (about 10 ns a sin+cos pair:
ANYmal C's 12 angles were about a tenth of its printed forward dynamics), and XLA's fusion
copies them, like any elementwise producer, into each loop that reads them (the printed
Panda arm's 7 angles were 16 sines). `sincos_stacked` computes every angle of a program
under one check, behind lax.cond, which XLA does not fuse through: each sine and cosine is
computed once, into an array of its own that its readers read (one array per angle, not
one (batch, angles) array: its readers would read a column each, strided, which cost the
printed ANYmal C a third of the gain).

Method (gagen_math.h, fdlibm / FreeBSD msun): n = rint(x 2/π) and x − n π/2 = y0 + y1 by
Cody-Waite reduction with π/2 in 33-bit parts (every product n·part is exact as
|n| < 2^20), the second and third rounds taken where the first lost more than 16 (49) bits
to cancellation (x near a multiple of π/2); fdlibm's minimax kernels on [−π/4, π/4] and the
quadrant chosen by n mod 4 with selects. The rounds' compensation terms rely on XLA keeping
IEEE arithmetic (no reassociation: XLA's CPU default); rint, not the 1.5·2^52 trick, which
XLA's simplifier folds away.

Accuracy: for |x| < BOUND = 2^20 within 1 ulp of the correctly rounded result (as the C's;
tests/test_jax.py checks against NumPy at a million points and at the multiples of π/2),
sin(±0) = ±0, cos(±0) = 1. Where any angle of a batch is beyond BOUND, infinite or NaN,
that batch's angles beyond it are jnp.sin's and jnp.cos's (NaN for inf and NaN), chosen
with lax.cond over the whole batch (under jax.vmap too: a custom batching rule), so the
common batch pays one max-reduction for the check, not XLA's sin.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

BOUND = 1048576.0  # 2^20: below it the reduction's products n·(π/2)_k are exact

_INVPIO2 = 6.36619772367581382433e-01
# π/2 = PIO2_1 + PIO2_2 + PIO2_3 + PIO2_3T, each of the first three 33 bits;
# PIO2_kT = π/2 − (PIO2_1 + … + PIO2_k)
_PIO2_1 = 1.57079632673412561417e+00
_PIO2_1T = 6.07710050650619224932e-11
_PIO2_2 = 6.07710050630396597660e-11
_PIO2_2T = 2.02226624879595063154e-21
_PIO2_3 = 2.02226624871116645580e-21
_PIO2_3T = 8.47842766036889956997e-32
# fdlibm's __kernel_sin coefficients, negated (NSk = −Sk), and __kernel_cos's
_NS = (1.66666666666666324348e-01, -8.33333333332248946124e-03, 1.98412698298579493134e-04,
       -2.75573137070700676789e-06, 2.50507602534068634195e-08, -1.58969099521155010221e-10)
_C = (4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
      -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)
_EXPONENT = 0x7FF0000000000000


def _exponent(v):
    """The biased exponent bits of v (as int64, shifted by 52)."""
    return lax.bitcast_convert_type(v, jnp.int64) & _EXPONENT


def _round(r, fn, part, tail):
    """One further Cody-Waite round: (r, w, y0) with x − n π/2 = y0 + (w − (r − y0))."""
    w = fn * part
    t = r - w
    w = fn * tail - ((r - t) - w)
    return t, w, t - w


def _reduce(x):
    """(y0, m, n mod 4 as int64) with x − n π/2 = y0 − m, |y0| ≲ π/4, for |x| < BOUND."""
    n = jnp.rint(x * _INVPIO2).astype(jnp.int64)
    # fn from the integer: +0 for x = −0, so that the reduction keeps sin(−0) = −0
    fn = n.astype(x.dtype)
    r = x - fn * _PIO2_1  # exact
    w = fn * _PIO2_1T
    y0 = r - w
    ex = _exponent(x)
    r2, w2, y2 = _round(r, fn, _PIO2_2, _PIO2_2T)
    r3, w3, y3 = _round(r2, fn, _PIO2_3, _PIO2_3T)
    third = ex - _exponent(y2) > (49 << 52)
    r2, w2, y2 = (jnp.where(third, a, b) for a, b in ((r3, r2), (w3, w2), (y3, y2)))
    second = ex - _exponent(y0) > (16 << 52)
    r, w, y0 = (jnp.where(second, a, b) for a, b in ((r2, r), (w2, w), (y2, y0)))
    return y0, w - (r - y0), n


def _kernel(y0, m, n):
    """(sin, cos) of n π/2 + y0 − m from fdlibm's kernels on [−π/4, π/4] (gagen_math.h's
    gagen_trig_kernel, Estrin form) and the quadrant n mod 4."""
    z = y0 * y0
    w = z * z
    z4 = w * w
    v = z * y0
    hz = 0.5 * z
    t = 1.0 - hz
    ps = ((_NS[0] + z * _NS[1]) + w * (_NS[2] + z * _NS[3])) + z4 * (_NS[4] + z * _NS[5])
    pc = ((_C[0] + z * _C[1]) + w * (_C[2] + z * _C[3])) + z4 * (_C[4] + z * _C[5])
    ks = y0 - (v * ps + m * t)  # ends with a subtraction: sin(−0) = −0
    kc = t + (w * pc + (((1.0 - t) - hz) + y0 * m))
    # (sin, cos) = (ks, kc), (kc, −ks), (−ks, −kc), (−kc, ks) for n mod 4 = 0, 1, 2, 3
    odd = (n & 1) == 1
    s = jnp.where(odd, kc, ks)
    c = jnp.where(odd, ks, kc)
    return jnp.where((n & 2) == 2, -s, s), jnp.where(((n + 1) & 2) == 2, -c, c)


def sincos_fast(x):
    """(sin x, cos x) elementwise for float64 x, within 1 ulp for |x| < BOUND; beyond it
    less accurate (inf and NaN give NaN). Only elementwise arithmetic and selects."""
    return _kernel(*_reduce(x))


def _beyond(x):
    """sincos_fast, with jnp.sin and jnp.cos where |x| is not below BOUND."""
    s, c = sincos_fast(x)
    far = ~(jnp.abs(x) < BOUND)
    return jnp.where(far, jnp.sin(x), s), jnp.where(far, jnp.cos(x), c)


def _all(method, xs):
    return tuple(v for x in xs for v in method(x))


def _checked(xs):
    # (sin, cos) of each x: sincos_fast unless some |x| is not below BOUND (NaN included:
    # max is NaN then), which sends the whole batch to _beyond
    largest = jnp.max(jnp.stack([jnp.max(jnp.abs(x)) for x in xs]))
    return lax.cond(largest < BOUND, lambda xs: _all(sincos_fast, xs),
                    lambda xs: _all(_beyond, xs), xs)


@jax.custom_batching.custom_vmap
def _sincos_batch(xs):
    return _checked(xs)


@_sincos_batch.def_vmap
def _sincos_batch_rule(axis_size, in_batched, xs):
    # elementwise: the batched arrays are just bigger ones, checked as a whole
    return _checked(xs), tuple(b for b in in_batched[0] for _ in range(2))


@jax.custom_jvp
def _sincos(xs):
    return _sincos_batch(xs)


@_sincos.defjvp
def _sincos_jvp(primals, tangents):
    (xs,), (dxs,) = primals, tangents
    out = _sincos(xs)
    dout = []
    for i, dx in enumerate(dxs):
        s, c = out[2 * i], out[2 * i + 1]
        dout += [c * dx, -s * dx]
    return out, tuple(dout)


def sincos(x):
    """(sin x, cos x) of a float64 array: sincos_fast where every |x| < BOUND, else
    jnp.sin and jnp.cos beyond it; derivatives (cos x, −sin x)."""
    return _sincos((jnp.asarray(x),))


def sincos_stacked(angles):
    """(sin a0, cos a0, sin a1, cos a1, …) of the angles (float64 arrays), computed together
    and checked together: an array of its own for each, which its readers read (XLA's
    fusion would otherwise copy the polynomials into every reader)."""
    xs = tuple(jnp.asarray(a) for a in angles)
    if any(x.dtype != jnp.float64 for x in xs):
        return _all(lambda x: (jnp.sin(x), jnp.cos(x)), xs)  # the constants are float64's
    return _sincos(xs)
