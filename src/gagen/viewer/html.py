"""One self-contained HTML file that plays a simulation back: viser's scene recording.

Why viser: its client is built into one HTML file of 0.8 MB (React, three.js and its glTF
loader inlined, no CDN), and `StateSerializer.as_html()` embeds a scene recording in it
(zstd-compressed messages, meshes as glTF): the page plays offline in any current browser,
from a file, with a time slider, play/pause and speed (0.5x-8x), and fetches nothing.
meshcat's `static_html` also inlines its three.js bundle, but its animations are three.js
clips of the whole scene state per frame and its Python package has not had a release
since November 2021 (0.3.2); viser is maintained and is also the live viewer
(`gagen.viewer.live`).

The file is written by building the robot in a viser server bound to 127.0.0.1 (on a free
port, no client ever connects), recording a pose message per moving body per sample,
then the page; nothing is written until the page is complete (a temporary file renamed).
"""

from __future__ import annotations

import html as html_text
import logging
import math
import os
from pathlib import Path

import numpy as np

from .scene import MeshLibrary, RobotScene, quiet_server, safe_name
from .visuals import robot_visuals

log = logging.getLogger(__name__)

MAX_FRAMES = 20_000  # samples a file plays (all runs together); more are thinned evenly
MAX_RUNS = 100  # runs of a sweep in one file
GHOST_ALPHA = 0.3  # opacity of the overlaid runs after the first
MODES = ("overlay", "sequence")


def write_html(path, dyn, t, q, p=None, *, package_dirs=None, mode: str = "overlay",
               labels=None, max_frames: int = MAX_FRAMES) -> Path:
    """Write a self-contained HTML playback of one or several runs of `dyn`.

    t       sample times (m,), increasing.
    q       configurations (m, nq) of one run, or (k, m, nq) of k runs (a sweep's chosen
            runs) on the same times.
    p       None (defaults), a dict of overrides or a parameter vector for every run; for
            k runs also a list of k of them, or a (k, P) array: the placements follow each
            run's parameters (link lengths).
    mode    k runs "overlay": drawn together, the first opaque and the others ghosted
            (translucent); "sequence": one at a time, one after the other, each labelled.
    labels  k names of the runs (default "run 0", ...), shown in "sequence" mode.
    package_dirs  folders for a URDF's package:// meshes (with $ROS_PACKAGE_PATH).

    A mesh that cannot be read is a `gagen.viewer.MeshWarning` and its link is drawn as its
    inertia box. Returns the path written.
    """
    path = Path(path)
    t, runs = _samples(t, q, dyn.nq)
    params = _parameters(dyn, p, len(runs))
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    if len(runs) > MAX_RUNS:
        raise ValueError(f"{len(runs)} runs: a file shows at most {MAX_RUNS}")
    labels = [f"run {k}" for k in range(len(runs))] if labels is None else list(labels)
    if len(labels) != len(runs):
        raise ValueError(f"{len(labels)} labels for {len(runs)} runs")
    per_run = max_frames // len(runs) if mode == "sequence" else max_frames
    keep = _thinned(len(t), max(2, per_run))
    if len(keep) < len(t):
        log.info(f"the file plays {len(keep)} of the {len(t)} samples (every "
                 f"{keep[1] - keep[0]}th)")
    visuals = robot_visuals(dyn, package_dirs, params[0])
    page = _recording(dyn, visuals, t[keep], [run[keep] for run in runs], params, mode,
                      labels)
    title = f"<title>gagen: {html_text.escape(safe_name(dyn.info.name))}</title>"
    page = page.replace("<title>Viser</title>", title, 1)
    _write_atomically(path, page.encode("utf-8"))
    return path


def _samples(t, q, nq: int) -> tuple[np.ndarray, list[np.ndarray]]:
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    if t.ndim != 1 or t.size < 1:
        raise ValueError(f"t must be a 1-D array of sample times, got shape {t.shape}")
    if q.ndim == 2:
        q = q[None]
    if q.ndim != 3 or q.shape[1:] != (t.size, nq):
        raise ValueError(f"q must have shape ({t.size}, {nq}) or (runs, {t.size}, {nq}), got "
                         f"{q.shape}")
    if not (np.isfinite(t).all() and np.isfinite(q).all()):
        raise ValueError("t and q must be finite (a failed run's samples are NaN: leave it "
                         "out)")
    if np.any(np.diff(t) < 0):
        raise ValueError("t must be increasing")
    return t, list(q)


def _parameters(dyn, p, runs: int) -> list[np.ndarray]:
    stacked = isinstance(p, (list, tuple)) or (isinstance(p, np.ndarray) and p.ndim == 2)
    if not stacked:
        return [dyn.parameter_vector(p)] * runs
    if len(p) != runs:
        raise ValueError(f"p has {len(p)} rows for {runs} runs")
    return [dyn.parameter_vector(row) for row in p]


def _thinned(m: int, frames: int) -> np.ndarray:
    """Sample indices: all of them, or every s-th (and the last) to keep at most `frames`."""
    if m <= frames:
        return np.arange(m)
    stride = math.ceil((m - 1) / (frames - 1))
    keep = np.arange(0, m, stride)
    return keep if keep[-1] == m - 1 else np.append(keep, m - 1)


