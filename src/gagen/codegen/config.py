"""The choices of the code generator that are not the model's: one place, one dataclass."""

from __future__ import annotations

from dataclasses import dataclass, replace

from .segments import DERIVATIVE_SPLIT_CHARS, FILE_CHARS, SEGMENT_CHARS, SPLIT_CHARS

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
    split_chars        a kernel with more characters of C than this is split into segment
                       functions (codegen/segments.py)
    segment_chars      ... into segments of about this many characters each
    derivative_split_chars
                       split_chars for the derivative module's kernels (codegen/segments.py)
    file_chars         the segment functions go into files of about this many characters
    derivative_form    the derivative module's form: "unrolled", "loop" or "auto" (by the
                       measured rule of gagen.symbolic.derivatives.derivative_form)
    cse                sympy.cse over the intermediates and outputs (False: the derivation's
                       own named intermediates as they are; None: for the Gibbs-Appell form
                       only. The recursive form names every per-body quantity once already:
                       on a 50-link chain CSE removed 6 % of the operations, left the speed
                       per call unchanged, and took more than half of the generation time)
    """

    inline_stage_ops: int = INLINE_STAGE_OPS
    fast_trig: bool = True
    split_chars: int = SPLIT_CHARS
    segment_chars: int = SEGMENT_CHARS
    derivative_split_chars: int = DERIVATIVE_SPLIT_CHARS
    cse: bool | None = None
    file_chars: int = FILE_CHARS
    derivative_form: str = "auto"

    def for_main_module(self) -> CodegenConfig:
        """These settings without those that only the derivative module reads: the main
        module's source key does not move with them."""
        return replace(self, derivative_split_chars=DERIVATIVE_SPLIT_CHARS,
                       derivative_form="auto")
