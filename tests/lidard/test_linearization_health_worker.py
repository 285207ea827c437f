"""The job worker's use of the linearization health check (issue 13): a stored drive whose chirp error
exceeds the limit is re-learned before the scan, one within it is reused, the temperature rule stays a
second trigger, and the scan's sidecar and GET /health say what happened."""

from __future__ import annotations

import json
import math

import pytest

from lidard.cli.lidarctl import main as lidarctl
from lidard.instrument.healthcheck import NOISE_GUARD, HealthCheck, health_record
from lidard.instrument.types import ScanRequest
from lidard.jobs import ScanWorker
from lidard.outputs import read_sidecar
from lidard.store import Store
from tests.helpers.api import live_server, make_app
from tests.helpers.fakes import FRESH_CHIRP_ERROR_HZ, FakeInstrument
from tests.helpers.deadlines import WAIT_S

T = WAIT_S  # a deadline for a hung test (tests/helpers/deadlines.py)
SMALL = dict(pattern="roi", rows=(0, 3), cols=(0, 20), formats=("npz",))


@pytest.fixture
def rig(tmp_path):
    inst = FakeInstrument()
    inst.chirp_error_hz = FRESH_CHIRP_ERROR_HZ          # the check is on
    store = Store(tmp_path)
    w = ScanWorker(inst, store, laser="dfb_default", progress_interval_s=0.0, recalibrate_delta_c=0.5)
    w.start()
    yield inst, store, w
    w.stop()


def _scan(store, w) -> dict:
    rec = w.wait(w.submit_scan(ScanRequest(**SMALL)).id, T)
    assert rec.state == "done"
    return read_sidecar(store.data_dir / rec.files["npz"])["linearization"]


def test_a_chirp_error_above_the_threshold_relearns_before_the_scan(rig):
    inst, store, w = rig
    lin = _scan(store, w)                                   # nothing stored: learned, then checked
    assert inst.linearize_calls == 1 and lin["relinearized"] and lin["reason"] == "no calibration stored"
    assert lin["residual_hz"] == FRESH_CHIRP_ERROR_HZ and "stale_residual_hz" not in lin
    inst.chirp_error_hz = 150e3                             # below the fake's 200 kHz: reused
    lin = _scan(store, w)
    assert inst.linearize_calls == 1 and not lin["relinearized"] and lin["reason"] is None
    assert lin["residual_hz"] == 150e3 and lin["threshold_hz"] == 200e3
    inst.chirp_error_hz = 800e3                             # a TEC step: re-learned first
    lin = _scan(store, w)
    assert inst.linearize_calls == 2 and lin["relinearized"]
    assert lin["reason"] == "linearization health: chirp error 800 kHz rms above 200 kHz (scan.linearity_threshold_hz)"
    assert lin["stale_residual_hz"] == 800e3 and lin["residual_hz"] == FRESH_CHIRP_ERROR_HZ
    assert inst.calibrations_used[-1].meta["id"] == store.latest_calibration("dfb_default").meta["id"]
    assert w.last_linearization == lin


def test_the_temperature_rule_still_triggers_without_a_check(rig):
    inst, store, w = rig
    _scan(store, w)
    inst.temperature_c = 25.6                               # 0.6 C > recalibrate_delta_c, chirp still fine
    lin = _scan(store, w)
    assert inst.linearize_calls == 2 and lin["relinearized"] and lin["reason"].startswith("laser at 25.60 C")
    checks = inst.checks
    inst.chirp_error_hz = None                              # scan.linearity_check = false: no record
    inst.temperature_c = 25.6
    assert _scan(store, w) is None and inst.checks == checks and inst.linearize_calls == 2


def _check(residual_hz: float, noise_hz: float) -> HealthCheck:
    return HealthCheck(residual_hz=residual_hz, up_error_hz=residual_hz, down_error_hz=residual_hz,
                       nonlinearity_hz=0.0, relative=residual_hz / 8.6e9, noise_floor_hz=noise_hz,
                       threshold_hz=200e3, records=16, hardware_time_s=2.56e-3, wall_time_s=0.1,
                       temperature_c=25.0)


def test_the_limit_is_the_threshold_unless_the_check_itself_is_noisier():
    assert _check(190e3, 50e3).limit_hz == 200e3 and not _check(190e3, 50e3).exceeded
    assert _check(210e3, 50e3).exceeded
    noisy = _check(250e3, 100e3)                             # a broad-linewidth monitor: 3 x 100 kHz
    assert noisy.limit_hz == NOISE_GUARD * 100e3 and not noisy.exceeded
    assert _check(400e3, 100e3).reason() == ("linearization health: chirp error 400 kHz rms above 300 kHz "
                                             "(3x the check's noise floor, above scan.linearity_threshold_hz "
                                             "200 kHz)")
    assert _check(math.nan, math.nan).exceeded              # nothing measurable is not a pass
    assert _check(100e3, math.nan).limit_hz == 200e3        # one record: no noise estimate


def test_health_record_without_a_check():
    assert health_record(None, None, None) is None
    assert health_record(None, None, "no calibration stored") == {"relinearized": True,
                                                                  "reason": "no calibration stored"}


def test_get_health_and_lidarctl_status_show_the_last_check(tmp_path, capsys):
    inst = FakeInstrument()
    inst.chirp_error_hz = 800e3                              # the first scan learns anyway (nothing stored)
    with live_server(make_app(tmp_path, inst)) as url:
        assert lidarctl(["status", "--url", url]) == 0
        assert "linearization" not in capsys.readouterr().out            # no scan yet
        assert lidarctl(["scan", "--url", url, "--pattern", "roi", "--rows", "0:3", "--cols", "0:20",
                         "--progress", "none"]) == 0
        capsys.readouterr()
        inst.chirp_error_hz = 900e3
        assert lidarctl(["scan", "--url", url, "--pattern", "roi", "--rows", "0:3", "--cols", "0:20",
                         "--progress", "none"]) == 0
        capsys.readouterr()
        assert lidarctl(["status", "--url", url, "--json"]) == 0
        lin = json.loads(capsys.readouterr().out)["linearization"]
        assert lin["relinearized"] and lin["stale_residual_hz"] == 900e3
        assert lin["residual_hz"] == FRESH_CHIRP_ERROR_HZ
        assert lidarctl(["status", "--url", url]) == 0
        out = capsys.readouterr().out
        assert "linearization: chirp error 50 kHz rms (threshold 200 kHz); re-linearized: linearization " \
               "health: chirp error 900 kHz rms above 200 kHz" in out
