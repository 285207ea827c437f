"""``lidarctl calibration`` and the uncalibrated warning of ``lidarctl scan`` against a live daemon whose
instrument is a fake with a plate: ranges R_raw = s (d / d_z + z0) + noise, a known truth the fit must
find through CLI -> REST -> worker -> store (issue 13 items 2 and 4)."""

import json

import numpy as np
import pytest

from lidard.config import CONFIG_DIR, load_config
from lidard.instrument.calibration.setup import calibration_setup
from lidard.instrument.types import POINT_DTYPE, ScanProgress, ScanResult
from lidard.instrument.plan import plan
from tests.helpers.api import live_server, make_app
from tests.helpers.fakes import FakeInstrument
from tests.helpers.cli import run

S_TRUE, Z0_TRUE = 200 / 201.4, 0.031


class PlateFake(FakeInstrument):
    def __init__(self):
        super().__init__()
        self.plate_m = 1.0
        self.rng = np.random.default_rng(11)

    def run_scan(self, request, progress, cancel, calibration=None):
        px = plan(request, self.optics)
        d = self.optics.directions(px[:, 0], px[:, 1])
        r = S_TRUE * (self.plate_m / d[:, 2] + Z0_TRUE) + self.rng.normal(0, 50e-6, len(px))
        pts = np.zeros(len(px), POINT_DTYPE)
        xyz = d * r[:, None]
        pts["x"], pts["y"], pts["z"], pts["range"] = xyz[:, 0], xyz[:, 1], xyz[:, 2], r
        pts["row"], pts["col"], pts["valid"] = px[:, 0], px[:, 1], 1
        progress(ScanProgress(len(px), len(px), len(px), 1e-3))
        return ScanResult(points=pts, meta={}, pixels_scanned=len(px), pixels_planned=len(px), hardware_time_s=1e-3)



@pytest.fixture
def live(tmp_path):
    inst = PlateFake()
    with live_server(make_app(tmp_path / "data", inst, progress_interval_s=0.0)) as url:
        yield url, inst


def _add(capsys, url, inst, true_m, entered_m):
    inst.plate_m = true_m
    code, out, err = run(capsys, "calibration", "range", "add", "--known-m", str(entered_m), "--url", url, "--json")
    assert code == 0, err
    return json.loads(out)


def test_range_steps_refusal_fit_and_records_through_lidarctl(capsys, live, tmp_path):
    url, inst = live
    code, out, err = run(capsys, "scan", "--url", url, "--rows", "2:4", "--json")
    assert code == 0, err
    assert json.loads(out)["calibrated"] == {"range": False, "pointing": False, "linearization": True}
    assert err.count("warning: uncalibrated range and pointing") == 1

    _add(capsys, url, inst, 0.8, 0.8)
    _add(capsys, url, inst, 1.2, 1.2)
    bad = _add(capsys, url, inst, 1.6, 1.65)
    _add(capsys, url, inst, 2.0, 2.0)
    code, out, err = run(capsys, "calibration", "range", "fit", "--url", url)
    assert code != 0 and "measurement #3 (known_m=1.65)" in err and "without it the others agree" in err
    code, out, err = run(capsys, "calibration", "range", "list", "--url", url)
    assert code == 0 and out.count("\n") >= 5 and bad["id"] in out
    code, out, err = run(capsys, "calibration", "range", "drop", "--url", url)
    assert code != 0 and "give one plate ID or --all" in err
    assert run(capsys, "calibration", "range", "drop", bad["id"], "--url", url)[0] == 0
    _add(capsys, url, inst, 1.6, 1.6)
    code, out, err = run(capsys, "calibration", "range", "fit", "--url", url, "--json")
    assert code == 0, err
    rec = json.loads(out)
    f = rec["fitted"]
    assert f["scale"] == pytest.approx(S_TRUE, abs=3e-5)
    assert f["zero_offset_m"] == pytest.approx(Z0_TRUE, abs=4 * f["zero_offset_stderr_m"] + 2e-6)
    assert f["delay_s"] == pytest.approx(200e-9 / S_TRUE, rel=3e-5)

    code, out, err = run(capsys, "calibration", "list", "--url", url)
    assert code == 0 and rec["id"] in out and "range" in out and "linearization" in out
    code, out, err = run(capsys, "calibration", "show", rec["id"], "--url", url)
    assert code == 0 and "range calibration" in out and '"measurements"' in out
    code, out, err = run(capsys, "calibration", "show", "NOPE", "--url", url)
    assert code != 0 and "no calibration record 'NOPE'" in err

    # a scan now uses the range calibration and warns about the pointing alone
    code, out, err = run(capsys, "scan", "--url", url, "--rows", "2:4", "--json")
    assert code == 0
    assert json.loads(out)["calibrated"]["range"] is True
    assert err.count("warning: uncalibrated") == 1 and "uncalibrated pointing:" in err
    code, out, err = run(capsys, "scans", "show", json.loads(out)["id"], "--url", url)
    assert code == 0 and f"range {rec['id']}, pointing NO, linearization " in out


