"""The choices of the code generator that are not the model's: one place, one dataclass."""

from __future__ import annotations

from dataclasses import dataclass

# Stages of at most this many operations go inline into each of the integrators' stages
# (a dozen copies): measured, larger ones compile slowly for no gain (docs/benchmarks.md).
INLINE_STAGE_OPS = 400


@dataclass(frozen=True)
class CodegenConfig:
    """How the C is written.

    inline_stage_ops   the position and velocity stages of forward dynamics go inline into
                       the integrators when they have at most this many operations
    fast_trig          sin and cos from gagen_math.h (within 1 ulp, about twice as fast as
                       libm's) instead of libm's
    """

    inline_stage_ops: int = INLINE_STAGE_OPS
    fast_trig: bool = True
