"""Constrained dynamics in NumPy: the constraints' rows (Jacobian, drift J̇ q̇, position
error), the KKT solution through M's factors and the Delassus matrix, impulses at impact.

The lambdify backend computes these here; compiled models do the same arithmetic in C
(codegen/templates/model/constraints.c.j2). The conventions are gagen.constraints's
(Pinocchio's RigidConstraintModel); the equations:

    M q̈ = F(q, q̇, τ) + Jᵀ λ          J q̈ + J̇ q̇ = −kp e − kd J q̇

with J the active constraints' rows, λ their forces (on frame A's body, in the rows' axes)
and e their position error (Pinocchio's contact_placement_error: frame A's origin less B's,
or for a constraint with rotation axes −log₆ of B's placement in A's). With M = L Lᵀ,
Y = L⁻¹ Jᵀ: the Delassus matrix G = J M⁻¹ Jᵀ = Yᵀ Y, and

    G λ = −J̇ q̇ − kp e − kd J q̇ − J M⁻¹ F,     q̈ = M⁻¹ (F + Jᵀ λ).

At an impact (impulse_dynamics), G Λ = −(1 + r) J q̇⁻ and q̇⁺ = q̇⁻ + M⁻¹ Jᵀ Λ. A damped
solve (damping d > 0) takes (G + d I) for G: the constraints then give way by d λ.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..constraints import AXES, anchor_parameter
from ..errors import SingularConstraintError, one_line
from ..manifest import ModelInfo
from .frames import jacobian as aligned_jacobian
from .frames import pose
from .taskspace import _cross_columns, frame_motion

# a pivot of G's factorisation at most this fraction of its diagonal entry: the rows are
# dependent (the C uses the same number, GAGEN_TS_PIVOT)
SINGULAR_PIVOT = 1e-11


# --- the per-call arguments ------------------------------------------------------------------

def active_mask(info: ModelInfo, active) -> np.ndarray:
    """The active constraints as a bool array (k,): None (all), k booleans, or names."""
    k = len(info.constraints)
    if active is None:
        return np.ones(k, dtype=bool)
    if isinstance(active, (str, bytes, Mapping)) or not isinstance(active, (Sequence,
                                                                            np.ndarray)):
        raise TypeError(f"active must be None, {k} booleans (one per constraint) or a list "
                        f"of constraint names; got {type(active).__name__}")
    items = list(np.asarray(active).ravel()) if isinstance(active, np.ndarray) else list(active)
    if items and all(isinstance(x, str) for x in items):
        names = [c.name for c in info.constraints]
        unknown = [x for x in items if x not in names]
        if unknown:
            raise KeyError(f"unknown constraint {unknown[0]!r} (constraints: "
                           f"{', '.join(names) or 'none'})")
        return np.array([name in items for name in names], dtype=bool)
    if len(items) != k or not all(isinstance(x, (bool, np.bool_)) or x in (0, 1)
                                  for x in items):
        raise ValueError(f"active must have {k} booleans (one per constraint, in "
                         f"dyn.constraints order); got {len(items)} entries")
    return np.array([bool(x) for x in items], dtype=bool)


def baumgarte_gains(baumgarte) -> tuple[float, float]:
    """(kp, kd), finite and >= 0."""
    try:
        kp, kd = (float(x) for x in baumgarte)
    except (TypeError, ValueError):
        raise TypeError(f"baumgarte must be a pair (kp, kd) of numbers; got "
                        f"{baumgarte!r}") from None
    if not (0 <= kp < np.inf and 0 <= kd < np.inf):
        raise ValueError(f"baumgarte gains must be finite and >= 0; got ({kp:g}, {kd:g})")
    return kp, kd


def nonnegative(value, name: str) -> float:
    """A finite number >= 0 (damping, restitution)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating,
                                                         np.integer)):
        raise TypeError(f"{name} must be a number; got {type(value).__name__}")
    value = float(value)
    if not 0 <= value < np.inf:
        raise ValueError(f"{name} must be finite and >= 0; got {value:g}")
    return value


def active_rows(info: ModelInfo, mask: np.ndarray) -> np.ndarray:
    """The indices of the active constraints' rows among every declared row."""
    rows = [np.arange(c.rows.start, c.rows.stop) for c, on in zip(info.constraint_infos, mask)
            if on]
    return np.concatenate(rows) if rows else np.zeros(0, dtype=int)


