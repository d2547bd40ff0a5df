"""The derivative rules of gagen.jax's functions: JVPs from gagen's analytic derivatives.

A rule maps the tangents of a method's state arguments to the tangent of its result. It
evaluates matrices at the primal point (the derivative kernels, M, the regressor: through
the same `Ops` as the function itself) and applies them to the tangents with linear JAX
operations only (einsum, solve with a fixed matrix), so JAX can transpose it: `jax.grad`
and `jax.jacrev` work as `jax.jvp` and `jax.jacfwd` do.

Conventions (gagen.runtime.dynamics): the derivative kernels differentiate along the nv
velocity directions, d/dε f(q ⊕ ε e_j). `velocity` turns a tangent of q's own entries into
that velocity: the identity for 1-dof joints; for a floating joint v_lin = Rᵀ dp and
v_ang = 4 Qᵀ dquat / |quat|² (Q the quaternion's rates, symbolic.derivatives.tangent_map).
The kernels build rotations from the quaternion divided by its squared norm, so they do not
change along the quaternion itself, and this is the exact derivative by q's entries.

`RULES[name]` = (arguments it differentiates, rule); `PARAMETER_RULES[name]` maps dπ, the
tangent of the regressor's parameters π, to the result's tangent: the dynamics are linear
in π (τ = Y(q, q̇, q̈) π), so ∂τ/∂p = Y ∂π/∂p, and q̈ = M⁻¹(τ − ...) gives −M⁻¹ Y ∂π/∂p at q̈.
"""

from __future__ import annotations

import jax.numpy as jnp

from gagen.jax.product import jacobian_product


def mv(A, x):
    """A @ x over leading dimensions: (..., m, n) by (..., n). For the dynamics' square
    matrices (n up to a few dozen) as n products of columns summed: XLA fuses them into one
    elementwise loop over the batch, where a batched dot of such small matrices costs it
    several times more on the CPU (under jax.jacfwd's basis of tangents most of all); for
    the regressor's long rows (P = 10 per body) a dot."""
    if A.shape[-1] > SMALL:
        return jnp.einsum("...ij,...j->...i", A, x)
    total = A[..., :, 0] * x[..., 0:1]
    for j in range(1, A.shape[-1]):
        total = total + A[..., :, j] * x[..., j: j + 1]
    return total


# the widest matrix `mv` multiplies column by column
SMALL = 48


def side_by_side(arrays):
    """The arrays joined along their last axis, their other axes broadcast."""
    lead = jnp.broadcast_shapes(*(a.shape[:-1] for a in arrays))
    return jnp.concatenate([jnp.broadcast_to(a, lead + a.shape[-1:]) for a in arrays], -1)


def add(total, term):
    return term if total is None else total + term


class Context:
    """The primal point of a rule: the ops, the full parameters (or None), the frame."""

    def __init__(self, ops, p, frame: int):
        self.ops, self.p, self.frame = ops, p, frame
        self._calls: dict = {}  # (name, ids of the states) -> (results, the states)
        info = ops.dyn.info
        self.nv = ops.dyn.nv
        self.floating = info.floating_joints()
        self.joints = info.joints

    def call(self, name: str, *states):
        """A method's results at this point; kept for the rule's other terms (the
        parameters' term reuses the derivative kernel's M⁻¹)."""
        key = (name, tuple(id(s) for s in states))
        found = self._calls.get(key)
        if found is None:
            found = self._calls[key] = (self.ops.call(name, *states, p=self.p,
                                                      frame=self.frame), states)
        return found[0]

    def forward_dynamics_jacobian(self, q, qd, tau):
        """[∂q̈/∂q | ∂q̈/∂q̇ | M⁻¹] (..., nv, nq + 2 nv) at this point, ∂q̈/∂q by q's own
        entries (Ops.forward_dynamics_jacobian), kept as `call` keeps results."""
        key = ("forward_dynamics_jacobian", (id(q), id(qd), id(tau)))
        found = self._calls.get(key)
        if found is None:
            found = self._calls[key] = (self.ops.forward_dynamics_jacobian(q, qd, tau, p=self.p),
                                        (q, qd, tau))
        return found[0]

    def called(self, name: str, *states):
        """The results of an earlier `call` with these very arrays, or None."""
        found = self._calls.get((name, tuple(id(s) for s in states)))
        return None if found is None else found[0]

    def zeros(self, like):
        return jnp.zeros(like.shape[:-1] + (self.nv,), like.dtype)

    def velocity(self, q, dq):
        """The velocity tangent (..., nv) of a tangent dq (..., nq) of the configuration
        (slices and products only: JAX transposes it)."""
        if not self.floating:
            return dq
        lead = jnp.broadcast_shapes(q.shape[:-1], dq.shape[:-1])
        pieces, iq = [], 0
        for joint in self.joints:
            if joint.type != "floating":
                pieces.append(jnp.broadcast_to(dq[..., iq: iq + 1], lead + (1,)))
                iq += 1
                continue
            quat = q[..., iq + 3: iq + 7]
            R, Q = rotation_and_rates(quat)
            scale = 4.0 / jnp.sum(quat * quat, axis=-1, keepdims=True)
            pieces.append(jnp.broadcast_to(mv(jnp.swapaxes(R, -1, -2), dq[..., iq: iq + 3]),
                                           lead + (3,)))
            pieces.append(jnp.broadcast_to(
                scale * mv(jnp.swapaxes(Q, -1, -2), dq[..., iq + 3: iq + 7]), lead + (3,)))
            iq += 7
        return jnp.concatenate(pieces, axis=-1)


