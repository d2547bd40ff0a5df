"""Every exception and warning a user of gagen can meet, in one place (and no SymPy here).

- `ModelError`: a description that cannot be used; names the file, the element, the reason.
- `BuildError` (and `CompilerNotFoundError`): generated code that did not compile.
- `SingularMassMatrixError`: M(q) is singular or not positive definite at a state.
- `SingularTaskError`: a task's rows are dependent: no operational-space inertia there.
- `InertiaWarning`: an inertia slightly off physical (CAD round-off), accepted unless strict.
"""

from __future__ import annotations

import os
import sys
import warnings

import numpy as np

_PACKAGE = os.path.dirname(os.path.abspath(__file__)) + os.sep


class ModelError(ValueError):
    """A model that cannot be used; the message names the file, the element and the reason."""

    def __init__(self, source: str, element: str, reason: str):
        self.source, self.element, self.reason = source, element, reason
        where = f"{source}: {element}" if element else source
        super().__init__(one_line(f"{where}: {reason}"))


def warn_user(message: str, category: type[Warning]) -> None:
    """`warnings.warn` attributed to the user's line: the first caller outside gagen (and
    outside Python's import machinery), however deep in gagen the warning arises, so that
    the location shown, and the filters that match it, are the user's own code."""
    level, frame = 2, sys._getframe(1)
    while frame is not None and _inside_gagen(frame.f_code.co_filename):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, category, stacklevel=level)


def _inside_gagen(filename: str) -> bool:
    return filename.startswith((_PACKAGE, "<frozen importlib"))


def one_line(text: str) -> str:
    """`text` with line breaks and other control characters escaped, so that a name taken
    from a description cannot forge extra lines in a terminal or a log."""
    return "".join(ch if ch.isprintable() else ascii(ch)[1:-1] for ch in text)


class NonFiniteStateError(ValueError):
    """The dynamics met NaN or inf where they need finite numbers: in the state given, or,
    in a simulation, in a state the motion reached (a controller's NaN torques, a motion
    that diverged)."""


class BuildError(RuntimeError):
    """Generated code did not compile; the message holds the compiler's output."""


class CompilerNotFoundError(BuildError):
    """No C compiler: the compiled backend cannot be built here."""


class SingularMassMatrixError(np.linalg.LinAlgError):
    """The mass matrix is singular or not positive definite at the given state."""


class SingularTaskError(np.linalg.LinAlgError):
    """The rows of a task (frames' stacked Jacobian rows) are linearly dependent at the given
    state, so its operational-space inertia (J M⁻¹ Jᵀ)⁻¹ does not exist."""


class InertiaWarning(UserWarning):
    """An inertia tensor that breaks positive-definiteness or the triangle inequality by a
    small margin (CAD round-off) was accepted; `strict=True` refuses it instead. Filter it
    with `warnings.filterwarnings("ignore", category=gagen.InertiaWarning)`."""
