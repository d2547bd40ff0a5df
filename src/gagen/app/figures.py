"""The paper's figures: Fig. 2 (coordinates), Fig. 3 (arm positions), Fig. 4 (inverse dynamics).

Figures are drawn off screen on `matplotlib.figure.Figure` objects, each with its own Agg
canvas: gagen never selects matplotlib's global backend (an application's choice stays
its own), never imports pyplot, never opens a window and leaves no figures in pyplot's
registry.
Each `fig*` function saves to `path` and returns it, or returns the Figure if path is None.

Positions of the arm come from `arm_points`: the paper's closed-form geometry for `rrr`
(O, A = L1 j1, B = A + L2 j2, the tip B + L3 j3) and, for any other model, a numerical
forward kinematics of the gagen Model (body frame origins, plus a tip at twice the mass
centre offset for every leaf body) at the model's parameters.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..model import numeric
from ..model.model import Model

PAPER_TORQUE_LABELS = ("T01z", "T12x", "T23x")


# ----------------------------------------------------------------- forward kinematics


def body_frames(model: Model, q, p=None) -> tuple[np.ndarray, np.ndarray]:
    """World origins (m, nb, 3) and rotations (m, nb, 3, 3) of every body frame, for q of
    shape (n,) or (m, n) (gagen.model.numeric.body_frames at the parameters p)."""
    return numeric.body_frames(numeric.numeric_model(model, p), q)


def rrr_points(q, p=None, model: Model | None = None) -> np.ndarray:
    """The paper's arm: O, A = L1 j1, B = A + L2 j2, tip = B + L3 j3 -> (m, 4, 3) or (4, 3)."""
    if model is None:
        from ..model.builtin import load_builtin

        model = load_builtin("rrr")
    values = numeric.parameter_values(model, p)
    L1, L2, L3 = values["L1"], values["L2"], values["L3"]
    q = np.asarray(q, dtype=float)
    qq = np.atleast_2d(q)
    q1, q2, q3 = qq[:, 0], qq[:, 1], qq[:, 2]
    c1, s1 = np.cos(q1), np.sin(q1)
    c2, s2 = np.cos(q2), np.sin(q2)
    c23, s23 = np.cos(q2 + q3), np.sin(q2 + q3)
    zero = np.zeros_like(q1)
    j1 = np.stack([-s1, c1, zero], axis=-1)
    k1 = np.stack([zero, zero, np.ones_like(q1)], axis=-1)
    j2 = c2[:, None] * j1 + s2[:, None] * k1
    j3 = c23[:, None] * j1 + s23[:, None] * k1
    A = L1 * j1
    B = A + L2 * j2
    tip = B + L3 * j3
    pts = np.stack([np.zeros_like(A), A, B, tip], axis=1)
    return pts[0] if q.ndim == 1 else pts


def arm_points(model: Model, q, p=None) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Points to draw (m, k, 3) and the segments between them (pairs of point indices).

    rrr: `rrr_points` (O, A, B, tip; segments O-A, A-B, B-tip). Other models: point 0 is
    the world origin, then every body's frame origin, then a tip for every leaf body whose
    mass centre is off its origin (at twice the offset: the far end of a uniform link).
    Segments join each body origin to its parent's (the world origin for root bodies) and
    each leaf to its tip.
    """
    from ..sim.controllers import is_paper_robot

    q = np.asarray(q, dtype=float)
    qq = np.atleast_2d(q)
    if is_paper_robot(model) and {"L1", "L2", "L3"} <= set(model.parameters):
        return rrr_points(qq, p, model), [(0, 1), (1, 2), (2, 3)]
    nm = numeric.numeric_model(model, p)
    origins, rotations = numeric.body_frames(nm, qq)
    links = nm.bodies
    nb = len(links)
    points = [np.zeros((qq.shape[0], 3))] + [origins[:, i] for i in range(nb)]
    edges = [(0 if link.parent < 0 else link.parent + 1, i + 1) for i, link in enumerate(links)]
    has_child = {link.parent for link in links}
    for i, link in enumerate(links):
        if i not in has_child and np.linalg.norm(link.com) > 1e-12:
            points.append(origins[:, i] + rotations[:, i] @ (2.0 * link.com))
            edges.append((i + 1, len(points) - 1))
    edges = [(a, b) for a, b in edges if a != b]
    return np.stack(points, axis=1), edges


# --------------------------------------------------------------------------- figures


def _new_figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _finish(fig: Figure, path):
    if path is None:
        return fig
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    return path


def _units(model: Model | None, n: int) -> list[str]:
    """Per coordinate: 'deg' (rotating joint, shown in degrees) or 'm' (prismatic)."""
    if model is None:
        return ["deg"] * n
    return ["m" if b.joint.type == "prismatic" else "deg" for b in model.moving_bodies]


def _coordinate_names(model: Model | None, n: int) -> list[str]:
    return list(model.coordinates) if model is not None else [f"q{i + 1}" for i in range(n)]


def _display(q: np.ndarray, units: list[str]) -> np.ndarray:
    scale = np.array([180.0 / math.pi if u == "deg" else 1.0 for u in units])
    return q * scale


def _label(ax, name: str, unit: str) -> None:
    """y label 'name (unit)'; long names go inside the panel, so that labels don't collide."""
    if len(name) <= 8:
        ax.set_ylabel(f"{name} ({unit})")
        return
    ax.set_ylabel(f"({unit})")
    ax.text(0.01, 0.95, name, transform=ax.transAxes, fontsize=8, va="top", ha="left",
            bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8, "pad": 1.0})


