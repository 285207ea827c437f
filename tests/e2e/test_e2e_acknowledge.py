"""Recover after a safety stop (issue 11, item 4), with a REAL daemon process and its child bench.

An interlock opening mid-scan fails the scan with a safety stop and latches INTERLOCK_OPEN in the
controller. Then: POST /scans is refused (409 naming the latch and ``lidarctl faults ack``), GET
/health shows the latch, an acknowledgement while the interlock is still open is refused (409 naming
it, also through ``lidarctl faults ack``), and once the bench fault is cleared the acknowledgement
clears the latch (200 naming who and when) and the next scan is done.
"""

from __future__ import annotations

import time

import httpx
import pytest
from tests.helpers.deadlines import HTTP_S, WAIT_S

from lidard.cli.lidarctl import main as lidarctl
from lidard.config import load_config
from tests.e2e.test_e2e_kill9 import _kill_group, _poll, _scan, _start_daemon

pytestmark = pytest.mark.slow  # a real daemon through an interlock trip

SCAN = {"pattern": "roi", "rows": [44, 48], "cols": [60, 70], "max_range_m": 2.0}


def _ended(c: httpx.Client, sid: str) -> dict:
    return _poll(lambda: (s := _scan(c, sid))["state"] not in ("queued", "running") and s, WAIT_S, f"scan {sid}")


def test_interlock_trip_latches_refuses_scans_until_acknowledged_then_scans_again(tmp_path, capsys):
    proc, url = _start_daemon(tmp_path / "data")
    try:
        with httpx.Client(base_url=url, timeout=HTTP_S) as c:
            lease = c.post("/control", json={"client": "alice@lab"}).json()["lease"]
            c.headers["X-Lidard-Lease"] = lease
            r = c.post("/scans", json=SCAN)          # the first scan linearizes the chirp first
            assert r.status_code == 201 and _ended(c, r.json()["id"])["state"] == "done"
            # mid-scan: after the linearization health check's records and 3 of the scan's segments
            after = load_config("config/sim.toml").scan.linearity_check_records + 3
            assert c.post("/sim/faults", json={"kind": "interlock_open", "after_segments": after}).status_code == 201
            r = c.post("/scans", json=SCAN)
            assert r.status_code == 201, r.text
            failed = _ended(c, r.json()["id"])
            assert failed["state"] == "failed" and failed["error"].startswith("SafetyStop:"), failed
            assert "interlock" in failed["error"]

            h = c.get("/health").json()
            assert h["latched_faults"] == ["INTERLOCK_OPEN"] and h["interlock_closed"] is False
            r = c.post("/scans", json=SCAN)
            assert r.status_code == 409, r.text
            assert "INTERLOCK_OPEN" in r.json()["detail"] and "lidarctl faults ack" in r.json()["detail"]

            # the cause is still there: refused, naming it (API and CLI)
            r = c.post("/controller/acknowledge")
            assert r.status_code == 409 and "INTERLOCK_OPEN" in r.json()["detail"], r.text
            assert lidarctl(["faults", "ack", "--url", url, "--lease", lease]) != 0
            assert "INTERLOCK_OPEN" in capsys.readouterr().err
            # without the lease the lock answers first
            assert httpx.post(url + "/controller/acknowledge").status_code == 423

            assert c.delete("/sim/faults").status_code == 200
            t0 = time.time()
            r = c.post("/controller/acknowledge")
            assert r.status_code == 200, r.text
            ack = r.json()
            assert ack["cleared"] == ["INTERLOCK_OPEN"] and ack["by"] == "alice@lab"
            assert t0 - 1.0 <= ack["at"] <= time.time() + 1.0
            h = c.get("/health").json()
            assert h["latched_faults"] == [] and h["interlock_closed"] is True
            # nothing latched any more: a second acknowledgement clears nothing, through the CLI
            assert lidarctl(["faults", "ack", "--url", url, "--lease", lease]) == 0
            assert "no latched faults" in capsys.readouterr().out

            r = c.post("/scans", json=SCAN)
            assert r.status_code == 201, r.text
            assert _ended(c, r.json()["id"])["state"] == "done"
    finally:
        _kill_group(proc)
