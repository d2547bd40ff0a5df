"""The live viewer of `python -m gagen view MODEL [--run RUN.csv]`: a viser server.

The page shows the robot in its neutral configuration with its visuals, a slider per joint
(a floating base: its position and roll, pitch, yaw), a "Show frames" switch that draws
the axes of every frame of `dyn.frames`, and, with a run, its playback: a time slider,
play/pause and the speed. Every placement is `dyn.frame_placement`'s.

The server listens on 127.0.0.1 by default (give `host="0.0.0.0"` to share it on the
network) and on `port`, or the next free one.
"""

from __future__ import annotations

import contextlib
import io
import math
import signal
import threading
import time

import numpy as np

from .html import add_ground, add_lights, aim_camera, opening_view, texels_per_metre
from .placements import wxyz
from .scene import MeshLibrary, RobotScene
from .visuals import robot_visuals, rotation_rpy

SPEEDS = ("0.1x", "0.25x", "0.5x", "1x", "2x", "4x")
FPS = 30.0


class LiveViewer:
    """A running viewer: `url`, `port`, `set_configuration(q)`, `set_time(t)`, `play()`,
    `pause()`, `serve_forever()`, `stop()`."""

    def __init__(self, dyn, run=None, p=None, package_dirs=None, host: str = "127.0.0.1",
                 port: int = 8080):
        import viser

        self.dyn, self.p = dyn, dyn.parameter_vector(p)
        self.run = None if run is None else _checked_run(run, dyn.nq)
        self.q = dyn.neutral() if self.run is None else self.run[1][0].copy()
        visuals = robot_visuals(dyn, package_dirs, self.p)
        with contextlib.redirect_stdout(io.StringIO()):  # viser's address table
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.port = self.server.get_port()
        self.url = f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{self.port}"
        self._lock = threading.RLock()
        self._stopped = threading.Event()
        scene = self.server.scene
        view = opening_view(dyn, self.q, self.p)
        library = MeshLibrary(visuals, texels_per_metre=texels_per_metre(self.server, view))
        self.robot = RobotScene(scene, dyn, visuals, library, p=self.p, q0=self.q)
        add_ground(self.server, self.robot, self.q)
        aim_camera(self.server, view)
        add_lights(self.server)
        self._frames = None
        self.sliders = self._joint_sliders()
        self._frames_switch()
        self.playing, self.speed, self.time = False, 1.0, 0.0
        if self.run is not None:
            self._playback()

    # --- the GUI ---------------------------------------------------------------------------

    def _joint_sliders(self) -> list:
        """(slider, what it sets) per joint; a floating joint has six."""
        gui, out = self.server.gui, []
        iq = 0
        with gui.add_folder("Joints"):
            for joint in self.dyn.info.joints:
                if joint.type == "floating":
                    for k, axis in enumerate("xyz"):
                        out.append((gui.add_slider(f"{joint.name} {axis} (m)", -2.0, 2.0, 1e-3,
                                                   float(self.q[iq + k])), ("base", iq, k)))
                    for k, angle in enumerate(("roll", "pitch", "yaw")):
                        out.append((gui.add_slider(f"{joint.name} {angle} (rad)", -math.pi,
                                                   math.pi, 1e-3, 0.0), ("angle", iq, k)))
                    iq += 7
                    continue
                low, high = _range(joint)
                value = float(np.clip(self.q[iq], low, high))
                unit = "m" if joint.type == "prismatic" else "rad"
                out.append((gui.add_slider(f"{joint.name} ({unit})", low, high,
                                           (high - low) / 1000.0, value), ("joint", iq, 0)))
                iq += 1
        for slider, _ in out:
            slider.on_update(self._slider_moved)
        return out

    def _slider_moved(self, event) -> None:
        if event.client is None:  # set by the playback, not by a person
            return
        with self._lock:
            self.playing = False
            self._sync_play_button()
            self.set_configuration(self._configuration_from_sliders())

    def _configuration_from_sliders(self) -> np.ndarray:
        q = self.q.copy()
        angles: dict[int, list[float]] = {}
        for slider, (kind, iq, k) in self.sliders:
            if kind == "joint":
                q[iq] = slider.value
            elif kind == "base":
                q[iq + k] = slider.value
            else:
                angles.setdefault(iq, [0.0, 0.0, 0.0])[k] = slider.value
        for iq, (roll, pitch, yaw) in angles.items():
            w, x, y, z = wxyz(rotation_rpy(roll, pitch, yaw))
            q[iq + 3:iq + 7] = (x, y, z, w)  # gagen's quaternion order: x, y, z, w
        return q

    def _frames_switch(self) -> None:
        switch = self.server.gui.add_checkbox("Show frames", initial_value=False)

        @switch.on_update
        def _(_event) -> None:
            with self._lock:
                self._show_frames(switch.value)

    def _show_frames(self, shown: bool) -> None:
        if self._frames is None and shown:
            R, origin = self._frame_placements(self.q)
            size = max(float(np.ptp(origin, axis=0).max()), 0.2)
            self._frames = self.server.scene.add_batched_axes(
                "/gagen_frames", batched_wxyzs=wxyz(R), batched_positions=origin,
                axes_length=0.06 * size, axes_radius=0.004 * size)
        elif self._frames is not None:
            self._frames.visible = shown

    def _frame_placements(self, q) -> tuple[np.ndarray, np.ndarray]:
        placed = [self.dyn.frame_placement(q, name, self.p) for name in self.dyn.frames]
        return np.array([R for R, _ in placed]), np.array([o for _, o in placed])

    def _playback(self) -> None:
        t, _ = self.run
        gui = self.server.gui
        self.time = float(t[0])
        step = float(np.min(np.diff(t))) if len(t) > 1 and np.min(np.diff(t)) > 0 else 1e-3
        with gui.add_folder("Playback"):
            self.time_slider = gui.add_slider("Time (s)", float(t[0]), float(t[-1]),
                                              step, float(t[0]))
            self.play_button = gui.add_button("Play")
            self.speed_menu = gui.add_dropdown("Speed", SPEEDS, initial_value="1x")

        @self.time_slider.on_update
        def _(event) -> None:
            if event.client is not None:
                with self._lock:
                    self.playing = False
                    self._sync_play_button()
                    self.set_time(self.time_slider.value)

        @self.play_button.on_click
        def _(_event) -> None:
            with self._lock:
                self.play() if not self.playing else self.pause()

        @self.speed_menu.on_update
        def _(_event) -> None:
            self.speed = float(self.speed_menu.value.rstrip("x"))

    def _sync_play_button(self) -> None:
        if self.run is not None:
            self.play_button.label = "Pause" if self.playing else "Play"

    # --- the state -------------------------------------------------------------------------

    def set_configuration(self, q) -> None:
        """Show the robot at configuration q (nq,)."""
        with self._lock:
            self.q = np.array(q, dtype=float)
            self.robot.set_pose(self.q)
            if self._frames is not None and self._frames.visible:
                R, origin = self._frame_placements(self.q)
                self._frames.batched_wxyzs = wxyz(R)
                self._frames.batched_positions = origin

    def set_time(self, time_: float) -> None:
        """Show the run's sample at (or last before) `time_`."""
        with self._lock:
            t, q = self.run
            self.time = float(np.clip(time_, t[0], t[-1]))
            k = max(0, int(np.searchsorted(t, self.time, side="right")) - 1)
            self.set_configuration(q[k])
            self.time_slider.value = self.time
            for slider, (kind, iq, _) in self.sliders:
                if kind == "joint":
                    slider.value = float(np.clip(q[k, iq], slider.min, slider.max))

    def play(self) -> None:
        with self._lock:
            self.playing = self.run is not None
            self._sync_play_button()

    def pause(self) -> None:
        with self._lock:
            self.playing = False
            self._sync_play_button()

    def advance(self, seconds: float) -> None:
        """Move the playback on by `seconds` of wall time (at its speed; from the start
        again after the end)."""
        with self._lock:
            if not self.playing or self.run is None:
                return
            t = self.run[0]
            time_ = self.time + seconds * self.speed
            if time_ > t[-1]:
                time_ = float(t[0])
            self.set_time(time_)

    def serve_forever(self) -> None:
        """Play until `stop()` (or Ctrl-C, which stops the server and is raised again).

        In the main thread, Ctrl-C (SIGINT) gets a handler of its own that marks the loop to
        end after its frame: a process started in the background by a non-interactive shell
        inherits SIGINT ignored, and Python then raises no KeyboardInterrupt, so the viewer
        would never stop (as a CI run's `view` did)."""
        interrupted: list[bool] = []
        previous = None
        if threading.current_thread() is threading.main_thread():
            previous = signal.signal(signal.SIGINT, lambda *_: interrupted.append(True))
        last = time.monotonic()
        try:
            while not interrupted and not self._stopped.wait(1.0 / FPS):
                now = time.monotonic()
                self.advance(now - last)
                last = now
        finally:
            if previous is not None:
                signal.signal(signal.SIGINT, previous)
            self.stop()
        if interrupted:
            raise KeyboardInterrupt

    def stop(self) -> None:
        if not self._stopped.is_set():
            self._stopped.set()
            with contextlib.redirect_stdout(io.StringIO()):
                self.server.stop()