def _position_panels(fig, axes, t, q, model):
    n = q.shape[1]
    units = _units(model, n)
    names = _coordinate_names(model, n)
    values = _display(q, units)
    for k, ax in enumerate(axes):
        ax.plot(t, values[:, k], color="C0", lw=1.6)
        _label(ax, names[k], units[k])
        ax.grid(True, alpha=0.3)
        lo, hi = values[:, k].min(), values[:, k].max()
        pad = 0.08 * max(hi - lo, 1.0 if units[k] == "deg" else 0.01)
        ax.set_ylim(lo - pad, hi + pad)
    axes[-1].set_xlabel("t (s)")
    for ax in axes:
        ax.set_xlim(t[0], t[-1])


def fig2_positions(t, q, model: Model | None = None, path=None, title: str | None = None):
    """Fig. 2: the generalized coordinates against time, one panel each (degrees, or m)."""
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    n = q.shape[1]
    fig = _new_figure(6.4, 1.2 + 1.5 * n)
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    _position_panels(fig, axes, t, q, model)
    name = model.name if model is not None else "model"
    fig.suptitle(title or f"Fig. 2  Generalized coordinates ({name})")
    fig.tight_layout()
    return _finish(fig, path)


def _torque_names(model: Model | None, n: int) -> tuple[list[str], list[str]]:
    """Names and units of the generalized forces: T01z, T12x, T23x for rrr, else tau_<q>."""
    from ..sim.controllers import is_paper_robot

    if model is not None and is_paper_robot(model):
        return list(PAPER_TORQUE_LABELS), ["N m"] * 3
    names = [f"tau_{name}" for name in _coordinate_names(model, n)]
    return names, ["N" if u == "m" else "N m" for u in _units(model, n)]


def _torque_labels(model: Model | None, n: int) -> list[str]:
    names, units = _torque_names(model, n)
    return [f"{name} ({unit})" for name, unit in zip(names, units)]


def fig4_inverse(t, q, tau, model: Model | None = None, path=None, title: str | None = None):
    """Fig. 4: (a) the input positions of eq. 11 and (b) the torques that produce them."""
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    tau = np.asarray(tau, dtype=float)
    n = q.shape[1]
    fig = _new_figure(10.0, 1.4 + 1.6 * n)
    axes = fig.subplots(n, 2, sharex=True, squeeze=False)
    _position_panels(fig, axes[:, 0], t, q, model)
    names, units = _torque_names(model, n)
    for k in range(n):
        ax = axes[k, 1]
        ax.plot(t, tau[:, k], color="C3", lw=1.6)
        _label(ax, names[k], units[k])
        ax.grid(True, alpha=0.3)
        ax.axhline(0.0, color="0.6", lw=0.6)
        ax.set_xlim(t[0], t[-1])
    axes[-1, 1].set_xlabel("t (s)")
    axes[0, 0].set_title("(a) input positions")
    axes[0, 1].set_title("(b) calculated torques")
    name = model.name if model is not None else "model"
    fig.suptitle(title or f"Fig. 4  Inverse dynamics ({name})")
    fig.tight_layout()
    return _finish(fig, path)


