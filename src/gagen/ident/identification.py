"""Identification: the base parameters that best explain measured torques.

    minimise  sum over samples s and joints k of  w_sk (tau_sk - Y_b(q_s, qd_s, qdd_s)_k . pi_b)^2

is ordinary (weighted) least squares on the stacked base regressor A, which has full
column rank by construction (gagen.ident.base). It is accumulated over chunks of samples,
so that memory stays bounded (A of 10,000 Panda samples would take 55 MB), as the normal
equations: the Gram matrix A^T W A with its columns scaled to a unit diagonal, solved by
Cholesky. That squares A's condition number, so when the scaled A's passes
`QR_CONDITION` (1e5: more than 10 of 16 digits would be lost) the problem is solved again
by Householder QR of the chunks (TSQR), stable at any conditioning; on the Panda the Gram
matrix takes 0.1 s for 10,000 samples where QR takes 0.7-2 s. The residuals come from a
second pass over the samples.

Statistics, as in Gautier's and Swevers' identification papers: with m weighted rows and
r parameters, sigma^2 = sum w e^2 / (m - r) estimates the variance of a unit-weight
residual, the covariance of pi_b is sigma^2 (Y_b^T W Y_b)^-1, and the standard deviations
are the square roots of its diagonal. They assume the residuals independent and the
weights right (w_k = 1 / noise variance of joint k makes sigma^2 about 1).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .base import BaseParameters

CHUNK = 4096  # samples per update of the Gram matrix (or the QR)
QR_CONDITION = 1e5


@dataclass
class IdentificationResult:
    """What `identify` found.

    names, expressions  each base parameter's name and the combination of the regressor's
                        parameters it stands for (gagen.ident.BaseParameters)
    values, std         the estimates and their standard deviations (module docstring)
    covariance          (r, r), the estimates' covariance
    residual            (N, n): tau - Y_b values, per sample and joint
    rms                 (n,): the residual's root mean square per joint
    sigma               the weighted residual's standard deviation (1 for exact weights)
    condition           the condition number of the column-scaled base regressor: small
                        (below a few hundred) when the trajectory excites every parameter
    grouping            the BaseParameters (`grouping.text()` prints the regrouping)
    p                   the parameter vector whose kinematic parameters were used
    """

    names: list[str]
    expressions: list[str]
    values: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    residual: np.ndarray
    rms: np.ndarray
    sigma: float
    condition: float
    grouping: BaseParameters
    p: np.ndarray
    coordinates: list[str] = field(default_factory=list)
    dyn: object = field(default=None, repr=False)
    # A^T W A of the weighted base regressor (the Fisher information, up to sigma^2)
    information: np.ndarray | None = field(default=None, repr=False)

    @property
    def samples(self) -> int:
        return self.residual.shape[0]

    @property
    def relative_std(self) -> np.ndarray:
        """std / |value| in percent (inf for a value of 0)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.values != 0, 100.0 * self.std / np.abs(self.values), np.inf)

    def predict(self, q, qd, qdd) -> np.ndarray:
        """The torques of the identified robot: Y_b(q, qd, qdd) values, (n,) or (N, n)."""
        return self.dyn.base_regressor(q, qd, qdd, self.p) @ self.values

    def to_dict(self) -> dict:
        """Everything but the residuals and the dynamics, as JSON-ready data."""
        return {
            "coordinates": list(self.coordinates),
            "samples": self.samples,
            "sigma": self.sigma,
            "condition": self.condition,
            "rms": dict(zip(self.coordinates, self.rms.tolist())),
            "base_parameters": [
                {"name": n, "expression": e, "value": float(v), "std": float(s)}
                for n, e, v, s in zip(self.names, self.expressions, self.values, self.std)],
            "regressor_names": list(self.grouping.regressor_names),
            "grouping": self.grouping.matrix.tolist(),
            "covariance": self.covariance.tolist(),
        }

    def to_json(self, path) -> Path:
        """Write `to_dict()` as JSON."""
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=1) + "\n")
        return path

    def to_csv(self, path) -> Path:
        """One row per base parameter: name, value, std, relative std (%), expression (text
        cells escaped as spreadsheets expect: gagen.csvtext)."""
        import csv

        from ..csvtext import text_cell

        path = Path(path)
        with path.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(["name", "value", "std", "relative_std_percent", "expression"])
            for row in zip(self.names, self.values, self.std, self.relative_std,
                           self.expressions):
                writer.writerow([text_cell(row[0]), repr(float(row[1])), repr(float(row[2])),
                                 f"{float(row[3]):.4g}", text_cell(row[4])])
        return path

    def summary(self, digits: int = 6) -> str:
        """The estimates as a table, then the fit: residual RMS per joint, sigma, condition."""
        width = max(len(n) for n in self.names) if self.names else 4
        lines = [f"{'name':<{width}}  {'value':>13}  {'std':>10}  {'std %':>8}  expression"]
        for n, v, s, r, e in zip(self.names, self.values, self.std, self.relative_std,
                                 self.expressions):
            lines.append(f"{n:<{width}}  {v:>13.{digits}g}  {s:>10.3g}  {r:>8.3g}  {e}")
        rms = ", ".join(f"{c} {v:.3g}" for c, v in zip(self.coordinates, self.rms))
        lines += ["", (f"{self.samples} samples, {len(self.names)} base parameters; residual "
                  f"RMS per joint: {rms}"), (f"sigma {self.sigma:.4g}, condition number "
                  f"{self.condition:.4g}")]
        return "\n".join(lines)


