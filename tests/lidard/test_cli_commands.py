"""lidarctl/lidard: optics and budget figures, scans against a daemon and --sim, one-line errors."""

import json
import math

import pytest

from lidard import cli
from lidard.cli import base as cli_base
from lidard.cli.progress import Progress
from lidard.outputs import read_points, read_sidecar
from tests.helpers.api import live_server, make_app
from tests.helpers.fakes import FakeInstrument
from tests.helpers.cli import run

TABLE_2_2 = """
profile = "fpsa20"
[detector]
balanced = true
cmrr_db = -25.0
[link]
reference = "mzi"
laser_power_w = 0.05
r_ref = 0.1
eta_tx = 0.7
eta_rx = 0.5
rx_aperture_m = 0.01
"""



def one_json(out):
    lines = [ln for ln in out.splitlines() if ln.strip()]
    assert len(lines) == 1, out
    return json.loads(lines[0])


# -- optics: dissertation §4.2.1 (20x20), §4.3.1 (128x128, 5 mm lens), §4.4.1 (25 mm lens)
@pytest.mark.parametrize("profile,lens,fov,res,div", [
    ("fpsa20", None, 32.0, 1.7, 0.064),
    ("fpsa128", "compound_5mm", 70.0, 0.6, 0.05),
    ("fpsa128", "lidar_25mm", 16.0, 0.13, None),
])
def test_optics_json_matches_dissertation(capsys, profile, lens, fov, res, div):
    argv = ["optics", "--profile", profile, "--json"] + (["--lens", lens] if lens else [])
    code, out, err = run(capsys, *argv)
    assert code == 0 and err == ""
    s = one_json(out)
    assert s["fov_deg"][0] == pytest.approx(fov, rel=0.02) and s["fov_deg"][1] == pytest.approx(fov, rel=0.02)
    assert s["resolution_deg"][0] == pytest.approx(res, rel=0.06)
    if div is not None:
        assert s["divergence_deg"][0] == pytest.approx(div, rel=0.03)
    assert len(s["pixels"]) == 2 and isinstance(s["bonded_rows"], int)
    assert s["bonded_rows"] == (96 if profile == "fpsa128" else 20)


def test_optics_human_output(capsys):
    code, out, _ = run(capsys, "optics", "--profile", "fpsa20")
    assert code == 0 and "field of view" in out and "31.7" in out


# -- budget: Table 2-2 set-up, signal meets shot noise near 220 m (Fig. 2-8)
@pytest.fixture
def t22(tmp_path):
    p = tmp_path / "t22.toml"
    p.write_text(TABLE_2_2)
    return str(p)


def test_budget_json_keys_and_shot_noise_crossing(capsys, t22):
    reps = {}
    for d in (150, 300):
        code, out, err = run(capsys, "budget", "--config", t22, "--distance", str(d), "--json")
        assert code == 0, err
        reps[d] = one_json(out)
    assert set(reps[150]["asd_v_per_rthz"]) == {"signal", "pedestal", "shot", "rin", "thermal", "adc", "ambient"}
    assert {"snr_db", "max_range_m"} <= set(reps[150])
    a150, a300 = reps[150]["asd_v_per_rthz"], reps[300]["asd_v_per_rthz"]
    assert a150["signal"] > a150["shot"] and a300["signal"] < a300["shot"]
    # the signal amplitude falls as 1/d (eq. 2-10 power ~ 1/d^2) apart from the coherence decay
    assert reps[150]["snr_db"] > reps[300]["snr_db"]
    # crossing by log-interpolation of signal/shot between the two distances: ~220 m
    r1, r2 = math.log(a150["signal"] / a150["shot"]), math.log(a300["signal"] / a300["shot"])
    cross = math.exp(math.log(150) + (math.log(300) - math.log(150)) * r1 / (r1 - r2))
    assert 200 < cross < 240


def test_budget_power_moves_the_crossing(capsys, t22):
    # signal ~ P (sqrt(P_ref P_rx)), shot ~ sqrt(P_ref) ~ sqrt(P): 4x power doubles signal/shot, so
    # at 230 m (just beyond the ~220 m crossing) the signal rises above shot noise again
    code, out, _ = run(capsys, "budget", "--config", t22, "--distance", "230", "--power", "0.2", "--json")
    a = one_json(out)["asd_v_per_rthz"]
    assert code == 0 and a["signal"] > a["shot"]
    code, out, _ = run(capsys, "budget", "--config", t22, "--distance", "230", "--power", "0.05", "--json")
    b = one_json(out)["asd_v_per_rthz"]
    assert b["signal"] < b["shot"]
    assert a["signal"] / b["signal"] == pytest.approx(4.0, rel=1e-6)
    assert a["shot"] / b["shot"] == pytest.approx(2.0, rel=1e-3)