def by_configuration(joints, q, A):
    """A (..., m, nv), a derivative by the velocity directions, as the derivative by q's
    own entries (..., m, nq): A times the map `Context.velocity` applies to dq, which is the
    identity for 1-dof joints (elementwise products only: XLA fuses them). The FFI shim
    does the same in C for forward dynamics' Jacobian (templates/ffi_shim.cc.j2)."""
    if not any(joint.type == "floating" for joint in joints):
        return A
    pieces, iq, iv = [], 0, 0
    for joint in joints:
        if joint.type != "floating":
            pieces.append(A[..., iv: iv + 1])
            iq, iv = iq + 1, iv + 1
            continue
        quat = q[..., iq + 3: iq + 7]
        R, Q = rotation_and_rates(quat)
        scale = 4.0 / jnp.sum(quat * quat, axis=-1)
        # v_lin = Rᵀ dp: A_lin Rᵀ; v_ang = scale Qᵀ dquat: scale A_ang Qᵀ
        pieces.append(_times_transpose(A[..., iv: iv + 3], R))
        pieces.append(scale[..., None, None] * _times_transpose(A[..., iv + 3: iv + 6], Q))
        iq, iv = iq + 7, iv + 6
    return side_by_side(pieces)


def _times_transpose(A, B):
    """A Bᵀ over leading dimensions, (..., m, k) by (..., n, k), as k products summed."""
    total = A[..., :, None, 0] * B[..., None, :, 0]
    for k in range(1, A.shape[-1]):
        total = total + A[..., :, None, k] * B[..., None, :, k]
    return total


def rotation_and_rates(quat):
    """R of a quaternion (x, y, z, w), normalised, and its rates Q (4 x 3): column k is
    d quat / d w_k = 1/2 quat ⊗ (e_k, 0) (gagen.symbolic.derivatives.tangent_map)."""
    x, y, z, w = (quat[..., k] for k in range(4))
    s = 1.0 / jnp.sum(quat * quat, axis=-1)
    R = jnp.stack([
        jnp.stack([1 - 2 * s * (y * y + z * z), 2 * s * (x * y - z * w),
                   2 * s * (x * z + y * w)], -1),
        jnp.stack([2 * s * (x * y + z * w), 1 - 2 * s * (x * x + z * z),
                   2 * s * (y * z - x * w)], -1),
        jnp.stack([2 * s * (x * z - y * w), 2 * s * (y * z + x * w),
                   1 - 2 * s * (x * x + y * y)], -1)], -2)
    Q = 0.5 * jnp.stack([jnp.stack([w, z, -y, -x], -1), jnp.stack([-z, w, x, -y], -1),
                         jnp.stack([y, -x, w, -z], -1)], -1)
    return R, Q


def _zero_velocity(ctx, q):
    return jnp.zeros(q.shape[:-1] + (ctx.nv,), q.dtype)


# --- the state arguments ---------------------------------------------------------------------

def inverse_dynamics(ctx, x, dx, out):
    q, qd, qdd = x["q"], x["qd"], x["qdd"]
    total = None
    if dx["q"] is not None or dx["qd"] is not None:
        Dq, Dqd = ctx.call("inverse_dynamics_derivatives", q, qd, qdd)
        if dx["q"] is not None:
            total = add(total, mv(Dq, ctx.velocity(q, dx["q"])))
        if dx["qd"] is not None:
            total = add(total, mv(Dqd, dx["qd"]))
    if dx["qdd"] is not None:
        total = add(total, mv(ctx.call("mass_matrix", q), dx["qdd"]))
    return total


