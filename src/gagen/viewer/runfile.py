"""A run's CSV as `SimulationResult.to_csv` writes it, read for the viewer by column names.

The columns are found by name, never by position: `t` and each entry of
`dyn.configuration` (a floating joint's `<joint>_x` ... `<joint>_qw`); other columns
(rates, torques, anything else) are ignored, so a file written with another coordinate
order, or with extra columns, plays the same. The file is untrusted: at most MAX_RUN_BYTES
and MAX_SAMPLES rows, numbers only, finite, times increasing.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from ..model.inputs import quote

MAX_RUN_BYTES = 128 * 2**20  # a 10-s run of ANYmal C at 1 kHz is 10 MB
MAX_SAMPLES = 2_000_000
MAX_COLUMNS = 100_000


def read_run(path, dyn) -> tuple[np.ndarray, np.ndarray]:
    """(t (m,), q (m, nq)) of a run's CSV for the model `dyn` (module docstring); ValueError
    naming the file and what is wrong."""
    path = Path(path)
    source = str(path)
    try:
        size = path.stat().st_size
        if size > MAX_RUN_BYTES:
            raise ValueError(f"{source}: {size:,} bytes; gagen reads runs of at most "
                             f"{MAX_RUN_BYTES:,} bytes")
        with path.open("rb") as handle:
            data = handle.read(MAX_RUN_BYTES + 1)
    except OSError as exc:
        raise ValueError(f"{source}: cannot read: {exc.strerror or exc}") from None
    if len(data) > MAX_RUN_BYTES:
        raise ValueError(f"{source}: grew while it was read")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{source}: not UTF-8 text") from None
    reader = csv.reader(io.StringIO(text, newline=""))
    header = _header(reader, source)
    wanted = ["t", *dyn.configuration]
    missing = [name for name in wanted if name not in header]
    if missing:
        shown = ", ".join(quote(m) for m in missing[:5]) + (" ..." if len(missing) > 5 else "")
        raise ValueError(f"{source}: no column {shown} (the columns t and "
                         f"{', '.join(dyn.configuration[:4])}{' ...' if dyn.nq > 4 else ''} "
                         f"of model {quote(dyn.info.name)} are read by name)")
    columns = [header.index(name) for name in wanted]
    try:
        rows = _rows(reader, columns, len(header), source)
    except csv.Error as exc:
        raise ValueError(f"{source}: not a CSV file ({exc})") from None
    if not rows:
        raise ValueError(f"{source}: no samples")
    table = np.array(rows, dtype=float)
    t, q = table[:, 0], table[:, 1:]
    if np.any(np.diff(t) < 0):
        raise ValueError(f"{source}: the times t must increase")
    return t, q


def _rows(reader, columns: list[int], width: int, source: str) -> list[list[float]]:
    rows = []
    for line, row in enumerate(reader, start=2):
        if not row:
            continue
        if len(rows) >= MAX_SAMPLES:
            raise ValueError(f"{source}: more than {MAX_SAMPLES:,} samples")
        if len(row) != width:
            raise ValueError(f"{source}: line {line} has {len(row)} values, the header "
                             f"{width}")
        try:
            values = [float(row[k]) for k in columns]
        except ValueError:
            raise ValueError(f"{source}: line {line}: a value that is not a number") from None
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"{source}: line {line}: NaN or infinite values")
        rows.append(values)
    return rows


def _header(reader, source: str) -> list[str]:
    try:
        header = [name.strip() for name in next(reader)]
    except StopIteration:
        raise ValueError(f"{source}: empty file") from None
    except csv.Error as exc:
        raise ValueError(f"{source}: not a CSV file ({exc})") from None
    if len(header) > MAX_COLUMNS:
        raise ValueError(f"{source}: more than {MAX_COLUMNS:,} columns")
    return header
