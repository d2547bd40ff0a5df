"""Ctrl-C in a subprocess, for the tests that check that long runs stop."""

from __future__ import annotations

import signal
import subprocess
import sys
import time


def interrupt_after_ready(script: str, delay: float = 1.0) -> tuple[int, str, float]:
    """Run `script` (which prints "ready" before its long run), send SIGINT `delay` seconds
    after "ready", and return (exit code, the rest of stdout, seconds it took to stop)."""
    # A shell starts background jobs with SIGINT ignored, and Python then installs no
    # handler of its own: give the script Python's usual Ctrl-C whatever it inherited.
    script = ("import signal\nsignal.signal(signal.SIGINT, signal.default_int_handler)\n"
              + script)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(delay)  # well inside the run, which would take hours
        sent = time.perf_counter()
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
        return proc.returncode, out, time.perf_counter() - sent
    finally:
        proc.kill()


def seconds_to_stop(call: str) -> float:
    """Run `call` (Python, with numpy as np, gagen, and dyn = rrr loaded) in a subprocess,
    press Ctrl-C a second into it, check that it raised KeyboardInterrupt; the seconds it
    took to stop."""
    script = (
        "import sys\nimport numpy as np\nimport gagen\ndyn = gagen.load('rrr')\n"
        "print('ready', flush=True)\n"
        f"try:\n    {call}\n"
        "except KeyboardInterrupt:\n    print('interrupted', flush=True)\n    sys.exit(3)\n"
        "sys.exit(4)\n")
    code, out, seconds = interrupt_after_ready(script)
    assert code == 3 and "interrupted" in out, (code, out)
    return seconds
