"""Driver <-> simulated controller over real Modbus TCP on 127.0.0.1."""

from __future__ import annotations

import math
import socket

import pytest
from pymodbus.client import ModbusTcpClient

from drivers.controller import protocol as p
from drivers.controller.driver import LaserHvController, SettleCheck
from drivers.errors import ProtocolError
from drivers.controller.errors import (
    ConfigError,
    DeviceBusy,
    DeviceFailure,
    DeviceFaulted,
    DeviceRefused,
    DeviceTimeout,
    DeviceUnreachable,
    IllegalAddress,
    IllegalFunction,
    InterlockOpen,
    LimitError,
    ModbusExceptionError,
    SettleError,
)

# LIMITS' ranges are asserted in messages below.
from .conftest import FAST_TIMEOUT_S, LIMITS, TIMEOUT_S


# --- round trips ----------------------------------------------------------------------------------
def test_identify(ctl):
    ident = ctl.identify()
    assert ident == p.Identity(model="LHV-1550", firmware="1.0", map_version=1)


def test_identify_refuses_another_map_version(clock):
    from sim_devices.controller import ControllerSim, ControllerSpec

    with ControllerSim(clock, spec=ControllerSpec(map_version=2, model="NEWER", firmware=(2, 7))) as newer:
        with LaserHvController("127.0.0.1", newer.port, timeout_s=TIMEOUT_S, limits=LIMITS) as c:
            with pytest.raises(ProtocolError, match="MAP_VERSION = 2"):
                c.identify()


def test_setpoints_round_trip(ctl, sim):
    ctl.set_laser_current_ma(123.45)
    ctl.set_tec_c(21.5)
    ctl.set_hv_v(32.0)
    assert ctl.laser_current_setpoint_ma() == pytest.approx(123.45, abs=1e-9)
    assert ctl.tec_setpoint_c() == pytest.approx(21.5, abs=1e-9)
    assert ctl.hv_setpoint_v() == pytest.approx(32.0, abs=1e-9)
    st = sim.state
    assert (st.laser_setpoint_ma, st.tec_setpoint_c, st.hv_setpoint_v) == pytest.approx((123.45, 21.5, 32.0))


def test_hold_voltage_round_trips_and_is_limit_checked(ctl, sim):
    ctl.set_hv_hold_v(30.5)
    assert ctl.hv_hold_setpoint_v() == pytest.approx(30.5, abs=1e-9)
    assert sim.state.hv_hold_setpoint_v == pytest.approx(30.5)
    with pytest.raises(LimitError, match="HV_HOLD_SETPOINT"):
        ctl.set_hv_hold_v(60.5)  # the deployment's HV limit applies to the hold rail too


def test_enables_round_trip_and_readbacks_follow_first_order_lag(ctl, sim, clock):
    ctl.set_laser_current_ma(100.0)
    ctl.set_hv_v(50.0)
    assert ctl.laser_current_ma() == 0.0  # setpoint alone does not drive current
    ctl.laser_enable(True)
    ctl.hv_enable(True)
    assert ctl.laser_is_on() and ctl.hv_is_on()
    assert sim.state.laser_on and sim.state.hv_on
    clock.advance(1e-3)  # one laser time constant, 0.2 HV time constants
    assert ctl.laser_current_ma() == pytest.approx(100.0 * (1 - math.exp(-1.0)), abs=0.01)
    assert ctl.hv_v() == pytest.approx(50.0 * (1 - math.exp(-0.2)), abs=0.01)
    ctl.laser_enable(False)
    ctl.hv_enable(False)
    assert not ctl.laser_is_on() and not ctl.hv_is_on()


def test_tec_readback_approaches_setpoint(ctl, clock):
    assert ctl.tec_c() == pytest.approx(25.0)
    ctl.set_tec_c(30.0)
    clock.advance(2.0)  # one TEC time constant
    assert ctl.tec_c() == pytest.approx(25.0 + 5.0 * (1 - math.exp(-1.0)), abs=0.01)
    assert ctl.flags().tec_settled is False
    clock.advance(30.0)
    assert ctl.tec_c() == pytest.approx(30.0, abs=0.01)
    assert ctl.flags().tec_settled is True


def test_status_uptime_and_heartbeat(ctl, sim, clock):
    clock.advance(1.5)
    assert ctl.uptime_s() == pytest.approx(1.5)
    h1 = ctl.heartbeat()
    h2 = ctl.heartbeat()
    assert h2 == h1 + 1
    s = ctl.status()
    assert s.uptime_ms == 1500 and s.heartbeat == h2 + 1 and s.faults == frozenset()


def test_interlock_and_flags(ctl, sim):
    assert ctl.interlock_closed() is True
    sim.set_interlock(False)
    assert ctl.interlock_closed() is False
    f = ctl.flags()
    assert f.interlock_closed is False and f.fault_active is True


