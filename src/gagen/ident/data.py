"""Measured trajectories for identification, from CSV.

Columns are named as `SimulationResult.to_csv` writes them: `t`, each coordinate `<name>`,
its rate `<name>_d`, optionally its acceleration `<name>_dd`, and the torque `tau_<name>`.
Other columns are ignored.

Where rates or accelerations are missing, they are estimated from the samples by a
Savitzky-Golay filter (scipy.signal.savgol_filter): a polynomial of degree `polyorder`
(default 4) fitted by least squares over a sliding window of `window` seconds (default
0.05 s, an odd number of samples, at least polyorder + 2), differentiated analytically:
q̇ from q (first derivative), q̈ from q̇ when q̇ is given, else from q (second derivative).
Degree 4 because a cubic's second derivative is a quadratic's: on a 0.5 Hz five-harmonic
trajectory sampled at 1 kHz, q̈ from q is off by 0.9 % with degree 3 and 2.4e-5 with
degree 4 (relative to its peak; tests/test_identification.py); noise on q is amplified
more by shorter windows and higher degrees.
The window is centred, so the estimates have no delay; q and τ are smoothed by the same
window (the same low-pass, so all columns keep the same phase), and the half-windows at
both ends, where the fit is one-sided, are dropped. The samples must be evenly spaced.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..csvtext import read_name

DEFAULT_WINDOW = 0.05  # seconds
DEFAULT_POLYORDER = 4


@dataclass
class Measurements:
    """Samples t (N,), q, qd, qdd, tau (N, n); `estimated` says what the filter computed
    (empty when every column was read)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    estimated: str = ""


def read_measurements(path, coordinates: list[str], window: float | None = None,
                      polyorder: int = DEFAULT_POLYORDER) -> Measurements:
    """Read a CSV of measurements for a model with these coordinates (module docstring)."""
    path = Path(path)
    header, rows = _read_csv(path)
    column = {name: k for k, name in enumerate(header)}

    def columns(names: list[str], required: bool) -> np.ndarray | None:
        missing = [n for n in names if n not in column]
        if missing and (required or len(missing) < len(names)):
            raise ValueError(f"{path}: missing column(s) {', '.join(missing)} (columns: "
                             f"t, {', '.join(coordinates)}, <name>_d, <name>_dd, tau_<name>)")
        return None if missing else rows[:, [column[n] for n in names]]

    t = columns(["t"], True)[:, 0]
    q = columns(coordinates, True)
    tau = columns([f"tau_{c}" for c in coordinates], True)
    qd = columns([f"{c}_d" for c in coordinates], False)
    qdd = columns([f"{c}_dd" for c in coordinates], False)
    if qd is not None and qdd is not None:
        return Measurements(t, q, qd, qdd, tau)
    return estimate_derivatives(t, q, qd, tau, window, polyorder)


def estimate_derivatives(t: np.ndarray, q: np.ndarray, qd: np.ndarray | None,
                         tau: np.ndarray, window: float | None = None,
                         polyorder: int = DEFAULT_POLYORDER) -> Measurements:
    """q̈ (and q̇ if None) by Savitzky-Golay differentiation (module docstring)."""
    from scipy.signal import savgol_filter

    dt = _uniform_step(t)
    length = _window_samples(window, dt, polyorder, len(t))

    def sg(x: np.ndarray, deriv: int) -> np.ndarray:
        return savgol_filter(x, length, polyorder, deriv=deriv, delta=dt, axis=0)

    if qd is None:
        qd_est, qdd_est = sg(q, 1), sg(q, 2)
        estimated = "qd and qdd from q"
    else:
        qd_est, qdd_est = sg(qd, 0), sg(qd, 1)
        estimated = "qdd from qd"
    keep = slice(length // 2, len(t) - length // 2)
    estimated += (f" (Savitzky-Golay, window {length} samples = {length * dt:.4g} s, "
                  f"degree {polyorder}; {2 * (length // 2)} edge samples dropped)")
    return Measurements(t[keep], sg(q, 0)[keep], qd_est[keep], qdd_est[keep],
                        sg(tau, 0)[keep], estimated)


def _read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    """The header (names as gagen wrote them: gagen.csvtext) and the numbers of a CSV file
    of UTF-8 text; ValueError naming the file (and the line) for anything else."""
    try:
        with path.open("rb") as fh:
            reader = csv.reader(_text_lines(fh, path))
            header = _header(next(reader, None), path)
            values = []
            for row in reader:
                if not row:
                    continue
                line = reader.line_num
                if len(row) != len(header):
                    raise ValueError(f"{path}: line {line} has {len(row)} values, the header "
                                     f"{len(header)}")
                try:
                    values.append([float(v) for v in row])
                except ValueError:
                    raise ValueError(f"{path}: line {line} holds a value that is not a "
                                     "number") from None
    except csv.Error as exc:
        raise ValueError(f"{path}: line {reader.line_num}: not readable as CSV ({exc})") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if not values:
        raise ValueError(f"{path}: has a header and no rows of data")
    data = np.array(values, dtype=float).reshape(-1, len(header))
    if not np.isfinite(data).all():
        raise ValueError(f"{path}: holds NaN or inf")
    return header, data


def _text_lines(fh, path: Path):
    """The lines of a binary file as UTF-8 text (a byte-order mark allowed first);
    ValueError naming the line of bytes that are not UTF-8."""
    for number, raw in enumerate(fh, start=1):
        try:
            yield raw.decode("utf-8-sig" if number == 1 else "utf-8")
        except UnicodeDecodeError as exc:
            raise ValueError(f"{path}: line {number}: byte 0x{raw[exc.start]:02x} at column "
                             f"{exc.start + 1} is not UTF-8 text") from None


def _header(row: list[str] | None, path: Path) -> list[str]:
    """The column names of a header row; ValueError for none, or a name given twice."""
    if not row:
        raise ValueError(f"{path}: empty file (expected a header: t, the coordinates, ...)")
    header = [read_name(name.strip()) for name in row]
    seen: dict[str, int] = {}
    for k, name in enumerate(header, start=1):
        if name in seen:
            raise ValueError(f"{path}: column {name!r} appears twice (columns {seen[name]} "
                             f"and {k}); which one holds the data is ambiguous")
        seen[name] = k
    return header


def _uniform_step(t: np.ndarray) -> float:
    steps = np.diff(t)
    if steps.size == 0 or not (steps > 0).all():
        raise ValueError("the times t must increase")
    dt = float(np.median(steps))
    if np.abs(steps - dt).max() > 1e-3 * dt:
        raise ValueError("estimating derivatives needs evenly spaced samples (t varies by "
                         f"more than 0.1 % of its median step {dt:g} s)")
    return dt


def _window_samples(window: float | None, dt: float, polyorder: int, count: int) -> int:
    seconds = DEFAULT_WINDOW if window is None else float(window)
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"the filter window must be a positive time, got {window}")
    if polyorder < 2:
        raise ValueError("the filter's polynomial degree must be at least 2 (q̈ is its "
                         "second derivative)")
    length = max(round(seconds / dt), polyorder + 2)
    length += 1 - length % 2  # odd: a centred window
    if count < 2 * length:
        raise ValueError(f"{count} samples are too few for a filter window of {length} "
                         "samples: record more, or pass a shorter window")
    return length