def _equal_3d(ax, pts: np.ndarray) -> None:
    lo = pts.reshape(-1, 3).min(axis=0)
    hi = pts.reshape(-1, 3).max(axis=0)
    centre = (lo + hi) / 2
    half = max(float((hi - lo).max()) / 2 * 1.1, 0.05)
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")


def _draw_arm(ax, pts, edges, color, lw=2.0, alpha=1.0, markers=True):
    for a, b in edges:
        seg = pts[[a, b]]
        ax.plot(seg[:, 0], seg[:, 1], seg[:, 2], color=color, lw=lw, alpha=alpha)
    if markers:
        ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], color=color, s=10, alpha=alpha,
                   depthshade=False)


def _spread(model: Model, q: np.ndarray, count: int, p=None) -> np.ndarray:
    """Indices of `count` samples evenly spaced along the path of the arm's points."""
    pts, _ = arm_points(model, q, p)
    step = np.linalg.norm(np.diff(pts, axis=0), axis=2).sum(axis=1)
    s = np.concatenate([[0.0], np.cumsum(step)])
    if not s[-1] > 0:
        return np.array([0, len(q) - 1])
    wanted = np.linspace(0.0, s[-1], count)
    return np.unique(np.searchsorted(s, wanted).clip(0, len(q) - 1))


def fig3_arm(model: Model, q, path=None, p=None, t=None, count: int = 11,
             spacing: str = "path", title: str | None = None):
    """Fig. 3: successive positions of the arm along the samples q (m, n).

    `count` positions, the first and last sample included, spaced evenly along the path
    the arm's points travel (`spacing="path"`, the default: positions do not pile up
    where the arm rests) or evenly in sample index, i.e. in time (`spacing="time"`).
    """
    import mpl_toolkits.mplot3d  # noqa: F401  (registers the 3-D projection)
    from matplotlib import colormaps

    q = np.atleast_2d(np.asarray(q, dtype=float))
    count = max(int(count), 2)
    if spacing == "path":
        pick = _spread(model, q, count, p)
    elif spacing == "time":
        pick = np.unique(np.linspace(0, len(q) - 1, count).round().astype(int))
    else:
        raise ValueError(f"spacing must be 'path' or 'time', got {spacing!r}")
    pts, edges = arm_points(model, q[pick], p)
    fig = _new_figure(7.0, 6.4)
    ax = fig.add_subplot(projection="3d")
    cmap = colormaps["viridis"]
    for k, idx in enumerate(pick):
        frac = k / max(len(pick) - 1, 1)
        first_or_last = k in (0, len(pick) - 1)
        _draw_arm(ax, pts[k], edges, cmap(0.9 * frac), lw=2.6 if first_or_last else 1.3,
                  alpha=1.0 if first_or_last else 0.75)
    tip = pts[:, -1]
    ax.plot(tip[:, 0], tip[:, 1], tip[:, 2], color="0.5", lw=0.8, ls="--")
    when = (lambda i: f" (t = {t[i]:g} s)") if t is not None else (lambda i: "")
    ax.text(*pts[0, -1], "  initial position" + when(pick[0]), fontsize=8)
    ax.text(*pts[-1, -1], "  final position" + when(pick[-1]), fontsize=8)
    ax.scatter([0], [0], [0], color="k", s=18)
    ax.text(0, 0, 0, " O", fontsize=8)
    _equal_3d(ax, pts)
    ax.view_init(elev=22, azim=-55)
    fig.suptitle(title or f"Fig. 3  Position of the robot arm ({model.name})")
    fig.tight_layout()
    return _finish(fig, path)


