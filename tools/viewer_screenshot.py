"""Screenshot the web viewer after a full scan: ``python tools/viewer_screenshot.py [URL] [OUT.png]``.

Start a daemon first (``lidard --config config/sim.toml``, the CAL letters scene); this drives Debian's
/usr/bin/chromium through Playwright (no browser download): takes control on the page, starts a full
raster scan from the form, waits for the end and saves the whole page (docs/img/viewer.png in README).
"""

from __future__ import annotations

import sys

from playwright.sync_api import sync_playwright

ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]


def main(url: str = "http://127.0.0.1:8470", out: str = "docs/img/viewer.png", timeout_s: float = 900) -> None:
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path="/usr/bin/chromium", headless=True, args=ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 860})
        page.goto(url + "/")
        page.wait_for_function("window.viewer && window.viewer.ready")
        page.click("#control-take")
        page.wait_for_selector("#scan-start:not([disabled])")
        page.select_option("select[name=pattern]", "raster")
        page.click("#scan-start")
        page.wait_for_function("window.viewer.scanId !== null")
        page.wait_for_function("window.viewer.complete && window.viewer.scanState !== null",
                               timeout=timeout_s * 1000)
        page.wait_for_timeout(1500)  # let the 1 s panel refresh show the finished queue
        page.screenshot(path=out)
        print(f"{out}: scan {page.evaluate('window.viewer.scanId')}, "
              f"{page.evaluate('window.viewer.pointCount')} points")
        browser.close()


if __name__ == "__main__":
    main(*sys.argv[1:3])