def identify(dyn, q, qd, qdd, tau, weights=None, p=None,
             min_speed=0.0) -> IdentificationResult:
    """Identify the base parameters of `dyn` from measured motion and torques.

    q, qd, qdd, tau  (N, n) arrays: positions, velocities, accelerations and the measured
                     joint torques (forces for prismatic joints) of N samples.
    weights          None (all 1), one number, one per joint (n,), or one per sample and
                     joint (N, n); usually 1 / (noise variance of each joint's torque).
    p                the parameters whose kinematic part (lengths, gravity) the regressor
                     uses; the inertial and joint parameters in it play no role.
    min_speed        leave out (weight 0) each joint's torque at samples where that joint
                     moves slower than this (rad/s, m/s; one number, or one per joint). At
                     rest or creeping, Coulomb friction holds any torque within +-friction
                     (stiction, or a simulation's smooth sign), which friction * sign(qd)
                     cannot explain: real data need a threshold of a few hundredths, and
                     data simulated with `coulomb_width` w about 5 w.

    Returns an `IdentificationResult`: the base parameters with names and the combination
    each stands for (`dyn.base_grouping(p)`), standard deviations, residuals.
    Least squares on the base regressor (module docstring).
    """
    pv = dyn.parameter_vector(p)
    grouping = dyn.base_grouping(pv)
    q, qd, qdd, tau, w = checked_samples(dyn, q, qd, qdd, tau, weights, grouping.count,
                                         min_speed)
    r = grouping.count

    def weighted_blocks():
        """Per chunk: the weighted rows of A and of tau."""
        for rows in _chunks(len(q)):
            A = dyn.base_regressor(q[rows], qd[rows], qdd[rows], pv).reshape(-1, r)
            sw = np.sqrt(w[rows]).ravel()
            yield A * sw[:, None], tau[rows].ravel() * sw

    values, information, covariance_unit, condition = _normal_equations(weighted_blocks(), r)
    if condition > QR_CONDITION:
        values, information, covariance_unit, condition = _householder(weighted_blocks(), r)
    full = np.zeros(len(grouping.regressor_names))  # Y_b x = Y x with x scattered
    full[grouping.independent] = values
    residual = residuals(dyn, q, qd, qdd, tau, full, pv)
    sigma2 = float(np.sum(w * residual**2) / (np.count_nonzero(w) - r))
    covariance = sigma2 * covariance_unit
    return IdentificationResult(
        names=list(grouping.names), expressions=grouping.expressions(), values=values,
        std=np.sqrt(np.clip(np.diag(covariance), 0.0, None)), covariance=covariance,
        residual=residual, rms=np.sqrt(np.mean(residual**2, axis=0)), sigma=sigma2**0.5,
        condition=condition, grouping=grouping, p=pv, coordinates=list(dyn.coordinates),
        dyn=dyn, information=information)


