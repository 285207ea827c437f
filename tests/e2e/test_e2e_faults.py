"""The daemon under faults (issue 6): one test per fault kind of the simulated bench, each showing
recovery or a clean failed state, and that no data was lost.

Everything runs through the daemon's own job path (ScanWorker + Store + point-cloud writer) on the
real instrument composition with an embedded bench (real drivers, real pty, Modbus TCP, pyusb).
"No data lost" is checked the same way for every test (:func:`_assert_nothing_lost`): every file the
store lists parses and holds exactly the point count the store reports, no temporary file is left,
and a scan that stopped early kept its points.
"""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest
from plyfile import PlyData

from lidard.config import load_config
from lidard.instrument import SAFETY_CHECK_S, open_instrument
from lidard.instrument.types import ScanRequest
from lidard.jobs import ScanWorker
from lidard.store import Store
from tests.helpers.tolerances import NOMINAL_ENV
from tests.helpers.deadlines import WAIT_S

pytestmark = pytest.mark.slow  # a linearized bench, then one scan per fault kind (~1 min)

ROI = ScanRequest(pattern="roi", rows=(40, 56), cols=(40, 72), max_range_m=2.0)   # 384 bonded pixels
N_PIX = 12 * 32
# Short wall-clock timeouts: a swallowed answer costs one timeout of real waiting (the pty / TCP
# read), so keep them small; they are not asserted on.
ENV = {**NOMINAL_ENV, "LIDARD__DEVICES__CONTROLLER__TIMEOUT_S": "0.2", "LIDARD__DEVICES__FPSA__TIMEOUT_S": "0.1"}


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    cfg = load_config("config/sim.toml", environ=ENV)
    inst = open_instrument(cfg, scene_path="config/scenes/cal_letters.toml", bench="embedded")
    bench = inst._on_close.__self__
    data_dir = tmp_path_factory.mktemp("faults-data")
    store = Store(data_dir)
    worker = ScanWorker(inst, store, laser=cfg.laser, optics=cfg.optics(), progress_interval_s=0.0)
    worker.start()
    # the first scan linearizes; its points are the reference for every later scan
    ref = worker.wait(worker.submit_scan(ROI).id, timeout_s=WAIT_S)
    assert ref.state == "done" and ref.points >= 0.98 * N_PIX
    yield {"inst": inst, "bench": bench, "store": store, "worker": worker, "ref_points": ref.points}
    worker.stop()
    store.close()
    inst.close()


@pytest.fixture
def r(rig):
    yield rig
    inst = rig["inst"]
    inst.clear_faults()
    inst.controller.clear_faults()       # a latched INTERLOCK_OPEN / HV_FAULT needs CLEAR_FAULTS
    assert inst.active_faults() == []


def _scan(rig, req=ROI, on_progress=None):
    w = rig["worker"]
    rec = w.submit_scan(req)
    if on_progress is not None:
        w.subscribe(rec.id, on_progress)
    return w.wait(rec.id, timeout_s=WAIT_S)


def _assert_nothing_lost(rig, rec):
    """Every listed file parses with the stored point count; no temp file; early stops kept points."""
    store = rig["store"]
    data_dir = store.data_dir
    assert not [p for p in data_dir.rglob("*") if p.name.endswith(".tmp") or ".tmp" in p.suffixes]
    for fmt, rel in rec.files.items():
        path = data_dir / rel
        assert path.is_file(), path
        if fmt == "ply":
            assert len(PlyData.read(str(path))["vertex"]) == rec.points
        side = json.loads(path.with_name(path.name + ".json").read_text())
        assert side["scan_id"] == rec.id
        assert side["pixels_scanned"] == rec.pixels_scanned
    if rec.pixels_scanned > 0:
        assert rec.files, f"scan {rec.id} measured {rec.pixels_scanned} pixels but wrote no file"


