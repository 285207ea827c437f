"""The instrument package's rooms on fake drivers: the Instrument protocol, device attribution, the
device registry, the acquisition lifecycle (order, re-reads, resume) and the safety monitor."""

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tests.helpers.fakes import FakeInstrument
from tests.helpers.deadlines import WAIT_S
from drivers.usbtmc import DeviceStall, DeviceTimeout
from lidard.config import load_config
from lidard.instrument import DeviceFault, InstrumentError, SegmentsLost
from lidard.instrument.acquisition import (BATCH_BACKOFF_S, BATCH_RETRIES, AcquisitionLifecycle,
                                           AcquisitionPlan)
from lidard.instrument.devices import DEVICE_NAMES, DeviceRegistry
from lidard.instrument.errors import describe_failure, on_device
from lidard.instrument.facade import LidarInstrument
from lidard.instrument.protocol import INSTRUMENT_MEMBERS, Instrument
from lidard.instrument.safety import SafetyMonitor

REPO = Path(__file__).resolve().parents[2]


# -- protocol -------------------------------------------------------------------------------------
def test_real_and_fake_instruments_provide_every_member_the_callers_use():
    assert set(INSTRUMENT_MEMBERS) == {n for n in vars(Instrument) if not n.startswith("_")} | {"simulated"}
    for cls in (LidarInstrument, FakeInstrument):
        missing = [n for n in INSTRUMENT_MEMBERS if n != "simulated" and not callable(getattr(cls, n, None))]
        assert missing == [], (cls.__name__, missing)
    assert isinstance(FakeInstrument(), Instrument)


# -- which device failed ----------------------------------------------------------------------------
def test_a_driver_failure_is_named_by_the_device_called_and_its_own_device_wins():
    with pytest.raises(DeviceFault) as ei:
        with on_device("fpsa", "start"):
            raise OSError("port gone")
    assert (ei.value.device, ei.value.command) == ("fpsa", "start")
    assert str(ei.value) == "fpsa: OSError: port gone" and isinstance(ei.value.__cause__, OSError)
    with pytest.raises(DeviceFault) as ei:
        with on_device("awg", "load drive"):
            raise DeviceTimeout("digitizer", "READ")      # the exception names its device itself
    assert ei.value.device == "digitizer"
    own = InstrumentError("awg: refusing drive waveform")
    with pytest.raises(InstrumentError) as ei:
        with on_device("awg", "load drive"):
            raise own
    assert ei.value is own                                   # our own errors pass unchanged
    assert describe_failure(ValueError("x")) == "instrument: ValueError: x"


# -- registry -------------------------------------------------------------------------------------
class _Dev:
    def __init__(self, name, log, fail=0):
        self.name, self.log, self.fail, self.reconnect_count = name, log, fail, 0

    def identify(self):
        return f"{self.name}-1"

    def _probe(self):
        self.log.append((self.name, "probe"))
        if self.fail:
            self.fail -= 1
            raise TimeoutError("no answer")
        return SimpleNamespace(faults={"b", "a"})

    status = errors = _probe

    def reconnect(self, *_):
        self.log.append((self.name, "reconnect"))
        self.reconnect_count += 1


def test_registry_checks_every_device_in_order_and_heals_with_one_reconnect():
    log = []
    reg = DeviceRegistry(**{n: _Dev(n, log, fail=(1 if n == "digitizer" else 2 if n == "controller" else 0))
                            for n in DEVICE_NAMES})
    reg.identify_all()
    out = reg.check_all()
    assert [e["name"] for e in out] == list(DEVICE_NAMES)
    by = {e["name"]: e for e in out}
    assert by["fpsa"]["connected"] and by["fpsa"]["faults"] == ["a", "b"] and by["fpsa"]["identity"] == "fpsa-1"
    assert by["digitizer"]["connected"] and by["digitizer"]["reconnected"]
    assert not by["controller"]["connected"] and "TimeoutError: no answer" in by["controller"]["faults"][0]
    assert log.count(("controller", "reconnect")) == 1


# -- acquisition lifecycle ------------------------------------------------------------------------
class _Recorder:
    """Records every driver call as (device, method); the digitizer fails reads as told."""

    def __init__(self, calls, name, read_failures=()):
        self.calls, self.name, self.read_failures = calls, name, list(read_failures)

    def __getattr__(self, method):
        def call(*args, **kw):
            self.calls.append((self.name, method))
            if method == "configure":
                return SimpleNamespace(channels=tuple(kw["channels"]))
            if method == "read_segments":
                if self.read_failures:
                    raise self.read_failures.pop(0)
                return [], np.zeros((args[1], 1, 4), np.int16)
        return call


def _lifecycle(read_failures=()):
    calls, slept = [], []
    devs = {n: _Recorder(calls, n, read_failures if n == "digitizer" else ()) for n in DEVICE_NAMES}
    lc = AcquisitionLifecycle(DeviceRegistry(**devs), load_config(REPO / "config" / "sim.toml"), slept.append)
    plan = AcquisitionPlan(np.array([[0, 0], [0, 1], [0, 2]]), 2, ("beat",), 1e6, 4, 16)
    return lc, plan, calls, slept


