"""Hardware limits, twice (issue 6): the driver refuses an over-limit setpoint before any byte is
sent, and the simulated controller refuses it on the wire when a raw Modbus client bypasses the
driver (exception 3, ILLEGAL DATA VALUE, setpoint unchanged).

The driver's limits here are the daemon's configured ones (lidard.config ``[devices.controller]``
``max_laser_current_ma`` / ``max_hv_v``, as lidard.instrument passes them); the device's are
``drivers.controller.protocol.HARDWARE_LIMITS`` (250 mA, 100 V, above the 50 V MEMS actuation of
§4.3). Properties over the whole value range, not a few picked points.
"""

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymodbus.client import ModbusTcpClient

from drivers.controller import protocol as p
from drivers.controller.driver import LaserHvController, SettleCheck
from drivers.controller.errors import LimitError
from lidard.config import Config
from sim_devices.clock import VirtualClock
from sim_devices.controller.device import ControllerSim
from tests.helpers.deadlines import REPLY_S

CFG = Config().devices.controller
DEPLOY = p.Limits(max_laser_current_ma=CFG.max_laser_current_ma, max_hv_v=CFG.max_hv_v, tec_range_c=(15.0, 40.0))
HW = p.HARDWARE_LIMITS
PROPS = settings(max_examples=120, derandomize=True, deadline=None,
                 suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def sim():
    s = ControllerSim(VirtualClock())
    s.start()
    yield s
    s.stop()


@pytest.fixture(scope="module")
def ctl(sim):
    c = LaserHvController("127.0.0.1", sim.port, timeout_s=REPLY_S, retries=0, limits=DEPLOY)
    c.identify()  # connected: a refused write would show up as bytes
    yield c
    c.close()


@pytest.fixture(scope="module")
def raw(sim):
    c = ModbusTcpClient("127.0.0.1", port=sim.port, timeout=REPLY_S, retries=0)
    yield c
    c.close()


def test_configured_limits_are_inside_the_hardware_limits():
    assert 0 < DEPLOY.max_hv_v <= HW.max_hv_v and 0 < DEPLOY.max_laser_current_ma <= HW.max_laser_current_ma
    assert DEPLOY.max_hv_v >= 50.0  # the 128x128 FPSA actuates at 50 V (§4.3)


over_hv = st.one_of(st.floats(min_value=DEPLOY.max_hv_v, exclude_min=True, allow_infinity=True),
                    st.floats(max_value=0.0, exclude_max=True, allow_infinity=True), st.just(math.nan))
over_ma = st.one_of(st.floats(min_value=DEPLOY.max_laser_current_ma, exclude_min=True, allow_infinity=True),
                    st.floats(max_value=0.0, exclude_max=True, allow_infinity=True), st.just(math.nan))


@PROPS
@given(which=st.sampled_from(["hv", "laser"]), data=st.data())
def test_driver_refuses_out_of_limit_setpoints_before_sending(ctl, sim, which, data):
    value = data.draw(over_hv if which == "hv" else over_ma)
    sent, received = ctl.bytes_sent, sim.requests_received
    before = sim.state
    with pytest.raises(LimitError) as ei:
        (ctl.set_hv_v if which == "hv" else ctl.set_laser_current_ma)(value)
    assert ("HV_SETPOINT" if which == "hv" else "LASER_CURRENT_SETPOINT") in str(ei.value)
    assert ctl.bytes_sent == sent and sim.requests_received == received
    assert (sim.state.hv_setpoint_v, sim.state.laser_setpoint_ma) == (before.hv_setpoint_v, before.laser_setpoint_ma)
    # bring_up checks both setpoints before touching anything either
    sc = SettleCheck(sleep=lambda dt_s: None)
    with pytest.raises(LimitError):
        if which == "hv":
            ctl.bring_up(current_ma=10.0, hv_v=value, settle_check=sc)
        else:
            ctl.bring_up(current_ma=value, hv_v=10.0, settle_check=sc)
    assert ctl.bytes_sent == sent and sim.requests_received == received


@PROPS
@given(which=st.sampled_from(["hv", "laser"]), word=st.integers(0, 0xFFFF), multi=st.booleans())
def test_device_refuses_raw_over_limit_words_on_the_wire(raw, sim, which, word, multi):
    reg = p.HV_SETPOINT if which == "hv" else p.LASER_CURRENT_SETPOINT
    limit = HW.max_hv_v if which == "hv" else HW.max_laser_current_ma
    value = p.decode_value(reg, [word])
    before = sim.state
    old = before.hv_setpoint_v if which == "hv" else before.laser_setpoint_ma
    if multi:  # fc 16 over the whole setpoint block; the other words are valid and unchanged
        block = [p.encode_value(p.LASER_CURRENT_SETPOINT, before.laser_setpoint_ma)[0],
                 p.encode_value(p.TEC_SETPOINT, before.tec_setpoint_c)[0],
                 p.encode_value(p.HV_SETPOINT, before.hv_setpoint_v)[0]]
        block[0 if which == "laser" else 2] = word
        rsp = raw.write_registers(p.LASER_CURRENT_SETPOINT.address, block, device_id=1)
    else:  # fc 6
        rsp = raw.write_register(reg.address, word, device_id=1)
    after = sim.state
    new = after.hv_setpoint_v if which == "hv" else after.laser_setpoint_ma
    if value <= limit:
        assert not rsp.isError() and new == pytest.approx(value)
    else:
        assert rsp.isError() and rsp.exception_code == p.ExceptionCode.ILLEGAL_DATA_VALUE
        assert new == old and after.tec_setpoint_c == before.tec_setpoint_c


@settings(max_examples=60, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(garbage=st.one_of(
    st.binary(min_size=1, max_size=64),
    # a valid MBAP header (protocol 0, unit 1) around a random PDU: reaches the PDU decoder
    st.builds(lambda tid, pdu: tid.to_bytes(2, "big") + b"\x00\x00" + (len(pdu) + 1).to_bytes(2, "big") + b"\x01" + pdu,
              st.integers(0, 0xFFFF), st.binary(min_size=1, max_size=20))))
def test_sim_controller_survives_raw_garbage_and_keeps_serving(sim, raw, garbage):
    """Raw bytes at the Modbus TCP port must not take the simulated device down."""
    import socket
    before = sim.state
    with socket.create_connection(("127.0.0.1", sim.port), timeout=2.0) as s:
        s.sendall(garbage)
        s.shutdown(socket.SHUT_WR)
        try:
            while s.recv(4096):  # whatever it answers (an exception response, or it closes)
                pass
        except OSError:
            pass
    after = sim.state
    assert (after.hv_setpoint_v, after.laser_setpoint_ma, after.hv_on, after.laser_on) == \
        (before.hv_setpoint_v, before.laser_setpoint_ma, before.hv_on, before.laser_on) or _was_a_valid_write(garbage)
    rsp = raw.read_input_registers(p.MAP_VERSION_REG.address, count=1, device_id=1)
    assert not rsp.isError() and rsp.registers == [p.MAP_VERSION]


def _was_a_valid_write(frame: bytes) -> bool:
    """A random PDU can be a well-formed write (fc 5/6/15/16); then a state change is legitimate."""
    return len(frame) >= 8 and frame[2:4] == b"\x00\x00" and frame[7] in (5, 6, 15, 16)
