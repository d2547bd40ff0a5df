"""How big an HTML playback file is and how soon it plays in headless Chromium.

    python benchmarks/viewer_playback.py out/anymal/simulate.html --runs 3

Opens the file (a fresh Chromium each run, software WebGL: SwiftShader) and reports, from
the navigation: when the playback starts (the embedded recording decoded, the playback bar
shown and its clock running), and when the first frame shows the robot (its meshes decoded
and drawn: the canvas holds coloured pixels, ANYmal C's red shell; a grey robot needs
another test), the playback held at t = 0 from when it starts (a falling robot leaves the
camera's view). Medians over the runs; the machine's load average is printed with them.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from chromium import Browser

TIME_INPUT = "input.mantine-NumberInput-input"


def coloured(image: np.ndarray) -> int:
    rgb = image.astype(int)
    return int(((rgb.max(axis=2) - rgb.min(axis=2)) > 80).sum())


def one_run(path: Path, timeout: float, window: tuple[int, int]) -> tuple[float, float]:
    with Browser(timeout=timeout, window=window) as browser:
        start = browser.open(path)
        browser.wait_for(f"(() => {{ const e = document.querySelector('{TIME_INPUT}'); "
                         "return e !== null && parseFloat(e.value) > 0; })()",
                         timeout=timeout, every=0.01)
        playing = time.monotonic() - start
        browser.type_into(TIME_INPUT, "0")  # held at the start, where the camera looks
        browser.evaluate("(() => { const s = document.createElement('style'); s.textContent "
                         "= '.mantine-Notifications-root { display: none !important; }'; "
                         "document.head.appendChild(s); return true; })()")
        while time.monotonic() - start < timeout:
            if coloured(np.asarray(browser.screenshot())) > 500:
                return playing, time.monotonic() - start
            browser.pump(0.05)
        raise TimeoutError(f"no robot drawn within {timeout} s")


def main() -> int:
    args = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    args.add_argument("file", type=Path)
    args.add_argument("--runs", type=int, default=3)
    args.add_argument("--timeout", type=float, default=120.0)
    args.add_argument("--window", type=int, nargs=2, default=(1024, 700), metavar=("W", "H"),
                      help="the browser window in pixels (default: 1024 700)")
    options = args.parse_args()
    size = options.file.stat().st_size
    results = [one_run(options.file, options.timeout, tuple(options.window))
               for _ in range(options.runs)]
    playing = statistics.median(r[0] for r in results)
    drawn = statistics.median(r[1] for r in results)
    print(f"{options.file}: {size / 1e6:.2f} MB ({size:,} bytes)")
    print(f"playback starts after {playing:.2f} s, first frame with the robot after "
          f"{drawn:.2f} s (medians of {options.runs}: "
          + ", ".join(f"{a:.2f}/{b:.2f}" for a, b in results) + ")")
    print(f"window {options.window[0]} x {options.window[1]}; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    sys.exit(main())