def _assert_complete(rig, rec):
    """Every pixel measured and (nearly) every pixel ranged on the CAL letters / card at 0.8-0.9 m.
    (Not an exact count: the noise is seeded by the run's virtual start time, which faults shift.)"""
    assert rec.pixels_scanned == N_PIX
    pts = _points(rig, rec)
    good = np.asarray(pts["valid"]) == 1
    assert good.sum() >= 0.98 * N_PIX
    assert np.all(np.abs(np.asarray(pts["range"])[good] - 0.85) < 0.06)


def _sidecar(rig, rec) -> dict:
    return json.loads((rig["store"].data_dir / (rec.files["ply"] + ".json")).read_text())


def _points(rig, rec):
    return PlyData.read(str(rig["store"].data_dir / rec.files["ply"]))["vertex"]


# ---------------------------------------------------------------------------------------- serial
@pytest.mark.parametrize("kind", ["serial_drop", "serial_flip"])
def test_serial_line_noise_is_retried_and_the_scan_completes(r, kind):
    fpsa = r["inst"].fpsa
    retries0 = fpsa.retry_count
    r["inst"].inject_fault(kind, rate=2e-3)
    rec = _scan(r)
    assert rec.state == "done", rec.error
    assert fpsa.retry_count > retries0                     # the noise was really there and retried
    _assert_complete(r, rec)
    _assert_nothing_lost(r, rec)


def test_serial_disconnect_reconnects_through_the_stable_path(r):
    inst = r["inst"]
    inst.inject_fault("serial_disconnect")
    fpsa = [d for d in inst.devices() if d["name"] == "fpsa"][0]
    assert fpsa["connected"] is False and fpsa["faults"]          # shown with its cause
    inst.clear_faults("serial_disconnect")                        # the FPGA is back on a NEW pty
    n0 = inst.fpsa.reconnect_count
    fpsa = [d for d in inst.devices() if d["name"] == "fpsa"][0]
    assert fpsa["connected"] is True and fpsa["reconnected"] is True   # no daemon restart
    assert inst.fpsa.reconnect_count == n0 + 1
    rec = _scan(r)
    assert rec.state == "done", rec.error
    _assert_complete(r, rec)
    _assert_nothing_lost(r, rec)


def test_serial_disconnect_that_comes_back_by_itself_mid_transaction(r):
    inst = r["inst"]
    # back after 15 ms of virtual time: inside the driver's backoff schedule (10 + 20 + 40 ms)
    inst.inject_fault("serial_disconnect", reconnect_after_s=0.015)
    rec = _scan(r)
    assert rec.state == "done", rec.error
    _assert_complete(r, rec)
    _assert_nothing_lost(r, rec)


# ------------------------------------------------------------------------------------------- USB
def test_usb_timeouts_are_retried_by_the_driver(r):
    r["inst"].inject_fault("usb_timeout", device="digitizer", n=2)
    r["inst"].inject_fault("usb_timeout", device="awg", n=1)
    rec = _scan(r)
    assert rec.state == "done", rec.error
    _assert_complete(r, rec)
    _assert_nothing_lost(r, rec)


def test_usb_device_that_stays_down_fails_the_scan_naming_it_then_recovers(r):
    inst = r["inst"]
    inst.inject_fault("usb_timeout", device="digitizer")            # until cleared
    rec = _scan(r)
    assert rec.state == "failed"
    assert "digitizer" in rec.error and "DeviceTimeout" in rec.error
    _assert_nothing_lost(r, rec)
    inst.clear_faults()
    rec = _scan(r)
    assert rec.state == "done", rec.error
    _assert_complete(r, rec)


def test_usb_stall_is_a_clean_failure_naming_the_device(r):
    r["inst"].inject_fault("usb_stall", device="awg", n=1)
    rec = _scan(r)
    assert rec.state == "failed"
    assert "awg" in rec.error and "stall" in rec.error.lower()
    _assert_nothing_lost(r, rec)
    rec = _scan(r)                                  # a single stall does not wedge the AWG
    assert rec.state == "done", rec.error