def start_viewer(dyn, run=None, p=None, package_dirs=None, host: str = "127.0.0.1",
                 port: int = 8080, open_browser: bool = False, play: bool = True) -> LiveViewer:
    """Start the live viewer of `dyn` (module docstring) and return it; `run` is (t, q) of a
    run to play back (`read_run`), `port` the first port tried (0: any free one)."""
    viewer = LiveViewer(dyn, run, p, package_dirs, host, port)
    if run is not None and play:
        viewer.play()
    if open_browser:
        import webbrowser

        webbrowser.open(viewer.url)
    return viewer


def _range(joint) -> tuple[float, float]:
    if joint.lower is not None and joint.upper is not None and joint.upper > joint.lower:
        return float(joint.lower), float(joint.upper)
    return (-1.0, 1.0) if joint.type == "prismatic" else (-math.pi, math.pi)


def _checked_run(run, nq: int) -> tuple[np.ndarray, np.ndarray]:
    t, q = (np.asarray(a, dtype=float) for a in run)
    if t.ndim != 1 or q.shape != (t.size, nq) or t.size == 0:
        raise ValueError(f"run must be (t (m,), q (m, {nq})), got shapes {t.shape}, {q.shape}")
    if not (np.isfinite(t).all() and np.isfinite(q).all()) or np.any(np.diff(t) < 0):
        raise ValueError("run: t and q must be finite, t increasing")
    return t, q
