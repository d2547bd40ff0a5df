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
# From this many coordinates on, "auto" takes the recursive form. Measured on this
# project's 2-core machine (compiled, cold cache): up to 6 coordinates (rrr, UR5) neither
# form is clearly faster per call and both build in 13-22 s; at 9 the recursive form
# builds in about half the time (chain:9 14 s vs 27 s, Panda 14 s vs 31 s) and its
# forward dynamics is faster per state in the batched loop (chain:9 0.47 vs 0.93 us,
# Panda 0.71 vs 1.38 us); at 12 it builds in 18 s instead of 61 s.
RECURSIVE_FROM_DOF = 9


def derivation_for(model: Model, derivation: str = "auto") -> str:
    """The derivation that `derivation` ("auto", "gibbs-appell" or "recursive") means here."""
    if derivation not in DERIVATIONS:
        raise ValueError(f"unknown derivation '{derivation}' (expected one of "
                         f"{', '.join(DERIVATIONS)})")
    if derivation != "auto":
        return derivation
    return "recursive" if model.dof >= RECURSIVE_FROM_DOF else "gibbs-appell"


def derive_equations(model: Model, derivation: str = "auto") -> Equations:
    """The equations of motion of `model` by the chosen derivation.

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
