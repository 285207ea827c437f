"""The safety watch (issue 11, item 3): the host's interlock/fault check runs on its own thread at a
wall-clock period, so it trips while the scan thread is blocked in the DSP.

The DSP stage is replaced by one that blocks on an Event (never a sleep): while it is blocked the
interlock opens on the bench, and the monitor must have commanded laser and HV off and read them back
before the DSP call returns. Everything else is the real instrument on an embedded bench.
"""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument
from lidard.instrument import scan_loop
from lidard.instrument.points import PointBuffer
from lidard.instrument.safety import SafetyMonitor, SafetyWatch
from tests.helpers.deadlines import WAIT_S  # a deadline for a hung test
from tests.helpers.tolerances import NOMINAL_ENV

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def inst():
    cfg = load_config(REPO / "config" / "sim.toml", environ=dict(NOMINAL_ENV))
    i = open_instrument(cfg, scene_path=str(REPO / "config" / "scenes" / "cal_letters.toml"), bench="embedded")
    try:
        yield i
    finally:
        i.close()


def test_the_watch_trips_while_the_scan_thread_is_blocked_in_the_dsp(inst, monkeypatch):
    in_dsp, release = threading.Event(), threading.Event()
    seen: dict = {}
    original = PointBuffer.flush

    def blocking_flush(self):
        if not seen:                      # the first DSP batch: open the interlock, then block
            # the watch is running here (it ends once it trips, which may be before the main thread looks)
            seen["watching_before_fault"] = inst.safety.watching
            inst.inject_fault("interlock_open")
            in_dsp.set()
            seen["released"] = release.wait(WAIT_S)
            seen["tripped_before_return"] = inst.safety.tripped is not None
        return original(self)

    monkeypatch.setattr(PointBuffer, "flush", blocking_flush)
    monkeypatch.setattr(scan_loop, "BATCH_BYTES", 64 << 10)     # several DSP batches in a small scan
    out: dict = {}
    req = ScanRequest(pattern="roi", rows=(40, 48), cols=(40, 72), max_range_m=2.0)
    t = threading.Thread(target=lambda: out.update(res=inst.run_scan(req, lambda p: None, threading.Event())),
                         daemon=True)
    t.start()
    assert in_dsp.wait(WAIT_S), "the scan never reached the DSP"
    assert seen["watching_before_fault"] and inst.safety.period_s == 0.02      # [daemon] safety_period_s
    # the scan thread is inside the DSP call; the watch must trip on its own
    assert inst.safety.trip_event.wait(WAIT_S), "the safety watch did not trip while the DSP was busy"
    trip = inst.safety.tripped
    assert trip["by"] == "watch" and "interlock" in trip["reason"]
    assert trip["safe"]["safe"] and not trip["safe"]["laser_on"] and not trip["safe"]["hv_on"]
    assert "released" not in seen          # the DSP call has not returned yet
    release.set()
    t.join(WAIT_S)
    assert not t.is_alive()
    assert seen == {"watching_before_fault": True, "released": True, "tripped_before_return": True}
    res = out["res"]
    # the scan stops and keeps the points of the batch already in the DSP, as after a check-trip
    assert res.partial and "interlock" in res.stop_reason and "read back" in res.stop_reason
    assert res.meta["safe_state"]["detected_by"] == "watch"
    assert 0 < res.pixels_scanned < res.pixels_planned
    # the watch lives only while the outputs may be on
    assert not inst.safety.watching
    assert not [th for th in threading.enumerate() if th.name == "lidard-safety-watch"]


class _Flags:
    def __init__(self, interlock_closed=True, fault_active=False):
        self.interlock_closed, self.fault_active = interlock_closed, fault_active
        self.laser_on = self.hv_on = False


