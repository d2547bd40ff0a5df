"""Exciting trajectories for identification: finite Fourier series (Swevers et al.,
"Optimal robot excitation and identification", IEEE T-RA 1997).

Each joint follows

    q_k(t) = c_k + sum_{l=1..L} a_kl sin(l w t) + b_kl cos(l w t),   w = 2 pi f,

periodic with period 1/f, so that measurements can be averaged over periods and the
derivatives are exact. Random coefficients, scaled so that each joint stays within
`c_k +- amplitude_k`, excite every parameter in practice; an optimised trajectory
(minimum condition number of the base regressor) would do better, and can be given as
coefficients.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FourierTrajectory:
    """q, q̇, q̈ of a finite Fourier series per joint (module docstring).

    centre (n,), a and b (n, L) coefficients, frequency f in Hz.
    """

    centre: np.ndarray
    a: np.ndarray
    b: np.ndarray
    frequency: float

    @classmethod
    def random(cls, n: int, rng: np.random.Generator, amplitude=0.5, centre=0.0,
               harmonics: int = 5, frequency: float = 0.1) -> FourierTrajectory:
        """Random coefficients, the l-th harmonic weighted by 1/l (smooth motions), scaled
        so that |q_k - centre_k| <= amplitude_k (radians or metres) at all times."""
        amplitude = np.broadcast_to(np.asarray(amplitude, dtype=float), (n,))
        weight = 1.0 / np.arange(1, harmonics + 1)
        a = rng.normal(size=(n, harmonics)) * weight
        b = rng.normal(size=(n, harmonics)) * weight
        bound = np.abs(a).sum(axis=1) + np.abs(b).sum(axis=1)
        factor = (amplitude / bound)[:, None]
        return cls(np.broadcast_to(np.asarray(centre, dtype=float), (n,)).copy(),
                   a * factor, b * factor, float(frequency))

    def __call__(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, qd, qdd) at the times t: each (m, n) for t of shape (m,)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        w = 2 * np.pi * self.frequency * np.arange(1, self.a.shape[1] + 1)  # (L,)
        phase = t[:, None] * w  # (m, L)
        s, c = np.sin(phase), np.cos(phase)
        q = self.centre + s @ self.a.T + c @ self.b.T
        qd = (c * w) @ self.a.T - (s * w) @ self.b.T
        qdd = -(s * w**2) @ self.a.T - (c * w**2) @ self.b.T
        return q, qd, qdd
