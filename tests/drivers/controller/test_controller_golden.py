"""Golden Modbus TCP ADUs from docs/protocols/controller.md, checked on both sides of the wire.

Client side: pymodbus' socket framer must build exactly the documented request bytes and decode
the documented response bytes into the documented values. Server side: the simulated device,
put into the documented state, must answer the documented request with exactly the documented
response bytes (raw TCP socket, no pymodbus client involved).
"""

from __future__ import annotations

import re
import socket
from pathlib import Path

import pytest
from pymodbus.framer import FramerSocket
from pymodbus.pdu import DecodePDU, ExceptionResponse
from pymodbus.pdu.bit_message import WriteSingleCoilRequest
from pymodbus.pdu.register_message import (
    ReadInputRegistersRequest,
    ReadInputRegistersResponse,
    WriteSingleRegisterRequest,
    WriteSingleRegisterResponse,
)

from drivers.controller import protocol as p
from tests.helpers.deadlines import REPLY_S

DOC = Path(__file__).resolve().parents[3] / "docs" / "protocols" / "controller.md"


def _golden() -> dict[str, tuple[bytes, bytes]]:
    text = DOC.read_text()
    found = {}
    for name in ("G1", "G2", "G3", "G4", "G5", "G6"):
        req = re.search(rf"^{name} request:\s+([0-9A-Fa-f ]+)$", text, re.M)
        rsp = re.search(rf"^{name} response:\s+([0-9A-Fa-f ]+)$", text, re.M)
        assert req and rsp, f"{name} missing from {DOC}"
        found[name] = (bytes.fromhex(req.group(1)), bytes.fromhex(rsp.group(1)))
    return found


GOLDEN = _golden()


def _client_frame(pdu) -> bytes:
    return FramerSocket(DecodePDU(False)).buildFrame(pdu)


def _client_decode(data: bytes):
    used, pdu = FramerSocket(DecodePDU(False)).handleFrame(data, 0, 0)
    assert used == len(data) and pdu is not None
    return pdu


# --- client side (pymodbus framer) ---------------------------------------------------------------
def test_g1_read_laser_current_client_side():
    req, rsp = GOLDEN["G1"]
    assert _client_frame(ReadInputRegistersRequest(address=p.LASER_CURRENT.address, count=1,
                                                   dev_id=1, transaction_id=1)) == req
    pdu = _client_decode(rsp)
    assert isinstance(pdu, ReadInputRegistersResponse) and pdu.transaction_id == 1
    assert p.decode_value(p.LASER_CURRENT, pdu.registers) == pytest.approx(120.00)


def test_g2_refused_hv_write_client_side():
    req, rsp = GOLDEN["G2"]
    (word,) = p.encode_value(p.HV_SETPOINT, 150.0)
    assert _client_frame(WriteSingleRegisterRequest(address=p.HV_SETPOINT.address, registers=[word],
                                                    dev_id=1, transaction_id=2)) == req
    pdu = _client_decode(rsp)
    assert isinstance(pdu, ExceptionResponse)
    assert pdu.exception_code == p.ExceptionCode.ILLEGAL_DATA_VALUE and pdu.function_code == 0x86


def test_g3_refused_laser_enable_client_side():
    req, rsp = GOLDEN["G3"]
    assert _client_frame(WriteSingleCoilRequest(address=p.LASER_ENABLE.address, bits=[True],
                                                dev_id=1, transaction_id=3)) == req
    pdu = _client_decode(rsp)
    assert isinstance(pdu, ExceptionResponse)
    assert pdu.exception_code == p.ExceptionCode.SERVER_DEVICE_FAILURE


def test_g4_tec_write_echo_client_side():
    req, rsp = GOLDEN["G4"]
    (word,) = p.encode_value(p.TEC_SETPOINT, 25.0)
    assert _client_frame(WriteSingleRegisterRequest(address=p.TEC_SETPOINT.address, registers=[word],
                                                    dev_id=1, transaction_id=4)) == req
    pdu = _client_decode(rsp)
    assert isinstance(pdu, WriteSingleRegisterResponse) and pdu.registers == [word]


def test_g6_hold_voltage_write_client_side():
    req, rsp = GOLDEN["G6"]
    (word,) = p.encode_value(p.HV_HOLD_SETPOINT, 30.0)
    assert word == 3000
    assert _client_frame(WriteSingleRegisterRequest(address=p.HV_HOLD_SETPOINT.address,
                                                    registers=[word], dev_id=1, transaction_id=6)) == req
    pdu = _client_decode(rsp)
    assert isinstance(pdu, WriteSingleRegisterResponse) and pdu.registers == [word]


def test_g5_identity_client_side():
    req, rsp = GOLDEN["G5"]
    assert _client_frame(ReadInputRegistersRequest(address=0, count=6, dev_id=1, transaction_id=5)) == req
    ident = p.decode_identity(_client_decode(rsp).registers)
    assert ident == p.Identity(model="LHV-1550", firmware="1.0", map_version=1)


# --- server side (simulated device over a raw socket) ---------------------------------------------
def _exchange(port: int, request: bytes, expected_len: int) -> bytes:
    with socket.create_connection(("127.0.0.1", port), timeout=REPLY_S) as s:
        s.sendall(request)
        data = b""
        while len(data) < expected_len:
            chunk = s.recv(expected_len - len(data))
            if not chunk:
                break
            data += chunk
        return data


def test_server_answers_golden_requests_with_golden_responses():
    from sim_devices.clock import VirtualClock
    from sim_devices.controller.device import ControllerSim

    clock = VirtualClock()
    with ControllerSim(clock) as sim:
        # G1: laser running at 120.00 mA, settled (100 time constants)
        assert sim.model.write(p.Table.HOLDING, p.LASER_CURRENT_SETPOINT.address, [12000]) is None
        assert sim.model.write(p.Table.COIL, p.LASER_ENABLE.address, [True]) is None
        clock.advance(0.1)
        for name in ("G1", "G2", "G5"):
            req, rsp = GOLDEN[name]
            assert _exchange(sim.port, req, len(rsp)) == rsp, name
        # G3: interlock open -> enable refused
        sim.set_interlock(False)
        req, rsp = GOLDEN["G3"]
        assert _exchange(sim.port, req, len(rsp)) == rsp
        # G4: accepted write echoes the request
        req, rsp = GOLDEN["G4"]
        assert _exchange(sim.port, req, len(rsp)) == rsp
        assert sim.state.tec_setpoint_c == pytest.approx(25.0)
        # G6: the hold voltage is accepted and reaches the device state
        req, rsp = GOLDEN["G6"]
        assert _exchange(sim.port, req, len(rsp)) == rsp
        assert sim.state.hv_hold_setpoint_v == pytest.approx(30.0)