def _recording(dyn, visuals, t, runs, params, mode: str, labels) -> str:
    """The page: the robots built in a private server, their motion recorded."""
    with quiet_server() as server:
        library = MeshLibrary(visuals)
        several = len(runs) > 1
        scenes = [RobotScene(server.scene, dyn, visuals, library,
                             prefix=f"/gagen/run_{k}" if several else "/gagen", p=params[k],
                             ghost=GHOST_ALPHA if several and mode == "overlay" and k else None,
                             q0=run[0])
                  for k, run in enumerate(runs)]
        aim_camera(server, scenes[0], runs[0][0])
        add_ground(server, scenes[0], runs[0][0])
        if mode == "sequence" and several:
            _label_runs(server, scenes, runs, labels)
        serializer = server.get_scene_serializer()
        recorder = PoseRecorder(serializer, server.scene)
        poses = [scene.pose_arrays(run) for scene, run in zip(scenes, runs)]
        if mode == "sequence" and several:
            _play_in_sequence(serializer, recorder, scenes, poses, t)
        else:
            _play_together(serializer, recorder, scenes, poses, t)
        return serializer.as_html()


def _play_together(serializer, recorder, scenes, poses, t) -> None:
    last = [None] * len(scenes)
    for i in range(len(t)):
        if i:
            serializer.insert_sleep(float(t[i] - t[i - 1]))
        for k, scene in enumerate(scenes):
            last[k] = recorder.move(scene, poses[k], i, last[k])


def _play_in_sequence(serializer, recorder, scenes, poses, t) -> None:
    step = float(t[1] - t[0]) if len(t) > 1 else 0.1
    for k, scene in enumerate(scenes):
        if k:
            serializer.insert_sleep(step)
            scenes[k - 1].root.visible = False
            scene.root.visible = True
        last = None
        for i in range(len(t)):
            if i:
                serializer.insert_sleep(float(t[i] - t[i - 1]))
            last = recorder.move(scene, poses[k], i, last)


def _label_runs(server, scenes, runs, labels) -> None:
    for k, (scene, run) in enumerate(zip(scenes, runs)):
        scene.root.visible = k == 0
        origin, _ = scene.pose_arrays(run[:1])
        top = origin[0].max(axis=0) + np.array([0.0, 0.0, 0.15])
        server.scene.add_label(f"{scene.prefix}/label", str(labels[k])[:80],
                               position=tuple(float(v) for v in top))


def add_ground(server, scene: RobotScene, q) -> None:
    """A grid on the world's xy-plane (z = 0), 10 cm cells, around the robot."""
    origin, _ = scene.pose_arrays(np.atleast_2d(q))
    extent = float(np.abs(origin[0][:, :2]).max()) + 0.5
    size = 2.0 * math.ceil(extent)
    server.scene.add_grid("/ground", width=size, height=size, cell_size=0.1, section_size=0.5,
                          plane="xy")


def aim_camera(server, scene: RobotScene, q) -> None:
    """Look at the robot in configuration q from the front, right and above."""
    origin, _ = scene.pose_arrays(np.atleast_2d(q))
    points = origin[0]
    centre = (points.max(axis=0) + points.min(axis=0)) / 2
    radius = max(float(np.linalg.norm(points - centre, axis=1).max()) + 0.15, 0.3)
    direction = np.array([1.3, -1.6, 0.9])
    direction /= np.linalg.norm(direction)
    server.initial_camera.look_at = tuple(float(v) for v in centre)
    server.initial_camera.position = tuple(float(v) for v in centre + 2.2 * radius * direction)


class PoseRecorder:
    """Pose messages of the bodies, straight into the recording.

    Through viser's public handles each pose change also wakes the server's event loop
    (0.2 ms a message here: 5 s for ANYmal's 1,001 samples), and a change within viser's
    `allclose` tolerance (1e-5 relative) is not sent. The recording needs neither, so the
    message is given to the serializer directly (viser's own message classes); if this
    viser lacks them, the handles are used instead."""

    def __init__(self, serializer, scene_api):
        try:
            from viser import _messages

            self._direct = (serializer._insert_message, scene_api._owner_id,
                            _messages.SetPositionMessage, _messages.SetOrientationMessage)
        except (ImportError, AttributeError):
            self._direct = None

    def move(self, scene: RobotScene, poses, i: int, last):
        """Send body poses of sample i that differ from `last` (None: sample 0, already in
        the scene); returns what to compare the next sample with."""
        origin, quaternion = poses[0][i], poses[1][i]
        if last is None:
            return origin, quaternion
        changed = np.flatnonzero(np.any(origin != last[0], axis=1)
                                 | np.any(quaternion != last[1], axis=1))
        for b in changed:
            self._send(scene, b, tuple(float(v) for v in origin[b]),
                       tuple(float(v) for v in quaternion[b]))
        return origin, quaternion

    def _send(self, scene: RobotScene, b: int, position, wxyz) -> None:
        if self._direct is not None:
            insert, owner, position_message, orientation_message = self._direct
            try:
                for message in (orientation_message(scene.body_nodes[b], wxyz),
                                position_message(scene.body_nodes[b], position)):
                    message.owner = owner
                    insert(message)
                return
            except (TypeError, AttributeError):
                self._direct = None  # another viser: its handles from now on
        handle = scene.handles[b]
        handle.wxyz = wxyz
        handle.position = position


def _write_atomically(path: Path, data: bytes) -> None:
    """Write the file whole or not at all (a temporary file next to it, renamed)."""
    if path.exists() and path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder")
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        temporary.write_bytes(data)
        os.replace(temporary, path)
    finally:
        if temporary.exists():
            temporary.unlink()
