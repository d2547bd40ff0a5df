"""The HTML playback in headless Chromium (Debian's `chromium`): it loads from a file with no
console error and no request beyond the file, the robot's meshes are drawn, and
screenshots at two times of a run differ where the robot moved and match where it did not.

Behind the `browser` marker; skipped (with the reason) where no Chromium is installed.
.ci/run installs Debian's chromium, so CI runs these in its default step.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("viser")
pytest.importorskip("trimesh")
pytest.importorskip("collada")
pytest.importorskip("websockets")

from chromium import Browser, chromium_path
from viewer_robots import swing, toy_robot

import gagen
from gagen.viewer import write_html

pytestmark = [pytest.mark.browser,
              pytest.mark.skipif(chromium_path() is None, reason="no Chromium installed "
                                 "(Debian: apt-get install chromium)")]

TIME_INPUT = "input.mantine-NumberInput-input"
# Chromium warns about software WebGL in a notification that may come and go: hidden
HIDE_NOTES = ("(() => { const s = document.createElement('style'); s.textContent = "
              "'.mantine-Notifications-root { display: none !important; }'; "
              "document.head.appendChild(s); return true; })()")


def red(image: np.ndarray) -> np.ndarray:
    r, g, b = (image[..., k].astype(int) for k in range(3))
    return (r > 110) & (g < 90) & (b < 90) & (r > 2 * g)


def blue(image: np.ndarray) -> np.ndarray:
    r, g, b = (image[..., k].astype(int) for k in range(3))
    return (b > 110) & (r < 90) & (b > 1.5 * g)


def canvas_shot(browser: Browser) -> np.ndarray:
    """The 3-D canvas only (not the playback bar, whose time display changes)."""
    box = browser.evaluate("(() => { const r = document.querySelector('canvas')"
                           ".getBoundingClientRect(); return [r.left, r.top, r.right, "
                           "r.bottom]; })()")
    image = np.asarray(browser.screenshot())
    left, top, right, bottom = (round(v) for v in box)
    return image[top:bottom, left:right]


def at_time(browser: Browser, seconds: float, settle: float = 1.0) -> np.ndarray:
    # typing a time pauses the playback there; typed twice, since the first keystrokes
    # may race the running clock's own updates of the field
    browser.type_into(TIME_INPUT, f"{seconds:g}")
    browser.pump(0.2)
    browser.type_into(TIME_INPUT, f"{seconds:g}")
    browser.pump(settle)
    return canvas_shot(browser)


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    """The toy robot's run (every joint moves for 1 s, then holds still for 1 s), opened
    in Chromium with its meshes drawn."""
    folder = tmp_path_factory.mktemp("browser")
    urdf, packages = toy_robot(folder)
    dyn = gagen.load(urdf)
    t = np.linspace(0.0, 2.0, 201)
    path = write_html(folder / "toy.html", dyn, t, swing(dyn, t, rest_after=1.0),
                      package_dirs=[packages])
    with Browser() as browser:
        browser.open(path)
        browser.wait_for(f"document.querySelector('{TIME_INPUT}') !== null", timeout=60)
        browser.evaluate(HIDE_NOTES)
        deadline = time.monotonic() + 120  # software WebGL on a busy machine: seconds
        while True:  # meshes are decoded and faded in after the page loads
            shot = at_time(browser, 0.2, settle=0.5)
            if red(shot).sum() > 200 and blue(shot).sum() > 200 or time.monotonic() > deadline:
                break
        yield browser


def test_page_loads_offline_without_errors(page):
    page.pump(0.5)
    assert page.console_errors == []
    assert page.remote_requests() == []
    assert any("Embedded data loaded" in line for line in page.console)


def test_the_robots_meshes_are_drawn(page):
    shot = at_time(page, 0.2)
    assert red(shot).sum() > 200, "the base (a red STL mesh) is not drawn"
    assert blue(shot).sum() > 200, "the arm (a blue OBJ mesh) is not drawn"


def test_screenshots_differ_where_the_robot_moved_and_match_where_it_did_not(page):
    moving = at_time(page, 0.2)
    moved = at_time(page, 1.2)
    still = at_time(page, 1.8)
    changed = np.any(moving != moved, axis=2)
    # the arm moved: its pixels changed
    arm = blue(moving) | blue(moved)
    assert changed[arm].mean() > 0.3 and (blue(moving) != blue(moved)).sum() > 200
    # the base did not: where it was drawn, nothing changed
    base = red(moving)
    assert base.sum() > 200 and not changed[base].any()
    # nor did anything between 1.2 s and 1.8 s, when the robot held still
    assert np.array_equal(moved, still)
    assert page.console_errors == []