# --- limits: driver refuses before sending; device refuses when bypassed --------------------------
@pytest.mark.parametrize(
    "method, value, quantity, rng",
    [
        ("set_laser_current_ma", 200.01, "LASER_CURRENT_SETPOINT", "[0, 200]"),
        ("set_laser_current_ma", -1.0, "LASER_CURRENT_SETPOINT", "[0, 200]"),
        ("set_hv_v", 60.5, "HV_SETPOINT", "[0, 60]"),
        ("set_tec_c", 17.0, "TEC_SETPOINT", "[18, 35]"),
        ("set_tec_c", math.nan, "TEC_SETPOINT", "[18, 35]"),
    ],
)
def test_driver_refuses_out_of_range_without_sending(ctl, sim, method, value, quantity, rng):
    ctl.identify()  # connection up, so a refused write would be visible as bytes
    sent, received = ctl.bytes_sent, sim.requests_received
    with pytest.raises(LimitError) as ei:
        getattr(ctl, method)(value)
    assert quantity in str(ei.value) and rng in str(ei.value) and repr(value) in str(ei.value)
    assert ctl.bytes_sent == sent
    assert sim.requests_received == received


@pytest.mark.parametrize(
    "method, value, register",
    [
        ("set_laser_current_ma", 250.01, "LASER_CURRENT_SETPOINT"),
        ("set_hv_v", 100.01, "HV_SETPOINT"),
        ("set_tec_c", 14.99, "TEC_SETPOINT"),
        ("set_tec_c", 40.5, "TEC_SETPOINT"),
    ],
)
def test_device_refuses_out_of_range_with_exception_3(wide, sim, method, value, register):
    before = sim.state
    with pytest.raises(DeviceRefused) as ei:
        getattr(wide, method)(value)
    assert ei.value.exception_code == 3
    assert ei.value.register == register and ei.value.value == pytest.approx(value)
    assert register in str(ei.value) and "ILLEGAL DATA VALUE" in str(ei.value)
    after = sim.state
    assert (after.laser_setpoint_ma, after.hv_setpoint_v, after.tec_setpoint_c) == \
        (before.laser_setpoint_ma, before.hv_setpoint_v, before.tec_setpoint_c)


def test_device_refuses_multi_register_write_atomically(sim):
    client = ModbusTcpClient("127.0.0.1", port=sim.port, timeout=TIMEOUT_S, retries=0)
    try:
        # current 100 mA and TEC 25 degC are fine, HV 150 V is not: nothing may change.
        rsp = client.write_registers(0, [10000, 2500, 15000], device_id=1)
        assert rsp.isError() and rsp.exception_code == 3
        assert sim.state.laser_setpoint_ma == 0.0
        rsp = client.write_registers(0, [10000, 2600, 5000], device_id=1)
        assert not rsp.isError()
        st = sim.state
        assert (st.laser_setpoint_ma, st.tec_setpoint_c, st.hv_setpoint_v) == pytest.approx((100.0, 26.0, 50.0))
        rsp = client.write_register(p.COMMAND.address, 0x1234, device_id=1)  # unknown command
        assert rsp.isError() and rsp.exception_code == 3
        rsp = client.read_input_registers(13, count=1, device_id=1)  # outside the map
        assert rsp.isError() and rsp.exception_code == 2
    finally:
        client.close()


# --- interlock ------------------------------------------------------------------------------------
def test_interlock_open_turns_laser_and_hv_off_in_readback(ctl, sim, settle):
    ctl.bring_up(150.0, 50.0, settle_check=settle)
    assert sim.state.laser_on and sim.state.hv_on
    sim.set_interlock(False)
    # immediately, without advancing the clock
    assert ctl.laser_is_on() is False and ctl.hv_is_on() is False
    assert ctl.laser_current_ma() == 0.0 and ctl.hv_v() == 0.0
    assert p.Fault.INTERLOCK_OPEN in ctl.faults()
    st = sim.state
    assert (st.laser_on, st.hv_on, st.laser_current_ma, st.hv_v) == (False, False, 0.0, 0.0)


def test_enable_refused_while_interlock_open_then_after_clear(ctl, sim):
    sim.set_interlock(False)
    with pytest.raises(InterlockOpen, match="laser enable"):
        ctl.laser_enable(True)
    with pytest.raises(InterlockOpen, match="HV enable"):
        ctl.hv_enable(True)
    assert not sim.state.laser_on and not sim.state.hv_on
    assert ctl.clear_faults() == {p.Fault.INTERLOCK_OPEN}  # cause still present
    sim.set_interlock(True)
    with pytest.raises(DeviceFaulted) as ei:  # latched until cleared
        ctl.laser_enable(True)
    assert ei.value.faults == {p.Fault.INTERLOCK_OPEN}
    assert ctl.clear_faults() == frozenset()
    ctl.laser_enable(True)
    assert sim.state.laser_on


