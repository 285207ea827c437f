"""Issue 13, Done-when: a tolerance injected mid-run (a TEC step) is caught by the linearization health
check and the next scan is re-linearized; without it nothing is re-linearized (no false alarm).

The daemon's job worker runs scans on the embedded bench; a plate at a known distance stands in for
the lab's reference target. The TEC step moves the laser's TRUE temperature only (the readback still
shows the set point, so the temperature rule ``scan.recalibrate_delta_c`` cannot see it). It scales
the FM response by 1 + k dT (k = ``[sim.tolerances] tec_response_per_c``), so a scan with the stale
drive measures every range k dT too long; after the re-linearization the plate is where it was.
The other bench tolerances (MZI delay, zero offset, pointing) are switched off here so that ranges
compare with the scene's truth directly (their calibrations are other tests' business).
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument
from lidard.jobs import ScanWorker
from lidard.outputs import read_points, read_sidecar
from lidard.store import Store
from sim_devices.world.scene import Scene

pytestmark = pytest.mark.slow  # a bench relinearized after a TEC step

PLATE_M = 1.5
STEP_C = 0.5
OTHER_TOLERANCES_OFF = {f"LIDARD__SIM__TOLERANCES__{k}": "0" for k in
                        ("MZI_DELAY_REL", "ZERO_OFFSET_M", "FOCAL_REL", "DECENTRE_PX", "ROTATION_DEG", "K1")}
REQUEST = ScanRequest(pattern="roi", rows=(60, 68), cols=(60, 68), max_range_m=2.0, formats=["npz"])


def _plate() -> Scene:
    return Scene.from_dict({"name": "plate", "target": [
        {"kind": "plane", "point": [0.0, 0.0, PLATE_M], "normal": [0.0, 0.0, -1.0], "size": [1.0, 1.0],
         "up": [0.0, 1.0, 0.0], "reflectivity": 0.9}]})


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    cfg = load_config("config/sim.toml", environ=OTHER_TOLERANCES_OFF)
    inst = open_instrument(cfg, bench="embedded")
    bench = inst._on_close.__self__
    bench.set_scene(_plate())
    store = Store(tmp_path_factory.mktemp("health"))
    worker = ScanWorker(inst, store, laser=cfg.laser, optics=cfg.optics(),
                        recalibrate_delta_c=cfg.scan.recalibrate_delta_c)
    worker.start()
    yield cfg, inst, bench, store, worker
    worker.stop()
    store.close()
    inst.close()


def _run(store, worker) -> tuple[dict, np.ndarray]:
    rec = worker.wait(worker.submit_scan(REQUEST).id, timeout_s=300)
    assert rec.state == "done", rec
    path = store.data_dir / rec.files["npz"]
    return read_sidecar(path), read_points(path)


def _plate_error_m(bench, pts) -> float:
    good = pts["valid"] == 1
    assert good.sum() >= 0.9 * len(np.unique(pts["row"] * 1000 + pts["col"]))
    truth = bench.ground_truth(pts["row"][good], pts["col"][good])
    return float(np.median(pts["range"][good] - truth))


def test_a_tec_step_mid_run_is_caught_and_the_next_scan_relinearized(rig):
    cfg, inst, bench, store, worker = rig
    threshold = cfg.scan.linearity_threshold_hz
    # 1. no calibration yet: the first scan linearizes, and its fresh drive checks below the threshold
    side, _ = _run(store, worker)
    lin = side["linearization"]
    assert lin["relinearized"] and lin["reason"] == "no calibration stored"
    assert lin["residual_hz"] < threshold and lin["threshold_hz"] == threshold
    assert lin["records"] == cfg.scan.linearity_check_records
    first_cal = side["calibration_id"]

    # 2. nothing happened: the stored drive passes the check, no re-linearization (no false alarm)
    side, pts = _run(store, worker)
    lin = side["linearization"]
    assert not lin["relinearized"] and lin["reason"] is None, lin
    assert lin["residual_hz"] < threshold and side["calibration_id"] == first_cal
    err_before = _plate_error_m(bench, pts)

    # 3. mid-run the laser chip warms by STEP_C; the TEC readback does not show it
    readback_c = inst.laser_temperature_c()
    inst.inject_fault("tec_offset", offset_c=STEP_C)
    assert abs(inst.laser_temperature_c() - readback_c) < 0.01
    stale_cal = store.latest_calibration(cfg.laser)
    stale = inst.run_scan(REQUEST, lambda p: None, threading.Event(), stale_cal)
    scale = cfg.sim.tolerances.tec_response_per_c * STEP_C          # the FM response grew by this
    err_stale = _plate_error_m(bench, stale.points)
    assert err_stale - err_before == pytest.approx(scale * PLATE_M, rel=0.25)

    # 4. the next scan's health check sees it and re-linearizes first; then the plate is right again
    side, pts = _run(store, worker)
    lin = side["linearization"]
    assert lin["relinearized"] and lin["reason"].startswith("linearization health"), lin
    # the stale drive's error: slope error k dT over the ROI (0.8 of a ramp): k dT excursion 0.8 / sqrt(12)
    expected_hz = scale * cfg.chirp.excursion_hz * 0.8 / np.sqrt(12)
    assert lin["stale_residual_hz"] > threshold
    assert lin["stale_residual_hz"] == pytest.approx(expected_hz, rel=0.25)
    assert lin["residual_hz"] < threshold
    assert side["calibration_id"] != first_cal
    err_after = _plate_error_m(bench, pts)
    assert abs(err_after) < 0.3e-3 and abs(err_after - err_before) < 0.2e-3
    assert worker.last_linearization == lin
    inst.clear_faults("tec_offset")


def test_the_check_follows_its_configuration_keys(rig, monkeypatch):
    cfg, inst, bench, store, worker = rig
    cal = store.latest_calibration(cfg.laser)
    scan = cfg.scan
    monkeypatch.setattr(inst, "cfg", cfg.model_copy(update={"scan": scan.model_copy(update={
        "linearity_threshold_hz": 1e3, "linearity_check_records": 4})}))
    h = inst.check_linearization(cal)
    assert h.records == 4 and h.threshold_hz == 1e3
    assert h.exceeded                                   # no chirp is within 1 kHz of ideal
    assert h.hardware_time_s == pytest.approx(4 * cfg.chirp.period_s, rel=0.2)   # whole chirp periods
    monkeypatch.setattr(inst, "cfg", cfg.model_copy(update={"scan": scan.model_copy(update={
        "linearity_check": False})}))
    assert inst.check_linearization(cal) is None
