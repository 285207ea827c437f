"""Modbus TCP framing and the function codes the simulated controller answers (the server side of
docs/protocols/controller.md), as an asyncio protocol with no per-request task, future or thread hop.

Why not pymodbus' server: the daemon's safety check reads the controller's flags after every digitizer
read and the wall-clock watch fills the gaps, ~700 requests a full frame; pymodbus' server spent
~100 us of CPU a request on an idle machine (a task and a cross-thread future per request, its
datastore layers, its framer), mostly on the bench's interpreter lock beside the scan thread. This
serves the same bytes for every request the driver sends (the golden vectors and a differential test
against pymodbus' server, tests/sim_devices/controller/test_controller_modbus_tcp.py) for a fraction
of that. Requests outside the protocol get the Modbus specification's answers (exception 1, 2 or 3),
where pymodbus' answers varied (it answered some out-of-range reads with data).

:class:`ModbusDevice` is what a connection asks: ``request(unit, pdu) -> response pdu | None``.
"""

from __future__ import annotations

import asyncio
import struct
from typing import Protocol

from drivers.controller import protocol as p

MBAP = struct.Struct(">HHHB")    # transaction id, protocol id (0), length (unit + pdu), unit id
MAX_PDU = 253                    # Modbus PDU limit (a 260-byte ADU)

READ_TABLES = {1: p.Table.COIL, 2: p.Table.DISCRETE_INPUT, 3: p.Table.HOLDING, 4: p.Table.INPUT}
#: function code -> (table, most bits / registers a request may carry) for reads
READ_LIMITS = {1: 2000, 2: 2000, 3: 125, 4: 125}

ILLEGAL_FUNCTION, ILLEGAL_ADDRESS, ILLEGAL_VALUE = 1, 2, 3
TABLE_SIZE = {t: p.table_size(t) for t in p.Table}     # addresses each table holds, from 0


class ModbusDevice(Protocol):
    """The register images and write logic behind the wire (the controller model)."""

    def image(self, table: p.Table) -> list[int] | list[bool]: ...

    def write(self, table: p.Table, address: int, values: list[int] | list[bool]) -> p.ExceptionCode | None: ...


def exception_pdu(fc: int, code: int) -> bytes:
    return bytes((fc | 0x80, code))


