"""The constraints section's derivatives rows: ANYmal C on four 3-D point contacts,
`dyn.constrained_forward_dynamics_derivatives(q, qd, tau)` against Pinocchio's
`constraintDynamics` then `computeConstraintDynamicsDerivatives` (the derivatives need
the forward pass at the same state; gagen's call does both too), checked equal (1e-9)
before anything is timed. A third gagen row times the unconstrained inverse dynamics
derivatives at the solution alone, the part of gagen's call that issue 27's faster
floating-base derivatives change.
"""

from __future__ import annotations

import numpy as np

from .common import optional
from .percall import GAGEN
from .timing import Candidate

QUANTITY = "derivatives"
PART = "ID derivatives (part)"
GOAL = 1.5  # Pinocchio's time over gagen's


def _candidate(quantity: str, implementation: str, call: str, fn, args) -> Candidate:
    return Candidate(f"{quantity} / {implementation}", fn, tuple(args), group=quantity,
                     info={"quantity": quantity, "implementation": implementation,
                           "call": call})


def gagen_candidates(dyn, q, qd, tau) -> list[Candidate]:
    """gagen's derivatives call, and the inverse dynamics derivatives it makes."""
    qdd, _ = dyn.constrained_forward_dynamics(q, qd, tau)
    return [
        _candidate(QUANTITY, GAGEN, "dyn.constrained_forward_dynamics_derivatives(q, qd, tau)",
                   dyn.constrained_forward_dynamics_derivatives, (q, qd, tau)),
        _candidate(PART, GAGEN, "dyn.inverse_dynamics_derivatives(q, qd, qdd) at the "
                   "constrained solution (inside the call above)",
                   dyn.inverse_dynamics_derivatives, (q, qd, qdd)),
    ]


def pinocchio_candidate(dyn, model, data, pq, pv, ptau, models, datas, settings, v_order,
                        q, qd, tau) -> list[Candidate]:
    """Pinocchio's forward pass and derivatives, checked against gagen's first."""
    pin = optional("pinocchio")
    if pin is None:
        return []

    def derivatives(model, data, q, v, tau, models, datas, settings):
        pin.constraintDynamics(model, data, q, v, tau, models, datas, settings)
        pin.computeConstraintDynamicsDerivatives(model, data, models, datas, settings)
        return data.ddq_dq

    derivatives(model, data, pq, pv, ptau, models, datas, settings)
    ours = dyn.constrained_forward_dynamics_derivatives(q, qd, tau)
    theirs = (data.ddq_dq, data.ddq_dv, data.ddq_dtau)
    for x, y in zip(ours[:3], theirs):
        y = np.asarray(y)[np.ix_(v_order, v_order)]
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-9 * np.abs(y).max())
    for x, y in zip(ours[3:], (data.dlambda_dq, data.dlambda_dv, data.dlambda_dtau)):
        y = np.asarray(y)[:, v_order]
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-9 * np.abs(y).max())
    return [_candidate(QUANTITY, "Pinocchio",
                       "constraintDynamics(...); computeConstraintDynamicsDerivatives(model, "
                       "data, contacts, datas, settings)",
                       derivatives, (model, data, pq, pv, ptau, models, datas, settings))]


def goal_notes(rows: list[dict]) -> list[str]:
    """The goal's line: Pinocchio's derivatives time over gagen's, and the ID part."""
    ratio = [r["ratio"] for r in rows
             if r["quantity"] == QUANTITY and r["implementation"] == "Pinocchio"]
    if not ratio:
        return []
    part = [r for r in rows if r["quantity"] == PART]
    whole = [r for r in rows if r["quantity"] == QUANTITY and r["implementation"] == GAGEN]
    share = ""
    if part and whole:
        share = (f"; its inverse dynamics derivatives {part[0]['median_us']:.1f} us of "
                 f"{whole[0]['median_us']:.1f} us")
    return [(f"Goal: constrained forward dynamics derivatives of ANYmal C on four 3-D "
             f"contacts at least {GOAL}x faster than Pinocchio's constraintDynamics + "
             f"computeConstraintDynamicsDerivatives per call: "
             f"{'met' if ratio[0] >= GOAL else 'NOT met'} ({ratio[0]:.2f}x){share}.")]
