"""The fixed numbers of the digitizer's wire format (docs/protocols/digitizer.md; §4.4.1): USB ids and
endpoints, the vendor request codes, the acquisition states, the channel bits (beat, I/Q beat,
monitor MZI and its quadrature, tap) and the sample formats (int8/int16 records, channel-major).

PURE, part of the codec ``drivers.digitizer.protocol``, which re-exports every name here and adds the
control payloads and the framed segment stream. The one error type of the codec is defined here.
"""

from __future__ import annotations

import enum
import struct

import numpy as np

from drivers.errors import ProtocolError


DIGITIZER_VID = 0x1209
DIGITIZER_PID = 0xA902
EP_DATA_IN = 0x81

REQTYPE_OUT = 0x40  # vendor | device | host-to-device
REQTYPE_IN = 0xC0   # vendor | device | device-to-host


class Req(enum.IntEnum):
    IDENTIFY = 0x01        # IN, 64 bytes ASCII "maker,model,serial,fw"
    SET_CHANNELS = 0x10    # OUT, wValue = channel mask
    SET_SAMPLE_RATE = 0x11  # OUT, data u64 Hz
    SET_RECORD_LENGTH = 0x12  # OUT, data u32 samples per channel
    SET_SEGMENTS = 0x13    # OUT, data u32 segments per acquisition
    SET_FORMAT = 0x14      # OUT, wValue = bits (8 | 16)
    SET_RANGE = 0x15       # OUT, data u32 full-scale input range in millivolts (peak)
    SET_RESOLUTION = 0x16  # OUT, wValue = resolution bits (8..format bits): quantization of the samples
    SET_BANDWIDTH = 0x17   # OUT, data u64 Hz: anti-alias low-pass corner (0 = full bandwidth)
    ARM = 0x20             # OUT, no data
    ABORT = 0x21           # OUT, no data
    GET_STATUS = 0x30      # IN, 16 bytes (see Status)
    GET_CONFIG = 0x31      # IN, 32 bytes (see Config)
    READ_SEGMENTS = 0x40   # OUT, data u32 first, u32 count -> stream on EP 0x81


CHANNEL_BITS = {"beat": 0x01, "beat_i": 0x02, "beat_q": 0x04, "mzi": 0x08, "tap": 0x10, "mzi_q": 0x20}
ALL_CHANNELS_MASK = 0x3F
MAGIC = b"DGSG"
VERSION = 1
HEADER = struct.Struct("<4sBBBBIIQII")
HEADER_LEN = HEADER.size  # 32
assert HEADER_LEN == 32


class DigitizerProtocolError(ProtocolError):
    """Digitizer bytes that cannot be decoded (bad magic, CRC, field values, lengths)."""

    DEVICE = "digitizer"


class State(enum.IntEnum):
    IDLE = 0
    ARMED = 1
    CAPTURING = 2
    DONE = 3


# --------------------------------------------------------------------------- channel masks


def channel_mask(channels: tuple[str, ...] | list[str]) -> int:
    mask = 0
    for ch in channels:
        try:
            bit = CHANNEL_BITS[ch]
        except KeyError:
            raise DigitizerProtocolError(f"unknown digitizer channel {ch!r}; known {sorted(CHANNEL_BITS)}") from None
        if mask & bit:
            raise DigitizerProtocolError(f"digitizer channel {ch!r} listed twice")
        mask |= bit
    validate_mask(mask)
    return mask


def validate_mask(mask: int) -> None:
    if mask <= 0 or mask & ~ALL_CHANNELS_MASK:
        raise DigitizerProtocolError(f"digitizer channel mask 0x{mask:02x} invalid")
    iq = mask & 0x06
    if iq and iq != 0x06:
        raise DigitizerProtocolError("I/Q option needs both beat_i and beat_q")
    if iq and mask & 0x01:
        raise DigitizerProtocolError("beat and beat_i/beat_q are exclusive (one ADC pair)")
    if mask & CHANNEL_BITS["mzi_q"] and not mask & CHANNEL_BITS["mzi"]:
        raise DigitizerProtocolError("mzi_q (the monitor's quadrature output) needs mzi (its in-phase output)")


def channels_of(mask: int) -> tuple[str, ...]:
    """Channel names in payload order (ascending mask bit)."""
    validate_mask(mask)
    return tuple(name for name, bit in sorted(CHANNEL_BITS.items(), key=lambda kv: kv[1]) if mask & bit)


def bytes_per_sample(bits: int) -> int:
    if bits not in (8, 16):
        raise DigitizerProtocolError(f"sample format must be 8 or 16 bits, got {bits}")
    return bits // 8


def sample_dtype(bits: int) -> np.dtype:
    return np.dtype("<i1") if bytes_per_sample(bits) == 1 else np.dtype("<i2")


def segment_bytes(n_channels: int, record_length: int, bits: int) -> int:
    return HEADER_LEN + n_channels * record_length * bytes_per_sample(bits)


def segment_dtype(n_channels: int, record_length: int, bits: int) -> np.dtype:
    """numpy record layout of one header+payload segment: lets both sides build and parse a
    whole batch of segments with vectorized field access instead of per-sample loops."""
    return np.dtype([
        ("magic", "S4"), ("version", "u1"), ("bits", "u1"), ("mask", "u1"), ("overrange", "u1"),
        ("index", "<u4"), ("n_samples", "<u4"), ("trigger_time_ns", "<u8"),
        ("payload_crc32", "<u4"), ("header_crc32", "<u4"),
        ("data", sample_dtype(bits), (n_channels, record_length)),
    ])


def overrange_flags(overrange: np.ndarray) -> np.ndarray:
    """bool (count, n_channels) -> u8 flags per segment, bit i = channel i."""
    ov = np.asarray(overrange, dtype=bool)
    weights = (1 << np.arange(ov.shape[1], dtype=np.uint16))
    return (ov.astype(np.uint16) @ weights).astype(np.uint8)
