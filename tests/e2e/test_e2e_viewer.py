"""The web viewer in a real browser (issue 16 item 1): headless Debian Chromium driven by Playwright.

A real ``lidard`` process on the simulated bench (config/sim.toml, CAL letters, temp data dir, port
0) serves the page. The test does what a user does: take control on the page, start a 16 x 16 ROI
scan from the form, wait for the page to see the end. Then the page's own state
(``window.viewer.pointCount``, built from the incremental ``/points/live`` fetches) must equal the
count the API reports, and the WebGL canvas must not be blank (pixel variance of what it drew, and
of the screenshot). Then the control lease: a reload keeps control (under a fresh lease, the old one
void), another tab is an observer, and closing the tab releases the lock. A second test follows a
stream: the page takes the running stream's view, its frame counter advances with the frames the
API lists, and after DELETE it replays the kept frames. Only Debian's /usr/bin/chromium is used; nothing is downloaded. Without that
executable (or the playwright package) the test skips, saying which is missing.
"""

from __future__ import annotations

import io
import os
import shutil
from pathlib import Path

import httpx
import numpy as np
import pytest

from tests.helpers.daemon import poll, start_daemon, stop_daemon
from tests.helpers.deadlines import HTTP_S, WAIT_S

pytestmark = pytest.mark.slow  # a real daemon and a browser

REPO = Path(__file__).resolve().parents[2]
CHROMIUM = os.environ.get("LIDARD_CHROMIUM", "/usr/bin/chromium")
# Software WebGL (SwiftShader) in a headless, sandbox-less container (CI runs as root).
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--ignore-gpu-blocklist"]


