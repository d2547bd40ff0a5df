"""Read back what a viser HTML playback file will draw: its embedded scene recording.

The file holds `window.__VISER_EMBED_DATA__ = "<base64>"`: viser's `.viser` format, an
8-byte size and a zstd stream of [8-byte msgpack length][msgpack {durationSeconds,
messages: [(time, message)], viserVersion, binaryBufferLengths}][aligned binary buffers]
(viser.infra.StateSerializer.serialize). The poses of the scene's nodes at a time are
replayed here from the messages, and nodes are composed along their names' paths as
viser composes them (`/a/b` is placed in `/a`).
"""

from __future__ import annotations

import base64
import re
from dataclasses import dataclass

import numpy as np

_EMBED = re.compile(rb'window\.__VISER_EMBED_DATA__="([A-Za-z0-9+/=]*)"')


@dataclass
class Recording:
    duration: float
    messages: list  # (time, message dict), in time order
    version: str

    def at(self, time: float) -> dict[str, dict]:
        """Each node's state at `time`: {"position", "wxyz", "visible", "type", "props"}."""
        nodes: dict[str, dict] = {}
        for when, message in self.messages:
            if when > time + 1e-12:
                break
            kind, name = message.get("type", ""), message.get("name")
            if name is None:
                continue
            if kind in ("SetPositionMessage", "SetOrientationMessage",
                        "SetSceneNodeVisibilityMessage") and name not in nodes:
                continue  # a node viser made itself (the root, the world axes)
            if kind == "SetPositionMessage":
                nodes[name]["position"] = np.array(message["position"], dtype=float)
            elif kind == "SetOrientationMessage":
                nodes[name]["wxyz"] = np.array(message["wxyz"], dtype=float)
            elif kind == "SetSceneNodeVisibilityMessage":
                nodes[name]["visible"] = bool(message["visible"])
            elif kind == "RemoveSceneNodeMessage":
                nodes.pop(name, None)
            elif "props" in message and kind.endswith("Message"):
                props = message["props"]
                nodes[name] = {"type": kind, "props": props, "visible": True,
                               "position": np.array(props.get("position", (0, 0, 0)), float),
                               "wxyz": np.array(props.get("wxyz", (1, 0, 0, 0)), float)}
        return nodes

    def world_pose(self, nodes: dict, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(R, p) of a node in the world: its ancestors' poses composed."""
        R, p = np.eye(3), np.zeros(3)
        parts = name.strip("/").split("/")
        for k in range(1, len(parts) + 1):
            node = nodes.get("/" + "/".join(parts[:k]))
            if node is None:
                continue
            Rk = rotation(node["wxyz"])
            p = p + R @ node["position"]
            R = R @ Rk
        return R, p

    def times(self) -> list[float]:
        return sorted({when for when, _ in self.messages})


def rotation(wxyz) -> np.ndarray:
    w, x, y, z = np.asarray(wxyz, dtype=float) / np.linalg.norm(wxyz)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def read_recording(path) -> Recording:
    """The recording embedded in a viser HTML file."""
    import msgspec
    import zstandard

    with open(path, "rb") as handle:
        page = handle.read()
    found = _EMBED.search(page)
    if found is None:
        raise ValueError(f"{path}: no embedded viser recording")
    data = base64.b64decode(found.group(1))
    inner_size = int.from_bytes(data[:8], "little")
    inner = zstandard.ZstdDecompressor().decompress(data[8:], max_output_size=inner_size)
    length = int.from_bytes(inner[:8], "little")
    payload = msgspec.msgpack.decode(inner[8:8 + length])
    return Recording(float(payload["durationSeconds"]), list(payload["messages"]),
                     payload["viserVersion"])