def row_names(info: ModelInfo, mask: np.ndarray | None = None) -> list[str]:
    """'<constraint>.<axis>' of each (active) row."""
    return [f"{c.name}.{AXES[a]}" for k, c in enumerate(info.constraints)
            if mask is None or mask[k] for a in c.axes]


# --- the rows ----------------------------------------------------------------------------------

def constraint_rows(dyn, q, qd, p, mask: np.ndarray, drift: bool = True,
                    error: bool = False):
    """(J (..., m, nv), drift (..., m) or None, error (..., m) or None) of the active rows."""
    info, nv = dyn.info, dyn.nv
    X, F, _ = dyn._frame_data(q, p)
    lead = X.shape[:-1]
    pv = dyn.parameter_vector(p) if error else None
    names = list(dyn.parameters) if error else None
    Js, drifts, errors = [], [], []
    for c, on in zip(info.constraints, mask):
        if not on:
            continue
        kA = info.frame_indices[c.frames[0]]
        kB = info.frame_indices[c.frames[1]] if c.type == "loop" else None
        R, pA = pose(info, X, F, kA)
        if c.type == "loop":
            RB, pB = pose(info, X, F, kB)
        elif error:
            pB, RB = _anchor(c, pv, names, lead)
        else:
            pB = RB = None
        J = aligned_jacobian(info, X, F, kA, nv)
        if kB is not None:
            JB = aligned_jacobian(info, X, F, kB, nv)
        if not c.holds_frame:
            J = J[..., :3, :] - (JB[..., :3, :] if kB is not None else 0.0)
        elif kB is not None:  # body B's motion at A's origin
            JB[..., :3, :] -= _cross_columns(pA - pB, JB[..., 3:, :])
            J = J - JB
        if drift:
            d = _drift(info, X, F, c, kA, kB, qd, pA, pB if kB is not None else None)
        if error:
            e = _error(c, R, pA, RB, pB)
        if c.reference == "local":
            Rt = np.swapaxes(R, -1, -2)
            J = np.concatenate([Rt @ J[..., 3 * h: 3 * h + 3, :]
                                for h in range(J.shape[-2] // 3)], axis=-2)
            if drift:
                d = _rotated(Rt, d)
        elif error:  # e is in A's axes: "local_world_aligned" turns it into the world's
            e = _rotated(R, e)
        rows = list(c.axes)
        Js.append(J[..., rows, :])
        if drift:
            drifts.append(d[..., rows])
        if error:
            errors.append(e[..., rows])
    J = np.concatenate(Js, axis=-2) if Js else np.zeros(lead + (0, nv))
    d = (np.concatenate(drifts, axis=-1) if drifts else np.zeros(lead + (0,))) if drift \
        else None
    e = (np.concatenate(errors, axis=-1) if errors else np.zeros(lead + (0,))) if error \
        else None
    return J, d, e


def _rotated(R, x):
    """R applied to each 3-vector of x (..., 3k)."""
    return np.concatenate([np.einsum("...ij,...j->...i", R, x[..., 3 * h: 3 * h + 3])
                           for h in range(x.shape[-1] // 3)], axis=-1)


def _anchor(c, pv, names, lead):
    """A contact's anchor (origin, axes) from the parameters."""
    values = [pv[names.index(anchor_parameter(c.name, key))] for key in ("x", "y", "z")]
    origin = np.broadcast_to(np.array(values), lead + (3,))
    if not c.holds_frame:
        return origin, None
    roll, pitch, yaw = (pv[names.index(anchor_parameter(c.name, key))]
                        for key in ("roll", "pitch", "yaw"))
    R = rpy_matrix(roll, pitch, yaw)
    return origin, np.broadcast_to(R, lead + (3, 3))


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF's Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp_, cy, sy = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                               np.cos(yaw), np.sin(yaw))
    return np.array([[cy * cp, cy * sp_ * sr - sy * cr, cy * sp_ * cr + sy * sr],
                     [sy * cp, sy * sp_ * sr + cy * cr, sy * sp_ * cr - cy * sr],
                     [-sp_, cp * sr, cp * cr]])


def _drift(info, X, F, c, kA, kB, qd, pA, pB):
    """J̇ q̇ of the constraint's 3 (point) or 6 (frame) rows, world axes (module docstring)."""
    _, _, wA, vA, alA, aA = frame_motion(info, X, F, kA, qd, None)
    if kB is None:
        return aA if not c.holds_frame else np.concatenate([aA - np.cross(wA, vA), alA],
                                                            axis=-1)
    _, _, wB, vB, alB, aB = frame_motion(info, X, F, kB, qd, None)
    if not c.holds_frame:
        return aA - aB
    sA = aA - np.cross(wA, vA)
    arm = pA - pB
    sB = aB - np.cross(wB, vB) + np.cross(alB, arm)  # body B's spatial acceleration at pA
    d = np.concatenate([sA - sB, alA - alB], axis=-1)
    if c.reference == "local":  # + V_A x V_B (motion vectors at pA)
        vB_at_A = vB + np.cross(wB, arm)
        d = d + np.concatenate([np.cross(wA, vB_at_A) + np.cross(vA, wB), np.cross(wA, wB)],
                               axis=-1)
    return d


def _error(c, R, pA, RB, pB):
    """The position error in frame A's axes: Rᵀ (pA − pB), or −log₆(A⁻¹ B)."""
    Rt = np.swapaxes(R, -1, -2)
    if not c.holds_frame:
        return np.einsum("...ij,...j->...i", Rt, pA - pB)
    return -log6(Rt @ RB, np.einsum("...ij,...j->...i", Rt, pB - pA))


def log3(R: np.ndarray) -> np.ndarray:
    """The rotation vector of R (..., 3, 3): angle in [0, π] times the unit axis."""
    R = np.asarray(R, dtype=float)
    w = 0.5 * np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                        R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    s = np.linalg.norm(w, axis=-1)
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    theta = np.arctan2(s, c)
    out = np.empty(R.shape[:-2] + (3,))
    flat_R, flat_w = R.reshape(-1, 3, 3), w.reshape(-1, 3)
    flat_s, flat_t, flat_c = s.reshape(-1), theta.reshape(-1), c.reshape(-1)
    flat = out.reshape(-1, 3)
    for i in range(flat.shape[0]):
        flat[i] = _log3_one(flat_R[i], flat_w[i], flat_s[i], flat_t[i], flat_c[i])
    return out


def _log3_one(R, w, s, theta, c):
    if c > -0.99:  # away from a half turn: theta / sin(theta) times the axis' vector
        return w * (theta / s) if s > 1e-300 else w * (1.0 + theta * theta / 6.0)
    # near a half turn: the axis from R + Rᵀ = 2 (cos θ I + (1 − cos θ) u uᵀ)
    B = 0.5 * (R + R.T) - c * np.eye(3)
    k = int(np.argmax(np.diag(B)))
    u = B[:, k] / np.sqrt(max(B[k, k], 1e-300))
    u = u / np.linalg.norm(u)
    if np.dot(u, w) < 0:
        u = -u
    return theta * u


def log6(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Pinocchio's log6 of the placement (R, p): (v, ω), ω = log3(R) and v the translation's
    part along the screw."""
    w = log3(R)
    t2 = np.sum(w * w, axis=-1)
    t = np.sqrt(t2)
    with np.errstate(divide="ignore", invalid="ignore"):
        st, ct = np.sin(t), np.cos(t)
        alpha = np.where(t < 1e-4, 1.0 - t2 / 12.0 - t2 * t2 / 720.0,
                         t * st / (2.0 * (1.0 - ct)))
        beta = np.where(t < 1e-4, 1.0 / 12.0 + t2 / 720.0,
                        1.0 / t2 - st / (2.0 * t * (1.0 - ct)))
    v = alpha[..., None] * p - 0.5 * np.cross(w, p) \
        + (beta * np.sum(w * p, axis=-1))[..., None] * w
    return np.concatenate([v, w], axis=-1)


# --- the KKT solution ---------------------------------------------------------------------------

def solve(dyn, q, qd, tau, p, mask, kp: float, kd: float, damping: float, fext=None):
    """(q̈, λ over every declared row) of the constrained forward dynamics (module
    docstring); stacked states give stacked outputs."""
    from .inputs import as_states
    from .taskspace import _mass_cholesky

    (q, qd, tau), stacked = as_states(dyn._sizes, q, qd, tau, names=("q", "qd", "tau"))
    if fext is not None:
        tau = tau + dyn.external_forces(q, fext, p)
    L = _mass_cholesky(dyn.mass_matrix(q, p))
    Fq = dyn.forcing(q, qd, tau, p)
    free = _cholesky_solve(L, Fq[..., None])[..., 0]
    J, drift, error = constraint_rows(dyn, q, qd, p, mask, error=kp != 0.0)
    rhs = -drift - np.einsum("...ij,...j->...i", J, free)
    if kd:
        rhs = rhs - kd * np.einsum("...ij,...j->...i", J, qd)
    if kp:
        rhs = rhs - kp * error
    lam = _delassus_solve(dyn, q, L, J, rhs, damping, mask, stacked)
    qdd = free + _cholesky_solve(L, np.einsum("...ji,...j->...i", J, lam)[..., None])[..., 0]
    return qdd, _all_rows(dyn.info, mask, lam)


def impulse(dyn, q, qd_minus, p, mask, restitution: float, damping: float):
    """(q̇⁺, Λ over every declared row) at an impact (module docstring)."""
    from .inputs import as_states
    from .taskspace import _mass_cholesky

    (q, qd), stacked = as_states(dyn._sizes[:2], q, qd_minus, names=("q", "qd_minus"))
    L = _mass_cholesky(dyn.mass_matrix(q, p))
    J, _, _ = constraint_rows(dyn, q, qd, p, mask, drift=False)
    rhs = -(1.0 + restitution) * np.einsum("...ij,...j->...i", J, qd)
    lam = _delassus_solve(dyn, q, L, J, rhs, damping, mask, stacked)
    qd_plus = qd + _cholesky_solve(L, np.einsum("...ji,...j->...i", J, lam)[..., None])[..., 0]
    return qd_plus, _all_rows(dyn.info, mask, lam)


def _all_rows(info, mask, lam):
    out = np.zeros(lam.shape[:-1] + (info.constraint_rows,))
    out[..., active_rows(info, mask)] = lam
    return out


def _cholesky_solve(L, rhs):
    y = np.linalg.solve(L, rhs)
    return np.linalg.solve(np.swapaxes(L, -1, -2), y)


def _delassus_solve(dyn, q, L, J, rhs, damping, mask, stacked):
    """λ of G λ = rhs (G = J M⁻¹ Jᵀ, + damping I), each stacked state apart; the C's pivot
    rule for dependent rows."""
    if J.shape[-2] == 0:
        return np.zeros(rhs.shape)
    Y = np.linalg.solve(L, np.swapaxes(J, -1, -2))
    G = np.swapaxes(Y, -1, -2) @ Y
    Gs, bs = (G, rhs) if stacked else (G[None], rhs[None])
    out = np.empty_like(bs)
    for row, (g, b) in enumerate(zip(Gs, bs)):
        out[row] = delassus_solution(g, b, damping, lambda j, row=row: singular_constraints(
            dyn.info, mask, j, row if stacked else -1))
    return out if stacked else out[0]


def delassus_solution(G: np.ndarray, b: np.ndarray, damping: float, fail) -> np.ndarray:
    """x of (G + damping I) x = b by G's L D Lᵀ with the C's pivot rule (a pivot at most
    SINGULAR_PIVOT of its diagonal entry: `fail(row)` raises)."""
    m = len(b)
    A = G + damping * np.eye(m)
    Lf, d = np.eye(m), np.zeros(m)
    for j in range(m):
        dj = A[j, j] - np.sum(Lf[j, :j] ** 2 * d[:j])
        if not dj > SINGULAR_PIVOT * A[j, j]:
            raise fail(j)
        d[j] = dj
        Lf[j + 1:, j] = (A[j + 1:, j] - Lf[j + 1:, :j] @ (Lf[j, :j] * d[:j])) / dj
    z = np.linalg.solve(Lf, b)
    return np.linalg.solve(Lf.T, z / d)


def singular_constraints(info: ModelInfo, mask, row: int, stacked_row: int = -1):
    """The SingularConstraintError for the active rows when row `row` (among them) depends
    on those before it."""
    names = row_names(info, mask)
    which = f": row {names[row]} is zero or depends on the rows before it" \
        if 0 <= row < len(names) else ""
    where = "" if stacked_row < 0 else f" (stacked input, row {stacked_row})"
    active = ", ".join(repr(c.name) for c, on in zip(info.constraints, mask) if on)
    return SingularConstraintError(one_line(
        f"the rows of constraints {active} are linearly dependent at this state{where}"
        f"{which} (redundant axes, e.g. a planar loop held in 3-D, a loop at a singular "
        f"configuration, or a frame that cannot move); declare fewer axes, or pass damping= "
        f"(> 0) for a damped solve"))


# --- the forces as external wrenches ------------------------------------------------------------

def constraint_wrenches(dyn, q, forces, p=None, mask=None) -> list[tuple[int, np.ndarray]]:
    """The forces λ (every declared row, as constrained_forward_dynamics returns them) as
    wrenches on frames [(frame index, (force, torque) in world axes at the frame's origin)],
    whose generalised force Σ J_frameᵀ w is Jᵀ λ: a contact's on its frame, a loop's on
    frame A and, opposite, on frame B (its moment moved to B's origin)."""
    info = dyn.info
    X, F, _ = dyn._frame_data(q, p)
    forces = np.asarray(forces, dtype=float)
    out = []
    for c, ci in zip(info.constraints, info.constraint_infos):
        if mask is not None and not mask[info.constraints.index(c)]:
            continue
        lam = forces[..., ci.rows]
        size = 6 if c.holds_frame else 3
        full = np.zeros(lam.shape[:-1] + (size,))
        full[..., list(c.axes)] = lam
        kA = info.frame_indices[c.frames[0]]
        R, pA = pose(info, X, F, kA)
        if c.reference == "local":
            full = _rotated(R, full)
        force, torque = full[..., :3], (full[..., 3:] if size == 6 else np.zeros_like(
            full[..., :3]))
        out.append((kA, np.concatenate([force, torque], axis=-1)))
        if c.type == "loop":
            kB = info.frame_indices[c.frames[1]]
            _, pB = pose(info, X, F, kB)
            moment = -torque - (np.cross(pA - pB, force) if size == 6 else 0.0)
            out.append((kB, np.concatenate([-force, moment], axis=-1)))
    return out


# --- the compiled runtime's checks of the per-call arguments ------------------------------------

class Arguments:
    """The checks of the constrained kernels' per-call arguments, for the compiled runtime
    (gagen.runtime._native): the active set as one byte per constraint (None: all, which the
    C reads as NULL), the gains, damping and restitution, and the error that names dependent
    rows."""

    # active sets given as tuples or lists are kept, checked, up to this many
    KEPT = 256

    def __init__(self, dyn):
        self.dyn, self.info = dyn, dyn.info
        self._kept: dict = {}

    def rows(self, active):
        """(mask as uint8 or None for all, the number of active rows)."""
        if active is None:
            return None, self.info.constraint_rows
        key = tuple(active) if type(active) in (list, tuple) else None
        try:
            found = self._kept.get(key) if key is not None else None
        except TypeError:  # something unhashable in the list: the checks say what
            key = found = None
        if found is not None:
            return found
        mask = active_mask(self.info, active)
        found = (mask.astype(np.uint8), int(sum(c.dimension for c, on in
                                                zip(self.info.constraints, mask) if on)))
        if key is not None and len(self._kept) < self.KEPT:
            self._kept[key] = found
        return found

    @staticmethod
    def gains(baumgarte) -> tuple[float, float]:
        return baumgarte_gains(baumgarte)

    @staticmethod
    def damping(damping) -> float:
        return nonnegative(damping, "damping")

    def impulse_arguments(self, active, restitution, damping):
        """(mask, rows, restitution, damping) of impulse_dynamics."""
        mask, m = self.rows(active)
        r = nonnegative(restitution, "restitution")
        if r > 1.0:
            raise ValueError(f"restitution must be in [0, 1]; got {r:g}")
        return mask, m, r, nonnegative(damping, "damping")

    def singular(self, q, mask, damping: float, row: int, p=None):
        """Raise the SingularConstraintError of the rows at q, naming the first dependent one
        (found again in NumPy, by the C's pivot rule)."""
        on = np.ones(len(self.info.constraints), dtype=bool) if mask is None \
            else np.asarray(mask, dtype=bool)
        dyn = self.dyn
        J = dyn.constraint_jacobian(q, active=on, p=p)
        M = dyn.mass_matrix(q, p)
        G = J @ np.linalg.solve(M, J.T)
        if len(G):  # raises naming the row, if NumPy's rounding meets it too
            delassus_solution(0.5 * (G + G.T), np.zeros(len(G)), damping,
                              lambda j: singular_constraints(self.info, on, j, row))
        raise singular_constraints(self.info, on, -1, row)