def test_ready_start_stop_drive_the_devices_in_the_one_order():
    lc, plan, calls, _ = _lifecycle()
    acq = lc.ready(plan, drive_v=np.linspace(-1, 1, 16))
    lc.start(acq)
    lc.stop(acq)
    order = [c for c in calls if c[1] in ("upload_waveform", "upload_pattern", "abort", "configure", "arm",
                                          "start", "stop")]
    assert order == [("awg", "upload_waveform"), ("fpsa", "upload_pattern"), ("digitizer", "abort"),
                     ("digitizer", "configure"), ("digitizer", "arm"), ("fpsa", "arm"), ("fpsa", "start"),
                     ("fpsa", "stop")]
    assert acq.plan.segments == 6 and not acq.started


def test_a_failed_read_is_re_read_with_doubling_backoff_then_segments_lost():
    lc, plan, _, slept = _lifecycle([DeviceTimeout("digitizer", "READ")] * 2)
    acq = lc.ready(plan)
    _, samples = lc.read(acq, 0, 6)
    assert samples.shape[0] == 6 and acq.faults["batch_retries"] == 2
    assert slept == [BATCH_BACKOFF_S, 2 * BATCH_BACKOFF_S]
    lc, plan, _, slept = _lifecycle([DeviceTimeout("digitizer", "READ")] * (BATCH_RETRIES + 1))
    with pytest.raises(SegmentsLost, match=r"segments 0\.\.5 could not be read after 4 attempts"):
        lc.read(lc.ready(plan), 0, 6)
    lc, plan, _, _ = _lifecycle([DeviceStall("digitizer", "READ")])
    with pytest.raises(SegmentsLost, match="refused"):
        lc.read(lc.ready(plan), 0, 6)


def test_restart_runs_the_rest_of_the_pattern_as_a_new_acquisition():
    lc, plan, calls, _ = _lifecycle()
    acq = lc.ready(plan)
    acq.faults["batch_retries"] = 3
    new = lc.restart(acq, 2)
    assert new.first_pixel == 2 and new.plan.pixels.tolist() == [[0, 2]] and new.plan.segments == 2
    assert new.faults is acq.faults and new.started
    n_ready = len(calls) - 8
    assert calls[n_ready:] == [("fpsa", "stop"), ("fpsa", "upload_pattern"), ("fpsa", "set_timing"),
                               ("digitizer", "abort"), ("digitizer", "configure"), ("digitizer", "arm"),
                               ("fpsa", "arm"), ("fpsa", "start")]


# -- safety ---------------------------------------------------------------------------------------
class _Controller:
    def __init__(self, interlock=True, fault=False, unreadable=False):
        self.calls, self.interlock, self.fault, self.unreadable = [], interlock, fault, unreadable

    def flags(self):
        if self.unreadable:
            raise TimeoutError("modbus")
        return SimpleNamespace(interlock_closed=self.interlock, fault_active=self.fault, laser_on=False, hv_on=False)

    def faults(self):
        return [SimpleNamespace(name="HV_FAULT")]

    def laser_enable(self, on):
        self.calls.append(("laser", on))

    def hv_enable(self, on):
        self.calls.append(("hv", on))

    def set_laser_current_ma(self, v):
        self.calls.append(("laser_ma", v))

    def set_hv_v(self, v):
        self.calls.append(("hv_v", v))

    def status(self):
        self.calls.append(("status", None))
        return SimpleNamespace(laser_current_ma=0.0, hv_v=0.0)


def _monitor(ctrl):
    t = iter(range(100))
    return SafetyMonitor(ctrl, laser_current_ma=50.0, hv_v=100.0, sleep=lambda s: None, now=lambda: float(next(t)))


def test_safety_check_fails_safe_and_trip_commands_outputs_off_before_the_readback():
    assert _monitor(_Controller()).check() is None
    assert "interlock opened" in _monitor(_Controller(interlock=False)).check()
    assert "HV_FAULT" in _monitor(_Controller(fault=True)).check()
    assert "unreadable" in _monitor(_Controller(unreadable=True)).check()
    ctrl = _Controller(interlock=False)
    safe = _monitor(ctrl).trip()
    assert ctrl.calls == [("laser", False), ("hv", False), ("status", None), ("laser_ma", 0.0), ("hv_v", 0.0)]
    assert safe["safe"] and safe["off_commanded_at_s"] < safe["safe_at_s"]


def test_the_config_names_its_file_for_a_child_bench(tmp_path):
    from lidard.config import Config

    cfg = load_config(REPO / "config" / "sim.toml", environ={})
    assert cfg.path == str(REPO / "config" / "sim.toml")
    assert Config.model_validate(cfg.model_dump()).path == cfg.path     # survives a re-validation
    assert load_config(None, environ={}).path is None


def test_the_api_and_the_job_queue_import_the_instrument_seam_without_the_hardware_stack():
    import subprocess

    code = ("import sys, lidard.jobs, lidard.api.deps, lidard.api.routers.sim; "
            "print(sorted(m for m in sys.modules if m.startswith(('drivers', 'sim_devices', 'lidard.dsp', "
            "'lidard.instrument.facade', 'lidard.instrument.compose'))))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=WAIT_S)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
