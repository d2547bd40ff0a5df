"""Feedback laws tau(t, q, qd) that run in Python (any backend) and in gagen's C integrator.

A controller is configured without a robot, then bound to one:

    ctrl = PD(kp=300, kd=150, target=[0.1, -0.2, 0.3], gravity_compensation=True)
    law = ctrl.bind(dyn, p)          # a bound copy; `ctrl` itself stays reusable
    tau = law(t, q, qd)              # (n,), or (m, n) for stacked times and states

`gagen.simulate` binds the controller it is given. Each controller also describes itself
to the compiled integrator (`c_spec()`: the keyword arguments of the extension's
`CompiledSimulation`), so with method "dopri5" or "rk4" the same law runs in C without
Python in the loop. Gains are scalars (the same for every joint) or per-joint arrays.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable

import numpy as np

from ..manifest import ModelInfo
from .trajectory import PAPER_QF, Eq11Trajectory

# C controller kinds (integrator.h: GAGEN_CTRL_*).
KIND_NONE = 0
KIND_PD = 1
KIND_COMPUTED_TORQUE = 2

# The paper's direct dynamics (Fig. 2, 3), see paper_controller().
PAPER_TARGET = PAPER_QF
PAPER_KP = (500.0, 300.0, 200.0)  # N m / rad
PAPER_KD = (300.0, 150.0, 100.0)  # N m s / rad

# Generic models (default_controller): closed-loop natural frequency and damping ratio.
DEFAULT_OMEGA = 4.0  # rad/s
DEFAULT_ZETA = 1.0
DEFAULT_ROTATION_TARGET = -math.pi / 6  # rad, every revolute or continuous joint
DEFAULT_SLIDE_TARGET = 0.05  # m, every prismatic joint


def _gains(value, name: str) -> np.ndarray:
    arr = np.array(value, dtype=float).ravel()
    if arr.size == 0 or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a finite number or a per-joint array, got {value!r}")
    arr.flags.writeable = False
    return arr


class Controller:
    """Base class: a feedback law bound to a dynamics object (see the module docstring)."""

    kind = KIND_NONE
    needs_dynamics = True

    def __init__(self):
        self._dyn = None
        self._p = None
        self._n = None

    # ---- binding
    def bind(self, dyn, p=None) -> Controller:
        """A copy bound to `dyn` and the parameters `p` (None, dict of overrides or array)."""
        bound = copy.copy(self)
        bound._dyn = dyn
        bound._p = dyn.parameter_vector(p)
        bound._n = dyn.n
        bound._check_size(dyn.n)
        return bound

    @property
    def bound(self) -> bool:
        return self._dyn is not None

    def _sized(self, arr: np.ndarray, n: int, name: str) -> np.ndarray:
        if arr.size == 1:
            return np.full(n, arr[0])
        if arr.size != n:
            raise ValueError(f"{type(self).__name__}: {name} has {arr.size} entries but the "
                             f"model has {n} coordinates")
        return arr

    def _check_size(self, n: int) -> None:
        raise NotImplementedError

    def _require_dynamics(self):
        if self._dyn is None:
            raise RuntimeError(f"{type(self).__name__} needs the robot's dynamics: call "
                               "controller.bind(dyn, p) first (gagen.simulate does it for you)")
        return self._dyn

    # ---- evaluation
    def __call__(self, t, q, qd) -> np.ndarray:
        raise NotImplementedError

    def c_spec(self, n: int) -> dict | None:
        """Keyword arguments of `CompiledSimulation` for this law, or None if it has no C form."""
        raise NotImplementedError


class PD(Controller):
    """Joint-space PD toward a fixed target, optionally with gravity compensation:

        tau = feedforward - kp (q - target) - kd qd  [+ g(q)],   g(q) = dyn.gravity(q)

    `kp`, `kd` and `target` are scalars or per-coordinate arrays (one entry per velocity
    coordinate). g(q) is the torque that holds the arm still at q, so with compensation the
    arm settles exactly at the target. `feedforward` is a constant torque added to the law
    (e.g. what holds a robot still while known wrenches act on it). A floating joint has no
    actuator: its torques are zero, whatever its entries of kp, kd, target and feedforward.
    """

    kind = KIND_PD

    def __init__(self, kp, kd, target=0.0, gravity_compensation: bool = False,
                 feedforward=0.0):
        super().__init__()
        self.kp = _gains(kp, "kp")
        self.kd = _gains(kd, "kd")
        self.target = _gains(target, "target")
        self.feedforward = _gains(feedforward, "feedforward")
        self.gravity_compensation = bool(gravity_compensation)
        self.needs_dynamics = self.gravity_compensation
        sizes = {a.size for a in (self.kp, self.kd, self.target, self.feedforward)} - {1}
        if len(sizes) > 1:
            raise ValueError(f"kp, kd, target and feedforward have different lengths: "
                             f"{self.kp.size}, {self.kd.size}, {self.target.size}, "
                             f"{self.feedforward.size}")

    def _check_size(self, n: int) -> None:
        self._kp_n = self._sized(self.kp, n, "kp")
        self._kd_n = self._sized(self.kd, n, "kd")
        self._target_n = self._sized(self.target, n, "target")
        self._ff_n = self._sized(self.feedforward, n, "feedforward")

    def __call__(self, t, q, qd) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        qd = np.asarray(qd, dtype=float)
        if self._n is not None:
            kp, kd, target, ff = self._kp_n, self._kd_n, self._target_n, self._ff_n
        else:
            n = qd.shape[-1]
            kp, kd = self._sized(self.kp, n, "kp"), self._sized(self.kd, n, "kd")
            target = self._sized(self.target, n, "target")
            ff = self._sized(self.feedforward, n, "feedforward")
        floating = self._dyn is not None and self._dyn.nq != self._dyn.nv
        if floating:
            # the error of each joint; a floating joint has no actuator (its torque is 0)
            from ..runtime.manifold import floating_velocities, plain_entries

            plain_q, plain_v = plain_entries(self._dyn.info)
            error = np.zeros(np.broadcast_shapes(qd.shape, target.shape))
            error[..., plain_v] = q[..., plain_q] - target[plain_v]
        else:
            error = q - target
        tau = ff - kp * error - kd * qd
        if self.gravity_compensation:
            tau += self._require_dynamics().gravity(q, self._p)
        if floating:
            tau[..., floating_velocities(self._dyn.info)] = 0.0
        return tau

    def c_spec(self, n: int) -> dict:
        return {"kind": KIND_PD, "kp": self._sized(self.kp, n, "kp"),
                "kd": self._sized(self.kd, n, "kd"),
                "target": self._sized(self.target, n, "target"),
                "gravity_compensation": self.gravity_compensation,
                "feedforward": self._sized(self.feedforward, n, "feedforward")}

    def __repr__(self) -> str:
        extra = "" if not np.any(self.feedforward) else \
            f", feedforward={self.feedforward.tolist()}"
        return (f"PD(kp={self.kp.tolist()}, kd={self.kd.tolist()}, "
                f"target={self.target.tolist()}, "
                f"gravity_compensation={self.gravity_compensation}{extra})")


class ComputedTorque(Controller):
    """Computed-torque tracking of a reference trajectory (inverse dynamics in the loop):

        tau = inverse_dynamics(q, qd, qdd_r + kd (qd_r - qd) + kp (q_r - q))

    `trajectory` maps t to (q_r, qd_r, qdd_r), e.g. an `Eq11Trajectory` (the paper's eq. 11,
    which also runs in C) or any callable of the same form (Python methods only). With exact
    dynamics the tracking error obeys e'' + kd e' + kp e = 0; the defaults kp = 100 1/s^2,
    kd = 20 1/s make that critically damped (double pole at -10 1/s). With kp = kd = 0 the
    controller replays the eq. 11 inverse-dynamics torques (evaluated at the actual state).
    """

    kind = KIND_COMPUTED_TORQUE

    def __init__(self, trajectory: Callable, kp=100.0, kd=20.0):
        super().__init__()
        if not callable(trajectory):
            raise TypeError("trajectory must be callable: t -> (q, qd, qdd), e.g. "
                            "gagen.Eq11Trajectory")
        self.trajectory = trajectory
        self.kp = _gains(kp, "kp")
        self.kd = _gains(kd, "kd")

    def _check_size(self, n: int) -> None:
        if self._dyn is not None and self._dyn.nq != self._dyn.nv:
            raise ValueError("ComputedTorque tracks a trajectory of every coordinate; a "
                             "floating joint has no actuator: use PD on the joints, or your "
                             "own controller with a scipy method")
        self._kp_n = self._sized(self.kp, n, "kp")
        self._kd_n = self._sized(self.kd, n, "kd")
        tn = getattr(self.trajectory, "n", None)
        if tn is not None and tn != n:
            raise ValueError(f"the trajectory has {tn} coordinates but the model has {n}")

    def __call__(self, t, q, qd) -> np.ndarray:
        dyn = self._require_dynamics()
        q = np.asarray(q, dtype=float)
        qd = np.asarray(qd, dtype=float)
        kp, kd = self._kp_n, self._kd_n
        qr, qdr, qddr = self.trajectory(t)
        v = qddr + kd * (qdr - qd) + kp * (qr - q)
        return dyn.inverse_dynamics(q, qd, v, self._p)

    def c_spec(self, n: int) -> dict | None:
        if not isinstance(self.trajectory, Eq11Trajectory):
            return None
        if self.trajectory.n != n:
            raise ValueError(f"the trajectory has {self.trajectory.n} coordinates but the "
                             f"model has {n}")
        return {"kind": KIND_COMPUTED_TORQUE, "kp": self._sized(self.kp, n, "kp"),
                "kd": self._sized(self.kd, n, "kd"), "traj_q0": self.trajectory.q0,
                "traj_qf": self.trajectory.qf, "traj_Tp": self.trajectory.Tp}

    def __repr__(self) -> str:
        return f"ComputedTorque({self.trajectory!r}, kp={self.kp.tolist()}, kd={self.kd.tolist()})"


def paper_controller() -> PD:
    """The feedback law of the paper's direct dynamics (Fig. 2 and Fig. 3) for `rrr`.

    The paper only says its law "is arbitrarily selected"; its authors' MATLAB examples
    use T = -Kd q' - Kp (q - qf) + (gravity compensation) with gains of a few hundred.
    gagen's defaults, with rrr's default links (60/50/40 kg, 0.4 m):

    - target qf = (-pi/3, -pi/3, -pi/6) rad = (-60, -60, -30) deg: the end values of
      q1, q2, q3 in Fig. 2 (and the final arm position of Fig. 3);
    - gravity compensation g(q) = inverse_dynamics(q, 0, 0): without it the arm would
      sag below the target under the 150 kg of links (Fig. 2 ends on the target);
    - kp = (500, 300, 200) N m/rad, kd = (300, 150, 100) N m s/rad (Fig. 2's time
      scale and shapes): joint 1 moves 30-62 kg m^2, joint 2 about 17, so kp1 > kp2 lets
      both reach 90 % of their travel together, at about 1.1 s, and settle within
      0.002 deg of the target well before 5 s, without overshoot. Joint 3 is coupled to
      joint 2 (M23/M22 = 0.3): with kp3/kp2 and kd3/kd2 at 2/3 its own torque outweighs
      the reaction of link 2's swing, so q3 too goes monotonically from 0 to -30 deg
      (with kp3 = 100 it first rises by 1.5 deg). Smooth, monotone curves (Fig. 2) and
      evenly converging arm positions (Fig. 3); the peak torques are 524, 317 and 69 N m.
      The closed loop is mildly stiff (joint 3's effective inertia is 0.5 kg m^2):
      RK45 takes about 300 steps for the 5 s at rtol = 1e-6.
    """
    return PD(kp=PAPER_KP, kd=PAPER_KD, target=PAPER_TARGET, gravity_compensation=True)


def is_paper_robot(model) -> bool:
    return model.name == "rrr" and model.dof == 3


def default_target(model) -> np.ndarray:
    """Target of the default direct dynamics (and qf of the default inverse dynamics).

    rrr: the paper's (-pi/3, -pi/3, -pi/6). Other models: -pi/6 rad (-30 deg) for every
    revolute or continuous joint and 0.05 m for every prismatic joint, clipped into the
    joint's limits when the model gives them (limits with lower >= upper, as in URDFs that
    write lower="0" upper="0" for "no limits", are ignored).
    """
    if is_paper_robot(model):
        return np.array(PAPER_TARGET)
    info = model if isinstance(model, ModelInfo) else ModelInfo.from_model(model)
    out = []
    for j in info.joints:
        if j.type == "floating":  # no actuator: its entries are not used
            out += [0.0] * 6
            continue
        value = DEFAULT_SLIDE_TARGET if j.type == "prismatic" else DEFAULT_ROTATION_TARGET
        lower, upper = (None, None) if j.type == "continuous" else (j.lower, j.upper)
        if not (lower is not None and upper is not None and lower >= upper):
            if lower is not None:
                value = max(value, lower)
            if upper is not None:
                value = min(value, upper)
        out.append(value)
    return np.array(out, dtype=float)


def default_controller(dyn, p=None) -> PD:
    """The controller of `python -m gagen simulate`: `paper_controller()` for rrr.

    Other models: PD toward `default_target(model)` with gravity compensation and per-joint
    gains kp_i = w^2 I_i and kd_i = 2 zeta w I_i with w = 4 rad/s and zeta = 1, where I_i is
    the largest M_ii(q) at q = 0, at the target and half-way: each joint is critically
    damped as if it moved alone with its largest inertia along the way (settling in about
    1.5 s), and over-damped, never oscillating, where its inertia is smaller.
    """
    if is_paper_robot(dyn.info):
        return paper_controller()
    from ..runtime.manifold import configuration_of

    target = default_target(dyn.info)
    samples = np.stack([configuration_of(dyn.info, k * target) for k in (0.0, 0.5, 1.0)])
    M = np.asarray(dyn.mass_matrix(samples, p))
    inertia = np.maximum(np.diagonal(M, axis1=1, axis2=2).max(axis=0), 1e-6)
    kp = DEFAULT_OMEGA ** 2 * inertia
    kd = 2.0 * DEFAULT_ZETA * DEFAULT_OMEGA * inertia
    return PD(kp=kp, kd=kd, target=target, gravity_compensation=True)