def test_budget_human_table(capsys, t22):
    code, out, _ = run(capsys, "budget", "--config", t22, "--distance", "220")
    assert code == 0 and "shot" in out and "SNR" in out


# -- one-line errors
@pytest.mark.parametrize("argv,needle", [
    (["optics"], "--profile"),
    (["optics", "--profile", "fpsa20", "--frobnicate"], "frobnicate"),
    (["budget", "--profile", "fpsa20", "--distance", "abc"], "distance"),
    (["optics", "--profile", "nope"], "nope"),
    (["optics", "--profile", "fpsa20", "--lens", "fisheye"], "fisheye"),
    (["budget", "--distance", "-5"], "distance"),
    (["scans", "show", "X", "--url", "http://127.0.0.1:9"], "cannot reach lidard"),
    (["status", "--url", "http://127.0.0.1:9"], "cannot reach lidard"),
    (["scan", "--url", "http://127.0.0.1:9", "--out", "x.ply"], "cannot reach lidard"),
    (["scan", "--out", "x.txt"], "txt"),
    (["scan", "--scene", "s.toml"], "--sim"),
])
def test_errors_are_one_line_nonzero(capsys, argv, needle):
    code, out, err = run(capsys, *argv)
    assert code not in (0, None)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert needle in lines[0] and "Traceback" not in err


