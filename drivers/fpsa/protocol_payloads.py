"""Payload layouts of the FPSA serial protocol's commands and answers (docs/protocols/fpsa.md;
§4.3.3 and §4.2.1): SET_PIXEL, pattern upload (begin, chunks with their own CRC-32, pixel pairs),
the per-pixel timing block, the identity block and the status block. PURE: part of the codec
``drivers.fpsa.protocol``, which re-exports every name here; framing and the parser are there.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from drivers.errors import LengthError, PayloadError

from .errors import DEVICE
from .protocol_codes import CHUNK_HEADER_LEN, MAX_CHUNK_PIXELS, FaultFlag, State, crc32


def _expect_len(payload: bytes, n: int, what: str) -> None:
    if len(payload) != n:
        raise LengthError(f"{what}: expected {n} B of payload, got {len(payload)} B", device=DEVICE)


def encode_set_pixel(row: int, col: int) -> bytes:
    if not (0 <= row <= 0xFF and 0 <= col <= 0xFF):
        raise PayloadError(f"SET_PIXEL: row/col must fit u8, got ({row!r}, {col!r})", device=DEVICE)
    return struct.pack("<BB", row, col)


def decode_set_pixel(payload: bytes) -> tuple[int, int]:
    _expect_len(payload, 2, "SET_PIXEL")
    return payload[0], payload[1]


def pack_pixels(pixels: np.ndarray) -> bytes:
    """(n, 2) array of (row, col) -> interleaved u8 bytes r0 c0 r1 c1 ..."""
    arr = np.asarray(pixels)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise PayloadError(f"pixels must have shape (n, 2), got {arr.shape}", device=DEVICE)
    if arr.size and (arr.min() < 0 or arr.max() > 0xFF):
        raise PayloadError("pixel row/col must fit u8 (0..255)", device=DEVICE)
    return np.ascontiguousarray(arr, dtype=np.uint8).tobytes()


def unpack_pixels(data: bytes) -> np.ndarray:
    if len(data) % 2:
        raise LengthError(f"pixel data of {len(data)} B is not whole (row, col) pairs", device=DEVICE)
    return np.frombuffer(data, dtype=np.uint8).reshape(-1, 2)


def encode_pattern_begin(total: int, pattern_crc32: int) -> bytes:
    if not 0 <= total <= 0xFFFF:
        raise PayloadError(f"PATTERN_BEGIN: total must fit u16, got {total!r}", device=DEVICE)
    return struct.pack("<HI", total, pattern_crc32 & 0xFFFFFFFF)


def decode_pattern_begin(payload: bytes) -> tuple[int, int]:
    _expect_len(payload, 6, "PATTERN_BEGIN")
    total, crc = struct.unpack("<HI", payload)
    return total, crc


def encode_pattern_chunk(offset: int, pixel_bytes: bytes) -> bytes:
    """offset:u16 crc32:u32 then the (row, col) u8 pairs; the CRC covers the pairs only."""
    if not 0 <= offset <= 0xFFFF:
        raise PayloadError(f"PATTERN_CHUNK: offset must fit u16, got {offset!r}", device=DEVICE)
    if len(pixel_bytes) % 2:
        raise LengthError("PATTERN_CHUNK: pixel bytes are not whole pairs", device=DEVICE)
    if len(pixel_bytes) // 2 > MAX_CHUNK_PIXELS:
        raise LengthError(f"PATTERN_CHUNK: {len(pixel_bytes) // 2} pixels > {MAX_CHUNK_PIXELS}", device=DEVICE)
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
        raise LengthError(f"PATTERN_CHUNK: payload of {len(payload)} B is not 6 + 2n B", device=DEVICE)
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
                raise PayloadError(f"SET_TIMING: {name} must be an integer in 0..{lim}, got {v!r}", device=DEVICE)
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
                raise PayloadError(f"IDENTIFY: bonded row {r} outside 0..{self.rows - 1}", device=DEVICE)
            bitmap[r // 8] |= 1 << (r % 8)
        return (
            _fixed_ascii(self.vendor, 16) + _fixed_ascii(self.model, 16)
            + struct.pack("<BBBHH", *self.firmware, self.rows, self.cols) + bytes(bitmap)
        )

    @classmethod
    def unpack(cls, payload: bytes) -> Identity:
        if len(payload) < 39:
            raise LengthError(f"IDENTIFY: payload of {len(payload)} B shorter than 39 B", device=DEVICE)
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
        raise PayloadError(f"string {text!r} longer than {n} B", device=DEVICE)
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
            raise PayloadError(f"STATUS: unknown state {state}", device=DEVICE) from exc
        return cls(st, FaultFlag(faults), idx, pixels, triggers)
