"""Derivatives of the equations of motion: what MPC and trajectory optimisation need.

`derive_derivatives(eqs)` differentiates the straight-line program of an `Equations`
(either derivation: Gibbs-Appell or recursive RNEA/CRBA) by forward mode through its named
intermediates (`differentiate.differentiate`: the chain rule per definition, each sum
named; nothing is expanded, nothing is a finite difference). From 4 coordinates on, a
fixed-base model's inverse-dynamics derivatives come instead from the analytical
algorithm of `rnea_derivatives` (the chain rule worked out once by hand in one common
frame, then written symbolically per model: half the Panda's operations), and so do a
floating-base model's, always (a floating joint's six coordinates are carried like the
other joints'; ANYmal's kernel has half the operations of forward mode). The rule and its
measurements are at ANALYTIC_FROM_DOF. Either way it returns one program,
`DerivativeEquations.intermediates` = `eqs.intermediates` followed by the derivative's
own definitions (numbered after them, never defining a name twice, reusing every
expression `eqs` already named), and two kernels' outputs, flat lists of expressions in
that program:

kernel `inverse_dynamics_derivatives`, arguments (q, qd, qdd, p), 2 n^2 values:
    `dtau_dq`  row-major n x n, entry i*n + j = d tau_i / d q_j   of tau = ID(q, qd, qdd)
    `dtau_dqd` row-major n x n, entry i*n + j = d tau_i / d qd_j  (free of qdd)
    (d tau / d qdd is M(q), the existing `mass_matrix` output.)
kernel `coriolis_matrix`, arguments (q, qd, p), n^2 values:
    `coriolis` row-major n x n, entry i*n + j = C_ij, the Christoffel-symbol matrix.

The Coriolis matrix. With M's Christoffel symbols of the first kind
    Gamma_ijk = 1/2 (dM_ij/dq_k + dM_ik/dq_j - dM_jk/dq_i),
C_ij = sum_k Gamma_ijk qd_k. Then C qd = b, the velocity terms (b_i = sum_jk Gamma_ijk
qd_j qd_k, Lagrange's equations), and Mdot - 2C is skew-symmetric. Since Gamma_ijk is
symmetric in j and k, and b is quadratic in qd,
    d b_i / d qd_j = sum_k (Gamma_ijk + Gamma_ikj) qd_k = 2 C_ij,     so  C = 1/2 db/dqd:
one forward-mode pass over the velocity terms' program with the n rates as variables,
cheaper than C = 1/2 (Mdot + J - J^T) with Mdot = sum_k dM/dq_k qd_k and J = d(M qd)/dq
(the same matrix, from M's program with n + 1 directions). With the analytical algorithm
C is half its rigid-body d tau/d qd, computed by the same world-frame pass. Pinocchio's
`computeCoriolisMatrix` gives this same C (tests/test_derivatives.py). For the same
reason the rigid-body dtau_dqd = db/dqd = 2 C; the joints' damping adds its diagonal.

With a floating base the rates are quasi-velocities (the base's twist in its own axes),
the symbols are no longer symmetric, and 1/2 db/dqd is a matrix with C qd = b whose
Mdot - 2C is not skew-symmetric. C is then Pinocchio's: S^T (Y Sdot + B S / 2) over the
tree, with Sdot the rate of each motion vector (rnea_derivatives; it is 1/2 db/dqd
wherever every joint has one coordinate), which keeps C qd = b and makes Mdot - 2C
skew-symmetric (tests/test_floating_derivatives.py).

The compiled module comes in one of two forms (`derivative_form`, DERIVATIVE_FORMS): the
program above printed whole ("unrolled"), or for the analytical algorithm, the tree's
geometry at q generated and short C loops over the tree running the algorithm on it
("loop": its code grows with the bodies, not with the pairs of joints on a path).

How the API composes its results from these kernels (the lambdify backend does it in
NumPy; the compiled backend is to do the same in C):

- `inverse_dynamics_derivatives(q, qd, qdd)` -> (dtau_dq, dtau_dqd): the kernel.
- `coriolis_matrix(q, qd)` -> C: the kernel.
- `forward_dynamics_derivatives(q, qd, tau)` -> (dqdd_dq, dqdd_dqd, dqdd_dtau):
    1. qdd = FD(q, qd, tau) = M^-1 forcing, keeping the factors of M (L D L^T in C,
       Cholesky in NumPy);
    2. (dtau_dq, dtau_dqd) = the `inverse_dynamics_derivatives` kernel at (q, qd, qdd);
    3. dqdd_dq = -M^-1 dtau_dq, dqdd_dqd = -M^-1 dtau_dqd (n right-hand sides each, by
       the triangular solves with the factors of step 1), dqdd_dtau = M^-1 (the solves on
       the identity).
  Why: ID(q, qd, FD(q, qd, tau)) = tau identically; differentiating it, with
  d ID / d qdd = M, gives d ID/dx + M dFD/dx = 0 for x = q, qd, and M dFD/dtau = I.
- `linearize(q, qd, tau)` -> (A, B) of xdot = f(x, u), x = (q, qd), u = tau:
    A = [[0, I], [dqdd_dq, dqdd_dqd]]  (2n x 2n),   B = [[0], [dqdd_dtau]]  (2n x n).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import sympy as sp

from . import rnea_derivatives
from .differentiate import differentiate, needed_definitions, recorder_after
from .gibbs_appell import Equations
from .joints import armatures, dampings, dissipative_forces
from .kinematics import Recorder, quaternion_rotation


@dataclass
class DerivativeEquations:
    """The derivative kernels of a model as one straight-line program (module docstring).

    `intermediates` starts with all of `equations.intermediates`; every output is an
    expression in the intermediates, the coordinate symbols and the parameters. The zero
    entries of a Jacobian (a chain's joint k never depends on the joints after it, ...) are
    exact zeros.
    """

    equations: Equations
    intermediates: list[tuple[sp.Symbol, sp.Expr]]
    dtau_dq: list[sp.Expr]      # row-major n x n, in q, qd, qdd, p
    dtau_dqd: list[sp.Expr]     # row-major n x n, in q, qd, p
    coriolis: list[sp.Expr]     # row-major n x n, in q, qd, p
    # M(q) and the forcing tau - b + g that the forward-dynamics derivatives factor and
    # solve with: the equations' own, or the same quantities from the derivatives'
    # world-frame pass (rnea_derivatives), which then costs a dot product per entry
    mass_matrix: sp.Matrix | None = None
    forcing: list[sp.Expr] | None = None
    # the loop form (DERIVATIVE_FORMS): the tree's geometry, which the compiled loops run the
    # analytical algorithm on; the lists above are then empty (no backend but the compiled
    # one reads this form)
    geometry: rnea_derivatives.TreeGeometry | None = None
    seconds: float = 0.0

    @property
    def n(self) -> int:
        return self.equations.n

    def outputs(self) -> dict[str, list[sp.Expr]]:
        """Each kernel's outputs, flat: `inverse_dynamics_derivatives` is dtau_dq then
        dtau_dqd (2 n^2 values), `coriolis_matrix` is C (n^2 values), all row-major."""
        return {
            "inverse_dynamics_derivatives": [*self.dtau_dq, *self.dtau_dqd],
            "coriolis_matrix": list(self.coriolis),
        }

    def arguments(self) -> dict[str, list[list[sp.Symbol]]]:
        """Each kernel's arguments, as groups of symbols in call order."""
        c, p = self.equations.coords, self.equations.parameters
        return {
            "inverse_dynamics_derivatives": [c.q, c.qd, c.qdd, p],
            "coriolis_matrix": [c.q, c.qd, p],
        }

    def operation_count(self, kernel: str | None = None) -> int:
        """`sympy.count_ops` over the definitions a kernel needs (default: all kernels
        together) and its outputs, each definition counted once."""
        outputs = self.outputs()
        exprs = [e for name, out in outputs.items() if kernel in (None, name) for e in out]
        needed = needed_definitions(self.intermediates, exprs)
        return sum(sp.count_ops(e) for _, e in needed) + sum(sp.count_ops(e) for e in exprs)


DERIVATIVE_METHODS = ("auto", "forward", "analytic")
# "auto" takes the analytical algorithm (symbolic/rnea_derivatives.py) for a fixed-base
# model from this many coordinates on, and for every model with a floating joint; forward
# mode through the equations' program otherwise. Measured by benchmarks/derivative_ops.py:
# count_ops of the inverse-dynamics-derivatives kernel, forward mode / analytical:
#
#   fixed base: rrr 704 / 1201, chain:3 869 / 1256, double pendulum 176 / 193 (closed
#   forms: forward mode wins); chain:4 2360 / 2237, chain:5 4763 / 3280, chain:6 4252 /
#   4385, SO-100 7114 / 6062, UR5 5932 / 4808, Panda 15313 / 7695.
#   floating base (its own frame as the common frame, rnea_derivatives.common_frames): a
#   lone free body 511 / 282, random floating trees of 7, 7, 8 and 10 coordinates 2448 /
#   1233, 4357 / 1693, 6261 / 2396, 12726 / 4691, ANYmal C 22033 / 10671.
#
# The analytical pass also gives M and the bias forces at a dot product per entry, which
# the forward-dynamics derivatives factor (the Panda's went from 3.70 to 2.50 us per call).
# It is also what gives a floating base's Coriolis matrix (below, derive_derivatives).
ANALYTIC_FROM_DOF = 4


def derivative_method(model, method: str = "auto") -> str:
    """"forward" or "analytic": what `method` ("auto", "forward", "analytic") means here."""
    if method not in DERIVATIVE_METHODS:
        raise ValueError(f"unknown derivative method '{method}' (expected one of "
                         f"{', '.join(DERIVATIVE_METHODS)})")
    if method != "auto":
        return method
    return "analytic" if model.floating or model.dof >= ANALYTIC_FROM_DOF else "forward"


DERIVATIVE_FORMS = ("auto", "unrolled", "loop")
# From this many coordinates on, fixed base or floating, "auto" writes the derivative module
# in loop form: the tree's geometry generated (O(n) code) and short C loops running the
# analytical algorithm on it, instead of its whole program unrolled, whose code grows with
# the (ancestor, descendant) pairs: O(n * depth). Measured by benchmarks/derivative_form.py
# on this project's 2-core machine (shared and busy: the best of 200 rounds of 200 calls,
# both forms in one C program, alternating; builds cold in fresh processes): cold build s
# of the main module, the unrolled and the loop derivative module; per call µs unrolled /
# loop (ratio, above 1: the loop form is faster) of the forward-dynamics derivatives, the
# inverse-dynamics derivatives and the Coriolis matrix:
#
#   model (coordinates)       builds s           FD                  ID                 C
#   chain:4 (4)               9.1, 7.6, 7.0      0.23/0.53 (0.43)    0.19/0.44 (0.44)   0.11/0.26 (0.41)
#   UR5 (6)                   22.8, 14.3, 7.9    0.53/0.92 (0.58)    0.42/0.72 (0.58)   0.22/0.43 (0.52)
#   chain:8 (8)               18.0, 25.4, 6.8    1.44/1.34 (1.08)    0.62/1.04 (0.60)   0.31/0.60 (0.52)
#   double pendulum, floating (8)
#                             19.9, 7.3, 8.8     0.27/1.01 (0.27)    0.17/0.66 (0.26)   0.08/0.36 (0.23)
#   Panda (9)                 20.3, 24.2, 9.5    1.79/1.62 (1.10)    1.43/1.16 (1.23)   0.37/0.69 (0.54)
#   chain:10 (10)             17.3, 34.1, 8.2    2.38/1.94 (1.23)    1.75/1.33 (1.32)   0.44/0.81 (0.54)
#   SO-100, floating (12)     15.4, 35.6, 13.5   2.01/2.05 (0.98)    1.46/1.19 (1.22)   0.36/0.69 (0.51)
#   chain:12 (12)             26.0, 50.5, 12.8   3.01/2.56 (1.18)    2.22/1.66 (1.34)   0.56/0.96 (0.58)
#   Panda, floating (15)      38.1, 52.6, 17.2   3.77/3.28 (1.15)    2.02/1.69 (1.20)   0.49/0.99 (0.50)
#   chain:16 (16)             36.9, 123.4, 20.9  5.88/4.18 (1.41)    3.47/2.48 (1.40)   1.85/1.37 (1.35)
#   ANYmal C, floating (18)   45.0, 57.1, 12.4   4.13/3.90 (1.06)    2.34/2.16 (1.08)   0.54/1.07 (0.50)
#   Talos reduced, fl. (38)   51.1, 91.9, 21.8   20.4/14.9 (1.37)    8.70/6.24 (1.39)   4.57/2.97 (1.54)
#   chain:50 (50)             115.8, 329.3, 35.2 405/71.0 (5.70)     27.9/15.4 (1.81)   13.2/8.59 (1.54)
#   Talos full, fl. (50)      77.2, 127.4, 16.7  85.3/26.7 (3.19)    14.2/9.51 (1.49)   6.81/5.28 (1.29)
#   Tiago, floating (54)      75.1, 143.4, 40.5  151/36.5 (4.14)     16.5/11.2 (1.47)   8.55/6.33 (1.35)
#
# Up to 8 coordinates the unrolled program is faster on every kernel (2 to 4x on the
# smallest), its build no slower; from 9 on the loop form is faster on the derivatives MPC
# calls (the ID derivatives 1.08x to 1.81x, the FD derivatives 1.06x to 5.7x but for the
# floating SO-100's, level at 0.98x), builds 2.5 to 9x faster (and faster than the main
# module), and from 16 on its Coriolis matrix is faster too (below, it takes up to twice as
# long: 0.3 to 0.5 µs more). (The fixed-base rows were measured before the loop form
# skipped D for a root's coordinates, which only helps it.)
DERIVATIVE_LOOP_FROM_DOF = 9


def derivative_form(model, form: str = "auto") -> str:
    """"unrolled" or "loop": what `form` ("auto", "unrolled", "loop") means here (the
    compiled derivative module's form, by the measured rule above; forward mode, below
    ANALYTIC_FROM_DOF, is unrolled)."""
    if form not in DERIVATIVE_FORMS:
        raise ValueError(f"unknown derivative form '{form}' (expected one of "
                         f"{', '.join(DERIVATIVE_FORMS)})")
    if form != "auto":
        return form
    return "loop" if model.dof >= DERIVATIVE_LOOP_FROM_DOF else "unrolled"


def derive_derivatives(eqs: Equations, method: str = "auto", form: str = "unrolled"
                       ) -> DerivativeEquations:
    """The derivative kernels of `eqs` as a continuation of its program (module docstring).

    With a floating joint (q holds a quaternion, nq > n), d tau / d q is taken along the n
    velocity directions, as Pinocchio's derivatives are: d/de tau(q (+) e v_j) at e = 0,
    the Jacobian by q's nq entries times the tangent map G(q) (`tangent_map`).

    `method`: "forward" differentiates the equations' program by forward mode,
    "analytic" writes the algorithm of `rnea_derivatives` (already along the velocity
    directions), "auto" chooses by the measured rule above (`derivative_method`). `form` "loop" derives
    the tree's geometry only, for the compiled loop form (`derivative_form`)."""
    start = time.perf_counter()
    if form == "loop":
        geometry = rnea_derivatives.tree_geometry(eqs)
        return DerivativeEquations(equations=eqs, intermediates=geometry.intermediates,
                                   dtau_dq=[], dtau_dqd=[], coriolis=[], geometry=geometry,
                                   seconds=time.perf_counter() - start)
    n, nq, c = eqs.n, eqs.nq, eqs.coords
    rec = recorder_after(eqs.intermediates)
    method = derivative_method(eqs.model, method)
    mass_matrix, forcing = eqs.mass_matrix, list(eqs.forcing)
    if method == "analytic":  # along the velocity directions already, floating or not
        world = rnea_derivatives.rnea_derivatives(eqs.model, c, rec)
        by_q, coriolis = world.dtau_dq, world.coriolis
        damping = [d * qd for d, qd in zip(dampings(eqs.model), c.qd)]
        by_qd = [[rec.name(e + damping[i].diff(c.qd[j])) for j, e in enumerate(row)]
                 for i, row in enumerate(world.dtau_dqd)]
        mass_matrix, forcing = _with_joint_terms(eqs, world.mass_matrix, world.bias)
    else:
        db_dqd = differentiate(eqs.intermediates, list(eqs.velocity_terms), c.qd, rec)
        jacobian = differentiate(eqs.intermediates, list(eqs.inverse_dynamics),
                                 c.q + c.qd, rec)
        by_q = [row[:nq] for row in jacobian]
        by_qd = [row[nq:] for row in jacobian]
        half = sp.Rational(1, 2)
        coriolis = [[half * e for e in row] for row in db_dqd]
        if eqs.model.floating:  # C = 1/2 db/dqd only with a fixed base (module docstring)
            coriolis = rnea_derivatives.rnea_derivatives(eqs.model, c, rec).coriolis
        if nq != n:
            columns = tangent_map(eqs.model, c.q, rec)
            by_q = [[rec.name(sp.Add(*(row[r] * g for r, g in columns[j] if row[r] != 0)))
                     for j in range(n)] for row in by_q]
    derivatives = DerivativeEquations(
        equations=eqs,
        intermediates=rec.definitions,
        dtau_dq=[e for row in by_q for e in row],
        dtau_dqd=[e for row in by_qd for e in row],
        coriolis=[e for row in coriolis for e in row],
        mass_matrix=mass_matrix,
        forcing=forcing,
    )
    derivatives.seconds = time.perf_counter() - start
    return derivatives


def _with_joint_terms(eqs: Equations, rigid_mass: list[list[sp.Expr]], bias: list[sp.Expr]
                      ) -> tuple[sp.Matrix, list[sp.Expr]]:
    """M and the forcing from a rigid-body M and bias forces (b - g), with the joint terms
    of `symbolic.joints` added as `add_joint_terms` adds them to the equations."""
    M = sp.Matrix(rigid_mass) + sp.diag(*armatures(eqs.model))
    dissipative = dissipative_forces(eqs.model, eqs.coords)
    forcing = [t - b - d for t, b, d in zip(eqs.coords.tau, bias, dissipative)]
    return M, forcing


def tangent_map(model, q: list[sp.Symbol], rec: Recorder) -> list[list[tuple[int, sp.Expr]]]:
    """G(q) = d (q (+) v) / d v at v = 0, column by column: for each velocity coordinate j,
    the (entry of q, derivative) pairs. A 1-dof joint's coordinate moves its own entry of q;
    a floating joint's linear velocity (in its frame) moves the position by R(quaternion),
    and its angular velocity w the quaternion by 1/2 quaternion (x) (w, 0), as
    `gagen.runtime.manifold.configuration_rate` (and Pinocchio's `integrate`) do."""
    columns: list[list[tuple[int, sp.Expr]]] = [[] for _ in range(model.dof)]
    for body in model.moving_bodies:
        iq, iv = model.indices()[body.name]
        if not body.joint.floating:
            columns[iv] = [(iq, sp.Integer(1))]
            continue
        quaternion = q[iq + 3: iq + 7]
        R = quaternion_rotation(quaternion, rec)
        for k in range(3):
            columns[iv + k] = [(iq + r, R[r][k]) for r in range(3)]
        x, y, z, s = quaternion
        half = sp.Rational(1, 2)
        for k, rates in enumerate(((s, z, -y, -x), (-z, s, x, -y), (y, -x, s, -z))):
            columns[iv + 3 + k] = [(iq + 3 + r, half * e) for r, e in enumerate(rates)]
    return columns