class _ScriptedController:
    """Flags from a list (one per read); records the commands in order."""

    def __init__(self, flags, hold_from: int | None = None):
        self._flags = list(flags)
        self.calls: list = []
        self.read = threading.Event()
        # reads from number ``hold_from`` (0-based) on wait for ``go``: the test decides when the watch
        # may see them (a watch thread spinning on a fake clock would otherwise race the caller)
        self.hold_from, self.go, self._reads = hold_from, threading.Event(), 0

    def flags(self):
        if self.hold_from is not None and self._reads >= self.hold_from:
            assert self.go.wait(WAIT_S), "the test never released the held flag read"
        self._reads += 1
        f = self._flags.pop(0) if len(self._flags) > 1 else self._flags[0]
        self.calls.append("flags")
        self.read.set()
        return f

    def faults(self):
        return set()

    def laser_enable(self, on):
        self.calls.append(("laser", on))

    def hv_enable(self, on):
        self.calls.append(("hv", on))

    def bring_down(self, settle_check):
        self.calls.append("bring_down")

    def set_laser_current_ma(self, v):
        self.calls.append(("laser_ma", v))

    def set_hv_v(self, v):
        self.calls.append(("hv_v", v))

    def status(self):
        return type("Status", (), {"laser_current_ma": 0.0, "hv_v": 0.0})()

    def interlock_closed(self):
        return True

    def bring_up(self, current_ma, hv_v, settle_check):
        self.calls.append("bring_up")


def _monitor(ctrl, period_s=0.005):
    return SafetyMonitor(ctrl, laser_current_ma=50.0, hv_v=50.0, sleep=lambda s: None, now=lambda: 0.0,
                         period_s=period_s)


def test_the_watch_trips_once_outputs_off_first_then_check_answers_its_reason():
    ctrl = _ScriptedController([_Flags(), _Flags(), _Flags(interlock_closed=False)], hold_from=2)
    mon = _monitor(ctrl)
    mon.bring_up()                     # the watch's third read (the open interlock) waits for this
    ctrl.go.set()
    assert mon.trip_event.wait(WAIT_S)
    assert mon.tripped["by"] == "watch"
    first_off = ctrl.calls.index(("laser", False))
    assert ctrl.calls[first_off:first_off + 3] == [("laser", False), ("hv", False), "flags"]   # readback
    assert ctrl.calls[first_off + 3:first_off + 5] == [("laser_ma", 0.0), ("hv_v", 0.0)]
    assert ctrl.calls[:first_off].count("flags") == 3          # tripped on the third read, not before
    assert mon.check() == "controller: interlock opened mid-scan"  # no new read: the watch's reason
    assert mon.trip("again") is mon.tripped["safe"]             # a second trip answers the first
    assert ctrl.calls.count(("laser", False)) == 1
    mon.bring_down()
    assert not mon.watching


def test_no_watch_thread_without_a_period_and_a_clean_session_stops_it():
    ctrl = _ScriptedController([_Flags()])
    mon = _monitor(ctrl, period_s=None)
    mon.bring_up()
    assert not mon.watching and ctrl.calls == ["bring_up"]
    mon.bring_down()
    mon = _monitor(_ScriptedController([_Flags()]))
    mon.bring_up()
    assert mon.watching
    assert mon.controller.read.wait(WAIT_S)                    # it reads the flags on its own
    mon.bring_down()
    assert not mon.watching and mon.tripped is None


@pytest.mark.parametrize("bad", [0, -0.01, 2.0, "fast"])
def test_a_bad_period_is_refused_naming_the_key(bad):
    with pytest.raises(Exception, match="safety_period_s"):
        SafetyWatch(_monitor(_ScriptedController([_Flags()])), bad)


def test_the_config_key_reaches_the_monitor_and_bad_values_are_refused():
    from lidard.config import ConfigError

    cfg = load_config(REPO / "config" / "sim.toml", environ={"LIDARD__DAEMON__SAFETY_PERIOD_S": "0.05"})
    assert cfg.daemon.safety_period_s == 0.05
    assert load_config(REPO / "config" / "sim.toml", environ={}).daemon.safety_period_s == 0.02
    with pytest.raises(ConfigError, match="safety_period_s"):
        load_config(REPO / "config" / "sim.toml", environ={"LIDARD__DAEMON__SAFETY_PERIOD_S": "0"})
