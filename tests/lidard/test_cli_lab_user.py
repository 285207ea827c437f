"""lidarctl as a lab user meets it (issue 11, item 7): pixel lists, requests refused before a bench
starts with the daemon's words, sim-only flags refused without --sim, readable tables, the sidecar of
a daemon scan, help text with units and examples, lidarctl faults ack."""

import hashlib
import json

import httpx
import pytest

from lidard import cli
from lidard.api.schemas import describe_errors
from lidard.cli import base as cli_base
from lidard.cli import faults as cli_faults
from lidard.cli.progress import Progress
from lidard.config import CONFIG_DIR, load_config
from lidard.outputs import read_points, read_sidecar
from tests.helpers.api import live_server, make_app
from tests.helpers.fakes import FakeInstrument
from tests.helpers.cli import run



@pytest.fixture
def fake_bench(monkeypatch):
    """--sim with the fake instrument; records every instrument opened (none when refused early)."""
    made = []

    def fake_open(cfg, **kw):
        made.append(FakeInstrument(profile=cfg.profile))
        return made[-1]
    monkeypatch.setattr(cli_base, "open_instrument", fake_open)
    return made


# -- pixels
def test_pixels_flag_scans_exactly_those_pixels(capsys, fake_bench, tmp_path):
    out_file = tmp_path / "px.npz"
    code, out, err = run(capsys, "scan", "--sim", "--profile", "fpsa20", "--pixels", "0,0", "3,4", "7,19",
                         "--out", str(out_file), "--json")
    assert code == 0, err
    (req,) = fake_bench[0].requests
    assert req.pattern == "pixels" and [tuple(p) for p in req.pixels] == [(0, 0), (3, 4), (7, 19)]
    pts = read_points(out_file)
    assert sorted(zip(pts["row"].tolist(), pts["col"].tolist())) == [(0, 0), (3, 4), (7, 19)]


@pytest.mark.parametrize("text", ["# two pixels\n1,2\n5 6  # a comment\n", "[[1, 2], [5, 6]]"])
def test_pixels_file_text_or_json(capsys, fake_bench, tmp_path, text):
    f = tmp_path / "px.txt"
    f.write_text(text)
    code, out, err = run(capsys, "scan", "--sim", "--profile", "fpsa20", "--pixels-file", str(f),
                         "--out", str(tmp_path / "p.npz"), "--json")
    assert code == 0, err
    assert [tuple(p) for p in fake_bench[0].requests[0].pixels] == [(1, 2), (5, 6)]


@pytest.mark.parametrize("argv,needle", [
    (["--pixels", "1;2"], "--pixels: expected ROW,COL"),
    (["--pixels", "1,2", "--pixels-file", "x"], "not both"),
    (["--pixels", "1,2", "--pattern", "raster"], "'pixels' is only allowed with pattern 'pixels'"),
    (["--pattern", "pixels"], "pattern 'pixels' needs a non-empty 'pixels' list"),
    (["--pixels", "0,25"], "pixels[0]: pixel (0, 25) is outside"),
])
def test_bad_pixels_refused_before_the_bench_starts(capsys, fake_bench, argv, needle):
    code, out, err = run(capsys, "scan", "--sim", "--profile", "fpsa20", *argv)
    assert code in (1, 2) and needle in err and len(err.strip().splitlines()) == 1
    assert fake_bench == []


# -- bad numbers: refused before any bench, in the daemon's own words
@pytest.mark.parametrize("argv,body", [
    (["--averages", "0"], {"averages": 0}),
    (["--max-range", "-1"], {"max_range_m": -1.0}),
    (["--averages", "101"], {"averages": 101}),
])
def test_bad_numbers_refused_with_the_daemons_message(capsys, fake_bench, make_client, argv, body):
    r = make_client(FakeInstrument()).post("/scans", json=body)
    assert r.status_code == 422
    daemon_says = r.json()["detail"]      # the problem's one line, worded from its field errors
    assert daemon_says == describe_errors(r.json()["errors"])
    code, out, err = run(capsys, "scan", "--sim", *argv)
    assert code == 1 and fake_bench == []
    assert err.strip() == f"lidarctl: error: {daemon_says}"
    # through a daemon, too: refused before any request (the URL is unreachable)
    code, out, err = run(capsys, "scan", "--url", "http://127.0.0.1:9", *argv)
    assert err.strip() == f"lidarctl: error: {daemon_says}"


def test_describe_errors_never_repeats_the_field():
    assert describe_errors([{"loc": ["body", "rows"], "msg": "rows: [0, 99) is not a non-empty range"}]) \
        == "rows: [0, 99) is not a non-empty range"
    assert describe_errors([{"loc": ["body", "averages"], "msg": "Input should be greater than or equal to 1"},
                            {"loc": ["body"], "msg": "Value error, pattern 'pixels' needs a list"}]) \
        == "averages: Input should be greater than or equal to 1; pattern 'pixels' needs a list"


