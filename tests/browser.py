"""A real headless browser for the tests of HTML pages: Debian's chromium, or a skip that names it."""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest


def browser():
    """Debian's chromium, or a skip naming it (a failure where MOCAPFLOW_REQUIRE_BROWSER=1)."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        if os.environ.get("MOCAPFLOW_REQUIRE_BROWSER") == "1":
            pytest.fail("chromium is missing but MOCAPFLOW_REQUIRE_BROWSER=1; install it (apt-get install chromium)")
        pytest.skip("chromium is not installed (apt-get install chromium): the report's 3D view is not checked in a "
                    "browser")
    return found


def run_browser(page, tmp_path, *args):
    """The page loaded in headless chromium, its script run; returns the process."""
    return subprocess.run([browser(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                           "--disable-component-update", "--disable-sync", "--no-first-run",
                           f"--user-data-dir={tmp_path / 'chromium-profile'}", "--virtual-time-budget=3000", *args,
                           page.as_uri()], capture_output=True, text=True, timeout=120, check=False)
