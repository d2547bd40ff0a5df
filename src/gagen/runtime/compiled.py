"""The compiled backend's dynamics object: a module built from generated C, bound to the
API of `Dynamics` (no SymPy: names and defaults come from the module's manifest)."""

from __future__ import annotations

from functools import partial

from ..errors import BuildError
from ..manifest import ModelInfo
from .constraint_derivatives import compiled_call
from .constraints import Arguments
from .dynamics import Dynamics
from .frames import frame_index
from .taskspace import singular_task, task_dims, task_frames

KERNEL_METHODS = ("mass_matrix", "forcing", "forward_dynamics", "inverse_dynamics",
                  "gravity", "energy", "regressor", "regressor_parameters")
# the centre of mass and centroidal dynamics (centroidal.c), bound like KERNEL_METHODS
CENTROIDAL_METHODS = ("center_of_mass", "com_velocity", "com_jacobian", "centroidal_map",
                      "centroidal_momentum", "centroidal_map_time_variation",
                      "centroidal_bias")
# the frames' methods, by name (gagen.runtime.taskspace has their conventions)
FRAME_METHODS = ("frame_jacobian", "frame_velocity", "frame_acceleration",
                 "frame_bias_acceleration", "frame_jacobian_time_variation")
# the constrained dynamics (constraints.c), bound like KERNEL_METHODS
CONSTRAINED_METHODS = ("constrained_forward_dynamics", "impulse_dynamics")
# the methods of a model's derivative module (codegen/derivatives.py), bound on first use
DERIVATIVE_METHODS = ("inverse_dynamics_derivatives", "forward_dynamics_derivatives",
                      "coriolis_matrix", "linearize")


def native():
    """gagen's compiled runtime, imported on first use: without it (a source tree that was
    never built), `import gagen` and the lambdify backend still work."""
    from . import _native

    return _native


