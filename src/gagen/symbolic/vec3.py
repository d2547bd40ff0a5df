"""3-vectors and 3x3 matrices of SymPy expressions, multiplied out entry by entry.

The recursive derivations (recursive.py, aba.py) do little else than small linear
algebra on symbolic entries: rotating vectors and inertias from frame to frame, cross
products, sums. `sympy.Matrix` arithmetic is slow for that: every product goes through
DomainMatrix's EXRAW domain, which also multiplies each entry by zero to look for
infinities, and each Matrix costs more to build than its three or nine entries. Here each
entry is one `sp.Add` over the products of the non-zero entries, built once; a product
skips exact zeros and multiplies by no exact one. The result is the same SymPy expression
as the Matrix product's (SymPy puts sums and products in one canonical form), only built
with less work.

A vector is a tuple of 3 expressions (`Vec3`), a matrix a tuple of 3 rows (`Mat3`). Their
`+` would concatenate: add them with `add`, `sub`, `mat_add`. `as_vec` and `as_mat` take
anything indexable (a sympy.Matrix, a list of numbers) and sympify its entries.

A sum of several products (f = m a + alpha x h, say) is best added up as `Terms`: each
product's terms, gathered per entry and added once (`(scale_terms(m, a) + cross_terms(alpha,
h)).vec()`), instead of an Add per product whose terms the outer Add then takes apart again.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import sympy as sp

Vec3 = tuple[sp.Expr, sp.Expr, sp.Expr]
Mat3 = tuple[Vec3, Vec3, Vec3]

ZERO: Vec3 = (sp.S.Zero, sp.S.Zero, sp.S.Zero)
IDENTITY: Mat3 = ((sp.S.One, sp.S.Zero, sp.S.Zero),
                  (sp.S.Zero, sp.S.One, sp.S.Zero),
                  (sp.S.Zero, sp.S.Zero, sp.S.One))


def as_vec(v) -> Vec3:
    """A vector's 3 entries (a sympy.Matrix, list or tuple), sympified."""
    return tuple(sp.sympify(e) for e in v)


def as_mat(A) -> Mat3:
    """A 3x3 matrix as rows of sympified entries (a sympy.Matrix or nested sequences)."""
    if isinstance(A, sp.MatrixBase):
        return tuple(tuple(A[r, c] for c in range(3)) for r in range(3))
    return tuple(as_vec(row) for row in A)


def is_zero(x: sp.Expr) -> bool:
    """An exact zero (also 0.0: sympy.Matrix drops those from its products too). Never
    asks SymPy's assumptions, which cost far more than the arithmetic they would save."""
    return x.is_Number and not x


def product(*factors: sp.Expr | int) -> sp.Expr:
    """The product, without building a Mul for a zero or around exact ones (Python ints
    are taken as SymPy integers).

    The numbers are multiplied together first and passed first: Mul(c, x) is then the
    very call that Add makes again when it collects the term c x, which SymPy's cache
    answers (Mul(x, c) would miss it, and a Mul with a float costs about 0.3 ms: its
    coefficient is a new Float, whose assumptions SymPy works out from scratch)."""
    coefficient = sp.S.One
    others = []
    for f in factors:
        if isinstance(f, int):
            f = sp.Integer(f)
        if not f.is_Number:
            others.append(f)
        elif not f:
            return sp.S.Zero
        elif coefficient is sp.S.One:
            coefficient = f
        else:
            coefficient = coefficient * f
    if not others:
        return coefficient
    if coefficient is not sp.S.One:
        return sp.Mul(coefficient, *others)
    return others[0] if len(others) == 1 else sp.Mul(*others)


def total(terms: Iterable[sp.Expr]) -> sp.Expr:
    """The sum of the non-zero terms, as one Add (or the only term, or zero)."""
    kept = [t for t in terms if not is_zero(t)]
    if not kept:
        return sp.S.Zero
    return kept[0] if len(kept) == 1 else sp.Add(*kept)


def sum_of_products(pairs: Iterable[tuple[sp.Expr, sp.Expr]]) -> sp.Expr:
    """sum a * b over the pairs (a, b), the pairs with a zero left out."""
    return total(product(a, b) for a, b in pairs)


def dot(a: Sequence[sp.Expr], b: Sequence[sp.Expr]) -> sp.Expr:
    """a . b (vectors of any one length)."""
    return sum_of_products(zip(a, b))


