"""Constrained dynamics per call: ANYmal C standing on four 3-D point contacts (its feet,
LOCAL_WORLD_ALIGNED), gagen's constrained forward dynamics and impulse dynamics against
Pinocchio's `constraintDynamics` and `impulseDynamics`.

Pinocchio's way, from Python, on its own URDF parse (FreeFlyer): four
`RigidConstraintModel(CONTACT_3D, ...)` of the feet against the world, their datas and
`initConstraintDynamics` made once, then per call `constraintDynamics(model, data, q, v,
tau, models, datas, settings)` with `ProximalSettings(1e-12, mu=0, 1 iteration)` (the exact
KKT solution, as gagen's), and `impulseDynamics(..., restitution=0, settings)`. The numbers
are checked equal (1e-9) before anything is timed; the ratios are Pinocchio's time over
gagen's (> 1: gagen is faster).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from . import constraint_derivatives as derivatives
from .common import optional
from .percall import GAGEN, _candidate, rows_from
from .timing import Candidate, interleaved

ROBOT = "anymal_c.urdf"
FEET = ("LF_FOOT", "RF_FOOT", "LH_FOOT", "RH_FOOT")
QUANTITIES = ("constrained FD", "impulse", derivatives.QUANTITY, derivatives.PART)
GOAL = 2.0  # Pinocchio's constraintDynamics time over gagen's



def constraints_rows(urdf_dir: Path, cache_dir: Path, repeats: int, target: float,
                     progress=None) -> list[dict]:
    """Rows of `percall.rows_from` for ANYmal C on its four feet; ratios to gagen."""
    import gagen

    path = Path(urdf_dir) / ROBOT
    if not path.exists():
        if progress:
            progress(f"{ROBOT} not found in {urdf_dir}: skipped")
        return []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        dyn = gagen.load(path, floating_base=True, cache_dir=cache_dir,
                         constraints=[gagen.Contact(foot) for foot in FEET])
    if progress:
        progress(f"{ROBOT}: nv {dyn.nv}, {len(FEET)} 3-D contacts built; timing")
    q, qd, tau = standing_state(dyn, np.random.default_rng(0))
    cands = [
        _candidate("constrained FD", GAGEN, "dyn.constrained_forward_dynamics(q, qd, tau)",
                   dyn.constrained_forward_dynamics, (q, qd, tau)),
        _candidate("impulse", GAGEN, "dyn.impulse_dynamics(q, qd)", dyn.impulse_dynamics,
                   (q, qd)),
    ] + derivatives.gagen_candidates(dyn, q, qd, tau)
    cands += _pinocchio(dyn, path, q, qd, tau)
    base = {quantity: f"{quantity} / {GAGEN}" for quantity in QUANTITIES}
    return rows_from(interleaved(cands, repeats, target, baseline=base), GAGEN)


def goal_notes(rows: list[dict]) -> list[str]:
    """The goal's line: Pinocchio's constraintDynamics time over gagen's."""
    ratios = [r["ratio"] for r in rows
              if r["quantity"] == "constrained FD" and r["implementation"] == "Pinocchio"]
    if not ratios:
        return []
    met = ratios[0] >= GOAL
    return [(f"Goal: constrained forward dynamics of ANYmal C on four 3-D contacts at least "
             f"{GOAL}x faster than Pinocchio's constraintDynamics per call: "
             f"{'met' if met else 'NOT met'} ({ratios[0]:.2f}x).")] \
        + derivatives.goal_notes(rows)


def standing_state(dyn, rng):
    """ANYmal near its standing posture, with random velocities and torques."""
    q = dyn.neutral()
    q[2] = 0.5
    posture = {"HAA": 0.0, "HFE": 0.6, "KFE": -1.0}
    for k, name in enumerate(dyn.configuration):
        for joint, angle in posture.items():
            if name.endswith(joint):
                front = name.startswith(("LF", "RF"))
                q[k] = (angle if front else -angle) + rng.normal(scale=0.05)
    return q, rng.normal(size=dyn.nv), rng.normal(size=dyn.nv) * 10


def _pinocchio(dyn, path: Path, q, qd, tau) -> list[Candidate]:
    pin = optional("pinocchio")
    if pin is None:
        return []
    model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    data = model.createData()
    ids = [model.getJointId(n) for n in dyn.coordinates[6:]]
    v_order = np.array([*range(6), *(model.idx_vs[j] for j in ids)])
    q_order = np.array([*range(7), *(model.idx_qs[j] for j in ids)])
    pq, pv, ptau = np.zeros(model.nq), np.zeros(model.nv), np.zeros(model.nv)
    pq[q_order], pv[v_order], ptau[v_order] = q, qd, tau
    models = pin.StdVec_RigidConstraintModel()
    for foot in FEET:
        frame = model.frames[model.getFrameId(foot)]
        models.append(pin.RigidConstraintModel(
            pin.ContactType.CONTACT_3D, model, frame.parentJoint, frame.placement, 0,
            pin.SE3.Identity(), pin.LOCAL_WORLD_ALIGNED))
    datas = pin.StdVec_RigidConstraintData()
    for m in models:
        datas.append(m.createData())
    pin.initConstraintDynamics(model, data, models, datas)
    settings = pin.ProximalSettings(1e-12, 0.0, 1)

    def forward(model, data, q, v, tau, models, datas, settings):
        return pin.constraintDynamics(model, data, q, v, tau, models, datas, settings)

    def impulse(model, data, q, v, models, datas, settings):
        return pin.impulseDynamics(model, data, q, v, models, datas, 0.0, settings)

    # the same numbers first
    qdd, forces = dyn.constrained_forward_dynamics(q, qd, tau)
    a = forward(model, data, pq, pv, ptau, models, datas, settings)
    np.testing.assert_allclose(a[v_order], qdd, rtol=1e-9, atol=1e-9 * np.abs(qdd).max())
    np.testing.assert_allclose(data.lambda_c, forces, rtol=1e-9,
                               atol=1e-9 * np.abs(forces).max())
    qd_plus, impulses = dyn.impulse_dynamics(q, qd)
    v_plus = impulse(model, data, pq, pv, models, datas, settings)
    np.testing.assert_allclose(v_plus[v_order], qd_plus, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(data.impulse_c, impulses, rtol=1e-9, atol=1e-9)
    return [
        _candidate("constrained FD", "Pinocchio",
                   "constraintDynamics(model, data, q, v, tau, contacts, datas, "
                   "ProximalSettings(1e-12, 0, 1))",
                   forward, (model, data, pq, pv, ptau, models, datas, settings)),
        _candidate("impulse", "Pinocchio",
                   "impulseDynamics(model, data, q, v, contacts, datas, 0, settings)",
                   impulse, (model, data, pq, pv, models, datas, settings)),
    ] + derivatives.pinocchio_candidate(dyn, model, data, pq, pv, ptau, models, datas,
                                        settings, v_order, q, qd, tau)
