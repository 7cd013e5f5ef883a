"""A headless Chromium for the viewer's tests, benchmarks and gallery: screenshots of a page
at a time given in its URL fragment, and the page's DOM after its load event.

Debian's ``chromium`` (``.ci/browser.sh`` installs it) draws WebGL in software (SwiftShader);
``--virtual-time-budget`` lets the page run its animation frames before the screenshot.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
FLAGS = ("--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--hide-scrollbars", "--mute-audio", "--no-first-run", "--disable-extensions")  # fmt: skip
TIMEOUT = 120  # s for one browser run


def find_chromium() -> str | None:
    """The Chromium executable (MBSIM_CHROMIUM, else the first of NAMES on PATH), or None."""
    env = os.environ.get("MBSIM_CHROMIUM")
    if env:
        return env if shutil.which(env) else None
    return next((p for p in map(shutil.which, NAMES) if p), None)


def _run(args: list[str], timeout: float = TIMEOUT) -> subprocess.CompletedProcess:
    exe = find_chromium()
    if exe is None:
        raise RuntimeError("no Chromium found (install it with .ci/browser.sh)")
    with tempfile.TemporaryDirectory(prefix="mbsim-chromium-") as profile:
        return subprocess.run([exe, *FLAGS, f"--user-data-dir={profile}", *args],
                              capture_output=True, text=True, timeout=timeout)  # fmt: skip


def screenshot(page: str | Path, png: str | Path, fragment: str = "", size=(1200, 700),
               budget_ms: int = 10000) -> Path:
    """PNG of ``page`` (an HTML file) opened at ``#fragment`` in a ``size`` window."""
    url = Path(page).resolve().as_uri() + (f"#{fragment}" if fragment else "")
    png = Path(png).resolve()
    proc = _run([f"--window-size={size[0]},{size[1]}", f"--virtual-time-budget={budget_ms}",
                 f"--screenshot={png}", url])  # fmt: skip
    if not png.is_file():
        raise RuntimeError(f"chromium wrote no screenshot: {proc.stderr.strip()[-300:]}")
    return png


def dump_dom(page: str | Path, fragment: str = "", size=(1200, 700),
             timeout: float = TIMEOUT) -> str:
    """The page's DOM (HTML text) right after its load event (and its handlers)."""
    url = Path(page).resolve().as_uri() + (f"#{fragment}" if fragment else "")
    return _run([f"--window-size={size[0]},{size[1]}", "--dump-dom", url], timeout).stdout
