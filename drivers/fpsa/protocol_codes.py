"""The numbers of the FPSA serial protocol (docs/protocols/fpsa.md; §4.3.3): frame sizes and limits,
command, NAK, state and fault codes, and the two checksums (CRC-16/CCITT-FALSE over each frame,
CRC-32 end to end over pattern data). PURE: part of the codec ``drivers.fpsa.protocol``, which
re-exports every name here.
"""

from __future__ import annotations

import binascii
import zlib
from enum import IntEnum, IntFlag


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