@dataclass(frozen=True)
class Terms:
    """A 3-vector as the terms of each entry, not yet added up."""

    entries: tuple[tuple[sp.Expr, ...], tuple[sp.Expr, ...], tuple[sp.Expr, ...]]

    @staticmethod
    def of(v: Vec3) -> Terms:
        """A vector's entries as one term each."""
        return Terms(((v[0],), (v[1],), (v[2],)))

    def __add__(self, other: Terms) -> Terms:
        return Terms(tuple(a + b for a, b in zip(self.entries, other.entries)))

    def vec(self) -> Vec3:
        """The vector: one Add per entry over all its terms."""
        return tuple(total(terms) for terms in self.entries)


def scale_terms(k: sp.Expr | int, v: Vec3) -> Terms:
    """k v, as terms."""
    return Terms(tuple((product(k, e),) for e in v))


def cross_terms(a: Vec3, b: Vec3) -> Terms:
    """a x b, as terms."""
    minus = sp.S.NegativeOne
    return Terms(((product(a[1], b[2]), product(minus, a[2], b[1])),
                  (product(a[2], b[0]), product(minus, a[0], b[2])),
                  (product(a[0], b[1]), product(minus, a[1], b[0]))))


def mat_vec_terms(A: Mat3, v: Vec3) -> Terms:
    """A v, as terms."""
    return Terms(tuple(tuple(product(a, x) for a, x in zip(row, v)) for row in A))


def mat_T_vec_terms(A: Mat3, v: Vec3) -> Terms:
    """A^T v, as terms (A is not transposed)."""
    return Terms(tuple(tuple(product(A[k][c], v[k]) for k in range(3)) for c in range(3)))


def add(*vectors: Vec3) -> Vec3:
    """The entrywise sum of vectors."""
    return tuple(total(v[i] for v in vectors) for i in range(3))


def sub(a: Vec3, b: Vec3) -> Vec3:
    """a - b."""
    return add(a, neg(b))


def neg(a: Vec3) -> Vec3:
    """-a."""
    return tuple(-e for e in a)


def scale(k: sp.Expr | int, v: Vec3) -> Vec3:
    """k v."""
    return tuple(product(k, e) for e in v)


def cross(a: Vec3, b: Vec3) -> Vec3:
    """a x b."""
    return cross_terms(a, b).vec()


def mat_vec(A: Mat3, v: Vec3) -> Vec3:
    """A v."""
    return mat_vec_terms(A, v).vec()


def mat_T_vec(A: Mat3, v: Vec3) -> Vec3:
    """A^T v, without transposing A."""
    return mat_T_vec_terms(A, v).vec()


def mat_mat(A: Mat3, B: Mat3) -> Mat3:
    """A B."""
    return tuple(tuple(sum_of_products((A[r][k], B[k][c]) for k in range(3))
                       for c in range(3)) for r in range(3))


def mat_mat_T(A: Mat3, B: Mat3) -> Mat3:
    """A B^T, without transposing B."""
    return tuple(tuple(dot(A[r], B[c]) for c in range(3)) for r in range(3))


def transpose(A: Mat3) -> Mat3:
    """A^T."""
    return tuple(zip(*A))


def mat_add(*matrices: Mat3) -> Mat3:
    """The entrywise sum of matrices."""
    return tuple(tuple(total(M[r][c] for M in matrices) for c in range(3)) for r in range(3))


def mat_sub(A: Mat3, B: Mat3) -> Mat3:
    """A - B."""
    return mat_add(A, mat_neg(B))


def mat_neg(A: Mat3) -> Mat3:
    """-A."""
    return tuple(neg(row) for row in A)


def mat_scale(k: sp.Expr, A: Mat3) -> Mat3:
    """k A."""
    return tuple(scale(k, row) for row in A)


def outer(a: Vec3, b: Vec3) -> Mat3:
    """a b^T."""
    return tuple(scale(x, b) for x in a)


def skew(v: Vec3) -> Mat3:
    """[v], the matrix of v x: [v] u = v x u."""
    zero = sp.S.Zero
    return ((zero, -v[2], v[1]), (v[2], zero, -v[0]), (-v[1], v[0], zero))


def unit(j: int) -> Vec3:
    """e_j, the j-th coordinate axis."""
    return IDENTITY[j]


def expanded(e: sp.Expr) -> sp.Expr:
    """sp.expand(e), without its cost when e is already a sum of products of symbols,
    numbers and integer powers of symbols (most entries here), which it leaves as is."""
    return e if _is_expanded(e) else sp.expand(e)


def _is_expanded(e: sp.Expr) -> bool:
    terms = e.args if e.is_Add else (e,)
    return all(_is_monomial(t) for t in terms)


def _is_monomial(e: sp.Expr) -> bool:
    factors = e.args if e.is_Mul else (e,)
    return all(f.is_Symbol or f.is_Number
               or (f.is_Pow and f.base.is_Symbol and f.exp.is_Integer) for f in factors)
