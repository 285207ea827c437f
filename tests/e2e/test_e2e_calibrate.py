"""``lidarctl calibrate`` end to end on a REAL daemon whose simulated bench hides its tolerances (delay,
zero offset, pointing drawn from ``[sim.tolerances]``): a plate left pending by an earlier run stops the
command until it is kept or dropped; then the command places its own fixtures through the bench, fits
range and pointing, puts the scene back, and the next scan is calibrated without re-linearizing.

The fitted values are compared with the bench's hidden truth, drawn here the way the bench draws it
(sim_devices.world.tolerances.draw_truth with the same configuration and seed): the test may know it,
the daemon never reads it.
"""

from __future__ import annotations

import json
import tomllib

import httpx
import pytest

from lidard.config import load_config
from lidard.instrument.calibration.range import plate_scene
from tests.helpers.cli import run
from tests.helpers.daemon import REPO, poll, start_daemon, stop_daemon

TOLERANCES_ON = {"LIDARD__SIM__TOLERANCES__ENABLED": "true"}


def _truth():
    from sim_devices.world.tolerances import draw_truth
    cfg = load_config(REPO / "config" / "sim.toml", environ=TOLERANCES_ON)
    return cfg, draw_truth(cfg.sim.tolerances, nominal_mzi_delay_s=cfg.monitor.delay_s, seed=cfg.sim.seed)


@pytest.mark.slow
def test_calibrate_on_a_simulated_daemon_then_the_scan_is_calibrated(capsys, tmp_path):
    cfg, truth = _truth()
    proc, url = start_daemon(tmp_path / "data", env=TOLERANCES_ON)
    try:
        # an earlier run measured one plate and stopped
        assert httpx.put(url + "/sim/scene", json=plate_scene(1.25)).status_code == 200
        early = httpx.post(url + "/calibration/range/plates", json={"known_m": 1.25}, timeout=300).json()
        code, out, err = run(capsys, "calibrate", "--url", url)
        assert code != 0 and early["id"] in err and "--keep-pending" in err and "--drop-pending" in err
        assert [m["id"] for m in httpx.get(url + "/calibration/range/plates").json()] == [early["id"]]

        httpx.put(url + "/sim/scene", content=(REPO / "config/scenes/cal_letters.toml").read_bytes(),
                  headers={"Content-Type": "application/toml"})
        code, out, err = run(capsys, "calibrate", "--url", url, "--drop-pending", "--json")
        assert code == 0, err
        got = json.loads(out)
        # progress: one line per step on stderr (3 plates, the range fit, pointing)
        assert [ln[:5] for ln in err.splitlines() if ln.startswith("[")] == ["[1/5]", "[2/5]", "[3/5]", "[4/5]", "[5/5]"]
        assert "dropped 1 pending plate" in err
        assert [p["known_m"] for p in got["plates"]] == [0.8, 1.1, 1.4]
        f = got["range"]["fitted"]
        assert abs(f["delay_s"] - truth.mzi_delay_s) < 10e-12            # 10 ps of 198 ns
        assert abs(f["zero_offset_m"] - truth.zero_offset_m) < 0.2e-3
        assert got["range"]["inputs"]["setup"]["parts"]["laser"] == cfg.laser
        p = got["pointing"]["fitted"]
        assert p["focal_scale"] == pytest.approx(truth.pointing.focal_scale, abs=2e-3)
        assert got["pointing"]["residuals"]["rms_mm"] < 0.5
        assert httpx.get(url + "/calibration/range/plates").json() == []
        # the bench shows the scene it showed before
        assert httpx.get(url + "/sim/scene").json() == tomllib.loads((REPO / "config/scenes/cal_letters.toml").read_text())

        sid = httpx.post(url + "/scans", json={"pattern": "roi", "rows": [60, 64], "cols": [60, 64]}).json()["id"]
        rec = poll(lambda: (r := httpx.get(f"{url}/scans/{sid}").json())["state"] in ("done", "failed") and r,
                   300, "the scan")
        assert rec["state"] == "done" and rec["calibrated"] == {"range": True, "pointing": True, "linearization": True}
        assert (rec["range_calibration_id"], rec["pointing_calibration_id"]) == (got["range"]["id"], got["pointing"]["id"])
        side = httpx.get(f"{url}/scans/{sid}/sidecar", params={"format": "ply"}).json()
        assert side["linearization"]["relinearized"] is False, side["linearization"]
    finally:
        stop_daemon(proc)
