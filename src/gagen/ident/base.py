"""Base parameters: the combinations of the dynamic parameters that the torques determine.

The regressor Y (n x P) has dependent columns: a body's mass may act only through its
parent's inertia terms, a first joint about the vertical moves no mass up, Ixx and Iyy of a
body on a revolute joint act only through their difference, and so on. The torques then
determine only r = rank Y combinations, the base parameters:

    tau = Y pi = Y_b pi_b,   Y_b = Y[:, independent],   pi_b = K pi   (K: r x P).

Computed numerically, as Gautier ("Numerical calculation of the base inertial parameters
of robots", 1991): the regressor at `STATES` random states (q uniform in [-pi, pi], a
floating joint's quaternion uniform on the sphere, qd and qdd standard normal; a fixed
seed, so the result is reproducible), stacked into W, each
column scaled to unit norm. Then

- rank: QR with column pivoting (scipy.linalg.qr); r = the number of |R_jj| above
  `TOLERANCE` * |R_00|, TOLERANCE = 1e-8. On unit-norm columns |R_jj| is about a column's
  distance from the span of the columns before it. Random states give independent columns
  a distance from the others' span of 1e-4 or more, dependent ones of 1e-14 or less, so the
  choice is clear-cut; at the edge, a weakly excited column 1e-6 from the others' span (the
  kept columns' smallest singular value about 1e-6 of their largest) is still a base
  parameter, and one 1e-12 from it is dependent (tests/test_identification.py);
- which columns: in the regressor's order (QR without pivoting, |R_jj| > TOLERANCE), so a
  parameter is grouped into earlier ones: a body's into its ancestors', Iyy into Ixx and
  Izz, an armature into its body's inertia. If that order does not give r columns, the
  pivoted choice is used;
- the grouping: K's dependent part by least squares, W_dep = W_ind beta, checked to hold to
  `CHECK` (relative); coefficients below `ZERO` (on the unit-norm columns) are set to 0,
  and those within 1e-12 (relative) of an integer to that integer.

Columns that are zero at every state (a parameter with no effect at all) belong to no base
parameter. The grouping depends on the kinematic parameters (lengths, gravity) at which it
is computed, never on the inertial ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STATES = 64  # at least; more when the regressor has many columns per coordinate
TOLERANCE = 1e-8
CHECK = 1e-8
ZERO = 1e-10
SEED = 20240601


@dataclass(frozen=True)
class BaseParameters:
    """The regrouping of a regressor's P parameters into r base parameters.

    `independent` are the regressor columns kept (Y_b = Y[:, independent]), `matrix` is K
    (r x P) with pi_b = K pi, and `names[i]` is the name of column independent[i] (the
    parameter each base parameter is grouped into); `expressions()` writes each as the
    combination it stands for.
    """

    names: list[str]
    independent: np.ndarray
    matrix: np.ndarray
    regressor_names: list[str]

    @property
    def count(self) -> int:
        """r, the number of base parameters (the rank of the regressor)."""
        return len(self.names)

    def expressions(self, digits: int = 6) -> list[str]:
        """Each base parameter as text, e.g. `IOzz_link1 + 0.16*m_link2 + armature_q1`."""
        return [_combination(row, self.regressor_names, digits) for row in self.matrix]

    def text(self, digits: int = 6) -> str:
        """The grouping, one base parameter a line: `name = combination`."""
        width = max((len(n) for n in self.names), default=0)
        return "\n".join(f"{name:<{width}} = {expr}"
                         for name, expr in zip(self.names, self.expressions(digits)))

    def __str__(self) -> str:
        return self.text()


def _combination(row: np.ndarray, names: list[str], digits: int) -> str:
    parts = []
    for j in np.flatnonzero(row):
        c = float(row[j])
        sign = "-" if c < 0 else "+"
        magnitude = abs(c)
        term = names[j] if magnitude == 1.0 else f"{magnitude:.{digits}g}*{names[j]}"
        parts.append((sign, term))
    if not parts:
        return "0"
    first_sign, first = parts[0]
    text = ("-" if first_sign == "-" else "") + first
    return text + "".join(f" {sign} {term}" for sign, term in parts[1:])


def _snapped(coefficients: np.ndarray) -> np.ndarray:
    """Coefficients within rounding (1e-12, relative) of an integer become that integer:
    the 1s and -1s of the grouping (Ixx - Iyy, inertia + armature) come out as 1 +- 1e-16."""
    nearest = np.round(coefficients)
    close = np.abs(coefficients - nearest) <= 1e-12 * np.maximum(1.0, np.abs(coefficients))
    return np.where(close, nearest, coefficients)


def random_states(info, count: int, seed: int = SEED) -> tuple[np.ndarray, ...]:
    """(q, qd, qdd) of a model (its `ModelInfo`): q (count, nq) uniform in [-pi, pi] with a
    random unit quaternion for each floating joint, rates (count, nv) standard normal."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-np.pi, np.pi, (count, info.nq))
    for iq, _ in info.floating_joints():
        quaternion = rng.normal(size=(count, 4))
        q[:, iq + 3:iq + 7] = quaternion / np.linalg.norm(quaternion, axis=1, keepdims=True)
    return q, rng.normal(size=(count, info.dof)), rng.normal(size=(count, info.dof))


def base_parameters(dyn, p=None) -> BaseParameters:
    """The base parameters of `dyn`'s regressor at the kinematic parameters of `p`."""
    n, names = dyn.n, dyn.regressor_names
    count = max(STATES, -(-4 * len(names) // n))
    W = dyn.regressor(*random_states(dyn.info, count), p).reshape(-1, len(names))
    return group_columns(W, names)


def group_columns(W: np.ndarray, names: list[str]) -> BaseParameters:
    """The base parameters of a stacked regressor W (rows: states x coordinates)."""
    from scipy.linalg import qr

    norms = np.linalg.norm(W, axis=0)
    active = np.flatnonzero(norms > TOLERANCE * norms.max()) if norms.max() > 0 else \
        np.array([], dtype=int)
    Wn = W[:, active] / norms[active]
    if active.size == 0:
        return BaseParameters([], np.array([], dtype=int), np.zeros((0, len(names))), names)
    _, R, pivots = qr(Wn, mode="economic", pivoting=True)
    diag = np.abs(np.diag(R))
    rank = int(np.count_nonzero(diag > TOLERANCE * diag[0]))
    R_natural = qr(Wn, mode="r")[0]
    kept = np.flatnonzero(np.abs(np.diag(R_natural)) > TOLERANCE)
    if kept.size != rank:
        kept = np.sort(pivots[:rank])
    dependent = np.setdiff1d(np.arange(active.size), kept)
    beta = np.linalg.lstsq(Wn[:, kept], Wn[:, dependent], rcond=None)[0]
    misfit = np.linalg.norm(Wn[:, kept] @ beta - Wn[:, dependent], axis=0) if dependent.size \
        else np.zeros(0)
    if misfit.size and misfit.max() > CHECK:
        raise RuntimeError(f"the regressor's columns do not regroup exactly (misfit "
                           f"{misfit.max():.2g}); its rank is not clear at these states")
    beta[np.abs(beta) < ZERO] = 0.0
    K = np.zeros((rank, len(names)))
    independent = active[kept]
    K[np.arange(rank), independent] = 1.0
    # beta acts on unit-norm columns: pi_b,i = pi_i + sum_j beta_ij |W_j| / |W_i| pi_j
    K[:, active[dependent]] = _snapped(beta * norms[active[dependent]]
                                       / norms[independent][:, None])
    return BaseParameters([names[j] for j in independent], independent, K, list(names))