def forward_dynamics(ctx, x, dx, out):
    """q̈'s tangent as one product: the Jacobian's blocks of the moving arguments side by
    side, [∂q̈/∂q | ∂q̈/∂q̇ | M⁻¹] (…, nv, nq + 2 nv), times their tangents stacked. The
    configuration block is by q's own entries (the velocity map folded into the matrix,
    per state, in the FFI shim's C loop), so under jax.jacfwd the stacked tangents are jacfwd's basis, the same for
    every state, and the product is one dot of all states' rows by that basis, written in
    the Jacobian's own layout: no per-block products, sums or transposes over the batch."""
    q, qd, tau = x["q"], x["qd"], x["tau"]
    moving = [a for a in ("q", "qd", "tau") if dx[a] is not None]
    if not moving:
        return None
    if len(moving) == 3 and ctx.ops.target == "ffi":
        # one primitive, whose batching rule under jax.jacfwd is one FFI call of the
        # Jacobian times jacfwd's basis (gagen.jax.product)
        tangent = side_by_side([dx[a] for a in moving])
        return jacobian_product(ctx.ops, q, qd, tau, ctx.p, tangent)
    jacobian = ctx.forward_dynamics_jacobian(q, qd, tau)
    if len(moving) < 3:
        nq, nv = q.shape[-1], ctx.nv
        block = {"q": jacobian[..., :nq], "qd": jacobian[..., nq: nq + nv],
                 "tau": jacobian[..., nq + nv:]}
        jacobian = side_by_side([block[a] for a in moving])
    tangent = side_by_side([dx[a] for a in moving])
    return jnp.einsum("...ij,...j->...i", jacobian, tangent)


def gravity(ctx, x, dx, out):
    q = x["q"]
    zero = _zero_velocity(ctx, q)
    Dq, _ = ctx.call("inverse_dynamics_derivatives", q, zero, zero)
    return mv(Dq, ctx.velocity(q, dx["q"]))


def forcing(ctx, x, dx, out):
    """F = τ − ID(q, q̇, 0)."""
    q, qd = x["q"], x["qd"]
    total = None
    if dx["q"] is not None or dx["qd"] is not None:
        Dq, Dqd = ctx.call("inverse_dynamics_derivatives", q, qd, _zero_velocity(ctx, q))
        if dx["q"] is not None:
            total = add(total, -mv(Dq, ctx.velocity(q, dx["q"])))
        if dx["qd"] is not None:
            total = add(total, -mv(Dqd, dx["qd"]))
    if dx["tau"] is not None:
        total = add(total, dx["tau"])
    return total


def mass_derivative(ctx, q):
    """T[..., j, i, k] = ∂M_ij/∂v_k: ∂ID(q, 0, e_j)/∂q − ∂ID(q, 0, 0)/∂q (ID is linear in
    q̈), every column in one call."""
    nv = ctx.nv
    eye = jnp.eye(nv, dtype=q.dtype)
    zero = jnp.zeros((nv,), q.dtype)
    columns, _ = ctx.call("inverse_dynamics_derivatives", q[..., None, :], zero, eye)
    base, _ = ctx.call("inverse_dynamics_derivatives", q, zero, zero)
    return columns - base[..., None, :, :]


def mass_matrix(ctx, x, dx, out):
    q = x["q"]
    return jnp.einsum("...jik,...k->...ij", mass_derivative(ctx, q), ctx.velocity(q, dx["q"]))


def energy(ctx, x, dx, out):
    """(T, V) with T = ½ q̇ᵀ M q̇: ∂T/∂q̇ = M q̇, ∂V/∂q = g(q), and ∂T/∂q = Cᵀ q̇ for a
    fixed base (Ṁ = C + Cᵀ), ½ q̇ᵀ (∂M/∂v_k) q̇ with a floating one (its velocities are
    not the rates of q's entries, and Cᵀ q̇ is not that derivative there)."""
    q, qd = x["q"], x["qd"]
    dT = dV = None
    if dx["q"] is not None:
        v = ctx.velocity(q, dx["q"])
        if ctx.floating:
            dT = 0.5 * jnp.einsum("...jik,...i,...j,...k->...", mass_derivative(ctx, q), qd,
                                  qd, v)
        else:
            C = ctx.call("coriolis_matrix", q, qd)
            dT = jnp.einsum("...ji,...j,...i->...", C, qd, v)
        dV = jnp.einsum("...i,...i->...", ctx.call("gravity", q), v)
    if dx["qd"] is not None:
        Mqd = mv(ctx.call("mass_matrix", q), qd)
        dT = add(dT, jnp.einsum("...i,...i->...", Mqd, dx["qd"]))
    if dV is None:
        dV = jnp.zeros_like(dT)
    return dT, dV