def test_injected_fault_trips_outputs(ctl, sim, settle):
    ctl.bring_up(100.0, 40.0, settle_check=settle)
    sim.inject_fault(p.Fault.LASER_OVER_CURRENT)
    assert ctl.faults() == {p.Fault.LASER_OVER_CURRENT}
    assert not ctl.laser_is_on() and not ctl.hv_is_on()
    with pytest.raises(DeviceFaulted, match="bring_up.*LASER_OVER_CURRENT"):
        ctl.bring_up(100.0, 40.0, settle_check=settle)
    assert ctl.clear_faults() == frozenset()


# --- bring_up / bring_down ------------------------------------------------------------------------
def test_bring_up_and_down_read_back(ctl, sim, settle, clock):
    t0 = clock.now()
    status = ctl.bring_up(120.0, 50.0, settle_check=settle)
    assert status.laser_current_ma == pytest.approx(120.0, abs=settle.laser_tol_ma)
    assert status.hv_v == pytest.approx(50.0, abs=settle.hv_tol_v)
    assert clock.now() > t0  # waited in virtual time
    st = sim.state
    assert st.laser_on and st.hv_on
    status = ctl.bring_down(settle_check=settle)
    assert status.laser_current_ma <= settle.laser_tol_ma and status.hv_v <= settle.hv_tol_v
    st = sim.state
    assert not st.laser_on and not st.hv_on and st.laser_setpoint_ma == 0.0 and st.hv_setpoint_v == 0.0


def test_bring_up_uses_constructor_settle_check(sim, clock):
    sc = SettleCheck(sleep=clock.advance, poll_s=0.002)
    with LaserHvController("127.0.0.1", sim.port, timeout_s=TIMEOUT_S, limits=LIMITS, settle_check=sc) as c:
        c.bring_up(80.0, 32.0)  # 20x20 FPSA pull-in voltage
        assert sim.state.hv_v == pytest.approx(32.0, abs=sc.hv_tol_v)
        c.bring_down()
        assert sim.state.hv_v <= sc.hv_tol_v


def test_bring_up_without_settle_check_is_a_config_error(ctl):
    with pytest.raises(ConfigError, match="SettleCheck"):
        ctl.bring_up(10.0, 10.0)


def test_bring_up_refuses_limits_before_sending(ctl, sim, settle):
    ctl.identify()
    sent = ctl.bytes_sent
    with pytest.raises(LimitError, match="HV_SETPOINT"):
        ctl.bring_up(100.0, 75.0, settle_check=settle)
    assert ctl.bytes_sent == sent


def test_bring_up_with_interlock_open_enables_nothing(ctl, sim, settle):
    sim.set_interlock(False)
    with pytest.raises(InterlockOpen, match="bring_up"):
        ctl.bring_up(100.0, 50.0, settle_check=settle)
    assert not sim.state.laser_on and not sim.state.hv_on


def test_bring_up_waits_for_tec_and_names_it_when_it_does_not_settle(ctl, sim, clock):
    ctl.set_tec_c(35.0)  # 10 degC step, tau 2 s: ~9 s to come within 0.1 degC
    short = SettleCheck(sleep=clock.advance, timeout_s=1.0, poll_s=0.01)
    with pytest.raises(SettleError) as ei:
        ctl.bring_up(100.0, 50.0, settle_check=short)
    assert ei.value.quantity == "TEC temperature" and ei.value.setpoint == pytest.approx(35.0)
    assert "TEC temperature" in str(ei.value) and "35" in str(ei.value)
    assert not sim.state.laser_on and not sim.state.hv_on
    long = SettleCheck(sleep=clock.advance, timeout_s=20.0, poll_s=0.05)
    ctl.bring_up(100.0, 50.0, settle_check=long)
    assert sim.state.tec_c == pytest.approx(35.0, abs=0.1)


def test_bring_up_hv_not_settling_names_hv_and_switches_outputs_off(clock):
    from sim_devices.controller import ControllerSim, ControllerSpec, Dynamics

    with ControllerSim(clock, spec=ControllerSpec(dynamics=Dynamics(hv_tau_s=100.0))) as slow:
        sc = SettleCheck(sleep=clock.advance, timeout_s=0.5, poll_s=0.05)
        with LaserHvController("127.0.0.1", slow.port, timeout_s=TIMEOUT_S, limits=LIMITS) as c:
            with pytest.raises(SettleError, match="HV voltage readback .* setpoint 50 V") as ei:
                c.bring_up(100.0, 50.0, settle_check=sc)
            assert ei.value.unit == "V" and ei.value.waited_s >= 0.5
            assert not slow.state.hv_on and not slow.state.laser_on


