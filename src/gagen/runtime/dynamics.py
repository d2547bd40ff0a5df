"""The runtime API, written once for every backend: names, parameters, and the documented
dynamics methods (the backends supply the numbers)."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from ..errors import SingularMassMatrixError  # noqa: F401 (re-exported)
from ..manifest import ModelInfo
from .frames import frame_index, frame_indices
from .inputs import as_states, check_quaternions, parameter_array


class Dynamics:
    """A model's equations of motion, M(q) q̈ = F(q, q̇, τ), evaluated numerically.

    Every method takes one state (arrays of shape (n,)) or N stacked states (shape (N, n))
    and returns fresh arrays: nothing returned is ever overwritten by a later call.
    `p` is None (the model's defaults), a dict of overrides by name, or a full array in
    `parameters` order.
    """

    backend: str
    info: ModelInfo
    _model_ref: object = None

    # --- names and parameters --------------------------------------------------------------

    @property
    def model(self):
        """The full `gagen.model.Model` (symbolic; read from its source on first use)."""
        model = self.__dict__.get("_model")
        if model is None:
            from ..model.resolve import resolve_model

            ref, floating_base = self._model_ref if isinstance(self._model_ref, tuple) \
                else (self._model_ref, False)
            model = self.__dict__["_model"] = resolve_model(ref, floating_base=floating_base)
        return model

    @property
    def source(self) -> str:
        """Where the model was read from: its description's path as given to `gagen.load`
        (for a given Model, the path it was read from), or a built-in's name. The viewer
        finds the description's meshes from it."""
        ref = self._model_ref[0] if isinstance(self._model_ref, tuple) else self._model_ref
        if ref is None:
            return self.info.source
        return str(getattr(ref, "source", ref))

    @property
    def coordinates(self) -> list[str]:
        """The velocity coordinates' names, in the order of qd, qdd and tau (and of q, when
        no joint floats): the moving joints; a floating joint's six first among its own,
        `<joint>_vx, _vy, _vz` (its origin's velocity) and `_wx, _wy, _wz` (its angular
        velocity), both in its body's frame."""
        return list(self._coordinates)

    @property
    def configuration(self) -> list[str]:
        """The names of q's entries: the coordinates, except that a floating joint has
        seven, `<joint>_x, _y, _z` (its origin in the world) and `_qx, _qy, _qz, _qw` (its
        orientation as a unit quaternion, Pinocchio's FreeFlyer order)."""
        return list(self.info.configuration)

    @property
    def parameters(self) -> dict[str, float]:
        """The parameters' names and default values, in the order of a p array."""
        return self.info.parameter_defaults

    @property
    def n(self) -> int:
        """The number of velocity coordinates (nv)."""
        return len(self._coordinates)

    @property
    def nv(self) -> int:
        """The number of velocity coordinates: the size of qd, qdd, tau; M is nv x nv."""
        return len(self._coordinates)

    @property
    def nq(self) -> int:
        """The size of q: nv, plus one per floating joint (a quaternion for 3 rotations)."""
        return self._sizes[0]

    @cached_property
    def _sizes(self) -> tuple[int, int, int]:
        """(nq, nv, nv): the sizes of a call's three state arguments."""
        return (self.info.nq, self.nv, self.nv)

    @cached_property
    def _coordinates(self) -> tuple[str, ...]:
        return tuple(self.info.coordinates)

    @cached_property
    def _parameter_names(self) -> list[str]:
        return [name for name, _ in self.info.parameters]

    @cached_property
    def _default_parameters(self) -> np.ndarray:
        return self.info.parameter_vector()

    def parameter_vector(self, p=None) -> np.ndarray:
        """Full parameter array in `parameters` order from None, a dict of overrides or an array."""
        return parameter_array(p, self._parameter_names, self._default_parameters)

    def __repr__(self) -> str:
        return (f"<gagen dynamics '{self.info.name}' backend={self.backend} "
                f"coordinates={self.coordinates}>")

    # --- the configuration space -----------------------------------------------------------

    def integrate(self, q, v, dt=1.0) -> np.ndarray:
        """q ⊕ v·dt, as Pinocchio's `integrate(model, q, v * dt)`: a floating joint moves
        along the twist v (its origin's velocity and its angular velocity, in its body's
        frame) held for dt, every other coordinate by v·dt. Shapes (nq,), (nv,) or stacked;
        dt a number."""
        from .manifold import checked_step, integrate

        (q, v), _ = as_states(self._sizes[:2], q, v, names=("q", "v"))
        check_quaternions(q, self._quaternions)
        return integrate(self.info, q, checked_step(self.info, v, dt), 1.0)

    def difference(self, q0, q1) -> np.ndarray:
        """The velocity v, shape (nv,), with `integrate(q0, v) == q1` (Pinocchio's
        `difference`); stacked inputs give stacked outputs."""
        from .manifold import difference

        (q0, q1), _ = as_states((self.nq, self.nq), q0, q1, names=("q0", "q1"))
        check_quaternions(q0, self._quaternions, "q0")
        check_quaternions(q1, self._quaternions, "q1")
        return difference(self.info, q0, q1)

    @cached_property
    def _quaternions(self) -> tuple[tuple[int, str], ...]:
        """(first entry in q, description) of each floating joint's quaternion."""
        return self.info.quaternions()

    def neutral(self) -> np.ndarray:
        """The configuration with every coordinate 0 and every quaternion the identity."""
        from .manifold import neutral

        return neutral(self.info)

    # --- frames ------------------------------------------------------------------------------

    @property
    def frames(self) -> list[str]:
        """Every frame's name: each link of the description (those merged into a body by
        fixed joints too, e.g. a tool flange or a foot) and each joint."""
        return [name for name, _, _ in self.info.frames]

    def frame_placement(self, q, frame, p=None) -> tuple[np.ndarray, np.ndarray]:
        """(R, p): the frame's orientation (world components of its axes, (3, 3)) and its
        origin in the world (3,); stacked q gives (N, 3, 3) and (N, 3). `frame` is a name of
        `frames` or an index into it."""
        from .frames import pose

        X, F, _ = self._frame_data(q, p)
        return pose(self.info, X, F, frame_index(self.info, frame))

    def frame_jacobian(self, q, frame, reference="local_world_aligned", p=None) -> np.ndarray:
        """The frame's Jacobian, (6, nv) or (N, 6, nv): rows 0-2 map qd to the linear
        velocity, rows 3-5 to the angular velocity, in `reference` (Pinocchio's):
        "local_world_aligned" (the velocity of the frame's origin, world axes), "local"
        (the same in the frame's axes) or "world" (the velocity of the point of the frame's
        body at the world's origin, world axes). A list of frames gives their Jacobians,
        (k, 6, nv) or (N, k, 6, nv), their common ancestors placed once."""
        from .taskspace import jacobian, reference_code

        code = reference_code(reference)
        X, F, _ = self._frame_data(q, p)
        if isinstance(frame, (list, tuple)):
            indices = frame_indices(self.info, frame)
            if not indices:
                return np.zeros(X.shape[:-1] + (0, 6, self.nv))
            return np.stack([jacobian(self.info, X, F, k, self.nv, code) for k in indices],
                            axis=-3)
        return jacobian(self.info, X, F, frame_index(self.info, frame), self.nv, code)

    def frame_velocity(self, q, qd, frame, reference="local_world_aligned", p=None
                       ) -> np.ndarray:
        """The frame's velocity, (6,) or (N, 6): linear, then angular, in `reference` (as
        frame_jacobian's; = frame_jacobian(q, frame, reference) @ qd)."""
        from .taskspace import reference_code, velocity

        code = reference_code(reference)
        (q, qd), _ = as_states(self._sizes[:2], q, qd, names=("q", "qd"))
        X, F, _ = self._frame_data(q, p)
        return velocity(self.info, X, F, frame_index(self.info, frame), qd, code)

    def _frame_data(self, q, p):
        """(placements X, frame offsets F, stacked?) at q (see gagen.runtime.frames)."""
        (q,), stacked = as_states(self.nq, q, names=("q",))
        return self._placements(q, p), self._frame_offsets(p), stacked

    def _placements(self, q, p) -> np.ndarray:
        raise NotImplementedError

    def _frame_offsets(self, p) -> np.ndarray:
        raise NotImplementedError

    # --- task space: accelerations, Jacobians' time variation, operational-space inertia
    # (gagen.runtime.taskspace has the conventions and the recursion) -----------------------

    def frame_acceleration(self, q, qd, qdd, frame, reference="local_world_aligned",
                           kind="classical", p=None) -> np.ndarray:
        """The frame's acceleration at (q, qd, qdd), (6,) or (N, 6), linear then angular, in
        `reference` (as frame_jacobian's). kind="classical": the acceleration of the point
        of the frame's body at the reference's origin (Pinocchio's
        getFrameClassicalAcceleration; in "local_world_aligned", the frame origin's
        acceleration in world axes); kind="spatial": the rate of the velocity's components
        in that reference (getFrameAcceleration). Both are J qdd + frame_bias_acceleration."""
        from .taskspace import acceleration, kind_code, reference_code

        codes = reference_code(reference), kind_code(kind)
        (q, qd, qdd), _ = as_states(self._sizes, q, qd, qdd, names=("q", "qd", "qdd"))
        X, F, _ = self._frame_data(q, p)
        return acceleration(self.info, X, F, frame_index(self.info, frame), qd, qdd, *codes)

    def frame_bias_acceleration(self, q, qd, frame, reference="local_world_aligned",
                                kind="classical", p=None) -> np.ndarray:
        """frame_acceleration at qdd = 0, (6,) or (N, 6): the drift of a task, J̇ qd in the
        convention of `kind` (with kind="classical", the frame origin's acceleration that
        the velocities alone cause)."""
        from .taskspace import acceleration, kind_code, reference_code

        codes = reference_code(reference), kind_code(kind)
        (q, qd), _ = as_states(self._sizes[:2], q, qd, names=("q", "qd"))
        X, F, _ = self._frame_data(q, p)
        return acceleration(self.info, X, F, frame_index(self.info, frame), qd, None, *codes)

    def frame_jacobian_time_variation(self, q, qd, frame, reference="local_world_aligned",
                                      p=None) -> np.ndarray:
        """J̇ = dJ/dt of frame_jacobian(q, frame, reference) along qd, (6, nv) or (N, 6, nv):
        Pinocchio's getFrameJacobianTimeVariation. J̇ qd is the spatial acceleration at
        qdd = 0 in "local" and "world", the classical one in "local_world_aligned"."""
        from .taskspace import jacobian_time_variation, reference_code

        code = reference_code(reference)
        (q, qd), _ = as_states(self._sizes[:2], q, qd, names=("q", "qd"))
        X, F, _ = self._frame_data(q, p)
        return jacobian_time_variation(self.info, X, F, frame_index(self.info, frame), qd,
                                       self.nv, code)

    def delassus(self, q, frames, dims=6, p=None) -> np.ndarray:
        """G = J M⁻¹ Jᵀ, (m, m) or (N, m, m), of the frames' stacked LOCAL_WORLD_ALIGNED
        Jacobian rows (each frame's 6, or with dims=3 its linear 3; m = dims · frames): the
        Delassus matrix of contacts at those frames. From M's factors; M is never inverted.
        `frames` is one frame or a list. Raises as forward_dynamics for a singular M."""
        from .taskspace import delassus

        return delassus(self, q, frames, dims, p)

    def operational_space_inertia(self, q, frames, dims=6, p=None) -> np.ndarray:
        """Λ = (J M⁻¹ Jᵀ)⁻¹, (m, m) or (N, m, m), for the rows of `delassus(q, frames, dims)`:
        the inertia the frames' tasks see (F = Λ ẍ + ...). SingularTaskError, naming the
        frames, when the rows are dependent (a singular configuration, a frame welded to the
        world, more rows than coordinates, or rows constraining the same motion)."""
        from .taskspace import operational_space_inertia

        return operational_space_inertia(self, q, frames, dims, p)

    def external_forces(self, q, fext, p=None) -> np.ndarray:
        """The generalised force, (nv,) or (N, nv), of external wrenches fext = {frame: w},
        w = (fx, fy, fz, tx, ty, tz) in world axes at the frame's origin ((6,) or one row
        per stacked state): sum of J_frame^T w. forward_dynamics and inverse_dynamics take
        `fext=` and add or subtract it."""
        from .frames import external_wrenches, generalized_forces

        X, F, stacked = self._frame_data(q, p)
        wrenches = external_wrenches(self.info, fext, X.shape[0] if stacked else None)
        return generalized_forces(self.info, X, F, wrenches, self.nv)

    # --- centre of mass and centroidal dynamics (gagen.runtime.centroidal) ------------------
    # Pinocchio's conventions (centerOfMass, ccrba, dccrba): 6-vectors and the rows of 6 x nv
    # matrices are linear then angular, in world axes, about the centre of mass. The compiled
    # backend binds its C kernels (centroidal.c) in their place.

    def center_of_mass(self, q, p=None) -> np.ndarray:
        """The centre of mass in the world: (3,), or (N, 3) for stacked q. The robot's mass
        is its moving bodies' (a body welded to the world is left out, as in Pinocchio)."""
        from . import centroidal

        X, pi = self._centroidal_data(q, None, p)
        return centroidal.center_of_mass(self.info, X, pi)

    def com_velocity(self, q, qd, p=None) -> np.ndarray:
        """The centre of mass's velocity in the world, (3,) or (N, 3): com_jacobian(q) @ qd."""
        from . import centroidal

        X, pi, qd = self._centroidal_data(q, qd, p)
        return centroidal.com_velocity(self.info, X, pi, qd)

    def com_jacobian(self, q, p=None) -> np.ndarray:
        """J_com, (3, nv) or (N, 3, nv): com_velocity = J_com qd; the first three rows of
        centroidal_map over the total mass (Pinocchio's jacobianCenterOfMass)."""
        from . import centroidal

        X, pi = self._centroidal_data(q, None, p)
        return centroidal.com_jacobian(self.info, X, pi, self.nv)

    def centroidal_map(self, q, p=None) -> np.ndarray:
        """A_g, the centroidal momentum matrix, (6, nv) or (N, 6, nv): h_g = A_g qd, at the
        centre of mass, world axes, linear rows first (Pinocchio's computeCentroidalMap)."""
        from . import centroidal

        X, pi = self._centroidal_data(q, None, p)
        return centroidal.centroidal_map(self.info, X, pi, self.nv)

    def centroidal_momentum(self, q, qd, p=None) -> np.ndarray:
        """h_g, (6,) or (N, 6): the robot's linear momentum, then its angular momentum about
        the centre of mass, world axes (Pinocchio's computeCentroidalMomentum)."""
        from . import centroidal

        X, pi, qd = self._centroidal_data(q, qd, p)
        return centroidal.centroidal_momentum(self.info, X, pi, qd)

    def centroidal_map_time_variation(self, q, qd, p=None) -> np.ndarray:
        """d/dt A_g, (6, nv) or (N, 6, nv), along the velocity qd (Pinocchio's
        computeCentroidalMapTimeVariation and dccrba's dAg)."""
        from . import centroidal

        X, pi, qd = self._centroidal_data(q, qd, p)
        return centroidal.centroidal_map_time_variation(self.info, X, pi, qd, self.nv)

    def centroidal_bias(self, q, qd, p=None) -> np.ndarray:
        """d/dt A_g qd, (6,) or (N, 6): the rate of h_g at qdd = 0, so that d/dt h_g =
        A_g qdd + centroidal_bias; by Newton and Euler, d/dt h_g is also m g plus the
        external wrenches about the centre of mass (Pinocchio's dccrba's dAg @ v)."""
        from . import centroidal

        X, pi, qd = self._centroidal_data(q, qd, p)
        return centroidal.centroidal_bias(self.info, X, pi, qd)

    def _centroidal_data(self, q, qd, p):
        """The placements and the regressor's parameters at q (and qd checked with it)."""
        if qd is None:
            (q,), _ = as_states(self.nq, q, names=("q",))
            return self._placements(q, p), self.regressor_parameters(p)
        (q, qd), _ = as_states(self._sizes[:2], q, qd, names=("q", "qd"))
        return self._placements(q, p), self.regressor_parameters(p), qd

    # --- the dynamics (each backend implements these) --------------------------------------

    def mass_matrix(self, q, p=None) -> np.ndarray:
        """M(q): shape (n, n), or (N, n, n) for stacked q. Symmetric positive definite."""
        raise NotImplementedError

    def forcing(self, q, qd, tau, p=None) -> np.ndarray:
        """F(q, q̇, τ) such that M(q) q̈ = F: shape (n,) or (N, n)."""
        raise NotImplementedError

    def forward_dynamics(self, q, qd, tau, p=None, fext=None) -> np.ndarray:
        """q̈ = M(q)⁻¹ F(q, q̇, τ): shape (n,) or (N, n).

        `fext` = {frame: w} adds external wrenches w = (force, torque) in world axes at the
        frames' origins (a foot's contact, a payload): τ + Σ J_frameᵀ w (`external_forces`).
        Raises SingularMassMatrixError when M(q) is not positive definite (zero or negative
        masses or inertias), NonFiniteStateError when q holds NaN or inf."""
        raise NotImplementedError

    def inverse_dynamics(self, q, qd, qdd, p=None, fext=None) -> np.ndarray:
        """The joint torques (forces for prismatic joints) τ that give q̈: shape (n,) or
        (N, n). With `fext` = {frame: w} (as in forward_dynamics) the torques that give q̈
        while those wrenches act: τ − Σ J_frameᵀ w."""
        raise NotImplementedError

    def gravity(self, q, p=None) -> np.ndarray:
        """The gravity torques g(q) = inverse_dynamics(q, 0, 0): shape (n,) or (N, n)."""
        raise NotImplementedError

    def energy(self, q, qd, p=None):
        """(kinetic, potential): floats, or arrays of shape (N,) for stacked states."""
        raise NotImplementedError

    # --- derivatives (how they are derived and composed: gagen.symbolic.derivatives) -------

    def inverse_dynamics_derivatives(self, q, qd, qdd, p=None) -> tuple:
        """(∂τ/∂q, ∂τ/∂q̇) of τ = inverse_dynamics(q, q̇, q̈): each (n, n), or (N, n, n) for
        stacked states; entry [i, j] is ∂τ_i/∂q_j. (∂τ/∂q̈ is `mass_matrix(q)`.)"""
        raise NotImplementedError

    def forward_dynamics_derivatives(self, q, qd, tau, p=None) -> tuple:
        """(∂q̈/∂q, ∂q̈/∂q̇, ∂q̈/∂τ) of q̈ = forward_dynamics(q, q̇, τ): each (n, n), or
        (N, n, n) for stacked states. ∂q̈/∂τ is M(q)⁻¹, and ∂q̈/∂x = −M⁻¹ ∂τ/∂x at
        q̈ = forward_dynamics(q, q̇, τ). Raises as `forward_dynamics` does."""
        raise NotImplementedError

    def coriolis_matrix(self, q, qd, p=None) -> np.ndarray:
        """C(q, q̇) from the Christoffel symbols of the first kind of M: shape (n, n), or
        (N, n, n) for stacked states. C q̇ is the velocity terms of the equations of motion
        (`inverse_dynamics(q, q̇, 0) - gravity(q)` less the joints' damping and friction)
        and Ṁ − 2C is skew-symmetric."""
        raise NotImplementedError

    def linearize(self, q, qd, tau, p=None) -> tuple:
        """(A, B) of ẋ = f(x, u) at x = (q, q̇), u = τ: A = ∂f/∂x of shape (2n, 2n),
        B = ∂f/∂u of shape (2n, n), or (N, 2n, 2n) and (N, 2n, n) for stacked states.

        A = [[0, I], [∂q̈/∂q, ∂q̈/∂q̇]] and B = [[0], [M⁻¹]], from
        `forward_dynamics_derivatives`."""
        dqdd_dq, dqdd_dqd, dqdd_dtau = self.forward_dynamics_derivatives(q, qd, tau, p)
        n, lead = self.n, dqdd_dq.shape[:-2]
        A = np.zeros(lead + (2 * n, 2 * n))
        A[..., :n, n:] = np.eye(n)
        A[..., n:, :n] = dqdd_dq
        A[..., n:, n:] = dqdd_dqd
        B = np.zeros(lead + (2 * n, n))
        B[..., n:, :] = dqdd_dtau
        return A, B
    # --- the regressor: tau = Y(q, q̇, q̈) π -------------------------------------------------

    def regressor(self, q, qd, qdd, p=None) -> np.ndarray:
        """Y(q, q̇, q̈) with `inverse_dynamics(q, qd, qdd, p) == Y @ regressor_parameters(p)`:
        shape (n, P), or (N, n, P) for stacked states. Its columns (`regressor_names`) are
        each moving body's 10 inertial parameters about its frame's origin, in Pinocchio's
        order (m, m cx, m cy, m cz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz), then damping, friction and
        armature per joint. Y depends on `p` only through the kinematic parameters (lengths,
        gravity); columns of friction hold sign(q̇) (0 at q̇ = 0)."""
        raise NotImplementedError

    def regressor_parameters(self, p=None) -> np.ndarray:
        """π, shape (P,): the dynamic parameters at `p` (fixed bodies merged into their
        moving parent, inertias moved to the frame's origin by the parallel-axes theorem)."""
        raise NotImplementedError

    @property
    def regressor_names(self) -> list[str]:
        """The names of the regressor's P columns: `m_<body>`, `mcx_<body>`, `mcy_<body>`,
        `mcz_<body>`, `IOxx_<body>`, `IOxy_<body>`, `IOyy_<body>`, `IOxz_<body>`,
        `IOyz_<body>`, `IOzz_<body>` per moving body (IO: about the frame's origin O), then
        `damping_<joint>`, `friction_<joint>`, `armature_<joint>` for every joint."""
        return self.info.regressor_names

    def joint_terms(self, p=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(damping, friction, armature) at `p`, each of shape (n,): per velocity
        coordinate, 0 for a floating joint's (from `regressor_parameters`)."""
        pi = self.regressor_parameters(p)
        where = self.info.jointed_coordinates()
        m = len(where)
        out = []
        for k in range(3):
            values = np.zeros(self.n)
            values[where] = pi[len(pi) - (3 - k) * m:len(pi) - (2 - k) * m]
            out.append(values)
        return tuple(out)

    # --- base parameters: tau = Y_b π_b (gagen.ident.base) -----------------------------------

    def base_grouping(self, p=None):
        """The base parameters of the regressor at the kinematic parameters of `p`: a
        `gagen.ident.BaseParameters` with their `names`, the `independent` columns of Y that
        Y_b keeps, the matrix K (r x P) of π_b = K π, and `text()`, the regrouping written out.
        Computed numerically once per parameter vector (QR over the regressor at random
        states, gagen.ident.base) and kept."""
        pv = self.parameter_vector(p)
        cache = self.__dict__.setdefault("_base_groupings", {})
        key = pv.tobytes()
        if key not in cache:
            from ..ident.base import base_parameters

            if len(cache) >= 16:
                cache.pop(next(iter(cache)))
            cache[key] = base_parameters(self, pv)
        return cache[key]

    def base_regressor(self, q, qd, qdd, p=None) -> np.ndarray:
        """Y_b(q, q̇, q̈), the regressor's independent columns: shape (n, r), or (N, n, r) for
        stacked states, with `base_regressor(...) @ base_parameters(p) == inverse_dynamics(...)`
        and r the rank of the regressor (`base_grouping`)."""
        # np.take: 3x faster than fancy indexing along the last axis
        return np.take(self.regressor(q, qd, qdd, p), self.base_grouping(p).independent,
                       axis=-1)

    def base_parameters(self, p=None) -> np.ndarray:
        """π_b = K π at `p`, shape (r,): the combinations of the dynamic parameters that the
        torques determine (names and combinations: `base_grouping(p)`)."""
        return self.base_grouping(p).matrix @ self.regressor_parameters(p)


# The name of earlier versions, kept for code that imported it.
DynamicsInfo = Dynamics
