"""gagen's diagnostics go through `logging`, under the `gagen` logger.

Every module logs to its own child logger (`logging.getLogger(__name__)`, e.g.
`gagen.building.builder`): build stages and their times, the command line's progress, at
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

    Does nothing when not `enabled`, or when a StderrHandler is already attached (the
    command line's, or an enclosing call's): the outermost caller decides, e.g. the command
    line's --quiet (level WARNING) wins over a `verbose=True` inside. In the block, gagen's
    records stop at this handler (they do not propagate to the root logger), so that an
    application's `logging.basicConfig()` does not show them a second time.
    """
    logger = logging.getLogger(LOGGER_NAME)
    if not enabled or any(isinstance(h, StderrHandler) for h in logger.handlers):
        yield
        return
    handler = StderrHandler(level)
    saved_level, saved_propagate = logger.level, logger.propagate
    logger.setLevel(level)
    logger.propagate = False
    logger.addHandler(handler)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(saved_level)
        logger.propagate = saved_propagate
