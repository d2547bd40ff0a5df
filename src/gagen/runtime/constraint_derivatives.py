"""The derivatives of the constrained forward dynamics, on either backend's kernels: a
compiled model's one or stacked states in one call into the C of _constraint_terms.pyx;
the lambdify backend (and a source tree without that build, and a state the C refuses) in
the NumPy below, which is its reference.

At the solution (q̈, λ) of constrained_forward_dynamics (gagen.runtime.constraints),

    ID(q, q̇, q̈) − J(q)ᵀ λ = τ            a_c(q, q̇, q̈) = −damping · λ

with ID the inverse dynamics and a_c(q, q̇, a) = J(q) a + J̇ q̇ the active rows' acceleration
(plus kd J q̇ with Baumgarte's kd). Differentiating along x = q (tangent), q̇ or τ:

    M ∂q̈ − Jᵀ ∂λ = ∂τ − ∂ID + ∂(Jᵀ λ)|λ        J ∂q̈ + damping ∂λ = −∂a_c|a

which the factors of M (M = L Lᵀ) and of the Delassus matrix G = J M⁻¹ Jᵀ solve:
∂λ = (G + damping I)⁻¹ (r₂ − J M⁻¹ r₁), ∂q̈ = M⁻¹ (r₁ + Jᵀ ∂λ). ∂ID are the backend's
inverse_dynamics_derivatives (C for compiled models).

The two constraint terms, ∂a_c with a held and ∂(Jᵀ λ) with λ held, come here from the
constrained frames' world motion subspaces: column S_j of a frame's chain (a twist at the
world's origin, linear first) moves with coordinate k on or above j's joint as
∂S_j/∂q_k = S_k × S_j (a floating joint's six coordinates all act on each other: its
tangent is its body's local twist, Pinocchio's integrate), and its time derivative is
Ṡ_j = V_j × S_j (V_j the velocity of j's body). Then, for the frame's body,

    V = Σ S_j q̇_j,   A = Σ S_j a_j + Ṡ_j q̇_j,   ∂V/∂q_k = Σ_{j ⪰ k} (S_k × S_j) q̇_j,
    ∂A/∂q_k = Σ_{j ⪰ k} (S_k × S_j) a_j + (∂V_j/∂q_k × S_j + V_j × (S_k × S_j)) q̇_j,
    ∂A/∂q̇_k = Ṡ_k + Σ_{j ⪰ k} (S_k × S_j) q̇_j

and the rows (a point's classical acceleration, a frame's spatial one, a loop's relative
one, rotated into frame A's axes for "local") follow by the product rule, carried as
(value, ∂/∂q, ∂/∂q̇) triples. Pinocchio's computeConstraintDynamicsDerivatives has the same
conventions (tests/test_constraint_derivatives.py).
"""

from __future__ import annotations

import math

import numpy as np

from ..manifest import chain_order, constraint_derivative_layout
from .constraints import active_rows
from .frames import pose

try:  # the C of one state (setup.py builds it with the runtime); NumPy without it
    from . import _constraint_terms as _terms
except ImportError:  # pragma: no cover - a source tree without its build
    _terms = None

# --- (value, ∂/∂q, ∂/∂q̇) triples: value (..., d), derivatives (..., nv, d) ---------------------

