"""PURE codec of the serial link between the host and the FPSA controller FPGA (§4.3.3, Fig. 4-22).

The FPGA (Digilent Cmod-S7) receives scan patterns "from a personal computer via serial
communications" (§4.3.3) and drives two HV583 serial-to-parallel high-voltage converters that
select one row switch and one column switch of the row-column addressed FPSA (§4.2.1). This
module is the wire format only: no I/O, no clock, no logging. The driver (``driver.py``) and the
simulated FPGA (``sim_devices/fpsa/device.py``) both use it, and docs/protocols/fpsa.md holds golden
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

Parts: this module is the framing (COBS, header, CRC), the parser and the ACK/NAK answers; the codes,
limits and checksums are ``protocol_codes.py``, the command payloads ``protocol_payloads.py``. Every
name of the codec is importable from here.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from cobs import cobs as _cobs

from drivers.errors import CrcError, FramingError, LengthError, PayloadError, ProtocolError, detached

from .errors import DEVICE, error_command
from .protocol_codes import (
    BITS_PER_BYTE_ON_WIRE,
    CHUNK_HEADER_LEN,
    CRC_LEN,
    DELIMITER,
    HEADER_LEN,
    MAX_CHUNK_PIXELS,
    MAX_ENCODED_LEN,
    MAX_PATTERN_PIXELS,
    MAX_PAYLOAD,
    MIN_INNER_LEN,
    NO_DETAIL,
    REQUEST_CMDS,
    Cmd,
    FaultFlag,
    NakCode,
    State,
    crc16_ccitt_false,
    crc32,
)
from .protocol_payloads import (
    DEFAULT_TIMING,
    Identity,
    PatternChunk,
    Status,
    Timing,
    decode_pattern_begin,
    decode_pattern_chunk,
    decode_set_pixel,
    encode_pattern_begin,
    encode_pattern_chunk,
    encode_set_pixel,
    pack_pixels,
    unpack_pixels,
)

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
        raise FramingError(f"COBS: {exc}", device=DEVICE) from None


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
        raise PayloadError(f"seq must be 0..255, got {seq!r}", device=DEVICE)
    if not 0 <= cmd <= 0xFF:
        raise PayloadError(f"cmd must be 0..255, got {cmd!r}", device=DEVICE)
    if len(payload) > MAX_PAYLOAD:
        raise LengthError(f"payload of {len(payload)} B exceeds MAX_PAYLOAD {MAX_PAYLOAD} B",
                          seq=seq, cmd=cmd, device=DEVICE, command=error_command(cmd))
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
        raise LengthError(f"frame of {n} B is shorter than the minimum {MIN_INNER_LEN} B", device=DEVICE)
    body, (crc_rx,) = inner[:-CRC_LEN], struct.unpack("<H", inner[-CRC_LEN:])
    crc_calc = crc16_ccitt_false(body)
    if crc_rx != crc_calc:
        raise CrcError(f"frame CRC 0x{crc_rx:04X} != computed 0x{crc_calc:04X}",
                       seq=inner[0], cmd=inner[1], device=DEVICE, command=error_command(inner[1]))
    (length,) = struct.unpack("<H", body[2:4])
    if length != n - MIN_INNER_LEN:
        raise LengthError(f"header length {length} B but {n - MIN_INNER_LEN} B of payload",
                          seq=inner[0], cmd=inner[1], device=DEVICE, command=error_command(inner[1]))
    return Frame(seq=body[0], cmd=body[1], payload=bytes(body[HEADER_LEN:]))


def decode_frame(wire: bytes) -> Frame:
    """Decode exactly one frame (with or without its trailing 0x00)."""
    if wire.endswith(b"\x00"):
        wire = wire[:-1]
    if b"\x00" in wire:
        raise FramingError("more than one frame (a 0x00 inside)", device=DEVICE)
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
                        f"no delimiter within {self.max_encoded_len} B: discarding until next 0x00", device=DEVICE))
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
                # kept in ``errors`` for the parser's life: without the frames it passed through (a
                # daemon's driver parses on the scan's thread, and a kept traceback pinned the scan's
                # whole call stack with its arrays, ~5 MB each, until 64 newer errors pushed it out)
                out.append(detached(exc))
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
            raise LengthError("ACK without the echoed request command", seq=frame.seq, cmd=frame.cmd,
                              device=DEVICE, command=error_command(frame.cmd))
        return Response(frame.seq, frame.payload[0], True, bytes(frame.payload[1:]))
    if frame.cmd == Cmd.NAK:
        if len(frame.payload) != 6:
            raise LengthError(f"NAK payload of {len(frame.payload)} B, expected 6",
                              seq=frame.seq, cmd=frame.cmd, device=DEVICE, command=error_command(frame.cmd))
        req, code, detail = struct.unpack("<BBI", frame.payload)
        try:
            nak = NakCode(code)
        except ValueError as exc:
            raise PayloadError(f"NAK with unknown code 0x{code:02X}", device=DEVICE) from exc
        return Response(frame.seq, req, False, b"", nak, None if detail == NO_DETAIL else detail)
    raise PayloadError(f"expected ACK or NAK, got command {cmd_name(frame.cmd)}", device=DEVICE)


def wire_time_s(n_bytes: int, baudrate: float) -> float:
    """Time ``n_bytes`` occupy an 8N1 UART line at ``baudrate`` (10 bit times per byte)."""
    return n_bytes * BITS_PER_BYTE_ON_WIRE / float(baudrate)


__all__ = ["BITS_PER_BYTE_ON_WIRE", "CHUNK_HEADER_LEN", "CRC_LEN", "Cmd", "DEFAULT_TIMING", "DELIMITER",
           "FaultFlag", "Frame", "FrameParser", "HEADER_LEN", "Identity", "MAX_CHUNK_PIXELS",
           "MAX_ENCODED_LEN", "MAX_PATTERN_PIXELS", "MAX_PAYLOAD", "MIN_INNER_LEN", "NO_DETAIL", "NakCode",
           "PatternChunk", "REQUEST_CMDS", "Response", "State", "Status", "Timing", "cmd_name", "cobs_decode",
           "cobs_encode", "crc16_ccitt_false", "crc32", "decode_frame", "decode_inner",
           "decode_pattern_begin", "decode_pattern_chunk", "decode_response", "decode_set_pixel",
           "encode_ack", "encode_frame", "encode_inner", "encode_nak", "encode_pattern_begin",
           "encode_pattern_chunk", "encode_set_pixel", "pack_pixels", "unpack_pixels", "wire_time_s"]
