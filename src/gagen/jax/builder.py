"""The JAX functions of `gagen.jax.functions`: each METHODS entry as a function of JAX
arrays with a custom JVP (gagen.jax.rules), over one of the targets' `Ops`.

A function checks and converts its arguments (states of shape (..., size); p None, a
dict of overrides or a full array), then calls a `jax.custom_jvp` core whose primal is
the target's evaluation and whose JVP rule applies gagen's analytic derivatives, with
symbolic zeros: a rule runs only for the arguments being differentiated, and an argument
without a rule raises a NotImplementedError naming it (the printed target differentiates
its program there instead).

Parameters (`p`): on the compiled targets, derivatives with respect to p go through the
regressor (τ = Y π: ∂τ/∂p = Y ∂π/∂p, ∂π/∂p from the printed π(p)). That covers every
parameter the regressor's kinematics do not read: masses, mass centres, inertias, damping,
friction and armature. The others (lengths, gravity: `kinematic_parameters`) raise a
ValueError when differentiated; pass the parameters to differentiate as a dict
(`p={"m_link7": m}`), whose entries are differentiated one by one. On the printed target
every parameter is differentiable (JAX differentiates the printed program in p).
"""

from __future__ import annotations

from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from gagen.jax.registry import ARGUMENT_SIZES, Method
from gagen.jax.rules import PARAMETER_RULES, RULES, Context

COMPILED_TARGETS = ("ffi", "callback")


def _is_zero(t) -> bool:
    return t is None or isinstance(t, SymbolicZero)