def _cross(a, b):
    """a × b over the last axis, broadcast (np.cross's axis handling costs 10x more)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    np.subtract(a1 * b2, a2 * b1, out=out[..., 0])
    np.subtract(a2 * b0, a0 * b2, out=out[..., 1])
    np.subtract(a0 * b1, a1 * b0, out=out[..., 2])
    return out


def _dual_cross(x, y):
    """x × y of 3-vector triples."""
    x0, xq, xv = x
    y0, yq, yv = y
    return (_cross(x0, y0),
            _cross(xq, y0[..., None, :]) + _cross(x0[..., None, :], yq),
            _cross(xv, y0[..., None, :]) + _cross(x0[..., None, :], yv))


def _dual_add(x, y, sign: float = 1.0):
    return tuple(a + sign * b for a, b in zip(x, y))


def _part(x, lo: int, hi: int):
    return tuple(a[..., lo:hi] for a in x)


def _join(x, y):
    return tuple(np.concatenate([a, b], axis=-1) for a, b in zip(x, y))


def _motion_cross(a, b):
    """The spatial cross product a × b of twists (..., 6), linear first."""
    al, aw, bl, bw = a[..., :3], a[..., 3:], b[..., :3], b[..., 3:]
    return np.concatenate([_cross(aw, bl) + _cross(al, bw), _cross(aw, bw)], axis=-1)


def _dual_motion_cross(x, y):
    lin = _dual_add(_dual_cross(_part(x, 3, 6), _part(y, 0, 3)),
                    _dual_cross(_part(x, 0, 3), _part(y, 3, 6)))
    return _join(lin, _dual_cross(_part(x, 3, 6), _part(y, 3, 6)))


def _at(x, p):
    """The twist (or spatial acceleration) triple x, given at the world's origin, at p."""
    return _join(_dual_add(_part(x, 0, 3), _dual_cross(_part(x, 3, 6), p)), _part(x, 3, 6))


# --- one frame's motion and its derivatives ---------------------------------------------------

class FrameMotions:
    """The constrained frames' world quantities at (q, q̇, a) with their derivatives
    (module docstring), the frames on an axis of their own (f): S (..., f, nv, 6) their
    chains' twists at the world's origin, `order` (f, nv, nv) each chain's j ⪰ k relation,
    C[..., f, k, j] = S_k × S_j, p, V, A and `acc` (the origin's classical acceleration) as
    triples, R (..., f, 3, 3) their axes."""

    def __init__(self, J, R, p, order, v, a):
        St = np.swapaxes(J, -1, -2).copy()  # J: linear rows at p, world axes
        St[..., :3] -= _cross(St[..., 3:], p[..., None, :])  # now at the world's origin
        C = _motion_cross(St[..., :, None, :], St[..., None, :, :])
        Vb = np.einsum("fij,...i,...fic->...fjc", order, v, St)  # V_j: j's body's velocity
        Sdot = _motion_cross(Vb, St)
        V = np.einsum("...j,...fjc->...fc", v, St)
        T = C * (order[..., None] * v[..., None, None, :, None])  # [k, i]: (S_k × S_i) q̇_i
        dV_dq = T.sum(axis=-2)
        dVb = np.einsum("...fkic,fij->...fkjc", T, order)  # ∂V_j/∂q_k
        E = _motion_cross(dVb, St[..., None, :, :]) + _motion_cross(Vb[..., None, :, :], C)
        A = np.einsum("...j,...fjc->...fc", a, St) + np.einsum("...j,...fjc->...fc", v, Sdot)
        dA_dq = np.einsum("...fkjc,fkj,...j->...fkc", C, order, a) \
            + np.einsum("...fkjc,fkj,...j->...fkc", E, order, v)
        self.R, self.S, self.order, self.C = R, St, order, C
        self.p = (p, np.swapaxes(J[..., :3, :], -1, -2), np.zeros(St.shape[:-1] + (3,)))
        self.V = (V, dV_dq, St)
        self.A = (A, dA_dq, dV_dq + Sdot)
        self.w = St[..., 3:]  # ∂R/∂q_k = [w_k]× R
        Vp = _at(self.V, self.p)
        self.acc = _dual_add(_part(_at(self.A, self.p), 0, 3),
                             _dual_cross(_part(Vp, 3, 6), _part(Vp, 0, 3)))

    def frame(self, i: int) -> _Frame:
        return _Frame(self, i)


class _Frame:
    """One frame of FrameMotions: R, w, p, V, A, acc (triples without the frames' axis)."""

    def __init__(self, motions: FrameMotions, i: int):
        def pick(x):
            return (x[0][..., i, :], x[1][..., i, :, :], x[2][..., i, :, :])
        self.R, self.w = motions.R[..., i, :, :], motions.w[..., i, :, :]
        self.p, self.V, self.A = pick(motions.p), pick(motions.V), pick(motions.A)
        self.acc = pick(motions.acc)


def _chain_order(info, body: int, nv: int) -> np.ndarray:
    """order[k, j] = 1 where coordinates k and j are on the body's chain and k's joint is
    j's or above it (a floating joint's six coordinates are each other's)."""
    return chain_order(info.bodies, body, nv)