def test_pointing_through_lidarctl_refuses_what_does_not_fit(capsys, live, tmp_path):
    url, inst = live
    code, out, err = run(capsys, "calibration", "pointing", "--geometry", str(tmp_path / "none.toml"), "--url", url)
    assert code != 0 and "none.toml: cannot read" in err
    geo = tmp_path / "spheres.toml"
    geo.write_text("[[sphere]]\ncentre = [0.0, 0.0, 1.0]\nradius = 0.03\n")
    code, out, err = run(capsys, "calibration", "pointing", "--geometry", str(geo), "--url", url)
    assert code != 0 and "no range calibration yet" in err
    for d in (0.8, 1.4):
        _add(capsys, url, inst, d, d)
    assert run(capsys, "calibration", "range", "fit", "--url", url)[0] == 0
    # the fake shows a flat plate at 1 m, not the sphere the geometry promises
    code, out, err = run(capsys, "calibration", "pointing", "--geometry", str(geo), "--url", url)
    assert code != 0 and "pointing calibration" in err and "422" in err


def test_sim_scan_says_uncalibrated_without_a_store_and_uses_the_stored_calibrations_with_one(
        capsys, monkeypatch, tmp_path):
    from lidard.cli import base as cli_base
    from lidard.outputs import read_sidecar
    from lidard.store import Store
    inst = FakeInstrument()
    monkeypatch.setattr(cli_base, "open_instrument", lambda cfg, **kw: inst)
    out_file = tmp_path / "s.ply"
    code, out, err = run(capsys, "scan", "--sim", "--rows", "2:4", "--out", str(out_file), "--json")
    assert code == 0, err
    assert json.loads(out)["calibrated"] == {"range": False, "pointing": False, "linearization": True}
    assert err.count("warning: uncalibrated range and pointing") == 1
    side = read_sidecar(out_file)
    assert side["calibrated"]["range"] is False and side["pointing_calibration_id"] is None

    data = tmp_path / "data"
    st = Store(data)
    setup = calibration_setup(load_config(CONFIG_DIR / "sim.toml"))   # what the --sim scans run on
    rng = st.geometry.save("range", temperature_c=25.0, inputs={"setup": setup["range"].as_dict()},
                                       residuals={}, fitted={"delay_s": 201.2e-9, "zero_offset_m": 0.02})
    pnt = st.geometry.save("pointing", temperature_c=25.0, inputs={"setup": setup["pointing"].as_dict()},
                                       residuals={},
                                       fitted={"focal_scale": 1.01, "decentre_px": [0.5, -0.2],
                                               "rotation_rad": 0.004, "k1": 0.1})
    st.close()
    code, out, err = run(capsys, "scan", "--sim", "--data-dir", str(data), "--rows", "2:4", "--out", str(out_file),
                         "--json")
    assert code == 0, err
    assert json.loads(out)["calibrated"] == {"range": True, "pointing": True, "linearization": True}
    assert "warning" not in err
    side = read_sidecar(out_file)
    assert (side["range_calibration_id"], side["pointing_calibration_id"]) == (rng.id, pnt.id)
    # the worker handed both to the instrument before the scan
    assert inst.applied.delay_s == 201.2e-9 and inst.applied.zero_offset_m == 0.02
    assert inst.applied.pointing.decentre_px == (0.5, -0.2) and inst.monitor_delay_s() == 201.2e-9

    # the same data directory under another laser: its range records are another set-up's; the
    # pointing (the chip behind its lens) is still this one's
    other = tmp_path / "other_laser.toml"
    other.write_text((CONFIG_DIR / "sim.toml").read_text().replace('laser = "dfb_default"', 'laser = "ideal"'))
    code, out, err = run(capsys, "scan", "--sim", "--config", str(other), "--data-dir", str(data), "--rows", "2:4",
                         "--out", str(out_file), "--json")
    assert code == 0, err
    got = json.loads(out)
    assert got["calibrated"] == {"range": False, "pointing": True, "linearization": True}
    assert f"range calibration {rng.id} not used" in got["uncalibrated_reason"]
    assert "laser dfb_default here ideal" in got["uncalibrated_reason"]
    assert err.count("warning: uncalibrated range:") == 1 and "another set-up" in err
    side = read_sidecar(out_file)
    assert side["calibrated"]["range"] is False and side["uncalibrated_reason"] == got["uncalibrated_reason"]
    assert inst.applied.delay_s is None and inst.applied.pointing is not None
    # a record that names no set-up (an older data directory) is not trusted either
    st = Store(data)
    st.geometry.save("range", temperature_c=25.0, inputs={}, residuals={},
                                 fitted={"delay_s": 201.2e-9, "zero_offset_m": 0.02})
    st.close()
    code, out, err = run(capsys, "scan", "--sim", "--data-dir", str(data), "--rows", "2:4", "--json")
    got = json.loads(out)
    assert got["calibrated"]["range"] is True and got["uncalibrated_reason"] is None   # the older matching one