def checked_samples(dyn, q, qd, qdd, tau, weights, unknowns: int, min_speed=0.0):
    """(q, qd, qdd, tau, weights) as (N, n) float arrays, with enough weighted rows; the
    weights are 0 where a joint is slower than min_speed."""
    q, qd, qdd, tau = (_samples(a, dyn.n, name) for a, name in
                       ((q, "q"), (qd, "qd"), (qdd, "qdd"), (tau, "tau")))
    count = q.shape[0]
    if not all(a.shape[0] == count for a in (qd, qdd, tau)):
        raise ValueError("q, qd, qdd and tau must have the same number of samples")
    w = _weights(weights, count, dyn.n)
    speed = np.asarray(min_speed, dtype=float)
    if speed.shape not in ((), (dyn.n,)) or not (np.isfinite(speed) & (speed >= 0)).all():
        raise ValueError(f"min_speed must be a number >= 0 or {dyn.n} of them, got {min_speed}")
    w = np.where(np.abs(qd) < speed, 0.0, w)
    if np.count_nonzero(w) <= unknowns:
        raise ValueError(f"{count} samples of {dyn.n} joints (with non-zero weight) cannot "
                         f"determine {unknowns} base parameters: more samples are needed")
    return q, qd, qdd, tau, w


def residuals(dyn, q, qd, qdd, tau, pi: np.ndarray, p: np.ndarray) -> np.ndarray:
    """tau - Y(q, qd, qdd) pi, (N, n), chunk by chunk."""
    out = np.empty_like(tau)
    for rows in _chunks(len(q)):
        out[rows] = tau[rows] - dyn.regressor(q[rows], qd[rows], qdd[rows], p) @ pi
    return out


def _samples(a, n: int, name: str) -> np.ndarray:
    arr = np.asarray(a, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != n:
        raise ValueError(f"{name} must have shape (N, {n}); got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} holds NaN or inf")
    return arr


def _weights(weights, count: int, n: int) -> np.ndarray:
    if weights is None:
        return np.ones((count, n))
    w = np.asarray(weights, dtype=float)
    if w.ndim == 0 or w.shape == (n,):
        w = np.broadcast_to(w, (count, n))
    if w.shape != (count, n):
        raise ValueError(f"weights must be a number, ({n},) or ({count}, {n}); got {w.shape}")
    if not (np.isfinite(w).all() and (w >= 0).all()):
        raise ValueError("weights must be finite and non-negative")
    return np.array(w)


def _chunks(count: int):
    return (slice(start, min(start + CHUNK, count)) for start in range(0, count, CHUNK))


def _normal_equations(blocks, r: int):
    """x, A^T A, (A^T A)^-1 and the condition number of A with unit-norm columns, from the
    Gram matrix of the blocks (A, b); inf for the condition when Cholesky fails."""
    from scipy.linalg import LinAlgError, cho_factor, cho_solve

    G, c = np.zeros((r, r)), np.zeros(r)
    for A, b in blocks:
        G += A.T @ A
        c += A.T @ b
    scale = _column_scale(np.sqrt(np.diag(G)))
    Gs = G / np.outer(scale, scale)
    eigenvalues = np.linalg.eigvalsh(Gs)
    failed = np.zeros(r), G, np.zeros((r, r)), np.inf
    if not eigenvalues[0] > 0:
        return failed
    try:
        factor = cho_factor(Gs)
    except LinAlgError:
        return failed
    x = cho_solve(factor, c / scale) / scale
    covariance = cho_solve(factor, np.eye(r)) / np.outer(scale, scale)
    return x, G, covariance, float(np.sqrt(eigenvalues[-1] / eigenvalues[0]))


def _householder(blocks, r: int):
    """The same by QR, R updated block by block: R of [R; A_k | b_k]."""
    from scipy.linalg import lapack, solve_triangular

    R_aug = np.zeros((0, r + 1))
    for A, b in blocks:
        stacked = np.vstack([R_aug, np.column_stack([A, b])])
        R_aug = np.triu(lapack.dgeqrf(stacked, overwrite_a=True)[0][: r + 1])
    R, z = R_aug[:r, :r], R_aug[:r, r]
    scale = _column_scale(np.linalg.norm(R, axis=0))
    Rs = R / scale
    x = solve_triangular(Rs, z) / scale
    Rinv = solve_triangular(Rs, np.eye(r)) / scale[:, None]
    return x, R.T @ R, Rinv @ Rinv.T, float(np.linalg.cond(Rs))


def _column_scale(norms: np.ndarray) -> np.ndarray:
    if not (norms > 0).all():
        raise ValueError("a base parameter is not excited by these samples (its regressor "
                         "column is zero): use a richer trajectory")
    return norms