def arm_gif(model: Model, t, q, path, p=None, fps: int = 20, max_frames: int = 60,
            dpi: int = 80) -> Path:
    """An animated GIF of the arm along (t, q), at most `max_frames` frames (PillowWriter)."""
    import mpl_toolkits.mplot3d  # noqa: F401
    from matplotlib.animation import FuncAnimation, PillowWriter

    t = np.asarray(t, dtype=float)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    pick = np.unique(np.linspace(0, len(q) - 1, max(2, min(max_frames, len(q))))
                     .round().astype(int))
    pts, edges = arm_points(model, q[pick], p)
    fig = _new_figure(5.0, 5.0)
    ax = fig.add_subplot(projection="3d")
    _equal_3d(ax, pts)
    ax.view_init(elev=22, azim=-55)
    lines = [ax.plot([], [], [], color="C0", lw=2.5)[0] for _ in edges]
    trail, = ax.plot([], [], [], color="0.5", lw=0.8, ls="--")
    label = ax.text2D(0.02, 0.95, "", transform=ax.transAxes)
    fig.suptitle(f"{model.name}")

    def draw(k):
        for line, (a, b) in zip(lines, edges):
            seg = pts[k][[a, b]]
            line.set_data_3d(seg[:, 0], seg[:, 1], seg[:, 2])
        tip = pts[: k + 1, -1]
        trail.set_data_3d(tip[:, 0], tip[:, 1], tip[:, 2])
        label.set_text(f"t = {t[pick[k]]:.2f} s")
        return [*lines, trail, label]

    anim = FuncAnimation(fig, draw, frames=len(pick), interval=1000 / fps, blit=False)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    anim.save(path, writer=PillowWriter(fps=fps), dpi=dpi)
    return path


def fig2_fan(t, q_runs, q_nominal=None, model: Model | None = None, path=None,
             title: str | None = None, total: int | None = None):
    """Fig. 2 of many runs: each coordinate's trajectories (thin lines), the 5-95 % band
    and the median across runs, the nominal run (bold, if given) and, in a second column,
    each run's deviation from the nominal one.

    q_runs (N, m, n) are the runs drawn (failed runs, NaN, are left out); `total` is the
    number of runs of the sweep they were taken from, for the title."""
    t = np.asarray(t, dtype=float)
    q_runs = np.asarray(q_runs, dtype=float)
    q_runs = q_runs[~np.isnan(q_runs).any(axis=(1, 2))]
    n = q_runs.shape[2]
    units = _units(model, n)
    names = _coordinate_names(model, n)
    values = _display(q_runs, units)
    nominal = None if q_nominal is None else _display(np.asarray(q_nominal, dtype=float), units)
    columns = 1 if nominal is None else 2
    fig = _new_figure(6.4 if columns == 1 else 11.0, 1.2 + 1.6 * n)
    axes = fig.subplots(n, columns, sharex=True, squeeze=False)
    for k in range(n):
        _fan_panel(axes[k, 0], t, values[:, :, k], None if nominal is None else nominal[:, k])
        _label(axes[k, 0], names[k], units[k])
        if nominal is not None:
            _fan_panel(axes[k, 1], t, values[:, :, k] - nominal[:, k], None)
            _label(axes[k, 1], f"{names[k]} - nominal", units[k])
    axes[0, 0].legend(loc="best", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    name = model.name if model is not None else "model"
    shown = f"{len(values)} runs" if total in (None, len(values)) else \
        f"{len(values)} of {total} runs"
    fig.suptitle(title or f"Fig. 2 under uncertainty ({name}, {shown})")
    fig.tight_layout()
    return _finish(fig, path)


def _fan_panel(ax, t, runs: np.ndarray, nominal) -> None:
    """Runs (N, m) as thin lines, their 5-95 % band and median, and the nominal run."""
    if len(runs):
        alpha = float(np.clip(8.0 / len(runs), 0.03, 0.5))
        ax.plot(t, runs.T, color="C0", lw=0.6, alpha=alpha)
        lo, mid, hi = np.percentile(runs, [5, 50, 95], axis=0)
        ax.fill_between(t, lo, hi, color="C1", alpha=0.3, lw=0, label="5-95 %")
        ax.plot(t, mid, color="C1", lw=1.2, label="median")
    if nominal is not None:
        ax.plot(t, nominal, color="k", lw=1.4, ls="--", label="nominal")
    ax.grid(True, alpha=0.3)
    ax.set_xlim(t[0], t[-1])
