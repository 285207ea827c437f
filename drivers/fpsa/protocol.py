"""PURE codec of the serial link between the host and the FPSA controller FPGA (§4.3.3, Fig. 4-22).

The FPGA (Digilent Cmod-S7) receives scan patterns "from a personal computer via serial
communications" (§4.3.3) and drives two HV583 serial-to-parallel high-voltage converters that
select one row switch and one column switch of the row-column addressed FPSA (§4.2.1). This
module is the wire format only: no I/O, no clock, no logging. The driver (``driver.py``) and the
simulated FPGA (``sim_devices/fpga.py``) both use it, and docs/protocols/fpsa.md holds golden
byte vectors that tests check on both sides.

Wire format (all integers little-endian)::

    wire  = COBS(inner) 0x00                 -- 0x00 never appears inside a frame
    inner = seq:u8 cmd:u8 len:u16 payload[len] crc:u16
    crc   = CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0) over
            seq..payload; stored little-endian

A response echoes the request's ``seq``; its ``cmd`` is ``ACK`` (0x80) or ``NAK`` (0x81) and the
first payload byte echoes the request command. Pattern data carries an additional end-to-end
CRC-32 (IEEE 802.3, ``zlib.crc32``) per chunk and over the whole pattern, because the frame CRC
only protects the wire, not the FPGA's block RAM write path.

The parser (:class:`FrameParser`) accepts arbitrary byte chunks, resynchronises on the next 0x00
after garbage, and reports only :class:`ProtocolError` subclasses.
"""

from __future__ import annotations

import binascii
import struct
import zlib
from dataclasses import dataclass, field
from enum import IntEnum, IntFlag

import numpy as np
from cobs import cobs as _cobs

from .errors import CrcError, FramingError, LengthError, PayloadError, ProtocolError

DELIMITER = 0x00
HEADER_LEN = 4  # seq, cmd, len u16
CRC_LEN = 2
MIN_INNER_LEN = HEADER_LEN + CRC_LEN
MAX_PAYLOAD = 4096
# COBS adds one byte per 254 (plus one); anything longer than this cannot be a valid frame.
MAX_ENCODED_LEN = MIN_INNER_LEN + MAX_PAYLOAD + (MIN_INNER_LEN + MAX_PAYLOAD) // 254 + 2
CHUNK_HEADER_LEN = 6  # offset u16 + crc32 u32
MAX_CHUNK_PIXELS = (MAX_PAYLOAD - CHUNK_HEADER_LEN) // 2
MAX_PATTERN_PIXELS = 128 * 128  # the largest array of the dissertation, §4.3
NO_DETAIL = 0xFFFFFFFF
BITS_PER_BYTE_ON_WIRE = 10  # 8N1: start + 8 data + stop


class Cmd(IntEnum):
    IDENTIFY = 0x01
    RESET = 0x02
    SET_PIXEL = 0x03
    CLEAR = 0x04
    PATTERN_BEGIN = 0x10
    PATTERN_CHUNK = 0x11
    PATTERN_END = 0x12
    SET_TIMING = 0x20
    ARM = 0x21
    START = 0x22
    STOP = 0x23
    STATUS = 0x24
    ACK = 0x80
    NAK = 0x81


REQUEST_CMDS = frozenset(c for c in Cmd if c < 0x80)


class NakCode(IntEnum):
    BAD_CRC = 0x01
    BAD_LENGTH = 0x02
    UNKNOWN_CMD = 0x03
    BAD_ROW_UNBONDED = 0x04
    OUT_OF_RANGE = 0x05
    BAD_STATE = 0x06
    PATTERN_CRC = 0x07
    CHUNK_CRC = 0x08
    PATTERN_INCOMPLETE = 0x09
    BAD_TIMING = 0x0A


class State(IntEnum):
    IDLE = 0
    ARMED = 1
    RUNNING = 2
    DONE = 3
    FAULT = 4


