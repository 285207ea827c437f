"""``lidarctl sim`` against a REAL daemon process on a simulated bench: a scene file placed, faults
injected, listed and cleared, and the control lock's lease honoured (held by another client: refused
naming the holder; with its lease: done). Nothing here needs curl.

The checks compare with what the daemon itself reports through other endpoints (the bench's own count
of the scene's targets, GET /sim/faults), not with the CLI's own output alone.
"""

from __future__ import annotations

import json
import tomllib

import httpx
import pytest

from tests.helpers.cli import run
from tests.helpers.daemon import REPO, start_daemon, stop_daemon

MIXED = REPO / "config" / "scenes" / "mixed.toml"


@pytest.fixture
def daemon(tmp_path):
    proc, url = start_daemon(tmp_path / "data")
    try:
        yield url
    finally:
        stop_daemon(proc)


def test_scene_and_faults_through_lidarctl_sim_with_the_lease(capsys, daemon):
    url = daemon
    scene = tomllib.loads(MIXED.read_text())
    code, out, err = run(capsys, "sim", "scene", str(MIXED), "--url", url, "--json")
    assert code == 0, err
    got = json.loads(out)
    assert got == {"name": scene["name"], "targets": len(scene["target"])}

    code, out, err = run(capsys, "sim", "faults", "inject", "usb_timeout", "device=digitizer", "n=2",
                         "--url", url, "--json")
    assert code == 0, err
    fault = json.loads(out)
    listed = httpx.get(url + "/sim/faults").json()["faults"]
    assert [f["id"] for f in listed] == [fault["id"]]
    assert listed[0]["kind"] == "usb_timeout" and listed[0]["device"] == "digitizer" and listed[0]["n"] == 2
    code, out, err = run(capsys, "sim", "faults", "list", "--url", url)
    assert code == 0 and str(fault["id"]) in out and "usb_timeout" in out
    # a parameter the bench refuses is named
    code, out, err = run(capsys, "sim", "faults", "inject", "usb_timeout", "device=fridge", "--url", url)
    assert code != 0 and "422" in err and "fridge" in err
    code, out, err = run(capsys, "sim", "faults", "inject", "usb_timeout", "digitizer", "--url", url)
    assert code != 0 and "KEY=VALUE" in err

    # another client takes the control lock: mutating sim commands need its lease
    lease = httpx.post(url + "/control", json={"client": "bench-operator"}).json()["lease"]
    code, out, err = run(capsys, "sim", "faults", "clear", "--url", url)
    assert code != 0 and "bench-operator" in err and "--lease" in err
    assert len(httpx.get(url + "/sim/faults").json()["faults"]) == 1        # nothing cleared
    code, out, err = run(capsys, "sim", "faults", "clear", "--kind", "usb_timeout", "--url", url,
                         "--lease", lease, "--json")
    assert code == 0, err
    assert json.loads(out) == {"cleared": 1}
    assert httpx.get(url + "/sim/faults").json()["faults"] == []
    code, out, err = run(capsys, "sim", "scene", str(REPO / "config" / "scenes" / "nope.toml"), "--url", url,
                         "--lease", lease)
    assert code != 0 and "nope.toml" in err and "cannot read" in err
