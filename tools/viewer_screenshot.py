"""Regenerate the README's viewer screenshot: ``python tools/viewer_screenshot.py [--url URL] [--out PNG]``.

Without ``--url`` it starts its own daemon on the simulated bench (``python -m lidard --config
config/sim.toml``, the CAL letters scene, a temporary data directory, a free port) and stops it after.
It drives Debian's /usr/bin/chromium through Playwright (no browser download): takes control on the
page, starts a full raster scan from the form, waits for the end and saves the whole page (default
docs/img/viewer.png, shown in README.md). The full 128 x 128 raster takes minutes on the simulated
bench (2-core Xeon); ``--timeout`` bounds the wait.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]


@contextlib.contextmanager
def own_daemon(startup_s: float = 90.0):
    """A daemon on the simulated bench in its own process group; yields its URL."""
    with tempfile.TemporaryDirectory(prefix="lidard-shot-") as data:
        proc = subprocess.Popen([sys.executable, "-m", "lidard", "--config", str(ROOT / "config" / "sim.toml"),
                                 "--port", "0", "--data-dir", data, "--log-level", "warning"],
                                cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, start_new_session=True,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            deadline, url = time.monotonic() + startup_s, None
            while url is None and time.monotonic() < deadline:
                line = proc.stderr.readline().decode(errors="replace")
                if not line and proc.poll() is not None:
                    raise SystemExit(f"lidard exited with status {proc.returncode} before serving")
                m = re.search(r"serving on (http://[\d.]+:\d+)", line)
                url = m.group(1) if m else None
            if url is None:
                raise SystemExit(f"lidard did not say where it serves within {startup_s:.0f} s")
            yield url
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=30)


def shoot(url: str, out: str, timeout_s: float) -> None:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path="/usr/bin/chromium", headless=True, args=ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 860})
        page.goto(url + "/", timeout=60_000)
        page.wait_for_function("window.viewer && window.viewer.ready", timeout=60_000)
        page.click("#control-take")
        page.wait_for_selector("#scan-start:not([disabled])")
        page.select_option("select[name=pattern]", "raster")
        page.click("#scan-start")
        page.wait_for_function("window.viewer.scanId !== null", timeout=60_000)
        page.wait_for_function("window.viewer.complete && window.viewer.scanState !== null",
                               timeout=timeout_s * 1000)
        # the panels refresh every second; the calibrations and device checks once the scan let go
        page.wait_for_function("window.viewer.calibrationsShown && window.viewer.scanner", timeout=60_000)
        page.wait_for_timeout(2500)
        page.screenshot(path=out)
        print(f"{out}: scan {page.evaluate('window.viewer.scanId')}, "
              f"{page.evaluate('window.viewer.pointCount')} points")
        browser.close()


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--url", default=None, help="a running daemon (default: start one on the simulated bench)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "img" / "viewer.png"))
    ap.add_argument("--timeout", type=float, default=1800.0, help="s to wait for the scan (default 1800)")
    a = ap.parse_args(argv)
    if a.url:
        shoot(a.url, a.out, a.timeout)
    else:
        with own_daemon() as url:
            shoot(url, a.out, a.timeout)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
