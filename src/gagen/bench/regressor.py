"""The regressor and identification on the Panda: gagen against Pinocchio.

- per call: `dyn.regressor(q, qd, qdd)` (compiled) against
  `pinocchio.computeJointTorqueRegressor`, checked first to agree on the body columns
  (gagen's regressor has the 3 n joint columns on top);
- identification from `SAMPLES` samples of an exciting trajectory with noisy torques:
  `gagen.identify` (base regressor, QR, standard deviations) against what a Pinocchio user
  writes: the regressor in a Python loop over the samples, stacked, and
  `numpy.linalg.lstsq` (its minimum-norm solution: Pinocchio has no base parameters);
  and, once per model and parameter vector, gagen's base grouping (`dyn.base_grouping`,
  QR over the regressor at random states).

All interleaved (gagen.bench.timing); ratios to gagen.
"""

from __future__ import annotations

import numpy as np

from . import peers
from .common import optional
from .percall import GAGEN, rows_from
from .timing import Candidate, interleaved

SAMPLES = 10_000


def _state(dyn, seed: int = 0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.0, 1.0, (3, dyn.n))


def regressor_rows(dyn, urdf, repeats: int, target: float) -> list[dict]:
    """Per call: gagen compiled's regressor against Pinocchio's (without Pinocchio, gagen
    only, no ratios)."""
    q, qd, qdd = _state(dyn)
    cands = [Candidate(f"regressor / {GAGEN}", dyn.regressor, (q, qd, qdd), group="regressor",
                       info={"quantity": "regressor", "implementation": GAGEN,
                             "call": "dyn.regressor(q, qd, qdd)"})]
    pm = peers.pinocchio_from_urdf(dyn, urdf)
    if pm is not None:
        pin = optional("pinocchio")
        data = pm.createData()
        args = (pm, data, *peers.to_pinocchio(pm, q, qd, qdd))
        theirs = np.array(pin.computeJointTorqueRegressor(*args))
        ours = dyn.regressor(q, qd, qdd)[:, :10 * dyn.n]
        peers._agree("gagen's and Pinocchio's regressors", ours, _in_gagen_order(pm, theirs),
                     rtol=1e-9)
        cands.append(Candidate("regressor / Pinocchio", pin.computeJointTorqueRegressor, args,
                               group="regressor",
                               info={"quantity": "regressor", "implementation": "Pinocchio",
                                     "call": "pinocchio.computeJointTorqueRegressor(model, "
                                             "data, q, qd, qdd)"}))
    timings = interleaved(cands, repeats, target,
                          baseline={"regressor": f"regressor / {GAGEN}"})
    return rows_from(timings, GAGEN)


def _in_gagen_order(pm, Y: np.ndarray) -> np.ndarray:
    """Pinocchio's regressor with rows and 10-column blocks in gagen's coordinate order."""
    order = np.empty(pm.nv, dtype=int)
    order[pm.gagen_order] = np.arange(pm.nv)  # Pinocchio's index of gagen's coordinate k
    blocks = np.hstack([Y[:, 10 * j:10 * (j + 1)] for j in order])
    return blocks[order]


def identification_data(dyn, samples: int = SAMPLES, seed: int = 1):
    """q, qd, qdd along a random Fourier trajectory of the Panda, and torques with 1 %
    noise, `samples` of them over 100 s."""
    from ..ident import FourierTrajectory

    rng = np.random.default_rng(seed)
    trajectory = FourierTrajectory.random(dyn.n, rng, 0.8, frequency=0.1)
    q, qd, qdd = trajectory(np.linspace(0.0, 100.0, samples))
    tau = dyn.inverse_dynamics(q, qd, qdd)
    scale = 0.01 * np.maximum(np.abs(tau).max(axis=0), 1.0)
    return q, qd, qdd, tau + rng.normal(size=tau.shape) * scale


def identification_rows(dyn, urdf, repeats: int, samples: int = SAMPLES) -> list[dict]:
    """Seconds to identify from `samples` samples (module docstring)."""
    from ..ident import identify
    from ..ident.base import base_parameters

    q, qd, qdd, tau = identification_data(dyn, samples)
    dyn.base_grouping()  # identify's share is the least squares; the grouping is timed alone
    cands = [
        Candidate(f"identify / {GAGEN}", identify, (dyn, q, qd, qdd, tau), group="identify",
                  info={"task": f"identify from {samples:,} samples",
                        "implementation": GAGEN,
                        "call": "gagen.identify(dyn, q, qd, qdd, tau)"}),
        Candidate(f"grouping / {GAGEN}", base_parameters, (dyn,), group="grouping",
                  info={"task": "base grouping (once per model)", "implementation": GAGEN,
                        "call": "dyn.base_grouping()  # first call"}),
    ]
    pm = peers.pinocchio_from_urdf(dyn, urdf)
    if pm is not None:
        pin = optional("pinocchio")
        data = pm.createData()
        states = [peers.to_pinocchio(pm, *x) for x in zip(q, qd, qdd)]
        taus = np.concatenate([peers.to_pinocchio(pm, t)[0] for t in tau])

        def pinocchio_identify():
            Y = np.vstack([pin.computeJointTorqueRegressor(pm, data, *s) for s in states])
            return np.linalg.lstsq(Y, taus, rcond=None)[0]

        cands.append(Candidate("identify / Pinocchio", pinocchio_identify, (),
                               group="identify",
                               info={"task": f"identify from {samples:,} samples",
                                     "implementation": "Pinocchio + NumPy",
                                     "call": "computeJointTorqueRegressor per sample, "
                                             "numpy.linalg.lstsq"}))
    timings = interleaved(cands, repeats, target=0.0, numbers=[1] * len(cands),
                          baseline={"identify": f"identify / {GAGEN}"})
    return [{"task": t.info["task"], "implementation": t.info["implementation"],
             "call": t.info["call"], "median_s": t.median, "q1_s": t.q1, "q3_s": t.q3,
             "ratio": t.ratio, "repeats": len(t.samples), "samples_s": list(t.samples)}
            for t in timings]