def test_usb_disconnect_is_found_again_by_vid_pid(r):
    inst = r["inst"]
    n0 = inst.digitizer.reconnect_count
    inst.inject_fault("usb_disconnect", device="digitizer", n=1)
    rec = _scan(r)
    assert rec.state == "done", rec.error
    assert inst.digitizer.reconnect_count == n0 + 1
    _assert_complete(r, rec)
    _assert_nothing_lost(r, rec)


def test_usb_disconnect_shown_by_devices_until_it_is_back(r):
    inst = r["inst"]
    inst.inject_fault("usb_disconnect", device="awg")               # gone until cleared
    awg = [d for d in inst.devices() if d["name"] == "awg"][0]
    assert awg["connected"] is False and any("awg" in f for f in awg["faults"])
    inst.clear_faults("usb_disconnect")
    awg = [d for d in inst.devices() if d["name"] == "awg"][0]
    assert awg["connected"] is True and awg["faults"] == []


def test_digitizer_disconnect_mid_scan_keeps_the_points_so_far(r):
    inst = r["inst"]
    fired = []

    def pull_the_cable(ev):
        if ev.get("event") == "progress" and ev.get("pixels_done", 0) >= 100 and not fired:
            fired.append(inst.inject_fault("usb_disconnect", device="digitizer"))

    rec = _scan(r, on_progress=pull_the_cable)
    assert fired
    assert rec.state == "failed" and "digitizer" in rec.error
    assert rec.partial and 100 <= rec.pixels_scanned < N_PIX and rec.points > 0
    _assert_nothing_lost(r, rec)


# ------------------------------------------------------------------------------------- digitizer
def test_overrange_points_are_flagged_invalid_never_good(r):
    r["inst"].inject_fault("digitizer_overrange", gain=2000)
    rec = _scan(r)
    assert rec.state == "done", rec.error
    pts = _points(r, rec)
    meta = _sidecar(r, rec)["faults"]
    assert meta["overrange_segments"] > 0 and meta["overrange_pixels"] > 0
    clipped = meta["overrange_pixels"]
    # at most (pixels not clipped) points can be valid
    assert int(np.sum(np.asarray(pts["valid"]) == 1)) <= (N_PIX - clipped) * 4
    assert clipped == N_PIX and int(np.sum(np.asarray(pts["valid"]))) == 0
    _assert_nothing_lost(r, rec)


# ---------------------------------------------------------------------------------------- Modbus
def test_modbus_busy_is_retried_with_backoff(r):
    r["inst"].inject_fault("modbus_exception", code=6, n=2)
    rec = _scan(r)
    assert rec.state == "done", rec.error
    _assert_complete(r, rec)


def test_modbus_device_failure_is_a_clean_failure_naming_the_controller(r):
    # the worker's first controller request is the TEC temperature read that decides whether the stored
    # calibration still holds (an unreadable temperature keeps it); the second, the scan's bring-up, fails
    r["inst"].inject_fault("modbus_exception", code=4, n=2)
    rec = _scan(r)
    assert rec.state == "failed"
    assert "controller" in rec.error.lower() or "DeviceFailure" in rec.error
    _assert_nothing_lost(r, rec)
    # outputs are off after the failure (the bring-down ran)
    st = r["bench"].controller.state
    assert not st.laser_on and not st.hv_on


def test_modbus_timeouts_are_retried_with_a_reconnect(r):
    r["inst"].inject_fault("modbus_timeout", n=2)
    rec = _scan(r)
    assert rec.state == "done", rec.error
    _assert_complete(r, rec)


def test_controller_unreachable_then_back_is_shown_by_devices(r):
    inst = r["inst"]
    inst.controller.close()                # drop the TCP connection under the driver
    ctl = [d for d in inst.devices() if d["name"] == "controller"][0]
    assert ctl["connected"] is True        # pymodbus reconnects on the next request


