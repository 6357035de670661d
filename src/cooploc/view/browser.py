"""Load a viewer page in headless Chromium: what it rendered, its JavaScript errors, a screenshot.

Used by the browser test, the page benchmark and to take the documentation's
screenshots. Chromium is driven through its command line only (``--dump-dom`` after a
``--virtual-time-budget``, ``--screenshot``): no driver, no DevTools client, no extra
Python package, and every flag that would reach the network is off, so it runs
offline. The page's own hooks (`cooploc.view.page`) write the errors and the render
status into the DOM that ``--dump-dom`` prints.
"""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["PageReport", "chromium", "load_page", "screenshot"]

_CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "chrome")
_OFFLINE_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run",
                  "--disable-default-apps", "--disable-extensions", "--mute-audio",
                  "--hide-scrollbars")


def chromium() -> str | None:
    """Path of a Chromium (or Chrome) binary, or None (``$COOPLOC_CHROMIUM`` wins)."""
    wanted = os.environ.get("COOPLOC_CHROMIUM")
    if wanted:
        return wanted if Path(wanted).is_file() else shutil.which(wanted)
    for name in _CANDIDATES:
        found = shutil.which(name)
        if found:
            return found
    return None


@dataclass(frozen=True)
class PageReport:
    """What the page reported after loading: its JSON status, JavaScript errors, the DOM."""

    status: dict[str, Any]
    errors: list[str]
    dom: str


def _run(args: list[str], timeout: float) -> subprocess.CompletedProcess:
    binary = chromium()
    if binary is None:
        raise FileNotFoundError("no chromium binary found (apt-get install chromium)")
    with tempfile.TemporaryDirectory(prefix="cooploc-chromium-") as profile:
        return subprocess.run([binary, *_OFFLINE_FLAGS, f"--user-data-dir={profile}", *args],
                              capture_output=True, text=True, timeout=timeout, check=False)


def _hook(dom: str, element: str) -> str:
    found = re.search(rf'<pre id="{element}"[^>]*>(.*?)</pre>', dom, re.S)
    return html.unescape(found.group(1)) if found else ""


def load_page(page: str | os.PathLike[str], budget_ms: int = 20000, timeout: float = 180.0) -> PageReport:
    """Load `page` from disk and read its hooks from the DOM after `budget_ms` of virtual time."""
    url = Path(page).resolve().as_uri()
    done = _run([f"--virtual-time-budget={budget_ms}", "--dump-dom", url], timeout)
    dom = done.stdout
    status_text = _hook(dom, "cooploc-status")
    status = json.loads(status_text) if status_text.strip() else {}
    errors_text = _hook(dom, "cooploc-errors")
    errors = json.loads(errors_text) if errors_text.strip() else ["page hooks missing from the DOM"]
    return PageReport(status, errors, dom)


def screenshot(page: str | os.PathLike[str], png: str | os.PathLike[str], size: tuple[int, int] = (1400, 860),
               budget_ms: int = 20000, timeout: float = 180.0, fragment: str = "") -> Path:
    """A PNG screenshot of `page` at `size` pixels; `fragment` is the page's URL fragment
    (``step=K``, ``x=x0,x1&y=y0,y1``: see `cooploc.view.page`)."""
    out = Path(png).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    url = Path(page).resolve().as_uri() + (f"#{fragment}" if fragment else "")
    _run([f"--virtual-time-budget={budget_ms}", f"--window-size={size[0]},{size[1]}",
          f"--screenshot={out}", url], timeout)
    if not out.is_file():
        raise RuntimeError(f"chromium wrote no screenshot to {out}")
    return out
