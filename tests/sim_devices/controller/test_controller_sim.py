"""Simulated controller: device logic on the virtual clock, and server lifecycle."""

from __future__ import annotations

import asyncio
import math
import socket
import threading

import pytest
from pymodbus.client import ModbusTcpClient

from drivers.controller import protocol as p
from sim_devices.clock import VirtualClock
from sim_devices.controller.device import ControllerModel, ControllerSim, Dynamics
from tests.helpers.deadlines import REPLY_S

EC = p.ExceptionCode


@pytest.fixture
def clock():
    return VirtualClock()


@pytest.fixture
def model(clock):
    return ControllerModel(clock)


def _w(reg: p.Register, value: float) -> list[int]:
    return p.encode_value(reg, value)


# --- device logic (no network) -------------------------------------------------------------------
def test_first_order_lag_matches_analytic_curve(model, clock):
    d = model.dynamics
    assert model.write(p.Table.HOLDING, 0, _w(p.LASER_CURRENT_SETPOINT, 80.0) + _w(p.TEC_SETPOINT, 20.0)
                       + _w(p.HV_SETPOINT, 50.0)) is None
    assert model.write(p.Table.COIL, 0, [True, True]) is None
    for t in (0.5e-3, 1e-3, 3e-3, 10e-3):
        clock.advance_to(t)
        s = model.state
        assert s.laser_current_ma == pytest.approx(80.0 * (1 - math.exp(-t / d.laser_tau_s)), rel=1e-9)
        assert s.hv_v == pytest.approx(50.0 * (1 - math.exp(-t / d.hv_tau_s)), rel=1e-9)
        assert s.tec_c == pytest.approx(20.0 + 5.0 * math.exp(-t / d.tec_tau_s), rel=1e-9)


def test_lag_result_does_not_depend_on_how_often_it_is_sampled(clock):
    a, b = ControllerModel(clock), ControllerModel(clock)
    for m in (a, b):
        m.write(p.Table.HOLDING, p.HV_SETPOINT.address, _w(p.HV_SETPOINT, 50.0))
        m.write(p.Table.COIL, p.HV_ENABLE.address, [True])
    for _ in range(7):
        clock.advance(1e-3)
        _ = a.state  # a is sampled every ms, b only at the end
    assert a.state.hv_v == pytest.approx(b.state.hv_v, rel=1e-12)


def test_readbacks_in_input_registers_are_scaled(model, clock):
    model.write(p.Table.HOLDING, 0, [12345, 2750, 3200])  # 123.45 mA, 27.50 degC, 32.00 V
    model.write(p.Table.COIL, 0, [True, True])
    clock.advance(60.0)
    ir = model.image(p.Table.INPUT)
    assert ir[p.LASER_CURRENT.address] == 12345
    assert ir[p.TEC_TEMPERATURE.address] == 2750
    assert ir[p.HV_VOLTAGE.address] == 3200
    assert model.image(p.Table.DISCRETE_INPUT) == [True, True, True, False, True]


@pytest.mark.parametrize(
    "reg, value",
    [(p.LASER_CURRENT_SETPOINT, 250.01), (p.HV_SETPOINT, 100.01), (p.TEC_SETPOINT, 14.99),
     (p.TEC_SETPOINT, -5.0), (p.TEC_SETPOINT, 40.01)],
)
def test_device_refuses_values_outside_hardware_limits(model, reg, value):
    before = model.image(p.Table.HOLDING)
    assert model.write(p.Table.HOLDING, reg.address, _w(reg, value)) == EC.ILLEGAL_DATA_VALUE
    assert model.image(p.Table.HOLDING) == before


def test_device_accepts_hardware_limit_edges(model):
    assert model.write(p.Table.HOLDING, 0, _w(p.LASER_CURRENT_SETPOINT, 250.0)) is None
    assert model.write(p.Table.HOLDING, 1, _w(p.TEC_SETPOINT, 15.0)) is None
    assert model.write(p.Table.HOLDING, 2, _w(p.HV_SETPOINT, 100.0)) is None
    assert model.image(p.Table.HOLDING)[:3] == [25000, 1500, 10000]


def test_unmapped_write_address(model):
    # the first address past the map (HR 4 is HV_HOLD_SETPOINT since the hold drive, issue 15)
    assert model.write(p.Table.HOLDING, p.table_size(p.Table.HOLDING), [0]) == EC.ILLEGAL_DATA_ADDRESS
    assert p.table_size(p.Table.HOLDING) == 5
    assert model.write(p.Table.COIL, 1, [True, True]) == EC.ILLEGAL_DATA_ADDRESS
    assert model.write(p.Table.INPUT, 0, [0]) == EC.ILLEGAL_FUNCTION