# ------------------------------------------------------------------------------------- interlock
def _open_interlock_during(rig, after_pixels: int, delay_s: float, kind: str = "interlock_open"):
    inst, bench = rig["inst"], rig["bench"]
    when = {}

    def trip(ev):
        if ev.get("event") == "progress" and ev.get("pixels_done", 0) >= after_pixels and not when:
            if kind == "interlock_open":
                when["at_s"] = bench.clock.now() + delay_s
                inst.inject_fault("interlock_open", at_s=when["at_s"])
            else:
                when["at_s"] = bench.clock.now()
                inst.inject_fault(kind)
    return when, trip


def test_interlock_opening_mid_scan_brings_outputs_down_first_and_keeps_the_points(r):
    when, trip = _open_interlock_during(r, 100, 0.004)
    rec = _scan(r, on_progress=trip)
    assert when
    assert rec.state == "failed" and rec.partial
    assert "interlock" in rec.error and "read back" in rec.error
    assert 100 <= rec.pixels_scanned < N_PIX and rec.points > 0
    side = _sidecar(r, rec)
    safe = side["safe_state"]
    assert safe["safe"] and safe["laser_ma"] <= 0.5 and safe["hv_v"] <= 0.25
    assert not safe["laser_on"] and not safe["hv_on"]
    # time to safe state on the virtual clock: within one safety batch plus its transfer
    t_safe = safe["safe_at_s"] - when["at_s"]
    assert 0 < t_safe <= 2 * SAFETY_CHECK_S
    # points kept are from before the opening only: all valid ones are good ranges (0.8 / 0.9 m)
    pts = _points(r, rec)
    good = np.asarray(pts["valid"]) == 1
    assert np.all(np.abs(np.asarray(pts["range"])[good] - 0.85) < 0.06)
    _assert_nothing_lost(r, rec)
    st = r["bench"].controller.state
    assert not st.laser_on and not st.hv_on and st.hv_v < 0.25


def test_interlock_open_before_a_scan_refuses_cleanly(r):
    r["inst"].inject_fault("interlock_open")
    rec = _scan(r)
    assert rec.state == "failed" and "interlock" in rec.error.lower()
    assert rec.pixels_scanned == 0 and rec.files == {}


def test_hv_fault_mid_scan_takes_the_same_safe_path(r):
    when, trip = _open_interlock_during(r, 100, 0.0, kind="hv_fault")
    rec = _scan(r, on_progress=trip)
    assert when
    assert rec.state == "failed" and rec.partial and "HV_FAULT" in rec.error
    assert 100 <= rec.pixels_scanned < N_PIX
    safe = _sidecar(r, rec)["safe_state"]
    assert safe["safe"] and safe["hv_v"] <= 0.25 and not safe["laser_on"]
    _assert_nothing_lost(r, rec)


# ---------------------------------------------------------------------------------------- switch
def test_stuck_switch_is_found_by_the_selftest_job(r):
    r["inst"].inject_fault("stuck_switch", line="col", index=50, state="off")
    report = r["worker"].submit_selftest().result(timeout=WAIT_S)
    assert not report["ok"]
    assert [(s["line"], s["index"], s["state"]) for s in report["stuck"]] == [("col", 50, "off")]
    r["inst"].clear_faults()
    assert r["worker"].submit_selftest().result(timeout=WAIT_S)["ok"]


def test_digitizer_replugged_mid_scan_resumes_and_completes(r):
    inst = r["inst"]
    fired = []

    def replug(ev):
        if ev.get("event") == "progress" and ev.get("pixels_done", 0) >= 100 and not fired:
            # unplugged for 2 transfers; re-enumeration drops the armed acquisition
            fired.append(inst.inject_fault("usb_disconnect", device="digitizer", n=2))

    rec = _scan(r, on_progress=replug)
    assert fired
    assert rec.state == "done", rec.error
    _assert_complete(r, rec)
    side = _sidecar(r, rec)
    assert side["faults"]["resumes"] >= 1
    t = np.asarray(_points(r, rec)["t"])
    assert np.all(np.diff(np.sort(t)) >= 0) and t.max() < 1.0     # one continuous time axis
    _assert_nothing_lost(r, rec)