# -- flags that configure the embedded bench
@pytest.mark.parametrize("argv,flag", [
    (["scan", "--profile", "fpsa20"], "--profile"),
    (["scan", "--config", "config/sim.toml"], "--config"),
    (["scan", "--data-dir", "/tmp/x"], "--data-dir"),
    (["linearize", "--config", "config/sim.toml"], "--config"),
    (["selftest", "--data-dir", "/tmp/x"], "--data-dir"),
])
def test_sim_only_flags_without_sim_are_refused(capsys, argv, flag):
    code, out, err = run(capsys, *argv, "--url", "http://127.0.0.1:9")
    assert code == 1 and flag in err and "--sim" in err and "cannot reach" not in err


# -- against a live daemon
SIM_TOML = CONFIG_DIR / "sim.toml"
# GET /devices entries as the real registry gives them (lidard.instrument.devices: status as data)
REAL_DEVICES = [
    {"name": "fpsa", "connected": True, "reconnected": False, "busy": False, "faults": [],
     "identity": "vendor=lidard-sim, model=FPSA128-HV583, firmware=[1, 0, 0], rows=128, cols=128, bonded_rows=96 values",
     "identity_fields": {"vendor": "lidard-sim", "model": "FPSA128-HV583", "firmware": [1, 0, 0], "rows": 128,
                         "cols": 128, "bonded_rows": [r for r in range(128) if r % 4 != 3]},
     "state": "state=IDLE, faults=none, pattern_index=0, pixel_counter=0, trigger_counter=0",
     "status": {"state": "IDLE", "faults": [], "pattern_index": 0, "pixel_counter": 0, "trigger_counter": 0}},
    {"name": "controller", "connected": False, "reconnected": False, "busy": False, "faults": ["INTERLOCK_OPEN"],
     "identity": "model=LHV-1550, firmware=1.0, map_version=1",
     "identity_fields": {"model": "LHV-1550", "firmware": "1.0", "map_version": 1},
     "state": "laser_current_ma=0, tec_c=25, hv_v=0, faults=none, uptime_ms=0, heartbeat=2",
     "status": {"laser_current_ma": 0.0, "tec_c": 25.0, "hv_v": 0.0, "faults": [], "uptime_ms": 0, "heartbeat": 2}},
]


class RealLookingDevices(FakeInstrument):
    def devices(self):
        return REAL_DEVICES


@pytest.fixture
def live(tmp_path):
    inst = RealLookingDevices(profile="fpsa20")
    with live_server(make_app(tmp_path / "data", inst, load_config(SIM_TOML), progress_interval_s=0.0)) as url:
        yield url, inst


def test_devices_table_has_no_reprs_or_long_tuples(capsys, live):
    url, _ = live
    code, out, err = run(capsys, "devices", "--url", url)
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0].split() == ["DEVICE", "LINK", "IDENTITY", "STATE", "FAULTS"] and len(lines) == 3
    for bad in ("Identity(", "Status(", "<State", "frozenset", "(0, 1, 2"):
        assert bad not in out
    assert "bonded_rows=96 values, 0..126" in lines[1] and "firmware=1.0.0" in lines[1] and "idle" in lines[1]
    assert "DISCONNECTED" in lines[2] and "INTERLOCK_OPEN" in lines[2] and "tec_c=25" in lines[2]
    code, out, err = run(capsys, "devices", "--url", url, "--json")
    assert json.loads(out)["devices"] == REAL_DEVICES


def test_daemon_scan_writes_the_sidecar_naming_the_scene(capsys, live, tmp_path):
    url, _ = live
    out_file = tmp_path / "d.ply"
    code, out, err = run(capsys, "scan", "--url", url, "--rows", "0:2", "--cols", "0:3", "--out", str(out_file),
                         "--json", "--progress", "none")
    assert code == 0, err
    s = json.loads(out)
    side = read_sidecar(out_file)
    scene_file = load_config(SIM_TOML).resolve_path(load_config(SIM_TOML).sim.scene)
    assert side["scene"] == {"path": str(scene_file.resolve()),
                             "sha256": hashlib.sha256(scene_file.read_bytes()).hexdigest()}
    assert side["scan_id"] == s["id"] and side["points"] == len(read_points(out_file)) == 6
    # scans show: a table, the request summarised
    code, out, err = run(capsys, "scans", "show", s["id"], "--url", url)
    assert code == 0 and "{" not in out and "roi, rows 0:2, cols 0:3" in out and "6/6 (100.0 % coverage)" in out


def test_daemon_plan_error_is_not_prefixed_twice(capsys, live):
    url, _ = live
    # the daemon's device has 128 rows: its planner refuses 0:200, and names the field once
    code, out, err = run(capsys, "scan", "--url", url, "--rows", "0:200")
    assert code == 1 and "lidarctl: error: lidard answered 422: rows: [0, 200)" in err
    assert "rows: rows" not in err


# -- help
def _subparsers(parser):
    import argparse
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return sub.choices


def test_every_flag_has_help_text():
    missing = [f"{name} {a.option_strings or a.dest}"
               for name, sp in _subparsers(cli.build_lidarctl_parser()).items()
               for a in sp._actions if a.dest != "help" and not (a.help or "").strip()]
    missing += [str(a.option_strings) for a in cli.build_lidard_parser()._actions
                if a.dest != "help" and not (a.help or "").strip()]
    assert missing == []