def test_bad_config_is_one_line(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[adc]\nbits = 9\n")
    code, out, err = run(capsys, "budget", "--config", str(bad), "--distance", "10")
    assert code == 1 and len(err.strip().splitlines()) == 1 and "adc.bits" in err


def test_lidard_refuses_public_bind_without_token(capsys, monkeypatch):
    monkeypatch.delenv("LIDARD_API_TOKEN", raising=False)
    opened = []
    monkeypatch.setattr(cli_base, "open_instrument", lambda cfg, **kw: opened.append(cfg))
    code = cli.lidard_main(["--host", "0.0.0.0", "--port", "0"])
    err = capsys.readouterr().err
    assert code != 0 and "token" in err and len(err.strip().splitlines()) == 1
    assert opened == []


def test_lidard_bad_config_one_line(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("profile = 'nope'\n")
    code = cli.lidard_main(["--config", str(bad)])
    err = capsys.readouterr().err
    assert code == 1 and len(err.strip().splitlines()) == 1 and "nope" in err


def test_is_loopback():
    assert cli.is_loopback("127.0.0.1") and cli.is_loopback("localhost") and cli.is_loopback("::1")
    assert not cli.is_loopback("0.0.0.0") and not cli.is_loopback("192.168.1.5")


# -- --sim: the daemon's job path in process, with the fake instrument as the bench
def test_scan_sim_writes_out_and_json(capsys, monkeypatch, tmp_path):
    seen = {}

    def fake_open(cfg, **kw):
        seen.update(kw, profile=cfg.profile)
        return FakeInstrument(profile=cfg.profile)
    monkeypatch.setattr(cli_base, "open_instrument", fake_open)
    out_file = tmp_path / "cloud.npz"
    code, out, err = run(capsys, "scan", "--sim", "--profile", "fpsa20", "--rows", "0:4", "--cols", "0:5",
                         "--averages", "2", "--out", str(out_file), "--json")
    assert code == 0, err
    s = one_json(out)
    assert seen["bench"] == "embedded" and seen["profile"] == "fpsa20"
    assert s["points"] == 20 and s["coverage"] == 1.0 and s["simulated"] is True and s["out"] == str(out_file)
    assert s["hardware_time_s"] == pytest.approx(20 * 200e-6)
    assert s["realtime_factor"] == pytest.approx(s["hardware_time_s"] / s["wall_time_s"])
    pts = read_points(out_file)
    assert len(pts) == 20 and set(pts["row"].tolist()) == {0, 1, 2, 3}
    side = read_sidecar(out_file)
    assert side["simulated"] is True and side["profile"] == "fpsa20" and side["partial"] is False
    # stderr is not a terminal: no bar redrawn with "\r", plain progress lines at 10 % steps up to 100 %
    assert "\r" not in err
    steps = [int(line.split()[1]) for line in err.splitlines() if line.startswith("scanning")]
    assert steps and steps[-1] == 100 and all(b > a for a, b in zip(steps, steps[1:]))
    assert all(p % 10 == 0 for p in steps) and len(steps) <= 10


def test_scan_sim_phase_noise_option_reaches_the_request(capsys, monkeypatch, tmp_path):
    made = []

    def fake_open(cfg, **kw):
        made.append(FakeInstrument(profile=cfg.profile))
        return made[-1]
    monkeypatch.setattr(cli_base, "open_instrument", fake_open)
    code, out, err = run(capsys, "scan", "--sim", "--profile", "fpsa20", "--rows", "0:2", "--cols", "0:2",
                         "--phase-noise", "on", "--out", str(tmp_path / "pn.npz"), "--json")
    assert code == 0, err
    assert [q.phase_noise_compensation for q in made[0].requests] == ["on"]
    code, out, err = run(capsys, "scan", "--sim", "--phase-noise", "maybe")
    assert code != 0 and "--phase-noise" in err


def test_scan_sim_bad_rows_is_one_line(capsys, monkeypatch):
    monkeypatch.setattr(cli_base, "open_instrument", lambda cfg, **kw: FakeInstrument(profile=cfg.profile))
    code, out, err = run(capsys, "scan", "--sim", "--profile", "fpsa20", "--rows", "0:99")
    assert code == 1 and "rows" in err and len(err.strip().splitlines()) == 1


def test_linearize_sim_json_and_plot(capsys, monkeypatch, tmp_path):
    monkeypatch.setattr(cli_base, "open_instrument", lambda cfg, **kw: FakeInstrument())
    png = tmp_path / "ilc.png"
    code, out, err = run(capsys, "linearize", "--sim", "--json", "--plot", str(png))
    assert code == 0, err
    j = one_json(out)
    assert j["iterations"] == [{"up_rms_hz": 4e6, "down_rms_hz": 5e6}, {"up_rms_hz": 4e4, "down_rms_hz": 1e5}]
    assert j["reduction"] == {"up": 100.0, "down": 50.0}
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# -- against a live uvicorn server on a free loopback port
@pytest.fixture
def live(tmp_path):
    inst = FakeInstrument(profile="fpsa20")
    with live_server(make_app(tmp_path / "data", inst, progress_interval_s=0.0)) as url:
        yield url, inst
    assert inst.closed


def test_live_server_scan_fetch_and_status(capsys, live, tmp_path):
    url, inst = live
    code, out, err = run(capsys, "status", "--url", url, "--json")
    assert code == 0 and one_json(out)["status"] == "ok"
    code, out, err = run(capsys, "devices", "--url", url)
    assert code == 0 and "digitizer" in out
    out_file = tmp_path / "live.ply"
    code, out, err = run(capsys, "scan", "--url", url, "--rows", "2:4", "--out", str(out_file), "--json")
    assert code == 0, err
    s = one_json(out)
    assert s["state"] == "done" and s["points"] == 40 and s["coverage"] == 1.0 and s["simulated"] is True
    assert len(read_points(out_file)) == 40
    code, out, err = run(capsys, "scans", "list", "--url", url)
    assert code == 0 and s["id"] in out
    code, out, err = run(capsys, "scans", "show", s["id"], "--url", url, "--json")
    assert code == 0 and one_json(out)["counts"]["points"] == 40
    fetched = tmp_path / "f.ply"
    code, out, err = run(capsys, "scans", "fetch", s["id"], "--format", "ply", "--out", str(fetched), "--url", url)
    assert code == 0 and fetched.read_bytes() == out_file.read_bytes()
    code, out, err = run(capsys, "scans", "show", "NOPE", "--url", url)
    assert code == 1 and "404" in err and len(err.strip().splitlines()) == 1
    code, out, err = run(capsys, "linearize", "--url", url, "--json")
    assert code == 0 and one_json(out)["reduction"]["up"] == 100.0


def test_progress_bar_draws_only_when_enabled(capsys):
    bar = Progress("bar", width=10)
    bar({"event": "progress", "stage": "scanning", "fraction": 0.5, "pixels_done": 5, "pixels_planned": 10,
         "points": 4})
    bar({"event": "end"})
    bar.close()
    err = capsys.readouterr().err
    assert "[#####.....]" in err and "50.0%" in err and "5/10 px" in err and err.endswith("\n")
    quiet = Progress("none")
    quiet({"event": "progress", "fraction": 1.0})
    quiet.close()
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("command", ["scan", "stream"])
def test_max_range_help_states_the_gate_margin_the_dsp_applies(capsys, command):
    # the help and the API docs say how far past max_range_m points are still reported: the DSP's figure
    from pathlib import Path
    from lidard.dsp.detect.gate import GATE_MARGIN
    said = f"points are reported up to {round((GATE_MARGIN - 1) * 100)} % past it"
    code, out, _ = run(capsys, command, "--help")
    assert code == 0 and said in " ".join(out.split())
    api = Path(__file__).resolve().parents[2] / "docs" / "api.md"
    assert f"up to {round((GATE_MARGIN - 1) * 100)} % past it" in " ".join(api.read_text().split())
    # ... and the near end the DSP keeps (no point nearer: a 4.5 cm plate gave none, unannounced)
    from lidard.dsp.frame import FrameDsp
    assert f"none nearer than {FrameDsp.min_range_m * 100:g} cm" in " ".join(api.read_text().split())