class Builder:
    """Makes the functions of one dynamics object on one target's ops."""

    def __init__(self, ops, parameter_program=None):
        self.ops = ops
        self.dyn = ops.dyn
        self.names = list(self.dyn.parameters)
        self.index = {name: k for k, name in enumerate(self.names)}
        self.defaults = np.asarray(self.dyn.info.parameter_vector(), dtype=np.float64)
        # (π(p), kinematic indices) for parameter derivatives on the compiled targets
        self._parameter_program = parameter_program
        self._cores: dict[tuple[str, int], object] = {}

    # --- the arguments -----------------------------------------------------------------------

    def states(self, method: Method, values) -> tuple:
        arrays = []
        for name, value in zip(method.args, values):
            if isinstance(value, (str, bytes)) or value is None:
                raise TypeError(f"{name} must be an array of numbers, got "
                                f"{type(value).__name__}")
            a = jnp.asarray(value)
            if not (jnp.issubdtype(a.dtype, jnp.floating) or jnp.issubdtype(a.dtype, jnp.integer)
                    or a.dtype == jnp.bool_):
                raise TypeError(f"{name} must hold real numbers, got dtype {a.dtype}")
            size = self.ops.sizes[ARGUMENT_SIZES[name]]
            if a.ndim == 0 or a.shape[-1] != size:
                raise ValueError(f"{name} must have shape ({size},) or (..., {size}); got "
                                 f"{tuple(a.shape)}")
            arrays.append(a)
        return tuple(arrays)

    def dtype(self, arrays, p):
        floats = [a.dtype for a in arrays if jnp.issubdtype(a.dtype, jnp.floating)]
        if isinstance(p, Mapping):
            floats += [jnp.asarray(v).dtype for v in p.values()
                       if jnp.issubdtype(jnp.asarray(v).dtype, jnp.floating)]
        elif p is not None:
            pa = jnp.asarray(p)
            if jnp.issubdtype(pa.dtype, jnp.floating):
                floats.append(pa.dtype)
        return jnp.result_type(*floats) if floats else jnp.asarray(0.0).dtype

    def parameters(self, p, dtype):
        """(base: a full array or None, overrides: {index: value})."""
        if p is None:
            return None, {}
        if isinstance(p, Mapping):
            over = {}
            for name, value in p.items():
                if name not in self.index:
                    raise KeyError(f"unknown parameter '{name}' (parameters: "
                                   f"{', '.join(self.names)})")
                if isinstance(value, (str, bytes)) or value is None:
                    raise TypeError(f"parameter '{name}' must be a number, got {value!r}")
                over[self.index[name]] = jnp.asarray(value, dtype)
            return None, over
        if isinstance(p, (str, bytes)):
            raise TypeError(f"p must be None, a dict or an array of numbers, got "
                            f"{type(p).__name__}")
        pa = jnp.asarray(p, dtype)
        if pa.ndim == 0 or pa.shape[-1] != len(self.names):
            raise ValueError(f"p must have shape ({len(self.names)},) or (..., "
                             f"{len(self.names)}); got {tuple(pa.shape)}")
        return pa, {}

    def full(self, base, over, dtype):
        """The full parameter array, or None for the defaults untouched."""
        if base is None and not over:
            return None
        p = jnp.asarray(self.defaults, dtype) if base is None else base
        if over:
            lead = jnp.broadcast_shapes(p.shape[:-1], *(v.shape for v in over.values()))
            p = jnp.broadcast_to(p, lead + p.shape[-1:])
            for k, value in over.items():
                p = p.at[..., k].set(jnp.broadcast_to(value, lead))
        return p

    # --- the functions -------------------------------------------------------------------------

    def function(self, method: Method):
        """The public function of a method: f(*states, [frame,] p=None)."""
        nargs = len(method.args)
        frames = method.frame

        def f(*args, p=None):
            expected = nargs + (1 if frames else 0)
            if len(args) != expected:
                names = list(method.args) + (["frame"] if frames else [])
                raise TypeError(f"{method.name}() takes {', '.join(names) or 'no arguments'}"
                                f" and p=None; got {len(args)} positional arguments")
            frame = -1
            if frames:
                from gagen.runtime.frames import frame_index

                frame = frame_index(self.dyn.info, args[-1])
                args = args[:-1]
            states = self.states(method, args)
            dtype = self.dtype(states, p)
            states = tuple(jnp.asarray(s, dtype) for s in states)
            base, over = self.parameters(p, dtype)
            return self.core(method, frame)(states, base, over)

        f.__name__ = method.name
        f.__qualname__ = method.name
        f.__doc__ = _docstring(self.dyn, method, self.ops.target)
        return f

    def core(self, method: Method, frame: int):
        key = (method.name, frame)
        core = self._cores.get(key)
        if core is None:
            core = self._cores[key] = self._make_core(method, frame)
        return core

    def _make_core(self, method: Method, frame: int):
        ops = self.ops

        def primal(states, base, over):
            dtype = _dtype_of(states, base, over)
            p = self.full(base, over, dtype)
            return ops.call(method.name, *states, p=p, frame=frame)

        core = jax.custom_jvp(primal)

        def jvp(primals, tangents):
            states, base, over = primals
            dstates, dbase, dover = tangents
            dtype = _dtype_of(states, base, over)
            p = self.full(base, over, dtype)
            out = ops.call(method.name, *states, p=p, frame=frame)
            x = dict(zip(method.args, states))
            dx = {a: None if _is_zero(t) else t for a, t in zip(method.args, dstates)}
            ctx = Context(ops, p, frame)
            total = self._state_tangent(method, ctx, x, dx, out, states, p)
            dp = self._parameter_tangent(method, base, over, dbase, dover, dtype)
            if dp is not None:
                total = _add_tree(total, self._through_parameters(method, ctx, x, out, states,
                                                                  p, base, over, dp, dtype))
            if total is None:
                total = jax.tree_util.tree_map(jnp.zeros_like, out)
            return out, total

        core.defjvp(jvp, symbolic_zeros=True)
        return core

    def _state_tangent(self, method, ctx, x, dx, out, states, p):
        moving = [a for a in method.args if dx[a] is not None]
        if not moving:
            return None
        supported = RULES[method.rule][0] if method.rule else ()
        printed = self.ops.target == "jax"
        analytic = [a for a in moving if a in supported and (not printed or _printed_rule(method))]
        others = [a for a in moving if a not in analytic]
        total = None
        if analytic:
            total = RULES[method.rule][1](ctx, x, {a: dx[a] if a in analytic else None
                                                   for a in method.args}, out)
        if others:
            if not printed:
                raise NotImplementedError(
                    f"gagen.jax: {method.name} has no derivative with respect to "
                    f"{', '.join(others)} on the compiled path (target='{self.ops.target}'); "
                    "use gagen.jax.functions(dyn, target='jax'), whose printed programs JAX "
                    "differentiates")
            total = _add_tree(total, self._autodiff(method, states, p, ctx.frame,
                                                    {a: dx[a] for a in others}))
        return total

    def _autodiff(self, method, states, p, frame, tangents):
        """JAX's own JVP of the printed program in some arguments."""
        names = list(tangents)
        position = {a: k for k, a in enumerate(method.args)}

        def partial(*moving):
            values = list(states)
            for a, v in zip(names, moving):
                values[position[a]] = v
            return self.ops.call(method.name, *values, p=p, frame=frame)

        primals = tuple(states[position[a]] for a in names)
        return jax.jvp(partial, primals, tuple(tangents[a] for a in names))[1]

    def _parameter_tangent(self, method, base, over, dbase, dover, dtype):
        """The tangent of the full parameter array, or None when p is not differentiated;
        on the compiled targets, a ValueError for a kinematic parameter."""
        moving_base = base is not None and not _is_zero(dbase)
        moving = {k: dover[k] for k in over if not _is_zero(dover[k])}
        if not moving_base and not moving:
            return None
        if self.ops.target != "jax":
            kinematic = set(self.kinematic())
            named = [self.names[k] for k in moving if k in kinematic]
            if named:
                raise ValueError(
                    f"gagen.jax: {', '.join(named)} {'is a' if len(named) == 1 else 'are'} "
                    "kinematic parameter(s) (the regressor's kinematics read them): the "
                    f"compiled path (target='{self.ops.target}') differentiates p through the "
                    "regressor only; use target='jax' to differentiate them")
            if moving_base and kinematic:
                shown = ", ".join(self.names[k] for k in sorted(kinematic)[:6])
                raise ValueError(
                    "gagen.jax: differentiating a full parameter array p would include its "
                    f"kinematic parameters ({shown}), which the compiled path "
                    f"(target='{self.ops.target}') differentiates through the regressor "
                    "only; pass the parameters to differentiate as a dict "
                    "(p={'m_link': m, ...}), or use target='jax'")
        lead_shapes = [dbase.shape[:-1]] if moving_base else []
        lead_shapes += [t.shape for t in moving.values()]
        lead = jnp.broadcast_shapes(*lead_shapes)
        dp = jnp.zeros(lead + (len(self.names),), dtype)
        if moving_base:
            dp = dp + dbase
        for k, t in moving.items():
            dp = dp.at[..., k].add(jnp.broadcast_to(t, lead))
        return dp

    def _through_parameters(self, method, ctx, x, out, states, p, base, over, dp, dtype):
        if p is None:
            p = jnp.asarray(self.defaults, dtype)
        if self.ops.target == "jax":
            return jax.jvp(lambda pf: self.ops.call(method.name, *states, p=pf,
                                                    frame=ctx.frame), (p,), (dp,))[1]
        if method.parameter_rule is None:
            raise NotImplementedError(
                f"gagen.jax: {method.name} has no derivative with respect to p on the compiled "
                f"path (target='{self.ops.target}'); use target='jax'")
        # dπ = (∂π/∂p) dp with ∂π/∂p evaluated at p from the printed π(p) (forward mode):
        # it depends on p alone, so in a rollout JAX's partial evaluation computes it once,
        # outside the loop, and the reverse pass only multiplies by its transpose
        dpi = jnp.einsum("...ij,...j->...i", self._pi_jacobian(p), dp)
        return PARAMETER_RULES[method.parameter_rule](ctx, x, out, dpi)

    def _pi_jacobian(self, p):
        """∂π/∂p at p, (..., P, np), from the printed program of π."""
        pi = self.parameter_program().regressor_parameters
        if p.ndim == 1:
            return jax.jacfwd(pi)(p)
        flat = p.reshape(-1, p.shape[-1])
        jac = jax.vmap(jax.jacfwd(pi))(flat)
        return jac.reshape(p.shape[:-1] + jac.shape[-2:])

    def parameter_program(self):
        """The printed dynamics module (π(p) and KINEMATIC), printed on first use."""
        if self._parameter_program is None:
            from gagen.jax.printed import printed_module

            self._parameter_program = printed_module(self.dyn, "dynamics", self.ops.cache_dir)
        return self._parameter_program

    def kinematic(self) -> tuple[int, ...]:
        """The indices of the parameters the regressor's kinematics read."""
        return tuple(self.parameter_program().KINEMATIC)


def _printed_rule(method: Method) -> bool:
    """Whether the printed target uses the analytic rule (the printed derivative
    programs) rather than JAX's autodiff of the printed program: for the dynamics, whose
    derivative programs are gagen's optimised ones; the other rules compose several
    evaluations, which autodiff of one program does more cheaply."""
    return method.name in ("inverse_dynamics", "forward_dynamics", "gravity", "forcing")


def _dtype_of(states, base, over):
    for a in list(states) + ([base] if base is not None else []) + list(over.values()):
        return a.dtype
    return jnp.asarray(0.0).dtype


def _add_tree(total, term):
    if total is None:
        return term
    if term is None:
        return total
    return jax.tree_util.tree_map(lambda a, b: a + b, total, term)


def _docstring(dyn, method: Method, target: str) -> str:
    from gagen.runtime.dynamics import Dynamics

    own = getattr(Dynamics, method.name, None)
    text = (own.__doc__ or "").strip() if own is not None else ""
    frame = ", frame" if method.frame else ""
    signature = f"{method.name}({', '.join(method.args)}{frame}, p=None)"
    return (f"{signature}: gagen's {method.name} of model '{dyn.info.name}' as a JAX function "
            f"(target '{target}'; gagen.jax).\n\n{text}")
