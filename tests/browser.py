"""Headless Chromium for the tests that load a page in a real browser (the report, the docs site): where
Chromium is, and the flags every such run shares. A test skips visibly when :func:`find_chromium` returns
None (CI installs Chromium: ``.ci/run``)."""

from __future__ import annotations

import shutil
from pathlib import Path

#: where Chromium is looked for, in order (Debian's package first)
CHROMIUM_CANDIDATES = ("/usr/bin/chromium", "chromium", "chromium-browser", "google-chrome")
#: the reason a browser test gives when it skips
NO_CHROMIUM = "Chromium is not installed (apt-get install -y chromium); the browser check did not run"


def find_chromium() -> str | None:
    """The path of the first Chromium found, or None."""
    for name in CHROMIUM_CANDIDATES:
        path = shutil.which(name)
        if path:
            return path
    return None


def headless(chromium: str, profile: Path, *args: str) -> list[str]:
    """The command line of one headless run with a private profile folder, no network and no first-run
    pages, followed by ``args`` (e.g. ``--dump-dom URL``)."""
    return [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={profile}", *args]