def _browser_or_skip():
    if not (os.path.isfile(CHROMIUM) and os.access(CHROMIUM, os.X_OK)):
        pytest.skip(f"no browser: {CHROMIUM} is missing (apt-get install chromium; .ci/run does)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("the playwright package is not installed (pip install -e '.[test]')")
    return sync_playwright


def run_scan_in_page(page, url: str, rows: tuple[int, int], cols: tuple[int, int], timeout_s: float) -> str:
    """Take control and start an ROI scan from the page's own controls; answers the scan id."""
    page.goto(url + "/")
    page.wait_for_function("window.viewer && window.viewer.ready")
    page.click("#control-take")
    page.wait_for_selector("#scan-start:not([disabled])", timeout=WAIT_S * 1000)
    page.select_option("select[name=pattern]", "roi")
    for name, value in (("row0", rows[0]), ("row1", rows[1]), ("col0", cols[0]), ("col1", cols[1])):
        page.fill(f"input[name={name}]", str(value))
    page.click("#scan-start")
    page.wait_for_function("window.viewer.scanId !== null || window.viewer.lastError !== null",
                           timeout=timeout_s * 1000)
    assert page.evaluate("window.viewer.lastError") is None
    page.wait_for_function("window.viewer.complete && window.viewer.scanState !== null",
                           timeout=timeout_s * 1000)
    return page.evaluate("window.viewer.scanId")


def check_panels(page, api):
    """What the page says beside the cloud: a colour bar with the mode's unit and the limits the points
    are coloured with, the unbonded rows named, rows/cols inputs that follow the pattern, device and
    calibration panels with content."""
    page.wait_for_function("window.viewer.calibrationsShown && window.viewer.scanner", timeout=WAIT_S * 1000)
    legend = page.evaluate("window.viewer.legend")
    assert legend["mode"] == "range" and legend["unit"] == "range, m"
    assert page.inner_text("#legend-unit") == "range, m"
    assert [float(page.inner_text("#legend-lo")), float(page.inner_text("#legend-hi"))] == pytest.approx(
        page.evaluate("window.viewer.cloud.colorLimits"), rel=1e-2)
    bar = page.evaluate("""(() => { const c = document.getElementById('colorbar').getContext('2d');
        return [Array.from(c.getImageData(1, 5, 1, 1).data), Array.from(c.getImageData(158, 5, 1, 1).data)]; })()""")
    assert bar[0] != bar[1] and bar[0][3] == 255       # a drawn gradient, not an empty canvas
    page.select_option("#color-mode", "velocity")
    assert page.evaluate("window.viewer.legend.unit").startswith("radial velocity, m/s")
    # unbonded rows: the sim FPSA leaves every 4th row unbonded (rows 3, 7, ...)
    assert page.evaluate("window.viewer.unbondedRows.slice(0, 3)") == [3, 7, 11]
    note = page.inner_text("#rows-note")
    assert "32 of 128 FPSA rows are not bonded" in note and "rows 3, 7, 11, 15" in note
    # controls follow the pattern
    page.select_option("select[name=pattern]", "raster")
    assert page.evaluate("document.getElementById('roi-fields').disabled") is True
    assert "whole array" in page.inner_text("#pattern-note")
    page.select_option("select[name=pattern]", "roi")
    assert page.evaluate("document.getElementById('roi-fields').disabled") is False
    # devices: one line per device with its state, no bare "none", no repr
    devices = page.inner_text("#devices").splitlines()
    assert [d.split(":")[0] for d in devices] == ["fpsa", "awg", "digitizer", "controller"]
    assert "awg: ready (error queue empty)" in devices and not any(d.endswith(": none") for d in devices)
    assert not any("Status(" in d or "<" in d for d in devices)
    # calibrations: the linearization the scan made, and the chirp check line
    # the panel reads the calibrations again on the refresh after a scan ends (a scan shorter than a
    # refresh tick may save its linearization between two reads)
    page.wait_for_function("document.getElementById('calibrations').innerText.includes('it.,')",
                           timeout=WAIT_S * 1000)
    cals = page.inner_text("#calibrations")
    assert "it.," in cals and "loading" not in cals
    assert page.inner_text("#linearization").startswith(("chirp error", "chirp re-linearized"))


# Every answer of GET /control reaches the page 1.5 s late: a refresh that asked while the lock was free
# is answered after the user took control (what a loaded machine does to a refresh in flight).
LATE_CONTROL = """(() => { const send = window.fetch;
  window.fetch = async (url, opts) => { const r = await send(url, opts);
    if (String(url) === '/control' && !(opts && opts.method)) await new Promise((ok) => setTimeout(ok, 1500));
    return r; }; })()"""


def check_take_outlives_a_late_refresh(browser, url: str) -> None:
    """Taking control while a refresh is in flight: that refresh's answer (lock free) arrives after the
    take and must not void the lease just taken (on main before this check, the button stayed disabled)."""
    page = browser.new_page()
    page.add_init_script(LATE_CONTROL)
    page.goto(url + "/")
    page.wait_for_function("window.viewer && window.viewer.ready")   # its first refresh is on its way
    assert page.evaluate("window.viewer.refreshes") == 0 and not _control(url)["held"]
    page.click("#control-take")
    page.wait_for_selector("#scan-start:not([disabled])", timeout=WAIT_S * 1000)
    page.wait_for_function("window.viewer.refreshes >= 1", timeout=WAIT_S * 1000)  # the late answer is in
    assert page.evaluate("window.viewer.lease") is not None
    assert page.is_enabled("#scan-start") and _control(url)["holder"] == "web viewer"
    page.click("#control-release")
    poll(lambda: not _control(url)["held"], WAIT_S, "the release")
    page.close()


def _control(url: str) -> dict:
    return httpx.get(f"{url}/control", timeout=HTTP_S).json()


def check_lease_survives_reload_and_close(browser, page, url: str) -> None:
    """The tab that took control keeps it across a reload, another tab cannot steer, closing releases."""
    old = page.evaluate("window.viewer.lease")
    assert old and _control(url)["holder"] == "web viewer"
    page.reload()
    page.wait_for_function("window.viewer && window.viewer.ready")
    page.wait_for_selector("#scan-start:not([disabled])", timeout=WAIT_S * 1000)    # still in control
    new = page.evaluate("window.viewer.lease")
    assert new and new != old and _control(url)["holder"] == "web viewer"
    # the old page's lease is void: its late release (or anyone replaying it) frees nothing
    r = httpx.delete(f"{url}/control", headers={"X-Lidard-Lease": old}, timeout=HTTP_S)
    assert r.status_code == 423 and _control(url)["held"] is True
    # another tab (its own sessionStorage) is an observer
    other = browser.new_page()
    other.goto(url + "/")
    other.wait_for_function("window.viewer && window.viewer.ready")
    assert other.evaluate("window.viewer.lease") is None
    assert other.is_disabled("#scan-start") and not other.is_hidden("#control-take")
    other.close()
    assert _control(url)["held"] is True        # a tab without the lease releases nothing
    # closing the controlling tab releases the lock (pagehide, fetch keepalive)
    page.close(run_before_unload=True)
    poll(lambda: not _control(url)["held"], WAIT_S, "the closed tab's release")


def test_viewer_starts_a_scan_and_shows_every_point(tmp_path):
    sync_playwright = _browser_or_skip()
    from PIL import Image

    proc, url = start_daemon(tmp_path / "data")
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            try:
                check_take_outlives_a_late_refresh(browser, url)
                page = browser.new_page(viewport={"width": 1100, "height": 700})
                sid = run_scan_in_page(page, url, (40, 56), (56, 72), timeout_s=WAIT_S)
                api = httpx.get(f"{url}/scans/{sid}", timeout=HTTP_S).json()
                assert api["state"] == "done"
                # every planned pixel (the ROI's bonded rows) was scanned
                assert 0 < api["counts"]["pixels_scanned"] == api["counts"]["pixels_planned"] <= 256
                assert api["counts"]["points"] > 0
                assert page.evaluate("window.viewer.scanState") == "done"
                assert page.evaluate("window.viewer.pointCount") == api["counts"]["points"]
                # the page really drew them: the WebGL buffer is not one flat colour
                stats = page.evaluate("window.viewer.cloud.pixelStats()")
                assert stats["lit"] > 0 and stats["variance"] > 1.0, stats
                shot = tmp_path / "viewer.png"
                page.locator("#cloud").screenshot(path=str(shot))
                if os.environ.get("LIDARD_VIEWER_SHOT"):
                    shutil.copy(shot, os.environ["LIDARD_VIEWER_SHOT"])
                img = np.asarray(Image.open(io.BytesIO(shot.read_bytes())).convert("L"), dtype=float)
                assert img.var() > 1.0, f"blank canvas in {shot}"
                # the pixel picker: a click where the middle point is drawn shows that point's fields
                mid = api["counts"]["points"] // 2
                at = page.evaluate(f"window.viewer.cloud.screenOf({mid})")
                page.mouse.click(at["x"], at["y"])
                picked = page.evaluate("window.viewer.picked")
                want = page.evaluate(f"[window.viewer.cloud.column('row')[{mid}], window.viewer.cloud.column('col')[{mid}]]")
                # that pixel (a second return of the same beam may be drawn on the same spot)
                assert picked is not None and [picked["row"], picked["col"]] == want, (picked, want)
                assert 40 <= picked["row"] < 56 and 56 <= picked["col"] < 72, picked
                assert 0.7 < picked["range"] < 1.0  # the letters at 0.8 m or the board at 0.9 m
                assert f"row       {picked['row']}" in page.inner_text("#picked")
                assert page.evaluate("window.viewer.cloud.pick({clientX: -1e6, clientY: -1e6})") is None
                check_panels(page, api)
                check_lease_survives_reload_and_close(browser, page, url)
            finally:
                browser.close()
    finally:
        stop_daemon(proc)


def test_viewer_follows_a_running_stream_and_replays_it_after_stop(tmp_path):
    sync_playwright = _browser_or_skip()
    proc, url = start_daemon(tmp_path / "data")
    try:
        r = httpx.post(url + "/streams", json={"pattern": "roi", "rows": [48, 56], "cols": [48, 64],
                                               "max_range_m": 2.0}, timeout=10)      # until stopped
        assert r.status_code == 201, r.text
        sid = r.json()["id"]
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page(viewport={"width": 1100, "height": 700})
                page.goto(url + "/")
                page.wait_for_function("window.viewer && window.viewer.ready")
                # the running stream takes the view; its first frame is drawn
                page.wait_for_function(f"window.viewer.streamId === '{sid}' && window.viewer.frameIndex !== null",
                                       timeout=300_000)
                first = page.evaluate("window.viewer.frameIndex")
                # the counter advances with the stream (the page shows each newest frame)
                page.wait_for_function(f"window.viewer.frameIndex > {first}", timeout=300_000)
                state = page.evaluate("""({k: window.viewer.frameIndex, n: window.viewer.pointCount,
                    text: document.getElementById('frame-counter').textContent, hz: window.viewer.frameRateHz})""")
                api = httpx.get(f"{url}/streams/{sid}", timeout=10).json()
                k = state["k"]
                assert api["state"] == "running" and api["frames_done"] > k >= 1
                assert state["n"] == api["frames"][k]["points"] > 0          # that frame's points, all of them
                assert state["text"].startswith(f"frame {k + 1} / ") and state["text"].endswith(" Hz")
                assert state["hz"] is not None and state["hz"] > 0
                assert page.evaluate("window.viewer.lastError") is None
                stats = page.evaluate("window.viewer.cloud.pixelStats()")
                assert stats["lit"] > 0 and stats["variance"] > 1.0, stats
                assert httpx.delete(f"{url}/streams/{sid}", timeout=10).status_code == 200
                page.wait_for_function("window.viewer.streamState === 'stopped'", timeout=120_000)
                end = httpx.get(f"{url}/streams/{sid}", timeout=10).json()
                n = end["frames_done"]
                starts = [f["start_s"] for f in end["frames"]]
                # stopped: the kept frames are replayed in a loop; the counter runs through all of them
                # every draw rewrites the counter: the page notes each one (a sampler from here would
                # miss draws on a busy machine), until every frame was drawn twice
                page.evaluate("""() => { window.drawnCounters = [];
                    new MutationObserver(() => window.drawnCounters.push(
                        document.getElementById('frame-counter').textContent)).observe(
                        document.getElementById('frame-counter'), {childList: true, characterData: true, subtree: true}); }""")
                page.wait_for_function(f"window.drawnCounters.length >= {2 * n}", timeout=120_000)
                drawn = page.evaluate("window.drawnCounters")
                idx = [int(t.split(" ")[1]) - 1 for t in drawn]
                assert all(t.startswith(f"frame {k + 1} / {n} ") for k, t in zip(idx, drawn)), drawn
                assert all(b == (a + 1) % n for a, b in zip(idx, idx[1:])), idx    # in order, none skipped
                assert set(idx) == set(range(n))
                assert page.evaluate("window.viewer.frameRateHz") == pytest.approx(
                    (n - 1) / (starts[-1] - starts[0]), rel=1e-9)
            finally:
                browser.close()
    finally:
        stop_daemon(proc)
