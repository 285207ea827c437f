"""Switch self-test (issue 6): the analysis of tap readings, POST /selftest + /sim/faults over REST on
the real instrument with an embedded bench, and ``lidarctl selftest`` (exit 3 on a stuck switch).

The analysis is checked against beam counting: a reading is ``k`` single-beam levels, and the
expected ``k`` per line follows from which lines are on (the toggled line, its fixed partner, and
any stuck-on line), written out per case below, not taken from the code.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lidard.cli import lidarctl_main
from lidard.config import load_config
from lidard.instrument import analyse_selftest, open_instrument
from tests.helpers.api import app_client
from tests.helpers.fakes import FakeInstrument

REPO = Path(__file__).resolve().parents[2]
ROWS = [0, 1, 2, 4, 5, 6, 8, 9]          # bonded rows of a small array (every 4th row missing)
COLS = list(range(8))
R0, C0 = 5, 4                            # fixed partners
V1 = 0.095                               # one beam at the tap, V


def _readings(stuck_on_rows=(), stuck_on_cols=(), stuck_off_rows=(), stuck_off_cols=(), noise=0.0, seed=0):
    """Beam count x V1 for the sweep, from first principles: beams = (rows on) x (cols on)."""
    rng = np.random.default_rng(seed)

    def beams(r_on: set, c_on: set) -> int:
        r_on = (r_on | set(stuck_on_rows)) - set(stuck_off_rows)
        c_on = (c_on | set(stuck_on_cols)) - set(stuck_off_cols)
        return len(r_on) * len(c_on)
    row_v = np.array([beams({r}, {C0}) for r in ROWS], float) * V1
    col_v = np.array([beams({R0}, {c}) for c in COLS], float) * V1
    return row_v + noise * rng.standard_normal(len(ROWS)), col_v + noise * rng.standard_normal(len(COLS))


def _stuck(report):
    return sorted((s["line"], s["index"], s["state"]) for s in report["stuck"])


def test_healthy_array_reports_nothing_and_the_single_beam_level():
    rep = analyse_selftest(*_readings(noise=1e-3), ROWS, COLS, R0, C0)
    assert rep["ok"] and rep["stuck"] == []
    assert rep["single_beam_v"] == pytest.approx(V1, rel=0.03)


@pytest.mark.parametrize("fault, expect", [
    (dict(stuck_off_rows=(8,)), [("row", 8, "off")]),
    (dict(stuck_off_cols=(2,)), [("col", 2, "off")]),
    (dict(stuck_on_rows=(1,)), [("row", 1, "on")]),
    (dict(stuck_on_cols=(6,)), [("col", 6, "on")]),
    (dict(stuck_on_rows=(R0,)), [("row", R0, "on")]),        # the fixed partner itself stuck on
    (dict(stuck_on_cols=(C0,)), [("col", C0, "on")]),
    (dict(stuck_off_cols=(C0,)), [("col", C0, "off")]),      # partner stuck off: every row dark
    (dict(stuck_off_rows=(2,), stuck_off_cols=(7,)), [("col", 7, "off"), ("row", 2, "off")]),
])
def test_each_stuck_line_is_named_with_its_state(fault, expect):
    rep = analyse_selftest(*_readings(noise=2e-3, seed=3, **fault), ROWS, COLS, R0, C0)
    assert not rep["ok"]
    got = _stuck(rep)
    for e in expect:
        assert e in got
    # nothing healthy is blamed (a partner stuck off is reported once, as the partner)
    assert len(got) <= len(expect) + (1 if fault.get("stuck_off_cols") == (C0,) else 0)


def test_no_light_at_all_blames_nothing_as_healthy():
    rep = analyse_selftest(np.zeros(len(ROWS)), np.zeros(len(COLS)), ROWS, COLS, R0, C0)
    assert not rep["ok"]          # a dark tap is never "all switches respond"


# ------------------------------------------------------------------------------ REST, real rig
@pytest.fixture(scope="module")
def client(tmp_path_factory):
    cfg = load_config(REPO / "config" / "sim.toml")
    inst = open_instrument(cfg, bench="embedded")
    with app_client(tmp_path_factory.mktemp("selftest-data"), inst, cfg) as c:
        yield c


def test_post_selftest_finds_an_injected_stuck_switch_and_clearing_heals_it(client):
    assert client.get("/sim/faults").json() == {"faults": []}
    r = client.post("/sim/faults", json={"kind": "stuck_switch", "line": "row", "index": 21, "state": "on"})
    assert r.status_code == 201, r.text
    fault = r.json()
    assert fault["kind"] == "stuck_switch" and "id" in fault
    assert [f["kind"] for f in client.get("/sim/faults").json()["faults"]] == ["stuck_switch"]
    rep = client.post("/selftest").json()
    assert rep["ok"] is False
    assert [(s["line"], s["index"], s["state"]) for s in rep["stuck"]] == [("row", 21, "on")]
    assert rep["rows_tested"] == 96 and rep["cols_tested"] == 128
    # the rest of the rows read two beams (their own + the stuck row's), the stuck row one
    row_v = np.array(rep["row_tap_v"])
    assert np.median(row_v) == pytest.approx(2 * rep["single_beam_v"], rel=0.05)
    assert client.delete("/sim/faults", params={"kind": "stuck_switch"}).json() == {"cleared": 1}
    rep = client.post("/selftest").json()
    assert rep["ok"] is True and rep["stuck"] == []


def test_get_devices_shows_a_lost_device_with_its_cause_and_its_return(client):
    assert client.post("/sim/faults", json={"kind": "usb_disconnect", "device": "digitizer"}).status_code == 201
    devs = {d["name"]: d for d in client.get("/devices").json()["devices"]}
    assert devs["digitizer"]["connected"] is False
    assert any("digitizer" in f and "disconnect" in f.lower() for f in devs["digitizer"]["faults"])
    assert all(devs[n]["connected"] for n in ("fpsa", "awg", "controller"))
    client.delete("/sim/faults")
    devs = {d["name"]: d for d in client.get("/devices").json()["devices"]}
    assert all(d["connected"] for d in devs.values())     # back without a daemon restart


def test_sim_faults_refuses_unknown_kinds_and_bad_parameters_by_name(client):
    r = client.post("/sim/faults", json={"kind": "gremlins"})
    assert r.status_code == 422 and "gremlins" in r.text
    r = client.post("/sim/faults", json={"kind": "serial_drop", "rate": 3.0})
    assert r.status_code == 422 and "rate" in r.text
    assert client.get("/sim/faults").json() == {"faults": []}


def test_sim_faults_on_real_hardware_is_a_conflict(tmp_path):
    cfg = load_config(REPO / "config" / "sim.toml")
    with app_client(tmp_path, FakeInstrument(simulated=False), cfg) as c:
        for method, kw in (("POST", {"json": {"kind": "hv_fault"}}), ("GET", {}), ("DELETE", {})):
            r = c.request(method, "/sim/faults", **kw)
            assert r.status_code == 409 and "real hardware" in r.text


# ------------------------------------------------------------------------------------------- CLI
def _config_with_faults(tmp_path: Path, faults: str) -> Path:
    """config/sim.toml plus ``[[sim.faults]]`` tables, written elsewhere (scene path made absolute)."""
    base = (REPO / "config" / "sim.toml").read_text()
    base = base.replace('scene = "scenes/cal_letters.toml"',
                        f'scene = "{(REPO / "config" / "scenes" / "cal_letters.toml").as_posix()}"')
    p = tmp_path / "sim_stuck.toml"
    p.write_text(base + "\n" + faults)
    return p


def test_lidarctl_selftest_exits_3_and_names_the_stuck_switch(tmp_path, capsys):
    cfg = _config_with_faults(tmp_path, '[[sim.faults]]\nkind = "stuck_switch"\nline = "col"\nindex = 17\n'
                                        'state = "off"\n')
    rc = lidarctl_main(["selftest", "--sim", "--config", str(cfg), "--json"])
    out = capsys.readouterr().out
    assert rc == 3
    rep = json.loads(out)
    assert [(s["line"], s["index"], s["state"]) for s in rep["stuck"]] == [("col", 17, "off")]


def test_lidarctl_selftest_healthy_exits_0(capsys):
    rc = lidarctl_main(["selftest", "--sim"])
    out = capsys.readouterr().out
    assert rc == 0 and "none stuck" in out