def coriolis_matrix(ctx, x, dx, out):
    """C is linear in q̇: ∂C/∂q̇_k = C(q, e_k), every k in one call."""
    q = x["q"]
    eye = jnp.eye(ctx.nv, dtype=q.dtype)
    columns = ctx.call("coriolis_matrix", q[..., None, :], eye)
    return jnp.einsum("...kij,...k->...ij", columns, dx["qd"])


def _skew(w):
    zero = jnp.zeros_like(w[..., 0])
    return jnp.stack([jnp.stack([zero, -w[..., 2], w[..., 1]], -1),
                      jnp.stack([w[..., 2], zero, -w[..., 0]], -1),
                      jnp.stack([-w[..., 1], w[..., 0], zero], -1)], -2)


def frame_placement(ctx, x, dx, out):
    """d pos = J_lin v, dR = [J_ang v]× R (LOCAL_WORLD_ALIGNED)."""
    q = x["q"]
    R, _ = out
    J = ctx.call("frame_jacobian", q)
    v = mv(J, ctx.velocity(q, dx["q"]))
    return jnp.einsum("...ij,...jk->...ik", _skew(v[..., 3:]), R), v[..., :3]


def frame_velocity(ctx, x, dx, out):
    return mv(ctx.call("frame_jacobian", x["q"]), dx["qd"])


# name -> (the arguments the rule differentiates, the rule)
RULES = {
    "inverse_dynamics": (("q", "qd", "qdd"), inverse_dynamics),
    "forward_dynamics": (("q", "qd", "tau"), forward_dynamics),
    "gravity": (("q",), gravity),
    "forcing": (("q", "qd", "tau"), forcing),
    "mass_matrix": (("q",), mass_matrix),
    "energy": (("q", "qd"), energy),
    "coriolis_matrix": (("qd",), coriolis_matrix),
    "frame_placement": (("q",), frame_placement),
    "frame_velocity": (("qd",), frame_velocity),
}


# --- the parameters, through the regressor ----------------------------------------------------

def _parameters_inverse_dynamics(ctx, x, out, dpi):
    return mv(ctx.call("regressor", x["q"], x["qd"], x["qdd"]), dpi)


def _parameters_forward_dynamics(ctx, x, out, dpi):
    q = x["q"]
    dtau = mv(ctx.call("regressor", q, x["qd"], out), dpi)
    jacobian = ctx.called("forward_dynamics_jacobian", q, x["qd"], x["tau"])
    if jacobian is not None:  # the state's term computed M⁻¹ already
        return -mv(jacobian[..., q.shape[-1] + ctx.nv:], dtau)
    M = ctx.call("mass_matrix", q)
    M, dtau = jnp.broadcast_arrays(M, dtau[..., None])
    return -jnp.linalg.solve(M, dtau)[..., 0]


def _parameters_gravity(ctx, x, out, dpi):
    q = x["q"]
    zero = _zero_velocity(ctx, q)
    return mv(ctx.call("regressor", q, zero, zero), dpi)


def _parameters_forcing(ctx, x, out, dpi):
    q = x["q"]
    return -mv(ctx.call("regressor", q, x["qd"], _zero_velocity(ctx, q)), dpi)


def _parameters_mass_matrix(ctx, x, out, dpi):
    q = x["q"]
    eye = jnp.eye(ctx.nv, dtype=q.dtype)
    zero = jnp.zeros((ctx.nv,), q.dtype)
    columns = ctx.call("regressor", q[..., None, :], zero, eye)
    base = ctx.call("regressor", q, zero, zero)
    return jnp.einsum("...jip,...p->...ij", columns - base[..., None, :, :], dpi)


def _parameters_regressor_parameters(ctx, x, out, dpi):
    return dpi


PARAMETER_RULES = {
    "inverse_dynamics": _parameters_inverse_dynamics,
    "forward_dynamics": _parameters_forward_dynamics,
    "gravity": _parameters_gravity,
    "forcing": _parameters_forcing,
    "mass_matrix": _parameters_mass_matrix,
    "regressor_parameters": _parameters_regressor_parameters,
}
