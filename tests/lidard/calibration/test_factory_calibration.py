"""The factory calibration of a simulated bench (lidard.jobs.guided.FactoryCalibration).

* Daemon wiring, cheaply: a fake bench whose plate follows the scene the procedure places
  (R_raw = s (d / d_z + z0)); its "spheres" are still a flat plate, so the pointing fit is refused.
  The first scan then runs with the range record it fitted, says why pointing is uncalibrated, the
  scene the bench showed is put back, and the next scan does not try again.
* The one-shot ``lidarctl scan --sim`` on the real simulated bench with hidden tolerances (slow): the
  first run calibrates and says so once, the sidecar says range and pointing calibrated with values
  near the bench's truth; the second run reuses the user's cache silently; ``--uncalibrated`` skips it.
"""

from __future__ import annotations

import json

import pytest

from lidard.config import CONFIG_DIR, load_config
from tests.helpers.api import make_app
from tests.helpers.cli import run
from tests.helpers.deadlines import WAIT_S
from tests.lidard.calibration.test_calibration_cli import S_TRUE, Z0_TRUE, PlateFake


class RailFake(PlateFake):
    """The plate sits where the placed scene's first plane is."""

    def set_scene(self, scene):
        out = super().set_scene(scene)
        first = scene["target"][0]
        if first["kind"] == "plane":
            self.plate_m = float(first["point"][2])
        return out


def test_a_daemon_on_a_simulated_bench_calibrates_at_its_first_scan(tmp_path, monkeypatch):
    from fastapi.testclient import TestClient
    monkeypatch.setenv("LIDARD__SIM__FACTORY_CALIBRATION", "true")
    cfg = load_config(CONFIG_DIR / "sim.toml")
    inst = RailFake()
    with TestClient(make_app(tmp_path / "data", inst, cfg, progress_interval_s=0.0,
                             factory_calibration=True)) as c:
        sid = c.post("/scans", json={"pattern": "roi", "rows": [60, 62], "cols": [60, 62]}).json()["id"]
        c.app.state.worker.wait(sid, timeout_s=WAIT_S)
        rec = c.get(f"/scans/{sid}").json()
        assert rec["state"] == "done"
        assert rec["calibrated"]["range"] is True and rec["calibrated"]["pointing"] is False
        assert "factory calibration was refused" in rec["uncalibrated_reason"]
        rng = c.get(f"/calibration/records/{rec['range_calibration_id']}").json()
        assert [m["known_m"] for m in rng["inputs"]["measurements"]] == [0.8, 1.1, 1.4]
        assert rng["fitted"]["scale"] == pytest.approx(S_TRUE, rel=2e-5)
        assert rng["fitted"]["zero_offset_m"] == pytest.approx(Z0_TRUE, abs=1e-4)
        # plates, then the spheres, then the configuration's scene put back
        names = [s["name"] for s in inst.scenes]
        assert names[:3] == ["plate_0.8m", "plate_1.1m", "plate_1.4m"] and names[3] == "pointing_targets"
        assert inst.scenes[-1]["name"] == c.get("/sim/scene").json()["name"] == "cal_letters"
        # tried once: the next scan does not run it again
        placed = len(inst.scenes)
        sid = c.post("/scans", json={"pattern": "roi", "rows": [60, 62], "cols": [60, 62]}).json()["id"]
        c.app.state.worker.wait(sid, timeout_s=WAIT_S)
        assert len(inst.scenes) == placed


