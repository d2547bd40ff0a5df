"""Which derivation writes a model's equations: the paper's Gibbs-Appell form, or the
recursive Newton-Euler / composite-rigid-body form, chosen by the number of coordinates.

Both give the same `Equations` (tests/test_recursive.py checks them against each other
to 1e-11). Gibbs-Appell differentiates each body's Gibbs function, so its size grows
faster than n² and a 24-link chain takes minutes to build; the recursive form names every
per-body quantity once and grows about linearly (benchmarks/recursive_scaling.py).
"""

from __future__ import annotations

import time

import sympy as sp

from ..model.model import Model
from .aba import forward_dynamics_aba_after
from .frames import add_frame_kinematics
from .gibbs_appell import Equations, derive
from .recursive import derive_recursive

DERIVATIONS = ("auto", "gibbs-appell", "recursive")
# From this many coordinates on, "auto" takes the recursive form (with the articulated-body
# forward dynamics). Measured by benchmarks/derivation_rule.py on this project's 2-core
# machine: both forms compiled, per call from Python and per state over 1000 stacked states,
# interleaved; Gibbs-Appell time / recursive time (above 1: the recursive form is faster):
#
#   model     n  build GA/rec s   FD    ID    M    FD batched  ID batched
#   chain:4   4   13.8 / 12.7    0.91  0.77  0.75     0.60        0.98
#   chain:6   6   16.4 / 14.4    1.03  1.30  1.22     0.96        1.82
#   UR5       6   16.8 / 10.6    0.93  1.03  0.61     1.13        2.06
#   chain:7   7   18.8 / 15.5    1.02  1.93  2.22     0.99        1.15
#   chain:9   9   26.3 / 17.8    1.30  1.70  1.50     1.55        2.77
#   Panda     9   29.0 / 19.2    2.58  2.52  1.80     2.00        2.85
#
# The closed form wins at 4 coordinates (the paper's 3 too); from 6 on the recursive form
# is faster on most kernels (geometric means 1.23 and 1.05 at 6) and always builds faster.
RECURSIVE_FROM_DOF = 6


def derivation_for(model: Model, derivation: str = "auto") -> str:
    """The derivation that `derivation` ("auto", "gibbs-appell" or "recursive") means here."""
    if derivation not in DERIVATIONS:
        raise ValueError(f"unknown derivation '{derivation}' (expected one of "
                         f"{', '.join(DERIVATIONS)})")
    if derivation != "auto":
        return derivation
    return "recursive" if model.dof >= RECURSIVE_FROM_DOF else "gibbs-appell"


def derive_equations(model: Model, derivation: str = "auto") -> Equations:
    """The equations of motion of `model` by the chosen derivation, with the frames'
    kinematics (the regressor is attached on demand: symbolic.regressor.with_regressor).

    The recursive form also writes forward dynamics by the articulated-body algorithm
    (`Equations.forward_dynamics`), as a continuation of the same program: O(n) where
    M \\ forcing costs O(n * depth) for M and O(n^3) for its factorisation."""
    if derivation_for(model, derivation) == "recursive":
        eqs = with_articulated_body(derive_recursive(model))
    else:
        eqs = derive(model)
    return add_frame_kinematics(eqs)


def with_articulated_body(eqs: Equations) -> Equations:
    """`eqs` with forward dynamics by the articulated-body algorithm added to its program."""
    start = time.perf_counter()
    program = forward_dynamics_aba_after(eqs)
    eqs.intermediates = program.intermediates
    eqs.forward_dynamics = sp.Matrix(program.qdd)
    eqs.pivots = list(program.pivots)
    eqs.seconds += time.perf_counter() - start
    return eqs
