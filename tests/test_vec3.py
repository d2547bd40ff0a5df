"""gagen.symbolic.vec3 builds the same SymPy expressions as sympy.Matrix arithmetic."""

import sympy as sp

from gagen.symbolic import vec3

a = sp.symbols("a0:3")
b = sp.symbols("b0:3")
c, s, m = sp.symbols("c s m")
# a rotation with exact zeros and ones, a float, and symbolic entries, as the joints give
R = ((1, 0, 0), (0, c, -s), (sp.Float(0.5), s, c))
A = tuple(tuple(sp.Symbol(f"A{r}{k}") for k in range(3)) for r in range(3))


def entries(M: sp.Matrix) -> tuple:
    return tuple(M) if M.shape[1] == 1 else tuple(tuple(M.row(r)) for r in range(M.rows))


def test_products_match_sympy_matrices():
    Rm = vec3.as_mat(R)
    assert vec3.mat_vec(Rm, a) == entries(sp.Matrix(R) * sp.Matrix(a))
    assert vec3.mat_T_vec(Rm, a) == entries(sp.Matrix(R).T * sp.Matrix(a))
    assert vec3.mat_mat(Rm, A) == entries(sp.Matrix(R) * sp.Matrix(A))
    assert vec3.mat_mat_T(A, Rm) == entries(sp.Matrix(A) * sp.Matrix(R).T)
    assert vec3.cross(a, b) == entries(sp.Matrix(a).cross(sp.Matrix(b)))
    assert vec3.dot(a, b) == sp.Matrix(a).dot(sp.Matrix(b))
    assert vec3.outer(a, b) == entries(sp.Matrix(a) * sp.Matrix(b).T)
    assert vec3.skew(a) == entries(sp.Matrix([[0, -a[2], a[1]], [a[2], 0, -a[0]],
                                              [-a[1], a[0], 0]]))


def test_sums_and_scaling_match_sympy_matrices():
    assert vec3.add(a, b, vec3.cross(a, b)) == entries(sp.Matrix(a) + sp.Matrix(b)
                                                       + sp.Matrix(a).cross(sp.Matrix(b)))
    assert vec3.sub(a, vec3.scale(2, b)) == entries(sp.Matrix(a) - 2 * sp.Matrix(b))
    assert vec3.mat_sub(A, vec3.mat_scale(m, vec3.as_mat(R))) == \
        entries(sp.Matrix(A) - m * sp.Matrix(R))
    terms = vec3.scale_terms(m, a) + vec3.cross_terms(a, b) + vec3.mat_vec_terms(A, b) \
        + vec3.mat_T_vec_terms(A, a) + vec3.Terms.of(b)
    M = sp.Matrix(A)
    assert terms.vec() == entries(m * sp.Matrix(a) + sp.Matrix(a).cross(sp.Matrix(b))
                                  + M * sp.Matrix(b) + M.T * sp.Matrix(a) + sp.Matrix(b))


def test_products_leave_out_zeros_and_ones():
    assert vec3.product(0, a[0]) is sp.S.Zero
    assert vec3.product(sp.Float(0.0), a[0]) is sp.S.Zero
    assert vec3.product(1, a[0]) is a[0]
    assert vec3.product(-1, 2, a[0], a[1]) == -2 * a[0] * a[1]
    assert vec3.total([sp.S.Zero, a[0]]) is a[0]
    assert vec3.total([]) is sp.S.Zero


def test_expanded_matches_sympy_expand():
    for e in (a[0] * b[0] - 2 * a[1] ** 2 + sp.Float(0.25) * c,  # already expanded
              m * (a[0] ** 2 + a[1] ** 2), (1 - c) * a[0] * a[1] + c, (a[0] + b[0]) ** 2,
              sp.sin(a[0]) * (b[0] + b[1])):
        assert vec3.expanded(e) == sp.expand(e)
