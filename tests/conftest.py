"""Shared fixtures: every compiled build of the test session goes to one private cache."""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

# Keep the test-suite out of the user's cache, also for code that does not take cache_dir.
_SESSION_CACHE = Path(tempfile.mkdtemp(prefix="gagen-test-cache-"))
os.environ.setdefault("GAGEN_CACHE_DIR", str(_SESSION_CACHE))
sys.path.insert(0, str(Path(__file__).parent))

REPO = Path(__file__).resolve().parents[1]
# Copies of ../shared/urdf (licences alongside), so a clean clone tests the real robots.
SHARED_URDF = REPO / "tests" / "data" / "urdf"


def pytest_sessionfinish(session, exitstatus):
    shutil.rmtree(_SESSION_CACHE, ignore_errors=True)


@pytest.fixture(scope="session")
def cache_dir() -> Path:
    return Path(os.environ["GAGEN_CACHE_DIR"])
