"""gagen's diagnostics go through `logging`, under the `gagen` logger.

Every module logs to its own child logger (`logging.getLogger(__name__)`, e.g.
`gagen.build.builder`): build stages and their times, the command line's progress, at
INFO. A library call is quiet unless the application turns logging on, as for any
library; `showing_progress()` shows gagen's INFO records on stderr as `gagen: <message>`
lines for the duration of one call (what `gagen.load(..., verbose=True)` and the command
line use). Problems the user should act on stay `warnings.warn` (e.g. CacheWarning).
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Iterator

LOGGER_NAME = "gagen"


class StderrHandler(logging.StreamHandler):
    """`gagen: <message>` lines on whatever sys.stderr is when a record is emitted (so
    redirections made after the handler was attached, pytest's capture included, see them)."""

    def __init__(self, level: int = logging.INFO):
        logging.Handler.__init__(self, level)
        self.setFormatter(logging.Formatter("gagen: %(message)s"))

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, _value) -> None:  # StreamHandler.setStream; the stream is always stderr
        pass


@contextlib.contextmanager
def showing_progress(enabled: bool = True, level: int = logging.INFO) -> Iterator[None]:
    """Within the block, show gagen's records of `level` and above on stderr.

    Does nothing when not `enabled`, when a StderrHandler is already attached (the command
    line's, or an enclosing call's: the outermost caller, e.g. the command line's --quiet,
    decides), or when the application's own logging already handles these records. In the
    block, gagen's records stop at this handler, so that they are not shown twice (e.g.
    once more by a `logging.basicConfig()` handler at the root).
    """
    logger = logging.getLogger(LOGGER_NAME)
    already_shown = logger.isEnabledFor(level) and _handled(logger)
    if (not enabled or already_shown
            or any(isinstance(h, StderrHandler) for h in logger.handlers)):
        yield
        return
    handler = StderrHandler(level)
    saved = logger.level, logger.propagate
    logger.setLevel(min(level, logger.getEffectiveLevel()))
    logger.propagate = False
    logger.addHandler(handler)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(saved[0])
        logger.propagate = saved[1]


def _handled(logger: logging.Logger) -> bool:
    """Whether a handler other than a NullHandler receives the logger's records."""
    current: logging.Logger | None = logger
    while current is not None:
        if any(not isinstance(h, logging.NullHandler) for h in current.handlers):
            return True
        current = current.parent if current.propagate else None
    return False
