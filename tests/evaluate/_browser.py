"""A headless Chromium for the report tests: Debian's ``chromium`` package (``.ci/run`` installs
it with apt; browser builds that download themselves cannot be fetched here).

Where no Chromium is found the browser tests skip, except when ``RADAR4DGS_REQUIRE_BROWSER=1``
(set by ``.ci/run``): then CI lacking its browser fails instead of passing silently.
``RADAR4DGS_CHROMIUM`` names another executable."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

REQUIRE_ENV = "RADAR4DGS_REQUIRE_BROWSER"
EXECUTABLE_ENV = "RADAR4DGS_CHROMIUM"
NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    named = os.environ.get(EXECUTABLE_ENV)
    if named:
        return shutil.which(named) or (named if Path(named).is_file() else None)
    return next((path for path in map(shutil.which, NAMES) if path), None)


def chromium_or_skip() -> str:
    """The Chromium executable; skips the test without one, fails it where CI requires one."""
    path = find_chromium()
    if path is not None:
        return path
    message = f"no Chromium executable ({', '.join(NAMES)}; or set {EXECUTABLE_ENV})"
    if os.environ.get(REQUIRE_ENV) == "1":
        pytest.fail(f"{message}, and {REQUIRE_ENV}=1 says this run must check the report in a browser "
                    f"(apt-get install -y chromium)")
    pytest.skip(f"{message}: apt-get install -y chromium - headless browser checks skipped")


def headless(chromium: str, profile: Path, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run headless Chromium with ``args``; ``--no-sandbox`` because CI runs as root."""
    command = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
               "--hide-scrollbars", "--mute-audio", "--no-first-run", f"--user-data-dir={profile}", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=timeout)