class FaultFlag(IntFlag):
    NONE = 0
    HV_UNINITIALIZED = 0x0001  # HV583 latches hold power-up garbage: RESET required
    MULTI_ROW = 0x0002  # more than one row line was latched high (ghost beams possible)
    LINK_ERRORS = 0x0004  # at least one bad frame was received since the last STATUS
    PATTERN_INVALID = 0x0008  # the last PATTERN_END failed its checks


def crc16_ccitt_false(data: bytes, init: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE; ``binascii.crc_hqx`` is exactly this polynomial, unreflected."""
    return binascii.crc_hqx(data, init)


def crc32(data: bytes) -> int:
    """CRC-32/ISO-HDLC (zlib) of ``data``, used for pattern and chunk integrity."""
    return zlib.crc32(data) & 0xFFFFFFFF


# --- COBS -------------------------------------------------------------------------------------
# The `cobs` package (C extension, pure-Python fallback) does the byte stuffing; these wrappers
# keep the codec's names and turn its DecodeError into our typed FramingError.
def cobs_encode(data: bytes) -> bytes:
    """Consistent-overhead byte stuffing: output contains no 0x00 (Cheshire & Baker 1999)."""
    return _cobs.encode(bytes(data))


def cobs_decode(enc: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises :class:`FramingError` on malformed input."""
    try:
        return _cobs.decode(bytes(enc))
    except _cobs.DecodeError as exc:
        raise FramingError(f"COBS: {exc}") from None


# --- frames -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Frame:
    seq: int
    cmd: int
    payload: bytes = b""

    @property
    def cmd_name(self) -> str:
        return cmd_name(self.cmd)


def cmd_name(cmd: int) -> str:
    try:
        return Cmd(cmd).name
    except ValueError:
        return f"0x{cmd:02X}"


def encode_inner(seq: int, cmd: int, payload: bytes = b"") -> bytes:
    if not 0 <= seq <= 0xFF:
        raise PayloadError(f"seq must be 0..255, got {seq!r}")
    if not 0 <= cmd <= 0xFF:
        raise PayloadError(f"cmd must be 0..255, got {cmd!r}")
    if len(payload) > MAX_PAYLOAD:
        raise LengthError(f"payload of {len(payload)} B exceeds MAX_PAYLOAD {MAX_PAYLOAD} B",
                          seq=seq, cmd=cmd)
    body = struct.pack("<BBH", seq, cmd, len(payload)) + bytes(payload)
    return body + struct.pack("<H", crc16_ccitt_false(body))


def encode_frame(seq: int, cmd: int, payload: bytes = b"") -> bytes:
    """Complete wire bytes of one frame: COBS(inner) + 0x00."""
    return cobs_encode(encode_inner(seq, cmd, payload)) + b"\x00"


def decode_inner(inner: bytes) -> Frame:
    """Check CRC and length of a COBS-decoded frame; raises a :class:`ProtocolError` subclass."""
    n = len(inner)
    if n < MIN_INNER_LEN:
        # too short to carry a CRC: nothing in it (not even seq) can be trusted or answered
        raise LengthError(f"frame of {n} B is shorter than the minimum {MIN_INNER_LEN} B")
    body, (crc_rx,) = inner[:-CRC_LEN], struct.unpack("<H", inner[-CRC_LEN:])
    crc_calc = crc16_ccitt_false(body)
    if crc_rx != crc_calc:
        raise CrcError(f"frame CRC 0x{crc_rx:04X} != computed 0x{crc_calc:04X}",
                       seq=inner[0], cmd=inner[1])
    (length,) = struct.unpack("<H", body[2:4])
    if length != n - MIN_INNER_LEN:
        raise LengthError(f"header length {length} B but {n - MIN_INNER_LEN} B of payload",
                          seq=inner[0], cmd=inner[1])
    return Frame(seq=body[0], cmd=body[1], payload=bytes(body[HEADER_LEN:]))


def decode_frame(wire: bytes) -> Frame:
    """Decode exactly one frame (with or without its trailing 0x00)."""
    if wire.endswith(b"\x00"):
        wire = wire[:-1]
    if b"\x00" in wire:
        raise FramingError("more than one frame (a 0x00 inside)")
    return decode_inner(cobs_decode(wire))


@dataclass
class FrameParser:
    """Incremental frame parser: ``feed(bytes) -> list[Frame]``, resynchronising after garbage.

    Bad frames are dropped from the returned list and kept as :class:`ProtocolError` instances
    (``errors``, drained with :meth:`pop_errors`) so a device can NAK them and a driver can retry
    at once instead of waiting for a timeout. :meth:`feed_all` returns both, in wire order.
    """

    max_encoded_len: int = MAX_ENCODED_LEN
    errors: list[ProtocolError] = field(default_factory=list)
    error_count: int = 0
    _buf: bytearray = field(default_factory=bytearray)
    _discarding: bool = False

    def feed_all(self, data: bytes) -> list[Frame | ProtocolError]:
        out: list[Frame | ProtocolError] = []
        self._buf += data
        while True:
            end = self._buf.find(b"\x00")
            if end < 0:
                if len(self._buf) > self.max_encoded_len and not self._discarding:
                    out.append(FramingError(
                        f"no delimiter within {self.max_encoded_len} B: discarding until next 0x00"))
                    self._discarding = True
                if self._discarding:
                    self._buf.clear()
                break
            chunk = bytes(self._buf[:end])
            del self._buf[: end + 1]
            if self._discarding:
                self._discarding = False
                continue
            if not chunk:
                continue  # empty frame: a flush byte, ignored by design
            try:
                out.append(decode_inner(cobs_decode(chunk)))
            except ProtocolError as exc:
                out.append(exc)
        for item in out:
            if isinstance(item, ProtocolError):
                self.errors.append(item)
                self.error_count += 1
        del self.errors[:-64]  # bounded memory on a noisy line
        return out

    def feed(self, data: bytes) -> list[Frame]:
        return [f for f in self.feed_all(data) if isinstance(f, Frame)]

    def pop_errors(self) -> list[ProtocolError]:
        errs, self.errors = self.errors, []
        return errs

    def reset(self) -> None:
        self._buf.clear()
        self._discarding = False


# --- payloads ---------------------------------------------------------------------------------
def _expect_len(payload: bytes, n: int, what: str) -> None:
    if len(payload) != n:
        raise LengthError(f"{what}: expected {n} B of payload, got {len(payload)} B")


def encode_set_pixel(row: int, col: int) -> bytes:
    if not (0 <= row <= 0xFF and 0 <= col <= 0xFF):
        raise PayloadError(f"SET_PIXEL: row/col must fit u8, got ({row!r}, {col!r})")
    return struct.pack("<BB", row, col)


def decode_set_pixel(payload: bytes) -> tuple[int, int]:
    _expect_len(payload, 2, "SET_PIXEL")
    return payload[0], payload[1]


def pack_pixels(pixels: np.ndarray) -> bytes:
    """(n, 2) array of (row, col) -> interleaved u8 bytes r0 c0 r1 c1 ..."""
    arr = np.asarray(pixels)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise PayloadError(f"pixels must have shape (n, 2), got {arr.shape}")
    if arr.size and (arr.min() < 0 or arr.max() > 0xFF):
        raise PayloadError("pixel row/col must fit u8 (0..255)")
    return np.ascontiguousarray(arr, dtype=np.uint8).tobytes()


def unpack_pixels(data: bytes) -> np.ndarray:
    if len(data) % 2:
        raise LengthError(f"pixel data of {len(data)} B is not whole (row, col) pairs")
    return np.frombuffer(data, dtype=np.uint8).reshape(-1, 2)


def encode_pattern_begin(total: int, pattern_crc32: int) -> bytes:
    if not 0 <= total <= 0xFFFF:
        raise PayloadError(f"PATTERN_BEGIN: total must fit u16, got {total!r}")
    return struct.pack("<HI", total, pattern_crc32 & 0xFFFFFFFF)


def decode_pattern_begin(payload: bytes) -> tuple[int, int]:
    _expect_len(payload, 6, "PATTERN_BEGIN")
    total, crc = struct.unpack("<HI", payload)
    return total, crc


def encode_pattern_chunk(offset: int, pixel_bytes: bytes) -> bytes:
    """offset:u16 crc32:u32 then the (row, col) u8 pairs; the CRC covers the pairs only."""
    if not 0 <= offset <= 0xFFFF:
        raise PayloadError(f"PATTERN_CHUNK: offset must fit u16, got {offset!r}")
    if len(pixel_bytes) % 2:
        raise LengthError("PATTERN_CHUNK: pixel bytes are not whole pairs")
    if len(pixel_bytes) // 2 > MAX_CHUNK_PIXELS:
        raise LengthError(f"PATTERN_CHUNK: {len(pixel_bytes) // 2} pixels > {MAX_CHUNK_PIXELS}")
    return struct.pack("<HI", offset, crc32(pixel_bytes)) + bytes(pixel_bytes)


@dataclass(frozen=True)
class PatternChunk:
    offset: int
    crc32: int
    pixel_bytes: bytes

    @property
    def count(self) -> int:
        return len(self.pixel_bytes) // 2


def decode_pattern_chunk(payload: bytes) -> PatternChunk:
    if len(payload) < CHUNK_HEADER_LEN or (len(payload) - CHUNK_HEADER_LEN) % 2:
        raise LengthError(f"PATTERN_CHUNK: payload of {len(payload)} B is not 6 + 2n B")
    offset, crc = struct.unpack("<HI", payload[:CHUNK_HEADER_LEN])
    return PatternChunk(offset, crc, bytes(payload[CHUNK_HEADER_LEN:]))


@dataclass(frozen=True)
class Timing:
    """Per-pixel schedule the FPGA runs (all ns, u32 except the u16 trigger count).

    For pixel i the FPGA shifts row and column into the HV583s (0.8 us), latches, waits
    ``settle_ns`` for the MEMS switches (§4.3.6: up to 2.7 us), emits ``triggers_per_pixel``
    triggers ``trigger_period_ns`` apart, then waits ``dwell_ns`` after the last period.
    """

    settle_ns: int = 8_000
    dwell_ns: int = 0
    triggers_per_pixel: int = 1
    trigger_period_ns: int = 80_000  # one 80 us chirp per trigger, §4.4

    def pack(self) -> bytes:
        for name, lim in (("settle_ns", 0xFFFFFFFF), ("dwell_ns", 0xFFFFFFFF),
                          ("triggers_per_pixel", 0xFFFF), ("trigger_period_ns", 0xFFFFFFFF)):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or not 0 <= v <= lim:
                raise PayloadError(f"SET_TIMING: {name} must be an integer in 0..{lim}, got {v!r}")
        return struct.pack("<IIHI", self.settle_ns, self.dwell_ns, self.triggers_per_pixel,
                           self.trigger_period_ns)

    @classmethod
    def unpack(cls, payload: bytes) -> Timing:
        _expect_len(payload, 14, "SET_TIMING")
        return cls(*struct.unpack("<IIHI", payload))


DEFAULT_TIMING = Timing()


@dataclass(frozen=True)
class Identity:
    vendor: str
    model: str
    firmware: tuple[int, int, int]
    rows: int
    cols: int
    bonded_rows: tuple[int, ...]

    def pack(self) -> bytes:
        bitmap = bytearray((self.rows + 7) // 8)
        for r in self.bonded_rows:
            if not 0 <= r < self.rows:
                raise PayloadError(f"IDENTIFY: bonded row {r} outside 0..{self.rows - 1}")
            bitmap[r // 8] |= 1 << (r % 8)
        return (
            _fixed_ascii(self.vendor, 16) + _fixed_ascii(self.model, 16)
            + struct.pack("<BBBHH", *self.firmware, self.rows, self.cols) + bytes(bitmap)
        )

    @classmethod
    def unpack(cls, payload: bytes) -> Identity:
        if len(payload) < 39:
            raise LengthError(f"IDENTIFY: payload of {len(payload)} B shorter than 39 B")
        vendor = payload[:16].rstrip(b"\x00").decode("ascii", "replace")
        model = payload[16:32].rstrip(b"\x00").decode("ascii", "replace")
        major, minor, patch, rows, cols = struct.unpack("<BBBHH", payload[32:39])
        bitmap = payload[39:]
        _expect_len(bitmap, (rows + 7) // 8, "IDENTIFY bonded-rows bitmap")
        bonded = tuple(r for r in range(rows) if bitmap[r // 8] >> (r % 8) & 1)
        return cls(vendor, model, (major, minor, patch), rows, cols, bonded)


def _fixed_ascii(text: str, n: int) -> bytes:
    raw = text.encode("ascii")
    if len(raw) > n:
        raise PayloadError(f"string {text!r} longer than {n} B")
    return raw.ljust(n, b"\x00")


@dataclass(frozen=True)
class Status:
    state: State
    faults: FaultFlag
    pattern_index: int
    pixel_counter: int
    trigger_counter: int

    def pack(self) -> bytes:
        return struct.pack("<BHHII", int(self.state), int(self.faults), self.pattern_index,
                           self.pixel_counter, self.trigger_counter)

    @classmethod
    def unpack(cls, payload: bytes) -> Status:
        _expect_len(payload, 13, "STATUS")
        state, faults, idx, pixels, triggers = struct.unpack("<BHHII", payload)
        try:
            st = State(state)
        except ValueError as exc:
            raise PayloadError(f"STATUS: unknown state {state}") from exc
        return cls(st, FaultFlag(faults), idx, pixels, triggers)


# --- responses --------------------------------------------------------------------------------
def encode_ack(seq: int, request_cmd: int, data: bytes = b"") -> bytes:
    return encode_frame(seq, Cmd.ACK, bytes([request_cmd]) + bytes(data))


def encode_nak(seq: int, request_cmd: int, code: NakCode, detail: int | None = None) -> bytes:
    d = NO_DETAIL if detail is None else int(detail)
    return encode_frame(seq, Cmd.NAK, struct.pack("<BBI", request_cmd, int(code), d))


@dataclass(frozen=True)
class Response:
    seq: int
    request_cmd: int
    ok: bool
    data: bytes = b""
    code: NakCode | None = None
    detail: int | None = None


def decode_response(frame: Frame) -> Response:
    if frame.cmd == Cmd.ACK:
        if len(frame.payload) < 1:
            raise LengthError("ACK without the echoed request command", seq=frame.seq, cmd=frame.cmd)
        return Response(frame.seq, frame.payload[0], True, bytes(frame.payload[1:]))
    if frame.cmd == Cmd.NAK:
        if len(frame.payload) != 6:
            raise LengthError(f"NAK payload of {len(frame.payload)} B, expected 6",
                              seq=frame.seq, cmd=frame.cmd)
        req, code, detail = struct.unpack("<BBI", frame.payload)
        try:
            nak = NakCode(code)
        except ValueError as exc:
            raise PayloadError(f"NAK with unknown code 0x{code:02X}") from exc
        return Response(frame.seq, req, False, b"", nak, None if detail == NO_DETAIL else detail)
    raise PayloadError(f"expected ACK or NAK, got command {cmd_name(frame.cmd)}")


def wire_time_s(n_bytes: int, baudrate: float) -> float:
    """Time ``n_bytes`` occupy an 8N1 UART line at ``baudrate`` (10 bit times per byte)."""
    return n_bytes * BITS_PER_BYTE_ON_WIRE / float(baudrate)
