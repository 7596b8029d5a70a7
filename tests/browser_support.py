"""What the browser tests share: Debian's chromium driven by Playwright, skipped only outside CI.

Playwright's own browser download is not reachable here, so the tests launch the system ``chromium``
(``apt-get install -y chromium``; ``make test`` installs it when it can) through ``executable_path``. With
``SPADE_REQUIRE_BROWSER=1`` (set by ``.ci/run``) a missing browser fails the test instead of skipping it.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

ARTIFACTS = Path(os.environ.get("SPADE_TEST_ARTIFACTS", "test-artifacts"))


def chromium_path() -> str:
    """The chromium executable, or skip (fail under SPADE_REQUIRE_BROWSER=1) when there is none."""
    for name in (os.environ.get("SPADE_CHROMIUM"), "chromium", "chromium-browser", "google-chrome"):
        if name and (found := shutil.which(name)):
            return found
    message = "no chromium executable: apt-get install -y chromium (or set SPADE_CHROMIUM)"
    if os.environ.get("SPADE_REQUIRE_BROWSER") == "1":
        pytest.fail(message)
    pytest.skip(message)


@contextmanager
def browser_page(width: int = 1400, height: int = 900) -> Iterator[object]:
    """A Playwright page in headless chromium; closed on exit."""
    sync_api = pytest.importorskip("playwright.sync_api")
    executable = chromium_path()
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=executable, headless=True,
                                     args=["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"])
        try:
            page = browser.new_page(viewport={"width": width, "height": height})
            yield page
        finally:
            browser.close()


def screenshot(page: object, name: str) -> Path:
    """Save a full-page screenshot under ``test-artifacts/`` (kept by CI) and return its path."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    path = ARTIFACTS / name
    page.screenshot(path=str(path), full_page=True)  # type: ignore[attr-defined]
    return path