# --- timeouts and exception responses ------------------------------------------------------------
def test_timeouts_retry_bounded_then_device_timeout(fast, sim):
    ctl = fast
    ctl.identify()
    received = sim.requests_received
    sim.inject_timeout(3)  # retries=2 -> 3 attempts, all unanswered
    with pytest.raises(DeviceTimeout) as ei:
        ctl.status()
    assert ei.value.device == "controller" and ei.value.command == "read status"
    assert ei.value.attempts == 3
    assert sim.requests_received - received == 3 and sim.responses_dropped == 3
    assert "controller" in str(ei.value) and "read status" in str(ei.value)
    # the driver recovers on the next call
    assert ctl.interlock_closed() is True


def test_timeouts_within_retry_budget_succeed(fast, sim):
    ctl = fast
    ctl.set_hv_v(12.5)
    sim.inject_timeout(2)
    assert ctl.hv_setpoint_v() == pytest.approx(12.5)
    assert sim.responses_dropped == 2


def test_write_retried_after_lost_reply_is_applied_once_in_effect(fast, sim):
    ctl = fast
    sim.inject_timeout(1)  # the write executes, its reply is lost, the retry repeats it
    ctl.set_laser_current_ma(42.0)
    assert sim.state.laser_setpoint_ma == pytest.approx(42.0)


def test_no_retries_means_one_attempt(sim):
    one_shot = LaserHvController("127.0.0.1", sim.port, timeout_s=FAST_TIMEOUT_S, retries=0, limits=LIMITS)
    one_shot.identify()
    received = sim.requests_received
    sim.inject_timeout(1)
    with pytest.raises(DeviceTimeout) as ei:
        one_shot.tec_c()
    assert ei.value.attempts == 1 and sim.requests_received - received == 1
    one_shot.close()


@pytest.mark.parametrize(
    "code, cls",
    [(1, IllegalFunction), (2, IllegalAddress), (3, DeviceRefused), (4, DeviceFailure),
     (6, DeviceBusy), (11, ModbusExceptionError)],
)
def test_exception_responses_map_to_typed_errors(ctl, sim, code, cls):
    sim.inject_exception(code)
    with pytest.raises(cls) as ei:
        ctl.tec_c()
    assert type(ei.value) is cls and ei.value.exception_code == code
    assert ei.value.register == "TEC_TEMPERATURE" and ei.value.operation == "read TEC temperature"
    assert ctl.tec_c() == pytest.approx(25.0)  # only one request was affected


def test_unreachable_port_is_device_unreachable():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    c = LaserHvController("127.0.0.1", port, timeout_s=TIMEOUT_S, limits=LIMITS)
    with pytest.raises(DeviceUnreachable, match=f"127.0.0.1:{port}"):
        c.identify()
    c.close()


@pytest.mark.parametrize(
    "kwargs",
    [dict(retries=-1), dict(timeout_s=0.0), dict(device_id=300), dict(limits="tight")],
)
def test_bad_driver_configuration(kwargs):
    args = dict(timeout_s=0.1, retries=1, limits=LIMITS) | kwargs
    with pytest.raises(ConfigError):
        LaserHvController("127.0.0.1", 502, **args)


def test_enable_requires_bool(ctl):
    with pytest.raises(TypeError, match="laser enable expects a bool"):
        ctl.laser_enable(1)


def test_wrong_unit_id_is_a_typed_device_failure(sim):
    with LaserHvController("127.0.0.1", sim.port, device_id=7, timeout_s=TIMEOUT_S, limits=LIMITS) as c:
        with pytest.raises(DeviceFailure) as ei:
            c.tec_c()
    assert ei.value.exception_code == 4 and ei.value.register == "TEC_TEMPERATURE"


def test_from_url_opens_the_same_driver_and_refuses_other_urls(sim):
    with LaserHvController.from_url(f"modbus+tcp://127.0.0.1:{sim.port}", limits=p.HARDWARE_LIMITS,
                                    timeout_s=0.5, retries=0) as c:
        assert (c.host, c.port) == ("127.0.0.1", sim.port)
        assert c.identify().map_version == p.MAP_VERSION
    assert LaserHvController.from_url("modbus+tcp://10.0.0.9", limits=p.HARDWARE_LIMITS).port == 502
    for bad in ("tcp://127.0.0.1:502", "modbus+tcp://:502", "modbus+tcp://h:99999", "modbus+tcp://h/x", 5):
        with pytest.raises(ConfigError, match="modbus\\+tcp") as ei:
            LaserHvController.from_url(bad, limits=p.HARDWARE_LIMITS)
        assert ei.value.device == "controller"