def test_interlock_during_linearization_fails_it_safely(r):
    inst, bench = r["inst"], r["bench"]
    inst.inject_fault("interlock_open", after_segments=40)        # inside the first ILC measurements
    with pytest.raises(Exception, match="interlock") as ei:
        r["worker"].submit_calibration().result(timeout=WAIT_S)
    assert "read back" in str(ei.value) or "interlock" in str(ei.value)
    st = bench.controller.state
    assert not st.laser_on and not st.hv_on and st.hv_v < 0.25


def test_child_bench_faults_travel_over_the_control_socket():
    cfg = load_config("config/sim.toml", environ=ENV)
    inst = open_instrument(cfg, bench="child")
    try:
        f = inst.inject_fault("usb_timeout", device="digitizer", n=1)
        assert f["kind"] == "usb_timeout" and "id" in f
        assert [x["kind"] for x in inst.active_faults()] == ["usb_timeout"]
        with pytest.raises(ValueError, match="gremlins"):
            inst.inject_fault("gremlins")
        assert inst.clear_faults() == 1 and inst.active_faults() == []
        inst.inject_fault("stuck_switch", line="row", index=9, state="off")
        rep = inst.selftest()
        assert [(s["line"], s["index"], s["state"]) for s in rep["stuck"]] == [("row", 9, "off")]
    finally:
        inst.close()


def test_adaptive_scan_failing_in_its_dense_pass_keeps_the_coarse_points(tmp_path):
    from tests.helpers.fakes import FakeInstrument

    class DenseFails(FakeInstrument):
        def run_scan(self, request, progress, cancel, calibration=None):
            if len(self.requests) == 1:           # the second run_scan is the dense pass
                self.requests.append(request)
                raise RuntimeError("digitizer: unplugged during the dense pass")
            return super().run_scan(request, progress, cancel, calibration)

    inst = DenseFails(hit=lambda r, c: True)
    store = Store(tmp_path)
    w = ScanWorker(inst, store, laser="dfb_default", optics=inst.optics)
    w.start()
    try:
        rec = w.wait(w.submit_scan(ScanRequest(pattern="adaptive", rows=(0, 16), cols=(0, 16))).id, 30)
    finally:
        w.stop()
    coarse = len(inst.requests[0].pixels)
    assert rec.state == "failed" and "dense pass" in rec.error
    assert rec.partial and rec.pixels_scanned == coarse and rec.points == coarse   # one hit per pixel
    assert len(PlyData.read(str(tmp_path / rec.files["ply"]))["vertex"]) == coarse
    store.close()


def test_devices_answers_busy_from_the_last_check_while_a_job_holds_the_instrument(r):
    inst = r["inst"]
    fresh = inst.devices()                                 # a real check: every device answers
    assert all(d["connected"] for d in fresh) and not any(d["busy"] for d in fresh)
    held, release = threading.Event(), threading.Event()

    def job():                                             # stands for a running scan
        with inst._lock:
            held.set()
            release.wait(WAIT_S)
    t = threading.Thread(target=job)
    t.start()
    try:
        assert held.wait(WAIT_S)
        busy = inst.devices()                              # does not wait for the job
        assert [d["name"] for d in busy] == [d["name"] for d in fresh]
        assert all(d["busy"] for d in busy)                # the last check, flagged as such
        assert [d["state"] for d in busy] == [d["state"] for d in fresh]
        assert [d["connected"] for d in busy] == [d["connected"] for d in fresh]
        assert [d["identity"] for d in busy] == [d["identity"] for d in fresh]
    finally:
        release.set()
        t.join(30)
    assert not any(d["busy"] for d in inst.devices())