def _rotated_t(R, w, x):
    """Rᵀ x of a triple of 3-vectors, R a frame's axes with ∂R/∂q_k = [w_k]× R."""
    x0, xq, xv = x
    Rt = np.swapaxes(R, -1, -2)
    turn = xq - _cross(w, x0[..., None, :])
    return (np.einsum("...ij,...j->...i", Rt, x0), np.einsum("...ij,...kj->...ki", Rt, turn),
            np.einsum("...ij,...kj->...ki", Rt, xv))


def _rotated_blocks(fm: _Frame, x):
    """Each 3-block of a triple (..., 3h) in the frame's axes."""
    blocks = [_rotated_t(fm.R, fm.w, _part(x, 3 * h, 3 * h + 3))
              for h in range(x[0].shape[-1] // 3)]
    out = blocks[0]
    for b in blocks[1:]:
        out = _join(out, b)
    return out


# --- one constraint's rows ---------------------------------------------------------------------

def _rows(c, A: _Frame, B: _Frame | None, kd: float):
    """(value, ∂/∂q, ∂/∂q̇) of the constraint's rows (its axes) of a_c (+ kd J q̇)."""
    if not c.holds_frame:
        acc, vel = A.acc, _part(_at(A.V, A.p), 0, 3)
        if B is not None:
            acc = _dual_add(acc, B.acc, -1.0)
            vel = _dual_add(vel, _part(_at(B.V, B.p), 0, 3), -1.0)
    elif B is None:
        acc, vel = _at(A.A, A.p), _at(A.V, A.p)
    else:
        acc = _at(_dual_add(A.A, B.A, -1.0), A.p)
        vel = _at(_dual_add(A.V, B.V, -1.0), A.p)
        if c.reference == "local":
            acc = _dual_add(acc, _at(_dual_motion_cross(A.V, B.V), A.p))
    if kd:
        acc = _dual_add(acc, tuple(kd * x for x in vel))
    if c.reference == "local":
        acc = _rotated_blocks(A, acc)
    rows = list(c.axes)
    return tuple(x[..., rows] for x in acc)


def _wrenches(c, A: _Frame, B: _Frame | None, lam):
    """The constraint's wrench W at the world's origin on A's body and −W on B's, as
    (value (..., 6), ∂/∂q (..., nv, 6)) pairs with λ (..., rows) held: Jᵀ λ = Σ Sᵀ W."""
    size = 6 if c.holds_frame else 3
    full = np.zeros(lam.shape[:-1] + (size,))
    full[..., list(c.axes)] = lam
    zero = np.zeros(A.w.shape)
    f = (full[..., :3], zero, zero)
    t = (full[..., 3:], zero, zero) if size == 6 else None
    if c.reference == "local":  # ∂(R x)/∂q_k = w_k × R x
        f0 = np.einsum("...ij,...j->...i", A.R, f[0])
        f = (f0, _cross(A.w, f0[..., None, :]), zero)
        if t is not None:
            t0 = np.einsum("...ij,...j->...i", A.R, t[0])
            t = (t0, _cross(A.w, t0[..., None, :]), zero)

    def wrench(point, sign):
        moment = _dual_cross(point, f)
        if t is not None:
            moment = _dual_add(moment, t)
        W = _join(f, moment)
        return sign * W[0], sign * W[1]
    out = [wrench(A.p, 1.0)]
    if B is not None:
        out.append(wrench(B.p if not c.holds_frame else A.p, -1.0))
    return out


def _on_chains(fm: FrameMotions, W0, Wq):
    """∂(Σ_f S_fᵀ W_f)/∂q: [j, k] = Σ_f (∂S_j/∂q_k) · W_f + S_j · ∂W_f/∂q_k."""
    moved = np.einsum("fkj,...fkjc,...fc->...jk", fm.order, fm.C, W0)
    return moved + np.einsum("...fjc,...fkc->...jk", fm.S, Wq)


# --- the derivatives ------------------------------------------------------------------------------

def derivatives(dyn, q, qd, tau, p, mask, kd: float, damping: float):
    """(∂q̈/∂q, ∂q̈/∂q̇, ∂q̈/∂τ, ∂λ/∂q, ∂λ/∂q̇, ∂λ/∂τ) at the constrained forward dynamics'
    solution (module docstring), λ over every declared row (zero rows for the inactive
    constraints); stacked states give stacked outputs. A compiled model's call is one call
    into _constraint_terms's C (one state or a C loop over stacked ones); the NumPy below
    serves the lambdify backend and any state the C refuses (it raises or answers)."""
    if _terms is not None and dyn.backend == "compiled":
        found = _compiled(dyn, q, qd, tau, p, mask, kd, damping)
        if found is not None:
            return found
    from .inputs import as_states
    from .taskspace import _mass_cholesky

    info, nv = dyn.info, dyn.nv
    (q, qd, tau), _ = as_states(dyn._sizes, q, qd, tau, names=("q", "qd", "tau"))
    on = tuple(bool(x) for x in mask)  # the compiled runtime keeps a tuple's checks
    qdd, forces = dyn.constrained_forward_dynamics(q, qd, tau, active=on,
                                                   baumgarte=(0.0, kd), damping=damping, p=p)
    dID_dq, dID_dv = dyn.inverse_dynamics_derivatives(q, qd, qdd, p)
    L = _mass_cholesky(dyn.mass_matrix(q, p))
    lead, rows = q.shape[:-1], active_rows(info, mask)
    m = len(rows)
    eye = np.broadcast_to(np.eye(nv), lead + (nv, nv))
    r1 = np.concatenate([-dID_dq, -dID_dv, eye], axis=-1)
    if m:
        r1[..., :nv] += _constraint_terms(dyn, q, qd, qdd, p, mask, forces[..., rows], kd,
                                          r2 := [])
    u = _cholesky_solve(L, r1)
    if m:
        J = dyn.constraint_jacobian(q, mask, p)
        r2 = np.concatenate(r2, axis=-2)
        Y = np.linalg.solve(L, np.swapaxes(J, -1, -2))
        G = np.swapaxes(Y, -1, -2) @ Y + damping * np.eye(m)
        dlam = np.linalg.solve(G, r2 - J @ u)
        dqdd = u + _cholesky_solve(L, np.swapaxes(J, -1, -2) @ dlam)
    else:
        dlam, dqdd = np.zeros(lead + (0, 3 * nv)), u
    dforces = np.zeros(lead + (info.constraint_rows, 3 * nv))
    dforces[..., rows, :] = dlam
    return (dqdd[..., :nv], dqdd[..., nv: 2 * nv], dqdd[..., 2 * nv:],
            dforces[..., :nv], dforces[..., nv: 2 * nv], dforces[..., 2 * nv:])


def compiled_call(dyn, q, qd, tau, active, baumgarte, damping, p):
    """A compiled model's call whose options need no conversion, straight into the C:
    `active` None or a list or tuple of one bool per constraint, `baumgarte` a tuple
    (0, kd) of finite numbers >= 0, `damping` a finite number >= 0, the default parameters.
    None for any other call, or where the C refuses an input or a state: the caller then
    takes the checked path (which converts, or raises its one-line error)."""
    if p is not None or _terms is None or type(baumgarte) is not tuple or len(baumgarte) != 2:
        return None
    kp, kd = baumgarte
    if type(kp) not in _NUMBERS or type(kd) not in _NUMBERS or type(damping) not in _NUMBERS \
            or kp != 0 or not 0 <= kd < math.inf or not 0 <= damping < math.inf:
        return None
    if active is not None:
        if type(active) not in (list, tuple) or len(active) != len(dyn.info.constraints) \
                or any(type(x) is not bool for x in active):
            return None
        active = tuple(active)
    plans = dyn.__dict__.setdefault("_constraint_derivative_calls", {})
    plan = plans.get(active)
    if plan is None:
        on = [True] * len(dyn.info.constraints) if active is None else active
        plan = _plan(dyn, np.array(on, dtype=bool))
        if len(plans) < 256:
            plans[active] = plan
    return _terms.derivatives(plan, q, qd, tau, None, float(kd), float(damping))


_NUMBERS = (float, int)


def _compiled(dyn, q, qd, tau, p, mask, kd, damping):
    """The six derivatives by _constraint_terms's C, at one state or stacked ones (None
    where it refuses an input or a state: the NumPy path then raises or answers)."""
    plan = _plan(dyn, mask)
    if p is not None:
        p = np.ascontiguousarray(dyn.parameter_vector(p), dtype=float)
        if not np.isfinite(p).all():
            return None
    found = _terms.derivatives(plan, q, qd, tau, p, kd, damping)
    if found is not None:
        return found
    from .inputs import as_states  # lists, other dtypes, strides: converted, or the error

    (q, qd, tau), _ = as_states(dyn._sizes, q, qd, tau, names=("q", "qd", "tau"))
    return _terms.derivatives(plan, np.ascontiguousarray(q, dtype=float),
                              np.ascontiguousarray(qd, dtype=float),
                              np.ascontiguousarray(tau, dtype=float), p, kd, damping)


def _plan(dyn, mask):
    """_constraint_terms's Plan of a compiled model and an active set, kept per model and
    set: the layout of every declared constraint (the generated C's), the set chosen in C."""
    kept = dyn.__dict__.setdefault("_constraint_derivative_plans", {})
    key = mask.tobytes()
    found = kept.get(key)
    if found is not None:
        return found
    dyn.load_derivatives()
    t = constraint_derivative_layout(dyn.info)
    found = _terms.Plan(dyn.module.API, dyn.derivative_module.API, t["frames"], t["bodies"],
                        t["table"], t["parent"], t["quat"], t["chain"], t["chain_len"],
                        t["group_start"], t["group_end"], t["order"],
                        np.ascontiguousarray(mask, dtype=np.uint8), t["desc_ptr"], t["desc"])
    if len(kept) < 256:
        kept[key] = found
    return found


def _constraint_terms(dyn, q, qd, qdd, p, mask, lam, kd: float, r2: list):
    """∂(Jᵀ λ)/∂q with λ held, (..., nv, nv); appends to r2 each active constraint's
    (..., rows, 3 nv) block [−∂a_c/∂q, −∂a_c/∂q̇, 0] (a_c with kd J q̇)."""
    info, nv = dyn.info, dyn.nv
    active = [c for c, on in zip(info.constraints, mask) if on]
    names = list(dict.fromkeys(f for c in active for f in c.frames[:2 if c.type == "loop"
                                                                      else 1]))
    index = {name: i for i, name in enumerate(names)}
    X, F, _ = dyn._frame_data(q, p)
    poses = [pose(info, X, F, info.frame_indices[name]) for name in names]
    R = np.stack([r for r, _ in poses], axis=-3)
    P = np.stack([x for _, x in poses], axis=-2)
    order = np.stack([_chain_order(info, info.frames[info.frame_indices[name]][1], nv)
                      for name in names])
    J = dyn.frame_jacobian(q, names, p=p)
    motions = FrameMotions(J, R, P, order, qd, qdd)
    frames = [motions.frame(i) for i in range(len(names))]
    W0 = np.zeros(q.shape[:-1] + (len(names), 6))
    Wq = np.zeros(q.shape[:-1] + (len(names), nv, 6))
    start = 0
    for c in active:
        A = frames[index[c.frames[0]]]
        B = frames[index[c.frames[1]]] if c.type == "loop" else None
        _, dq, dv = _rows(c, A, B, kd)
        zeros = np.zeros(dq.shape)
        r2.append(-np.swapaxes(np.concatenate([dq, dv, zeros], axis=-2), -1, -2))
        targets = [index[c.frames[0]]] + ([index[c.frames[1]]] if B is not None else [])
        for i, (w0, wq) in zip(targets, _wrenches(c, A, B, lam[..., start: start
                                                                 + c.dimension])):
            W0[..., i, :] += w0
            Wq[..., i, :, :] += wq
        start += c.dimension
    return _on_chains(motions, W0, Wq)


def _cholesky_solve(L, rhs):
    y = np.linalg.solve(L, rhs)
    return np.linalg.solve(np.swapaxes(L, -1, -2), y)
