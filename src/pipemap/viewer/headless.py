"""Opening a viewer page in headless Chromium: what it drew, what it printed to the console, how long it took.

Used by the tests and benchmarks/bench_viewer.py. WebGL runs on SwiftShader (no GPU needed). The page marks
itself on <html> once drawn: data-ready, data-ready-ms (since navigation), data-drawn-pixels (3D view pixels
not background), data-walls, data-errors (console errors and uncaught exceptions) and, for an address with
#probe=WALL:col:row, the chainage and clock the click there read (data-probe-along, data-probe-clock).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--enable-logging=stderr", "--v=0")
_CONSOLE = re.compile(r":CONSOLE[^\]]*\] \"(.*)\", source: ")


@dataclass(frozen=True)
class PageLoad:
    attributes: dict  # the data-* attributes of <html> after loading
    console: list[str]  # every console message the page printed
    seconds: float  # the browser's wall time, start to exit
    html: str = ""  # the DOM as dumped (empty for a screenshot)

    @property
    def ready(self) -> bool:
        return self.attributes.get("data-ready") == "1"

    @property
    def errors(self) -> list[str]:
        """Console messages that are errors: the page's own count plus uncaught exceptions Chromium reported."""
        found = [m for m in self.console if m.startswith("Uncaught") or "pipemap viewer:" in m]
        count = int(self.attributes.get("data-errors", "0") or 0)
        return found if len(found) >= count else found + [f"{count - len(found)} more console errors"]


def chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def load_page(page: Path, fragment: str = "", budget_ms: int = 20000, window: str = "1400,900",
              screenshot: Path | None = None, timeout_s: float = 120.0) -> PageLoad:
    """Open `page` (file://) in a fresh headless Chromium profile and dump the DOM (or take a screenshot)."""
    exe = chromium()
    if exe is None:
        raise FileNotFoundError("no chromium on PATH")
    url = Path(page).resolve().as_uri() + (f"#{fragment}" if fragment else "")
    with tempfile.TemporaryDirectory(prefix="pipemap-chromium-") as profile:
        what = [f"--screenshot={screenshot}"] if screenshot else ["--dump-dom"]
        cmd = [exe, *FLAGS, f"--user-data-dir={profile}", f"--window-size={window}",
               f"--virtual-time-budget={budget_ms}", *what, url]
        t0 = time.perf_counter()
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        seconds = time.perf_counter() - t0
    console = _CONSOLE.findall(done.stderr)
    head = re.search(r"<html([^>]*)>", done.stdout)
    attributes = dict(re.findall(r'(data-[\w-]+)="([^"]*)"', head.group(1))) if head else {}
    return PageLoad(attributes, console, seconds, "" if screenshot else done.stdout)


__all__ = ["PageLoad", "chromium", "load_page"]