def test_scan_help_explains_patterns_with_two_examples(capsys):
    code, out, err = run(capsys, "scan", "--help")
    assert code == 0
    examples = out.split("examples:")[1]
    assert sum(line.strip().startswith("lidarctl scan ") for line in examples.splitlines()) == 2
    for pattern in ("raster", "serpentine", "roi", "pixels", "adaptive"):
        assert f"\n  {pattern} " in out.split("patterns (--pattern):")[1]
    for unit in ("metres", "count", "row,col"):
        assert unit in out


# -- progress renderings
def test_progress_lines_one_per_decile_and_json_one_per_event(capsys):
    lines = Progress("lines")
    events = [{"event": "progress", "stage": "scanning", "fraction": i / 1000, "pixels_done": i,
               "pixels_planned": 1000, "points": i} for i in range(1, 1001)]
    for ev in events:
        lines(ev)
    err = capsys.readouterr().err
    assert [int(line.split()[1]) for line in err.splitlines()] == list(range(10, 101, 10))
    js = Progress("json")
    for ev in events[:5] + [{"event": "end", "state": "done"}]:
        js(ev)
    assert [json.loads(line) for line in capsys.readouterr().err.splitlines()] == events[:5] + [
        {"event": "end", "state": "done"}]


def test_bar_shows_an_eta_and_says_stages_without_pixels_in_words(capsys):
    import re
    ticks = iter([0.0, 100.0, 110.0, 120.0])     # 100 s of linearization, then 2 px/s of scanning
    bar = Progress("bar", width=10, clock=lambda: next(ticks))
    bar({"event": "progress", "stage": "linearizing", "fraction": 0.0, "pixels_done": 0, "pixels_planned": 0,
         "points": 0})
    for done in (0, 20, 40):
        bar({"event": "progress", "stage": "scanning", "fraction": done / 100, "pixels_done": done,
             "pixels_planned": 100, "points": done})
    bar.close()
    err = capsys.readouterr().err
    assert err.startswith("linearizing...\n") and "0/?" not in err
    # 60 px to go at the scanning rate since the first pixels (20 px in 10 s): 30 s, not the linearization's
    assert re.search(r"40/100 px, 40 pts  ETA 30 s", err), err


# -- plot without matplotlib: the error names the package
def test_linearize_plot_without_matplotlib_names_it(capsys, monkeypatch, tmp_path):
    import sys
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.setattr(cli_base, "open_instrument", lambda cfg, **kw: FakeInstrument())
    code, out, err = run(capsys, "linearize", "--sim", "--plot", str(tmp_path / "p.png"))
    assert code == 1 and "matplotlib" in err and "pip install" in err and not (tmp_path / "p.png").exists()


# -- faults ack (POST /controller/acknowledge), against an httpx MockTransport
def _faults_ack(capsys, handler, *extra):
    args = cli.build_lidarctl_parser().parse_args(["faults", "ack", "--url", "http://lidard.test", *extra])
    code = cli_base.run(lambda a: cli_faults.cmd_faults(a, transport=httpx.MockTransport(handler)), args,
                        "lidarctl")
    out, err = capsys.readouterr()
    return code, out, err


def test_faults_ack_prints_what_was_cleared(capsys, monkeypatch):
    monkeypatch.delenv("LIDARD_LEASE", raising=False)
    seen = []

    def handler(request: httpx.Request) -> httpx.Response:
        seen.append((request.method, request.url.path, request.headers.get("X-Lidard-Lease")))
        return httpx.Response(200, json={"cleared": ["INTERLOCK_OPEN", "HV_FAULT"], "by": "ana@lab",
                                         "at": 1_700_000_000.0})
    code, out, err = _faults_ack(capsys, handler, "--lease", "L-123")
    assert code == 0 and err == ""
    assert seen == [("POST", "/controller/acknowledge", "L-123")]
    assert "cleared INTERLOCK_OPEN, HV_FAULT" in out and "by ana@lab" in out and "2023-11-14" in out
    code, out, err = _faults_ack(capsys, handler, "--lease", "L-123", "--json")
    assert json.loads(out)["cleared"] == ["INTERLOCK_OPEN", "HV_FAULT"]


def test_faults_ack_409_exits_nonzero_with_the_detail(capsys, monkeypatch):
    monkeypatch.delenv("LIDARD_LEASE", raising=False)

    def handler(request):
        return httpx.Response(409, json={"detail": "interlock still open (door switch)"})
    code, out, err = _faults_ack(capsys, handler, "--lease", "L")
    assert code == 1 and out == ""
    assert err.strip() == "lidarctl: error: faults not acknowledged, still open: interlock still open (door switch)"


def test_faults_ack_needs_the_lease(capsys, monkeypatch):
    monkeypatch.delenv("LIDARD_LEASE", raising=False)
    calls = []
    code, out, err = _faults_ack(capsys, lambda r: calls.append(r) or httpx.Response(200, json={}))
    assert code == 1 and "control acquire" in err and calls == []