def _bits_pdu(fc: int, bits: list[bool] | list[int]) -> bytes:
    packed = bytearray((len(bits) + 7) // 8)
    for i, b in enumerate(bits):
        if b:
            packed[i >> 3] |= 1 << (i & 7)
    return bytes((fc, len(packed))) + bytes(packed)


def _words_pdu(fc: int, words: list[int]) -> bytes:
    return bytes((fc, 2 * len(words))) + struct.pack(f">{len(words)}H", *words)


def _read(device: ModbusDevice, table: p.Table, address: int, count: int) -> list:
    img = device.image(table)
    return list(img[address:address + count])


def answer(device: ModbusDevice, pdu: bytes) -> bytes:
    """The response PDU to one request PDU (an exception PDU for anything refused)."""
    fc = pdu[0]
    try:
        if fc in READ_TABLES:
            address, count = struct.unpack_from(">HH", pdu, 1)
            table = READ_TABLES[fc]
            if not 1 <= count <= READ_LIMITS[fc]:
                return exception_pdu(fc, ILLEGAL_VALUE)
            if address + count > TABLE_SIZE[table]:
                return exception_pdu(fc, ILLEGAL_ADDRESS)
            values = _read(device, table, address, count)
            return _bits_pdu(fc, values) if fc <= 2 else _words_pdu(fc, values)
        if fc == 5:
            address, value = struct.unpack_from(">HH", pdu, 1)
            if value not in (0x0000, 0xFF00):
                return exception_pdu(fc, ILLEGAL_VALUE)
            return _written(device, fc, p.Table.COIL, address, [value == 0xFF00], pdu[:5])
        if fc == 6:
            address, value = struct.unpack_from(">HH", pdu, 1)
            return _written(device, fc, p.Table.HOLDING, address, [value], pdu[:5])
        if fc == 15:
            address, qty, nbytes = struct.unpack_from(">HHB", pdu, 1)
            if not 1 <= qty <= 1968 or nbytes != (qty + 7) // 8 or len(pdu) < 6 + nbytes:
                return exception_pdu(fc, ILLEGAL_VALUE)
            bits = [bool(pdu[6 + (i >> 3)] >> (i & 7) & 1) for i in range(qty)]
            return _written(device, fc, p.Table.COIL, address, bits, pdu[:5])
        if fc == 16:
            address, qty, nbytes = struct.unpack_from(">HHB", pdu, 1)
            if not 1 <= qty <= 123 or nbytes != 2 * qty or len(pdu) < 6 + nbytes:
                return exception_pdu(fc, ILLEGAL_VALUE)
            return _written(device, fc, p.Table.HOLDING, address, list(struct.unpack_from(f">{qty}H", pdu, 6)),
                            pdu[:5])
        if fc == 22:        # mask write: (current AND and_mask) OR (or_mask AND NOT and_mask)
            address, and_mask, or_mask = struct.unpack_from(">HHH", pdu, 1)
            if address >= TABLE_SIZE[p.Table.HOLDING]:
                return exception_pdu(fc, ILLEGAL_ADDRESS)
            current = int(device.image(p.Table.HOLDING)[address])
            value = (current & and_mask) | (or_mask & ~and_mask & 0xFFFF)
            return _written(device, fc, p.Table.HOLDING, address, [value], pdu[:7])
        if fc == 23:        # write, then read
            r_addr, r_qty, w_addr, w_qty, nbytes = struct.unpack_from(">HHHHB", pdu, 1)
            if not (1 <= r_qty <= 125 and 1 <= w_qty <= 121 and nbytes == 2 * w_qty and len(pdu) >= 10 + nbytes):
                return exception_pdu(fc, ILLEGAL_VALUE)
            if r_addr + r_qty > TABLE_SIZE[p.Table.HOLDING]:
                return exception_pdu(fc, ILLEGAL_ADDRESS)
            written = _written(device, fc, p.Table.HOLDING, w_addr, list(struct.unpack_from(f">{w_qty}H", pdu, 10)),
                               b"")
            if written:
                return written
            return _words_pdu(fc, _read(device, p.Table.HOLDING, r_addr, r_qty))
    except struct.error:
        return exception_pdu(fc, ILLEGAL_VALUE)        # a request shorter than its function's fields
    return exception_pdu(fc, ILLEGAL_FUNCTION)


def _written(device: ModbusDevice, fc: int, table: p.Table, address: int, values: list, echo: bytes) -> bytes:
    """The device's answer to a write: ``echo`` when accepted (an fc 15/16 echoes address and count)."""
    if address + len(values) > TABLE_SIZE[table]:
        return exception_pdu(fc, ILLEGAL_ADDRESS)
    code = device.write(table, address, values)
    return echo if code is None else exception_pdu(fc, int(code))


class Handler(Protocol):
    def request(self, unit: int, pdu: bytes) -> bytes | None: ...


class ModbusTcpConnection(asyncio.Protocol):
    """One client connection: MBAP frames in, ``handler.request``'s answers out (None: no answer, a
    reply lost on the wire). A frame whose header is not Modbus TCP closes the connection (the stream
    cannot be resynchronised)."""

    def __init__(self, handler: Handler, connections: set[asyncio.Transport]):
        self.handler, self.connections = handler, connections
        self.buf = b""
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport) -> None:
        self.transport = transport
        self.connections.add(transport)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.transport is not None:
            self.connections.discard(self.transport)

    def data_received(self, data: bytes) -> None:
        buf = self.buf + data
        while len(buf) >= MBAP.size:
            tid, proto, length, unit = MBAP.unpack_from(buf)
            if proto != 0 or not 2 <= length <= MAX_PDU + 1:
                assert self.transport is not None
                self.transport.close()
                self.buf = b""
                return
            end = 6 + length
            if len(buf) < end:
                break
            pdu, buf = buf[MBAP.size:end], buf[end:]
            rsp = self.handler.request(unit, pdu)
            if rsp is not None and self.transport is not None:
                self.transport.write(MBAP.pack(tid, 0, len(rsp) + 1, unit) + rsp)
        self.buf = buf
