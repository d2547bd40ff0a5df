"""The symbols of the equations, each kind in a namespace of its own.

A model's parameters are plain SymPy symbols named by the user. Everything else has a class
of its own: the coordinates and their rates, accelerations and torques, and gagen's internal
intermediates and temporaries. SymPy symbols of different classes never compare equal, so no
name a user picks (a joint called `_g0`, a parameter called `q1_d`) can ever denote one of
gagen's symbols: the namespaces are separate by construction, not by a list of reserved names.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import sympy as sp


class Coordinate(sp.Symbol):
    """A generalized coordinate q_k, named after its joint."""


class Rate(sp.Symbol):
    """A generalized velocity qd_k (printed `<joint>_d`)."""


class Acceleration(sp.Symbol):
    """A generalized acceleration qdd_k (printed `<joint>_dd`)."""


class Torque(sp.Symbol):
    """A generalized force tau_k (printed `tau_<joint>`)."""


class Internal(sp.Symbol):
    """An intermediate or temporary of gagen's own, named `_g<k>`, `_x<k>`, `_h<k>`."""


def internal_symbols(prefix: str) -> Iterator[Internal]:
    """Internal symbols `<prefix>0`, `<prefix>1`, ... (for sympy.cse and the stage split)."""
    return (Internal(f"{prefix}{k}") for k in itertools.count())
