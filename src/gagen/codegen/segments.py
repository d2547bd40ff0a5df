"""Big kernels as a driver and several segment functions, in translation units of their own.

A C compiler's time on one straight-line function grows much faster than the function:
the articulated-body forward dynamics of a 50-link chain (about 15,000 operations) takes
gcc 18.5 s as one function and 1.9 s as 15 functions of about 1,000 operations each, and
runs no slower (3.5 us either way; register allocation over one huge function is no
better). So a kernel whose code is large is cut, in its dependency order, into segments of
about `segment_chars` characters of C. Each segment is a function of the kernel's own
arguments plus a workspace `w`: a value that a later segment reads is stored in a slot of
`w` where it is defined and read back where it is used; the other values stay locals.
Slots are reused once the last segment that reads their value has run, so `w` stays about
as small as the widest cut through the program (a few hundred doubles for a 50-link chain,
hot in the L1 cache).

sin and cos of the coordinates are computed once, in the first segment, and shared through
`w` like any other value (recomputing them per segment would cost about as much as a
segment). The segment functions go into files `kernels_<k>.c`, which the build compiles in
parallel with the kernels' own files.
"""

from __future__ import annotations

from dataclasses import dataclass, field

# A kernel whose statements exceed this many characters of C is split into segments...
SPLIT_CHARS = 24_000
# ... of about this many characters each ...
SEGMENT_CHARS = 12_000
# ... and the segment functions are gathered into files of about this many characters.
FILE_CHARS = 120_000
# The derivative module's kernels are split only above this many characters: a segment
# boundary stores and reloads every value that crosses it, and the derivative module is
# built on demand, not by every load. Measured on the Panda (forward-dynamics derivatives
# per call from Python, its largest kernel 87k characters): 2.52 us split at SPLIT_CHARS,
# 2.26 us whole; the module's cold build took about a second longer.
DERIVATIVE_SPLIT_CHARS = 120_000


@dataclass
class Segment:
    """One segment function: its statements, and what it reads from and writes to `w`."""

    name: str
    prelude: list[str] = field(default_factory=list)
    imports: list[tuple[str, str]] = field(default_factory=list)   # (local, source)
    locals: list[tuple[str, str]] = field(default_factory=list)    # (local, expression)
    exports: list[tuple[str, str]] = field(default_factory=list)   # (w slot, local)
    outputs: list[tuple[str, str]] = field(default_factory=list)   # (target, expression)
    params: str = ""                                                # its C parameters
    looped: bool = False  # part of a kernel that runs in loops: built for FMA too

    @property
    def chars(self) -> int:
        return sum(len(a) + len(b) for a, b in self.locals + self.outputs)


@dataclass
class Statement:
    """A local definition (`name = text`) and the names it reads."""

    name: str
    text: str
    reads: frozenset[str]


def split(name: str, prelude: tuple[list[str], list[str]], statements: list[Statement],
          outputs: list[tuple[str, str, frozenset[str]]], externals: dict[str, str] | None = None,
          segment_chars: int = SEGMENT_CHARS) -> tuple[list[Segment], int]:
    """Cut a kernel into segments; return them and the workspace size (doubles).

    `prelude` is the trig code, its lines and the names they define, run in the first
    segment; `statements` are in dependency order; `outputs` are (target, text, names
    read), each written by the segment that defines the last value it reads; `externals`
    are names read from the kernel's arrays (name -> `S[3]`), imported where used. Names
    defined nowhere here (the kernel's arguments, `q[3]`, `p[0]`) are left as they are.
    """
    externals = externals or {}
    lines, defined = prelude
    chunks = _chunks(statements, segment_chars)
    first = 1 if lines else 0
    # at least one segment: a kernel of outputs alone (constants, say) still has a place
    segments = [Segment(f"{name}_part{k}") for k in range(max(1, len(chunks) + first))]
    where: dict[str, int] = {}           # name -> the segment defining it
    reads: list[set[str]] = [set() for _ in segments]
    if lines:
        segments[0].prelude = list(lines)
        where.update({n: 0 for n in defined})
    for k, chunk in enumerate(chunks, start=first):
        where.update({s.name: k for s in chunk})
        segments[k].locals = [(s.name, s.text) for s in chunk]
        reads[k].update(*(s.reads for s in chunk))
    for target, text, names in outputs:
        k = max((where[r] for r in names if r in where), default=len(segments) - 1)
        segments[k].outputs.append((target, text))
        reads[k].update(names)
    last_use: dict[str, int] = {}
    for k, names in enumerate(reads):
        for r in names:
            if r in where and where[r] != k:
                last_use[r] = max(last_use.get(r, k), k)
    slots = _slots(where, last_use, len(segments))
    for value in sorted(slots, key=lambda v: (where[v], slots[v])):
        segments[where[value]].exports.append((f"w[{slots[value]}]", value))
    for k, segment in enumerate(segments):
        imported = sorted((r for r in reads[k] if r in slots and where[r] != k),
                          key=lambda r: slots[r])
        segment.imports = [(r, externals[r]) for r in sorted(reads[k] & externals.keys())]
        segment.imports += [(r, f"w[{slots[r]}]") for r in imported]
    return segments, (max(slots.values()) + 1) if slots else 0


