"""Controller faults read through the real Modbus driver: exception answers, lost replies, an HV
supply trip and the interlock opening (at a virtual time, or mid-scan after N segments)."""


import numpy as np
import pytest
import usb.core

from drivers.controller.errors import (
    DeviceBusy,
    DeviceFailure,
    DeviceFaulted,
    DeviceTimeout,
    InterlockOpen,
)
from drivers.controller.protocol import Fault
from drivers.digitizer import protocol as dig_p
from drivers.digitizer.driver import DigitizerDriver
from sim_devices.digitizer.device import CaptureConfig
from tests.helpers.deadlines import REPLY_S
from tests.helpers.sim_bench import controller, fpsa, power_up, run_pattern

PIXELS = [[0, c] for c in range(10)]   # row 0 is bonded; one trigger per pixel


def test_modbus_exception_for_n_requests_executes_nothing(bench):
    ctl = controller(bench, busy_retries=0)
    bench.inject_fault("modbus_exception", code=6, n=2)
    for _ in range(2):
        with pytest.raises(DeviceBusy):
            ctl.set_hv_v(42.0)
    assert bench.controller.state.hv_setpoint_v == 0.0     # refused requests changed nothing
    ctl.set_hv_v(42.0)
    assert ctl.hv_setpoint_v() == pytest.approx(42.0)
    ctl.close()


def test_modbus_exception_until_cleared(bench):
    ctl = controller(bench)
    bench.inject_fault("modbus_exception", code=4)
    for _ in range(3):
        with pytest.raises(DeviceFailure):
            ctl.status()
    assert bench.clear_faults("modbus_exception") == 1
    assert ctl.status().faults == frozenset()
    ctl.close()


def test_modbus_timeout_loses_replies_but_requests_execute(bench):
    ctl = controller(bench, timeout_s=0.1, retries=0)           # each lost reply waits this long
    patient = controller(bench, timeout_s=REPLY_S, retries=0)  # the checks: a late reply is no loss
    bench.inject_fault("modbus_timeout", n=1)
    with pytest.raises(DeviceTimeout):
        ctl.set_tec_c(30.0)
    assert bench.controller.state.tec_setpoint_c == 30.0   # executed, only the reply was lost
    assert patient.tec_setpoint_c() == pytest.approx(30.0)
    bench.inject_fault("modbus_timeout")                     # until cleared
    for _ in range(2):
        with pytest.raises(DeviceTimeout):
            ctl.heartbeat()
    bench.clear_faults("modbus_timeout")
    assert patient.heartbeat() > 0
    ctl.close()
    patient.close()


def test_hv_fault_trips_to_zero_volts_and_stays_latched_until_cleared(bench):
    ctl = power_up(bench)
    assert ctl.hv_v() == pytest.approx(50.0, abs=0.1)
    bench.inject_fault("hv_fault")
    assert ctl.hv_v() == 0.0 and not ctl.hv_is_on()          # read back over Modbus
    assert Fault.HV_FAULT in ctl.faults()
    bench.clock.advance(1.0)
    assert ctl.clear_faults() == frozenset({Fault.HV_FAULT})  # the cause is still there
    with pytest.raises(DeviceFaulted):
        ctl.hv_enable(True)
    bench.clear_faults("hv_fault")
    assert Fault.HV_FAULT in ctl.faults()                     # latched until CLEAR_FAULTS
    assert ctl.clear_faults() == frozenset()
    ctl.bring_up(100.0, 50.0)
    assert ctl.hv_v() == pytest.approx(50.0, abs=0.1)
    ctl.close()


def _digitizer(bench, segments: int) -> tuple[DigitizerDriver, dig_p.Config]:
    dev = usb.core.find(idVendor=dig_p.DIGITIZER_VID, idProduct=dig_p.DIGITIZER_PID,
                        backend=bench.usb_backend)
    dig = DigitizerDriver(dev)
    cfg = dig.configure(channels=("tap",), sample_rate_hz=10e6, record_length=200,
                        segments=segments, bits=16, input_range_v=1.0)
    dig.arm()
    return dig, cfg


def _tap_v(samples: np.ndarray, cfg: dig_p.Config) -> np.ndarray:
    return samples[:, 0].mean(axis=1) * (cfg.input_range_mv / 1000.0) / 2 ** cfg.bits


def test_interlock_opens_mid_scan_after_n_segments(bench):
    ctl = power_up(bench)
    fp = fpsa(bench)
    fp.reset()
    run_pattern(fp, PIXELS)
    bench.inject_fault("interlock_open", after_segments=4)
    assert ctl.interlock_closed()            # nothing yet: no segment produced
    dig, cfg = _digitizer(bench, len(PIXELS))
    headers, samples = dig.read_segments(0, len(PIXELS), cfg)
    level = _tap_v(samples, cfg)
    one = bench.tap_volts_per_beam()
    assert np.allclose(level[:4], one, rtol=0.05)             # light for 4 segments ...
    assert np.all(np.abs(level[4:]) < 0.02 * one)              # ... then dark at once
    # the controller dropped laser and HV at once and latched INTERLOCK_OPEN
    assert not ctl.interlock_closed()
    assert ctl.laser_current_ma() == 0.0 and ctl.hv_v() == 0.0
    assert Fault.INTERLOCK_OPEN in ctl.faults()
    with pytest.raises(InterlockOpen):
        ctl.laser_enable(True)
    # clearing closes the loop; the latched fault still needs CLEAR_FAULTS
    bench.clear_faults("interlock_open")
    assert ctl.interlock_closed() and Fault.INTERLOCK_OPEN in ctl.faults()
    assert ctl.clear_faults() == frozenset()
    ctl.bring_up(100.0, 50.0)
    assert ctl.laser_is_on()
    fp.close()
    ctl.close()


def test_interlock_opens_at_a_virtual_time(bench):
    ctl = power_up(bench)
    fp = fpsa(bench)
    fp.reset()
    run_pattern(fp, PIXELS, trigger_period_ns=1_000_000, settle_ns=20_000)
    trig = bench.fpga.triggers(0, len(PIXELS), 0.0)
    at = float(trig.t_s[6]) - 1e-6            # between triggers 5 and 6
    bench.inject_fault("interlock_open", at_s=at)
    assert bench.controller.state.interlock_closed
    cc = CaptureConfig(10e6, 200, ("tap",), 16, 1.0)
    cap = bench.capture(0, len(PIXELS), cc)   # computed before the clock reaches at_s
    lsb = 1.0 / 2**16
    level = cap.codes[:, 0].mean(axis=1) * lsb
    one = bench.tap_volts_per_beam()
    assert np.allclose(level[:6], one, rtol=0.05) and np.all(np.abs(level[6:]) < 0.02 * one)
    bench.clock.advance_to(at - 1e-9)
    assert ctl.interlock_closed()
    bench.clock.advance_to(at + 1e-9)
    assert not ctl.interlock_closed() and Fault.INTERLOCK_OPEN in ctl.faults()
    assert ctl.hv_v() == 0.0
    fp.close()
    ctl.close()
