"""Latched controller faults through the API and the CLI, against the fake instrument (issue 11,
item 4): POST /scans refused while a fault is latched, GET /health and ``lidarctl status`` show it,
POST /controller/acknowledge answers who and when and is refused while the cause is present. The
same flow against a real daemon and bench: tests/e2e/test_e2e_acknowledge.py."""

from __future__ import annotations

import time

from lidard.cli.lidarctl import main as lidarctl
from tests.helpers.api import app_client, live_server, make_app
from tests.helpers.fakes import FakeInstrument

SCAN = {"pattern": "roi", "rows": [44, 48], "cols": [60, 70]}


def test_a_latched_fault_refuses_scans_until_acknowledged(tmp_path):
    inst = FakeInstrument()
    inst.latched, inst.interlock_closed = ["INTERLOCK_OPEN"], False
    with app_client(tmp_path, inst) as c:
        h = c.get("/health").json()
        assert h["latched_faults"] == ["INTERLOCK_OPEN"] and h["interlock_closed"] is False
        r = c.post("/scans", json=SCAN)
        assert r.status_code == 409
        assert "INTERLOCK_OPEN" in r.json()["detail"] and "lidarctl faults ack" in r.json()["detail"]
        assert inst.requests == []                          # nothing was queued
        r = c.post("/controller/acknowledge")
        assert r.status_code == 409 and "INTERLOCK_OPEN" in r.json()["detail"]
        assert inst.latched == ["INTERLOCK_OPEN"]
        inst.interlock_closed = True
        lease = c.post("/control", json={"client": "bob@lab"}).json()["lease"]
        assert c.post("/controller/acknowledge").status_code == 423       # the lock applies
        t0 = time.time()
        r = c.post("/controller/acknowledge", headers={"X-Lidard-Lease": lease})
        assert r.status_code == 200
        assert r.json()["cleared"] == ["INTERLOCK_OPEN"] and r.json()["by"] == "bob@lab"
        assert t0 <= r.json()["at"] <= time.time()
        assert c.get("/health").json()["latched_faults"] == []
        assert c.post("/scans", json=SCAN, headers={"X-Lidard-Lease": lease}).status_code == 201


def test_acknowledge_without_a_lease_is_anonymous_and_an_unreadable_controller_does_not_block_scans(tmp_path):
    class Unreadable(FakeInstrument):
        def controller_faults(self):
            raise TimeoutError("controller: no answer")

    with app_client(tmp_path, FakeInstrument()) as c:
        r = c.post("/controller/acknowledge")
        assert r.status_code == 200 and r.json()["by"] == "anonymous" and r.json()["cleared"] == []
    with app_client(tmp_path / "u", Unreadable()) as c:
        h = c.get("/health").json()
        assert h["latched_faults"] is None and h["interlock_closed"] is None
        assert c.post("/scans", json=SCAN).status_code == 201           # the scan reports the real error


def test_lidarctl_status_shows_the_latch(tmp_path, capsys):
    inst = FakeInstrument()
    inst.latched, inst.interlock_closed = ["HV_FAULT"], True
    with live_server(make_app(tmp_path, inst)) as url:
        assert lidarctl(["status", "--url", url]) == 0
        out = capsys.readouterr().out
        assert "controller faults LATCHED: HV_FAULT" in out and "lidarctl faults ack" in out
        inst.latched = []
        assert lidarctl(["status", "--url", url]) == 0
        assert "LATCHED" not in capsys.readouterr().out