@pytest.mark.slow
@pytest.mark.tolerances
def test_one_shot_sim_scan_runs_the_factory_calibration_once_then_uses_the_cache(capsys, monkeypatch, tmp_path):
    from sim_devices.world.tolerances import draw_truth
    monkeypatch.setenv("LIDARD__SIM__FACTORY_CALIBRATION", "true")
    cfg = load_config(CONFIG_DIR / "sim.toml")
    truth = draw_truth(cfg.sim.tolerances, nominal_mzi_delay_s=cfg.monitor.delay_s, seed=cfg.sim.seed)
    out_file = tmp_path / "c.ply"
    scan = ("scan", "--sim", "--rows", "60:64", "--cols", "60:64", "--out", str(out_file), "--json")
    code, out, err = run(capsys, *scan)
    assert code == 0, err
    assert err.count("factory calibration") == 1 and "warning" not in err
    got = json.loads(out)
    assert got["calibrated"] == {"range": True, "pointing": True, "linearization": True}
    side = json.loads((tmp_path / "c.ply.json").read_text())
    geo = side["geometry"]
    assert abs(geo["monitor_delay_s"] - truth.mzi_delay_s) < 10e-12
    assert abs(geo["zero_offset_m"] - truth.zero_offset_m) < 0.2e-3
    # the range error the calibration leaves at the scan's gate, against the bench's truth, is within
    # 4 x the uncertainty the sidecar states there
    gate = geo["range_uncertainty_at_m"]
    left = (gate + truth.zero_offset_m) * geo["monitor_delay_s"] / truth.mzi_delay_s - geo["zero_offset_m"] - gate
    assert gate == side["request"]["max_range_m"] and 0 < geo["range_uncertainty_m"] < 1e-3
    assert abs(left) <= 4 * geo["range_uncertainty_m"], (left, geo["range_uncertainty_m"])
    assert side["linearization"]["relinearized"] is False      # the scan reuses the factory run's chirp

    code, out, err = run(capsys, *scan)                         # the cache: no second factory run
    assert code == 0 and "factory calibration" not in err and "warning" not in err
    side2 = json.loads((tmp_path / "c.ply.json").read_text())
    assert side2["range_calibration_id"] == side["range_calibration_id"]

    code, out, err = run(capsys, *scan, "--uncalibrated")        # the cached chirp, no records
    assert code == 0 and "factory calibration" not in err and "warning: uncalibrated range and pointing" in err


def test_rest_run_places_the_fixtures_refuses_pending_plates_and_real_hardware(tmp_path):
    from fastapi.testclient import TestClient
    cfg = load_config(CONFIG_DIR / "sim.toml")
    inst = RailFake()
    with TestClient(make_app(tmp_path / "data", inst, cfg, progress_interval_s=0.0)) as c:
        assert c.get("/sim/scene").json()["name"] == "cal_letters"
        inst.plate_m = 1.3
        early = c.post("/calibration/range/plates", json={"known_m": 1.3}).json()
        r = c.post("/calibration/run")
        assert r.status_code == 422 and early["id"] in r.json()["detail"] and "keep" in r.json()["detail"]
        assert len(inst.scenes) == 1               # refused before any fixture moved (only the put-back)
        r = c.post("/calibration/run", json={"pending": "keep", "plates_m": [0.9, 1.6]})
        # the fake's "spheres" are a flat plate: the pointing fit is refused (422), after the range fit
        assert r.status_code == 422 and "pointing" in r.json()["detail"]
        rng = c.get("/calibration/records", params={"kind": "range"}).json()[0]
        assert sorted(m["known_m"] for m in rng["inputs"]["measurements"]) == [0.9, 1.3, 1.6]
        assert rng["fitted"]["scale"] == pytest.approx(S_TRUE, rel=2e-5)
        assert [s["name"] for s in inst.scenes[1:]] == ["plate_0.9m", "plate_1.6m", "pointing_targets", "cal_letters"]
        assert c.post("/calibration/run", json={"pending": "later"}).status_code == 422
        assert c.post("/calibration/run", json={"plates_m": [1.0]}).status_code == 422
    lab = RailFake()
    lab.simulated = False
    with TestClient(make_app(tmp_path / "lab", lab, cfg, progress_interval_s=0.0)) as c:
        r = c.post("/calibration/run")
        assert r.status_code == 409 and "lidarctl calibrate" in r.json()["detail"]
        assert c.get("/sim/scene").status_code == 409
