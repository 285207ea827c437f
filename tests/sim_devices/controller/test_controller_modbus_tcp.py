"""The simulated controller's own Modbus TCP server against pymodbus' server (the reference it
replaced): the same response bytes for every well-formed request of the protocol, byte for byte, on
two devices in the same state; requests outside the protocol get the Modbus specification's
exception codes; several frames in one TCP segment are each answered."""

from __future__ import annotations

import asyncio
import socket
import struct
import threading

import pytest
from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusBaseServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from drivers.controller import protocol as p
from sim_devices.clock import VirtualClock
from sim_devices.controller.device import ControllerSim
from sim_devices.controller.model import ControllerModel
from tests.helpers.deadlines import REPLY_S, WAIT_S

_READ = {1: p.Table.COIL, 2: p.Table.DISCRETE_INPUT, 3: p.Table.HOLDING, 4: p.Table.INPUT}
_WRITE = {5: p.Table.COIL, 15: p.Table.COIL, 6: p.Table.HOLDING, 16: p.Table.HOLDING, 22: p.Table.HOLDING,
          23: p.Table.HOLDING}


def _words(bits) -> list[int]:
    out = [0] * ((len(bits) + 15) // 16)
    for i, b in enumerate(bits):
        if b:
            out[i // 16] |= 1 << (i % 16)
    return out


class _PymodbusReference:
    """The model served by pymodbus' TCP server through its simulator datastore (how the simulated
    controller was served before), on its own thread."""

    def __init__(self, model: ControllerModel):
        self.model = model
        self.port: int | None = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=asyncio.run, args=(self._main(),), daemon=True)

    async def _action(self, function_code, start_address, address, count, registers, set_values):
        if set_values is not None:
            code = self.model.write(_WRITE[function_code], address, set_values)
            if code is not None:
                return ExcCodes(int(code))
        table = _READ.get(function_code) or _WRITE[function_code]
        img = self.model.image(table)
        words = _words(img) if table in (p.Table.COIL, p.Table.DISCRETE_INPUT) else list(img)
        registers[0:len(words)] = words
        return None

    def _trace_pdu(self, sending, pdu):
        if not sending:
            self.model.heartbeat += 1
        return pdu

    async def _main(self):
        def bits(t):
            return [SimData(0, values=[False] * p.table_size(t), datatype=DataType.BITS)]

        def regs(t):
            return [SimData(0, values=[0] * p.table_size(t), datatype=DataType.REGISTERS)]

        dev = SimDevice(1, simdata=(bits(p.Table.COIL), bits(p.Table.DISCRETE_INPUT), regs(p.Table.HOLDING),
                                    regs(p.Table.INPUT)), action=self._action)
        server = ModbusTcpServer(dev, address=("127.0.0.1", 0), trace_pdu=self._trace_pdu)
        await server.serve_forever(background=True)
        self.port = server.transport.sockets[0].getsockname()[1]
        self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
        self._ready.set()
        await self._stop.wait()
        await server.shutdown()
        if ModbusBaseServer.active_server is server:
            ModbusBaseServer.active_server = None

    def __enter__(self):
        self._thread.start()
        assert self._ready.wait(WAIT_S)
        return self

    def __exit__(self, *exc):
        self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(WAIT_S)


def _frame(tid: int, pdu: bytes, unit: int = 1) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def _recv(sock: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = sock.recv(n - len(out))
        assert chunk, "connection closed mid-response"
        out += chunk
    return out


def _exchange(sock: socket.socket, req: bytes) -> bytes:
    """Send ``req`` (nothing if empty) and read one response ADU."""
    if req:
        sock.sendall(req)
    head = _recv(sock, 6)
    return head + _recv(sock, struct.unpack(">H", head[4:6])[0])


def _reg(r: p.Register, v: float) -> int:
    return p.encode_value(r, v)[0]


def _protocol_requests() -> list[bytes]:
    """Every function code of the protocol, whole tables and single registers, accepted writes and
    refused ones (over a hardware limit, an enable with the interlock open, an unmapped address)."""
    size = {t: p.table_size(t) for t in p.Table}
    pdus = [struct.pack(">BHH", fc, 0, size[t]) for fc, t in _READ.items()]
    pdus += [struct.pack(">BHH", fc, a, 1) for fc, t in _READ.items() for a in range(size[t])]
    pdus += [
        struct.pack(">BHH", 6, p.LASER_CURRENT_SETPOINT.address, _reg(p.LASER_CURRENT_SETPOINT, 120.0)),
        struct.pack(">BHH", 6, p.HV_SETPOINT.address, _reg(p.HV_SETPOINT, 50.0)),
        struct.pack(">BHH", 6, p.HV_SETPOINT.address, 65000),                           # over the limit
        struct.pack(">BHH", 5, p.HV_ENABLE.address, 0xFF00),
        struct.pack(">BHH", 5, p.LASER_ENABLE.address, 0xFF00),
        struct.pack(">BHH", 3, 0, size[p.Table.HOLDING]), struct.pack(">BHH", 1, 0, size[p.Table.COIL]),
        struct.pack(">BHHBB", 15, 0, 2, 1, 0b01),
        struct.pack(">BHHBH", 16, p.TEC_SETPOINT.address, 1, 2, _reg(p.TEC_SETPOINT, 24.0)),
        struct.pack(">BHHBH", 16, p.TEC_SETPOINT.address, 1, 2, _reg(p.TEC_SETPOINT, 99.0)),  # refused
        struct.pack(">BHHH", 22, p.TEC_SETPOINT.address, 0xFFFF, 0),
        struct.pack(">BHHHHBH", 23, 0, size[p.Table.HOLDING], p.TEC_SETPOINT.address, 1, 2,
                    _reg(p.TEC_SETPOINT, 25.0)),
        struct.pack(">BHH", 6, 60, 1),                                                    # unmapped
        struct.pack(">BHH", 2, 0, size[p.Table.DISCRETE_INPUT]), struct.pack(">BHH", 4, 0, size[p.Table.INPUT]),
    ]
    return [_frame(i + 1, pdu) for i, pdu in enumerate(pdus)]


def _interlock_sequence():
    """(action, requests) pairs: the protocol's requests, then with the interlock open."""
    reqs = _protocol_requests()
    return [(None, reqs), ("open", reqs + [_frame(900, struct.pack(">BHH", 5, p.HV_ENABLE.address, 0xFF00))])]


def test_the_same_bytes_as_pymodbus_server_for_every_request_of_the_protocol():
    clock = VirtualClock()
    ours = ControllerSim(clock)
    ref_model = ControllerModel(clock)
    with ours, _PymodbusReference(ref_model) as ref:
        with socket.create_connection(("127.0.0.1", ours.port), timeout=REPLY_S) as a, \
                socket.create_connection(("127.0.0.1", ref.port), timeout=REPLY_S) as b:
            n = 0
            for action, reqs in _interlock_sequence():
                if action == "open":
                    ours.set_interlock(False)
                    ref_model.set_interlock(False)
                for req in reqs:
                    clock.advance(0.003)        # the lags move between requests, alike on both
                    got, want = _exchange(a, req), _exchange(b, req)
                    assert got == want, f"request {req.hex()}: {got.hex()} != pymodbus {want.hex()}"
                    n += 1
    assert n > 40 and ours.requests_received == n


@pytest.mark.parametrize("pdu, code", [
    (struct.pack(">BHH", 1, 0, 0), 3),                       # no bits asked for
    (struct.pack(">BHH", 3, 0, 126), 3),                     # more registers than a frame carries
    (struct.pack(">BHH", 1, 0, p.table_size(p.Table.COIL) + 1), 2),   # past the table's end
    (struct.pack(">BHH", 4, 100, 1), 2),
    (struct.pack(">BHH", 5, p.HV_ENABLE.address, 0x1234), 3),         # a coil is 0xFF00 or 0x0000
    (struct.pack(">BHHBB", 15, 0, 2, 2, 0), 3),              # byte count does not match the quantity
    (struct.pack(">BH", 3, 0), 3),                           # shorter than its fields
    (struct.pack(">B", 7), 1), (struct.pack(">B", 43), 1),   # not a function of this device
])
def test_requests_outside_the_protocol_get_the_specifications_exception(pdu, code):
    with ControllerSim(VirtualClock()) as sim, socket.create_connection(("127.0.0.1", sim.port), timeout=REPLY_S) as s:
        rsp = _exchange(s, _frame(7, pdu))
        assert rsp[7:] == bytes((pdu[0] | 0x80, code)) and rsp[:2] == b"\x00\x07"
        assert sim.state.hv_on is False


def test_two_frames_in_one_segment_are_both_answered_and_a_foreign_header_closes_the_connection():
    with ControllerSim(VirtualClock()) as sim:
        with socket.create_connection(("127.0.0.1", sim.port), timeout=REPLY_S) as s:
            s.sendall(_frame(1, struct.pack(">BHH", 2, 0, 1)) + _frame(2, struct.pack(">BHH", 4, p.HEARTBEAT.address, 1)))
            first, second = _exchange(s, b""), _exchange(s, b"")
            assert first[:2] == b"\x00\x01" and second[:2] == b"\x00\x02" and second[7] == 4
            assert struct.unpack(">H", second[9:11])[0] == 2        # the heartbeat counted both
        with socket.create_connection(("127.0.0.1", sim.port), timeout=REPLY_S) as s:
            s.sendall(struct.pack(">HHHB", 1, 7, 6, 1) + struct.pack(">BHH", 2, 0, 1))   # protocol id 7
            assert s.recv(16) == b""                                  # closed, nothing answered