def test_interlock_open_crowbars_outputs_and_latches(model, clock):
    model.write(p.Table.HOLDING, 0, [15000, 2500, 5000])
    model.write(p.Table.COIL, 0, [True, True])
    clock.advance(1.0)
    assert model.state.laser_current_ma == pytest.approx(150.0)
    model.set_interlock(False)
    s = model.state  # same virtual instant: no lag on the way down
    assert (s.laser_on, s.hv_on, s.laser_current_ma, s.hv_v) == (False, False, 0.0, 0.0)
    assert s.faults == {p.Fault.INTERLOCK_OPEN} and s.interlock_closed is False
    assert model.image(p.Table.COIL) == [False, False]
    assert model.write(p.Table.COIL, 0, [True]) == EC.SERVER_DEVICE_FAILURE
    assert model.write(p.Table.COIL, 0, [False]) is None  # switching off is always allowed
    model.set_interlock(True)
    assert model.state.laser_on is False  # closing does not re-enable
    assert model.write(p.Table.COIL, 1, [True]) == EC.SERVER_DEVICE_FAILURE  # still latched


def test_clear_faults_command(model):
    clear = [int(p.Command.CLEAR_FAULTS)]
    model.set_interlock(False)
    model.inject_fault(p.Fault.HV_FAULT)
    assert model.write(p.Table.HOLDING, p.COMMAND.address, clear) is None
    assert model.state.faults == {p.Fault.INTERLOCK_OPEN}  # cause still present
    model.set_interlock(True)
    model.write(p.Table.HOLDING, p.COMMAND.address, clear)
    assert model.state.faults == set()
    assert model.image(p.Table.HOLDING)[p.COMMAND.address] == p.Command.CLEAR_FAULTS
    assert model.write(p.Table.HOLDING, p.COMMAND.address, [0xBEEF]) == EC.ILLEGAL_DATA_VALUE


def test_uptime_counts_virtual_ms_and_wraps(clock):
    clock.advance(10.0)
    m = ControllerModel(clock)  # uptime counts from the model's power-up
    clock.advance(1.234)
    ir = m.image(p.Table.INPUT)
    assert p.decode_value(p.UPTIME_MS, ir[10:12]) == 1234
    clock.advance(2**32 / 1000.0)
    assert p.decode_value(p.UPTIME_MS, m.image(p.Table.INPUT)[10:12]) == 1234


def test_bad_dynamics_rejected():
    with pytest.raises(ValueError, match="hv_tau_s"):
        Dynamics(hv_tau_s=0.0)


# --- server lifecycle ----------------------------------------------------------------------------
def _sim_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("controller-sim")]


def test_start_stop_leaves_no_thread_and_frees_the_port(clock):
    sim = ControllerSim(clock)
    port = sim.start()
    assert port == sim.port and port > 0
    with pytest.raises(RuntimeError, match="already started"):
        sim.start()
    c = ModbusTcpClient("127.0.0.1", port=port, timeout=REPLY_S, retries=0)
    assert not c.read_discrete_inputs(0, count=1, device_id=1).isError()
    sim.stop()
    c.close()
    assert _sim_threads() == []
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
    with socket.socket() as s:  # the port is free again
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))
    sim.stop()  # idempotent


def test_two_sims_get_distinct_ports(clock):
    with ControllerSim(clock) as a, ControllerSim(clock) as b:
        assert a.port != b.port
    assert _sim_threads() == []


def test_start_async_inside_a_running_loop(clock):
    from drivers.controller.driver import LaserHvController

    async def main() -> tuple[str, bool]:
        sim = ControllerSim(clock)
        port = await sim.start_async()
        limits = p.Limits(max_laser_current_ma=200.0, max_hv_v=60.0, tec_range_c=(18.0, 35.0))

        def use() -> tuple[str, bool]:
            with LaserHvController("127.0.0.1", port, timeout_s=REPLY_S, limits=limits) as c:
                c.set_hv_v(50.0)
                c.hv_enable(True)
                return c.identify().model, c.hv_is_on()

        try:
            return await asyncio.to_thread(use)
        finally:
            await sim.stop_async()

    assert asyncio.run(main()) == ("LHV-1550", True)


def test_injected_exception_affects_exactly_n_requests(clock):
    with ControllerSim(clock) as sim:
        c = ModbusTcpClient("127.0.0.1", port=sim.port, timeout=REPLY_S, retries=0)
        try:
            sim.inject_exception(6, n=2)
            r1 = c.write_register(p.HV_SETPOINT.address, 1000, device_id=1)
            r2 = c.write_coil(p.HV_ENABLE.address, True, device_id=1)
            r3 = c.write_register(p.HV_SETPOINT.address, 2000, device_id=1)
            assert [r.isError() for r in (r1, r2, r3)] == [True, True, False]
            assert r1.exception_code == 6 and r2.exception_code == 6
            assert sim.state.hv_setpoint_v == pytest.approx(20.0) and not sim.state.hv_on
            assert sim.requests_received == 3
        finally:
            c.close()
        with pytest.raises(ValueError):
            sim.inject_exception(99)


def test_heartbeat_counts_requests(clock):
    with ControllerSim(clock) as sim:
        c = ModbusTcpClient("127.0.0.1", port=sim.port, timeout=REPLY_S, retries=0)
        try:
            beats = [c.read_input_registers(p.HEARTBEAT.address, count=1, device_id=1).registers[0]
                     for _ in range(3)]
        finally:
            c.close()
        assert beats[1] - beats[0] == 1 and beats[2] - beats[1] == 1