class CompiledDynamics(Dynamics):
    """`gagen.load(..., backend="compiled")`: the dynamics of a compiled extension module.

    The module's kernel methods are bound to the instance, so a call costs no Python frame
    of gagen's; they check their inputs like every backend (gagen.runtime.inputs).

    The derivatives are in a second module of their own, so that they never slow down a
    model's default build: `derivatives(dyn)` finds or builds it (gagen.load supplies it),
    on the first call of a derivative method, or up front with `load_derivatives()`.
    """

    backend = "compiled"

    def __init__(self, module, model_ref=None, derivatives=None):
        self.module = module
        self.info = ModelInfo.from_hex(module.MANIFEST_HEX)
        self._model_ref = model_ref
        self._derivatives = derivatives
        self.derivative_module = None
        self.kernels = native().CompiledModel(module.API, self.parameter_vector,
                                              self.external_forces, self.info.quaternions(),
                                              self.info.frame_indices,
                                              partial(frame_index, self.info),
                                              Arguments(self))
        for name in KERNEL_METHODS + CENTROIDAL_METHODS + FRAME_METHODS + CONSTRAINED_METHODS:
            setattr(self, name, getattr(self.kernels, name))
        self._frame_numbers = self.info.frame_indices

    # frames: the C of frames.c, one call per state (stacked states in one C loop)

    def _placements(self, q, p):
        return self.kernels.placements(q, p)

    def _frame_offsets(self, p):
        return self.kernels.frame_offsets(p)

    def frame_placement(self, q, frame, p=None):
        out = self.kernels.frame(0, frame_index(self.info, frame), q, None, p)
        return out[..., :9].reshape(out.shape[:-1] + (3, 3)), out[..., 9:].copy()

    # task space: the C of taskspace.c.j2 (in frames.c); the frames' kernels are bound

    def delassus(self, q, frames, dims=6, p=None):
        return self._task_matrix(0, q, frames, dims, p)

    def operational_space_inertia(self, q, frames, dims=6, p=None):
        return self._task_matrix(1, q, frames, dims, p)

    def _task_matrix(self, which: int, q, frames, dims, p):
        """J M^-1 J^T (which 0) or its inverse (1) from the C, the frames checked here."""
        try:  # one frame by name
            indices = [self._frame_numbers[frames]]
        except (KeyError, TypeError):
            indices = task_frames(self.info, frames)
        if type(dims) is not int or (dims != 6 and dims != 3):
            dims = task_dims(dims)
        if which == 1 and dims * len(indices) > self.nv:
            raise singular_task(self.info, indices, dims, -1)
        out, status, row = self.kernels.task_matrix(which, indices, dims, q, p)
        if status:
            raise singular_task(self.info, indices, dims, row)
        return out

    # constraints: the C of constraints.c.j2 (in frames.c); the dynamics are bound

    def constraint_jacobian(self, q, active=None, p=None):
        return self.kernels.constraint_rows(0, q, None, active, p)

    def constraint_drift(self, q, qd, active=None, p=None):
        return self.kernels.constraint_rows(1, q, qd, active, p)

    def constraint_error(self, q, active=None, p=None):
        return self.kernels.constraint_rows(2, q, None, active, p)

    def constrained_forward_dynamics_derivatives(self, q, qd, tau, active=None,
                                                 baumgarte=(0.0, 0.0), damping=0.0, p=None):
        # a call whose options need no conversion goes straight into the C
        found = compiled_call(self, q, qd, tau, active, baumgarte, damping, p)
        if found is not None:
            return found
        return Dynamics.constrained_forward_dynamics_derivatives(self, q, qd, tau, active,
                                                                 baumgarte, damping, p)

    constrained_forward_dynamics_derivatives.__doc__ = \
        Dynamics.constrained_forward_dynamics_derivatives.__doc__
    constraint_jacobian.__doc__ = Dynamics.constraint_jacobian.__doc__
    constraint_drift.__doc__ = Dynamics.constraint_drift.__doc__
    constraint_error.__doc__ = Dynamics.constraint_error.__doc__
    delassus.__doc__ = Dynamics.delassus.__doc__
    operational_space_inertia.__doc__ = Dynamics.operational_space_inertia.__doc__

    # --- derivatives: the second module ---------------------------------------------------

    def load_derivatives(self) -> None:
        """Find or build the derivative module now, and bind its methods."""
        if self.derivative_module is not None:
            return
        if self._derivatives is None:
            raise RuntimeError(
                "this dynamics object was made from a module alone, without a way to find or "
                "build its derivative module; load the model with gagen.load(model)")
        self.bind_derivatives(self._derivatives(self))

    def bind_derivatives(self, module) -> None:
        """Bind the methods of a derivative module built from this module's equations."""
        if module.EQUATIONS_KEY != self.module.KEY:
            raise BuildError(
                f"the derivative module {module.__name__} was not built from the equations of "
                f"{self.module.__name__} (its key {module.EQUATIONS_KEY[:12]}, expected "
                f"{self.module.KEY[:12]})")
        kernels = native().CompiledDerivatives(module.API, self.parameter_vector,
                                               self.info.quaternions())
        for name in DERIVATIVE_METHODS:
            setattr(self, name, getattr(kernels, name))
        self.derivative_module = module

    # Until the derivative module is bound, these find it, then call its method (bound to
    # the instance from then on, so later calls go straight to the compiled code).

    def inverse_dynamics_derivatives(self, q, qd, qdd, p=None):
        self.load_derivatives()
        return self.inverse_dynamics_derivatives(q, qd, qdd, p)

    def forward_dynamics_derivatives(self, q, qd, tau, p=None):
        self.load_derivatives()
        return self.forward_dynamics_derivatives(q, qd, tau, p)

    def coriolis_matrix(self, q, qd, p=None):
        self.load_derivatives()
        return self.coriolis_matrix(q, qd, p)

    def linearize(self, q, qd, tau, p=None):
        self.load_derivatives()
        return self.linearize(q, qd, tau, p)

    inverse_dynamics_derivatives.__doc__ = Dynamics.inverse_dynamics_derivatives.__doc__
    forward_dynamics_derivatives.__doc__ = Dynamics.forward_dynamics_derivatives.__doc__
    coriolis_matrix.__doc__ = Dynamics.coriolis_matrix.__doc__
    linearize.__doc__ = Dynamics.linearize.__doc__

