"""ANYmal C's 10-s run as an HTML playback: the file's size, when it starts playing and
when its first frame with the robot's meshes comes, in headless Chromium.

    python benchmarks/viewer_first_frame.py --baseline /path/to/main/src --runs 3

Writes ANYmal C (example-robot-data) falling freely for 10 s, 1,001 samples, with `python
-m gagen simulate MODEL --floating-base --duration 10 --points 1001 --html`: once with this
tree's gagen and, with --baseline SRC, once more with the gagen in SRC (another checkout's
src folder, its runtime built in place; main's for a before-and-after). Then opens the
files in turn, a fresh Chromium for each (runs interleaved, so that both files meet the
same machine load), and prints per file its size and the medians of the two times
(benchmarks/viewer_playback.py says how each is taken), with the load average.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))
from viewer_playback import one_run

ROBOT = "example-robot-data/robots/anymal_c_simple_description/urdf/anymal.urdf"


def robot_share() -> Path:
    """The cmeel share folder that holds example-robot-data (its package:// root)."""
    for root in {sys.prefix, sys.base_prefix}:
        for found in Path(root).glob("lib/python3*/site-packages/cmeel.prefix/share"):
            if (found / ROBOT).is_file():
                return found
    raise SystemExit("example-robot-data is not installed (pip install example-robot-data)")


def write_playback(src: Path, out: Path) -> Path:
    """ANYmal C's 10-s playback written by the gagen in `src`."""
    share = robot_share()
    env = dict(os.environ, PYTHONPATH=str(src))
    done = subprocess.run([sys.executable, "-W", "ignore", "-m", "gagen", "simulate",
                           str(share / ROBOT), "--floating-base", "--duration", "10",
                           "--points", "1001", "--html", "--package-path", str(share),
                           "--out", str(out)], env=env, capture_output=True, text=True,
                          check=False)
    if done.returncode != 0:
        raise SystemExit(f"gagen simulate ({src}) failed:\n{done.stderr}")
    return out / "simulate.html"


def main() -> int:
    args = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    args.add_argument("--baseline", type=Path, metavar="SRC",
                      help="another gagen's src folder (built in place) to compare with")
    args.add_argument("--runs", type=int, default=3)
    args.add_argument("--timeout", type=float, default=120.0)
    args.add_argument("--out", type=Path, help="where the files are written (default: a "
                      "temporary folder)")
    options = args.parse_args()
    out = options.out or Path(tempfile.mkdtemp(prefix="gagen-first-frame-"))
    sources = {"this tree": HERE.parent / "src"}
    if options.baseline is not None:
        sources = {"baseline": options.baseline.resolve(), **sources}
    files = {label: write_playback(src, out / label.replace(" ", "_"))
             for label, src in sources.items()}
    load = [os.getloadavg()[0]]
    results: dict[str, list[tuple[float, float]]] = {label: [] for label in files}
    for _ in range(options.runs):
        for label, path in files.items():
            results[label].append(one_run(path, options.timeout, (1024, 700)))
            load.append(os.getloadavg()[0])
    for label, path in files.items():
        size = path.stat().st_size
        runs = results[label]
        print(f"{label} ({sources[label]}): {size / 1e6:.2f} MB; playback starts after "
              f"{statistics.median(r[0] for r in runs):.2f} s, first frame with the robot "
              f"after {statistics.median(r[1] for r in runs):.2f} s (medians of "
              f"{len(runs)}: " + ", ".join(f"{a:.2f}/{b:.2f}" for a, b in runs) + ")")
    print(f"window 1024 x 700, headless Chromium (software WebGL); load average "
          f"{min(load):.1f}-{max(load):.1f} on {os.cpu_count()} cores during the runs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