def schedule_late(statements: list[Statement], outputs: list[frozenset[str]]
                  ) -> list[Statement]:
    """The statements reordered so that each comes just before its first use: depth-first
    from the outputs, in their order, each statement after the statements it reads (in
    their given order).

    The derivations define things pass by pass (every body's setup, then every body's
    velocities, ...), so in their order a value often waits many statements for its use;
    cut into segments, it would cross segments through the workspace. Depth-first from the
    outputs, a recursive algorithm runs body by body instead, and a segment mostly reads
    what it computed itself (for a 50-link chain's inverse dynamics, about a third as many
    workspace loads and stores)."""
    by_name = {s.name: s for s in statements}
    position = {s.name: k for k, s in enumerate(statements)}
    placed: set[str] = set()
    order: list[Statement] = []
    for reads in outputs:
        stack = [(None, _inputs(reads, position))]
        while stack:
            name, pending = stack[-1]
            if pending:
                dep = pending.pop()
                if dep not in placed:
                    stack.append((dep, _inputs(by_name[dep].reads, position)))
                continue
            stack.pop()
            if name is not None and name not in placed:
                placed.add(name)
                order.append(by_name[name])
    order += [s for s in statements if s.name not in placed]  # read by no output
    return order


def _inputs(reads: frozenset[str], position: dict[str, int]) -> list[str]:
    """The statements among `reads`, last-defined first (popped from the end: first first)."""
    return sorted((r for r in reads if r in position), key=position.__getitem__, reverse=True)


def _chunks(statements: list[Statement], budget: int) -> list[list[Statement]]:
    """Consecutive runs of statements of about `budget` characters each."""
    chunks: list[list[Statement]] = [[]]
    size = 0
    for s in statements:
        if size >= budget:
            chunks.append([])
            size = 0
        chunks[-1].append(s)
        size += len(s.name) + len(s.text)
    return [c for c in chunks if c]


def _slots(where: dict[str, int], last_use: dict[str, int], count: int) -> dict[str, int]:
    """A workspace slot for every value read by a later segment, reused after its last
    reader: a slot freed by values last read in segment k serves values defined after k."""
    defined_in: dict[int, list[str]] = {k: [] for k in range(count)}
    for value in where:  # in the order of definition: last_use's comes from sets of names
        if value in last_use:
            defined_in[where[value]].append(value)
    released_after: dict[int, list[int]] = {k: [] for k in range(count)}
    free: list[int] = []
    size = 0
    slots: dict[str, int] = {}
    for k in range(count):
        for value in defined_in[k]:
            if free:
                slot = free.pop()
            else:
                slot, size = size, size + 1
            slots[value] = slot
            released_after[last_use[value]].append(slot)
        # values last read in segment k free their slots for segments after k
        free.extend(sorted(released_after[k], reverse=True))
    return slots
