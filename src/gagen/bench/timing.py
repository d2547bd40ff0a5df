"""One timing runner for every benchmark: candidates interleaved round-robin over repeats.

Every repeat times each candidate once (a `timeit` loop of `number` calls; the sample is
the loop time divided by `number`), the starting candidate rotating from one repeat to the
next. A slow phase of a busy machine then hits all candidates alike instead of whichever
happened to run during it. Reported per candidate: the median sample, the quartiles and
their spread (IQR), and the ratio of its median to a named baseline's median.
"""

from __future__ import annotations

import statistics
import time
import timeit
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

DEFAULT_REPEATS = 21
DEFAULT_TARGET = 0.02  # seconds per sample (one timeit loop)


@dataclass
class Candidate:
    """Something to time: `fn(*args)`, optionally in a group (for per-group baselines)."""

    name: str
    fn: Callable
    args: tuple = ()
    group: str | None = None
    info: dict = field(default_factory=dict)  # carried into the result, e.g. the call text

    def timer(self, clock: Callable[[], float] = time.perf_counter) -> timeit.Timer:
        # `fn(a0, a1, ...)` with the arguments as globals: the call a user would write,
        # without the cost of unpacking `*args` in the loop
        names = [f"a{k}" for k in range(len(self.args))]
        namespace = {"fn": self.fn, **dict(zip(names, self.args))}
        return timeit.Timer(f"fn({', '.join(names)})", timer=clock, globals=namespace)


@dataclass
class Timing:
    """Seconds per call of one candidate: every sample, and their summary."""

    name: str
    group: str | None
    samples: list[float]
    number: int
    info: dict = field(default_factory=dict)
    baseline: str | None = None
    ratio: float | None = None  # median / the baseline's median
    first: list[float] = field(default_factory=list)  # warm-up calls (interleaved(warmup=))

    @property
    def median(self) -> float:
        return quartiles(self.samples)[1]

    @property
    def q1(self) -> float:
        return quartiles(self.samples)[0]

    @property
    def q3(self) -> float:
        return quartiles(self.samples)[2]

    @property
    def iqr(self) -> float:
        q1, _, q3 = quartiles(self.samples)
        return q3 - q1

    @property
    def min(self) -> float:
        return min(self.samples)

    @property
    def first_median(self) -> float:
        """The median of the warm-up calls (interleaved(warmup=True))."""
        return quartiles(self.first)[1]

    def as_dict(self) -> dict:
        return {"name": self.name, "group": self.group, "median_s": self.median,
                "q1_s": self.q1, "q3_s": self.q3, "iqr_s": self.iqr, "min_s": self.min,
                "repeats": len(self.samples), "number": self.number,
                "baseline": self.baseline, "ratio": self.ratio,
                **({"first_median_s": self.first_median} if self.first else {}),
                **self.info}


def quartiles(values: Sequence[float]) -> tuple[float, float, float]:
    """(q1, median, q3), by linear interpolation between the sorted values (inclusive)."""
    values = list(values)
    if not values:
        raise ValueError("no samples")
    if len(values) == 1:
        return values[0], values[0], values[0]
    q1, median, q3 = statistics.quantiles(values, n=4, method="inclusive")
    return q1, median, q3


def loop_size(timer: timeit.Timer, target: float, clock: Callable[[], float] | None = None
              ) -> int:
    """Calls per sample so that one sample takes about `target` seconds (at least 1).

    One untimed call first: a candidate's first call (its pages, caches, a JIT's lazy
    set-up) would otherwise size the loop, and a call hundreds of times slower than the
    next ones would leave every sample a single call."""
    timer.timeit(1)
    number = 1
    while True:
        elapsed = timer.timeit(number)
        if elapsed >= min(target, 0.002) or number >= 10**7:
            break
        number *= 10
    per_call = elapsed / number
    return max(1, int(target / per_call)) if per_call > 0 else number


def order(count: int, repeats: int) -> list[list[int]]:
    """The round-robin: per repeat, the candidate indices in the order they are timed."""
    return [[(k + r) % count for k in range(count)] for r in range(repeats)]


def interleaved(candidates: Sequence[Candidate], repeats: int = DEFAULT_REPEATS,
                target: float = DEFAULT_TARGET, baseline: str | Mapping | None = None,
                numbers: Sequence[int] | None = None,
                clock: Callable[[], float] = time.perf_counter,
                progress: Callable[[int, int], None] | None = None,
                warmup: bool = False) -> list[Timing]:
    """Time the candidates round-robin; one `Timing` per candidate, in the given order.

    `warmup`: each sample follows one call of its own candidate, timed apart (`Timing.first`),
    so that samples measure a candidate's throughput in a run of calls and not its first
    call after the others (whose data and allocations have displaced its own): for calls
    of milliseconds, a sample is only a few calls long.

    `numbers` fixes the calls per sample (one per candidate); otherwise each candidate is
    warmed up and its loop sized so that one sample takes about `target` seconds.
    `baseline` names the candidate every ratio refers to, or maps each group to the name
    of its baseline (a group without one gets no ratios). `clock` is the timer (seconds).
    """
    if not candidates:
        return []
    names = [c.name for c in candidates]
    if len(set(names)) != len(names):
        raise ValueError(f"candidate names must be unique: {names}")
    timers = [c.timer(clock) for c in candidates]
    if numbers is None:
        numbers = [loop_size(t, target) for t in timers]
    elif len(numbers) != len(candidates):
        raise ValueError("one loop size per candidate")
    samples: list[list[float]] = [[] for _ in candidates]
    firsts: list[list[float]] = [[] for _ in candidates]
    for r, sequence in enumerate(order(len(candidates), max(1, repeats))):
        for i in sequence:
            if warmup:
                firsts[i].append(timers[i].timeit(1))
            samples[i].append(timers[i].timeit(numbers[i]) / numbers[i])
        if progress:
            progress(r + 1, repeats)
    results = [Timing(c.name, c.group, s, n, dict(c.info), first=f)
               for c, s, n, f in zip(candidates, samples, numbers, firsts)]
    apply_baseline(results, baseline)
    return results


def apply_baseline(results: Sequence[Timing], baseline: str | Mapping | None) -> None:
    """Set each result's ratio: its median over the median of its (group's) baseline."""
    if baseline is None:
        return
    by_name = {t.name: t for t in results}
    for t in results:
        ref = baseline if isinstance(baseline, str) else baseline.get(t.group)
        if ref is None:
            continue
        if ref not in by_name:
            raise KeyError(f"baseline '{ref}' is not among the candidates")
        t.baseline = ref
        t.ratio = t.median / by_name[ref].median
